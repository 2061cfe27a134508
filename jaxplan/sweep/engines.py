"""`jaxplan sweep`: weight x seed x scenario grids, batched and resumable, on this
machine, on a Ray cluster or in shards (docs/DESIGN.md "A sweep directory").

    run_sweep(config, out_dir, *, progress=True, batch_size=None, figures=True,
              echo=print, engine=None, address=None, shard=None) -> SweepResult
    merge_shards(config, out_dir, *, figures=True, echo=print) -> SweepResult
    shard_csv_name(index, count) -> "sweep.shard-I-of-N.csv"

sweep.csv itself (its columns, both of its readers, the best setting) is
:mod:`jaxplan.sweep.table`; the grid's points and scenarios :mod:`jaxplan.sweep.points`;
one batch of points (padding, the compiled program, the rows) :mod:`jaxplan.sweep.batch`;
the config guard :mod:`jaxplan.sweep.guard`.

The grid is ``[sweep] q_obs x q_lim x seeds x scenarios`` (``scenarios`` empty: the
config's own fleet, named by its ``[scenario] kind`` or, with ``[[robots]]``, by the
config's name; ``scenarios`` given: those registry scenarios, built with their
defaults and the config's [limits], instead of the config's fleet).  The seed seeds
the scenario (the paper scenarios' jitter, the generators' draws); every run lasts
``sim.duration_s`` under the ideal backend.

Batches. ``batch_size`` (local engine: default :data:`DEFAULT_BATCH` on an accelerator,
:data:`DEFAULT_BATCH_CPU` per CPU device on a CPU; Ray engine: :data:`DEFAULT_BATCH_CPU`
per task; or the environment variable ``JAXPLAN_SWEEP_BATCH``) is, on a CPU, the runs in
flight: every run is its own one-run program, compiled once and called by ``batch_size``
threads side by side (:meth:`jaxplan.sweep.batch.BatchRunner.run`), so a row does not
depend on the batch size, the CPU devices or the engine; on an accelerator, the runs of
one vmapped call. Points are grouped by shape (spatial dimensions, waypoints:
:func:`shape_groups`); scenarios of different robot counts share one shape (smaller
fleets padded with masked robots to the largest of the whole grid's group, worlds to its
most static rows, so that resuming, a shard, every engine and every batch size pad a run
alike). A program is compiled once per shape group and process; compilations are counted
from JAX's own compile events and printed (``compilations: 1`` for a one-group grid; one
per worker and shape group on Ray).

Engines (``engine``, default ``[sweep] engine``).  "local": the shape groups one after
another in this process.  "ray": each batch of ``batch_size`` points is a Ray task
(:mod:`jaxplan.sweep.ray`) on a local Ray instance or the cluster at ``address``; the
driver writes the rows as the tasks return them, and a task whose worker died runs
again.  Both write the same row for the same point, bitwise.

Shards (``shard=(I, N)``, for batch schedulers): only the grid points whose index in
:func:`jaxplan.sweep.points.sweep_points`'s order is I mod N, into their own
``sweep.shard-I-of-N.csv`` in the sweep directory (no figures); :func:`merge_shards`
merges every shard file (and any sweep.csv already there) into sweep.csv, one row per
key, in grid order, and draws the figures.

Baselines.  A config whose ``[planner] method`` is a baseline (not "krishnan") sweeps
seeds and scenarios only, under the local engine, each point through the method's own
simulation in this process (:mod:`jaxplan.sweep.methods`); its rows have the same
columns and metrics.

Resuming.  Rows are keyed by (q_obs, q_lim, scenario, seed), the weights written with
Python's ``repr`` (exact round trip).  After each batch its rows are appended to the
CSV as complete lines in one write, under the file's lock
(:func:`jaxplan.files.file_lock`), then fsync'ed, so a kill (even SIGKILL) loses at
most the batches in flight; a process never appends a key twice.  Re-running the same
command reads the CSV, drops a trailing partial line (a kill mid-write) and skips every
finished key.  The resolved config is kept in ``config.toml``; a sweep directory made
with a different config (anything but ``[sweep]``, ``[tune]``, the name and the
description) is refused (:func:`jaxplan.sweep.guard.guard_config`), so rows of two
different planners are never mixed.
Growing the grid in the same directory is fine: only the new points run.

Columns (:data:`jaxplan.sweep.table.COLUMNS`): the key, then success (1/0), collisions,
min_separation_ratio, makespan_s (empty: not every robot reached its last waypoint),
mean_time_to_goal_s (mean over the robots that reached their last waypoint),
reached_frac (robots that reached their last waypoint), waypoints_frac (waypoints
reached / waypoints, mean over robots: progress through a multi-transition scenario),
peak_speed_ratio (max speed / v_max, max over robots), converged_frac,
iterations_median, fallbacks_kept_previous, fallbacks_braking, fallbacks_best_effort,
fallbacks_goal_occupied (robot replans that planned to a point beside an occupied goal),
robots, duration_s,
replans, error (empty unless the run's metrics could not be computed).  Solver timing
per replan is not measured in sweeps (one batch is one program).

Figures (``figures/``, :func:`jaxplan.plots.plot_sweep`): heatmaps of success rate,
minimum separation ratio and makespan over the grid; the best setting
(:func:`jaxplan.sweep.table.best_setting`) is printed.
"""

