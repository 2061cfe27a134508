"""Run a scenario from Python and read its metrics (what `jaxplan run` does).

Shows: building a Config (from a TOML file, or a tiny built-in 3-robot scenario),
running it closed loop (jaxplan.experiment.run: every robot replans at the replan rate
and flies its plan), reading the metrics (success, collisions, separation, makespan,
each robot's time to goal) and optionally writing the run directory
(config.toml, metrics.json, trajectories.npz) with jaxplan.files and its figures/ with
jaxplan.plots.

Run:  .venv/bin/python examples/run_scenario.py [CONFIG.toml] [--out RUN_DIR]
      e.g. .venv/bin/python examples/run_scenario.py experiments/paper/six_neos.toml
"""

import argparse
import tomllib
from pathlib import Path

import jaxplan  # noqa: F401  (importing jaxplan turns on float64 in JAX)
from jaxplan.config import load_config, parse_config
from jaxplan.experiment import run
from jaxplan.files import write_run
from jaxplan.plots import plot_run

# Two robots swapping places head-on and a third crossing their path (the test suite's
# tiny scenario): runs in a few seconds after compiling.
TINY_TOML = (Path(__file__).resolve().parent / "tiny.toml").read_text()


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("config", nargs="?", default=None, help="TOML config (default: tiny)")
    ap.add_argument("--out", default=None, help="also write the run directory here")
    ap.add_argument("--no-figures", action="store_true", help="with --out: skip figures/")
    args = ap.parse_args(argv)

    # A Config is validated and has every default filled in (ConfigError otherwise).
    if args.config:
        config = load_config(args.config)
    else:
        config = parse_config(tomllib.loads(TINY_TOML), source="tiny.toml")

    result = run(config)  # a RunResult: .metrics (the metrics.json dict), .arrays, ...
    m = result.metrics
    ratio = m["min_separation_ratio"]  # closest approach / sum of radii (> 1: no contact)
    print(f"{m['name']}: success {m['success']}, collisions {m['collisions']}, "
          f"min separation ratio {ratio if ratio is None else round(ratio, 3)}, "
          f"makespan {m['makespan_s']} s (compile {result.compile_s:.1f} s, "
          f"run {result.run_s:.1f} s)")
    for i, r in enumerate(m["per_robot"]):  # time_to_goal_s is None if never reached
        print(f"  robot {i} ({r['vehicle']}): time to goal {r['time_to_goal_s']} s, "
              f"path {r['path_length_m']:.2f} m, max speed {r['max_speed']:.2f} m/s")

    if args.out:
        out = write_run(result, args.out)
        if not args.no_figures:
            plot_run(out)  # figures/, drawn from the files just written
        print(f"wrote {out}")
    return result


if __name__ == "__main__":
    main()
