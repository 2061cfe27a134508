"""sweep.csv: its columns, reading it, and what it says (docs/DESIGN.md "A sweep directory").

    COLUMNS, KEY_COLUMNS                        the header, and the columns that key a row
    make_key(q_obs, q_lim, scenario, seed), row_key(row)   (repr q_obs, repr q_lim, scenario, seed)
    csv_text(rows, header=False) -> str         rows (dicts of strings) as CSV lines
    read_sweep_csv(path) -> (rows, CsvInfo)     complete rows, as strings (for resuming)
    read_sweep_rows(path) -> SweepRows          the analysis columns, typed and checked
    grid(rows, mask) -> Grid                    per-(q_obs, q_lim) cell aggregates
    best_index(grid), best_setting(path), best_summary(grid, index)
    csv_row(point, metrics, n_waypoints, error) -> row   a run's row from its metrics.json

Both readers parse the file the same way (:func:`_read_records`: a trailing line without
its newline, what a kill mid-append leaves, is dropped).  :func:`read_sweep_csv` is the
resuming reader of :mod:`jaxplan.sweep.engines`: it wants exactly :data:`COLUMNS` and drops
malformed and duplicate rows.  :func:`read_sweep_rows` is the analysis reader used by
:func:`best_setting`, the CLI's summary and :func:`jaxplan.plots.plot_sweep`: it needs
at least :data:`ANALYSIS_COLUMNS` and raises ``ValueError("<file>: <column>: <problem>")``
on an unreadable cell.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = [
    "COLUMNS", "KEY_COLUMNS", "ANALYSIS_COLUMNS", "SweepError", "CsvInfo", "SweepRows", "Grid",
    "make_key", "row_key", "csv_text", "read_sweep_csv", "read_sweep_rows", "grid", "best_index",
    "best_setting", "best_summary", "csv_row",
]

KEY_COLUMNS = ("q_obs", "q_lim", "scenario", "seed")
COLUMNS = KEY_COLUMNS + (
    "success", "collisions", "min_separation_ratio", "makespan_s", "mean_time_to_goal_s",
    "reached_frac", "waypoints_frac", "peak_speed_ratio", "converged_frac", "iterations_median",
    "fallbacks_kept_previous", "fallbacks_braking", "fallbacks_best_effort",
    "fallbacks_goal_occupied", "robots", "duration_s", "replans",
    "error",
    "obstacle_collisions", "min_obstacle_clearance_m", "workspace_violations",
    "min_workspace_clearance_m",
    "stalls", "stalled_s", "parked", "makespan_over_bound",
    "settled_makespan_s", "max_goal_departure_m",
    "peak_acc_ratio", "peak_jerk_ratio", "goal_excursion_m", "escape_m",
)
ANALYSIS_COLUMNS = ("q_obs", "q_lim", "scenario", "seed", "success", "min_separation_ratio",
                    "makespan_s", "collisions")
_TRUE = {"1", "1.0", "true", "yes", "y", "t"}
_FALSE = {"0", "0.0", "false", "no", "n", "f"}


class SweepError(ValueError):
    """A sweep that cannot run or resume (one line, naming the file)."""


def make_key(q_obs, q_lim, scenario, seed) -> tuple[str, str, str, str]:
    """The row key of a grid point: the weights as Python's repr (exact round trip)."""
    return (repr(float(q_obs)), repr(float(q_lim)), str(scenario), str(int(seed)))


def row_key(row: dict) -> tuple[str, str, str, str]:
    """The key (repr q_obs, repr q_lim, scenario, seed) of a csv row (a dict of strings)."""
    return make_key(float(row["q_obs"]), float(row["q_lim"]), row["scenario"], int(row["seed"]))


