"""jaxplan.tune: [tune] config errors, the trial objective, and a tiny tune end to end
(2 weights, 6 trials in batches of 3, the tiny scenario) stopped in its second batch and
resumed from its SQLite storage: at most the trials in flight are lost, the weights of
those are run again, and the defaults' trial matches the tiny scenario's own `jaxplan
run`.  The same with a real SIGKILL of a `jaxplan tune` child: behind the slow marker."""

from __future__ import annotations

import json
import math
import signal
import sqlite3
import tomllib
from pathlib import Path

import pytest

from jaxplan.config import ConfigError, parse_config
from tests._proc import child_env, jaxplan_cmd, kill_when
from tests.conftest import TINY_TOML

TUNE_TABLE = """
[tune]
trials = 6
batch = 3
seeds = [0]
holdout_seeds = [1]
[tune.weights]
q_obs = {low = 1.0, high = 100.0, log = true}
k_t = {low = 3.0, high = 9.0}
"""


def _parse(tune_text: str):
    return parse_config(tomllib.loads(TINY_TOML + tune_text), source="tune.toml")


# ----------------------------------------------------------------------------- config


@pytest.mark.parametrize("weights, key, problem", [
    ("q_obs = {low = 10.0, high = 1.0}", "tune.weights.q_obs.high", "must be > low = 10"),
    ("q_obs = {low = 5.0, high = 5.0}", "tune.weights.q_obs.high", "must be > low = 5"),
    ("q_lim = {low = 0.0, high = 1.0, log = true}", "tune.weights.q_lim.low",
     "a log range needs low > 0"),
    ("k_p = {low = 0.0, high = 9.0}", "tune.weights.k_p.low", "must be >= 0.001"),
    ("q_dynm = {low = 0.0, high = 2.0}", "tune.weights.q_dynm.low", "must be >= 1e-06"),
    ("q_obs = {low = 1.0, high = 1e7}", "tune.weights.q_obs.high", "must be <= 1e+06"),
    ("q_obs = {low = -1.0, high = 1.0}", "tune.weights.q_obs.low", "must be >= 0"),
    ("safety_margin_m = {low = 0.0, high = 11.0}", "tune.weights.safety_margin_m.high",
     "must be <= 10"),
    ("q_obs = {low = 1.0}", "tune.weights.q_obs.high", "missing"),
    ('q_obs = {low = 1.0, high = "big"}', "tune.weights.q_obs.high", "expected a number"),
    ("q_obs = {low = 1.0, high = 2.0, lg = true}", "tune.weights.q_obs.lg",
     "did you mean 'log'"),
    ("q_ob = {low = 1.0, high = 2.0}", "tune.weights.q_ob", "did you mean 'q_obs'"),
    ("q_obs = 3.0", "tune.weights.q_obs", "expected a table"),
])
def test_bad_ranges_fail_naming_the_key(weights, key, problem):
    with pytest.raises(ConfigError) as e:
        _parse(f"[tune]\n[tune.weights]\n{weights}\n")
    msg = str(e.value)
    assert msg.startswith(f"tune.toml: {key}: ") and problem in msg, msg


@pytest.mark.parametrize("line, key, problem", [
    ("seeds = [0, 1]\nholdout_seeds = [1, 2]", "tune.holdout_seeds", "also a training seed"),
    ('scenarios = ["no_such"]', "tune.scenarios[0]", "unknown scenario"),
    ('scenarios = ["missing.toml"]', "tune.scenarios[0]", "cannot read the file"),
    ('sampler = "grid"', "tune.sampler", "choose one of 'tpe', 'cmaes'"),
    ("min_success_rate = 1.5", "tune.min_success_rate", "must be <= 1"),
    ("trials = 0", "tune.trials", "must be >= 1"),
])
def test_bad_tune_options_fail_naming_the_key(line, key, problem):
    with pytest.raises(ConfigError) as e:
        _parse(f"[tune]\n{line}\n[tune.weights]\nq_obs = {{low = 1.0, high = 2.0}}\n")
    msg = str(e.value)
    assert msg.startswith(f"tune.toml: {key}: ") and problem in msg, msg


