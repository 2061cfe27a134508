"""`jaxplan export`: Crazyswarm CSVs read back as Crazyswarm reads them, within 1 cm of
the executed pieces in at most 31 pieces; an MCAP file read back with the mcap reader.

The synthetic runs below are written by hand (no JAX); the tiny scenario's planner run
(conftest's, shared) in the fast tier, the four paper scenarios in the slow tier.
"""

import json
from pathlib import Path

import numpy as np
import pytest

from jaxplan.cli import main
from jaxplan.export import ExportError, export_run
from jaxplan.metrics import sample_pieces

ROOT = Path(__file__).resolve().parents[1]
PAPER = ("six_neos", "eight_fireflys_stacked", "eight_mixed_transitions", "ten_mixed_rest")

# ------------------------------------------------------------------ Crazyswarm's reader


def crazyswarm_csv(path):
    """What uav_trajectory.Trajectory.loadcsv reads: (durations (P,), x, y, z, yaw
    coefficients (P, 4, 8)), numpy.loadtxt exactly as it calls it."""
    data = np.loadtxt(path, delimiter=",", skiprows=1, usecols=range(33))
    assert data.ndim == 2 and data.shape[1] == 33  # (a single row would break loadcsv)
    return data[:, 0], data[:, 1:].reshape(-1, 4, 8)


def crazyswarm_eval(durations, coeffs, t, derivative=0):
    """Trajectory.eval at each t (K,): the first piece with t <= start + duration,
    Horner in the piece's own time -> (K, 4)."""
    ends = np.cumsum(durations)
    k = np.minimum(np.searchsorted(ends, t, side="left"), len(durations) - 1)
    tau = t - (ends[k] - durations[k])
    c = coeffs[k]
    for _ in range(derivative):
        c = c[..., 1:] * np.arange(1, c.shape[-1])
    y = np.zeros(c.shape[:2])
    for j in range(c.shape[-1] - 1, -1, -1):
        y = y * tau[:, None] + c[..., j]
    return y


def check_crazyswarm(run_dir, out, height=1.0):
    """Every robot's CSV within 1 cm of trajectories.npz's pieces on a 1 ms grid, at
    most 31 pieces, C2 at the joins; returns [(pieces, max error m)] per robot."""
    with np.load(Path(run_dir) / "trajectories.npz", allow_pickle=False) as z:
        seg = tuple(z[k] for k in ("seg_robot", "seg_t0", "seg_t1", "seg_coeffs"))
        m = z["pos"].shape[0]
    n = seg[3].shape[1]
    rows = []
    for i in range(m):
        durations, coeffs = crazyswarm_csv(out / f"robot_{i}.csv")
        assert 2 <= durations.size <= 31 and np.all(durations > 0)
        start = seg[1].min()  # every CSV's t = 0: the run's first piece's start
        assert durations.sum() == pytest.approx(seg[2][seg[0] == i].max() - start, abs=1e-9)
        t = np.arange(0.0, durations.sum(), 1e-3)
        y = crazyswarm_eval(durations, coeffs, t)
        p = sample_pieces(*seg, start + t, m, outside="clamp")[0][i]
        err = np.linalg.norm(y[:, :n] - p, axis=1)
        assert err.max() <= 0.01, f"robot {i}: {err.max()} m"
        assert np.all(y[:, 3] == 0)  # yaw
        if n == 2:
            assert np.all(y[:, 2] == height)
        # continuous in position, velocity and acceleration at every join
        joins = np.cumsum(durations)[:-1]
        for d, tol in ((0, 1e-9), (1, 1e-7), (2, 1e-5)):
            left = np.array([crazyswarm_eval(durations[k:k + 1], coeffs[k:k + 1],
                                             np.array([durations[k]]), d)[0]
                             for k in range(joins.size)])
            right = coeffs[1:, :, d] * [1, 1, 2][d]
            assert np.allclose(left, right, atol=tol)
        rows.append((durations.size, float(err.max())))
    return rows


# ------------------------------------------------------------------ synthetic runs


