"""One batch of sweep grid points, run in this process: what both sweep engines run
(:mod:`jaxplan.sweep.engines` locally, :mod:`jaxplan.sweep.ray` on Ray workers), so that a
point's sweep.csv row is the same whatever the engine.

    BatchRunner(config, say).rows(points, built, m_pad, batch, on_compiled=None, *,
                                  weights=None, r_pad=None) -> [row]
    CompileCounter.install(), CompileCounter.get()      compilations of the batch program
    csv_row(point, metrics, n_waypoints, error) -> row  a run's sweep.csv row
    pad_robots(fp, task, m_pad), structure_for(config, n_dim, ...), with_weights(config, w)

The points and their built scenarios (``built``) come from :mod:`jaxplan.sweep.points`.

A batch is one call of one compiled program (:func:`jaxplan.rollout.rollout_batch`,
vmapped over runs) with the weights and every other fleet parameter as traced batched
inputs.  A batch of fewer points than ``batch`` is padded by repeating its last run (the
duplicates are dropped), so every batch of a shape has the same shape.  Fleets smaller
than ``m_pad`` robots are padded with masked robots (``FleetParams.robot_mask``) parked
far away, which the planner never plans for and no robot sees.  On a CPU with several
devices a batch whose size is a multiple of their number is split over them, each
device running its own runs side by side (:func:`jaxplan.solve.shard_lanes`).  The
program is compiled once per process, structure and shape (robots, dimensions,
waypoints, batch) and kept; compilations are counted from JAX's own compile events
(``jax.monitoring``, :class:`CompileCounter`).

Per-run weights (``weights``, for :mod:`jaxplan.tune`): each point may override any of
the [planner] settings in :data:`jaxplan.config.TUNABLE_WEIGHTS` besides its own q_obs and
q_lim (q_dynm, k_t, k_p, safety_margin_m); they are traced inputs like the point's q_obs
and q_lim (the weights, the prediction weight k_t / q_dynm, the radii plus the margin),
so runs of different weights share one compiled program.

Rows: :data:`jaxplan.sweep.table.COLUMNS`, from the run's metrics (:func:`csv_row`).
"""

from __future__ import annotations

import dataclasses
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import jax
import numpy as np

from jaxplan.config import TUNABLE_WEIGHTS, Config
from jaxplan.experiment import stack_trees
from jaxplan.metrics.report import compute_metrics
from jaxplan.nlp import Weights
from jaxplan.planner.guide import guide_enabled
from jaxplan.rollout import RolloutStructure, Task, rollout_batch
from jaxplan.run_setup import fleet_params, structures, task_of
from jaxplan.scenarios import Scenario
from jaxplan.solve import shard_lanes
from jaxplan.sweep.points import SweepPoint
from jaxplan.timing import KeptPrograms, arg_key, timed
from jaxplan.world import ALL_KINDS, PLANE, row_kinds, static_rows

__all__ = [
    "BatchRunner",
    "CompileCounter",
    "Tally",
    "csv_row",
    "grid_kinds",
    "pad_robots",
    "structure_for",
    "with_weights",
]

PARK_DISTANCE = 1.0e4  # m: where padding robots are parked
PARK_SPACING = 10.0  # m between parked padding robots
PROGRAM = "jaxplan_sweep_batch"  # the batch program's name in JAX's compile events


# ------------------------------------------------------------------------ rows


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


def csv_row(point: SweepPoint, metrics: dict | None, n_waypoints: int = 1,
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
        "error": error,
        "obstacle_collisions": _csv_cell(int(metrics["obstacle_collisions"])),
        "min_obstacle_clearance_m": _csv_cell(metrics["min_obstacle_clearance_m"]),
        "workspace_violations": _csv_cell(int(metrics["workspace_violations"])),
        "min_workspace_clearance_m": _csv_cell(metrics["min_workspace_clearance_m"]),
        "stalls": _csv_cell(int(metrics.get("stalls", 0))),
        "stalled_s": _csv_cell(metrics.get("stalled_s")),
        "parked": _csv_cell(int(metrics.get("parked", 0))),
        "makespan_over_bound": _csv_cell(metrics.get("makespan_over_bound")),
        "settled_makespan_s": _csv_cell(metrics.get("settled_makespan_s")),
        "max_goal_departure_m": _csv_cell(metrics.get("max_goal_departure_m")),
    })
    return row


