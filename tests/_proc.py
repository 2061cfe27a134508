"""Subprocess helpers shared by the kill-mid-write tests."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def jaxplan_cmd(command: str, cfg: Path, out: Path) -> list[str]:
    """``python -m jaxplan COMMAND CFG --out OUT --quiet`` with this interpreter."""
    return [sys.executable, "-m", "jaxplan", command, str(cfg), "--out", str(out), "--quiet"]


def child_env(cache_dir, **extra) -> dict:
    """The environment for a `python -m jaxplan` child: this checkout importable, and a
    persistent compilation cache shared by the children (only the first compiles)."""
    env = dict(os.environ)
    env.update(extra)
    env["JAX_COMPILATION_CACHE_DIR"] = str(cache_dir)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return env


def kill_when(cmd, env, cwd, ready, *, timeout: float, poll: float, what: str):
    """Start ``cmd``, SIGKILL it as soon as ``ready()`` holds, return the Popen.

    Fails (with the child's stderr) if it exits first, or with ``what`` if ``ready()``
    does not hold within ``timeout`` seconds.  The child never outlives this call."""
    proc = subprocess.Popen(cmd, env=env, cwd=cwd, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, start_new_session=True)
    try:
        deadline = time.monotonic() + timeout
        while not ready():
            assert proc.poll() is None, proc.stderr.read().decode()[-3000:]
            assert time.monotonic() < deadline, what
            time.sleep(poll)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            os.kill(proc.pid, signal.SIGKILL)
            proc.wait()
    return proc
