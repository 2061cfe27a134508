"""A tune config's best weights beside its defaults on its held-out seeds, with the
planner as it is now: what `jaxplan tune` does at the end of a study, for weights found
earlier (docs/TUNING.md, "The five-weight study").

    python experiments/tune_reeval.py CONFIG.toml BEST.toml [--json FILE]

BEST.toml: a `[planner]` snippet as `jaxplan tune` writes it (best.toml).  Prints, for
the defaults and the best weights, over all held-out runs and per scenario: median
makespan (a run that did not succeed counting as sim.duration_s), success rate,
collisions, worst min d/rho and peak speed / v_max.
"""

from __future__ import annotations

import argparse
import json
import time
import tomllib
from pathlib import Path

from jaxplan.cli import _use_compile_cache
from jaxplan.config import load_config
from jaxplan.tune import evaluate, trial_stats


def _stats(rows, config) -> dict:
    s = trial_stats(rows, config.tune, config.sim.duration_s)
    s["peak_speed_ratio"] = max(float(r["peak_speed_ratio"]) for r in rows)
    return s


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("config", type=Path)
    ap.add_argument("best", type=Path, help="a [planner] snippet (best.toml)")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    _use_compile_cache(False)  # as `jaxplan tune` does
    config = load_config(args.config)
    best = tomllib.loads(args.best.read_text("utf-8"))["planner"]
    defaults = {k: float(getattr(config.planner, k)) for k in best}
    t0 = time.perf_counter()
    rows = evaluate(config, {"defaults": defaults, "best": best}, config.tune.holdout_seeds,
                    echo=print)
    out = {"wall_s": time.perf_counter() - t0, "best": best}
    for name, mine in rows.items():
        out[name] = {"all": _stats(mine, config)}
        for label in dict.fromkeys(r["scenario"] for r in mine):
            out[name][label] = _stats([r for r in mine if r["scenario"] == label], config)
        for part, s in out[name].items():
            print(f"{name:8s} {part:14s} runs {s['runs']:3d}  median makespan "
                  f"{s['median_makespan_s']:.3f} s  success {100 * s['success_rate']:.1f}%  "
                  f"collisions {s['collisions']}  min d/rho {s['min_separation_ratio']:.3f}  "
                  f"peak speed {s['peak_speed_ratio']:.3f} v_max")
    print(f"{out['wall_s']:.0f} s wall")
    if args.json:
        args.json.write_text(json.dumps(out, indent=2) + "\n")


if __name__ == "__main__":
    main()
