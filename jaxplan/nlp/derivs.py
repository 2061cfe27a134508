"""The augmented Lagrangian's value, gradient and Hessian by structured derivatives
(the "Derivatives" part of :mod:`jaxplan.nlp`'s doc): what the solver evaluates at each
step.

:func:`merit_derivs` gives (value, gradient, Hessian[, constraints]) at one point;
:func:`merit_shapes` the values at several shapes of one horizon; :func:`prepare_others`
lays out the other robots' predictions once per solve and :func:`others_jet` evaluates
their derivatives.  Checked against jax.hessian of :func:`jaxplan.nlp.terms.merit` in
tests/test_costs.py.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.nlp.basis import basis, boundary_vector, falling, pack, unpack
from jaxplan.nlp.terms import (
    al_term,
    coast_time,
    collision_rows,
    has_sampled_collision,
    limit_priority,
    needs_col_features,
    paper_collision,
    sexp,
    static_allowance,
    static_local,
    static_scale,
)
from jaxplan.nlp.types import DIST_EPS2, Multipliers
from jaxplan.pytree import sum_all
from jaxplan.trajectory import Trajectory
from jaxplan.world import path_at, signed_distance_jet

_E_POW = np.array([0, 1, 2, 0, 1, 2])  # the power of h in each row of boundary_vector


def _smooth_time_derivs(x, params, structure, kind):
    """(value, gradient, Hessian) of :func:`jaxplan.nlp.terms.smooth_time` in closed form: with
    h = T / S and e(h) = E diag(h^k) (boundary_vector), the jerk integral is
    sum_ij W_ij h^(k_i + k_j - 5) + h^-5 sum q z^2, W = M * (E E^T); each power of h has
    tau derivatives m h^m and m^2 h^m."""
    z, tau = unpack(x, structure)
    T = jnp.exp(tau)
    h = T / structure.segments
    E = jnp.stack([params.p0, params.v0, params.a0, params.goal_p, params.goal_v,
                   params.goal_a])  # (6, N)
    m = jnp.asarray(_E_POW[:, None] + _E_POW[None, :] - 5, jnp.float64)
    hm = jnp.exp(m * jnp.log(h))
    W = kind.M * (E @ E.T) * hm
    h5 = jnp.exp(-5.0 * jnp.log(h))
    qz = kind.q[None, :] * z  # (N, nz)
    Qz = jnp.sum(qz * z) * h5
    wd, kt = params.weights.q_dynm, params.weights.k_t
    v = wd * (jnp.sum(W) + Qz) + kt * T
    g = jnp.concatenate([jnp.ravel(2.0 * wd * h5 * qz),
                         (wd * (jnp.sum(W * m) - 5.0 * Qz) + kt * T)[None]])
    dz = jnp.ravel(jnp.broadcast_to(2.0 * wd * h5 * kind.q[None, :], z.shape))
    htt = wd * (jnp.sum(W * m * m) + 25.0 * Qz) + kt * T
    H = jnp.diag(jnp.concatenate([dz, htt[None]]))
    hzt = jnp.ravel(-10.0 * wd * h5 * qz)
    H = H.at[:-1, -1].set(hzt).at[-1, :-1].set(hzt)
    return v, g, H


# ---------------------------------------------------------------------- derivatives
def _value_grad_hessian(f, y, *args):
    def g_aux(yy):
        v, g = jax.value_and_grad(f)(yy, *args)
        return g, (v, g)

    H, (v, g) = jax.jacfwd(g_aux, has_aux=True)(y)
    return v, g, H


def _elementwise_derivs(fn, x):
    """Elementwise value, first and second derivative of an elementwise function (autodiff)."""
    one = jnp.ones_like(x)
    (v, d1), (_, d2) = jax.jvp(lambda y: jax.jvp(fn, (y,), (one,)), (x,), (one,))
    return v, d1, d2


# ---------------------------------------------------------------------- structured derivatives
class OthersPrep(NamedTuple):
    """The other robots' predictions in the layout the derivatives read, formed once per
    solve (:func:`prepare_others`): coefficients of their derivatives 0..2 in seconds,
    components first and the other robots before the sample axis, non-finite or masked
    ones zeroed."""

    c: tuple  # r = 0, 1, 2: (N, So, Mo, Kd - r) d^r/dt^r coefficients in the segment's s
    lo: jax.Array  # (So, Mo) segment start, s
    he: jax.Array  # (So, Mo) segment length (1 where zero)
    pos: jax.Array  # (So, Mo) bool: the segment has a positive length
    brk: jax.Array  # (max(So - 1, 1), Mo) interior breaks (segment look-up)
    end: jax.Array  # (Mo,) end time T_j
    coast: jax.Array  # (Mo,) bool


def prepare_others(others: Trajectory, mask) -> OthersPrep:
    """:class:`OthersPrep` of the others' predictions (what
    :func:`jaxplan.nlp.terms.others_derivs` reads at every call, cleaned and scaled once)."""
    c = others.coeffs
    b = others.breaks
    ok = mask & jnp.all(jnp.isfinite(c), axis=(-1, -2, -3)) & jnp.all(jnp.isfinite(b), axis=-1)
    b = jnp.where(ok[:, None], b, 0.0)
    So, N, Kd = c.shape[-3:]
    lo, hi = b[:, :-1].T, b[:, 1:].T  # (So, Mo)
    h = hi - lo
    he = jnp.where(h > 0, h, 1.0)
    cc = jnp.where(ok[None, None, :, None], jnp.transpose(c, (2, 1, 0, 3)), 0.0)  # (N, So, Mo, Kd)
    rows = []
    for r in range(3):
        if r >= Kd:
            rows.append(jnp.zeros(cc.shape[:-1] + (1,), c.dtype))
            continue
        f = np.array([falling(i, r) for i in range(r, Kd)], float)
        rows.append(cc[..., r:] * f / (he[None, :, :, None] ** r))
    brk = b[:, 1:So].T if So > 1 else jnp.zeros((1, b.shape[0]), b.dtype)
    return OthersPrep(tuple(rows), lo, he, h > 0, brk, b[:, -1], others.coast)


def others_jet(op: OthersPrep, t, R: int):
    """The others' derivatives 0..R at times t (K,): a list of (N, Mo, K) arrays (what
    :func:`jaxplan.nlp.terms.others_derivs` gives, laid out components first and samples last).
    After an other's end it holds (coast False) or coasts (coast True)."""
    So = op.c[0].shape[1]
    tt = t[None, :]
    To = op.end[:, None]
    tc = jnp.clip(tt, 0.0, To)  # (Mo, K)
    if So > 1:
        k = jnp.clip(jnp.sum(op.brk[:, :, None] <= tc[None], axis=0), 0, So - 1)
    vals = []
    for r in range(max(R, 1) + 1):
        out = 0.0
        for i in range(So):
            s = jnp.where(op.pos[i][:, None], (tc - op.lo[i][:, None]) / op.he[i][:, None], 0.0)
            cr = op.c[r][:, i]  # (N, Mo, Kd - r)
            v = cr[..., -1, None]
            for j in range(cr.shape[-1] - 2, -1, -1):
                v = v * s[None] + cr[..., j, None]
            out = v if So == 1 else out + jnp.where((k == i)[None], v, 0.0)
        vals.append(out)
    after = (tt > To)[None]
    coast = op.coast[None, :, None]
    res = [vals[0] + jnp.where(after & coast, vals[1] * (tt - To)[None], 0.0)]
    if R >= 1:
        res.append(jnp.where(after & ~coast, 0.0, vals[1]))
    for r in range(2, R + 1):
        res.append(jnp.where(after, 0.0, vals[r]))
    return res


