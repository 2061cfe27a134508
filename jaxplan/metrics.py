"""Post-run metrics on the host (NumPy): exact continuous-time separation, kinematics,
sampling, time to goal and solver timing (docs/DESIGN.md "A run directory", docs/MATH.md 4).

Everything here works on the executed plan pieces of a run, as stored in
``trajectories.npz``:

    seg_robot  (S,)          int, the robot each piece belongs to, 0 <= r < M
    seg_t0     (S,)          s, piece start time
    seg_t1     (S,)          s, piece end time (>= seg_t0; zero-length pieces allowed)
    seg_coeffs (S, N, D+1)   m, monomial coefficients in (t - seg_t0) seconds,
                             lowest power first; N >= 1 spatial dims, D >= 0 the degree

A robot's pieces must not overlap each other in time (shared end points allowed, with a
1e-9 relative slack); they normally tile its time line without gaps, but gaps are
allowed (nothing is measured in a gap).  Pieces of different robots need not align:
every pair of pieces of two robots whose closed time intervals intersect is compared on
the intersection.

Exactness (docs/MATH.md 4).  On an overlap [a, b] both polynomials are re-expressed in the
common normalised time u = (t - a) / (b - a) in [0, 1], so that the coefficients of
every polynomial handed to the root finder are well scaled for intervals of 1e-3 s to
1e3 s.  The extrema of |p(u)|^2 on [0, 1] lie at u = 0, u = 1 or at a real root of
p . p' (degree 2D - 1).  Roots come from batched companion-matrix eigenvalues (one
``np.linalg.eigvals`` call per effective degree); leading coefficients below 1e-12 of
the largest are dropped (on [0, 1] they change the polynomial by less than round-off,
and the roots they carry lie far outside [0, 1]), which handles degenerate degrees
(equal velocities, constant pieces, zero-length overlaps).  The real part of EVERY
eigenvalue, clipped to [0, 1], is a candidate, and every candidate is polished with two
Newton steps on p . p' (the polished points are added, not substituted).  Since every
candidate is a point of the interval, the reported minimum is always a value the
trajectories really take (never below the true minimum by more than the round-off of
evaluating the polynomials), and since the true minimiser is among the candidates it is
the true minimum up to that round-off.  Two exact shortcuts skip the eigenvalue work
where it cannot matter: a polynomial whose Bernstein coefficients on [0, 1] all share a
sign (by a margin far above round-off) has no root there; and a piece pair whose lower
bound |d(end)| - sum_{m>=1} |d_m| exceeds the smallest end-point distance of its robot
pair cannot hold that pair's minimum.  Distances are finally evaluated from the
ORIGINAL coefficients (Horner in t - seg_t0, as :func:`sample_pieces` does), never from
|d|^2 expanded, so distances near 0 keep full absolute accuracy (~1e-16 x the size of
the coordinates) instead of the sqrt(eps) an expanded square would give.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

__all__ = [
    "pairwise_min_separation",
    "separation_report",
    "Kinematics",
    "kinematics",
    "sample_pieces",
    "time_to_goal",
    "time_to_goal_pieces",
    "solver_summary",
    "parked_robots",
    "makespan_bound",
]

_ROOT_RTOL = 1e-12  # leading coefficients below this x max|coeff| are treated as zero
_NEWTON_STEPS = 2
_CHUNK = 16384  # piece pairs per batch (bounds memory: ~ CHUNK x 30 x N x 8 bytes x few)


# ----------------------------------------------------------------------------- inputs


def _check_pieces(seg_robot, seg_t0, seg_t1, seg_coeffs, num_robots):
    r = np.asarray(seg_robot)
    t0 = np.asarray(seg_t0, dtype=np.float64)
    t1 = np.asarray(seg_t1, dtype=np.float64)
    c = np.asarray(seg_coeffs, dtype=np.float64)
    if r.ndim != 1 or t0.shape != r.shape or t1.shape != r.shape:
        raise ValueError(
            f"seg_robot, seg_t0, seg_t1 must all be (S,); got {r.shape}, {t0.shape}, {t1.shape}"
        )
    if c.ndim != 3 or c.shape[0] != r.shape[0] or c.shape[1] < 1 or c.shape[2] < 1:
        raise ValueError(f"seg_coeffs must be (S, N, D+1) with S={r.shape[0]}; got {c.shape}")
    if r.size and not np.issubdtype(r.dtype, np.integer):
        if not np.all(r == np.round(r)):
            raise ValueError("seg_robot must hold integer robot indices")
    r = r.astype(np.int64)
    if r.size and r.min() < 0:
        raise ValueError("seg_robot must be >= 0")
    m = int(r.max()) + 1 if r.size else 0
    if num_robots is not None:
        if r.size and int(num_robots) < m:
            raise ValueError(f"num_robots={num_robots} but seg_robot holds index {m - 1}")
        m = int(num_robots)
    if not (np.all(np.isfinite(t0)) and np.all(np.isfinite(t1)) and np.all(np.isfinite(c))):
        raise ValueError("seg_t0, seg_t1 and seg_coeffs must be finite")
    if np.any(t1 < t0):
        raise ValueError("every piece needs seg_t1 >= seg_t0")
    # one robot's pieces must not overlap (sorted by robot, then start time)
    order = np.lexsort((t1, t0, r))
    rs, t0s, t1s = r[order], t0[order], t1[order]
    same = rs[1:] == rs[:-1]
    slack = 1e-9 * np.maximum(1.0, np.abs(t1s[:-1]))
    bad = same & (t0s[1:] < t1s[:-1] - slack)
    if np.any(bad):
        k = int(np.nonzero(bad)[0][0])
        raise ValueError(
            f"robot {rs[k]} has overlapping pieces: [{t0s[k]}, {t1s[k]}] and "
            f"[{t0s[k + 1]}, {t1s[k + 1]}]"
        )
    return r, t0, t1, c, m, order


# ------------------------------------------------------------------ polynomial helpers


def _deriv(c):
    """Derivative of polynomials c (..., L) (lowest power first) -> (..., max(L-1, 1))."""
    L = c.shape[-1]
    if L == 1:
        return np.zeros_like(c)
    return c[..., 1:] * np.arange(1, L, dtype=np.float64)


def _horner(c, x):
    """Evaluate vector polynomials c (B, N, L) at points x (B, C) -> (B, C, N)."""
    y = np.zeros(x.shape + (c.shape[1],))
    for k in range(c.shape[2] - 1, -1, -1):
        y = y * x[..., None] + c[:, None, :, k]
    return y


def _to_unit(c, shift, h):
    """Re-express c (B, N, L) in (t - t0) as coefficients in u, t = t0 + shift + h u.

    shift, h: (B,) (h may be 0 or negative).  Taylor shift by repeated synthetic
    division (q_m = sum_k C(k, m) shift^(k-m) c_k), then q_m *= h^m.
    """
    L = c.shape[2]
    q = np.array(c, dtype=np.float64, copy=True)
    s = shift[:, None]
    for i in range(L - 1):
        for j in range(L - 2, i - 1, -1):
            q[:, :, j] += s * q[:, :, j + 1]
    return q * (h[:, None] ** np.arange(L))[:, None, :]


_BERNSTEIN: dict[int, np.ndarray] = {}


def _bernstein(K):
    """(K+1, K+1) matrix B with (monomial coeffs g) @ B = Bernstein coeffs on [0, 1]."""
    if K not in _BERNSTEIN:
        b = np.zeros((K + 1, K + 1))
        for i in range(K + 1):
            for k in range(i + 1):
                b[k, i] = math.comb(i, k) / math.comb(K, k)
        _BERNSTEIN[K] = b
    return _BERNSTEIN[K]


def _dot_conv(p, q):
    """sum_n p_n(u) q_n(u) as coefficients: p (B, N, Lp), q (B, N, Lq) -> (B, Lp+Lq-1)."""
    B, _, Lp = p.shape
    Lq = q.shape[2]
    outer = np.einsum("bnm,bnl->bml", p, q)
    g = np.zeros((B, Lp + Lq - 1))
    for m in range(Lp):
        g[:, m : m + Lq] += outer[:, m, :]
    return g


def _unit_roots(g):
    """Candidate roots in [0, 1] of scalar polynomials g (B, K+1) -> (B, K).

    Real parts of all companion-matrix eigenvalues, clipped to [0, 1]; rows of lower
    effective degree are padded with 0.  Leading coefficients with |g_k| <= 1e-12 max|g|
    are dropped (degenerate degree); an all-zero row has no roots.
    """
    B, L = g.shape
    K = L - 1
    out = np.zeros((B, max(K, 0)))
    if K < 1 or B == 0:
        return out
    a = np.abs(g)
    big = a > _ROOT_RTOL * a.max(axis=1, keepdims=True)
    deg = np.where(big.any(axis=1), K - np.argmax(big[:, ::-1], axis=1), 0)
    # Exclusion test: g has no root in [0, 1] when all its Bernstein coefficients on
    # [0, 1] share a sign by a margin far above their round-off (convex-hull property).
    bern = g @ _bernstein(K)
    margin = 1e-11 * a.sum(axis=1, keepdims=True)
    deg = np.where(np.all(bern > margin, axis=1) | np.all(bern < -margin, axis=1), 0, deg)
    for k in range(1, K + 1):
        rows = np.nonzero(deg == k)[0]
        if rows.size == 0:
            continue
        monic = g[rows, :k] / g[rows, k : k + 1]
        if k == 1:
            r = -monic
        else:
            comp = np.zeros((rows.size, k, k))
            comp[:, np.arange(1, k), np.arange(k - 1)] = 1.0
            comp[:, :, -1] = -monic
            r = np.linalg.eigvals(comp)
        out[rows, :k] = np.clip(r.real, 0.0, 1.0)
    return out


def _stationary_candidates(p, polish=True):
    """Points of [0, 1] among which the extrema of |p(u)|^2 lie, and |p|^2 there.

    p: (B, N, L) vector polynomials in u.  Returns u (B, C): 0, 1, the roots of p . p'
    and (if polish) two successive Newton-polished copies of them all; and
    sq (B, C) = |p(u)|^2 at those points.
    """
    B = p.shape[0]
    dp = _deriv(p)
    ddp = _deriv(dp)
    roots = _unit_roots(_dot_conv(p, dp))
    u = np.concatenate([np.zeros((B, 1)), np.ones((B, 1)), roots], axis=1)
    if not polish:
        return u, np.sum(_horner(p, u) ** 2, axis=-1)
    us, sqs = [], []
    for it in range(_NEWTON_STEPS + 1):
        x = _horner(p, u)
        us.append(u)
        sqs.append(np.sum(x * x, axis=-1))
        if it == _NEWTON_STEPS:
            break
        dx, ddx = _horner(dp, u), _horner(ddp, u)
        phi = np.sum(x * dx, axis=-1)
        dphi = np.sum(dx * dx + x * ddx, axis=-1)
        with np.errstate(divide="ignore", invalid="ignore"):
            step = np.where(dphi != 0.0, phi / dphi, 0.0)
        step = np.where(np.isfinite(step), step, 0.0)
        u = np.clip(u - step, 0.0, 1.0)
    return np.concatenate(us, axis=1), np.concatenate(sqs, axis=1)


# ------------------------------------------------------------------- piece-pair overlaps


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


# ------------------------------------------------------------------------ 1. separation


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
    Typical: 10 robots x 240 pieces (30 s at 8 Hz, misaligned clocks) ~0.06 s on one
    CPU core; ~0.45 s when nothing can be pruned (all robots within 2 cm for 30 s).
    """
    r, t0, t1, c, m, order = _check_pieces(seg_robot, seg_t0, seg_t1, seg_coeffs, num_robots)
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
    for s in range(0, P.size, _CHUNK):
        p, q = P[s : s + _CHUNK], Q[s : s + _CHUNK]
        a = np.maximum(t0[p], t0[q])
        h = np.minimum(t1[p], t1[q]) - a
        d0 = _to_unit(c[p], a - t0[p], h) - _to_unit(c[q], a - t0[q], h)
        d1 = _to_unit(c[p], a + h - t0[p], -h) - _to_unit(c[q], a + h - t0[q], -h)
        n0 = np.linalg.norm(d0, axis=1)  # (B, L): |d_m| about u = 0
        n1 = np.linalg.norm(d1, axis=1)  # about the other end
        lb[s : s + _CHUNK] = np.maximum(
            n0[:, 0] - n0[:, 1:].sum(axis=1), n1[:, 0] - n1[:, 1:].sum(axis=1)
        )
        ub_row[s : s + _CHUNK] = np.minimum(n0[:, 0], n1[:, 0])
        scale[s : s + _CHUNK] = n0.sum(axis=1) + n1.sum(axis=1)
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
    for s in range(0, P.size, _CHUNK):
        p, q = P[s : s + _CHUNK], Q[s : s + _CHUNK]
        a = np.maximum(t0[p], t0[q])
        b = np.minimum(t1[p], t1[q])
        h = b - a
        d = _to_unit(c[p], a - t0[p], h) - _to_unit(c[q], a - t0[q], h)
        u, sq = _stationary_candidates(d)
        rows = np.arange(p.size)
        k = np.argmin(sq, axis=1)
        # the final distance from the ORIGINAL coefficients, at the best candidate
        t = np.minimum(a + u[rows, k] * h, b)[:, None]
        xp = _horner(c[p], t - t0[p][:, None])[:, 0]
        xq = _horner(c[q], t - t0[q][:, None])[:, 0]
        best_d[s : s + _CHUNK] = np.sqrt(np.sum((xp - xq) ** 2, axis=-1))
        best_t[s : s + _CHUNK] = t[:, 0]
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


