"""Files jaxplan writes and reads back (docs/DESIGN.md "A run directory").

Modules:

    durable.py   durable writes: atomic replace, whole-line appends under a file lock
                 (every file jaxplan writes goes through them)
    rundir.py    the run directory: write_run, load_run (validated), RunData
    media.py     GIF / MP4 encoding of animation frames

Import the names from the package (``from jaxplan.files import load_run``).  Drawing is
not here: :mod:`jaxplan.plots` reads a run directory with :func:`load_run` and draws
its figures.
"""

from __future__ import annotations

from jaxplan.files.durable import (
    append_lines,
    atomic_write,
    atomic_write_bytes,
    atomic_write_text,
    file_lock,
)
from jaxplan.files.media import ffmpeg_available, write_gif, write_mp4
from jaxplan.files.rundir import REQUIRED_NPZ, RunData, load_run, write_run

__all__ = ["atomic_write", "atomic_write_bytes", "atomic_write_text", "append_lines",
           "file_lock", "write_run", "load_run", "RunData", "REQUIRED_NPZ", "write_gif",
           "write_mp4", "ffmpeg_available"]