def _affine_jets(fn, tau):
    """fn(tau) -> (b (N, K), C (K, nz)), the features P = b + z C^T, affine in z for a
    fixed tau: their values and first and second tau derivatives (nested jvp)."""
    one = jnp.ones_like(tau)
    (v, d1), (_, d2) = jax.jvp(lambda t: jax.jvp(fn, (t,), (one,)), (tau,), (one,))
    return v, d1, d2


def _rows(jets, G, Hgg, HgT, GT, HTT):
    """One sample set's jets and local terms (m feature groups of K samples, as
    :func:`_chain` documents them) laid out as m K rows of one group: (jets, local)
    with b (N, R), C (R, nz), G (N, R), Hgg (N, N, R), HgT (N, R), GT and HTT (K,)."""
    (b, C), (b1, C1), (b2, C2) = jets
    m, N, K = b.shape
    row = lambda a: jnp.moveaxis(a, 0, -2).reshape(a.shape[1:-1] + (m * K,))  # (.., m K)
    crow = lambda c: c.reshape(m * K, c.shape[-1])
    return ((row(b), crow(C)), (row(b1), crow(C1)), (row(b2), crow(C2))), (
        row(G), row(Hgg), row(HgT), GT, HTT)


def _chain(z, T, parts):
    """(gradient (n,), Hessian (n, n)) in x = (z, tau) of a sum over samples k of local
    terms F_k(P_1k, .., P_mk, T) through m feature groups P_g = b_g(tau) + z C_g(tau)^T
    (N, K) each and T = exp(tau) (the chain rule of that composition; every factor comes
    from autodiff), for several sample sets at once.

    parts: one (jets, G, Hgg, HgT, GT, HTT) per sample set.  jets: ((b, C), (b', C'),
    (b'', C'')) from :func:`_affine_jets`, b (m, N, K) and C (m, K, nz).  G, Hgg, HgT:
    the local gradient (m, N, K), Hessian (m, N, N, K) and T cross term (m, N, K) of F in
    each group; GT, HTT (K,): its T gradient and curvature.  The local Hessian has no
    blocks between groups (true of the radial terms here), so every (group, sample) pair
    of every set is a row of one sum, formed by matrix products over the rows (one sum
    is faster than a chain per set: docs/SOLVER.md, "Measurements behind the code")."""
    N, nz = z.shape
    jets, local = zip(*(_rows(j, *loc) for j, *loc in parts), strict=True)
    cat = lambda arrays, axis=-1: jnp.concatenate(list(arrays), axis=axis)
    C, C1, C2 = (cat((j[i][1] for j in jets), 0) for i in range(3))  # (R, nz)
    b1, b2 = (cat(j[i][0] for j in jets) for i in (1, 2))  # (N, R)
    G, Hgg, HgT, GT, HTT = (cat(loc[i] for loc in local) for i in range(5))
    hi = jax.lax.Precision.HIGHEST
    pt = b1 + jnp.matmul(z, C1.T, precision=hi)  # (N, R)
    ptt = b2 + jnp.matmul(z, C2.T, precision=hi)
    gz = jnp.matmul(G, C, precision=hi)  # (N, nz)
    gt = sum_all(GT) * T + sum_all(G * pt)
    CC = (C[:, :, None] * C[:, None, :]).reshape(C.shape[0], nz * nz)  # (R, nz nz)
    hzz = jnp.matmul(Hgg.reshape(N * N, -1), CC, precision=hi)  # (N N, nz nz)
    hzz = jnp.transpose(hzz.reshape(N, N, nz, nz), (0, 2, 1, 3)).reshape(N * nz, N * nz)
    Hpt = jnp.sum(Hgg * pt[None, :, :], axis=1)  # (N, R)
    hzt = (jnp.matmul(Hpt + HgT * T, C, precision=hi) + jnp.matmul(G, C1, precision=hi)
           ).reshape(-1)
    htt = (sum_all(T * T * HTT + T * GT) + sum_all(pt * Hpt) + 2.0 * T * sum_all(HgT * pt)
           + sum_all(G * ptt))
    H = jnp.concatenate([jnp.concatenate([hzz, hzt[:, None]], axis=1),
                         jnp.concatenate([hzt, htt[None]])[None]], axis=0)
    return jnp.concatenate([gz.reshape(-1), gt[None]]), H


