"""`jaxplan bench solver`: the JAX AL-SQP against NLopt SLSQP on the same NLPs.

Run:  python -m jaxplan.benchmarks.solver [--json FILE] [--quick]
(the lead wires it as `jaxplan bench solver`: call :func:`main`).

Its problems come from :mod:`jaxplan.testing`.
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
from jaxplan import planner as _planner
from jaxplan import solve
from jaxplan.nlp import NLPStructure
from jaxplan.reference import solve_slsqp
from jaxplan.testing import antipodal, fleet_params, index_params

# ---------------------------------------------------------------------- benchmark
DT = 0.125
NEIGHBORS_K = 16  # the 100-robot fleet's neighbour count in the max_neighbors variant


def _timed(fn, *args, repeats=5, spread=False):
    """(output, median ms) of ``repeats`` timed calls after one untimed; with ``spread``
    also (min ms, max ms)."""
    out = jax.block_until_ready(fn(*args))
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = jax.block_until_ready(fn(*args))
        ts.append(time.perf_counter() - t0)
    med = 1e3 * statistics.median(ts)
    return (out, med, (1e3 * min(ts), 1e3 * max(ts))) if spread else (out, med)


def _cold(P, structure, settings):
    """A cold solve as timed here: the initial guesses (solve.initial_guess) and the
    solve from them, both counted (solve_batch with x0 = None: one compiled program)."""
    return solve.solve_batch(P, None, structure, settings)


def _fleet_run(M, radius_m, structure, settings, rng, steps, repeats, max_neighbors=0):
    """Cold solve, then ``steps`` warm replans 1/8 s apart (ideal tracking)."""
    pos, goals = antipodal(M, radius_m, rng)
    vel = np.zeros_like(pos)
    acc = np.zeros_like(pos)
    P, idx = fleet_params(pos, vel, acc, goals, max_neighbors=max_neighbors, return_neighbors=True)
    t0 = time.perf_counter()
    jax.block_until_ready(_cold(P, structure, settings))
    compile_s = time.perf_counter() - t0
    sol, cold_ms = _timed(lambda P: _cold(P, structure, settings), P, repeats=repeats)
    # the same guesses, for the SLSQP reference's start (untimed)
    x0 = jax.block_until_ready(solve.initial_guess_batch(P, structure))
    cold = dict(P=P, x0=x0, sol=sol)
    warm_ms, warm_conv, warm_iters, warm_cases = [], [], [], []
    ws = jax.jit(jax.vmap(lambda tr, p: solve.warm_start(tr, DT, p, structure)))
    for _ in range(steps):
        tr = sol.traj
        pos, vel, acc = (np.asarray(a) for a in tr.state_at(jnp.full(tr.batch_shape, DT)))
        P, idx_new = fleet_params(pos, vel, acc, goals, max_neighbors=max_neighbors,
                                  return_neighbors=True)
        x0 = ws(tr, P)
        mult = sol.multipliers._replace(
            collision=_planner.remap_slots(sol.multipliers.collision, idx, idx_new))
        idx = idx_new
        fn = lambda P, x0, m, mu: solve.solve_batch(P, x0, structure, settings, m, mu)
        sol, ms = _timed(fn, P, x0, mult, sol.penalty, repeats=repeats)
        warm_ms.append(ms)
        warm_conv.append(float(np.mean(np.asarray(sol.status) == solve.CONVERGED)))
        warm_iters.append(int(np.max(sol.iterations)))
        warm_cases.append(dict(P=P, x0=x0, sol=sol))
    return dict(compile_s=compile_s, cold_ms=cold_ms,
                cold_conv=float(np.mean(np.asarray(cold["sol"].status) == 0)),
                cold_iters=int(np.max(cold["sol"].iterations)), warm_ms=statistics.median(warm_ms),
                warm_ms_all=warm_ms, warm_conv=float(np.mean(warm_conv)),
                warm_iters_max=max(warm_iters)), cold, warm_cases


def _slsqp_serial(case, structure):
    P, x0, sol = case["P"], case["x0"], case["sol"]
    M = x0.shape[0]
    wall = cb = 0.0
    evals = 0
    gaps, viol, conv = [], [], []
    for i in range(M):
        r = solve_slsqp(index_params(P, i), np.asarray(x0[i]), structure)
        wall += r.wall_s
        cb += r.callback_s
        evals += r.evaluations
        conv.append(r.converged)
        viol.append(r.ineq_violation)
        gaps.append((float(sol.objective[i]) - r.objective) / max(1.0, abs(r.objective)))
    return dict(ms=1e3 * wall, callback_ms=1e3 * cb, evaluations=evals,
                converged=float(np.mean(conv)),
                max_violation=float(max(viol)), jax_max_violation=float(np.max(sol.ineq_violation)),
                rel_gap_max=float(max(gaps)), rel_gap_median=float(np.median(gaps)))


def run(quick: bool = False, structure: NLPStructure | None = None, echo: bool = True) -> dict:
    """Run every part of the benchmark (module docstring); print it unless ``echo`` is
    False; return the figures."""
    structure = structure or NLPStructure()
    settings = solve.SolverSettings()
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
                               repeats=2 if quick else 7,  # 0.1-0.2 s each
                               spread=True)
    # the same run's serial SLSQP rate (10 cold NLPs, (b)) as a reference: this machine's
    # speed drifts by up to ~1.7x within minutes, and both figures drift with it
    slsqp_rate = 10 / (res["slsqp10_cold"]["ms"] / 1e3)
    rate = 640 / (ms / 1e3)
    res["batch64x10"] = dict(ms=ms, ms_min=lo, ms_max=hi, solves_per_s=rate,
                             solves_per_s_range=[640 / (hi / 1e3), 640 / (lo / 1e3)],
                             slsqp_serial_solves_per_s=slsqp_rate,
                             ratio_vs_slsqp_serial=rate / slsqp_rate,
                             compile_s=comp,
                             converged=float(np.mean(np.asarray(sol.status) == 0)))
    if echo:
        report(res)
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


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="jaxplan bench solver")
    ap.add_argument("--json", default=None)
    ap.add_argument("--quick", action="store_true")
    a = ap.parse_args(argv)
    res = run(quick=a.quick)
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(res, fh, indent=2, default=str)
    return 0


if __name__ == "__main__":
    sys.exit(main())
