"""Planner step (shapes, fallbacks, no NaN) and receding-horizon rollout (determinism,
goals, exact separation of the executed pieces)."""

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplan import experiment as ex
from jaxplan import metrics as mt
from jaxplan import run_setup as rs
from jaxplan import solve
from jaxplan.config import build_scenario
from jaxplan.metrics.report import goal_departure
from jaxplan.planner import (
    ACCEPTED,
    BEST_EFFORT,
    BRAKING,
    KEPT_PREVIOUS,
    braking_plan,
    fresh_views,
    resample,
)
from jaxplan.rollout import initial_state
from jaxplan.trajectory import Trajectory


def _setup(cfg):
    sc = build_scenario(cfg)
    structure = rs.structures(cfg)
    return sc, structure, rs.fleet_params(cfg, sc), rs.task_of(cfg, sc)


def test_tiny_run_succeeds_and_is_collision_free(tiny_run):
    m = tiny_run.metrics
    assert m["success"], m
    assert m["collisions"] == 0
    assert m["min_separation_ratio"] > 1.0
    for r in m["per_robot"]:
        assert r["reached"]
        assert r["max_speed"] <= 1.05 * r["v_max"]
    a = tiny_run.arrays
    assert np.all(np.isfinite(a["pos"])) and np.all(np.isfinite(a["seg_coeffs"]))


def test_goal_departure_after_reaching(tiny_run):
    # by hand: robot 0 reaches its goal at 1 s, drifts 0.5 m away at 2 s and comes back;
    # robot 1 never reaches it; robot 2 reaches it at the last sample
    t = np.linspace(0.0, 3.0, 31)
    pos = np.zeros((3, 31, 2))
    pos[0, :, 0] = np.where(t < 1.0, 1.0 - t, 0.5 * np.sin(np.pi * (t - 1.0) / 2.0) ** 2)
    pos[1, :, 0] = 5.0
    goal = np.zeros((3, 2))
    dep = goal_departure(t, pos, goal, np.array([1.0, np.nan, 3.0]))
    assert dep[0] == pytest.approx(0.5) and np.isnan(dep[1]) and dep[2] == 0.0
    # the tiny run: per robot, against the trajectories.npz samples from its time to goal
    m, a = tiny_run.metrics, tiny_run.arrays
    for i, r in enumerate(m["per_robot"]):
        after = a["t"] >= r["time_to_goal_s"]
        d = np.linalg.norm(a["pos"][i, after] - a["goal"][i], axis=-1).max()
        assert r["goal_departure_m"] == pytest.approx(d, abs=1e-12)
        assert d >= np.linalg.norm(a["pos"][i, -1] - a["goal"][i])
    assert m["max_goal_departure_m"] == max(r["goal_departure_m"] for r in m["per_robot"])
    # settled: within goal_tolerance_m from then to the end, not the sample before (free
    # ends: position only)
    assert not np.any(tiny_run.scenario.rest)
    tol = tiny_run.config.sim.goal_tolerance_m
    for i, r in enumerate(m["per_robot"]):
        d = np.linalg.norm(a["pos"][i] - a["goal"][i], axis=-1)
        k = int(np.searchsorted(a["t"], r["settled_s"]))
        assert a["t"][k] == r["settled_s"] and np.all(d[k:] <= tol) and d[k - 1] > tol
        assert r["settled_s"] >= r["time_to_goal_s"]
    assert m["settled_makespan_s"] == max(r["settled_s"] for r in m["per_robot"])
    # free ends: the tiny swap's robots pass their goals at speed (first within 0.1 m)
    # and come back (examples/tiny.toml: the default end_state, "free", the paper's)
    assert m["settled_makespan_s"] > m["makespan_s"]
    assert m["max_goal_departure_m"] > 10 * tol
    # and a sweep's row of this run carries both
    from jaxplan.sweep import SweepPoint, csv_row

    row = csv_row(SweepPoint(1.0, 1.0, "tiny", 0), m)
    assert float(row["settled_makespan_s"]) == m["settled_makespan_s"]
    assert float(row["max_goal_departure_m"]) == m["max_goal_departure_m"]


