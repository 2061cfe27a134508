"""jaxplan.timing: the key a kept program is found under, and the programs a process keeps."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from jaxplan.timing import KeptPrograms, arg_key


def test_arg_key_tells_apart_what_jit_compiles_apart():
    a = (np.zeros((3, 2)), {"w": jnp.float64(1.0)})
    assert arg_key(*a) == arg_key(np.ones((3, 2)), {"w": jnp.float64(5.0)})  # values: same
    assert arg_key(*a) != arg_key(np.zeros((2, 3)), {"w": jnp.float64(1.0)})  # shape
    assert arg_key(*a) != arg_key(np.zeros((3, 2), np.int32), {"w": jnp.float64(1.0)})  # dtype
    assert arg_key(*a) != arg_key(np.zeros((3, 2)), {"v": jnp.float64(1.0)})  # tree
    # a weakly typed scalar (a Python float passed to jit) compiles apart from a float64
    assert arg_key(jnp.asarray(1.0)) != arg_key(jnp.asarray(1.0, jnp.float64))
    assert arg_key(1.0) == arg_key(2.0) and arg_key(1.0) != arg_key(1)


def test_kept_programs_drop_the_least_recently_used():
    kept = KeptPrograms(2)
    assert kept.get("a") is None and "a" not in kept
    assert kept.put("a", 1) == 1 and kept.put("b", 2) == 2
    assert kept.get("a") == 1  # "a" used last: "b" goes first
    kept.put("c", 3)
    assert "b" not in kept and kept.get("a") == 1 and kept.get("c") == 3
