"""The run directory: writing it and reading it back (docs/DESIGN.md "A run directory").

    write_run(result, out_dir) -> Path
    load_run(run_dir, *, complete=False) -> RunData      read and validated

Files: config.toml (the fully resolved config), metrics.json and trajectories.npz
(loadable with allow_pickle=False).  Every file is written atomically
(:mod:`jaxplan.files.durable`), so a crash never leaves a half-written file under a
final name.  metrics.json is written after config.toml and trajectories.npz and marks a
complete run.  The figures (figures/) are drawn from those files by
:func:`jaxplan.plots.plot_run`, which reads the directory with :func:`load_run`: after
:func:`write_run` (``jaxplan run``), or again with ``jaxplan plot RUN_DIR``; writing a
run's files never imports the plots.

Bad input (a missing file or key, a wrong shape, non-finite numbers) makes
:func:`load_run` raise ``ValueError("<file>: <key>: <problem>")``.
"""

from __future__ import annotations

import io
import json
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from jaxplan.files.durable import atomic_write_bytes, atomic_write_text
from jaxplan.world import World, world_from_arrays

__all__ = ["write_run", "load_run", "RunData", "REQUIRED_NPZ"]

_SAMPLE_KEYS = ("t", "pos", "vel", "acc", "radius", "goal", "vehicle")
_PIECE_KEYS = ("seg_robot", "seg_t0", "seg_t1", "seg_coeffs")
REQUIRED_NPZ = _SAMPLE_KEYS + _PIECE_KEYS  # what write_run always writes


# ------------------------------------------------------------------------------ writing


