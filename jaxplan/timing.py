"""Wall-clock timing of JAX calls: one helper for every place that times one.

    timed(fn, *args, **kwargs) -> (result, seconds)

The clock stops when every array of the result is ready (``jax.block_until_ready``), so
an asynchronously dispatched computation is timed whole.  Used by the run loop
(:mod:`jaxplan.experiment`), the sweep's batches (:mod:`jaxplan.sweep`) and the
benchmarks (:mod:`jaxplan.benchmarks.common`).
"""

from __future__ import annotations

import time

import jax

__all__ = ["timed"]


def timed(fn, *args, **kwargs):
    """(fn(*args, **kwargs), its wall time in seconds, up to the result being ready)."""
    t0 = time.perf_counter()
    out = jax.block_until_ready(fn(*args, **kwargs))
    return out, time.perf_counter() - t0
