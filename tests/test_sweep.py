"""jaxplan.sweep: the grid, sweep.csv (resume, partial lines), padding, and the command
end to end with a real SIGKILL of a subprocess and a resume."""

from __future__ import annotations

import csv
import dataclasses
import os
import signal
import subprocess
import tomllib
from pathlib import Path

import numpy as np
import pytest

from jaxplan.config import parse_config
from tests._proc import child_env, jaxplan_cmd, kill_when
from tests.conftest import TINY_TOML

# 2 x 2 weights x 2 seeds on three robots crossing a 2 m sphere (seeded perturbation)
SWEEP_TOML = """
name = "tiny_sweep"
seed = 0
[sim]
duration_s = 3.0
[scenario]
kind = "antipodal_sphere"
count = 3
radius = 1.0
perturbation = 0.1
vehicles = ["firefly", "neo11"]
[sweep]
q_obs = [1.0, 100.0]
q_lim = {log_min = -1, log_max = 1, num = 2}
seeds = [0, 1]
"""


def _config(text=SWEEP_TOML, source="tiny_sweep.toml"):
    return parse_config(tomllib.loads(text), source=source)


# ----------------------------------------------------------------------------- no JAX


def test_points_cover_the_grid_once_with_exact_keys():
    from jaxplan.sweep import sweep_points

    cfg = _config()
    pts = sweep_points(cfg)
    assert len(pts) == 2 * 2 * 2
    assert len({p.key for p in pts}) == len(pts)
    assert {p.scenario for p in pts} == {"antipodal_sphere"}
    assert sorted({p.q_lim for p in pts}) == [0.1, 10.0]
    # the key is the exact repr: a float written and read back has the same key
    for p in pts:
        assert float(p.key[0]) == p.q_obs and float(p.key[1]) == p.q_lim


def test_registry_scenarios_label_rows():
    from jaxplan.sweep import sweep_points

    cfg = _config(SWEEP_TOML + 'scenarios = ["paper:six_neos", "stacked"]\n')
    labels = [p.scenario for p in sweep_points(cfg)]
    assert labels[:8] == ["paper:six_neos"] * 8 and labels[8:] == ["stacked"] * 8


def _write(path: Path, rows, partial: str = ""):
    from jaxplan.sweep import csv_text

    path.write_text(csv_text(rows, header=True) + partial)


def _row(qo, ql, seed, **kw):
    r = {"q_obs": repr(qo), "q_lim": repr(ql), "scenario": "s", "seed": str(seed),
         "success": "1", "min_separation_ratio": "1.5", "makespan_s": "3.0",
         "collisions": "0"}
    r.update(kw)
    return r


def test_csv_reader_drops_partial_malformed_and_duplicate_lines(tmp_path):
    from jaxplan.sweep import COLUMNS, read_sweep_csv, row_key

    p = tmp_path / "sweep.csv"
    rows = [_row(1.0, 0.1, 0), _row(1.0, 0.1, 1), _row(1.0, 0.1, 0, success="0")]
    _write(p, rows, partial="1.0,0.1,s,2,1,0,1.2")  # killed mid-write: no newline
    got, info = read_sweep_csv(p)
    assert [row_key(r) for r in got] == [("1.0", "0.1", "s", "0"), ("1.0", "0.1", "s", "1")]
    assert got[0]["success"] == "1"  # the first occurrence wins
    assert info.duplicates == 1 and info.partial_bytes > 0 and not info.clean
    # a malformed line (wrong field count) in the middle
    text = p.read_text().splitlines(keepends=True)
    p.write_text(text[0] + "1.0,2.0\n" + "".join(text[1:3]))
    got, info = read_sweep_csv(p)
    assert len(got) == 2 and info.malformed == 1
    # 1e-05 and 0.00001 are one key
    assert row_key({"q_obs": "0.00001", "q_lim": "1", "scenario": "s", "seed": "3"}) == \
        row_key({"q_obs": "1e-05", "q_lim": "1.0", "scenario": "s", "seed": "3"})
    assert COLUMNS[:4] == ("q_obs", "q_lim", "scenario", "seed")


