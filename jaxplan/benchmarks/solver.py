"""`jaxplan bench solver`: the JAX AL-SQP against IPOPT (CasADi) and NLopt SLSQP on the
same NLPs from the same starts.

Run:  python -m jaxplan.benchmarks.solver [--json FILE] [--quick]
(`jaxplan bench solver` calls :func:`run`).

Two NLPs (:func:`nlp_setup`): "product", the one `jaxplan run` solves with the planner's
defaults, built by run_setup.structures and run_setup.fleet_params as the planner
builds it (two quintic segments per axis, 8 coast samples, the default world's ground
z >= 0 as a static row, the default weights, the safety margin, the planner's
prediction weight, iteration cap and tolerance), and "paper", the paper's (one quintic
per axis, no coast, no static row).  For each (:func:`compare`): a 10-robot
antipodal fleet's cold replan and 4 warm replans (the warm start as the planner makes
it: the previous plan shifted and re-fitted, the previous multipliers and penalty), the
JAX fleet solve against IPOPT and SLSQP solving the same NLPs one after another from
the same starts, each timed as medians of the same number of repeats.  One core against
one core: a child process pinned to one CPU (sched_setaffinity), one JAX CPU device and
one XLA thread (:data:`ONE_CORE_ENV`); the whole machine against the whole machine: JAX
in this process (its CPU devices), the references over one process per core.  Also the
100-robot product fleet (every other robot in every NLP), warm, and the figures this
benchmark has always had (``fleet10``, ``slsqp10_*``, ``fleet100``, ``fleet100_k``,
``batch64x10``: the paper's NLP, the whole machine), and ``product.obstacles20``
(:func:`obstacles_row`): the product NLP's 10-robot warm replan among 20 obstacles
against the same fleet and arena without them, its NLPs built by the planner's
:func:`jaxplan.planner.fleet_nlps` (each holding its ``max_static_rows`` nearest rows).
Where the product's warm 10-robot (one core) and 100-robot replans spend their time
(:func:`_time_split`): each lane's evaluations, the pool's steps replayed from them
(solve.pool_steps), and the measured cost of a step, with and without the other robots.

Its fleets come from :mod:`jaxplan.testing` and jaxplan/scenarios/worlds.py.  This module
runs the parts and assembles their figures (the JSON, the printed lines); the parts live
in jaxplan/benchmarks/solver_fleets.py (the NLPs, the fleets and their timings),
jaxplan/benchmarks/solver_refs.py (IPOPT and SLSQP on the same NLPs) and
jaxplan/benchmarks/solver_split.py (where a replan's time goes).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

import jaxplan  # noqa: F401  (float64)
from jaxplan import solve
from jaxplan.benchmarks.solver_fleets import (
    _cold,
    _fleet_cases,
    _fleet_run,
    _paper_settings,
    _planner_nlps,
    _retime,
    _rounds,
    _timed,
    nlp_setup,
)
from jaxplan.benchmarks.solver_refs import _pairs, _ref_cases, _slsqp_serial
from jaxplan.benchmarks.solver_split import _time_split
from jaxplan.nlp import NLPStructure
from jaxplan.testing import antipodal, fleet_params
from jaxplan.world import static_rows

NEIGHBORS_K = 16  # the 100-robot fleet's neighbour count in the max_neighbors variant


# ---------------------------------------------------------------------- product vs paper
# one core: one CPU (the child pins itself), one JAX CPU device, Eigen's single-threaded
# kernels, one OpenMP / BLAS thread for the references (every entry a --flag: XLA reads
# XLA_FLAGS only up to the first word that is not one and silently drops the rest)
ONE_CORE_ENV = {"JAXPLAN_CPU_DEVICES": "1", "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1",
                "XLA_FLAGS_EXTRA": "--xla_cpu_multi_thread_eigen=false"}
WARM_STEPS = 4  # warm replans compared per fleet


def compare(kind: str, reps: int = 3, steps: int = WARM_STEPS, workers: int = 1) -> dict:
    """The 10-robot comparison of one NLP kind in this process (module doc)."""
    # JAX's ``reps`` timings of each replan in rounds (_rounds): before the references,
    # between them, after them
    structure, cases, compile_s, cpu_per_wall = _fleet_cases(kind, 10, 5.0, 0, steps, 1)
    settings = nlp_setup(kind)[1]
    ip = _ref_cases(kind, cases, "ipopt", reps, workers)
    later = [_retime(cases, structure, settings) for _ in range(min(reps - 1, 1))]
    sq = _ref_cases(kind, cases, "slsqp", reps, workers)
    later += [_retime(cases, structure, settings) for _ in range(reps - 1 - len(later))]
    rounds = _rounds(cases, later)
    med = lambda xs: float(statistics.median(xs))
    conv = lambda c: float(np.mean(c["sol"].status == solve.CONVERGED))
    jw = med([c["ms"] for c in cases[1:]])
    out = {
        "nlp": dict(structure.__dict__, n_x=structure.n_x),
        "fleet10": dict(cold_ms=cases[0]["ms"], warm_ms=jw,
                        warm_ms_all=[c["ms"] for c in cases[1:]], compile_s=compile_s,
                        **rounds,
                        cold_conv=conv(cases[0]), warm_conv=med([conv(c) for c in cases[1:]]),
                        cold_iters_max=int(np.max(cases[0]["sol"].iterations)),
                        warm_lane_iters_per_replan=med([int(np.sum(c["sol"].iterations))
                                                        for c in cases[1:]]),
                        warm_iters_max=int(max(np.max(c["sol"].iterations) for c in cases[1:])),
                        status_counts={solve.STATUS_NAMES[k]: int(sum(
                            np.sum(c["sol"].status == k) for c in cases))
                            for k in solve.STATUS_NAMES},
                        cpu_per_wall=cpu_per_wall),
        "repeats": reps, "warm_replans": steps, "workers": workers,
        "loadavg_1min": __import__("os").getloadavg()[0],
    }
    if kind == "product" and workers == 1:  # where the time goes (the product's targets)
        out["fleet10"]["time_split"] = _time_split(structure, nlp_setup(kind)[1], cases[1:],
                                                   reps)
    for name, r in (("ipopt10", ip), ("slsqp10", sq)):
        out[name] = dict(cold_ms=r[0]["ms"], warm_ms=med([x["ms"] for x in r[1:]]),
                         cold_callback_ms=r[0]["callback_ms"],
                         warm_callback_ms=med([x["callback_ms"] for x in r[1:]]),
                         iterations_or_evals_median=med([a[5] for x in r for a in x["per_nlp"]]),
                         **_pairs(cases, r))
    s = out["slsqp10"]
    # SLSQP's own work: its wall time less the time in the JAX callbacks (with several
    # processes: the slowest process's)
    s["cold_algorithm_ms"] = sq[0]["algorithm_ms"]
    s["warm_algorithm_ms"] = med([x["algorithm_ms"] for x in sq[1:]])
    f = out["fleet10"]
    out.update(ratio_vs_ipopt_warm=out["ipopt10"]["warm_ms"] / jw,
               ratio_vs_ipopt_cold=out["ipopt10"]["cold_ms"] / f["cold_ms"],
               ratio_vs_slsqp_warm=s["warm_ms"] / jw,
               ratio_vs_slsqp_cold=s["cold_ms"] / f["cold_ms"],
               ratio_vs_slsqp_algorithm_warm=s["warm_algorithm_ms"] / jw,
               ratio_vs_slsqp_algorithm_cold=s["cold_algorithm_ms"] / f["cold_ms"],
               rel_gap_max=max(out["ipopt10"]["rel_gap_max"], s["rel_gap_max"]),
               cold_over_warm=f["cold_ms"] / jw)
    return out


def _one_core(kind: str, reps: int, steps: int) -> dict:
    """:func:`compare` in a child process on one core (ONE_CORE_ENV)."""
    import os
    import subprocess
    import tempfile

    env = dict(os.environ)
    env.update({k: v for k, v in ONE_CORE_ENV.items() if k != "XLA_FLAGS_EXTRA"})
    env["XLA_FLAGS"] = (env.get("XLA_FLAGS", "") + " " + ONE_CORE_ENV["XLA_FLAGS_EXTRA"]).strip()
    with tempfile.TemporaryDirectory() as d:
        out = os.path.join(d, "r.json")
        subprocess.run([sys.executable, "-m", "jaxplan.benchmarks.solver", "--one-core", kind,
                        "--reps", str(reps), "--steps", str(steps), "--json", out],
                       env=env, check=True)
        with open(out, encoding="utf-8") as fh:
            return json.load(fh)


def _pin_one_cpu() -> int:
    import os

    cpu = min(os.sched_getaffinity(0))
    os.sched_setaffinity(0, {cpu})
    return cpu


def product_and_paper(quick: bool = False) -> dict:
    """The product and paper comparisons: one core against one core (child processes),
    the whole machine against the whole machine, and the 100-robot product fleet."""
    import os

    reps, steps = (2, 2) if quick else (3, WARM_STEPS)
    ncpu = len(os.sched_getaffinity(0))
    out = {}
    # 100 robots, every other robot in every NLP, the product NLP, warm (whole machine):
    # its ``reps`` timings in rounds (_rounds): here, after the 10-robot comparisons,
    # after its time split
    structure, cases, comp, _ = _fleet_cases("product", 100, 15.0, 1, 2, 1)
    settings = nlp_setup("product")[1]
    for kind in ("product", "paper"):
        r = _one_core(kind, reps, steps)
        r["whole_machine"] = compare(kind, reps, steps, workers=ncpu)
        out[kind] = r
    later = [_retime(cases, structure, settings) for _ in range(min(reps - 1, 1))]
    split = _time_split(structure, settings, cases[1:], reps)
    later += [_retime(cases, structure, settings) for _ in range(reps - 1 - len(later))]
    rounds = _rounds(cases, later)
    it = np.concatenate([np.asarray(c["sol"].iterations) for c in cases[1:]])
    out["product"]["fleet100"] = dict(
        cold_ms=cases[0]["ms"], warm_ms=float(statistics.median(c["ms"] for c in cases[1:])),
        compile_s=comp, warm_conv=float(np.mean([np.mean(c["sol"].status == solve.CONVERGED)
                                                 for c in cases[1:]])),
        warm_iters_median=float(np.median(it)), warm_iters_max=int(np.max(it)),
        warm_iters_sum_per_replan=float(it.sum() / len(cases[1:])),
        warm_ms_per_lane_iteration=float(statistics.median(c["ms"] for c in cases[1:]))
        / float(it.sum() / len(cases[1:])), **rounds)
    out["product"]["fleet100"]["time_split"] = split
    return out


OBSTACLES = 20  # the world row: a random_obstacles world of this many obstacles


def obstacles_row(reps: int = 5, steps: int = WARM_STEPS, obstacles: int = OBSTACLES,
                  max_static_rows: int | None = None) -> dict:
    """The 10-robot warm fleet replan of the product NLP in a world with ``obstacles``
    random obstacles (jaxplan/scenarios/worlds.py's random_obstacles, seed 0: its
    starts, goals, arena walls and ceiling) against the same fleet in the same arena
    without them; JAX in this process, the same repeats and warm replans for both.  The
    NLPs are built as the planner builds them (:func:`_planner_nlps`): each holds the
    ``[planner] max_static_rows`` nearest of the world's static rows (``n_static`` of
    ``static_rows``; ``max_static_rows``: instead of the default)."""
    from jaxplan import run_setup
    from jaxplan.config import build_scenario, parse_config

    planner = {} if max_static_rows is None else {"max_static_rows": max_static_rows}
    cfg = parse_config({"name": "bench_obstacles", "seed": 0, "planner": planner,
                        "scenario": {"kind": "random_obstacles", "count": 10,
                                     "obstacles": obstacles}})
    sc = build_scenario(cfg)
    out = {}
    for name, scen in (("with", sc), ("none", sc.with_world(sc.world.with_obstacles([])))):
        R = static_rows(scen.world).mask.shape[0]
        planner = run_setup.structures(cfg, n_static=R,
                                       static_kinds=run_setup.world_kinds(scen.world)).planner
        fp = run_setup.fleet_params(cfg, scen, n_static=R)
        goals = np.asarray(scen.waypoints[:, -1])
        structure, cases, comp, _ = _fleet_cases(
            "product", 10, 0.0, 0, steps, reps, setup=(planner.nlp, fp.settings, {}),
            fleet=(np.asarray(scen.start), goals),
            nlps=_planner_nlps(fp, planner, goals, np.asarray(scen.rest[:, -1])))
        conv = [float(np.mean(c["sol"].status == solve.CONVERGED)) for c in cases[1:]]
        out[name] = dict(n_static=structure.n_static, static_rows=R, compile_s=comp,
                         cold_ms=cases[0]["ms"],
                         warm_ms=float(statistics.median(c["ms"] for c in cases[1:])),
                         warm_ms_all=[c["ms"] for c in cases[1:]],
                         warm_conv=float(np.mean(conv)),
                         warm_iters_sum=[int(np.sum(c["sol"].iterations)) for c in cases[1:]])
    out.update(obstacles=obstacles, repeats=reps, warm_replans=steps,
               max_static_rows=cfg.planner.max_static_rows,
               loadavg_1min=__import__("os").getloadavg()[0],
               warm_ratio=out["with"]["warm_ms"] / out["none"]["warm_ms"])
    return out


def run(quick: bool = False, structure: NLPStructure | None = None, echo: bool = True) -> dict:
    """Run every part of the benchmark (module docstring); print it unless ``echo`` is
    False; return the figures."""
    structure = structure or NLPStructure()
    settings = _paper_settings()
    rng = np.random.default_rng(0)
    res = {"structure": structure.__dict__, "backend": jax.default_backend(),
           "xla_flags": __import__("os").environ.get("XLA_FLAGS", "")}
    steps, reps = (3, 3) if quick else (8, 5)
    r10, cold10, warm10 = _fleet_run(10, 5.0, structure, settings, rng, steps, reps)
    res["fleet10"] = r10
    res["slsqp10_cold"] = _slsqp_serial(cold10, structure)
    res["slsqp10_warm"] = _slsqp_serial(warm10[0], structure)
    res["ratio_cold"] = res["slsqp10_cold"]["ms"] / r10["cold_ms"]
    res["ratio_warm"] = res["slsqp10_warm"]["ms"] / r10["warm_ms"]
    # 100 robots, every other robot in each NLP (cost ~ M^2): few repeats, it is slow
    r100, _, _ = _fleet_run(100, 15.0, structure, settings, np.random.default_rng(1), 2, 1)
    res["fleet100"] = r100
    # the same fleet with each NLP holding its K nearest others ([planner] max_neighbors)
    res["neighbors_k"] = NEIGHBORS_K
    r100k, _, _ = _fleet_run(100, 15.0, structure, settings, np.random.default_rng(1),
                             2 if quick else 4, 2 if quick else 3, max_neighbors=NEIGHBORS_K)
    res["fleet100_k"] = r100k
    # (e) 64 scenarios x 10 robots in one batch
    Ps = []
    for _ in range(64):
        pos, goals = antipodal(10, rng.uniform(4.0, 6.0), rng)
        Ps.append(fleet_params(pos, np.zeros_like(pos), np.zeros_like(pos), goals))
    P = jax.tree.map(lambda *a: jnp.concatenate(a), *Ps)
    t0 = time.perf_counter()
    jax.block_until_ready(_cold(P, structure, settings))
    comp = time.perf_counter() - t0
    sol, ms, (lo, hi) = _timed(lambda P: _cold(P, structure, settings), P,
                               repeats=2 if quick else 7, spread=True)
    # the same run's serial SLSQP rate (10 cold NLPs, (b)) as a reference: a shared
    # machine's speed drifts within minutes (docs/SOLVER.md, "Speed"), and both figures
    # drift with it
    slsqp_rate = 10 / (res["slsqp10_cold"]["ms"] / 1e3)
    rate = 640 / (ms / 1e3)
    res.update(product_and_paper(quick))
    res["product"]["obstacles20"] = obstacles_row(*((2, 2) if quick else (5, WARM_STEPS)))
    res["batch64x10"] = dict(ms=ms, ms_min=lo, ms_max=hi, solves_per_s=rate,
                             solves_per_s_range=[640 / (hi / 1e3), 640 / (lo / 1e3)],
                             slsqp_serial_solves_per_s=slsqp_rate,
                             ratio_vs_slsqp_serial=rate / slsqp_rate,
                             compile_s=comp,
                             converged=float(np.mean(np.asarray(sol.status) == 0)))
    if echo:
        report(res)
        report_product(res)
    return res


def report(res: dict) -> None:
    """Print the benchmark's figures (what `jaxplan bench solver` shows)."""
    f10, f100, b = res["fleet10"], res["fleet100"], res["batch64x10"]
    sc, sw = res["slsqp10_cold"], res["slsqp10_warm"]
    print(f"M=10  cold (guess + solve) {f10['cold_ms']:.1f} ms (conv {f10['cold_conv']:.0%}, "
          f"iters<= {f10['cold_iters']})  "
          f"warm {f10['warm_ms']:.1f} ms median (conv {f10['warm_conv']:.0%})  "
          f"compile {f10['compile_s']:.1f} s")
    print(f"SLSQP serial cold {sc['ms']:.1f} ms ({sc['evaluations']} evals, "
          f"callbacks {sc['callback_ms']:.1f} ms, "
          f"conv {sc['converged']:.0%}) ratio {res['ratio_cold']:.1f}x; "
          f"warm {sw['ms']:.1f} ms ratio {res['ratio_warm']:.1f}x")
    print(f"objective gap (jax - slsqp)/max(1,|slsqp|): cold max {sc['rel_gap_max']:.2e} "
          f"median {sc['rel_gap_median']:.2e}; "
          f"warm max {sw['rel_gap_max']:.2e}; violation jax {sc['jax_max_violation']:.1e} "
          f"slsqp {sc['max_violation']:.1e}")
    print(f"M=100 cold {f100['cold_ms']:.1f} ms warm {f100['warm_ms']:.1f} ms "
          f"(conv {f100['warm_conv']:.0%}) compile {f100['compile_s']:.1f} s")
    if "fleet100_k" in res:
        fk = res["fleet100_k"]
        print(f"M=100, {res['neighbors_k']} nearest others per NLP: cold {fk['cold_ms']:.1f} ms "
              f"(conv {fk['cold_conv']:.0%}) warm {fk['warm_ms']:.1f} ms "
              f"(conv {fk['warm_conv']:.0%}) "
              f"compile {fk['compile_s']:.1f} s")
    print(f"64x10 batch, cold (guess + solve) {b['ms']:.1f} ms -> "
          f"{b['solves_per_s']:.0f} robot-NLP solves/s "
          f"(conv {b['converged']:.0%}) compile {b['compile_s']:.1f} s", flush=True)
    lo, hi = b["solves_per_s_range"]
    print(f"  fastest-slowest timed call {b['ms_min']:.1f}-{b['ms_max']:.1f} ms "
          f"({hi:.0f}-{lo:.0f} solves/s); "
          f"{b['ratio_vs_slsqp_serial']:.0f}x serial SLSQP's "
          f"{b['slsqp_serial_solves_per_s']:.1f} solves/s in this run", flush=True)


