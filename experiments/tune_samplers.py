"""The measurement behind `jaxplan tune`'s default sampler: Optuna's TPE against its
CMA-ES, on a small version of experiments/tune/antipodal_random_box.toml (the same
five weights, ranges, objective, constraints and 20 s runs; training seed 0 only of
both scenarios, no held-out seeds), each sampler with two sampler seeds.  Prints, per
study, the best objective after every batch of trials and the feasible trials; writes
tunes/samplers/samplers.json.

    python experiments/tune_samplers.py [--trials 16]

docs/TUNING.md ("Choosing the sampler") says what has been run of it.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

from jaxplan.cli import _use_compile_cache
from jaxplan.config import load_config
from jaxplan.tune import run_tune

ROOT = Path(__file__).resolve().parent
CONFIG = ROOT / "tune" / "antipodal_random_box.toml"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--trials", type=int, default=16)
    ap.add_argument("--out", type=Path, default=Path("tunes/samplers"))
    args = ap.parse_args()
    _use_compile_cache(False)  # as `jaxplan tune` does: ~/.cache/jaxplan/xla
    base = load_config(CONFIG)
    small = dataclasses.replace(
        base, tune=dataclasses.replace(base.tune, seeds=(0,), holdout_seeds=(),
                                       trials=args.trials))
    results = {}
    for seed in (0, 1):
        for sampler in ("tpe", "cmaes"):
            cfg = dataclasses.replace(small, seed=seed, name=f"{sampler}_{seed}",
                                      tune=dataclasses.replace(small.tune, sampler=sampler))
            t0 = time.perf_counter()
            res = run_tune(cfg, args.out / cfg.name, progress=False, figures=False, echo=None)
            rows = (args.out / cfg.name / "trials.csv").read_text().splitlines()[1:]
            values, feasible = [], 0
            for r in rows:
                cells = r.split(",")
                if cells[1] == "COMPLETE":
                    values.append(float(cells[2 + len(cfg.tune.weights)]))
                    feasible += cells[3 + len(cfg.tune.weights)] == "1"
            best_after = [min(values[:k]) for k in range(cfg.tune.batch, len(values) + 1,
                                                         cfg.tune.batch)]
            results[cfg.name] = {"best_after_each_batch": best_after, "feasible": feasible,
                                 "trials": len(values), "best": res.best,
                                 "wall_s": time.perf_counter() - t0}
            print(f"{cfg.name}: best after each batch of {cfg.tune.batch}: "
                  + " ".join(f"{v:.3f}" for v in best_after)
                  + f"; feasible {feasible}/{len(values)}; "
                  f"{time.perf_counter() - t0:.0f} s", flush=True)
    (args.out / "samplers.json").write_text(json.dumps(results, indent=2) + "\n")


if __name__ == "__main__":
    main()
