"""Weights that tune themselves: `jaxplan tune` (docs/DESIGN.md "A tune directory";
how and why: docs/TUNING.md).

    run_tune(config, out_dir, *, trials=None, progress=True, batch_size=None,
             figures=True, echo=print) -> TuneResult

The config's ``[tune]`` names the weights to tune (any of q_dynm, q_obs, q_lim, k_t,
k_p, safety_margin_m) with their ranges (log or linear), the scenarios with their
training and held-out seeds, and the objective.  Optuna (ask/tell) proposes the weights,
``batch`` trials at a time; every run of a batch of trials (trials x scenarios x
training seeds) goes through the sweep's batch program
(:class:`jaxplan.sweep_batch.BatchRunner`, its per-run ``weights``), where every weight
is a traced input: one compilation per shape group for the whole study.  The runs are
grouped by shape (dimensions, waypoints and robot count: a fleet is not padded to a
larger one's size, which measured ~60x slower: antipodal_10 padded to 20 robots took
93 s of CPU for 2 runs of 40 replans, random_box_20 unpadded 1.5 s; the worlds' static
rows are padded to the group's largest) and cut into batches of ``batch_size`` runs
(:func:`_batch_size`: one run per batch on a CPU).

The objective (minimized) of a trial, over its training runs: ``objective`` (the median,
mean or max) of the runs' makespans, a run that did not succeed counting as
``sim.duration_s``; plus, when a constraint fails (success rate below
``min_success_rate``, or the worst run's minimum separation ratio below
``min_separation_ratio``), the penalty ``D (1 + shortfall in success rate + relative
shortfall in separation ratio)`` with D = sim.duration_s.  So every feasible trial
ranks above every infeasible one, and infeasible ones are ranked by how far they miss
(constraints as a penalty: the same objective for both samplers).

Resuming.  The study lives in ``study.db`` (Optuna's SQLite storage), which records
every trial when it is asked and when it is told.  A trial asked but never told (a
kill) is marked failed on the next start and its weights are queued again, so a kill
loses at most the trials in flight.  A tune directory made with a different config
(anything but [sweep], name, description and [tune]'s trials, batch and holdout_seeds)
is refused.

Outputs (``out_dir``): study.db, config.toml, trials.csv (every trial: its weights,
objective and training statistics), best.toml (the best weights as a [planner]
snippet), holdout.csv and summary.json (the best setting and the defaults re-run on
the held-out seeds), figures/ (objective.png, importance.png, pareto.png).
"""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import math
import time
import tomllib
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from jaxplan import env_positive_int, scenarios
from jaxplan.config import (
    Config,
    ConfigError,
    TuneConfig,
    build_scenario,
    config_to_toml,
    load_config,
    parse_config,
    tune_scenario_path,
)
from jaxplan.fileio import atomic_write_text
from jaxplan.scenarios import Scenario
from jaxplan.sweep import BATCH_ENV, DEFAULT_BATCH, check_revision, stamped
from jaxplan.sweep_batch import BatchRunner, SweepPoint
from jaxplan.sweep_csv import SweepError
from jaxplan.world import static_rows

__all__ = ["STUDY_NAME", "TuneError", "TuneResult", "evaluate", "run_tune", "trial_stats"]

STUDY_NAME = "jaxplan_tune"
_FREE_TABLES = ("sweep", "name", "description")
_FREE_TUNE_KEYS = ("trials", "batch", "holdout_seeds")
STAT_COLUMNS = ("value", "feasible", "success_rate", "collisions", "min_separation_ratio",
                "median_makespan_s", "mean_makespan_s", "max_makespan_s", "runs")


class TuneError(ValueError):
    """A tune that cannot start: one line naming the problem."""


@dataclass
class TuneResult:
    """What :func:`run_tune` did.

    out: the tune directory.  trials: complete trials in the study; ran: trials run now;
    requeued: trials in flight at a kill, queued again.  best: {number, weights, value,
    feasible, stats}.  holdout: {"best": stats, "defaults": stats} on the held-out
    seeds (None without held-out seeds).  compilations: of the batch program, now.
    compile_s, run_s, wall_s: seconds.  figures: their paths.
    """

    out: Path
    trials: int
    ran: int
    requeued: int
    best: dict
    holdout: dict | None
    compilations: int
    compile_s: float
    run_s: float
    wall_s: float
    figures: list


# ------------------------------------------------------------------------ scenarios


def _sources(config: Config) -> dict[str, Callable[[int], Scenario]]:
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


# ------------------------------------------------------------------------ the study