def test_csv_reader_refuses_foreign_columns(tmp_path):
    from jaxplan.sweep import SweepError, read_sweep_csv

    p = tmp_path / "sweep.csv"
    p.write_text("a,b\n1,2\n")
    with pytest.raises(SweepError, match="columns"):
        read_sweep_csv(p)
    with pytest.raises(SweepError, match="columns"):
        read_sweep_csv(p, older=True)


def test_csv_reader_reads_an_older_version_only_when_asked(tmp_path):
    # an earlier version wrote the leading columns only: a finished sweep is read (the
    # later columns empty), a resume refuses it
    from jaxplan.sweep import COLUMNS, SweepError, csv_text, read_sweep_csv

    old = COLUMNS[:-2]
    row = {c: "1" for c in COLUMNS} | {"q_obs": "1.0", "q_lim": "2.0", "scenario": "s",
                                        "seed": "3", "error": ""}
    lines = csv_text([row], header=True).splitlines()
    cut = lambda line: ",".join(line.split(",")[:len(old)])  # noqa: E731
    p = tmp_path / "sweep.csv"
    p.write_text("\n".join(cut(x) for x in lines) + "\n")
    with pytest.raises(SweepError, match="not this version's"):
        read_sweep_csv(p)
    (got,), info = read_sweep_csv(p, older=True)
    assert info.malformed == 0
    assert [got[c] for c in old] == [row[c] for c in old]
    assert got[COLUMNS[-1]] == "" and got[COLUMNS[-2]] == ""


def test_pad_robots_parks_masked_robots_far_away():
    import jax

    from jaxplan.config import build_scenario
    from jaxplan.run_setup import fleet_params, task_of
    from jaxplan.sweep import pad_robots as _pad_robots

    cfg = _config()
    sc = build_scenario(cfg)
    fp = jax.tree.map(np.asarray, fleet_params(cfg, sc))
    task = jax.tree.map(np.asarray, task_of(cfg, sc))
    fp2, task2 = _pad_robots(fp, task, 5)
    assert task2.start.shape == (5, 3) and task2.waypoints.shape[0] == 5
    assert fp2.robot_mask.tolist() == [True] * 3 + [False] * 2
    assert fp2.radius.shape == (5,) and fp2.limits.v_max.shape == (5,)
    assert np.all(task2.rest[3:]) and np.all(task2.goal_velocity[3:] == 0)
    assert np.min(np.linalg.norm(task2.start[3:] - task2.start[:3, None], axis=-1)) > 1e3
    np.testing.assert_array_equal(task2.waypoints[3:, 0], task2.start[3:])
    fp3, task3 = _pad_robots(fp, task, 3)
    assert task3 is task and fp3 is fp


def test_a_directory_made_with_another_config_is_refused(tmp_path):
    from jaxplan.sweep import SweepError
    from jaxplan.sweep import guard_config as _guard_config

    _guard_config(tmp_path, _config())
    _guard_config(tmp_path, _config(SWEEP_TOML.replace("seeds = [0, 1]", "seeds = [0, 1, 2]")))
    with pytest.raises(SweepError, match="different config.*sim"):
        _guard_config(tmp_path, _config(SWEEP_TOML.replace("3.0", "4.0")))


