"""Tests of jaxplan.sim.fleet: the MJX closed loop that tracks the planner's plans.

One 3-vehicle mixed fleet (hummingbird, firefly, neo11), 500 Hz physics, 250 Hz
control, 8 Hz periods (31.25 control ticks: periods of 32 and 31 ticks alternate), in a
world with a floor, a ceiling and one obstacle of each kind, the cylinder moving (WORLD:
a mocap body of the model), is shared by most tests so that ``simulate_period`` compiles
once for them.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import jaxplan  # noqa: F401  (x64)
from jaxplan.sim import fleet, se3
from jaxplan.sim import model as sm
from jaxplan.trajectory import Trajectory
from jaxplan.vehicles import get_vehicle
from jaxplan.world import World, signed_distance, static_rows

NAMES = ["hummingbird", "firefly", "neo11"]
START = np.array([[0.0, 0.0, 1.0], [0.0, 2.0, 1.5], [0.0, 4.0, 2.0]])
PERIOD = 0.125
HZ_C, HZ_P = 250.0, 500.0


# away from every other test's paths; vehicle 0's line to WORLD_GOAL[0] crosses the
# sphere, vehicle 1 descends below its radius above the floor, vehicle 2 stays clear;
# the cylinder walks towards vehicle 1 (closest at t = 1 s) and back (CYL_PATH)
CYL_PATH = ([0.0, 1.0, 2.0], [[-3.0, 2.5, 1.0], [-0.8, 2.5, 1.0], [-3.0, 2.5, 1.0]])
WORLD = World(np.array([-np.inf, -np.inf, 0.0]), np.array([np.inf, np.inf, 6.0]),
              np.zeros(0, np.int32), np.zeros((0, 3)), np.zeros((0, 3)),
              np.zeros(0)).with_obstacles([
                  dict(kind="sphere", center=[1.5, 0.0, 1.0], radius=0.3),
                  dict(kind="box", center=[1.0, 5.5, 2.0], half_extents=[0.3, 0.3, 0.3]),
                  dict(kind="cylinder", radius=0.2, half_height=1.0,
                       path=[dict(t=t, p=p) for t, p in zip(*CYL_PATH, strict=True)])])
WORLD_GOAL = np.array([[2.0, 0.0, 1.0], [0.0, 2.0, 0.15], [2.0, 4.0, 2.0]])


@pytest.fixture(scope="module")
def sim():
    return fleet.init_sim(NAMES, START, world=WORLD)


def cylinder_at(t):
    """(..., 3) m: WORLD's cylinder at times t (...,) s, interpolated here by hand (at
    rest before the first and after the last point), not by jaxplan.motion."""
    t = np.asarray(t, np.float64)
    ts, ps = np.asarray(CYL_PATH[0]), np.asarray(CYL_PATH[1])
    return np.stack([np.interp(t, ts, ps[:, d]) for d in range(3)], axis=-1)


def world_centres(t):
    """(..., R, 3): WORLD's rows (3 obstacles, z_min, z_max) where they are at times t."""
    rows = static_rows(WORLD)
    c = np.broadcast_to(rows.center, np.shape(t) + rows.center.shape).copy()
    c[..., 2, :] = cylinder_at(t)
    return c

def min_jerk(p0, p1, peak_speed=2.0):
    """Straight min-jerk (quintic) lines p0 -> p1 (M, 3) at the given peak speed, m/s."""
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    L = p1 - p0
    T = 1.875 * np.linalg.norm(L, axis=1) / peak_speed
    c = np.zeros((len(p0), 1, 3, 6))
    c[:, 0, :, 0] = p0
    c[:, 0, :, 3], c[:, 0, :, 4], c[:, 0, :, 5] = 10 * L, -15 * L, 6 * L
    return Trajectory.from_normalized(jnp.asarray(c), jnp.asarray(T))


def run_periods(sim_model, state, plans, n_periods, t_offset=None):
    """n periods of one plan that started at tick 0; returns (state, list of records)."""
    recs = []
    for _ in range(n_periods):
        t0 = fleet.sim_time(sim_model, state) if t_offset is None else t_offset(state)
        state, rec = fleet.simulate_period(sim_model, state, plans, t0, PERIOD)
        recs.append(jax.tree.map(np.asarray, rec))
    return state, recs


