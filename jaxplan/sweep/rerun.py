"""`jaxplan rerun`: a sweep.csv row re-run as a full run (docs/SWEEPS.md, "A row as a
run").

    rerun_row(sweep_dir, row, out=None, *, figures=True, echo=print) -> RerunResult

``row`` is the row's index in the directory's sweep.csv (0-based, the header not
counted).  The row's grid point runs through the very program the sweep ran it with
(:meth:`jaxplan.sweep.batch.BatchRunner.run_one`: on a CPU every sweep run is its own
one-run program, padded to the grid's robots and static rows), so its metrics are
bitwise the row's; the run directory (:func:`jaxplan.files.write_run`) is written from
its records as `jaxplan run` writes one (metrics.json without replan timings: the
program runs the whole closed loop as one call).  Its config.toml is the sweep's
config with the row's q_obs, q_lim and seed (and, for a ``[sweep] scenarios`` grid, the
row's registry scenario as ``[scenario] kind``).  On an accelerator a sweep runs
vmapped batches, and a row re-run alone is a different program: its metrics agree to
round-off, not bitwise (the result says whether they are equal).
"""

from __future__ import annotations

import dataclasses
import time
import tomllib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from jaxplan.config import Config, ConfigError, build_scenario, config_to_toml, parse_config
from jaxplan.sweep.batch import BatchRunner, csv_row
from jaxplan.sweep.guard import check_revision
from jaxplan.sweep.points import SweepPoint, build_scenarios, sweep_points
from jaxplan.sweep.table import COLUMNS, SweepError, read_sweep_csv, row_key

__all__ = ["RerunResult", "rerun_row"]


@dataclass
class RerunResult:
    """What :func:`rerun_row` did: out (the run directory), point (the row's grid
    point), row (the sweep.csv row), metrics (the run's metrics.json dict), differ (the
    sweep.csv columns whose re-run value differs from the row's; empty: bitwise equal),
    figures (paths)."""

    out: Path
    point: SweepPoint
    row: dict
    metrics: dict
    differ: list[str]
    figures: list


def _sweep_config(sweep_dir: Path) -> Config:
    path = sweep_dir / "config.toml"
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise SweepError(f"{sweep_dir}: no config.toml: not a sweep directory") from None
    check_revision(path, text, "sweep")
    try:
        return parse_config(tomllib.loads(text), source=str(path))
    except (ConfigError, tomllib.TOMLDecodeError) as e:
        raise SweepError(f"{path}: {e}") from None


def _run_config(config: Config, run_config: Config, point: SweepPoint, row: int,
                scenario) -> tuple[Config, str]:
    """The run directory's config: the sweep's, with the row's weights, seed and (for a
    ``[sweep] scenarios`` grid) scenario; and a note when its scenario does not rebuild
    the row's exactly ('' when it does)."""
    planner = dataclasses.replace(run_config.planner, q_obs=float(point.q_obs),
                                  q_lim=float(point.q_lim))
    cfg = dataclasses.replace(run_config, planner=planner, seed=int(point.seed))
    if config.sweep.scenarios:
        doc = tomllib.loads(config_to_toml(cfg))
        doc["scenario"] = {"kind": point.scenario}
        doc.pop("robots", None)
        try:
            cfg = parse_config(doc, source=config.source)
        except ConfigError as e:
            return cfg, f"config.toml's fleet is the sweep's own, not {point.scenario!r} ({e})"
    cfg = dataclasses.replace(cfg, name=f"{config.name}_row{row}")
    try:
        same = _same_scenario(build_scenario(cfg), scenario)
    except (ConfigError, ValueError) as e:
        return cfg, f"config.toml does not build the row's scenario ({e})"
    return cfg, "" if same else ("config.toml's [scenario] does not rebuild the row's "
                                 "scenario exactly (the run directory is the row's)")


def _same_scenario(a, b) -> bool:
    fields = ("start", "waypoints", "radius", "v_max", "a_max", "j_max", "rest", "auto",
              "cooperative")
    return all(np.array_equal(np.asarray(getattr(a, f)), np.asarray(getattr(b, f)))
               for f in fields)


def rerun_row(sweep_dir, row: int, out=None, *, figures: bool = True,
              echo: Callable[[str], None] | None = print) -> RerunResult:
    """Re-run sweep.csv row ``row`` (0-based) of ``sweep_dir`` as a full run into
    ``out`` (default ``SWEEP_DIR/runs/row-ROW``): config.toml, trajectories.npz,
    metrics.json, and the figures and animation unless ``figures`` is False.  Raises
    SweepError for a directory or row it cannot re-run."""
    from jaxplan.experiment import RunResult
    from jaxplan.files import write_run
    from jaxplan.metrics.report import compute_metrics
    from jaxplan.sweep.engines import shape_groups

    say = echo or (lambda s: None)
    sweep_dir = Path(sweep_dir)
    if not sweep_dir.is_dir():
        raise SweepError(f"{sweep_dir}: no such sweep directory")
    config = _sweep_config(sweep_dir)
    rows, _ = read_sweep_csv(sweep_dir / "sweep.csv")
    if not 0 <= row < len(rows):
        raise SweepError(f"{sweep_dir / 'sweep.csv'}: no row {row} (it has {len(rows)} rows, "
                         "numbered from 0)")
    want = rows[row]
    grid = sweep_points(config)
    point = next((p for p in grid if p.key == row_key(want)), None)
    if point is None:
        raise SweepError(f"{sweep_dir / 'sweep.csv'}: row {row} is not a point of the "
                         "directory's [sweep] grid (config.toml): cannot pad it as the sweep did")
    built = build_scenarios(config, grid)
    ((_, m_pad, r_pad),) = shape_groups(config, [point], grid, built)
    say(f"rerun: row {row} of {sweep_dir / 'sweep.csv'}: q_obs = {point.q_obs!r}, q_lim = "
        f"{point.q_lim!r}, scenario {point.scenario}, seed {point.seed}")
    runner = BatchRunner(config, say)
    t0 = time.perf_counter()
    run_config, scenario, records, final = runner.run_one(point, built, m_pad, r_pad)
    run_s = time.perf_counter() - t0 - runner.tally.compile_s
    metrics, arrays = compute_metrics(run_config, scenario, records, final, np.empty(0))
    got = csv_row(point, metrics, scenario.num_waypoints)
    differ = [c for c in COLUMNS if got.get(c, "") != want.get(c, "")]
    cfg, note = _run_config(config, run_config, point, row, scenario)
    metrics.update(name=cfg.name, compile_s=runner.tally.compile_s, run_s=run_s)
    out = Path(out) if out is not None else sweep_dir / "runs" / f"row-{row}"
    write_run(RunResult(cfg, scenario, metrics, arrays, records, runner.tally.compile_s,
                        run_s), out)
    figs = []
    if figures:
        from jaxplan.plots import plot_run

        figs = plot_run(out)
    if note:
        say(f"note: {note}")
    if differ:
        say(f"rerun: {len(differ)} column(s) differ from the sweep row: " + ", ".join(
            f"{c} {want.get(c, '')!r} -> {got.get(c, '')!r}" for c in differ[:6]))
    else:
        say("rerun: every sweep.csv column equal to the row's (bitwise)")
    return RerunResult(out, point, want, metrics, differ, figs)