def test_no_weights_is_an_error_and_a_config_round_trips():
    from jaxplan.config import config_to_toml

    with pytest.raises(ConfigError, match="tune.weights: name at least one weight"):
        _parse("[tune]\ntrials = 3\n")
    cfg = _parse(TUNE_TABLE)
    assert list(cfg.tune.weights) == ["q_obs", "k_t"]
    assert cfg.tune.weights["q_obs"].log and not cfg.tune.weights["k_t"].log
    again = parse_config(tomllib.loads(config_to_toml(cfg)), source="again.toml")
    assert again == cfg and hash(again) == hash(cfg)


def test_cli_refuses_a_config_without_tune(tmp_path, capsys):
    from jaxplan.cli import main

    cfg = tmp_path / "tiny.toml"
    cfg.write_text(TINY_TOML)
    assert main(["tune", str(cfg), "--out", str(tmp_path / "o")]) == 2
    assert "tune: missing" in capsys.readouterr().err


# ----------------------------------------------------------------------------- objective


def _row(success, makespan, msr, collisions=0):
    return {"success": "1" if success else "0", "makespan_s": "" if makespan is None
            else repr(makespan), "min_separation_ratio": repr(msr),
            "collisions": str(collisions)}


def test_objective_counts_failures_as_the_duration_and_penalizes_constraints():
    from jaxplan.tune import trial_stats

    tune = _parse(TUNE_TABLE).tune  # min success 100%, min d/rho 1.1, median makespan
    good = trial_stats([_row(1, 4.0, 1.5), _row(1, 6.0, 1.3), _row(1, 5.0, 1.2)], tune, 12.0)
    assert good["feasible"] and good["value"] == 5.0 and good["max_makespan_s"] == 6.0
    assert good["min_separation_ratio"] == 1.2 and good["success_rate"] == 1.0
    # one run failed (reached, collided): its makespan counts as the duration, 12 s;
    # median of (4, 12, 5) = 5; penalty 12 * (1 + 1/3)
    bad = trial_stats([_row(1, 4.0, 1.5), _row(0, 6.0, 0.9, 1), _row(1, 5.0, 1.2)], tune, 12.0)
    shortfall_ratio = (1.1 - 0.9) / 1.1
    assert not bad["feasible"] and bad["collisions"] == 1
    assert bad["value"] == pytest.approx(5.0 + 12.0 * (1 + 1 / 3 + shortfall_ratio))
    # a slow feasible setting still ranks before any infeasible one
    slow = trial_stats([_row(1, 11.9, 1.2)] * 3, tune, 12.0)
    assert slow["feasible"] and slow["value"] < bad["value"]
    close = trial_stats([_row(1, 4.0, 1.09)] * 3, tune, 12.0)  # only the ratio is short
    assert not close["feasible"] and slow["value"] < close["value"] < bad["value"]


# ----------------------------------------------------------------------------- end to end


def _states(db: Path) -> dict[str, int]:
    """Trials by state in Optuna's SQLite storage, and "params": weights stored."""
    try:
        with sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=0.1) as c:
            n = dict(c.execute("SELECT state, COUNT(*) FROM trials GROUP BY state"))
            n["params"] = c.execute("SELECT COUNT(*) FROM trial_params").fetchone()[0]
            return n
    except sqlite3.Error:  # not made yet, or locked for a write
        return {}


class _Stop(BaseException):
    """The process stopping while a batch of trials is in flight."""


@pytest.fixture(scope="module")
def interrupted_and_resumed(tmp_path_factory):
    """A tiny tune (6 trials in batches of 3) stopped in this process once its second
    batch of trials was asked (stored as RUNNING) and before any of it was told (as a
    kill would), then resumed; the resumed run reuses the compiled program."""
    from jaxplan import tune
    from jaxplan.tune.trials import Runner

    out = tmp_path_factory.mktemp("tune") / "out"
    cfg = _parse(TUNE_TABLE)
    real_run = Runner.run
    calls = []

    def run_then_stop(self, runs, on_batch=None):
        calls.append(len(runs))
        if len(calls) == 2:
            raise _Stop
        return real_run(self, runs, on_batch)

    first = []
    Runner.run = run_then_stop
    try:
        with pytest.raises(_Stop):
            tune.run_tune(cfg, out, progress=False, echo=first.append)
    finally:
        Runner.run = real_run
    at_stop = _states(out / "study.db")
    lines = []
    res = tune.run_tune(cfg, out, progress=False, echo=lines.append)
    return out, at_stop, res, first + lines


