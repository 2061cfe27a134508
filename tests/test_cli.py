"""The `jaxplan` command: every contract file of a run directory, clear errors."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from jaxplan.cli import compile_cache_dir, main
from tests._proc import ROOT
from tests.conftest import TINY_TOML


def test_run_writes_every_contract_file(tmp_path, capsys, tiny_run, monkeypatch):
    cfg = tmp_path / "tiny.toml"
    cfg.write_text(TINY_TOML)
    out = tmp_path / "run"
    monkeypatch.setenv("JAXPLAN_CACHE_DIR", str(tmp_path / "cache"))
    import jax

    try:
        assert main(["run", str(cfg), "--out", str(out), "--quiet", "--no-cache"]) == 0
        # --no-cache: no cache directory made, JAX's own cache (the suite's) off too
        assert not (tmp_path / "cache").exists()
        assert not jax.config.jax_enable_compilation_cache
    finally:
        jax.config.update("jax_enable_compilation_cache", True)
    printed = capsys.readouterr().out
    assert "SUCCESS" in printed and str(out) in printed
    assert "compilation cache" not in printed
    # config.toml: the fully resolved config, loadable again
    from jaxplan.config import load_config

    resolved = load_config(out / "config.toml")
    assert resolved.planner.replan_hz == 8.0 and resolved.planner.degree == 5
    m = json.loads((out / "metrics.json").read_text())
    for key in ("success", "collisions", "min_separation_ratio", "makespan_s", "per_robot",
                "solver"):
        assert key in m
    for key in ("reached", "time_to_goal_s", "path_length_m", "max_speed", "max_acc",
                "max_jerk"):
        assert key in m["per_robot"][0]
    for key in ("median_ms", "p95_ms", "max_ms", "converged_frac"):
        assert key in m["solver"]
    with np.load(out / "trajectories.npz", allow_pickle=False) as z:
        M = 3
        K = z["t"].shape[0]
        assert z["pos"].shape == (M, K, 3) and z["vel"].shape == (M, K, 3)
        assert z["acc"].shape == (M, K, 3)
        assert np.all(np.diff(z["t"]) <= 0.01 + 1e-12)  # >= 100 Hz
        assert z["radius"].shape == (M,) and z["goal"].shape == (M, 3)
        assert z["vehicle"].dtype.kind == "U"
        S = z["seg_robot"].shape[0]
        assert z["seg_t0"].shape == (S,) and z["seg_t1"].shape == (S,)
        assert z["seg_coeffs"].shape == (S, 3, 6)
    figs = sorted(p.name for p in (out / "figures").iterdir())
    assert {"trajectories_3d.png", "speed_acc.png", "separation.png", "animation.gif"} <= set(
        figs)
    # the run's metrics agree with the in-process run of the same config
    assert m["collisions"] == tiny_run.metrics["collisions"]
    assert abs(m["min_separation_ratio"] - tiny_run.metrics["min_separation_ratio"]) < 1e-9


def test_a_second_run_in_this_process_reuses_the_compiled_planner(tiny_config, tiny_run,
                                                                  capsys):
    """experiment.run keeps its compiled replan period per structure and shapes: the same
    config run again in this process compiles nothing (compile_s 0, and says so) and
    gives the same results bitwise."""
    from jaxplan.experiment import run

    run(tiny_config)  # kept since tiny_run (or compiled again, were it pushed out since)
    again = run(tiny_config, progress=True)
    assert again.compile_s == 0.0
    assert "compiled already (in this process)" in capsys.readouterr().err
    timing = ("compile_s", "run_s", "solver")
    assert {k: v for k, v in again.metrics.items() if k not in timing} == {
        k: v for k, v in tiny_run.metrics.items() if k not in timing}
    assert again.arrays.keys() == tiny_run.arrays.keys()
    for k, v in tiny_run.arrays.items():
        np.testing.assert_array_equal(again.arrays[k], v, err_msg=k)


def test_summary_names_the_world_contacts(tmp_path):
    from jaxplan.cli import summary

    m = {"name": "w", "success": False, "robots": 2, "backend": "mjx", "replans": 8,
         "duration_s": 1.0, "collisions": 0, "min_separation_ratio": 1.5,
         "makespan_s": None, "peak_speed": 1.0, "peak_speed_over_limit": 0.5,
         "per_robot": [{"reached": True}] * 2, "compile_s": 1.0, "run_s": 1.0,
         "solver": {"median_ms": 1.0, "p95_ms": 2.0, "max_ms": 3.0, "converged_frac": 1.0},
         "fallbacks": {"kept_previous": 0, "braking": 0, "best_effort": 0},
         "tracking": {"rms_m": 0.01, "max_m": 0.02}}
    lines = summary(m, tmp_path).splitlines()
    assert not any("obstacle" in ln for ln in lines)
    assert lines[4].startswith("  tracking error")
    m.update(obstacle_collisions=1, min_obstacle_clearance_m=-0.2409,
             workspace_violations=0, min_workspace_clearance_m=None)
    lines = summary(m, tmp_path).splitlines()
    assert lines[2] == ("  obstacle contacts 1 (min clearance -0.241 m)   workspace "
                        "violations 0 (min clearance n/a m)")
    assert lines[5].startswith("  tracking error")


def test_bad_config_is_one_clear_line(tmp_path, capsys):
    cfg = tmp_path / "bad.toml"
    cfg.write_text(TINY_TOML.replace('seed = 0', 'seed = 0\n[planner]\nq_ob = 3.0'))
    assert main(["run", str(cfg)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0
    assert "bad.toml" in err and "planner.q_ob" in err


def test_the_mjx_flag_on_a_planar_config_is_one_clear_line(tmp_path, capsys):
    cfg = tmp_path / "planar.toml"
    cfg.write_text('[[robots]]\nvehicle = "ground"\nstart = [0.0, 0.0]\ngoal = [2.0, 0.0]\n')
    assert main(["run", str(cfg), "--backend", "mjx", "--no-figures"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "planar.toml" in err and "--backend" in err and "3-D" in err


def test_missing_file(tmp_path, capsys):
    assert main(["run", str(tmp_path / "nope.toml")]) == 2
    err = capsys.readouterr().err
    assert "nope.toml" in err and "No such file" in err


def test_scenarios_lists_builtins(capsys):
    assert main(["scenarios"]) == 0
    out = capsys.readouterr().out
    for name in ("paper:six_neos", "antipodal_sphere", "random_box", "grid_swap", "stacked"):
        assert name in out


def test_python_dash_m(tmp_path):
    r = subprocess.run([sys.executable, "-m", "jaxplan", "--help"], capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 0 and "run" in r.stdout


def test_bad_cpu_device_count_exits_with_one_line_that_names_it():
    import os

    env = dict(os.environ, JAXPLAN_CPU_DEVICES="two")
    r = subprocess.run([sys.executable, "-m", "jaxplan", "scenarios"], capture_output=True,
                       text=True, timeout=120, env=env)
    assert r.returncode == 2 and r.stdout == ""
    assert r.stderr.strip().splitlines()[-1] == (
        "jaxplan: error: JAXPLAN_CPU_DEVICES='two': expected a positive integer")


@pytest.mark.parametrize("cmd", [["plot", "/nonexistent/dir"]])
def test_plot_bad_dir(cmd, capsys):
    assert main(cmd) == 2
    assert "not a directory" in capsys.readouterr().err


def test_compile_cache_dir_follows_the_environment(monkeypatch, tmp_path):
    monkeypatch.setenv("JAXPLAN_CACHE_DIR", str(tmp_path / "c"))
    assert compile_cache_dir() == tmp_path / "c"
    monkeypatch.setenv("JAXPLAN_CACHE_DIR", " ")
    assert compile_cache_dir() is None  # empty: no cache
    monkeypatch.delenv("JAXPLAN_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "x"))
    assert compile_cache_dir() == tmp_path / "x" / "jaxplan" / "xla"
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "h"))
    assert compile_cache_dir() == tmp_path / "h" / ".cache" / "jaxplan" / "xla"


@pytest.mark.slow  # two children, the first compiling the tiny scenario from an empty cache
def test_a_rerun_from_the_compilation_cache_gives_the_same_results(tmp_path):
    """Two `jaxplan run` processes of one config sharing a cache directory: the first
    fills it, the second runs from it, and both write the same results."""
    cfg = tmp_path / "tiny.toml"
    cfg.write_text(TINY_TOML)
    cache = tmp_path / "cache"
    # not tests._proc.child_env: that one sets JAX_COMPILATION_CACHE_DIR, which jaxplan keeps
    env = dict(os.environ, JAXPLAN_CACHE_DIR=str(cache),
               PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    outs, entries = [], []
    for i in range(2):
        out = tmp_path / f"run{i}"
        r = subprocess.run([sys.executable, "-m", "jaxplan", "run", str(cfg), "--out", str(out),
                            "--quiet", "--no-figures"], env=env, capture_output=True, text=True,
                           timeout=600)
        assert r.returncode == 0, r.stderr[-3000:]
        assert f"compilation cache: {cache}" in r.stdout
        entries.append(sorted(p.name for p in cache.iterdir()))
        outs.append(out)
    assert entries[0], "the first run cached nothing"
    assert entries[1] == entries[0]  # the second found every program it needed there
    m0, m1 = (json.loads((o / "metrics.json").read_text()) for o in outs)
    for m in (m0, m1):  # wall-clock figures differ run to run
        for key in ("compile_s", "run_s"):
            m.pop(key)
        for key in ("median_ms", "p95_ms", "max_ms"):
            m["solver"].pop(key)
    assert m0 == m1
    t0, t1 = (np.load(o / "trajectories.npz", allow_pickle=False) for o in outs)
    assert sorted(t0.files) == sorted(t1.files)
    for k in t0.files:
        np.testing.assert_array_equal(t0[k], t1[k], err_msg=k)


_EVICT_CHILD = r"""
import sys
from pathlib import Path

