"""`jaxplan bench predict`: closed-form predictions per second.

1,000,000 random (state, goal) pairs (moving starts, half free ends, half fully defined
ends), jitted, after warm-up, median over repeats, split over one thread per core (and
on one thread, reported beside it); and in the same run a plain
NumPy loop that picks the least-cost positive root with ``numpy.roots`` per pair on a
subsample, with the ratio and the largest disagreement in T.
"""

from __future__ import annotations

import os
import time
from concurrent.futures import ThreadPoolExecutor

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.benchmarks.common import machine, median, time_calls, write_json
from jaxplan.predict import predict_arrays


def _inputs(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    p0 = rng.uniform(-5, 5, size=(n, 3))
    pf = rng.uniform(-5, 5, size=(n, 3))
    v0 = rng.normal(scale=1.0, size=(n, 3))
    a0 = rng.normal(scale=1.0, size=(n, 3))
    vf = np.zeros((n, 3))
    af = np.zeros((n, 3))
    full = rng.integers(0, 2, size=n).astype(bool)
    return p0, v0, a0, pf, vf, af, full


def numpy_reference(p0, v0, a0, pf, vf, af, full, w=1.0):
    """Per-pair NumPy loop: sextic coefficients, numpy.roots, least-cost positive root."""
    out = np.empty(len(p0))
    for i in range(len(p0)):
        D = pf[i] - p0[i]
        v, a, V, A = v0[i], a0[i], vf[i], af[i]
        if full[i]:
            q = [
                np.sum(720 * D * D),
                np.sum(-720 * (v + V) * D),
                np.sum(3 * (64 * v * v + 112 * v * V + 64 * V * V - 40 * (a - A) * D)),
                np.sum(24 * (3 * a * v + 2 * a * V - 2 * A * v - 3 * A * V)),
                np.sum(3 * (3 * a * a - 2 * a * A + 3 * A * A)),
            ]
        else:
            q = [np.sum(20 * D * D), np.sum(-40 * D * v), np.sum(20 * (v * v - D * a)),
                 np.sum(20 * v * a), np.sum(5 * a * a)]
        coeffs = [w, 0.0] + [-(5 - k) * q[k] for k in (4, 3, 2, 1, 0)]  # highest first
        r = np.roots(coeffs)
        r = r[(np.abs(r.imag) <= 1e-9 * np.abs(r)) & (r.real > 0)].real
        if len(r) == 0:
            out[i] = 0.0
            continue
        J = w * r + sum(q[k] * r ** (k - 5) for k in range(5))
        out[i] = r[np.argmin(J)]
    return out


def run(json_path=None, n: int = 1_000_000, n_reference: int = 2000, repeats: int = 5,
        threads: int | None = None) -> dict:
    """Run the benchmark; print a table; optionally write JSON. Returns the figures.

    XLA:CPU runs one elementwise program on one core, so the batch is split into
    ``threads`` equal chunks (default: one per CPU core) dispatched from as many Python
    threads at once (JAX releases the GIL while a program runs); the single-thread figure
    is reported beside it.
    """
    threads = threads or os.cpu_count() or 1
    args = _inputs(n)
    dev = [jnp.asarray(x) for x in args]
    fn = jax.jit(lambda *a: predict_arrays(*a, 1.0))
    chunk = -(-n // threads)
    parts = [[x[i * chunk:(i + 1) * chunk] for x in dev] for i in range(threads)]
    t0 = time.perf_counter()
    compiled = fn.lower(*dev).compile()
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    compiled_part = fn.lower(*parts[0]).compile() if threads > 1 else compiled
    compile_s += time.perf_counter() - t0
    jax.block_until_ready(compiled(*dev))  # warm-up
    cpu0 = time.process_time()
    times_1 = time_calls(lambda: compiled(*dev), repeats)
    cpu_per_call = (time.process_time() - cpu0) / repeats
    pool = ThreadPoolExecutor(max_workers=threads)

    def threaded():
        futs = [pool.submit(lambda p: jax.block_until_ready(compiled_part(*p)), p)
                for p in parts]
        return [f.result() for f in futs]

    threaded()  # warm-up
    times = time_calls(threaded, repeats) if threads > 1 else times_1
    pool.shutdown()
    med = median(times)
    rate = n / med
    rate_1 = n / median(times_1)

    sub = [x[:n_reference] for x in args]
    t0 = time.perf_counter()
    T_ref = numpy_reference(*sub)
    ref_s = time.perf_counter() - t0
    ref_rate = n_reference / ref_s
    T_jax = np.asarray(compiled(*dev).duration[:n_reference])
    rel = np.abs(T_jax - T_ref) / np.maximum(T_ref, 1e-300)
    res = {
        "benchmark": "predict",
        "pairs": n,
        "compile_s": compile_s,
        "run_s_median": med,
        "run_s_all": times,
        "cpu_s_per_call_single_thread": cpu_per_call,
        "threads": threads,
        "predictions_per_s": rate,
        "predictions_per_s_single_thread": rate_1,
        "numpy_roots_pairs": n_reference,
        "numpy_roots_predictions_per_s": ref_rate,
        "speedup_vs_numpy_roots": rate / ref_rate,
        "max_rel_T_difference_vs_numpy_roots": float(rel.max()),
        "target_predictions_per_s": 2_000_000,
        "machine": machine(),
    }
    print("jaxplan bench predict (float64)")
    print(f"  pairs                       {n:,}")
    print(f"  compile                     {compile_s:8.2f} s")
    print(f"  run, {threads} threads (median of {repeats}) {med:8.3f} s")
    print(f"  predictions / s             {rate:12,.0f}   (target 2,000,000)")
    print(f"  one thread                  {rate_1:12,.0f}   ({cpu_per_call:.3f} s CPU per call)")
    print(f"  numpy.roots loop / s        {ref_rate:12,.0f}   ({n_reference} pairs)")
    print(f"  ratio                       {rate / ref_rate:12,.0f} x")
    print(f"  max |T - T_numpy| / T       {rel.max():12.2e}")
    if json_path:
        write_json(json_path, res)
        print(f"  wrote {json_path}")
    return res
