"""`jaxplan bench solver`: the JAX AL-SQP against IPOPT (CasADi) and NLopt SLSQP on the
same NLPs from the same starts.

Run:  python -m jaxplan.benchmarks.solver [--json FILE] [--quick]
(`jaxplan bench solver` calls :func:`run`).

Two NLPs (:func:`nlp_setup`): "product", the one `jaxplan run` solves with the planner's
defaults, built by experiment.structures and experiment.fleet_params as the planner
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

Its fleets come from :mod:`jaxplan.testing` and jaxplan/scenarios/worlds.py.
"""

from __future__ import annotations

import argparse
import functools
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
from jaxplan.nlp import Limits, NLPStructure, kind_constants, merit_and_constraints
from jaxplan.reference import solve_slsqp
from jaxplan.testing import antipodal, fleet_params, index_params
from jaxplan.world import static_rows

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


# ---------------------------------------------------------------------- product vs paper
# one core: one CPU (the child pins itself), one JAX CPU device, Eigen's single-threaded
# kernels, one OpenMP / BLAS thread for the references (every entry a --flag: XLA reads
# XLA_FLAGS only up to the first word that is not one and silently drops the rest)
ONE_CORE_ENV = {"JAXPLAN_CPU_DEVICES": "1", "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1",
                "XLA_FLAGS_EXTRA": "--xla_cpu_multi_thread_eigen=false"}
WARM_STEPS = 4  # warm replans compared per fleet
PAPER_MAX_ITERS = 60


