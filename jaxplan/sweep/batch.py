"""Sweep grid points run in this process: what both sweep engines run
(:mod:`jaxplan.sweep.engines` locally, :mod:`jaxplan.sweep.ray` on Ray workers) and
`jaxplan tune` and `jaxplan rerun` too, so that a point's sweep.csv row is the same
whatever the engine, the batch size and the number of CPU devices.

    BatchRunner(config, say).run(points, built, m_pad, in_flight, on_compiled=None, *,
                                 weights=None, r_pad=None, on_rows=None) -> [row]
    BatchRunner(config, say).run_one(point, built, m_pad, r_pad) -> (config, scenario,
                                                                     records, final)
    BatchRunner(config, say).rows(points, built, m_pad, batch, ...) -> [row]   (vmapped)
    CompileCounter.install(), CompileCounter.get()      compilations of the batch program
    csv_row(point, metrics, n_waypoints, error) -> row  a run's row (jaxplan.sweep.table's)
    pad_robots(fp, task, m_pad), structure_for(config, n_dim, ...), with_weights(config, w)

The points and their built scenarios (``built``: the whole grid's) come from
:mod:`jaxplan.sweep.points`.

The program is :func:`jaxplan.rollout.rollout_batch` (vmapped over runs) with the
weights and every other fleet parameter as traced batched inputs, compiled once per
process, structure, shape (robots, dimensions, waypoints, static rows, batch) and
device, and kept. On a CPU every run is its own program of ONE run
(:meth:`BatchRunner.run`): the same program on every engine, whatever runs beside it, so
each run's closed loop computes the same floating-point operations wherever it runs;
``in_flight`` such runs go at once, in threads that call the one compiled program side
by side (a call runs without the GIL), so the number of CPU devices changes nothing. On
an accelerator a batch of ``in_flight`` runs is one vmapped call
(:meth:`BatchRunner.rows`; a batch of fewer points is padded by repeating its last run,
the duplicates dropped): its rows agree with a CPU's to round-off only.

What a run's program and inputs depend on is the grid's, never its batch's: fleets are
padded to ``m_pad`` robots (the largest fleet of the grid's shape group; masked robots,
``FleetParams.robot_mask``, parked far away, which the planner never plans for and no
robot sees), worlds to ``r_pad`` static rows (the grid's shape group's most; masked
rows), the NLP forms the static-row kinds of the whole grid (:func:`grid_kinds`), and
the guide is on for every run where a world of the grid needs it.  Compilations are
counted from JAX's own compile events (``jax.monitoring``, :class:`CompileCounter`).

Per-run weights (``weights``, for :mod:`jaxplan.tune`): each point may override any of
the [planner] settings in :data:`jaxplan.config.TUNABLE_WEIGHTS` besides its own q_obs and
q_lim (q_dynm, k_t, k_p, safety_margin_m); they are traced inputs like the point's q_obs
and q_lim (the weights, the prediction weight k_t / q_dynm, the radii plus the margin),
so runs of different weights share one compiled program.

Rows: :data:`jaxplan.sweep.table.COLUMNS`, from the run's metrics
(:func:`jaxplan.sweep.table.csv_row`).
"""

from __future__ import annotations

import dataclasses
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
from jaxplan.run_setup import fleet_params, planner_rows, structures, task_of
from jaxplan.scenarios import Scenario
from jaxplan.sweep.points import SweepPoint
from jaxplan.sweep.table import csv_row
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
        auto=cat(task.auto, False),
        goal_velocity=cat(task.goal_velocity, 0.0),
        faults=task.faults._replace(frozen=cat(task.faults.frozen, False)),
        guide=None if task.guide is None else task.guide._replace(value=np.concatenate(
            [np.asarray(task.guide.value),
             np.zeros((W, extra) + np.shape(task.guide.value)[2:])], axis=1)),
        own=None if task.own is None else jax.tree.map(
            lambda x: cat(x, np.asarray(x)[0]), task.own)._replace(
                mask=cat(task.own.mask, False)),
    )
    lim = fp.limits
    fp = fp._replace(
        limits=type(lim)(*(cat(x, np.asarray(x)[0]) for x in lim)),
        radius=cat(fp.radius, np.asarray(fp.radius)[0]),
        robot_mask=cat(fp.robot_mask, False),
    )
    return fp, task


