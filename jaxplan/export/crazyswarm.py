"""A run's flights as Crazyswarm trajectories (`jaxplan export RUN_DIR --format crazyswarm`).

Crazyswarm's (and Crazyswarm2's) ``uav_trajectory`` CSV: a header row, then one row per
piece with 33 columns, ``duration, x^0..x^7, y^0..y^7, z^0..z^7, yaw^0..yaw^7``: the
piece's duration (s) and its monomial coefficients, lowest power first, in the piece's
own time (seconds from the piece's start).  A Crazyflie keeps at most
:data:`MAX_PIECES` (31) such pieces of degree 7 in its 4 KiB trajectory memory (a piece:
33 float32, 132 bytes), so a robot's executed trajectory, hundreds of replanned pieces
(trajectories.npz's seg_*), is fitted again (:func:`refit`):

- breakpoints chosen adaptively: start with two pieces (Crazyswarm's ``loadcsv`` cannot
  read a file of one row), fit, split at its middle the piece whose position error is
  largest (or where a limit is broken), fit again;
- each fit a least-squares fit of degree-7 polynomials to the executed position,
  velocity and acceleration on the 1 ms grid, under equality constraints (a KKT
  system): C2 at every breakpoint (position, velocity and acceleration continuous), and
  the executed position, velocity and acceleration at both ends (a flight starts and
  ends as the run did: at rest, in a rest-start run);
- accepted when the position error on the 1 ms grid is at most :data:`TOL_M` (1 cm) and
  the refit's peak speed, acceleration and jerk (exact) are at most
  (1 + :data:`LIMIT_SLACK`) x max(limit, the executed pieces' peak).

If midpoint splitting runs out of pieces, 31 equal pieces are tried; a flight that fits
neither way is an :class:`ExportError` naming the robot.  Planar runs fly at a constant
height (``height``, default 1 m); yaw is 0 throughout.  The trajectory's time 0 is the
run's first piece's start (t = 0).

    refit(t, pos, vel, acc, limits, exec_peaks) -> Refit
    refit_robot(run, i) -> Refit                      robot i of a run (RunData)
    write_csv(path, refit, height)                    one robot's CSV
    read_csv(path) -> (durations (P,), coeffs (P, 4, 8))   as Crazyswarm reads it
    evaluate(durations, coeffs, t, derivative=0) -> (K, 4)  as Crazyswarm evaluates it
    export_crazyswarm(run_dir, out_dir, height=1.0) -> report (export.json's content)
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.linalg

from jaxplan.export.common import ExportError, json_safe, read_run, robot_limits, robot_pieces

__all__ = ["MAX_PIECES", "DEGREE", "TOL_M", "CHECK_DT_S", "LIMIT_SLACK", "HEADER", "Refit",
           "refit", "refit_robot", "check_grid", "csv_text", "write_csv", "read_csv", "evaluate",
           "export_crazyswarm", "table"]

MAX_PIECES = 31  # pieces of degree 7 a Crazyflie's 4 KiB trajectory memory holds
DEGREE = 7
TOL_M = 0.01  # m, the largest position error allowed against the executed pieces
CHECK_DT_S = 1e-3  # s, the grid the error is fitted and checked on
LIMIT_SLACK = 0.01  # the refit's peaks may exceed max(limit, executed peak) by this fraction
# Weights of the velocity (s^2) and acceleration (s^4) residuals in the least squares:
# a velocity error of 0.1 m/s, or an acceleration error of 1 m/s^2, counts as 1 cm of
# position error.  Without them the fit is free to swing its acceleration and jerk
# between samples (eight_mixed_transitions: a jerk of 27 m/s^3 where the run's is 5).
W_VEL = 1e-2
W_ACC = 1e-4
MIN_PIECE_S = 0.02  # s: a piece is not split below this
AXES = ("x", "y", "z", "yaw")
HEADER = "duration," + ",".join(f"{a}^{j}" for a in AXES for j in range(DEGREE + 1))
_L = DEGREE + 1
_POW = np.arange(_L)


@dataclass(frozen=True)
class Refit:
    """One robot's refitted flight.

    breaks (P+1,) s from the trajectory's start (breaks[0] = 0); coeffs (P, N, 8)
    monomials in seconds from each piece's start, lowest power first, N = the run's
    dimensions (x, y[, z]); max_error_m: the largest distance on the 1 ms grid to the
    executed pieces; peaks: the refit's exact peak speed, acceleration, jerk (m/s,
    m/s^2, m/s^3); exec_peaks: the executed pieces' (exact); limits: the robot's
    v_max, a_max, j_max; ok: within :data:`TOL_M` and the limits, in at most
    :data:`MAX_PIECES` pieces; problem: what is wrong when not ok, else "".
    """

    breaks: np.ndarray
    coeffs: np.ndarray
    max_error_m: float
    peaks: tuple
    exec_peaks: tuple
    limits: tuple
    ok: bool
    problem: str

    @property
    def pieces(self) -> int:
        return self.coeffs.shape[0]

    @property
    def duration(self) -> float:
        return float(self.breaks[-1] - self.breaks[0])


# ------------------------------------------------------------------------------ the fit


def _basis(s: np.ndarray, d: int) -> np.ndarray:
    """The d-th derivative in s of [s^0, ..., s^7] at s (K,) -> (K, 8)."""
    out = np.zeros((s.size, _L))
    for j in range(d, _L):
        f = np.prod(np.arange(j - d + 1, j + 1, dtype=np.float64))
        out[:, j] = f * s ** (j - d)
    return out


def _fit(breaks, t, pos, vel, acc):
    """The C2 least-squares fit on the pieces ``breaks`` (P+1,) s, in normalized time:
    coefficients (P, N, 8) of s = (t - breaks[p]) / h_p in [0, 1].

    t (K,) s; pos, vel, acc (K, N): the executed trajectory on the grid.  Minimizes
    sum |p - pos|^2 + W_VEL |v - vel|^2 + W_ACC |a - acc|^2 over the grid subject to
    position, velocity and acceleration continuity at the P - 1 inner breakpoints and
    the executed values at both ends (every axis shares the KKT matrix)."""
    P = breaks.size - 1
    h = np.diff(breaks)
    n_dim = pos.shape[1]
    k = np.clip(np.searchsorted(breaks, t, side="right") - 1, 0, P - 1)
    s = (t - breaks[k]) / h[k]
    B = [_basis(s, d) for d in range(3)]
    n = _L * P
    H = np.zeros((n, n))
    g = np.zeros((n, n_dim))
    edges = np.searchsorted(k, np.arange(P + 1))  # t is sorted: piece q's samples
    for q in range(P):
        m = slice(edges[q], edges[q + 1])
        sl = slice(_L * q, _L * (q + 1))
        b0, b1, b2 = B[0][m], B[1][m] / h[q], B[2][m] / h[q] ** 2
        H[sl, sl] = b0.T @ b0 + W_VEL * (b1.T @ b1) + W_ACC * (b2.T @ b2)
        g[sl] = b0.T @ pos[m] + W_VEL * (b1.T @ vel[m]) + W_ACC * (b2.T @ acc[m])
    at0 = [_basis(np.zeros(1), d)[0] for d in range(3)]
    at1 = [_basis(np.ones(1), d)[0] for d in range(3)]
    rows, rhs = [], []
    for d, value in enumerate((pos[0], vel[0], acc[0])):  # the start
        r = np.zeros(n)
        r[:_L] = at0[d] / h[0] ** d
        rows.append(r)
        rhs.append(value)
    for q in range(P - 1):  # C2 joins, each row scaled to the size of a position row
        for d in range(3):
            r = np.zeros(n)
            scale = min(h[q], h[q + 1]) ** d
            r[_L * q:_L * (q + 1)] = at1[d] * (scale / h[q] ** d)
            r[_L * (q + 1):_L * (q + 2)] = -at0[d] * (scale / h[q + 1] ** d)
            rows.append(r)
            rhs.append(np.zeros(n_dim))
    for d, value in enumerate((pos[-1], vel[-1], acc[-1])):  # the end
        r = np.zeros(n)
        r[_L * (P - 1):] = at1[d] / h[-1] ** d
        rows.append(r)
        rhs.append(value)
    A = np.array(rows)
    scale = np.trace(H) / n
    kkt = np.block([[H / scale, A.T], [A, np.zeros((A.shape[0], A.shape[0]))]])
    sol = scipy.linalg.lu_solve(scipy.linalg.lu_factor(kkt, check_finite=False),
                                np.vstack([g / scale, np.array(rhs)]), check_finite=False)
    return sol[:n].reshape(P, _L, n_dim).transpose(0, 2, 1)


def _horner(coeffs, tau):
    """Polynomials coeffs (K, N, L) (lowest power first) at tau (K,) -> (K, N)."""
    y = np.zeros(coeffs.shape[:2])
    for j in range(coeffs.shape[2] - 1, -1, -1):
        y = y * tau[:, None] + coeffs[:, :, j]
    return y


def _derivative(coeffs, d: int):
    """The d-th derivative of monomial coefficients (..., L) -> (..., L) (zero-padded)."""
    c = np.array(coeffs, dtype=np.float64)
    for _ in range(d):
        c = np.concatenate([c[..., 1:] * np.arange(1, c.shape[-1]), np.zeros_like(c[..., :1])],
                           axis=-1)
    return c


def _eval_breaks(breaks, coeffs, t, d=0):
    """Pieces on ``breaks`` with coefficients (P, N, L) in seconds at t (K,): the d-th
    derivative (K, N), and the piece index of each t (K,)."""
    k = np.clip(np.searchsorted(breaks, t, side="right") - 1, 0, breaks.size - 2)
    return _horner(_derivative(coeffs, d)[k], t - breaks[k]), k


def _peaks(breaks, coeffs):
    """Exact peak speed, acceleration and jerk of the pieces (m/s, m/s^2, m/s^3)."""
    from jaxplan.metrics import kinematics

    P = coeffs.shape[0]
    kin = kinematics(np.zeros(P, dtype=np.int64), breaks[:-1], breaks[1:], coeffs, 1)
    return float(kin.max_speed[0]), float(kin.max_acc[0]), float(kin.max_jerk[0])


def _assess(breaks, t, pos, coeffs, allowed):
    """(max error, per-piece badness (P,), problem): badness > 1 where a piece breaks
    the 1 cm tolerance or a limit (the worst ratio); problem "" when none does."""
    P = breaks.size - 1
    y, k = _eval_breaks(breaks, coeffs, t)
    err = np.linalg.norm(y - pos, axis=1)
    bad = np.zeros(P)
    np.maximum.at(bad, k, err / TOL_M)
    max_err = float(err.max())
    problem = "" if max_err <= TOL_M else f"max position error {100 * max_err:.2f} cm > 1 cm"
    peaks = _peaks(breaks, coeffs)
    for d, (name, peak, lim) in enumerate(zip(("speed", "acceleration", "jerk"), peaks,
                                              allowed, strict=True)):
        if not peak > lim:
            continue
        size = np.linalg.norm(_eval_breaks(breaks, coeffs, t, d + 1)[0], axis=1)
        over = np.zeros(P)
        np.maximum.at(over, k, size / lim)
        over[int(np.argmax(over))] = max(over.max(), peak / lim)  # the grid may miss it
        bad = np.maximum(bad, np.where(over > 1.0, 1.0 + over, 0.0))
        problem = problem or f"peak {name} {peak:.3g} > {lim:.3g} allowed"
    return max_err, bad, problem


def _to_seconds(breaks, coeffs_u):
    """Normalized-time coefficients (P, N, 8) -> seconds from each piece's start."""
    return coeffs_u / np.diff(breaks)[:, None, None] ** _POW


