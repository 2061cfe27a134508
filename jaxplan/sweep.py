"""Weight x seed x scenario grids, batched and resumable (docs/DESIGN.md "A sweep
directory").

    run_sweep(config, out_dir, *, progress=True, batch_size=None, figures=True)
        -> SweepResult
    sweep_points(config) -> list[SweepPoint]          the whole grid, in run order

sweep.csv itself (its columns, both of its readers, the best setting) is
:mod:`jaxplan.sweep_csv`.

The grid is ``[sweep] q_obs x q_lim x seeds x scenarios`` (``scenarios`` empty: the
config's own fleet, named by its ``[scenario] kind`` or, with ``[[robots]]``, by the
config's name; ``scenarios`` given: those registry scenarios, built with their
defaults and the config's [limits], instead of the config's fleet).  The seed seeds
the scenario (the paper scenarios' jitter, the generators' draws); every run lasts
``sim.duration_s`` under the ideal backend.

Batches.  The grid is cut into batches of ``batch_size`` runs (default
:data:`DEFAULT_BATCH` on an accelerator, :data:`DEFAULT_BATCH_CPU` per CPU device on a
CPU, or the environment variable ``JAXPLAN_SWEEP_BATCH``); one batch
is one call of one compiled program: :func:`jaxplan.rollout.rollout_batch`, vmapped
over runs, with the weights (and every other fleet parameter) as traced batched
inputs.  On a CPU with several devices (jaxplan makes one per core: :mod:`jaxplan`) a
batch whose size is a multiple of their number is split over them, each device running
its own runs side by side (:func:`jaxplan.solve.shard_lanes`).  The last batch is
padded by repeating its last run (the duplicates are dropped), so every batch has the
same shape and the planner compiles once per shape group.  Scenarios of different robot
counts share one shape: smaller fleets are padded to the largest with masked robots
(``FleetParams.robot_mask``) parked far away, which the planner never plans for and no
robot sees.  Scenarios that differ in the number of
waypoints or of spatial dimensions form separate shape groups (one compilation each).
Compilations of the batch program are counted from JAX's own compile events
(``jax.monitoring``) and printed (``compilations: 1`` for a one-group grid).

Resuming.  Rows are keyed by (q_obs, q_lim, scenario, seed), the weights written with
Python's ``repr`` (exact round trip).  After each batch its rows are appended to
sweep.csv as complete lines in one write, then fsync'ed, so a kill (even SIGKILL)
loses at most the batch in flight.  Re-running the same command reads sweep.csv,
drops a trailing partial line (a kill mid-write) and skips every finished key.  The
resolved config is kept in ``config.toml``; a sweep directory made with a different
config (anything but ``[sweep]``, the name and the description) is refused
(:class:`SweepError`), so rows of two different planners are never mixed.  Growing the
grid in the same directory is fine: only the new points run.

Columns (:data:`jaxplan.sweep_csv.COLUMNS`): the key, then success (1/0), collisions,
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
(:func:`jaxplan.sweep_csv.best_setting`) is printed.
"""

from __future__ import annotations

import dataclasses
import math
import threading
import time
import tomllib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import jax
import numpy as np

from jaxplan import env_positive_int, scenarios
from jaxplan.config import Config, ConfigError, build_scenario, config_to_toml, parse_config
from jaxplan.experiment import compute_metrics, fleet_params, stack_trees, structures, task_of
from jaxplan.fileio import append_lines, atomic_write_text
from jaxplan.nlp import Weights
from jaxplan.rollout import RolloutStructure, Task, rollout_batch
from jaxplan.scenarios import Scenario
from jaxplan.solve import shard_lanes
from jaxplan.sweep_csv import (
    SweepError,
    best_setting,
    csv_text,
    make_key,
    read_sweep_csv,
    row_key,
)
from jaxplan.timing import timed

__all__ = [
    "DEFAULT_BATCH",
    "SweepError",
    "SweepPoint",
    "SweepResult",
    "run_sweep",
    "sweep_points",
]