from __future__ import annotations

import math
import re
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import jax

from jaxplan import env_positive_int
from jaxplan.config import SWEEP_ENGINES, Config
from jaxplan.files import append_lines, atomic_write_text, file_lock
from jaxplan.progress import AfterFirstUpdate, NoProgress
from jaxplan.run_setup import planner_rows
from jaxplan.sweep.batch import BatchRunner, CompileCounter, Tally
from jaxplan.sweep.guard import guard_config
from jaxplan.sweep.methods import MethodGridError, check_method_grid, run_method_points
from jaxplan.sweep.points import SweepPoint, build_scenarios, sweep_points
from jaxplan.sweep.table import SweepError, best_setting, csv_text, read_sweep_csv, row_key

__all__ = [
    "BATCH_ENV",
    "DEFAULT_BATCH",
    "DEFAULT_BATCH_CPU",
    "SweepResult",
    "merge_shards",
    "parse_shard",
    "run_sweep",
    "shape_groups",
    "shard_csv_name",
]

DEFAULT_BATCH = 27  # runs per batch on an accelerator
# On a CPU one run per core at a time, each its own one-run program: faster than
# vmapping runs on one device (a vmapped solver runs every lane for as many iterations as
# its slowest lane needs: docs/SWEEPS.md, "Batches on a CPU"), and the same program
# wherever the run goes.  jaxplan makes one CPU device per core, so their count is the
# cores'; a Ray task has one CPU and one device.
DEFAULT_BATCH_CPU = 1  # runs in flight per CPU device (core)
BATCH_ENV = "JAXPLAN_SWEEP_BATCH"
SHARD_CSV = re.compile(r"sweep\.shard-(\d+)-of-(\d+)\.csv")


def shard_csv_name(index: int, count: int) -> str:
    """The CSV of shard ``index`` of ``count``: ``sweep.shard-I-of-N.csv``."""
    return f"sweep.shard-{index}-of-{count}.csv"


def parse_shard(text: str) -> tuple[int, int]:
    """``"I/N"`` -> (I, N), with 0 <= I < N; ValueError naming the problem otherwise."""
    m = re.fullmatch(r"\s*(\d+)\s*/\s*(\d+)\s*", str(text))
    if not m:
        raise ValueError(f"expected I/N (shard I of N, 0 <= I < N), got {text!r}")
    i, n = int(m.group(1)), int(m.group(2))
    if not 0 <= i < n:
        raise ValueError(f"expected I/N with 0 <= I < N, got {text!r}")
    return i, n


@dataclass
class SweepResult:
    """What :func:`run_sweep` or :func:`merge_shards` did.

    out: the sweep directory; csv: the CSV written (sweep.csv, or a shard's).  total:
    grid points (of the shard); skipped: already in the CSV; ran: run now.  batches:
    batches run; batch_size: runs per batch.  compilations: compilations of the batch
    program (JAX compile events; on Ray, summed over the workers), cache_hits of them
    loaded from the persistent compilation cache.  compile_s, run_s:
    seconds (on Ray, summed over the workers), wall_s: seconds.  best:
    :func:`jaxplan.sweep.table.best_setting`'s dict (None without rows or for a shard).
    figures: the heatmap paths.  engine: "local" or "ray" ("merge" for a merge).
    missing: grid points without a row (after a merge).
    """

    out: Path
    csv: Path
    total: int
    skipped: int
    ran: int
    batches: int
    batch_size: int
    compilations: int
    compile_s: float
    run_s: float
    wall_s: float
    best: dict | None
    figures: list
    engine: str = "local"
    missing: int = 0
    cache_hits: int = 0


