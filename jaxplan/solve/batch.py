"""The batch entry points: :func:`solve_batch` (a jitted solve over leading axes, split
over CPU devices, lanes pooled) and :func:`initial_guess_batch`.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.nlp import Multipliers, NLPParams, NLPStructure
from jaxplan.pytree import traced
from jaxplan.solve.devices import as_strong_dtypes, default_shards, shard_lanes
from jaxplan.solve.guess import initial_guess
from jaxplan.solve.pool import default_pool, solve_lanes
from jaxplan.solve.types import Solution, SolverSettings

PACK_ALONE_BYTES = 1 << 16  # pack_leaves: leaves this large go as they are


@functools.partial(jax.jit, static_argnames=("structure", "pool", "shards"))
def _solve_batch_jit(params, x0, structure, settings, multipliers, penalty, pool, shards=1,
                     x_fallback=None, warm=None):
    lead = jnp.shape(params.radius)  # radius: () per problem
    # the batch size spelt out, not -1: a leaf may have no elements (the static rows'
    # multipliers of an NLP without static rows, (..., n_col, 0))
    flat = lambda t: None if t is None else jax.tree.map(
        lambda a: a.reshape((math.prod(lead),) + a.shape[len(lead):]), t)
    if x_fallback is None:
        x_fallback = x0

    def lanes(p, x, m, u, xf, w):
        if x is None:  # a cold start: each shard forms its own lanes' guesses
            x = xf = jax.vmap(lambda q: initial_guess(q, structure))(p)
        return solve_lanes(p, x, structure, settings, m, u, pool=pool, x_fallback=xf, warm=w)

    args = (flat(params), flat(x0), flat(multipliers), flat(penalty), flat(x_fallback),
            flat(warm))
    sol = lanes(*args) if shards == 1 else shard_lanes(lanes, args, shards)
    return jax.tree.map(lambda a: a.reshape(lead + a.shape[1:]), sol)


def solve_batch(params: NLPParams, x0, structure: NLPStructure,
                settings: SolverSettings = SolverSettings(),
                multipliers: Multipliers | None = None, penalty=None,
                pool: int | None = None, shards: int | None = None, warm=None) -> Solution:
    """:func:`jaxplan.solve.alsqp.solve` over all leading axes of x0 (..., n_x) and params (same
    leading axes), jitted; ``settings`` is shared.  x0 = None: a cold start, every problem from
    its :func:`initial_guess`, formed in the same compiled program as the solve (each
    CPU device forms its own problems' guesses: the same guesses as
    :func:`initial_guess_batch`, without a second call and its wait for every device).
    Weights, limits and settings are traced: new values (Python scalars or arrays)
    reuse the compiled function (``_solve_batch_jit``).
    ``shards``: CPU devices the problems are split over (default :func:`default_shards`
    of the number of problems; at most ``len(jax.devices("cpu"))``).  ``warm``: bool of
    x0's leading shape (or a scalar), the problems whose x0 is a warm start
    (:func:`jaxplan.solve.alsqp.solve`'s ``warm``; default none).  ``pool``: lanes
    stepped at a time on each (:func:`solve_lanes`; default :func:`default_pool` of the
    problems per shard and of the other robots per problem).  Each problem takes the
    same iterations whatever the pool and shards; with shards the compiled code differs,
    so results can differ by rounding.  A problem whose x0 is not finite starts from
    :func:`initial_guess` (formed by a separate call, only then).  A program split over
    devices takes its arguments as host arrays, the small ones packed per dtype
    (:func:`pack_leaves`: placing ~50 arrays one by one on every device cost more than
    the copy)."""
    lead = jnp.shape(params.radius)
    if x0 is not None and tuple(jnp.shape(x0)[:-1]) != tuple(lead):
        raise ValueError(f"x0 has leading axes {tuple(jnp.shape(x0)[:-1])}, params {tuple(lead)}")
    B = math.prod(lead)
    if shards is None:
        shards = default_shards(B)
    n_cpu = len(jax.devices("cpu"))
    if not 1 <= int(shards) <= n_cpu:
        raise ValueError(f"shards = {shards}: expected 1 .. {n_cpu} (the CPU devices)")
    shards = min(int(shards), max(B, 1))
    if pool is None:
        pool = default_pool(-(-B // shards), n_others=params.other_mask.shape[-1])
    params = as_strong_dtypes(params)
    x0 = None if x0 is None else as_strong_dtypes(x0)
    # the lanes whose x0 is not finite start from initial_guess (as solve() does); it is
    # formed by a call of its own, only when needed, so that the solver's program does
    # not carry it (a part of its compile time: docs/SOLVER.md)
    x_fallback = x0
    if x0 is not None and not np.all(np.isfinite(np.asarray(x0))):
        x_fallback = initial_guess_batch(
            jax.tree.map(lambda a: a.reshape((-1,) + a.shape[x0.ndim - 1:]), params),
            structure).reshape(x0.shape)
    if warm is not None:
        if x0 is None:
            raise ValueError("warm: a cold start (x0 = None) has no warm starts")
        warm = np.broadcast_to(np.asarray(warm, bool), tuple(lead)) if not traced(warm) \
            else jnp.broadcast_to(jnp.asarray(warm, bool), tuple(lead))
    args = (params, x0, as_strong_dtypes(settings),
            None if multipliers is None else as_strong_dtypes(multipliers),
            None if penalty is None else as_strong_dtypes(penalty), x_fallback, warm)
    if shards > 1 and not traced(args):
        # the arguments go to every device: as a few host arrays, not ~50 placed one by one
        buffers, layout = pack_leaves(args)
        return _solve_batch_packed(buffers, layout, structure, pool, shards)
    p, x, s, m, u, xf, w = args
    return _solve_batch_jit(p, x, structure, s, m, u, pool, shards, xf, w)


def pack_leaves(tree, alone_bytes: int = PACK_ALONE_BYTES):
    """(arrays, layout): the leaves of ``tree`` as host (NumPy) arrays for a jitted call,
    the small ones packed end to end into one flat array per dtype, each leaf of at
    least ``alone_bytes`` as it is; and the static layout :func:`unpack_leaves` takes
    them apart by (the tree's structure, each leaf's shape and dtype).  Exact: the same
    values, dtypes and shapes come back.

    Why: a program split over several CPU devices (``shards``) takes each argument
    replicated on every device, and placing an array that lives on one device costs a
    fixed amount of Python however small it is (jax's resharding of a committed array),
    a host array far less: the warm 100-robot replan has ~50 arguments
    (docs/SOLVER.md, "Batches: CPU devices")."""
    leaves, treedef = jax.tree.flatten(tree)
    host = [np.asarray(v) for v in leaves]
    small = [h for h in host if h.nbytes < alone_bytes]
    dtypes = tuple(sorted({h.dtype.str for h in small}))
    packed = tuple(np.concatenate([h.reshape(-1) for h in small if h.dtype.str == d])
                   for d in dtypes)
    alone = tuple(h for h in host if h.nbytes >= alone_bytes)
    shapes = tuple((h.shape, h.dtype.str, h.nbytes >= alone_bytes) for h in host)
    return packed + alone, (treedef, shapes, dtypes)


def unpack_leaves(arrays, layout):
    """The tree :func:`pack_leaves` packed (``arrays`` as NumPy or jax arrays)."""
    treedef, shapes, dtypes = layout
    at = dict.fromkeys(dtypes, 0)
    alone = iter(arrays[len(dtypes):])
    leaves = []
    for shape, d, own in shapes:
        if own:
            leaves.append(next(alone))
            continue
        n = math.prod(shape)
        leaves.append(arrays[dtypes.index(d)][at[d]:at[d] + n].reshape(shape))
        at[d] += n
    return jax.tree.unflatten(treedef, leaves)


@functools.partial(jax.jit, static_argnames=("layout", "structure", "pool", "shards"))
def _solve_batch_packed(buffers, layout, structure, pool, shards):
    p, x, s, m, u, xf, w = unpack_leaves(buffers, layout)
    return _solve_batch_jit.__wrapped__(p, x, structure, s, m, u, pool, shards, xf, w)


def initial_guess_batch(params: NLPParams, structure: NLPStructure,
                        shards: int | None = None):
    """initial_guess over one leading batch axis, jitted; split over ``shards`` CPU
    devices (default :func:`default_shards` of the batch size, as :func:`solve_batch`)."""
    B = jax.tree.leaves(params)[0].shape[0]
    shards = default_shards(B) if shards is None else max(1, min(int(shards), B))
    return _initial_guess_jit(as_strong_dtypes(params), structure, shards)


@functools.partial(jax.jit, static_argnames=("structure", "shards"))
def _initial_guess_jit(params, structure, shards):
    fn = jax.vmap(lambda p: initial_guess(p, structure))
    return fn(params) if shards == 1 else shard_lanes(fn, (params,), shards)
