"""Starting points of a solve: :func:`initial_guess` (cold: the closed-form prediction,
a horizon grid, a swerve stage), :func:`swerve_guess` and :func:`warm_start` (the previous
plan shifted and re-fitted).  docs/SOLVER.md ("Starting points") gives the measurements behind
the choices.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan import nlp
from jaxplan.nlp import NLPParams, NLPStructure
from jaxplan.predict import predict_arrays
from jaxplan.solve.types import SolverSettings, sanitize, zero_multipliers
from jaxplan.trajectory import Trajectory

GUESS_SHAPES = (0.0, 0.5)  # free ends: z = alpha z_rest(T) (initial_guess)
GUESS_T_FACTORS = np.geomspace(0.5, 8.0, 25)  # the grid of horizons (x the prediction's)
GUESS_SWERVE = 1.5  # swerve candidates' RMS displacement / rho_max (swerve_guess)
GUESS_SWERVE_PENALTY = SolverSettings._field_defaults["mu0"]  # swerve_guess's AL penalty
GUESS_SWERVE_TIE = 1e-12  # swerve_guess: merits within this (relative) of the least tie
GUESS_STEPS = (8, 4, 2, 1)  # initial_guess's bisection of that grid (its 25 = 3 x 8 + 1 points)
# the bisection is exact for a unimodal objective only if the grid is 1 + a multiple of
# the first step and each step halves the last down to 1
assert (len(GUESS_T_FACTORS) - 1) % GUESS_STEPS[0] == 0 and GUESS_STEPS == tuple(
    GUESS_STEPS[0] >> i for i in range(GUESS_STEPS[0].bit_length())), GUESS_STEPS


def rest_shape(structure: NLPStructure) -> np.ndarray:
    """G (nz, 6): z = G e(h) puts the rest end's minimum-jerk path (z = 0 of the rest
    kind, through e(h)'s end velocity and acceleration) into the free-end
    parametrization: the free kind holds every rest path (it has fewer end conditions),
    so the least-squares fit is exact."""
    b = nlp.basis(structure)
    return np.linalg.pinv(b.free.Z) @ (b.rest.P - b.free.P)


def initial_guess(params: NLPParams, structure: NLPStructure, swerve: bool = True) -> jax.Array:
    """x0 from the robot's own closed-form minimum time-jerk prediction to its goal.

    z = 0 is exactly the minimum-jerk path for a given T (:mod:`jaxplan.nlp`).  T starts
    from the prediction's optimal horizon with time weight k_t / q_dynm and is then
    chosen on a geometric grid (x0.5 .. x8, and >= t_min) to minimize the objective
    without collision terms (smoothness + time + soft limits), so that x0 does not
    start deep in the exponential soft limits.  For a free end the shape is chosen
    with T, among z = alpha z_rest(T) for alpha in GUESS_SHAPES, where z_rest(T) is
    the rest end's minimum-jerk path (slowing to the goal's end velocity,
    :func:`rest_shape`): alpha = 0 is the free end's minimum-jerk path, which ends at
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
    about half its cost.  Last, :func:`swerve_guess` may bend the chosen path across itself
    (right, left, up or down), where the collision terms say a swerve beats the straight
    line through the others' predictions (``swerve=False``: the grid's choice alone).
    Finite for any input.
    """
    p, _ = sanitize(params)
    w = p.weights.k_t / jnp.maximum(p.weights.q_dynm, 1e-12)
    w = jnp.where(jnp.isfinite(w) & (w > 0), w, 1.0)
    pred = predict_arrays(p.p0, p.v0, p.a0, p.goal_p, p.goal_v, p.goal_a, p.rest, w)
    T = pred.duration
    tmin = jnp.where(jnp.isfinite(p.t_min) & (p.t_min > 0), p.t_min, 1e-3)
    T = jnp.where(jnp.isfinite(T), jnp.maximum(T, tmin), tmin)
    free = dataclasses.replace(structure, collision="none", hard_limits=False)
    kind = nlp.kind_constants(p.rest, free)
    K = len(GUESS_T_FACTORS)
    taus = jnp.log(jnp.maximum(T * jnp.asarray(GUESS_T_FACTORS), tmin))  # (K,)
    G = jnp.asarray(rest_shape(structure))
    al = jnp.where(jnp.asarray(p.rest, bool), 0.0, jnp.asarray(GUESS_SHAPES))  # (A,)

    def candidates(idx):  # (A, m) grid indices -> x (A, m, n_x), objective (A, m)
        t = taus[idx]
        zr = jax.vmap(lambda tt: (G @ nlp.boundary_vector(p, jnp.exp(tt) / structure.segments)
                                  ).T.reshape(-1))(t.reshape(-1)).reshape(t.shape + (-1,))
        xs = jnp.concatenate([al[:, None, None] * zr, t[..., None]], axis=-1)
        fs = jax.vmap(lambda x: nlp.evaluate_terms(x, p, free, kind, None, 1.0))(
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
        x = swerve_guess(x, p, structure)
    return jnp.where(jnp.all(jnp.isfinite(x)), x, jnp.zeros_like(x).at[-1].set(jnp.log(tmin)))


def _crossing_directions(p: NLPParams, N: int) -> list:
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


def swerve_guess(x, p: NLPParams, structure: NLPStructure):
    """initial_guess's last stage: x, or x with a swerve across its path, whichever has
    the lower merit (the objective with the collision terms, zero multipliers and the
    default penalty).

    The candidates add GUESS_SWERVE (rho_max) along each direction of
    :func:`_crossing_directions`, both signs (right, left, up, down), to the shape
    variable of the smoothest mode of the lane's end kind (z[:, 0], the mode of least
    jerk per unit of RMS displacement, jaxplan.nlp.basis: an RMS displacement of
    GUESS_SWERVE rho_max over the plan, 1.6-1.7x
    that at its peak), where rho_max = own radius + the largest other radius, at the
    horizon already chosen.  Straight guesses put the robots of a crossing into one
    another: on the benchmark's 640 antipodal NLPs the solutions swerve (RMS 0.6 m up or
    down, 0.15 m sideways, where rho = 0.5 m), and this stage took the iterations from
    4,851 to 3,152 (objectives: 45 lanes better, 30 worse by the local minimum reached,
    mean -0.005) at 4 extra merit values per lane (nlp.merit_shapes).  Ties (within
    GUESS_SWERVE_TIE) keep the first candidate in the order x, right, left, up, down:
    two robots head-on, each predicting the other straight, both swerve to their right
    and pass.  Only with sampled collision terms (x otherwise: no swerve can pay)."""
    N, nz = structure.n_dim, structure.nz
    dirs = _crossing_directions(p, N)
    if not dirs or not nz or not nlp.has_sampled_collision(structure):
        return x
    kind = nlp.kind_constants(p.rest, structure)
    rho = p.radius + jnp.max(jnp.where(p.other_mask, p.other_radius, 0.0), initial=0.0)
    z, tau = nlp.unpack(x, structure)
    amp = GUESS_SWERVE * jnp.where(jnp.isfinite(rho) & (rho > 0), rho, 0.0)
    zs = [z] + [z.at[:, 0].add(sg * amp * w) for w in dirs for sg in (1.0, -1.0)]
    zs = jnp.stack(zs)
    f = nlp.merit_shapes(zs, tau, p, structure, kind, zero_multipliers(p, structure),
                           GUESS_SWERVE_PENALTY)
    f = jnp.where(jnp.isfinite(f), f, jnp.inf)
    # the first candidate within rounding of the least (exact ties differ in the last bits)
    first = jnp.argmax(f <= jnp.min(f) + GUESS_SWERVE_TIE * (1.0 + jnp.abs(jnp.min(f))))
    return nlp.pack(zs[first], tau)


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
    p, _ = sanitize(params)
    kind = nlp.kind_constants(p.rest, structure)
    b = nlp.basis(structure)
    sh = prev.shift(dt)
    T = sh.duration
    ok = jnp.isfinite(T) & (T > p.t_min)
    Ts = jnp.where(ok, T, 1.0)
    tgt = sh.evaluate(Ts * jnp.asarray(b.fit_s))  # (Kf, N)
    e = nlp.boundary_vector(p, Ts / structure.segments)
    zt = kind.fit_pinv @ (tgt - kind.fit_B @ e)  # (nz, N)
    x = nlp.pack(zt.T, jnp.log(Ts))
    ok = ok & jnp.all(jnp.isfinite(x))
    if fallback is None:
        fallback = initial_guess(params, structure)
    return jnp.where(ok, x, fallback)
