"""jaxplan: JAX-accelerated, batched decentralized multi-robot trajectory optimization.

Importing the package enables float64 in JAX (DESIGN.md: float64 everywhere) and, unless
JAX has already run something, makes one JAX CPU device per usable core (at most
:data:`MAX_CPU_DEVICES`), so that large solver batches and sweeps can run their parts
side by side (:func:`jaxplan.solver.default_shards`; one XLA program on a CPU runs its
kernels one after another).  The environment variable ``JAXPLAN_CPU_DEVICES`` sets the
count (1: off); a count already chosen through JAX (``jax_num_cpu_devices`` or
``XLA_FLAGS=--xla_force_host_platform_device_count``) is left as it is.  The default
device stays ``cpu:0``; a GPU, where there is one, is still JAX's default backend.
"""

from __future__ import annotations

import os

import jax

jax.config.update("jax_enable_x64", True)

__version__ = "0.1.0"

CPU_DEVICES_ENV = "JAXPLAN_CPU_DEVICES"
MAX_CPU_DEVICES = 8  # measured with 2 (the 2-core CPU); more is untested


def _cpu_device_count() -> int | None:
    """The CPU device count to ask JAX for, or None to leave JAX's choice."""
    env = os.environ.get(CPU_DEVICES_ENV, "").strip()
    if env:
        try:
            n = int(env)
        except ValueError:
            raise ValueError(f"{CPU_DEVICES_ENV}={env!r}: expected a positive integer") from None
        if n < 1:
            raise ValueError(f"{CPU_DEVICES_ENV}={env!r}: expected a positive integer")
        return n
    if jax.config.jax_num_cpu_devices != -1 or (
            "xla_force_host_platform_device_count" in os.environ.get("XLA_FLAGS", "")):
        return None
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        cores = os.cpu_count() or 1
    return max(1, min(cores, MAX_CPU_DEVICES))


CPU_DEVICES_ERROR: str | None = None  # a bad JAXPLAN_CPU_DEVICES (the CLI exits on it)


def _set_cpu_devices() -> None:
    global CPU_DEVICES_ERROR
    try:
        n = _cpu_device_count()
    except ValueError as e:  # warn, keep JAX's choice; `jaxplan` (the CLI) exits on it
        CPU_DEVICES_ERROR = str(e)
        import warnings

        warnings.warn(f"{e}; using JAX's default CPU device count", stacklevel=2)
        return
    if n is None or n == max(jax.config.jax_num_cpu_devices, 1):
        return
    try:
        jax.config.update("jax_num_cpu_devices", n)
    except RuntimeError:  # JAX already ran something: its devices are fixed
        pass


_set_cpu_devices()