def _clean(obj):
    """JSON-safe: NaN / inf become None (strict JSON has neither), numpy scalars floats."""
    if isinstance(obj, dict):
        return {str(k): _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    if isinstance(obj, (np.bool_, bool)):
        return bool(obj)
    if isinstance(obj, (np.integer, int)):
        return int(obj)
    if isinstance(obj, (np.floating, float)):
        x = float(obj)
        return x if math.isfinite(x) else None
    if isinstance(obj, np.ndarray):
        return _clean(obj.tolist())
    return obj


def write_run(result, out_dir) -> Path:
    """Write a RunResult (jaxplan.experiment) as a run directory: config.toml,
    trajectories.npz, then metrics.json (a previous run's metrics.json is removed first,
    so that the directory is complete only once all three are written); returns its
    path.  The figures are :func:`jaxplan.plots.plot_run`'s."""
    from jaxplan.config import config_to_toml

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    stale = out / "metrics.json"
    if stale.exists():  # a previous run in the same place: it is no longer complete
        stale.unlink()
    atomic_write_text(out / "config.toml", config_to_toml(result.config))
    buf = io.BytesIO()
    np.savez_compressed(buf, **result.arrays)
    atomic_write_bytes(out / "trajectories.npz", buf.getvalue())
    atomic_write_text(out / "metrics.json",
                      json.dumps(_clean(result.metrics), indent=2, allow_nan=False) + "\n")
    return out


# ------------------------------------------------------------------------------ reading


@dataclass(frozen=True)
class RunData:
    """A run directory's data, validated (shapes: M robots, K samples, N = 2 or 3 dims).

    t (K,) s; pos (M, K, N) m; vel (M, K, N) m/s; acc (M, K, N) m/s^2; radius (M,) m;
    goal (M, N) m; vehicle: M names; pieces: (seg_robot (S,), seg_t0 (S,), seg_t1 (S,),
    seg_coeffs (S, N, D+1)) or None; waypoints (M, W, N) m or None; metrics: the parsed
    metrics.json or {}; limits: {"v_max": (M,), "a_max": (M,)} m/s, m/s^2, NaN where
    unknown; name: the run's name (config ``name`` or the folder name); world: the
    :class:`jaxplan.world.World` (unbounded and empty for a run that stored none);
    cooperative: (M,) bool, False for a robot that ran no planner (all True for a run
    that stored none).
    """

    run_dir: Path
    t: np.ndarray
    pos: np.ndarray
    vel: np.ndarray
    acc: np.ndarray
    radius: np.ndarray
    goal: np.ndarray
    vehicle: tuple
    pieces: tuple | None
    waypoints: np.ndarray | None
    metrics: dict
    limits: dict
    name: str
    world: World | None = None
    cooperative: np.ndarray | None = None

    @property
    def num_robots(self) -> int:
        return self.pos.shape[0]

    @property
    def ndim(self) -> int:
        return self.pos.shape[2]


def _err(path, key, problem):
    return ValueError(f"{path}: {key}: {problem}")


def _finite(path, key, a):
    if a.size and not np.all(np.isfinite(a)):
        bad = np.argwhere(~np.isfinite(a))[0]
        idx = tuple(int(b) for b in bad)
        raise _err(path, key, f"non-finite value {a[idx]} at index {idx}")


def _float_array(path, key, raw):
    try:
        return np.asarray(raw, dtype=np.float64)
    except (TypeError, ValueError):
        raise _err(path, key, f"not numeric (dtype {raw.dtype})") from None


def load_run(run_dir, *, complete: bool = False) -> RunData:
    """Read and validate run_dir/trajectories.npz, metrics.json and config.toml (both
    optional unless ``complete``).

    complete: also require what :func:`write_run` always writes: metrics.json (its
        absence means the run did not finish) and the executed pieces (seg_*).
    Raises ValueError("<file>: <key>: <problem>").
    """
    run_dir = Path(run_dir)
    npz = run_dir / "trajectories.npz"
    mpath = run_dir / "metrics.json"
    if complete and not mpath.is_file():
        raise ValueError(f"{mpath}: missing (the run did not finish)")
    raw = _read_npz(npz, REQUIRED_NPZ if complete else _SAMPLE_KEYS)
    t, pos, vel, acc = _samples(npz, raw)
    m, _, n = pos.shape
    radius, goal, vehicle = _fleet(npz, raw, m, n)
    metrics = _read_json(mpath)
    cpath = run_dir / "config.toml"
    config = _read_toml(cpath)
    name = config.get("name") if isinstance(config.get("name"), str) else run_dir.name
    return RunData(
        run_dir=run_dir, t=t, pos=pos, vel=vel, acc=acc, radius=radius, goal=goal,
        vehicle=vehicle, pieces=_pieces(npz, raw, m, n), waypoints=_waypoints(npz, raw, m, n),
        metrics=metrics, limits=_resolve_limits(vehicle, config, metrics, cpath, mpath),
        name=name, world=_world(npz, raw, n), cooperative=_cooperative(npz, raw, m),
    )


def _cooperative(npz: Path, raw: dict, m: int) -> np.ndarray:
    """(M,) bool: the run's ``cooperative`` flags, all True where it stored none."""
    if "cooperative" not in raw:
        return np.ones(m, bool)
    c = np.asarray(raw["cooperative"])
    if c.shape != (m,) or c.dtype != bool:
        raise _err(npz, "cooperative", f"must be (M,) = ({m},) bool; got {c.dtype} {c.shape}")
    return c


def _world(npz: Path, raw: dict, n: int) -> World:
    try:
        return world_from_arrays(raw, n)
    except ValueError as e:
        raise _err(npz, "world", str(e)) from None


def _read_npz(npz: Path, required) -> dict:
    """Every array of the file (no pickled objects), with the ``required`` keys present."""
    if not npz.is_file():
        raise ValueError(f"{npz}: file not found")
    try:
        z = np.load(npz, allow_pickle=False)
    except Exception as e:  # noqa: BLE001  (zip errors, bad magic, ...)
        raise ValueError(f"{npz}: cannot be read as .npz: {e}") from None
    with z:
        keys = set(z.files)
        raw = {}
        for key in sorted(keys):
            try:
                raw[key] = z[key]
            except ValueError:
                raise _err(npz, key, "holds Python objects (needs pickle)") from None
    for key in required:
        if key not in raw:
            raise _err(npz, key, f"missing (the file has {', '.join(sorted(keys)) or 'no keys'})")
    return raw


def _samples(npz: Path, raw: dict):
    """t (K,), pos, vel, acc (M, K, N): finite, t non-decreasing, N = 2 or 3."""
    t = _float_array(npz, "t", raw["t"])
    if t.ndim != 1 or t.size < 1:
        raise _err(npz, "t", f"must be (K,) with K >= 1; got shape {t.shape}")
    _finite(npz, "t", t)
    if np.any(np.diff(t) < 0):
        raise _err(npz, "t", "must be non-decreasing")
    pos = _float_array(npz, "pos", raw["pos"])
    if pos.ndim != 3 or pos.shape[1] != t.size or pos.shape[2] not in (2, 3) or pos.shape[0] < 1:
        raise _err(npz, "pos", f"must be (M, K={t.size}, N) with N = 2 or 3; got {pos.shape}")
    _finite(npz, "pos", pos)
    derivs = []
    for key in ("vel", "acc"):
        a = _float_array(npz, key, raw[key])
        if a.shape != pos.shape:
            raise _err(npz, key, f"must have the shape of pos {pos.shape}; got {a.shape}")
        _finite(npz, key, a)
        derivs.append(a)
    return t, pos, *derivs


def _fleet(npz: Path, raw: dict, m: int, n: int):
    """radius (M,) > 0, goal (M, N), vehicle: M names."""
    radius = _float_array(npz, "radius", raw["radius"])
    if radius.shape != (m,):
        raise _err(npz, "radius", f"must be (M,) = ({m},); got {radius.shape}")
    _finite(npz, "radius", radius)
    if np.any(radius <= 0):
        raise _err(npz, "radius", "must be > 0")
    goal = _float_array(npz, "goal", raw["goal"])
    if goal.shape != (m, n):
        raise _err(npz, "goal", f"must be (M, N) = ({m}, {n}); got {goal.shape}")
    _finite(npz, "goal", goal)
    veh = raw["vehicle"]
    if veh.shape != (m,) or veh.dtype.kind not in "US":
        raise _err(npz, "vehicle", f"must be (M,) = ({m},) strings; got {veh.dtype} {veh.shape}")
    vehicle = tuple(v.decode() if isinstance(v, bytes) else str(v) for v in veh.tolist())
    return radius, goal, vehicle


def _pieces(npz: Path, raw: dict, m: int, n: int):
    """(seg_robot, seg_t0, seg_t1, seg_coeffs) checked, or None when the file has none."""
    present = [k for k in _PIECE_KEYS if k in raw]
    if not present:
        return None
    missing = [k for k in _PIECE_KEYS if k not in raw]
    if missing:
        raise _err(npz, missing[0], f"missing while {', '.join(present)} present")
    r = raw["seg_robot"]
    t0 = _float_array(npz, "seg_t0", raw["seg_t0"])
    t1 = _float_array(npz, "seg_t1", raw["seg_t1"])
    co = _float_array(npz, "seg_coeffs", raw["seg_coeffs"])
    s = r.shape[0] if r.ndim == 1 else -1
    if r.ndim != 1 or r.dtype.kind not in "iu":
        raise _err(npz, "seg_robot", f"must be (S,) integers; got {r.dtype} {r.shape}")
    if r.size and (r.min() < 0 or r.max() >= m):
        raise _err(npz, "seg_robot", f"robot indices must lie in [0, {m})")
    for key, a in (("seg_t0", t0), ("seg_t1", t1)):
        if a.shape != (s,):
            raise _err(npz, key, f"must be (S,) = ({s},); got {a.shape}")
        _finite(npz, key, a)
    if co.ndim != 3 or co.shape[:2] != (s, n) or co.shape[2] < 1:
        raise _err(npz, "seg_coeffs", f"must be (S, N, D+1) = ({s}, {n}, D+1); got {co.shape}")
    _finite(npz, "seg_coeffs", co)
    return r.astype(np.int64), t0, t1, co


def _waypoints(npz: Path, raw: dict, m: int, n: int):
    """waypoints (M, W, N), NaN rows allowed (padding for robots with fewer), or None."""
    if "waypoints" not in raw:
        return None
    w = _float_array(npz, "waypoints", raw["waypoints"])
    if w.ndim != 3 or w.shape[0] != m or w.shape[2] != n:
        raise _err(npz, "waypoints", f"must be (M, W, N) = ({m}, W, {n}); got {w.shape}")
    return w


def _read_json(path: Path) -> dict:
    """The JSON object in ``path``, or {} when there is no such file."""
    if not path.is_file():
        return {}
    try:
        obj = json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise ValueError(f"{path}: not valid JSON: {e}") from None
    if not isinstance(obj, dict):
        raise ValueError(f"{path}: must hold a JSON object")
    return obj


def _read_toml(path: Path) -> dict:
    """The TOML document in ``path``, or {} when there is no such file."""
    if not path.is_file():
        return {}
    try:
        return tomllib.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise ValueError(f"{path}: not valid TOML: {e}") from None


def _limit_value(table, key, path, where):
    if not isinstance(table, dict) or table.get(key) is None:
        return None
    v = table[key]
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or v <= 0:
        raise _err(path, f"{where}{key}", f"must be a positive number; got {v!r}")
    return float(v)


def _resolve_limits(vehicle, config, metrics, cpath, mpath):
    """Per-robot v_max, a_max: config [limits], else metrics.json (limits.* or top level),
    else the vehicle table; NaN where none is known (an unknown vehicle name)."""
    from jaxplan.vehicles import ROBOTS

    out = {}
    for key in ("v_max", "a_max"):
        v = _limit_value(config.get("limits"), key, cpath, "limits.")
        if v is None:
            v = _limit_value(metrics.get("limits"), key, mpath, "limits.")
        if v is None:
            v = _limit_value(metrics, key, mpath, "")
        if v is not None:
            out[key] = np.full(len(vehicle), v)
        else:
            out[key] = np.array(
                [getattr(ROBOTS[name], key) if name in ROBOTS else np.nan for name in vehicle]
            )
    return out