# ------------------------------------------------------------------------ the CSV


class _Writer:
    """Appends rows to one CSV (under its lock), never a key twice from this process."""

    def __init__(self, path: Path, done: set):
        self.path, self.written = path, set(done)

    def __call__(self, rows: list[dict]) -> None:
        new = []
        for r in rows:
            k = row_key(r)
            if k not in self.written:
                self.written.add(k)
                new.append(r)
        if new:
            append_lines(self.path, csv_text(new))


def _resume_csv(csv_path: Path, say) -> set:
    """The keys already in a sweep CSV; a fresh file gets its header, and a damaged one
    (a kill mid-write) is rewritten with its complete rows, atomically (under its lock)."""
    with file_lock(csv_path):
        rows, info = read_sweep_csv(csv_path)
        if not csv_path.exists() or not info.clean or csv_path.stat().st_size == 0:
            atomic_write_text(csv_path, csv_text(rows, header=True))
            if not info.clean:
                say(f"{csv_path}: dropped {info.partial_bytes} bytes of a partial last line, "
                    f"{info.malformed} malformed and {info.duplicates} duplicate rows")
    return {row_key(r) for r in rows}


# ------------------------------------------------------------------------ the sweep


def shape_groups(config: Config, todo: list[SweepPoint], grid: list[SweepPoint],
                 built) -> list[tuple[tuple, int, int]]:
    """The points to run by shape group (dimensions, waypoints), each with the robot
    count and the static rows of that group over the whole grid (so that a resumed
    sweep, a shard, every engine and every batch size pad a run alike): [(points, m_pad,
    r_pad)]."""
    def shape(p):
        sc = built[(p.scenario, p.seed)]
        return sc.dim, sc.num_waypoints

    pads: dict[tuple[int, int], tuple[int, int]] = {}
    for p in grid:
        sc = built[(p.scenario, p.seed)]
        m, r = pads.get(shape(p), (0, 0))
        pads[shape(p)] = (max(m, sc.num_robots),
                          max(r, planner_rows(config, sc)))
    groups: dict[tuple[int, int], list[SweepPoint]] = {}
    for p in todo:
        groups.setdefault(shape(p), []).append(p)
    return [(tuple(pts), *pads[key]) for key, pts in groups.items()]


def _batches(config: Config, todo: list[SweepPoint], grid: list[SweepPoint], built,
             batch: int) -> list[tuple[tuple, int, int]]:
    """The points to run cut into batches of at most ``batch``, each of one shape group
    (:func:`shape_groups`): [(points, m_pad, r_pad)]."""
    return [(pts[i:i + batch], m_pad, r_pad)
            for pts, m_pad, r_pad in shape_groups(config, todo, grid, built)
            for i in range(0, len(pts), batch)]


def _run_local(config: Config, groups, built, batch: int, write: _Writer,
               bar: AfterFirstUpdate, say) -> Tally:
    """The shape groups one after another in this process, ``batch`` runs in flight
    (:meth:`jaxplan.sweep.batch.BatchRunner.run`); rows written as they are done."""
    runner = BatchRunner(config, say)

    def done(rows):
        write(rows)
        bar.update(len(rows))

    for points, m_pad, r_pad in groups:
        runner.run(points, built, m_pad, batch, on_compiled=bar.start, r_pad=r_pad,
                   on_rows=done)
    return runner.tally


def _best_and_figures(csv_path: Path, out: Path, figures: bool):
    """(rows in sweep.csv, the best setting or None, the heatmap paths)."""
    rows, _ = read_sweep_csv(csv_path)
    if not rows:
        return 0, None, []
    best = best_setting(csv_path)
    if not figures:
        return len(rows), best, []
    from jaxplan import plots

    return len(rows), best, plots.plot_sweep(out)


def _best_lines(best: dict | None) -> list[str]:
    if best is None:
        return []
    return [
        "best setting: q_obs = {q_obs:.6g}, q_lim = {q_lim:.6g}  (success {s:.0f}%, "
        "{collisions:.3g} collisions/run, min separation ratio {msr:.3f}, makespan "
        "{mk} over {runs} runs)".format(
            s=100 * best["success_rate"], msr=best["min_separation_ratio"],
            mk=(f"{best['makespan_s']:.2f} s" if math.isfinite(best["makespan_s"])
                else "n/a"), **best)]


