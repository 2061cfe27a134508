"""The MuJoCo MJX fleet simulation: quadrotor models, the SE(3) controller, the fleet in
lockstep."""

from __future__ import annotations

import contextlib
import io
import sys

# what mujoco.mjx prints (to stdout, on every import) when NVIDIA Warp, an optional
# backend jaxplan does not use, is not installed
_WARP_NOTES = ("Failed to import warp:", "Failed to import mujoco_warp:")


def import_mjx():
    """``mujoco.mjx``, imported without its two "Failed to import warp" lines (see
    _WARP_NOTES); anything else its import prints is passed on to stdout."""
    if "mujoco.mjx" in sys.modules:
        return sys.modules["mujoco.mjx"]
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        from mujoco import mjx
    for line in buf.getvalue().splitlines():
        if not line.startswith(_WARP_NOTES):
            print(line)
    return mjx