def _kind_rows(params, structure, name: str, orders):
    """The basis rows of sample set ``name`` for derivative ``orders`` and the lane's end
    kind: (apply, C) with apply(e (6, N)) -> (m, N, K) the boundary part B e and C (m, K,
    nz).  Both kinds' constants are applied in one matrix product (for all lanes under
    vmap; a per-lane matrix would be a batched product of small matrices) and the lane's
    result selected."""
    b = basis(structure)
    both = np.stack([np.stack([getattr(k, name)[r] for r in orders]) for k in (b.free, b.rest)])
    m, K = len(orders), both.shape[2]  # both: (2, m, K, 6 + nz)
    Bm = jnp.asarray(both[..., :6].reshape(-1, 6))
    rest = jnp.asarray(params.rest, bool)

    def apply(e):
        out = (Bm @ e).reshape(2, m, K, -1)
        return jnp.swapaxes(jnp.where(rest, out[1], out[0]), 1, 2)

    return apply, jnp.where(rest, jnp.asarray(both[1, ..., 6:]), jnp.asarray(both[0, ..., 6:]))


def _lim_affine(params, structure, name):
    """tau -> (b (3, N, K), C (3, K, nz)): the velocity, acceleration and jerk features at
    the basis sample set ``name`` ("quad" or "lim"), Y_r = (B_r e(h) + C_r z) / h^r =
    b_r + z C_r^T, three stacked groups."""
    S = structure.segments
    apply, C = _kind_rows(params, structure, name, (1, 2, 3))
    r = jnp.arange(1, 4, dtype=jnp.float64)[:, None, None]

    def f(t):
        h = jnp.exp(t) / S
        sc = h ** -r
        return apply(boundary_vector(params, h)) * sc, C * sc

    return f


