"""A run's inputs from its config (the config adapter): the static structures
(:class:`jaxplan.rollout.RolloutStructure`, with the planner's and the NLP's), the traced
fleet parameters (:class:`jaxplan.planner.FleetParams`) and the task (the scenario's
arrays, its faults, its guide field: :class:`jaxplan.rollout.Task`).

What ``jaxplan run`` (:mod:`jaxplan.experiment`), a sweep's batches and the benchmarks
build before the first replan.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan import solve
from jaxplan.config import Config, build_scenario
from jaxplan.faults import FaultParams, no_faults
from jaxplan.nlp import Limits, NLPStructure, Weights
from jaxplan.planner import FleetParams, GuideField, PlannerStructure
from jaxplan.planner.guide import guide_enabled, guide_field
from jaxplan.planner.stall import (
    announces_plan_ends,
    mutual_hold,
    mutual_window,
    resolution_enabled,
    sidestep_wait,
    stall_window,
)
from jaxplan.planner.stall import default_params as deadlock_params
from jaxplan.rollout import OwnPath, RolloutStructure, Task
from jaxplan.scenarios import Scenario
from jaxplan.trajectory import Trajectory
from jaxplan.world import ALL_KINDS, PLANE, World, fleet_box, row_kinds, rows_as_jax, static_rows

# lower bound on every plan's horizon: two replan periods, so that a plan ends after the
# next replan.  A shorter one is flown to its end within the period, braking far beyond
# a_max, and the replans that start from that acceleration can fling the robot away
# (docs/SOLVER.md, "Why the planner's safeguards are there")
T_MIN_PERIODS = 2.0
ACCEPT_VIOLATION = 1e-3  # m^2: largest collision-constraint violation accepted at max-iters


def structures(config: Config, *, only_needed: bool = True,
               n_static: int | None = None,
               static_kinds: tuple[int, ...] | None = None) -> RolloutStructure:
    """Static structures of a config (shapes other than M, N, W).

    only_needed: leave out the coast constraints when no robot of the config's own
    scenario ever has a free end (they would be inactive rows, which cost time).  A sweep,
    whose grid may hold other scenarios, passes False.  n_static: the world's static rows
    (obstacles and workspace faces); default: those of the config's own world (a sweep
    passes the most of its grid); each NLP holds ``max_static_rows`` of them
    (PlannerStructure.static_slots).
    static_kinds: the kinds of static rows the NLP's derivatives form
    (NLPStructure.static_kinds); default: the config's own world's, with PLANE (its
    workspace faces and the padding rows); a sweep, whose grid may hold other worlds,
    passes jaxplan.world.ALL_KINDS.
    """
    pc = config.planner
    sc = build_scenario(config)
    free = ~(np.asarray(sc.rest) | np.asarray(sc.has_goal_velocity))
    coast = pc.coast_samples if (np.any(free) or not only_needed) else 0
    world = planner_world(config, sc)
    R = static_rows(world).mask.shape[0] if n_static is None else n_static
    # a world of at most max_static_rows rows: no selection (the same program as 0)
    planner = PlannerStructure(max_neighbors=pc.max_neighbors, solver_pool=pc.solver_pool,
                               max_static_rows=pc.max_static_rows
                               if pc.max_static_rows < R else 0,
                               prediction=pc.prediction)
    nlp = NLPStructure(
        n_dim=sc.start.shape[1], degree=pc.degree, segments=pc.segments,
        collision=pc.collision, n_collision_samples=pc.n_samples,
        n_coast_samples=coast, n_static=planner.static_slots(R),
        # the kinds matter only to static rows: without, the default (one program)
        static_kinds=ALL_KINDS if planner.static_slots(R) == 0 else
        world_kinds(world) if static_kinds is None else tuple(static_kinds),
        hard_limits=pc.limits == "hard",
    )
    steps = max(1, math.ceil(config.sim.duration_s * pc.replan_hz - 1e-9))
    fc = config.faults
    return RolloutStructure(planner=dataclasses.replace(planner, nlp=nlp),
                            steps=steps, faults=fc.enabled,
                            latency_periods=round(fc.latency_s * pc.replan_hz) if fc.enabled
                            else 0)


def planner_world(config: Config, scenario: Scenario) -> World:
    """The world the planner's NLPs keep to (their static rows): the scenario's, with
    ``[planner] region = "fleet"`` its workspace intersected with the fleet's region, the
    box spanned by every robot's start and waypoints grown by ``region_margin_m`` on every
    side (:func:`jaxplan.world.fleet_box`, what escape_m measures against
    with its own margin).  The faces hold the robot's body, so its centre stays its
    radius inside them.  The metrics and the simulation keep the scenario's world."""
    pc = config.planner
    if pc.region == "workspace":
        return scenario.world
    lo, hi = fleet_box(scenario.start, scenario.waypoints, pc.region_margin_m)
    return scenario.world.within(lo, hi)


