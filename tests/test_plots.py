"""Tests of jaxplan.plots: every figure of a synthetic run and sweep is written, is a
valid, non-blank image of the documented size; best_setting's order; clear errors."""

from __future__ import annotations

import json
import math

import matplotlib
import numpy as np
import pytest
from PIL import Image

import jaxplan  # noqa: F401
from jaxplan import plots
from jaxplan.files import load_run, media
from jaxplan.metrics import sample_pieces
from jaxplan.plots.animation import animate, frame_times
from jaxplan.plots.run import _pair_minima, _plot_clearance, _plot_top_view, _plot_trajectories
from jaxplan.plots.scene import clearances
from jaxplan.sweep import best_setting
from jaxplan.world import World, world_arrays

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
GIF_MAGICS = (b"GIF89a", b"GIF87a")

# ------------------------------------------------------------------------------ fixtures


def min_jerk_piece(p0, p1, T):
    """Rest-to-rest quintic from p0 to p1 in T s: coefficients (N, 6) in t, lowest first."""
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    d = p1 - p0
    c = np.zeros((p0.size, 6))
    c[:, 0] = p0
    c[:, 3] = 10 * d / T**3
    c[:, 4] = -15 * d / T**4
    c[:, 5] = 6 * d / T**5
    return c


def make_run(run_dir, *, ndim=3, metrics=True, config=None, drop=None, nan_key=None,
             world=None, extra=None):
    """A 3-robot run: robots 0 and 1 swap along x passing 0.7 m apart (rho = 0.54 m,
    ratio 1.296), robot 2 crosses them later; each moves on one quintic piece, then holds
    its goal on a constant piece until t_end = 5 s.  ``world``: stored with the run."""
    starts = np.array([[-2.0, 0.0, 1.0], [2.0, 0.7, 1.0], [0.0, -2.5, 1.6]])[:, :ndim]
    goals = np.array([[2.0, 0.0, 1.0], [-2.0, 0.7, 1.0], [0.0, 2.5, 1.6]])[:, :ndim]
    durations = [4.0, 4.0, 3.0]
    t_end = 5.0
    seg_robot, seg_t0, seg_t1, coeffs = [], [], [], []
    for i in range(3):
        seg_robot += [i, i]
        seg_t0 += [0.0, durations[i]]
        seg_t1 += [durations[i], t_end]
        coeffs.append(min_jerk_piece(starts[i], goals[i], durations[i]))
        hold = np.zeros((ndim, 6))
        hold[:, 0] = goals[i]
        coeffs.append(hold)
    seg = (np.array(seg_robot), np.array(seg_t0), np.array(seg_t1), np.stack(coeffs))
    t = np.linspace(0.0, t_end, 501)  # 100 Hz
    pos, vel, acc = sample_pieces(*seg, t, num_robots=3, outside="clamp")
    data = dict(
        t=t, pos=pos, vel=vel, acc=acc, radius=np.array([0.27, 0.27, 0.315]), goal=goals,
        vehicle=np.array(["hummingbird", "hummingbird", "firefly"]),
        seg_robot=seg[0], seg_t0=seg[1], seg_t1=seg[2], seg_coeffs=seg[3],
    )
    if world is not None:
        data.update(world_arrays(world))
    data.update(extra or {})
    if nan_key is not None:
        data[nan_key] = data[nan_key].copy()
        data[nan_key][1, 7, 0] = np.nan
    for k in drop or ():
        data.pop(k)
    run_dir.mkdir(parents=True, exist_ok=True)
    np.savez(run_dir / "trajectories.npz", **data)
    if metrics:
        (run_dir / "metrics.json").write_text(json.dumps(dict(
            success=True, collisions=0, min_separation_ratio=0.7 / 0.54, makespan_s=4.0)))
    if config is not None:
        (run_dir / "config.toml").write_text(config)
    return run_dir


def check_png(path, size):
    assert path.is_file(), path
    assert path.read_bytes()[:8] == PNG_MAGIC
    with Image.open(path) as im:
        assert im.size == size
        a = np.asarray(im.convert("RGB"), dtype=float)
    assert a.std() > 10.0, f"{path.name} looks blank (std {a.std():.2f})"
    # a real figure uses many colours, not two or three (RGB packed into one integer)
    rgb = a.reshape(-1, 3).astype(np.uint32)
    assert np.unique((rgb[:, 0] << 16) | (rgb[:, 1] << 8) | rgb[:, 2]).size > 20


