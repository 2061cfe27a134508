"""Exact continuous-time separation of every robot pair (docs/MATH.md 4).

    pairwise_min_separation(seg_robot, seg_t0, seg_t1, seg_coeffs) -> (min_dist, t_min)
    separation_report(min_dist, radius) -> dict         the metrics.json keys

The pieces are the package's (:mod:`jaxplan.metrics`).  Pieces of different robots need
not align: every pair of pieces of two robots whose closed time intervals intersect is
compared on the intersection.

Exactness.  On an overlap [a, b] both polynomials are re-expressed in the common
normalised time u = (t - a) / (b - a) in [0, 1] (:mod:`jaxplan.metrics.pieces`).  The
extrema of |p(u)|^2 on [0, 1] lie at u = 0, u = 1 or at a real root of p . p' (degree
2D - 1).  Roots come from batched companion-matrix eigenvalues (one
``np.linalg.eigvals`` call per effective degree); every candidate is polished with two
Newton steps on p . p' (the polished points are added, not substituted).  Since every
candidate is a point of the interval, the reported minimum is always a value the
trajectories really take (never below the true minimum by more than the round-off of
evaluating the polynomials), and since the true minimiser is among the candidates it is
the true minimum up to that round-off.  Two exact shortcuts skip the eigenvalue work
where it cannot matter: the Bernstein exclusion test of
:func:`jaxplan.metrics.pieces.unit_roots`; and a piece pair whose lower bound
|d(end)| - sum_{m>=1} |d_m| exceeds the smallest end-point distance of its robot pair
cannot hold that pair's minimum.  Distances are finally evaluated from the ORIGINAL
coefficients (Horner in t - seg_t0, as :func:`jaxplan.metrics.sample_pieces` does),
never from |d|^2 expanded, so distances near 0 keep full absolute accuracy (~1e-16 x the
size of the coordinates) instead of the sqrt(eps) an expanded square would give.  Cost:
docs/SOLVER.md, "Metrics".
"""

from __future__ import annotations

import math

import numpy as np

from jaxplan.metrics.pieces import CHUNK, check_pieces, horner, stationary_candidates, to_unit

__all__ = ["pairwise_min_separation", "separation_report"]

# ------------------------------------------------------------------ piece-pair overlaps


def _overlapping_pairs(r, t0, t1, m, order):
    """All (p, q) piece index pairs with r[p] < r[q] whose closed intervals intersect."""
    rs, t0s, t1s = r[order], t0[order], t1[order]
    starts = np.searchsorted(rs, np.arange(m + 1), side="left")
    ps, qs = [], []
    for j in range(1, m):  # loop over robots (not pieces): partner j, pieces of robots < j
        lo_j, hi_j, n_i = starts[j], starts[j + 1], starts[j]
        if hi_j == lo_j or n_i == 0:
            continue
        t0j = t0s[lo_j:hi_j]
        t1j = np.maximum.accumulate(t1s[lo_j:hi_j])
        lo = np.searchsorted(t1j, t0s[:n_i], side="left")  # first j piece with t1 >= t0_p
        hi = np.searchsorted(t0j, t1s[:n_i], side="right")  # j pieces with t0 <= t1_p
        cnt = np.maximum(hi - lo, 0)
        tot = int(cnt.sum())
        if tot == 0:
            continue
        p = np.repeat(np.arange(n_i), cnt)
        first = np.repeat(np.cumsum(cnt) - cnt, cnt)
        q = lo_j + np.repeat(lo, cnt) + (np.arange(tot) - first)
        ps.append(p)
        qs.append(q)
    if not ps:
        e = np.zeros(0, dtype=np.int64)
        return e, e
    p = np.concatenate(ps)
    q = np.concatenate(qs)
    keep = np.maximum(t0s[p], t0s[q]) <= np.minimum(t1s[p], t1s[q])
    return order[p[keep]], order[q[keep]]


# ------------------------------------------------------------------------ separation


def pairwise_min_separation(seg_robot, seg_t0, seg_t1, seg_coeffs, num_robots=None):
    """Exact minimum distance between every pair of robots over their common time span.

    Args:
        seg_robot: (S,) int robot index of each piece.
        seg_t0, seg_t1: (S,) s, piece start / end times.
        seg_coeffs: (S, N, D+1) m, monomial coefficients in (t - seg_t0), lowest first.
        num_robots: M (default: max(seg_robot) + 1); robots without pieces get inf / NaN.

    Returns:
        min_dist: (M, M) m, symmetric; min_t |x_i(t) - x_j(t)| over the times where both
            robots have a piece (closed intervals); inf on the diagonal and for pairs
            that never overlap in time.
        t_min: (M, M) s, a time at which that minimum is attained (NaN where min_dist is
            inf).  When the minimum is attained on a whole interval (parallel motion) it
            is one of the attaining candidate times.

    Method: docs/MATH.md 4, see the module docstring; cost at most one (2D-1) x (2D-1)
    eigenvalue problem per overlapping piece pair (batched), usually far fewer.
    """
    r, t0, t1, c, m, order = check_pieces(seg_robot, seg_t0, seg_t1, seg_coeffs, num_robots)
    min_dist = np.full((m, m), np.inf)
    t_min = np.full((m, m), np.nan)
    P, Q = _overlapping_pairs(r, t0, t1, m, order)
    if P.size == 0:
        return min_dist, t_min
    pair = r[P] * m + r[Q]
    live = _prune(t0, t1, c, P, Q, pair, m)
    P, Q, pair = P[live], Q[live], pair[live]
    best_d, best_t = _piece_pair_minima(t0, t1, c, P, Q)
    flat = np.full(m * m, np.inf)
    np.minimum.at(flat, pair, best_d)
    hit = best_d == flat[pair]
    tflat = np.full(m * m, np.nan)
    tflat[pair[hit]] = best_t[hit]
    min_dist = np.minimum(flat.reshape(m, m), flat.reshape(m, m).T)
    tt = tflat.reshape(m, m)
    t_min = np.where(np.isnan(tt), tt.T, tt)
    np.fill_diagonal(min_dist, np.inf)
    np.fill_diagonal(t_min, np.nan)
    return min_dist, t_min


