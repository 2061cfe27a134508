"""Small shared helpers for the benchmarks: timing with medians, machine facts, JSON."""

from __future__ import annotations

import json
import os
import platform
import statistics
import time
from pathlib import Path

import jax


def block(x):
    """Wait for every array in a pytree."""
    return jax.block_until_ready(x)


def time_calls(fn, repeats: int) -> list[float]:
    """Wall-clock seconds of ``repeats`` calls of fn() (results blocked on)."""
    out = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        block(fn())
        out.append(time.perf_counter() - t0)
    return out


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
    """Write ``data`` as JSON atomically (temp file + rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(data, indent=2, sort_keys=True, default=float) + "\n")
    os.replace(tmp, path)
