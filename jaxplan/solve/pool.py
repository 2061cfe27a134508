"""The lane pool: :func:`solve_lanes` steps a pool of lanes at a time and hands each
finished slot the next lane; :func:`default_pool` picks the pool size (docs/SOLVER.md,
"Batches: the lane pool").
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.nlp import Multipliers, NLPParams, NLPStructure
from jaxplan.pytree import tree_where
from jaxplan.solve.alsqp import Lane, State, finish_lane, init_lane, is_active, step_lanes
from jaxplan.solve.guess import initial_guess
from jaxplan.solve.types import Solution, SolverSettings


def solve_lanes(params: NLPParams, x0, structure: NLPStructure,
                settings: SolverSettings = SolverSettings(),
                multipliers: Multipliers | None = None, penalty=None, x_fallback=None,
                pool: int | None = None, warm=None) -> Solution:
    """:func:`jaxplan.solve.alsqp.solve` over one leading axis of B lanes, ``pool`` lanes
    stepped at a time.

    Under a plain vmap every lane runs for as many iterations as the slowest lane needs
    (the finished ones idle).  Here a pool of ``pool`` slots steps together; a slot
    whose lane finishes takes the next unstarted lane.  Each lane still takes exactly
    the iterations of :func:`jaxplan.solve.alsqp.solve` (the same results to round-off: XLA
    compiles steps of different widths into different kernels, docs/SOLVER.md "Speed"),
    but the work is about the sum of the lanes' iterations instead of B times the largest.
    pool = B (or None) is the plain vmap.  ``warm`` (B,) bool: the lanes whose x0 is a warm
    start (:func:`jaxplan.solve.alsqp.solve`'s ``warm``; default none).  A batch of at
    most LOCKSTEP_MAX lanes first steps all its lanes in lockstep while more than half
    are active (:func:`_pooled`).
    On a CPU, where a step costs a fixed part plus about in proportion to its lanes, a
    small pool pays when iteration counts are uneven; on a GPU a step of B lanes costs
    about what one of a few lanes costs, so pool = B is right there (:func:`default_pool`).
    Pure; jit at the call site (``pool`` and ``structure`` are static).
    """
    s = settings
    B = x0.shape[0]
    pool = B if pool is None else max(1, min(int(pool), B))
    if x_fallback is None:  # cold guesses (20 objective and 5 merit values each) only if needed
        x_fallback = jax.lax.cond(
            jnp.all(jnp.isfinite(x0)), lambda: jnp.zeros_like(x0),
            lambda: jax.vmap(lambda p: initial_guess(p, structure))(params))
    warm = jnp.zeros((B,), bool) if warm is None else jnp.broadcast_to(warm, (B,))
    lane, st, finite_in, x0u = jax.vmap(
        lambda p, x, m, pe, xf, w: init_lane(p, x, structure, s, m, pe, xf, w),
        in_axes=(0, 0, None if multipliers is None else 0, None if penalty is None else 0, 0,
                 0),
    )(params, x0, multipliers, penalty, x_fallback, warm)
    step = lambda st, ln: step_lanes(st, ln, structure, s)
    if pool == B:
        st = jax.lax.while_loop(lambda st: jnp.any(is_active(st, s)),
                                lambda st: step(st, lane),
                                st)
    else:
        st = _pooled(st, lane, step, pool, s)
    return jax.vmap(lambda st, ln, fi, x: finish_lane(st, ln, fi, x, structure, s))(
        st, lane, finite_in, x0u)


def _pooled(st_all: State, lane_all: Lane, step, C: int, s: SolverSettings) -> State:
    """Run every lane of ``st_all`` (B lanes) to its end: for B <= LOCKSTEP_MAX, all B
    in lockstep while more than half of them (and more than C) are active; then the
    rest with C slots (see solve_lanes).

    A step costs a fixed part (XLA's per-kernel overheads) plus a part per lane, active
    or not.  Lockstep pays the fixed part once for all
    lanes, and wastes the idle lanes' part; slots waste nothing but pay the fixed part
    per C lanes.  So the common first iterations run in lockstep and the stragglers in
    slots (a lane that needs 60 iterations does not hold B - 1 idle lanes for them).
    Larger batches go to the slots at once: there lockstep cost more than it saved
    (docs/SOLVER.md, "Measurements behind the code").
    """
    B = st_all.it.shape[0]
    take = lambda tree, idx: jax.tree.map(lambda a: jnp.take(a, idx, axis=0, mode="clip"), tree)
    if B <= LOCKSTEP_MAX:
        many = max(C, B // 2)
        st_all = jax.lax.while_loop(
            lambda st: jnp.sum(is_active(st, s)) > many,
            lambda st: step(st, lane_all), st_all)
    # the lanes still active, in lane order; queue[j] for j < n_act
    act = is_active(st_all, s)
    n_act = jnp.sum(act, dtype=jnp.int32)
    queue = jnp.argsort(~act, stable=True).astype(jnp.int32)
    pos = jnp.arange(C, dtype=jnp.int32)  # slot k holds queue[pos[k]]
    lane_of = lambda q: jnp.where(q < n_act, jnp.take(queue, q, mode="clip"), B)  # B: none

    def cond(c):
        _, _, _, _, nxt, sl_valid = c
        return jnp.any(sl_valid) | (nxt < n_act)

    def body(c):
        st_all, sl, sl_st, sl_lane, nxt, sl_valid = c
        sl_st = step(sl_st, sl_lane)  # inactive lanes come back as they were
        fin = sl_valid & ~is_active(sl_st, s)
        # finished lanes go home; free slots take the next queued lanes in order
        st_all = jax.tree.map(
            lambda a, u: a.at[jnp.where(fin, sl, B)].set(u, mode="drop"), st_all, sl_st)
        free = fin | ~sl_valid
        new = nxt + jnp.cumsum(free, dtype=jnp.int32) - 1
        refill = free & (new < n_act)
        sl = jnp.where(refill, lane_of(new), jnp.where(free, B, sl))
        sl_valid = (sl_valid & ~fin) | refill
        nxt = jnp.minimum(nxt + jnp.sum(free, dtype=jnp.int32), n_act)
        sl_st = tree_where(refill, take(st_all, sl), sl_st)
        sl_lane = tree_where(refill, take(lane_all, sl), sl_lane)
        return st_all, sl, sl_st, sl_lane, nxt, sl_valid

    sl0 = lane_of(pos)
    c0 = (st_all, sl0, take(st_all, sl0), take(lane_all, sl0), jnp.minimum(C, n_act),
          pos < n_act)
    return jax.lax.while_loop(cond, body, c0)[0]


def pool_steps(evaluations, pool: int) -> tuple[int, int]:
    """The steps :func:`solve_lanes` takes on one device for lanes that need these
    ``evaluations`` (in lane order; ``Solution.evaluations``) with ``pool`` slots, as
    (steps holding every lane, steps holding ``pool`` slots): the schedule of
    :func:`_pooled` replayed on the host (a batch of at most LOCKSTEP_MAX lanes steps all
    its lanes while more than half are active; then the slots, each finished slot taking
    the next lane in lane order; pool >= B: every step holds all lanes).  A step costs
    about the same whatever its lanes do, so the call's fixed part plus these counts times
    the costs of the two kinds of step are the solve's time (`jaxplan bench solver`'s
    account of where the time goes)."""
    e = [int(v) for v in np.asarray(evaluations).reshape(-1)]
    B = len(e)
    if B == 0:
        return 0, 0
    C = max(1, min(int(pool), B))
    if C == B:
        return max(e), 0
    lock = 0
    if B <= LOCKSTEP_MAX:  # all lanes step while more than `many` are active
        many = max(C, B // 2)
        while sum(v > lock for v in e) > many:
            lock += 1
    queue = [v - lock for v in e if v > lock]
    slots = [0] * C  # the step at which each slot's current lane ends
    for k, rem in enumerate(queue[:C]):
        slots[k] = rem
    for rem in queue[C:]:  # the first slot to free (lowest index on a tie) takes it
        k = min(range(C), key=lambda i: (slots[i], i))
        slots[k] += rem
    return lock, max(slots, default=0)


LOCKSTEP_MAX = 32  # batches up to this size start in lockstep (_pooled)
POOL_CPU = 2  # lanes per step on a CPU (see default_pool)
POOL_CPU_FEW = 12  # ... in a batch of more than LOCKSTEP_MAX NLPs with few others each
POOL_CPU_MANY = 4  # ... in a batch of more than LOCKSTEP_MAX NLPs with more others each
FEW_OTHERS = 16  # "few": at most this many other robots per NLP
SMALL_BATCH = 3  # a CPU batch of at most this many lanes steps them all at once (one step)


def default_pool(batch: int, backend: str | None = None, n_others: int | None = None) -> int:
    """The pool size :func:`jaxplan.solve.batch.solve_batch` and the planner use: on a CPU,
    for a batch of more than LOCKSTEP_MAX NLPs POOL_CPU_FEW (12) lanes if they have at most
    FEW_OTHERS other robots each (``n_others``: the other-robot slots of an NLP, masked
    ones included), else POOL_CPU_MANY (4); the whole batch for at most SMALL_BATCH (3)
    NLPs, else POOL_CPU (2); B elsewhere.

    A pool smaller than the batch puts two copies of the solver step in the program (the
    lockstep one and the slots'); a batch of 3 gains little from the slots, and one copy
    compiles faster.  A step costs a fixed part (XLA's per-kernel overheads) plus a part
    per lane: wide pools share the fixed part, but once the per-lane arrays grow (many
    others) caches lose, so many NLPs with few others each step in a wide pool and with
    more others in a narrower one.  Warm 10-robot replans start in lockstep
    (:func:`_pooled`), so their pool matters little.  The sizes are the fastest of the
    bench's NLPs timed with each (docs/SOLVER.md, "Measurements behind the code"); in
    solve_batch each lane's results were bitwise those of pool 2 there (not in the
    planner's closed loop, whose rounding differed from the first replan of a 40-robot
    fleet)."""
    backend = backend or jax.default_backend()
    if backend != "cpu":
        return batch
    if batch <= SMALL_BATCH:
        return max(1, batch)
    if batch > LOCKSTEP_MAX:
        few = n_others is not None and n_others <= FEW_OTHERS
        return POOL_CPU_FEW if few else POOL_CPU_MANY
    return max(1, min(batch, POOL_CPU))