def test_plans_last_at_least_two_replan_periods(tiny_run):
    # a plan shorter than that is flown to its end within one period and can brake at
    # several a_max there (run_setup.T_MIN_PERIODS)
    rec = tiny_run.records
    hz = tiny_run.config.planner.replan_hz
    T = np.asarray(rec.piece_t0)[:, :, -1] - np.asarray(rec.t)[:, None]  # the plan's end
    assert T.min() >= 2.0 / hz - 1e-9
    assert np.isclose(T.min(), 2.0 / hz)  # the bound is reached (settled robots)


def test_executed_pieces_tile_and_match_states(tiny_run):
    a = tiny_run.arrays
    rec = tiny_run.records
    for i in range(3):
        sel = a["seg_robot"] == i
        t0, t1 = a["seg_t0"][sel], a["seg_t1"][sel]
        np.testing.assert_allclose(t0[1:], t1[:-1], atol=1e-12)  # no gaps, no overlaps
        assert t0[0] == 0.0
    # the executed pieces reproduce the measured state at every replan
    pos, vel, _ = mt.sample_pieces(a["seg_robot"], a["seg_t0"], a["seg_t1"], a["seg_coeffs"],
                                   np.asarray(rec.t), num_robots=3, outside="clamp")
    np.testing.assert_allclose(pos.transpose(1, 0, 2), rec.p, atol=1e-9)
    np.testing.assert_allclose(vel.transpose(1, 0, 2), rec.v, atol=1e-9)


def test_exact_separation_not_above_dense_samples(tiny_run):
    a = tiny_run.arrays
    t = np.linspace(0, a["seg_t1"].max(), 20001)
    pos, _, _ = mt.sample_pieces(a["seg_robot"], a["seg_t0"], a["seg_t1"], a["seg_coeffs"],
                                 t, num_robots=3, outside="clamp")
    for i in range(3):
        for j in range(i + 1, 3):
            dense = np.linalg.norm(pos[i] - pos[j], axis=-1).min()
            assert a["min_dist"][i, j] <= dense + 1e-12


def _avals(tree):
    return [(jax.tree_util.keystr(k), x.shape, x.dtype, x.weak_type)
            for k, x in jax.tree_util.tree_leaves_with_path(jax.eval_shape(lambda t: t, tree))]


def test_a_step_returns_the_state_types_it_was_given(tiny_config):
    """The state after a replan period has the initial state's shapes, dtypes and weak
    types (ideal and mjx): a jitted step then compiles once, not once for the first state
    and again for every later one (a weakly typed inf in the initial state did that)."""
    from jaxplan.sim import closed_loop as cl
    from jaxplan.sim import fleet as sf

    sc, structure, fp, task = _setup(tiny_config)
    st = initial_state(task, structure)
    # the ideal step as the Python API jits it (compiled once for the tiny unit: the
    # experiment's run and the next tests use it): two periods, one compilation
    f = ex.step_runner(structure)
    out, _ = f(fp, task, st)
    assert _avals(out) == _avals(st)
    f(fp, task, out)
    assert f._cache_size() == 1
    sim, _ = sf.init_sim(list(sc.vehicles), sc.start, world=sc.world)
    carry = cl.mjx_initial_state(task, structure, sim)
    out, _ = jax.eval_shape(
        lambda f, t, c: cl.mjx_step(f, t, *c, structure, sim, 0.125), fp, task, carry)
    assert _avals(out) == _avals(carry)


def test_rollout_is_deterministic(tiny_config):
    sc, structure, fp, task = _setup(tiny_config)
    f = ex.step_runner(structure)
    outs = []
    for _ in range(2):
        st = initial_state(task, structure)
        for _ in range(5):
            st, rec = f(fp, task, st)
        outs.append((np.asarray(st.p), np.asarray(rec.piece_coeffs)))
    np.testing.assert_array_equal(outs[0][0], outs[1][0])
    np.testing.assert_array_equal(outs[0][1], outs[1][1])


