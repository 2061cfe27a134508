"""Where the robots went beyond their task: how far each strayed from its last goal after
reaching it, and how far it left the region of its task (host, NumPy; exact, from the
executed pieces).

    goal_excursion_pieces(pieces, goal, tol, t_from) -> (excursion, reach)
        the largest |x(t) - g| after the robot first came within tol of g, and when
    escape_pieces(pieces, lo, hi) -> (M,)
        the largest Euclidean distance of x(t) outside the box lo <= x <= hi
    fleet_box(start, waypoints, margin) -> (lo, hi)
        the box spanned by a fleet's starts and waypoints, grown by margin

The pieces are the package's (:mod:`jaxplan.metrics`); every extremum comes from the
exact root machinery of :mod:`jaxplan.metrics.pieces` (ends of an interval and roots
of a polynomial's derivative), so the values are exact up to round-off, not sampled.
"""

from __future__ import annotations

import numpy as np

from jaxplan.metrics.pieces import (
    bernstein,
    check_pieces,
    dot_conv,
    horner,
    stationary_candidates,
    to_unit,
    unit_roots,
)
from jaxplan.world import fleet_box

__all__ = ["goal_excursion_pieces", "escape_pieces", "fleet_box"]


def _first_within(eu, tol):
    """(S,) u in [0, 1]: the first point of each piece (eu (S, N, L), the offset from the
    goal in normalised time) within tol of the goal; NaN where none is.

    The piece is cut at the roots in [0, 1] of |eu|^2 - tol^2; being within is constant
    on each cut (tested at its midpoint), and a cut's start point is tested on its own
    (a touch of the sphere at one instant counts)."""
    g = dot_conv(eu, eu)
    g[:, 0] -= tol**2
    S = eu.shape[0]
    u = np.sort(np.concatenate([np.zeros((S, 1)), np.ones((S, 1)), unit_roots(g)], axis=1),
                axis=1)
    at = np.linalg.norm(horner(eu, u), axis=-1) <= tol  # (S, C)
    mid = 0.5 * (u[:, :-1] + u[:, 1:])
    during = np.linalg.norm(horner(eu, mid), axis=-1) <= tol  # (S, C-1)
    ok = at | np.concatenate([during, np.zeros((S, 1), bool)], axis=1)
    first = np.argmax(ok, axis=1)
    return np.where(ok.any(axis=1), u[np.arange(S), first], np.nan)


def goal_excursion_pieces(seg_robot, seg_t0, seg_t1, seg_coeffs, goal, tol, t_from=None,
                          num_robots=None):
    """How far each robot went from its goal after it first reached it, exactly.

    Args:
        seg_robot, seg_t0, seg_t1, seg_coeffs: the pieces (:mod:`jaxplan.metrics`).
        goal: (M, N) m, each robot's goal (its last waypoint).
        tol: m, the goal tolerance: "reached" is the first instant with |x - g| <= tol.
        t_from: (M,) s, optional: search for that instant from this time on (e.g. when
            the robot reached the waypoint before its last one); NaN: the robot is
            never searched (its results are NaN).  Default: from its first piece.
        num_robots: M (default goal.shape[0]).

    Returns:
        (excursion (M,) m, reach (M,) s): reach is the first instant t >= t_from at
        which the robot is within tol of its goal, and excursion the maximum of
        |x(t) - g| over its pieces from reach to its end (>= tol at a crossing, the
        distance at reach when it started within); both NaN where the robot is never
        within tol (or has no pieces).  Gaps between pieces are ignored.

    Method: the first instant, by the roots in [0, 1] of |x - g|^2 - tol^2 on each piece
    (from t_from on); then on each piece's part after it, re-expressed in normalised
    time, the maximum of |x - g|^2 at its ends and at the roots of (x - g) . x'
    (:func:`jaxplan.metrics.pieces.stationary_candidates`).
    """
    goal = np.asarray(goal, dtype=np.float64)
    if num_robots is None:
        num_robots = goal.shape[0]
    r, t0, t1, c, m, _ = check_pieces(seg_robot, seg_t0, seg_t1, seg_coeffs, num_robots)
    if goal.shape != (m, c.shape[1]):
        raise ValueError(f"goal must be (M, N) = ({m}, {c.shape[1]}); got {goal.shape}")
    exc, reach = np.full(m, np.nan), np.full(m, np.nan)
    tf = np.full(m, -np.inf) if t_from is None else np.asarray(t_from, np.float64)
    if tf.shape != (m,):
        raise ValueError(f"t_from must be (M,) = ({m},); got {tf.shape}")
    e = c.copy()
    e[:, :, 0] -= goal[r]
    # each piece from t_from on: [a, t1]
    with np.errstate(invalid="ignore"):
        a = np.maximum(t0, tf[r])
        keep = np.isfinite(a) & (a <= t1)
    if not keep.any():
        return exc, reach
    k = np.nonzero(keep)[0]
    u = _first_within(to_unit(e[k], a[k] - t0[k], t1[k] - a[k]), tol)
    t_hit = np.where(u >= 1.0, t1[k], a[k] + u * (t1[k] - a[k]))
    first = np.full(m, np.inf)
    np.minimum.at(first, r[k], np.where(np.isnan(u), np.inf, t_hit))
    reach = np.where(np.isfinite(first), first, np.nan)
    # the largest distance from the goal on each piece's part after the reach
    with np.errstate(invalid="ignore"):
        b = np.maximum(t0, reach[r])
        after = np.isfinite(b) & (b <= t1)
    if after.any():
        j = np.nonzero(after)[0]
        _, sq = stationary_candidates(to_unit(e[j], b[j] - t0[j], t1[j] - b[j]))
        best = np.full(m, -np.inf)
        np.maximum.at(best, r[j], np.sqrt(np.max(sq, axis=1)))
        exc = np.where(np.isfinite(best), best, np.nan)
    return exc, reach


