"""The reference values of the NLP's objective and constraints (docs/MATH.md section 2):
each term written plainly, per sample, differentiable by autodiff.

:func:`objective`, :func:`constraints`, :func:`merit` (the augmented Lagrangian) and
:func:`evaluate_terms` (all of them in one pass) are what the solver's results and the
reference solver (:mod:`jaxplan.reference`) use; :mod:`jaxplan.nlp.derivs` computes the
same values with hand-structured derivatives and is checked against these
(tests/test_costs.py).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxplan.nlp.basis import basis, boundary_vector, falling, kind_constants, unpack
from jaxplan.nlp.types import DIST_EPS2, SEXP_KNEE, Limits, Multipliers, NLPParams, NLPStructure
from jaxplan.trajectory import Trajectory
from jaxplan.world import centres_at, signed_distance


# ---------------------------------------------------------------------- features
def _features(x, params, structure, mats, derivs):
    """Own derivatives at a sample set: concat([X_r (K, N) for r in derivs] + [T]) -> (K, m)."""
    z, tau = unpack(x, structure)
    T = jnp.exp(tau)
    h = T / structure.segments
    e = boundary_vector(params, h)
    ez = jnp.concatenate([e, z.T], axis=0)  # (6 + nz, N)
    out = [(mats[r] @ ez) / h**r for r in derivs]
    K = mats.shape[1]
    out.append(jnp.broadcast_to(T, (K, 1)))
    return jnp.concatenate(out, axis=-1)


def coast_time(limits: Limits):
    """Length t_c (s) of the coast checked after a free end: v_max / (2 a_max) +
    a_max / (2 j_max), so that the coast at any speed v <= v_max, v t_c, is at least the
    distance v^2 / (2 a_max) + v a_max / (2 j_max) of a jerk-limited stop from v (from
    zero acceleration; exact for v >= a_max^2 / j_max)."""
    return limits.v_max / (2.0 * limits.a_max) + limits.a_max / (2.0 * limits.j_max)


def collision_rows(params, structure):
    """Collision rows: (s, off, w, on) (n_col,) each.  Row k is at time T s_k + off_k;
    w_k its barrier quadrature weight; on_k whether its constraint is active."""
    b = basis(structure)
    s = jnp.asarray(b.col_s)
    Kc = len(b.col_s)
    off = jnp.zeros(Kc)
    w = jnp.asarray(b.col_w)
    on = jnp.ones(Kc, bool)
    n = structure.n_coast
    if n:
        sig = jnp.arange(1, n + 1) / n
        s = jnp.concatenate([s, jnp.ones(n)])
        off = jnp.concatenate([off, sig * coast_time(params.limits)])
        w = jnp.concatenate([w, jnp.zeros(n)])
        on = jnp.concatenate([on, jnp.broadcast_to(~jnp.asarray(params.rest, bool), (n,))])
    return s, off, w, on


def _col_features(x, params, structure, kind, derivs):
    """:func:`_features` at the collision samples, then (coast) the positions
    p(T) + v(T) t_c k / n (derivs must be (0,) when there are coast rows)."""
    y = _features(x, params, structure, kind.col, derivs)
    n = structure.n_coast
    if not n:
        return y
    N = structure.n_dim
    e = _features(x, params, structure, kind.end, (0, 1))[0]  # (p(T), v(T), T)
    t = jnp.arange(1, n + 1) / n * coast_time(params.limits)
    yk = jnp.concatenate([e[:N] + t[:, None] * e[N : 2 * N], jnp.broadcast_to(e[-1], (n, 1))],
                         axis=-1)
    return jnp.concatenate([y, yk], axis=0)


def others_derivs(others: Trajectory, mask, t, R: int):
    """Derivatives 0..R of the others at times t (K,) -> list of (K, Mo, N).

    After an other's end time it holds (coast False) or coasts (coast True).
    """
    c = others.coeffs
    b = others.breaks
    ok = mask & jnp.all(jnp.isfinite(c), axis=(-1, -2, -3)) & jnp.all(jnp.isfinite(b), axis=-1)
    c = jnp.where(ok[:, None, None, None], c, 0.0)
    b = jnp.where(ok[:, None], b, 0.0)
    So, N, Kd = c.shape[-3:]
    To = b[:, -1]
    tt = t[:, None]
    tc = jnp.clip(tt, 0.0, To[None, :])  # (K, Mo)
    if So == 1:  # closed-form predictions: one segment, nothing to look up
        lo, hi = b[None, :, 0], b[None, :, 1]
        ck = c[None, :, 0]  # (1, Mo, N, Kd)
    else:  # the segment of each time, selected elementwise (a gather was slower on a CPU)
        k = jnp.clip(jnp.sum(b[None, :, 1:So] <= tc[..., None], axis=-1), 0, So - 1)
        sel = [k == i for i in range(So)]
        pick = lambda arr: sum(jnp.where(m, a, 0.0) for m, a in zip(sel, arr, strict=True))
        lo = pick([b[None, :, i] for i in range(So)])
        hi = pick([b[None, :, i + 1] for i in range(So)])
        ck = sum(jnp.where(m[..., None, None], c[None, :, i], 0.0) for i, m in enumerate(sel))
    h = hi - lo
    he = jnp.where(h > 0, h, 1.0)
    s = jnp.where(h > 0, (tc - lo) / he, 0.0)
    vals = []
    for r in range(max(R, 1) + 1):
        if r < Kd:
            f = jnp.asarray([falling(i, r) for i in range(r, Kd)], c.dtype)
            cr = ck[..., r:] * f
            v = cr[..., -1]
            for i in range(cr.shape[-1] - 2, -1, -1):
                v = v * s[..., None] + cr[..., i]
            vals.append(v / he[..., None] ** r)
        else:
            vals.append(jnp.zeros(ck.shape[:-1], c.dtype))
    after = (tt > To[None, :])[..., None]
    coast = others.coast[None, :, None]
    out = [vals[0] + jnp.where(after & coast, vals[1] * (tt - To[None, :])[..., None], 0.0)]
    if R >= 1:
        out.append(jnp.where(after & ~coast, 0.0, vals[1]))
    for r in range(2, R + 1):
        out.append(jnp.where(after, 0.0, vals[r]))
    return out


def sexp(u):
    """exp(u) for u <= 30, its quadratic Taylor continuation above (finite, C^2)."""
    a = jnp.minimum(u, SEXP_KNEE)
    d = jnp.maximum(u - SEXP_KNEE, 0.0)
    return jnp.exp(a) * (1.0 + d + 0.5 * d * d)


def al_term(g, lam, mu):
    """Augmented-Lagrangian term of g >= 0 with multiplier lam >= 0, penalty mu > 0."""
    act = lam - mu * g > 0
    return jnp.where(act, -lam * g + 0.5 * mu * g * g, -0.5 * lam * lam / mu)


# ---------------------------------------------------------------------- local terms
def _collision_local(y, o, w, lam, params, structure, mu, on=True):
    """Sampled collision terms (barrier, AL of the constraints) at one sample: y = (p (N),
    T), o (Mo, N) the others' positions there; ``on``: its constraint is active."""
    N = structure.n_dim
    p = y[:N]
    T = y[-1]
    dx = p - o
    d2 = jnp.sum(dx * dx, axis=-1)
    mask = params.other_mask
    rho = params.radius + params.other_radius
    wt = params.weights
    val = 0.0
    if structure.barrier:
        d = jnp.sqrt(d2 + DIST_EPS2)
        ex = jnp.exp(-wt.k_p * (d - rho))
        val = val + wt.q_obs * T * w * jnp.sum(jnp.where(mask, ex, 0.0))
    if structure.collision_constraints and lam is not None:
        g = d2 - rho * rho
        val = val + jnp.sum(jnp.where(mask & on, al_term(g, lam, mu), 0.0))
    return val


