"""The NLP's static bases and its decision variables (docs/MATH.md section 2).

:func:`basis` builds, once per :class:`NLPStructure` (numpy, cached), the null-space
parametrization c = P e(h) + Z z of each end-state kind and its rows at the sample sets;
:func:`kind_constants` selects a lane's kind.  :func:`pack` / :func:`unpack` map between
x = (z, tau) and its parts; :func:`coefficients` and :func:`to_trajectory` turn x into a
plan; :func:`equality_residual` checks the equality constraints from the coefficients.
"""

from __future__ import annotations

import functools
from math import comb, factorial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg

from jaxplan.nlp.types import NLPParams, NLPStructure
from jaxplan.trajectory import Trajectory


# ---------------------------------------------------------------------- static basis
def falling(i: int, r: int) -> int:
    """The falling factorial i (i - 1) ... (i - r + 1): d^r/ds^r s^i = falling(i, r) s^(i - r)."""
    return factorial(i) // factorial(i - r) if i >= r else 0


def _beta(r: int, s: float, D: int) -> np.ndarray:
    """Row (D+1,): d^r/ds^r of the monomials at s."""
    return np.array([falling(i, r) * s ** (i - r) if i >= r else 0.0 for i in range(D + 1)])


def _jerk_gram(D: int) -> np.ndarray:
    Q = np.zeros((D + 1, D + 1))
    for i in range(3, D + 1):
        for j in range(3, D + 1):
            Q[i, j] = falling(i, 3) * falling(j, 3) / (i + j - 5)
    return Q


def _seg_local(sigma: np.ndarray, S: int):
    k = np.minimum(np.floor(sigma * S).astype(int), S - 1)
    return k, sigma * S - k


class KindConstants(NamedTuple):
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
    free: KindConstants
    rest: KindConstants
    col_s: np.ndarray  # (Kc,) global normalized sample times
    col_w: np.ndarray  # (Kc,) quadrature weights (sum 1)
    quad_s: np.ndarray
    quad_w: np.ndarray
    lim_s: np.ndarray
    fit_s: np.ndarray


def _control_points(D: int, S: int, Q: int) -> tuple[np.ndarray, np.ndarray]:
    """The hard limits' rows: each segment cut into Q equal pieces; on each, derivative
    r (a polynomial of degree n = D - r in the piece's own time u) has n + 1 Bernstein
    control points b = B^-1 f, from its values f at n + 1 nodes u_l = (l + 1/2) / (n + 1)
    (B[l, j] = C(n, j) u_l^j (1 - u_l)^(n - j)).  Every piece gets D rows (the velocity's
    count; the acceleration's and jerk's last control point repeated), so one row set
    serves r = 1..3.

    Returns (lim_s (S Q D,) global normalized node times, mix (4, S Q D, S Q D): row i of
    mix[r] combines the rows of derivative r at lim_s into control point i; row 0 (the
    position, unused) is the identity)."""
    u = (np.arange(D) + 0.5) / D  # D nodes per piece
    pieces = S * Q
    lim_s = ((np.arange(pieces)[:, None] + u[None]) / pieces).ravel()
    K = pieces * D
    mix = np.zeros((4, K, K))
    mix[0] = np.eye(K)
    for r in (1, 2, 3):
        n = D - r
        ur = (np.arange(n + 1) + 0.5) / (n + 1)
        B = np.array([[comb(n, j) * x**j * (1 - x) ** (n - j) for j in range(n + 1)]
                      for x in ur])
        # the values at ur from the values at u (exact: degree n < D interpolates)
        V = np.vander(u, D, increasing=True)
        Vr = np.vander(ur, D, increasing=True)
        to_cp = np.linalg.solve(B, Vr @ np.linalg.inv(V))  # (n + 1, D)
        to_cp = np.vstack([to_cp, np.repeat(to_cp[-1:], D - n - 1, axis=0)])
        for p in range(pieces):
            mix[r, p * D:(p + 1) * D, p * D:(p + 1) * D] = to_cp
    return lim_s, mix


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
    lim_s, lim_mix = _control_points(D, S, structure.limit_subdivisions)
    fit_s = np.linspace(0.0, 1.0, 4 * (D + 1) * S + 1)

    def rows(r, sigma):
        k, s = _seg_local(np.asarray(sigma, float), S)
        out = np.zeros((len(k), nc))
        for i, (kk, ss) in enumerate(zip(k, s, strict=True)):
            out[i, kk * (D + 1) : (kk + 1) * (D + 1)] = _beta(r, ss, D)
        return out

    Qb = scipy.linalg.block_diag(*[_jerk_gram(D)] * S)
    pos_gram = rows(0, fit_s)

    def kind(rest: bool) -> KindConstants:
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

        def control_mats():
            # each row a Bernstein control point of derivative r on one piece: a fixed
            # combination (lim_mix[r]) of the derivative at that piece's nodes lim_s
            vals = sample_mats(lim_s)
            return np.stack([lim_mix[r] @ vals[r] for r in range(4)])

        Bf = rows(0, fit_s) @ P
        Cf = rows(0, fit_s) @ Z
        return KindConstants(P, Z, M, q, sample_mats(col_s), sample_mats(quad_s),
                             control_mats(), sample_mats(np.ones(1)),
                             np.linalg.pinv(Cf, rcond=1e-10), Bf)

    return Basis(kind(False), kind(True), col_s, col_w, quad_s, quad_w, lim_s, fit_s)


def kind_constants(rest, structure: NLPStructure) -> KindConstants:
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
    """z (N, nz), tau () -> x (n_x,) (the inverse of :func:`unpack`)."""
    return jnp.concatenate([jnp.ravel(z), jnp.reshape(tau, (1,))])


def boundary_vector(params: NLPParams, h):
    """e(h) (6, N) = [p0, v0 h, a0 h^2, pf, vf h, af h^2]."""
    return jnp.stack(
        [params.p0, params.v0 * h, params.a0 * h**2,
         params.goal_p, params.goal_v * h, params.goal_a * h**2]
    )


def coefficients(x, params: NLPParams, structure: NLPStructure, kind: KindConstants | None = None):
    """Normalized-time coefficients (S, N, D+1) and T of decision vector x."""
    kind = kind_constants(params.rest, structure) if kind is None else kind
    z, tau = unpack(x, structure)
    T = jnp.exp(tau)
    e = boundary_vector(params, T / structure.segments)
    c = kind.P @ e + kind.Z @ z.T  # (S(D+1), N)
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