def _summary(res: SweepResult, n_rows: int, cpu_s: float) -> list[str]:
    """The lines run_sweep prints at the end."""
    summed = " summed over the workers" if res.engine == "ray" else ""
    lines = [
        f"compilations: {res.compilations}"
        + (f" ({res.cache_hits} loaded from the compilation cache)" if res.cache_hits else "")
        + (" over the workers" if summed else ""),
        f"runs: {res.ran} run now, {res.skipped} skipped (already done), "
        f"{n_rows} rows in {res.csv}",
        f"time: {res.wall_s:.1f} s wall ({res.compile_s:.1f} s compiling, {res.run_s:.1f} s "
        f"running {res.batches} batch{'es' if res.batches != 1 else ''}{summed}); "
        f"{cpu_s:.1f} s CPU in this process",
    ]
    return lines + _best_lines(res.best) + [f"figure: {f}" for f in res.figures]


def _batch_size(batch_size: int | None, engine: str) -> int:
    if batch_size is None:
        batch_size = env_positive_int(BATCH_ENV, SweepError)
    if batch_size is None:
        if engine == "ray":
            batch_size = DEFAULT_BATCH_CPU  # a task: one CPU, one device
        elif jax.default_backend() == "cpu":
            batch_size = DEFAULT_BATCH_CPU * len(jax.devices("cpu"))
        else:
            batch_size = DEFAULT_BATCH
    if int(batch_size) < 1:
        raise SweepError(f"batch size must be >= 1, got {batch_size}")
    return int(batch_size)


def run_sweep(config: Config, out_dir, *, progress: bool = True,
              batch_size: int | None = None, figures: bool = True,
              echo: Callable[[str], None] | None = print, engine: str | None = None,
              address: str | None = None, shard: tuple[int, int] | None = None) -> SweepResult:
    """Run (or resume) the config's [sweep] grid into ``out_dir`` (see the module doc).

    Args:
        config: a validated Config with a [sweep] table (backend "ideal").
        out_dir: the sweep directory (created): sweep.csv, config.toml, figures/.
        progress: a tqdm progress bar over runs (with ETA).
        batch_size: runs in flight on a CPU, runs per vmapped batch on an accelerator,
            runs per Ray task (default: $JAXPLAN_SWEEP_BATCH, else one per CPU device
            (local) or per task (ray), DEFAULT_BATCH on an accelerator; at most the
            number of runs left).  The rows do not depend on it on a CPU.
        figures: draw the heatmaps at the end (never for a shard).
        echo: where the summary lines go (None: nowhere).
        engine: "local" or "ray" (default: ``config.sweep.engine``).
        address: the Ray cluster to join (engine "ray"; default: a local instance).
        shard: (I, N): only the points of index I mod N, into sweep.shard-I-of-N.csv.
    Returns: a :class:`SweepResult`.
    """
    t_wall = time.perf_counter()
    cpu0 = time.process_time()
    say = echo or (lambda s: None)
    where = config.source or config.name
    engine = config.sweep.engine if engine is None else engine
    if engine not in SWEEP_ENGINES:
        raise SweepError(f"engine {engine!r}: choose one of {', '.join(SWEEP_ENGINES)}")
    baseline = config.planner.method != "krishnan"
    if baseline:
        try:
            check_method_grid(config, engine)
        except MethodGridError as e:
            raise SweepError(f"{where}: {e}") from None
    if address is not None and engine != "ray":
        raise SweepError(f"a Ray address ({address}) needs the ray engine (--engine ray)")
    if shard is not None and not 0 <= shard[0] < shard[1]:
        raise SweepError(f"shard {shard[0]}/{shard[1]}: expected I/N with 0 <= I < N")
    if config.sim.backend != "ideal":
        raise SweepError(f"{where}: sim.backend = {config.sim.backend!r}: sweeps run the "
                         "ideal backend only")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    csv_path = out / (shard_csv_name(*shard) if shard else "sweep.csv")
    guard_config(out, config)
    done = _resume_csv(csv_path, say)
    grid = sweep_points(config)
    points = grid if shard is None else grid[shard[0]::shard[1]]
    todo = [p for p in points if p.key not in done]
    skipped = len(points) - len(todo)
    batch = min(_batch_size(batch_size, engine), max(1, len(todo)))

    CompileCounter.install()
    tally = Tally()
    if todo:
        part = f" (shard {shard[0]}/{shard[1]})" if shard else ""
        say(f"sweep {config.name}{part}: {len(points)} runs ({skipped} already in {csv_path}), "
            f"{len(todo)} to go in batches of {batch}")
        built = build_scenarios(config, grid)  # (scenario, seed) pairs: few, cheap
        write = _Writer(csv_path, done)
        # opened after the first compilation (its ETA counts runs only)
        bar = (AfterFirstUpdate(len(points), config.name, "run", initial=skipped)
               if progress else NoProgress())
        try:
            if baseline:
                run_method_points(config, todo, built, write, bar, tally)
            elif engine == "ray":
                from jaxplan.sweep import ray as sweep_ray

                bar.start()
                sweep_ray.run_batches(config, _batches(config, todo, grid, built, batch), batch,
                                      write, tally, address=address, progress=bar.update,
                                      say=say)
            else:
                tally = _run_local(config, shape_groups(config, todo, grid, built), built, batch,
                                   write, bar, say)
        finally:
            bar.close()

    if shard is None:
        n_rows, best, figs = _best_and_figures(csv_path, out, figures)
    else:
        n_rows, best, figs = len(read_sweep_csv(csv_path)[0]), None, []
    res = SweepResult(out, csv_path, len(points), skipped, len(todo), tally.batches, batch,
                      tally.compilations, tally.compile_s, tally.run_s,
                      time.perf_counter() - t_wall, best, figs, engine,
                      cache_hits=tally.cache_hits)
    for line in _summary(res, n_rows, time.process_time() - cpu0):
        say(line)
    if shard is not None:
        say(f"merge the shards with: jaxplan sweep {where} --out {out} --merge")
    return res