def static_gap(p, params, t=None):
    """Clearance sd(p) - r (m) of the robot at p (N,) to each static row (R,)
    (:func:`jaxplan.world.signed_distance`; masked rows included), each row where it
    is at time t (s after the replan; None: ``center``, where it is at 0).  Rows that
    move (``static.motion``, :func:`jaxplan.world.rows_at`) are then at their predicted
    centres (:func:`jaxplan.world.path_at`); the signed distance is that of p - c(t) to
    the row at the origin."""
    st = params.static
    center = st.center if st.motion is None or t is None else centres_at(st, t)
    return signed_distance(st.kind, center, st.half, st.radius, p, xp=jnp) - params.radius


def static_times(yc, params, structure):
    """The collision rows' times T s_k + off_k (n_col,), s, where the static rows move
    (``static.motion``), else None (static rows sit still: no time needed)."""
    if params.static is None or params.static.motion is None:
        return None
    s, off, _, _ = collision_rows(params, structure)
    return yc[:, -1] * s + off


# How much a metre inside an obstacle's (or a workspace face's) planning distance weighs
# against a metre inside another robot's, in the constraints and in the fallback choice
# (jaxplan.planner.plan_violation).  An obstacle does not move out of the way; another
# robot avoids this one too and its prediction is only a prediction.  With equal weights
# (and the static constraint scaled as 2 r gap against a pair's d^2 - rho^2 ~ 4 r gap) a
# robot squeezed between an obstacle and another robot in a gap whose solve could not
# meet both gave up on the obstacle first: random_obstacles seed 9 of 20 flew 2.3 cm
# into a sphere.
STATIC_PRIORITY = 2.0

