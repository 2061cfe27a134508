"""jaxplan sweep beyond one process: the same grid run by the local engine in batches of
1, 2 and 4, by the Ray engine (a local instance of 2 workers, one of them SIGKILLed
mid-sweep) and as shards + merge gives the same rows, bitwise; `jaxplan rerun` of a row
gives its metrics bitwise; the shard, merge, lock and option plumbing on made-up
rows."""

from __future__ import annotations

import csv
import os
import signal
import subprocess
import sys
import threading
import time
import tomllib
from pathlib import Path

import pytest

from jaxplan.config import ConfigError, parse_config
from tests._proc import ROOT, jaxplan_cmd
from tests.test_sweep import SWEEP_TOML

# the 4-point sweep: (q_obs 5, q_lim 1) once succeeded with min d/rho 1.626 on
# the local engine (a batch of two runs split over two CPU devices) and failed with
# 1.419 on Ray (one run on one device)
FOUR_POINTS_TOML = """
name = "sweep4"
seed = 0
[sim]
duration_s = 6.0
[scenario]
kind = "antipodal_sphere"
count = 3
radius = 2.0
[sweep]
q_obs = [5.0, 20.0]
q_lim = [1.0, 4.0]
"""


def _config(text=SWEEP_TOML):
    return parse_config(tomllib.loads(text), source="tiny_sweep.toml")


def _read(path: Path) -> dict:
    """sweep.csv as {key: row}; fails on a duplicate key."""
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    keyed = {(r["q_obs"], r["q_lim"], r["scenario"], r["seed"]): r for r in rows}
    assert len(keyed) == len(rows), f"{path}: duplicate rows"
    return keyed


def _assert_same_rows(got: dict, ref: dict):
    """Same keys; every cell equal (bitwise: floats are written with repr)."""
    assert sorted(got) == sorted(ref)
    for k, r in ref.items():
        for c, v in r.items():
            assert got[k][c] == v, (k, c, got[k][c], v)


# ----------------------------------------------------------------------------- no JAX


def test_shard_option_and_engine_key():
    from jaxplan.sweep import parse_shard, shard_csv_name

    assert parse_shard("0/2") == (0, 2) and parse_shard(" 3 / 4 ") == (3, 4)
    for bad in ("2/2", "1/0", "-1/2", "a/b", "1", ""):
        with pytest.raises(ValueError, match="I/N"):
            parse_shard(bad)
    assert shard_csv_name(1, 4) == "sweep.shard-1-of-4.csv"
    assert _config(SWEEP_TOML + 'engine = "ray"\n').sweep.engine == "ray"
    assert _config().sweep.engine == "local"
    with pytest.raises(ConfigError, match=r"sweep\.engine.*'local', 'ray'"):
        _config(SWEEP_TOML + 'engine = "dask"\n')


def test_cli_refuses_inconsistent_sweep_options(tmp_path, capsys):
    from jaxplan.cli import main

    cfg = tmp_path / "tiny_sweep.toml"
    cfg.write_text(SWEEP_TOML)
    out = str(tmp_path / "out")
    assert main(["sweep", str(cfg), "--out", out, "--address", "auto"]) == 2
    assert "--address auto: needs --engine ray" in capsys.readouterr().err
    assert main(["sweep", str(cfg), "--out", out, "--merge", "--engine", "ray"]) == 2
    assert "--merge runs nothing" in capsys.readouterr().err
    assert main(["sweep", str(cfg), "--out", out, "--merge"]) == 2
    assert "no such sweep directory" in capsys.readouterr().err
    for argv in (["--shard", "2/2"], ["--shard", "0/2", "--merge"]):
        with pytest.raises(SystemExit) as e:
            main(["sweep", str(cfg), *argv])
        assert e.value.code == 2
    assert "--shard" in capsys.readouterr().err


