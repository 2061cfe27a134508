"""The per-robot NLP (MATH.md section 2): objective, constraints and their derivatives.

Decision variables
------------------
Robot i's trajectory has ``S`` equal segments of degree ``D`` per axis (paper: D = 5,
S = 1) joined C^2, and a horizon T.  Every equality constraint of the NLP is LINEAR in
the normalized-time coefficients c (per axis, stacked over segments) for a given
segment length h = T / S:

    start      x(0) = p0, x'(0) = v0, x''(0) = a0         ->  rows of A c = e(h)
    joints     C^2 continuity between segments             ->  A c = 0
    end        x(T) = pf  (and v(T) = vf, a(T) = af when ``rest``)
    with  e(h) = [p0, v0 h, a0 h^2, pf, vf h, af h^2]  and A CONSTANT.

So the feasible coefficients are exactly  c = P e(h) + Z z  (a null-space, i.e. reduced
KKT, parametrization), where

* P e(h) is the minimum-jerk trajectory through the boundary conditions for this T
  (z = 0 *is* the closed-form prediction of MATH.md section 1 for that T), and
* Z spans null(A), chosen so that Z' Q Z = diag(q) (Q the jerk Gram matrix) and the
  positions of Z z at dense samples are orthonormal: one unit of z moves the path by
  about one metre RMS.  The smoothness term is then exactly
  h^-5 (sum_d e_d' M e_d + sum q_i z_di^2)  with M = P' Q P.

The decision vector is  x = (z (N, nz) flattened, tau = log T):  N nz + 1 numbers
(paper, free end: 7; the rest end of the paper has nz_rest = 0 shape freedom, MATH.md).
The equality constraints hold to rounding at every iterate (see
:func:`equality_residual`).  Free and rest ends share the size nz = nz_free; a rest lane
uses two fewer shape variables per axis and its spare ones are inert (they carry only
the cost h^-5 z^2, so they stay 0).  The end-state kind is a traced per-lane flag.

Objective terms (all integrals over [0, T], T = exp(tau)):
  smoothness  q_dynm * int |x'''|^2 dt             exact (analytic)
  time        k_t * T
  limits      q_lim * int sum_k sexp(|x^(k)|^2 - tau_k^2) dt, k = 1, 2, 3 (norms over
              axes), Gauss-Legendre per segment.  sexp = exp below 30 and its quadratic
              Taylor continuation above (keeps the value finite; documented deviation).
  collision   per ``NLPStructure.collision``:
     "paper"       q_obs * int sum_j (dx . dv) / (d exp(k_p (d - rho_j))) dt  (the printed
                   term).  It is a total derivative (MATH.md), so it is integrated
                   exactly, as q_obs sum_j (exp(-k_p (d_j(0) - rho_j)) - exp(-k_p (d_j(T)
                   - rho_j))) / k_p: path independent.  (Quadrature of the printed
                   integrand is path dependent only through its error, which a solver
                   then exploits: objective unbounded in the nodes, no convergence.)
     "barrier"     q_obs * int sum_j exp(-k_p (d_j - rho_j)) dt
     "constraint"  d_j(t_k)^2 >= rho_j^2 at the collision samples (hard; augmented
                   Lagrangian in the solver)
     "barrier+constraint"  both.
  Integrals over collision terms use composite 4-point Gauss-Legendre panels; the
  same nodes are the constraint samples (t = 0 and t = T excluded: both are fixed).
Optional hard limits (``hard_limits``): 1 - |x^(k)(t_i)|^2 / tau_k^2 >= 0 at uniform
sample times in (0, T].  Bound: T >= t_min.

Derivatives
-----------
All derivatives come from JAX autodiff; structure makes them cheap.  Every sampled term
is  sum_k F_k(P_1k, .., P_mk, T)  with a few feature groups P_g (N, K) (the own
position at the collision samples; velocity, acceleration and jerk at the limit
samples) and T.  Each axis's features are affine in that axis's shape variables for a
fixed tau:  P_g = b_g(tau) + z C_g(tau)^T  (C_g the same for every axis; constant except
on the coast rows).  So, with the local gradient and Hessian of F_k in its few
features (autodiff of the scalar functions: :func:`_d012`) and the tau jets of b_g and
C_g (nested jvp: :func:`_affine_jets`), the gradient and Hessian in x are sums of
small per-sample blocks (:func:`_chain`): no (n x n) Hessian per sample, no batched
small matrix products.  The other robots' positions at t_k = T s_k depend on T; their
second-order Taylor jet in T (exact value, first and second derivative at the current
T) is formed at every evaluation from their coefficients, laid out once per solve
(:func:`prepare_others`).  Checked against jax.hessian in tests/test_costs.py.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from math import factorial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg

from jaxplan.trajectory import Trajectory

COLLISION_MODES = ("paper", "barrier", "constraint", "barrier+constraint", "none")
SEXP_KNEE = 30.0
DIST_EPS2 = 1e-12  # m^2, smooths |dx| at 0


# ---------------------------------------------------------------------- data
class Weights(NamedTuple):
    """Objective weights (scalars, traced: changing them does not recompile)."""

    q_dynm: jax.Array  # smoothness, per (m/s^3)^2 s
    q_obs: jax.Array  # collision cost
    q_lim: jax.Array  # soft dynamic limits
    k_t: jax.Array  # price of one second
    k_p: jax.Array  # 1/m, collision decay rate


class Limits(NamedTuple):
    """Dynamic limits (norms over axes), traced scalars."""

    v_max: jax.Array  # m/s
    a_max: jax.Array  # m/s^2
    j_max: jax.Array  # m/s^3


@dataclass(frozen=True)
class NLPStructure:
    """Static shape of the NLP (hashable; a change recompiles).

    Attributes:
        n_dim: spatial axes N.
        degree: polynomial degree D per segment (>= 5 for C^2 joints with freedom).
        segments: number of equal segments S (C^2 joints).
        collision: one of COLLISION_MODES ("none" disables collision terms).
        n_collision_samples: collision samples (a multiple of 4: composite 4-point
            Gauss-Legendre panels over [0, T]).
        n_quadrature: Gauss-Legendre nodes per segment for the soft-limit integral.
        hard_limits: add the constraints |x^(k)(t_i)| <= tau_k.
        n_limit_samples: uniform sample times in (0, T] for the hard limits.
        n_coast_samples: collision constraints on a FREE-end plan's coast after T (what
            it flies if nothing replaced it: p(T) + v(T) t), at t = t_c k / n for
            k = 1..n, with t_c = :func:`coast_time` (long enough to stop from v_max).
            Only in the modes with collision constraints; no barrier there; inactive on
            rest lanes (their coast is a hold, checked by the last samples).  0 = off
            (the paper's NLP).
    """

    n_dim: int = 3
    degree: int = 5
    segments: int = 1
    collision: str = "barrier+constraint"
    n_collision_samples: int = 32
    n_quadrature: int = 8
    hard_limits: bool = False
    n_limit_samples: int = 16
    n_coast_samples: int = 0

    def __post_init__(self):
        if self.collision not in COLLISION_MODES:
            raise ValueError(f"collision must be one of {COLLISION_MODES}, got {self.collision!r}")
        if self.degree < 5:
            raise ValueError("degree must be >= 5 (a rest end needs 6 conditions per segment)")
        if self.segments < 1 or self.n_dim < 1:
            raise ValueError("segments and n_dim must be >= 1")
        if self.n_collision_samples % 4 or self.n_collision_samples < 4:
            raise ValueError("n_collision_samples must be a positive multiple of 4")
        if self.n_coast_samples < 0:
            raise ValueError("n_coast_samples must be >= 0")

    @property
    def barrier(self) -> bool:
        return self.collision in ("barrier", "barrier+constraint")

    @property
    def paper(self) -> bool:
        return self.collision == "paper"

    @property
    def collision_constraints(self) -> bool:
        return self.collision in ("constraint", "barrier+constraint")

    @property
    def n_coast(self) -> int:
        """Coast samples in use (0 unless the mode has collision constraints)."""
        return self.n_coast_samples if self.collision_constraints else 0

    @property
    def n_col(self) -> int:
        """Rows of the collision constraints: the samples in [0, T], then the coast."""
        return self.n_collision_samples + self.n_coast

    @property
    def nz(self) -> int:
        """Shape variables per axis (free-end count; rest lanes use nz - 2)."""
        return self.segments * (self.degree - 2) - 1

    @property
    def n_x(self) -> int:
        return self.n_dim * self.nz + 1


class NLPParams(NamedTuple):
    """Everything one robot's NLP depends on besides its structure (a pytree).

    Shapes for one problem (add leading batch axes for vmap):
        p0, v0, a0: (N,) start state.   goal_p, goal_v, goal_a: (N,) end state.
        rest: () bool; True: fully defined end state (goal_p, goal_v, goal_a), False:
            free end (goal_p only).
        others: Trajectory with batch (Mo,): the other robots' predictions (any S, D).
        other_radius: (Mo,) m.   other_mask: (Mo,) bool, False = ignore.
        radius: () m.   weights: Weights.   limits: Limits.   t_min: () s (> 0).
    """

    p0: jax.Array
    v0: jax.Array
    a0: jax.Array
    goal_p: jax.Array
    goal_v: jax.Array
    goal_a: jax.Array
    rest: jax.Array
    others: Trajectory
    other_radius: jax.Array
    other_mask: jax.Array
    radius: jax.Array
    weights: Weights
    limits: Limits
    t_min: jax.Array


class Multipliers(NamedTuple):
    """Augmented-Lagrangian multipliers (>= 0) of the inequality constraints."""

    collision: jax.Array  # (Kc + n_coast, Mo)
    limits: jax.Array  # (Kh, 3)


# ---------------------------------------------------------------------- static basis
def _falling(i: int, r: int) -> int:
    return factorial(i) // factorial(i - r) if i >= r else 0


def _beta(r: int, s: float, D: int) -> np.ndarray:
    """Row (D+1,): d^r/ds^r of the monomials at s."""
    return np.array([_falling(i, r) * s ** (i - r) if i >= r else 0.0 for i in range(D + 1)])


def _jerk_gram(D: int) -> np.ndarray:
    Q = np.zeros((D + 1, D + 1))
    for i in range(3, D + 1):
        for j in range(3, D + 1):
            Q[i, j] = _falling(i, 3) * _falling(j, 3) / (i + j - 5)
    return Q


def _seg_local(sigma: np.ndarray, S: int):
    k = np.minimum(np.floor(sigma * S).astype(int), S - 1)
    return k, sigma * S - k


class _Kind(NamedTuple):
    """Constants of one end-state kind (numpy; selected per lane)."""

    P: np.ndarray  # (S(D+1), 6)
    Z: np.ndarray  # (S(D+1), nz)
    M: np.ndarray  # (6, 6)
    q: np.ndarray  # (nz,)
    col: np.ndarray  # (4, Kc, 6 + nz): rows [B_r | C_r], r = 0..3
    quad: np.ndarray  # (4, Kq, 6 + nz)
    lim: np.ndarray  # (4, Kh, 6 + nz)
    end: np.ndarray  # (4, 1, 6 + nz) at s = 1
    fit_pinv: np.ndarray  # (nz, Kf)  z = pinv (target - B0 e)
    fit_B: np.ndarray  # (Kf, 6)


class Basis(NamedTuple):
    free: _Kind
    rest: _Kind
    col_s: np.ndarray  # (Kc,) global normalized sample times
    col_w: np.ndarray  # (Kc,) quadrature weights (sum 1)
    quad_s: np.ndarray
    quad_w: np.ndarray
    lim_s: np.ndarray
    fit_s: np.ndarray


def _gauss01(n: int):
    x, w = np.polynomial.legendre.leggauss(n)
    return (x + 1) / 2, w / 2


@functools.cache
def basis(structure: NLPStructure) -> Basis:
    """Static matrices of a structure (numpy, cached)."""
    D, S = structure.degree, structure.segments
    nc = S * (D + 1)
    nz = structure.nz
    # sample sets (global normalized time)
    xg, wg = _gauss01(4)
    npan = structure.n_collision_samples // 4
    col_s = ((np.arange(npan)[:, None] + xg[None]) / npan).ravel()
    col_w = np.tile(wg, npan) / npan
    xq, wq = _gauss01(structure.n_quadrature)
    quad_s = ((np.arange(S)[:, None] + xq[None]) / S).ravel()
    quad_w = np.tile(wq, S) / S
    lim_s = np.arange(1, structure.n_limit_samples + 1) / structure.n_limit_samples
    fit_s = np.linspace(0.0, 1.0, 4 * (D + 1) * S + 1)

    def rows(r, sigma):
        k, s = _seg_local(np.asarray(sigma, float), S)
        out = np.zeros((len(k), nc))
        for i, (kk, ss) in enumerate(zip(k, s, strict=True)):
            out[i, kk * (D + 1) : (kk + 1) * (D + 1)] = _beta(r, ss, D)
        return out

    Qb = scipy.linalg.block_diag(*[_jerk_gram(D)] * S)
    pos_gram = rows(0, fit_s)

    def kind(rest: bool) -> _Kind:
        A, E = [], []
        for r in range(3):  # start
            row = np.zeros(nc)
            row[: D + 1] = _beta(r, 0.0, D)
            A.append(row)
            E.append(np.eye(6)[r])
        for k in range(S - 1):  # joints
            for r in range(3):
                row = np.zeros(nc)
                row[k * (D + 1) : (k + 1) * (D + 1)] = _beta(r, 1.0, D)
                row[(k + 1) * (D + 1) : (k + 2) * (D + 1)] = -_beta(r, 0.0, D)
                A.append(row)
                E.append(np.zeros(6))
        for r in range(3 if rest else 1):  # end
            row = np.zeros(nc)
            row[(S - 1) * (D + 1) :] = _beta(r, 1.0, D)
            A.append(row)
            E.append(np.eye(6)[3 + r])
        A, E = np.array(A), np.array(E)
        m = A.shape[0]
        K = np.block([[2 * Qb, A.T], [A, np.zeros((m, m))]])
        rhs = np.vstack([np.zeros((nc, 6)), E])
        P = np.linalg.solve(K, rhs)[:nc]
        N0 = scipy.linalg.null_space(A)
        nzk = N0.shape[1]
        if nzk:
            Qz = N0.T @ Qb @ N0
            G = pos_gram @ N0
            Gz = G.T @ G / len(fit_s)
            q, V = scipy.linalg.eigh(Qz, Gz)
            Z = N0 @ V
        else:
            q, Z = np.zeros(0), np.zeros((nc, 0))
        pad = nz - nzk
        Z = np.hstack([Z, np.zeros((nc, pad))])
        q = np.concatenate([q, np.ones(pad)])
        M = P.T @ Qb @ P

        def sample_mats(sigma):
            return np.stack([np.hstack([rows(r, sigma) @ P, rows(r, sigma) @ Z]) for r in range(4)])

        Bf = rows(0, fit_s) @ P
        Cf = rows(0, fit_s) @ Z
        return _Kind(P, Z, M, q, sample_mats(col_s), sample_mats(quad_s), sample_mats(lim_s),
                     sample_mats(np.ones(1)), np.linalg.pinv(Cf, rcond=1e-10), Bf)

    return Basis(kind(False), kind(True), col_s, col_w, quad_s, quad_w, lim_s, fit_s)


def kind_constants(rest, structure: NLPStructure) -> _Kind:
    """The constants of the lane's end-state kind (traced ``rest`` flag selects)."""
    b = basis(structure)
    return jax.tree.map(lambda f, r: jnp.where(rest, jnp.asarray(r), jnp.asarray(f)),
                        b.free, b.rest)


# ---------------------------------------------------------------------- variables
def unpack(x, structure: NLPStructure):
    """x (n_x,) -> z (N, nz), tau ()."""
    N, nz = structure.n_dim, structure.nz
    return x[: N * nz].reshape(N, nz), x[-1]


def pack(z, tau):
    return jnp.concatenate([jnp.ravel(z), jnp.reshape(tau, (1,))])


def boundary_vector(params: NLPParams, h):
    """e(h) (6, N) = [p0, v0 h, a0 h^2, pf, vf h, af h^2]."""
    return jnp.stack(
        [params.p0, params.v0 * h, params.a0 * h**2,
         params.goal_p, params.goal_v * h, params.goal_a * h**2]
    )


def coefficients(x, params: NLPParams, structure: NLPStructure, kc: _Kind | None = None):
    """Normalized-time coefficients (S, N, D+1) and T of decision vector x."""
    kc = kind_constants(params.rest, structure) if kc is None else kc
    z, tau = unpack(x, structure)
    T = jnp.exp(tau)
    e = boundary_vector(params, T / structure.segments)
    c = kc.P @ e + kc.Z @ z.T  # (S(D+1), N)
    S, D, N = structure.segments, structure.degree, structure.n_dim
    return c.reshape(S, D + 1, N).transpose(0, 2, 1), T


def to_trajectory(x, params: NLPParams, structure: NLPStructure) -> Trajectory:
    """The plan of x: S equal segments; coasts after T unless ``rest`` (then holds)."""
    c, T = coefficients(x, params, structure)
    return Trajectory.from_normalized(c, T, coast=~jnp.asarray(params.rest, bool))


def equality_residual(x, params: NLPParams, structure: NLPStructure):
    """Max abs residual of the NLP's equality constraints (start, joints, end), in
    m, m/s, m/s^2, from the coefficients themselves (not from the parametrization)."""
    c, T = coefficients(x, params, structure)
    S, D = structure.segments, structure.degree
    h = T / S
    b0 = [jnp.asarray(_beta(r, 0.0, D)) for r in range(3)]
    b1 = [jnp.asarray(_beta(r, 1.0, D)) for r in range(3)]
    res = []
    start = (params.p0, params.v0, params.a0)
    end = (params.goal_p, params.goal_v, params.goal_a)
    for r in range(3):
        res.append(c[0] @ b0[r] / h**r - start[r])
        for k in range(S - 1):
            res.append((c[k] @ b1[r] - c[k + 1] @ b0[r]) / h**r)
        e = c[-1] @ b1[r] / h**r - end[r]
        res.append(e if r == 0 else jnp.where(params.rest, e, 0.0))
    return jnp.max(jnp.abs(jnp.stack(res)))


# ---------------------------------------------------------------------- features
def _features(x, params, structure, mats, derivs):
    """Own derivatives at a sample set: concat([X_r (K, N) for r in derivs] + [T]) -> (K, m)."""
    z, tau = unpack(x, structure)
    T = jnp.exp(tau)
    h = T / structure.segments
    e = boundary_vector(params, h)
    ez = jnp.concatenate([e, z.T], axis=0)  # (6 + nz, N)
    out = [(mats[r] @ ez) / h**r for r in derivs]
    K = mats.shape[1]
    out.append(jnp.broadcast_to(T, (K, 1)))
    return jnp.concatenate(out, axis=-1)


def coast_time(limits: Limits):
    """Length t_c (s) of the coast checked after a free end: v_max / (2 a_max) +
    a_max / (2 j_max), so that the coast at any speed v <= v_max, v t_c, is at least the
    distance v^2 / (2 a_max) + v a_max / (2 j_max) of a jerk-limited stop from v (from
    zero acceleration; exact for v >= a_max^2 / j_max)."""
    return limits.v_max / (2.0 * limits.a_max) + limits.a_max / (2.0 * limits.j_max)


def _col_samples(params, structure):
    """Collision rows: (s, off, w, on) (n_col,) each.  Row k is at time T s_k + off_k;
    w_k its barrier quadrature weight; on_k whether its constraint is active."""
    b = basis(structure)
    s = jnp.asarray(b.col_s)
    Kc = len(b.col_s)
    off = jnp.zeros(Kc)
    w = jnp.asarray(b.col_w)
    on = jnp.ones(Kc, bool)
    n = structure.n_coast
    if n:
        sig = jnp.arange(1, n + 1) / n
        s = jnp.concatenate([s, jnp.ones(n)])
        off = jnp.concatenate([off, sig * coast_time(params.limits)])
        w = jnp.concatenate([w, jnp.zeros(n)])
        on = jnp.concatenate([on, jnp.broadcast_to(~jnp.asarray(params.rest, bool), (n,))])
    return s, off, w, on


def _col_features(x, params, structure, kc, derivs):
    """:func:`_features` at the collision samples, then (coast) the positions
    p(T) + v(T) t_c k / n (derivs must be (0,) when there are coast rows)."""
    y = _features(x, params, structure, kc.col, derivs)
    n = structure.n_coast
    if not n:
        return y
    N = structure.n_dim
    e = _features(x, params, structure, kc.end, (0, 1))[0]  # (p(T), v(T), T)
    t = jnp.arange(1, n + 1) / n * coast_time(params.limits)
    yk = jnp.concatenate([e[:N] + t[:, None] * e[N : 2 * N], jnp.broadcast_to(e[-1], (n, 1))],
                         axis=-1)
    return jnp.concatenate([y, yk], axis=0)


def _others_derivs(others: Trajectory, mask, t, R: int):
    """Derivatives 0..R of the others at times t (K,) -> list of (K, Mo, N).

    After an other's end time it holds (coast False) or coasts (coast True).
    """
    c = others.coeffs
    b = others.breaks
    ok = mask & jnp.all(jnp.isfinite(c), axis=(-1, -2, -3)) & jnp.all(jnp.isfinite(b), axis=-1)
    c = jnp.where(ok[:, None, None, None], c, 0.0)
    b = jnp.where(ok[:, None], b, 0.0)
    So, N, Kd = c.shape[-3:]
    To = b[:, -1]
    tt = t[:, None]
    tc = jnp.clip(tt, 0.0, To[None, :])  # (K, Mo)
    if So == 1:  # closed-form predictions: one segment, nothing to look up
        lo, hi = b[None, :, 0], b[None, :, 1]
        ck = c[None, :, 0]  # (1, Mo, N, Kd)
    else:  # the segment of each time, selected elementwise (a gather was ~5x slower on CPU)
        k = jnp.clip(jnp.sum(b[None, :, 1:So] <= tc[..., None], axis=-1), 0, So - 1)
        sel = [k == i for i in range(So)]
        pick = lambda arr: sum(jnp.where(m, a, 0.0) for m, a in zip(sel, arr, strict=True))
        lo = pick([b[None, :, i] for i in range(So)])
        hi = pick([b[None, :, i + 1] for i in range(So)])
        ck = sum(jnp.where(m[..., None, None], c[None, :, i], 0.0) for i, m in enumerate(sel))
    h = hi - lo
    he = jnp.where(h > 0, h, 1.0)
    s = jnp.where(h > 0, (tc - lo) / he, 0.0)
    vals = []
    for r in range(max(R, 1) + 1):
        if r < Kd:
            f = jnp.asarray([_falling(i, r) for i in range(r, Kd)], c.dtype)
            cr = ck[..., r:] * f
            v = cr[..., -1]
            for i in range(cr.shape[-1] - 2, -1, -1):
                v = v * s[..., None] + cr[..., i]
            vals.append(v / he[..., None] ** r)
        else:
            vals.append(jnp.zeros(ck.shape[:-1], c.dtype))
    after = (tt > To[None, :])[..., None]
    coast = others.coast[None, :, None]
    out = [vals[0] + jnp.where(after & coast, vals[1] * (tt - To[None, :])[..., None], 0.0)]
    if R >= 1:
        out.append(jnp.where(after & ~coast, 0.0, vals[1]))
    for r in range(2, R + 1):
        out.append(jnp.where(after, 0.0, vals[r]))
    return out


def sexp(u):
    """exp(u) for u <= 30, its quadratic Taylor continuation above (finite, C^2)."""
    a = jnp.minimum(u, SEXP_KNEE)
    d = jnp.maximum(u - SEXP_KNEE, 0.0)
    return jnp.exp(a) * (1.0 + d + 0.5 * d * d)


def al_term(g, lam, mu):
    """Augmented-Lagrangian term of g >= 0 with multiplier lam >= 0, penalty mu > 0."""
    act = lam - mu * g > 0
    return jnp.where(act, -lam * g + 0.5 * mu * g * g, -0.5 * lam * lam / mu)


# ---------------------------------------------------------------------- local terms
def _collision_local(y, o, w, lam, params, structure, mu, on=True):
    """Sampled collision terms (barrier, AL of the constraints) at one sample: y = (p (N),
    T), o (Mo, N) the others' positions there; ``on``: its constraint is active."""
    N = structure.n_dim
    p = y[:N]
    T = y[-1]
    dx = p - o
    d2 = jnp.sum(dx * dx, axis=-1)
    mask = params.other_mask
    rho = params.radius + params.other_radius
    wt = params.weights
    val = 0.0
    if structure.barrier:
        d = jnp.sqrt(d2 + DIST_EPS2)
        ex = jnp.exp(-wt.k_p * (d - rho))
        val = val + wt.q_obs * T * w * jnp.sum(jnp.where(mask, ex, 0.0))
    if structure.collision_constraints and lam is not None:
        g = d2 - rho * rho
        val = val + jnp.sum(jnp.where(mask & on, al_term(g, lam, mu), 0.0))
    return val


def _limits_local(y, w, params, structure):
    """Soft limits at one quadrature node: y = (v, a, j, T)."""
    N = structure.n_dim
    lim = params.limits
    T = y[-1]
    v, a, j = y[:N], y[N : 2 * N], y[2 * N : 3 * N]
    f = (
        sexp(v @ v - lim.v_max**2)
        + sexp(a @ a - lim.a_max**2)
        + sexp(j @ j - lim.j_max**2)
    )
    return params.weights.q_lim * T * w * f


def _hard_g(y, params, structure):
    N = structure.n_dim
    lim = params.limits
    v, a, j = y[:N], y[N : 2 * N], y[2 * N : 3 * N]
    return jnp.stack([1 - v @ v / lim.v_max**2, 1 - a @ a / lim.a_max**2, 1 - j @ j / lim.j_max**2])


def _hard_local(y, lam, params, structure, mu):
    return jnp.sum(al_term(_hard_g(y, params, structure), lam, mu))


def _smooth_time(x, params, structure, kc):
    z, tau = unpack(x, structure)
    T = jnp.exp(tau)
    h = T / structure.segments
    e = boundary_vector(params, h)
    jerk = (jnp.sum(e * (kc.M @ e)) + jnp.sum(kc.q * z * z)) / h**5
    return params.weights.q_dynm * jerk + params.weights.k_t * T


_E_POW = np.array([0, 1, 2, 0, 1, 2])  # the power of h in each row of boundary_vector


def _smooth_time_derivs(x, params, structure, kc):
    """(value, gradient, Hessian) of :func:`_smooth_time` in closed form: with h = T / S
    and e(h) = E diag(h^k) (boundary_vector), the jerk integral is
    sum_ij W_ij h^(k_i + k_j - 5) + h^-5 sum q z^2, W = M * (E E^T); each power of h has
    tau derivatives m h^m and m^2 h^m."""
    z, tau = unpack(x, structure)
    T = jnp.exp(tau)
    h = T / structure.segments
    E = jnp.stack([params.p0, params.v0, params.a0, params.goal_p, params.goal_v,
                   params.goal_a])  # (6, N)
    m = jnp.asarray(_E_POW[:, None] + _E_POW[None, :] - 5, jnp.float64)
    hm = jnp.exp(m * jnp.log(h))
    W = kc.M * (E @ E.T) * hm
    h5 = jnp.exp(-5.0 * jnp.log(h))
    qz = kc.q[None, :] * z  # (N, nz)
    Qz = jnp.sum(qz * z) * h5
    wd, kt = params.weights.q_dynm, params.weights.k_t
    v = wd * (jnp.sum(W) + Qz) + kt * T
    g = jnp.concatenate([jnp.ravel(2.0 * wd * h5 * qz),
                         (wd * (jnp.sum(W * m) - 5.0 * Qz) + kt * T)[None]])
    dz = jnp.ravel(jnp.broadcast_to(2.0 * wd * h5 * kc.q[None, :], z.shape))
    htt = wd * (jnp.sum(W * m * m) + 25.0 * Qz) + kt * T
    H = jnp.diag(jnp.concatenate([dz, htt[None]]))
    hzt = jnp.ravel(-10.0 * wd * h5 * qz)
    H = H.at[:-1, -1].set(hzt).at[-1, :-1].set(hzt)
    return v, g, H


def _has_collision(structure):
    """Whether the NLP has SAMPLED collision terms (barrier or constraints)."""
    return structure.barrier or structure.collision_constraints


def _paper_exact(x, params, structure, kc):
    """The "paper" collision term integrated exactly (module doc): q_obs sum_j
    (exp(-k_p (d_j(0) - rho_j)) - exp(-k_p (d_j(T) - rho_j))) / k_p, d_j(t) = |x(t) -
    x_j(t)| (softened by DIST_EPS2 as the sampled terms are)."""
    N = structure.n_dim
    yT = _features(x, params, structure, kc.end, (0,))[0]  # (p(T), T)
    T = yT[-1]
    o = _others_derivs(params.others, params.other_mask, jnp.stack([jnp.zeros_like(T), T]), 0)[0]
    p = jnp.stack([params.p0, yT[:N]])  # (2, N)
    d = jnp.sqrt(jnp.sum((p[:, None, :] - o) ** 2, axis=-1) + DIST_EPS2)  # (2, Mo)
    rho = params.radius + params.other_radius
    wt = params.weights
    ex = jnp.where(params.other_mask, jnp.exp(-wt.k_p * (d - rho)), 0.0)
    return wt.q_obs * jnp.sum(ex[0] - ex[1]) / wt.k_p


# ---------------------------------------------------------------------- values
def _terms(x, params, structure, kc, mult: Multipliers | None, mu, with_g: bool = False):
    """Objective (+ AL terms if ``mult`` given): exact values, differentiable in x.

    With ``with_g`` also the inequality constraints g(x) (as :func:`constraints`, bitwise
    equal), sharing the features and the other robots' positions: (value, Multipliers).
    """
    b = basis(structure)
    Mo = params.other_mask.shape[-1]
    val = _smooth_time(x, params, structure, kc)
    yq = _features(x, params, structure, kc.quad, (1, 2, 3))
    val = val + jnp.sum(jax.vmap(lambda y, w: _limits_local(y, w, params, structure))(
        yq, jnp.asarray(b.quad_w)))
    gc = jnp.ones((structure.n_col, Mo), x.dtype)
    if structure.paper:
        val = val + _paper_exact(x, params, structure, kc)
    if _has_collision(structure):
        N = structure.n_dim
        yc = _col_features(x, params, structure, kc, (0,))
        T = yc[0, -1]
        s, off, w, on = _col_samples(params, structure)
        o0 = _others_derivs(params.others, params.other_mask, T * s + off, 0)[0]
        lam = mult.collision if mult is not None else None

        def one(y, a0, wk, lk, ok):
            return _collision_local(y, a0, wk, lk, params, structure, mu, ok)

        vals = jax.vmap(one)(yc, o0, w, lam, on)
        val = val + jnp.sum(vals)
        if with_g and structure.collision_constraints:
            dx = yc[:, None, :N] - o0
            rho = params.radius + params.other_radius
            gc = jnp.where(params.other_mask & on[:, None],
                           jnp.sum(dx * dx, axis=-1) - rho**2, 1.0)
    gh = jnp.ones((len(b.lim_s), 3), x.dtype)
    if structure.hard_limits and (mult is not None or with_g):
        yh = _features(x, params, structure, kc.lim, (1, 2, 3))
        if mult is not None:
            val = val + jnp.sum(jax.vmap(lambda y, l: _hard_local(y, l, params, structure, mu))(
                yh, mult.limits))
        gh = jax.vmap(lambda y: _hard_g(y, params, structure))(yh)
    if with_g:
        return val, Multipliers(gc, gh)
    return val


def objective(x, params: NLPParams, structure: NLPStructure):
    """The NLP objective at x (no constraint terms).  Differentiable (used by SLSQP)."""
    kc = kind_constants(params.rest, structure)
    return _terms(x, params, structure, kc, None, 1.0)


def constraints(x, params: NLPParams, structure: NLPStructure):
    """Inequality constraints g(x) >= 0 as (collision (Kc, Mo), limits (Kh, 3)).

    Collision: d^2 - rho^2 (m^2) at the collision samples (masked pairs: +1; zeros of
    shape (Kc, Mo) when the mode has no collision constraints).  Limits: 1 - |x^(k)|^2 /
    tau_k^2 at the hard-limit samples (+1 when ``hard_limits`` is off).
    """
    kc = kind_constants(params.rest, structure)
    return _constraints(x, params, structure, kc)


def _constraints(x, params, structure, kc):
    b = basis(structure)
    Mo = params.other_mask.shape[-1]
    Kc, Kh = structure.n_col, len(b.lim_s)
    if structure.collision_constraints:
        yc = _col_features(x, params, structure, kc, (0,))
        T = yc[0, -1]
        s, off, _, on = _col_samples(params, structure)
        o = _others_derivs(params.others, params.other_mask, T * s + off, 0)[0]
        dx = yc[:, None, : structure.n_dim] - o
        rho = params.radius + params.other_radius
        gc = jnp.sum(dx * dx, axis=-1) - rho**2
        gc = jnp.where(params.other_mask & on[:, None], gc, 1.0)
    else:
        gc = jnp.ones((Kc, Mo), x.dtype)
    if structure.hard_limits:
        yh = _features(x, params, structure, kc.lim, (1, 2, 3))
        gh = jax.vmap(lambda y: _hard_g(y, params, structure))(yh)
    else:
        gh = jnp.ones((Kh, 3), x.dtype)
    return Multipliers(gc, gh)


def merit(x, params, structure, kc, mult: Multipliers, mu):
    """Augmented Lagrangian value: objective + AL terms of the inequality constraints."""
    return _terms(x, params, structure, kc, mult, mu)


def merit_and_constraints(x, params, structure, kc, mult: Multipliers, mu):
    """(:func:`merit`, :func:`constraints`) at x in one pass (shared features and
    other-robot positions; what a line search needs at its accepted point)."""
    return _terms(x, params, structure, kc, mult, mu, with_g=True)


# ---------------------------------------------------------------------- derivatives
def _vgh(f, y, *args):
    def g_aux(yy):
        v, g = jax.value_and_grad(f)(yy, *args)
        return g, (v, g)

    H, (v, g) = jax.jacfwd(g_aux, has_aux=True)(y)
    return v, g, H


def _d012(fn, x):
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
    """:class:`OthersPrep` of the others' predictions (what :func:`_others_derivs` reads
    at every call, cleaned and scaled once)."""
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
        f = np.array([_falling(i, r) for i in range(r, Kd)], float)
        rows.append(cc[..., r:] * f / (he[None, :, :, None] ** r))
    brk = b[:, 1:So].T if So > 1 else jnp.zeros((1, b.shape[0]), b.dtype)
    return OthersPrep(tuple(rows), lo, he, h > 0, brk, b[:, -1], others.coast)


def _jet(op: OthersPrep, t, R: int):
    """The others' derivatives 0..R at times t (K,): a list of (N, Mo, K) arrays (what
    :func:`_others_derivs` gives, laid out components first and samples last).  After an
    other's end it holds (coast False) or coasts (coast True)."""
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


def _chain(z, T, jets, G, Hgg, HgT, GT, HTT):
    """(gradient (n,), Hessian (n, n)) in x = (z, tau) of a sum over samples k of local
    terms F_k(P_1k, .., P_mk, T) through m feature groups P_g = b_g(tau) + z C_g(tau)^T
    (N, K) each and T = exp(tau) (the chain rule of that composition; every factor comes
    from autodiff).  The groups are stacked on a leading axis.

    jets: ((b, C), (b', C'), (b'', C'')) from :func:`_affine_jets`, b (m, N, K) and C
    (m, K, nz).  G, Hgg, HgT: the local gradient (m, N, K), Hessian (m, N, N, K) and T
    cross term (m, N, K) of F in each group; GT, HTT (K,): its T gradient and curvature.
    The local Hessian has no blocks between groups (true of the radial terms here)."""
    N, nz = z.shape
    (_, C), (b1, C1), (b2, C2) = jets
    Ct, C1t, C2t = (jnp.swapaxes(c, 1, 2)[:, None] for c in (C, C1, C2))  # (m, 1, nz, K)
    pt = b1 + jnp.sum(z[None, :, :, None] * C1t, axis=2)  # (m, N, K)
    ptt = b2 + jnp.sum(z[None, :, :, None] * C2t, axis=2)
    gz = jnp.sum(G[:, :, None, :] * Ct, axis=(0, 3))  # (N, nz)
    gt = jnp.sum(GT) * T + jnp.sum(G * pt)
    CC = Ct[:, 0, :, None, :] * Ct[:, 0, None, :, :]  # (m, nz, nz, K)
    hzz = jnp.sum(Hgg[:, :, None, :, None, :] * CC[:, None, :, None, :, :], axis=(0, 5))
    Hpt = jnp.sum(Hgg * pt[:, None, :, :], axis=2)  # (m, N, K)
    hzt = (jnp.sum((Hpt + HgT * T)[:, :, None, :] * Ct, axis=(0, 3))
           + jnp.sum(G[:, :, None, :] * C1t, axis=(0, 3)))
    htt = (jnp.sum(T * T * HTT + T * GT) + jnp.sum(pt * Hpt) + 2.0 * T * jnp.sum(HgT * pt)
           + jnp.sum(G * ptt))
    n = N * nz + 1
    H = jnp.zeros((n, n), z.dtype)
    H = H.at[:-1, :-1].set(hzz.reshape(N * nz, N * nz))
    H = H.at[:-1, -1].set(hzt.reshape(-1)).at[-1, :-1].set(hzt.reshape(-1)).at[-1, -1].set(htt)
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
    """Value, gradient and Hessian of the soft limits (``w`` the quadrature weights) or of
    the hard-limit AL terms (``lam`` (K, 3)) through their three radial feature groups;
    and the features Y (3, N, K)."""
    lim = params.limits
    (b, C), _, _ = jets
    Y = b + jnp.sum(z[None, :, :, None] * jnp.swapaxes(C, 1, 2)[:, None], axis=2)  # (3, N, K)
    rho = jnp.sum(Y * Y, axis=1)  # (3, K)
    tm2 = (jnp.stack([lim.v_max, lim.a_max, lim.j_max]) ** 2)[:, None]
    K = Y.shape[-1]
    if soft:
        av, a1, a2 = _d012(lambda rr: params.weights.q_lim * w * sexp(rr - tm2), rho)
        cd, cdd = T * a1, T * a2
        val = T * jnp.sum(av)
        GT = jnp.sum(av, axis=0)
        HgT = 2.0 * a1[:, None] * Y
    else:
        bv, cd, cdd = _d012(lambda rr: al_term(1.0 - rr / tm2, lam.T, mu), rho)
        val = jnp.sum(bv)
        GT = jnp.zeros(K, z.dtype)
        HgT = jnp.zeros_like(Y)
    N = z.shape[0]
    G = 2.0 * cd[:, None] * Y
    Hgg = (4.0 * cdd[:, None, None] * Y[:, :, None] * Y[:, None, :]
           + 2.0 * cd[:, None, None] * jnp.eye(N, dtype=z.dtype)[:, :, None])
    g, H = _chain(z, T, jets, G, Hgg, HgT, GT, jnp.zeros(K, z.dtype))
    return val, g, H, Y


def _col_affine(params, structure, kc):
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
            E0, E1 = kc.end[0, 0], kc.end[1, 0]
            be = (E0[:6] @ e)[:, None] + (E1[:6] @ e)[:, None] * (tc / h)[None, :]
            Ce = E0[None, 6:] + (tc / h)[:, None] * E1[None, 6:]
            b = jnp.concatenate([b, be[None]], axis=2)
            C = jnp.concatenate([C, Ce[None]], axis=1)
        return b, C

    return f


def _col_jets(params, structure, kc, tau):
    """Jets of :func:`_col_affine`'s positions (value, first and second tau derivative)."""
    return _affine_jets(_col_affine(params, structure, kc), tau)


def merit_shapes(zs, tau, params, structure, kc, mult: Multipliers, mu,
                 others: OthersPrep | None = None):
    """:func:`merit` at the C points x = (z, tau) for the shapes zs (C, N, nz) at ONE
    horizon tau: the values (C,), equal to a vmap of :func:`merit` over the points to
    rounding.  What depends on tau alone (boundary terms, the other robots' positions at
    the samples) is formed once, and the terms are laid out as in :func:`merit_derivs`
    (components first): on the benchmark's NLPs (9 others) five shapes cost about what
    one :func:`merit` call costs, ~4x less than a vmap of it over the five points (used
    by :func:`jaxplan.solver.initial_guess`)."""
    b = basis(structure)
    T = jnp.exp(tau)
    h = T / structure.segments
    wt = params.weights
    e = boundary_vector(params, h)
    val = (wt.q_dynm * (jnp.sum(e * (kc.M @ e)) + jnp.sum(kc.q * zs * zs, axis=(1, 2))) / h**5
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
        val = val + jax.vmap(lambda z: _paper_exact(pack(z, tau), params, structure, kc))(zs)
    if _has_collision(structure):
        op = prepare_others(params.others, params.other_mask) if others is None else others
        s, off, w, on = _col_samples(params, structure)
        bp, C = _col_affine(params, structure, kc)(tau)
        p = bp[0][None] + jnp.einsum("cnz,kz->cnk", zs, C[0])  # (C, N, K)
        X = p[:, :, None, :] - _jet(op, T * s + off, 0)[0][None]  # (C, N, Mo, K)
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
        val = val + jnp.sum(al_term(1.0 - radial("lim") / tm2, mult.limits.T, mu), axis=(1, 2))
    return val


def merit_derivs(x, params, structure, kc, mult: Multipliers, mu, with_g: bool = False,
                 others: OthersPrep | None = None):
    """(value, gradient (n,), Hessian (n, n)) of the augmented Lagrangian at x; with
    ``with_g`` also the inequality constraints g(x) (as :func:`constraints`, from the
    same features and other-robot positions: what the solver needs at a trial point).

    By the features' block structure (module doc): each axis's features are affine in
    that axis's shape variables, so the chain rule (:func:`_chain`) runs on small
    per-sample blocks; the other robots' jets come from ``others`` (formed once per solve
    by :func:`prepare_others`; here when None)."""
    b = basis(structure)
    N = structure.n_dim
    Mo = params.other_mask.shape[-1]
    z, tau = unpack(x, structure)
    T = jnp.exp(tau)
    gc = jnp.ones((structure.n_col, Mo), x.dtype)
    gh = jnp.ones((len(b.lim_s), 3), x.dtype)
    tv, tg, tH = _smooth_time_derivs(x, params, structure, kc)
    jq = _lim_jets(params, structure, "quad", tau)
    v, g, H, _ = _lim_terms(z, T, jq, jnp.asarray(b.quad_w), None, params, mu, True)
    tv, tg, tH = tv + v, tg + g, tH + H
    if structure.paper:
        v, g, H = _vgh(lambda xx: _paper_exact(xx, params, structure, kc), x)
        tv, tg, tH = tv + v, tg + g, tH + H
    if _has_collision(structure):
        op = prepare_others(params.others, params.other_mask) if others is None else others
        s, off, w, on = _col_samples(params, structure)
        jets = _col_jets(params, structure, kc, tau)
        (bp, C), _, _ = jets
        p = bp[0] + jnp.sum(z[:, :, None] * C[0].T[None], axis=1)  # (N, K)
        o0, o1, o2 = _jet(op, T * s + off, 2)  # (N, Mo, K)
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
            av, a1, a2 = _d012(af, r)
        else:
            av, a1, a2 = zero
        if structure.collision_constraints:
            use = mask & on[None, :]
            lam = mult.collision.T
            bf = lambda rr: jnp.where(use, al_term(rr - rho * rho, lam, mu), 0.0)
            bv, b1, b2 = _d012(bf, r)
            if with_g:
                gc = jnp.where(use, r - rho * rho, 1.0).T
        else:
            bv, b1, b2 = zero
        cd = T * a1 + b1
        cdd = T * a2 + b2
        Xu = jnp.sum(X * u, axis=0)
        v = jnp.sum(T * av + bv)
        Gp = 2.0 * jnp.sum(cd * X, axis=1)
        GT = jnp.sum(2.0 * cd * Xu + av, axis=0)
        eye = jnp.eye(N, dtype=x.dtype)[:, :, None]
        Hpp = (4.0 * jnp.sum(cdd * X[:, None] * X[None, :], axis=2)
               + 2.0 * jnp.sum(cd, axis=0) * eye)
        HpT = jnp.sum((4.0 * cdd * Xu + 2.0 * a1) * X + 2.0 * cd * u, axis=1)
        q = jnp.sum(u * u + X * ww, axis=0)
        HTT = jnp.sum(cdd * (2.0 * Xu) ** 2 + 2.0 * cd * q + 4.0 * a1 * Xu, axis=0)
        g, H = _chain(z, T, jets, Gp[None], Hpp[None], HpT[None], GT, HTT)
        tv, tg, tH = tv + v, tg + g, tH + H
    if structure.hard_limits:
        jh = _lim_jets(params, structure, "lim", tau)
        v, g, H, Yh = _lim_terms(z, T, jh, None, mult.limits, params, mu, False)
        tv, tg, tH = tv + v, tg + g, tH + H
        if with_g:
            lim = params.limits
            tm2 = jnp.stack([lim.v_max, lim.a_max, lim.j_max]) ** 2
            gh = (1.0 - jnp.sum(Yh * Yh, axis=1) / tm2[:, None]).T
    if with_g:
        return tv, tg, tH, Multipliers(gc, gh)
    return tv, tg, tH
