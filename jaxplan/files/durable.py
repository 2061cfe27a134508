"""Durable file writes: every file jaxplan writes goes through one of these.

    atomic_write(path, write, *, suffix=".tmp") -> path     write(tmp_path) fills a temporary
    atomic_write_bytes(path, data), atomic_write_text(path, text)
    append_lines(path, text)                  whole lines, one write, fsync, under file_lock
    file_lock(path) -> filelock.FileLock      the lock of ``path`` (``.<name>.lock`` beside it)

An atomic write fills a temporary file in the same folder (``.<name>.<random><suffix>``),
flushes it to disk and renames it over ``path``, so a crash (even SIGKILL) never leaves a
half-written file under a final name; temporaries left by an earlier killed write of the
same name are removed first.  The file gets the usual permissions (0666 minus the umask;
a bare temporary file's are 0600).  Used for the run directory
(:mod:`jaxplan.files.rundir`), the figures (:mod:`jaxplan.plots`,
:mod:`jaxplan.files.media`) and sweep.csv / config.toml of a sweep directory
(:mod:`jaxplan.sweep`); docs/DESIGN.md "A run directory".

Appends take the file's lock (:func:`file_lock`, the ``filelock`` library: an ``flock``
on ``.<name>.lock`` in the same folder, which stays there), so that processes appending
to one file, on one machine or over a shared file system that supports locks, never
interleave their lines; a reader that must not see a write in progress takes it too.
"""

from __future__ import annotations

import contextlib
import glob
import os
import tempfile
from collections.abc import Callable
from pathlib import Path

from filelock import FileLock

__all__ = ["atomic_write", "atomic_write_bytes", "atomic_write_text", "append_lines",
           "file_lock"]


def _umask() -> int:
    umask = os.umask(0)
    os.umask(umask)
    return umask


def atomic_write(path, write: Callable[[str], object], *, suffix: str = ".tmp") -> Path:
    """Write ``path`` atomically: ``write(tmp)`` fills the temporary file ``tmp`` (a str
    path in the same folder, ending in ``suffix``: a writer that picks the format by the
    name, like ffmpeg, gets the right one), which is then fsync'ed and renamed over
    ``path``.  Returns ``path`` (a Path)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    for old in path.parent.glob(f".{glob.escape(path.name)}.*{glob.escape(suffix)}"):
        with contextlib.suppress(OSError):
            old.unlink()
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix, dir=path.parent)
    try:
        try:
            os.fchmod(fd, 0o666 & ~_umask())
        finally:
            os.close(fd)
        write(tmp)
        fd = os.open(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    return path


def atomic_write_bytes(path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (:func:`atomic_write`)."""

    def write(tmp):
        with open(tmp, "wb") as f:
            f.write(data)

    return atomic_write(path, write)


def atomic_write_text(path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically (:func:`atomic_write`)."""
    return atomic_write_bytes(path, text.encode("utf-8"))


def file_lock(path) -> FileLock:
    """The inter-process lock of ``path``: a :class:`filelock.FileLock` on
    ``.<name>.lock`` beside it (one object per path in a process, re-entrant in a thread:
    ``with file_lock(p): append_lines(p, ...)`` is fine).  Blocks until it is free."""
    path = Path(path)
    return FileLock(path.parent / f".{path.name}.lock", is_singleton=True)


def append_lines(path, text: str) -> None:
    """Append complete lines to ``path`` (created 0644 minus the umask) in one write,
    then fsync, holding :func:`file_lock`: a kill leaves at most a partial trailing line,
    which a reader drops (:func:`jaxplan.sweep.table.read_sweep_csv`)."""
    data = text.encode("utf-8")
    with file_lock(path):
        fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        try:
            view = memoryview(data)
            while view:
                n = os.write(fd, view)
                view = view[n:]
            os.fsync(fd)
        finally:
            os.close(fd)
