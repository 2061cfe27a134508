"""From a Config to a finished run: set-up, the jitted rollout, metrics.

``run(config)`` is what ``jaxplan run`` does, without writing files (that is
:mod:`jaxplan.files`; the metrics are :mod:`jaxplan.metrics.report`'s).  A single run
steps through one compiled replan period per call (:func:`simulate`), which times every
fleet replan individually (``solver.median_ms / p95_ms / max_ms`` in metrics.json: wall
time of the whole jitted replan + execution period, i.e. predictions, all NLP solves and
bookkeeping) and drives the progress bar.  Batches of runs use the single ``lax.scan`` of
:mod:`jaxplan.rollout`, vmapped.
"""

from __future__ import annotations

import dataclasses
import hashlib
from dataclasses import dataclass

import jax
import numpy as np

from jaxplan.config import Config, build_scenario
from jaxplan.metrics.report import compute_metrics, merge_sim_metrics
from jaxplan.planner import FleetParams
from jaxplan.rollout import RolloutStructure, Task, initial_state, step
from jaxplan.run_setup import fleet_params, structures, task_of
from jaxplan.scenarios import Scenario
from jaxplan.timing import KeptPrograms, arg_key, timed


@dataclass
class RunResult:
    """Everything a run produced (host arrays).

    metrics: the metrics.json dict.  arrays: the trajectories.npz dict.  records: the
    stacked StepRecord (numpy).  compile_s, run_s: seconds.  scenario: the Scenario.
    """

    config: Config
    scenario: Scenario
    metrics: dict
    arrays: dict
    records: object
    compile_s: float
    run_s: float


_STEP_CACHE: dict = {}


def step_runner(structure: RolloutStructure):
    """The jitted replan period (cached per structure: one compilation per shape)."""
    key = dataclasses.replace(structure, steps=0)  # the step does not depend on steps
    if key not in _STEP_CACHE:
        _STEP_CACHE[key] = jax.jit(lambda fp, task, st: step(fp, task, st, key))
    return _STEP_CACHE[key]


# this process's compiled replan periods (backend "ideal"): another run of the same
# structure and shapes in this process (a notebook's, the tests') reuses one
_PROGRAMS = KeptPrograms(8)


def _program_key(structure: RolloutStructure, fp, task, st):
    """What a compiled replan period is kept under: the structure but its steps, and its
    arguments' shapes (:func:`jaxplan.timing.arg_key`)."""
    return dataclasses.replace(structure, steps=0), arg_key(fp, task, st)


def compiled_step(fp: FleetParams, task: Task, st, structure: RolloutStructure):
    """(the compiled replan period of :func:`step_runner`, seconds spent compiling it):
    compiled once per structure and shapes in this process and kept (the last 8); a kept
    one costs 0 s."""
    key = _program_key(structure, fp, task, st)
    compiled = _PROGRAMS.get(key)
    if compiled is not None:
        return compiled, 0.0
    compiled, compile_s = timed(lambda: step_runner(structure).lower(fp, task, st).compile())
    return _PROGRAMS.put(key, compiled), compile_s


def simulate(fp: FleetParams, task: Task, structure: RolloutStructure, progress=None):
    """Run one scenario, one jitted replan period per call, timing every replan.

    Each call is the same compiled computation as one iteration of
    :func:`jaxplan.rollout.rollout`'s scan (batches use that scan); stepping from the
    host costs ~0.1 ms per replan and gives every replan's wall time and a live
    progress bar.

    Returns (final state, records stacked over ``structure.steps``, compile_s (0 where
    this process compiled the same program before: :func:`compiled_step`), run_s,
    replan_ms (steps,)).  ``progress``: optional callable(n_steps_done).
    """
    st = initial_state(task, structure)
    compiled, compile_s = compiled_step(fp, task, st, structure)
    st, records, run_s, ms = _run_periods(lambda st: compiled(fp, task, st), st,
                                          structure.steps, progress)
    return st, records, compile_s, run_s, ms


# this process's compiled MJX periods: another run of the same structure, vehicles,
# rates and shapes in this process (a notebook's loop over weights) reuses one
_MJX_PROGRAMS = KeptPrograms(4)


