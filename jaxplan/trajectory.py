"""Piecewise-polynomial trajectories in normalized time.

A :class:`Trajectory` holds, per axis, ``S`` polynomial segments of degree ``D``.
Segment ``k`` covers ``[breaks[k], breaks[k+1]]`` seconds from the trajectory's start
and is stored as monomial coefficients in its own normalized time

    s = (t - breaks[k]) / h_k  in [0, 1],   h_k = breaks[k+1] - breaks[k],

lowest power first.  Normalized time keeps the numbers well conditioned (raw seconds
reach t^10 in squared terms).  The paper's trajectory is D = 5, S = 1.

Conventions
-----------
* Shapes: ``coeffs (..., S, N, D+1)`` metres; ``breaks (..., S+1)`` seconds with
  ``breaks[..., 0] == 0`` and non-decreasing; ``coast (...)`` bool.  ``...`` is any batch
  shape (robots, scenarios, ...).  N is the number of spatial axes (3 in the air, 2 on
  the ground).
* Before the start (t < 0) the trajectory is evaluated at t = 0.
* After the end (t > T = breaks[..., -1]) the trajectory either **holds** its end
  position (``coast=False``: velocity, acceleration and jerk are 0) or **coasts** at its
  end velocity (``coast=True``: p(T) + v(T) (t - T), acceleration and jerk 0).
  Predicted free-end trajectories coast; rest-end ones hold (their end velocity is 0
  anyway).  At t = T exactly the polynomial's own values are returned.
* Zero-length segments (h_k = 0) are allowed; they are skipped by evaluation, except
  when every segment has zero length (T = 0).  A zero-length segment's "normalized"
  time unit is one second, so its coefficients are a Taylor expansion in seconds at
  its break: a T = 0 trajectory therefore still carries an end position and velocity
  (this is what :meth:`Trajectory.shift` returns past the end).

Everything is a pure function of arrays: jit- and vmap-able, float64 under
``import jaxplan``.
"""

from __future__ import annotations

from math import comb, factorial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.pytree import traced


def _falling(i: int, d: int) -> int:
    """i (i-1) ... (i-d+1): the factor d/ds^d brings to s^i."""
    return factorial(i) // factorial(i - d) if i >= d else 0


def _deriv_coeffs(c: jax.Array, d: int) -> jax.Array:
    """Coefficients (..., D+1-d) of the d-th derivative (in s) of polynomials c (..., D+1)."""
    n = c.shape[-1]
    if d >= n:
        return jnp.zeros(c.shape[:-1] + (1,), c.dtype)
    f = jnp.asarray([_falling(i, d) for i in range(d, n)], dtype=c.dtype)
    return c[..., d:] * f


def _horner(c: jax.Array, s: jax.Array) -> jax.Array:
    """Evaluate polynomials c (..., K) (lowest power first) at s (broadcast against c[..., 0])."""
    out = c[..., -1]
    for i in range(c.shape[-1] - 2, -1, -1):
        out = out * s + c[..., i]
    return out