def _attempt(breaks, t, pos, vel, acc, allowed):
    coeffs = _to_seconds(breaks, _fit(breaks, t, pos, vel, acc))
    max_err, bad, problem = _assess(breaks, t, pos, coeffs, allowed)
    return coeffs, max_err, bad, problem


def refit(t, pos, vel, acc, limits=(np.nan, np.nan, np.nan), exec_peaks=None,
          max_pieces: int = MAX_PIECES) -> Refit:
    """Refit one robot's trajectory as at most ``max_pieces`` C2 pieces of degree 7.

    Args:
        t: (K,) s, the check grid from the trajectory's start (t[0] = 0), spaced at
            most :data:`CHECK_DT_S`, its last point the end.
        pos, vel, acc: (K, N) m, m/s, m/s^2: the executed trajectory on it.
        limits: the robot's (v_max, a_max, j_max); NaN: none.
        exec_peaks: the executed trajectory's exact (speed, acc, jerk) peaks (default:
            the largest norms on the grid).
        max_pieces: the piece budget.

    Returns:
        a :class:`Refit` (``ok`` False and ``problem`` saying why when no split within
        the budget meets the tolerance and the limits: the attempt with the smallest
        error is returned).
    """
    t = np.asarray(t, dtype=np.float64)
    if exec_peaks is None:
        exec_peaks = tuple(float(np.linalg.norm(a, axis=1).max()) for a in (vel, acc))
        exec_peaks += (np.nan,)
    allowed = tuple((1.0 + LIMIT_SLACK) * float(np.fmax(lim, pk))
                    for lim, pk in zip(limits, exec_peaks, strict=True))
    allowed = tuple(a if np.isfinite(a) else np.inf for a in allowed)
    # two pieces at least: Crazyswarm's loadcsv reads a one-row file as a 1-D array
    breaks = np.array([t[0], 0.5 * (t[0] + t[-1]), t[-1]]) if max_pieces > 1 else \
        np.array([t[0], t[-1]])
    best = None
    while True:
        coeffs, max_err, bad, problem = _attempt(breaks, t, pos, vel, acc, allowed)
        if best is None or (problem == "") or max_err < best[2]:
            best = (breaks, coeffs, max_err, problem)
        h = np.diff(breaks)
        splittable = np.where(h >= 2 * MIN_PIECE_S, bad, -np.inf)
        if problem == "" or breaks.size - 1 >= max_pieces or not np.any(splittable > 1.0):
            break
        q = int(np.argmax(splittable))
        breaks = np.insert(breaks, q + 1, 0.5 * (breaks[q] + breaks[q + 1]))
    if best[3] and max_pieces > 1:  # midpoint splits ran out: equal pieces
        even = np.linspace(t[0], t[-1], max_pieces + 1)
        coeffs, max_err, _, problem = _attempt(even, t, pos, vel, acc, allowed)
        if problem == "" or max_err < best[2]:
            best = (even, coeffs, max_err, problem)
    breaks, coeffs, max_err, problem = best
    return Refit(breaks=breaks - breaks[0], coeffs=coeffs, max_error_m=max_err,
                 peaks=_peaks(breaks, coeffs), exec_peaks=tuple(exec_peaks),
                 limits=tuple(limits), ok=problem == "", problem=problem)


