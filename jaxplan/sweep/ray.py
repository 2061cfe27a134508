"""The Ray engine of `jaxplan sweep` (``--engine ray``; docs/DESIGN.md "A sweep directory"):
each batch of grid points is one Ray task.

    run_batches(config, batches, batch, write_rows, tally, *, address=None, progress=None,
                say=print) -> None
    jaxplan_sweep_batch(config_text, source, points, m_pad, batch, r_pad) -> (rows, stats)

Ray is optional (``pip install "jaxplan[ray]"``); this module imports it only when a
sweep runs on it.  Without ``address`` the driver starts a local Ray instance with one
CPU per core (or ``JAXPLAN_RAY_CPUS``), so as many workers; with one (``auto``,
``HOST:PORT``, ``ray://HOST:PORT``) it joins that cluster, whose nodes must have jaxplan
installed at the same version.

A task (:func:`jaxplan_sweep_batch`) runs in a Ray worker process with one CPU and one
JAX CPU device (``JAXPLAN_CPU_DEVICES=1`` in the task's runtime environment): it reads
the resolved config (its config.toml text), builds its points' scenarios and returns
their sweep.csv rows (:class:`jaxplan.sweep.batch.BatchRunner`, the same code the
local engine runs).  A worker keeps its compiled batch programs for its next tasks, so
each worker compiles once per shape; workers use the driver's
persistent compilation cache directory (JAX's settings passed as environment
variables), which they share where they share a file system.

The driver alone writes: it appends each task's rows as they come back
(``write_rows``), and never the same key twice.  A worker that dies (a crash, a kill,
a node lost) loses only its task, which Ray runs again on another worker, up to
:data:`RETRIES` times; a task that still fails leaves its points out of the CSV (a
re-run resumes them) and the sweep ends with a SweepError naming it once every other
task is done.
"""

from __future__ import annotations

import logging
import os
import tomllib
from collections.abc import Callable

from jaxplan import env_positive_int
from jaxplan.config import Config, config_to_toml, parse_config
from jaxplan.sweep.batch import BatchRunner, Tally
from jaxplan.sweep.points import SweepPoint, build_scenarios, sweep_points
from jaxplan.sweep.table import SweepError

__all__ = ["RETRIES", "TASK_NAME", "jaxplan_sweep_batch", "run_batches"]

RETRIES = 3  # Ray's retries of a task whose worker died
TASK_NAME = "jaxplan_sweep_batch"  # the task's name (a busy worker's process title is ray::NAME)
CPUS_ENV = "JAXPLAN_RAY_CPUS"  # CPUs (so workers) of a local instance; default: one per core
LOCAL_OBJECT_STORE_BYTES = 256 << 20  # a local instance's object store: rows are small

_RUNNERS: dict[str, BatchRunner] = {}  # in a worker: the config text's runner (one)
_GRIDS: dict[str, dict] = {}  # ... and its grid's scenarios


def jaxplan_sweep_batch(config_text: str, source: str, points: tuple[SweepPoint, ...],
                        m_pad: int, batch: int, r_pad: int) -> tuple[list[dict], dict]:
    """The Ray task: the sweep.csv rows of ``points`` (one batch of at most ``batch``
    runs, padded to ``m_pad`` robots and ``r_pad`` static rows, the grid's) under the
    config whose resolved TOML is ``config_text``; on a CPU each run is its own
    one-run program, the local engine's (:meth:`jaxplan.sweep.batch.BatchRunner.run`).

    Returns (rows, stats): stats = compilations (of the batch program, in this task),
    cache_hits (of them, loads from the persistent cache), compile_s, run_s, pid (the
    worker's process id)."""
    runner = _RUNNERS.get(config_text)
    if runner is None:
        _RUNNERS.clear()
        _GRIDS.clear()
        config = parse_config(tomllib.loads(config_text), source=source)
        runner = _RUNNERS[config_text] = BatchRunner(config)
        # the whole grid's scenarios, as the local engine has them: the same structure
        # (static-row kinds, coast rows) for every batch, so the same program and rows
        _GRIDS[config_text] = build_scenarios(config, sweep_points(config))
    t = runner.tally
    before = (t.compilations, t.cache_hits, t.compile_s, t.run_s)
    rows = runner.run(points, _GRIDS[config_text], m_pad, batch, r_pad=r_pad)
    return rows, {"compilations": t.compilations - before[0],
                  "cache_hits": t.cache_hits - before[1], "compile_s": t.compile_s - before[2],
                  "run_s": t.run_s - before[3], "pid": os.getpid()}