def csv_text(rows: list[dict], header: bool = False) -> str:
    """Rows (dicts of strings keyed by :data:`COLUMNS`; a missing column is empty) as CSV
    lines, each ending in a newline; the header first when ``header``."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    if header:
        w.writerow(COLUMNS)
    for r in rows:
        w.writerow([r.get(c, "") for c in COLUMNS])
    return buf.getvalue()


def _read_records(path: Path) -> tuple[list[list[str]], int]:
    """(the CSV records of the file's complete lines, bytes of a trailing partial line)."""
    data = path.read_bytes()
    end = data.rfind(b"\n") + 1
    text = data[:end].decode("utf-8", errors="replace")
    return list(csv.reader(io.StringIO(text, newline=""))), len(data) - end


# ----------------------------------------------------------------- the resuming reader


@dataclass
class CsvInfo:
    """What :func:`read_sweep_csv` found: complete rows kept, a trailing partial line
    dropped (bytes), malformed or duplicate rows dropped."""

    kept: int = 0
    partial_bytes: int = 0
    malformed: int = 0
    duplicates: int = 0

    @property
    def clean(self) -> bool:
        return not (self.partial_bytes or self.malformed or self.duplicates)


def read_sweep_csv(path, older: bool = False) -> tuple[list[dict], CsvInfo]:
    """The complete rows of a sweep.csv (dicts of strings, first occurrence per key).

    A trailing line without its newline (a kill mid-write) is dropped, and so are rows
    with the wrong number of fields or an unreadable key.  Raises SweepError when the
    header is not :data:`COLUMNS` (``older``: nor a leading part of it, what an earlier
    version wrote, its rows then read with the columns it lacks empty; for reading a
    finished sweep, never for resuming one).  A missing or empty file has no rows.
    """
    path = Path(path)
    info = CsvInfo()
    if not path.exists():
        return [], info
    lines, info.partial_bytes = _read_records(path)
    if not lines:
        return [], info
    header = tuple(lines[0])
    ok = header == COLUMNS or (older and 0 < len(header) and header == COLUMNS[:len(header)])
    if not ok:
        raise SweepError(f"{path}: columns {', '.join(header)} are not this version's "
                         f"({', '.join(COLUMNS)}); use another --out")
    rows, seen = [], set()
    for fields in lines[1:]:
        if len(fields) != len(header):
            info.malformed += 1
            continue
        row = dict(zip(COLUMNS, fields + [""] * (len(COLUMNS) - len(header)), strict=True))
        try:
            k = row_key(row)
        except (ValueError, TypeError):
            info.malformed += 1
            continue
        if k in seen:
            info.duplicates += 1
            continue
        seen.add(k)
        rows.append(row)
    info.kept = len(rows)
    return rows, info


# ----------------------------------------------------------------- the analysis reader


@dataclass(frozen=True)
class SweepRows:
    """sweep.csv as columns (R rows): q_obs, q_lim (R,) floats; scenario (R,) str;
    seed (R,) str; success (R,) bool; min_separation_ratio, makespan_s (R,) floats
    (NaN allowed: a failed run); collisions (R,) floats (NaN allowed)."""

    q_obs: np.ndarray
    q_lim: np.ndarray
    scenario: np.ndarray
    seed: np.ndarray
    success: np.ndarray
    min_separation_ratio: np.ndarray
    makespan_s: np.ndarray
    collisions: np.ndarray


def _err(path, key, problem):
    return ValueError(f"{path}: {key}: {problem}")


def _cell(path, column, text, line):
    """One cell of :data:`ANALYSIS_COLUMNS` as its type (str, bool or float)."""
    s = (text or "").strip()
    if column in ("scenario", "seed"):
        return s
    if column == "success":
        if s.lower() in _TRUE:
            return True
        if s.lower() in _FALSE:
            return False
        raise _err(path, column, f"line {line}: {s!r} is not 0/1/true/false")
    try:
        v = float(s) if s else math.nan
    except ValueError:
        raise _err(path, column, f"line {line}: {s!r} is not a number") from None
    if column in ("q_obs", "q_lim") and not math.isfinite(v):
        raise _err(path, column, f"line {line}: {s!r} must be a finite number")
    return v


def read_sweep_rows(path) -> SweepRows:
    """The :data:`ANALYSIS_COLUMNS` of a sweep.csv (any header holding them), typed.
    Raises ValueError("<file>: <column>: <problem>") on a missing file, column or row, or
    an unreadable cell (naming its line)."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: file not found")
    records, _ = _read_records(path)
    header = [h.strip() for h in (records[0] if records else [])]
    missing = [c for c in ANALYSIS_COLUMNS if c not in header]
    if missing:
        raise _err(path, missing[0], f"column missing (header: {', '.join(header) or 'empty'})")
    if not any(records[1:]):
        raise ValueError(f"{path}: no rows")
    cols = {c: [] for c in ANALYSIS_COLUMNS}
    for line, fields in enumerate(records[1:], start=2):
        if not fields:  # a blank line
            continue
        row = dict(zip(header, fields, strict=False))
        for c in ANALYSIS_COLUMNS:
            cols[c].append(_cell(path, c, row.get(c), line))
    return SweepRows(**{c: np.asarray(v) for c, v in cols.items()})


# ------------------------------------------------------------------ the weight grid


@dataclass(frozen=True)
class Grid:
    """Aggregates per (q_obs, q_lim) cell of some rows (A q_obs values, B q_lim values)."""

    q_obs: np.ndarray  # (A,)
    q_lim: np.ndarray  # (B,)
    success: np.ndarray  # (A, B) rate in [0, 1]; NaN where no run
    min_sep: np.ndarray  # (A, B) worst over runs
    makespan: np.ndarray  # (A, B) mean over successful runs; NaN if none
    collisions: np.ndarray  # (A, B) mean per run
    runs: np.ndarray  # (A, B) int


def grid(rows: SweepRows, mask) -> Grid:
    """The :class:`Grid` of the rows selected by ``mask`` (R,) bool, over every q_obs and
    q_lim value of all rows."""
    qo = np.unique(rows.q_obs)
    ql = np.unique(rows.q_lim)
    shape = (qo.size, ql.size)
    g = {k: np.full(shape, np.nan) for k in ("success", "min_sep", "makespan", "collisions")}
    runs = np.zeros(shape, dtype=int)
    for a, vo in enumerate(qo):
        for b, vl in enumerate(ql):
            sel = mask & (rows.q_obs == vo) & (rows.q_lim == vl)
            runs[a, b] = int(sel.sum())
            if not runs[a, b]:
                continue
            g["success"][a, b] = rows.success[sel].mean()
            ms = rows.min_separation_ratio[sel]
            ms = ms[~np.isnan(ms)]
            if ms.size:
                g["min_sep"][a, b] = ms.min()
            ok = sel & rows.success & np.isfinite(rows.makespan_s)
            if ok.any():
                g["makespan"][a, b] = rows.makespan_s[ok].mean()
            co = rows.collisions[sel]
            co = co[~np.isnan(co)]
            if co.size:
                g["collisions"][a, b] = co.mean()
    return Grid(qo, ql, runs=runs, **g)


def best_index(g: Grid):
    """(a, b) of the best cell: highest success, then fewest collisions, then largest
    min separation ratio, then shortest makespan; ties -> smallest q_obs, then q_lim."""

    def val(x, worst):
        return worst if np.isnan(x) else float(x)

    best, key_best = None, None
    for a in range(g.q_obs.size):
        for b in range(g.q_lim.size):
            if g.runs[a, b] == 0:
                continue
            key = (
                -val(g.success[a, b], 0.0),
                val(g.collisions[a, b], math.inf),
                -val(g.min_sep[a, b], -math.inf),
                val(g.makespan[a, b], math.inf),
            )
            if key_best is None or key < key_best:
                best, key_best = (a, b), key
    return best


def best_setting(sweep_csv_path) -> dict:
    """The best (q_obs, q_lim) of a sweep, over all scenarios and seeds.

    Order: highest success rate, then fewest collisions (mean per run), then the
    largest minimum separation ratio (worst over the runs), then the shortest makespan
    (mean over successful runs); remaining ties go to the smallest q_obs, then q_lim.

    Returns: dict(q_obs, q_lim, success_rate, collisions (mean per run),
    min_separation_ratio, makespan_s (NaN if no run succeeded), runs).
    """
    rows = read_sweep_rows(sweep_csv_path)
    g = grid(rows, np.ones(rows.q_obs.size, dtype=bool))
    a, b = best_index(g)
    return dict(
        q_obs=float(g.q_obs[a]),
        q_lim=float(g.q_lim[b]),
        success_rate=float(g.success[a, b]),
        collisions=float(g.collisions[a, b]),
        min_separation_ratio=float(g.min_sep[a, b]),
        makespan_s=float(g.makespan[a, b]),
        runs=int(g.runs[a, b]),
    )


def best_summary(g: Grid, best) -> str:
    """Two lines on the cell ``best`` = (a, b) of ``g``: its weights, then its numbers."""
    a, b = best
    s = f"q_obs={g.q_obs[a]:.3g}, q_lim={g.q_lim[b]:.3g}\n(success {100 * g.success[a, b]:.0f}%"
    if np.isfinite(g.collisions[a, b]):
        s += f", {g.collisions[a, b]:.2g} collisions/run"
    if np.isfinite(g.min_sep[a, b]):
        s += f", min d/ρ {g.min_sep[a, b]:.2f}"
    if np.isfinite(g.makespan[a, b]):
        s += f", makespan {g.makespan[a, b]:.1f} s"
    return s + ")"


# ------------------------------------------------------------------------ a run's row


def _csv_cell(x) -> str:
    """A value as a sweep.csv cell: 1/0 for booleans, repr for floats, empty for None,
    NaN and inf."""
    if x is None:
        return ""
    if isinstance(x, (bool, np.bool_)):
        return "1" if x else "0"
    if isinstance(x, (int, np.integer)):
        return str(int(x))
    x = float(x)
    return repr(x) if math.isfinite(x) else ""


def csv_row(point, metrics: dict | None, n_waypoints: int = 1, error: str = "") -> dict:
    """The sweep.csv row of a run (``point``: its grid point, a
    :class:`jaxplan.sweep.points.SweepPoint`) from its metrics.json dict (None: the run
    failed with ``error``)."""
    row = {"q_obs": repr(float(point.q_obs)), "q_lim": repr(float(point.q_lim)),
           "scenario": point.scenario, "seed": str(point.seed)}
    if metrics is None:
        row.update(success="0", error=error)
        return row
    pr = metrics["per_robot"]
    ttg = [r["time_to_goal_s"] for r in pr if r["reached"] and r["time_to_goal_s"] is not None]
    row.update({
        "success": _csv_cell(bool(metrics["success"])),
        "collisions": _csv_cell(int(metrics["collisions"])),
        "min_separation_ratio": _csv_cell(metrics["min_separation_ratio"]),
        "makespan_s": _csv_cell(metrics["makespan_s"]),
        "mean_time_to_goal_s": _csv_cell(float(np.mean(ttg)) if ttg else None),
        "reached_frac": _csv_cell(float(np.mean([r["reached"] for r in pr]))),
        "waypoints_frac": _csv_cell(float(np.mean([r["waypoints_reached"] for r in pr]))
                               / max(1, n_waypoints)),
        "peak_speed_ratio": _csv_cell(metrics["peak_speed_over_limit"]),
        "converged_frac": _csv_cell(metrics["solver"].get("converged_frac")),
        "iterations_median": _csv_cell(metrics["solver"].get("iterations_median")),
        "fallbacks_kept_previous": _csv_cell(int(metrics["fallbacks"]["kept_previous"])),
        "fallbacks_braking": _csv_cell(int(metrics["fallbacks"]["braking"])),
        "fallbacks_best_effort": _csv_cell(int(metrics["fallbacks"]["best_effort"])),
        "fallbacks_goal_occupied": _csv_cell(int(metrics["fallbacks"].get("goal_occupied", 0))),
        "robots": _csv_cell(int(metrics["robots"])),
        "duration_s": _csv_cell(metrics["duration_s"]),
        "replans": _csv_cell(int(metrics["replans"])),
        "error": error,
        "obstacle_collisions": _csv_cell(int(metrics["obstacle_collisions"])),
        "min_obstacle_clearance_m": _csv_cell(metrics["min_obstacle_clearance_m"]),
        "workspace_violations": _csv_cell(int(metrics["workspace_violations"])),
        "min_workspace_clearance_m": _csv_cell(metrics["min_workspace_clearance_m"]),
        "stalls": _csv_cell(int(metrics.get("stalls", 0))),
        "stalled_s": _csv_cell(metrics.get("stalled_s")),
        "parked": _csv_cell(int(metrics.get("parked", 0))),
        "makespan_over_bound": _csv_cell(metrics.get("makespan_over_bound")),
        "settled_makespan_s": _csv_cell(metrics.get("settled_makespan_s")),
        "max_goal_departure_m": _csv_cell(metrics.get("max_goal_departure_m")),
        "peak_acc_ratio": _csv_cell(metrics.get("peak_acc_ratio")),
        "peak_jerk_ratio": _csv_cell(metrics.get("peak_jerk_ratio")),
        "goal_excursion_m": _csv_cell(metrics.get("goal_excursion_m")),
        "escape_m": _csv_cell(metrics.get("escape_m")),
    })
    return row
