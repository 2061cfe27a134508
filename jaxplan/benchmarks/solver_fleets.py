"""The fleets `jaxplan bench solver` times, and how it times them.

The two NLPs (:func:`nlp_setup`): "product", the one `jaxplan run` solves with the
planner's defaults (:func:`_planner_setup`, :func:`_product_config`), and "paper", the
paper's (:func:`_paper_settings`).  An antipodal fleet's cold replan and warm replans
1/8 s apart as the planner makes them (:func:`_fleet_cases`; its NLPs built as
jaxplan.testing builds them, :func:`_testing_nlps`, or the planner's way,
:func:`_planner_nlps`), each call timed as a median (:func:`_timed`; :func:`_cold`,
:func:`_warm`), then timed again in later rounds (:func:`_retime`) whose medians make the
figures (:func:`_rounds`).  The benchmark's oldest figures, the paper NLP's fleets on the
whole machine: :func:`_fleet_run`.
"""

from __future__ import annotations

import functools
import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np

import jaxplan  # noqa: F401  (float64)
from jaxplan import planner as _planner
from jaxplan import solve
from jaxplan.nlp import Limits, NLPStructure
from jaxplan.testing import antipodal, fleet_params
from jaxplan.world import static_rows

DT = 0.125  # s between replans (8 Hz)
PAPER_MAX_ITERS = 60


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


def _warm(P, x0, mult, mu, structure, settings):
    """A warm replan as timed here: solve_batch from warm starts, marked as the planner
    marks them (SolverSettings.warm_convex_step), with the previous multipliers and
    penalty."""
    return solve.solve_batch(P, x0, structure, settings, mult, mu, warm=True)


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
        fn = lambda P, x0, m, mu: _warm(P, x0, m, mu, structure, settings)
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


def _planner_setup(config, scenario=None):
    """(structure, settings, fleet_params keywords) of the NLPs `jaxplan run` builds for
    ``config`` (its scenario, or ``scenario``): run_setup.structures and
    run_setup.fleet_params, so the static rows (the ground in 3-D, the obstacles and
    workspace faces of a world) are the planner's.  One vehicle's radius and limits
    (the first robot's) stand for the fleet's."""
    from jaxplan import run_setup
    from jaxplan.config import build_scenario

    sc = scenario if scenario is not None else build_scenario(config)
    n_static = static_rows(sc.world).mask.shape[0]
    st = run_setup.structures(config, n_static=n_static,
                              static_kinds=run_setup.world_kinds(sc.world)).planner.nlp
    fp = run_setup.fleet_params(config, sc, n_static=n_static)
    first = lambda a: float(np.asarray(a).reshape(-1)[0])
    kw = dict(w=fp.weights, lim=Limits(*(first(a) for a in fp.limits)),
              radius=first(fp.radius), t_min=float(fp.t_min),
              prediction_weight=float(fp.prediction_weight), static=fp.static)
    return st, fp.settings, kw


def _product_config():
    """The planner's defaults on two free-ended fireflies in 3-D (the default world: the
    ground z >= 0, one static row): only the NLP's structure and parameters are used."""
    from jaxplan.config import parse_config

    robot = lambda y: {"vehicle": "firefly", "start": [0.0, y, 1.5], "goal": [4.0, y, 1.5]}
    return parse_config({"name": "bench_product", "robots": [robot(0.0), robot(2.0)]})


def _paper_settings():
    """The paper NLP's solver settings (60 iterations, as the benchmark's from the start),
    on the device as the planner's are (run_setup.fleet_params: a Python scalar leaf is
    copied to the device at every call)."""
    return jax.device_put(solve.as_strong_dtypes(solve.SolverSettings(max_iters=PAPER_MAX_ITERS)))


@functools.cache
def nlp_setup(kind: str):
    """(structure, settings, fleet_params keywords) of the "product" or "paper" NLP."""
    if kind == "paper":  # the benchmark's NLP from the start (60 iterations, as then)
        return NLPStructure(), _paper_settings(), {}
    return _planner_setup(_product_config())


def _testing_nlps(goals, kw, max_neighbors=0):
    """An NLP builder for :func:`_fleet_cases`: (pos, vel, acc, previous Solution or
    None) -> (the fleet's NLPParams as :func:`jaxplan.testing.fleet_params` builds them
    with keywords ``kw``, the previous multipliers following their robot)."""
    slots = {}

    def nlps(pos, vel, acc, prev):
        P, idx = fleet_params(pos, vel, acc, goals, max_neighbors=max_neighbors,
                              return_neighbors=True, **kw)
        mult = None if prev is None else prev.multipliers._replace(
            collision=_planner.remap_slots(prev.multipliers.collision, slots["idx"], idx))
        slots["idx"] = idx
        return P, mult

    return nlps


@functools.partial(jax.jit, static_argnames="structure")
def _fleet_nlps_jit(fp, ps, pos, vel, acc, goals, rest, structure):
    z = jnp.zeros_like(goals)
    views = _planner.fresh_views(pos, vel, acc, goals, z, rest)
    fleet, goals = _planner.FleetState(pos, vel, acc, views), _planner.Goals(goals, z, rest)
    preds = _planner.view_predictions(fp, views)
    goals, preds, _ = _planner.unoccupied_goals(fp, fleet, preds, goals, structure)
    nlps = _planner.fleet_nlps(fp, ps, fleet, preds, goals, structure)
    return nlps.params, nlps.multipliers, nlps.neighbors, nlps.static_ids