def test_forced_solver_failure_keeps_previous_plan(tiny_config):
    sc, structure, fp, task = _setup(tiny_config)
    f = ex.step_runner(structure)
    st = initial_state(task, structure)
    # a solve that cannot be evaluated (NaN weight -> NON_FINITE) and no previous plan: braking
    fp_nan = fp._replace(weights=fp.weights._replace(q_dynm=jnp.asarray(jnp.nan)))
    st1, rec1 = f(fp_nan, task, st)
    assert np.all(np.asarray(rec1.info.status) == solve.NON_FINITE)
    assert np.all(np.asarray(rec1.info.fallback) == BRAKING)
    # again: now the previous (braking) plan is kept, exactly, shifted by the period
    st2, rec2 = f(fp_nan, task, st1)
    assert np.all(np.asarray(rec2.info.fallback) == KEPT_PREVIOUS)
    prev = st1.plans.plan.shift(fp.dt)
    t = np.linspace(0, 1.0, 7)
    np.testing.assert_allclose(np.asarray(st2.plans.plan.sample(t)), np.asarray(prev.sample(t)),
                               atol=1e-12)
    for x in jax.tree.leaves(st2):  # no NaN anywhere (reach times are inf until reached)
        assert not np.any(np.isnan(np.asarray(x)))
    # nothing is accepted (zero iterations never converge, no violation is small enough)
    # but the solves are finite: they are flown (BEST_EFFORT), not the old plan
    fp_fail = fp._replace(settings=fp.settings._replace(max_iters=np.int32(0)),
                          accept_violation=jnp.asarray(-1.0))
    st3, rec3 = f(fp_fail, task, st2)
    assert np.all(np.asarray(rec3.info.status) != solve.CONVERGED)
    assert np.all(np.asarray(rec3.info.fallback) == BEST_EFFORT)
    kept = st2.plans.plan.shift(fp.dt)
    assert not np.allclose(np.asarray(st3.plans.plan.sample(t)), np.asarray(kept.sample(t)))
    assert np.all(np.isfinite(np.asarray(st3.plans.plan.coeffs)))
    # with normal settings every lane of the first replan is accepted
    _, rec_ok = f(fp, task, st)
    assert np.all(np.asarray(rec_ok.info.fallback) == ACCEPTED)


def test_nonfinite_views_do_not_poison_the_step(tiny_config):
    sc, structure, fp, task = _setup(tiny_config)
    st = initial_state(task, structure)
    f = ex.step_runner(structure)
    st1, _ = f(fp, task, st)
    # corrupt robot 2's state: its own plan falls back; the others stay finite
    bad = st1._replace(p=st1.p.at[2, 0].set(jnp.nan))
    st2, rec = f(fp, task, bad)
    assert np.all(np.isfinite(np.asarray(rec.piece_coeffs)[:2]))
    assert np.all(np.isfinite(np.asarray(st2.plans.plan.coeffs)[:2]))


def test_braking_plan_stops(rng):
    from jaxplan.planner import PlannerStructure

    p = rng.normal(size=(4, 3))
    v = rng.normal(size=(4, 3))
    a = rng.normal(size=(4, 3))

    @jax.jit  # one program: op by op (eager) this test took ~2 s more
    def run(p, v, a):
        b = braking_plan(p, v, a, jnp.full((4,), 4.0), PlannerStructure())
        return (b.evaluate(0.0), b.evaluate(0.0, 1), b.evaluate(b.duration, 1),
                b.evaluate(b.duration + 1.0, 1))

    p0, v0, v_end, v_after = map(np.asarray, run(jnp.asarray(p), jnp.asarray(v), jnp.asarray(a)))
    np.testing.assert_allclose(p0, p, atol=1e-12)
    np.testing.assert_allclose(v0, v, atol=1e-12)
    np.testing.assert_allclose(v_end, 0.0, atol=1e-12)
    np.testing.assert_allclose(v_after, 0.0, atol=1e-12)


