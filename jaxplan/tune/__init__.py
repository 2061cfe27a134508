"""Weights that tune themselves: `jaxplan tune` (docs/DESIGN.md "A tune directory";
how and why: docs/TUNING.md).

    run_tune(config, out_dir, *, trials=None, progress=True, batch_size=None,
             figures=True, echo=print) -> TuneResult
    evaluate(config, settings, seeds, *, batch_size=None, echo=None) -> {name: rows}
    trial_stats(rows, tune, duration_s) -> dict        a trial's statistics and objective

The config's ``[tune]`` names the weights to tune (any of q_dynm, q_obs, q_lim, k_t,
k_p, safety_margin_m) with their ranges (log or linear), the scenarios with their
training and held-out seeds, and the objective.  Optuna (ask/tell) proposes the weights,
``batch`` trials at a time; every run of a batch of trials (trials x scenarios x
training seeds) goes through the sweep's batch program
(:class:`jaxplan.sweep.batch.BatchRunner`, its per-run ``weights``), where every weight
is a traced input: one compilation per shape group for the whole study.  The runs are
grouped by shape (dimensions, waypoints and robot count; fleets are not padded to one
size) and cut into batches of ``batch_size`` runs (one run per batch on a CPU).

The objective (minimized) of a trial, over its training runs, is ``objective`` of the
runs' makespans plus a penalty when a constraint fails
(:func:`jaxplan.tune.trials.trial_stats`).

Resuming.  The study lives in ``study.db`` (Optuna's SQLite storage); a kill loses at
most the trials in flight, which are queued again on the next start
(:func:`jaxplan.tune.study.open_study`).  A tune directory made with a different config
(anything but [sweep], name, description and [tune]'s trials, batch and holdout_seeds)
is refused (:func:`jaxplan.sweep.guard.guard_config`).

Outputs (``out_dir``): study.db, config.toml, trials.csv (every trial: its weights,
objective and training statistics), best.toml (the best weights as a [planner]
snippet), holdout.csv and summary.json (the best setting and the defaults re-run on
the held-out seeds), figures/ (objective.png, importance.png, pareto.png).

Modules: command.py (run_tune: the command, its outputs and summary), study.py (the
Optuna study: open and resume, ask / run / tell, trials.csv, the best, the figures),
trials.py (the [tune] scenarios, runs of weight settings through the sweep's batch
program, a trial's statistics and objective), holdout.py (held-out re-evaluation,
:func:`evaluate`).
"""

from __future__ import annotations

from jaxplan.tune.command import TuneResult, run_tune
from jaxplan.tune.holdout import HOLDOUT_COLUMNS, evaluate
from jaxplan.tune.study import STUDY_NAME
from jaxplan.tune.trials import STAT_COLUMNS, TuneError, trial_stats

__all__ = ["HOLDOUT_COLUMNS", "STAT_COLUMNS", "STUDY_NAME", "TuneError", "TuneResult",
           "evaluate", "run_tune", "trial_stats"]