def check_gif(path, size, min_frames=2):
    assert path.is_file(), path
    assert path.read_bytes()[:6] in GIF_MAGICS
    with Image.open(path) as im:
        assert im.size == size
        n = im.n_frames
        assert n >= min_frames
        frames = []
        for k in range(n):
            im.seek(k)
            frames.append(np.asarray(im.convert("RGB"), dtype=float))
    assert frames[0].std() > 10.0
    diffs = [np.abs(frames[k] - frames[0]).mean() for k in range(1, n)]
    assert max(diffs) > 0.5, "the animation does not move"
    return n


# --------------------------------------------------------------------------------- runs


def test_plot_run_3d_writes_every_figure(tmp_path):
    run = make_run(tmp_path / "run")
    rc = dict(matplotlib.rcParams)
    paths = plots.plot_run(run, max_frames=16)
    assert dict(matplotlib.rcParams) == rc  # no global style leaked
    names = [p.name for p in paths]
    assert names == ["trajectories_3d.png", "trajectories_top.png", "speed_acc.png",
                     "separation.png", "clearance.png", "animation.gif"]
    assert all(p.parent == run / "figures" for p in paths)
    check_png(paths[0], (840, 720))
    check_png(paths[1], (840, 720))
    check_png(paths[2], (960, 660))
    check_png(paths[3], (1320, 576))
    with Image.open(paths[4]) as im:   # no world stored: a note, no curves
        assert im.size == (1320, 576)
    n = check_gif(paths[5], (640, 480))
    assert 2 <= n <= 16
    assert not [p for p in (run / "figures").iterdir() if p.name.startswith(".")]  # no temp


def test_plot_run_2d_without_optional_files(tmp_path):
    run = make_run(tmp_path / "planar", ndim=2, metrics=False)
    paths = plots.plot_run(run, max_frames=8)
    assert [p.name for p in paths] == [
        "trajectories_2d.png", "speed_acc.png", "separation.png", "clearance.png",
        "animation.gif"]
    check_png(paths[0], (840, 720))
    check_gif(paths[4], (640, 480))


def test_plot_run_without_animation_and_pieces(tmp_path):
    run = make_run(tmp_path / "r", drop=("seg_robot", "seg_t0", "seg_t1", "seg_coeffs"))
    paths = plots.plot_run(run, animation=False)
    assert [p.name for p in paths] == ["trajectories_3d.png", "trajectories_top.png",
                                       "speed_acc.png", "separation.png", "clearance.png"]
    assert not (run / "figures" / "animation.gif").exists()


# robot 0 flies through the sphere, robot 2 past the cylinder; y >= -3 m, z in [0, 2.5] m
WORLD_OBSTACLES = [dict(kind="sphere", center=[0.0, 0.0, 1.0], radius=0.4),
                   dict(kind="box", center=[-1.0, 2.0, 1.0], half_extents=[0.4, 0.3, 0.8]),
                   dict(kind="cylinder", center=[1.5, -1.5, 1.0], radius=0.3, half_height=1.0)]


def make_world(ndim=3):
    obs = [{k: (v[:ndim] if isinstance(v, list) else v) for k, v in o.items()
            if ndim == 3 or k != "half_height"} for o in WORLD_OBSTACLES]
    lo, hi = [-np.inf, -3.0, 0.0][:ndim], [np.inf, np.inf, 2.5][:ndim]
    if ndim == 2:
        hi = [2.5, np.inf]   # a wall at x = 2.5 m
    empty = World.unbounded(ndim)
    return World(np.array(lo), np.array(hi), empty.kind, empty.center, empty.half,
                 empty.radius).with_obstacles(obs)


OBSTACLE_BLEND = np.array([212.0, 193.0, 173.0])  # the top view's tan at alpha 0.55 on white


def obstacle_pixels(path):
    with Image.open(path) as im:
        a = np.asarray(im.convert("RGB"), dtype=float)
    return int(np.sum(np.all(np.abs(a - OBSTACLE_BLEND) <= 3, axis=-1)))


