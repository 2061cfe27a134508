"""How the robots moved: kinematics, sampling and time to goal of the executed pieces,
parked robots and the makespan's straight-line bound; and the solver's replan times
(host, NumPy).

    kinematics(pieces) -> Kinematics          exact max speed, acceleration, jerk; path length
    sample_pieces(pieces, t) -> pos, vel, acc          the pieces on a time grid
    time_to_goal(t, pos, goal, tol)           on samples
    time_to_goal_pieces(pieces, goal, tol)    exact, from the pieces
    solver_summary(solve_ms, converged)       replan wall times, convergence
    parked_robots(...), makespan_bound(...)   occupied goals; the makespan's bound

The pieces are the package's (:mod:`jaxplan.metrics`); maxima and crossings come from
the exact root machinery of :mod:`jaxplan.metrics.pieces`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from jaxplan.metrics.pieces import (
    check_pieces,
    deriv,
    dot_conv,
    horner,
    stationary_candidates,
    to_unit,
    unit_roots,
)

__all__ = ["Kinematics", "kinematics", "sample_pieces", "time_to_goal", "time_to_goal_pieces",
           "solver_summary", "parked_robots", "makespan_bound"]

# ------------------------------------------------------------------------ kinematics


class Kinematics(NamedTuple):
    """Per-robot kinematic summary, each (M,); NaN for a robot without pieces.

    max_speed (m/s), max_acc (m/s^2), max_jerk (m/s^3): exact maxima of |x'|, |x''|,
        |x'''| over all the robot's pieces (closed intervals; derivative-root method).
    path_length_m (m): integral of |x'(t)| dt over its pieces.
    """

    max_speed: np.ndarray
    max_acc: np.ndarray
    max_jerk: np.ndarray
    path_length_m: np.ndarray


def _gauss_legendre(n):
    x, w = np.polynomial.legendre.leggauss(n)
    return 0.5 * (x + 1.0), 0.5 * w  # on [0, 1]


def kinematics(seg_robot, seg_t0, seg_t1, seg_coeffs, num_robots=None, quad_nodes=32):
    """Max speed, acceleration, jerk and path length of each robot from its pieces.

    Args:
        seg_robot, seg_t0, seg_t1, seg_coeffs: the pieces (:mod:`jaxplan.metrics`; seconds, m).
        num_robots: M (default max(seg_robot) + 1).
        quad_nodes: Gauss-Legendre nodes per sub-interval for the path length.

    Returns:
        :class:`Kinematics` of (M,) arrays.

    Maxima are exact (up to round-off): the maximum of |x^(k)|^2 on a piece is at an end
    or at a root of x^(k) . x^(k+1), found as for the separation
    (:func:`jaxplan.metrics.pieces.stationary_candidates`).

    Path length accuracy: each piece is first cut at the stationary points of |v|^2
    (roots of v . a: the speed's local minima, in particular every point where the
    robot stops and |v| has a kink), so |v| is smooth on every sub-interval, with at
    worst a one-sided linear zero at an end; Gauss-Legendre with quad_nodes (32) nodes
    per sub-interval then integrates it: exact up to round-off for constant velocity and
    for exact stops; near-stops, |v| = sqrt(eps^2 + s^2 (t - t*)^2) with the minimum at a
    cut, are the hard case (accuracy: docs/SOLVER.md, "Metrics").  Cost: S x 2(D-1) x
    quad_nodes evaluations of v.
    """
    r, t0, t1, c, m, _ = check_pieces(seg_robot, seg_t0, seg_t1, seg_coeffs, num_robots)
    nan = np.full(m, np.nan)
    if r.size == 0:
        return Kinematics(nan.copy(), nan.copy(), nan.copy(), nan.copy())
    h = t1 - t0
    zero = np.zeros_like(h)
    maxima = []
    dk = c
    vel_u = None
    for k in (1, 2, 3):
        dk = deriv(dk)
        q = to_unit(dk, zero, h)
        if k == 1:
            vel_u = q
        _, sq = stationary_candidates(q)
        val = np.sqrt(np.max(sq, axis=1))
        out = np.full(m, -np.inf)
        np.maximum.at(out, r, val)
        maxima.append(np.where(np.isneginf(out), np.nan, out))
    # path length: cut at the stationary points of |v|^2, then Gauss-Legendre
    brk = np.sort(stationary_candidates(vel_u, polish=False)[0], axis=1)  # (S, C)
    xg, wg = _gauss_legendre(int(quad_nodes))
    lo, hi = brk[:, :-1], brk[:, 1:]  # (S, C-1)
    nodes = lo[..., None] + (hi - lo)[..., None] * xg  # (S, C-1, G)
    S = r.size
    speed = np.linalg.norm(horner(vel_u, nodes.reshape(S, -1)), axis=-1).reshape(nodes.shape)
    length = h * np.sum((hi - lo) * np.sum(speed * wg, axis=-1), axis=1)
    plen = np.zeros(m)
    np.add.at(plen, r, length)
    has = np.zeros(m, dtype=bool)
    has[r] = True
    return Kinematics(maxima[0], maxima[1], maxima[2], np.where(has, plen, np.nan))


# -------------------------------------------------------------------------- sampling


def sample_pieces(seg_robot, seg_t0, seg_t1, seg_coeffs, t, num_robots=None, outside="nan"):
    """Evaluate the pieces of every robot at the times t.

    Args:
        seg_robot, seg_t0, seg_t1, seg_coeffs: the pieces (:mod:`jaxplan.metrics`).
        t: (K,) s, sample times (any order; typically a uniform grid at >= 100 Hz).
        num_robots: M (default max(seg_robot) + 1).
        outside: what a robot reports at times outside its pieces' span [first t0,
            last t1] (a 1e-9 relative slack at both ends counts as inside):
            "nan" (default) NaN; "clamp" the state at the nearest end of the span.
            Times in a gap between two of its pieces use the earlier piece (extrapolated).

    Returns:
        pos (m), vel (m/s), acc (m/s^2): each (M, K, N).  At a break the later piece is
        used (pieces are half-open [t0, t1), except the last one, which is closed).
    """
    if outside not in ("nan", "clamp"):
        raise ValueError(f"outside must be 'nan' or 'clamp', not {outside!r}")
    r, t0, t1, c, m, order = check_pieces(seg_robot, seg_t0, seg_t1, seg_coeffs, num_robots)
    t = np.asarray(t, dtype=np.float64)
    if t.ndim != 1:
        raise ValueError(f"t must be (K,); got {t.shape}")
    n = c.shape[1]
    out = np.full((3, m, t.size, n), np.nan)
    rs = r[order]
    starts = np.searchsorted(rs, np.arange(m + 1))
    cv = deriv(c)
    ca = deriv(cv)
    for i in range(m):  # loop over robots, vectorized over samples
        idx = order[starts[i] : starts[i + 1]]
        if idx.size == 0:
            continue
        first, last = t0[idx[0]], t1[idx[-1]]
        slack = 1e-9 * max(1.0, abs(first), abs(last))
        inside = (t >= first - slack) & (t <= last + slack)
        tt = np.clip(t, first, last) if outside == "clamp" else t
        k = np.clip(np.searchsorted(t0[idx], tt, side="right") - 1, 0, idx.size - 1)
        seg = idx[k]
        # a zero-length last piece at the very end is fine: tau = 0
        tau = (tt - t0[seg])[:, None]
        for j, cc in enumerate((c, cv, ca)):
            val = horner(cc[seg], tau)[:, 0, :]
            if outside == "nan":
                val = np.where(inside[:, None], val, np.nan)
            out[j, i] = val
    return out[0], out[1], out[2]


# ------------------------------------------------------------------------ time to goal


def time_to_goal(t, pos, goal, tol, vel=None, speed_tol=None):
    """First sample time after which each robot stays within tol of its goal to the end.

    Args:
        t: (K,) s, increasing sample times.
        pos: (M, K, N) m, sampled positions (e.g. from :func:`sample_pieces`).
        goal: (M, N) m.
        tol: m, position tolerance (|pos - goal| <= tol counts as within).
        vel: (M, K, N) m/s, needed when speed_tol is given.
        speed_tol: m/s, optional residual-speed tolerance for rest goals: a sample
            counts as within only if also |vel| <= speed_tol.

    Returns:
        (M,) s: t[k] for the smallest k such that samples k..K-1 are all within; NaN if
        the last sample is not within (never reached, or left the goal again).
        Non-finite samples count as not within.  On a grid this is the first sample
        after the exact crossing, i.e. late by less than one sample step; use
        :func:`time_to_goal_pieces` for the exact time.
    """
    t = np.asarray(t, dtype=np.float64)
    pos = np.asarray(pos, dtype=np.float64)
    goal = np.asarray(goal, dtype=np.float64)
    if pos.ndim != 3 or pos.shape[1] != t.size or goal.shape != (pos.shape[0], pos.shape[2]):
        raise ValueError(
            f"need t (K,), pos (M, K, N), goal (M, N); got {t.shape}, {pos.shape}, {goal.shape}"
        )
    with np.errstate(invalid="ignore"):
        ok = np.linalg.norm(pos - goal[:, None, :], axis=-1) <= tol
        if speed_tol is not None:
            if vel is None:
                raise ValueError("speed_tol needs vel")
            ok &= np.linalg.norm(np.asarray(vel, dtype=np.float64), axis=-1) <= speed_tol
    m, k = ok.shape
    res = np.full(m, np.nan)
    if k == 0:
        return res
    # index of the last sample not within (-1 if none)
    last_bad = k - 1 - np.argmax(~ok[:, ::-1], axis=1)
    last_bad = np.where(ok.all(axis=1), -1, last_bad)
    good = last_bad < k - 1
    res[good] = t[last_bad[good] + 1]
    return res


def time_to_goal_pieces(
    seg_robot, seg_t0, seg_t1, seg_coeffs, goal, tol, speed_tol=None, num_robots=None
):
    """Exact first time after which each robot stays within tol of its goal to its end.

    Args:
        seg_robot, seg_t0, seg_t1, seg_coeffs: the pieces (:mod:`jaxplan.metrics`).
        goal: (M, N) m.
        tol: m, position tolerance.
        speed_tol: m/s, optional; "within" then also needs |v| <= speed_tol.
        num_robots: M (default goal.shape[0]).

    Returns:
        (M,) s: the infimum of the times T such that the robot is within on [T, end of
        its last piece]; the start of its first piece if it is always within; NaN if it
        is not within at the end of its last piece, or has no pieces.

    Method: each piece is cut at the real roots in [0, 1] of |x - g|^2 - tol^2 (and of
    |v|^2 - speed_tol^2), found as for the separation
    (:func:`jaxplan.metrics.pieces.unit_roots`); the condition is constant on each
    cut and is evaluated at its midpoint.  Gaps between pieces are ignored.
    """
    goal = np.asarray(goal, dtype=np.float64)
    if num_robots is None:
        num_robots = goal.shape[0]
    r, t0, t1, c, m, _ = check_pieces(seg_robot, seg_t0, seg_t1, seg_coeffs, num_robots)
    if goal.shape != (m, c.shape[1]):
        raise ValueError(f"goal must be (M, N) = ({m}, {c.shape[1]}); got {goal.shape}")
    res = np.full(m, np.nan)
    if r.size == 0:
        return res
    h = t1 - t0
    zero = np.zeros_like(h)
    e = c.copy()
    e[:, :, 0] -= goal[r]
    eu = to_unit(e, zero, h)
    g1 = dot_conv(eu, eu)
    g1[:, 0] -= tol**2
    cuts = [unit_roots(g1)]
    vu = None
    if speed_tol is not None:
        vu = to_unit(deriv(c), zero, h)
        g2 = dot_conv(vu, vu)
        g2[:, 0] -= speed_tol**2
        cuts.append(unit_roots(g2))
    S = r.size
    u = np.sort(np.concatenate([np.zeros((S, 1)), np.ones((S, 1))] + cuts, axis=1), axis=1)
    mid = 0.5 * (u[:, :-1] + u[:, 1:])
    ok = np.linalg.norm(horner(eu, mid), axis=-1) <= tol
    if vu is not None:
        ok &= np.linalg.norm(horner(vu, mid), axis=-1) <= speed_tol
    ok |= u[:, 1:] <= u[:, :-1]  # empty cuts carry no information
    # end time of each cut (u = 1 maps to t1 exactly; a zero-length piece is its point)
    tcut = np.where(u[:, 1:] >= 1.0, t1[:, None], t0[:, None] + u[:, 1:] * h[:, None])
    bad_end = np.where(~ok, tcut, -np.inf).max(axis=1)  # (S,) end of the last bad cut
    last_bad = np.full(m, -np.inf)
    np.maximum.at(last_bad, r, bad_end)
    start = np.full(m, np.inf)
    np.minimum.at(start, r, t0)
    end = np.full(m, -np.inf)
    np.maximum.at(end, r, t1)
    has = np.isfinite(start)
    res = np.where(np.isneginf(last_bad), start, last_bad)
    # not within at the very end (the last bad cut ends at the end of the span) -> NaN
    res = np.where(has & (last_bad < end), res, np.nan)
    return res


# --------------------------------------------------------------------- solver timing


def solver_summary(solve_ms, converged):
    """Summary of per-replan solve times.

    Args:
        solve_ms: (R,) ms, wall time of each fleet replan (non-finite entries ignored).
        converged: bool array of any shape (per replan, or per replan x robot lane).

    Returns:
        dict median_ms, p95_ms (linear-interpolated 95th percentile), max_ms,
        converged_frac (fraction of True in converged); each a float, NaN when its
        input is empty.
    """
    ms = np.asarray(solve_ms, dtype=np.float64).ravel()
    ms = ms[np.isfinite(ms)]
    conv = np.asarray(converged, dtype=bool).ravel()
    if ms.size:
        med, p95, mx = np.percentile(ms, [50.0, 95.0, 100.0])
    else:
        med = p95 = mx = math.nan
    return dict(
        median_ms=float(med),
        p95_ms=float(p95),
        max_ms=float(mx),
        converged_frac=float(conv.mean()) if conv.size else math.nan,
    )


# ------------------------------------------------- occupied goals, the makespan bound


def parked_robots(t, pos, vel, goal_moved, goal_point, last_wp, tol, speed_tol):
    """Robots parked beside an occupied last goal, and when they arrived there.

    A robot is **parked** when, at some replan k_a, it was at rest (speed <= speed_tol)
    within ``tol`` of the free point its planner chose beside its occupied goal, and its
    goal stayed occupied (the planner planned to a free point) at every replan from k_a
    to the end of the run (so a robot whose goal was freed and that then did not go on
    to it is not parked).

    Args:
        t: (R,) replan times, s.  pos, vel: (R, M, N) measured state at each replan.
        goal_moved: (R, M) bool, the replan planned to a free point.  goal_point: (R, M, N)
        the point it planned to.  last_wp: (R,) bool, the last waypoint was published.
        tol: m.  speed_tol: m/s.
    Returns: (parked (M,) bool, arrival time (M,) s, NaN where not parked).
    """
    t = np.asarray(t, np.float64)
    moved = np.asarray(goal_moved, bool) & np.asarray(last_wp, bool)[:, None]
    R, M = moved.shape
    dist = np.linalg.norm(np.asarray(pos) - np.asarray(goal_point), axis=-1)
    speed = np.linalg.norm(np.asarray(vel), axis=-1)
    at = moved & (dist <= tol) & (speed <= speed_tol)
    # occupied from replan k to the end: a suffix of True values
    occupied_after = np.flip(np.logical_and.accumulate(np.flip(moved, 0), axis=0), 0)
    ok = at & occupied_after
    parked = np.any(ok, axis=0) if R else np.zeros(M, bool)
    first = np.argmax(ok, axis=0) if R else np.zeros(M, int)
    arrival = np.where(parked, t[first] if R else np.nan, np.nan)
    return parked, arrival


def makespan_bound(start, waypoints, v_max, a_max):
    """The straight-line bound on the makespan, s: max over robots of D_i / v_max +
    v_max / a_max, D_i the length of the polyline from its start through its waypoints
    (a robot alone, accelerating to v_max and braking at a_max, needs at least
    D / v_max + v_max / a_max when D >= v_max^2 / a_max).

    Args: start (M, N) m; waypoints (M, W, N) m; v_max, a_max (M,) m/s, m/s^2.
    """
    pts = np.concatenate([np.asarray(start)[:, None], np.asarray(waypoints)], axis=1)
    D = np.sum(np.linalg.norm(np.diff(pts, axis=1), axis=-1), axis=1)
    v, a = np.asarray(v_max, np.float64), np.asarray(a_max, np.float64)
    return float(np.max(D / v + v / a)) if len(D) else math.nan
