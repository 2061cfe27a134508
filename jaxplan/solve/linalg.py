"""The Newton directions of a batch of lanes: Cholesky where it settles the step, else
an eigendecomposition with floored eigenvalues (:func:`directions`), and the LAPACK
batching that keeps those calls safe on a CPU (:func:`lapack_safe`; docs/SOLVER.md,
"LAPACK and threads").
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

# On a CPU, jaxlib's batched LAPACK kernels (jaxlib/cpu/lapack_kernels.cc:
# GetLapackBatchChunkSize, ParallelBatchMap) split a batch over XLA's CPU thread pool once
# batch * cost_per_matrix >= kMinWorkPerTask (200,000; eigh's cost_per_matrix is 5 n^3)
# and block a pool thread until the parts finish, so two such calls at once (two Python
# threads, or two CPU devices) can leave every pool thread waiting: a deadlock at 0% CPU.
# eigh_safe therefore never passes a CPU kernel a batch that it would split.  No public
# API states these two numbers: they are copied from the C++ of jaxlib
# LAPACK_JAXLIB_VERSION, and tests/test_solver_devices.py fails when another jaxlib is
# installed (re-read them there) and checks the LAPACK call sizes the solver compiles.
LAPACK_JAXLIB_VERSION = "0.10.2"
LAPACK_SPLIT_COST = 200_000  # kMinWorkPerTask
EIGH_COST = 5  # eigh's cost_per_matrix, per n^3
UNROLL_EIGH = 8  # eigh_safe: up to this many calls unrolled, more in a loop


def eigh_chunk(n: int) -> int:
    """The most n x n matrices one CPU eigh call takes without splitting its batch."""
    return max(1, (LAPACK_SPLIT_COST - 1) // (EIGH_COST * n ** 3))


def lapack_safe(fn, per: int = 1):
    """``fn`` of one matrix (n, n) (first argument; LAPACK inside) made safe to vmap on a
    CPU: under vmap the batch goes to LAPACK in calls of at most eigh_chunk(n) matrices
    (cheaper kernels than eigh's split later, so its bound covers them), which jaxlib
    runs on the calling thread (see LAPACK_SPLIT_COST); elsewhere (a GPU) one batched
    call.  The results are those of the batched call: LAPACK treats each matrix alone.
    Every argument must be batched along with the matrix.

    Nested vmaps (``jax.vmap`` of :func:`jaxplan.solve.alsqp.solve`, whose steps vmap over a
    batch of one lane) stay safe too: the batched function each level forms is itself made safe,
    with ``per`` the matrices one of its calls already holds, so an outer level chunks its
    batch by eigh_chunk(n) // per (an outer vmap that batched the inner level's LAPACK
    call whole hung a vmapped solve of 640 lanes at 0% CPU)."""
    safe = jax.custom_batching.custom_vmap(fn)

    @safe.def_vmap
    def rule(axis_size, in_batched, *args):
        if not any(in_batched):
            out = safe(*args)
            return out, jax.tree.map(lambda _: False, out)
        args = [a if b else jnp.broadcast_to(a, (axis_size,) + jnp.shape(a))
                for a, b in zip(args, in_batched, strict=True)]
        n = args[0].shape[-1]
        k = max(1, eigh_chunk(n) // per)  # lanes per LAPACK call
        many = lapack_safe(jax.vmap(fn), per * min(k, axis_size))

        def in_chunks(*args):
            if k >= axis_size:
                return many(*args)
            parts = -(-axis_size // k)
            if parts <= UNROLL_EIGH:
                outs = [many(*(a[i:i + k] for a in args)) for i in range(0, axis_size, k)]
                return jax.tree.map(lambda *o: jnp.concatenate(o), *outs)
            pad = parts * k - axis_size  # padded with copies of the first lane
            padded = [jnp.concatenate([a, jnp.broadcast_to(a[:1], (pad,) + a.shape[1:])])
                      for a in args]
            out = jax.lax.map(lambda xs: many(*xs),
                              [a.reshape((parts, k) + a.shape[1:]) for a in padded])
            return jax.tree.map(lambda o: o.reshape((parts * k,) + o.shape[2:])[:axis_size],
                                out)

        out = jax.lax.platform_dependent(*args, cpu=in_chunks, default=many)
        return out, jax.tree.map(lambda _: True, out)

    return safe


@lapack_safe
def eigh_safe(H):
    """(eigenvalues, eigenvectors) of the symmetric H (n, n) by jnp.linalg.eigh (LAPACK
    syevd on a CPU, batched safely: :func:`lapack_safe`)."""
    return tuple(jnp.linalg.eigh(H))


def direction(H, grad, reg):
    """-|H|_reg^-1 grad: eigenvalues by magnitude, floored at reg * max|eigenvalue|.

    reg = 1e-13 (~450 x the float64 epsilon, so a floored eigenvalue is still well above
    eigh's rounding).  With large penalties (mu ~ 1e9-1e10, where warm-started fleets
    with close encounters go) the largest eigenvalue is ~1e12, and a floor of 1e-10
    floors the objective's own curvature: Newton degrades to linear convergence and
    lanes run to max_iters (`jaxplan bench solver`, 100 robots: 1-4 such lanes per
    replan with 1e-10, none with 1e-12..1e-14, and 2x fewer iterations)."""
    return direction_pair(H, grad, reg, False)[0]


def direction_pair(H, grad, reg, convex):
    """(d, step): d = :func:`direction`'s -|H|_reg^-1 grad, whose decrement -grad d the
    stopping test reads; and the step to take: d, or where ``convex`` d without the
    components along H's negative-curvature eigenvectors (the Newton step on the
    positive-curvature part), unless that part has no component (then d)."""
    w, V = eigh_safe(H)
    wa = jnp.abs(w)
    floor = reg * jnp.max(wa) + 1e-300
    wm = jnp.maximum(wa, floor)
    c = (V.T @ grad) / wm
    d = -V @ c
    cp = jnp.where(w < 0, 0.0, c)
    return d, jnp.where(convex & jnp.any(cp != 0), -V @ cp, d)


@lapack_safe
def newton_cholesky(H, grad, reg):
    """(d, settled) for one H (n, n): the Newton step d = -H^-1 grad by Cholesky (LAPACK
    potrf and a triangular inverse L^-1, then d = -L^-T L^-1 grad: a small fraction of
    syevd's time on a CPU, docs/SOLVER.md), and whether it is
    :func:`direction`'s step: H positive definite with lambda_min >= reg * lambda_max,
    so that no eigenvalue is floored.  That is checked without eigenvalues: lambda_max
    <= |H|_F and lambda_min >= 1 / trace(H^-1) = 1 / |L^-1|_F^2.  Where not settled, d
    is 0."""
    n = H.shape[-1]
    eye = jnp.eye(n, dtype=H.dtype)
    L = jnp.linalg.cholesky(H)  # NaN where H is not positive definite
    pd = jnp.all(jnp.isfinite(L))
    L = jnp.where(pd, L, eye)
    Li = jax.scipy.linalg.solve_triangular(L, eye, lower=True)
    settled = pd & (jnp.sum(Li * Li) * jnp.sqrt(jnp.sum(H * H)) * reg <= 1.0)
    # H^-1 = L^-T L^-1 with L^-1 at hand: two small products instead of two more LAPACK
    # calls (triangular solves); steps within ~1e-14 of the solves', the same iterations
    # on the benchmark's batch, in less time (docs/SOLVER.md)
    d = -(Li.T @ (Li @ grad))
    return jnp.where(settled & jnp.all(jnp.isfinite(d)), d, 0.0), settled & jnp.all(
        jnp.isfinite(d))


# directions: matrices per eigh call where Cholesky does not settle it.  On a CPU one
# (EIGH_CHUNK_CPU): a step seldom has more than one such lane, and a call of two then
# decomposed a copy as well (the same directions, in more time: docs/SOLVER.md, "One
# iteration", and "Measurements behind the code").  Two (EIGH_CHUNK) under an
# outer vmap (a sweep's batch of runs), where a chunk of 1 rounds differently (its
# batched products are other XLA programs) and the sweeps' rows, the studies' included,
# would move; and off the CPU, where it was not measured.
EIGH_CHUNK_CPU = 1
EIGH_CHUNK = 2


def _directions(H, grad, need, reg, convex, chunk: int):
    """:func:`directions` with ``chunk`` lanes per eigh call."""
    B, n = grad.shape
    d, well = jax.vmap(newton_cholesky, in_axes=(0, 0, None))(H, grad, reg)
    d = (d, d)  # a positive definite H has no negative curvature: its step is d
    use = need & ~well
    order = jnp.argsort(~use, stable=True)  # the lanes that need eigh first
    cnt = jnp.sum(use, dtype=jnp.int32)
    c = min(chunk, B)
    one = jax.vmap(lambda h, gr, cv: direction_pair(h, gr, reg, cv))

    def body(carry):
        i, d = carry
        idx = jax.lax.dynamic_slice(order, (i,), (c,))  # clamped to fit: repeats are harmless
        de = one(H[idx], grad[idx], convex[idx])
        d = tuple(dd.at[idx].set(jnp.where(use[idx][:, None], e, dd[idx]))
                  for dd, e in zip(d, de, strict=True))
        return i + c, d

    return jax.lax.while_loop(lambda carry: carry[0] < cnt, body, (jnp.int32(0), d))[1]


@jax.custom_batching.custom_vmap
def directions(H, grad, need, reg, convex):
    """(d, step): the Newton directions -|H|_reg^-1 grad of a batch (B, n, n), (B, n)
    (what :func:`direction` gives), for the lanes where ``need`` (the others: anything
    finite), and the steps to take: d, or where ``convex`` (B,) d on H's
    positive-curvature part alone (:func:`direction_pair`).

    Where H is positive definite with lambda_min >= reg * lambda_max, no eigenvalue is
    floored and the direction is -H^-1 grad: solved by Cholesky.  That bound is checked
    without eigenvalues: lambda_max <= |H|_F and lambda_min >= 1 / |L^-1|_F^2.  The
    other lanes (indefinite or nearly singular Hessians: about half of the iterations of
    a cold fleet solve) get :func:`direction`, EIGH_CHUNK_CPU lanes per call on a CPU
    (EIGH_CHUNK elsewhere and under an outer vmap), in a loop that runs as many times as
    they need, so a batch pays an eigendecomposition only for them (on a CPU it costs
    many times the Cholesky).  LAPACK decomposes each matrix alone; the products around it are
    XLA's, and under an outer vmap they round differently with another chunk."""
    return jax.lax.platform_dependent(
        H, grad, need, reg, convex, cpu=lambda *a: _directions(*a, EIGH_CHUNK_CPU),
        default=lambda *a: _directions(*a, EIGH_CHUNK))


@directions.def_vmap
def _directions_vmap(axis_size, in_batched, H, grad, need, reg, convex):
    axes = [0 if b else None for b in in_batched]
    out = jax.vmap(lambda *a: _directions(*a, EIGH_CHUNK), in_axes=axes,
                   axis_size=axis_size)(H, grad, need, reg, convex)
    return out, (True, True)