DEFAULT_BATCH = 27  # runs per batch on an accelerator
# On a CPU one run per device at a time is faster than vmapping runs on one device: a
# vmapped solver runs every lane for as many iterations as its slowest lane needs
# (2 cores: 20 antipodal_10 runs took 127 s as one batch, about 90 s one after another;
# `JAXPLAN_SWEEP_BATCH=20` against `JAXPLAN_SWEEP_BATCH=1` on such a sweep shows it).
# Several CPU devices (jaxplan makes one per core) run their runs side by side (_shards).
DEFAULT_BATCH_CPU = 1  # runs per CPU device
BATCH_ENV = "JAXPLAN_SWEEP_BATCH"
PARK_DISTANCE = 1.0e4  # m: where padding robots are parked
PARK_SPACING = 10.0  # m between parked padding robots
_PROGRAM = "jaxplan_sweep_batch"  # the batch program's name in JAX's compile events


@dataclass(frozen=True)
class SweepPoint:
    """One run of the grid: weights, scenario label, seed."""

    q_obs: float
    q_lim: float
    scenario: str
    seed: int

    @property
    def key(self) -> tuple[str, str, str, str]:
        return make_key(self.q_obs, self.q_lim, self.scenario, self.seed)


@dataclass
class SweepResult:
    """What :func:`run_sweep` did.

    out: the sweep directory; csv: its sweep.csv.  total: grid points; skipped: already
    in sweep.csv; ran: run now.  batches: batches run; batch_size: runs per batch.
    compilations: compilations of the batch program (JAX compile events).
    compile_s, run_s, wall_s: seconds.  best: :func:`jaxplan.sweep_csv.best_setting`'s dict
    (None without rows).  figures: the heatmap paths.
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


# ------------------------------------------------------------------------ the grid


@dataclass(frozen=True)
class _ScenarioSource:
    label: str
    build: Callable[[int], Scenario]


def _sources(config: Config) -> list[_ScenarioSource]:
    sw = config.sweep
    if not sw.scenarios:
        if config.scenario is not None and not config.robots:
            label = config.scenario.kind
        else:
            label = config.name
        return [_ScenarioSource(
            label, lambda s: build_scenario(dataclasses.replace(config, seed=int(s))))]
    lim = config.limits

    def builder(name):
        def build(seed):
            return scenarios.build(name, seed=int(seed)).with_limits(
                lim.v_max, lim.a_max, lim.j_max)
        return build

    return [_ScenarioSource(n, builder(n)) for n in dict.fromkeys(sw.scenarios)]


def sweep_points(config: Config) -> list[SweepPoint]:
    """The whole grid of a config's [sweep], in run order: scenario, q_obs, q_lim, seed."""
    sw = config.sweep
    return [SweepPoint(float(qo), float(ql), src.label, int(s))
            for src in _sources(config)
            for qo in dict.fromkeys(sw.q_obs)
            for ql in dict.fromkeys(sw.q_lim)
            for s in dict.fromkeys(sw.seeds)]


# ------------------------------------------------------------------------ sweep.csv


def _csv_cell(x) -> str:
    """A value as a sweep.csv cell: 1/0 for booleans, repr for floats, empty for None,
    NaN and inf."""
    if x is None:
        return ""
    if isinstance(x, (bool, np.bool_)):
        return "1" if x else "0"
    if isinstance(x, (int, np.integer)):
        return str(int(x))
    x = float(x)
    return repr(x) if math.isfinite(x) else ""


def _csv_row(point: SweepPoint, metrics: dict | None, n_waypoints: int = 1,
             error: str = "") -> dict:
    """The sweep.csv row of a run from its metrics.json dict (None: the run failed with
    ``error``)."""
    row = {"q_obs": repr(float(point.q_obs)), "q_lim": repr(float(point.q_lim)),
           "scenario": point.scenario, "seed": str(point.seed)}
    if metrics is None:
        row.update(success="0", error=error)
        return row
    pr = metrics["per_robot"]
    ttg = [r["time_to_goal_s"] for r in pr if r["reached"] and r["time_to_goal_s"] is not None]
    row.update({
        "success": _csv_cell(bool(metrics["success"])),
        "collisions": _csv_cell(int(metrics["collisions"])),
        "min_separation_ratio": _csv_cell(metrics["min_separation_ratio"]),
        "makespan_s": _csv_cell(metrics["makespan_s"]),
        "mean_time_to_goal_s": _csv_cell(float(np.mean(ttg)) if ttg else None),
        "reached_frac": _csv_cell(float(np.mean([r["reached"] for r in pr]))),
        "waypoints_frac": _csv_cell(float(np.mean([r["waypoints_reached"] for r in pr]))
                               / max(1, n_waypoints)),
        "peak_speed_ratio": _csv_cell(metrics["peak_speed_over_limit"]),
        "converged_frac": _csv_cell(metrics["solver"].get("converged_frac")),
        "iterations_median": _csv_cell(metrics["solver"].get("iterations_median")),
        "fallbacks_kept_previous": _csv_cell(int(metrics["fallbacks"]["kept_previous"])),
        "fallbacks_braking": _csv_cell(int(metrics["fallbacks"]["braking"])),
        "fallbacks_best_effort": _csv_cell(int(metrics["fallbacks"]["best_effort"])),
        "fallbacks_goal_occupied": _csv_cell(int(metrics["fallbacks"].get("goal_occupied", 0))),
        "robots": _csv_cell(int(metrics["robots"])),
        "duration_s": _csv_cell(metrics["duration_s"]),
        "replans": _csv_cell(int(metrics["replans"])),
        "stalls": _csv_cell(int(metrics.get("stalls", 0))),
        "stalled_s": _csv_cell(metrics.get("stalled_s")),
        "parked": _csv_cell(int(metrics.get("parked", 0))),
        "makespan_over_bound": _csv_cell(metrics.get("makespan_over_bound")),
        "error": error,
    })
    return row