def report_product(res: dict) -> None:
    """Print the product / paper comparison."""
    for kind in ("product", "paper"):
        if kind not in res:
            continue
        r = res[kind]
        f, ip, sq = r["fleet10"], r["ipopt10"], r["slsqp10"]
        print(f"{kind} NLP (n_x {r['nlp']['n_x']}), one core: JAX cold {f['cold_ms']:.2f} ms warm "
              f"{f['warm_ms']:.2f} ms (cpu/wall {f['cpu_per_wall']:.2f}); IPOPT cold "
              f"{ip['cold_ms']:.1f} warm {ip['warm_ms']:.1f} ms; SLSQP cold {sq['cold_ms']:.1f} "
              f"warm {sq['warm_ms']:.1f} ms (algorithm {sq['warm_algorithm_ms']:.1f} ms); ratios "
              f"warm: IPOPT {r['ratio_vs_ipopt_warm']:.1f}x, SLSQP algorithm "
              f"{r['ratio_vs_slsqp_algorithm_warm']:.1f}x; gaps IPOPT "
              f"{ip['rel_gap_min']:.1e}..{ip['rel_gap_max']:.1e}, SLSQP "
              f"{sq['rel_gap_min']:.1e}..{sq['rel_gap_max']:.1e}", flush=True)
        w = r.get("whole_machine")
        if w:
            print(f"  whole machine: JAX warm {w['fleet10']['warm_ms']:.2f} ms; IPOPT "
                  f"{w['ratio_vs_ipopt_warm']:.1f}x, SLSQP algorithm "
                  f"{w['ratio_vs_slsqp_algorithm_warm']:.1f}x", flush=True)
    if "product" in res and "fleet100" in res["product"]:
        g = res["product"]["fleet100"]
        print(f"product, 100 robots warm {g['warm_ms']:.1f} ms, iterations per lane median "
              f"{g['warm_iters_median']:.0f} max {g['warm_iters_max']}", flush=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="jaxplan bench solver")
    ap.add_argument("--json", default=None)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--one-core", default=None, help=argparse.SUPPRESS)  # the child
    ap.add_argument("--reps", type=int, default=3, help=argparse.SUPPRESS)
    ap.add_argument("--steps", type=int, default=WARM_STEPS, help=argparse.SUPPRESS)
    ap.add_argument("--product-only", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.one_core:
        cpu = _pin_one_cpu()
        res = compare(a.one_core, a.reps, a.steps)
        res["one_core"] = dict(cpu=cpu, devices=len(jax.devices()),
                               xla_flags=__import__("os").environ.get("XLA_FLAGS", ""))
    elif a.product_only:
        res = product_and_paper(quick=a.quick)
        report_product(res)
    else:
        res = run(quick=a.quick)
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(res, fh, indent=2, default=str)
    return 0


if __name__ == "__main__":
    sys.exit(main())
