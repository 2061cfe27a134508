"""Benchmark studies behind the README's tables: each is a set of resumable sweeps.

    python experiments/studies.py collision [--seeds N] [--out DIR] [--batch B]
    python experiments/studies.py faults    [--seeds N] [--out DIR] [--batch B]
    make studies                                    (both, 20 seeds, into sweeps/studies/)

``collision``: the four collision modes ("paper", "barrier", "constraint",
"barrier+constraint") x the two benchmark fleets (experiments/benchmarks/antipodal_10.toml
and random_box_20.toml), everything else at its default.

``faults``: the same two fleets under each fault of jaxplan.faults alone, at the default
planner settings: 20% message loss; 300 ms latency; sigma = 2 cm noise on the states the
robots receive; robot 0 freezing (silent) at t = 2 s.  "Success" excepts the frozen robot
(it cannot reach its goal); a collision with it still counts.

Each (study, setting, fleet) cell is one `jaxplan sweep` directory under ``--out``, so an
interrupted study resumes where it stopped.  The table (markdown) is printed and written
to ``--out/<study>.md``; the cells' aggregates to ``--out/<study>.json``.  Batches of one
run are the default because on a CPU a vmapped batch runs every lane for as many solver
iterations as its slowest lane needs (measured: 20 antipodal runs took 127 s batched
vs about 90 s one after another).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import statistics
import sys
import time
import tomllib
from pathlib import Path

from jaxplan.config import parse_config
from jaxplan.sweep import run_sweep

ROOT = Path(__file__).resolve().parent
FLEETS = {"antipodal_10": ROOT / "benchmarks" / "antipodal_10.toml",
          "random_box_20": ROOT / "benchmarks" / "random_box_20.toml"}
COLLISION_MODES = ("paper", "barrier", "constraint", "barrier+constraint")
FAULTS = {
    "20% message loss": {"enabled": True, "message_loss": 0.2},
    "300 ms latency": {"enabled": True, "latency_s": 0.3},
    "2 cm state noise": {"enabled": True, "noise_sigma_m": 0.02},
    "one frozen robot": {"enabled": True, "frozen_robot": 0, "frozen_at_s": 2.0,
                         "frozen_mode": "silent"},
}


def _slug(s: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in s).strip("_")


def _cell(base: Path, seeds: int, out: Path, batch: int, *, planner=None, faults=None) -> dict:
    doc = tomllib.loads(base.read_text())
    doc.setdefault("planner", {}).update(planner or {})
    if faults:
        doc["faults"] = dict(faults)
    doc["sweep"] = {"seeds": {"start": 0, "num": seeds}}
    cfg = parse_config(doc, source=str(base))
    res = run_sweep(cfg, out, progress=sys.stderr.isatty(), batch_size=batch, figures=False,
                    echo=None)
    with open(res.csv, newline="") as f:
        rows = list(csv.DictReader(f))
    num = lambda k: [float(r[k]) for r in rows if r[k] not in ("", "nan")]  # noqa: E731
    ms = num("makespan_s")
    return {
        "runs": len(rows),
        "success_rate": statistics.fmean(num("success")),
        "collisions_total": int(sum(num("collisions"))),
        "runs_with_collisions": sum(1 for r in rows if float(r["collisions"]) > 0),
        "min_separation_ratio": min(num("min_separation_ratio"), default=math.nan),
        "makespan_median_s": statistics.median(ms) if ms else None,
        "errors": sum(1 for r in rows if r.get("error")),
        "run_s": res.run_s, "compile_s": res.compile_s,
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("study", choices=("collision", "faults"))
    ap.add_argument("--seeds", type=int, default=20, help="seeds per cell (default 20)")
    ap.add_argument("--out", type=Path, default=Path("sweeps/studies"))
    ap.add_argument("--batch", type=int, default=None,
                    help="runs per compiled batch (default: jaxplan.sweep's, one per CPU device)")
    ap.add_argument("--fleets", nargs="+", choices=tuple(FLEETS), default=tuple(FLEETS))
    ap.add_argument("--only", nargs="+", help="only these settings (mode or fault names)")
    a = ap.parse_args(argv)
    if a.study == "collision":
        settings = {m: {"planner": {"collision": m}} for m in COLLISION_MODES}
        head = "collision mode"
    else:
        settings = {k: {"faults": v} for k, v in FAULTS.items()}
        head = "fault"
    if a.only:
        settings = {k: v for k, v in settings.items() if k in a.only}
    results = {}
    t0 = time.perf_counter()
    for name, kw in settings.items():
        for fleet in a.fleets:
            out = a.out / a.study / f"{_slug(name)}__{fleet}__{a.seeds}seeds"
            print(f"[{time.perf_counter() - t0:7.0f} s] {name} / {fleet} -> {out}", flush=True)
            results[f"{name} | {fleet}"] = _cell(FLEETS[fleet], a.seeds, out, a.batch, **kw)
    lines = [f"| {head} | fleet | runs | success | runs with collisions | collisions "
             "| min separation ratio | median makespan (s) |",
             "|---|---|---|---|---|---|---|---|"]
    for key, r in results.items():
        name, fleet = key.split(" | ")
        mk = "n/a" if r["makespan_median_s"] is None else f"{r['makespan_median_s']:.2f}"
        lines.append(f"| {name} | {fleet} | {r['runs']} | {100 * r['success_rate']:.0f}% | "
                     f"{r['runs_with_collisions']} | {r['collisions_total']} | "
                     f"{r['min_separation_ratio']:.3f} | {mk} |")
    table = "\n".join(lines)
    print(table)
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / f"{a.study}.md").write_text(table + "\n")
    (a.out / f"{a.study}.json").write_text(json.dumps(results, indent=1) + "\n")
    print(f"total {time.perf_counter() - t0:.0f} s; table in {a.out / (a.study + '.md')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