# ------------------------------------------------------------------------ config guard

_FREE_TABLES = ("sweep", "name", "description")
# keys added later whose default changed what a run does: a config.toml without one was
# written by a version that behaved as this value (so resuming it under the new default
# is a different config, not the same one)
_LEGACY_VALUES = {("planner", "coast_samples"): 0, ("planner", "deadlock"): "off"}


def _guard_config(out: Path, config: Config) -> None:
    """Keep config.toml; refuse a directory made with a different config."""
    path = out / "config.toml"
    text = config_to_toml(config)
    if path.exists():
        try:
            old = tomllib.loads(path.read_text("utf-8"))
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
            raise SweepError(f"{path}: unreadable ({e}); use another --out") from None
        # compare resolved configs: a key added later with its default (written by this
        # version, absent from an older config.toml) is no difference, unless the
        # default changed the behaviour (_LEGACY_VALUES)
        for (table, key), value in _LEGACY_VALUES.items():
            if isinstance(old.get(table, {}), dict) and key not in old.get(table, {}):
                old.setdefault(table, {})[key] = value
        try:
            old = tomllib.loads(config_to_toml(parse_config(old, source=str(path))))
        except ConfigError as e:
            raise SweepError(f"{path}: not a config this version reads ({e}); use another "
                             "--out") from None
        new = tomllib.loads(text)
        strip = lambda d: {k: v for k, v in d.items() if k not in _FREE_TABLES}  # noqa: E731
        if strip(old) != strip(new):
            diff = sorted(k for k in set(strip(old)) | set(strip(new))
                          if strip(old).get(k) != strip(new).get(k))
            raise SweepError(f"{path}: this sweep directory was made with a different config "
                             f"(differs in: {', '.join(diff)}); use another --out")
    atomic_write_text(path, text)


# ------------------------------------------------------------------------ batches


class _Prepared(NamedTuple):
    """One grid point's traced inputs, padded to the group's robot count."""

    point: SweepPoint
    scenario: Scenario
    fp: object  # FleetParams
    task: Task


def _weights(config: Config, q_obs: float, q_lim: float) -> Weights:
    pc = config.planner
    return Weights(*(np.asarray(float(x)) for x in
                     (pc.q_dynm, q_obs, q_lim, pc.k_t, pc.k_p)))


def _pad_robots(fp, task: Task, m_pad: int):
    """Pad a fleet to m_pad robots: masked, parked far apart and far away, at rest."""
    M, W, N = np.shape(task.waypoints)
    extra = m_pad - M
    if extra == 0:
        return fp, task
    park = np.zeros((extra, N))
    park[:, 0] = PARK_DISTANCE + PARK_SPACING * np.arange(extra)
    park[:, -1] = PARK_DISTANCE

    def cat(x, fill):
        x = np.asarray(x)
        return np.concatenate([x, np.broadcast_to(fill, (extra,) + x.shape[1:])], axis=0)

    task = task._replace(
        start=np.concatenate([np.asarray(task.start), park]),
        waypoints=np.concatenate([np.asarray(task.waypoints),
                                  np.repeat(park[:, None, :], W, axis=1)]),
        rest=cat(task.rest, True),
        goal_velocity=cat(task.goal_velocity, 0.0),
        faults=task.faults._replace(frozen=cat(task.faults.frozen, False)),
    )
    lim = fp.limits
    fp = fp._replace(
        limits=type(lim)(*(cat(x, np.asarray(x)[0]) for x in lim)),
        radius=cat(fp.radius, np.asarray(fp.radius)[0]),
        robot_mask=cat(fp.robot_mask, False),
    )
    return fp, task


