"""Small shared helpers for the benchmarks: timing with medians (:func:`jaxplan.timing.timed`),
machine facts, JSON written atomically (:mod:`jaxplan.fileio`)."""

from __future__ import annotations

import json
import os
import platform
import statistics

import jax

from jaxplan.fileio import atomic_write_text
from jaxplan.timing import timed


def block(x):
    """Wait for every array in a pytree."""
    return jax.block_until_ready(x)


def time_calls(fn, repeats: int) -> list[float]:
    """Wall-clock seconds of ``repeats`` calls of fn() (results blocked on)."""
    return [timed(fn)[1] for _ in range(repeats)]


def median(xs) -> float:
    return float(statistics.median(xs))


def machine() -> dict:
    """Facts that make a benchmark figure interpretable."""
    return {
        "platform": platform.platform(),
        "python": platform.python_version(),
        "jax": jax.__version__,
        "backend": jax.default_backend(),
        "devices": [str(d) for d in jax.devices()],
        "cpu_count": os.cpu_count(),
        "xla_flags": os.environ.get("XLA_FLAGS", ""),
    }


def write_json(path, data: dict) -> None:
    """Write ``data`` as JSON atomically."""
    atomic_write_text(path, json.dumps(data, indent=2, sort_keys=True, default=float) + "\n")