def _lim_jets(params, structure, name, tau):
    """Jets of :func:`_lim_affine`'s features (value, first and second tau derivative)."""
    return _affine_jets(_lim_affine(params, structure, name), tau)


def _lim_terms(z, T, jets, w, lam, params, mu, soft: bool):
    """Value and :func:`_chain`'s local terms (G, Hgg, HgT, GT, HTT) of the soft limits
    (``w`` the quadrature weights) or of the hard-limit AL terms (``lam`` (K, 3)) in
    their three radial feature groups; and the features Y (3, N, K)."""
    lim = params.limits
    (b, C), _, _ = jets
    Y = b + jnp.sum(z[None, :, :, None] * jnp.swapaxes(C, 1, 2)[:, None], axis=2)  # (3, N, K)
    rho = jnp.sum(Y * Y, axis=1)  # (3, K)
    tm2 = (jnp.stack([lim.v_max, lim.a_max, lim.j_max]) ** 2)[:, None]
    K = Y.shape[-1]
    if soft:
        av, a1, a2 = _elementwise_derivs(lambda rr: params.weights.q_lim * w * sexp(rr - tm2), rho)
        cd, cdd = T * a1, T * a2
        val = T * sum_all(av)
        GT = jnp.sum(av, axis=0)
        HgT = 2.0 * a1[:, None] * Y
    else:
        bv, cd, cdd = _elementwise_derivs(
            lambda rr: al_term(limit_priority(params) * (1.0 - rr / tm2), lam.T, mu), rho)
        val = sum_all(bv)
        GT = jnp.zeros(K, z.dtype)
        HgT = jnp.zeros_like(Y)
    N = z.shape[0]
    G = 2.0 * cd[:, None] * Y
    Hgg = (4.0 * cdd[:, None, None] * Y[:, :, None] * Y[:, None, :]
           + 2.0 * cd[:, None, None] * jnp.eye(N, dtype=z.dtype)[:, :, None])
    return val, (G, Hgg, HgT, GT, jnp.zeros(K, z.dtype)), Y


