"""The references of `jaxplan bench solver`: IPOPT (CasADi) and NLopt SLSQP solving a
fleet's NLPs one after another from JAX's starts (:func:`_ref_cases`: serially, or over
one process per core), and the objective gaps and violations of each pair
(:func:`_pairs`); :func:`_slsqp_serial` for the benchmark's oldest figures."""

from __future__ import annotations

import statistics
import time

import jax
import numpy as np

import jaxplan  # noqa: F401  (float64)
from jaxplan.benchmarks.solver_fleets import nlp_setup
from jaxplan.reference import solve_slsqp
from jaxplan.testing import index_params


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


def _ref_solve(kind, P, x0s, which):
    """Solve the NLPs of one fleet one after another with a reference: per-NLP (wall s,
    callback s, objective, violation, converged, evaluations)."""
    from jaxplan.reference_casadi import solve_ipopt

    structure, _, _ = nlp_setup(kind)
    out = []
    for i in range(np.shape(x0s)[0]):
        p, x = index_params(P, i), np.asarray(x0s[i])
        if which == "ipopt":
            r = solve_ipopt(p, x, structure)
            out.append((r.wall_s, 0.0, r.objective, r.ineq_violation, r.converged, r.iterations))
        else:
            r = solve_slsqp(p, x, structure)
            out.append((r.wall_s, r.callback_s, r.objective, r.ineq_violation, r.converged,
                        r.evaluations))
    return out


def _ref_job(args):
    kind, P, x0s, which = args
    return _ref_solve(kind, P, x0s, which)


def _ref_cases(kind, cases, which, reps, workers=1):
    """A reference on every case: per case the median over ``reps`` of the fleet's wall
    time (serial sum with one worker; with several, the wall time of the NLPs split over
    ``workers`` processes), and the last repeat's per-NLP results."""
    import concurrent.futures as cf
    import multiprocessing as mp

    res = []
    pool = None
    if workers > 1:
        # spawned: each worker imports this module (and so jaxplan: float64)
        pool = cf.ProcessPoolExecutor(workers, mp.get_context("spawn"))
        host = lambda c: (jax.device_get(c["P"]), np.asarray(c["x0"]))
        for c in cases[:1]:  # build each worker's solvers and evaluators first (untimed)
            P, x0 = host(c)
            list(pool.map(_ref_job, [(kind, P, x0, which)] * workers))
    try:
        for c in cases:
            walls = []
            for _ in range(reps):
                if pool is None:
                    r = _ref_solve(kind, c["P"], c["x0"], which)
                    w = sum(a[0] for a in r)
                    cb = sum(a[1] for a in r)
                    walls.append((w, cb, w - cb))
                else:
                    P, x0 = host(c)
                    parts = np.array_split(np.arange(x0.shape[0]), workers)
                    jobs = [(kind, jax.tree.map(lambda a, ix=ix: a[ix], P), x0[ix], which)
                            for ix in parts]
                    t0 = time.perf_counter()
                    parts_r = list(pool.map(_ref_job, jobs))
                    w = time.perf_counter() - t0
                    r = [a for part in parts_r for a in part]
                    # the work without callbacks: the slowest process's
                    alg = max(sum(a[0] - a[1] for a in part) for part in parts_r)
                    walls.append((w, sum(a[1] for a in r), alg))
            ms = 1e3 * statistics.median(w[0] for w in walls)
            cb = 1e3 * statistics.median(w[1] for w in walls)
            alg = 1e3 * statistics.median(w[2] for w in walls)
            res.append(dict(ms=ms, callback_ms=cb, algorithm_ms=alg, per_nlp=r))
    finally:
        if pool is not None:
            pool.shutdown()
    return res


def _pairs(cases, refs):
    """Objective gaps (JAX - ref) / max(1, |ref|) and violations over every NLP."""
    gaps, vj, vr, conv = [], [], [], []
    for c, r in zip(cases, refs, strict=True):
        for i, (_, _, obj, viol, ok, _) in enumerate(r["per_nlp"]):
            gaps.append((float(c["sol"].objective[i]) - obj) / max(1.0, abs(obj)))
            vj.append(float(c["sol"].ineq_violation[i]))
            vr.append(viol)
            conv.append(ok)
    g = np.asarray(gaps)
    return dict(rel_gap_max=float(np.max(g)), rel_gap_min=float(np.min(g)),
                abs_rel_gap_max=float(np.max(np.abs(g))),
                pairs_gap_over_1e6=int(np.sum(np.abs(g) > 1e-6)), pairs=len(gaps),
                jax_max_violation=float(np.max(vj)), ref_max_violation=float(np.max(vr)),
                ref_converged=float(np.mean(conv)))
