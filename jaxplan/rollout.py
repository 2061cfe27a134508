"""Receding horizon under ideal tracking: the paper's whole algorithm, end to end.

Every ``1 / replan_hz`` seconds the fleet replans (:func:`jaxplan.planner.replan`) and
each robot executes the first period of its plan exactly ("ideal" backend: the robot's
next state is its plan's state).  The executed pieces are recorded as polynomial
segments, so that separations can be checked exactly in continuous time.  The whole run
is one jitted ``lax.scan``; a batch of scenarios (seeds, weights) is one vmapped run.

Goals and "reached" (the definition used everywhere)
----------------------------------------------------
* Goals are waypoint sequences, synchronized across the fleet: every robot flies to its
  waypoint w; when ALL robots have reached waypoint w, waypoint w + 1 is published
  (the paper's multi-transition protocol).
* A robot has **reached** waypoint w at the first instant at which its executed
  trajectory is within ``goal_tolerance_m`` of the waypoint and, for a rest waypoint,
  its speed is at most ``goal_speed_tolerance_mps``.  Executed pieces are checked at
  ``checks_per_period`` evenly spaced instants per replan period (16 by default: 7.8 ms
  apart at 8 Hz, 1.6 cm of travel at 2 m/s), so a fly-through is not missed.
* A robot that has reached its current waypoint settles there: it replans to the same
  point with a rest end state until the next waypoint is published (after its last
  waypoint: until the end of the run).
* A goal velocity (a non-rest end state with a given velocity) is planned as a fully
  defined end state (v = goal velocity, a = 0).
* An "auto" waypoint is planned with a free end while the robot is farther from it
  than :func:`auto_rest_distance` and with a rest end within it, so that the robot
  arrives slowing down and stops there instead of flying through; it is reached as a
  free end is (within ``goal_tolerance_m``; it is slow by then).

Non-cooperative robots
----------------------
A robot with ``Scenario.cooperative`` False runs no planner: at every replan its plan
is replaced by its own path (:class:`OwnPath`, :func:`own_plans`), rest-to-rest straight
legs through its waypoints, each started at the first replan at or after the previous
one ended; it publishes the end of its current leg as its goal.  The others see its
state as they see any robot's and predict it as any robot.  It counts as having reached
every fleet waypoint (it does not hold the fleet's waypoints back); the metrics leave it
out of success and the makespan, and count its collisions.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxplan.faults import CommState, FaultParams, communicate, initial_comm
from jaxplan.planner import (
    FleetParams,
    FleetState,
    Goals,
    GuideField,
    PlannerStructure,
    PlanState,
    ReplanInfo,
    braking_plan,
    fresh_views,
    initial_plan_state,
    limited_braking_plan,
    replan,
)
from jaxplan.planner.stall import published_goals
from jaxplan.pytree import tree_where
from jaxplan.trajectory import Trajectory


@dataclass(frozen=True)
class RolloutStructure:
    """Static rollout settings (hashable)."""

    planner: PlannerStructure = field(default_factory=PlannerStructure)
    steps: int = 240
    checks_per_period: int = 16
    faults: bool = False  # inject faults (jaxplan.faults); off: every view is fresh
    latency_periods: int = 0  # message delay in replan periods (with faults)


class Task(NamedTuple):
    """One scenario as traced arrays (add a leading axis for a batch).

    start: (M, N).  waypoints: (M, W, N).  rest: (M, W) bool (fully defined end state).
    auto: (M, W) bool, an "auto" end (a rest end near the waypoint, a free end far from
    it; never where ``rest``).  goal_velocity: (M, W, N) (used where ``rest``).
    goal_tolerance: () m.  speed_tolerance: () m/s.  guide: the way round the static world
    to each goal (:class:`jaxplan.planner.GuideField`, value (W, M, *G)), or None: no
    guide.
    """

    start: jax.Array
    waypoints: jax.Array
    rest: jax.Array
    auto: jax.Array
    goal_velocity: jax.Array
    goal_tolerance: jax.Array
    speed_tolerance: jax.Array
    faults: FaultParams
    guide: GuideField | None = None
    own: OwnPath | None = None


class OwnPath(NamedTuple):
    """The non-cooperative robots' own paths (module docstring), traced.

    mask: (M,) bool, True = the robot flies its own path.  start: (M, L) s, when each leg
    starts (multiples of the replan period; leg 0 at 0).  legs: Trajectory with batch
    (M, L), each leg in the plans' structure (S segments, degree D), from rest to rest.
    goal: (M, L, N) m, each leg's end.
    """

    mask: jax.Array
    start: jax.Array
    legs: Trajectory
    goal: jax.Array


class RolloutState(NamedTuple):
    """The scan carry."""

    t: jax.Array  # () s
    p: jax.Array  # (M, N)
    v: jax.Array
    a: jax.Array
    plans: PlanState
    wp: jax.Array  # () int32, the published waypoint
    reached: jax.Array  # (M, W) bool
    reach_time: jax.Array  # (M, W) s, inf until reached
    comm: CommState  # messages and views (used with faults)


class StepRecord(NamedTuple):
    """What one replan period leaves behind (stacked over steps by the scan).

    t: () start of the period.  p, v, a: (M, N) measured state at the replan.
    piece_t0, piece_t1: (M, S+1) absolute times of the executed pieces (t1 <= t0: none).
    piece_coeffs: (M, S+1, N, D+1) monomials in (t - piece_t0) seconds.
    wp: () published waypoint.  info: ReplanInfo.
    """

    t: jax.Array
    p: jax.Array
    v: jax.Array
    a: jax.Array
    piece_t0: jax.Array
    piece_t1: jax.Array
    piece_coeffs: jax.Array
    wp: jax.Array
    info: ReplanInfo
    comm: jax.Array  # (3,) messages delivered, messages lost, oldest view age (s)


def guide_now(task: Task, wp) -> GuideField | None:
    """The guide to the published waypoint wp (value (M, *G)), or None without a guide."""
    g = task.guide
    return None if g is None else g._replace(value=g.value[wp])


def auto_rest_distance(limits):
    """(M,) m: how near its "auto" waypoint a robot plans a rest end there.

    Twice the distance in which a robot at v_max stops within a_max and j_max (v^2 /
    (2 a) braking, and v a / (2 j) more while the deceleration ramps up): room for the
    replan period it flies before it sees the switch, and for a plan that brakes below
    a_max."""
    v, a, j = limits.v_max, limits.a_max, limits.j_max
    return v * v / a + v * a / j


def current_goals(task: Task, wp, reached, p, limits) -> Goals:
    """The goals each robot plans to now, from where it is, p (M, N): position, velocity
    and end kind, (M, N), (M, N), (M,), and the guide to them (:func:`guide_now`).
    An "auto" waypoint is a rest end within :func:`auto_rest_distance` of p (limits:
    each robot's own), a free end beyond."""
    M = task.start.shape[0]
    idx = jnp.arange(M)
    goal_p = task.waypoints[idx, wp]
    rest = task.rest[idx, wp]
    goal_v = jnp.where(rest[:, None], task.goal_velocity[idx, wp], 0.0)
    near = jnp.linalg.norm(p - goal_p, axis=-1) <= auto_rest_distance(limits)
    settled = reached[idx, wp]
    rest = rest | settled | (task.auto[idx, wp] & near)
    goal_v = jnp.where(settled[:, None], 0.0, goal_v)
    return Goals(goal_p, goal_v, rest, guide_now(task, wp))


def own_leg(own: OwnPath, t, dt):
    """(M,) int32: each robot's leg at time t (the last started by t; dt / 2 of slack
    for a t accumulated in floating point)."""
    started = own.start <= t + 0.5 * dt
    return jnp.maximum(jnp.sum(started, axis=1) - 1, 0).astype(jnp.int32)


def own_goals(task: Task, t, dt, goals: Goals) -> Goals:
    """``goals`` with each non-cooperative robot's replaced by its current leg's end (a
    rest end)."""
    own = task.own
    if own is None:
        return goals
    M = own.mask.shape[0]
    end = own.goal[jnp.arange(M), own_leg(own, t, dt)]
    m = own.mask
    return goals._replace(goal_p=jnp.where(m[:, None], end, goals.goal_p),
                          goal_v=jnp.where(m[:, None], 0.0, goals.goal_v),
                          rest=goals.rest | m)


def own_plans(task: Task, t, dt, plans: PlanState) -> PlanState:
    """``plans`` with each non-cooperative robot's plan replaced by its own path from
    time t on: its current leg, shifted to t (past the leg's end: holding there)."""
    own = task.own
    if own is None:
        return plans
    M = own.mask.shape[0]
    k = own_leg(own, t, dt)
    idx = jnp.arange(M)
    leg = jax.tree.map(lambda x: x[idx, k], own.legs)
    path = leg.shift(t - own.start[idx, k])
    plan = tree_where(own.mask, path, plans.plan)
    return plans._replace(plan=plan, has_plan=plans.has_plan | own.mask)


def executed_pieces(plan: Trajectory, t0, dt):
    """The first ``dt`` seconds of each plan as polynomial pieces.

    Returns (piece_t0, piece_t1) (M, S+1) absolute times and coefficients
    (M, S+1, N, D+1) in (t - piece_t0) seconds: the S plan segments clipped to [0, dt]
    and a tail piece for the hold / coast part after the plan's end.
    """
    cm, b = plan.to_monomials()  # (M, S, N, K), (M, S+1)
    M, S, N, K = cm.shape
    T = b[:, -1]
    s0 = b[:, :-1]
    s1 = jnp.minimum(b[:, 1:], dt)
    # tail after T: p(T) + coast * v(T) (t - T)
    pT = plan.evaluate(T, 0)
    vT = plan.evaluate(T, 1) * plan.coast[:, None]
    tail = jnp.zeros((M, 1, N, K)).at[:, 0, :, 0].set(pT).at[:, 0, :, 1].set(vT)
    coeffs = jnp.concatenate([cm, tail], axis=1)
    pt0 = jnp.concatenate([s0, T[:, None]], axis=1)
    pt1 = jnp.concatenate([s1, jnp.full((M, 1), dt)], axis=1)
    pt1 = jnp.where(pt1 > pt0, pt1, pt0)  # empty pieces: t1 == t0
    return t0 + pt0, t0 + pt1, coeffs


def step(fp: FleetParams, task: Task, st: RolloutState, structure: RolloutStructure):
    """One replan period: plan, execute the first period exactly, check goals."""
    M = st.p.shape[0]
    dt = fp.dt
    goals = own_goals(task, st.t, dt, current_goals(task, st.wp, st.reached, st.p, fp.limits))
    # what the robots broadcast: a robot that sidesteps its sub-goal (jaxplan.planner.stall)
    pub = publish(task, st.t, dt, st.plans, goals)
    comm, views, cstats = exchange(task, st, *pub, structure)
    plans, info = replan(fp, st.plans, FleetState(st.p, st.v, st.a, views), goals,
                         structure.planner, st.t)
    plans = own_plans(task, st.t, dt, freeze(fp, task, st, plans, structure))
    plan = plans.plan
    p1, v1, a1 = plan.state_at(jnp.broadcast_to(dt, (M,)))
    pt0, pt1, pc = executed_pieces(plan, st.t, dt)
    # goal checks along the executed period
    C = structure.checks_per_period
    tau = dt * jnp.arange(1, C + 1) / C  # (C,)
    reached, reach_time, wp = goal_update(
        fp, task, st, goals.goal_p, plan.sample(tau), jnp.linalg.norm(plan.sample(tau, 1), axis=-1),
        st.t + tau, jnp.ones((C,), bool))
    rec = StepRecord(st.t, st.p, st.v, st.a, pt0, pt1, pc, st.wp, info, cstats)
    new = RolloutState(st.t + dt, p1, v1, a1, plans, wp, reached, reach_time, comm)
    return new, rec


def publish(task: Task, t, dt, ps: PlanState, goals: Goals):
    """(goal_p, goal_v, rest) each robot broadcasts: its goal, a sidestep sub-goal
    (:func:`jaxplan.planner.stall.published_goals`), a non-cooperative robot's leg end."""
    pub = published_goals(ps.deadlock, goals.goal_p, goals.goal_v, goals.rest)
    own = own_goals(task, t, dt, Goals(*pub))
    return own.goal_p, own.goal_v, own.rest


def exchange(task: Task, st: RolloutState, goal_p, goal_v, rest, structure: RolloutStructure):
    """Views for this replan: fresh (no faults) or through the faulty channel.

    Returns (CommState, Views, (3,) stats: delivered, lost, oldest age).
    """
    if not structure.faults:
        views = fresh_views(st.p, st.v, st.a, goal_p, goal_v, rest)
        return st.comm, views, jnp.zeros((3,))
    comm, views, s = communicate(st.comm, task.faults, st.t, st.p, st.v, st.a, goal_p,
                                 goal_v, rest)
    stats = jnp.stack([s["delivered"], s["lost"], jnp.max(views.age)]).astype(jnp.float64)
    return comm, views, stats


def freeze(fp: FleetParams, task: Task, st: RolloutState, plans, structure: RolloutStructure):
    """A robot that stopped responding stops planning (faults only): at its first replan
    from ``frozen_at`` on it brakes to rest within its a_max (the planner's braking plan)
    and then hovers there.  Its body obeys its limits: a robot that stopped dead in one
    step would stand farther behind the prediction its last message gave the others than
    their a_max age^2 / 2 allowance (docs/SOLVER.md, "Why the planner's safeguards are
    there")."""
    if not structure.faults:
        return plans
    frozen = task.faults.frozen & (st.t >= task.faults.frozen_at)
    first = frozen & (st.t - fp.dt < task.faults.frozen_at)
    if structure.planner.nlp.hard_limits:
        brake = limited_braking_plan(st.p, st.v, st.a, fp.limits, structure.planner)
    else:
        brake = braking_plan(st.p, st.v, st.a, fp.limits.a_max, structure.planner)
    plan = tree_where(first, brake, tree_where(frozen, st.plans.plan.shift(fp.dt), plans.plan))
    return plans._replace(plan=plan)


def goal_update(fp: FleetParams, task: Task, st: RolloutState, goal_p, pos, speed, times,
                valid):
    """Reached flags, reach times and the published waypoint after a period.

    Args: goal_p (M, N); pos (M, C, N) and speed (M, C) at C instants ``times`` (C,)
    of the period (``valid`` (C,) masks instants that did not happen).
    Returns: (reached (M, W), reach_time (M, W), wp ()).
    """
    M = st.p.shape[0]
    dist = jnp.linalg.norm(pos - goal_p[:, None, :], axis=-1)
    rest_now = task.rest[jnp.arange(M), st.wp]
    ok = (dist <= task.goal_tolerance) & (~rest_now[:, None] | (speed <= task.speed_tolerance))
    ok = ok & valid[None, :]
    hit = jnp.any(ok, axis=1)
    first = times[jnp.argmax(ok, axis=1)]
    W = task.waypoints.shape[1]
    col = jnp.arange(W)[None, :] == st.wp
    new_hit = col & hit[:, None] & ~st.reached
    reached = st.reached | new_hit
    reach_time = jnp.where(new_hit, first[:, None], st.reach_time)
    # padding robots, robots that stopped responding and non-cooperative robots count as
    # having reached everything (for publishing the next waypoint; metrics exclude them
    # from success)
    frozen = task.faults.frozen & (st.t >= task.faults.frozen_at)
    if task.own is not None:
        frozen = frozen | task.own.mask
    reached = reached | ~fp.robot_mask[:, None] | frozen[:, None]
    all_here = jnp.all(reached[:, st.wp])
    wp = jnp.where(all_here & (st.wp < W - 1), st.wp + 1, st.wp).astype(jnp.int32)
    return reached, reach_time, wp


def initial_state(task: Task, structure: RolloutStructure) -> RolloutState:
    """Everyone at rest at its start, no plans yet, waypoint 0."""
    M, W, _ = task.waypoints.shape
    z = jnp.zeros_like(task.start)
    ps = initial_plan_state(task.start, structure.planner, M)
    gv = jnp.where(task.rest[:, 0, None], task.goal_velocity[:, 0], 0.0)
    comm = initial_comm(task.start, task.waypoints[:, 0], gv, task.rest[:, 0],
                        structure.latency_periods if structure.faults else 0,
                        task.faults.seed)
    # dtypes given: a weakly typed leaf would differ from a step's output state, and a
    # jitted step would compile twice (tests/test_planner.py checks the state's types)
    f64 = jnp.float64
    return RolloutState(jnp.asarray(0.0, f64), task.start, z, z, ps, jnp.asarray(0, jnp.int32),
                        jnp.zeros((M, W), bool), jnp.full((M, W), jnp.inf, dtype=f64), comm)


def rollout(fp: FleetParams, task: Task, structure: RolloutStructure):
    """The whole run: ``structure.steps`` replans as one ``lax.scan`` (jit at the call site).

    Returns (final RolloutState, StepRecord stacked over steps).
    """
    st0 = initial_state(task, structure)

    def body(st, _):
        return step(fp, task, st, structure)

    return jax.lax.scan(body, st0, None, length=structure.steps)


def rollout_batch(fp: FleetParams, task: Task, structure: RolloutStructure,
                  fp_axis=None):
    """A batch of runs: ``task`` (and ``fp`` where ``fp_axis=0``) carry a leading axis.

    The vmap of :func:`rollout`, written as a scan of the vmapped step over a state that
    is batched from the start: vmapping the scan itself makes JAX batch its body (the
    whole step) in passes until it knows which carry leaves are batched (a leaf that
    starts unbatched, such as the clock, and comes out batched costs a pass), about half
    the batch program's tracing.  The same operations (a sweep's rows are bitwise those
    of the vmap); the records are returned batch-major, as the vmap returns them."""
    st0 = jax.vmap(lambda t: initial_state(t, structure))(task)
    vstep = jax.vmap(lambda f, t, s: step(f, t, s, structure), in_axes=(fp_axis, 0, 0))
    final, records = jax.lax.scan(lambda st, _: vstep(fp, task, st), st0, None,
                                  length=structure.steps)
    return final, jax.tree.map(lambda a: jnp.swapaxes(a, 0, 1), records)
