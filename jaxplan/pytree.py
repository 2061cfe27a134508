"""Pytree helpers shared by the solver, the planner and the rollout."""

from __future__ import annotations

import jax
import jax.numpy as jnp


def traced(*trees) -> bool:
    """Whether any leaf of ``trees`` is a JAX tracer: the caller runs inside jit, vmap,
    grad ... (not on concrete arrays)."""
    return any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves(trees))


def tree_where(cond, a, b):
    """Leafwise ``jnp.where(cond, a, b)`` over two pytrees of the same structure.

    ``cond`` is a boolean array whose shape is a prefix of every leaf's shape (a scalar,
    or per-lane flags over the leaves' leading axes); it is broadcast against the
    trailing axes of each leaf."""
    cond = jnp.asarray(cond)
    return jax.tree.map(
        lambda u, v: jnp.where(cond.reshape(cond.shape + (1,) * (jnp.ndim(u) - cond.ndim)),
                               u, v), a, b)


# XLA's CPU compiler (its TreeReductionRewriter) turns a reduction over any axis longer
# than this into a reduce-window of this width and a second reduction: two kernels, the
# first a slow one.  The solver's per-step bookkeeping reduces the constraints (n_col x
# the other robots, n_col = 40 for the product NLP) several times per evaluation.
REDUCE_WINDOW = 32


def _fold(a, op, pad=None):
    """``a`` with every axis longer than REDUCE_WINDOW folded onto itself by the elementwise
    ``op``, so that a reduction of the result by ``op`` equals the reduction of ``a`` (for
    a sum: to rounding, a pairwise order) and is one kernel.  Where an axis is odd, the
    second half is padded with ``pad`` (op's identity), or, where ``pad`` is None (an
    idempotent op: maximum, minimum, and, or), the two halves overlap by one entry."""
    for ax in range(a.ndim):
        while a.shape[ax] > REDUCE_WINDOW:
            n = a.shape[ax]
            h = (n + 1) // 2
            lo = jax.lax.slice_in_dim(a, 0, h, axis=ax)
            if pad is None or n == 2 * h:
                hi = jax.lax.slice_in_dim(a, n - h, n, axis=ax)
            else:
                widths = [(0, 0, 0)] * a.ndim
                widths[ax] = (0, 1, 0)
                hi = jax.lax.pad(jax.lax.slice_in_dim(a, h, n, axis=ax),
                                 jnp.asarray(pad, a.dtype), widths)
            a = op(lo, hi)
    return a


def sum_all(a):
    """``jnp.sum(a)`` over every axis, as one kernel on a CPU (:func:`_fold`; the same
    sum to rounding)."""
    a = jnp.asarray(a)
    return jnp.sum(_fold(a, jnp.add, 0))


def max_all(a, initial=None):
    """``jnp.max(a, initial=initial)`` over every axis, as one kernel on a CPU (:func:`_fold`)."""
    a = jnp.asarray(a)
    return jnp.max(_fold(a, jnp.maximum), initial=initial)


def min_all(a, initial=None):
    """``jnp.min(a, initial=initial)`` over every axis, as one kernel on a CPU (:func:`_fold`)."""
    a = jnp.asarray(a)
    return jnp.min(_fold(a, jnp.minimum), initial=initial)


def any_all(a):
    """``jnp.any(a)`` over every axis, as one kernel on a CPU (:func:`_fold`)."""
    return jnp.any(_fold(jnp.asarray(a, bool), jnp.logical_or))


def all_all(a):
    """``jnp.all(a)`` over every axis, as one kernel on a CPU (:func:`_fold`)."""
    return jnp.all(_fold(jnp.asarray(a, bool), jnp.logical_and))
