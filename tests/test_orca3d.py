"""The JAX RVO2-3D baseline (jaxplan/baselines/orca3d.py, [planner] method = "orca3d"):
its step against RVO2's (pyrvo) on planar states embedded at z = 0, a 3-D fleet through
`jaxplan run` with the exact metrics on its pieces, a planar fleet against the pyrvo
engine, and the configs it refuses.  One compiled step (12 robots, 11 slots) serves the
planar tests; the 3-D run compiles one more (6 robots)."""

from __future__ import annotations

import json
import tomllib

import numpy as np
import pytest

from jaxplan.baselines import orca, orca3d
from jaxplan.cli import main
from jaxplan.config import ConfigError, build_scenario, parse_config
from jaxplan.metrics import pairwise_min_separation, sample_pieces

M = 12  # the planar tests' fleet size: one compiled step, k = M - 1 slots
DT = 0.05


@pytest.fixture(scope="module")
def step12():
    program, _ = orca3d.compiled_step(M, M - 1)
    return program


def _rvo2_step(p, v, pref, radius, v_max, neighbor_dist, max_neighbors, horizon):
    """pyrvo's new velocities (M, 2): an RVO2 simulator of these agents only, one
    do_step (which also moves them: only the velocities are read)."""
    pyrvo = pytest.importorskip("pyrvo")
    sim = pyrvo.RVOSimulator()
    sim.set_time_step(DT)
    for i in range(len(p)):
        sim.add_agent(tuple(map(float, p[i])), neighbor_dist, max_neighbors, horizon, 2.0,
                      float(radius[i]), float(v_max[i]), tuple(map(float, v[i])))
        sim.set_agent_pref_velocity(i, tuple(map(float, pref[i])))
    sim.do_step()
    return np.array([sim.get_agent_velocity(i).to_tuple() for i in range(len(p))])


def _z0(x):
    return np.concatenate([x, np.zeros((len(x), 1))], axis=1)