def test_ray_engine_without_ray_says_how_to_install_it(tmp_path, monkeypatch):
    from jaxplan.sweep import SweepError, run_sweep

    monkeypatch.setitem(sys.modules, "ray", None)  # import ray -> ImportError
    with pytest.raises(SweepError, match=r'pip install "jaxplan\[ray\]"'):
        run_sweep(_config(), tmp_path, engine="ray", progress=False, echo=None)
    with pytest.raises(SweepError, match="needs the ray engine"):
        run_sweep(_config(), tmp_path, address="auto", progress=False, echo=None)


def _row(point, success="1", sep="1.5"):
    from jaxplan.sweep import make_key

    qo, ql, sc, seed = make_key(point.q_obs, point.q_lim, point.scenario, point.seed)
    return {"q_obs": qo, "q_lim": ql, "scenario": sc, "seed": seed, "success": success,
            "collisions": "0", "min_separation_ratio": sep, "makespan_s": "3.0"}


def test_merge_of_made_up_shards(tmp_path):
    from jaxplan.sweep import (
        SweepError,
        csv_text,
        merge_shards,
        read_sweep_csv,
        row_key,
        sweep_points,
    )

    cfg = _config()
    pts = sweep_points(cfg)
    with pytest.raises(SweepError, match="no shard files"):
        merge_shards(cfg, tmp_path, figures=False, echo=None)
    # shard 0 complete; shard 1 lost its last point (its last line cut mid-write) and
    # holds shard 0's first point again with other values; a sweep.csv with one row
    (tmp_path / "sweep.shard-0-of-2.csv").write_text(
        csv_text([_row(p) for p in pts[0::2]][::-1], header=True))
    (tmp_path / "sweep.shard-1-of-2.csv").write_text(
        csv_text([_row(p) for p in pts[1:-1:2]] + [_row(pts[0], "0", "0.5")], header=True)
        + "1.0,0.1,antipodal")
    (tmp_path / "sweep.csv").write_text(csv_text([_row(pts[2], sep="2.5")], header=True))
    (tmp_path / "sweep.shard-x-of-2.csv").write_text("not,a,shard\n")  # not a shard name
    res = merge_shards(cfg, tmp_path, figures=False, echo=None)
    rows, info = read_sweep_csv(tmp_path / "sweep.csv")
    assert info.clean
    assert [row_key(r) for r in rows] == [p.key for p in pts[:-1]]  # grid order, once each
    assert rows[0]["success"] == "1"  # shard 0's, not shard 1's duplicate
    assert rows[2]["min_separation_ratio"] == "2.5"  # sweep.csv's own row comes first
    assert res.missing == 1 and res.skipped == len(pts) - 1 and res.best is not None
    with pytest.raises(SweepError, match="different config"):
        merge_shards(_config(SWEEP_TOML.replace("3.0", "4.0")), tmp_path, figures=False,
                     echo=None)


def test_appends_take_the_lock_and_never_repeat_a_key(tmp_path):
    from jaxplan.files import append_lines, file_lock
    from jaxplan.sweep import csv_text, read_sweep_csv, sweep_points
    from jaxplan.sweep.engines import _Writer

    path = tmp_path / "sweep.csv"
    path.write_text(csv_text([], header=True))
    pts = sweep_points(_config())
    write = _Writer(path, {pts[0].key})
    write([_row(pts[0]), _row(pts[1])])
    write([_row(pts[1]), _row(pts[2])])
    assert [r["seed"] for r in read_sweep_csv(path)[0]] == [pts[1].key[3], pts[2].key[3]]
    size = path.stat().st_size
    with file_lock(path):  # another thread's append waits for the lock
        t = threading.Thread(target=append_lines, args=(path, "x\n"))
        t.start()
        time.sleep(0.3)
        assert t.is_alive() and path.stat().st_size == size
    t.join(timeout=10)
    assert not t.is_alive() and path.read_text().endswith("x\n")