def test_plot_run_in_a_world(tmp_path):
    """Obstacles and faces are drawn in every view; the clearance figure has curves."""
    w = make_world()
    run = make_run(tmp_path / "w", world=w)
    m = json.loads((run / "metrics.json").read_text())
    m.update(obstacle_collisions=1, min_obstacle_clearance_m=-0.67, workspace_violations=0,
             min_workspace_clearance_m=0.185)
    (run / "metrics.json").write_text(json.dumps(m))
    paths = plots.plot_run(run, max_frames=3)
    check_png(paths[1], (840, 720))
    check_png(paths[4], (1320, 576))
    check_gif(paths[5], (640, 480))
    # the same run without a world: the 3-D view, the top view and the animation change
    bare = load_run(make_run(tmp_path / "bare"))
    out = tmp_path / "bare" / "figures"
    bare_paths = [_plot_trajectories(bare, out), _plot_top_view(bare, out),
                  animate(bare, out, mp4=False, max_frames=3)]
    for a, b in zip([paths[0], paths[1], paths[5]], bare_paths, strict=True):
        with Image.open(a) as ia, Image.open(b) as ib:
            diff = np.abs(np.asarray(ia.convert("RGB"), float)
                          - np.asarray(ib.convert("RGB"), float)).mean()
        assert diff > 1.0, (a.name, diff)
    # the top view: the three footprints (~0.5 + 0.28 + 0.48 m^2 at ~100 px/m), none bare
    assert obstacle_pixels(paths[1]) > 3000 and obstacle_pixels(bare_paths[1]) == 0
    # planar: discs, a rectangle and the two walls in the 2-D view; clearance curves
    d2 = load_run(make_run(tmp_path / "w2", ndim=2, world=make_world(2)))
    out2 = tmp_path / "w2" / "figures"
    assert obstacle_pixels(_plot_trajectories(d2, out2)) > 3000
    check_png(_plot_clearance(d2, out2), (1320, 576))


def test_clearances_against_direct_formulas(tmp_path):
    """clearance = distance to each obstacle's surface / face - radius, by hand."""
    d = load_run(make_run(tmp_path / "w", world=make_world()))
    obs, ws = clearances(d.world, d.pos, d.radius)
    p, r = d.pos, d.radius[:, None]
    sph = np.linalg.norm(p - [0.0, 0.0, 1.0], axis=-1) - 0.4 - r
    q = np.abs(p - [-1.0, 2.0, 1.0]) - [0.4, 0.3, 0.8]
    box = np.linalg.norm(np.maximum(q, 0), axis=-1) + np.minimum(q.max(-1), 0) - r
    rho = np.linalg.norm(p[..., :2] - [1.5, -1.5], axis=-1) - 0.3
    hz = np.abs(p[..., 2] - 1.0) - 1.0
    cyl = np.hypot(np.maximum(rho, 0), np.maximum(hz, 0)) + np.minimum(np.maximum(rho, hz), 0) - r
    np.testing.assert_allclose(obs, np.stack([sph, box, cyl], -1), atol=3e-6)
    faces = np.stack([p[..., 1] + 3.0, p[..., 2], 2.5 - p[..., 2]], -1) - r[..., None]
    np.testing.assert_allclose(ws, faces, atol=1e-12)       # y_min, z_min, z_max
    assert obs[0, :, 0].min() < -0.6                          # robot 0 through the sphere
    assert clearances(None, p, d.radius)[0].shape == (3, p.shape[1], 0)


# a static disc, a disc on a timed path (at rest before t = 1 s and after t = 3 s) and
# one at a constant velocity; in 3-D the path's cylinder stands on the floor
MOVING_OBSTACLES = [
    dict(kind="sphere", center=[0.0, -1.5, 1.0], radius=0.3),
    dict(kind="cylinder", radius=0.3, half_height=0.9,
         path=[dict(t=1.0, p=[-1.5, 1.5, 0.9]), dict(t=3.0, p=[1.5, 1.5, 0.9])]),
    dict(kind="sphere", center=[1.0, -0.5, 1.0], radius=0.2, velocity=[-0.4, 0.2, 0.0])]


def moving_world(ndim):
    obs = [{k: ([dict(t=q["t"], p=q["p"][:ndim]) for q in v] if k == "path" else
                v[:ndim] if isinstance(v, list) else v)
            for k, v in o.items() if ndim == 3 or k != "half_height"} for o in MOVING_OBSTACLES]
    return World.unbounded(ndim).with_obstacles(obs)


def moving_centres(t):
    """(2, 3) m: the moving obstacles (1 and 2) at time t, by hand."""
    x1 = -1.5 + 3.0 * min(max(t - 1.0, 0.0), 2.0) / 2.0
    return np.array([[x1, 1.5, 0.9], [1.0 - 0.4 * t, -0.5 + 0.2 * t, 1.0]])


@pytest.mark.parametrize("ndim", [2, 3])
def test_animation_draws_moving_obstacles_where_they_are(tmp_path, ndim):
    """Each frame draws the moving obstacles (one collection of outlines, offset to each
    one's centre) where their motion puts them at the frame's time: the offsets are the
    projections of the hand-computed centres (2-D: back in data coordinates), the
    outlines as wide as the bodies; the still scene holds only the static obstacle."""
    from jaxplan.plots.animation import _frames, _px_per_m, _static_scene, _to_pixels
    from jaxplan.plots.style import STYLE, bounds, robot_colors

    d = load_run(make_run(tmp_path / "m", ndim=ndim, world=moving_world(ndim)))
    cols, lim = np.asarray(robot_colors(3)), bounds(d)
    tf = np.array([0.5, 2.0, 4.5])
    with matplotlib.rc_context(STYLE):
        fig, ax = _static_scene(d, cols, lim)
        arts = {}
        frames = _frames(d, fig, ax, cols, lim, tf, arts)
        assert arts["obstacle_index"] == [1, 2]
        for f, _ in enumerate(frames):
            want = moving_centres(tf[f])[:, :ndim]
            got = arts["obstacles"].get_offsets()
            np.testing.assert_allclose(got, _to_pixels(ax, want)[0], rtol=0, atol=1e-6)
            if ndim == 2:
                np.testing.assert_allclose(ax.transData.inverted().transform(got), want,
                                           rtol=0, atol=1e-9)
        # the outlines' widths in metres: the bodies' diameters (48-gons)
        px = np.array([np.ptp(p.vertices[:, 0]) for p in arts["obstacles"].get_paths()])
        np.testing.assert_allclose(px / _px_per_m(ax, lim), [0.6, 0.4], rtol=5e-3)
    if ndim == 2:  # the still scene holds the static disc only
        assert [tuple(p.center) for p in ax.patches] == [(0.0, -1.5)]


def test_still_figures_draw_a_moving_obstacle_at_its_start_with_its_path():
    """draw_world_2d over a run's times: every obstacle where it is at the first time,
    and each moving one's path (dotted, its knots inside the span, an arrowhead at its
    end); without the moving bodies (the animation's still scene) the static one only."""
    from matplotlib.figure import Figure

    from jaxplan.plots.scene import draw_world_2d

    w, lim = moving_world(2), np.array([[-3.0, 3.0], [-3.0, 3.0]])
    ax = Figure().add_subplot()
    draw_world_2d(ax, w, lim, span=(0.5, 5.0))
    assert [tuple(np.round(p.center, 12)) for p in ax.patches] == [
        (0.0, -1.5), (-1.5, 1.5), (0.8, -0.4)]
    paths = [ln.get_xydata() for ln in ax.lines]
    np.testing.assert_allclose(paths[0], [[-1.5, 1.5], [-1.5, 1.5], [1.5, 1.5], [1.5, 1.5]])
    np.testing.assert_allclose(paths[1], [moving_centres(0.5)[1, :2],
                                          moving_centres(5.0)[1, :2]], atol=1e-12)
    assert all(ln.get_linestyle() == ":" for ln in ax.lines)
    heads = [t.xy for t in ax.texts]                       # the arrowheads, at the ends
    np.testing.assert_allclose(heads, [paths[0][-1], paths[1][-1]], atol=1e-12)
    ax = Figure().add_subplot()
    draw_world_2d(ax, w, lim, span=(0.5, 5.0), moving=False)
    assert len(ax.patches) == 1 and len(ax.lines) == 2


def test_frame_count_is_bounded():
    t = np.linspace(0, 60.0, 6001)
    assert frame_times(t, 150).size == 150
    assert frame_times(np.linspace(0, 1.0, 101), 150).size <= 20  # real time