class Trajectory(NamedTuple):
    """A batch of piecewise-polynomial trajectories (a JAX pytree).

    Attributes:
        coeffs: (..., S, N, D+1) monomial coefficients of each segment in its normalized
            time s in [0, 1], lowest power first, metres.
        breaks: (..., S+1) segment boundaries in seconds from the start; breaks[..., 0] = 0.
        coast: (...,) bool; after the end, coast at the end velocity (True) or hold the
            end position (False).
    """

    coeffs: jax.Array
    breaks: jax.Array
    coast: jax.Array

    # ------------------------------------------------------------------ shape facts
    @property
    def batch_shape(self) -> tuple[int, ...]:
        return tuple(self.breaks.shape[:-1])

    @property
    def num_segments(self) -> int:
        return self.coeffs.shape[-3]

    @property
    def ndim_space(self) -> int:
        return self.coeffs.shape[-2]

    @property
    def degree(self) -> int:
        return self.coeffs.shape[-1] - 1

    @property
    def duration(self) -> jax.Array:
        """(...,) seconds: the end time T of the polynomial part."""
        return self.breaks[..., -1]

    # ------------------------------------------------------------------ construction
    @staticmethod
    def from_normalized(coeffs, duration, coast=False) -> Trajectory:
        """Equal-length segments over [0, duration].

        Args:
            coeffs: (..., S, N, D+1) per-segment normalized-time coefficients, metres.
            duration: (...,) total duration T, seconds (>= 0).
            coast: bool or (...,) bool.
        """
        coeffs = jnp.asarray(coeffs)
        duration = jnp.asarray(duration, dtype=coeffs.dtype)
        S = coeffs.shape[-3]
        frac = jnp.linspace(0.0, 1.0, S + 1, dtype=coeffs.dtype)
        breaks = duration[..., None] * frac
        coast = jnp.broadcast_to(jnp.asarray(coast, dtype=bool), duration.shape)
        return Trajectory(coeffs, breaks, coast)

    @staticmethod
    def from_monomials(coeffs_sec, breaks, coast=False) -> Trajectory:
        """Inverse of :meth:`to_monomials`.

        Args:
            coeffs_sec: (..., S, N, D+1) coefficients in (t - breaks[k]) seconds, lowest
                power first.
            breaks: (..., S+1) seconds, breaks[..., 0] = 0, non-decreasing.
            coast: bool or (...,) bool.
        """
        coeffs_sec = jnp.asarray(coeffs_sec)
        breaks = jnp.asarray(breaks, dtype=coeffs_sec.dtype)
        h = _h_eff(breaks)  # (..., S)
        powers = jnp.arange(coeffs_sec.shape[-1], dtype=coeffs_sec.dtype)
        scale = h[..., :, None, None] ** powers
        coast = jnp.broadcast_to(jnp.asarray(coast, dtype=bool), breaks.shape[:-1])
        return Trajectory(coeffs_sec * scale, breaks, coast)

    @staticmethod
    def hold(position, degree: int = 5, segments: int = 1) -> Trajectory:
        """A zero-duration trajectory that holds ``position`` (..., N) forever."""
        position = jnp.asarray(position)
        batch, N = position.shape[:-1], position.shape[-1]
        c = jnp.zeros(batch + (segments, N, degree + 1), position.dtype)
        c = c.at[..., 0].set(position[..., None, :])
        breaks = jnp.zeros(batch + (segments + 1,), position.dtype)
        return Trajectory(c, breaks, jnp.zeros(batch, bool))

    # ------------------------------------------------------------------ export
    def to_monomials(self) -> tuple[jax.Array, jax.Array]:
        """Monomial coefficients in seconds.

        Returns:
            coeffs: (..., S, N, D+1) in (t - breaks[k]) seconds, lowest power first.
            breaks: (..., S+1) seconds.
        """
        h = _h_eff(self.breaks)
        powers = jnp.arange(self.coeffs.shape[-1], dtype=self.coeffs.dtype)
        return self.coeffs / h[..., :, None, None] ** powers, self.breaks

    # ------------------------------------------------------------------ evaluation
    def evaluate(self, t, derivative: int = 0) -> jax.Array:
        """Position (derivative=0), velocity (1), acceleration (2) or jerk (3) at times t.

        Args:
            t: seconds from the start; any shape that broadcasts (NumPy rules) against
                the batch shape, e.g. () or (...,) or (K, 1) for K times of an (M,) batch.
            derivative: static int >= 0.

        Returns:
            (broadcast(batch_shape, t.shape)..., N) in m / s^derivative.

        Called outside jit / vmap / grad it runs as one compiled program, compiled once
        per shape of its arguments (see ``_evaluate_jit``).
        """
        if not traced(self, t):
            return _evaluate_jit(self, t, derivative)
        return _evaluate(self, t, derivative)

    def sample(self, t, derivative: int = 0) -> jax.Array:
        """Evaluate each trajectory of the batch at its own K times.

        Args:
            t: (K,) or (..., K) seconds (leading axes broadcast against the batch shape).
        Returns:
            (..., K, N).
        """
        t = jnp.asarray(t, dtype=self.coeffs.dtype)
        traj = Trajectory(
            self.coeffs[..., None, :, :, :], self.breaks[..., None, :], self.coast[..., None]
        )
        return traj.evaluate(t, derivative)

    def state_at(self, t) -> tuple[jax.Array, jax.Array, jax.Array]:
        """(position, velocity, acceleration) at t, each (..., N)."""
        return self.evaluate(t, 0), self.evaluate(t, 1), self.evaluate(t, 2)

    def end_state(self) -> tuple[jax.Array, jax.Array, jax.Array]:
        """(position, velocity, acceleration) of the polynomial at t = T, each (..., N)."""
        return self.state_at(self.duration)

    # ------------------------------------------------------------------ time shift
    def shift(self, dt) -> Trajectory:
        """The remaining part of the trajectory from time ``dt`` on, re-expressed exactly.

        ``shift(dt).evaluate(t) == evaluate(t + dt)`` for all t >= 0 (and all derivatives),
        including after the end.  Segments already passed become zero-length; past the end
        the result has T = 0 and carries the hold / coast state.

        Args:
            dt: () or (...,) seconds, >= 0 (negative values are treated as 0).
        """
        if not traced(self, dt):
            return _shift_jit(self, dt)
        return _shift(self, dt)


