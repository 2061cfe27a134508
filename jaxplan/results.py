"""The run directory (DESIGN.md "A run directory"), written atomically.

Files: config.toml (the fully resolved config), metrics.json, trajectories.npz
(loadable with allow_pickle=False) and figures/.  Every file is written to a temporary
name in the same directory and renamed into place, so a crash never leaves a
half-written file under a final name.  metrics.json is written after config.toml and
trajectories.npz and marks a complete run; the figures come last and can always be
redrawn from those files with ``jaxplan plot RUN_DIR``.
"""

from __future__ import annotations

import contextlib
import glob
import io
import json
import math
import os
import tempfile
from pathlib import Path

import numpy as np

from jaxplan.config import config_to_toml

REQUIRED_NPZ = ("t", "pos", "vel", "acc", "radius", "goal", "vehicle",
                "seg_robot", "seg_t0", "seg_t1", "seg_coeffs")


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` via a temporary file in the same directory + rename.

    The file gets the usual permissions (0666 minus the umask; mkstemp's are 0600), and
    temporary files left by an earlier killed write of the same name are removed."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    for old in path.parent.glob(f".{glob.escape(path.name)}.*.tmp"):
        with contextlib.suppress(OSError):
            old.unlink()
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        umask = os.umask(0)
        os.umask(umask)
        os.fchmod(fd, 0o666 & ~umask)
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def atomic_write_text(path: Path, text: str) -> None:
    atomic_write_bytes(path, text.encode("utf-8"))


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


def write_run(result, out_dir, *, figures: bool = True) -> Path:
    """Write a RunResult (jaxplan.experiment) as a run directory; returns its path."""
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
    if figures:
        from jaxplan.plots import plot_run

        plot_run(out)
    return out


def load_run(run_dir) -> tuple[dict, dict]:
    """(metrics, arrays) of a complete run directory, checked.

    Raises ValueError naming the file when metrics.json is missing (an incomplete run) or
    trajectories.npz lacks a required key or holds non-finite positions.
    """
    run_dir = Path(run_dir)
    mpath = run_dir / "metrics.json"
    if not mpath.exists():
        raise ValueError(f"{mpath}: missing (the run did not finish)")
    metrics = json.loads(mpath.read_text())
    npz = run_dir / "trajectories.npz"
    with np.load(npz, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    for k in REQUIRED_NPZ:
        if k not in arrays:
            raise ValueError(f"{npz}: missing key {k!r}")
    if not np.all(np.isfinite(arrays["pos"])):
        raise ValueError(f"{npz}: pos holds non-finite values")
    return metrics, arrays