def test_a_directory_made_by_another_behaviour_revision_is_refused(tmp_path):
    # config.toml's first line says which revision of what a run does made the directory
    # (changes that no config key shows); another, or none (older versions), is refused
    from jaxplan import sweep
    from jaxplan.config import config_to_toml

    cfg = _config()
    sweep.guard_config(tmp_path, cfg)
    path = tmp_path / "config.toml"
    text = path.read_text()
    assert text.startswith(f"# jaxplan behaviour revision: {sweep.BEHAVIOUR_REVISION}\n")
    assert parse_config(tomllib.loads(text), source="c.toml") == parse_config(
        tomllib.loads(config_to_toml(cfg)), source="c.toml")  # still the config
    sweep.guard_config(tmp_path, cfg)  # the same revision: resumes
    for other in (config_to_toml(cfg),
                  text.replace(f"revision: {sweep.BEHAVIOUR_REVISION}",
                               f"revision: {sweep.BEHAVIOUR_REVISION + 1}")):
        path.write_text(other)
        with pytest.raises(sweep.SweepError, match="behaviour revision"):
            sweep.guard_config(tmp_path, cfg)


def test_an_older_config_without_a_newer_default_key_still_resumes(tmp_path):
    import tomllib

    from jaxplan.config import config_to_toml
    from jaxplan.sweep import SweepError, stamped
    from jaxplan.sweep import guard_config as _guard_config

    cfg = _config()
    doc = tomllib.loads(config_to_toml(cfg))
    assert doc["planner"].pop("max_neighbors") == 0  # as an older version wrote it
    import tomli_w

    (tmp_path / "config.toml").write_text(stamped(tomli_w.dumps(doc)))
    _guard_config(tmp_path, cfg)  # same config: accepted
    doc["planner"]["max_neighbors"] = 4
    (tmp_path / "config.toml").write_text(stamped(tomli_w.dumps(doc)))
    with pytest.raises(SweepError, match="different config.*planner"):
        _guard_config(tmp_path, cfg)
    # a config.toml written before coast_samples existed ran without coast constraints
    # (the new default is 8): resuming it is a different config
    doc["planner"]["max_neighbors"] = 0
    doc["planner"].pop("coast_samples")
    (tmp_path / "config.toml").write_text(stamped(tomli_w.dumps(doc)))
    with pytest.raises(SweepError, match="different config.*planner"):
        _guard_config(tmp_path, cfg)
    _guard_config(tmp_path, dataclasses.replace(
        cfg, planner=dataclasses.replace(cfg.planner, coast_samples=0)))  # same: accepted
    # nor one written before 3-D fleets sidestepped under "auto" (sidestep_wait_3d_s)
    doc["planner"]["coast_samples"] = cfg.planner.coast_samples
    doc["planner"].pop("sidestep_wait_3d_s")
    (tmp_path / "config.toml").write_text(stamped(tomli_w.dumps(doc)))
    with pytest.raises(SweepError, match="different config.*planner"):
        _guard_config(tmp_path, cfg)
    # nor one written before a mutual stall sidestepped at once (sidestep_mutual_at_once)
    doc["planner"]["sidestep_wait_3d_s"] = cfg.planner.sidestep_wait_3d_s
    doc["planner"].pop("sidestep_mutual_at_once")
    (tmp_path / "config.toml").write_text(stamped(tomli_w.dumps(doc)))
    with pytest.raises(SweepError, match="different config.*planner"):
        _guard_config(tmp_path, cfg)
    # nor one written before a mutual stall had its own window (stall_window_mutual_s)
    doc["planner"]["sidestep_mutual_at_once"] = True
    doc["planner"].pop("stall_window_mutual_s")
    (tmp_path / "config.toml").write_text(stamped(tomli_w.dumps(doc)))
    with pytest.raises(SweepError, match="different config.*planner"):
        _guard_config(tmp_path, cfg)
    doc["planner"]["stall_window_mutual_s"] = cfg.planner.stall_window_mutual_s
    # nor one written before such a stall's sidestep had its own hold (sidestep_hold_mutual_s)
    doc["planner"].pop("sidestep_hold_mutual_s")
    (tmp_path / "config.toml").write_text(stamped(tomli_w.dumps(doc)))
    with pytest.raises(SweepError, match="different config.*planner"):
        _guard_config(tmp_path, cfg)
    doc["planner"]["sidestep_hold_mutual_s"] = 1.5  # the same config again: accepted
    (tmp_path / "config.toml").write_text(stamped(tomli_w.dumps(doc)))
    _guard_config(tmp_path, cfg)
    doc["planner"]["no_such_key"] = 1
    (tmp_path / "config.toml").write_text(stamped(tomli_w.dumps(doc)))
    with pytest.raises(SweepError, match="not a config this version reads"):
        _guard_config(tmp_path, cfg)