# ------------------------------------------------------------------------ inputs


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


def pad_robots(fp, task: Task, m_pad: int):
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
        guide=None if task.guide is None else task.guide._replace(value=np.concatenate(
            [np.asarray(task.guide.value),
             np.zeros((W, extra) + np.shape(task.guide.value)[2:])], axis=1)),
    )
    lim = fp.limits
    fp = fp._replace(
        limits=type(lim)(*(cat(x, np.asarray(x)[0]) for x in lim)),
        radius=cat(fp.radius, np.asarray(fp.radius)[0]),
        robot_mask=cat(fp.robot_mask, False),
    )
    return fp, task


def _prepare(config: Config, point: SweepPoint, scenario: Scenario, m_pad: int,
             r_pad: int) -> _Prepared:
    """A point's fleet parameters and task, as numpy, padded to m_pad robots and r_pad
    static rows (masked rows add exact zeros: the results do not depend on r_pad)."""
    fp = fleet_params(config, scenario, _weights(config, point.q_obs, point.q_lim), r_pad)
    fp, task = pad_robots(jax.tree.map(np.asarray, fp),
                          jax.tree.map(np.asarray, task_of(config, scenario)), m_pad)
    return _Prepared(point, scenario, fp, task)


def structure_for(config: Config, n_dim: int, n_static: int | None = None,
                  scenarios: list[Scenario] | None = None) -> RolloutStructure:
    """The config's static structure for fleets in n_dim dimensions in worlds of
    ``n_static`` static rows (default: the config's own world's).  ``scenarios``: the
    grid's (those of n_dim dimensions count): the NLP forms the kinds of static rows
    their worlds hold (:func:`grid_kinds`; the solutions are bitwise those of every
    kind); None: every kind.  The coast rows are always formed (the grid may hold free
    ends; leaving them out where it holds none rounds differently)."""
    kinds = ALL_KINDS if scenarios is None else grid_kinds(scenarios, n_dim)
    st = structures(config, only_needed=False, n_static=n_static, static_kinds=kinds)
    nlp = dataclasses.replace(st.planner.nlp, n_dim=n_dim)
    return dataclasses.replace(st, planner=dataclasses.replace(st.planner, nlp=nlp))


def grid_kinds(scenarios, n_dim: int) -> tuple[int, ...]:
    """The kinds of static rows the NLPs of these scenarios' n_dim-dimensional fleets
    hold: their worlds' obstacles' and PLANE (workspace faces and padding rows)."""
    kinds = [np.asarray(static_rows(s.world).kind).reshape(-1)
             for s in scenarios if s.dim == n_dim]
    return row_kinds(np.concatenate(kinds + [np.asarray([PLANE])]))


# ------------------------------------------------------------------------ the program


def _batch_program(fp, task, structure: RolloutStructure, shards: int = 1):
    def runs(fp, task):
        final, records = rollout_batch(fp, task, structure, fp_axis=0)
        return (final.reached, final.reach_time), records

    # runs split over the CPU's devices, each running its own (module doc)
    return shard_lanes(runs, (fp, task), shards)


_batch_program.__name__ = PROGRAM
_batch_program.__qualname__ = PROGRAM
_batch_jit = jax.jit(_batch_program, static_argnames=("structure", "shards"))


def cpu_shards(batch: int) -> int:
    """CPU devices a batch of ``batch`` runs is split over: all of them when the batch
    is a multiple of their number (on a CPU backend), else 1."""
    n = len(jax.devices("cpu"))
    return n if jax.default_backend() == "cpu" and n > 1 and batch % n == 0 else 1


