"""The planner's data: its static structure, its traced parameters, what a replan takes
in and gives out, and the memory it carries from one replan to the next.

Every type here is a pytree (a NamedTuple) but :class:`PlannerStructure`, a hashable
frozen dataclass whose change recompiles.  Arrays carry the fleet axis M first (padded
robots included, masked by ``FleetParams.robot_mask``); views add the sender axis,
(M, M, ...) indexed [observer, sender].
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import NamedTuple

import jax

from jaxplan import solve
from jaxplan.nlp import Limits, Multipliers, NLPStructure, Weights
from jaxplan.trajectory import Trajectory
from jaxplan.world import StaticRows


class Fallback(enum.IntEnum):
    """What a robot flies after a replan (``ReplanInfo.fallback``, an int32 array of
    these values): its solve, ACCEPTED; or, where the solve was not accepted, the least
    violating of its previous plan shifted to now (KEPT_PREVIOUS), a braking plan to rest
    (BRAKING) and its finite best-effort solve (BEST_EFFORT) (:mod:`.choice`)."""

    ACCEPTED = 0
    KEPT_PREVIOUS = 1
    BRAKING = 2
    BEST_EFFORT = 3


@dataclass(frozen=True)
class PlannerStructure:
    """Static planner settings (hashable; a change recompiles).

    nlp: the NLP's static structure.  (The solver's iteration cap and tolerances are
    traced: FleetParams.settings.)
    max_neighbors: 0 (every other robot is in each robot's NLP) or K >= 1: each robot's
    NLP holds only the K others that come nearest to its own closed-form prediction
    (:func:`jaxplan.planner.nlps.nearest_neighbors`); the NLP's cost then grows with K,
    not with the fleet.
    solver_pool: robots' NLPs stepped at once (:func:`jaxplan.solve.solve_lanes`);
    0 = :func:`jaxplan.solve.default_pool` of the fleet size and of the others per NLP.
    max_static_rows: 0 (every static row, obstacle or workspace face, is in each
    robot's NLP) or K >= 1: each robot's NLP holds only the K rows nearest to where it
    is (:func:`jaxplan.planner.nlps.nearest_static_rows`); ``nlp.n_static`` is then
    :meth:`static_slots` of the world's rows, and ``FleetParams.static`` holds them all.
    prediction: what each robot predicts the others will do
    (:data:`jaxplan.planner.views.PREDICTIONS`): "min_time_jerk", the paper's closed form
    (the default); "constant_velocity" or "static", ablations of it
    (:func:`jaxplan.planner.views.predict_views`).
    """

    nlp: NLPStructure = field(default_factory=NLPStructure)
    max_neighbors: int = 0
    solver_pool: int = 0
    max_static_rows: int = 0
    prediction: str = "min_time_jerk"

    def others(self, M: int) -> int:
        """Other-robot slots in each NLP of an M-robot fleet (M: the fleet, padded): K
        (``max_neighbors``) when that is fewer than the M - 1 others, else M - 1: every
        other robot, the robot itself left out (at least one slot, masked, for M = 1)."""
        K = self.max_neighbors
        return K if 0 < K < M - 1 else max(M - 1, 1)

    def static_slots(self, R: int) -> int:
        """Static-row slots in each NLP of a world of R rows (padding included): K
        (``max_static_rows``) when that is fewer than R, else R (every row)."""
        K = self.max_static_rows
        return K if 0 < K < R else R


class DeadlockParams(NamedTuple):
    """Traced stall detection and sidestep settings (scalars, or batched for sweeps;
    :mod:`jaxplan.planner.stall`).

    enabled: () bool, sidestep when stalled.  window: () s.  progress: () m.  near: () m
    of clearance.  hold: () s of sidestep.  step: () m to the sub-goal.  angle: () rad
    to the right of the goal direction.  wait: () s a robot stays stalled before it
    sidesteps.  announce: () bool, broadcast the end of the plan flown
    (:func:`jaxplan.planner.stall.broadcast`).  mutual: () bool, no wait in a mutual
    stall (:func:`jaxplan.planner.stall.observe`).  window_mutual: () s without progress
    before a robot in a mutual stall is stalled.  hold_mutual: () s of a sidestep that
    starts in such a stall (after ``window_mutual``).
    """

    enabled: jax.Array
    window: jax.Array
    progress: jax.Array
    near: jax.Array
    hold: jax.Array
    step: jax.Array
    angle: jax.Array
    wait: jax.Array
    announce: jax.Array
    mutual: jax.Array
    window_mutual: jax.Array
    hold_mutual: jax.Array


class DeadlockState(NamedTuple):
    """Each robot's stall memory, (M, ...) (:mod:`jaxplan.planner.stall`).

    goal: (M, N) the goal the clock refers to.  best: (M,) m, closest distance to it
    since the clock restarted.  since: (M,) s since ``best`` last fell by ``progress``.
    left: (M,) s of sidestep left (> 0: sidestepping).  sub: (M, N) the sub-goal of the
    last replan.  occupied: (M,) bool, the last replan planned beside an occupied goal.
    pub_p, pub_v: (M, N), pub_rest: (M,) bool: what the robot broadcasts as its goal at
    the next replan (:func:`jaxplan.planner.stall.broadcast`) where pub_ok (M,) bool.
    arrived: (M,) bool, it has been within ``progress`` of its goal since that goal was
    set (``best`` then follows it away from the goal).  settled: (M,) s since its goal
    was set or its last sidestep ended (a mutual stall is one after ``window_mutual``
    only once this is ``window``: a robot starting from rest, or turning back to its
    goal after a sidestep, makes little progress for a while).
    """

    goal: jax.Array
    best: jax.Array
    since: jax.Array
    left: jax.Array
    sub: jax.Array
    occupied: jax.Array
    pub_p: jax.Array
    pub_v: jax.Array
    pub_rest: jax.Array
    pub_ok: jax.Array
    arrived: jax.Array
    settled: jax.Array


class GuideField(NamedTuple):
    """The way round the static world (:mod:`jaxplan.planner.guide`).  value: (W, M,
    *GUIDE_CELLS[N]) m, grid path length to robot m's goal of waypoint w from each node
    (in a replan's :class:`Goals`: (M, *G), the current waypoint's).  origin, spacing:
    (N,) m, node (i, j, k) at origin + spacing * (i, j, k)."""

    value: object
    origin: object
    spacing: object


class FleetParams(NamedTuple):
    """Traced fleet parameters (a pytree; changing values never recompiles).

    weights: Weights (scalars, or batched for sweeps).  limits: Limits with (M,) arrays.
    radius: (M,) m.  robot_mask: (M,) bool, False for padding robots (never planned,
    invisible to others).  dt: () replan period, s.  t_min: () s, lower bound on T.
    prediction_weight: () time weight w of the closed-form predictions.
    accept_violation: () largest inequality violation (m^2) accepted from a solve that
    hit its iteration cap.  settings: solve.SolverSettings.  static: the world's
    obstacles and workspace faces (:class:`jaxplan.world.StaticRows`, all R rows; None
    when R = 0), the same for every robot: each robot's NLP holds
    ``structure.nlp.n_static`` = ``structure.static_slots(R)`` of them (the nearest:
    :func:`jaxplan.planner.nlps.select_static`), the checks
    (:func:`jaxplan.planner.choice.plan_violation`,
    :func:`jaxplan.planner.goals.clear_of_static`) use every row.
    keep_right: () m, or None (off): each robot predicts every other shifted this far to
    that other's right of its way to its goal, with its radius grown as much
    (:func:`jaxplan.planner.views.view_predictions`), so that two robots meeting head on
    each plan to pass on their own right.
    deadlock: stall detection and sidestep settings (:class:`DeadlockParams`); None:
    neither.
    """

    weights: Weights
    limits: Limits
    radius: jax.Array
    robot_mask: jax.Array
    dt: jax.Array
    t_min: jax.Array
    prediction_weight: jax.Array
    accept_violation: jax.Array
    settings: solve.SolverSettings
    static: StaticRows | None = None
    deadlock: DeadlockParams | None = None
    keep_right: jax.Array | None = None


class Views(NamedTuple):
    """What each observer last received from each sender, arrays indexed [i, j].

    p, v, a: (M, M, N) state; goal_p, goal_v: (M, M, N); rest: (M, M) bool;
    age: (M, M) seconds since the message was sent; valid: (M, M) bool (False: nothing
    received, the sender is ignored).
    """

    p: jax.Array
    v: jax.Array
    a: jax.Array
    goal_p: jax.Array
    goal_v: jax.Array
    rest: jax.Array
    age: jax.Array
    valid: jax.Array


class FleetState(NamedTuple):
    """What the fleet knows at a replan: each robot's own state now, p, v, a (M, N)
    (measured, or its reference), and its views of the others (:class:`Views`)."""

    p: jax.Array
    v: jax.Array
    a: jax.Array
    views: Views


class Goals(NamedTuple):
    """Where each robot plans to: goal_p, goal_v (M, N) its end position and velocity;
    rest: (M,) bool, a fully defined end state (velocity goal_v, acceleration 0) rather
    than a free end (position only).  guide: the way round the static world to these
    goals (:class:`GuideField` with value (M, *G)), or None: no guide."""

    goal_p: jax.Array
    goal_v: jax.Array
    rest: jax.Array
    guide: GuideField | None = None


class PlanState(NamedTuple):
    """Per-robot planner memory carried between replans.

    plan: Trajectory (M,), each starting at the time of the last replan.  has_plan: (M,).
    multipliers, penalty: augmented-Lagrangian warm start.  neighbors: (M, Mo) int32, the
    robot in each other-robot slot of the NLPs (with ``max_neighbors``; -1: none), so
    that multipliers follow their robot when the selection changes.  static_ids: (M, Ks)
    int32, the static row (index into ``FleetParams.static``) in each static-row slot of
    the NLPs (-1: none yet), so that the static rows' multipliers follow their row when
    the selection (``max_static_rows``) changes.  retry: (M,) bool, the robot's last solve
    was not accepted, or it is idle (:func:`jaxplan.planner.stall.idle`): its next solve
    starts from the cold guesses (:func:`jaxplan.planner.fleet_solve.solve_fleet`).
    deadlock: each robot's stall memory (:class:`DeadlockState`).
    """

    plan: Trajectory
    has_plan: jax.Array
    multipliers: Multipliers
    penalty: jax.Array
    neighbors: jax.Array
    static_ids: jax.Array
    retry: jax.Array
    deadlock: DeadlockState | None = None


class ReplanInfo(NamedTuple):
    """Per-robot diagnostics of one replan, each (M,) (goal_point (M, N)).

    status, iterations, objective, eq_violation, ineq_violation: the solve's
    (:class:`jaxplan.solve.Solution`).  fallback: int32 :class:`Fallback` values, what
    the robot flies.  goal_moved: it planned to the nearest free point, its goal is
    occupied.  stalled: the robot is stalled (:mod:`jaxplan.planner.stall`; False
    without ``FleetParams.deadlock``).  sidestep: it plans to a sidestep sub-goal.
    goal_point: the end point it planned to (its goal, a sub-goal, a guide point, or the
    free point beside an occupied goal).
    """

    status: jax.Array
    iterations: jax.Array
    objective: jax.Array
    eq_violation: jax.Array
    ineq_violation: jax.Array
    fallback: jax.Array
    goal_moved: jax.Array
    stalled: jax.Array
    sidestep: jax.Array
    goal_point: jax.Array