def _guard_config(out: Path, config: Config) -> None:
    """Keep config.toml; refuse a directory made with a different config."""
    path = out / "config.toml"
    text = config_to_toml(config)
    if path.exists():
        try:
            raw = path.read_text("utf-8")
            old = tomllib.loads(config_to_toml(parse_config(
                tomllib.loads(raw), source=str(config.source))))
        except (tomllib.TOMLDecodeError, UnicodeDecodeError, ConfigError) as e:
            raise TuneError(f"{path}: not a config this version reads ({e}); use another "
                            "--out") from None
        try:
            check_revision(path, raw, "tune")
        except SweepError as e:
            raise TuneError(str(e)) from None

        def strip(d):
            d = {k: v for k, v in d.items() if k not in _FREE_TABLES}
            d["tune"] = {k: v for k, v in d.get("tune", {}).items()
                         if k not in _FREE_TUNE_KEYS}
            return d

        new = tomllib.loads(text)
        if strip(old) != strip(new):
            diff = sorted(k for k in set(strip(old)) | set(strip(new))
                          if strip(old).get(k) != strip(new).get(k))
            raise TuneError(f"{path}: this tune directory was made with a different config "
                            f"(differs in: {', '.join(diff)}); use another --out")
    atomic_write_text(path, stamped(text))


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


def _defaults(config: Config) -> dict[str, float]:
    """The config's [planner] values of the tuned weights."""
    return {k: float(getattr(config.planner, k)) for k in config.tune.weights}


def _in_range(tune: TuneConfig, weights: dict[str, float]) -> bool:
    return all(r.low <= weights[k] <= r.high for k, r in tune.weights.items())


def _open_study(config: Config, out: Path, say):
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
        d = _defaults(config)
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


def _complete(study) -> list:
    optuna = _optuna()
    return study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.COMPLETE,))


def _trials_csv(study, tune: TuneConfig) -> str:
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


@dataclass(frozen=True)
class _Run:
    """One run: its weights (overrides of [planner], any of TUNABLE_WEIGHTS), a scenario
    label (a key of the sources) and a seed."""

    weights: tuple[tuple[str, float], ...]
    scenario: str
    seed: int


def _runs(weights: dict[str, float], labels, seeds) -> list[_Run]:
    w = tuple((k, float(v)) for k, v in weights.items())
    return [_Run(w, label, int(s)) for label in labels for s in seeds]


class _Runner:
    """Lists of runs, each with its own weights, through the sweep's batch program
    (:class:`jaxplan.sweep_batch.BatchRunner`): grouped by shape (dimensions, waypoints,
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

    def run(self, runs: list[_Run], on_batch: Callable[[int], None] | None = None
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
            r_pad = max(static_rows(self.scenario(runs[i].scenario, runs[i].seed).world)
                        .mask.shape[0] for i in idx)
            for k in range(0, len(idx), self.batch):
                chunk = idx[k:k + self.batch]
                points, weights = [], []
                for i in chunk:
                    w = dict(runs[i].weights)
                    points.append(SweepPoint(w.pop("q_obs", pc.q_obs), w.pop("q_lim", pc.q_lim),
                                             runs[i].scenario, runs[i].seed))
                    weights.append(w)
                out = self.runner.rows(points, self.built, m, self.batch, weights=weights,
                                       r_pad=r_pad)
                for i, row in zip(chunk, out, strict=True):
                    rows[i] = row
                if on_batch is not None:
                    on_batch(len(chunk))
        return rows


def _run_batches(config: Config, study, runner: _Runner, labels, target: int,
                 out: Path, bar, say) -> int:
    """Ask, run and tell batches of trials until ``target`` trials are complete;
    trials.csv rewritten after each batch.  Returns the trials run."""
    tune = config.tune
    dists = _distributions(tune)
    ran = 0
    while (done := len(_complete(study))) < target:
        k = min(tune.batch, target - done)
        asked = [study.ask(dists) for _ in range(k)]
        runs = [r for t in asked for r in _runs(t.params, labels, tune.seeds)]
        rows = runner.run(runs, on_batch=bar.update)
        per = len(labels) * len(tune.seeds)
        for i, t in enumerate(asked):
            stats = trial_stats(rows[i * per:(i + 1) * per], tune, config.sim.duration_s)
            t.set_user_attr("stats", stats)
            study.tell(t, stats["value"])
        ran += k
        atomic_write_text(out / "trials.csv", _trials_csv(study, tune))
    return ran


def _best(study) -> dict:
    """The best complete trial (lowest value; feasible ones first by construction)."""
    t = min(_complete(study), key=lambda t: (t.value, t.number))
    return {"number": t.number, "weights": dict(t.params), "value": t.value,
            "feasible": bool(t.user_attrs["stats"]["feasible"]),
            "stats": t.user_attrs["stats"], "defaults": bool(t.user_attrs.get("defaults"))}


def _best_toml(config: Config, best: dict, n_trials: int) -> str:
    s = best["stats"]
    lines = [f"# jaxplan tune {config.name}: the best of {n_trials} trials (trial "
             f"{best['number']}); on the training runs: {config.tune.objective} = "
             f"{s[config.tune.objective]:.3f} s, success {100 * s['success_rate']:.0f}%, "
             f"min separation ratio {s['min_separation_ratio']:.3f}"
             + ("" if best["feasible"] else " (INFEASIBLE: no trial met the constraints)"),
             "[planner]"]
    lines += [f"{k} = {float(v)!r}" for k, v in best["weights"].items()]
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------ held out

HOLDOUT_COLUMNS = ("setting", "scenario", "seed", "success", "collisions",
                   "obstacle_collisions", "workspace_violations", "min_separation_ratio",
                   "min_obstacle_clearance_m", "min_workspace_clearance_m", "makespan_s",
                   "makespan_over_bound", "mean_time_to_goal_s", "reached_frac",
                   "peak_speed_ratio", "stalls", "converged_frac", "error")


def _holdout(config: Config, runner: _Runner, labels, best: dict, out: Path,
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
    settings = {"best": best["weights"], "defaults": _defaults(config)}
    say(f"held-out re-evaluation: best and defaults x {len(labels)} scenario(s) x "
        f"{len(tune.holdout_seeds)} seeds")
    runs = [r for w in settings.values() for r in _runs(w, labels, tune.holdout_seeds)]
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
    TUNABLE_WEIGHTS; the others from [planner]).  Summarize with :func:`trial_stats`."""
    if config.tune is None:
        raise TuneError(f"{config.source or config.name}: no [tune] table")
    sources = _sources(config)
    runner = _Runner(config, sources, _batch_size(batch_size), echo or (lambda s: None))
    labels = list(sources)
    runs = [r for w in settings.values() for r in _runs(w, labels, seeds)]
    rows = runner.run(runs)
    per = len(labels) * len(tuple(seeds))
    return {name: rows[i * per:(i + 1) * per] for i, name in enumerate(settings)}


