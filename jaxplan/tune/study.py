"""The Optuna study of `jaxplan tune`: opened or resumed from study.db, batches of
trials asked, run and told, trials.csv, the best trial and its [planner] snippet, the
figures.

    open_study(config, out, say) -> (study, requeued)
    run_batches(config, study, runner, labels, target, out, bar, say) -> trials run
    complete(study), best_trial(study), best_toml(config, best, n), trials_csv(study, tune)
    defaults(config) -> {weight: value}         the [planner] values of the tuned weights
    figures(study, config, out) -> [Path]

Optuna (ask/tell) proposes the weights, ``[tune] batch`` trials at a time.  The study
lives in ``study.db`` (Optuna's SQLite storage), which records every trial when it is
asked and when it is told.  A trial asked but never told (a kill) is marked failed on
the next start and its weights are queued again, so a kill loses at most the trials in
flight.  Optuna is imported only here, when a study runs.
"""

from __future__ import annotations

import csv
import io
import math
import warnings
from pathlib import Path

from jaxplan.config import Config, TuneConfig
from jaxplan.files import atomic_write_text
from jaxplan.tune.trials import STAT_COLUMNS, Runner, runs_of, trial_stats

__all__ = ["STUDY_NAME", "best_toml", "best_trial", "complete", "defaults", "figures",
           "open_study", "run_batches", "trials_csv"]

STUDY_NAME = "jaxplan_tune"


def _optuna():
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    return optuna


def _sampler(tune: TuneConfig, seed: int):
    optuna = _optuna()
    seed = int(seed % 2**32)
    if tune.sampler == "cmaes":
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
            return optuna.samplers.CmaEsSampler(seed=seed)
    # multivariate: the weights interact (k_t / q_lim sets the cruise speed);
    # constant_liar: the trials of a batch are asked before any is told
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        return optuna.samplers.TPESampler(seed=seed, multivariate=True, constant_liar=True)


def _distributions(tune: TuneConfig) -> dict:
    optuna = _optuna()
    return {k: optuna.distributions.FloatDistribution(r.low, r.high, log=r.log)
            for k, r in tune.weights.items()}


def defaults(config: Config) -> dict[str, float]:
    """The config's [planner] values of the tuned weights."""
    return {k: float(getattr(config.planner, k)) for k in config.tune.weights}


def _in_range(tune: TuneConfig, weights: dict[str, float]) -> bool:
    return all(r.low <= weights[k] <= r.high for k, r in tune.weights.items())


def open_study(config: Config, out: Path, say):
    """The study in out/study.db (created, or loaded); a new one gets the defaults as
    its first trial; trials in flight at a kill are failed and queued again.  Returns
    (study, requeued)."""
    optuna = _optuna()
    storage = f"sqlite:///{(out / 'study.db').resolve()}"
    study = optuna.create_study(storage=storage, study_name=STUDY_NAME, direction="minimize",
                                sampler=_sampler(config.tune, config.seed),
                                load_if_exists=True)
    trials = study.get_trials(deepcopy=False)
    if not trials and config.tune.enqueue_defaults:
        d = defaults(config)
        if _in_range(config.tune, d):
            study.enqueue_trial(d, user_attrs={"defaults": True})
        else:
            say("the [planner] defaults lie outside the [tune] ranges: not a trial")
    requeued = 0
    for t in trials:
        if t.state == optuna.trial.TrialState.RUNNING:
            # a trial killed while it was asked has no complete weights: it never ran
            if set(t.params) == set(config.tune.weights):
                study.enqueue_trial(dict(t.params),
                                    user_attrs={**t.user_attrs, "requeued_from": t.number})
                requeued += 1
            study.tell(t.number, state=optuna.trial.TrialState.FAIL)
    if requeued:
        say(f"{requeued} trial(s) in flight at the last stop queued again")
    return study, requeued


def complete(study) -> list:
    """The study's complete trials."""
    optuna = _optuna()
    return study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.COMPLETE,))