def _sim_key(sim) -> tuple:
    """A simulated fleet (jaxplan.sim.fleet.SimModel) as a key: its tree (the static
    fields: vehicle names, layout, rates, ...) and a digest of its arrays' shapes, dtypes
    and bytes (~5 kB for a fleet; the starts are not in it)."""
    leaves, tree = jax.tree.flatten(sim)
    h = hashlib.sha256()
    for x in leaves:
        x = np.ascontiguousarray(np.asarray(x))
        h.update(f"{x.shape}{x.dtype.str};".encode())
        h.update(x.tobytes())
    return tree, h.hexdigest()


@dataclass(frozen=True)
class MjxSetup:
    """What a run on the MJX backend simulates: the fleet (jaxplan.sim.fleet.SimModel),
    the replan period (s), the initial planner and simulator states, and the key its
    compiled period is kept under in this process (:data:`_MJX_PROGRAMS`)."""

    sim: object
    period: float
    state: object
    sim_state: object
    key: tuple


def mjx_setup(config: Config, scenario: Scenario, fp: FleetParams, task: Task,
              structure: RolloutStructure) -> MjxSetup:
    """The simulated fleet and initial states of a run on the MJX backend (3-D only)."""
    from jaxplan.sim import closed_loop as cl
    from jaxplan.sim import fleet as sf

    if scenario.start.shape[1] != 3:
        raise ValueError(f"{config.source or config.name}: sim.backend = 'mjx' needs 3-D "
                         "positions")
    sim, _ = sf.init_sim(list(scenario.vehicles), scenario.start,
                         physics_hz=config.sim.physics_hz, control_hz=config.sim.control_hz,
                         world=scenario.world)
    period = 1.0 / config.planner.replan_hz
    st, ss = cl.mjx_initial_state(task, structure, sim)
    # the period closes over the simulated fleet (its model's arrays are constants of
    # the program): kept under the fleet's tree and bytes as well as the arguments' shapes
    key = (dataclasses.replace(structure, steps=0), period, _sim_key(sim),
           arg_key(fp, task, st, ss))
    return MjxSetup(sim, period, st, ss, key)


def simulate_mjx(config: Config, scenario: Scenario, fp: FleetParams, task: Task,
                 structure: RolloutStructure, progress=None, setup: MjxSetup | None = None):
    """Backend "mjx": the planner closed around MJX quadrotors, one jitted period per call.

    ``setup``: :func:`mjx_setup`'s (made here when None).  Returns (final RolloutState,
    StepRecords (numpy, stacked), PeriodRecords (numpy, stacked), compile_s (0 where this
    process compiled the same period before: the same structure but its steps, vehicles,
    rates and shapes), run_s, period_ms (steps,): wall time of each period, planning and
    physics together).
    """
    from jaxplan.sim import closed_loop as cl

    s = setup or mjx_setup(config, scenario, fp, task, structure)
    compiled, compile_s = _MJX_PROGRAMS.get(s.key), 0.0
    if compiled is None:
        fn = jax.jit(lambda fp, task, st, ss: cl.mjx_step(fp, task, st, ss, structure, s.sim,
                                                           s.period))
        compiled, compile_s = timed(lambda: fn.lower(fp, task, s.state, s.sim_state).compile())
        _MJX_PROGRAMS.put(s.key, compiled)
    (st, ss), stacked, run_s, ms = _run_periods(lambda c: compiled(fp, task, *c),
                                                (s.state, s.sim_state), structure.steps,
                                                progress)
    return st, stacked.step, stacked.period, compile_s, run_s, ms


def stack_trees(items):
    """Stack a list of equally shaped pytrees into one pytree of numpy arrays (leading
    axis: the list)."""
    return jax.tree.map(lambda *xs: np.stack([np.asarray(x) for x in xs]), *items)