def _hermite(p0, v0, a0, p1, v1, a1, h):
    """Quintic monomials (lowest power first, seconds) through both ends' p, v, a."""
    A = np.array([[1, 0, 0, 0, 0, 0], [0, 1, 0, 0, 0, 0], [0, 0, 2, 0, 0, 0],
                  [1, h, h**2, h**3, h**4, h**5], [0, 1, 2 * h, 3 * h**2, 4 * h**3, 5 * h**4],
                  [0, 0, 2, 6 * h, 12 * h**2, 20 * h**3]], dtype=float)
    return np.linalg.solve(A, np.stack([p0, v0, a0, p1, v1, a1])).T  # (N, 6)


def write_synthetic_run(path, freqs, amp=0.5, duration=10.0, dim=3, world=None):
    """A run directory whose robot i follows a sum of sines of frequency freqs[i] Hz
    (amplitude amp m per axis), as C2 quintic pieces of 0.125 s; limits 2, 4, 12."""
    path.mkdir(parents=True, exist_ok=True)
    m = len(freqs)
    knots = np.linspace(0.0, duration, int(round(duration * 8)) + 1)
    t = np.linspace(0.0, duration, int(round(duration * 100)) + 1)
    phase = np.arange(dim) * 0.7

    def f(i, tt, d):
        w = 2 * np.pi * freqs[i]
        arg = w * tt[:, None] + phase + i
        base = (np.sin, np.cos, lambda x: -np.sin(x))[d](arg) * amp * w**d
        return base + (np.array([i, 0.0, 1.5][:dim]) if d == 0 else 0.0)

    seg_robot, seg_t0, seg_t1, seg_coeffs = [], [], [], []
    for i in range(m):
        P, V, A = (f(i, knots, d) for d in range(3))
        for k in range(knots.size - 1):
            seg_robot.append(i)
            seg_t0.append(knots[k])
            seg_t1.append(knots[k + 1])
            seg_coeffs.append(_hermite(P[k], V[k], A[k], P[k + 1], V[k + 1], A[k + 1],
                                       knots[k + 1] - knots[k]))
    arrays = dict(
        t=t, pos=np.stack([f(i, t, 0) for i in range(m)]),
        vel=np.stack([f(i, t, 1) for i in range(m)]), acc=np.stack([f(i, t, 2) for i in range(m)]),
        radius=np.full(m, 0.2), goal=np.stack([f(i, t[-1:], 0)[0] for i in range(m)]),
        vehicle=np.array(["firefly"] * m), seg_robot=np.array(seg_robot),
        seg_t0=np.array(seg_t0), seg_t1=np.array(seg_t1), seg_coeffs=np.array(seg_coeffs))
    if world is not None:
        from jaxplan.world import world_arrays

        arrays.update(world_arrays(world))
    np.savez(path / "trajectories.npz", **arrays)
    per_robot = [{"vehicle": "firefly", "v_max": 2.0, "a_max": 4.0, "j_max": 12.0}] * m
    (path / "metrics.json").write_text(json.dumps(
        {"name": path.name, "backend": "ideal", "success": True, "robots": m,
         "per_robot": per_robot}))
    (path / "config.toml").write_text(f'name = "{path.name}"\n')
    return path


def test_crazyswarm_synthetic_round_trip(tmp_path, capsys):
    run = write_synthetic_run(tmp_path / "slow", [0.05, 0.1, 0.15])
    assert main(["export", str(run), "--format", "crazyswarm"]) == 0
    out = run / "crazyswarm"
    rows = check_crazyswarm(run, out)
    printed = capsys.readouterr().out
    assert "robot_2.csv" in printed and "max err" in printed
    report = json.loads((out / "export.json").read_text())
    assert report["tolerance_m"] == 0.01 and report["max_pieces"] == 31
    for e, (pieces, err) in zip(report["robots"], rows, strict=True):
        assert e["pieces"] == pieces and e["max_error_m"] == pytest.approx(err, abs=1e-6)
        for k, lim in (("speed", "v_max"), ("acc", "a_max"), ("jerk", "j_max")):
            assert e[f"peak_{k}"] <= 1.01 * max(e[lim], e[f"executed_peak_{k}"])
    # the header is Crazyswarm's column naming
    header = (out / "robot_0.csv").read_text().splitlines()[0].split(",")
    assert header[:2] == ["duration", "x^0"] and header[-1] == "yaw^7" and len(header) == 33


