"""A tune's runs and a trial's objective: the [tune] scenarios, runs of weight settings
through the sweep's batch program, and the statistics of a trial's runs.

    TuneError                                   a tune that cannot start
    scenario_sources(config) -> {label: seed -> Scenario}
    runs_of(weights, labels, seeds) -> [Run]    one setting's runs, scenario by scenario
    Runner(config, sources, batch, say).run(runs, on_batch=None) -> [row]
    trial_stats(rows, tune, duration_s) -> dict the statistics and the objective
    runs_per_batch(batch_size) -> int           runs per batch

Every run goes through :class:`jaxplan.sweep.batch.BatchRunner` with its own weights (its
per-run ``weights``), where every weight is a traced input: one compilation per shape
group for the whole study.  The runs are grouped by shape (dimensions, waypoints and
robot count: a fleet is not padded to a larger one's size, which is many times slower,
docs/TUNING.md; the worlds' static rows are padded to the group's largest) and run
``batch`` at a time (:meth:`jaxplan.sweep.batch.BatchRunner.run`: on a CPU each run its
own one-run program, so a run's row does not depend on the batch size or on the other
runs; on an accelerator vmapped batches of ``batch``).

The objective (minimized) of a trial, over its training runs: ``objective`` (the median,
mean or max) of the runs' makespans, a run that did not succeed counting as
``sim.duration_s``; plus, when a constraint fails (success rate below
``min_success_rate``, or the worst run's minimum separation ratio below
``min_separation_ratio``), the penalty ``D (1 + shortfall in success rate + relative
shortfall in separation ratio)`` with D = sim.duration_s.  So every feasible trial
ranks above every infeasible one, and infeasible ones are ranked by how far they miss
(constraints as a penalty: the same objective for both samplers).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from jaxplan import env_positive_int, scenarios
from jaxplan.config import Config, TuneConfig, build_scenario, load_config, tune_scenario_path
from jaxplan.run_setup import planner_rows
from jaxplan.scenarios import Scenario
from jaxplan.sweep import BATCH_ENV, DEFAULT_BATCH, BatchRunner, SweepError, SweepPoint

__all__ = ["STAT_COLUMNS", "Run", "Runner", "TuneError", "runs_of", "runs_per_batch",
           "scenario_sources", "trial_stats"]

STAT_COLUMNS = ("value", "feasible", "success_rate", "collisions", "min_separation_ratio",
                "median_makespan_s", "mean_makespan_s", "max_makespan_s", "runs")


class TuneError(ValueError):
    """A tune that cannot start: one line naming the problem."""


# ------------------------------------------------------------------------ scenarios


def scenario_sources(config: Config) -> dict[str, Callable[[int], Scenario]]:
    """{label: seed -> Scenario} of [tune] scenarios: a registry name (built with its
    defaults and the config's [limits]), a TOML config's fleet (its own [limits]; label:
    the file's stem), or, with none given, the config's own fleet."""
    tc = config.tune
    if not tc.scenarios:
        label = (config.scenario.kind if config.scenario is not None and not config.robots
                 else config.name)
        return {label: lambda s: build_scenario(dataclasses.replace(config, seed=int(s)))}
    lim = config.limits

    def from_file(sub: Config):
        return lambda s: build_scenario(dataclasses.replace(sub, seed=int(s)))

    def from_registry(name: str):
        return lambda s: scenarios.build(name, seed=int(s)).with_limits(
            lim.v_max, lim.a_max, lim.j_max)

    out: dict = {}
    for name in tc.scenarios:
        if name.endswith(".toml"):
            label = Path(name).stem if Path(name).stem not in out else name
            out[label] = from_file(load_config(tune_scenario_path(name, config.source)))
        else:
            out[name] = from_registry(name)
    return out


# ------------------------------------------------------------------------ statistics


def _float(cell: str) -> float:
    return float(cell) if cell not in ("", None) else math.nan


def trial_stats(rows: list[dict], tune: TuneConfig, duration_s: float) -> dict:
    """A trial's training statistics and objective from its runs' sweep.csv rows.

    success_rate; collisions (sum); min_separation_ratio (worst run); median, mean and
    max makespan_s, a run that did not succeed counting as ``duration_s``; runs; value
    (the objective plus the penalty, module doc); feasible.
    """
    ok = np.array([r.get("success") == "1" for r in rows], bool)
    span = np.array([_float(r.get("makespan_s", "")) for r in rows])
    span = np.where(ok & np.isfinite(span), span, duration_s)
    msr = np.array([_float(r.get("min_separation_ratio", "")) for r in rows])
    worst = float(np.min(msr)) if np.all(np.isfinite(msr)) and msr.size else 0.0
    stats = {
        "success_rate": float(np.mean(ok)) if ok.size else 0.0,
        "collisions": int(sum(int(_float(r.get("collisions", "")) or 0)
                              for r in rows if r.get("collisions", "") != "")),
        "min_separation_ratio": worst,
        "median_makespan_s": float(np.median(span)),
        "mean_makespan_s": float(np.mean(span)),
        "max_makespan_s": float(np.max(span)),
        "runs": len(rows),
    }
    short_s = max(0.0, tune.min_success_rate - stats["success_rate"])
    short_r = (max(0.0, tune.min_separation_ratio - worst) / tune.min_separation_ratio
               if tune.min_separation_ratio > 0 else 0.0)
    feasible = short_s == 0.0 and short_r == 0.0
    penalty = 0.0 if feasible else duration_s * (1.0 + short_s + short_r)
    stats["value"] = stats[tune.objective] + penalty
    stats["feasible"] = feasible
    return stats


# ------------------------------------------------------------------------ runs


@dataclass(frozen=True)
class Run:
    """One run: its weights (overrides of [planner], any of TUNABLE_WEIGHTS), a scenario
    label (a key of the sources) and a seed."""

    weights: tuple[tuple[str, float], ...]
    scenario: str
    seed: int


def runs_of(weights: dict[str, float], labels, seeds) -> list[Run]:
    """One weight setting's runs: every label, every seed."""
    w = tuple((k, float(v)) for k, v in weights.items())
    return [Run(w, label, int(s)) for label in labels for s in seeds]


class Runner:
    """Lists of runs, each with its own weights, through the sweep's batch program
    (:class:`jaxplan.sweep.batch.BatchRunner`): grouped by shape (dimensions, waypoints,
    robot count; static rows padded to the group's largest) and cut into batches of
    ``batch`` runs; scenarios built once."""

    def __init__(self, config: Config, sources: dict[str, Callable[[int], Scenario]],
                 batch: int, say: Callable[[str], None]):
        self.config = config
        self.sources = dict(sources)
        self.batch = batch
        self.runner = BatchRunner(config, say)
        self.built: dict[tuple[str, int], Scenario] = {}

    @property
    def tally(self):
        return self.runner.tally

    def scenario(self, label: str, seed: int) -> Scenario:
        key = (label, int(seed))
        if key not in self.built:
            try:
                self.built[key] = self.sources[label](int(seed))
            except (scenarios.ScenarioError, ValueError) as e:
                raise SweepError(f"scenario {label!r}, seed {seed}: {e}") from None
        return self.built[key]

    def run(self, runs: list[Run], on_batch: Callable[[int], None] | None = None
            ) -> list[dict]:
        """The sweep.csv row of every run (its q_obs and q_lim in the key columns), in
        the order given.  ``on_batch(n)`` after each batch of n runs."""
        pc = self.config.planner
        rows: list[dict | None] = [None] * len(runs)
        groups: dict[tuple[int, int, int], list[int]] = {}
        for i, r in enumerate(runs):
            sc = self.scenario(r.scenario, r.seed)
            groups.setdefault((sc.dim, sc.num_waypoints, sc.num_robots), []).append(i)
        for (_, _, m), idx in groups.items():
            r_pad = max(planner_rows(self.config, self.scenario(runs[i].scenario, runs[i].seed))
                        for i in idx)
            points, weights = [], []
            for i in idx:
                w = dict(runs[i].weights)
                points.append(SweepPoint(w.pop("q_obs", pc.q_obs), w.pop("q_lim", pc.q_lim),
                                         runs[i].scenario, runs[i].seed))
                weights.append(w)
            out = self.runner.run(points, self.built, m, self.batch, weights=weights,
                                  r_pad=r_pad, on_rows=None if on_batch is None else
                                  (lambda done: on_batch(len(done))))
            for i, row in zip(idx, out, strict=True):
                rows[i] = row
        return rows


def runs_per_batch(batch_size: int | None) -> int:
    """Runs per batch: ``batch_size``, else $JAXPLAN_SWEEP_BATCH, else one per CPU device
    (core) on a CPU (runs in flight, each its own one-run program: no batch meets at a
    collective) and :data:`jaxplan.sweep.DEFAULT_BATCH` on an accelerator."""
    if batch_size is None:
        batch_size = env_positive_int(BATCH_ENV, TuneError)
    if batch_size is None:
        import jax

        batch_size = (len(jax.devices("cpu")) if jax.default_backend() == "cpu"
                      else DEFAULT_BATCH)
    if int(batch_size) < 1:
        raise TuneError(f"batch size must be >= 1, got {batch_size}")
    return int(batch_size)