# Hard limits: the scale of their constraints (1 - |b|^2 / tau^2, dimensionless) against
# the collision constraints (m^2).  Where a solve cannot meet both (a robot already
# inside another's planning distance), the augmented Lagrangian then gives up on the
# distance, not on the limits, and the least violating plan it returns is within the
# limits and may fly as the best effort (jaxplan.planner.choice); at equal scale such
# solves broke the limits and were refused, robots flew their previous plans or braked
# into each other (docs/SOLVER.md "Hard limits").  The planner gives a robot this scale
# only while its last solve was not accepted (PlanState.retry) and LIMIT_PRIORITY_CALM
# otherwise: at 100 for every solve the 3-D fleets' makespans grew 15-24% (the solves
# within their iteration budget traded time for limit margin), at 1 for every solve the
# planar crowds collided (jaxplan.planner.nlps.fleet_nlps; docs/SOLVER.md).
LIMIT_PRIORITY = 100.0
LIMIT_PRIORITY_CALM = 1.0


def limit_priority(params):
    """The hard-limit rows' scale: params.limit_priority (per NLP), else LIMIT_PRIORITY."""
    return LIMIT_PRIORITY if params.limit_priority is None else params.limit_priority


def static_scale(params):
    """The static constraint's scale (m): g = static_scale (sd - r - a), 4 r times
    STATIC_PRIORITY, so that near its boundary a static row's g grows STATIC_PRIORITY
    times as fast per metre as a pair's d^2 - rho^2 (~ 2 rho gap, rho ~ 2 r)."""
    return 4.0 * STATIC_PRIORITY * params.radius


def static_allowance(params):
    """How far (m, <= 0) each static row's constraint lets the robot stay inside its
    planning radius: min(sd(p0) - r, 0), what its start already lacks.  A robot that
    drifted inside the planning radius between collision samples (the safety margin is
    for that) can then plan out: without it the first samples' constraints, a few
    milliseconds after the start, were unsatisfiable, every solve INFEASIBLE, and the
    robot held still beside the obstacle for good (pillars, 2 of 20 seeds)."""
    return jnp.minimum(static_gap(params.p0, params), 0.0)


def static_local(y, w, lam, on, params, structure, mu, t=None):
    """Static-row terms at one collision row: y = (p (N), T); barrier q_obs T w
    sum exp(-k_p (sd - r)); AL terms of g = s (sd - r - a) >= 0 (m^2 like d^2 - rho^2;
    s = :func:`static_scale`, a = :func:`static_allowance`) where the row's constraint
    is ``on``; t: the row's time (moving rows, :func:`static_gap`)."""
    N = structure.n_dim
    p, T = y[:N], y[-1]
    gap = static_gap(p, params, t)
    mask = params.static.mask
    wt = params.weights
    val = 0.0
    if structure.static_barrier:
        val = val + wt.q_obs * T * w * jnp.sum(jnp.where(mask, jnp.exp(-wt.k_p * gap), 0.0))
    if structure.collision_constraints and lam is not None:
        g = static_scale(params) * (gap - static_allowance(params))
        val = val + jnp.sum(jnp.where(mask & on, al_term(g, lam, mu), 0.0))
    return val


def static_constraints(yc, on, params, structure):
    """g (n_col, R) of the static rows at the collision rows' positions yc (n_col, >= N):
    s (sd - r - a) (s: :func:`static_scale`, a: :func:`static_allowance`), +1 where
    masked or the row is off; moving rows at the collision rows' times
    (:func:`static_times`)."""
    N = structure.n_dim
    tc = static_times(yc, params, structure)
    if tc is None:
        gap = jax.vmap(lambda y: static_gap(y[:N], params))(yc)
    else:
        gap = jax.vmap(lambda y, t: static_gap(y[:N], params, t))(yc, tc)
    gap = gap - static_allowance(params)
    return jnp.where(params.static.mask[None, :] & on[:, None], static_scale(params) * gap, 1.0)