def _read_json(path: Path) -> dict | None:
    try:
        return json.loads(path.read_text("utf-8"))
    except (OSError, ValueError):
        return None


# ------------------------------------------------------------------------ figures


def _importance(study) -> dict[str, float] | None:
    """PED-ANOVA importances of the weights (Optuna), or None with too few trials."""
    optuna = _optuna()
    if len(_complete(study)) < 4 or len(study.get_trials(deepcopy=False)[0].params) < 1:
        return None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            ev = optuna.importance.PedAnovaImportanceEvaluator()
            return {k: float(v) for k, v in
                    optuna.importance.get_param_importances(study, evaluator=ev).items()}
    except (ValueError, RuntimeError, ZeroDivisionError):
        return None


def _figures(study, config: Config, out: Path) -> list[Path]:
    from jaxplan.plots import plot_tune

    trials = [{"number": t.number, "params": dict(t.params), **t.user_attrs["stats"]}
              for t in _complete(study)]
    return plot_tune(out / "figures", trials, _importance(study),
                     objective=config.tune.objective)


# ------------------------------------------------------------------------ the command


def _summary_lines(res: TuneResult, tune: TuneConfig) -> list[str]:
    b = res.best
    s = b["stats"]
    w = ", ".join(f"{k} = {v:.6g}" for k, v in b["weights"].items())
    lines = [
        f"compilations: {res.compilations}",
        f"trials: {res.trials} complete, {res.ran} run now"
        + (f", {res.requeued} requeued after a kill" if res.requeued else ""),
        f"time: {res.wall_s:.1f} s wall ({res.compile_s:.1f} s compiling, {res.run_s:.1f} s "
        "running)",
        f"best: trial {b['number']}{' (the defaults)' if b['defaults'] else ''}: {w}",
        f"  training: {tune.objective} {s[tune.objective]:.3f} s, success "
        f"{100 * s['success_rate']:.0f}%, min separation ratio "
        f"{s['min_separation_ratio']:.3f}{'' if b['feasible'] else '  INFEASIBLE'}",
    ]
    if res.holdout:
        for name in ("best", "defaults"):
            h = res.holdout[name]
            lines.append(f"  held out, {name:8s}: {tune.objective} {h[tune.objective]:.3f} s, "
                         f"success {100 * h['success_rate']:.0f}%, collisions "
                         f"{h['collisions']}, min separation ratio "
                         f"{h['min_separation_ratio']:.3f}")
    return lines + [f"figure: {f}" for f in res.figures]


