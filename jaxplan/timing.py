"""Wall-clock timing of JAX calls: one helper for every place that times one; and the
compiled programs a process keeps.

    timed(fn, *args, **kwargs) -> (result, seconds)
    KeptPrograms(size), arg_key(*args)

The clock stops when every array of the result is ready (``jax.block_until_ready``), so
an asynchronously dispatched computation is timed whole.  Used by the run loop
(:mod:`jaxplan.experiment`), the sweep's batches (:mod:`jaxplan.sweep`) and the
benchmarks (:mod:`jaxplan.benchmarks.common`).  Both the run loop and the sweep's batches
compile with ``lower().compile()``, to time the compile apart from the run; that bypasses
jit's own cache of compiled programs, so they keep theirs in a :class:`KeptPrograms`.
"""

from __future__ import annotations

import time
from collections import OrderedDict

import jax
import numpy as np

__all__ = ["KeptPrograms", "arg_key", "timed"]


def timed(fn, *args, **kwargs):
    """(fn(*args, **kwargs), its wall time in seconds, up to the result being ready)."""
    t0 = time.perf_counter()
    out = jax.block_until_ready(fn(*args, **kwargs))
    return out, time.perf_counter() - t0


def arg_key(*args) -> tuple:
    """What jit keys a compiled program on besides its static arguments: the arguments'
    tree, and each leaf's shape, dtype and weak type (no copy of the arrays)."""
    leaves, tree = jax.tree.flatten(args)
    dtype = lambda x: np.dtype(x.dtype if hasattr(x, "dtype") else np.asarray(x).dtype)  # noqa: E731
    return tree, tuple((np.shape(x), dtype(x).str, bool(getattr(x, "weak_type", False)))
                       for x in leaves)


class KeptPrograms:
    """This process's compiled programs by key, the most recently used last, at most
    ``size`` of them (the oldest dropped)."""

    def __init__(self, size: int = 8):
        self.size = size
        self._programs: OrderedDict = OrderedDict()

    def __contains__(self, key) -> bool:
        return key in self._programs

    def get(self, key):
        """The program kept under ``key`` (now the most recently used), or None."""
        program = self._programs.get(key)
        if program is not None:
            self._programs.move_to_end(key)
        return program

    def put(self, key, program):
        """Keep ``program`` under ``key``; returns it."""
        self._programs[key] = program
        while len(self._programs) > self.size:
            self._programs.popitem(last=False)
        return program
