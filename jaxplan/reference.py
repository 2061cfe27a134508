"""Reference solver: NLopt LD_SLSQP (the paper's solver) on the identical NLP.

Same variables x = (z, log T), objective :func:`jaxplan.nlp.objective`, inequality
constraints :func:`jaxplan.nlp.constraints` (as -g <= 0), bound T >= t_min; values
and gradients from the same JAX functions (jitted once per structure and number of
other robots; one jitted call evaluates objective, constraints and both gradients,
cached per x, so each NLopt callback pair costs one dispatch).  The equality
constraints are eliminated exactly by the parametrization for both solvers.

Reported beside the result: evaluations, wall time and the time spent inside the JAX
callbacks, so a comparison is not flattered by callback overhead.
"""

from __future__ import annotations

import functools
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import nlopt
import numpy as np

from jaxplan import nlp
from jaxplan.nlp import NLPParams, NLPStructure


class SLSQPResult(NamedTuple):
    x: np.ndarray
    objective: float
    ineq_violation: float
    converged: bool  # NLopt reported success (ftol / xtol reached), finite result
    nlopt_code: int
    evaluations: int
    wall_s: float  # the solve (opt.optimize), evaluator compilation excluded
    callback_s: float  # of wall_s, time spent in the JAX objective / constraint callbacks


@functools.cache
def _evaluator(structure: NLPStructure):
    def ev(x, params):
        f, gf = jax.value_and_grad(nlp.objective)(x, params, structure)
        gfun = lambda xx: jnp.concatenate(
            [jnp.ravel(a) for a in nlp.constraints(xx, params, structure)])
        g = gfun(x)
        J = jax.jacfwd(gfun)(x)
        return f, gf, g, J

    return jax.jit(ev)


def solve_slsqp(params: NLPParams, x0, structure: NLPStructure, *, ftol_rel: float = 1e-10,
                xtol_rel: float = 1e-10, maxeval: int = 1000, tau_max: float = np.log(1e3),
                maxtime: float = 30.0,
                tol_feasibility: float = 1e-8) -> SLSQPResult:
    """Solve one NLP (unbatched params) with NLopt LD_SLSQP from x0."""
    ev = _evaluator(structure)
    x0 = np.asarray(x0, np.float64)
    n = x0.size
    cache = {"x": None}
    stats = {"n": 0, "t": 0.0}

    def evaluate(x):
        if cache["x"] is None or not np.array_equal(cache["x"], x):
            t0 = time.perf_counter()
            f, gf, g, J = jax.device_get(ev(jnp.asarray(x), params))
            stats["t"] += time.perf_counter() - t0
            stats["n"] += 1
            cache.update(x=x.copy(), f=float(f), gf=np.asarray(gf), g=np.asarray(g),
                         J=np.asarray(J))
        return cache

    def fobj(x, grad):
        c = evaluate(x)
        if grad.size:
            grad[:] = c["gf"]
        return c["f"] if np.isfinite(c["f"]) else 1e300

    def fcon(result, x, grad):
        c = evaluate(x)
        result[:] = -c["g"]
        if grad.size:
            grad[:] = -c["J"]

    m = evaluate(x0)["g"].size
    opt = nlopt.opt(nlopt.LD_SLSQP, n)
    opt.set_min_objective(fobj)
    opt.add_inequality_mconstraint(fcon, np.full(m, tol_feasibility * 0.1))
    lb = np.full(n, -np.inf)
    ub = np.full(n, np.inf)
    tmin = float(params.t_min)
    lb[-1] = np.log(tmin)
    ub[-1] = max(tau_max, lb[-1] + 1.0)
    opt.set_lower_bounds(lb)
    opt.set_upper_bounds(ub)
    opt.set_ftol_rel(ftol_rel)
    opt.set_xtol_rel(xtol_rel)
    opt.set_maxeval(maxeval)
    # a wall-clock guard: NLopt's SLSQP was seen here to loop for hours on one problem
    opt.set_maxtime(maxtime)
    x0c = np.clip(x0, lb, ub)
    # callback time counted inside the timed solve only (the evaluation of x0 above
    # includes the evaluator's compilation on its first call)
    cb0 = stats["t"]
    t0 = time.perf_counter()
    try:
        x = opt.optimize(x0c)
        code = opt.last_optimize_result()
    except Exception:  # NLopt raises RoundoffLimited / runtime_error on failure
        x = cache["x"] if cache["x"] is not None else x0c
        code = -4
    wall = time.perf_counter() - t0
    callback_s = stats["t"] - cb0
    c = evaluate(np.asarray(x))
    viol = float(np.max(np.maximum(-c["g"], 0.0), initial=0.0))
    ok = (code > 0 and code not in (nlopt.MAXEVAL_REACHED, nlopt.MAXTIME_REACHED)
          and np.isfinite(c["f"]))
    return SLSQPResult(np.asarray(x), c["f"], viol, bool(ok), int(code), stats["n"], wall,
                       callback_s)