def test_shards_starting_together_share_config_toml(tmp_path):
    """Shards of one sweep check and write the directory's config.toml at the same time
    (here threads; guard_config takes the file's lock)."""
    from jaxplan.sweep import guard_config

    cfg, errors = _config(), []

    def guard():
        try:
            for _ in range(10):
                guard_config(tmp_path, cfg)
        except Exception as e:  # any failure is the finding
            errors.append(e)

    threads = [threading.Thread(target=guard) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=60)
    assert not errors, errors[0]
    assert parse_config(tomllib.loads((tmp_path / "config.toml").read_text())) == cfg


# ----------------------------------------------------------------------------- end to end


@pytest.fixture(scope="module")
def engines_env(tmp_path_factory):
    """The tiny sweep: its one-run program compiled once, in this process (the local
    run; the shards reuse it), and loaded by the Ray workers from the test session's
    compilation cache (tests/conftest.py)."""
    d = tmp_path_factory.mktemp("engines")
    cfg = d / "tiny_sweep.toml"
    cfg.write_text(SWEEP_TOML)
    env = dict(os.environ, JAXPLAN_CPU_DEVICES="1", JAXPLAN_RAY_CPUS="2")
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return d, cfg, env


def _sweep(cfg: Path, out: Path, *args: str) -> None:
    """`jaxplan sweep CFG --out OUT --quiet --batch 1 ARGS`, in this process."""
    from jaxplan.cli import main

    assert main(["sweep", str(cfg), "--out", str(out), "--quiet", *args]) == 0


@pytest.fixture(scope="module")
def local_rows(engines_env):
    d, cfg, _ = engines_env
    _sweep(cfg, d / "local", "--batch", "1")
    rows = _read(d / "local" / "sweep.csv")
    assert len(rows) == 8
    return rows


def test_batch_sizes_and_three_shards_give_the_same_rows_and_reruns_the_row(
        tmp_path):
    """The 4-point sweep in this process (one device: conftest) with --batch 1 and 4, and
    as three shards of batches of 2 + merge: every cell equal; `jaxplan rerun` of rows
    0, 2 and 3: their metrics bitwise the row's, a full run directory.  One compilation for all (the
    one-run program); two CPU devices give these rows too (test_sweep.py, slow)."""
    from jaxplan.cli import main
    from jaxplan.files import load_run
    from jaxplan.sweep.rerun import rerun_row

    cfg = tmp_path / "sweep4.toml"
    cfg.write_text(FOUR_POINTS_TOML)
    _sweep(cfg, tmp_path / "b1", "--batch", "1")
    ref = _read(tmp_path / "b1" / "sweep.csv")
    assert len(ref) == 4
    _sweep(cfg, tmp_path / "b4", "--batch", "4")
    _assert_same_rows(_read(tmp_path / "b4" / "sweep.csv"), ref)
    for i in range(3):  # batches of 2 in each shard
        _sweep(cfg, tmp_path / "shards", "--batch", "2", "--shard", f"{i}/3")
    _sweep(cfg, tmp_path / "shards", "--merge")
    _assert_same_rows(_read(tmp_path / "shards" / "sweep.csv"), ref)

    for row in (0, 2):  # the first and a later row; row 3 through the command below
        res = rerun_row(tmp_path / "b1", row, tmp_path / f"row{row}", figures=False, echo=None)
        assert res.differ == [], res.differ
    run = load_run(tmp_path / "row0", complete=True)
    m = run.metrics
    with open(tmp_path / "b1" / "sweep.csv", newline="") as f:
        first = next(csv.DictReader(f))
    assert repr(m["min_separation_ratio"]) == first["min_separation_ratio"]
    assert ("1" if m["success"] else "0") == first["success"]
    text = (tmp_path / "row0" / "config.toml").read_text()
    assert f"q_obs = {first['q_obs']}" in text and f"q_lim = {first['q_lim']}" in text
    # the command: figures and animation unless --no-figures; a row that is not there
    assert main(["rerun", str(tmp_path / "b1"), "3", "--out", str(tmp_path / "cli")]) == 0
    m3 = load_run(tmp_path / "cli", complete=True).metrics
    with open(tmp_path / "b1" / "sweep.csv", newline="") as f:
        row3 = list(csv.DictReader(f))[3]
    assert repr(m3["min_separation_ratio"]) == row3["min_separation_ratio"]
    assert any((tmp_path / "cli" / "figures").glob("animation.*"))
    assert main(["rerun", str(tmp_path / "b1"), "4"]) == 2