def test_crazyswarm_planar_height(tmp_path):
    run = write_synthetic_run(tmp_path / "planar", [0.1, 0.2], dim=2)
    out = tmp_path / "cs"
    report = export_run(run, "crazyswarm", out, height=0.7)
    assert report["height_m"] == 0.7
    check_crazyswarm(run, out, height=0.7)
    with pytest.raises(ExportError, match="positive"):
        export_run(run, "crazyswarm", out, height=-1.0)
    run3 = write_synthetic_run(tmp_path / "three", [0.1])
    with pytest.raises(ExportError, match="only for planar runs"):
        export_run(run3, "crazyswarm", height=1.0)


def test_crazyswarm_too_busy_a_flight_is_refused(tmp_path, capsys):
    run = write_synthetic_run(tmp_path / "busy", [0.1, 5.0], amp=0.2, duration=8.0)
    assert main(["export", str(run), "--format", "crazyswarm"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("jaxplan: error: ") and "robot 1 (firefly)" in err
    assert "robot 0" not in err and "31 pieces" in err
    assert not (run / "crazyswarm").exists()  # nothing written


# ------------------------------------------------------------------ MCAP


def check_mcap(run_dir, path):
    """Read the file back with the mcap reader (CRCs checked): every robot's pose at
    every sample time of trajectories.npz, the scene, the metrics."""
    from mcap.reader import make_reader

    from jaxplan.files import load_run

    run = load_run(run_dir, complete=True)
    m, n = run.num_robots, run.ndim
    ns = np.round(run.t * 1e9).astype(np.int64)
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        summary = reader.get_summary()
        assert summary is not None and summary.chunk_indexes  # indexed: seekable
        schemas = {s.name for s in summary.schemas.values()}
        assert {"foxglove.PoseInFrame", "foxglove.SceneUpdate",
                "foxglove.FrameTransforms"} <= schemas
        assert {s.encoding for s in summary.schemas.values()} == {"jsonschema"}
        counts = summary.statistics.channel_message_counts
        by_topic = {c.topic: counts[cid] for cid, c in summary.channels.items()}
        for i in range(m):
            assert by_topic[f"/robot_{i}/pose"] == run.t.size
        poses = {i: [] for i in range(m)}
        states = {i: [] for i in range(m)}
        scenes = {}
        for schema, channel, msg in reader.iter_messages(log_time_order=True):
            assert channel.message_encoding == "json"
            body = json.loads(msg.data)
            topic = channel.topic
            if topic.endswith("/pose"):
                i = int(topic.split("/")[1].split("_")[1])
                stamp = body["timestamp"]["sec"] * 10**9 + body["timestamp"]["nsec"]
                assert stamp == msg.log_time and body["frame_id"] == "world"
                p = body["pose"]["position"]
                poses[i].append((msg.log_time, p["x"], p["y"], p["z"]))
            elif topic.endswith("/state"):
                states[int(topic.split("/")[1].split("_")[1])].append(body)
            elif schema.name == "foxglove.SceneUpdate" or topic == "/metrics":
                scenes[topic] = body
        metadata = {r.name: r.metadata for r in reader.iter_metadata()}
        attachments = {a.name for a in reader.iter_attachments()}
    for i in range(m):
        got = np.array(poses[i])
        assert np.array_equal(got[:, 0].astype(np.int64), ns)
        want = run.pos[i] if n == 3 else np.concatenate([run.pos[i], 0 * run.pos[i][:, :1]], 1)
        assert np.allclose(got[:, 1:], want, atol=1e-12)
        v = np.array([[s["velocity"][k] for k in "xyz"] for s in states[i]])
        assert np.allclose(v[:, :n], run.vel[i], atol=1e-12)
    assert len(scenes["/robots"]["entities"]) == m and len(scenes["/goals"]["entities"]) == m
    assert scenes["/metrics"]["name"] == run.metrics["name"]
    assert metadata["jaxplan_run"]["robots"] == str(m)
    assert "config.toml" in attachments
    return scenes


def test_mcap_synthetic_with_world(tmp_path, capsys):
    pytest.importorskip("mcap")
    from jaxplan.world import World

    world = World(lo=[-5.0, -5.0, 0.0], hi=[5.0, np.inf, 4.0], kind=[0, 1, 2],
                  center=[[3.0, 3.0, 1.0], [-3.0, 3.0, 1.0], [0.0, -3.0, 1.0]],
                  half=[[0, 0, 0], [0.5, 0.4, 0.3], [0, 0, 1.0]], radius=[0.5, 0, 0.3])
    run = write_synthetic_run(tmp_path / "scene", [0.1, 0.2], duration=3.0, world=world)
    assert main(["export", str(run), "--format", "mcap", "--out", str(tmp_path / "o")]) == 0
    assert "scene.mcap" in capsys.readouterr().out
    scenes = check_mcap(run, tmp_path / "o" / "scene.mcap")
    obstacles, workspace = scenes["/world"]["entities"]
    assert [len(obstacles[k]) for k in ("spheres", "cubes", "cylinders")] == [1, 1, 1]
    assert len(workspace["cubes"]) == 5  # every finite face: x_min, y_min, z_min, x_max, z_max
    assert obstacles["cylinders"][0]["size"] == {"x": 0.6, "y": 0.6, "z": 2.0}
    # --height belongs to the CSVs
    assert main(["export", str(run), "--format", "mcap", "--height", "1"]) == 2


def test_mcap_messages_match_their_schemas(tmp_path):
    jsonschema = pytest.importorskip("jsonschema")
    pytest.importorskip("mcap")
    from mcap.reader import make_reader

    from jaxplan.export.mcap import SCHEMAS
    from jaxplan.world import World

    world = World(lo=[-5.0, -5.0], hi=[5.0, 5.0], kind=[1], center=[[0.0, 2.0]],
                  half=[[0.5, 0.5]], radius=[0.0])
    run = write_synthetic_run(tmp_path / "planar", [0.1], duration=1.0, dim=2, world=world)
    report = export_run(run, "mcap")
    seen = set()
    with open(report["file"], "rb") as f:
        for schema, channel, msg in make_reader(f).iter_messages():
            assert json.loads(schema.data) == SCHEMAS[schema.name]
            if channel.topic not in seen:  # one of each topic
                seen.add(channel.topic)
                jsonschema.validate(json.loads(msg.data), SCHEMAS[schema.name])
    assert seen == set(report["topics"])


def test_mcap_moving_obstacles(tmp_path):
    """A moving cylinder (a velocity) on /obstacles at every sample, where
    World.center_at puts it; the static sphere only on /world; a run whose obstacles
    all rest has no /obstacles topic."""
    pytest.importorskip("mcap")
    from mcap.reader import make_reader

    from jaxplan.export.mcap import SCHEMAS, topics
    from jaxplan.world import World

    world = World.default(3).with_obstacles([
        {"kind": "cylinder", "center": [-2.0, 3.0, 1.0], "radius": 0.3, "half_height": 1.0,
         "velocity": [0.7, -0.2, 0.0]},
        {"kind": "sphere", "center": [2.0, -3.0, 1.0], "radius": 0.4}])
    assert world.moving.tolist() == [True, False]
    run = write_synthetic_run(tmp_path / "moving", [0.1], duration=1.0, world=world)
    report = export_run(run, "mcap", tmp_path / "o")
    assert report["topics"] == topics(1, moving=True) and "/obstacles" in report["topics"]
    scenes = check_mcap(run, report["file"])
    (static,) = [e for e in scenes["/world"]["entities"] if e["id"] == "obstacles"]
    assert [len(static[k]) for k in ("spheres", "cubes", "cylinders")] == [1, 0, 0]
    assert static["spheres"][0]["pose"]["position"] == {"x": 2.0, "y": -3.0, "z": 1.0}
    try:
        import jsonschema
    except ImportError:
        jsonschema = None
    moving = []
    with open(report["file"], "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        counts = reader.get_summary().statistics.channel_message_counts
        for schema, _, msg in reader.iter_messages(topics=["/obstacles"]):
            body = json.loads(msg.data)
            if jsonschema is not None and not moving:
                jsonschema.validate(body, SCHEMAS[schema.name])
            (e,) = body["entities"]
            assert e["id"] == "obstacle_0" and e["frame_id"] == "world"
            assert e["timestamp"]["sec"] * 10**9 + e["timestamp"]["nsec"] == msg.log_time
            assert [len(e[k]) for k in ("spheres", "cubes", "cylinders")] == [0, 0, 1]
            cyl = e["cylinders"][0]
            assert cyl["size"] == {"x": 0.6, "y": 0.6, "z": 2.0}  # as /world draws it
            p = cyl["pose"]["position"]
            moving.append((msg.log_time, p["x"], p["y"], p["z"]))
    with np.load(run / "trajectories.npz") as z:
        t = z["t"]
    got = np.array(moving)
    assert np.array_equal(got[:, 0].astype(np.int64), np.round(t * 1e9).astype(np.int64))
    want = world.center_at(got[:, 0] * 1e-9)[0][:, 0]  # (T, 3): the cylinder's centre
    assert np.abs(got[:, 1:] - want).max() <= 1e-9
    assert np.abs(got[-1, 1:] - [-1.3, 2.8, 1.0]).max() <= 1e-9  # 1 s at (0.7, -0.2, 0)
    assert sum(counts.values()) == report["messages"]
    # the same world with nothing moving: no /obstacles, the same /world
    still = write_synthetic_run(tmp_path / "still", [0.1], duration=1.0,
                                world=world.static_part())
    report = export_run(still, "mcap", tmp_path / "o")
    assert "/obstacles" not in report["topics"]
    with open(report["file"], "rb") as f:
        summary = make_reader(f).get_summary()
    assert "/obstacles" not in {c.topic for c in summary.channels.values()}
    assert check_mcap(still, report["file"])["/world"] == scenes["/world"]


# ------------------------------------------------------------------ the paper's runs


def _paper_run(name, out):
    from jaxplan.config import load_config
    from jaxplan.experiment import run
    from jaxplan.files import write_run

    return write_run(run(load_config(ROOT / "experiments" / "paper" / f"{name}.toml")), out)


def test_a_planner_run_exports(tiny_run, tmp_path):
    """The tiny scenario's planner run (shared with the other tiny-scenario tests: one
    compilation), both formats read back as their consumers read them."""
    from jaxplan.files import write_run

    run_dir = write_run(tiny_run, tmp_path / "tiny")
    assert main(["export", str(run_dir), "--format", "crazyswarm",
                 "--out", str(tmp_path / "cs")]) == 0
    rows = check_crazyswarm(run_dir, tmp_path / "cs")
    assert len(rows) == len(tiny_run.metrics["per_robot"])
    pytest.importorskip("mcap")
    report = export_run(run_dir, "mcap", tmp_path / "mcap")
    check_mcap(run_dir, report["file"])


@pytest.mark.slow  # the four paper scenarios, ~40 s each: `make test-slow`
@pytest.mark.parametrize("name", PAPER)
def test_paper_exports(name, tmp_path):
    run_dir = _paper_run(name, tmp_path / name)
    export_run(run_dir, "crazyswarm", tmp_path / "cs")
    check_crazyswarm(run_dir, tmp_path / "cs")
    pytest.importorskip("mcap")
    check_mcap(run_dir, export_run(run_dir, "mcap", tmp_path / "mcap")["file"])


def test_crazyswarm_a_robot_starting_late_waits_at_its_start(tmp_path):
    """Every CSV starts at the run's first instant: a robot whose pieces begin later
    holds its first piece's start until then."""
    run = write_synthetic_run(tmp_path / "late", [0.05, 0.05])
    with np.load(run / "trajectories.npz") as z:
        arrays = dict(z)
    keep = ~((arrays["seg_robot"] == 1) & (arrays["seg_t0"] < 1.0))  # robot 1 from t = 1 s
    for key in ("seg_robot", "seg_t0", "seg_t1", "seg_coeffs"):
        arrays[key] = arrays[key][keep]
    np.savez(run / "trajectories.npz", **arrays)
    report = export_run(run, "crazyswarm")
    assert [e["duration_s"] for e in report["robots"]] == pytest.approx([10.0, 10.0])
    durations, coeffs = crazyswarm_csv(run / "crazyswarm" / "robot_1.csv")
    first = arrays["seg_coeffs"][arrays["seg_robot"] == 1][0][:, 0]  # its start at t = 1 s
    y = crazyswarm_eval(durations, coeffs, np.arange(0.0, 1.0, 1e-3))[:, :3]
    assert np.abs(y - first).max() <= 0.01
    check_crazyswarm(run, run / "crazyswarm")
