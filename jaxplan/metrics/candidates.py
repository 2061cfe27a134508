"""The candidate times of the exact clearance of a polynomial piece to a box or a
vertical cylinder (:mod:`jaxplan.metrics.clearance`, whose docstring gives the method):
the roots of the polynomials whose zeros hold every minimiser, each polished by Newton
steps, grouped per piece (host, NumPy)."""

from __future__ import annotations

import numpy as np

from jaxplan.metrics.pieces import NEWTON_STEPS, deriv, dot_conv, horner, unit_roots

__all__ = ["box_candidates", "cylinder_candidates", "roots", "compact"]


# ---------------------------------------------------------------------- roots


def _hv(g, u):
    """Scalar polynomials g (B, L) at u (B, C) -> (B, C)."""
    return horner(g[:, None, :], u)[..., 0]


def _mul(a, b):
    """Products of scalar polynomials a (B, La), b (B, Lb) -> (B, La+Lb-1)."""
    return dot_conv(a[:, None, :], b[:, None, :])


def _add(a, b):
    """Sums of scalar polynomials of any lengths (B, La) + (B, Lb)."""
    L = max(a.shape[1], b.shape[1])
    out = np.zeros((a.shape[0], L))
    out[:, : a.shape[1]] += a
    out[:, : b.shape[1]] += b
    return out


def roots(g):
    """Candidate roots in [0, 1] of scalar polynomials g (B, L): every (clipped) real part
    of a companion eigenvalue (:func:`jaxplan.metrics.pieces.unit_roots`) and its copies
    after one and two Newton steps on g -> (B, (L-1) x 3)."""
    u = unit_roots(g)
    if u.shape[1] == 0:
        return u
    dg = deriv(g)
    out = [u]
    for _ in range(NEWTON_STEPS):
        f, df = _hv(g, u), _hv(dg, u)
        with np.errstate(divide="ignore", invalid="ignore"):
            step = np.where(df != 0.0, f / df, 0.0)
        u = np.clip(u - np.where(np.isfinite(step), step, 0.0), 0.0, 1.0)
        out.append(u)
    return np.concatenate(out, axis=1)


def _cuts(u):
    """Sorted cut points (with 0 and 1) of candidate roots u (B, C) -> sub-interval
    midpoints (B, C+1) and which are non-empty (B, C+1)."""
    B = u.shape[0]
    br = np.sort(np.concatenate([np.zeros((B, 1)), u, np.ones((B, 1))], axis=1), axis=1)
    return 0.5 * (br[:, :-1] + br[:, 1:]), br[:, 1:] > br[:, :-1]


def compact(u):
    """The distinct candidates of each row of u (B, C), padded with repeats -> (B, C')."""
    if u.shape[1] < 2:
        return u
    u = np.sort(u, axis=1)
    dup = np.zeros(u.shape, bool)
    dup[:, 1:] = u[:, 1:] == u[:, :-1]
    W = int((~dup).sum(axis=1).max())
    return np.take_along_axis(u, np.argsort(dup, axis=1, kind="stable")[:, :W], axis=1)


def _group_roots(row, key, make):
    """Candidate roots per (row, key) group: ``make(rows, keys)`` -> polynomials (G, L)
    for the distinct groups; returns (rows (G,), roots (G, C))."""
    code = np.unique(np.stack([row, key], axis=1), axis=0)
    if code.shape[0] == 0:
        return code[:, 0], np.zeros((0, 0))
    return code[:, 0], roots(make(code[:, 0], code[:, 1]))


def _scatter(B, rows, roots, parts):
    """Append per-row candidates from (rows (G,), roots (G, C)) groups to ``parts`` as a
    (B, C x max-multiplicity) array padded with 0 (0 is a candidate anyway)."""
    if rows.size == 0 or roots.shape[1] == 0:
        return
    order = np.argsort(rows, kind="stable")
    rows, roots = rows[order], roots[order]
    first = np.searchsorted(rows, rows, side="left")
    slot = np.arange(rows.size) - first
    W = int(slot.max()) + 1
    out = np.zeros((B, W, roots.shape[1]))
    out[rows, slot] = roots
    parts.append(out.reshape(B, -1))


# ---------------------------------------------------------------------- candidates