def _prepare(config: Config, point: SweepPoint, scenario: Scenario, m_pad: int,
             r_pad: int, own: bool = False, knots: int | None = None) -> _Prepared:
    """A point's fleet parameters and task, as numpy, padded to m_pad robots and r_pad
    static rows (masked rows add exact zeros: the results do not depend on r_pad), the
    rows' motion to ``knots`` knots where the grid has moving obstacles
    (:func:`grid_knots`; rows at rest add exact zeros); ``own``: the task carries the
    non-cooperative robots' paths (every run of a grid that has one: :func:`_has_own`)."""
    fp = fleet_params(config, scenario, _weights(config, point.q_obs, point.q_lim), r_pad,
                      knots)
    fp, task = pad_robots(jax.tree.map(np.asarray, fp),
                          jax.tree.map(np.asarray, task_of(config, scenario, own)), m_pad)
    return _Prepared(point, scenario, fp, task)


def _has_own(built: dict) -> bool:
    """A scenario of the grid (``built``) has a non-cooperative robot."""
    return any(not np.all(sc.cooperative) for sc in built.values())


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


def grid_knots(scenarios) -> int | None:
    """The most knots of the grid's moving obstacles' motions (every world's rows then
    carry a motion of that many knots: one tree for every batch), None where none
    moves."""
    P = [s.world.num_knots for s in scenarios if s.world.has_motion]
    return max(P) if P else None


def grid_kinds(scenarios, n_dim: int) -> tuple[int, ...]:
    """The kinds of static rows the NLPs of these scenarios' n_dim-dimensional fleets
    hold: their worlds' obstacles' and PLANE (workspace faces and padding rows)."""
    kinds = [np.asarray(static_rows(s.world).kind).reshape(-1)
             for s in scenarios if s.dim == n_dim]
    return row_kinds(np.concatenate(kinds + [np.asarray([PLANE])]))


# ------------------------------------------------------------------------ the program


def _batch_program(fp, task, structure: RolloutStructure):
    final, records = rollout_batch(fp, task, structure, fp_axis=0)
    return (final.reached, final.reach_time), records