def _limits_local(y, w, params, structure):
    """Soft limits at one quadrature node: y = (v, a, j, T)."""
    N = structure.n_dim
    lim = params.limits
    T = y[-1]
    v, a, j = y[:N], y[N : 2 * N], y[2 * N : 3 * N]
    f = (
        sexp(v @ v - lim.v_max**2)
        + sexp(a @ a - lim.a_max**2)
        + sexp(j @ j - lim.j_max**2)
    )
    return params.weights.q_lim * T * w * f


def _hard_g(y, params, structure):
    N = structure.n_dim
    lim = params.limits
    v, a, j = y[:N], y[N : 2 * N], y[2 * N : 3 * N]
    return limit_priority(params) * jnp.stack([1 - v @ v / lim.v_max**2, 1 - a @ a / lim.a_max**2,
                                       1 - j @ j / lim.j_max**2])


def _hard_local(y, lam, params, structure, mu):
    return jnp.sum(al_term(_hard_g(y, params, structure), lam, mu))


def smooth_time(x, params, structure, kind):
    """The smoothness and time terms at x: q_dynm int |x'''|^2 dt (exact) + k_t T."""
    z, tau = unpack(x, structure)
    T = jnp.exp(tau)
    h = T / structure.segments
    e = boundary_vector(params, h)
    jerk = (jnp.sum(e * (kind.M @ e)) + jnp.sum(kind.q * z * z)) / h**5
    return params.weights.q_dynm * jerk + params.weights.k_t * T


def has_sampled_collision(structure):
    """Whether the NLP has SAMPLED collision terms (barrier or constraints)."""
    return structure.barrier or structure.collision_constraints


def needs_col_features(structure):
    """Whether the own positions at the collision rows are needed (robots or statics)."""
    return has_sampled_collision(structure) or structure.static_terms


def _static_shape(x, structure):
    return jnp.ones((structure.n_col, structure.n_static), x.dtype)


def paper_collision(x, params, structure, kind):
    """The "paper" collision term integrated exactly (module doc): q_obs sum_j
    (exp(-k_p (d_j(0) - rho_j)) - exp(-k_p (d_j(T) - rho_j))) / k_p, d_j(t) = |x(t) -
    x_j(t)| (softened by DIST_EPS2 as the sampled terms are)."""
    N = structure.n_dim
    yT = _features(x, params, structure, kind.end, (0,))[0]  # (p(T), T)
    T = yT[-1]
    o = others_derivs(params.others, params.other_mask, jnp.stack([jnp.zeros_like(T), T]), 0)[0]
    p = jnp.stack([params.p0, yT[:N]])  # (2, N)
    d = jnp.sqrt(jnp.sum((p[:, None, :] - o) ** 2, axis=-1) + DIST_EPS2)  # (2, Mo)
    rho = params.radius + params.other_radius
    wt = params.weights
    ex = jnp.where(params.other_mask, jnp.exp(-wt.k_p * (d - rho)), 0.0)
    return wt.q_obs * jnp.sum(ex[0] - ex[1]) / wt.k_p


