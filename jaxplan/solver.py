"""Augmented-Lagrangian SQP for one robot's NLP (MATH.md section 2), in JAX.

Method (per problem; ``solve`` is pure, jit- and vmap-able)
------------------------------------------------------------
* Variables: x = (z, tau = log T) of :mod:`jaxplan.costs`.  The equality constraints
  (start state, C^2 joints, end state) are eliminated exactly by the null-space
  parametrization c = P e(h) + Z z, i.e. each step's KKT system is solved in its
  reduced (null-space) form; they hold to rounding at every iterate.
* Inequalities g(x) >= 0 (collision samples d^2 >= rho^2, optional hard limits) enter
  an augmented Lagrangian  L_A = f + sum psi(g; lam, mu).  Multipliers are updated
  (lam <- max(0, lam - mu g)) whenever the inner problem is nearly solved (Newton
  decrement <= ``inner_tol``); the penalty mu grows (x ``mu_growth``) only when the
  violation did not shrink by ``stall_ratio`` since the previous update.
* Step: exact Hessian of L_A (structured autodiff, costs.merit_derivs), eigenvalues
  floored at |lambda| >= reg * max|lambda| (eigh; negative curvature flipped), so the
  step is a descent direction (where the Hessian is provably positive definite with no
  eigenvalue below that floor, the same step by Cholesky: :func:`_directions`); T >=
  t_min by projection (tau at its bound with an
  outward gradient is held); the step is capped (|dtau| <= max_step_tau, |dz|_inf <=
  max_step_z); backtracking Armijo line search on L_A (a failed trial is cut back to
  just past the first constraint it pushed into the steep AL branch, else halved).
* Stopping: Newton decrement^2 <= tol_stationarity (1 + |L_A|), max violation <=
  tol_feasibility, max lam~ |g| <= tol_complementarity (1 + |L_A|), where
  lam~ = max(0, lam - mu g) (the multiplier estimate whose Lagrangian gradient is the
  AL gradient).  A bounded loop (``max_iters``); per-lane status, never raised.

Evaluations: a solver step (:func:`_step`) is ONE evaluation of L_A's value,
derivatives and constraints per lane, at the lane's next point: its iterate, or a
line-search trial.  An accepted trial's derivatives start the next iteration (unless
its multipliers change there), so the usual iteration (derivatives at x, then merit
trials) costs one evaluation when the first trial is accepted, and a rejected trial
costs derivatives that go unused.  In exchange no lane ever waits for another's
backtracking: under vmap a nested line-search loop runs every lane for as many trials
as the slowest needs.  The iterates are those of the textbook loop above.

Batches: :func:`solve_batch` / :func:`solve_lanes` step a pool of lanes at a time and
hand each finished slot the next lane, so a batch costs about the sum of its lanes'
evaluations rather than B times the largest (each lane's iterations are those of
:func:`solve`).  :func:`solve_differentiable`: the solution differentiable with respect
to the weights by implicit differentiation (jaxopt ``custom_root``).

Status codes (``Solution.status``, int32):
    0 CONVERGED      all three tests passed.
    1 MAX_ITERS      iteration budget spent, constraints satisfied to tolerance.
    2 NON_FINITE     a non-finite value appeared; x = x0 (finite), traj finite.
    3 INFEASIBLE     budget spent with violation > tol_feasibility (e.g. a start
                     inside another robot's radius, or a goal occupied).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan import costs
from jaxplan.costs import Multipliers, NLPParams, NLPStructure
from jaxplan.predict import predict_arrays
from jaxplan.trajectory import Trajectory

CONVERGED, MAX_ITERS, NON_FINITE, INFEASIBLE = 0, 1, 2, 3
STATUS_NAMES = {CONVERGED: "converged", MAX_ITERS: "max-iterations", NON_FINITE: "non-finite",
                INFEASIBLE: "infeasible"}


class SolverSettings(NamedTuple):
    """Solver settings; all traced (changing them does not recompile)."""

    max_iters: int = 60
    tol_stationarity: float = 1e-10  # Newton decrement^2 / (1 + |L_A|)
    tol_feasibility: float = 1e-8  # constraint units (m^2 for collisions)
    tol_complementarity: float = 1e-8  # lam |g| / (1 + |L_A|)
    inner_tol: float = 1e-4  # decrement^2 / (1 + |L_A|) that triggers a multiplier update
    mu0: float = 10.0
    mu_max: float = 1e10
    mu_growth: float = 10.0
    stall_ratio: float = 0.25
    max_step_tau: float = 0.5
    max_step_z: float = 4.0
    armijo: float = 1e-4
    max_backtracks: int = 30
    kink_overshoot: float = 1.1  # backtracking past an AL branch crossing (_step)
    reg: float = 1e-13  # eigenvalue floor / max|eigenvalue| (_direction)


class Solution(NamedTuple):
    """Result of one solve (leading batch axes under vmap).

    x: (n_x,) decision vector (z, log T).  traj: the plan (S segments; coasts after T
    unless ``rest``).  objective: f(x) without constraint terms.  status: int32 (see
    module doc).  iterations: int32.  kkt_residual: |projected grad of L_A|_inf at the
    last derivative evaluation (= Lagrangian gradient with lam~).  eq_violation: max
    residual of the equality constraints (m, m/s, m/s^2).  ineq_violation: max(0, -g)
    (m^2 for collisions, dimensionless for hard limits).  multipliers, penalty: warm-
    start the next solve.  decrement: last Newton decrement^2.  Never NaN: objective,
    kkt_residual, eq_violation, ineq_violation and decrement are +inf where they cannot
    be evaluated (NON_FINITE lanes, e.g. a NaN weight or an overflowing horizon).
    """

    x: jax.Array
    traj: Trajectory
    objective: jax.Array
    status: jax.Array
    iterations: jax.Array
    kkt_residual: jax.Array
    eq_violation: jax.Array
    ineq_violation: jax.Array
    multipliers: Multipliers
    penalty: jax.Array
    decrement: jax.Array


class _State(NamedTuple):
    """One lane's solver state between evaluations (:func:`_step`).

    The lane is either at its *base* (``base``: the next evaluation is at y = x, whose
    derivatives start an iteration) or in a line search from x along d (the next
    evaluation is the trial y = x + a d, its k-th)."""

    x: jax.Array  # the iterate (base)
    mult: Multipliers
    mu: jax.Array
    g: Multipliers  # the constraints at x
    f: jax.Array  # L_A at x with (mult, mu)
    viol_ref: jax.Array
    pending: jax.Array
    it: jax.Array
    done: jax.Array
    bad: jax.Array
    kkt: jax.Array
    theta: jax.Array  # Newton decrement^2 at x
    base: jax.Array  # bool: the next evaluation is at x
    y: jax.Array  # the point of the next evaluation
    d: jax.Array  # the (capped) step from x
    grad: jax.Array  # the projected gradient of L_A at x (Armijo)
    a: jax.Array  # the step length of y along d
    k: jax.Array  # int32: trials before y in this line search
    obj0: jax.Array  # the objective at x0 (from the first evaluation; reported where the
    viol0: jax.Array  # lane ends NON_FINITE) and the constraint violation there


def _tree_where(c, a, b):
    return jax.tree.map(lambda u, v: jnp.where(c, u, v), a, b)


_tree_where_lanes = jax.vmap(_tree_where)  # the same, per lane (leading axis of c, a, b)


def _max_violation(g: Multipliers):
    return jnp.maximum(jnp.max(-g.collision, initial=0.0), jnp.max(-g.limits, initial=0.0))


def zero_multipliers(params: NLPParams, structure: NLPStructure) -> Multipliers:
    b = costs.basis(structure)
    Mo = params.other_mask.shape[-1]
    return Multipliers(jnp.zeros((structure.n_col, Mo)), jnp.zeros((len(b.lim_s), 3)))


def _sanitize(params: NLPParams) -> tuple[NLPParams, jax.Array]:
    """Replace non-finite own-state entries and t_min by 0; report whether all own-state
    entries and scalars were finite."""
    own = (params.p0, params.v0, params.a0, params.goal_p, params.goal_v, params.goal_a)
    ok = jnp.all(jnp.stack([jnp.all(jnp.isfinite(a)) for a in own]))
    scal = jax.tree.leaves((params.weights, params.limits, params.t_min, params.radius))
    ok = ok & jnp.all(jnp.stack([jnp.isfinite(a) for a in scal]))
    fz = lambda a: jnp.where(jnp.isfinite(a), a, 0.0)
    return params._replace(**{k: fz(getattr(params, k)) for k in
                              ("p0", "v0", "a0", "goal_p", "goal_v", "goal_a", "t_min")}), ok


GUESS_SHAPES = (0.0, 0.5)  # free ends: z = alpha z_rest(T) (initial_guess)
GUESS_T_FACTORS = np.geomspace(0.5, 8.0, 25)  # the grid of horizons (x the prediction's)
GUESS_SWERVE = 1.5  # swerve candidates' RMS displacement / rho_max (_swerve)
GUESS_SWERVE_PENALTY = SolverSettings._field_defaults["mu0"]  # _swerve's AL penalty
GUESS_SWERVE_TIE = 1e-12  # _swerve: merits within this (relative) of the least tie
GUESS_STEPS = (8, 4, 2, 1)  # initial_guess's bisection of that grid (its 25 = 3 x 8 + 1 points)
# the bisection is exact for a unimodal objective only if the grid is 1 + a multiple of
# the first step and each step halves the last down to 1
assert (len(GUESS_T_FACTORS) - 1) % GUESS_STEPS[0] == 0 and GUESS_STEPS == tuple(
    GUESS_STEPS[0] >> i for i in range(GUESS_STEPS[0].bit_length())), GUESS_STEPS


def _rest_shape(structure: NLPStructure) -> np.ndarray:
    """G (nz, 6): z = G e(h) puts the rest end's minimum-jerk path (z = 0 of the rest
    kind, through e(h)'s end velocity and acceleration) into the free-end
    parametrization: the free kind holds every rest path (it has fewer end conditions),
    so the least-squares fit is exact."""
    b = costs.basis(structure)
    return np.linalg.pinv(b.free.Z) @ (b.rest.P - b.free.P)


def initial_guess(params: NLPParams, structure: NLPStructure, swerve: bool = True) -> jax.Array:
    """x0 from the robot's own closed-form minimum time-jerk prediction to its goal.

    z = 0 is exactly the minimum-jerk path for a given T (costs module doc).  T starts
    from the prediction's optimal horizon with time weight k_t / q_dynm and is then
    chosen on a geometric grid (x0.5 .. x8, and >= t_min) to minimize the objective
    without collision terms (smoothness + time + soft limits), so that x0 does not
    start deep in the exponential soft limits.  For a free end the shape is chosen
    with T, among z = alpha z_rest(T) for alpha in GUESS_SHAPES, where z_rest(T) is
    the rest end's minimum-jerk path (slowing to the goal's end velocity,
    :func:`_rest_shape`): alpha = 0 is the free end's minimum-jerk path, which ends at
    its highest speed, so that the soft velocity limit alone makes the grid pick a long
    T; alpha = 0.5 is the path halfway to the rest one.  (On the benchmark's 640
    antipodal NLPs the solutions' shapes project onto alpha ~0.48, the collision-free
    optimum's T is ~0.7 of the alpha = 0 choice, and the rest path itself, alpha = 1,
    was never the better start.)  A rest end keeps z = 0 (the same guess as with alpha = 0
    alone).  The grid is searched by bisection (GUESS_STEPS: its points 0, 8, 16, 24,
    then +-4, +-2, +-1 around the best so far; 10 objective evaluations per shape
    instead of 25), which finds the grid's minimum wherever the objective is unimodal
    along the grid (smoothness falls and time rises with T, the soft limits fall with
    it): on the benchmark's 640 NLPs, 160 rest-end fleet NLPs and 400 random ones, with
    1, 2 and 3 segments, the same guess as the full search to rounding (< 1e-12), at
    about half its cost.  Last, :func:`_swerve` may bend the chosen path across itself
    (right, left, up or down), where the collision terms say a swerve beats the straight
    line through the others' predictions (``swerve=False``: the grid's choice alone).
    Finite for any input.
    """
    p, _ = _sanitize(params)
    w = p.weights.k_t / jnp.maximum(p.weights.q_dynm, 1e-12)
    w = jnp.where(jnp.isfinite(w) & (w > 0), w, 1.0)
    pred = predict_arrays(p.p0, p.v0, p.a0, p.goal_p, p.goal_v, p.goal_a, p.rest, w)
    T = pred.duration
    tmin = jnp.where(jnp.isfinite(p.t_min) & (p.t_min > 0), p.t_min, 1e-3)
    T = jnp.where(jnp.isfinite(T), jnp.maximum(T, tmin), tmin)
    free = dataclasses.replace(structure, collision="none", hard_limits=False)
    kc = costs.kind_constants(p.rest, free)
    K = len(GUESS_T_FACTORS)
    taus = jnp.log(jnp.maximum(T * jnp.asarray(GUESS_T_FACTORS), tmin))  # (K,)
    G = jnp.asarray(_rest_shape(structure))
    al = jnp.where(jnp.asarray(p.rest, bool), 0.0, jnp.asarray(GUESS_SHAPES))  # (A,)

    def candidates(idx):  # (A, m) grid indices -> x (A, m, n_x), objective (A, m)
        t = taus[idx]
        zr = jax.vmap(lambda tt: (G @ costs.boundary_vector(p, jnp.exp(tt) / structure.segments)
                                  ).T.reshape(-1))(t.reshape(-1)).reshape(t.shape + (-1,))
        xs = jnp.concatenate([al[:, None, None] * zr, t[..., None]], axis=-1)
        fs = jax.vmap(lambda x: costs._terms(x, p, free, kc, None, 1.0))(
            xs.reshape(-1, structure.n_x)).reshape(t.shape)
        return xs, jnp.where(jnp.isfinite(fs), fs, jnp.inf)

    # per shape, the grid's minimum by bisection (GUESS_STEPS): exact where the objective
    # is unimodal along the grid, at 10 of its 25 points
    h0 = GUESS_STEPS[0]
    xs, fs = candidates(jnp.broadcast_to(jnp.arange(0, K, h0), (len(GUESS_SHAPES), -(-K // h0))))
    j = jnp.argmin(fs, axis=1)
    take = lambda a, j: a[jnp.arange(a.shape[0]), j]  # per shape, its j-th entry
    best, xb, fb = j * h0, take(xs, j), take(fs, j)
    for h in GUESS_STEPS[1:]:
        idx = jnp.clip(jnp.stack([best - h, best + h], axis=1), 0, K - 1)
        xc, fc = candidates(idx)
        idx3 = jnp.stack([idx[:, 0], best, idx[:, 1]], axis=1)  # in grid order (ties: first)
        x3 = jnp.stack([xc[:, 0], xb, xc[:, 1]], axis=1)
        f3 = jnp.stack([fc[:, 0], fb, fc[:, 1]], axis=1)
        j = jnp.argmin(f3, axis=1)
        best, xb, fb = take(idx3, j), take(x3, j), take(f3, j)
    x = xb[jnp.argmin(fb)]
    if swerve:
        x = _swerve(x, p, structure)
    return jnp.where(jnp.all(jnp.isfinite(x)), x, jnp.zeros_like(x).at[-1].set(jnp.log(tmin)))


def _across(p: NLPParams, N: int) -> list:
    """Unit vectors across the straight path p0 -> goal (N = 2: its right; N = 3: its
    right in the horizontal plane, then its "up", the last axis less its component along
    the path (the first axis where the path is near vertical)); none for other N."""
    u = p.goal_p - p.p0
    n = jnp.sqrt(jnp.sum(u * u))
    u = jnp.where(n > 1e-9, u / jnp.maximum(n, 1e-300), jnp.eye(N, dtype=u.dtype)[0])
    if N == 2:
        return [jnp.stack([u[1], -u[0]])]
    if N != 3:
        return []
    up = jnp.eye(3, dtype=u.dtype)[2] - u[2] * u
    ax = jnp.eye(3, dtype=u.dtype)[0] - u[0] * u
    nu, na = jnp.sqrt(up @ up), jnp.sqrt(ax @ ax)
    up = jnp.where(nu > 0.1, up / jnp.maximum(nu, 1e-300), ax / jnp.maximum(na, 1e-300))
    return [jnp.cross(u, up), up]


def _swerve(x, p: NLPParams, structure: NLPStructure):
    """initial_guess's last stage: x, or x with a swerve across its path, whichever has
    the lower merit (the objective with the collision terms, zero multipliers and the
    default penalty).

    The candidates add GUESS_SWERVE (rho_max) along each direction of :func:`_across`, both
    signs (right, left, up, down), to the shape variable of the smoothest mode of the
    lane's end kind (z[:, 0], the mode of least jerk per unit of RMS displacement,
    costs.basis: an RMS displacement of GUESS_SWERVE rho_max over the plan, 1.6-1.7x
    that at its peak), where rho_max = own radius + the largest other radius, at the
    horizon already chosen.  Straight guesses put the robots of a crossing into one
    another: on the benchmark's 640 antipodal NLPs the solutions swerve (RMS 0.6 m up or
    down, 0.15 m sideways, where rho = 0.5 m), and this stage took the iterations from
    4,851 to 3,152 (objectives: 45 lanes better, 30 worse by the local minimum reached,
    mean -0.005) at 4 extra merit values per lane (costs.merit_shapes).  Ties (within
    GUESS_SWERVE_TIE) keep the first candidate in the order x, right, left, up, down:
    two robots head-on, each predicting the other straight, both swerve to their right
    and pass.  Only with sampled collision terms (x otherwise: no swerve can pay)."""
    N, nz = structure.n_dim, structure.nz
    dirs = _across(p, N)
    if not dirs or not nz or not costs._has_collision(structure):
        return x
    kc = costs.kind_constants(p.rest, structure)
    rho = p.radius + jnp.max(jnp.where(p.other_mask, p.other_radius, 0.0), initial=0.0)
    z, tau = costs.unpack(x, structure)
    amp = GUESS_SWERVE * jnp.where(jnp.isfinite(rho) & (rho > 0), rho, 0.0)
    zs = [z] + [z.at[:, 0].add(sg * amp * w) for w in dirs for sg in (1.0, -1.0)]
    zs = jnp.stack(zs)
    f = costs.merit_shapes(zs, tau, p, structure, kc, zero_multipliers(p, structure),
                           GUESS_SWERVE_PENALTY)
    f = jnp.where(jnp.isfinite(f), f, jnp.inf)
    # the first candidate within rounding of the least (exact ties differ in the last bits)
    first = jnp.argmax(f <= jnp.min(f) + GUESS_SWERVE_TIE * (1.0 + jnp.abs(jnp.min(f))))
    return costs.pack(zs[first], tau)


def warm_start(prev: Trajectory, dt, params: NLPParams, structure: NLPStructure,
               fallback=None) -> jax.Array:
    """x0 from the previous plan shifted by ``dt`` seconds (receding horizon).

    The shifted plan (T' = T - dt, >= t_min) is re-fitted, by least squares on dense
    position samples, to the equal-segment parametrization through the CURRENT start
    state and goal of ``params``.  Falls back to ``fallback`` (default
    :func:`initial_guess`) when the previous plan is degenerate (non-finite, or
    T - dt < t_min); pass NaNs to find out where it did (the planner then computes cold
    guesses only when some robot needs one).
    """
    p, _ = _sanitize(params)
    kc = costs.kind_constants(p.rest, structure)
    b = costs.basis(structure)
    sh = prev.shift(dt)
    T = sh.duration
    ok = jnp.isfinite(T) & (T > p.t_min)
    Ts = jnp.where(ok, T, 1.0)
    tgt = sh.evaluate(Ts * jnp.asarray(b.fit_s))  # (Kf, N)
    e = costs.boundary_vector(p, Ts / structure.segments)
    zt = kc.fit_pinv @ (tgt - kc.fit_B @ e)  # (nz, N)
    x = costs.pack(zt.T, jnp.log(Ts))
    ok = ok & jnp.all(jnp.isfinite(x))
    if fallback is None:
        fallback = initial_guess(params, structure)
    return jnp.where(ok, x, fallback)


# jaxlib 0.10's LAPACK kernels split a batch over XLA's CPU thread pool once it costs
# batch * 5 n^3 >= 2e5 "FLOP" (eigh; jaxlib/cpu/lapack_kernels.cc, GetLapackBatchChunkSize)
# and block a pool thread until the parts finish (ParallelBatchMap).  Two such
# executions at once (two Python threads, or two CPU devices) can leave every pool
# thread waiting: a deadlock at 0% CPU (seen: two threads solving two-segment NLPs).
# So on a CPU _eigh never passes the kernel a batch that it would split.
_LAPACK_SPLIT_COST = 200_000  # the kernel's kMinWorkPerTask
_EIGH_COST = 5  # its cost_per_matrix of eigh, per n^3
UNROLL_EIGH = 8  # _eigh: up to this many calls unrolled, more in a loop


def eigh_chunk(n: int) -> int:
    """The most n x n matrices one CPU eigh call takes without splitting its batch."""
    return max(1, (_LAPACK_SPLIT_COST - 1) // (_EIGH_COST * n ** 3))


def _lapack_safe(fn, per: int = 1):
    """``fn`` of one matrix (n, n) (first argument; LAPACK inside) made safe to vmap on a
    CPU: under vmap the batch goes to LAPACK in calls of at most eigh_chunk(n) matrices
    (cheaper kernels than eigh's split later, so its bound covers them), which jaxlib
    runs on the calling thread (see _LAPACK_SPLIT_COST); elsewhere (a GPU) one batched
    call.  The results are those of the batched call: LAPACK treats each matrix alone.
    Every argument must be batched along with the matrix.

    Nested vmaps (``jax.vmap`` of :func:`solve`, whose steps vmap over a batch of one
    lane) stay safe too: the batched function each level forms is itself made safe, with
    ``per`` the matrices one of its calls already holds, so an outer level chunks its
    batch by eigh_chunk(n) // per (before, the outer vmap batched the inner level's
    LAPACK call whole: a vmapped solve of 640 lanes hung at 0% CPU)."""
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
        many = _lapack_safe(jax.vmap(fn), per * min(k, axis_size))

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


@_lapack_safe
def _eigh(H):
    """(eigenvalues, eigenvectors) of the symmetric H (n, n) by jnp.linalg.eigh (LAPACK
    syevd on a CPU, batched safely: :func:`_lapack_safe`)."""
    return tuple(jnp.linalg.eigh(H))


def _direction(H, grad, reg):
    """-|H|_reg^-1 grad: eigenvalues by magnitude, floored at reg * max|eigenvalue|.

    reg = 1e-13 (~450 x the float64 epsilon, so a floored eigenvalue is still well above
    eigh's rounding).  With large penalties (mu ~ 1e9-1e10, where warm-started fleets
    with close encounters go) the largest eigenvalue is ~1e12, and the former 1e-10
    floored the objective's own curvature: Newton degraded to linear convergence and
    lanes ran to max_iters (bench, 100 robots: 1-4 such lanes per replan, none with
    1e-12..1e-14, and 2x fewer iterations)."""
    w, V = _eigh(H)
    wa = jnp.abs(w)
    floor = reg * jnp.max(wa) + 1e-300
    wm = jnp.maximum(wa, floor)
    d = -V @ ((V.T @ grad) / wm)
    return d


@_lapack_safe
def _newton_cholesky(H, grad, reg):
    """(d, settled) for one H (n, n): the Newton step d = -H^-1 grad by Cholesky (LAPACK
    potrf and a triangular inverse L^-1, then d = -L^-T L^-1 grad: ~0.2-2 us per 7 x 7 -
    16 x 16 matrix on a 2-core CPU, against ~6-23 us for syevd), and whether it is
    :func:`_direction`'s step: H positive definite with lambda_min >= reg * lambda_max,
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
    # on the benchmark's batch, which took 1.02-1.09x less time (interleaved A/B, 20 and
    # 24 rounds, 2026-12-03)
    d = -(Li.T @ (Li @ grad))
    return jnp.where(settled & jnp.all(jnp.isfinite(d)), d, 0.0), settled & jnp.all(
        jnp.isfinite(d))


EIGH_CHUNK = 2  # _directions: matrices per eigh call where Cholesky does not settle it


def _directions(H, grad, need, reg):
    """The Newton directions -|H|_reg^-1 grad of a batch (B, n, n), (B, n) (what
    :func:`_direction` gives), for the lanes where ``need`` (the others: anything finite).

    Where H is positive definite with lambda_min >= reg * lambda_max, no eigenvalue is
    floored and the direction is -H^-1 grad: solved by Cholesky.  That bound is checked
    without eigenvalues: lambda_max <= |H|_F and lambda_min >= 1 / |L^-1|_F^2.  The
    other lanes (indefinite or nearly singular Hessians: about half of the iterations of
    a cold fleet solve) get :func:`_direction`, EIGH_CHUNK lanes per call, in a loop
    that runs as many times as they need, so a batch pays an eigendecomposition only
    for them (on a CPU it costs ~40x the Cholesky)."""
    B, n = grad.shape
    d, well = jax.vmap(_newton_cholesky, in_axes=(0, 0, None))(H, grad, reg)
    use = need & ~well
    order = jnp.argsort(~use, stable=True)  # the lanes that need eigh first
    cnt = jnp.sum(use, dtype=jnp.int32)
    c = min(EIGH_CHUNK, B)
    one = jax.vmap(lambda h, gr: _direction(h, gr, reg))

    def body(carry):
        i, d = carry
        idx = jax.lax.dynamic_slice(order, (i,), (c,))  # clamped to fit: repeats are harmless
        de = one(H[idx], grad[idx])
        d = d.at[idx].set(jnp.where(use[idx][:, None], de, d[idx]))
        return i + c, d

    return jax.lax.while_loop(lambda carry: carry[0] < cnt, body, (jnp.int32(0), d))[1]


def _next_trial(a, g_x: Multipliers, g_a: Multipliers, thr: Multipliers, overshoot):
    """The next backtracking step after the trial at step a failed.

    A constraint whose AL term is inactive at x (g_x >= thr = lam / mu) and active at
    the trial (g_a < thr) crossed into its quadratic branch, where a large mu makes
    L_A steep.  With g taken as linear along the step, the first such crossing is at
    a r, r = min (g_x - thr) / (g_x - g_a); the next trial goes just past it
    (overshoot r a, kept in [a / 1000, a / 2]), so that the constraint is active in the
    next iteration's model.  Without a crossing: a / 2.  (Halving alone took 8-19
    trials to cut such steps back: bench, 100 robots, warm replans with mu ~ 1e6-1e7.)
    """
    frac = jax.tree.map(
        lambda gx, ga, t: jnp.where((gx >= t) & (ga < t), (gx - t) / jnp.maximum(gx - ga, 1e-300),
                                    1.0), g_x, g_a, thr)
    r = jnp.minimum(jnp.min(frac.collision, initial=1.0), jnp.min(frac.limits, initial=1.0))
    return jnp.where(r < 1.0, jnp.clip(overshoot * r, 1e-3, 0.5), 0.5) * a


class _Lane(NamedTuple):
    """What a lane's iterations read besides its state: the sanitized params and the
    bound on tau (the end-kind constants are recomputed from params.rest: cheap)."""

    params: NLPParams
    tau_min: jax.Array
    others: costs.OthersPrep  # the others' predictions as the derivatives read them


def _prepare(params: NLPParams, x0, structure: NLPStructure, s: SolverSettings,
             multipliers, penalty, x_fallback):
    """(lane, start state, finite_in, x0 as used) of one solve (see :func:`solve`)."""
    params, finite_in = _sanitize(params)
    x0 = jnp.asarray(x0, jnp.float64)
    if x_fallback is None:
        x_fallback = initial_guess(params, structure)
    x0 = jnp.where(jnp.all(jnp.isfinite(x0)), x0, x_fallback)
    tau_min = jnp.log(jnp.maximum(params.t_min, 1e-6))
    x0 = x0.at[-1].set(jnp.maximum(x0[-1], tau_min))
    kc = costs.kind_constants(params.rest, structure)
    mult0 = zero_multipliers(params, structure) if multipliers is None else multipliers
    mult0 = jax.tree.map(lambda a: jnp.where(jnp.isfinite(a), jnp.maximum(a, 0.0), 0.0), mult0)
    mu0 = jnp.asarray(s.mu0 if penalty is None else penalty, jnp.float64)
    mu0 = jnp.where(jnp.isfinite(mu0) & (mu0 > 0), mu0, s.mu0)
    # L_A and the constraints at x0 come with the first evaluation; only a solve allowed
    # no iteration at all evaluates them here (for its report)
    unset = (jnp.asarray(jnp.inf, jnp.float64),
             jax.tree.map(jnp.ones_like, zero_multipliers(params, structure)))
    f0, g0 = jax.lax.cond(s.max_iters > 0, lambda: unset, lambda: costs.merit_and_constraints(
        x0, params, structure, kc, mult0, mu0))
    F = lambda v: jnp.asarray(v, jnp.float64)
    st0 = _State(x0, mult0, mu0, g0, f0, F(jnp.inf), jnp.asarray(False), jnp.asarray(0, jnp.int32),
                 jnp.asarray(False), jnp.asarray(False), F(jnp.inf), F(jnp.inf),
                 base=jnp.asarray(True), y=x0, d=jnp.zeros_like(x0), grad=jnp.zeros_like(x0),
                 a=F(0.0), k=jnp.asarray(-1, jnp.int32),
                 obj0=_objective(f0, g0, mult0, mu0, params, structure), viol0=_max_violation(g0))
    lane = _Lane(params, tau_min, costs.prepare_others(params.others, params.other_mask))
    return lane, st0, finite_in, x0


def _objective(f, g: Multipliers, mult: Multipliers, mu, params: NLPParams,
               structure: NLPStructure):
    """The objective at a point from its L_A value f and constraints g there: f less
    the AL terms (as costs._terms adds them), so that results need no second pass over
    the other robots."""
    al = 0.0
    if structure.collision_constraints:
        _, _, _, on = costs._col_samples(params, structure)
        use = params.other_mask[None, :] & on[:, None]
        al = al + jnp.sum(jnp.where(use, costs.al_term(g.collision, mult.collision, mu), 0.0))
    if structure.hard_limits:
        al = al + jnp.sum(costs.al_term(g.limits, mult.limits, mu))
    return f - al


class _Eval(NamedTuple):
    """What one evaluation decided before the Newton direction (:func:`_evaluate`)."""

    more: jax.Array
    x: jax.Array
    g: Multipliers
    f_x: jax.Array
    fy: jax.Array
    pending: jax.Array
    mult: Multipliers
    mu: jax.Array
    viol_ref: jax.Array
    start: jax.Array
    finite: jax.Array
    grp: jax.Array
    Hp: jax.Array
    a_next: jax.Array
    obj0: jax.Array
    viol0: jax.Array


def _active(st: _State, s: SolverSettings):
    """Whether the lane takes another evaluation: not converged, and in a line search or
    with iterations left."""
    return (~st.done) & ~(st.base & (st.it >= s.max_iters))


def _evaluate(st: _State, lane: _Lane, structure: NLPStructure, s: SolverSettings) -> _Eval:
    """The first half of :func:`_step` for one lane: the evaluation at st.y and what it
    decides before the Newton direction (which :func:`_directions` forms for a batch);
    see :func:`_step` for how trials and iterations share evaluations."""
    params, tau_min = lane.params, lane.tau_min
    kc = costs.kind_constants(params.rest, structure)
    n = st.x.shape[0]
    fy, gr, H, gy = costs.merit_derivs(st.y, params, structure, kc, st.mult, st.mu,
                                       with_g=True, others=lane.others)
    # 1. the trial: accepted, another one, or the line search failed
    trial = ~st.base
    ok = trial & jnp.isfinite(fy) & (fy <= st.f + s.armijo * (st.grad @ (st.y - st.x)))
    more = trial & ~ok & (st.k < s.max_backtracks)
    failed = trial & ~ok & ~more
    thr = jax.tree.map(lambda l: l / st.mu, st.mult)  # g < thr: the AL term is active
    a_next = _next_trial(st.a, st.g, gy, thr, s.kink_overshoot)
    # the iterate after this evaluation (an accepted trial, else x) and its constraints
    x = jnp.where(ok, st.y, st.x)
    g = _tree_where(ok | st.base, gy, st.g)
    f_x = jnp.where(ok | st.base, fy, st.f)
    # 2. a line search that ended: the multiplier / penalty update it calls for
    ended = ok | failed
    pending = jnp.where(ended, (st.theta <= s.inner_tol * (1.0 + jnp.abs(st.f))) | failed,
                        st.pending)
    upd = ended & pending & (st.it < s.max_iters)
    lam_new = jax.tree.map(lambda l, gg: jnp.maximum(0.0, l - st.mu * gg), st.mult, g)
    viol = _max_violation(g)
    grow = upd & (viol > s.tol_feasibility) & (viol > s.stall_ratio * st.viol_ref)
    mu = jnp.where(grow, jnp.minimum(st.mu * s.mu_growth, s.mu_max), st.mu)
    mult = _tree_where(upd, lam_new, st.mult)
    viol_ref = jnp.where(upd, viol, st.viol_ref)
    changed = grow | jnp.any(jnp.stack([jnp.any(m != l) for m, l in
                                        zip(jax.tree.leaves(mult), jax.tree.leaves(st.mult),
                                            strict=True)]))
    # 3. an iteration starts at x from this evaluation: at the base, or at an accepted
    # trial whose L_A is unchanged; after a failed search or changed multipliers the
    # next evaluation is at x
    start = st.base | (ok & ~changed & (st.it < s.max_iters))
    held = (x[-1] <= tau_min + 1e-12) & (gr[-1] > 0)
    grp = gr.at[-1].set(jnp.where(held, 0.0, gr[-1]))
    Hp = jnp.where(held, H.at[-1, :].set(0.0).at[:, -1].set(0.0).at[-1, -1].set(1.0), H)
    finite = jnp.isfinite(fy) & jnp.all(jnp.isfinite(grp)) & jnp.all(jnp.isfinite(Hp))
    grp = jnp.where(finite, grp, 0.0)
    Hp = jnp.where(finite, Hp, jnp.eye(n))
    first = st.base & (st.it == 0)  # the evaluation at x0
    obj0 = jnp.where(first, _objective(fy, gy, st.mult, st.mu, params, structure), st.obj0)
    viol0 = jnp.where(first, _max_violation(gy), st.viol0)
    return _Eval(more=more, x=x, g=g, f_x=f_x, fy=fy, pending=pending, mult=mult, mu=mu,
                 viol_ref=viol_ref, start=start, finite=finite, grp=grp, Hp=Hp, a_next=a_next,
                 obj0=obj0, viol0=viol0)


def _advance(st: _State, lane: _Lane, ev: _Eval, d, s: SolverSettings) -> _State:
    """The second half of :func:`_step` for one lane: the tests at the iterate, and the
    next evaluation point, given the Newton direction d there (-|H|_reg^-1 grad)."""
    tau_min = lane.tau_min
    more, x, g, f_x, fy, pending, mult, mu, viol_ref, start, finite, grp = (
        ev.more, ev.x, ev.g, ev.f_x, ev.fy, ev.pending, ev.mult, ev.mu, ev.viol_ref, ev.start,
        ev.finite, ev.grp)
    a_next = ev.a_next
    theta = -grp @ d
    scale = 1.0 + jnp.abs(fy)
    lam_t = jax.tree.map(lambda l, gg: jnp.maximum(0.0, l - mu * gg), mult, g)
    compl = jnp.maximum(jnp.max(lam_t.collision * jnp.abs(g.collision), initial=0.0),
                        jnp.max(lam_t.limits * jnp.abs(g.limits), initial=0.0))
    conv = (theta <= s.tol_stationarity * scale) & (_max_violation(g) <= s.tol_feasibility) & (
        compl <= s.tol_complementarity * scale)
    cap = jnp.minimum(1.0, s.max_step_tau / jnp.maximum(jnp.abs(d[-1]), 1e-300))
    cap = jnp.minimum(
        cap, s.max_step_z / jnp.maximum(jnp.max(jnp.abs(d[:-1]), initial=0.0), 1e-300))
    d = d * cap
    stop = start & (conv | ~finite)  # converged at x (or non-finite): no step
    search = start & ~stop
    point = lambda xb, dd, a: (xb + a * dd).at[-1].max(tau_min)
    # 4. the next evaluation: the first trial of a new search, the next trial, or x
    a_new = jnp.where(search, 1.0, jnp.where(more, a_next, 0.0))
    d_new = jnp.where(search, d, st.d)
    y_new = jnp.where(search | more, point(x, d_new, a_new), x)
    new = _State(
        x=x, mult=mult, mu=mu, g=g, f=f_x, viol_ref=viol_ref, pending=pending,
        it=jnp.where(search, st.it + 1, st.it), done=stop, bad=start & ~finite,
        kkt=jnp.where(start, jnp.max(jnp.abs(grp)), st.kkt),
        theta=jnp.where(start, theta, st.theta), base=~(search | more), y=y_new, d=d_new,
        grad=jnp.where(search, grp, st.grad), a=a_new,
        k=jnp.where(search, 0, jnp.where(more, st.k + 1, -1)).astype(jnp.int32),
        obj0=ev.obj0, viol0=ev.viol0)
    return _tree_where(_active(st, s), new, st)  # an inactive lane is returned as is


def _step(st: _State, lane: _Lane, structure: NLPStructure, s: SolverSettings) -> _State:
    """One evaluation of a batch of lanes (leading axis): the derivatives of L_A (and the
    constraints) at each lane's st.y, then what they decide (module doc); an inactive
    lane (:func:`_active`) is returned as is.

    In a line search, y is a trial: it is accepted (Armijo on L_A) or the next trial
    is set (cut back past the first AL branch crossing, else halved: _next_trial).  An
    accepted trial is the next iterate, and its derivatives, already at hand, start the
    next iteration unless the multipliers change there (then the next evaluation is at
    the iterate again, with the new ones).  So a trial costs the derivatives (a merit
    value alone would do for a rejected one), and no lane waits for another's
    backtracking: a pool step is one evaluation per lane.  The iterates are those of an
    SQP iteration "multiplier update, derivatives at x, step, backtracking line search"."""
    ev = jax.vmap(lambda a, b: _evaluate(a, b, structure, s))(st, lane)
    d = _directions(ev.Hp, ev.grp, ev.start & _active(st, s), s.reg)
    return jax.vmap(lambda a, b, e, dd: _advance(a, b, e, dd, s))(st, lane, ev, d)


def _finish(st: _State, lane: _Lane, finite_in, x0, structure: NLPStructure,
            s: SolverSettings) -> Solution:
    """The Solution of a lane whose iterations ended (state ``st``)."""
    params = lane.params
    bad = st.bad | ~finite_in | ~jnp.all(jnp.isfinite(st.x))
    x = jnp.where(bad, x0, st.x)
    # st.g and st.f are the constraints and L_A at st.x: no second pass over the others
    viol = jnp.where(bad, st.viol0, _max_violation(st.g))
    conv = st.done & ~bad
    status = jnp.where(bad, NON_FINITE, jnp.where(conv, CONVERGED,
                       jnp.where(viol > s.tol_feasibility, INFEASIBLE, MAX_ITERS))
                       ).astype(jnp.int32)
    traj = costs.to_trajectory(x, params, structure)
    traj_ok = jnp.all(jnp.isfinite(traj.coeffs)) & jnp.all(jnp.isfinite(traj.breaks))
    hold = Trajectory.hold(params.p0, structure.degree, structure.segments)
    traj = _tree_where(traj_ok, traj, hold._replace(coast=traj.coast))
    obj = jnp.where(bad, st.obj0, _objective(st.f, st.g, st.mult, st.mu, params, structure))
    eq = costs.equality_residual(x, params, structure)
    no_nan = lambda a: jnp.where(jnp.isnan(a), jnp.inf, a)
    return Solution(
        x=x, traj=traj, objective=no_nan(obj), status=status, iterations=st.it,
        kkt_residual=no_nan(st.kkt), eq_violation=no_nan(eq),
        ineq_violation=no_nan(viol), multipliers=st.mult, penalty=st.mu,
        decrement=no_nan(st.theta),
    )


def solve(params: NLPParams, x0, structure: NLPStructure,
          settings: SolverSettings = SolverSettings(),
          multipliers: Multipliers | None = None, penalty=None, x_fallback=None) -> Solution:
    """Solve one robot's NLP from x0 (pure; vmap/jit at the call site).

    Args:
        params: NLPParams of one problem.  x0: (n_x,) start (initial_guess / warm_start).
        structure: static NLPStructure.  settings: SolverSettings (traced).
        multipliers, penalty: optional warm start of the augmented Lagrangian (e.g. the
            previous Solution's); default zeros and settings.mu0.
        x_fallback: (n_x,) start used where x0 is not finite; default
            :func:`initial_guess` (which then costs its evaluation under vmap even where
            x0 is finite: a caller that already has a finite x0 or a guess passes it).
    Returns:
        Solution.
    """
    s = settings
    lane, st0, finite_in, x0 = _prepare(params, x0, structure, s, multipliers, penalty,
                                        x_fallback)
    one = lambda t: jax.tree.map(lambda a: a[None], t)
    lane1 = one(lane)  # a batch of one lane, as _step takes it
    st = jax.lax.while_loop(lambda st: _active(st, s)[0],
                            lambda st: _step(st, lane1, structure, s), one(st0))
    return _finish(jax.tree.map(lambda a: a[0], st), lane, finite_in, x0, structure, s)


def solve_lanes(params: NLPParams, x0, structure: NLPStructure,
                settings: SolverSettings = SolverSettings(),
                multipliers: Multipliers | None = None, penalty=None, x_fallback=None,
                pool: int | None = None) -> Solution:
    """:func:`solve` over one leading axis of B lanes, ``pool`` lanes stepped at a time.

    Under a plain vmap every lane runs for as many iterations as the slowest lane needs
    (the finished ones idle).  Here a pool of ``pool`` slots steps together; a slot
    whose lane finishes takes the next unstarted lane.  Each lane still takes exactly
    the iterations of :func:`solve` (the same results), but the work is about the sum of
    the lanes' iterations instead of B times the largest.  pool = B (or None) is the
    plain vmap.  A batch of at most LOCKSTEP_MAX lanes first steps all its lanes in
    lockstep while more than half are active (:func:`_pooled`).  On a CPU, where a step
    costs a fixed part plus about in proportion to its lanes, a small pool pays when
    iteration counts are uneven; on a GPU a step of B lanes costs about what one of a
    few lanes costs, so pool = B is right there (:func:`default_pool`).
    Pure; jit at the call site (``pool`` and ``structure`` are static).
    """
    s = settings
    B = x0.shape[0]
    pool = B if pool is None else max(1, min(int(pool), B))
    if x_fallback is None:  # cold guesses (20 objective and 5 merit values each) only if needed
        x_fallback = jax.lax.cond(
            jnp.all(jnp.isfinite(x0)), lambda: jnp.zeros_like(x0),
            lambda: jax.vmap(lambda p: initial_guess(p, structure))(params))
    lane, st, finite_in, x0u = jax.vmap(
        lambda p, x, m, pe, xf: _prepare(p, x, structure, s, m, pe, xf),
        in_axes=(0, 0, None if multipliers is None else 0, None if penalty is None else 0, 0),
    )(params, x0, multipliers, penalty, x_fallback)
    step = lambda st, ln: _step(st, ln, structure, s)
    if pool == B:
        st = jax.lax.while_loop(lambda st: jnp.any(_active(st, s)),
                                lambda st: step(st, lane),
                                st)
    else:
        st = _pooled(st, lane, step, pool, s)
    return jax.vmap(lambda st, ln, fi, x: _finish(st, ln, fi, x, structure, s))(
        st, lane, finite_in, x0u)


def _pooled(st_all: _State, lane_all: _Lane, step, C: int, s: SolverSettings) -> _State:
    """Run every lane of ``st_all`` (B lanes) to its end: for B <= LOCKSTEP_MAX, all B
    in lockstep while more than half of them (and more than C) are active; then the
    rest with C slots (see solve_lanes).

    A step costs a fixed part (XLA's per-kernel overheads: ~0.13 ms on a 2-core CPU)
    plus a part per lane, active or not.  Lockstep pays the fixed part once for all
    lanes, and wastes the idle lanes' part; slots waste nothing but pay the fixed part
    per C lanes.  So the common first iterations run in lockstep and the stragglers in
    slots (a lane that needs 60 iterations does not hold B - 1 idle lanes for them).
    Larger batches go to the slots at once: there lockstep cost more than it saved
    (measured when a step still held a whole line search, so that every lane waited for
    the slowest backtracking: 100 cold robots with 16 neighbours, 603 ms vs 281 ms; not
    re-measured since a step is one evaluation per lane).
    """
    B = st_all.it.shape[0]
    take = lambda tree, idx: jax.tree.map(lambda a: jnp.take(a, idx, axis=0, mode="clip"), tree)
    if B <= LOCKSTEP_MAX:
        many = max(C, B // 2)
        st_all = jax.lax.while_loop(
            lambda st: jnp.sum(_active(st, s)) > many,
            lambda st: step(st, lane_all), st_all)
    # the lanes still active, in lane order; queue[j] for j < n_act
    act = _active(st_all, s)
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
        fin = sl_valid & ~_active(sl_st, s)
        # finished lanes go home; free slots take the next queued lanes in order
        st_all = jax.tree.map(
            lambda a, u: a.at[jnp.where(fin, sl, B)].set(u, mode="drop"), st_all, sl_st)
        free = fin | ~sl_valid
        new = nxt + jnp.cumsum(free, dtype=jnp.int32) - 1
        refill = free & (new < n_act)
        sl = jnp.where(refill, lane_of(new), jnp.where(free, B, sl))
        sl_valid = (sl_valid & ~fin) | refill
        nxt = jnp.minimum(nxt + jnp.sum(free, dtype=jnp.int32), n_act)
        sl_st = _tree_where_lanes(refill, take(st_all, sl), sl_st)
        sl_lane = _tree_where_lanes(refill, take(lane_all, sl), sl_lane)
        return st_all, sl, sl_st, sl_lane, nxt, sl_valid

    sl0 = lane_of(pos)
    c0 = (st_all, sl0, take(st_all, sl0), take(lane_all, sl0), jnp.minimum(C, n_act),
          pos < n_act)
    return jax.lax.while_loop(cond, body, c0)[0]


LOCKSTEP_MAX = 32  # batches up to this size start in lockstep (_pooled)
POOL_CPU = 2  # lanes per step on a CPU (measured on 2 cores: see default_pool)
POOL_CPU_FEW = 12  # ... in a batch of more than LOCKSTEP_MAX NLPs with few others each
FEW_OTHERS = 16  # "few": at most this many other robots per NLP


def default_pool(batch: int, backend: str | None = None, n_others: int | None = None) -> int:
    """The pool size :func:`solve_batch` and the planner use: on a CPU, POOL_CPU_FEW (12)
    lanes for a batch of more than LOCKSTEP_MAX NLPs with at most FEW_OTHERS other
    robots each (``n_others``: the other-robot slots of an NLP, masked ones included),
    else POOL_CPU (2); B elsewhere.

    Measured on a 2-core CPU (2026-12-01, one evaluation per step; `jaxplan bench
    solver` NLPs, each batch split over the two CPU devices, medians of 10 interleaved in
    one process): the 64 x 10 cold batch (9 others) took 218 / 215 / 200 / 190 / 205 ms
    with pools 6 / 8 / 10 / 12 / 16 per device (an earlier, faster hour: 139 / 136 / 140
    / 141 / 147 / 155 ms with 8 / 12 / 16 / 24 / 32 / 48); 100 robots with 16 neighbours
    118 / 107 / 112 ms cold with 4 / 8 / 12 (warm 24 / 24 / 24) and 163 / 106 / 97 / 121 /
    133 ms cold with 2 / 4 / 8 / 16 / 32 earlier; with all 99 others 310 / 332 / 457 /
    619 ms cold with 2 / 8 / 16 / 32 (warm 58 / 72 / 81 / 166).  A step costs a fixed
    part (XLA's per-kernel overheads) plus a part per lane: wide pools share the fixed
    part, but once the per-lane arrays grow (many others) caches lose.  Warm 10-robot
    replans: 2.2-2.5 ms for pools 2-10 (they start in lockstep, :func:`_pooled`)."""
    backend = backend or jax.default_backend()
    if backend != "cpu":
        return batch
    few = n_others is not None and n_others <= FEW_OTHERS and batch > LOCKSTEP_MAX
    return max(1, min(batch, POOL_CPU_FEW if few else POOL_CPU))


_STRONG_DTYPES = (jnp.dtype(jnp.float64), jnp.dtype(jnp.int32), jnp.dtype(bool))


def _strong(tree):
    """Leaves as strongly typed arrays (float64 / int32 / bool), so that Python scalars
    and weakly typed arrays hit the same compiled function as float64 arrays."""
    def f(a):
        if isinstance(a, jax.Array) and not a.weak_type and a.dtype in _STRONG_DTYPES:
            return a  # already strong: no conversion (a tree map of jnp.asarray over
            # every leaf cost ~2 ms per call, a fifth of a warm 10-robot replan)
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
    """How many devices :func:`solve_batch` splits a batch of ``batch`` NLPs over: on a
    CPU with several devices (``jax.devices("cpu")``; jaxplan makes one per core, see
    :mod:`jaxplan`), all of them for a batch of more than LOCKSTEP_MAX NLPs, else 1.
    Elsewhere 1 (a GPU steps all lanes of a batch at once).

    Measured on a 2-core CPU (2 devices against 1, the `jaxplan bench solver` NLPs,
    medians of 5; 2026-12-01, after _eigh): in one process the 64 x 10 cold batch 1.46x
    faster, its first 64 NLPs 1.37x, 100 robots with 16 neighbours 1.48x warm and 1.63x
    cold, with all 99 others 1.27x warm; in separate processes (JAXPLAN_CPU_DEVICES=1
    against the default, twice) the batch 1.46x / 1.22x, 100 cold robots with 16
    neighbours 2.4x / 1.5x, 100 warm robots with all others 1.50x / 1.56x.  Warm
    10-robot replans stay on one device (split, measured earlier the same day: 0.75x,
    too little work per device).
    One XLA program on a CPU runs its kernels one after another; two devices run their
    halves side by side.  (Before _eigh, two devices could deadlock in LAPACK.)"""
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


@functools.partial(jax.jit, static_argnames=("structure", "pool", "shards"))
def _solve_batch_jit(params, x0, structure, settings, multipliers, penalty, pool, shards=1,
                     x_fallback=None):
    lead = jnp.shape(params.radius)  # radius: () per problem
    flat = lambda t: None if t is None else jax.tree.map(
        lambda a: a.reshape((-1,) + a.shape[len(lead):]), t)
    if x_fallback is None:
        x_fallback = x0

    def lanes(p, x, m, u, xf):
        if x is None:  # a cold start: each shard forms its own lanes' guesses
            x = xf = jax.vmap(lambda q: initial_guess(q, structure))(p)
        return solve_lanes(p, x, structure, settings, m, u, pool=pool, x_fallback=xf)

    args = (flat(params), flat(x0), flat(multipliers), flat(penalty), flat(x_fallback))
    sol = lanes(*args) if shards == 1 else shard_lanes(lanes, args, shards)
    return jax.tree.map(lambda a: a.reshape(lead + a.shape[1:]), sol)


def solve_batch(params: NLPParams, x0, structure: NLPStructure,
                settings: SolverSettings = SolverSettings(),
                multipliers: Multipliers | None = None, penalty=None,
                pool: int | None = None, shards: int | None = None) -> Solution:
    """:func:`solve` over all leading axes of x0 (..., n_x) and params (same leading
    axes), jitted; ``settings`` is shared.  x0 = None: a cold start, every problem from
    its :func:`initial_guess`, formed in the same compiled program as the solve (each
    CPU device forms its own problems' guesses: the same guesses as
    :func:`initial_guess_batch`, without a second call and its wait for every device).
    Weights, limits and settings are traced: new values (Python scalars or arrays)
    reuse the compiled function (``_solve_batch_jit``).
    ``shards``: CPU devices the problems are split over (default :func:`default_shards`
    of the number of problems; at most ``len(jax.devices("cpu"))``).  ``pool``: lanes
    stepped at a time on each (:func:`solve_lanes`; default :func:`default_pool` of the
    problems per shard and of the other robots per problem).  Each problem takes the
    same iterations whatever the pool and shards; with shards the compiled code differs,
    so results can differ by rounding.  A problem whose x0 is not finite starts from
    :func:`initial_guess` (formed by a separate call, only then)."""
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
    params = _strong(params)
    x0 = None if x0 is None else _strong(x0)
    # the lanes whose x0 is not finite start from initial_guess (as solve() does); it is
    # formed by a call of its own, only when needed, so that the solver's program does
    # not carry it (~2 s of its ~8-14 s compile time)
    x_fallback = x0
    if x0 is not None and not np.all(np.isfinite(np.asarray(x0))):
        x_fallback = initial_guess_batch(
            jax.tree.map(lambda a: a.reshape((-1,) + a.shape[x0.ndim - 1:]), params),
            structure).reshape(x0.shape)
    return _solve_batch_jit(params, x0, structure, _strong(settings),
                            None if multipliers is None else _strong(multipliers),
                            None if penalty is None else _strong(penalty), pool, shards,
                            x_fallback)


def initial_guess_batch(params: NLPParams, structure: NLPStructure,
                        shards: int | None = None):
    """initial_guess over one leading batch axis, jitted; split over ``shards`` CPU
    devices (default :func:`default_shards` of the batch size, as :func:`solve_batch`)."""
    B = jax.tree.leaves(params)[0].shape[0]
    shards = default_shards(B) if shards is None else max(1, min(int(shards), B))
    return _initial_guess_jit(_strong(params), structure, shards)


@functools.partial(jax.jit, static_argnames=("structure", "shards"))
def _initial_guess_jit(params, structure, shards):
    fn = jax.vmap(lambda p: initial_guess(p, structure))
    return fn(params) if shards == 1 else shard_lanes(fn, (params,), shards)


def solve_differentiable(params: NLPParams, x0, structure: NLPStructure,
                         settings: SolverSettings = SolverSettings(),
                         multipliers: Multipliers | None = None, penalty=None) -> Solution:
    """:func:`solve`, with ``x``, ``traj`` and ``objective`` differentiable with respect
    to ``params.weights`` (q_dynm, q_obs, q_lim, k_t, k_p) by implicit differentiation
    (jaxopt ``custom_root``): for tuning weights by gradient.

    The forward pass is :func:`solve` (no gradient flows through its iterations).  The
    derivative is that of the root of the optimality condition at the solution: the
    gradient of the augmented Lagrangian in x, with the solution's multipliers and
    penalty held fixed (and, where T sits at its lower bound t_min, T held there).
    Exact for the modes without collision constraints ("barrier", "paper", "none").  With
    collision constraints it is the derivative of the augmented-Lagrangian subproblem, in
    which an active constraint acts as a spring of stiffness ``penalty`` rather than a
    rigid wall: an approximation, closer the larger the penalty.  Meaningful where
    ``status`` is CONVERGED.  Pure; jit/vmap at the call site.
    """
    from jaxopt.implicit_diff import custom_root
    from jaxopt.linear_solve import solve_lu

    sol = jax.lax.stop_gradient(solve(jax.lax.stop_gradient(params), x0, structure, settings,
                                      multipliers, penalty))
    p_s, _ = _sanitize(params)
    kc = costs.kind_constants(p_s.rest, structure)
    tau_min = jnp.log(jnp.maximum(jax.lax.stop_gradient(p_s.t_min), 1e-6))

    def grad_al(x, weights):
        return jax.grad(costs.merit)(x, p_s._replace(weights=weights), structure, kc,
                                     sol.multipliers, sol.penalty)

    g_end = jax.lax.stop_gradient(grad_al(sol.x, p_s.weights))
    held = (sol.x[-1] <= tau_min + 1e-12) & (g_end[-1] > 0)

    def optimality(x, weights):
        g = grad_al(x, weights)
        return g.at[-1].set(jnp.where(held, x[-1] - tau_min, g[-1]))

    @custom_root(optimality, solve=solve_lu)
    def root(x_init, weights):
        del weights  # the forward solution is sol.x (computed above)
        return x_init

    x = root(sol.x, p_s.weights)
    traj = costs.to_trajectory(x, p_s, structure)
    traj = _tree_where(jnp.all(jnp.isfinite(sol.traj.coeffs)) & (sol.status != NON_FINITE),
                       traj, sol.traj)
    obj = costs._terms(x, p_s, structure, kc, None, 1.0)
    return sol._replace(x=x, traj=traj, objective=jnp.where(jnp.isnan(obj), jnp.inf, obj))