def test_resample_is_exact(rng):
    c = rng.normal(size=(5, 1, 3, 6))
    one = Trajectory.from_normalized(c, rng.uniform(0.5, 3, 5), coast=True)
    t = np.linspace(0, 4, 33)

    @functools.partial(jax.jit, static_argnums=(1, 2))  # one program each, not op by op
    def both(tr, S, D):
        r = resample(tr, S, D)
        return r.coeffs, [(r.sample(t, d), tr.sample(t, d)) for d in range(3)]

    for S, D in [(1, 5), (3, 5), (2, 7)]:
        coeffs, pairs = both(one, S, D)
        assert coeffs.shape == (5, S, 3, D + 1)
        for got, want in pairs:
            np.testing.assert_allclose(np.asarray(got), np.asarray(want), atol=1e-10)


def test_fresh_views_shapes():
    M, N = 4, 3
    z = jnp.zeros((M, N))
    v = fresh_views(z, z, z, z, z, jnp.zeros(M, bool))
    assert v.p.shape == (M, M, N) and v.valid.shape == (M, M) and bool(jnp.all(v.valid))


def test_structure_of_run_does_not_depend_on_duration(tiny_config):
    s1 = rs.structures(tiny_config)
    cfg2 = dataclasses.replace(tiny_config, sim=dataclasses.replace(tiny_config.sim,
                                                                    duration_s=3.0))
    s2 = rs.structures(cfg2)
    assert s1.steps != s2.steps
    assert ex.step_runner(s1) is ex.step_runner(s2)  # one compilation for both


def test_pick_fallback_takes_the_least_violation():
    from jaxplan.planner import pick_fallback
    inf = np.inf
    v_sol = jnp.asarray([0.0, 0.3, 0.3, inf, inf, 0.2, 0.1])
    v_prev = jnp.asarray([0.0, 0.1, 0.5, 0.2, inf, 0.2, 0.1 + 5e-7])
    v_brake = jnp.asarray([0.0, 0.2, 0.1, 0.2, 0.4, 0.2, 0.0])
    got = np.asarray(pick_fallback(v_sol, v_prev, v_brake))
    np.testing.assert_array_equal(
        got, [BEST_EFFORT, KEPT_PREVIOUS, BRAKING, KEPT_PREVIOUS, BRAKING, BEST_EFFORT, BRAKING])


def test_plan_violation_matches_a_direct_computation():
    from jaxplan.planner import CHECK_HORIZON_S, CHECK_SAMPLES, plan_violation
    # robot 0 flies along x at 1 m/s (a linear polynomial, coasting); robot 1 hovers.
    c = np.zeros((2, 1, 3, 6))
    c[0, 0, 0, 1] = 0.5  # x = 0.5 s over T = 0.5 s, then coasts at 1 m/s
    plans = Trajectory.from_normalized(c, jnp.asarray([0.5, 0.5]),
                                       coast=jnp.asarray([True, False]))
    # each robot sees the other held at a point: robot 0 sees (1.2, 0.1, 0), robot 1
    # sees (-5, 0, 0), far away
    pts = np.array([[[0.0, 0, 0], [1.2, 0.1, 0]], [[-5.0, 0, 0], [0.0, 0, 0]]])
    others = Trajectory.hold(jnp.asarray(pts), 5, 1)
    mask = jnp.asarray([[False, True], [True, False]])
    rad = jnp.asarray([0.25, 0.25])
    orad = jnp.full((2, 2), 0.3)
    got = np.asarray(jax.jit(plan_violation)(plans, others, rad, orad, mask))  # not op by op
    t = np.arange(1, CHECK_SAMPLES + 1) * CHECK_HORIZON_S / CHECK_SAMPLES
    d = np.hypot(t - 1.2, 0.1)
    np.testing.assert_allclose(got[0], max(0.0, np.max(0.55 - d)), rtol=1e-12)
    assert got[0] > 0.4
    assert got[1] == 0.0