def _col_affine(params, structure, kind):
    """tau -> (b (1, N, K), C (1, K, nz)): the own positions at the collision rows
    (samples, then the coast), p = b + z C^T, one group."""
    S = structure.segments
    n = structure.n_coast
    apply, C0 = _kind_rows(params, structure, "col", (0,))

    def f(t):
        e = boundary_vector(params, jnp.exp(t) / S)
        b = apply(e)  # (1, N, Kc)
        C = C0
        if n:
            h = jnp.exp(t) / S
            tc = jnp.arange(1, n + 1) / n * coast_time(params.limits)
            E0, E1 = kind.end[0, 0], kind.end[1, 0]
            be = (E0[:6] @ e)[:, None] + (E1[:6] @ e)[:, None] * (tc / h)[None, :]
            Ce = E0[None, 6:] + (tc / h)[:, None] * E1[None, 6:]
            b = jnp.concatenate([b, be[None]], axis=2)
            C = jnp.concatenate([C, Ce[None]], axis=1)
        return b, C

    return f


def _col_jets(params, structure, kind, tau):
    """Jets of :func:`_col_affine`'s positions (value, first and second tau derivative)."""
    return _affine_jets(_col_affine(params, structure, kind), tau)


def merit_shapes(zs, tau, params, structure, kind, mult: Multipliers, mu,
                 others: OthersPrep | None = None):
    """:func:`jaxplan.nlp.terms.merit` at the C points x = (z, tau) for the shapes zs (C, N, nz)
    at ONE horizon tau: the values (C,), equal to a vmap of :func:`jaxplan.nlp.terms.merit` over
    the points to rounding.  What depends on tau alone (boundary terms, the other robots'
    positions at the samples) is formed once, and the terms are laid out as in :func:`merit_derivs`
    (components first), so that five shapes cost about what one
    :func:`jaxplan.nlp.terms.merit` call costs, far less than a vmap of it over the five
    points (used by :func:`jaxplan.solve.initial_guess`; docs/SOLVER.md, "Measurements
    behind the code")."""
    b = basis(structure)
    T = jnp.exp(tau)
    h = T / structure.segments
    wt = params.weights
    e = boundary_vector(params, h)
    val = (wt.q_dynm * (jnp.sum(e * (kind.M @ e)) + jnp.sum(kind.q * zs * zs, axis=(1, 2))) / h**5
           + wt.k_t * T)
    lim = params.limits
    tm2 = (jnp.stack([lim.v_max, lim.a_max, lim.j_max]) ** 2)[:, None]

    def radial(name):  # (C, 3, K): |Y_r|^2 of the limit features
        bl, Cl = _lim_affine(params, structure, name)(tau)
        Y = bl[None] + jnp.einsum("cnz,gkz->cgnk", zs, Cl)
        return jnp.sum(Y * Y, axis=2)

    val = val + wt.q_lim * T * jnp.sum(jnp.asarray(b.quad_w) * sexp(radial("quad") - tm2),
                                       axis=(1, 2))
    if structure.paper:
        val = val + jax.vmap(lambda z: paper_collision(pack(z, tau), params, structure, kind))(zs)
    if needs_col_features(structure):
        s, off, w, on = collision_rows(params, structure)
        bp, C = _col_affine(params, structure, kind)(tau)
        p = bp[0][None] + jnp.einsum("cnz,kz->cnk", zs, C[0])  # (C, N, K)
    if structure.static_terms:
        y = jnp.concatenate([jnp.swapaxes(p, 1, 2), jnp.broadcast_to(T, p.shape[:1] + (
            p.shape[2], 1))], axis=-1)  # (C, K, N + 1)
        tc = None if params.static.motion is None else T * s + off  # moving rows' times
        one = lambda yk, wk, lk, ok, tk: static_local(yk, wk, lk, ok, params, structure, mu, tk)
        val = val + jnp.sum(jax.vmap(jax.vmap(one, in_axes=(0, 0, 0, 0, None if tc is None
                                                             else 0)),
                                     in_axes=(0, None, None, None, None))(
            y, w, mult.static, on, tc), axis=1)
    if has_sampled_collision(structure):
        op = prepare_others(params.others, params.other_mask) if others is None else others
        X = p[:, :, None, :] - others_jet(op, T * s + off, 0)[0][None]  # (C, N, Mo, K)
        r = jnp.sum(X * X, axis=1)  # (C, Mo, K)
        mask = params.other_mask[:, None]
        rho = (params.radius + params.other_radius)[:, None]
        if structure.barrier:
            ex = wt.q_obs * w * jnp.exp(-wt.k_p * (jnp.sqrt(r + DIST_EPS2) - rho))
            val = val + T * jnp.sum(jnp.where(mask, ex, 0.0), axis=(1, 2))
        if structure.collision_constraints:
            use = mask & on[None, :]
            val = val + jnp.sum(jnp.where(use, al_term(r - rho * rho, mult.collision.T, mu),
                                          0.0), axis=(1, 2))
    if structure.hard_limits:
        g = limit_priority(params) * (1.0 - radial("lim") / tm2)
        val = val + jnp.sum(al_term(g, mult.limits.T, mu), axis=(1, 2))
    return val


