"""One replanning step of the whole fleet (docs/MATH.md section 3).

Each robot i has its own *view* of every other robot j: the last state and goal it
received from j (:class:`Views`, arrays (M, M, ...) indexed [observer, sender]).  By
default every view is fresh (:func:`fresh_views`); the structure also carries an age
and a validity flag so that stale or missing messages can be injected.

From its view each robot predicts the others in closed form (:mod:`jaxplan.predict`),
advanced by the age of the message it came from.  An old message costs a larger radius
(at most MAX_INFLATION): a view up to STALE_AFTER_S old is a prediction advanced from
the sent state, which can be off by what the sender's acceleration could change since,
a_max age^2 / 2; an older view is a robot holding still, which can be off by how far it
could have flown since, v_max age.  It is held at the middle of the stretch from its
last message to where that message predicted it one period later and on to where it
comes to rest braking from there (it fell silent somewhere on the way, and a robot that
stops responding brakes to rest: :func:`jaxplan.rollout.freeze`), and it is never taken to be
known better than that stretch allows: half its length plus a_max dt^2 / 8 (``floor``;
without it, a robot that froze at 1.46 m/s stood 0.195 m from its last message, and a
robot planning beside it at the planning distance collided, d / rho 0.963; without the
braking stretch, a robot beside one that braked from 1.5 m/s, random_box_20 with robot 0
frozen, seed 19: d / rho 0.80).  Each robot then builds its NLP (:mod:`jaxplan.nlp`),
with the others (or its ``max_neighbors`` nearest) and the world's static rows (or its
``max_static_rows`` nearest: :func:`nlp_static_rows`), and solves it; all robots' NLPs
are solved in one call (:mod:`jaxplan.solve`, a pool of lanes).
Warm start: the robot's previous plan shifted by the replan period; the first plan starts from
its own prediction.

Goals another robot occupies: uncertainty never keeps a robot off its own goal.  Where
robot i's goal lies inside the inflated planning distance of where j's prediction ends
(a robot parked, frozen or silent near it), the inflation of j for i shrinks so that the
goal keeps GOAL_CLEARANCE outside it; the uninflated distance (both radii, which include
the safety margin) and the floor of a held robot are never given up.  Where the goal lies
inside even that, the robot plans to the nearest point GOAL_CLEARANCE outside it
(``ReplanInfo.goal_moved``) with a rest end and waits there (with a free end it flew
through that point at speed and back, replan after replan); it takes the goal again
once it is free.  Without this, such a robot's
solves are infeasible every replan and the plans it flies wander off (measured: 14.7 m
from its goal after 28 s beside a frozen robot).

Fallbacks (counted in :class:`ReplanInfo`): a robot whose solve is not accepted flies
whichever of three plans comes least deep into the others' planning distances over the
next CHECK_HORIZON_S (:func:`plan_violation`, CHECK_SAMPLES instants, against the
predictions its NLP used), ties going in this order: the solve itself if it is finite
and meets its equalities (BEST_EFFORT: typically INFEASIBLE because it starts inside
another robot's planning radius, or another's prediction crosses its start; the solve
minimized the violation against the newest predictions), its previous plan shifted to
now while that has not run out (KEPT_PREVIOUS), a braking plan that brings it to rest
(BRAKING): so a finite best-effort solve through a robot is not flown when a fallback
violates less.  A solve is ACCEPTED when its plan is finite, its equality residual
is <= 1e-6 and its status is CONVERGED, or MAX_ITERS with every inequality
satisfied to ``accept_violation``.  No NaN leaves this step.

Everything here is pure and jit-able; shapes are fixed by (M, N, structure).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan import deadlock as dl
from jaxplan import solve
from jaxplan.guide import guide_goals
from jaxplan.nlp import Limits, Multipliers, NLPParams, NLPStructure, Weights
from jaxplan.nlp.terms import STATIC_PRIORITY
from jaxplan.predict import predict_arrays, quintic_terms
from jaxplan.pytree import tree_where
from jaxplan.trajectory import Trajectory, compose_matrix
from jaxplan.world import StaticRows, signed_distance

# m: the most a sender's radius grows for an old message.  A silent robot is taken to
# hold its last known position within this much: with 2 m a robot frozen mid-course
# walled off a 2.6 m ball and the robot whose goal lay inside it never arrived.
MAX_INFLATION = 0.5
STALE_AFTER_S = 0.5  # s: an older view is a robot holding its last known position
# m: clearance a robot keeps between its goal and the planning distance of a robot that
# occupies it (see replan: goals another robot occupies)
GOAL_CLEARANCE = 0.05
GOAL_PROJECTIONS = 4  # fixed passes of the goal projection (several occupants)
CHECK_HORIZON_S = 1.5  # s: fallback plans are compared over this long (plan_violation)
CHECK_SAMPLES = 32  # instants in (0, CHECK_HORIZON_S] (47 ms apart: 9 cm at 2 m/s)

# fallback kinds in ReplanInfo.fallback
ACCEPTED, KEPT_PREVIOUS, BRAKING, BEST_EFFORT = 0, 1, 2, 3


@dataclass(frozen=True)
class PlannerStructure:
    """Static planner settings (hashable; a change recompiles).

    nlp: the NLP's static structure.  (The solver's iteration cap and tolerances are
    traced: FleetParams.settings.)
    max_neighbors: 0 (every other robot is in each robot's NLP) or K >= 1: each robot's
    NLP holds only the K others that come nearest to its own closed-form prediction
    (:func:`nearest_neighbors`); the NLP's cost then grows with K, not with the fleet.
    solver_pool: robots' NLPs stepped at once (:func:`jaxplan.solve.solve_lanes`);
    0 = :func:`jaxplan.solve.default_pool` of the fleet size and of the others per NLP.
    max_static_rows: 0 (every static row, obstacle or workspace face, is in each
    robot's NLP) or K >= 1: each robot's NLP holds only the K rows nearest to where it
    is (:func:`nearest_static_rows`); ``nlp.n_static`` is then
    :meth:`static_slots` of the world's rows, and ``FleetParams.static`` holds them all.
    """

    nlp: NLPStructure = field(default_factory=NLPStructure)
    max_neighbors: int = 0
    solver_pool: int = 0
    max_static_rows: int = 0

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
    :func:`select_static`), the checks (:func:`plan_violation`, :func:`clear_of_static`)
    use every row.
    deadlock: stall detection and sidestep settings
    (:class:`jaxplan.deadlock.DeadlockParams`); None: neither.
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
    deadlock: dl.DeadlockParams | None = None


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


class PlanState(NamedTuple):
    """Per-robot planner memory carried between replans.

    plan: Trajectory (M,), each starting at the time of the last replan.  has_plan: (M,).
    multipliers, penalty: augmented-Lagrangian warm start.  neighbors: (M, Mo) int32, the
    robot in each other-robot slot of the NLPs (with ``max_neighbors``; -1: none), so
    that multipliers follow their robot when the selection changes.  static_ids: (M, Ks)
    int32, the static row (index into ``FleetParams.static``) in each static-row slot of
    the NLPs (-1: none yet), so that the static rows' multipliers follow their row when
    the selection (``max_static_rows``) changes.  retry: (M,) bool, the robot's last solve
    was not accepted, or it is idle (:func:`jaxplan.deadlock.idle`): its next solve starts
    from the cold guesses (:func:`solve_fleet`).  deadlock: each robot's stall memory
    (:class:`jaxplan.deadlock.DeadlockState`).
    """

    plan: Trajectory
    has_plan: jax.Array
    multipliers: Multipliers
    penalty: jax.Array
    neighbors: jax.Array
    static_ids: jax.Array
    retry: jax.Array
    deadlock: dl.DeadlockState | None = None


class ReplanInfo(NamedTuple):
    """Per-robot diagnostics of one replan, each (M,) (goal_point (M, N)).

    stalled: the robot is stalled (:mod:`jaxplan.deadlock`; False without
    ``FleetParams.deadlock``).  sidestep: it plans to a sidestep sub-goal.  goal_point:
    the end point it planned to (its goal, a sub-goal, or the free point beside an
    occupied goal).
    """

    status: jax.Array
    iterations: jax.Array
    objective: jax.Array
    eq_violation: jax.Array
    ineq_violation: jax.Array
    fallback: jax.Array  # ACCEPTED / KEPT_PREVIOUS / BRAKING / BEST_EFFORT
    goal_moved: jax.Array  # bool: planned to the nearest free point, its goal is occupied
    stalled: jax.Array
    sidestep: jax.Array
    goal_point: jax.Array


def fresh_views(p, v, a, goal_p, goal_v, rest) -> Views:
    """Every observer sees every sender's current state and goal.

    Args: p, v, a, goal_p, goal_v (M, N); rest (M,) bool.
    """
    M = p.shape[0]
    b = lambda x: jnp.broadcast_to(x[None], (M,) + x.shape)
    return Views(b(p), b(v), b(a), b(goal_p), b(goal_v), b(rest),
                 jnp.zeros((M, M)), jnp.ones((M, M), bool))


def predict_views(views: Views, w) -> Trajectory:
    """Closed-form predictions of every sender from every observer's view: batch (M, M)."""
    return predict_arrays(views.p, views.v, views.a, views.goal_p, views.goal_v,
                          jnp.zeros_like(views.p), views.rest, w)


def braking_plan(p, v, a, a_max, structure: PlannerStructure) -> Trajectory:
    """A plan that brings each robot from (p, v, a) to rest, batch (M,).

    A rest-ended quintic over T_b = max(1.5 |v| / a_max, 0.5 s) to p + v T_b / 2 (the
    stopping point of a constant deceleration), re-expressed on the planner's segments
    and degree.  Finite for any input: non-finite entries of p, v, a count as 0 (as in
    :func:`jaxplan.predict.predict_arrays`), and a lane whose quintic overflows holds at p.
    """
    fin = lambda x: jnp.where(jnp.isfinite(x), x, 0.0)
    p, v, a = fin(p), fin(v), fin(a)
    speed = jnp.linalg.norm(v, axis=-1)
    Tb = jnp.maximum(1.5 * speed / jnp.maximum(a_max, 1e-3), 0.5)
    target = p + v * Tb[:, None] * 0.5
    N = p.shape[-1]
    ax = lambda x: [x[:, d] for d in range(N)]
    zero = [jnp.zeros_like(Tb)] * N
    rows = quintic_terms(ax(p), ax(v), ax(a), ax(target), zero, zero,
                          jnp.ones_like(Tb, bool), Tb)
    c = jnp.stack([jnp.stack(r, axis=-1) for r in rows], axis=-2)  # (M, N, 6)
    one = Trajectory.from_normalized(c[:, None], Tb, coast=False)
    ok = jnp.isfinite(Tb) & jnp.all(jnp.isfinite(one.coeffs), axis=(-1, -2, -3))
    hold = Trajectory.hold(p, 5, 1)
    one = tree_where(ok, one, hold)
    return resample(one, structure.nlp.segments, structure.nlp.degree)


def resample(traj: Trajectory, segments: int, degree: int) -> Trajectory:
    """Re-express one-segment trajectories (degree <= ``degree``) on ``segments`` equal
    segments of degree ``degree``: exact (segment k is the same polynomial composed with
    s = (k + sigma) / segments)."""
    D0 = traj.degree
    if D0 > degree:
        raise ValueError(f"cannot lower the degree from {D0} to {degree}")
    c = traj.coeffs[..., 0, :, :]  # (..., N, D0+1)
    if D0 < degree:
        c = jnp.concatenate([c, jnp.zeros(c.shape[:-1] + (degree - D0,), c.dtype)], -1)
    if segments == 1:
        return Trajectory(c[..., None, :, :], traj.breaks, traj.coast)
    K = degree + 1
    mats = jnp.stack([compose_matrix(k / segments, 1.0 / segments, K, c.dtype)
                      for k in range(segments)])  # (S, K, K)
    coeffs = jnp.einsum("smi,...ni->...snm", mats, c)
    return Trajectory.from_normalized(coeffs, traj.duration, traj.coast)


def replan(fp: FleetParams, ps: PlanState, views: Views, p, v, a, goal_p, goal_v, rest,
           structure: PlannerStructure, guide=None):
    """One receding-horizon replan of the whole fleet: the others' predictions from the
    views (:func:`view_predictions`), the robots' NLPs (:func:`fleet_nlps`), their solve
    (:func:`solve_fleet`) and each robot's plan or fallback (:func:`choose_plans`).

    Args:
        fp: FleetParams.  ps: PlanState from the previous replan (plans start at the
        previous replan time, i.e. ``fp.dt`` ago).  views: what each robot knows of the
        others.  p, v, a: (M, N) each robot's own measured state now.  goal_p, goal_v:
        (M, N) current goals; rest: (M,) bool fully defined end state.
        structure: static PlannerStructure.  guide: (value (M, *G), origin (N,),
        spacing (N,)) the guide field of the current goals (:mod:`jaxplan.guide`) or
        None: a robot whose line to its goal goes through an obstacle, and that does
        not sidestep, plans to its guide point (a rest end) instead.
    Returns:
        (new PlanState with every plan starting now, ReplanInfo).
    """
    M = p.shape[0]
    preds, inflate, floor = view_predictions(fp, views)
    ds, stalled, side, idle, goal_p, goal_v, rest = stall_step(fp, ps, views, p, v, goal_p,
                                                               goal_v, rest)
    if guide is not None and fp.static is not None:
        point, use = guide_goals(*guide, fp.static, fp.radius, p, goal_p)
        use = use & ~side & fp.robot_mask
        goal_p = jnp.where(use[:, None], point, goal_p)
        goal_v = jnp.where(use[:, None], 0.0, goal_v)
        rest = rest | use
    params, goal_moved, idx, sidx, mult_prev = fleet_nlps(fp, ps, views, preds, inflate, floor,
                                                          p, v, a, goal_p, goal_v, rest,
                                                          structure)
    if ds is not None:  # a sidestep starts or ends: the end state's kind changes
        switched = (ps.deadlock.left > 0) != side
        mult_prev = tree_where(switched, jax.tree.map(jnp.zeros_like, mult_prev), mult_prev)
        ps = ps._replace(penalty=jnp.where(switched, fp.settings.mu0, ps.penalty))
    sol = solve_fleet(fp, ps, params, mult_prev, structure)
    plan, fallback, new_mult, new_pen = choose_plans(fp, ps, params, sol, p, v, a, structure)
    if ds is not None:
        ds = ds._replace(occupied=goal_moved & ~side)
        # the next broadcast: the end of the plan flown (a braking plan's stopping point)
        ds = dl.broadcast(ds, fp.deadlock, params.goal_p, params.goal_v, params.rest,
                          plan.evaluate(plan.duration), fallback == BRAKING,
                          fallback == KEPT_PREVIOUS)
    new_ps = PlanState(plan, jnp.ones((M,), bool), new_mult, new_pen, idx.astype(jnp.int32),
                       sidx, ((fallback != ACCEPTED) | idle) & fp.robot_mask, ds)
    info = ReplanInfo(sol.status, sol.iterations, sol.objective, sol.eq_violation,
                      sol.ineq_violation, fallback.astype(jnp.int32),
                      goal_moved & fp.robot_mask, stalled & fp.robot_mask,
                      side & fp.robot_mask, params.goal_p)
    return new_ps, info


def stall_step(fp: FleetParams, ps: PlanState, views: Views, p, v, goal_p, goal_v, rest):
    """Stall detection and the sidestep (:mod:`jaxplan.deadlock`) from each robot's own
    view: who is near comes from ``views``; p, v (M, N) its own state.  Returns (the new
    DeadlockState or None, stalled (M,), sidestep (M,), and the goals to plan to: goal_p,
    goal_v (M, N), rest (M,)).  Without ``fp.deadlock`` (or ``ps.deadlock``): nothing
    changes."""
    M = p.shape[0]
    off = jnp.zeros((M,), bool)
    if fp.deadlock is None or ps.deadlock is None:
        return ps.deadlock, off, off, off, goal_p, goal_v, rest
    eye = jnp.eye(M, dtype=bool)
    mask = views.valid & ~eye & fp.robot_mask[None, :] & fp.robot_mask[:, None]
    pairs = dl.near_pairs(p, views.p, fp.radius, jnp.broadcast_to(fp.radius, (M, M)), mask,
                          fp.deadlock.near)
    near = jnp.any(pairs, axis=-1)
    mutual = ~jnp.any(pairs & dl.progressing(views.p, views.v, views.goal_p, fp.deadlock),
                      axis=-1)
    own = dl.progressing(p[:, None], v[:, None], goal_p[:, None], fp.deadlock)[:, 0]
    ds, stalled, side, _ = dl.observe(ps.deadlock, fp.deadlock, fp.dt, p, goal_p, near,
                                      mutual, own)
    idle = dl.idle(ds, fp.deadlock, p, goal_p, near) & fp.robot_mask
    stalled, side = stalled & fp.robot_mask, side & fp.robot_mask
    ds = ds._replace(left=jnp.where(fp.robot_mask, ds.left, 0.0))
    goal_p, goal_v, rest = dl.planning_goals(ds, goal_p, goal_v, rest)
    if fp.static is not None:  # a sidestep sub-goal stays out of obstacles and walls
        goal_p = jnp.where(side[:, None], clear_of_static(goal_p, fp.radius, fp.static),
                           goal_p)
    return ds, stalled, side, idle, goal_p, goal_v, rest


def view_predictions(fp: FleetParams, views: Views):
    """The others' predictions from each robot's views, advanced to now by the message's
    age: (preds (M, M) Trajectory, inflate (M, M) m, floor (M, M) m).  A view older than
    STALE_AFTER_S is taken as a robot holding its last known position; ``inflate`` is how
    far the other could be from where its view puts it, ``floor`` the part of it that a
    held robot is certainly within."""
    # an age from the future counts as 0, an unknown (NaN) age as infinitely old
    age = jnp.where(jnp.isnan(views.age), jnp.inf, jnp.maximum(views.age, 0.0))
    fresh = age <= STALE_AFTER_S
    preds0 = predict_views(views, fp.prediction_weight)
    preds = preds0.shift(jnp.where(fresh, age, 0.0))
    # a silent robot stopped somewhere between its last message and where it comes to
    # rest braking (as braking_plan does) from the next one due, one period later along
    # its prediction: held at the middle of that stretch's chord, which it is within
    # floor of (half the stretch's length, plus a_max dt^2 / 8 for the bend)
    nxt, v_nxt = preds0.evaluate(fp.dt), preds0.evaluate(fp.dt, 1)
    a_max = jnp.maximum(fp.limits.a_max[None, :], 1e-3)
    t_stop = jnp.maximum(1.5 * jnp.linalg.norm(v_nxt, axis=-1) / a_max, 0.5)
    stop = nxt + 0.5 * v_nxt * t_stop[..., None]
    held_p = 0.5 * (views.p + stop)
    held = Trajectory.hold(held_p, preds.degree, preds.num_segments)
    preds = tree_where(fresh, preds, held)
    floor = jnp.where(fresh, 0.0, 0.5 * (jnp.linalg.norm(nxt - views.p, axis=-1)
                                         + jnp.linalg.norm(stop - nxt, axis=-1))
                      + fp.limits.a_max[None, :] * fp.dt**2 / 8)
    floor = jnp.where(jnp.isfinite(floor), floor, 0.0)
    # old information: inflate the other's radius by how far it could be from where the
    # view puts it (unmodelled acceleration for a prediction, any motion for a hold)
    grow = jnp.where(fresh, 0.5 * fp.limits.a_max * age**2, fp.limits.v_max * age)
    inflate = jnp.maximum(jnp.minimum(grow, MAX_INFLATION), floor)
    return preds, inflate, floor


def fleet_nlps(fp: FleetParams, ps: PlanState, views: Views, preds, inflate, floor, p, v, a,
               goal_p, goal_v, rest, structure: PlannerStructure):
    """The robots' NLPs (NLPParams, batch (M,)): occupied goals moved (:func:`free_goals`;
    a robot whose goal moved gets a rest end there), the others in the NLPs' slots (all
    of them in a fixed order, or the nearest ``structure.max_neighbors``), the static rows
    in the NLPs' static slots (all of them, or the nearest ``structure.max_static_rows``:
    :func:`select_static`).  Returns (params, goal_moved (M,), idx (M, Mo) the other robot
    in each slot, sidx (M, Ks) the static row in each static slot, the previous
    multipliers remapped to those slots)."""
    M = p.shape[0]
    eye = jnp.eye(M, dtype=bool)
    other_mask = views.valid & ~eye & fp.robot_mask[None, :] & fp.robot_mask[:, None]
    goal_p, inflate, goal_moved = free_goals(goal_p, p, preds.end_state()[0], fp.radius,
                                             inflate, other_mask, floor)
    if fp.static is not None and structure.nlp.n_static:
        # a goal moved off an occupant must not land in an obstacle or a wall
        goal_clear = clear_of_static(goal_p, fp.radius, fp.static)
        goal_p = jnp.where(goal_moved[:, None], goal_clear, goal_p)
    # a robot whose goal moved waits there: a rest end, not a free end it would fly
    # through at speed (and back, every replan)
    rest = rest | goal_moved
    # (a non-finite goal velocity stays non-finite: the solve must still report it)
    goal_v = jnp.where(goal_moved[:, None] & jnp.isfinite(goal_v), 0.0, goal_v)
    limits_i = Limits(*(jnp.broadcast_to(x, (M,)) for x in fp.limits))
    other_radius = fp.radius[None, :] + inflate
    Mo = structure.others(M)
    mult_prev = ps.multipliers
    if Mo < M - 1:
        preds, other_radius, other_mask, idx = select_neighbors(preds, other_radius,
                                                                other_mask, Mo)
        mult_prev = mult_prev._replace(
            collision=remap_slots(mult_prev.collision, ps.neighbors, idx))
    else:  # every other robot, in a fixed order (the multipliers stay in their slots)
        idx = jnp.asarray(all_others(M))
        preds, other_radius, other_mask = take_slots((preds, other_radius, other_mask), idx)
    static, sidx, lam_static = nlp_static_rows(fp, ps, p, structure, goal_p)
    mult_prev = mult_prev._replace(static=lam_static)
    params = NLPParams(
        p0=p, v0=v, a0=a, goal_p=goal_p, goal_v=goal_v, goal_a=jnp.zeros_like(p), rest=rest,
        others=preds, other_radius=other_radius, other_mask=other_mask,
        radius=fp.radius, weights=jax.tree.map(lambda w: jnp.broadcast_to(w, (M,)), fp.weights),
        limits=limits_i, t_min=jnp.broadcast_to(fp.t_min, (M,)), static=static,
    )
    return params, goal_moved, idx, sidx, mult_prev


def nlp_static_rows(fp: FleetParams, ps: PlanState, p, structure: PlannerStructure,
                    goal_p=None):
    """The static rows in the NLPs' ``structure.nlp.n_static`` = Ks slots: every row of
    ``fp.static`` in a fixed order, or each robot's Ks nearest to where it is, p (M, N),
    and where it is headed: its previous plan and its line to ``goal_p`` (M, N)
    (:func:`heading_points`; None: p alone) (:func:`select_static`, ``max_static_rows``).
    Returns (StaticRows with leaves (M, Ks, ...) or None, sidx (M, Ks) the row in each
    slot, the previous static multipliers ``ps.multipliers.static`` following their row:
    a row new to a robot's selection starts at 0)."""
    M = p.shape[0]
    Ks = structure.nlp.n_static
    lam = ps.multipliers.static
    if fp.static is None or not Ks:
        return None, jnp.full((M, Ks), -1, jnp.int32), lam
    R = fp.static.mask.shape[0]
    if structure.static_slots(R) != Ks:
        raise ValueError(f"the NLP has {Ks} static rows, the planner selects "
                         f"{structure.static_slots(R)} of the world's {R}")
    if Ks < R:
        pts = p if goal_p is None else heading_points(ps, p, goal_p, fp.dt)
        static, sidx = select_static(fp.static, pts, fp.radius, Ks)
        return static, sidx, remap_slots(lam, ps.static_ids, sidx)
    # every row, in a fixed order (the multipliers stay in their slots)
    static = jax.tree.map(lambda a: jnp.broadcast_to(a, (M,) + a.shape), fp.static)
    return static, jnp.broadcast_to(jnp.arange(R, dtype=jnp.int32), (M, R)), lam


def solve_fleet(fp: FleetParams, ps: PlanState, params: NLPParams, mult_prev,
                structure: PlannerStructure):
    """The robots' NLPs solved from warm starts (the previous plans), cold guesses only
    where a robot has no usable previous plan or its last solve was not accepted
    (``ps.retry``), in a pool of lanes (the Solution, batch (M,)).

    The retry: a warm start is the previous plan, and a robot whose plan was pressed
    against an obstacle straight between it and its goal (it held still, the line to the
    goal through the cylinder's axis) was warm-started from that hold replan after
    replan: every solve INFEASIBLE, the robot stopped for good (pillars, 2 of 20
    seeds).  The cold guesses include swerves (:func:`jaxplan.solve.initial_guess`),
    which go round."""
    M = params.radius.shape[0]
    nlp = structure.nlp
    # warm starts; cold guesses (20 objective and 5 merit values each) only when some robot
    # has no usable previous plan
    nan_x = jnp.full((nlp.n_x,), jnp.nan)
    x_warm = jax.vmap(lambda prev, pr: solve.warm_start(prev, fp.dt, pr, nlp, nan_x))(
        ps.plan, params)
    need_cold = ~ps.has_plan | ps.retry | ~jnp.all(jnp.isfinite(x_warm), axis=-1)
    x_cold = jax.lax.cond(
        jnp.any(need_cold), lambda: jax.vmap(lambda pr: solve.initial_guess(pr, nlp))(params),
        lambda: jnp.zeros((M, nlp.n_x)))
    x0 = jnp.where(need_cold[:, None], x_cold, x_warm)
    mult = tree_where(ps.has_plan, mult_prev, jax.tree.map(jnp.zeros_like, mult_prev))
    pen = jnp.where(ps.has_plan, ps.penalty, fp.settings.mu0)
    # x0 is finite (initial_guess is finite for any input): no fallback guess needed
    # a pool of lanes: the replan costs about the sum of the robots' iterations, not M
    # times the largest (`jaxplan run experiments/benchmarks/random_box_20.toml` on a
    # 2-core CPU: 6.9 s with the pool, 22.8 s with solver_pool = M)
    pool = structure.solver_pool or solve.default_pool(M, n_others=params.other_mask.shape[-1])
    return solve.solve_lanes(params, x0, nlp, fp.settings, mult, pen, x_fallback=x0, pool=pool,
                             warm=~need_cold)


def choose_plans(fp: FleetParams, ps: PlanState, params: NLPParams, sol, p, v, a,
                 structure: PlannerStructure):
    """Each robot's new plan: its solution where accepted, else the least violating of
    its best-effort solution, its previous plan and a braking plan
    (:func:`pick_fallback`); padding robots hold.  Returns (plan, fallback code (M,),
    multipliers and penalty to warm-start the next replan)."""
    M = p.shape[0]
    nlp = structure.nlp
    finite = jnp.all(jnp.isfinite(sol.traj.coeffs), axis=(-1, -2, -3)) & jnp.all(
        jnp.isfinite(sol.traj.breaks), axis=-1)
    good_status = (sol.status == solve.CONVERGED) | (
        ((sol.status == solve.MAX_ITERS) | (sol.status == solve.LINE_SEARCH_FAILED))
        & (sol.ineq_violation <= fp.accept_violation))
    accepted = finite & good_status & (sol.eq_violation <= 1e-6)

    prev = ps.plan.shift(fp.dt)
    prev_ok = ps.has_plan & (prev.duration > 0) & jnp.all(
        jnp.isfinite(prev.coeffs), axis=(-1, -2, -3))
    brake = braking_plan(p, v, a, params.limits.a_max, structure)
    usable = finite & (sol.eq_violation <= 1e-6) & (sol.status != solve.NON_FINITE)

    # not accepted: the least violating of best effort, previous, braking (in that order
    # on ties); computed only when some robot needs it
    def choose():
        viol = lambda tr: plan_violation(tr, params.others, params.radius,
                                         params.other_radius, params.other_mask,
                                         fp.static if nlp.n_static else None)
        v_sol = jnp.where(usable, viol(sol.traj), jnp.inf)
        v_prev = jnp.where(prev_ok, viol(prev), jnp.inf)
        return pick_fallback(v_sol, v_prev, viol(brake))

    fallback = jnp.where(accepted, ACCEPTED, jax.lax.cond(
        jnp.any(~accepted & fp.robot_mask), choose, lambda: jnp.full((M,), BRAKING)))
    plan = tree_where(accepted | (fallback == BEST_EFFORT), sol.traj,
                      tree_where(fallback == KEPT_PREVIOUS, prev, brake))
    # padding robots hold where they are
    hold = Trajectory.hold(p, nlp.degree, nlp.segments)
    plan = tree_where(fp.robot_mask, plan, hold)
    fallback = jnp.where(fp.robot_mask, fallback, ACCEPTED)
    new_mult = tree_where(accepted, sol.multipliers,
                          jax.tree.map(jnp.zeros_like, sol.multipliers))
    new_pen = jnp.where(accepted, sol.penalty, fp.settings.mu0)
    return plan, fallback, new_mult, new_pen


def pick_fallback(v_sol, v_prev, v_brake, tol: float = 1e-6):
    """The fallback of a robot whose solve was not accepted, from the violations
    (:func:`plan_violation`, m; inf: not available) of its best-effort solve, its
    previous plan and its braking plan: the least, ties (within ``tol``) in that order."""
    use_sol = v_sol <= jnp.minimum(v_prev, v_brake) + tol
    use_prev = ~use_sol & (v_prev <= v_brake + tol)
    return jnp.where(use_sol, BEST_EFFORT, jnp.where(use_prev, KEPT_PREVIOUS, BRAKING))


def plan_violation(plans: Trajectory, others: Trajectory, radius, other_radius, mask,
                   static: StaticRows | None = None):
    """How deep each plan comes into the others' planning distances, or into the static
    rows (obstacles, workspace faces) by its radius, over the next CHECK_HORIZON_S: max
    over CHECK_SAMPLES instants, others and rows of rho_ij - d_ij and P (r_i - sd) (m;
    P = :data:`jaxplan.nlp.terms.STATIC_PRIORITY`: a plan into an obstacle is worse than
    one as deep into a robot's planning distance, which that robot avoids too), 0 when
    clear.  plans: (M,) trajectories starting now (holding or coasting after their
    end); others: (M, Mo) predictions; radius (M,); other_radius, mask (M, Mo)."""
    t = jnp.arange(1, CHECK_SAMPLES + 1) * (CHECK_HORIZON_S / CHECK_SAMPLES)
    me = plans.evaluate(t[:, None])  # (K, M, N)
    ot = others.evaluate(t[:, None, None])  # (K, M, Mo, N)
    d = jnp.sqrt(jnp.sum((me[:, :, None] - ot) ** 2, axis=-1))
    rho = radius[:, None] + other_radius
    pen = jnp.where(mask[None] & jnp.isfinite(d), rho[None] - d, 0.0)
    worst = jnp.maximum(jnp.max(pen, axis=(0, 2)), 0.0)
    if static is not None:
        sd = signed_distance(static.kind, static.center, static.half, static.radius, me,
                             xp=jnp)  # (K, M, R)
        pen_s = jnp.where(static.mask & jnp.isfinite(sd), radius[None, :, None] - sd, 0.0)
        worst = jnp.maximum(worst, STATIC_PRIORITY * jnp.max(pen_s, axis=(0, 2), initial=0.0))
    return worst


STATIC_PROJECTIONS = 3  # passes of clear_of_static


def clear_of_static(goal, radius, static: StaticRows):
    """Goals (M, N) moved out of the static rows: a goal whose clearance sd - r to a row
    is below GOAL_CLEARANCE is pushed along that row's distance gradient until it is
    (STATIC_PROJECTIONS passes, the deepest row first; exact for planes and spheres,
    for boxes and cylinders outside).  Finite goals stay finite."""
    def gap(g, r):
        return signed_distance(static.kind, static.center, static.half, static.radius, g,
                               xp=jnp) - r

    def one(g, r):
        for _ in range(STATIC_PROJECTIONS):
            gp = jnp.where(static.mask, gap(g, r), jnp.inf)
            k = jnp.argmin(gp)
            short = GOAL_CLEARANCE - gp[k]
            n = jax.grad(lambda q, kk=k: gap(q, r)[kk])(g)
            n = n / jnp.maximum(jnp.linalg.norm(n), 1e-12)
            g = jnp.where((short > 0) & jnp.all(jnp.isfinite(n)), g + short * n, g)
        return g

    return jax.vmap(one)(goal, radius)


def free_goals(goal_p, p, occupant, radius, inflate, mask, floor=None):
    """Goals another robot occupies (module docstring): shrink inflations, move goals.

    Args:
        goal_p: (M, N) each robot's goal.  p: (M, N) its position now.
        occupant: (M, M, N) where observer i expects sender j to end (its prediction's
            end position).  radius: (M,) planning radii (safety margin included).
        inflate: (M, M) extra radius observer i gives sender j.  mask: (M, M) bool,
            the senders that count.  floor: (M, M) part of ``inflate`` never given up
            (default 0: where a held robot is known to be only that well).
    Returns:
        (goal (M, N) to plan to, inflate (M, M) shrunk where a goal is inside it,
        moved (M,) bool: the goal had to move).  Finite for finite input; a non-finite
        occupant never moves a goal.
    """
    floor = jnp.zeros_like(inflate) if floor is None else jnp.minimum(floor, inflate)
    radii = radius[:, None] + radius[None, :]
    base = radii + floor  # (M, M) distance never given up
    ok = mask & jnp.all(jnp.isfinite(occupant), axis=-1)
    d0 = jnp.linalg.norm(goal_p[:, None, :] - occupant, axis=-1)
    room = jnp.where(ok, d0 - radii - GOAL_CLEARANCE, jnp.inf)
    inflate = jnp.where(ok, jnp.maximum(jnp.minimum(inflate, room), floor), inflate)
    target = base + GOAL_CLEARANCE
    g = goal_p
    N = goal_p.shape[-1]
    e0 = jnp.zeros((N,)).at[0].set(1.0)
    for _ in range(GOAL_PROJECTIONS):
        u = g[:, None, :] - occupant
        d = jnp.linalg.norm(u, axis=-1)
        short = jnp.where(ok, target - d, -jnp.inf)  # > 0: inside
        j = jnp.argmax(short, axis=1)
        inside = jnp.take_along_axis(short, j[:, None], 1)[:, 0] > 0
        c = jnp.take_along_axis(occupant, j[:, None, None], 1)[:, 0]
        # away from the occupant; from a coincident goal, towards where the robot is
        away = g - c
        back = p - c
        na, nb = jnp.linalg.norm(away, axis=-1), jnp.linalg.norm(back, axis=-1)
        u = jnp.where((na > 1e-9)[:, None], away / jnp.maximum(na, 1e-300)[:, None],
                      jnp.where((nb > 1e-9)[:, None], back / jnp.maximum(nb, 1e-300)[:, None],
                                e0))
        rad = jnp.take_along_axis(target, j[:, None], 1)[:, 0]
        g = jnp.where(inside[:, None], c + rad[:, None] * u, g)
    moved = jnp.any(g != goal_p, axis=-1) & jnp.all(jnp.isfinite(goal_p), axis=-1)
    return g, inflate, moved


def initial_plan_state(p, structure: PlannerStructure, n_others: int) -> PlanState:
    """Planner memory before the first replan: no plans (first solves start cold).

    Args: p (M, N) start positions; n_others: M, the fleet size (each NLP holds
    ``structure.others(M)`` other-robot slots).
    """
    M = p.shape[0]
    Mo = structure.others(n_others)
    nlp = structure.nlp
    plan = Trajectory.hold(p, nlp.degree, nlp.segments)
    dummy = _dummy_params(p.shape[-1], Mo)
    mult = solve.zero_multipliers(dummy, nlp)
    mult = jax.tree.map(lambda m: jnp.zeros((M,) + m.shape), mult)
    return PlanState(plan, jnp.zeros((M,), bool), mult, jnp.zeros((M,)),
                     jnp.full((M, Mo), -1, jnp.int32), jnp.full((M, nlp.n_static), -1, jnp.int32),
                     jnp.zeros((M,), bool), dl.initial_state(p))


def remap_slots(lam, old_idx, new_idx):
    """Multipliers (M, Kc, Mo) from the old slots to the new ones: each follows what is
    in its slot (another robot's, or a static row's, multipliers); one new to the
    selection starts at 0.

    Args: lam (M, Kc, Mo); old_idx, new_idx (M, Mo) int (the robot or row in each slot;
    -1: none).
    """
    match = (new_idx[:, :, None] == old_idx[:, None, :]) & (new_idx[:, :, None] >= 0)
    return jnp.einsum("mco,mno->mcn", lam, match.astype(lam.dtype))


NEIGHBOR_HORIZON_S = (1.0, 10.0)  # s: the window nearest_neighbors looks over (clipped)
NEIGHBOR_SAMPLES = 16
STATIC_PATH_SAMPLES = 8  # points of the previous plan, and of the line to the goal, by
# which each robot chooses its static rows (heading_points)


def all_others(M: int) -> np.ndarray:
    """(M, max(M - 1, 1)) int32: robot i's other-robot slots hold 0 .. M - 1 but i, in
    order (one robot: its one slot holds itself, masked)."""
    if M == 1:
        return np.zeros((1, 1), np.int32)
    j = np.arange(M - 1)[None, :]
    return (j + (j >= np.arange(M)[:, None])).astype(np.int32)


def take_slots(tree, idx):
    """Every leaf (M, M, ...) of ``tree`` at the other-robot slots idx (M, Mo)."""
    take = lambda u: jnp.take_along_axis(u, idx.reshape(idx.shape + (1,) * (u.ndim - 2)),
                                         axis=1)
    return jax.tree.map(take, tree)


def select_neighbors(preds: Trajectory, other_radius, mask, K: int):
    """Keep each robot's K nearest others (:func:`nearest_neighbors`): the predictions
    (M, K), radii (M, K) and mask (M, K) of the kept slots, and their indices (M, K)."""
    idx = nearest_neighbors(preds, other_radius, mask, K)
    preds, other_radius, mask = take_slots((preds, other_radius, mask), idx)
    return preds, other_radius, mask, idx


def nearest_neighbors(preds: Trajectory, other_radius, mask, K: int):
    """For each robot i, the K others that come nearest to it: (M, K) int32 indices.

    Nearness of j to i: the least clearance, min_t |x_i(t) - x_j(t)| - r_j, over
    NEIGHBOR_SAMPLES times spanning robot i's own closed-form prediction x_i (its view of
    itself, ``preds[i, i]``; its duration clipped to NEIGHBOR_HORIZON_S), x_j being i's
    prediction of j.  Masked or non-finite others come last.

    Args: preds: Trajectory (M, M) as in :func:`replan`.  other_radius: (M, M) m.
    mask: (M, M) bool.  K: static, 1 <= K <= M.
    """
    M = mask.shape[0]
    ar = jnp.arange(M)
    own = jax.tree.map(lambda u: u[ar, ar], preds)
    lo, hi = NEIGHBOR_HORIZON_S
    H = jnp.clip(jnp.where(jnp.isfinite(own.duration), own.duration, hi), lo, hi)
    t = H[:, None] * jnp.linspace(0.0, 1.0, NEIGHBOR_SAMPLES)  # (M, S)
    xi = own.sample(t)  # (M, S, N)
    xj = preds.sample(t[:, None, :])  # (M, M, S, N)
    d = jnp.min(jnp.linalg.norm(xj - xi[:, None], axis=-1), axis=-1) - other_radius
    d = jnp.where(mask & jnp.isfinite(d), d, jnp.inf)
    _, idx = jax.lax.top_k(-d, K)
    return idx.astype(jnp.int32)


def select_static(static: StaticRows, p, radius, K: int):
    """Keep each robot's K nearest static rows (:func:`nearest_static_rows`, p (M, N) or
    (M, S, N) as there): the rows as StaticRows with leaves (M, K, ...), and their
    indices (M, K)."""
    idx = nearest_static_rows(static, p, radius, K)
    rows = jax.tree.map(lambda a: jnp.broadcast_to(a, (idx.shape[0],) + a.shape), static)
    return take_slots(rows, idx), idx


def nearest_static_rows(static: StaticRows, p, radius, K: int):
    """For each robot, the K static rows nearest to it: (M, K) int32 indices, nearest
    first; masked or non-finite rows come last.

    With p (M, N), a robot's position, a row's key is its clearance sd(p) - r there.
    With p (M, S, N), points of where the robot is and where it is headed
    (:func:`heading_points`), the key is the least clearance over the points: how near
    the row comes to the robot's way.  (A key that adds the distance flown to each point
    ranks exactly as the clearance at the position alone: the signed distance is
    1-Lipschitz.)  So a row that its previous plan or its line to the goal passes is kept
    ahead of one as near to where it is but off its way (docs/SOLVER.md, "Which rows an
    NLP holds").

    Args: static: StaticRows (R rows).  p: (M, N) or (M, S, N) m.  radius: (M,) m.
    K: static, 1 <= K <= R.
    """
    if p.ndim == 2:
        p = p[:, None, :]
    M, S, N = p.shape
    gap = signed_distance(static.kind, static.center, static.half, static.radius,
                          p.reshape(M * S, N), xp=jnp).reshape(M, S, -1) - radius[:, None, None]
    key = jnp.where(jnp.isfinite(gap), gap, jnp.inf).min(axis=1)
    key = jnp.where(static.mask, key, jnp.inf)
    _, idx = jax.lax.top_k(-key, K)
    return idx.astype(jnp.int32)


def heading_points(ps: PlanState, p, goal_p, dt, samples: int = STATIC_PATH_SAMPLES):
    """Where each robot is and is headed, for choosing its static rows: its position,
    ``samples`` points of its previous plan from now on (where it has a finite one;
    else its position) and ``samples`` points of the line to its goal (a non-finite goal:
    its position).  Returns (M, 1 + 2 samples, N)."""
    frac = jnp.linspace(0.0, 1.0, samples + 1)[1:]
    prev = ps.plan.shift(dt)
    on_plan = prev.sample(prev.duration[:, None] * frac[None, :])  # (M, S, N)
    ok = ps.has_plan & jnp.all(jnp.isfinite(on_plan), axis=(-1, -2))
    on_plan = jnp.where(ok[:, None, None], on_plan, p[:, None, :])
    g = jnp.where(jnp.isfinite(goal_p), goal_p, p)
    on_line = p[:, None, :] + frac[None, :, None] * (g - p)[:, None, :]
    return jnp.concatenate([p[:, None], on_plan, on_line], axis=1)


def _dummy_params(N: int, Mo: int) -> NLPParams:
    z = jnp.zeros((N,))
    others = Trajectory.hold(jnp.zeros((Mo, N)))
    one = jnp.asarray(1.0)
    return NLPParams(z, z, z, z, z, z, jnp.asarray(False), others, jnp.ones((Mo,)),
                     jnp.ones((Mo,), bool), one, Weights(one, one, one, one, one),
                     Limits(one, one, one), one)