# ------------------------------------------------------------------------ 3. kinematics


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
        seg_robot, seg_t0, seg_t1, seg_coeffs: the pieces (module docstring; seconds, m).
        num_robots: M (default max(seg_robot) + 1).
        quad_nodes: Gauss-Legendre nodes per sub-interval for the path length.

    Returns:
        :class:`Kinematics` of (M,) arrays.

    Maxima are exact (up to round-off): the maximum of |x^(k)|^2 on a piece is at an end
    or at a root of x^(k) . x^(k+1), found as for the separation.

    Path length accuracy: each piece is first cut at the stationary points of |v|^2
    (roots of v . a: the speed's local minima, in particular every point where the
    robot stops and |v| has a kink), so |v| is smooth on every sub-interval, with at
    worst a one-sided linear zero at an end; Gauss-Legendre with quad_nodes (32) nodes
    per sub-interval then integrates it.  Measured (quintics, vs a 3000-node reference):
    exact up to round-off for constant velocity and for exact stops; relative error
    <= 2e-10 on random quintic pieces; near-stops (speed minimum eps x the speed scale)
    are the hard case, |v| = sqrt(eps^2 + s^2 (t - t*)^2) with the minimum at a cut:
    error peaks at ~1.3e-7 x (piece length) for eps ~ 1e-3 (16 nodes: ~2e-6), falling
    off on both sides.  Cost: S x 2(D-1) x quad_nodes evaluations of v.
    """
    r, t0, t1, c, m, _ = _check_pieces(seg_robot, seg_t0, seg_t1, seg_coeffs, num_robots)
    nan = np.full(m, np.nan)
    if r.size == 0:
        return Kinematics(nan.copy(), nan.copy(), nan.copy(), nan.copy())
    h = t1 - t0
    zero = np.zeros_like(h)
    maxima = []
    deriv = c
    vel_u = None
    for k in (1, 2, 3):
        deriv = _deriv(deriv)
        q = _to_unit(deriv, zero, h)
        if k == 1:
            vel_u = q
        _, sq = _stationary_candidates(q)
        val = np.sqrt(np.max(sq, axis=1))
        out = np.full(m, -np.inf)
        np.maximum.at(out, r, val)
        maxima.append(np.where(np.isneginf(out), np.nan, out))
    # path length: cut at the stationary points of |v|^2, then Gauss-Legendre
    brk = np.sort(_stationary_candidates(vel_u, polish=False)[0], axis=1)  # (S, C)
    xg, wg = _gauss_legendre(int(quad_nodes))
    lo, hi = brk[:, :-1], brk[:, 1:]  # (S, C-1)
    nodes = lo[..., None] + (hi - lo)[..., None] * xg  # (S, C-1, G)
    S = r.size
    speed = np.linalg.norm(_horner(vel_u, nodes.reshape(S, -1)), axis=-1).reshape(nodes.shape)
    length = h * np.sum((hi - lo) * np.sum(speed * wg, axis=-1), axis=1)
    plen = np.zeros(m)
    np.add.at(plen, r, length)
    has = np.zeros(m, dtype=bool)
    has[r] = True
    return Kinematics(maxima[0], maxima[1], maxima[2], np.where(has, plen, np.nan))


# -------------------------------------------------------------------------- 4. sampling


def sample_pieces(seg_robot, seg_t0, seg_t1, seg_coeffs, t, num_robots=None, outside="nan"):
    """Evaluate the pieces of every robot at the times t.

    Args:
        seg_robot, seg_t0, seg_t1, seg_coeffs: the pieces (module docstring).
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
    r, t0, t1, c, m, order = _check_pieces(seg_robot, seg_t0, seg_t1, seg_coeffs, num_robots)
    t = np.asarray(t, dtype=np.float64)
    if t.ndim != 1:
        raise ValueError(f"t must be (K,); got {t.shape}")
    n = c.shape[1]
    out = np.full((3, m, t.size, n), np.nan)
    rs = r[order]
    starts = np.searchsorted(rs, np.arange(m + 1))
    cv = _deriv(c)
    ca = _deriv(cv)
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
            val = _horner(cc[seg], tau)[:, 0, :]
            if outside == "nan":
                val = np.where(inside[:, None], val, np.nan)
            out[j, i] = val
    return out[0], out[1], out[2]


