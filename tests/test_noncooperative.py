"""Non-cooperative robots ([[robots]] cooperative = false): the path each flies, against
an independent closed form of its min-jerk legs, alone and inside a fleet that avoids
it; the metrics count it in collisions, not in success."""

import dataclasses
import math

import jax.numpy as jnp
import numpy as np
import pytest

from jaxplan.config import build_scenario, config_to_toml, parse_config
from jaxplan.planner import initial_plan_state
from jaxplan.rollout import own_goals, own_plans
from jaxplan.run_setup import structures, task_of


def min_jerk_path(points, v, a, j, dt, t):
    """Reference: positions (K, N) at times t (K,) of rest-to-rest legs through
    ``points`` (L+1, N), leg k lasting T_k = max(1.875 D / v, sqrt(10 / sqrt(3) D / a),
    (60 D / j)^(1/3)), each starting at the first multiple of dt after the previous
    one ended; at rest at each leg's end until the next."""
    out = np.repeat(np.asarray(points[:1], float), len(t), axis=0)
    t0 = 0.0
    for k in range(len(points) - 1):
        p0, p1 = np.asarray(points[k], float), np.asarray(points[k + 1], float)
        D = np.linalg.norm(p1 - p0)
        T = max(1.875 * D / v, math.sqrt(10.0 / math.sqrt(3.0) * D / a), (60.0 * D / j) ** (1 / 3))
        s = np.clip((t - t0) / T, 0.0, 1.0) if T > 0 else np.ones_like(t)
        shape = 10 * s**3 - 15 * s**4 + 6 * s**5
        on = t >= t0 - 1e-12
        out[on] = p0 + (p1 - p0) * shape[on, None]
        t0 = math.ceil((t0 + T) / dt - 1e-9) * dt
    return out


def _config(tiny_config, robot=2, waypoints=None):
    robots = list(tiny_config.robots)
    r = robots[robot]
    robots[robot] = dataclasses.replace(
        r, cooperative=False,
        **({} if waypoints is None else {"waypoints": tuple(map(tuple, waypoints)),
                                         "end_state": ("free",) * len(waypoints),
                                         "goal_velocity": (None,) * len(waypoints)}))
    return dataclasses.replace(tiny_config, robots=tuple(robots))


def test_the_config_reads_and_writes_cooperative(tiny_config):
    cfg = _config(tiny_config)
    sc = build_scenario(cfg)
    np.testing.assert_array_equal(sc.cooperative, [True, True, False])
    text = config_to_toml(cfg)
    assert text.count("cooperative = false") == 1
    again = parse_config(__import__("tomllib").loads(text), source="again.toml")
    np.testing.assert_array_equal(build_scenario(again).cooperative, sc.cooperative)
    # every robot cooperates: no own paths in the task (the programs of before)
    assert task_of(tiny_config, build_scenario(tiny_config)).own is None


def test_own_plans_follow_the_min_jerk_legs_within_the_limits(tiny_config):
    """At replan instants (and between them, as the rollout's t drifts) the robot's plan
    is its own path from then on: positions to 1e-8 m of the closed form (its durations
    carry 1e-9 of slack), and the plan's speed, acceleration and jerk within the
    vehicle's limits on a 1 ms sample."""
    wps = [[2.0, 2.0, 1.5], [2.0, 2.0, 2.5], [-1.0, 0.5, 2.0]]
    cfg = _config(tiny_config, waypoints=wps)
    sc = build_scenario(cfg)
    st = structures(cfg)
    task = task_of(cfg, sc)
    assert task.own is not None and bool(task.own.mask[2]) and not bool(task.own.mask[0])
    dt = 1.0 / cfg.planner.replan_hz
    v, a, j = (float(x[2]) for x in (sc.v_max, sc.a_max, sc.j_max))
    pts = np.concatenate([sc.start[2:3], sc.waypoints[2]])
    ps = initial_plan_state(jnp.asarray(sc.start), st.planner, sc.num_robots)
    horizon = 14.0
    peaks = np.zeros(3)
    for step in range(int(horizon / dt)):
        t = step * dt * (1.0 + 1e-12)  # the rollout's t, summed in floating point
        plan = jax_tree_index(own_plans(task, t, dt, ps).plan, 2)
        tau = np.arange(0.0, dt, 1e-3)
        got = np.asarray(plan.evaluate(jnp.asarray(tau), 0))
        want = min_jerk_path(pts, v, a, j, dt, t + tau)
        np.testing.assert_allclose(got, want, atol=1e-8, rtol=0)
        for d in (1, 2, 3):
            x = np.linalg.norm(np.asarray(plan.evaluate(jnp.asarray(tau), d)), axis=-1)
            peaks[d - 1] = max(peaks[d - 1], x.max())
    assert peaks[0] <= v and peaks[1] <= a and peaks[2] <= j + 1e-9, peaks
    assert peaks[0] > 0.999 * v  # the 3 m leg is speed-limited: as short as the limits allow
    # it publishes the end of its current leg, a rest end
    goals = own_goals(task, 4.0, dt, _dummy_goals(sc))
    np.testing.assert_allclose(np.asarray(goals.goal_p[2]), wps[1])
    assert bool(goals.rest[2])


