"""Where a fleet replan's time goes (:func:`_time_split`, `jaxplan bench solver`): each
lane's evaluations, the lane pool's steps replayed from them (solve.pool_steps), the
call's fixed part (:func:`_accounted`, :func:`_merit_ms`) and the cost of a solver step
timed alone, with and without the other robots' terms (:func:`_step_us`)."""

from __future__ import annotations

import functools
import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np

import jaxplan  # noqa: F401  (float64)
from jaxplan import solve
from jaxplan.benchmarks.solver_fleets import _timed
from jaxplan.nlp import kind_constants, merit_and_constraints


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
