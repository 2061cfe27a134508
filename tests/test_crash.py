"""`jaxplan run` killed (SIGKILL) while it writes its run directory: every file under a
final name is whole, nothing is left that a reader could take for a result, and running
the same command again completes the directory.

jaxplan/files/rundir.py writes each file to a hidden temporary name and renames it into
place (jaxplan/files/durable.py): config.toml, trajectories.npz, then metrics.json, which
marks a complete run; the figures (jaxplan/plots/) last.  Two kills land in the write
phase: one as soon as the first entry appears in the run directory (config.toml's
temporary file: config.toml being written), one as soon as the first entry appears in
figures/ (the first figure being written).  A third run completes.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import tomllib
from pathlib import Path

import numpy as np
import pytest

from tests._proc import child_env, jaxplan_cmd, kill_when
from tests.conftest import TINY_TOML

CONTRACT = ("config.toml", "trajectories.npz", "metrics.json")
FIGURES = ("trajectories_3d.png", "trajectories_top.png", "speed_acc.png", "separation.png",
           "clearance.png", "animation.gif")
TEMP = re.compile(r"^\..+\.tmp(\.mp4)?$")  # the writers' hidden temporary names


@pytest.fixture(scope="module")
def crash_env(tmp_path_factory):
    d = tmp_path_factory.mktemp("crash")
    cfg = d / "tiny.toml"
    cfg.write_text(TINY_TOML.replace("duration_s = 12.0", "duration_s = 1.0"))
    # the runs share the test session's persistent compilation cache: the tiny
    # scenario's programs (the same at any duration) are there once `tiny_run` ran in
    # this worker (tests/conftest.py SHARED_WORKER; else the first child compiles them)
    env = child_env(os.environ.get("JAX_COMPILATION_CACHE_DIR") or d / "jax_cache")
    return d, cfg, env


def _kill_when(cmd, env, cwd, ready, timeout=300.0) -> None:
    """Start cmd, SIGKILL it as soon as ready() holds (polled every ms)."""
    proc = kill_when(cmd, env, cwd, ready, timeout=timeout, poll=0.001,
                     what="the run never reached its write phase")
    # killed, not finished: the kill landed before the last figure was in place
    assert proc.returncode == -signal.SIGKILL, proc.returncode


def _listing(folder: Path) -> set[str]:
    try:
        return set(os.listdir(folder))
    except FileNotFoundError:
        return set()


def _check_whole(out: Path) -> set[str]:
    """Every file under a final name parses; anything else is a hidden temporary file.
    Returns the final names present (figures as figures/NAME)."""
    from PIL import Image

    present = set()
    for p in sorted(out.rglob("*")):
        if p.is_dir():
            assert p == out / "figures", p
            continue
        rel = p.relative_to(out).as_posix()
        if TEMP.match(p.name):
            continue  # e.g. .metrics.json.k2j4.tmp: never read as a result
        present.add(rel)
        if rel == "config.toml":
            tomllib.loads(p.read_text())
        elif rel == "metrics.json":
            m = json.loads(p.read_text())
            assert m["name"] == "tiny" and "success" in m
        elif rel == "trajectories.npz":
            with np.load(p, allow_pickle=False) as z:
                arrays = {k: z[k] for k in z.files}
            assert np.all(np.isfinite(arrays["pos"])) and arrays["pos"].shape[0] == 3
        elif rel in {f"figures/{f}" for f in FIGURES}:
            with Image.open(p) as im:
                im.verify()  # structure and checksums
            with Image.open(p) as im:
                im.load()  # and every byte of the (first) image decodes
        else:
            raise AssertionError(f"unexpected file in the run directory: {rel}")
    # metrics.json marks a complete run: the files written before it are there
    if "metrics.json" in present:
        assert {"config.toml", "trajectories.npz"} <= present, present
        from jaxplan.files import load_run

        load_run(out, complete=True)
    return present


def _kill_at_first_entry(d: Path, cfg, env, out: Path) -> None:
    """Kill a `jaxplan run` into ``out`` as soon as the directory has its first entry
    (config.toml's temp file): it holds whole files or none, and not the figures."""
    _kill_when(jaxplan_cmd("run", cfg, out), env, d, lambda: out.is_dir() and any(out.iterdir()))
    first = _check_whole(out)
    assert not {f"figures/{f}" for f in FIGURES} <= first, first


@pytest.mark.slow  # a `jaxplan run` child (~16-20 s of the suite): make test-slow, as the
# test below; `make test` keeps the atomic writes' own test (tests/test_results.py)
def test_sigkill_at_the_first_write_leaves_whole_files(crash_env):
    # the first half of the test below
    d, cfg, env = crash_env
    _kill_at_first_entry(d, cfg, env, d / "first")


@pytest.mark.slow  # three `jaxplan run` children (~34 s on 2 cores): make test-slow
def test_sigkill_mid_write_leaves_whole_files_and_a_rerun_completes(crash_env):
    d, cfg, env = crash_env
    out = d / "run"
    # 1. kill as soon as the run directory has its first entry (config.toml's temp file)
    _kill_at_first_entry(d, cfg, env, out)
    # 2. kill as soon as a new entry appears in figures/ (the first figure being written)
    figs = out / "figures"
    before = _listing(figs)
    _kill_when(jaxplan_cmd("run", cfg, out), env, d, lambda: bool(_listing(figs) - before))
    second = _check_whole(out)
    assert set(CONTRACT) <= second, second
    # 3. the same command again: a complete directory
    r = subprocess.run(jaxplan_cmd("run", cfg, out), env=env, cwd=d, capture_output=True, text=True,
                       timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    final = _check_whole(out)
    assert final == set(CONTRACT) | {f"figures/{f}" for f in FIGURES}, final
    m = json.loads((out / "metrics.json").read_text())
    assert m["robots"] == 3 and m["replans"] == 8
    assert str(out) in r.stdout