_batch_program.__name__ = PROGRAM
_batch_program.__qualname__ = PROGRAM
_batch_jit = jax.jit(_batch_program, static_argnames=("structure",))


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
                    cls._add(PROGRAM if PROGRAM in name else "other")

            def hits(event, **kw):
                if event == "/jax/compilation_cache/cache_hits":
                    cls._add("cache_hits")

            monitoring.register_event_duration_secs_listener(listener)
            monitoring.register_event_listener(hits)
            cls._installed = True

    _local = threading.local()  # this thread's counts (compiles run in several threads)

    @classmethod
    def _add(cls, key: str) -> None:
        with cls._lock:
            cls.counts[key] = cls.counts.get(key, 0) + 1
        mine = cls._local.__dict__.setdefault("counts", {})
        mine[key] = mine.get(key, 0) + 1

    @classmethod
    def get(cls, key: str = PROGRAM) -> int:
        return cls.counts.get(key, 0)

    @classmethod
    def get_here(cls, key: str = PROGRAM) -> int:
        """The count of this thread's events only (JAX reports a compilation in the
        thread that compiles)."""
        return cls._local.__dict__.get("counts", {}).get(key, 0)


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
_PROGRAMS_LOCK = threading.RLock()  # the kept programs and a runner's tally, across threads


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
        self._compile_locks: dict = {}
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

    def _compile(self, fpb, taskb, n_dim: int, batch: int, shape, structure, device=None):
        """The batch program for these inputs (``batch`` runs), compiled or kept from
        before; with ``device``, for that device (its inputs committed there)."""
        m_pad, _, n_wp, r_pad = shape
        # what jit keys a program on (the device: a CPU program runs on its own device)
        pkey = (structure, arg_key(fpb, taskb), device)
        with _PROGRAMS_LOCK:
            compiled = _PROGRAMS.get(pkey)
        if compiled is not None:
            self.say("the planner for this shape is compiled already (in this process)")
            return compiled
        where = f" on {device}" if device is not None else ""
        self.say(f"compiling the planner: batch of {batch} run{'s' if batch > 1 else ''} x "
                 f"{m_pad} robots x {structure.steps} replans ({n_dim}-D, {n_wp} "
                 f"waypoints){where}")
        c0, h0 = CompileCounter.get_here(), CompileCounter.get_here("cache_hits")
        if device is not None:
            fpb, taskb = jax.device_put((fpb, taskb), device)
        compiled, seconds = timed(
            lambda: _batch_jit.lower(fpb, taskb, structure=structure).compile())
        hits = CompileCounter.get_here("cache_hits") - h0
        with _PROGRAMS_LOCK:
            self.tally.compile_s += seconds
            self.tally.compilations += CompileCounter.get_here() - c0
            self.tally.cache_hits += hits
            _PROGRAMS.put(pkey, compiled)
        self.say(f"compiled in {seconds:.1f} s" + (" (from the compilation cache)" if hits else ""))
        return compiled

    # -------------------------------------------------------------- inputs of runs

    def _configs(self, points, weights, built) -> list[Config]:
        """Each point's config: its weights (``weights``: per point, {name: value} of
        its other traced [planner] weights, or None), and the guide on for every run
        where a scenario of ``built`` (the grid's) needs it: one task tree for the grid,
        whichever runs share a batch."""
        if weights is None:
            configs = [self.config] * len(points)
        else:
            if len(weights) != len(points):
                raise ValueError(f"{len(weights)} weight sets for {len(points)} points")
            if any({"q_obs", "q_lim"} & set(w) for w in weights):
                raise ValueError("q_obs and q_lim are the points' own, not weights'")
            configs = [with_weights(self.config, w) for w in weights]
        guide = self.config.planner.guide
        if guide not in ("off", "on") and any(guide_enabled(guide, sc.world)
                                              for sc in built.values()):
            configs = [dataclasses.replace(c, planner=dataclasses.replace(
                c.planner, guide="on")) for c in configs]
        return configs

    def _r_pad(self, points, built, r_pad: int | None) -> int:
        need = max(planner_rows(self.config, built[(p.scenario, p.seed)]) for p in points)
        if r_pad is None:
            return need
        if r_pad < need:
            raise ValueError(f"r_pad = {r_pad} < {need} static rows of a world in the batch")
        return r_pad

    # -------------------------------------------------------------- vmapped batches

    def rows(self, points, built: dict, m_pad: int, batch: int,
             on_compiled: Callable[[], None] | None = None, *, weights=None,
             r_pad: int | None = None) -> list[dict]:
        """The sweep.csv rows of ``points`` (at most ``batch``, one shape: dimensions and
        waypoints) run as one vmapped batch of ``batch`` runs with ``m_pad`` robots
        (what :meth:`run` does on an accelerator); ``built``: the grid's scenarios
        (:func:`jaxplan.sweep.points.build_scenarios`).  ``on_compiled`` is called after
        a compilation, before the run.  ``weights``: per point, {name: value} of its
        other traced [planner] weights (module doc; None: the config's).  ``r_pad``:
        static rows to pad every world to (default: the batch's largest world's)."""
        points = list(points)
        if not 1 <= len(points) <= batch:
            raise ValueError(f"a batch holds 1 to {batch} points, got {len(points)}")
        configs = self._configs(points, weights, built)
        r_pad = self._r_pad(points, built, r_pad)
        own, knots = _has_own(built), grid_knots(built.values())  # the grid's, once
        preps = [_prepare(c, p, built[(p.scenario, p.seed)], m_pad, r_pad, own, knots)
                 for c, p in zip(configs, points, strict=True)]
        full = preps + [preps[-1]] * (batch - len(preps))
        fpb = stack_trees([c.fp for c in full])
        taskb = stack_trees([c.task for c in full])
        sc = preps[0].scenario
        shape = (m_pad, sc.dim, sc.num_waypoints, r_pad)
        structure = self.structure(sc.dim, r_pad, built, [p.scenario for p in preps])
        key = (shape, batch, structure, None)
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

    # -------------------------------------------------------------- one-run programs

    def _one_run_inputs(self, prep: _Prepared):
        """A run's inputs as a batch of one (the one-run program's)."""
        return stack_trees([prep.fp]), stack_trees([prep.task])

    def _one_run_program(self, prep: _Prepared, built: dict, r_pad: int, device):
        """The one-run program of this run's shape on ``device``, compiled once per
        runner, shape and device (a lock per key: one compilation when two threads
        want it)."""
        sc = prep.scenario
        m_pad = np.shape(prep.task.start)[0]
        shape = (m_pad, sc.dim, sc.num_waypoints, r_pad)
        with _PROGRAMS_LOCK:
            structure = self.structure(sc.dim, r_pad, built, [sc])
            key = (shape, 1, structure, device)
            lock = self._compile_locks.setdefault(key, threading.Lock())
        with lock:
            compiled = self._compiled.get(key)
            if compiled is None:
                fpb, taskb = self._one_run_inputs(prep)
                compiled = self._compiled[key] = self._compile(fpb, taskb, sc.dim, 1, shape,
                                                               structure, device)
        return compiled

    def run_one(self, point: SweepPoint, built: dict, m_pad: int, r_pad: int | None = None,
                *, weights: dict | None = None, device=None):
        """One grid point through its one-run program (what :meth:`run` does with it on
        a CPU): (its config, its scenario, its records (numpy, unpadded robots), its
        final reached / reach_time).  ``device``: a CPU device (default the first)."""
        device = jax.devices("cpu")[0] if device is None else device
        config = self._configs([point], None if weights is None else [weights], built)[0]
        r_pad = self._r_pad([point], built, r_pad)
        prep = _prepare(config, point, built[(point.scenario, point.seed)], m_pad, r_pad,
                        _has_own(built), grid_knots(built.values()))
        compiled = self._one_run_program(prep, built, r_pad, device)
        (reached, reach_time), records = compiled(*jax.device_put(
            self._one_run_inputs(prep), device))
        M = prep.scenario.num_robots

        def lane(x):
            x = np.asarray(x)[0]
            return x[:, :M] if x.ndim >= 2 else x

        final = _ReachState(np.asarray(reached)[0, :M], np.asarray(reach_time)[0, :M])
        return config, prep.scenario, jax.tree.map(lane, records), final

    def run(self, points, built: dict, m_pad: int, in_flight: int,
            on_compiled: Callable[[], None] | None = None, *, weights=None,
            r_pad: int | None = None, on_rows: Callable[[list[dict]], None] | None = None
            ) -> list[dict]:
        """The sweep.csv rows of ``points`` (one shape group: dimensions and waypoints),
        in their order, with ``m_pad`` robots and ``r_pad`` static rows (default: the
        points' largest world's; a sweep passes its grid's).

        On a CPU every run is its own one-run program (the same program whatever else
        runs: its row is the same on every engine, batch size and number of CPU
        devices), ``in_flight`` runs at a time (threads calling that one compiled
        program).  On an accelerator: vmapped batches of ``in_flight`` runs
        (:meth:`rows`).
        ``on_compiled`` after the programs are compiled; ``on_rows(rows)`` as rows are
        done, in order."""
        points = list(points)
        if not points:
            return []
        if weights is not None and len(weights) != len(points):
            raise ValueError(f"{len(weights)} weight sets for {len(points)} points")
        r_pad = self._r_pad(points, built, r_pad)
        if jax.default_backend() != "cpu":
            out = []
            for k in range(0, len(points), in_flight):
                chunk = points[k:k + in_flight]
                w = None if weights is None else weights[k:k + in_flight]
                rows = self.rows(chunk, built, m_pad, in_flight, on_compiled, weights=w,
                                 r_pad=r_pad)
                if on_rows is not None:
                    on_rows(rows)
                out += rows
            return out
        return self._run_cpu(points, built, m_pad, max(1, int(in_flight)), on_compiled,
                             weights, r_pad, on_rows)

    def _run_cpu(self, points, built, m_pad, in_flight, on_compiled, weights, r_pad,
                 on_rows) -> list[dict]:
        """:meth:`run` on a CPU: the one-run program compiled once (for the first CPU
        device), then ``in_flight`` worker threads, each running one run after another
        through it (a call runs in its caller's thread, without the GIL: the runs go
        side by side on the cores; one executable, so the same operations for all)."""
        configs = self._configs(points, weights, built)
        own, knots = _has_own(built), grid_knots(built.values())  # the grid's, once
        preps = [_prepare(c, p, built[(p.scenario, p.seed)], m_pad, r_pad, own, knots)
                 for c, p in zip(configs, points, strict=True)]
        device = jax.devices("cpu")[0]
        self._one_run_program(preps[0], built, r_pad, device)
        if on_compiled is not None:
            on_compiled()

        results: list[dict | None] = [None] * len(points)
        todo = iter(range(len(points)))
        done = threading.Condition()
        errors: list = []

        def work():
            while not errors:
                with done:
                    i = next(todo, None)
                if i is None:
                    return
                compiled = self._one_run_program(preps[i], built, r_pad, device)
                t0 = time.perf_counter()
                (reached, reach_time), records = compiled(*jax.device_put(
                    self._one_run_inputs(preps[i]), device))
                records = jax.tree.map(np.asarray, records)
                final = _ReachState(np.asarray(reached), np.asarray(reach_time))
                row = _run_metrics(configs[i], preps[i], records, final, 0)
                with done:
                    self.tally.run_s += time.perf_counter() - t0
                    self.tally.batches += 1
                    results[i] = row
                    done.notify_all()

        threads = [threading.Thread(target=_capture, args=(work, errors), daemon=True)
                   for _ in range(min(in_flight, len(points)))]
        for t in threads:
            t.start()
        flushed = 0
        while flushed < len(points):
            with done:
                while (results[flushed] is None and not errors
                       and any(t.is_alive() for t in threads)):
                    done.wait(timeout=1.0)
                ready = []
                while flushed < len(points) and results[flushed] is not None:
                    ready.append(results[flushed])
                    flushed += 1
            if ready and on_rows is not None:
                on_rows(ready)
            if errors or not (ready or any(t.is_alive() for t in threads)):
                break
        for t in threads:
            t.join()
        if errors:
            raise errors[0]
        return list(results)


def _capture(fn, errors: list) -> None:
    """fn() in a thread, its exception kept in ``errors``."""
    try:
        fn()
    except BaseException as e:  # re-raised in the calling thread
        errors.append(e)