def test_an_interrupted_study_loses_only_the_trials_in_flight(interrupted_and_resumed):
    import optuna

    out, at_stop, res, lines = interrupted_and_resumed
    assert at_stop == {"COMPLETE": 3, "RUNNING": 3, "params": 12}  # 2 weights x 6 trials
    assert res.requeued == 3 and res.ran == 3 and res.trials == 6
    # weights are traced: the resumed study reuses the program compiled before the stop
    assert res.compilations == 0, lines
    # one program for both runs (and for test_sweep's end to end, where it ran before
    # in this process: then the first run finds it compiled already too)
    assert sum("compiling the planner" in x for x in lines) <= 1, lines
    assert sum("compiling the planner" in x or "compiled already (in this process)" in x
               for x in lines) == 2, lines
    study = optuna.load_study(study_name="jaxplan_tune", storage=f"sqlite:///{out}/study.db")
    trials = study.get_trials()
    done = [t for t in trials if t.state.name == "COMPLETE"]
    failed = [t for t in trials if t.state.name == "FAIL"]
    assert len(done) == 6 and len(failed) == 3 and len(trials) == 9
    # the first batch is kept as it was told; the stopped trials' weights ran again
    assert [t.number for t in done[:3]] == [0, 1, 2]
    again = {t.user_attrs["requeued_from"]: t.params for t in done[3:]}
    assert again == {t.number: t.params for t in failed}
    rows = (out / "trials.csv").read_text().splitlines()
    assert len(rows) == 1 + 9 and sum(",COMPLETE," in r for r in rows) == 6
    # the weights reach the runs: trials of different weights ran differently
    spans = {round(t.user_attrs["stats"]["median_makespan_s"], 9) for t in done}
    assert len(spans) > 1, spans


def test_the_defaults_trial_matches_jaxplan_run(interrupted_and_resumed, tiny_run):
    """Trial 0 is the [planner] defaults; its batched, vmapped run gives the same metrics
    as the tiny scenario's step-by-step `jaxplan run` (an independent code path)."""
    out, _, res, _ = interrupted_and_resumed
    import optuna

    study = optuna.load_study(study_name="jaxplan_tune", storage=f"sqlite:///{out}/study.db")
    t0 = study.trials[0]
    assert t0.user_attrs["defaults"] and t0.params == {"q_obs": 10.0, "k_t": 6.0}
    s = t0.user_attrs["stats"]
    m = tiny_run.metrics
    assert s["success_rate"] == (1.0 if m["success"] else 0.0)
    assert s["collisions"] == m["collisions"]
    assert s["median_makespan_s"] == pytest.approx(m["makespan_s"], rel=1e-9)
    # the vmapped batch program and the single-run step program round differently; the
    # closed loop carries that into the separation's 6th digit
    assert s["min_separation_ratio"] == pytest.approx(m["min_separation_ratio"], rel=1e-4)
    # held out (seed 1: the tiny fleet has no random part): the same again
    h = res.holdout["defaults"]
    assert h["median_makespan_s"] == pytest.approx(m["makespan_s"], rel=1e-9)


def test_outputs_best_snippet_holdout_and_figures(interrupted_and_resumed):
    from PIL import Image

    out, _, res, lines = interrupted_and_resumed
    best = res.best
    assert math.isfinite(best["value"]) and best["feasible"]
    snippet = tomllib.loads((out / "best.toml").read_text())
    assert snippet == {"planner": best["weights"]}
    assert set(best["weights"]) == {"q_obs", "k_t"}
    # the best is the lowest objective among the complete trials in trials.csv
    import csv

    with open(out / "trials.csv", newline="") as f:
        rows = [r for r in csv.DictReader(f) if r["state"] == "COMPLETE"]
    assert best["value"] == min(float(r["value"]) for r in rows)
    with open(out / "holdout.csv", newline="") as f:
        hold = list(csv.DictReader(f))
    assert [(r["setting"], r["seed"]) for r in hold] == [("best", "1"), ("defaults", "1")]
    # the world's checks beside the robots' (a run can fail on either)
    from jaxplan.tune import HOLDOUT_COLUMNS

    assert list(hold[0]) == list(HOLDOUT_COLUMNS)
    for r in hold:
        assert r["workspace_violations"] == "0" and float(r["min_workspace_clearance_m"]) > 0
    # the best weights held out (seed 1, the same fleet) run as they trained
    assert res.holdout["best"]["median_makespan_s"] == pytest.approx(
        best["stats"]["median_makespan_s"], rel=1e-9)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["best"]["number"] == best["number"] and summary["trials"] == 6
    assert set(summary["holdout"]) == {"best", "defaults"}
    for name in ("objective.png", "importance.png", "pareto.png"):
        with Image.open(out / "figures" / name) as im:
            assert im.size[0] > 300 and im.size[1] > 300
    assert any(line.startswith("  held out, best") for line in lines), lines