# ------------------------------------------------------------------------ 5. time to goal


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
        seg_robot, seg_t0, seg_t1, seg_coeffs: the pieces (module docstring).
        goal: (M, N) m.
        tol: m, position tolerance.
        speed_tol: m/s, optional; "within" then also needs |v| <= speed_tol.
        num_robots: M (default goal.shape[0]).

    Returns:
        (M,) s: the infimum of the times T such that the robot is within on [T, end of
        its last piece]; the start of its first piece if it is always within; NaN if it
        is not within at the end of its last piece, or has no pieces.

    Method: each piece is cut at the real roots in [0, 1] of |x - g|^2 - tol^2 (and of
    |v|^2 - speed_tol^2), found as for the separation; the condition is constant on each
    cut and is evaluated at its midpoint.  Gaps between pieces are ignored.
    """
    goal = np.asarray(goal, dtype=np.float64)
    if num_robots is None:
        num_robots = goal.shape[0]
    r, t0, t1, c, m, _ = _check_pieces(seg_robot, seg_t0, seg_t1, seg_coeffs, num_robots)
    if goal.shape != (m, c.shape[1]):
        raise ValueError(f"goal must be (M, N) = ({m}, {c.shape[1]}); got {goal.shape}")
    res = np.full(m, np.nan)
    if r.size == 0:
        return res
    h = t1 - t0
    zero = np.zeros_like(h)
    e = c.copy()
    e[:, :, 0] -= goal[r]
    eu = _to_unit(e, zero, h)
    g1 = _dot_conv(eu, eu)
    g1[:, 0] -= tol**2
    cuts = [_unit_roots(g1)]
    vu = None
    if speed_tol is not None:
        vu = _to_unit(_deriv(c), zero, h)
        g2 = _dot_conv(vu, vu)
        g2[:, 0] -= speed_tol**2
        cuts.append(_unit_roots(g2))
    S = r.size
    u = np.sort(np.concatenate([np.zeros((S, 1)), np.ones((S, 1))] + cuts, axis=1), axis=1)
    mid = 0.5 * (u[:, :-1] + u[:, 1:])
    ok = np.linalg.norm(_horner(eu, mid), axis=-1) <= tol
    if vu is not None:
        ok &= np.linalg.norm(_horner(vu, mid), axis=-1) <= speed_tol
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


# --------------------------------------------------------------------- 6. solver timing


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


# ------------------------------------------------- 6. occupied goals, the makespan bound


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
