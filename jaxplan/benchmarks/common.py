"""Small shared helpers for the benchmarks: timing with medians (:func:`jaxplan.timing.timed`),
machine facts, JSON written atomically (:mod:`jaxplan.files`)."""

from __future__ import annotations

import json
import os
import platform
import statistics

import jax

from jaxplan.files import atomic_write_text
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


def cpu_line() -> str:
    """``N-core CPU (model, ISA)``: the CPUs this process may run on, the CPU's model name
    and its widest vector instructions (AVX-512 or AVX2).  XLA compiles for the widest
    it finds, so both the speed and the round-off of a compiled program differ between
    two machines of one model name (docs/SOLVER.md, "Speed")."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:
        cores = os.cpu_count() or 1
    model, flags = platform.processor() or "", set()
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.startswith("model name") and not flags:
                    model = line.split(":", 1)[1].strip()
                elif line.startswith("flags"):
                    flags = set(line.split(":", 1)[1].split())
                    break
    except OSError:
        pass
    isa = "AVX-512" if "avx512f" in flags else "AVX2" if "avx2" in flags else ""
    model = ", ".join(x for x in (model, isa) if x)
    return f"{cores}-core CPU" + (f" ({model})" if model else "")


def write_json(path, data: dict) -> None:
    """Write ``data`` as JSON atomically."""
    atomic_write_text(path, json.dumps(data, indent=2, sort_keys=True, default=float) + "\n")