def _planner_nlps(fp, structure, goals, rest):
    """An NLP builder for :func:`_fleet_cases` that goes the planner's way
    (:func:`jaxplan.planner.fleet_nlps` on fresh views, FleetParams ``fp``,
    PlannerStructure ``structure``): its neighbour and static-row selection, the previous
    multipliers following their robot and their row."""
    M = goals.shape[0]
    # the plan state: the previous solution's plans (by which the static rows are
    # chosen), multipliers and slots
    state = {"ps": _planner.initial_plan_state(jnp.asarray(goals), structure, M)}
    goals, rest = jnp.asarray(goals), jnp.asarray(rest)

    def nlps(pos, vel, acc, prev):
        ps = state["ps"]
        if prev is not None:
            ps = ps._replace(plan=prev.traj, multipliers=prev.multipliers,
                             has_plan=jnp.ones((M,), bool))
        P, mult, idx, sidx = _fleet_nlps_jit(fp, ps, jnp.asarray(pos), jnp.asarray(vel),
                                             jnp.asarray(acc), goals, rest, structure)
        state["ps"] = ps._replace(neighbors=idx, static_ids=sidx)
        return P, (None if prev is None else mult)

    return nlps


def _fleet_cases(kind, M, radius_m, seed, steps, reps, max_neighbors=0, setup=None,
                 fleet=None, nlps=None):
    """JAX on an M-robot fleet: the cold replan and ``steps`` warm ones, each timed
    (median of ``reps`` calls); the cases (params, start, solution) for the references.
    setup: (structure, settings, keywords) instead of :func:`nlp_setup`'s; fleet:
    (starts, goals) instead of an antipodal fleet; nlps: how the NLPs are built
    (default :func:`_testing_nlps`)."""
    structure, settings, kw = setup or nlp_setup(kind)
    rng = np.random.default_rng(seed)
    pos, goals = fleet if fleet is not None else antipodal(M, radius_m, rng)
    nlps = nlps or _testing_nlps(goals, kw, max_neighbors)
    z = np.zeros_like(pos)
    P, _ = nlps(pos, z, z, None)
    t0 = time.perf_counter()
    jax.block_until_ready(_cold(P, structure, settings))
    compile_s = time.perf_counter() - t0
    c0, t0 = _cpu_s(), time.perf_counter()
    sol, ms = _timed(lambda P: _cold(P, structure, settings), P, repeats=reps)
    # CPU seconds per wall second of the timed cold calls: <= 1 on one core
    cpu_per_wall = (_cpu_s() - c0) / (time.perf_counter() - t0)
    x0 = jax.block_until_ready(solve.initial_guess_batch(P, structure))
    cases = [dict(P=P, x0=x0, sol=jax.device_get(sol), ms=ms)]
    ws = jax.jit(jax.vmap(lambda tr, p: solve.warm_start(tr, DT, p, structure)))
    for _ in range(steps):
        tr = sol.traj
        pos, vel, acc = (np.asarray(a) for a in tr.state_at(jnp.full(tr.batch_shape, DT)))
        P, mult = nlps(pos, vel, acc, sol)
        x0 = ws(tr, P)
        fn = lambda P, x0, m, mu: _warm(P, x0, m, mu, structure, settings)
        mu = sol.penalty
        sol, ms = _timed(fn, P, x0, mult, mu, repeats=reps)
        cases.append(dict(P=P, x0=x0, sol=jax.device_get(sol), ms=ms, mult=mult, mu=mu))
    return structure, cases, compile_s, cpu_per_wall


def _retime(cases, structure, settings) -> list[float]:
    """Ms of one call (after one untimed) of each of :func:`_fleet_cases`'s cases again,
    as it timed them (the cold one with its initial guesses, the warm ones from their
    warm starts): another round of the same timings, taken later in the run."""
    warm = lambda P, x0, m, mu: _warm(P, x0, m, mu, structure, settings)
    return [_timed(lambda P: _cold(P, structure, settings), c["P"], repeats=1)[1]
            if "mult" not in c else _timed(warm, c["P"], c["x0"], c["mult"], c["mu"],
                                           repeats=1)[1] for c in cases]


def _rounds(cases, later: list[list[float]]) -> dict:
    """Combine the rounds of timings of ``cases`` (their own ``ms``, from
    :func:`_fleet_cases` with one repeat, then each of ``later`` from :func:`_retime`):
    each case's ``ms`` becomes the median of its rounds (kept as ``ms_rounds``), so that
    a case is timed as often as the references time it (``reps`` calls, one per round)
    but minutes apart.  On a shared machine the same call can take much longer for a
    minute or more (docs/SOLVER.md, "Speed"): calls seconds apart say more about that
    minute than about the code.  Returns the headline figures per round: cold (the
    first case) and warm (the median of the others) ms."""
    for i, c in enumerate(cases):
        c["ms_rounds"] = [c["ms"], *(r[i] for r in later)]
        c["ms"] = float(statistics.median(c["ms_rounds"]))
    per = list(zip(*(c["ms_rounds"] for c in cases), strict=True))
    return dict(cold_ms_rounds=[r[0] for r in per],
                warm_ms_rounds=[float(statistics.median(r[1:])) for r in per])


def _cpu_s() -> float:
    import resource

    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime
