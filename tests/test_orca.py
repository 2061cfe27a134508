"""The ORCA baseline (jaxplan/baselines/orca.py): `jaxplan run` with [planner] method =
"orca" on planar fleets, its pieces against RVO2's positions, the exact metrics on them,
its parts against plain numpy, and the configs it refuses."""

from __future__ import annotations

import json
import tomllib

import numpy as np
import pytest

pytest.importorskip("pyrvo")

from jaxplan.baselines import orca  # noqa: E402
from jaxplan.cli import main  # noqa: E402
from jaxplan.config import ConfigError, parse_config  # noqa: E402
from jaxplan.metrics import pairwise_min_separation, sample_pieces  # noqa: E402
from jaxplan.world import World  # noqa: E402

# four ground robots: two pairs swapping head-on, slightly off the line (an exactly
# symmetric swap, or four robots crossing at one point, holds ORCA in a deadlock)
SWAP4 = """
name = "orca_swap4"
[planner]
method = "orca"
[sim]
duration_s = 8.0
[[robots]]
vehicle = "ground"
start = [-2.0, 0.1]
goal = [2.0, 0.1]
[[robots]]
vehicle = "ground"
start = [2.0, -0.1]
goal = [-2.0, -0.1]
[[robots]]
vehicle = "ground"
start = [-2.0, 1.5]
goal = [2.0, 1.5]
[[robots]]
vehicle = "ground"
start = [2.0, 1.4]
goal = [-2.0, 1.4]
"""


def _config(text=SWAP4, **planner):
    data = tomllib.loads(text)
    data["planner"].update(planner)
    return parse_config(data)


def test_a_four_robot_swap_runs_through_jaxplan_run(tmp_path):
    cfg = tmp_path / "swap4.toml"
    cfg.write_text(SWAP4)
    out = tmp_path / "run"
    assert main(["run", str(cfg), "--out", str(out), "--quiet", "--no-figures"]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["robots"] == 4 and m["collisions"] == 0 and m["success"]
    # stepwise velocities: the largest jump over a step within the clamp, no finite jerk
    assert 0.5 < m["peak_acc_ratio"] <= 1.0 + 1e-4 and m["peak_jerk_ratio"] is None
    assert m["peak_acc_ratio"] == max(r["peak_acc_ratio"] for r in m["per_robot"])
    assert m["duration_s"] == pytest.approx(8.0) and m["replans"] == 160
    z = np.load(out / "trajectories.npz", allow_pickle=False)
    assert z["seg_coeffs"].shape == (4 * 160, 2, 2)  # one straight piece per robot and step
    # the exact separation of the pieces is the minimum of a dense sample (linear pieces:
    # sampled finely round the exact minimum's time, coarsely everywhere)
    pieces = (z["seg_robot"], z["seg_t0"], z["seg_t1"], z["seg_coeffs"])
    d, tmin = pairwise_min_separation(*pieces, num_robots=4)
    for i in range(4):
        for j in range(i + 1, 4):
            t = np.concatenate([np.linspace(0.0, 8.0, 80001),
                                tmin[i, j] + np.linspace(-0.05, 0.05, 200001)])
            t = np.clip(t, 0.0, 8.0)
            pos = sample_pieces(*pieces, t, num_robots=4, outside="clamp")[0]
            dense = np.min(np.linalg.norm(pos[i] - pos[j], axis=-1))
            assert dense == pytest.approx(d[i, j], abs=1e-9)
            assert dense >= d[i, j] - 1e-12
    # every robot moved within its limits: speed <= v_max, each step's change <= a_max dt
    v = z["seg_coeffs"][:, :, 1].reshape(4, 160, 2)
    assert np.max(np.linalg.norm(v, axis=-1)) <= 2.0 + 1e-5
    assert np.max(np.linalg.norm(np.diff(v, axis=1), axis=-1)) <= 4.0 * 0.05 + 1e-4


def test_the_pieces_reproduce_rvo2s_positions(monkeypatch):
    config = _config()
    seen = []
    real = orca.positions
    monkeypatch.setattr(orca, "positions", lambda sim, M: seen.append(real(sim, M)) or seen[-1])
    records, final, ms, _ = orca.simulate_orca(config, config_scenario(config))
    assert len(seen) == 161 and ms.shape == (160,)
    c = records.piece_coeffs[:, :, 0]  # (K, M, 2, 2): p + v (t - t0)
    h = (records.piece_t1 - records.piece_t0)[:, :, 0]  # (K, M)
    start = c[..., 0]
    end = c[..., 0] + c[..., 1] * h[..., None]
    np.testing.assert_array_equal(start, np.stack(seen[:-1]))
    np.testing.assert_allclose(end, np.stack(seen[1:]), rtol=0, atol=1e-14)
    assert np.all(final.reached) and np.all(np.isfinite(final.reach_time))


def config_scenario(config):
    from jaxplan.config import build_scenario

    return build_scenario(config)


def test_an_obstacle_is_kept_clear():
    text = SWAP4.replace('name = "orca_swap4"', 'name = "orca_pillar"') + """
[[obstacles]]
kind = "cylinder"
center = [0.0, 0.0]
radius = 0.3
"""
    from jaxplan.experiment import run

    m = run(_config(text)).metrics
    assert m["obstacle_collisions"] == 0 and m["min_obstacle_clearance_m"] > 0
    assert m["collisions"] == 0


def test_obstacles_become_counter_clockwise_polygons_holding_them():
    box, disc = orca.obstacle_polygons(_world())
    np.testing.assert_allclose(box, [[0.5, 1.75], [1.5, 1.75], [1.5, 2.25], [0.5, 2.25]])
    for poly in (box, disc):
        e = np.roll(poly, -1, axis=0) - poly
        assert np.all(e[:, 0] * np.roll(e, -1, axis=0)[:, 1]
                      - e[:, 1] * np.roll(e, -1, axis=0)[:, 0] > 0)  # left turns: CCW
    # the disc's polygon circumscribes it: every edge is tangent to the disc
    a, b = disc, np.roll(disc, -1, axis=0)
    n = np.stack([b[:, 1] - a[:, 1], a[:, 0] - b[:, 0]], axis=-1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    np.testing.assert_allclose(np.sum((a - [-1.0, 0.0]) * n, axis=-1), 0.4, rtol=1e-12)


def _world():
    from jaxplan.world import BOX, CYLINDER

    return World(lo=np.full(2, -np.inf), hi=np.full(2, np.inf),
                 kind=np.array([BOX, CYLINDER]), center=np.array([[1.0, 2.0], [-1.0, 0.0]]),
                 half=np.array([[0.5, 0.25], [0.0, 0.0]]), radius=np.array([0.0, 0.4]))


def test_preferred_velocity_clamp_and_arrival_against_numpy(rng):
    p = rng.normal(size=(50, 2)) * 3
    g = rng.normal(size=(50, 2)) * 3
    v_max, a_max, dt = rng.uniform(0.5, 3, 50), rng.uniform(1, 5, 50), 0.05
    v = orca.preferred_velocity(p, g, v_max, a_max, dt)
    for i in range(50):
        d = np.linalg.norm(g[i] - p[i])
        want = (g[i] - p[i]) / d * min(v_max[i], np.sqrt(2 * a_max[i] * d), d / dt)
        np.testing.assert_allclose(v[i], want, rtol=1e-14)
    np.testing.assert_array_equal(orca.preferred_velocity(g, g, v_max, a_max, dt), 0.0)
    v0, v1 = rng.normal(size=(50, 2)), rng.normal(size=(50, 2))
    vc = orca.clamp_change(v0, v1, a_max, dt)
    dv = np.linalg.norm(vc - v0, axis=-1)
    assert np.all(dv <= a_max * dt * (1 + 1e-12))
    small = np.linalg.norm(v1 - v0, axis=-1) <= a_max * dt
    np.testing.assert_array_equal(vc[small], v1[small])
    # the first instant within tol of the goal, against a fine sample of the piece
    vel = (g - p) / dt * rng.uniform(0.5, 1.5, (50, 1))
    s = orca.first_arrival(p, vel, g, 0.1, dt)
    tt = np.linspace(0.0, dt, 200001)
    for i in range(50):
        inside = np.linalg.norm(p[i] + vel[i] * tt[:, None] - g[i], axis=-1) <= 0.1
        if inside.any():
            assert s[i] == pytest.approx(tt[np.argmax(inside)], abs=dt / 100000)
        else:
            assert np.isnan(s[i])


def test_a_sweep_of_seeds_gives_each_runs_own_row(tmp_path):
    """`jaxplan sweep` of an ORCA config: one row per seed, each the row of that seed's
    `jaxplan run` (same metrics, cell for cell); a weight grid and Ray are refused."""
    import dataclasses

    from jaxplan.experiment import run
    from jaxplan.sweep import SweepError, read_sweep_csv, run_sweep
    from jaxplan.sweep.points import sweep_points
    from jaxplan.sweep.table import csv_row

    text = SWAP4.replace("[sim]", "[scenario]\nkind = \"random_box\"\ncount = 6\n"
                         "box = [[-3.0, -3.0], [3.0, 3.0]]\n[sim]")
    text = text[:text.index("[[robots]]")]
    sweep = _config(text + "[sweep]\nseeds = [0, 1]\n")
    res = run_sweep(sweep, tmp_path / "sweep", progress=False, echo=None)
    rows, _ = read_sweep_csv(res.csv)
    assert [r["seed"] for r in rows] == ["0", "1"] and res.compilations == 0
    assert len({r["min_separation_ratio"] for r in rows}) == 2  # two different fleets
    assert res.best is not None  # one weight pair: the best setting is the only one

    for point, row in zip(sweep_points(sweep), rows, strict=True):
        one = run(dataclasses.replace(sweep, seed=point.seed))
        want = csv_row(point, one.metrics, one.scenario.num_waypoints)
        assert row == want
    grid = _config(text + "[sweep]\nseeds = [0]\nq_obs = [1.0, 2.0]\n")
    with pytest.raises(SweepError, match=r"\[planner\] method = 'orca' has no weights"):
        run_sweep(grid, tmp_path / "grid", progress=False, echo=None)
    with pytest.raises(SweepError, match="local engine only"):
        run_sweep(sweep, tmp_path / "ray", progress=False, echo=None, engine="ray")


def test_orca_is_planar_only(tmp_path):
    text = """
[planner]
method = "orca"
[[robots]]
vehicle = "firefly"
start = [0.0, 0.0, 1.0]
goal = [1.0, 0.0, 1.0]
"""
    with pytest.raises(ConfigError, match="planner.method: 'orca' is planar-only"):
        parse_config(tomllib.loads(text))
    cfg = tmp_path / "orca3d.toml"
    cfg.write_text(text)
    assert main(["run", str(cfg)]) == 2