def trials_csv(study, tune: TuneConfig) -> str:
    """Every trial of the study, by number: number, state, the weights, the statistics
    (empty unless complete), defaults (1: the [planner] defaults), requeued_from."""
    names = list(tune.weights)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["number", "state", *names, *STAT_COLUMNS, "defaults", "requeued_from"])
    for t in study.get_trials(deepcopy=False):
        ua = t.user_attrs
        stats = ua.get("stats", {})
        w.writerow([t.number, t.state.name, *(repr(float(t.params[k])) if k in t.params
                                              else "" for k in names),
                    *(_cell(stats.get(c)) for c in STAT_COLUMNS),
                    "1" if ua.get("defaults") else "", ua.get("requeued_from", "")])
    return buf.getvalue()


def _cell(x) -> str:
    if x is None:
        return ""
    if isinstance(x, bool):
        return "1" if x else "0"
    if isinstance(x, int):
        return str(x)
    return repr(float(x)) if math.isfinite(float(x)) else ""


def run_batches(config: Config, study, runner: Runner, labels, target: int,
                out: Path, bar, say) -> int:
    """Ask, run and tell batches of trials until ``target`` trials are complete;
    trials.csv rewritten after each batch.  Returns the trials run."""
    tune = config.tune
    dists = _distributions(tune)
    ran = 0
    while (done := len(complete(study))) < target:
        k = min(tune.batch, target - done)
        asked = [study.ask(dists) for _ in range(k)]
        runs = [r for t in asked for r in runs_of(t.params, labels, tune.seeds)]
        rows = runner.run(runs, on_batch=bar.update)
        per = len(labels) * len(tune.seeds)
        for i, t in enumerate(asked):
            stats = trial_stats(rows[i * per:(i + 1) * per], tune, config.sim.duration_s)
            t.set_user_attr("stats", stats)
            study.tell(t, stats["value"])
        ran += k
        atomic_write_text(out / "trials.csv", trials_csv(study, tune))
    return ran


def best_trial(study) -> dict:
    """The best complete trial (lowest value; feasible ones first by construction)."""
    t = min(complete(study), key=lambda t: (t.value, t.number))
    return {"number": t.number, "weights": dict(t.params), "value": t.value,
            "feasible": bool(t.user_attrs["stats"]["feasible"]),
            "stats": t.user_attrs["stats"], "defaults": bool(t.user_attrs.get("defaults"))}


def best_toml(config: Config, best: dict, n_trials: int) -> str:
    """best.toml: the best weights as a [planner] snippet, under a comment line."""
    s = best["stats"]
    lines = [f"# jaxplan tune {config.name}: the best of {n_trials} trials (trial "
             f"{best['number']}); on the training runs: {config.tune.objective} = "
             f"{s[config.tune.objective]:.3f} s, success {100 * s['success_rate']:.0f}%, "
             f"min separation ratio {s['min_separation_ratio']:.3f}"
             + ("" if best["feasible"] else " (INFEASIBLE: no trial met the constraints)"),
             "[planner]"]
    lines += [f"{k} = {float(v)!r}" for k, v in best["weights"].items()]
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------ figures


def _importance(study) -> dict[str, float] | None:
    """PED-ANOVA importances of the weights (Optuna), or None with too few trials."""
    optuna = _optuna()
    if len(complete(study)) < 4 or len(study.get_trials(deepcopy=False)[0].params) < 1:
        return None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            ev = optuna.importance.PedAnovaImportanceEvaluator()
            return {k: float(v) for k, v in
                    optuna.importance.get_param_importances(study, evaluator=ev).items()}
    except (ValueError, RuntimeError, ZeroDivisionError):
        return None


def figures(study, config: Config, out: Path) -> list[Path]:
    """The study's figures (objective, importance, Pareto front) in out/figures."""
    from jaxplan.plots import plot_tune

    trials = [{"number": t.number, "params": dict(t.params), **t.user_attrs["stats"]}
              for t in complete(study)]
    return plot_tune(out / "figures", trials, _importance(study),
                     objective=config.tune.objective)