def planner_rows(config: Config, scenario: Scenario) -> int:
    """The static rows of the planner's world (:func:`planner_world`): its obstacles and
    finite faces."""
    return static_rows(planner_world(config, scenario)).mask.shape[0]


def world_kinds(world: World) -> tuple[int, ...]:
    """The kinds of static rows an NLP in ``world`` holds (NLPStructure.static_kinds):
    its obstacles' and PLANE (its workspace faces, and the padding rows)."""
    return row_kinds(np.append(static_rows(world).kind, PLANE))


def fleet_params(config: Config, scenario: Scenario, weights: Weights | None = None,
                 n_static: int | None = None, knots: int | None = None) -> FleetParams:
    """Traced fleet parameters from a config and its scenario (the world's static rows
    padded to ``n_static``, default exactly its own; their motion to ``knots`` knots,
    default the world's own, none in a static world: :func:`jaxplan.world.static_rows`)."""
    pc = config.planner
    w = weights or Weights(*(jnp.asarray(float(x)) for x in
                             (pc.q_dynm, pc.q_obs, pc.q_lim, pc.k_t, pc.k_p)))
    lim = Limits(jnp.asarray(scenario.v_max), jnp.asarray(scenario.a_max),
                 jnp.asarray(scenario.j_max))
    M = scenario.start.shape[0]
    window = stall_window(pc.stall_window_s, scenario.dim)
    # on the device as strongly typed arrays, as every other leaf: a Python scalar leaf
    # is copied to the device at every call of a compiled step (docs/SOLVER.md)
    settings = jax.device_put(solve.as_strong_dtypes(solve.SolverSettings(
        max_iters=pc.max_iters, tol_feasibility=pc.tol, tol_complementarity=pc.tol)))
    return FleetParams(
        weights=w, limits=lim, radius=jnp.asarray(scenario.radius) + pc.safety_margin_m,
        robot_mask=jnp.ones((M,), bool), dt=jnp.asarray(1.0 / pc.replan_hz),
        t_min=jnp.asarray(T_MIN_PERIODS / pc.replan_hz),
        prediction_weight=jnp.asarray(pc.k_t / pc.q_dynm),
        accept_violation=jnp.asarray(ACCEPT_VIOLATION), settings=settings,
        static=_static(planner_world(config, scenario), n_static, knots),
        deadlock=deadlock_params(
            enabled=resolution_enabled(pc.deadlock, scenario.dim), window=window,
            progress=pc.stall_progress_m, near=pc.stall_near_m, hold=pc.sidestep_hold_s,
            step=pc.sidestep_step_m, angle_deg=pc.sidestep_angle_deg,
            wait=sidestep_wait(pc.deadlock, scenario.dim, pc.sidestep_wait_3d_s),
            announce=announces_plan_ends(pc.deadlock, scenario.dim),
            mutual=pc.sidestep_mutual_at_once,
            window_mutual=mutual_window(pc.deadlock, scenario.dim, window,
                                        pc.stall_window_mutual_s),
            hold_mutual=mutual_hold(pc.deadlock, scenario.dim, pc.sidestep_hold_s,
                                    pc.sidestep_hold_mutual_s)),
        keep_right=jnp.asarray(pc.keep_right_m) if pc.keep_right_m > 0 else None,
    )


def _static(world: World, n_static: int | None, knots: int | None = None):
    rows = static_rows(world, n_static, knots)
    if rows.mask.shape[0] == 0:
        return None
    return rows_as_jax(rows)


def task_of(config: Config, scenario: Scenario, own: bool | None = None) -> Task:
    """Traced task arrays of a scenario.  ``own``: carry the non-cooperative robots'
    paths (:class:`jaxplan.rollout.OwnPath`); default: where the scenario has such a
    robot (a sweep whose grid has one passes True for every run: one task tree)."""
    full = scenario.rest | scenario.has_goal_velocity
    gv = np.where(scenario.has_goal_velocity[..., None], scenario.goal_velocity, 0.0)
    return Task(
        start=jnp.asarray(scenario.start), waypoints=jnp.asarray(scenario.waypoints),
        rest=jnp.asarray(full), auto=jnp.asarray(scenario.auto & ~full),
        goal_velocity=jnp.asarray(gv),
        goal_tolerance=jnp.asarray(config.sim.goal_tolerance_m),
        speed_tolerance=jnp.asarray(config.sim.goal_speed_tolerance_mps),
        faults=fault_params(config, scenario.start.shape[0]),
        guide=_guide(config, scenario),
        own=own_path(config, scenario)
        if (not np.all(scenario.cooperative) if own is None else own) else None,
    )