def run_tune(config: Config, out_dir, *, trials: int | None = None, progress: bool = True,
             batch_size: int | None = None, figures: bool = True,
             echo: Callable[[str], None] | None = print) -> TuneResult:
    """Run (or resume) the config's [tune] study into ``out_dir`` (see the module doc).

    Args:
        config: a validated Config with a [tune] table (backend "ideal").
        out_dir: the tune directory (created).
        trials: complete trials wanted in all (default: [tune] trials).
        progress: a progress bar over runs.
        batch_size: runs per compiled batch (default $JAXPLAN_SWEEP_BATCH, else 1 on a
            CPU (:func:`_batch_size`), the sweep's 27 on an accelerator).
        figures: draw the figures at the end.
        echo: where the progress lines and the summary go (None: nowhere).
    Returns: a :class:`TuneResult`.  Raises: TuneError.
    """
    t_wall = time.perf_counter()
    say = echo or (lambda s: None)
    if config.tune is None:
        raise TuneError(f"{config.source or config.name}: no [tune] table; `jaxplan tune` "
                        "needs one (docs/DESIGN.md, [tune])")
    if config.sim.backend != "ideal":
        raise TuneError(f"{config.source or config.name}: sim.backend = "
                        f"{config.sim.backend!r}: tuning runs the ideal backend only")
    tune = config.tune
    target = tune.trials if trials is None else int(trials)
    if target < 1:
        raise TuneError(f"trials must be >= 1, got {target}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    _guard_config(out, config)
    try:
        sources = _sources(config)
        runner = _Runner(config, sources, _batch_size(batch_size), say)
    except (SweepError, ConfigError) as e:
        raise TuneError(str(e)) from None
    labels = list(sources)
    study, requeued = _open_study(config, out, say)
    done = len(_complete(study))
    per_trial = len(labels) * len(tune.seeds)
    todo = max(0, target - done)
    say(f"tune {config.name}: {len(tune.weights)} weights ({', '.join(tune.weights)}), "
        f"{target} trials ({done} done) in batches of {tune.batch}, {per_trial} runs each "
        f"({len(labels)} scenario(s) x {len(tune.seeds)} seeds), sampler {tune.sampler}")
    from jaxplan.progress import AfterFirstUpdate, NoProgress

    total = todo * per_trial + 2 * len(labels) * len(tune.holdout_seeds)
    # opened when the first batch is done, after the compile (its ETA counts runs only)
    bar = (AfterFirstUpdate(total, config.name, "run") if progress and total
           else NoProgress())
    try:
        ran = _run_batches(config, study, runner, labels, target, out, bar, say) \
            if todo else 0
        atomic_write_text(out / "trials.csv", _trials_csv(study, tune))
        best = _best(study)
        atomic_write_text(out / "best.toml", _best_toml(config, best, len(_complete(study))))
        holdout = _holdout(config, runner, labels, best, out, bar, say)
    except SweepError as e:
        raise TuneError(str(e)) from None
    finally:
        bar.close()
    figs = _figures(study, config, out) if figures else []
    res = TuneResult(out, len(_complete(study)), ran, requeued, best,
                     holdout and {k: v for k, v in holdout.items() if k != "key"},
                     runner.tally.compilations, runner.tally.compile_s, runner.tally.run_s,
                     time.perf_counter() - t_wall, figs)
    summary = {"name": config.name, "sampler": tune.sampler, "objective": tune.objective,
               "trials": res.trials, "best": best, "defaults": _defaults(config),
               "holdout": res.holdout, "holdout_key": holdout and holdout["key"],
               "compilations": res.compilations, "compile_s": res.compile_s,
               "run_s": res.run_s, "wall_s": res.wall_s}
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=2) + "\n")
    for line in _summary_lines(res, tune):
        say(line)
    return res


def _batch_size(batch_size: int | None) -> int:
    """Runs per batch: ``batch_size``, else $JAXPLAN_SWEEP_BATCH, else one on a CPU and
    :data:`jaxplan.sweep.DEFAULT_BATCH` on an accelerator.  One on a CPU, not the sweep's
    one per CPU device: a batch split over the CPU devices meets at an all-gather when
    it ends; a tune's runs differ in length (their weights differ), the device that
    finishes first waits for the other, and on a busy 2-core machine XLA aborted the
    process after 40 s of waiting (its collective timeout; docs/TUNING.md, Known
    limits)."""
    if batch_size is None:
        batch_size = env_positive_int(BATCH_ENV, TuneError)
    if batch_size is None:
        import jax

        batch_size = 1 if jax.default_backend() == "cpu" else DEFAULT_BATCH
    if int(batch_size) < 1:
        raise TuneError(f"batch size must be >= 1, got {batch_size}")
    return int(batch_size)
