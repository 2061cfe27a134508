"""The limit metrics (issue #68): the exact peaks over each robot's own limits, the goal
excursion and the escape, against a 0.1 ms dense sample of random polynomial pieces; and
the same keys through a run's metrics path (the shared tiny run: no compile of its own),
the mjx merge, the sweep's columns and the run summary."""

import copy
from types import SimpleNamespace

import numpy as np
import pytest

from jaxplan.metrics import escape_pieces, fleet_box, goal_excursion_pieces, kinematics
from jaxplan.metrics.report import ESCAPE_MARGIN_M, limit_metrics
from jaxplan.scenarios import make_scenario
from jaxplan.world import World

DT = 1e-4  # s, the dense sample


def _random_pieces(rng, scale, pieces=4):
    """Continuous random pieces of degree 5-7 (zero-padded to 7), several per robot:
    (seg_robot, seg_t0, seg_t1, seg_coeffs in seconds), robot i's amplitude scale[i]."""
    robot, t0s, t1s, coeffs = [], [], [], []
    for i, s in enumerate(scale):
        t, x = 0.0, rng.normal(0.0, 1.0, 3)
        for _ in range(pieces):
            h = rng.uniform(0.2, 0.6)
            deg = int(rng.integers(5, 8))
            a = np.zeros((3, 8))
            a[:, 1:deg + 1] = s * rng.normal(0.0, 1.0, (3, deg))
            a[:, 0] = x
            robot.append(i)
            t0s.append(t)
            t1s.append(t + h)
            coeffs.append(a / h ** np.arange(8))  # monomials in (t - t0) seconds
            t, x = t + h, a.sum(axis=1)
    return np.array(robot), np.array(t0s), np.array(t1s), np.array(coeffs)


def _dense(pieces, M):
    """Per robot: times (K,) and derivatives 0-4 (5, K, N) on a DT grid of each piece,
    both ends included (so a sampled maximum never exceeds the exact one)."""
    r, t0, t1, c = pieces
    out = []
    for i in range(M):
        ts, ds = [], []
        for k in np.nonzero(r == i)[0]:
            tau = np.append(np.arange(0.0, t1[k] - t0[k], DT), t1[k] - t0[k])
            p = c[k].T  # (L, N)
            d = []
            for _ in range(5):
                d.append(np.polynomial.polynomial.polyval(tau, p).T)  # (K, N)
                p = p[1:] * np.arange(1, p.shape[0])[:, None]
            ts.append(t0[k] + tau)
            ds.append(np.stack(d))
        out.append((np.concatenate(ts), np.concatenate(ds, axis=1)))
    return out


def _between(lo, x, hi, what):
    """lo <= x <= hi up to round-off (1e-9 relative)."""
    slack = 1e-9 * max(1.0, abs(lo), abs(hi))
    assert lo - slack <= x <= hi + slack, (what, lo, x, hi)


def _outside(x, lo, hi):
    """(K,) distance of the points x (K, N) outside the box lo <= x <= hi."""
    return np.linalg.norm(x - np.clip(x, lo, hi), axis=-1)