def _prune(t0, t1, c, P, Q, pair, m):
    """Indices of the piece pairs (P, Q) that can hold their robot pair's minimum.

    Exact pruning: an upper bound per robot pair (the smallest end-point distance of its
    piece pairs) and a lower bound per piece pair (|d(end)| - sum_m>=1 |d_m| in the
    normalised time of that end); piece pairs whose lower bound exceeds their robot
    pair's upper bound cannot hold the minimum and skip the root finding.
    """
    lb = np.empty(P.size)
    ub_row = np.empty(P.size)
    scale = np.empty(P.size)
    for s in range(0, P.size, CHUNK):
        p, q = P[s : s + CHUNK], Q[s : s + CHUNK]
        a = np.maximum(t0[p], t0[q])
        h = np.minimum(t1[p], t1[q]) - a
        d0 = to_unit(c[p], a - t0[p], h) - to_unit(c[q], a - t0[q], h)
        d1 = to_unit(c[p], a + h - t0[p], -h) - to_unit(c[q], a + h - t0[q], -h)
        n0 = np.linalg.norm(d0, axis=1)  # (B, L): |d_m| about u = 0
        n1 = np.linalg.norm(d1, axis=1)  # about the other end
        lb[s : s + CHUNK] = np.maximum(
            n0[:, 0] - n0[:, 1:].sum(axis=1), n1[:, 0] - n1[:, 1:].sum(axis=1)
        )
        ub_row[s : s + CHUNK] = np.minimum(n0[:, 0], n1[:, 0])
        scale[s : s + CHUNK] = n0.sum(axis=1) + n1.sum(axis=1)
    ub = np.full(m * m, np.inf)
    np.minimum.at(ub, pair, ub_row)
    slack = 1e-9 * (1.0 + scale + ub[pair])  # far above the round-off of lb and ub
    return np.nonzero(lb <= ub[pair] + slack)[0]


def _piece_pair_minima(t0, t1, c, P, Q):
    """(distance (B,) m, time (B,) s) of the exact minimum of each piece pair (P, Q) over
    its overlap: the best stationary candidate, its distance from the original
    coefficients."""
    best_d = np.empty(P.size)
    best_t = np.empty(P.size)
    for s in range(0, P.size, CHUNK):
        p, q = P[s : s + CHUNK], Q[s : s + CHUNK]
        a = np.maximum(t0[p], t0[q])
        b = np.minimum(t1[p], t1[q])
        h = b - a
        d = to_unit(c[p], a - t0[p], h) - to_unit(c[q], a - t0[q], h)
        u, sq = stationary_candidates(d)
        rows = np.arange(p.size)
        k = np.argmin(sq, axis=1)
        # the final distance from the ORIGINAL coefficients, at the best candidate
        t = np.minimum(a + u[rows, k] * h, b)[:, None]
        xp = horner(c[p], t - t0[p][:, None])[:, 0]
        xq = horner(c[q], t - t0[q][:, None])[:, 0]
        best_d[s : s + CHUNK] = np.sqrt(np.sum((xp - xq) ** 2, axis=-1))
        best_t[s : s + CHUNK] = t[:, 0]
    return best_d, best_t



def separation_report(min_dist, radius, rtol=0.0):
    """Collision count and worst separation ratio from a pairwise minimum-distance matrix.

    Args:
        min_dist: (M, M) m, from :func:`pairwise_min_separation` (only i < j is read).
        radius: (M,) m, collision radius of each robot; rho_ij = r_i + r_j.
        rtol: a pair collides when d_ij < rho_ij (1 - rtol); default 0 (strict, so a
            pair touching exactly at rho_ij is not a collision).

    Returns:
        dict with
            collisions (int): number of pairs with d_ij < rho_ij (1 - rtol);
            min_separation_ratio (float): min over pairs of d_ij / rho_ij (inf when no
                pair of robots ever overlaps in time, e.g. a single robot);
            worst_pair (tuple[int, int] | None): the (i, j), i < j, attaining it;
            worst_distance_m (float): d_ij of that pair (inf if none).
    """
    d = np.asarray(min_dist, dtype=np.float64)
    rad = np.asarray(radius, dtype=np.float64)
    m = d.shape[0]
    if d.shape != (m, m) or rad.shape != (m,):
        raise ValueError(f"min_dist must be (M, M) and radius (M,); got {d.shape}, {rad.shape}")
    i, j = np.triu_indices(m, k=1)
    dij = d[i, j]
    rho = rad[i] + rad[j]
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(np.isfinite(dij), dij / rho, np.inf)
    collisions = int(np.sum(np.isfinite(dij) & (dij < rho * (1.0 - rtol))))
    if ratio.size == 0 or not np.any(np.isfinite(ratio)):
        return dict(
            collisions=collisions,
            min_separation_ratio=math.inf,
            worst_pair=None,
            worst_distance_m=math.inf,
        )
    k = int(np.argmin(ratio))
    return dict(
        collisions=collisions,
        min_separation_ratio=float(ratio[k]),
        worst_pair=(int(i[k]), int(j[k])),
        worst_distance_m=float(dij[k]),
    )