def _run_periods(call, carry, steps: int, progress):
    """``carry, record = call(carry)`` ``steps`` times, timing every call.

    Returns (final carry, the records stacked (numpy), run_s: seconds of the whole loop,
    ms (steps,): milliseconds of each call).  ``progress``: optional callable(n_done).
    """
    def loop(carry):
        recs = []
        ms = np.empty(steps)
        for k in range(steps):
            (carry, rec), seconds = timed(call, carry)
            ms[k] = 1e3 * seconds
            recs.append(rec)
            if progress:
                progress(k + 1)
        return carry, stack_trees(recs), ms

    (carry, records, ms), run_s = timed(loop, carry)
    return carry, records, run_s, ms


def run_method(config: Config, scenario, *, progress: bool = False) -> RunResult:
    """A baseline planner's run of ``scenario`` (``[planner] method`` "orca": RVO2
    through pyrvo, :mod:`jaxplan.baselines.orca`; "orca3d": RVO2-3D in JAX,
    :mod:`jaxplan.baselines.orca3d`, compile_s its step's compile); no files are
    written.  Raises ValueError where the method refuses the scenario or the config."""
    method = config.planner.method
    if not np.all(scenario.cooperative):
        raise ValueError(f"[planner] method = {method!r} moves every robot itself: a fleet "
                         "with non-cooperative robots ([[robots]] cooperative) needs the "
                         "planner, method 'krishnan'")
    if method == "orca":
        from jaxplan.baselines.orca import run_orca

        metrics, arrays, records, run_s = run_orca(config, scenario, progress=progress)
        return RunResult(config, scenario, metrics, arrays, records, 0.0, run_s)
    if method == "orca3d":
        from jaxplan.baselines.orca3d import run_orca3d

        metrics, arrays, records, run_s = run_orca3d(config, scenario, progress=progress)
        return RunResult(config, scenario, metrics, arrays, records, metrics["compile_s"],
                         run_s)
    raise ValueError(f"[planner] method = {method!r}: no such baseline")


def run(config: Config, *, progress: bool = False) -> RunResult:
    """Run one experiment (backend "ideal" or "mjx"); no files are written.

    Args:
        config: a validated Config (jaxplan.config.load_config / parse_config).
        progress: say on stderr that the planner compiles, then show progress over
            replans from the first one (a tqdm bar on a terminal, a line every 30 s
            otherwise: jaxplan.progress).
    ``[planner] method`` other than "krishnan": a baseline (:func:`run_method`).
    """
    scenario = build_scenario(config)
    if config.planner.method != "krishnan":
        return run_method(config, scenario, progress=progress)
    structure = structures(config)
    fp = fleet_params(config, scenario)
    task = task_of(config, scenario)
    bar = setup = None
    if progress:  # opened at the first replan, after the compile (its ETA is the run's)
        import sys

        from jaxplan.progress import AfterFirstUpdate

        if config.sim.backend == "mjx":
            setup = mjx_setup(config, scenario, fp, task, structure)
            kept = setup.key in _MJX_PROGRAMS
        else:
            kept = _program_key(structure, fp, task, initial_state(task, structure)) in _PROGRAMS
        print(f"{config.name}: " + ("the planner is compiled already (in this process)" if kept
                                    else "compiling the planner") +
              f" ({scenario.start.shape[0]} robots, {structure.steps} replans, backend "
              f"{config.sim.backend})", file=sys.stderr, flush=True)
        bar = AfterFirstUpdate(structure.steps, config.name, "replan", leave=False)

    def _prog(n):
        if bar is not None:
            bar.set(n)

    if config.sim.backend == "mjx":
        final, records, period, compile_s, run_s, solve_ms = simulate_mjx(
            config, scenario, fp, task, structure, _prog, setup)
    else:
        final, records, compile_s, run_s, solve_ms = simulate(fp, task, structure, _prog)
    if bar is not None:
        bar.close()
    metrics, arrays = compute_metrics(config, scenario, records, final, solve_ms)
    if config.sim.backend == "mjx":
        merge_sim_metrics(metrics, arrays, scenario, period)
    metrics["compile_s"] = compile_s
    metrics["run_s"] = run_s
    return RunResult(config, scenario, metrics, arrays, records, compile_s, run_s)