def test_limits_from_config_metrics_and_vehicles(tmp_path):
    run = make_run(tmp_path / "a")
    d = load_run(run)
    np.testing.assert_allclose(d.limits["v_max"], [2.0, 2.0, 2.0])  # vehicle table
    run = make_run(tmp_path / "b", config='name = "swap"\n[limits]\nv_max = 1.5\n')
    d = load_run(run)
    np.testing.assert_allclose(d.limits["v_max"], 1.5)
    np.testing.assert_allclose(d.limits["a_max"], 4.0)
    assert d.name == "swap"
    (run / "metrics.json").write_text(json.dumps({"limits": {"a_max": 3.0}}))
    np.testing.assert_allclose(load_run(run).limits["a_max"], 3.0)


def test_exact_pair_minima_from_pieces(tmp_path):
    d = load_run(make_run(tmp_path / "r"))
    dist, _, exact = _pair_minima(d)
    assert exact
    assert dist[0, 1] == pytest.approx(0.7, abs=1e-9)


@pytest.mark.parametrize("key", ["pos", "radius", "vehicle", "t"])
def test_missing_key_names_file_and_key(tmp_path, key):
    run = make_run(tmp_path / "r", drop=(key,))
    with pytest.raises(ValueError, match=rf"trajectories\.npz: {key}: missing"):
        plots.plot_run(run, animation=False)


@pytest.mark.parametrize("key", ["pos", "vel"])
def test_non_finite_names_file_and_key(tmp_path, key):
    run = make_run(tmp_path / "r", nan_key=key)
    with pytest.raises(ValueError, match=rf"trajectories\.npz: {key}: non-finite"):
        plots.plot_run(run)
    assert not (run / "figures").exists()


def test_bad_inputs(tmp_path):
    with pytest.raises(ValueError, match=r"trajectories\.npz: file not found"):
        plots.plot_run(tmp_path)
    run = make_run(tmp_path / "r", drop=("seg_t1",))
    with pytest.raises(ValueError, match=r"trajectories\.npz: seg_t1: missing"):
        load_run(run)
    run = make_run(tmp_path / "c", config="[limits]\nv_max = -1\n")
    with pytest.raises(ValueError, match=r"config\.toml: limits\.v_max"):
        load_run(run)
    run = make_run(tmp_path / "m")
    (run / "metrics.json").write_text("{not json")
    with pytest.raises(ValueError, match=r"metrics\.json: not valid JSON"):
        load_run(run)


# ------------------------------------------------------------------------------- sweeps

Q_OBS = [0.1, 1.0, 10.0]
Q_LIM = [0.01, 0.1, 1.0]


def sweep_rows(scenarios=("antipodal",)):
    """3 x 3 grid, 2 seeds.  Success everywhere but q_obs = 0.1; of the fully successful
    cells, (10, 0.1) and (10, 1) and (1, 1) have no collisions; of these, (10, 0.1) and
    (10, 1) tie on min separation 1.4 and (10, 1) is faster: the best is (10, 1)."""
    rows = []
    for sc in scenarios:
        for a, qo in enumerate(Q_OBS):
            for b, ql in enumerate(Q_LIM):
                for seed in (0, 1):
                    success = qo > 0.5
                    collisions = 0 if (qo, ql) in ((10.0, 0.1), (10.0, 1.0), (1.0, 1.0)) else 1
                    sep = 1.4 if qo == 10.0 and ql >= 0.1 else 0.6 + 0.1 * a + 0.05 * b
                    if (qo, ql) == (1.0, 1.0):
                        sep = 1.2
                    makespan = 10.0 - (ql == 1.0) - 0.1 * seed
                    rows.append(dict(q_obs=qo, q_lim=ql, scenario=sc, seed=seed,
                                     success="true" if success else "false",
                                     min_separation_ratio=sep,
                                     makespan_s=makespan if success else "",
                                     collisions=collisions))
    return rows


def write_csv(path, rows, columns=None):
    columns = columns or list(rows[0])
    lines = [",".join(columns)] + [",".join(str(r[c]) for c in columns) for r in rows]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")
    return path


