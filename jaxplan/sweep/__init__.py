"""Weight x seed x scenario sweeps, batched and resumable (`jaxplan sweep`;
docs/DESIGN.md "A sweep directory", docs/SWEEPS.md), and the batch program `jaxplan
tune` runs its trials through.

    run_sweep(config, out_dir, ...) -> SweepResult      run or resume a [sweep] grid
    merge_shards(config, out_dir, ...) -> SweepResult   shard CSVs -> sweep.csv
    rerun_row(sweep_dir, row, out=None, ...) -> RerunResult   a row as a run directory
    sweep_points(config) -> [SweepPoint]                the whole grid, in run order
    read_sweep_csv(path), best_setting(path), COLUMNS   sweep.csv

Modules: engines.py (the command: the local engine, shards and their merge, resuming,
the summary), points.py (the grid's points and scenarios), batch.py (grid points run in
this process: the grid's padding, on a CPU one one-run program per run, the rows; both
engines, `jaxplan tune` and `jaxplan rerun`), rerun.py (`jaxplan rerun`), table.py
(sweep.csv: its columns, its readers, the per-cell grid, the best setting), ray.py
(the Ray engine; Ray imported only when used), guard.py (the config guard of sweep and
tune directories, the behaviour revision).
"""

from __future__ import annotations

from jaxplan.sweep.batch import (
    BatchRunner,
    CompileCounter,
    Tally,
    csv_row,
    grid_kinds,
    pad_robots,
    structure_for,
    with_weights,
)
from jaxplan.sweep.engines import (
    BATCH_ENV,
    DEFAULT_BATCH,
    DEFAULT_BATCH_CPU,
    SweepResult,
    merge_shards,
    parse_shard,
    run_sweep,
    shard_csv_name,
)
from jaxplan.sweep.guard import BEHAVIOUR_REVISION, check_revision, guard_config, stamped
from jaxplan.sweep.points import (
    ScenarioSource,
    SweepPoint,
    build_scenarios,
    scenario_sources,
    sweep_points,
)
from jaxplan.sweep.rerun import RerunResult, rerun_row
from jaxplan.sweep.table import (
    COLUMNS,
    KEY_COLUMNS,
    CsvInfo,
    SweepError,
    best_setting,
    csv_text,
    make_key,
    read_sweep_csv,
    read_sweep_rows,
    row_key,
)

__all__ = [
    "BATCH_ENV",
    "BEHAVIOUR_REVISION",
    "COLUMNS",
    "DEFAULT_BATCH",
    "DEFAULT_BATCH_CPU",
    "KEY_COLUMNS",
    "BatchRunner",
    "RerunResult",
    "CompileCounter",
    "CsvInfo",
    "ScenarioSource",
    "SweepError",
    "SweepPoint",
    "SweepResult",
    "Tally",
    "best_setting",
    "build_scenarios",
    "check_revision",
    "csv_row",
    "csv_text",
    "grid_kinds",
    "guard_config",
    "make_key",
    "merge_shards",
    "pad_robots",
    "parse_shard",
    "read_sweep_csv",
    "read_sweep_rows",
    "rerun_row",
    "row_key",
    "run_sweep",
    "scenario_sources",
    "shard_csv_name",
    "stamped",
    "structure_for",
    "sweep_points",
    "with_weights",
]