def merge_shards(config: Config, out_dir, *, figures: bool = True,
                 echo: Callable[[str], None] | None = print) -> SweepResult:
    """Merge every shard CSV of ``out_dir`` (``sweep.shard-I-of-N.csv``) and any
    sweep.csv already there into sweep.csv: one row per key (the first met: sweep.csv,
    then the shards by N, I), the grid's points in grid order, then any others; written
    atomically under sweep.csv's lock.  Then the best setting and the figures, as
    :func:`run_sweep`.  ``missing`` in the result: grid points without a row."""
    t_wall = time.perf_counter()
    say = echo or (lambda s: None)
    out = Path(out_dir)
    if not out.is_dir():
        raise SweepError(f"{out}: no such sweep directory")
    found = {p: SHARD_CSV.fullmatch(p.name) for p in out.iterdir()}
    shards = sorted((p for p, m in found.items() if m),
                    key=lambda p: (int(found[p].group(2)), int(found[p].group(1))))
    if not shards:
        raise SweepError(f"{out}: no shard files (sweep.shard-I-of-N.csv) to merge")
    guard_config(out, config)
    csv_path = out / "sweep.csv"
    points = sweep_points(config)
    order = {p.key: k for k, p in enumerate(points)}
    with file_lock(csv_path):
        rows, _ = read_sweep_csv(csv_path)
        merged = {row_key(r): r for r in rows}
        before = len(merged)
        for path in shards:
            with file_lock(path):
                shard_rows, _ = read_sweep_csv(path)
            for r in shard_rows:
                merged.setdefault(row_key(r), r)
        keys = sorted(merged, key=lambda k: order.get(k, len(order)))  # stable: others last
        atomic_write_text(csv_path, csv_text([merged[k] for k in keys], header=True))
    missing = sum(1 for p in points if p.key not in merged)
    say(f"merged {len(shards)} shard file(s) into {csv_path}: {len(merged) - before} new "
        f"rows, {len(merged)} in all; {len(points) - missing} of the grid's {len(points)} "
        f"points done" + (f", {missing} missing (re-run their shards)" if missing else ""))
    n_rows, best, figs = _best_and_figures(csv_path, out, figures)
    res = SweepResult(out, csv_path, len(points), len(points) - missing, 0, 0, 0, 0, 0.0, 0.0,
                      time.perf_counter() - t_wall, best, figs, "merge", missing)
    for line in _best_lines(best) + [f"figure: {f}" for f in figs]:
        say(line)
    return res