def escape_pieces(seg_robot, seg_t0, seg_t1, seg_coeffs, lo, hi, num_robots=None):
    """The largest Euclidean distance of each robot outside a box, exactly.

    Args:
        seg_robot, seg_t0, seg_t1, seg_coeffs: the pieces (:mod:`jaxplan.metrics`).
        lo, hi: (N,) m, the box lo <= x <= hi (an infinite bound: no bound on that side).
        num_robots: M (default max(seg_robot) + 1).

    Returns:
        (M,) m: the maximum over each robot's pieces and time of
        |x(t) - clip(x(t), lo, hi)| (the distance from x to the box; 0 when the robot
        never leaves it); NaN for a robot without pieces.

    Method: a piece whose Bernstein coefficients on each axis lie within the box never
    leaves it (the convex-hull property).  Any other piece is cut at the roots in [0, 1]
    of x_k - lo_k and x_k - hi_k for every axis k and finite bound; on each cut the axes
    outside and their sides are fixed (read at its midpoint), so the squared distance is
    the polynomial sum over those axes of (x_k - bound_k)^2, whose maximum on the cut is
    at its ends or at a root of its derivative
    (:func:`jaxplan.metrics.pieces.stationary_candidates`).  This is the exact Euclidean
    distance, also while two or three axes are outside at once.
    """
    r, t0, t1, c, m, _ = check_pieces(seg_robot, seg_t0, seg_t1, seg_coeffs, num_robots)
    N = c.shape[1]
    lo = np.broadcast_to(np.asarray(lo, np.float64), (N,))
    hi = np.broadcast_to(np.asarray(hi, np.float64), (N,))
    if np.any(np.isnan(lo)) or np.any(np.isnan(hi)) or np.any(lo > hi):
        raise ValueError(f"the box needs lo <= hi (no NaN); got lo {lo}, hi {hi}")
    out = np.full(m, np.nan)
    out[r] = 0.0
    if r.size == 0:
        return out
    q = to_unit(c, np.zeros_like(t0), t1 - t0)  # (S, N, L)
    bern = q @ bernstein(q.shape[2] - 1)
    maybe = np.nonzero(np.any((bern.min(axis=2) < lo) | (bern.max(axis=2) > hi), axis=1))[0]
    if maybe.size == 0:
        return out
    q = q[maybe]
    P = q.shape[0]
    cuts = [np.zeros((P, 1)), np.ones((P, 1))]
    for k in range(N):
        for bound in (lo[k], hi[k]):
            if np.isfinite(bound):
                g = q[:, k, :].copy()
                g[:, 0] -= bound
                cuts.append(unit_roots(g))
    u = np.sort(np.concatenate(cuts, axis=1), axis=1)
    ua, ub = u[:, :-1], u[:, 1:]  # (P, C) the cuts
    xm = horner(q, 0.5 * (ua + ub))  # (P, C, N)
    below, above = xm < lo, xm > hi
    active = below | above
    sel = np.nonzero(active.any(axis=2))  # (piece, cut) pairs outside on some axis
    if sel[0].size == 0:
        return out
    bound = np.where(below, lo, np.where(above, hi, 0.0))[sel]  # (Q, N)
    sub = q[sel[0]].copy()  # (Q, N, L): x_k - bound_k on the axes outside, 0 elsewhere
    sub[:, :, 0] -= bound
    sub *= active[sel][:, :, None]
    _, sq = stationary_candidates(to_unit(sub, ua[sel], ub[sel] - ua[sel]))
    np.maximum.at(out, r[maybe][sel[0]], np.sqrt(np.max(sq, axis=1)))
    return out