def test_best_setting_order(tmp_path):
    csv = write_csv(tmp_path / "sweep.csv", sweep_rows())
    best = best_setting(csv)
    assert (best["q_obs"], best["q_lim"]) == (10.0, 1.0)
    assert best["success_rate"] == 1.0
    assert best["collisions"] == 0.0
    assert best["min_separation_ratio"] == pytest.approx(1.4)
    assert best["makespan_s"] == pytest.approx(8.95)
    assert best["runs"] == 2
    # collisions outrank separation: give (1, 1) the largest separation of all
    rows = sweep_rows()
    for r in rows:
        if (r["q_obs"], r["q_lim"]) == (1.0, 0.01):
            r["min_separation_ratio"] = 3.0
    assert (best_setting(write_csv(tmp_path / "b.csv", rows))["q_lim"]) == 1.0
    # success outranks everything: one failure at the best cell moves it to (10, 0.1)
    rows = sweep_rows()
    rows[[k for k, r in enumerate(rows) if (r["q_obs"], r["q_lim"]) == (10.0, 1.0)][0]][
        "success"] = "0"
    best = best_setting(write_csv(tmp_path / "c.csv", rows))
    assert (best["q_obs"], best["q_lim"]) == (10.0, 0.1)


def test_plot_sweep_writes_heatmaps(tmp_path):
    write_csv(tmp_path / "sw" / "sweep.csv", sweep_rows())
    paths = plots.plot_sweep(tmp_path / "sw")
    assert [p.name for p in paths] == ["success_rate.png", "min_separation.png", "makespan.png"]
    for p in paths:
        check_png(p, (552, 480))


def test_plot_sweep_per_scenario_panels(tmp_path):
    rows = [r for r in sweep_rows(("antipodal", "random_box")) if r["q_obs"] > 0.5]  # 2 x 3
    write_csv(tmp_path / "sw" / "sweep.csv", rows)
    paths = plots.plot_sweep(tmp_path / "sw")
    for p in paths:
        check_png(p, (3 * 552, 480))  # all scenarios + one panel each


def test_sweep_bad_csv(tmp_path):
    rows = sweep_rows()
    cols = [c for c in rows[0] if c != "collisions"]
    write_csv(tmp_path / "a" / "sweep.csv", rows, cols)
    with pytest.raises(ValueError, match=r"sweep\.csv: collisions: column missing"):
        plots.plot_sweep(tmp_path / "a")
    rows[3]["success"] = "maybe"
    write_csv(tmp_path / "b" / "sweep.csv", rows)
    with pytest.raises(ValueError, match=r"sweep\.csv: success: line 5"):
        best_setting(tmp_path / "b" / "sweep.csv")
    with pytest.raises(ValueError, match=r"sweep\.csv: file not found"):
        plots.plot_sweep(tmp_path / "nothing")
    assert math.isfinite(best_setting(write_csv(tmp_path / "c.csv", sweep_rows()))["q_obs"])


def test_mp4_falls_back_to_gif_without_ffmpeg(tmp_path, monkeypatch):
    monkeypatch.setattr(media.shutil, "which", lambda name: None)
    run = make_run(tmp_path / "r")
    with pytest.warns(UserWarning, match="ffmpeg not found"):
        path = animate(load_run(run), run / "figures", mp4=True, max_frames=6)
    assert path.name == "animation.gif"
    check_gif(path, (640, 480))


@pytest.mark.skipif(not media.ffmpeg_available(), reason="ffmpeg not on PATH")
def test_mp4_with_ffmpeg(tmp_path):
    run = make_run(tmp_path / "r")
    path = plots.plot_run(run, mp4=True, max_frames=12)[-1]
    assert path.name == "animation.mp4"
    head = path.read_bytes()[:12]
    assert head[4:8] == b"ftyp"


def test_a_non_cooperative_robot_is_labelled_so(tmp_path):
    """trajectories.npz's ``cooperative`` reads back (all True where a run stored none,
    a wrong shape is an error naming the key) and labels the robot in the figures."""
    from jaxplan.plots.run import _robot_label

    d = load_run(make_run(tmp_path / "c", extra={"cooperative": np.array([True, True, False])}))
    np.testing.assert_array_equal(d.cooperative, [True, True, False])
    assert _robot_label(d, 2) == "2: firefly (non-cooperative)"
    assert _robot_label(d, 0) == "0: hummingbird"
    bare = load_run(make_run(tmp_path / "b"))
    assert bare.cooperative.all() and _robot_label(bare, 2) == "2: firefly"
    with pytest.raises(ValueError, match="cooperative"):
        load_run(make_run(tmp_path / "x", extra={"cooperative": np.array([True, False])}))