def _worker_env() -> dict[str, str]:
    """Environment variables of every task: one JAX CPU device (a task has one CPU), and
    the driver's persistent compilation cache settings."""
    import jax

    env = {"JAXPLAN_CPU_DEVICES": "1"}
    cache_dir = jax.config.jax_compilation_cache_dir
    if jax.config.jax_enable_compilation_cache and cache_dir:
        env["JAX_COMPILATION_CACHE_DIR"] = str(cache_dir)
        env["JAX_COMPILATION_CACHE_MAX_SIZE"] = str(jax.config.jax_compilation_cache_max_size)
    else:
        env["JAX_ENABLE_COMPILATION_CACHE"] = "false"
    return env


def _connect(ray, address: str | None, say) -> bool:
    """Start or join Ray; True when this call did (and so must shut it down)."""
    if ray.is_initialized():
        say("ray: using the Ray session already open in this process")
        return False
    kw = dict(logging_level=logging.WARNING, include_dashboard=False)
    try:
        if address:
            ray.init(address=address, **kw)
        else:
            cpus = env_positive_int(CPUS_ENV, SweepError)
            if cpus is None:
                try:
                    cpus = len(os.sched_getaffinity(0))
                except AttributeError:  # not Linux
                    cpus = os.cpu_count() or 1
            # "local": a new instance, never one that happens to run on this machine
            ray.init(address="local", num_cpus=cpus,
                     object_store_memory=LOCAL_OBJECT_STORE_BYTES, **kw)
    except (ConnectionError, RuntimeError, ValueError) as e:
        where = f"the Ray cluster at {address}" if address else "a local Ray instance"
        hint = ("; a cluster with token authentication also needs its ~/.ray/auth_token "
                "and RAY_AUTH_MODE=token here (docs/SWEEPS.md)" if address else "")
        raise SweepError(f"--engine ray: cannot start or join {where}: "
                         f"{str(e).splitlines()[0] if str(e) else type(e).__name__}{hint}"
                         ) from None
    return True


def run_batches(config: Config, batches, batch: int,
                write_rows: Callable[[list[dict]], None], tally: Tally, *,
                address: str | None = None, progress: Callable[[int], None] | None = None,
                say: Callable[[str], None] = print) -> None:
    """Run ``batches`` (a list of (points, m_pad, r_pad)) as Ray tasks of ``batch`` runs each;
    ``write_rows(rows)`` as each comes back; add the workers' compile and run seconds,
    batches and compilations to ``tally``; ``progress(n)`` after n more runs.

    Raises SweepError when Ray is not installed or cannot start, and, after every other
    task has finished, when a task failed after its retries."""
    try:
        import ray
    except ImportError:
        raise SweepError('--engine ray needs Ray: pip install "jaxplan[ray]" (or set '
                         '[sweep] engine = "local")') from None
    started = _connect(ray, address, say)
    try:
        cpus = int(ray.cluster_resources().get("CPU", 0))
        say(f"ray: {len(batches)} tasks of {batch} run(s) on "
            + (f"the cluster at {address}" if address else "a local instance")
            + f" ({cpus} CPUs; {RETRIES} retries per task)")
        task = ray.remote(jaxplan_sweep_batch).options(
            name=TASK_NAME, num_cpus=1, max_retries=RETRIES, retry_exceptions=False,
            runtime_env={"env_vars": _worker_env()})
        text = ray.put(config_to_toml(config))
        pending = {task.remote(text, config.source, tuple(points), m_pad, batch, r_pad): points
                   for points, m_pad, r_pad in batches}
        failed: list[tuple[int, str]] = []
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            for ref in ready:
                points = pending.pop(ref)
                try:
                    rows, stats = ray.get(ref)
                except ray.exceptions.RayError as e:
                    failed.append((len(points), str(e).strip().splitlines()[0][:300]))
                    continue
                write_rows(rows)
                tally.compile_s += stats["compile_s"]
                tally.run_s += stats["run_s"]
                tally.compilations += stats["compilations"]
                tally.cache_hits += stats["cache_hits"]
                tally.batches += 1
                if progress is not None:
                    progress(len(points))
    finally:
        if started:
            ray.shutdown()
    if failed:
        runs = sum(n for n, _ in failed)
        raise SweepError(f"{len(failed)} Ray task(s) ({runs} runs) failed after {RETRIES} "
                         f"retries, their rows are not written (re-run to retry them); "
                         f"first: {failed[0][1]}")