# ----------------------------------------------------------------------------- end to end


# The tiny scenario (tests/conftest.py) over the same 2 x 2 weights, one seed (the tiny
# fleet has no random part), one run per batch: the batch program is then
# tests/test_tune.py's (a tune on a CPU runs batches of one), compiled once for both:
# the end to end runs in this process, and both modules run in one worker
# (conftest.SHARED_WORKER); the slow tests' children load it from the session's
# compilation cache.
E2E_TOML = TINY_TOML + SWEEP_TOML[SWEEP_TOML.index("[sweep]"):].replace("seeds = [0, 1]",
                                                                       "seeds = [0]")


@pytest.fixture(scope="module")
def sweep_env(tmp_path_factory):
    d = tmp_path_factory.mktemp("sweep")
    cfg = d / "tiny_sweep.toml"
    cfg.write_text(E2E_TOML)
    # 4 runs in batches of 1 -> 4 batches, so a kill lands mid-sweep; the children (slow
    # tests) share the session's persistent compilation cache (each still reports its
    # one compilation of the batch program).  One CPU device: the program split over two
    # compiles and runs about twice as long on 2 cores (the suite's budget); the split is
    # checked by test_split_over_two_devices_runs_every_row_once (slow).
    cache = os.environ.get("JAX_COMPILATION_CACHE_DIR") or d / "jax_cache"
    env = child_env(cache, JAXPLAN_SWEEP_BATCH="1", JAXPLAN_CPU_DEVICES="1")
    return d, cfg, env


def _rows(path: Path):
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    return sorted(rows, key=lambda r: (r["scenario"], float(r["q_obs"]), float(r["q_lim"]),
                                       int(r["seed"])))


def _data_lines(path: Path) -> int:
    if not path.exists():
        return 0
    return max(0, path.read_bytes().count(b"\n") - 1)


def _sweep_here(cfg: Path, out: Path) -> str:
    """`jaxplan sweep CFG --out OUT --quiet` in this process, in batches of one run (as
    sweep_env's children); what it printed.  In this process its batch program is
    test_tune's (compiled once for both)."""
    import contextlib
    import io

    from jaxplan.cli import main

    buf = io.StringIO()
    with pytest.MonkeyPatch.context() as mp, contextlib.redirect_stdout(buf):
        mp.setenv("JAXPLAN_SWEEP_BATCH", "1")
        code = main(["sweep", str(cfg), "--out", str(out), "--quiet"])
    assert code == 0, buf.getvalue()
    return buf.getvalue()


@pytest.fixture(scope="module")
def uninterrupted(sweep_env):
    d, cfg, _ = sweep_env
    out = d / "whole"
    return out, _sweep_here(cfg, out)


def test_sweep_writes_rows_figures_and_counts_one_compilation(uninterrupted):
    out, printed = uninterrupted
    # one compilation for the 4 batches, or none where this process compiled the same
    # program before (test_tune's, run first)
    assert "compilations: 1" in printed or (
        "compilations: 0" in printed and "compiled already (in this process)" in printed), printed
    assert "best setting: q_obs =" in printed
    rows = _rows(out / "sweep.csv")
    assert len(rows) == 4
    assert len({(x["q_obs"], x["q_lim"], x["scenario"], x["seed"]) for x in rows}) == 4
    for x in rows:
        assert x["success"] in ("0", "1")
        assert float(x["min_separation_ratio"]) > 0
        assert x["robots"] == "3" and x["replans"] == "96" and x["error"] == ""
        # the world's columns (the default world: the ground, no obstacles; the tiny
        # fleet flies 1.5 m above it)
        assert x["obstacle_collisions"] == "0" and x["min_obstacle_clearance_m"] == ""
        assert x["workspace_violations"] == "0" and float(x["min_workspace_clearance_m"]) > 0
    # the weights reach the runs: rows of different weights differ
    assert len({(x["min_separation_ratio"], x["makespan_s"]) for x in rows}) > 1, rows
    for name in ("success_rate.png", "min_separation.png", "makespan.png"):
        assert (out / "figures" / name).stat().st_size > 0
    assert (out / "config.toml").exists()