def _collision_derivs(x, z, T, tau, params, structure, kind, mult: Multipliers, mu,
                      with_g: bool, others: OthersPrep | None, jets=None):
    """(value, local terms, g_collision) of the sampled collision terms (barrier and the
    AL terms of the collision constraints) for :func:`merit_derivs`: the local terms are
    :func:`_chain`'s (G, Hgg, HgT, GT, HTT) at the collision rows' positions, one
    group; g_collision (n_col, Mo) the constraints where ``with_g`` and the mode has
    them, else ones."""
    N = structure.n_dim
    Mo = params.other_mask.shape[-1]
    gc = jnp.ones((structure.n_col, Mo), x.dtype)
    op = prepare_others(params.others, params.other_mask) if others is None else others
    s, off, w, on = collision_rows(params, structure)
    jets = _col_jets(params, structure, kind, tau) if jets is None else jets
    (bp, C), _, _ = jets
    p = bp[0] + jnp.sum(z[:, :, None] * C[0].T[None], axis=1)  # (N, K)
    o0, o1, o2 = others_jet(op, T * s + off, 2)  # (N, Mo, K)
    X = p[:, None, :] - o0
    u = -s * o1
    ww = -(s * s) * o2
    r = jnp.sum(X * X, axis=0)  # (Mo, K)
    mask = params.other_mask[:, None]
    rho = (params.radius + params.other_radius)[:, None]
    wt = params.weights
    zero = (jnp.zeros_like(r),) * 3
    if structure.barrier:
        af = lambda rr: jnp.where(
            mask, wt.q_obs * w * jnp.exp(-wt.k_p * (jnp.sqrt(rr + DIST_EPS2) - rho)), 0.0)
        av, a1, a2 = _elementwise_derivs(af, r)
    else:
        av, a1, a2 = zero
    if structure.collision_constraints:
        use = mask & on[None, :]
        lam = mult.collision.T
        bf = lambda rr: jnp.where(use, al_term(rr - rho * rho, lam, mu), 0.0)
        bv, b1, b2 = _elementwise_derivs(bf, r)
        if with_g:
            gc = jnp.where(use, r - rho * rho, 1.0).T
    else:
        bv, b1, b2 = zero
    cd = T * a1 + b1
    cdd = T * a2 + b2
    Xu = jnp.sum(X * u, axis=0)
    v = sum_all(T * av + bv)
    Gp = 2.0 * jnp.sum(cd * X, axis=1)
    GT = jnp.sum(2.0 * cd * Xu + av, axis=0)
    eye = jnp.eye(N, dtype=x.dtype)[:, :, None]
    Hpp = (4.0 * jnp.sum(cdd * X[:, None] * X[None, :], axis=2)
           + 2.0 * jnp.sum(cd, axis=0) * eye)
    HpT = jnp.sum((4.0 * cdd * Xu + 2.0 * a1) * X + 2.0 * cd * u, axis=1)
    q = jnp.sum(u * u + X * ww, axis=0)
    HTT = jnp.sum(cdd * (2.0 * Xu) ** 2 + 2.0 * cd * q + 4.0 * a1 * Xu, axis=0)
    return v, (Gp[None], Hpp[None], HpT[None], GT, HTT), gc