def concat(recs, field):
    """Valid samples of a (M, K, ...) record field over periods: (M, sum K, ...)."""
    return np.concatenate([getattr(r, field)[:, r.valid] for r in recs], axis=1)


# ----------------------------------------------------------------------------- hover, grid


def test_hover_mixed_fleet(sim):
    model, state = sim
    state, recs = run_periods(model, state, Trajectory.hold(jnp.asarray(START)), 16)
    assert int(state.tick) == 500                       # 2 s exactly: the period grid holds
    assert [int(r.valid.sum()) for r in recs[:4]] == [32, 31, 31, 31]
    t = np.concatenate([r.t[r.valid] for r in recs])
    np.testing.assert_allclose(t, np.arange(500) / HZ_C, atol=1e-12)   # uniform 250 Hz
    pos = concat(recs, "pos")
    assert np.abs(pos - START[:, None, :]).max() < 1e-3
    p, v, a = (np.asarray(x) for x in fleet.measured_state(model, state))
    assert np.abs(p - START).max() < 1e-3 and np.abs(v).max() < 1e-3 and np.abs(a).max() < 1e-3
    assert all(r.saturated.sum() == 0 and r.bad_reference.sum() == 0 for r in recs)
    assert not any(r.nonfinite.any() for r in recs)


# ----------------------------------------------------------------------------- tracking


def test_tracking_min_jerk_each_kind(sim):
    """3 m straight lines at a 2 m/s peak speed (2.2 m/s^2 peak acceleration), one per
    vehicle kind, in different directions."""
    model, state = sim
    goal = START + np.array([[3.0, 0.0, 0.0], [-1.5, 1.5, 2.0], [2.0, -2.0, -0.7]])
    goal = START + (goal - START) * (3.0 / np.linalg.norm(goal - START, axis=1))[:, None]
    plans = min_jerk(START, goal)
    state, recs = run_periods(model, state, plans, 28)     # 3.5 s, the plans last 2.81 s
    err = concat(recs, "track_err")
    rms, mx = np.sqrt((err**2).mean(axis=1)), err.max(axis=1)
    # measured (hummingbird / firefly / neo11): rms 1.2 / 1.3 / 2.9 cm, max 2.1 / 2.4 / 5.1 cm
    assert np.all(rms <= 0.05) and np.all(mx <= 0.15), (rms, mx)
    vel = concat(recs, "vel")
    assert np.linalg.norm(vel, axis=-1).max() > 1.9          # it really flew at ~2 m/s
    p, v, _ = fleet.measured_state(model, state)
    assert np.abs(np.asarray(p) - goal).max() < 0.03   # measured 1.7 cm, 0.7 s after the end
    assert sum(int(r.saturated.sum()) for r in recs) == 0


# ----------------------------------------------------------------------------- C engine


def c_reference(plans, n_periods, names=NAMES, start=START, physics_hz=HZ_P, control_hz=HZ_C):
    """The same closed loop in the MuJoCo C engine (mj_step), independent of fleet.py.

    Returns (per-tick (qpos, qvel, qacc) before control, positions after every physics
    step (P+1, M, 3) including the start, period boundaries in ticks).
    """
    M = len(names)
    m = sm.fleet_model(names, start, timestep=1.0 / physics_hz, visual=False)
    d = mujoco.MjData(m)
    params = se3.controller_params(names)
    zero = jnp.zeros(M)

    @jax.jit
    def control(qp, qv, t):
        ref = se3.Reference(plans.evaluate(t, 0), plans.evaluate(t, 1), plans.evaluate(t, 2),
                            plans.evaluate(t, 3), zero, zero)
        out = se3.fleet_control(params, sm.fleet_state(qp, qv), ref)
        return out.thrust, out.moments

    per = PERIOD * control_hz
    bounds = [math.ceil(p * per - 1e-9) for p in range(n_periods + 1)]
    sub = int(round(physics_hz / control_hz))
    ticks, phys = [], [d.qpos.reshape(M, 7)[:, :3].copy()]
    for k in range(bounds[-1]):
        ticks.append((d.qpos.copy(), d.qvel.copy(), d.qacc.copy()))
        f, mom = control(d.qpos, d.qvel, k / control_hz)
        d.ctrl[:] = sm.fleet_ctrl(np.asarray(f), np.asarray(mom))
        for _ in range(sub):
            mujoco.mj_step(m, d)
            phys.append(d.qpos.reshape(M, 7)[:, :3].copy())
    return ticks, np.array(phys), bounds, sub