def test_rerun_skips_finished_rows(sweep_env, uninterrupted):
    _, cfg, _ = sweep_env
    out, _ = uninterrupted
    before = (out / "sweep.csv").read_bytes()
    printed = _sweep_here(cfg, out)
    assert "compilations: 0" in printed and "4 skipped" in printed
    assert (out / "sweep.csv").read_bytes() == before


@pytest.mark.slow  # a sweep child killed and resumed (~32 s on 2 cores): `make test-slow`
def test_sigkill_then_resume_gives_the_same_rows(sweep_env, uninterrupted):
    d, cfg, env = sweep_env
    whole, _ = uninterrupted
    out = d / "killed"
    csv_path = out / "sweep.csv"
    proc = kill_when(jaxplan_cmd("sweep", cfg, out), env, d, lambda: _data_lines(csv_path) > 0,
                     timeout=600, poll=0.02, what="no batch finished in time")
    assert proc.returncode == -signal.SIGKILL
    n_killed = _data_lines(csv_path)
    assert 1 <= n_killed < 4, n_killed  # killed mid-sweep: the batch in flight was lost
    r = subprocess.run(jaxplan_cmd("sweep", cfg, out), env=env, cwd=d, capture_output=True,
                       text=True, timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "compilations: 1" in r.stdout
    assert f"{n_killed} skipped" in r.stdout
    resumed = _rows(csv_path)
    assert len(resumed) == 4
    assert resumed == _rows(whole / "sweep.csv")


@pytest.mark.slow  # a child on two CPU devices: `make test-slow`
def test_two_cpu_devices_and_two_runs_in_flight_give_the_one_device_rows(sweep_env,
                                                                          uninterrupted):
    """Two runs in flight (two threads calling the one-run program) in a process of two
    CPU devices: one compilation, and the one-device sweep's rows, every cell equal
    (docs/SWEEPS.md, "Same rows on every engine")."""
    d, cfg, env = sweep_env
    whole, _ = uninterrupted
    out = d / "two_devices"
    r = subprocess.run(jaxplan_cmd("sweep", cfg, out), cwd=d, capture_output=True, text=True,
                       env=dict(env, JAXPLAN_CPU_DEVICES="2", JAXPLAN_SWEEP_BATCH="2"),
                       timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "compilations: 1" in r.stdout and "in batches of 2" in r.stdout, r.stdout
    split, one = _rows(out / "sweep.csv"), _rows(whole / "sweep.csv")
    assert len(split) == len(one) == 4
    assert split == one


@pytest.mark.slow
def test_mixed_fleet_sizes_share_one_compilation(tmp_path):
    """stacked (6 robots) is padded to antipodal_sphere's 10 with masked robots; its
    rows match an unpadded sweep of stacked alone."""
    from jaxplan.sweep import run_sweep

    base = SWEEP_TOML.split("[sweep]")[0].replace("3.0", "1.0")
    grid = '[sweep]\nq_obs = [10.0]\nq_lim = [1.0]\nseeds = [0]\n'
    mixed = _config(base + grid + 'scenarios = ["antipodal_sphere", "stacked"]\n')
    res = run_sweep(mixed, tmp_path / "mixed", progress=False, batch_size=2, figures=False,
                    echo=None)
    assert res.compilations == 1 and res.ran == 2
    rows = {r["scenario"]: r for r in _rows(tmp_path / "mixed" / "sweep.csv")}
    assert rows["antipodal_sphere"]["robots"] == "10" and rows["stacked"]["robots"] == "6"
    alone = _config(base + grid + 'scenarios = ["stacked"]\n')
    run_sweep(alone, tmp_path / "alone", progress=False, batch_size=1, figures=False,
              echo=None)
    (ref,) = _rows(tmp_path / "alone" / "sweep.csv")
    got = rows["stacked"]
    for c in ("success", "collisions", "reached_frac", "waypoints_frac", "error"):
        assert got[c] == ref[c], c
    # padded, another program (other shapes): the same run to round-off, which the closed
    # loop grows (measured: 2.1e-5 relative in peak_speed_ratio)
    for c in ("min_separation_ratio", "peak_speed_ratio"):
        assert float(got[c]) == pytest.approx(float(ref[c]), rel=1e-4, abs=1e-9), c


def test_the_batch_structure_forms_the_kinds_the_grid_needs():
    """structure_for with the grid's scenarios forms the static-row kinds of their
    worlds (PLANE always: workspace faces, padding); without scenarios, every kind; the
    coast rows always (a rest-ended grid too).  A runner keeps its structure while it
    covers a batch and makes a larger one (never a smaller) when a batch needs more."""
    from jaxplan.sweep import (
        BatchRunner,
        build_scenarios,
        grid_kinds,
        structure_for,
        sweep_points,
    )
    from jaxplan.world import ALL_KINDS, PLANE, row_kinds, static_rows

    sweep = SWEEP_TOML[SWEEP_TOML.index("[sweep]"):].replace("seeds = [0, 1]", "seeds = [0]")
    R = 64
    # the tiny fleet (its own scenario) with rest ends: PLANE only, the coast rows kept
    rest = _config(TINY_TOML + '[planner]\nend_state = "rest"\n' + sweep)
    tiny = list(build_scenarios(rest, sweep_points(rest)).values())
    assert grid_kinds(tiny, 3) == (PLANE,)
    st = structure_for(rest, 3, R, tiny)
    assert st.planner.nlp.static_kinds == (PLANE,) and st.planner.nlp.n_coast_samples == 8
    every = structure_for(rest, 3, R)
    assert every.planner.nlp.static_kinds == ALL_KINDS and every.planner.nlp.n_coast_samples == 8
    assert dataclasses.replace(st.planner.nlp, static_kinds=ALL_KINDS) == every.planner.nlp
    # registry worlds: the pillars' kinds
    cfg = _config(SWEEP_TOML.replace("seeds = [0, 1]", "seeds = [0]")
                  + 'scenarios = ["pillars", "stacked"]\n')
    built = build_scenarios(cfg, sweep_points(cfg))
    pillars = [s for (label, _), s in built.items() if label == "pillars"]
    stacked = [s for (label, _), s in built.items() if label == "stacked"]
    want = row_kinds(np.append(static_rows(pillars[0].world).kind, PLANE))
    assert want != (PLANE,) and want != ALL_KINDS  # the test needs a world of some kinds
    assert grid_kinds(pillars + stacked, 3) == want
    assert grid_kinds(stacked, 3) == (PLANE,)
    assert grid_kinds(pillars, 2) == (PLANE,)  # no 2-D fleet: PLANE alone
    assert structure_for(cfg, 3, R, pillars + stacked).planner.nlp.static_kinds == want
    # the runner: a structure from what it was given, kept while it covers the batch
    runner = BatchRunner(cfg)
    only_stacked = {k: s for k, s in built.items() if k[0] == "stacked"}
    first = runner.structure(3, R, only_stacked, stacked)
    assert first.planner.nlp.static_kinds == (PLANE,)
    assert runner.structure(3, R, only_stacked, stacked) is first
    larger = runner.structure(3, R, built, pillars)  # pillars need more: made again
    assert larger.planner.nlp.static_kinds == want
    assert runner.structure(3, R, built, stacked) is larger  # ... and kept
