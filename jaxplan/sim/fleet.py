"""MJX lockstep closed loop: a fleet tracking its plans under the SE(3) controller.

The receding-horizon loop calls :func:`simulate_period` once per replan period::

    sim, state = init_sim(names, start_positions)            # once per run
    p, v, a = measured_state(sim, state)                       # what the planner sees
    plans = ...                                                # Trajectory, batch (M,)
    state, rec = simulate_period(sim, state, plans, t_plan0, period_s)

Everything is a pure function of pytrees: jit-able (``simulate_period`` is jitted with
``period_s`` static) and vmap-able over a leading world axis of ``state``, ``plans``
and ``t_plan0`` (``sim`` is shared by the worlds; see :func:`initial_state` for a
batch of starts).

Inside one period (a ``lax.scan`` over control ticks at ``control_hz``):

1. every vehicle's plan is sampled at the tick's plan-local time (position, velocity,
   acceleration, and jerk as a feed-forward when ``jerk_feedforward``); all samples of
   the period are evaluated at once before the scan;
2. a sample with any non-finite number is never given to the controller: that
   vehicle's reference becomes "hold": the last good reference position with zero
   velocity, acceleration and jerk (counted in ``PeriodRecord.bad_reference``);
3. :func:`jaxplan.sim.se3.se3_control` (vmapped) computes rotor speeds, clamped to
   ``[0, w_max]`` (ticks with a clamped rotor are counted in ``saturated``);
4. ``physics_hz / control_hz`` MJX physics steps (a ``lax.scan`` of ``mjx.step``) run
   with the wrench of the clamped rotor speeds held, or, with ``motor_lag``, with the
   RotorS first-order motor lag integrated exactly at each physics step toward the
   commanded speeds (the wrench of step k uses the rotor speeds at its start);
5. after every physics step the pairwise centre distances update a running minimum,
   so collisions are counted on the simulated states at physics rate; so do the
   signed distances from every vehicle's centre to every obstacle and workspace face
   of the world (:func:`jaxplan.world.signed_distance`, exact for spheres, boxes,
   cylinders and planes to 1e-6 m; the vehicle's body is the sphere of its collision
   radius, subtracted by the caller), with the time of each minimum; a moving obstacle
   counts where its motion puts it at the step's time (below).

Moving obstacles are mocap bodies of the stepped models, placed from their motion at
every physics step (:mod:`jaxplan.sim.obstacles`, where the world's measures live).

The world is measured, not collided.  The stepped models carry no geoms at all; the
MJCF of :func:`jaxplan.sim.model.fleet_xml` with ``world=`` holds the floor, walls and
obstacles as non-colliding geoms for pictures and the C engine.  A contact with the
world fails the run (metrics.json), so a contact response would only change what
happens after the failure, and it is expensive in MJX (contacts and the constraint
solver, several times the step's time and compile time), where the per-step distances
cost about nothing (``jaxplan bench sim``'s ``world_cost_*``; docs/SOLVER.md,
"Measurements behind the code").

Period grid.  Time is kept as an integer count of control ticks (``SimState.tick``).
A period ends at the first control tick at or after the next multiple of ``period_s``
on the absolute simulation clock.  When ``period_s * control_hz`` is an integer (e.g.
8 Hz replanning with ``control_hz`` = 200 or 400) every period is exactly
``period_s`` long.  Otherwise (8 Hz with 250 or 500 Hz: 31.25 or 62.5 ticks) the scan
has ``ceil(period_s * control_hz)`` ticks, the last one is masked out when not needed
(``PeriodRecord.valid``), and the periods alternate in length so that the clock never
drifts from the replan grid by more than one control tick; read the true time of the
new state from :func:`sim_time`.

Layouts (``init_sim(layout=...)``):

* ``"vmap"``: one single-body MJX model, vmapped over the vehicles, with the fields
  that differ between vehicle kinds (mass, inertia and MuJoCo's constants derived from
  them) batched.  ``mjx.Data`` leaves have a leading (M,) axis.  A vehicle whose state
  became non-finite cannot touch the others.
* ``"fleet"``: one MJX model holding all M bodies; ``mjx.Data`` is the model's.
  MJX factors the whole (6M x 6M) mass matrix, so a non-finite vehicle poisons all.
* ``"auto"``: ``"vmap"``: one world costs about the same in both layouts, many worlds
  less as a vmap (jaxplan/benchmarks/sim.py; docs/SOLVER.md, "Measurements behind the
  code"); vmap also isolates vehicles, and one MJX model holding many drones slows
  down faster than their number.

Both layouts build their MuJoCo models with :func:`jaxplan.sim.model.fleet_model`
(``visual=False``: bodies without geoms, exact RotorS inertias) and step with the
model's integrator (semi-implicit Euler by default, which MJX and the C engine agree
on to rounding).

Measured acceleration (:func:`measured_state`): the free joint's ``qacc`` of the last
physics step, i.e. the world-frame linear acceleration that moved the velocity in that
step (thrust along the body axis at the start of the step, over mass, minus gravity).
It lags the velocity and position by one physics step (2 ms at 500 Hz).  Before the
first step it is 0 (the fleet starts in hover equilibrium).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.pytree import traced
from jaxplan.sim import import_mjx, se3
from jaxplan.sim import model as sim_model_lib
from jaxplan.sim.obstacles import obstacle_centres, set_mocap, sim_world, static_dists, static_min
from jaxplan.trajectory import Trajectory
from jaxplan.vehicles import get_vehicle
from jaxplan.world import StaticRows, World

mjx = import_mjx()

LAYOUTS = ("vmap", "fleet")
DEFAULT_LAYOUT = "vmap"
_EPS_TICKS = 1e-9  # tolerance when converting seconds to control ticks

Array = jax.Array


# ----------------------------------------------------------------------------- types


@partial(jax.tree_util.register_dataclass,
         data_fields=["mjx_model", "params", "world"],
         meta_fields=["names", "layout", "physics_hz", "control_hz", "motor_lag",
                      "jerk_feedforward", "batched_leaves", "mocap_rows"])
@dataclass(frozen=True)
class SimModel:
    """Static description of the simulated fleet (a pytree; share it between worlds).

    Attributes:
        mjx_model: mjx.Model.  ``"fleet"``: the whole fleet.  ``"vmap"``: one body,
            with the leaves listed in ``batched_leaves`` stacked along a leading (M,) axis.
        params: se3.SE3Params with a leading (M,) axis.
        world: :class:`jaxplan.world.StaticRows` (R rows: the obstacles, then the finite
            workspace faces; jnp arrays) whose distances are measured every physics
            step; R = 0 without a world; its ``motion`` (None if static) moves them.
        names: (M,) vehicle names (static).
        layout: "vmap" | "fleet" (static).
        physics_hz, control_hz: rates, Hz (static); physics_hz / control_hz is an integer.
        motor_lag: bool (static): first-order rotor-speed lag on.
        jerk_feedforward: bool (static): the plan's jerk feeds the controller's desired
            body rates (False gives RotorS's law exactly).
        batched_leaves: indices of ``mjx_model``'s flattened leaves that carry the
            vehicle axis ("vmap"; empty for "fleet").
        mocap_rows: the rows of ``world`` that are mocap bodies (the moving obstacles;
            mocap index j is row mocap_rows[j]; static).
    """

    mjx_model: object
    params: se3.SE3Params
    world: StaticRows
    names: tuple
    layout: str
    physics_hz: float
    control_hz: float
    motor_lag: bool
    jerk_feedforward: bool
    batched_leaves: tuple
    mocap_rows: tuple = ()

    @property
    def num_vehicles(self) -> int:
        return len(self.names)

    @property
    def substeps(self) -> int:
        """Physics steps per control tick."""
        return int(round(self.physics_hz / self.control_hz))


class SimState(NamedTuple):
    """Dynamic state of one world (vmap adds a leading world axis to every leaf).

    Attributes:
        data: mjx.Data.  ``"fleet"``: qpos (7 M,), qvel (6 M,), ...; ``"vmap"``: every
            leaf with a leading (M,) axis, qpos (M, 7), qvel (M, 6).  mocap_pos (J, 3)
            ("vmap": (M, J, 3)): the moving obstacles at the state's time.
        rotor_speed: (M, MAX_ROTORS) rotor speeds, rad/s (evolves only with motor_lag;
            otherwise the last commanded, clamped speeds).
        hold_position: (M, 3) m: the last finite reference position (used, with zero
            derivatives, whenever a plan sample is non-finite).
        yaw: (M,) rad: the yaw reference (the start yaw; the planner plans no yaw).
        tick: () int64: control ticks since the start; time = tick / control_hz.
    """

    data: object
    rotor_speed: Array
    hold_position: Array
    yaw: Array
    tick: Array


class PeriodRecord(NamedTuple):
    """What one :func:`simulate_period` call records (world axis first under vmap).

    K = ceil(period_s * control_hz) samples, one at the START of each control tick
    (the state the controller saw): concatenating the records of consecutive periods
    (keeping the ``valid`` samples) gives a uniform grid at control_hz (>= 100 Hz).

    Attributes:
        t: (K,) simulation time of each sample, s.
        valid: (K,) bool: the tick ran (False only for the masked last tick of a
            period that is not a whole number of ticks; those entries repeat the state).
        pos, vel: (M, K, 3) position m, velocity m/s (world).
        acc: (M, K, 3) measured acceleration m/s^2 (qacc of the previous physics step).
        ref_pos: (M, K, 3) reference position the controller used, m.
        track_err: (M, K) |pos - ref_pos|, m (0 where not valid).
        min_dist: (M, M) minimum centre distance of each pair over every physics state
            of the period (the start state and the state after every physics step), m;
            +inf on the diagonal.
        static_dist: (M, R) minimum over the same states of the signed distance from
            each vehicle's centre to each row of ``SimModel.world`` (a moving obstacle
            where it is at that state's time), m (negative: the centre is inside;
            subtract the collision radius for the clearance).
        static_t: (M, R) simulation time of that minimum, s (the first, on ties).
        saturated: (M,) int32: ticks in which some rotor speed was clamped.
        bad_reference: (M,) int32: ticks whose plan sample was non-finite (held instead).
        nonfinite: (M,) bool: the vehicle's simulated state was non-finite at some tick
            or at the end (its motors were then switched off by the controller).
    """

    t: Array
    valid: Array
    pos: Array
    vel: Array
    acc: Array
    ref_pos: Array
    track_err: Array
    min_dist: Array
    static_dist: Array
    static_t: Array
    saturated: Array
    bad_reference: Array
    nonfinite: Array


# ----------------------------------------------------------------------------- build


def _batched_model(names: Sequence[str], physics_hz: float, integrator: str,
                   mocap_world: World | None):
    """One-body MJX model (and the moving obstacles' mocap bodies of ``mocap_world``)
    with the leaves that differ between ``names`` stacked (M,)."""
    kinds = sorted(set(names))
    one = {n: sim_model_lib.to_mjx(sim_model_lib.fleet_model(
        [n], [[0.0, 0.0, 0.0]], timestep=1.0 / physics_hz, integrator=integrator,
        visual=False, mocap_world=mocap_world))[0] for n in kinds}
    leaves = {n: jax.tree.leaves(m) for n, m in one.items()}
    treedef = jax.tree.structure(one[kinds[0]])
    ref = leaves[kinds[0]]
    batched = tuple(
        i for i in range(len(ref))
        if not all(np.array_equal(np.asarray(leaves[n][i]), np.asarray(ref[i])) for n in kinds))
    stacked = [jnp.stack([leaves[n][i] for n in names]) if i in batched else ref[i]
               for i in range(len(ref))]
    return jax.tree.unflatten(treedef, stacked), batched


def _model_axes(sim: SimModel):
    """in_axes tree of ``sim.mjx_model`` for the vmap layout."""
    treedef = jax.tree.structure(sim.mjx_model)
    n = treedef.num_leaves
    return jax.tree.unflatten(treedef, [0 if i in sim.batched_leaves else None for i in range(n)])


def _single_model(sim: SimModel):
    """The vmap layout's model for vehicle 0 (unbatched), e.g. for mjx.make_data."""
    leaves, treedef = jax.tree.flatten(sim.mjx_model)
    return jax.tree.unflatten(
        treedef, [x[0] if i in sim.batched_leaves else x for i, x in enumerate(leaves)])


def init_sim(names: Sequence[str], start_positions, *, physics_hz: float = 500.0,
             control_hz: float = 250.0, motor_lag: bool = False, layout: str = "auto",
             yaws=None, jerk_feedforward: bool = True, integrator: str = "Euler",
             world: World | None = None):
    """Build the simulated fleet and its initial state (hovering at the starts).

    Args:
        names: M vehicle names ("hummingbird" | "firefly" | "neo11"), any mix.
        start_positions: (M, 3) m.
        physics_hz: MJX physics rate, Hz.
        control_hz: controller rate, Hz; physics_hz / control_hz must be an integer and
            control_hz >= 100 (records are sampled at control ticks).
        motor_lag: simulate the RotorS first-order motor lag.
        layout: "auto" | "vmap" | "fleet" (module docstring).
        yaws: (M,) start yaw = yaw reference, rad (default 0).
        jerk_feedforward: feed the plan's jerk to the controller (see se3).
        integrator: "Euler" (default) or "RK4" (MuJoCo's).
        world: a 3-D :class:`jaxplan.world.World` whose obstacles and finite workspace
            faces are measured every physics step (``PeriodRecord.static_dist``; a
            moving obstacle where it is then, and a mocap body of the model: module
            docstring), or None (nothing measured: R = 0).  A world with the same rows,
            moving obstacles and knot count can replace it later
            (``dataclasses.replace(sim, world=sim_world(w))``) without a recompilation.
    Returns:
        (SimModel, SimState) for one world.
    Raises:
        ValueError on unknown names/layout, bad rates or shapes, non-finite positions.
    """
    names = tuple(str(n) for n in names)
    for n in names:
        get_vehicle(n)  # raises on unknown names
    if len(names) == 0:
        raise ValueError("init_sim: no vehicles")
    if layout == "auto":
        layout = DEFAULT_LAYOUT
    if layout not in LAYOUTS:
        raise ValueError(f"layout must be 'auto' or one of {LAYOUTS}, got {layout!r}")
    physics_hz, control_hz = float(physics_hz), float(control_hz)
    if not (physics_hz > 0 and control_hz > 0 and math.isfinite(physics_hz)
            and math.isfinite(control_hz)):
        raise ValueError(f"rates must be positive, got physics_hz={physics_hz}, "
                         f"control_hz={control_hz}")
    ratio = physics_hz / control_hz
    if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
        raise ValueError(f"physics_hz / control_hz must be a whole number >= 1, got "
                         f"{physics_hz} / {control_hz}")
    if control_hz < 100.0:
        raise ValueError(f"control_hz must be >= 100 Hz (records are sampled at control "
                         f"ticks), got {control_hz}")
    pos = np.asarray(start_positions, dtype=np.float64)
    if pos.shape != (len(names), 3):
        raise ValueError(f"start_positions must be ({len(names)}, 3), got {pos.shape}")
    if not np.all(np.isfinite(pos)):
        raise ValueError("start_positions must be finite")
    world = world if world is not None else World.unbounded(3)
    mocap_world = world if world.has_motion else None  # its moving obstacles: mocap bodies
    if layout == "fleet":
        mx, _ = sim_model_lib.to_mjx(sim_model_lib.fleet_model(
            names, pos, timestep=1.0 / physics_hz, integrator=integrator, visual=False,
            mocap_world=mocap_world))
        batched = ()
    else:
        mx, batched = _batched_model(names, physics_hz, integrator, mocap_world)
    sim = SimModel(mjx_model=mx, params=se3.controller_params(names), world=sim_world(world),
                   names=names,
                   layout=layout,
                   physics_hz=physics_hz, control_hz=control_hz, motor_lag=bool(motor_lag),
                   jerk_feedforward=bool(jerk_feedforward), batched_leaves=batched,
                   mocap_rows=sim_model_lib.mocap_rows(world))
    yaw = np.zeros(len(names)) if yaws is None else np.asarray(yaws, np.float64)
    if yaw.shape != (len(names),) or not np.all(np.isfinite(yaw)):
        raise ValueError(f"yaws must be {len(names)} finite angles, got {yaws!r}")
    return sim, initial_state(sim, jnp.asarray(pos), jnp.asarray(yaw))


@jax.jit
def initial_state(sim: SimModel, positions, yaws=None) -> SimState:
    """State of one world hovering at rest at ``positions`` (pure; vmap for worlds).

    Jitted so that every leaf is a committed device array, like the leaves
    :func:`simulate_period` returns: jit keys its cache on committed-ness, and a state
    with uncommitted leaves (e.g. built with ``jnp.asarray`` outside jit) costs the
    caller's jitted loop one extra compilation when the returned state comes back.

    Args:
        sim: SimModel.
        positions: (M, 3) m.  yaws: (M,) rad or None (0).
    Returns:
        SimState at tick 0: zero velocity and acceleration, rotor speeds at hover, the
        moving obstacles' mocap bodies where they are at t = 0.
    """
    M = sim.num_vehicles
    p = jnp.asarray(positions, jnp.float64).reshape(M, 3)
    yaw = jnp.zeros(M) if yaws is None else jnp.asarray(yaws, jnp.float64).reshape(M)
    q = se3.yaw_to_quat(yaw)
    qpos = jnp.concatenate([p, q], axis=-1)  # (M, 7)
    if sim.layout == "fleet":
        data = mjx.make_data(sim.mjx_model)
        data = data.replace(qpos=qpos.reshape(-1))
    else:
        d1 = mjx.make_data(_single_model(sim))
        data = jax.tree.map(lambda x: jnp.broadcast_to(x, (M,) + x.shape), d1)
        data = data.replace(qpos=qpos)
    data = set_mocap(sim, data, obstacle_centres(sim.world, 0.0))
    hover = jax.vmap(lambda prm: se3.allocate(prm, prm.mass * prm.gravity, jnp.zeros(3))[0])(
        sim.params)
    return SimState(data=data, rotor_speed=jnp.sqrt(hover), hold_position=p, yaw=yaw,
                    tick=jnp.zeros((), jnp.int64))


# ----------------------------------------------------------------------------- views


def _per_vehicle(sim: SimModel, x: Array, width: int) -> Array:
    """(..., M, width) view of a qpos/qvel-like leaf of ``SimState.data``."""
    if sim.layout == "fleet":
        return x.reshape(x.shape[:-1] + (sim.num_vehicles, width))
    return x


def _vehicle_state(sim: SimModel, data) -> se3.VehicleState:
    qp = _per_vehicle(sim, data.qpos, 7)
    qv = _per_vehicle(sim, data.qvel, 6)
    return se3.VehicleState(qp[..., 0:3], qv[..., 0:3], qp[..., 3:7], qv[..., 3:6])


def vehicle_states(sim: SimModel, state: SimState) -> se3.VehicleState:
    """Rigid-body states (..., M, ...) of the fleet: position m, velocity m/s (world),
    quat (w, x, y, z), angular velocity rad/s (body)."""
    return _vehicle_state(sim, state.data)


def measured_state(sim: SimModel, state: SimState):
    """The state the planner sees.

    Args:
        sim: SimModel.  state: SimState (leading world axes allowed).
    Returns:
        (p, v, a) each (..., M, 3): position m, velocity m/s (world frame), and
        acceleration m/s^2 = the linear ``qacc`` of the last physics step (module
        docstring; 0 before the first step).
    """
    qp = _per_vehicle(sim, state.data.qpos, 7)
    qv = _per_vehicle(sim, state.data.qvel, 6)
    qa = _per_vehicle(sim, state.data.qacc, 6)
    return qp[..., 0:3], qv[..., 0:3], qa[..., 0:3]


def sim_time(sim: SimModel, state: SimState) -> Array:
    """Simulation time of ``state``, s: (...,) = tick / control_hz."""
    return state.tick.astype(jnp.float64) / sim.control_hz


# ----------------------------------------------------------------------------- stepping


def _physics_step(sim: SimModel, data, thrust: Array, moments: Array):
    """One mjx.step with per-vehicle thrust (M,) N and body moments (M, 3) N m."""
    if sim.layout == "fleet":
        return mjx.step(sim.mjx_model, data.replace(ctrl=sim_model_lib.fleet_ctrl(thrust, moments)))
    ctrl = jnp.concatenate([thrust[:, None], moments], axis=-1)
    return jax.vmap(mjx.step, in_axes=(_model_axes(sim), 0))(sim.mjx_model, data.replace(ctrl=ctrl))


def _positions(sim: SimModel, data) -> Array:
    return _per_vehicle(sim, data.qpos, 7)[..., 0:3]


def _sq_dists(p: Array) -> Array:
    """(M, M) squared centre distances, +inf on the diagonal."""
    d = p[:, None, :] - p[None, :, :]
    d2 = jnp.sum(d * d, axis=-1)
    return jnp.where(jnp.eye(p.shape[0], dtype=bool), jnp.inf, d2)


def _ticks_in_period(period_s: float, control_hz: float) -> int:
    n = period_s * control_hz
    return max(1, int(math.ceil(n - _EPS_TICKS * max(1.0, n))))


def _active_ticks(k0, period_s: float, hz: float, K: int):
    """Ticks of the period starting at tick k0 (1..K): the absolute period grid ends at
    the first tick at or after the next multiple of period_s."""
    ticks_per_period = period_s * hz
    j = jnp.floor(k0.astype(jnp.float64) / ticks_per_period + _EPS_TICKS)
    k1 = jnp.ceil((j + 1.0) * ticks_per_period - _EPS_TICKS * max(1.0, ticks_per_period))
    return jnp.clip(k1.astype(jnp.int64) - k0, 1, K)


def _plan_samples(sim: SimModel, plans: Trajectory, t_plan0, K: int):
    """The scan inputs of a period: (tick index (K,), reference position, velocity,
    acceleration, jerk (K, M, 3) each; jerk zero without the feed-forward)."""
    t_plan0 = jnp.broadcast_to(jnp.asarray(t_plan0, jnp.float64), (sim.num_vehicles,))
    tk = t_plan0[:, None] + (1.0 / sim.control_hz) * jnp.arange(K, dtype=jnp.float64)[None, :]
    ref_p, ref_v, ref_a = (plans.sample(tk, d) for d in range(3))
    ref_j = plans.sample(tk, 3) if sim.jerk_feedforward else jnp.zeros_like(ref_p)
    return (jnp.arange(K), *(jnp.swapaxes(r, 0, 1) for r in (ref_p, ref_v, ref_a, ref_j)))


def _simulate_period(sim: SimModel, state: SimState, plans: Trajectory, t_plan0, period_s: float):
    M = sim.num_vehicles
    hz = sim.control_hz
    dt_c = 1.0 / hz
    dt_p = 1.0 / sim.physics_hz
    K = _ticks_in_period(period_s, hz)
    k0 = state.tick
    n_active = _active_ticks(k0, period_s, hz, K)
    xs = _plan_samples(sim, plans, t_plan0, K)
    params = sim.params

    def physics(carry, t_step):
        data, w, w_sq_cmd, thrust, moments, dmin2, smin = carry
        if sim.motor_lag:
            thrust, moments = jax.vmap(se3.wrench_from_rotor_speeds)(params, w)
            w = jax.vmap(lambda prm, w1, c1: se3.motor_lag(prm, w1, c1, dt_p))(params, w, w_sq_cmd)
        data = _physics_step(sim, data, thrust, moments)
        c = obstacle_centres(sim.world, t_step)  # at the new state's time
        data = set_mocap(sim, data, c)
        p = _positions(sim, data)
        dmin2 = jnp.fmin(dmin2, _sq_dists(p))
        smin = static_min(smin, sim.world, p, c, t_step)
        return (data, w, w_sq_cmd, thrust, moments, dmin2, smin), None

    def tick(carry, x):
        data, w, hold, dmin2, smin, sat, bad, nonfin = carry
        k, rp, rv, ra, rj = x
        active = k < n_active
        ok = (jnp.all(jnp.isfinite(rp), -1) & jnp.all(jnp.isfinite(rv), -1)
              & jnp.all(jnp.isfinite(ra), -1) & jnp.all(jnp.isfinite(rj), -1))
        okc = ok[:, None]
        zero = jnp.zeros_like(rp)
        ref = se3.Reference(jnp.where(okc, rp, hold), jnp.where(okc, rv, zero),
                            jnp.where(okc, ra, zero), jnp.where(okc, rj, zero),
                            state.yaw, jnp.zeros(M))
        vs = _vehicle_state(sim, data)
        out = se3.fleet_control(params, vs, ref)
        finite_state = out.status != se3.STATUS_BAD_STATE
        w_cmd = jnp.sqrt(out.rotor_speeds_sq)
        carry_p = (data, w if sim.motor_lag else w_cmd, out.rotor_speeds_sq, out.thrust,
                   out.moments, dmin2, smin)
        t_steps = (k0 + k).astype(jnp.float64) * dt_c + dt_p * jnp.arange(
            1, sim.substeps + 1, dtype=jnp.float64)
        (data2, w2, _, _, _, dmin2_2, smin2), _ = jax.lax.scan(physics, carry_p, t_steps)
        acc = _per_vehicle(sim, data.qacc, 6)[:, 0:3]
        err = jnp.linalg.norm(vs.position - ref.position, axis=-1)
        rec = (vs.position, vs.velocity, acc, ref.position, jnp.where(active, err, 0.0))
        sel = lambda new, old: jax.tree.map(lambda a, b: jnp.where(active, a, b), new, old)
        new_carry = (
            sel(data2, data), sel(w2, w), sel(ref.position, hold), sel(dmin2_2, dmin2),
            sel(smin2, smin),
            sat + (active & out.saturated).astype(jnp.int32),
            bad + (active & ~ok).astype(jnp.int32),
            nonfin | (active & ~finite_state),
        )
        return new_carry, rec

    t0 = k0.astype(jnp.float64) * dt_c
    c0 = obstacle_centres(sim.world, t0)
    data0 = set_mocap(sim, state.data, c0)  # where they are now, whatever the state held
    p0 = _positions(sim, data0)
    dmin2_0 = _sq_dists(p0)
    sd0 = static_dists(sim.world, p0, c0)
    smin0 = (sd0, jnp.full(sd0.shape, t0))
    zeros_i = jnp.zeros(M, jnp.int32)
    carry0 = (data0, state.rotor_speed, state.hold_position, dmin2_0, smin0, zeros_i,
              zeros_i, jnp.zeros(M, bool))
    (data, w, hold, dmin2, smin, sat, bad, nonfin), recs = jax.lax.scan(tick, carry0, xs)
    pos, vel, acc, rpos, err = recs
    qp = _per_vehicle(sim, data.qpos, 7)
    qv = _per_vehicle(sim, data.qvel, 6)
    nonfin = nonfin | ~(jnp.all(jnp.isfinite(qp), -1) & jnp.all(jnp.isfinite(qv), -1))
    ks = jnp.arange(K)
    new_state = SimState(data=data, rotor_speed=w, hold_position=hold, yaw=state.yaw,
                         tick=k0 + n_active)
    record = PeriodRecord(
        t=(k0 + ks).astype(jnp.float64) * dt_c,
        valid=ks < n_active,
        pos=jnp.swapaxes(pos, 0, 1), vel=jnp.swapaxes(vel, 0, 1), acc=jnp.swapaxes(acc, 0, 1),
        ref_pos=jnp.swapaxes(rpos, 0, 1), track_err=jnp.swapaxes(err, 0, 1),
        min_dist=jnp.sqrt(dmin2), static_dist=smin[0], static_t=smin[1], saturated=sat,
        bad_reference=bad, nonfinite=nonfin)
    return new_state, record


def simulate_period(sim: SimModel, state: SimState, plans: Trajectory, t_plan0,
                    period_s: float):
    """Fly one replan period: the controller tracks ``plans`` under MJX physics.

    Args:
        sim: SimModel (from :func:`init_sim`).
        state: SimState of one world (vmap this function for a world axis).
        plans: Trajectory with batch shape (M,) (vehicle i follows plans[i]).
        t_plan0: () or (M,) s: each plan's local time at the start of the period.
        period_s: static float, s: the replan period (module docstring: period grid).
    Returns:
        (new_state, PeriodRecord).  One jitted call (jitted inside; call it from your
        own jit or vmap freely); the controller never sees NaN.
    """
    if not period_s > 0:
        raise ValueError(f"period_s must be > 0, got {period_s}")
    t_plan0 = jnp.broadcast_to(jnp.asarray(t_plan0, jnp.float64), (sim.num_vehicles,))
    if not traced(plans, t_plan0):
        # Commit host-side inputs to the device: jit keys its cache on committed-ness, so
        # a loop mixing NumPy / Python inputs with jit outputs would otherwise compile twice.
        plans, t_plan0 = jax.device_put((plans, t_plan0), jax.devices()[0])
    return _simulate_period_jit(sim, state, plans, t_plan0, float(period_s))


_simulate_period_jit = jax.jit(_simulate_period, static_argnames=("period_s",))