def brute_force_min(positions):
    """(M, M) min over the first axis of pairwise centre distances, inf on the diagonal."""
    d = np.linalg.norm(positions[:, :, None, :] - positions[:, None, :, :], axis=-1).min(0)
    np.fill_diagonal(d, np.inf)
    return d


def test_matches_c_engine_and_pairwise_minimum(sim):
    """Vehicles 0 and 1 cross (closest 0.160 m at physics rate, 0.161 m at tick rate),
    vehicle 2 climbs; 1 s = 8 periods."""
    model, state = sim
    goal = np.array([[0.0, 3.0, 1.6], [0.3, -0.5, 1.0], [0.0, 4.0, 4.0]])
    plans = min_jerk(START, goal, peak_speed=3.0)
    n = 8
    state, recs = run_periods(model, state, plans, n)
    ticks, phys, bounds, sub = c_reference(plans, n)
    # record samples = the C state at the start of every tick
    qp_c = np.array([t[0] for t in ticks]).reshape(len(ticks), 3, 7)
    qv_c = np.array([t[1] for t in ticks]).reshape(len(ticks), 3, 6)
    qa_c = np.array([t[2] for t in ticks]).reshape(len(ticks), 3, 6)
    pos, vel, acc = (concat(recs, f) for f in ("pos", "vel", "acc"))
    assert pos.shape[1] == len(ticks) == bounds[-1]
    err = max(np.abs(pos - qp_c[:, :, :3].transpose(1, 0, 2)).max(),
              np.abs(vel - qv_c[:, :, :3].transpose(1, 0, 2)).max())
    assert err < 1e-6, err                          # measured: 1.1e-15
    assert np.abs(acc - qa_c[:, :, :3].transpose(1, 0, 2)).max() < 1e-6
    vs = fleet.vehicle_states(model, state)
    assert np.abs(np.asarray(vs.position) - phys[-1]).max() < 1e-6
    # the pairwise minimum over every physics state of each period
    for p, r in enumerate(recs):
        seg = phys[bounds[p] * sub: bounds[p + 1] * sub + 1]
        np.testing.assert_allclose(r.min_dist, brute_force_min(seg), rtol=0, atol=1e-9)
    overall = np.min([r.min_dist for r in recs], axis=0)
    assert overall[0, 1] < 0.5                       # they did come close
    # physics rate matters: the tick-rate samples miss the true minimum
    assert brute_force_min(pos.transpose(1, 0, 2))[0, 1] > overall[0, 1]