class CompileCounter:
    """Counts JAX backend compilations of the batch program, and loads from the
    persistent compilation cache ("cache_hits", any program), from jax.monitoring
    events.  A load counts as a compilation too (JAX times both as one compile event)."""

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
                    key = PROGRAM if PROGRAM in name else "other"
                    cls.counts[key] = cls.counts.get(key, 0) + 1

            def hits(event, **kw):
                if event == "/jax/compilation_cache/cache_hits":
                    cls.counts["cache_hits"] = cls.counts.get("cache_hits", 0) + 1

            monitoring.register_event_duration_secs_listener(listener)
            monitoring.register_event_listener(hits)
            cls._installed = True

    @classmethod
    def get(cls, key: str = PROGRAM) -> int:
        return cls.counts.get(key, 0)


class _ReachState(NamedTuple):
    """What compute_metrics reads of a rollout's final state: reached (.., M, W) and
    reach_time (.., M, W) s."""

    reached: np.ndarray
    reach_time: np.ndarray


def with_weights(config: Config, weights) -> Config:
    """The config with [planner] settings of :data:`jaxplan.config.TUNABLE_WEIGHTS`
    replaced (``weights``: {name: value}, may be empty); any other name is a ValueError
    (it may change the program's structure)."""
    if not weights:
        return config
    bad = sorted(set(weights) - set(TUNABLE_WEIGHTS))
    if bad:
        raise ValueError(f"not traced weights: {', '.join(bad)} (traced: "
                         f"{', '.join(TUNABLE_WEIGHTS)})")
    return dataclasses.replace(config, planner=dataclasses.replace(
        config.planner, **{k: float(v) for k, v in weights.items()}))


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
        return csv_row(prep.point, None, error=msg)
    return csv_row(prep.point, metrics, prep.scenario.num_waypoints)


@dataclass
class Tally:
    """Seconds compiling and running, batches run and compilations of the batch
    program (cache_hits of them loaded from the persistent cache), so far."""

    compile_s: float = 0.0
    run_s: float = 0.0
    batches: int = 0
    compilations: int = 0
    cache_hits: int = 0  # of the compilations, loads from the persistent cache


# this process's compiled batch programs, the most recently used last: a sweep (or a
# shard, or a Ray worker's next task) of the same structure and shapes reuses one
MAX_PROGRAMS = 8
_PROGRAMS = KeptPrograms(MAX_PROGRAMS)


