"""jaxplan: JAX-accelerated, batched decentralized multi-robot trajectory optimization.

The top-level API (docs/DESIGN.md): :func:`predict` (the closed-form minimum time-jerk
prediction; ``jaxplan.predict`` is also the module, callable as the function),
:class:`Trajectory`, and :func:`run` (an experiment from its config: jaxplan.experiment.run,
imported on first use so that importing jaxplan stays light).  The NLP is in
:mod:`jaxplan.nlp`, its solver in :mod:`jaxplan.solve`.

Importing the package enables float64 in JAX (docs/DESIGN.md: float64 everywhere) and, unless
JAX has already run something, makes one JAX CPU device per usable core (at most
:data:`MAX_CPU_DEVICES`), so that large solver batches and sweeps can run their parts
side by side (:func:`jaxplan.solve.default_shards`; one XLA program on a CPU runs its
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
MAX_CPU_DEVICES = 8  # a cap: more devices than this are untested


def env_positive_int(name: str, error: type[Exception] = ValueError) -> int | None:
    """The positive integer set in environment variable ``name``; None when it is unset
    or empty.  Anything else raises ``error`` with a message that names the variable."""
    env = os.environ.get(name, "").strip()
    if not env:
        return None
    try:
        n = int(env)
    except ValueError:
        n = 0
    if n < 1:
        raise error(f"{name}={env!r}: expected a positive integer")
    return n


def _cpu_device_count() -> int | None:
    """The CPU device count to ask JAX for, or None to leave JAX's choice."""
    n = env_positive_int(CPU_DEVICES_ENV)
    if n is not None:
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


# XLA aborts the whole process when the CPU devices of one program reach a collective
# (the all-gather that ends a batch split over devices) more than 40 s apart: on a loaded
# machine (a 2-core CPU running a sweep beside other jobs) one device's half of a batch
# can lag that much, and a sweep of hours died with "Termination timeout for `all
# gather ...` of 40 seconds exceeded".  The devices of a jaxplan program only ever wait
# for each other's work, so jaxplan lets them wait up to an hour (and warns after 5 min);
# a value the user put in XLA_FLAGS is kept.  They go first: XLA reads XLA_FLAGS only up
# to the first word that is not a --flag and silently drops the rest (a value that is
# not a --flag at all names a file of flags, and is left alone).
COLLECTIVE_FLAGS = {"xla_cpu_collective_call_terminate_timeout_seconds": 3600,
                    "xla_cpu_collective_call_warn_stuck_timeout_seconds": 300}


def _set_collective_timeouts() -> None:
    flags = os.environ.get("XLA_FLAGS", "").strip()
    if flags and not flags.startswith("--"):
        return
    extra = [f"--{k}={v}" for k, v in COLLECTIVE_FLAGS.items() if k not in flags]
    if extra:
        os.environ["XLA_FLAGS"] = " ".join([*extra, flags]).strip()


_set_collective_timeouts()
_set_cpu_devices()


# the public names; imported after the CPU devices are set (they must come first)
import sys as _sys  # noqa: E402
import types as _types  # noqa: E402

from jaxplan import predict as _predict_module  # noqa: E402
from jaxplan.trajectory import Trajectory  # noqa: E402


class _CallableModule(_types.ModuleType):
    """The module jaxplan.predict, callable as its function :func:`jaxplan.predict.predict`,
    so that both ``from jaxplan import predict; predict(...)`` and ``import jaxplan.predict``
    (the module's other names) work."""

    def __call__(self, *args, **kwargs):
        return self.predict(*args, **kwargs)


_predict_module.__class__ = _CallableModule
predict = _sys.modules["jaxplan.predict"]


def __getattr__(name: str):
    """``jaxplan.run``: :func:`jaxplan.experiment.run`, imported on first use."""
    if name == "run":
        from jaxplan.experiment import run

        return run
    raise AttributeError(f"module 'jaxplan' has no attribute {name!r}")


__all__ = ["Trajectory", "predict", "run"]
