"""What both exports share: the error they raise, a complete run read back, each
robot's limits, and JSON that strict readers accept.

    ExportError                 a user-facing error (`jaxplan export` exits with status 2)
    read_run(run_dir)           the run directory, complete (metrics.json, the pieces)
    robot_limits(run)           {"v_max", "a_max", "j_max"}: (M,) m/s, m/s^2, m/s^3
    robot_pieces(run, i)        robot i's executed pieces, in time order
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

__all__ = ["ExportError", "read_run", "robot_limits", "robot_pieces", "json_safe"]

LIMIT_KEYS = ("v_max", "a_max", "j_max")


class ExportError(Exception):
    """An export that cannot be made as asked: one line naming the problem (the run
    directory, a robot, a flag); `jaxplan export` prints it and exits with status 2."""


def read_run(run_dir):
    """The run directory ``run_dir`` read back and validated (a finished run: its
    metrics.json and its executed pieces required); ExportError where it is not one."""
    from jaxplan.files import load_run

    path = Path(run_dir)
    if not path.is_dir():
        raise ExportError(f"{path}: not a directory")
    try:
        return load_run(path, complete=True)
    except ValueError as e:
        raise ExportError(str(e)) from None


def robot_limits(run) -> dict[str, np.ndarray]:
    """Each robot's v_max, a_max, j_max (m/s, m/s^2, m/s^3), each (M,): metrics.json's
    per_robot entries (what the run planned with), else the run's limits and the
    vehicle table; NaN where none is known."""
    from jaxplan.vehicles import ROBOTS

    m = run.num_robots
    per_robot = run.metrics.get("per_robot") if isinstance(run.metrics, dict) else None
    out = {}
    for key in LIMIT_KEYS:
        vals = np.full(m, np.nan)
        for i in range(m):
            entry = per_robot[i] if isinstance(per_robot, list) and i < len(per_robot) else {}
            v = entry.get(key) if isinstance(entry, dict) else None
            if isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v):
                vals[i] = float(v)
            elif key in run.limits:
                vals[i] = float(run.limits[key][i])
            elif run.vehicle[i] in ROBOTS:
                vals[i] = float(getattr(ROBOTS[run.vehicle[i]], key))
        out[key] = vals
    return out


def robot_pieces(run, robot: int):
    """Robot ``robot``'s executed pieces in time order: t0 (P,), t1 (P,) s, coeffs
    (P, N, D+1) monomials in t - t0 seconds, lowest power first (trajectories.npz's
    seg_*); ExportError when it has none."""
    seg_robot, seg_t0, seg_t1, seg_coeffs = run.pieces
    idx = np.nonzero(seg_robot == robot)[0]
    if idx.size == 0:
        raise ExportError(f"{run.run_dir}: robot {robot} has no executed pieces")
    idx = idx[np.argsort(seg_t0[idx], kind="stable")]
    return seg_t0[idx], seg_t1[idx], seg_coeffs[idx]


def json_safe(obj):
    """``obj`` with NaN / inf as None and numpy scalars and arrays as Python values
    (strict JSON has no NaN)."""
    if isinstance(obj, dict):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [json_safe(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return json_safe(obj.tolist())
    if isinstance(obj, bool | np.bool_):
        return bool(obj)
    if isinstance(obj, int | np.integer):
        return int(obj)
    if isinstance(obj, float | np.floating):
        x = float(obj)
        return x if math.isfinite(x) else None
    return obj