def box_candidates(d, h):
    """Candidate u (B, C) of the minimum of the box distance; d (B, N, L) the piece
    minus the centre in u, h (B, N) half extents (module doc)."""
    B, N, L = d.shape
    zero_one = [np.zeros((B, 1)), np.ones((B, 1))]
    planes = np.concatenate([d, d], axis=1)
    planes[:, :N, 0] -= h
    planes[:, N:, 0] += h
    cut = roots(planes.reshape(B * 2 * N, L)).reshape(B, -1)
    dd = deriv(d)
    stat = roots(dd.reshape(B * N, -1)).reshape(B, -1)
    parts = zero_one + [cut, stat]
    mid, live = _cuts(cut)
    x = horner(d, mid)  # (B, J, N)
    side = np.where(x > h[:, None, :], 1, np.where(x < -h[:, None, :], -1, 0))  # (B, J, N)
    code = np.sum((side + 1) * 3 ** np.arange(N), axis=-1)  # (B, J)
    inside_code = int(np.sum(3 ** np.arange(N)))
    rows = np.broadcast_to(np.arange(B)[:, None], code.shape)
    out_sel = live & (code != inside_code)

    def outside_poly(r, cd):
        s = (cd[:, None] // 3 ** np.arange(N)) % 3 - 1  # (G, N)
        e = d[r].copy()
        e[:, :, 0] -= s * h[r]
        e = np.where(s[:, :, None] != 0, e, 0.0)
        return dot_conv(e, dd[r])

    _scatter(B, *_group_roots(rows[out_sel], code[out_sel], outside_poly), parts)
    ins = np.nonzero(np.any(live & (code == inside_code), axis=1))[0]
    if ins.size:
        di, hi = d[ins], h[ins]
        polys = [di[:, i] for i in range(N)]  # kinks of |d_i|
        for i in range(N):
            for j in range(i + 1, N):
                for si in (1.0, -1.0):
                    for sj in (1.0, -1.0):
                        g = si * di[:, i] - sj * di[:, j]
                        g[:, 0] += hi[:, j] - hi[:, i]
                        polys.append(g)
        r = roots(np.concatenate(polys, axis=0)).reshape(len(polys), ins.size, -1)
        _scatter(B, np.repeat(ins, len(polys)), r.transpose(1, 0, 2).reshape(-1, r.shape[2]),
                 parts)
    return np.concatenate(parts, axis=1)


def cylinder_candidates(d, R, H):
    """Candidate u (B, C) of the minimum of the 3-D cylinder distance; d (B, 3, L) the
    piece minus the centre in u, R (B,) radius, H (B,) half height (module doc)."""
    B = d.shape[0]
    P = dot_conv(d[:, :2], d[:, :2])  # (B, 2L-1): rho^2
    Pd = deriv(P)
    z = d[:, 2]
    zd = deriv(z)
    ring = P.copy()
    ring[:, 0] -= R**2
    top, bot = z.copy(), z.copy()
    top[:, 0] -= H
    bot[:, 0] += H
    cut = np.concatenate([roots(ring), roots(top), roots(bot)], axis=1)
    parts = [np.zeros((B, 1)), np.ones((B, 1)), cut, roots(Pd), roots(zd), roots(z)]
    mid, live = _cuts(cut)
    rho2 = _hv(P, mid)
    zm = _hv(z, mid)
    out = rho2 > (R**2)[:, None]
    s = np.where(zm > H[:, None], 1, np.where(zm < -H[:, None], -1, 0))
    rows = np.broadcast_to(np.arange(B)[:, None], mid.shape)

    def w_of(r, sg):
        w = sg[:, None] * z[r]
        w[:, 0] -= H[r]
        return w

    def cross_poly(r, sg):  # inside: P - (s dz - H + R)^2
        w = w_of(r, sg)
        w[:, 0] += R[r]
        return _add(P[r], -_mul(w, w))

    def rim_poly(r, sg):  # rim: P (P' + 2 w w')^2 - R^2 P'^2
        w = w_of(r, sg)
        a = _add(Pd[r], 2.0 * _mul(w, deriv(w)))
        return _add(_mul(P[r], _mul(a, a)), -(R[r] ** 2)[:, None] * _mul(Pd[r], Pd[r]))

    ins = live & ~out & (s == 0)
    sgn = np.broadcast_to(np.array([1, -1])[None, :, None], (B, 2, mid.shape[1]))
    ins2 = np.broadcast_to(ins[:, None, :], sgn.shape)
    rows2 = np.broadcast_to(np.arange(B)[:, None, None], sgn.shape)
    _scatter(B, *_group_roots(rows2[ins2], sgn[ins2], cross_poly), parts)
    rim = live & out & (s != 0)
    _scatter(B, *_group_roots(rows[rim], s[rim], rim_poly), parts)
    return np.concatenate(parts, axis=1)