# ---------------------------------------------------------------------- values
def evaluate_terms(x, params, structure, kind, mult: Multipliers | None, mu, with_g: bool = False):
    """Objective (+ AL terms if ``mult`` given): exact values, differentiable in x.

    With ``with_g`` also the inequality constraints g(x) (as :func:`constraints`, bitwise
    equal), sharing the features and the other robots' positions: (value, Multipliers).
    """
    b = basis(structure)
    Mo = params.other_mask.shape[-1]
    val = smooth_time(x, params, structure, kind)
    yq = _features(x, params, structure, kind.quad, (1, 2, 3))
    val = val + jnp.sum(jax.vmap(lambda y, w: _limits_local(y, w, params, structure))(
        yq, jnp.asarray(b.quad_w)))
    gc = jnp.ones((structure.n_col, Mo), x.dtype)
    gs = _static_shape(x, structure)
    if structure.paper:
        val = val + paper_collision(x, params, structure, kind)
    if needs_col_features(structure):
        yc = _col_features(x, params, structure, kind, (0,))
        s, off, w, on = collision_rows(params, structure)
    if structure.static_terms:
        lam_s = mult.static if mult is not None else None
        tc = static_times(yc, params, structure)
        val = val + jnp.sum(jax.vmap(
            lambda y, wk, lk, ok, tk: static_local(y, wk, lk, ok, params, structure, mu, tk),
            in_axes=(0, 0, None if lam_s is None else 0, 0, None if tc is None else 0))(
                yc, w, lam_s, on, tc))
        if with_g and structure.collision_constraints:
            gs = static_constraints(yc, on, params, structure)
    if has_sampled_collision(structure):
        N = structure.n_dim
        T = yc[0, -1]
        o0 = others_derivs(params.others, params.other_mask, T * s + off, 0)[0]
        lam = mult.collision if mult is not None else None

        def one(y, a0, wk, lk, ok):
            return _collision_local(y, a0, wk, lk, params, structure, mu, ok)

        vals = jax.vmap(one)(yc, o0, w, lam, on)
        val = val + jnp.sum(vals)
        if with_g and structure.collision_constraints:
            dx = yc[:, None, :N] - o0
            rho = params.radius + params.other_radius
            gc = jnp.where(params.other_mask & on[:, None],
                           jnp.sum(dx * dx, axis=-1) - rho**2, 1.0)
    gh = jnp.ones((len(b.lim_s), 3), x.dtype)
    if structure.hard_limits and (mult is not None or with_g):
        yh = _features(x, params, structure, kind.lim, (1, 2, 3))
        if mult is not None:
            val = val + jnp.sum(jax.vmap(lambda y, l: _hard_local(y, l, params, structure, mu))(
                yh, mult.limits))
        gh = jax.vmap(lambda y: _hard_g(y, params, structure))(yh)
    if with_g:
        return val, Multipliers(gc, gh, gs)
    return val


def objective(x, params: NLPParams, structure: NLPStructure):
    """The NLP objective at x (no constraint terms).  Differentiable (used by SLSQP)."""
    kind = kind_constants(params.rest, structure)
    return evaluate_terms(x, params, structure, kind, None, 1.0)


def constraints(x, params: NLPParams, structure: NLPStructure):
    """Inequality constraints g(x) >= 0 as (collision (Kc, Mo), limits (Kh, 3), static
    (Kc, R)).

    Collision: d^2 - rho^2 (m^2) at the collision samples (masked pairs: +1; ones of
    shape (Kc, Mo) when the mode has no collision constraints).  Limits: P (1 - |b|^2 /
    tau_k^2) at the hard-limit rows, the derivatives' Bernstein control points b (P =
    LIMIT_PRIORITY; +1 when ``hard_limits`` is off).  Static:
    s (sd - r - a) (m^2, :func:`static_constraints`) of the obstacles and workspace
    faces at the same rows (+1 where masked or off, and without collision constraints).
    """
    kind = kind_constants(params.rest, structure)
    return _constraints(x, params, structure, kind)


def _constraints(x, params, structure, kind):
    b = basis(structure)
    Mo = params.other_mask.shape[-1]
    Kc, Kh = structure.n_col, len(b.lim_s)
    gs = _static_shape(x, structure)
    if structure.collision_constraints:
        yc = _col_features(x, params, structure, kind, (0,))
        T = yc[0, -1]
        s, off, _, on = collision_rows(params, structure)
        if structure.static_terms:
            gs = static_constraints(yc, on, params, structure)
        o = others_derivs(params.others, params.other_mask, T * s + off, 0)[0]
        dx = yc[:, None, : structure.n_dim] - o
        rho = params.radius + params.other_radius
        gc = jnp.sum(dx * dx, axis=-1) - rho**2
        gc = jnp.where(params.other_mask & on[:, None], gc, 1.0)
    else:
        gc = jnp.ones((Kc, Mo), x.dtype)
    if structure.hard_limits:
        yh = _features(x, params, structure, kind.lim, (1, 2, 3))
        gh = jax.vmap(lambda y: _hard_g(y, params, structure))(yh)
    else:
        gh = jnp.ones((Kh, 3), x.dtype)
    return Multipliers(gc, gh, gs)


def merit(x, params, structure, kind, mult: Multipliers, mu):
    """Augmented Lagrangian value: objective + AL terms of the inequality constraints."""
    return evaluate_terms(x, params, structure, kind, mult, mu)


def merit_and_constraints(x, params, structure, kind, mult: Multipliers, mu):
    """(:func:`merit`, :func:`constraints`) at x in one pass (shared features and
    other-robot positions; what a line search needs at its accepted point)."""
    return evaluate_terms(x, params, structure, kind, mult, mu, with_g=True)