def jax_tree_index(tree, i):
    import jax

    return jax.tree.map(lambda x: x[i], tree)


def _dummy_goals(sc):
    from jaxplan.planner import Goals

    M, N = sc.num_robots, sc.dim
    return Goals(jnp.zeros((M, N)), jnp.zeros((M, N)), jnp.zeros((M,), bool))


@pytest.fixture(scope="module")
def crossing(tiny_config):
    """The tiny fleet with its crossing robot (2) non-cooperative, run end to end (a
    program of its own: ~18 s of compile, so `make test-slow`)."""
    from jaxplan.experiment import run

    cfg = _config(tiny_config)
    return cfg, run(cfg)


@pytest.mark.slow
def test_a_non_cooperative_robot_flies_its_path_and_the_others_avoid_it(crossing):
    cfg, res = crossing
    sc, arr, m = res.scenario, res.arrays, res.metrics
    dt = 1.0 / cfg.planner.replan_hz
    pts = np.concatenate([sc.start[2:3], sc.waypoints[2]])
    want = min_jerk_path(pts, *(float(x[2]) for x in (sc.v_max, sc.a_max, sc.j_max)), dt,
                         arr["t"])
    # the executed pieces, sampled at 100 Hz: its own path, whatever the others did
    np.testing.assert_allclose(arr["pos"][2], want, atol=1e-8, rtol=0)
    np.testing.assert_array_equal(arr["cooperative"], [True, True, False])
    # it crossed the others' swap line at speed; they gave way (no collision, exact)
    assert m["collisions"] == 0 and m["min_separation_ratio"] >= 1.0
    assert m["per_robot"][2]["cooperative"] is False
    assert m["per_robot"][2]["peak_speed_ratio"] <= 1.0
    assert m["success"] and all(r["reached"] for r in m["per_robot"][:2])
    # the makespan is the cooperative robots' own
    assert m["makespan_s"] == pytest.approx(max(r["time_to_goal_s"] for r in m["per_robot"][:2]))


def test_success_counts_the_cooperative_robots_and_collisions_count_all(tiny_run):
    from jaxplan.metrics.report import _success

    m = dict(tiny_run.metrics)
    assert _success(m)
    per = [dict(r) for r in m["per_robot"]]
    per[2]["cooperative"] = False
    per[2]["reached"] = False
    assert _success({**m, "per_robot": per})  # the non-cooperative robot's arrival: no matter
    per[0]["reached"] = False
    assert not _success({**m, "per_robot": per})
    assert not _success({**m, "collisions": 1})  # its collisions (any pair) count


def test_the_baselines_refuse_a_fleet_with_a_non_cooperative_robot(tiny_config):
    """ORCA moves every agent itself: it would make the intruder avoid the others."""
    from jaxplan.experiment import run_method

    cfg = _config(tiny_config)
    for method in ("orca", "orca3d"):
        c = dataclasses.replace(cfg, planner=dataclasses.replace(cfg.planner, method=method))
        with pytest.raises(ValueError, match="non-cooperative"):
            run_method(c, build_scenario(c))