# ---------------------------------------------------------------------- internals
def _evaluate(traj: Trajectory, t, derivative: int) -> jax.Array:
    t = jnp.asarray(t, dtype=traj.coeffs.dtype)
    shape = jnp.broadcast_shapes(traj.batch_shape, t.shape)
    S, N, K = traj.coeffs.shape[-3:]
    c = jnp.broadcast_to(traj.coeffs, shape + (S, N, K)).reshape((-1, S, N, K))
    b = jnp.broadcast_to(traj.breaks, shape + (S + 1,)).reshape((-1, S + 1))
    co = jnp.broadcast_to(traj.coast, shape).reshape((-1,))
    tt = jnp.broadcast_to(t, shape).reshape((-1,))
    out = jax.vmap(lambda c1, b1, co1, t1: _eval_one(c1, b1, co1, t1, derivative))(
        c, b, co, tt
    )
    return out.reshape(shape + (N,))


def _shift(traj: Trajectory, dt) -> Trajectory:
    dt = jnp.asarray(dt, dtype=traj.coeffs.dtype)
    S, N, K = traj.coeffs.shape[-3:]
    shape = jnp.broadcast_shapes(traj.batch_shape, dt.shape)
    c = jnp.broadcast_to(traj.coeffs, shape + (S, N, K)).reshape((-1, S, N, K))
    b = jnp.broadcast_to(traj.breaks, shape + (S + 1,)).reshape((-1, S + 1))
    co = jnp.broadcast_to(traj.coast, shape).reshape((-1,))
    d = jnp.broadcast_to(dt, shape).reshape((-1,))
    c2, b2 = jax.vmap(_shift_one)(c, b, co, d)
    return Trajectory(
        c2.reshape(shape + (S, N, K)), b2.reshape(shape + (S + 1,)), co.reshape(shape)
    )


# Outside jit, vmap, grad ... (no tracer among the arguments) Trajectory.evaluate and
# Trajectory.shift run as one compiled program (cached per shape): op by op, every
# operation would compile on its own at each new shape and every call would trace its
# vmap again (docs/SOLVER.md, "Measurements behind the code").  Inside a transformation
# they add their operations to the caller's program, as any function does.
_evaluate_jit = jax.jit(_evaluate, static_argnums=2)
_shift_jit = jax.jit(_shift)


def _h_eff(breaks: jax.Array) -> jax.Array:
    """Segment lengths (..., S), with zero lengths replaced by one second."""
    h = jnp.diff(breaks, axis=-1)
    return jnp.where(h > 0, h, 1.0)