def test_plan_violation_weighs_an_obstacle_above_a_robot():
    """Depth into an obstacle counts STATIC_PRIORITY times depth into a robot's planning
    distance: of two plans, one 3 cm into a robot's and one 2 cm into a sphere's, the
    robot's is the lesser (an obstacle does not make way; random_obstacles seed 9 flew
    a best-effort plan 2.3 cm into a sphere when both weighed the same)."""
    from jaxplan.nlp.terms import STATIC_PRIORITY
    from jaxplan.planner import pick_fallback, plan_violation
    from jaxplan.world import World, static_rows
    assert STATIC_PRIORITY > 1.5
    rad = jnp.asarray([0.3, 0.3])
    world = World.default(3).with_obstacles(
        [{"kind": "sphere", "center": [0.0, 0.0, 5.0], "radius": 1.0}])
    static = jax.tree.map(jnp.asarray, static_rows(world))
    # robot 0 holds 2 cm inside its planning radius of the sphere, robot 1 3 cm inside
    # robot 0's planning distance (0.3 + 0.3), both well above the ground
    pts = np.array([[0.0, 0.0, 5.0 + 1.0 + 0.28], [20.0, 0.0, 5.0]])
    plans = Trajectory.hold(jnp.asarray(pts), 5, 1)
    seen = np.array([[[0.0, 0, 0], [40.0, 0, 5.0]], [[20.57, 0.0, 5.0], [0.0, 0, 0]]])
    others = Trajectory.hold(jnp.asarray(seen), 5, 1)
    mask = jnp.asarray([[False, True], [True, False]])
    orad = jnp.full((2, 2), 0.3)
    # one program (as the planner forms it): op by op (eager) this test took ~4 s more
    got = np.asarray(jax.jit(plan_violation)(plans, others, rad, orad, mask, static))
    np.testing.assert_allclose(got, [STATIC_PRIORITY * 0.02, 0.03], atol=1e-5)  # sqrt smoothing
    # as three fallbacks of one robot: the plan into the robot wins
    code = pick_fallback(jnp.asarray(got[0]), jnp.asarray(got[1]), jnp.asarray(np.inf))
    assert int(code) == KEPT_PREVIOUS


def test_static_constraint_grows_faster_than_a_pairs():
    """Near its boundary a static row's g grows STATIC_PRIORITY times as fast per metre
    as a pair's d^2 - rho^2 with rho = 2 r (jaxplan.nlp.terms.static_scale)."""
    from jaxplan.nlp.terms import STATIC_PRIORITY, static_scale

    class P:  # noqa: D401 - the one field static_scale reads
        radius = jnp.asarray(0.35)
    rho, eps = 0.7, 1e-6
    pair_rate = ((rho + eps) ** 2 - rho**2) / eps
    np.testing.assert_allclose(float(static_scale(P)), STATIC_PRIORITY * pair_rate, rtol=1e-5)


def test_coast_rows_only_where_a_free_end_can_occur():
    import tomllib

    from jaxplan.config import parse_config
    from jaxplan.sweep import structure_for as _structure
    from tests.conftest import TINY_TOML

    def cfg(end):
        return parse_config(tomllib.loads(TINY_TOML + f'[planner]\nend_state = "{end}"\n'),
                            source="t.toml")
    assert rs.structures(cfg("free")).planner.nlp.n_coast_samples == 8
    assert rs.structures(cfg("rest")).planner.nlp.n_coast_samples == 0
    assert _structure(cfg("rest"), 3).planner.nlp.n_coast_samples == 8  # a sweep keeps them


