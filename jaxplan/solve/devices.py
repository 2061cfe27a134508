"""Placing a batch on devices: :func:`default_shards` (how many CPU devices a batch is
split over), :func:`shard_lanes` (the split itself) and :func:`as_strong_dtypes` (the
dtype coercion that lets Python scalars reuse a compiled program).  docs/SOLVER.md
("Batches: CPU devices") gives the measurements.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.solve.pool import LOCKSTEP_MAX

_STRONG_DTYPES = (jnp.dtype(jnp.float64), jnp.dtype(jnp.int32), jnp.dtype(bool))


def as_strong_dtypes(tree):
    """Leaves as strongly typed arrays (float64 / int32 / bool), so that Python scalars
    and weakly typed arrays hit the same compiled function as float64 arrays."""
    def f(a):
        if isinstance(a, jax.Array) and not a.weak_type and a.dtype in _STRONG_DTYPES:
            return a  # already strong: no conversion (a tree map of jnp.asarray over
            # every leaf costs a noticeable part of a warm replan: docs/SOLVER.md)
        if isinstance(a, (bool, int, float, np.ndarray, np.generic)):  # host values:
            a = np.asarray(a)  # NumPy is strongly typed under jit and cheap to convert
            kind = a.dtype.kind
            return a.astype(np.float64 if kind == "f" else np.int32 if kind in "iu" else a.dtype,
                            copy=False)
        a = jnp.asarray(a)
        if jnp.issubdtype(a.dtype, jnp.floating):
            return jnp.asarray(a, jnp.float64)
        if jnp.issubdtype(a.dtype, jnp.integer):
            return jnp.asarray(a, jnp.int32)
        return jnp.asarray(a, a.dtype)
    return jax.tree.map(f, tree)


def default_shards(batch: int, backend: str | None = None) -> int:
    """How many devices :func:`jaxplan.solve.batch.solve_batch` splits a batch of ``batch`` NLPs
    over: on a CPU with several devices (``jax.devices("cpu")``; jaxplan makes one per core, see
    :mod:`jaxplan`), all of them for a batch of more than LOCKSTEP_MAX NLPs, else 1.
    Elsewhere 1 (a GPU steps all lanes of a batch at once).

    Large batches run faster split; warm 10-robot replans stay on one device (split,
    each device has too little work): docs/SOLVER.md, "Batches: CPU devices".
    One XLA program on a CPU runs its kernels one after another; two devices run their
    halves side by side (safe in LAPACK only through :func:`jaxplan.solve.linalg.eigh_safe`)."""
    backend = backend or jax.default_backend()
    if backend != "cpu" or batch <= LOCKSTEP_MAX:
        return 1
    return max(1, min(len(jax.devices("cpu")), batch))


def shard_lanes(fn, args, shards: int):
    """fn(*args) with every leaf's leading (lane) axis split over ``shards`` CPU devices
    (shard_map: each device runs fn on its own lanes, its own loops; fn's outputs carry
    the lane axis first); the lanes are padded to a multiple of ``shards`` by repeating
    the last (the copies are dropped).  Call it under jit.

    The lanes are dealt round-robin (device d takes lanes d, d + shards, ...), not in
    contiguous blocks: neighbouring lanes (the robots of one fleet, the runs of one
    weight) tend to cost alike, so that blocks leave one device with more work while
    the other waits (the benchmark's 64 x 10 batch: 2,322 / 2,529 iterations in blocks,
    2,452 / 2,399 dealt).  Each lane's results are the same either way."""
    from jax.sharding import Mesh, NamedSharding, PartitionSpec

    if shards == 1:
        return fn(*args)
    B = jax.tree.leaves(args)[0].shape[0]
    pad = (-B) % shards
    deal = np.arange(B + pad).reshape(-1, shards).T.reshape(-1)  # device d: lanes d + k shards
    undeal = np.argsort(deal)[:B]
    mesh = Mesh(np.asarray(jax.devices("cpu")[:shards]), ("lanes",))
    # inputs and outputs are held whole on every device, so that the caller's program
    # around this is not partitioned over the lanes (XLA's propagation of the split into
    # it put collectives inside its loops and conditionals, and a replan hung)
    rep = NamedSharding(mesh, PartitionSpec())
    whole = lambda t: jax.tree.map(lambda a: jax.lax.with_sharding_constraint(a, rep), t)
    padded = jax.tree.map(lambda a: jnp.concatenate([a, jnp.repeat(a[-1:], pad, axis=0)])[deal],
                          whole(args))
    out = jax.shard_map(lambda a: fn(*a), mesh=mesh, in_specs=(PartitionSpec("lanes"),),
                        out_specs=PartitionSpec("lanes"), check_vma=False)(padded)
    return whole(jax.tree.map(lambda a: a[undeal], out))
