"""Pytree helpers shared by the solver, the planner and the rollout."""

from __future__ import annotations

import jax
import jax.numpy as jnp


def tree_where(cond, a, b):
    """Leafwise ``jnp.where(cond, a, b)`` over two pytrees of the same structure.

    ``cond`` is a boolean array whose shape is a prefix of every leaf's shape (a scalar,
    or per-lane flags over the leaves' leading axes); it is broadcast against the
    trailing axes of each leaf."""
    cond = jnp.asarray(cond)
    return jax.tree.map(
        lambda u, v: jnp.where(cond.reshape(cond.shape + (1,) * (jnp.ndim(u) - cond.ndim)),
                               u, v), a, b)
