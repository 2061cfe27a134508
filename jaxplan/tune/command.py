"""`jaxplan tune`: run or resume a [tune] study into a tune directory, re-run the best
on the held-out seeds, write the outputs and print the summary (docs/DESIGN.md "A tune
directory").

    run_tune(config, out_dir, *, trials=None, progress=True, batch_size=None,
             figures=True, echo=print) -> TuneResult
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from jaxplan.config import Config, ConfigError, TuneConfig
from jaxplan.files import atomic_write_text
from jaxplan.sweep import SweepError, guard_config
from jaxplan.tune import study as studies
from jaxplan.tune.holdout import holdout as run_holdout
from jaxplan.tune.trials import Runner, TuneError, runs_per_batch, scenario_sources

__all__ = ["TuneResult", "run_tune"]


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
    """Run (or resume) the config's [tune] study into ``out_dir`` (see :mod:`jaxplan.tune`).

    Args:
        config: a validated Config with a [tune] table (backend "ideal").
        out_dir: the tune directory (created).
        trials: complete trials wanted in all (default: [tune] trials).
        progress: a progress bar over runs.
        batch_size: runs per batch (default $JAXPLAN_SWEEP_BATCH, else one per CPU
            device on a CPU, runs in flight (:func:`jaxplan.tune.trials.runs_per_batch`),
            the sweep's 27 on an accelerator).
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
    if config.planner.method != "krishnan":
        raise TuneError(f"{config.source or config.name}: [planner] method = "
                        f"{config.planner.method!r}: tuning tunes the paper's planner only")
    tune = config.tune
    target = tune.trials if trials is None else int(trials)
    if target < 1:
        raise TuneError(f"trials must be >= 1, got {target}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    try:
        guard_config(out, config, "tune")
        sources = scenario_sources(config)
        runner = Runner(config, sources, runs_per_batch(batch_size), say)
    except (SweepError, ConfigError) as e:
        raise TuneError(str(e)) from None
    labels = list(sources)
    study, requeued = studies.open_study(config, out, say)
    done = len(studies.complete(study))
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
        ran = studies.run_batches(config, study, runner, labels, target, out, bar, say) \
            if todo else 0
        atomic_write_text(out / "trials.csv", studies.trials_csv(study, tune))
        best = studies.best_trial(study)
        atomic_write_text(out / "best.toml",
                          studies.best_toml(config, best, len(studies.complete(study))))
        holdout = run_holdout(config, runner, labels, best, out, bar, say)
    except SweepError as e:
        raise TuneError(str(e)) from None
    finally:
        bar.close()
    figs = studies.figures(study, config, out) if figures else []
    res = TuneResult(out, len(studies.complete(study)), ran, requeued, best,
                     holdout and {k: v for k, v in holdout.items() if k != "key"},
                     runner.tally.compilations, runner.tally.compile_s, runner.tally.run_s,
                     time.perf_counter() - t_wall, figs)
    summary = {"name": config.name, "sampler": tune.sampler, "objective": tune.objective,
               "trials": res.trials, "best": best, "defaults": studies.defaults(config),
               "holdout": res.holdout, "holdout_key": holdout and holdout["key"],
               "compilations": res.compilations, "compile_s": res.compile_s,
               "run_s": res.run_s, "wall_s": res.wall_s}
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=2) + "\n")
    for line in _summary_lines(res, tune):
        say(line)
    return res