def test_world_contacts_match_c_engine(sim):
    """The per-period minimum signed distance of every vehicle to every obstacle and face
    (and its time) is the brute-force minimum over the C engine's physics states; the
    metrics count robot 0 in the sphere and robot 1 on the floor, nothing for robot 2."""
    from types import SimpleNamespace

    from jaxplan.metrics.report import SIM_WORLD_KEYS, sim_metrics, sim_world_report

    model, state = sim
    plans = min_jerk(START, WORLD_GOAL)
    n = 16                                            # 2 s; the plans last 1.1-1.9 s
    state, recs = run_periods(model, state, plans, n)
    _, phys, bounds, sub = c_reference(plans, n)
    rows = static_rows(WORLD)
    # every physics state against the world at its time (the cylinder moves)
    t_phys = np.arange(phys.shape[0]) / HZ_P
    sd = np.stack([signed_distance(rows.kind, c, rows.half, rows.radius, x)
                   for c, x in zip(world_centres(t_phys), phys, strict=True)])  # (P+1, M, R)
    for p, r in enumerate(recs):
        a, b = bounds[p] * sub, bounds[p + 1] * sub + 1
        np.testing.assert_allclose(r.static_dist, sd[a:b].min(0), rtol=0, atol=1e-9)
        np.testing.assert_allclose(r.static_t, (a + sd[a:b].argmin(0)) / HZ_P, atol=1e-12)
    radius = np.array([get_vehicle(v).radius for v in NAMES])
    rep = sim_world_report(WORLD, np.stack([r.static_dist for r in recs]),
                           np.stack([r.static_t for r in recs]), radius)
    clear = sd.min(0) - radius[:, None]              # (M, R): 3 obstacles, z_min, z_max
    assert rep["obstacle_collisions"] == 1 and rep["workspace_violations"] == 1, rep
    assert rep["worst_obstacle"]["robot"] == 0 and rep["worst_obstacle"]["obstacle"] == 0
    assert rep["worst_workspace"]["robot"] == 1 and rep["worst_workspace"]["face"] == "z_min"
    assert rep["min_obstacle_clearance_m"] == pytest.approx(clear[:, :3].min(), abs=1e-9)
    assert rep["min_workspace_clearance_m"] == pytest.approx(clear[:, 3:].min(), abs=1e-9)
    t_floor = rep["worst_workspace"]["t"]
    assert 1.0 < t_floor < 2.0                       # low when the descent ends
    assert np.all(clear[2] > 0.5)                    # robot 2 stays clear of everything
    # the walking cylinder: robot 1 is closest to it when it turns back, at t = 1 s, not
    # where it stood at t = 0 (3 m away then)
    t_cyl = np.stack([r.static_t for r in recs])[:, 1, 2]
    d_cyl = np.stack([r.static_dist for r in recs])[:, 1, 2]
    assert abs(t_cyl[np.argmin(d_cyl)] - 1.0) < 0.05, t_cyl[np.argmin(d_cyl)]
    sd_still = signed_distance(rows.kind, rows.center, rows.half, rows.radius, phys)
    assert sd[:, 1, 2].min() < sd_still[:, 1, 2].min() - 1.5
    # metrics.json's "sim" block (backend mjx) carries the same report
    period = jax.tree.map(lambda *x: np.stack(x), *recs)
    scenario = SimpleNamespace(radius=radius, v_max=np.full(3, 3.0), a_max=np.full(3, 6.0),
                               world=WORLD)
    over, _ = sim_metrics(scenario, period, n * PERIOD)
    assert {k: over["sim"][k] for k in SIM_WORLD_KEYS} == rep
    # the tracked vehicles' own peaks, each over its own limits
    sim = over["sim"]
    assert sim["tracked_peak_speed_ratio"] == sim["peak_speed_over_limit"] > 0
    assert sim["tracked_peak_acc_ratio"] == max(
        r["max_acc"] / 6.0 for r in over["per_robot"]) > 0
    # the report of an unbounded, empty world: nothing to count
    empty = sim_world_report(World.unbounded(3), np.zeros((2, 3, 0)), np.zeros((2, 3, 0)),
                             radius)
    assert empty == {"obstacle_collisions": 0, "min_obstacle_clearance_m": None,
                     "worst_obstacle": None, "workspace_violations": 0,
                     "min_workspace_clearance_m": None, "worst_workspace": None}


def mocap_body_id():
    """The cylinder's mocap body in the stepped models (the same in both layouts)."""
    m = sm.fleet_model(["firefly"], [[0.0, 0.0, 1.0]], visual=False, mocap_world=WORLD)
    assert m.nmocap == 1                                # only the moving obstacle
    return mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "obstacle2_body")


def check_mocap(model, state, dt_p=1.0 / HZ_P):
    """The mocap body holds the cylinder where it is at the state's time, and MuJoCo's
    kinematics of the last physics step placed the body where it was one step before."""
    t = float(fleet.sim_time(model, state))
    pos = np.asarray(state.data.mocap_pos).reshape(-1, 3)   # (M or 1, 3): one body
    np.testing.assert_allclose(pos, np.broadcast_to(cylinder_at(t), pos.shape), rtol=0,
                               atol=1e-9)
    if t > 0:
        xpos = np.asarray(state.data.xpos)[..., mocap_body_id(), :].reshape(-1, 3)
        np.testing.assert_allclose(xpos, np.broadcast_to(cylinder_at(t - dt_p), xpos.shape),
                                   rtol=0, atol=1e-9)


def test_moving_obstacle_is_a_mocap_body_at_its_motion(sim):
    """At the start and after every period of a 2.13 s flight (through the path's three
    knots, and at rest after them), the simulated cylinder is where its motion puts it."""
    model, state = sim
    assert model.mocap_rows == (2,)
    check_mocap(model, state)
    plans = min_jerk(START, WORLD_GOAL)
    for _ in range(17):
        state, _ = fleet.simulate_period(model, state, plans, fleet.sim_time(model, state),
                                         PERIOD)
        check_mocap(model, state)
    assert float(fleet.sim_time(model, state)) == pytest.approx(2.128)  # 532 ticks
    # a static world: no mocap bodies, nothing set
    still, st = fleet.init_sim(NAMES, START, world=World.default(3))
    assert still.mocap_rows == () and st.data.mocap_pos.shape[-2] == 0