def test_the_exact_limit_metrics_agree_with_a_dense_sample():
    rng = np.random.default_rng(68)
    scale = [1.0, 0.6, 1.4, 0.01, 0.8]  # robot 3 barely moves: never outside the box
    M = len(scale)
    pieces = _random_pieces(rng, scale)
    dense = _dense(pieces, M)
    # start, two waypoints: where each robot is at its start and at two instants, the goal
    # of robot 1 far away (never reached), robot 2's first waypoint never reached
    start = np.array([d[1][0, 0] for d in dense])
    waypoints = np.array([[d[1][0, len(d[0]) // 3], d[1][0, 2 * len(d[0]) // 3]]
                          for d in dense])
    waypoints[:, 1] += 0.05  # goals within tolerance of the path, not on it
    waypoints[1, 1] += 50.0
    world = World(np.array([-np.inf, -np.inf, start[3, 2] - 0.2]),  # robot 3 above it
                  np.full(3, np.inf), np.zeros(0, np.int32), np.zeros((0, 3)),
                  np.zeros((0, 3)), np.zeros(0))
    v_max, a_max, j_max = (rng.uniform(1.0, 3.0, M) * np.array(s) for s in (5.0, 50.0, 500.0))
    sc = make_scenario("random", ["firefly"] * M, start, waypoints, v_max=v_max, a_max=a_max,
                       j_max=j_max, world=world, validate=False)
    reach_time = np.stack([np.array([d[0][len(d[0]) // 3] for d in dense]),
                           np.full(M, np.inf)], axis=1)
    reached = np.isfinite(reach_time)
    reached[2, 0] = False
    tol = 0.1
    kin = kinematics(*pieces, num_robots=M)
    fleet, per = limit_metrics(sc, pieces, kin, reach_time, reached, tol)
    lo, hi = fleet_box(start, waypoints, ESCAPE_MARGIN_M)
    for i, ((t, d), r) in enumerate(zip(dense, per, strict=True)):
        n = np.linalg.norm(d, axis=-1)  # (5, K): |x|, |x'|, ..., |x''''|
        for key, k, limit in (("peak_speed_ratio", 1, v_max), ("peak_acc_ratio", 2, a_max),
                              ("peak_jerk_ratio", 3, j_max)):
            sampled = n[k].max() / limit[i]
            _between(sampled, r[key], sampled + n[k + 1].max() * DT / limit[i], key)
        speed = n[1].max()
        # escape: the larger of the distances outside the fleet's box and the workspace
        out = np.maximum(_outside(d[0], lo, hi), _outside(d[0], world.lo, world.hi))
        _between(out.max(), r["escape_m"], out.max() + speed * DT, "escape_m")
        # goal excursion: from the first sample within tol after the previous waypoint
        dist = np.linalg.norm(d[0] - waypoints[i, 1], axis=-1)
        within = np.nonzero((dist <= tol) & (t >= reach_time[i, 0]))[0]
        if i in (1, 2):  # 1: its goal far away; 2: its first waypoint never reached
            assert r["goal_excursion_m"] is None
            assert i == 2 or within.size == 0
            continue
        assert within.size, "the goal was put beside the path"
        exact_reach = goal_excursion_pieces(*pieces, waypoints[:, 1], tol,
                                            t_from=reach_time[:, 0], num_robots=M)[1][i]
        _between(t[within[0]] - DT, exact_reach, t[within[0]], "reach")
        sampled = dist[t >= t[within[0]]].max()
        _between(sampled, r["goal_excursion_m"], sampled + speed * DT, "goal_excursion_m")
    assert per[3]["escape_m"] == 0.0
    assert max(r["escape_m"] for r in per) > 0.5  # the sample does leave the box
    # and the workspace's floor, inside the box, gives the larger distance for some robot
    assert any(_outside(d[0], world.lo, world.hi).max() > _outside(d[0], lo, hi).max() + 0.1
               for _, d in dense)
    for key in fleet:
        vals = [r[key] for r in per if r[key] is not None]
        assert fleet[key] == max(vals), key
    assert fleet["peak_speed_ratio"] == np.nanmax(kin.max_speed / v_max)


def test_escape_is_the_euclidean_distance_while_two_axes_are_outside():
    """Outside the unit square past its corner, the axes peak at different times: the
    exact distance is below the corner bound from the per-axis extremes."""
    a = 27.0
    c = np.zeros((1, 2, 5))
    c[0, 0] = [1.0, a, -3 * a, 3 * a, -a]  # x = 1 + a t (1 - t)^3, peak at t = 1/4
    c[0, 1] = [1.0, 0.0, 0.0, a, -a]  # y = 1 + a t^3 (1 - t), peak at t = 3/4
    got = escape_pieces([0], [0.0], [1.0], c, [0.0, 0.0], [1.0, 1.0])[0]
    t = np.arange(0.0, 1.0 + DT / 2, DT)
    x, y = a * t * (1 - t) ** 3, a * t**3 * (1 - t)
    sampled = np.hypot(x, y).max()
    assert sampled - 1e-12 <= got <= sampled + 1e-7
    assert got < np.hypot(x.max(), y.max()) - 1.0
    # unbounded sides never count; inside on every axis: 0; no pieces: NaN
    assert escape_pieces([0], [0.0], [1.0], c, [-np.inf, 0.0], [np.inf, np.inf])[0] == 0.0
    assert escape_pieces([0], [0.0], [1.0], c, [0.0, 0.0], [9.0, 9.0], num_robots=2)[0] == 0.0
    assert np.isnan(escape_pieces([0], [0.0], [1.0], c, [0, 0], [9, 9], num_robots=2)[1])
    with pytest.raises(ValueError, match="lo <= hi"):
        escape_pieces([0], [0.0], [1.0], c, [1.0, 0.0], [0.0, 1.0])


def test_goal_excursion_of_a_line_through_its_goal():
    """x = 2 t on [0, 1] through the goal 1 (tol 0.1): reached at 0.45 s, then up to 1 m
    from it at the end; never within from t_from = 0.6 s on; NaN t_from: not searched."""
    c = np.array([[[0.0, 2.0]]])
    exc, reach = goal_excursion_pieces([0], [0.0], [1.0], c, np.array([[1.0]]), 0.1)
    assert reach[0] == pytest.approx(0.45, abs=1e-12) and exc[0] == pytest.approx(1.0)
    for t_from in (0.6, np.nan):
        exc, reach = goal_excursion_pieces([0], [0.0], [1.0], c, np.array([[1.0]]), 0.1,
                                           t_from=np.array([t_from]))
        assert np.isnan(exc[0]) and np.isnan(reach[0])


# ------------------------------------------------------------- through a run's metrics


def test_the_tiny_runs_metrics_carry_the_limit_keys(tiny_run, tmp_path):
    from jaxplan.cli import summary
    from jaxplan.sweep import COLUMNS, SweepPoint, csv_row

    m, a, sc = tiny_run.metrics, tiny_run.arrays, tiny_run.scenario
    assert m["peak_speed_ratio"] == m["peak_speed_over_limit"]
    for r, v, acc, j in zip(m["per_robot"], sc.v_max, sc.a_max, sc.j_max, strict=True):
        assert r["peak_speed_ratio"] == r["max_speed"] / v
        assert r["peak_acc_ratio"] == r["max_acc"] / acc
        assert r["peak_jerk_ratio"] == r["max_jerk"] / j
        # exact, from the first instant within tolerance: at least the sampled departure
        # from the rollout's (later) reach
        if r["goal_departure_m"] is not None:
            assert r["goal_excursion_m"] >= r["goal_departure_m"] - 1e-12
    for k in ("peak_speed_ratio", "peak_acc_ratio", "peak_jerk_ratio", "goal_excursion_m",
              "escape_m"):
        assert m[k] == max(r[k] for r in m["per_robot"]), k
    # the 100 Hz samples never exceed the exact values, and come within a step of them
    # (its free ends overshoot their goals: robots 0 and 2 leave the fleet's box)
    speed = np.linalg.norm(a["vel"], axis=-1).max(axis=1)
    assert np.all(speed / sc.v_max <= m["peak_speed_ratio"] + 1e-12)
    lo, hi = fleet_box(sc.start, sc.waypoints, ESCAPE_MARGIN_M)
    for r, p, v in zip(m["per_robot"], a["pos"], speed, strict=True):
        out = np.linalg.norm(p - np.clip(p, lo, hi), axis=-1).max()
        _between(out, r["escape_m"], out + v * (a["t"][1] - a["t"][0]), "escape_m")
    assert m["escape_m"] > 0.1
    row = csv_row(SweepPoint(1.0, 1.0, "tiny", 0), m, sc.num_waypoints)
    assert set(row) <= set(COLUMNS)
    for k in ("peak_acc_ratio", "peak_jerk_ratio", "goal_excursion_m", "escape_m"):
        assert float(row[k]) == m[k], k
    assert float(row["peak_speed_ratio"]) == m["peak_speed_ratio"]
    line = next(x for x in summary(m, tmp_path).splitlines() if "peak / limit" in x)
    assert f"jerk {m['peak_jerk_ratio']:.3f} (planned)" in line
    assert line.endswith(f"escape {m['escape_m']:.2f} m")


def test_the_mjx_merge_keeps_the_planned_peaks_and_adds_the_tracked_ones(tiny_run):
    """merge_sim_metrics on control-rate samples (here the tiny run's own 100 Hz samples,
    scaled, as one period): the planned ratios stay, the tracked ones are the samples'."""
    from jaxplan.metrics.report import merge_sim_metrics

    m, a, sc = copy.deepcopy(tiny_run.metrics), dict(tiny_run.arrays), tiny_run.scenario
    M, K = a["pos"].shape[:2]
    period = SimpleNamespace(  # one period of K ticks (PeriodRecord's fields, stacked)
        t=a["t"][None], valid=np.ones((1, K), bool), pos=a["pos"][None],
        vel=1.1 * a["vel"][None], acc=1.3 * a["acc"][None], track_err=np.zeros((1, M, K)),
        min_dist=np.where(np.eye(M, dtype=bool), np.inf, np.nan_to_num(a["min_dist"]))[None],
        static_dist=a["pos"][:, :, 2].min(axis=1)[None, :, None],
        static_t=np.zeros((1, M, 1)), saturated=np.zeros((1, M), np.int32),
        nonfinite=np.zeros((1, M), bool), bad_reference=np.zeros((1, M), np.int32))
    planned = {k: m[k] for k in ("peak_speed_ratio", "peak_acc_ratio", "peak_jerk_ratio",
                                 "goal_excursion_m", "escape_m")}
    merge_sim_metrics(m, a, sc, period)
    assert {k: m[k] for k in planned} == planned
    speed = np.linalg.norm(1.1 * tiny_run.arrays["vel"], axis=-1).max(axis=1) / sc.v_max
    acc = np.linalg.norm(1.3 * tiny_run.arrays["acc"], axis=-1).max(axis=1) / sc.a_max
    assert m["tracked_peak_speed_ratio"] == pytest.approx(speed.max(), rel=1e-12)
    assert m["tracked_peak_speed_ratio"] == m["peak_speed_over_limit"]
    assert m["tracked_peak_acc_ratio"] == pytest.approx(acc.max(), rel=1e-12)
    for r, r0, s, q in zip(m["per_robot"], tiny_run.metrics["per_robot"], speed, acc,
                           strict=True):
        assert r["peak_speed_ratio"] == r0["peak_speed_ratio"]
        assert r["tracked_peak_speed_ratio"] == pytest.approx(s, rel=1e-12)
        assert r["tracked_peak_acc_ratio"] == pytest.approx(q, rel=1e-12)


def test_an_older_sweep_csv_without_the_limit_columns_still_reads(tmp_path):
    from jaxplan.sweep import COLUMNS, SweepError, csv_text, read_sweep_csv

    new = ("peak_acc_ratio", "peak_jerk_ratio", "goal_excursion_m", "escape_m")
    assert COLUMNS[-4:] == new
    old = COLUMNS[:-4]
    row = {c: "1" for c in COLUMNS} | {"q_obs": "1.0", "q_lim": "2.0", "scenario": "s",
                                        "seed": "3", "error": ""}
    lines = csv_text([row], header=True).splitlines()
    p = tmp_path / "sweep.csv"
    p.write_text("".join(",".join(x.split(",")[:len(old)]) + "\n" for x in lines))
    with pytest.raises(SweepError, match="not this version's"):
        read_sweep_csv(p)  # resuming it would mix rows without the new columns
    (got,), _ = read_sweep_csv(p, older=True)
    assert [got[c] for c in new] == [""] * 4 and got["max_goal_departure_m"] == "1"


# ------------------------------------------------------------- end_state = "auto"


def test_an_auto_end_is_free_far_from_the_goal_and_rest_near_it():
    """current_goals: an "auto" waypoint is a rest end within auto_rest_distance of
    where the robot is (its own limits), a free end beyond; rest and free waypoints
    keep their kind wherever the robot is."""
    import jax.numpy as jnp

    from jaxplan.nlp import Limits
    from jaxplan.rollout import Task, auto_rest_distance, current_goals

    lim = Limits(jnp.array([2.0, 1.0, 2.0, 2.0]), jnp.array([4.0, 2.0, 4.0, 4.0]),
                 jnp.array([12.0, 6.0, 12.0, 12.0]))
    D = np.asarray(auto_rest_distance(lim))
    # v^2 / (2 a) braking and v a / (2 j) while the deceleration ramps, twice over
    v, a, j = (np.asarray(x) for x in lim)
    np.testing.assert_allclose(D, 2 * (v**2 / (2 * a) + v * a / (2 * j)))
    goal = np.array([[5.0, 0.0, 1.0]] * 4)
    rest = np.array([[False], [False], [True], [False]])
    auto = np.array([[True], [True], [False], [False]])
    task = Task(start=jnp.zeros((4, 3)), waypoints=jnp.asarray(goal[:, None]),
                rest=jnp.asarray(rest), auto=jnp.asarray(auto),
                goal_velocity=jnp.zeros((4, 1, 3)), goal_tolerance=jnp.asarray(0.1),
                speed_tolerance=jnp.asarray(0.1), faults=None)
    for dist, want in ((D * (1 + 1e-9), [False, False, True, False]),
                       (D * (1 - 1e-9), [True, True, True, False])):
        p = goal - np.stack([dist, np.zeros(4), np.zeros(4)], axis=1)
        g = current_goals(task, 0, jnp.zeros((4, 1), bool), jnp.asarray(p), lim)
        assert np.asarray(g.rest).tolist() == want
        np.testing.assert_array_equal(np.asarray(g.goal_v), 0.0)


def test_an_auto_end_arrives_and_stays(tiny_config, tiny_run):
    """The tiny fleet flies through its free ends and comes back (exact goal excursion
    well over 0.3 m); with end_state = "auto" (the same compiled program: the kind is
    traced) every robot stays within goal_tolerance_m of its goal once there, and is
    settled (still, within tolerance) soon after it first arrives."""
    import dataclasses

    from jaxplan.experiment import run

    free = tiny_run.metrics
    assert free["goal_excursion_m"] > 0.3
    cfg = dataclasses.replace(tiny_config, planner=dataclasses.replace(tiny_config.planner,
                                                                         end_state="auto"))
    cfg = dataclasses.replace(cfg, robots=tuple(dataclasses.replace(r, end_state=("auto",))
                                                for r in cfg.robots))
    res = run(cfg)
    m = res.metrics
    assert res.compile_s == 0.0
    assert np.asarray(res.scenario.auto).all() and not np.asarray(res.scenario.rest).any()
    assert m["success"] and m["collisions"] == 0
    tol = cfg.sim.goal_tolerance_m
    assert m["goal_excursion_m"] <= tol + 1e-9, m["goal_excursion_m"]
    assert m["settled_makespan_s"] <= m["makespan_s"] + 1.0
    assert m["settled_makespan_s"] < free["settled_makespan_s"] - 1.0