def _batch_program(fp, task, structure: RolloutStructure, shards: int = 1):
    def runs(fp, task):
        final, records = rollout_batch(fp, task, structure, fp_axis=0)
        return (final.reached, final.reach_time), records

    # runs split over the CPU's devices, each running its own (module doc)
    return shard_lanes(runs, (fp, task), shards)


_batch_program.__name__ = _PROGRAM
_batch_program.__qualname__ = _PROGRAM
_batch_jit = jax.jit(_batch_program, static_argnames=("structure", "shards"))


class _CompileCounter:
    """Counts JAX backend compilations of the batch program (jax.monitoring events)."""

    _lock = threading.Lock()
    _installed = False
    counts: dict[str, int] = {}

    @classmethod
    def install(cls) -> None:
        with cls._lock:
            if cls._installed:
                return
            from jax import monitoring

            def listener(event, duration, **kw):
                if event == "/jax/core/compile/backend_compile_duration":
                    name = str(kw.get("fun_name", ""))
                    key = _PROGRAM if _PROGRAM in name else "other"
                    cls.counts[key] = cls.counts.get(key, 0) + 1

            monitoring.register_event_duration_secs_listener(listener)
            cls._installed = True

    @classmethod
    def get(cls, key: str = _PROGRAM) -> int:
        return cls.counts.get(key, 0)


class _ReachState(NamedTuple):
    """What compute_metrics reads of a rollout's final state: reached (.., M, W) and
    reach_time (.., M, W) s."""

    reached: np.ndarray
    reach_time: np.ndarray


def _run_metrics(config: Config, prep: _Prepared, records, final: _ReachState, b: int):
    """Metrics of lane b (unpadded robots) -> a csv row."""
    M = prep.scenario.num_robots

    def lane(x):
        x = x[b]
        return x[:, :M] if x.ndim >= 2 else x

    rec = jax.tree.map(lane, records)
    fin = _ReachState(final.reached[b, :M], final.reach_time[b, :M])
    try:
        metrics, _ = compute_metrics(config, prep.scenario, rec, fin, np.empty(0))
    except Exception as e:  # one bad run never stops the sweep
        msg = f"{type(e).__name__}: {e}".replace("\n", " ")[:200]
        return _csv_row(prep.point, None, error=msg)
    return _csv_row(prep.point, metrics, prep.scenario.num_waypoints)


def _batch_size(batch_size: int | None) -> int:
    if batch_size is None:
        batch_size = env_positive_int(BATCH_ENV, SweepError)
    if batch_size is None:
        batch_size = (DEFAULT_BATCH_CPU * len(jax.devices("cpu"))
                      if jax.default_backend() == "cpu" else DEFAULT_BATCH)
    if int(batch_size) < 1:
        raise SweepError(f"batch size must be >= 1, got {batch_size}")
    return int(batch_size)


def _shards(batch: int) -> int:
    """CPU devices a batch of ``batch`` runs is split over: all of them when the batch
    is a multiple of their number (on a CPU backend), else 1."""
    n = len(jax.devices("cpu"))
    return n if jax.default_backend() == "cpu" and n > 1 and batch % n == 0 else 1


def _structure(config: Config, n_dim: int) -> RolloutStructure:
    """The config's static structure for fleets in n_dim dimensions."""
    st = structures(config, only_needed=False)  # the grid may hold free-end scenarios
    nlp = dataclasses.replace(st.planner.nlp, n_dim=n_dim)
    return dataclasses.replace(st, planner=dataclasses.replace(st.planner, nlp=nlp))


# ------------------------------------------------------------------------ the sweep


@dataclass
class _Tally:
    """Seconds compiling and running, and batches run, so far."""

    compile_s: float = 0.0
    run_s: float = 0.0
    batches: int = 0