# min-jerk rest-to-rest leg x(s) = a + (b - a) (10 s^3 - 15 s^4 + 6 s^5), s = t / T: its
# peaks of |x'|, |x''|, |x'''| are these times |b - a| / T, / T^2, / T^3
_LEG_POLY = np.array([0.0, 0.0, 0.0, 10.0, -15.0, 6.0])
_LEG_PEAKS = (1.875, 10.0 / math.sqrt(3.0), 60.0)
_LEG_SLACK = 1.0 + 1e-9  # the duration a hair longer: the peaks a hair below the limits


def leg_duration(distance: float, v_max: float, a_max: float, j_max: float) -> float:
    """s: the shortest min-jerk rest-to-rest leg over ``distance`` m within the limits."""
    if distance <= 0.0:
        return 0.0
    cv, ca, cj = _LEG_PEAKS
    return _LEG_SLACK * max(cv * distance / v_max, math.sqrt(ca * distance / a_max),
                            (cj * distance / j_max) ** (1.0 / 3.0))


def own_legs(scenario: Scenario, i: int, dt: float, segments: int, degree: int):
    """Robot i's own path (the module docstring of :mod:`jaxplan.rollout`): from its start
    through its waypoints, min-jerk rest-to-rest straight legs each as short as its
    limits allow (:func:`leg_duration`), each started at the first multiple of ``dt`` at
    or after the previous one ended.  Returns (start (W,) s, coeffs (W, S, N, D+1) in each
    segment's normalized time, duration (W,) s, end (W, N) m)."""
    if degree < 5:
        raise ValueError(f"a non-cooperative robot flies min-jerk legs of degree 5; [planner] "
                         f"degree is {degree}")
    P = np.polynomial.Polynomial
    pts = np.concatenate([scenario.start[i][None], scenario.waypoints[i]])
    W, N = scenario.num_waypoints, scenario.dim
    start, dur = np.zeros(W), np.zeros(W)
    coeffs = np.zeros((W, segments, N, degree + 1))
    t = 0.0
    for k in range(W):
        a, b = pts[k], pts[k + 1]
        T = leg_duration(float(np.linalg.norm(b - a)), float(scenario.v_max[i]),
                         float(scenario.a_max[i]), float(scenario.j_max[i]))
        start[k], dur[k] = t, T
        for s in range(segments):
            # the leg on [s / S, (s + 1) / S] of its normalized time, in the segment's own
            c = P(_LEG_POLY)(P([s / segments, 1.0 / segments])).coef if T > 0 else [0.0]
            c = np.pad(np.asarray(c, float), (0, 6 - len(c)))
            coeffs[k, s, :, :6] = (b - a)[:, None] * c[None, :]
            coeffs[k, s, :, 0] += a
        # (a leg that ends within 1e-6 periods after a replan, its slack, ends at it)
        t = math.ceil((t + T) / dt - 1e-6) * dt
    return start, coeffs, dur, pts[1:]


def own_path(config: Config, scenario: Scenario) -> OwnPath:
    """The traced :class:`jaxplan.rollout.OwnPath` of a scenario (the cooperative robots'
    entries are computed too, and unused: mask False)."""
    pc = config.planner
    dt = 1.0 / pc.replan_hz
    M, W = scenario.num_robots, scenario.num_waypoints
    parts = [own_legs(scenario, i, dt, pc.segments, pc.degree) for i in range(M)]
    start, coeffs, dur, end = (np.array([p[k] for p in parts]) for k in range(4))
    legs = Trajectory.from_normalized(jnp.asarray(coeffs), jnp.asarray(dur))
    return OwnPath(mask=jnp.asarray(~np.asarray(scenario.cooperative)),
                   start=jnp.asarray(start.reshape(M, W)), legs=legs, goal=jnp.asarray(end))


def _guide(config: Config, scenario: Scenario):
    """The scenario's guide field (jaxplan.planner.guide) where [planner] guide turns it
    on, or None."""
    if not guide_enabled(config.planner.guide, scenario.world):
        return None
    g = guide_field(scenario.world, scenario.waypoints,
                    np.asarray(scenario.radius) + config.planner.safety_margin_m,
                    scenario.start)
    return GuideField(*(jnp.asarray(a) for a in g))


def fault_params(config: Config, M: int) -> FaultParams:
    """Traced fault settings of a config (all zero when [faults] is off)."""
    fc = config.faults
    if not fc.enabled:
        return no_faults(M)._replace(seed=jnp.asarray(config.seed % 2**32, jnp.uint32))
    frozen = np.zeros(M, bool)
    if fc.frozen_robot >= 0:
        frozen[fc.frozen_robot] = True
    return FaultParams(jnp.asarray(fc.message_loss), jnp.asarray(fc.noise_sigma_m),
                       jnp.asarray(frozen), jnp.asarray(fc.frozen_at_s),
                       jnp.asarray(fc.frozen_mode == "stale"),
                       jnp.asarray(config.seed % 2**32, jnp.uint32))