def test_the_step_is_rvo2s_on_planar_states(step12):
    """Random crowded planar fleets (overlapping pairs, infeasible LPs, several neighbour
    distances, counts and horizons), embedded at z = 0: the new x-y velocities are
    pyrvo's to 1e-4 m/s absolute (pyrvo computes in single precision; the inputs are
    rounded to it first).  Left out: the agents whose pyrvo velocity itself moves by
    more than 2e-5 m/s when the positions are scaled by 1 + 1e-6 (its answer there is
    ill-conditioned at single precision: nearly parallel constraints in an infeasible
    LP), at most 3% of them.  z: 0 wherever the LP was feasible (where linearProgram4
    ran, RVO2-3D's tie-break on a vertical line may leave a z velocity, which planar
    fleets drop)."""
    pytest.importorskip("pyrvo")
    rng = np.random.default_rng(0)
    compared = left_out = infeasible = overlaps = 0
    worst = 0.0
    for trial in range(36):
        f32 = lambda x: np.float32(x).astype(np.float64)  # noqa: E731
        p = f32(rng.uniform(-2.5, 2.5, (M, 2)))
        v, pref = f32(rng.normal(size=(M, 2))), f32(rng.normal(size=(M, 2)))
        radius, v_max = f32(rng.uniform(0.2, 0.35, M)), f32(rng.uniform(1.0, 2.0, M))
        nd = (1.5, 3.0, 10.0)[trial % 3]
        kmax = (1, 3, 6, 11)[trial % 4]
        horizon = (0.5, 2.0, 5.0)[(trial // 3) % 3]
        want = _rvo2_step(p, v, pref, radius, v_max, nd, kmax, horizon)
        moved = _rvo2_step(p * (1 + 1e-6), v, pref, radius, v_max, nd, kmax, horizon)
        stable = np.max(np.abs(moved - want), axis=1) <= 2e-5
        got, inf = step12(_z0(p), _z0(v), _z0(pref), radius, v_max, nd, kmax, horizon, DT)
        got, inf = np.asarray(got), np.asarray(inf)
        err = np.max(np.abs(got[:, :2] - want), axis=1)
        worst = max(worst, float(np.max(err[stable])))
        assert np.all(got[~inf, 2] == 0.0)
        assert np.all(np.linalg.norm(got, axis=1) <= v_max * (1 + 1e-12))
        compared += int(stable.sum())
        left_out += int((~stable).sum())
        infeasible += int((inf & stable).sum())
        d = np.linalg.norm(p[:, None] - p[None], axis=-1) + 1e9 * np.eye(M)
        overlaps += int(np.sum(d < radius[:, None] + radius[None])) // 2
    assert worst <= 1e-4, worst
    assert left_out <= 0.03 * (compared + left_out)
    assert infeasible >= 50 and overlaps >= 20  # linearProgram4 and the collision planes ran


def test_degenerate_states_give_finite_velocities(step12):
    """Where RVO2-3D would divide by zero (two robots at one point with one velocity; a
    relative velocity exactly at the centre of the collision case's cut-off sphere) the
    plane is dropped (the velocities stay finite); every robot here, with no plane left,
    gets its preferred velocity clipped to v_max."""
    p = np.stack([np.arange(M) * 10.0, np.zeros(M), np.zeros(M)], axis=1)
    p[1] = p[0]  # robots 0 and 1 coincide, at rest
    p[3] = p[2] + [0.125, 0.0, 0.0]
    v = np.zeros((M, 3))
    v[2] = [2.5, 0.0, 0.0]  # v_2 - v_3 = (p_3 - p_2) / dt exactly (1 / dt is 20.0)
    pref = np.tile([3.0, 1.0, -0.5], (M, 1))
    v_max = np.full(M, 2.0)
    got, inf = step12(p, v, pref, np.full(M, 0.3), v_max, 5.0, 11, 2.0, DT)
    got = np.asarray(got)
    assert np.all(np.isfinite(got)) and not np.any(inf)
    free = pref / np.linalg.norm(pref, axis=1, keepdims=True) * 2.0
    np.testing.assert_allclose(got, free, rtol=1e-15)  # the dropped planes hold nothing


def test_a_planar_fleet_follows_the_pyrvo_engine(step12):
    """A planar fleet of 12 through both engines of the shared harness: the same pieces
    (positions to 1e-4 m) over the first 2 s, the JAX engine's in float64 joining exactly
    and within the limits."""
    pytest.importorskip("pyrvo")
    text = """
name = "orca3d_planar"
[planner]
method = "orca3d"
orca_max_neighbors = 11
[sim]
duration_s = 2.0
[scenario]
kind = "random_box"
count = 12
box = [[-2.5, -2.5], [2.5, 2.5]]
"""
    config = parse_config(tomllib.loads(text))
    scenario = build_scenario(config)
    rec3, final3, ms, _ = orca3d.simulate_orca3d(config, scenario)
    rec2, _, _, _ = orca.simulate_orca(config, scenario)
    assert rec3.p.shape == (40, M, 2) and rec3.piece_coeffs.shape == (40, M, 1, 2, 2)
    assert ms.shape == (40,) and final3.reached.shape == (M, 1)
    np.testing.assert_allclose(rec3.p, rec2.p, rtol=0, atol=1e-4)
    c = rec3.piece_coeffs[:, :, 0]
    end = c[..., 0] + c[..., 1] * DT
    np.testing.assert_array_equal(end[:-1], c[1:, ..., 0])  # the pieces join exactly
    speed = np.linalg.norm(c[..., 1], axis=-1)
    assert np.all(speed <= np.asarray(scenario.v_max) * (1 + 1e-12))
    dv = np.linalg.norm(np.diff(c[..., 1], axis=0), axis=-1)
    assert np.all(dv <= np.asarray(scenario.a_max) * DT * (1 + 1e-9))


def _sphere_fleet(n: int = 6, radius: float = 2.0, centre=(0.0, 0.0, 3.0)) -> str:
    """n fireflies at irregular points of a sphere, each bound for the antipode (an
    exactly symmetric fleet holds ORCA in a deadlock)."""
    rng = np.random.default_rng(3)
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    c = np.asarray(centre)
    out = ""
    for x in u:
        s, g = c + radius * x, c - radius * x
        out += (f'[[robots]]\nvehicle = "firefly"\nstart = {[round(float(a), 6) for a in s]}\n'
                f"goal = {[round(float(a), 6) for a in g]}\n")
    return out


SPHERE6 = """
name = "orca3d_sphere6"
[planner]
method = "orca3d"
[sim]
duration_s = 8.0
""" + _sphere_fleet()


def test_a_3d_fleet_runs_through_jaxplan_run(tmp_path):
    cfg = tmp_path / "sphere6.toml"
    cfg.write_text(SPHERE6)
    out = tmp_path / "run"
    assert main(["run", str(cfg), "--out", str(out), "--quiet", "--no-figures"]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["robots"] == 6 and m["collisions"] == 0 and m["success"]
    assert m["replans"] == 160 and m["compile_s"] >= 0.0
    z = np.load(out / "trajectories.npz", allow_pickle=False)
    assert z["seg_coeffs"].shape == (6 * 160, 3, 2)  # one straight 3-D piece per step
    v = z["seg_coeffs"][:, :, 1].reshape(6, 160, 3)
    assert np.ptp(v[..., 2]) > 0.1  # they move in z too
    # the exact separation of the pieces is the minimum of a dense sample (finely round
    # the exact minimum's time, coarsely everywhere)
    pieces = (z["seg_robot"], z["seg_t0"], z["seg_t1"], z["seg_coeffs"])
    d, tmin = pairwise_min_separation(*pieces, num_robots=6)
    for i in range(6):
        for j in range(i + 1, 6):
            t = np.concatenate([np.linspace(0.0, 8.0, 40001),
                                tmin[i, j] + np.linspace(-0.05, 0.05, 100001)])
            t = np.clip(t, 0.0, 8.0)
            pos = sample_pieces(*pieces, t, num_robots=6, outside="clamp")[0]
            dense = np.min(np.linalg.norm(pos[i] - pos[j], axis=-1))
            assert dense == pytest.approx(d[i, j], abs=1e-9)
            assert dense >= d[i, j] - 1e-12
    config = parse_config(tomllib.loads(SPHERE6))
    scenario = build_scenario(config)
    assert np.max(np.linalg.norm(v, axis=-1)) <= np.max(scenario.v_max) * (1 + 1e-12)
    dv = np.linalg.norm(np.diff(v, axis=1), axis=-1)
    assert np.max(dv) <= np.max(scenario.a_max) * DT * (1 + 1e-9)


def test_a_sweep_of_seeds_gives_each_runs_row(tmp_path):
    """`jaxplan sweep` with method "orca3d": a grid of seeds of a generated fleet, each
    row the row of that point's own run (cell for cell)."""
    import dataclasses

    from jaxplan.experiment import run_method
    from jaxplan.sweep import read_sweep_csv, run_sweep
    from jaxplan.sweep.points import build_scenarios, sweep_points
    from jaxplan.sweep.table import csv_row

    text = SPHERE6[:SPHERE6.index("[[robots]]")].replace("8.0", "4.0")
    text += ('[scenario]\nkind = "antipodal_sphere"\ncount = 6\n'
             '[sweep]\nseeds = [0, 1]\n')
    config = parse_config(tomllib.loads(text))
    res = run_sweep(config, tmp_path / "sweep", progress=False, echo=None)
    rows, _ = read_sweep_csv(res.csv)
    points = sweep_points(config)
    assert len(rows) == len(points) == 2 and not any(r["error"] for r in rows)
    built = build_scenarios(config, points)
    for point, row in zip(points, rows, strict=True):
        sc = built[(point.scenario, point.seed)]
        one = run_method(dataclasses.replace(config, seed=point.seed), sc)
        want = csv_row(point, one.metrics, sc.num_waypoints)
        assert row == want


def test_the_configs_it_refuses(tmp_path):
    pillar = '[[obstacles]]\nkind = "sphere"\ncenter = [5.0, 5.0, 5.0]\nradius = 0.3\n'
    with pytest.raises(ConfigError, match="planner.method: 'orca3d' takes no obstacles"):
        parse_config(tomllib.loads(SPHERE6 + pillar))
    mjx = SPHERE6.replace("[sim]\n", '[sim]\nbackend = "mjx"\n')
    with pytest.raises(ConfigError, match="sim.backend: .*'orca3d'"):
        parse_config(tomllib.loads(mjx))
    planar = SPHERE6.replace('method = "orca3d"', 'method = "orca"')
    with pytest.raises(ConfigError, match="planner.method: 'orca' is planar-only"):
        parse_config(tomllib.loads(planar))
    cfg = tmp_path / "pillar.toml"
    cfg.write_text(SPHERE6 + pillar)
    assert main(["run", str(cfg)]) == 2
