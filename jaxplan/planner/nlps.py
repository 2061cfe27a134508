"""Stage 4 of a replan: the robots' NLPs (:mod:`jaxplan.nlp`), one per robot, batch (M,).

Each robot's NLP holds its own state and the goal it plans to (:mod:`.goals`), the
others' predictions (:mod:`.views`) in its other-robot slots: all of them in a fixed
order, or the ``max_neighbors`` that come nearest to its own prediction
(:func:`nearest_neighbors`), and the world's static rows (obstacles, finite workspace
faces) in its static slots: all of them, or the ``max_static_rows`` nearest to where
it is and where it is headed (:func:`nlp_static_rows`; docs/SOLVER.md, "Which rows an
NLP holds").  Where the selection changes, the previous multipliers follow their robot
or their row (:func:`remap_slots`).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.nlp import Limits, Multipliers, NLPParams
from jaxplan.nlp.terms import LIMIT_PRIORITY, LIMIT_PRIORITY_CALM
from jaxplan.planner.types import FleetParams, FleetState, Goals, PlannerStructure, PlanState
from jaxplan.planner.views import Predictions, sender_mask
from jaxplan.trajectory import Trajectory
from jaxplan.world import StaticRows, centres_at, signed_distance

NEIGHBOR_HORIZON_S = (1.0, 10.0)  # s: the window nearest_neighbors looks over (clipped)
NEIGHBOR_SAMPLES = 16
STATIC_PATH_SAMPLES = 8  # points of the previous plan, and of the line to the goal, by
# which each robot chooses its static rows (heading_points)


class FleetNLPs(NamedTuple):
    """The NLPs of a replan (:func:`fleet_nlps`).

    params: NLPParams, batch (M,).  neighbors: (M, Mo) int32, the other robot in each
    other-robot slot (-1: none).  static_ids: (M, Ks) int32, the static row in each
    static slot (-1: none).  multipliers: the previous replan's multipliers
    (``PlanState.multipliers``) moved to those slots: each follows its robot or row, one
    new to a robot's selection starts at 0.
    """

    params: NLPParams
    neighbors: jax.Array
    static_ids: jax.Array
    multipliers: Multipliers


def fleet_nlps(fp: FleetParams, ps: PlanState, fleet: FleetState, preds: Predictions,
               goals: Goals, structure: PlannerStructure) -> FleetNLPs:
    """The robots' NLPs (module docstring): each robot's own state (``fleet``) and the
    goals it plans to (``goals``, as :mod:`.goals` left them), the others' predictions
    ``preds`` (radii inflated by ``preds.inflate``) in the NLPs' slots (all of them in a
    fixed order, or the nearest ``structure.max_neighbors``), the static rows in the
    NLPs' static slots (all of them, or the nearest ``structure.max_static_rows``:
    :func:`nlp_static_rows`)."""
    p, v, a = fleet.p, fleet.v, fleet.a
    M = p.shape[0]
    other_mask = sender_mask(fp, fleet.views)
    limits_i = Limits(*(jnp.broadcast_to(x, (M,)) for x in fp.limits))
    other_radius = fp.radius[None, :] + preds.inflate
    Mo = structure.others(M)
    mult_prev = ps.multipliers
    others = preds.traj
    if Mo < M - 1:
        others, other_radius, other_mask, idx = select_neighbors(others, other_radius,
                                                                 other_mask, Mo)
        mult_prev = mult_prev._replace(
            collision=remap_slots(mult_prev.collision, ps.neighbors, idx))
    else:  # every other robot, in a fixed order (the multipliers stay in their slots)
        idx = jnp.asarray(all_others(M))
        others, other_radius, other_mask = take_slots((others, other_radius, other_mask), idx)
    static, sidx, lam_static = nlp_static_rows(fp, ps, p, structure, goals.goal_p)
    mult_prev = mult_prev._replace(static=lam_static)
    params = NLPParams(
        p0=p, v0=v, a0=a, goal_p=goals.goal_p, goal_v=goals.goal_v, goal_a=jnp.zeros_like(p),
        rest=goals.rest, others=others, other_radius=other_radius, other_mask=other_mask,
        radius=fp.radius, weights=jax.tree.map(lambda w: jnp.broadcast_to(w, (M,)), fp.weights),
        limits=limits_i, t_min=jnp.broadcast_to(fp.t_min, (M,)), static=static,
        limit_priority=jnp.where(ps.retry, LIMIT_PRIORITY, LIMIT_PRIORITY_CALM),
    )
    return FleetNLPs(params, idx, sidx, mult_prev)


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
        times = None  # moving rows: where they will be when the robot gets there
        if fp.static.motion is not None:
            times = (jnp.zeros(p.shape[:1]) if goal_p is None else
                     heading_times(ps, p, goal_p, fp.dt, fp.limits.v_max))
        static, sidx = select_static(fp.static, pts, fp.radius, Ks, times)
        return static, sidx, remap_slots(lam, ps.static_ids, sidx)
    # every row, in a fixed order (the multipliers stay in their slots)
    static = jax.tree.map(lambda a: jnp.broadcast_to(a, (M,) + a.shape), fp.static)
    return static, jnp.broadcast_to(jnp.arange(R, dtype=jnp.int32), (M, R)), lam


def remap_slots(lam, old_idx, new_idx):
    """Multipliers (M, Kc, Mo) from the old slots to the new ones: each follows what is
    in its slot (another robot's, or a static row's, multipliers); one new to the
    selection starts at 0.

    Args: lam (M, Kc, Mo); old_idx, new_idx (M, Mo) int (the robot or row in each slot;
    -1: none).
    """
    match = (new_idx[:, :, None] == old_idx[:, None, :]) & (new_idx[:, :, None] >= 0)
    return jnp.einsum("mco,mno->mcn", lam, match.astype(lam.dtype))


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

    Args: preds: Trajectory (M, M), each robot's predictions of the others
    (:func:`jaxplan.planner.views.view_predictions`).  other_radius: (M, M) m.
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


def select_static(static: StaticRows, p, radius, K: int, t=None):
    """Keep each robot's K nearest static rows (:func:`nearest_static_rows`, p (M, N) or
    (M, S, N) and t as there): the rows as StaticRows with leaves (M, K, ...), and their
    indices (M, K)."""
    idx = nearest_static_rows(static, p, radius, K, t)
    rows = jax.tree.map(lambda a: jnp.broadcast_to(a, (idx.shape[0],) + a.shape), static)
    return take_slots(rows, idx), idx


def nearest_static_rows(static: StaticRows, p, radius, K: int, t=None):
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

    Moving rows (``static.motion``, relative to now) count where they will be at the
    points' times t (M,) or (M, S) s (:func:`heading_times`; None: where they are now).

    Args: static: StaticRows (R rows).  p: (M, N) or (M, S, N) m.  radius: (M,) m.
    K: static, 1 <= K <= R.
    """
    if p.ndim == 2:
        p = p[:, None, :]
        t = None if t is None else t[:, None]
    M, S, N = p.shape
    if static.motion is None or t is None:
        gap = signed_distance(static.kind, static.center, static.half, static.radius,
                              p.reshape(M * S, N), xp=jnp).reshape(M, S, -1)
    else:
        gap = signed_distance(static.kind, centres_at(static, t), static.half, static.radius,
                              p, xp=jnp)
    gap = gap - radius[:, None, None]
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


def heading_times(ps: PlanState, p, goal_p, dt, v_max, samples: int = STATIC_PATH_SAMPLES):
    """When each robot is at :func:`heading_points`' points, s from now: 0, the previous
    plan's sample times, and the line's points at v_max (M,).  Returns (M, 1 + 2 samples)."""
    frac = jnp.linspace(0.0, 1.0, samples + 1)[1:]
    prev = ps.plan.shift(dt)
    T = jnp.where(jnp.isfinite(prev.duration), prev.duration, 0.0)
    g = jnp.where(jnp.isfinite(goal_p), goal_p, p)
    line = jnp.linalg.norm(g - p, axis=-1) / v_max
    M = p.shape[0]
    return jnp.concatenate([jnp.zeros((M, 1)), T[:, None] * frac[None, :],
                            line[:, None] * frac[None, :]], axis=1)