@pytest.mark.slow  # ~45 s on 2 cores (a sweep compiled in-process): `make test-slow`
def test_two_shards_and_a_merge_give_the_local_rows(engines_env, local_rows):
    from jaxplan.sweep import sweep_points

    d, cfg, _ = engines_env
    out = d / "shards"
    for i in range(2):
        _sweep(cfg, out, "--batch", "1", "--shard", f"{i}/2")
    keys = [p.key for p in sweep_points(_config())]
    for i in range(2):
        assert sorted(_read(out / f"sweep.shard-{i}-of-2.csv")) == sorted(keys[i::2])
    assert not (out / "sweep.csv").exists() and not (out / "figures").exists()
    _sweep(cfg, out, "--merge")
    _assert_same_rows(_read(out / "sweep.csv"), local_rows)
    assert (out / "figures" / "success_rate.png").stat().st_size > 0


def _session(session: int) -> dict[int, str]:
    """{pid: process title} of the processes in process session ``session`` (the Ray
    driver's, which its instance's processes stay in)."""
    found = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            title = (entry / "cmdline").read_bytes().split(b"\0")[0].decode().strip()
            # after "(comm)": state, ppid, pgrp, session
            sid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[3])
        except (OSError, ValueError, IndexError):
            continue
        if sid == session:
            found[int(entry.name)] = title
    return found


def _busy_workers(session: int) -> list[int]:
    """Pids of the Ray workers running a sweep task in process session ``session``."""
    from jaxplan.sweep.ray import TASK_NAME

    return [pid for pid, title in _session(session).items() if title == f"ray::{TASK_NAME}"]


def _data_lines(path: Path) -> int:
    return max(0, path.read_bytes().count(b"\n") - 1) if path.exists() else 0


@pytest.mark.slow  # ~50 s on 2 cores (a local Ray instance, three workers): `make test-slow`
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="finds workers in /proc")
def test_ray_engine_with_a_worker_killed_mid_sweep_gives_the_local_rows(engines_env,
                                                                         local_rows):
    """`--engine ray` on a local instance of 2 workers; once the first rows are in,
    one worker busy with a task is SIGKILLed: Ray runs its task again, and sweep.csv
    ends complete, every row once, equal to the local engine's."""
    pytest.importorskip("ray")
    d, cfg, env = engines_env
    out = d / "ray"
    csv_path = out / "sweep.csv"
    driver = subprocess.Popen(jaxplan_cmd("sweep", cfg, out) + ["--engine", "ray"], env=env,
                              cwd=d, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True, start_new_session=True)
    killed, rows_at_kill = None, None
    try:
        deadline = time.monotonic() + 600
        while killed is None and driver.poll() is None and time.monotonic() < deadline:
            if _data_lines(csv_path) > 0:
                busy = _busy_workers(driver.pid)
                if busy:
                    rows_at_kill = _data_lines(csv_path)
                    os.kill(busy[0], signal.SIGKILL)
                    killed = busy[0]
            time.sleep(0.02)
        stdout, stderr = driver.communicate(timeout=600)
    finally:  # nothing this test started outlives it
        if driver.poll() is None:
            os.kill(driver.pid, signal.SIGKILL)
            driver.wait()
        for pid in _session(driver.pid):
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
    assert killed is not None, "no worker was found busy mid-sweep:\n" + stderr[-3000:]
    assert rows_at_kill < 8
    assert driver.returncode == 0, stderr[-3000:]
    assert "ray: 8 tasks" in stdout and "compilations: " in stdout, stdout
    assert _data_lines(csv_path) == 8 and csv_path.read_bytes().endswith(b"\n")
    _assert_same_rows(_read(csv_path), local_rows)