class _Progress:
    """The progress bar over runs, opened after the first compilation (so that its ETA
    counts runs only); does nothing when disabled."""

    def __init__(self, enabled: bool, total: int, name: str, initial: int):
        self.enabled, self.total, self.name, self.initial = enabled, total, name, initial
        self.bar = None

    def start(self) -> None:
        if self.enabled and self.bar is None:
            from jaxplan.progress import progress_bar

            self.bar = progress_bar(self.total, self.name, "run", initial=self.initial)

    def update(self, n: int) -> None:
        if self.bar is not None:
            self.bar.update(n)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _resume_csv(csv_path: Path, say) -> set:
    """The keys already in sweep.csv; a fresh file gets its header, and a damaged one (a
    kill mid-write) is rewritten with its complete rows, atomically."""
    rows, info = read_sweep_csv(csv_path)
    if not csv_path.exists() or not info.clean or csv_path.stat().st_size == 0:
        atomic_write_text(csv_path, csv_text(rows, header=True))
        if not info.clean:
            say(f"{csv_path}: dropped {info.partial_bytes} bytes of a partial last line, "
                f"{info.malformed} malformed and {info.duplicates} duplicate rows")
    return {row_key(r) for r in rows}


def _build_scenarios(config: Config, todo: list[SweepPoint]) -> dict[tuple[str, int], Scenario]:
    """Every (scenario label, seed) of the points, built once."""
    sources = {s.label: s for s in _sources(config)}
    built: dict[tuple[str, int], Scenario] = {}
    for p in todo:
        if (p.scenario, p.seed) not in built:
            try:
                built[(p.scenario, p.seed)] = sources[p.scenario].build(p.seed)
            except (scenarios.ScenarioError, ValueError) as e:
                raise SweepError(f"{config.source or config.name}: scenario "
                                 f"{p.scenario!r}, seed {p.seed}: {e}") from None
    return built


def _prepare(config: Config, point: SweepPoint, scenario: Scenario, m_pad: int) -> _Prepared:
    """A point's fleet parameters and task, as numpy, padded to m_pad robots."""
    fp = fleet_params(config, scenario, _weights(config, point.q_obs, point.q_lim))
    fp, task = _pad_robots(jax.tree.map(np.asarray, fp),
                           jax.tree.map(np.asarray, task_of(config, scenario)), m_pad)
    return _Prepared(point, scenario, fp, task)


def _compile_batch(fpb, taskb, structure: RolloutStructure, batch: int, shape, tally: _Tally,
                   say):
    """The batch program compiled for these stacked inputs; ``shape`` = (robots, dims,
    waypoints) for the message."""
    m_pad, n_dim, n_wp = shape
    sh = _shards(batch)
    say(f"compiling the planner: batch of {batch} runs x {m_pad} robots "
        f"x {structure.steps} replans ({n_dim}-D, {n_wp} waypoints"
        + (f"; {sh} CPU devices, {batch // sh} run(s) each)" if sh > 1 else ")"))
    compiled, seconds = timed(
        lambda: _batch_jit.lower(fpb, taskb, structure=structure, shards=sh).compile())
    tally.compile_s += seconds
    say(f"compiled in {seconds:.1f} s")
    return compiled


def _run_batch(config: Config, compiled, chunk: list[_Prepared], fpb, taskb,
               csv_path: Path) -> None:
    """Run one stacked batch; append the rows of its real (unpadded) runs to sweep.csv."""
    (reached, reach_time), records = compiled(fpb, taskb)
    records = jax.tree.map(np.asarray, records)
    final = _ReachState(np.asarray(reached), np.asarray(reach_time))
    rows = [_run_metrics(config, chunk[b], records, final, b) for b in range(len(chunk))]
    append_lines(csv_path, csv_text(rows))


def _run_group(config: Config, shape_key, points: list[SweepPoint], built, batch: int,
               csv_path: Path, tally: _Tally, bar: _Progress, say) -> None:
    """Run the points of one shape group (dims, waypoints) in batches of ``batch``, the
    last one padded by repeating its last run; each batch's rows appended to sweep.csv."""
    n_dim, n_wp = shape_key
    m_pad = max(built[(p.scenario, p.seed)].num_robots for p in points)
    structure = _structure(config, n_dim)
    preps = [_prepare(config, p, built[(p.scenario, p.seed)], m_pad) for p in points]
    compiled = None
    for i in range(0, len(preps), batch):
        chunk = preps[i:i + batch]
        full = chunk + [chunk[-1]] * (batch - len(chunk))
        fpb = stack_trees([c.fp for c in full])
        taskb = stack_trees([c.task for c in full])
        if compiled is None:
            compiled = _compile_batch(fpb, taskb, structure, batch, (m_pad, n_dim, n_wp),
                                      tally, say)
            bar.start()
        _, seconds = timed(_run_batch, config, compiled, chunk, fpb, taskb, csv_path)
        tally.run_s += seconds
        tally.batches += 1
        bar.update(len(chunk))


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


