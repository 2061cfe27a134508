"""The executed pieces and the exact polynomial machinery on them, shared by every metric
of the package (separation, kinematics, time to goal, clearance).

    check_pieces(seg_robot, seg_t0, seg_t1, seg_coeffs, num_robots)   validated arrays
    to_unit(c, shift, h)          a piece re-expressed in normalised time u in [0, 1]
    unit_roots(g)                 candidate roots in [0, 1] (companion eigenvalues)
    stationary_candidates(p)      the points of [0, 1] holding the extrema of |p(u)|^2
    deriv, horner, dot_conv, bernstein     polynomial helpers (lowest power first)

The piece format is the package's (:mod:`jaxplan.metrics`).  Why normalised time: on an
interval [a, b] re-expressed in u = (t - a) / (b - a) the coefficients handed to the
root finder are well scaled for intervals of 1e-3 s to 1e3 s.  Leading coefficients
below ROOT_RTOL of the largest are dropped (on [0, 1] they change the polynomial by
less than round-off, and the roots they carry lie far outside [0, 1]), which handles
degenerate degrees (equal velocities, constant pieces, zero-length overlaps).  The real
part of EVERY eigenvalue, clipped to [0, 1], is a candidate, so a candidate is always a
point of the interval; a polynomial whose Bernstein coefficients on [0, 1] all share a
sign (by a margin far above round-off) has no root there and skips the eigenvalues.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["ROOT_RTOL", "NEWTON_STEPS", "CHUNK", "check_pieces", "deriv", "horner", "to_unit",
           "bernstein", "dot_conv", "unit_roots", "stationary_candidates"]

ROOT_RTOL = 1e-12  # leading coefficients below this x max|coeff| are treated as zero
NEWTON_STEPS = 2
CHUNK = 16384  # piece pairs per batch (bounds memory: ~ CHUNK x 30 x N x 8 bytes x few)


# ----------------------------------------------------------------------------- inputs


def check_pieces(seg_robot, seg_t0, seg_t1, seg_coeffs, num_robots):
    """The pieces as arrays, checked: (r (S,) int64, t0 (S,), t1 (S,), c (S, N, D+1)
    float64, M, order (S,): the pieces sorted by robot, then start and end time).

    M is ``num_robots`` (default max(seg_robot) + 1).  Raises ValueError for wrong
    shapes, non-integer or negative robot indices, non-finite numbers, seg_t1 < seg_t0,
    or two pieces of one robot that overlap in time (beyond a 1e-9 relative slack)."""
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


def deriv(c):
    """Derivative of polynomials c (..., L) (lowest power first) -> (..., max(L-1, 1))."""
    L = c.shape[-1]
    if L == 1:
        return np.zeros_like(c)
    return c[..., 1:] * np.arange(1, L, dtype=np.float64)


def horner(c, x):
    """Evaluate vector polynomials c (B, N, L) at points x (B, C) -> (B, C, N)."""
    y = np.zeros(x.shape + (c.shape[1],))
    for k in range(c.shape[2] - 1, -1, -1):
        y = y * x[..., None] + c[:, None, :, k]
    return y


def to_unit(c, shift, h):
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


def bernstein(K):
    """(K+1, K+1) matrix B with (monomial coeffs g) @ B = Bernstein coeffs on [0, 1]."""
    if K not in _BERNSTEIN:
        b = np.zeros((K + 1, K + 1))
        for i in range(K + 1):
            for k in range(i + 1):
                b[k, i] = math.comb(i, k) / math.comb(K, k)
        _BERNSTEIN[K] = b
    return _BERNSTEIN[K]


def dot_conv(p, q):
    """sum_n p_n(u) q_n(u) as coefficients: p (B, N, Lp), q (B, N, Lq) -> (B, Lp+Lq-1)."""
    B, _, Lp = p.shape
    Lq = q.shape[2]
    outer = np.einsum("bnm,bnl->bml", p, q)
    g = np.zeros((B, Lp + Lq - 1))
    for m in range(Lp):
        g[:, m : m + Lq] += outer[:, m, :]
    return g


def unit_roots(g):
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
    big = a > ROOT_RTOL * a.max(axis=1, keepdims=True)
    deg = np.where(big.any(axis=1), K - np.argmax(big[:, ::-1], axis=1), 0)
    # Exclusion test: g has no root in [0, 1] when all its Bernstein coefficients on
    # [0, 1] share a sign by a margin far above their round-off (convex-hull property).
    bern = g @ bernstein(K)
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


def stationary_candidates(p, polish=True):
    """Points of [0, 1] among which the extrema of |p(u)|^2 lie, and |p|^2 there.

    p: (B, N, L) vector polynomials in u.  Returns u (B, C): 0, 1, the roots of p . p'
    and (if polish) two successive Newton-polished copies of them all; and
    sq (B, C) = |p(u)|^2 at those points.
    """
    B = p.shape[0]
    dp = deriv(p)
    ddp = deriv(dp)
    roots = unit_roots(dot_conv(p, dp))
    u = np.concatenate([np.zeros((B, 1)), np.ones((B, 1)), roots], axis=1)
    if not polish:
        return u, np.sum(horner(p, u) ** 2, axis=-1)
    us, sqs = [], []
    for it in range(NEWTON_STEPS + 1):
        x = horner(p, u)
        us.append(u)
        sqs.append(np.sum(x * x, axis=-1))
        if it == NEWTON_STEPS:
            break
        dx, ddx = horner(dp, u), horner(ddp, u)
        phi = np.sum(x * dx, axis=-1)
        dphi = np.sum(dx * dx + x * ddx, axis=-1)
        with np.errstate(divide="ignore", invalid="ignore"):
            step = np.where(dphi != 0.0, phi / dphi, 0.0)
        step = np.where(np.isfinite(step), step, 0.0)
        u = np.clip(u - step, 0.0, 1.0)
    return np.concatenate(us, axis=1), np.concatenate(sqs, axis=1)


