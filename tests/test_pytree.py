"""jaxplan.pytree's whole-array reductions: the values of jnp's, as one kernel on a CPU."""

import re
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplan.pytree import REDUCE_WINDOW, all_all, any_all, max_all, min_all, sum_all

SHAPES = [(), (5,), (33,), (40, 9), (9, 41), (33, 35, 2), (0, 40)]
# jitted, as the solver calls them: op by op (eager) each shape compiled every operation
# on its own (~4 s of this module)
J = SimpleNamespace(**{f.__name__: jax.jit(f)
                       for f in (max_all, min_all, sum_all, any_all, all_all)})


@pytest.mark.parametrize("shape", SHAPES)
def test_reductions_equal_numpy(shape):
    rng = np.random.default_rng(sum(shape) + len(shape))
    a = rng.normal(size=shape)
    np.testing.assert_array_equal(J.max_all(a, initial=-5.0), np.max(a, initial=-5.0))
    np.testing.assert_array_equal(J.min_all(a, initial=5.0), np.min(a, initial=5.0))
    np.testing.assert_allclose(J.sum_all(a), np.sum(a), rtol=1e-14, atol=1e-14)
    for p in (0.0, 0.05, 1.0):
        b = rng.random(shape) < p
        assert bool(J.any_all(b)) == bool(np.any(b))
        assert bool(J.all_all(b)) == bool(np.all(b))
    if a.size:  # one extreme entry anywhere, the last (an odd axis' overlap) included
        for i in (0, a.size - 1):
            c = a.copy().reshape(-1)
            c[i] = 1e3
            assert float(J.max_all(c.reshape(shape))) == 1e3
            c[i] = np.nan
            c = c.reshape(shape)
            assert np.isnan(J.max_all(c)) and np.isnan(J.sum_all(c))


def _reduce_windows(fn, x):
    text = jax.jit(jax.vmap(fn)).lower(x).compile().as_text()
    return len(re.findall(r"reduce-window\(", text))


def test_a_reduction_over_a_long_axis_is_one_kernel():
    """XLA's CPU compiler splits a reduction over an axis longer than REDUCE_WINDOW in two
    kernels (a reduce-window, slow, then a reduce); the helpers fold such axes first.
    (The solver's step reduces the constraints, 40 rows for the product NLP, several
    times per evaluation: 0.91x the time of a warm 10-robot replan with the helpers.)"""
    x = jnp.ones((4, REDUCE_WINDOW + 8, 9))
    if jax.default_backend() != "cpu" or _reduce_windows(jnp.max, x) == 0:
        pytest.skip("this XLA does not split long reductions")
    for fn in (max_all, min_all, sum_all, lambda a: any_all(a > 0), lambda a: all_all(a > 0)):
        assert _reduce_windows(fn, x) == 0