def _summary(res: SweepResult, n_rows: int, cpu_s: float) -> list[str]:
    """The lines run_sweep prints at the end."""
    lines = [
        f"compilations: {res.compilations}",
        f"runs: {res.ran} run now, {res.skipped} skipped (already done), "
        f"{n_rows} rows in {res.csv}",
        f"time: {res.wall_s:.1f} s wall ({res.compile_s:.1f} s compiling, {res.run_s:.1f} s "
        f"running {res.batches} batch{'es' if res.batches != 1 else ''}); {cpu_s:.1f} s CPU",
    ]
    best = res.best
    if best is not None:
        lines.append(
            "best setting: q_obs = {q_obs:.6g}, q_lim = {q_lim:.6g}  (success {s:.0f}%, "
            "{collisions:.3g} collisions/run, min separation ratio {msr:.3f}, makespan "
            "{mk} over {runs} runs)".format(
                s=100 * best["success_rate"], msr=best["min_separation_ratio"],
                mk=(f"{best['makespan_s']:.2f} s" if math.isfinite(best["makespan_s"])
                    else "n/a"), **best))
    return lines + [f"figure: {f}" for f in res.figures]


def run_sweep(config: Config, out_dir, *, progress: bool = True,
              batch_size: int | None = None, figures: bool = True,
              echo: Callable[[str], None] | None = print) -> SweepResult:
    """Run (or resume) the config's [sweep] grid into ``out_dir`` (see the module doc).

    Args:
        config: a validated Config with a [sweep] table (backend "ideal").
        out_dir: the sweep directory (created): sweep.csv, config.toml, figures/.
        progress: a tqdm progress bar over runs (with ETA).
        batch_size: runs per compiled batch (default: $JAXPLAN_SWEEP_BATCH or
            DEFAULT_BATCH; at most the number of runs left).
        figures: draw the heatmaps at the end.
        echo: where the summary lines go (None: nowhere).
    Returns: a :class:`SweepResult`.
    """
    t_wall = time.perf_counter()
    cpu0 = time.process_time()
    say = echo or (lambda s: None)
    if config.sim.backend != "ideal":
        raise SweepError(f"{config.source or config.name}: sim.backend = "
                         f"{config.sim.backend!r}: sweeps run the ideal backend only")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    csv_path = out / "sweep.csv"
    _guard_config(out, config)
    done = _resume_csv(csv_path, say)
    points = sweep_points(config)
    todo = [p for p in points if p.key not in done]
    skipped = len(points) - len(todo)
    batch = min(_batch_size(batch_size), len(todo))

    _CompileCounter.install()
    c0 = _CompileCounter.get()
    tally = _Tally()
    if todo:
        say(f"sweep {config.name}: {len(points)} runs ({skipped} already in {csv_path}), "
            f"{len(todo)} to go in batches of {batch}")
        built = _build_scenarios(config, todo)
        groups: dict[tuple[int, int], list[SweepPoint]] = {}  # by shape (dims, waypoints)
        for p in todo:
            sc = built[(p.scenario, p.seed)]
            groups.setdefault((sc.dim, sc.num_waypoints), []).append(p)
        bar = _Progress(progress, len(points), config.name, skipped)
        try:
            for shape_key, pts in groups.items():
                _run_group(config, shape_key, pts, built, batch, csv_path, tally, bar, say)
        finally:
            bar.close()
    compilations = _CompileCounter.get() - c0

    n_rows, best, figs = _best_and_figures(csv_path, out, figures)
    res = SweepResult(out, csv_path, len(points), skipped, len(todo), tally.batches, batch,
                      compilations, tally.compile_s, tally.run_s,
                      time.perf_counter() - t_wall, best, figs)
    for line in _summary(res, n_rows, time.process_time() - cpu0):
        say(line)
    return res
