"""Sweeps of the baseline planners (``[planner] method`` other than "krishnan": the ORCA
baselines of :mod:`jaxplan.baselines`): each grid point runs in this process through the
method's own simulation, one after another, and its row is a krishnan run's row (the
same metrics, :func:`jaxplan.sweep.table.csv_row`).

    check_method_grid(config, where)      the grid a baseline can sweep, or SweepError
    run_method_points(config, points, built, write, bar, tally) -> Tally

A baseline has no weights: its grid is seeds and scenarios (one q_obs and one q_lim
value, which it ignores); it runs under the local engine (no Ray task runs it).  A point
whose method refuses its scenario (e.g. RVO2 through pyrvo on a 3-D fleet) gets a row
with success 0 and the error.
"""

from __future__ import annotations

import dataclasses
import time

from jaxplan.config import Config
from jaxplan.sweep.batch import Tally
from jaxplan.sweep.table import csv_row

__all__ = ["MethodGridError", "check_method_grid", "run_method_points"]



class MethodGridError(ValueError):
    """A grid the baseline cannot sweep (raised as the sweep's SweepError)."""


def check_method_grid(config: Config, engine: str) -> None:
    """Raise MethodGridError where ``config``'s grid or ``engine`` does not suit its
    baseline method (see the module docstring)."""
    method = config.planner.method
    sw = config.sweep
    if len(sw.q_obs) > 1 or len(sw.q_lim) > 1:
        raise MethodGridError(f"[planner] method = {method!r} has no weights: sweep seeds "
                              "or scenarios only ([sweep] q_obs and q_lim: one value each)")
    if engine != "local":
        raise MethodGridError(f"[planner] method = {method!r} sweeps run under the local "
                              f"engine only, not {engine!r}")


def run_point(config: Config, scenario) -> tuple[dict, float, float]:
    """One baseline run of ``scenario``: (metrics.json's dict, compile seconds, run
    seconds)."""
    from jaxplan.experiment import run_method

    res = run_method(config, scenario)
    return res.metrics, float(res.metrics.get("compile_s") or 0.0), res.run_s


def run_method_points(config: Config, points, built: dict, write, bar, tally: Tally) -> Tally:
    """Run ``points`` (:class:`jaxplan.sweep.points.SweepPoint`; ``built`` maps
    (scenario name, seed) to its Scenario) one after another, writing each row as it is
    done (``write``), counting its seconds in ``tally`` (compile_s: a JAX method's
    compilations, run_s: the simulations)."""
    bar.start()
    for p in points:
        sc = built[(p.scenario, p.seed)]
        cfg = dataclasses.replace(config, seed=int(p.seed))
        t0 = time.perf_counter()
        try:
            metrics, compile_s, run_s = run_point(cfg, sc)
            row = csv_row(p, metrics, sc.num_waypoints)
        except ValueError as e:  # the method refuses the scenario: a row says why
            compile_s, run_s = 0.0, time.perf_counter() - t0
            row = csv_row(p, None, error=str(e).replace("\n", " "))
        tally.compile_s += compile_s
        tally.run_s += run_s
        tally.batches += 1
        write([row])
        bar.update(1)
    return tally
