"""Re-evaluation of weight settings on other seeds: the held-out runs at the end of
`jaxplan tune` (holdout.csv), and :func:`evaluate` for studies of a tune's results
(experiments/tune_reeval.py).

    holdout(config, runner, labels, best, out, bar, say) -> {"best", "defaults", "key"} | None
    evaluate(config, settings, seeds, *, batch_size=None, echo=None) -> {name: rows}
    HOLDOUT_COLUMNS                             holdout.csv's columns
"""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Callable
from pathlib import Path

from jaxplan.config import Config
from jaxplan.files import atomic_write_text
from jaxplan.tune.study import defaults
from jaxplan.tune.trials import (
    Runner,
    TuneError,
    runs_of,
    runs_per_batch,
    scenario_sources,
    trial_stats,
)

__all__ = ["HOLDOUT_COLUMNS", "evaluate", "holdout"]

HOLDOUT_COLUMNS = ("setting", "scenario", "seed", "success", "collisions",
                   "obstacle_collisions", "workspace_violations", "min_separation_ratio",
                   "min_obstacle_clearance_m", "min_workspace_clearance_m", "makespan_s",
                   "makespan_over_bound", "mean_time_to_goal_s", "reached_frac",
                   "peak_speed_ratio", "stalls", "converged_frac", "error")


def holdout(config: Config, runner: Runner, labels, best: dict, out: Path,
            bar, say) -> dict | None:
    """The best weights and the defaults on the held-out seeds: holdout.csv and their
    statistics ({"best": ..., "defaults": ...}, each with its weights).  Skipped (the
    saved result returned) when summary.json already holds them for this best trial."""
    tune = config.tune
    if not tune.holdout_seeds:
        return None
    old = _read_json(out / "summary.json")
    key = {"best_trial": best["number"], "seeds": list(tune.holdout_seeds)}
    if old and old.get("holdout_key") == key and (out / "holdout.csv").exists():
        return {**old["holdout"], "key": key}
    settings = {"best": best["weights"], "defaults": defaults(config)}
    say(f"held-out re-evaluation: best and defaults x {len(labels)} scenario(s) x "
        f"{len(tune.holdout_seeds)} seeds")
    runs = [r for w in settings.values() for r in runs_of(w, labels, tune.holdout_seeds)]
    rows = runner.run(runs, on_batch=bar.update)
    per = len(labels) * len(tune.holdout_seeds)
    result, lines = {}, []
    for i, (name, w) in enumerate(settings.items()):
        mine = rows[i * per:(i + 1) * per]
        result[name] = {"weights": w, **trial_stats(mine, tune, config.sim.duration_s)}
        lines += [{"setting": name, **r} for r in mine]
    buf = io.StringIO()
    wr = csv.DictWriter(buf, HOLDOUT_COLUMNS, extrasaction="ignore", lineterminator="\n")
    wr.writeheader()
    wr.writerows(lines)
    atomic_write_text(out / "holdout.csv", buf.getvalue())
    result["key"] = key
    return result


def evaluate(config: Config, settings: dict[str, dict[str, float]], seeds, *,
             batch_size: int | None = None, echo: Callable[[str], None] | None = None
             ) -> dict[str, list[dict]]:
    """Run weight settings on the config's [tune] scenarios and the given seeds, as
    the study runs its trials: {setting name: the sweep.csv rows of its runs, scenario
    by scenario, seed by seed}.  ``settings``: {name: {weight: value}} (any of
    TUNABLE_WEIGHTS; the others from [planner]).  Summarize with
    :func:`jaxplan.tune.trials.trial_stats`."""
    if config.tune is None:
        raise TuneError(f"{config.source or config.name}: no [tune] table")
    sources = scenario_sources(config)
    runner = Runner(config, sources, runs_per_batch(batch_size), echo or (lambda s: None))
    labels = list(sources)
    runs = [r for w in settings.values() for r in runs_of(w, labels, seeds)]
    rows = runner.run(runs)
    per = len(labels) * len(tuple(seeds))
    return {name: rows[i * per:(i + 1) * per] for i, name in enumerate(settings)}


def _read_json(path: Path) -> dict | None:
    try:
        return json.loads(path.read_text("utf-8"))
    except (OSError, ValueError):
        return None