import jax
import jax.numpy as jnp

from jaxplan import cli

jax.config.update("jax_persistent_cache_min_compile_time_secs", 0)
jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
d = Path(cli._use_compile_cache(False))
assert jax.config.jax_compilation_cache_max_size == int(sys.argv[1])
sizes = []
for k in range(6):  # six distinct programs, each cached on its first call
    jax.jit(lambda x, k=k: jnp.sin(x) * (k + 1.0) + jnp.cumsum(x) ** (k + 2))(jnp.ones(64))
    sizes.append(sum(p.stat().st_size for p in d.glob("*-cache")))
print(" ".join(map(str, sizes)))
"""


def test_the_cache_directory_is_bounded_and_evicts_old_entries(tmp_path):
    """`jaxplan run`'s own cache directory has a size bound (cli.CACHE_MAX_BYTES, here
    JAX_COMPILATION_CACHE_MAX_SIZE): JAX evicts the least recently used entries, also
    entries written before the bound was set (no access-time file)."""
    from jaxplan import cli

    assert cli.CACHE_MAX_BYTES > 0
    cache = tmp_path / "cache"
    cache.mkdir()
    old = cache / "jit_old_program-0123456789abcdef-cache"  # as jaxplan wrote it unbounded
    old.write_bytes(b"\0" * 1000)
    env = dict(os.environ, JAXPLAN_CACHE_DIR=str(cache), JAX_PLATFORMS="cpu",
               PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    # the bound from the environment: a little above the first new entry
    unbounded = dict(env, JAX_COMPILATION_CACHE_MAX_SIZE="-1",
                     JAXPLAN_CACHE_DIR=str(tmp_path / "p"))
    probe = subprocess.run([sys.executable, "-c", _EVICT_CHILD, "-1"], capture_output=True,
                           text=True, timeout=300, env=unbounded)
    assert probe.returncode == 0, probe.stderr[-3000:]
    first = int(probe.stdout.split()[0])
    cap = 2 * first + 500
    bounded = dict(env, JAX_COMPILATION_CACHE_MAX_SIZE=str(cap))
    r = subprocess.run([sys.executable, "-c", _EVICT_CHILD, str(cap)], capture_output=True,
                       text=True, timeout=300, env=bounded)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "Error writing persistent compilation cache" not in r.stderr, r.stderr[-3000:]
    sizes = [int(v) for v in r.stdout.split()]
    assert max(sizes) <= cap
    assert not old.exists()  # the oldest entry went first
    assert len(list(cache.glob("*-cache"))) < 6  # and some of the new ones after it


def test_the_cache_bound_defaults_to_jaxplans_and_yields_to_jaxs(monkeypatch, tmp_path):
    import jax

    from jaxplan import cli

    before = (jax.config.jax_compilation_cache_dir, jax.config.jax_compilation_cache_max_size)
    monkeypatch.delenv("JAX_COMPILATION_CACHE_MAX_SIZE", raising=False)
    monkeypatch.setenv("JAXPLAN_CACHE_DIR", str(tmp_path / "c"))
    try:
        jax.config.update("jax_compilation_cache_dir", None)
        (tmp_path / "c").mkdir()
        (tmp_path / "c" / "k-cache").write_bytes(b"x")
        assert cli._use_compile_cache(False) == str(tmp_path / "c")
        assert jax.config.jax_compilation_cache_max_size == cli.CACHE_MAX_BYTES
        assert (tmp_path / "c" / "k-atime").exists()  # stamped for the bounded cache
        jax.config.update("jax_compilation_cache_dir", None)
        jax.config.update("jax_compilation_cache_max_size", -1)
        monkeypatch.setenv("JAX_COMPILATION_CACHE_MAX_SIZE", "-1")
        cli._use_compile_cache(False)
        assert jax.config.jax_compilation_cache_max_size == -1  # the user's choice kept
    finally:
        jax.config.update("jax_compilation_cache_dir", before[0])
        jax.config.update("jax_compilation_cache_max_size", before[1])


def test_cache_file_suffixes_are_jaxs():
    """cli stamps cache entries by file name; the names must be the ones JAX's bounded
    cache reads (checked here against JAX's own module, which jaxplan does not import)."""
    from jax._src import lru_cache

    from jaxplan import cli

    assert cli.CACHE_ENTRY_SUFFIX == lru_cache._CACHE_SUFFIX
    assert cli.CACHE_ATIME_SUFFIX == lru_cache._ATIME_SUFFIX