# ----------------------------------------------------------------------------- bad plans


def test_nan_plan_never_reaches_controller(sim):
    model, state = sim
    goal = START + np.array([[2.0, 0.0, 0.0], [2.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    good = min_jerk(START, goal)
    bad_coeffs = good.coeffs.at[1, 0, 2, 3].set(jnp.nan)   # vehicle 1: NaN in z
    bad = good._replace(coeffs=bad_coeffs)
    # two good periods, then 1.5 s with vehicle 1's plan NaN and vehicle 2's plan time NaN
    state, recs = run_periods(model, state, good, 2)
    held = recs[-1].ref_pos[1, recs[-1].valid][-1]           # vehicle 1's last good reference
    t_nan = lambda st: jnp.asarray([fleet.sim_time(model, st), fleet.sim_time(model, st), jnp.nan])
    state, recs2 = run_periods(model, state, bad, 12, t_offset=t_nan)
    n_ticks = sum(int(r.valid.sum()) for r in recs2)
    bad_ref = sum(r.bad_reference for r in recs2)
    assert bad_ref.tolist() == [0, n_ticks, n_ticks]
    for r in recs2:
        assert np.all(np.isfinite(r.ref_pos)) and np.all(np.isfinite(r.pos))
        assert not r.nonfinite.any()
        held_k = np.broadcast_to(held, (r.valid.sum(), 3))
        np.testing.assert_array_equal(r.ref_pos[1][r.valid], held_k)
    for leaf in jax.tree.leaves(state):
        assert np.all(np.isfinite(np.asarray(leaf)))
    p, v, _ = (np.asarray(x) for x in fleet.measured_state(model, state))
    # vehicle 1 brakes (it was accelerating at 2.9 m/s^2) and turns back to the hold point
    dist = np.linalg.norm(concat(recs2, "pos")[1] - held, axis=-1)
    speed = np.linalg.norm(concat(recs2, "vel")[1], axis=-1)
    assert dist.max() < 0.5 and dist[-1] < 0.5 * dist.max()   # measured: 0.31 m, then 0.04 m
    assert speed[-1] < 0.5 * speed.max()                       # measured: 0.78 m/s, then 0.16
    assert np.linalg.norm(p[0] - START[0]) > 0.3              # vehicle 0 kept flying its plan


# ----------------------------------------------------------------------------- batching, layout


LAYOUT_GOAL = START + np.array([[1.0, 0.5, 0.2], [-1.0, 0.0, 0.5], [0.5, -1.0, -0.3]])


def test_worlds_vmap(sim):
    """A world axis (vmap) gives the same result as separate calls."""
    model, state0 = sim
    goal = LAYOUT_GOAL
    plans = min_jerk(START, goal)
    shift = np.array([0.0, 0.0, 0.5])
    starts = jnp.asarray(np.stack([START, START + shift]))
    plans_w = jax.tree.map(lambda *x: jnp.stack(x), plans, min_jerk(START + shift, goal + shift))
    states = jax.vmap(lambda p: fleet.initial_state(model, p))(starts)
    step_w = jax.jit(jax.vmap(lambda s, p: fleet.simulate_period(model, s, p, 0.0, PERIOD)))
    st_w, rec_w = step_w(states, plans_w)
    st_1, rec_1 = fleet.simulate_period(model, state0, plans, 0.0, PERIOD)
    np.testing.assert_allclose(rec_w.pos[0], rec_1.pos, atol=1e-12)
    np.testing.assert_allclose(rec_w.pos[1], np.asarray(rec_1.pos) + shift, atol=1e-9)
    np.testing.assert_allclose(rec_w.min_dist[0], rec_1.min_dist, atol=1e-12)


@pytest.mark.slow   # one more compilation (~20 s on the 2-core CPU)
def test_fleet_layout_matches_vmap_layout(sim):
    """The "fleet" layout (one MJX model holding all bodies) flies exactly like the
    default "vmap" layout (one small model per vehicle)."""
    model, state0 = sim
    plans = min_jerk(START, LAYOUT_GOAL)
    st_1, rec_1 = fleet.simulate_period(model, state0, plans, 0.0, PERIOD)
    model_f, state_f = fleet.init_sim(NAMES, START, layout="fleet", world=WORLD)
    st_f, rec_f = fleet.simulate_period(model_f, state_f, plans, 0.0, PERIOD)
    for f in ("pos", "vel", "acc", "track_err", "min_dist", "static_dist", "static_t"):
        np.testing.assert_allclose(getattr(rec_f, f), getattr(rec_1, f), atol=1e-12, err_msg=f)
    check_mocap(model_f, st_f)                       # the moving cylinder, one model
    np.testing.assert_allclose(fleet.measured_state(model_f, st_f)[0],
                               fleet.measured_state(model, st_1)[0], atol=1e-12)


@pytest.mark.slow
def test_motor_lag_hover_and_tracking():
    """With the RotorS motor lag (12.5-25 ms) the fleet still hovers and tracks."""
    model, state = fleet.init_sim(NAMES, START, motor_lag=True)
    goal = START + np.array([[3.0, 0.0, 0.0], [0.0, 0.0, 3.0], [0.0, -3.0, 0.0]])
    state, recs = run_periods(model, state, min_jerk(START, goal), 28)
    err = concat(recs, "track_err")
    assert np.sqrt((err**2).mean()) < 0.05 and err.max() < 0.15, err.max(axis=1)


def test_init_errors():
    with pytest.raises(ValueError, match="unknown vehicle"):
        fleet.init_sim(["blimp"], [[0, 0, 1]])
    with pytest.raises(ValueError, match="whole number"):
        fleet.init_sim(["firefly"], [[0, 0, 1]], physics_hz=500, control_hz=300)
    with pytest.raises(ValueError, match=">= 100"):
        fleet.init_sim(["firefly"], [[0, 0, 1]], physics_hz=500, control_hz=50)
    with pytest.raises(ValueError, match="layout"):
        fleet.init_sim(["firefly"], [[0, 0, 1]], layout="big")
    with pytest.raises(ValueError, match="start_positions"):
        fleet.init_sim(["firefly", "neo11"], [[0, 0, 1]])


# ----------------------------------------------------------------------------- kept periods


def test_a_kept_mjx_period_is_keyed_on_the_fleet():
    """experiment._sim_key: the same vehicles and rates give the same key wherever the
    fleet starts (the starts are in the state, not in the program); another vehicle,
    order or rate gives another."""
    from jaxplan.experiment import _sim_key

    key = lambda names, start=START, **kw: _sim_key(fleet.init_sim(names, start, **kw)[0])
    base = key(NAMES)
    assert key(NAMES, START + 1.0) == base
    assert key(NAMES[::-1]) != base
    assert key(["hummingbird", "firefly", "firefly"]) != base
    assert key(NAMES, physics_hz=1000.0) != base


@pytest.mark.slow  # an MJX closed loop of its own (~1 min on the 2-core CPU)
def test_a_second_mjx_run_in_a_process_reuses_the_compiled_period():
    """Two runs of one config in one process: the second compiles nothing and gives the
    same records to the bit; a new weight reuses the period too (a traced value) and
    changes the flight."""
    import tomllib

    from jaxplan.config import parse_config
    from jaxplan.experiment import run
    from tests.conftest import TINY_TOML

    text = TINY_TOML.replace("duration_s = 12.0", 'duration_s = 2.0\nbackend = "mjx"')
    cfg = parse_config(tomllib.loads(text), source="tiny_mjx.toml")
    first, again = run(cfg), run(cfg)
    assert again.compile_s == 0.0 < first.compile_s
    for a, b in zip(jax.tree.leaves(first.arrays), jax.tree.leaves(again.arrays), strict=True):
        np.testing.assert_array_equal(a, b)
    heavier = text.replace("seed = 0", "seed = 0\n[planner]\nq_obs = 500.0")
    heavier = parse_config(tomllib.loads(heavier), source="tiny_mjx.toml")
    other = run(heavier)
    assert other.compile_s == 0.0
    assert any(not np.array_equal(a, b) for a, b in
               zip(jax.tree.leaves(first.arrays), jax.tree.leaves(other.arrays), strict=True))