def test_a_silent_robot_is_held_where_it_can_have_braked_to():
    """A view older than STALE_AFTER_S: the sender flew on one period along its prediction
    and then braked to rest (the braking plan, as a frozen robot does); every point of
    that path lies within ``floor`` of where the view holds it."""
    from types import SimpleNamespace

    from jaxplan.nlp import Limits
    from jaxplan.planner import (
        STALE_AFTER_S,
        PlannerStructure,
        braking_plan,
        fresh_views,
        view_predictions,
    )
    from jaxplan.predict import predict_arrays

    p = jnp.array([[0.0, 0.0, 1.0], [3.0, 0.0, 1.0]])
    v = jnp.array([[1.5, 0.4, 0.0], [0.0, 0.0, 0.0]])
    a = jnp.array([[0.5, -1.0, 0.0], [0.0, 0.0, 0.0]])
    goal = jnp.array([[9.0, 3.0, 1.0], [3.0, 0.0, 1.0]])
    lim = Limits(jnp.full(2, 2.0), jnp.full(2, 4.0), jnp.full(2, 12.0))
    fp = SimpleNamespace(dt=jnp.asarray(0.125), prediction_weight=jnp.asarray(6.0), limits=lim,
                         keep_right=None)
    t1 = np.linspace(0.0, 0.125, 50)
    t2 = np.linspace(0.0, 3.0, 300)

    # jitted, one program: the same ops run eagerly cost ~3x longer (each op its own program)
    @jax.jit
    def run(p, v, a, goal):
        views = fresh_views(p, v, a, goal, jnp.zeros_like(p), jnp.zeros(2, bool))
        views = views._replace(age=jnp.full((2, 2), STALE_AFTER_S + 0.5))
        preds, inflate, floor = view_predictions(fp, views)
        held = preds.evaluate(0.0)[1, 0]  # robot 1's view of robot 0
        # reference: robot 0's own path, its prediction for one period, then its braking plan
        pr = predict_arrays(p[:1], v[:1], a[:1], goal[:1], jnp.zeros((1, 3)),
                            jnp.zeros((1, 3)), jnp.zeros(1, bool), 6.0)
        s1 = [x[0][None] for x in pr.state_at(jnp.asarray([0.125]))]
        brake = braking_plan(*s1, lim.a_max[:1], PlannerStructure())
        path = [pr.evaluate(jnp.asarray(t1)[:, None])[:, 0],
                brake.evaluate(jnp.asarray(t2)[:, None])[:, 0]]
        return held, jnp.concatenate(path), inflate, floor

    held, path, inflate, floor = map(np.asarray, run(p, v, a, goal))
    d = np.linalg.norm(path - held, axis=-1)
    assert d.max() > 0.2  # it moved a fair way
    assert d.max() <= float(floor[1, 0]) + 1e-9
    assert float(inflate[1, 0]) >= float(floor[1, 0])


def test_keep_right_shifts_each_prediction_to_its_senders_right():
    """[planner] keep_right_m: each observer's prediction of a sender is the closed form
    shifted by the offset to the sender's right of its way to its goal (horizontal in
    3-D; none for a vertical way), its radius grown by as much, so the shifted ball holds
    the unshifted one."""
    from types import SimpleNamespace

    from jaxplan.nlp import Limits
    from jaxplan.planner import fresh_views, view_predictions

    p = jnp.array([[0.0, 0.0, 1.0], [4.0, 0.0, 1.0], [2.0, 3.0, 1.0]])
    goal = jnp.array([[4.0, 0.0, 1.0], [0.0, 0.0, 1.0], [2.0, 3.0, 4.0]])  # 2: straight up
    z = jnp.zeros_like(p)
    lim = Limits(jnp.full(3, 2.0), jnp.full(3, 4.0), jnp.full(3, 12.0))
    views = fresh_views(p, z, z, goal, z, jnp.zeros(3, bool))
    t = jnp.linspace(0.0, 6.0, 25)[:, None, None]

    def run(offset):  # one program each (None and an offset are different trees)
        fp = SimpleNamespace(dt=jnp.asarray(0.125), prediction_weight=jnp.asarray(6.0),
                             limits=lim, keep_right=offset)
        preds, inflate, _ = jax.jit(lambda: view_predictions(fp, views))()
        return np.asarray(preds.evaluate(t)), np.asarray(inflate)

    (plain, inf0), (kept, inf1) = run(None), run(jnp.asarray(0.15))
    shift = kept - plain  # (t, observer, sender, N)
    # robot 0 flies +x: its right is -y; robot 1 flies -x: its right is +y
    np.testing.assert_allclose(shift[:, :, 0], np.broadcast_to([0.0, -0.15, 0.0], (25, 3, 3)),
                               atol=1e-12)
    np.testing.assert_allclose(shift[:, :, 1], np.broadcast_to([0.0, 0.15, 0.0], (25, 3, 3)),
                               atol=1e-12)
    np.testing.assert_allclose(shift[:, :, 2], 0.0, atol=1e-12)  # a vertical way: no right
    np.testing.assert_allclose(inf1 - inf0, 0.15, atol=1e-12)