def _static_derivs(z, T, jets, params, structure, mult: Multipliers, mu, with_g: bool):
    """(value, local terms, g_static) of the static rows' terms (barrier and AL terms,
    :func:`jaxplan.nlp.terms.static_local`) for :func:`merit_derivs`.  Each collision
    row's local term is F_k = T B_k(p) + A_k(p) (B the barrier without its T factor, A
    the AL terms), a sum over the static rows of a scalar function of the gap
    sd(p) - r: its p derivatives from the signed distance's closed-form jet
    (:func:`jaxplan.world.signed_distance_jet`) and the scalar's derivatives, as
    :func:`_chain`'s local terms (G, Hgg, HgT, GT, HTT) at the collision rows'
    positions, one group.  g_static (n_col, R): the constraints where ``with_g`` and the
    mode has them, else ones.

    Rows that move (``static.motion``): at collision row k (time t_k = T s_k + off_k)
    the row is at c(t_k) (:func:`jaxplan.world.path_at`, piecewise linear), so the gap is
    that of q = p - c(t_k), which depends on T through u_k = dq/dT = -s_k c'(t_k)
    (c'' = 0 between knots): with g = sd(q) - r, g_T = grad sd . u, the local terms gain
    GT += c1 g_T, HgT += c2 g_T grad sd + c1 Hess sd u, HTT = 2 B' g_T + c2 g_T^2 +
    c1 u . Hess sd u (c1 = T B' + A', c2 = T B'' + A'')."""
    s, off, w, on = collision_rows(params, structure)
    (bp, C), _, _ = jets
    p = (bp[0] + jnp.sum(z[:, :, None] * C[0].T[None], axis=1)).T  # (K, N)
    st = params.static
    wt = params.weights
    center, u = st.center, None
    if st.motion is not None:
        m = st.motion
        center, vel = path_at(m.t, m.p, m.v, T * s + off, xp=jnp)  # (K, R, N)
        u = -s[:, None, None] * vel
    sd, dg, dH = signed_distance_jet(st.kind, center, st.half, st.radius, p, xp=jnp,
                                     kinds=structure.static_kinds)
    gap = sd - params.radius  # (K, R), as static_gap
    cons = (structure.collision_constraints and mult is not None
            and mult.static is not None)
    # F = sum_R f(gap): gradient f' grad sd, Hessian f'' grad sd grad sd^T + f' Hess sd
    zero = jnp.zeros_like(gap)
    if structure.static_barrier:
        bf = lambda gg: jnp.where(st.mask, wt.q_obs * w[:, None] * jnp.exp(-wt.k_p * gg), 0.0)
        bv, b1, b2 = _elementwise_derivs(bf, gap)
    else:
        bv, b1, b2 = zero, zero, zero
    if cons:
        scale = static_scale(params)
        allow = static_allowance(params)
        af = lambda gg: jnp.where(st.mask & on[:, None],
                                  al_term(scale * (gg - allow), mult.static, mu), 0.0)
        av, a1, a2 = _elementwise_derivs(af, gap)
    else:
        av, a1, a2 = zero, zero, zero
    c1, c2 = T * b1 + a1, T * b2 + a2
    v = sum_all(T * bv + av)
    G = jnp.sum(c1[..., None] * dg, axis=1).T  # (N, K)
    Hgg = jnp.sum(c2[..., None, None] * dg[..., :, None] * dg[..., None, :]
                  + c1[..., None, None] * dH, axis=1)  # (K, N, N)
    Hgg = jnp.transpose(Hgg, (1, 2, 0))  # (N, N, K)
    HgT = jnp.sum(b1[..., None] * dg, axis=1).T
    GT, HTT = jnp.sum(bv, axis=1), jnp.zeros(p.shape[0], z.dtype)
    if u is not None:  # moving rows (docstring)
        gu = jnp.sum(dg * u, axis=-1)  # (K, R)
        Hu = jnp.sum(dH * u[..., None, :], axis=-1)  # (K, R, N)
        GT = GT + jnp.sum(c1 * gu, axis=1)
        HgT = HgT + jnp.sum((c2 * gu)[..., None] * dg + c1[..., None] * Hu, axis=1).T
        HTT = jnp.sum(2.0 * b1 * gu + c2 * gu * gu + c1 * jnp.sum(u * Hu, axis=-1), axis=1)
    local = (G[None], Hgg[None], HgT[None], GT, HTT)
    gs = jnp.ones((structure.n_col, structure.n_static), z.dtype)
    if with_g and structure.collision_constraints:
        gs = jnp.where(st.mask[None, :] & on[:, None],
                       static_scale(params) * (gap - static_allowance(params)), 1.0)
    return v, local, gs


