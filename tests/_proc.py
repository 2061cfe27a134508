"""Subprocess helpers shared by the kill-mid-write tests."""

import os
import signal
import subprocess
import time


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