def test_a_directory_made_with_another_config_is_refused(interrupted_and_resumed):
    import dataclasses

    from jaxplan.tune import TuneError, run_tune

    out = interrupted_and_resumed[0]
    cfg = _parse(TUNE_TABLE)
    other = dataclasses.replace(cfg, planner=dataclasses.replace(cfg.planner, k_p=4.0))
    with pytest.raises(TuneError, match="differs in: planner"):
        run_tune(other, out, progress=False, echo=None)
    # and one made by another behaviour revision (tune/config.toml's first line)
    path = out / "config.toml"
    text = path.read_text()
    try:
        path.write_text(text.split("\n", 1)[1])  # as a version without the line wrote it
        with pytest.raises(TuneError, match="behaviour revision 0"):
            run_tune(cfg, out, progress=False, echo=None)
    finally:
        path.write_text(text)


@pytest.mark.slow  # a `jaxplan tune` child SIGKILLed, another resuming (~100 s): make test-slow
def test_sigkill_then_resume_loses_only_the_trials_in_flight(tmp_path):
    """`jaxplan tune` in a child, SIGKILLed once its second batch of 3 trials is in
    flight, then resumed in another child."""
    import os
    import subprocess

    import optuna

    cfg = tmp_path / "tiny_tune.toml"
    cfg.write_text(TINY_TOML + TUNE_TABLE)
    out = tmp_path / "out"
    env = child_env(os.environ.get("JAX_COMPILATION_CACHE_DIR") or tmp_path / "jax_cache")
    db = out / "study.db"
    proc = kill_when(jaxplan_cmd("tune", cfg, out), env, tmp_path,
                     lambda: _states(db) == {"COMPLETE": 3, "RUNNING": 3, "params": 12},
                     timeout=600, poll=0.01, what="the second batch never started")
    assert proc.returncode == -signal.SIGKILL
    assert _states(db) == {"COMPLETE": 3, "RUNNING": 3, "params": 12}
    r = subprocess.run(jaxplan_cmd("tune", cfg, out) + ["--no-figures"], env=env,
                       cwd=tmp_path, capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "3 trial(s) in flight at the last stop queued again" in r.stdout, r.stdout
    assert "trials: 6 complete, 3 run now, 3 requeued after a kill" in r.stdout, r.stdout
    study = optuna.load_study(study_name="jaxplan_tune", storage=f"sqlite:///{db}")
    trials = study.get_trials()
    done = [t for t in trials if t.state.name == "COMPLETE"]
    failed = [t for t in trials if t.state.name == "FAIL"]
    assert [t.number for t in done[:3]] == [0, 1, 2] and len(done) == 6
    again = {t.user_attrs["requeued_from"]: t.params for t in done[3:]}
    assert again == {t.number: t.params for t in failed} and len(failed) == 3


def test_per_run_weights_are_the_traced_ones_only():
    """The sweep batch's per-run weights replace [planner] settings that are traced inputs
    of the batch program; anything else (it would change the program) is refused."""
    from jaxplan.sweep import with_weights

    cfg = _parse(TUNE_TABLE)
    w = with_weights(cfg, {"k_t": 3.5, "safety_margin_m": 0.1, "q_dynm": 2.0})
    assert (w.planner.k_t, w.planner.safety_margin_m, w.planner.q_dynm) == (3.5, 0.1, 2.0)
    assert w.planner.q_obs == cfg.planner.q_obs and with_weights(cfg, {}) is cfg
    with pytest.raises(ValueError, match="not traced weights: degree, max_iters"):
        with_weights(cfg, {"max_iters": 3, "degree": 7})


def test_pareto_front_by_hand():
    import numpy as np

    from jaxplan.plots.tune import pareto_front

    success = np.array([1.0, 1.0, 0.5, 0.5, 1.0, 0.0])
    makespan = np.array([5.0, 6.0, 4.0, 7.0, 5.0, 3.0])
    # (1, 5) twice: neither beats the other; (1, 6) and (0.5, 7) are beaten
    assert pareto_front(success, makespan).tolist() == [5, 2, 0, 4]