def merit_derivs(x, params, structure, kind, mult: Multipliers, mu, with_g: bool = False,
                 others: OthersPrep | None = None):
    """(value, gradient (n,), Hessian (n, n)) of the augmented Lagrangian at x; with
    ``with_g`` also the inequality constraints g(x) (as :func:`jaxplan.nlp.terms.constraints`,
    from the same features and other-robot positions: what the solver needs at a trial point).

    By the features' block structure (module doc): each axis's features are affine in
    that axis's shape variables, so the chain rule (:func:`_chain`) runs on small
    per-sample blocks; the other robots' jets come from ``others`` (formed once per solve
    by :func:`prepare_others`; here when None)."""
    b = basis(structure)
    Mo = params.other_mask.shape[-1]
    z, tau = unpack(x, structure)
    T = jnp.exp(tau)
    gc = jnp.ones((structure.n_col, Mo), x.dtype)
    gh = jnp.ones((len(b.lim_s), 3), x.dtype)
    tv, tg, tH = _smooth_time_derivs(x, params, structure, kind)
    jq = _lim_jets(params, structure, "quad", tau)
    v, loc, _ = _lim_terms(z, T, jq, jnp.asarray(b.quad_w), None, params, mu, True)
    tv = tv + v
    parts = [(jq, *loc)]  # every sampled term goes through one chain rule (_chain)
    if structure.paper:
        v, g, H = _value_grad_hessian(lambda xx: paper_collision(xx, params, structure, kind), x)
        tv, tg, tH = tv + v, tg + g, tH + H
    gs = jnp.ones((structure.n_col, structure.n_static), x.dtype)
    jets = _col_jets(params, structure, kind, tau) if needs_col_features(structure) else None
    # the static rows' and the other robots' terms share the collision rows' positions:
    # their local terms are summed before the chain rule (it is linear in them)
    local = []
    if structure.static_terms:
        v, loc, gs = _static_derivs(z, T, jets, params, structure, mult, mu, with_g)
        tv = tv + v
        local.append(loc)
    if has_sampled_collision(structure):
        v, loc, gc = _collision_derivs(x, z, T, tau, params, structure, kind, mult, mu, with_g,
                                       others, jets)
        tv = tv + v
        local.append(loc)
    if local:
        parts.append((jets, *(functools.reduce(jnp.add, t) for t in zip(*local, strict=True))))
    if structure.hard_limits:
        jh = _lim_jets(params, structure, "lim", tau)
        v, loc, Yh = _lim_terms(z, T, jh, None, mult.limits, params, mu, False)
        tv = tv + v
        parts.append((jh, *loc))
        if with_g:
            lim = params.limits
            tm2 = jnp.stack([lim.v_max, lim.a_max, lim.j_max]) ** 2
            gh = limit_priority(params) * (1.0 - jnp.sum(Yh * Yh, axis=1) / tm2[:, None]).T
    g, H = _chain(z, T, parts)
    tg, tH = tg + g, tH + H
    if with_g:
        return tv, tg, tH, Multipliers(gc, gh, gs)
    return tv, tg, tH