class BatchRunner:
    """Runs batches of one config's grid points in this process; the batch program is
    compiled once per shape and process, and kept (the last :data:`MAX_PROGRAMS`;
    ``tally``: what this runner cost so far, a reused program no compilation; ``say``:
    where the compiling messages go)."""

    def __init__(self, config: Config, say: Callable[[str], None] = lambda s: None):
        self.config = config
        self.say = say
        self.tally = Tally()
        self._compiled: dict = {}
        self._structures: dict[tuple[int, int], RolloutStructure] = {}
        CompileCounter.install()

    def structure(self, n_dim: int, r_pad: int, built: dict, batch_scenarios) -> RolloutStructure:
        """The structure of this runner's n_dim-dimensional batches padded to r_pad static
        rows: the kinds of static rows of every scenario in ``built`` (the grid's, in a
        sweep; :func:`structure_for`), made at the first batch and kept while it covers
        the batches' scenarios (a batch that needs more: one made from ``built`` again,
        so one more compilation)."""
        have = self._structures.get((n_dim, r_pad))
        # all else is the config's, n_dim's and r_pad's: only the kinds can fall short
        if have is None or not set(grid_kinds(batch_scenarios, n_dim)) <= set(
                have.planner.nlp.static_kinds):
            have = self._structures[(n_dim, r_pad)] = structure_for(
                self.config, n_dim, r_pad, [*built.values(), *batch_scenarios])
        return have

    def _compile(self, fpb, taskb, n_dim: int, batch: int, shape, structure):
        m_pad, _, n_wp, r_pad = shape
        sh = cpu_shards(batch)
        pkey = (structure, sh, arg_key(fpb, taskb))  # what jit keys a program on
        compiled = _PROGRAMS.get(pkey)
        if compiled is not None:
            self.say("the planner for this shape is compiled already (in this process)")
            return compiled
        self.say(f"compiling the planner: batch of {batch} runs x {m_pad} robots "
                 f"x {structure.steps} replans ({n_dim}-D, {n_wp} waypoints"
                 + (f"; {sh} CPU devices, {batch // sh} run(s) each)" if sh > 1 else ")"))
        c0, h0 = CompileCounter.get(), CompileCounter.get("cache_hits")
        compiled, seconds = timed(
            lambda: _batch_jit.lower(fpb, taskb, structure=structure, shards=sh).compile())
        self.tally.compile_s += seconds
        self.tally.compilations += CompileCounter.get() - c0
        hits = CompileCounter.get("cache_hits") - h0
        self.tally.cache_hits += hits
        self.say(f"compiled in {seconds:.1f} s" + (" (from the compilation cache)" if hits else ""))
        return _PROGRAMS.put(pkey, compiled)

    def rows(self, points, built: dict, m_pad: int, batch: int,
             on_compiled: Callable[[], None] | None = None, *, weights=None,
             r_pad: int | None = None) -> list[dict]:
        """The sweep.csv rows of ``points`` (at most ``batch``, one shape: dimensions and
        waypoints) run as one batch of ``batch`` runs with ``m_pad`` robots; ``built``:
        their scenarios (:func:`jaxplan.sweep.points.build_scenarios`).  ``on_compiled``
        is called after a compilation, before the run.  ``weights``: per point, {name:
        value} of its other traced [planner] weights (module doc; None: the config's).
        ``r_pad``: static rows to pad every world to (default: the batch's largest
        world's)."""
        points = list(points)
        if not 1 <= len(points) <= batch:
            raise ValueError(f"a batch holds 1 to {batch} points, got {len(points)}")
        if weights is None:
            configs = [self.config] * len(points)
        else:
            if len(weights) != len(points):
                raise ValueError(f"{len(weights)} weight sets for {len(points)} points")
            if any({"q_obs", "q_lim"} & set(w) for w in weights):
                raise ValueError("q_obs and q_lim are the points' own, not weights'")
            configs = [with_weights(self.config, w) for w in weights]
        need = max(static_rows(built[(p.scenario, p.seed)].world).mask.shape[0]
                   for p in points)
        if r_pad is None:
            r_pad = need
        elif r_pad < need:
            raise ValueError(f"r_pad = {r_pad} < {need} static rows of a world in the batch")
        # one batch, one task tree: the guide for every run if a run of it needs one
        if any(guide_enabled(c.planner.guide, built[(p.scenario, p.seed)].world)
               for c, p in zip(configs, points, strict=True)):
            configs = [c if c.planner.guide == "off" else dataclasses.replace(
                c, planner=dataclasses.replace(c.planner, guide="on")) for c in configs]
        preps = [_prepare(c, p, built[(p.scenario, p.seed)], m_pad, r_pad)
                 for c, p in zip(configs, points, strict=True)]
        full = preps + [preps[-1]] * (batch - len(preps))
        fpb = stack_trees([c.fp for c in full])
        taskb = stack_trees([c.task for c in full])
        sc = preps[0].scenario
        shape = (m_pad, sc.dim, sc.num_waypoints, r_pad)
        structure = self.structure(sc.dim, r_pad, built, [p.scenario for p in preps])
        key = (shape, batch, structure)
        compiled = self._compiled.get(key)
        if compiled is None:
            compiled = self._compiled[key] = self._compile(fpb, taskb, sc.dim, batch, shape,
                                                           structure)
            if on_compiled is not None:
                on_compiled()

        t0 = time.perf_counter()
        (reached, reach_time), records = compiled(fpb, taskb)
        records = jax.tree.map(np.asarray, records)
        final = _ReachState(np.asarray(reached), np.asarray(reach_time))
        rows = [_run_metrics(configs[b], preps[b], records, final, b)
                for b in range(len(preps))]
        self.tally.run_s += time.perf_counter() - t0
        self.tally.batches += 1
        return rows