def _eval_one(c, b, coast, t, d: int):
    """One trajectory: c (S, N, K), b (S+1,), coast (), t () -> (N,)."""
    S = c.shape[0]
    T = b[-1]
    tc = jnp.clip(t, 0.0, T)
    k = jnp.clip(jnp.sum(b[1:S] <= tc), 0, S - 1)
    h = b[k + 1] - b[k]
    h_eff = jnp.where(h > 0, h, 1.0)
    s = jnp.where(h > 0, (tc - b[k]) / h_eff, 0.0)
    ck = c[k]  # (N, K)
    val = _horner(_deriv_coeffs(ck, d), s) / h_eff**d
    # after the end: hold or coast
    after = t > T
    if d == 0:
        v_end = _end_derivative(c, b, 1)
        extra = jnp.where(coast, 1.0, 0.0) * v_end * jnp.maximum(t - T, 0.0)
        return val + jnp.where(after, extra, 0.0)
    if d == 1:
        return jnp.where(after & ~coast, 0.0, val)
    return jnp.where(after, 0.0, val)


def _end_derivative(c, b, d: int):
    """d-th time derivative of the polynomial at t = T: (N,)."""
    S = c.shape[0]
    T = b[-1]
    k = jnp.clip(jnp.sum(b[1:S] <= T), 0, S - 1)
    h = b[k + 1] - b[k]
    h_eff = jnp.where(h > 0, h, 1.0)
    s = jnp.where(h > 0, 1.0, 0.0)
    return _horner(_deriv_coeffs(c[k], d), s) / h_eff**d


def compose_matrix(alpha, beta, K: int, dtype):
    """(K, K) matrix A with new_c = A @ old_c for q(s') = p(alpha + beta s')."""
    rows = []
    for m in range(K):
        row = []
        for i in range(K):
            if i < m:
                row.append(jnp.zeros((), dtype))
            else:
                row.append(comb(i, m) * alpha ** (i - m) * beta**m)
        rows.append(jnp.stack(row))
    return jnp.stack(rows)


def _shift_one(c, b, coast, dt):
    """One trajectory: c (S, N, K), b (S+1,), coast (), dt () -> (c', b')."""
    S, N, K = c.shape
    T = b[-1]
    dt = jnp.maximum(dt, 0.0)
    past = dt > T  # dt == T keeps the whole Taylor expansion at T (a, j included)
    h = b[1:] - b[:-1]
    h_eff = jnp.where(h > 0, h, 1.0)
    new_start = jnp.maximum(b[:-1], dt)
    new_end = jnp.maximum(b[1:], dt)
    hn = new_end - new_start
    alpha = jnp.where(h > 0, (jnp.minimum(new_start, b[1:]) - b[:-1]) / h_eff, 0.0)
    beta = jnp.where(hn > 0, hn / h_eff, 1.0 / h_eff)
    A = jax.vmap(lambda a, be: compose_matrix(a, be, K, c.dtype))(alpha, beta)  # (S, K, K)
    c_new = jnp.einsum("smi,sni->snm", A, c)
    b_new = jnp.maximum(b - dt, 0.0)
    # Past the end: every segment has zero length; the last one carries the hold / coast
    # state as a Taylor expansion in seconds (position, velocity per second).
    pos = _eval_one(c, b, coast, dt, 0)
    vel = _eval_one(c, b, coast, dt, 1)
    tail = jnp.zeros((N, K), c.dtype).at[:, 0].set(pos)
    if K > 1:
        tail = tail.at[:, 1].set(vel)
    c_past = jnp.broadcast_to(tail, (S, N, K))
    c_out = jnp.where(past, c_past, c_new)
    b_out = jnp.where(past, jnp.zeros_like(b), b_new)
    return c_out, b_out


def as_numpy(traj: Trajectory) -> Trajectory:
    """Host copy of a trajectory (numpy arrays), e.g. for writing files."""
    return Trajectory(*(np.asarray(x) for x in traj))