def _planner_setup(config, scenario=None):
    """(structure, settings, fleet_params keywords) of the NLPs `jaxplan run` builds for
    ``config`` (its scenario, or ``scenario``): experiment.structures and
    experiment.fleet_params, so the static rows (the ground in 3-D, the obstacles and
    workspace faces of a world) are the planner's.  One vehicle's radius and limits
    (the first robot's) stand for the fleet's."""
    from jaxplan import experiment
    from jaxplan.config import build_scenario

    sc = scenario if scenario is not None else build_scenario(config)
    n_static = static_rows(sc.world).mask.shape[0]
    st = experiment.structures(config, n_static=n_static,
                               static_kinds=experiment.world_kinds(sc.world)).planner.nlp
    fp = experiment.fleet_params(config, sc, n_static=n_static)
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
    on the device as the planner's are (experiment.fleet_params: a Python scalar leaf is
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
    preds, inflate, floor = _planner.view_predictions(fp, views)
    params, _, idx, sidx, mult = _planner.fleet_nlps(fp, ps, views, preds, inflate, floor, pos,
                                                      vel, acc, goals, z, rest, structure)
    return params, mult, idx, sidx


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
    but minutes apart.  On a shared machine the same call can take ~1.8x longer for a
    minute or more (docs/SOLVER.md, "Speed"): calls seconds apart say more about that
    minute than about the code.  Returns the headline figures per round: cold (the
    first case) and warm (the median of the others) ms."""
    for i, c in enumerate(cases):
        c["ms_rounds"] = [c["ms"], *(r[i] for r in later)]
        c["ms"] = float(statistics.median(c["ms_rounds"]))
    per = list(zip(*(c["ms_rounds"] for c in cases), strict=True))
    return dict(cold_ms_rounds=[r[0] for r in per],
                warm_ms_rounds=[float(statistics.median(r[1:])) for r in per])


def _accounted(structure, settings, P, x0, mult, mu, pool, shards, reps):
    """(Solution, ms, fixed ms, ms allowed no iteration, ms of the evaluation) of
    solve_batch from warm starts: the fixed part is the call's time apart from its steps
    (setting the lanes up, placing the arguments, reporting them): the same call allowed
    no iteration (the settings are traced, so it is the same program), less the one
    evaluation of L_A and the constraints per lane that such a call makes for its report
    (:func:`_merit_ms`);
    a call that iterates makes that evaluation as its first step."""
    fn = lambda s: solve.solve_batch(P, x0, structure, s, mult, mu, pool=pool, shards=shards,
                                     warm=True)
    sol, ms = _timed(fn, settings, repeats=reps)
    _, ms0 = _timed(fn, settings._replace(max_iters=jax.device_put(np.int32(0))), repeats=reps)
    me = _merit_ms(structure, P, x0, mult, mu, shards, reps)
    return sol, ms, max(ms0 - me, 0.0), ms0, me


@functools.partial(jax.jit, static_argnames=("structure", "shards", "evaluate"))
def _merit_batch(P, x0, mult, mu, structure, shards, evaluate):
    def one(p, x, m, u):
        if not evaluate:
            return jnp.sum(x)
        if m.static is None:  # as init_lane: no static rows' multipliers given, zeros
            m = m._replace(static=solve.zero_multipliers(p, structure).static)
        f, g = merit_and_constraints(x, p, structure, kind_constants(p.rest, structure), m, u)
        return f + sum(jnp.sum(a) for a in jax.tree.leaves(g))

    return solve.shard_lanes(jax.vmap(one), (P, x0, mult, mu), shards)


def _merit_ms(structure, P, x0, mult, mu, shards, reps) -> float:
    """Median ms of L_A and the constraints evaluated once per lane (what init_lane does
    for a solve allowed no iteration), the lanes split over ``shards`` devices as
    solve_batch splits them: a program that evaluates them against the same program
    without the evaluation (the same arguments, one number out per lane), so that placing
    the arguments is not counted."""
    args = solve.as_strong_dtypes((P, x0, mult, mu))
    ms = [_timed(functools.partial(_merit_batch, structure=structure, shards=shards,
                                   evaluate=e), *args, repeats=reps)[1] for e in (True, False)]
    return max(ms[0] - ms[1], 0.0)


STEP_RUN = 8  # _step_us: steps per timed call
STEP_ROUNDS = 15  # _step_us: interleaved rounds (each times every program once)


@functools.partial(jax.jit, static_argnames=("structure",))
def _run_steps(st, lane, settings, structure):
    step = lambda _, st: solve.alsqp.step_lanes(st, lane, structure, settings)
    return jax.lax.fori_loop(0, STEP_RUN, step, st)


def _step_us(structure, settings, problems: dict, whole, rounds: int = STEP_ROUNDS):
    """(median us of one solver step (solve.alsqp.step_lanes) for each of ``problems``,
    median ms of ``whole()``): problems name -> (P, x0, mult, mu), lanes on the leading
    axis, one device; the lanes set up as solve_batch sets up warm starts, then STEP_RUN steps
    per timed call (from the first: a warm start's base evaluation, its directions, then
    trials); the calls of all the problems and of ``whole`` (the solve they come from)
    interleaved over ``rounds`` rounds, so that a drift of the machine's speed reaches
    them alike.  A step costs about the same whatever its lanes do (active or finished),
    so this is the cost of a step of that many lanes."""
    init = jax.jit(jax.vmap(lambda p, x, m, u: solve.alsqp.init_lane(
        p, x, structure, settings, m, u, x, True)[:2]))
    runs = {}
    for name, (P, x0, mult, mu) in problems.items():
        lane, st = init(*solve.as_strong_dtypes((P, x0, mult, mu)))
        jax.block_until_ready(_run_steps(st, lane, settings, structure))  # compile
        runs[name] = (st, lane)
    jax.block_until_ready(whole())
    ts = {name: [] for name in runs}
    tw = []
    for _ in range(rounds):
        for name, (st, lane) in runs.items():
            t0 = time.perf_counter()
            jax.block_until_ready(_run_steps(st, lane, settings, structure))
            ts[name].append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        jax.block_until_ready(whole())
        tw.append(time.perf_counter() - t0)
    return ({name: 1e6 * statistics.median(t) / STEP_RUN for name, t in ts.items()},
            1e3 * statistics.median(tw))


def _time_split(structure, settings, cases, reps: int = 5) -> dict:
    """Where a fleet replan's time goes, accounted on the first of the warm ``cases`` of
    :func:`_fleet_cases` (solve_batch's default pool and devices): its time = the call's
    fixed part (:func:`_accounted`) + its steps x the cost of a step, against the time
    measured.  The steps are those of the busiest device, replayed from each lane's
    evaluations (Solution.evaluations, solve.pool_steps): steps holding every lane of
    the device (lockstep) and steps of ``pool`` slots.  The measured time less the fixed
    part is shared between the steps as they cost timed alone (:func:`_step_us`, on the
    first device's lanes: a step of each kind with the other robots' terms and without
    them, the same NLPs with their slots cut, interleaved with the solve itself, whose
    median there is ``measured_ms``), the alone timings scaled by one factor
    (``step_timed_alone``: the timings, the factor): a step in the solve's loop and one
    timed alone differ, the shares of its parts less."""
    c = cases[0]
    P, x0, mult, mu = c["P"], c["x0"], c["mult"], c["mu"]
    B = int(np.size(c["sol"].status))
    shards = solve.default_shards(B)
    per = -(-B // shards)
    n_others = P.other_mask.shape[-1]
    pool = solve.default_pool(per, n_others=n_others)
    sol, ms, ms0, ms_none, ms_eval = _accounted(structure, settings, P, x0, mult, mu, pool,
                                                shards, reps)
    ev = np.asarray(sol.evaluations)
    lock, slots = max((solve.pool_steps(ev[d::shards], pool) for d in range(shards)), key=sum)
    bare = P._replace(others=jax.tree.map(lambda a: a[:, :0], P.others),
                      other_mask=P.other_mask[:, :0], other_radius=P.other_radius[:, :0])
    bare_mult = mult._replace(collision=mult.collision[..., :0])
    first = lambda t, n: jax.tree.map(lambda a: a[::shards][:n], t)  # device 0's lanes
    widths = {"pool": pool} | ({"all_lanes": per} if lock else {})
    us, ms_i = _step_us(structure, settings, {
        (w, o): first((PP, x0, mm, mu), n) for w, n in widths.items()
        for o, PP, mm in (("with", P, mult), ("without", bare, bare_mult))},
        lambda: solve.solve_batch(P, x0, structure, settings, mult, mu, pool=pool,
                                  shards=shards, warm=True))
    # the steps' share of the measured time (the solve timed among the steps), split as
    # the steps timed alone cost
    alone = 1e-3 * (lock * us.get(("all_lanes", "with"), 0.0) + slots * us[("pool", "with")])
    scale = max(ms_i - ms0, 0.0) / alone if alone > 0 else 0.0
    get = lambda w, o: scale * us.get((w, o), 0.0)
    return dict(lanes_per_device=per, pool=pool, shards=shards, others_per_nlp=n_others,
                evaluations_per_replan=int(ev.sum()),
                evaluations_lane_median=float(np.median(ev)),
                evaluations_lane_max=int(ev.max()), lockstep_steps=lock, slot_steps=slots,
                fixed_ms=ms0, no_iteration_ms=ms_none, merit_ms=ms_eval,
                step_us_all_lanes=get("all_lanes", "with"), step_us_pool=get("pool", "with"),
                step_us_pool_without_others=get("pool", "without"),
                step_us_all_lanes_without_others=get("all_lanes", "without"),
                step_timed_alone=dict(steps_per_call=STEP_RUN, rounds=STEP_ROUNDS, scale=scale,
                                      us={f"{w} {o}": v for (w, o), v in us.items()}),
                measured_ms=ms_i, measured_alone_ms=ms)


def _cpu_s() -> float:
    import resource

    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


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
    from jaxplan import experiment
    from jaxplan.config import build_scenario, parse_config

    planner = {} if max_static_rows is None else {"max_static_rows": max_static_rows}
    cfg = parse_config({"name": "bench_obstacles", "seed": 0, "planner": planner,
                        "scenario": {"kind": "random_obstacles", "count": 10,
                                     "obstacles": obstacles}})
    sc = build_scenario(cfg)
    out = {}
    for name, scen in (("with", sc), ("none", sc.with_world(sc.world.with_obstacles([])))):
        R = static_rows(scen.world).mask.shape[0]
        planner = experiment.structures(cfg, n_static=R,
                                        static_kinds=experiment.world_kinds(scen.world)).planner
        fp = experiment.fleet_params(cfg, scen, n_static=R)
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
                               repeats=2 if quick else 7,  # 0.1-0.2 s each
                               spread=True)
    # the same run's serial SLSQP rate (10 cold NLPs, (b)) as a reference: this machine's
    # speed drifts by up to ~1.7x within minutes, and both figures drift with it
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