def check_grid(duration: float) -> np.ndarray:
    """The 1 ms grid over [0, duration] (its last point ``duration``), (K,) s."""
    k = max(int(np.ceil(duration / CHECK_DT_S - 1e-9)), 1)
    t = np.minimum(np.arange(k + 1) * CHECK_DT_S, duration)
    t[-1] = duration
    return t


def refit_robot(run, robot: int, limits=None) -> Refit:
    """Robot ``robot`` of a run (:class:`jaxplan.files.RunData`) refitted (:func:`refit`)
    against its executed pieces, from the run's first piece's start (every robot's
    trajectory starts at the same instant; before its own first piece a robot holds
    that piece's start) to its last piece's end."""
    from jaxplan.metrics import kinematics, sample_pieces

    t0, t1, c = robot_pieces(run, robot)
    start, end = float(np.min(run.pieces[1])), float(t1[-1])
    if not end > start:
        raise ExportError(f"{run.run_dir}: robot {robot}: its pieces span no time")
    t = check_grid(end - start)
    ones = np.zeros(t0.size, dtype=np.int64)
    pos, vel, acc = sample_pieces(ones, t0, t1, c, start + t, 1, outside="clamp")
    if t0[0] > start:  # held at rest where it waits for its first piece
        wait = start + t < t0[0]
        vel[0, wait] = 0.0
        acc[0, wait] = 0.0
    kin = kinematics(ones, t0, t1, c, 1)
    if limits is None:
        lim = robot_limits(run)
        limits = tuple(float(lim[key][robot]) for key in ("v_max", "a_max", "j_max"))
    exec_peaks = (float(kin.max_speed[0]), float(kin.max_acc[0]), float(kin.max_jerk[0]))
    return refit(t, pos[0], vel[0], acc[0], limits, exec_peaks)


# ----------------------------------------------------------------------- the CSV file


def _rows(fit: Refit, height: float) -> np.ndarray:
    """The CSV's rows (P, 33): duration, then x, y, z, yaw coefficients (8 each)."""
    P, n_dim, _ = fit.coeffs.shape
    table = np.zeros((P, 4, _L))
    table[:, :n_dim] = fit.coeffs
    if n_dim == 2:
        table[:, 2, 0] = height
    return np.concatenate([np.diff(fit.breaks)[:, None], table.reshape(P, 4 * _L)], axis=1)


def csv_text(fit: Refit, height: float = 1.0) -> str:
    """One robot's CSV (header + a row per piece), numbers written to round-trip."""
    lines = [HEADER]
    lines += [",".join(repr(float(x)) for x in row) for row in _rows(fit, height)]
    return "\n".join(lines) + "\n"


def write_csv(path, fit: Refit, height: float = 1.0) -> Path:
    """Write one robot's CSV (atomically); returns its path."""
    from jaxplan.files import atomic_write_text

    path = Path(path)
    atomic_write_text(path, csv_text(fit, height))
    return path


def read_csv(path):
    """A Crazyswarm trajectory CSV read as ``uav_trajectory.Trajectory.loadcsv`` does
    (``numpy.loadtxt(delimiter=",", skiprows=1, usecols=range(33))``): durations (P,) s
    and coefficients (P, 4, 8) (x, y, z, yaw; seconds from each piece's start)."""
    data = np.loadtxt(path, delimiter=",", skiprows=1, usecols=range(33), ndmin=2)
    return data[:, 0], data[:, 1:].reshape(-1, 4, _L)


def evaluate(durations, coeffs, t, derivative: int = 0) -> np.ndarray:
    """A Crazyswarm trajectory at t (K,) s from its start, as ``Trajectory.eval`` does
    (the piece whose [start, start + duration) holds t; the last one at its end):
    the ``derivative``-th derivative of (x, y, z, yaw), (K, 4)."""
    durations = np.asarray(durations, dtype=np.float64)
    starts = np.concatenate([[0.0], np.cumsum(durations)])
    t = np.asarray(t, dtype=np.float64)
    return _eval_breaks(starts, np.asarray(coeffs, dtype=np.float64), t, derivative)[0]


# ------------------------------------------------------------------------------ export


def export_crazyswarm(run_dir, out_dir=None, height: float | None = None,
                      progress=None) -> dict:
    """Refit every robot of the run in ``run_dir`` and write ``robot_<i>.csv`` per robot
    and export.json into ``out_dir`` (default ``run_dir/crazyswarm``).

    height: m, the constant z of a planar run (default 1.0); only for planar runs.
    progress: called with each robot's report entry as it is done (e.g. to print).
    Returns export.json's content: format, run, out, height, tolerance_m, max_pieces,
    degree, robots[] (robot, vehicle, file, pieces, duration_s, max_error_m, peak_speed,
    peak_acc, peak_jerk, executed_peak_speed, executed_peak_acc, executed_peak_jerk,
    v_max, a_max, j_max).  Raises ExportError naming every robot whose flight does not
    fit in 31 pieces within 1 cm and the limits (nothing is written then).
    """
    from jaxplan.files import atomic_write_text

    run = read_run(run_dir)
    if run.ndim == 3 and height is not None:
        raise ExportError(f"--height {height}: only for planar runs ({run.run_dir} is 3-D)")
    if height is None:
        height = 1.0
    if not (np.isfinite(height) and height > 0):
        raise ExportError(f"--height {height}: must be a positive number of metres")
    out = Path(out_dir) if out_dir is not None else run.run_dir / "crazyswarm"
    limits = robot_limits(run)
    fits, entries, failures = [], [], []
    for i in range(run.num_robots):
        lim = tuple(float(limits[key][i]) for key in ("v_max", "a_max", "j_max"))
        fit = refit_robot(run, i, lim)
        entry = {
            "robot": i, "vehicle": run.vehicle[i], "file": f"robot_{i}.csv",
            "pieces": fit.pieces, "duration_s": fit.duration, "max_error_m": fit.max_error_m,
            "peak_speed": fit.peaks[0], "peak_acc": fit.peaks[1], "peak_jerk": fit.peaks[2],
            "executed_peak_speed": fit.exec_peaks[0], "executed_peak_acc": fit.exec_peaks[1],
            "executed_peak_jerk": fit.exec_peaks[2],
            "v_max": lim[0], "a_max": lim[1], "j_max": lim[2],
        }
        if progress is not None:
            progress(entry)
        if not fit.ok:
            failures.append(f"robot {i} ({run.vehicle[i]}): {fit.problem} with "
                            f"{fit.pieces} pieces")
        fits.append(fit)
        entries.append(entry)
    if failures:
        raise ExportError(f"{run.run_dir}: cannot fit in {MAX_PIECES} pieces of degree "
                          f"{DEGREE} within {100 * TOL_M:g} cm and the limits: "
                          + "; ".join(failures))
    out.mkdir(parents=True, exist_ok=True)
    for i, fit in enumerate(fits):
        write_csv(out / f"robot_{i}.csv", fit, height)
    report = {
        "format": "crazyswarm", "run": str(run.run_dir), "name": run.name, "out": str(out),
        "dimensions": run.ndim, "height_m": height if run.ndim == 2 else None,
        "tolerance_m": TOL_M, "max_pieces": MAX_PIECES, "degree": DEGREE,
        "check_dt_s": CHECK_DT_S, "limit_slack": LIMIT_SLACK, "robots": entries,
    }
    atomic_write_text(out / "export.json",
                      json.dumps(json_safe(report), indent=2, allow_nan=False) + "\n")
    return report


def table(report: dict) -> str:
    """The per-robot table `jaxplan export` prints: pieces, max error, and each peak as
    refit / executed / limit."""
    head = "  ".join(f"{k + ' fit/run/max':>18}" for k in ("speed", "acc", "jerk"))
    lines = [f"{'robot':>5}  {'vehicle':<10} {'pieces':>6}  {'max err cm':>10}  {head}  file"]
    for e in report["robots"]:
        pk = "  ".join(f"{e[f'peak_{k}']:.2f}/{e[f'executed_peak_{k}']:.2f}/{e[lim]:.3g}"
                       .rjust(18) for k, lim in (("speed", "v_max"), ("acc", "a_max"),
                                                 ("jerk", "j_max")))
        lines.append(f"{e['robot']:>5}  {e['vehicle']:<10} {e['pieces']:>6}  "
                     f"{100 * e['max_error_m']:>10.3f}  {pk}  {e['file']}")
    return "\n".join(lines)
