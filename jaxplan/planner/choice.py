"""Stage 6 of a replan: what each robot flies.

A solve is ACCEPTED when its plan is finite, its equality residual is <= 1e-6 and its
status is CONVERGED, or MAX_ITERS (or LINE_SEARCH_FAILED) with every inequality
satisfied to ``FleetParams.accept_violation``.  A robot whose solve is not accepted flies
whichever of three plans comes least deep into the others' planning distances (or into
the static rows) over the next CHECK_HORIZON_S (:func:`plan_violation`, CHECK_SAMPLES
instants, against the predictions its NLP used), ties going in this order: the solve
itself if it is finite and meets its equalities (BEST_EFFORT: typically INFEASIBLE
because it starts inside another robot's planning radius, or another's prediction
crosses its start; the solve minimized the violation against the newest predictions),
its previous plan shifted to now while that has not run out (KEPT_PREVIOUS), a braking
plan that brings it to rest (BRAKING, :func:`braking_plan`; under hard limits one that
breaks them, from a state near v_max still accelerating, only when neither other plan
may fly): so a finite best-effort
solve through a robot is not flown when a fallback violates less (:class:`Fallback`,
counted in ``ReplanInfo.fallback``).  No NaN leaves this stage.

With hard limits (``NLPStructure.hard_limits``, ``[planner] limits = "hard"``) a plan
flies only if its speed, acceleration and jerk stay within the robot's vehicle limits at
every instant (:func:`limit_ratio`, an upper bound): a solve beyond them is not accepted
and neither it nor a previous plan beyond them is a fallback; the braking plan is then
the one of :func:`limited_braking_plan`, kept within them.
"""

from __future__ import annotations

from math import comb
from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxplan import solve
from jaxplan.nlp import Multipliers, NLPParams
from jaxplan.nlp.terms import STATIC_PRIORITY
from jaxplan.nlp.types import LIMIT_SUBDIVISIONS
from jaxplan.planner.types import Fallback, FleetParams, FleetState, PlannerStructure, PlanState
from jaxplan.predict import quintic_terms
from jaxplan.pytree import tree_where
from jaxplan.trajectory import Trajectory, _falling, compose_matrix
from jaxplan.world import StaticRows, centres_at, signed_distance

CHECK_HORIZON_S = 1.5  # s: fallback plans are compared over this long (plan_violation)
CHECK_SAMPLES = 32  # instants in (0, CHECK_HORIZON_S] (47 ms apart: 9 cm at 2 m/s)
LIMIT_TOL = 1e-3  # hard limits: a plan is within them up to this relative excess
BRAKE_GROWTH = 1.25  # hard limits: the braking durations tried, T_b * BRAKE_GROWTH^k
BRAKE_CANDIDATES = 16
# hard limits: added to the violation of a braking plan beyond the limits (m), so that it
# flies only where neither the best effort nor the previous plan may (pick_fallback)
BRAKE_BEYOND = 1e3


class Choice(NamedTuple):
    """What each robot flies after a replan (:func:`choose_plans`).

    plan: Trajectory (M,) starting now.  fallback: (M,) :class:`Fallback` codes.
    multipliers, penalty: the augmented-Lagrangian warm start of the next replan (the
    solve's where accepted, else zero multipliers and the initial penalty).
    """

    plan: Trajectory
    fallback: jax.Array
    multipliers: Multipliers
    penalty: jax.Array


def choose_plans(fp: FleetParams, ps: PlanState, params: NLPParams, sol: solve.Solution,
                 fleet: FleetState, structure: PlannerStructure) -> Choice:
    """Each robot's new plan: its solution ``sol`` (of the NLPs ``params``) where
    accepted, else the least violating of its best-effort solution, its previous plan
    (``ps.plan``) and a braking plan from its state now (``fleet``)
    (:func:`pick_fallback`); padding robots hold."""
    p, v, a = fleet.p, fleet.v, fleet.a
    M = p.shape[0]
    nlp = structure.nlp
    finite = jnp.all(jnp.isfinite(sol.traj.coeffs), axis=(-1, -2, -3)) & jnp.all(
        jnp.isfinite(sol.traj.breaks), axis=-1)
    good_status = (sol.status == solve.CONVERGED) | (
        ((sol.status == solve.MAX_ITERS) | (sol.status == solve.LINE_SEARCH_FAILED))
        & (sol.ineq_violation <= fp.accept_violation))
    accepted = finite & good_status & (sol.eq_violation <= 1e-6)

    prev = ps.plan.shift(fp.dt)
    prev_ok = ps.has_plan & (prev.duration > 0) & jnp.all(
        jnp.isfinite(prev.coeffs), axis=(-1, -2, -3))
    usable = finite & (sol.eq_violation <= 1e-6) & (sol.status != solve.NON_FINITE)
    if nlp.hard_limits:  # only plans within the limits fly; the brake keeps to them
        true_limits = type(params.limits)(*(jnp.broadcast_to(x, (M,)) for x in fp.limits))
        brake = limited_braking_plan(p, v, a, true_limits, structure)
        within = limit_ratio(sol.traj, true_limits) <= 1.0 + LIMIT_TOL
        accepted = accepted & within
        usable = usable & within
        prev_ok = prev_ok & (limit_ratio(prev, true_limits) <= 1.0 + LIMIT_TOL)
        # from a state near v_max still accelerating, no braking plan keeps to them
        brake_ok = limit_ratio(brake, true_limits) <= 1.0 + LIMIT_TOL
    else:
        brake = braking_plan(p, v, a, params.limits.a_max, structure)
        brake_ok = None

    # not accepted: the least violating of best effort, previous, braking (in that order
    # on ties); computed only when some robot needs it
    def choose():
        viol = lambda tr: plan_violation(tr, params.others, params.radius,
                                         params.other_radius, params.other_mask,
                                         fp.static if nlp.n_static else None)
        v_sol = jnp.where(usable, viol(sol.traj), jnp.inf)
        v_prev = jnp.where(prev_ok, viol(prev), jnp.inf)
        return pick_fallback(v_sol, v_prev, viol(brake), brake_ok=brake_ok)

    fallback = jnp.where(accepted, Fallback.ACCEPTED, jax.lax.cond(
        jnp.any(~accepted & fp.robot_mask), choose,
        lambda: jnp.full((M,), Fallback.BRAKING)))
    plan = tree_where(accepted | (fallback == Fallback.BEST_EFFORT), sol.traj,
                      tree_where(fallback == Fallback.KEPT_PREVIOUS, prev, brake))
    # padding robots hold where they are
    hold = Trajectory.hold(p, nlp.degree, nlp.segments)
    plan = tree_where(fp.robot_mask, plan, hold)
    fallback = jnp.where(fp.robot_mask, fallback, Fallback.ACCEPTED)
    new_mult = tree_where(accepted, sol.multipliers,
                          jax.tree.map(jnp.zeros_like, sol.multipliers))
    new_pen = jnp.where(accepted, sol.penalty, fp.settings.mu0)
    return Choice(plan, fallback, new_mult, new_pen)


def pick_fallback(v_sol, v_prev, v_brake, tol: float = 1e-6, brake_ok=None):
    """The fallback of a robot whose solve was not accepted, from the violations
    (:func:`plan_violation`, m; inf: not available) of its best-effort solve, its
    previous plan and its braking plan: the least, ties (within ``tol``) in that order.
    ``brake_ok`` (hard limits): where False, the braking plan breaks the limits and
    flies only if neither other plan is available (its violation + BRAKE_BEYOND)."""
    if brake_ok is not None:
        v_brake = jnp.where(brake_ok, v_brake, v_brake + BRAKE_BEYOND)
    use_sol = v_sol <= jnp.minimum(v_prev, v_brake) + tol
    use_prev = ~use_sol & (v_prev <= v_brake + tol)
    return jnp.where(use_sol, Fallback.BEST_EFFORT,
                     jnp.where(use_prev, Fallback.KEPT_PREVIOUS, Fallback.BRAKING))


def plan_violation(plans: Trajectory, others: Trajectory, radius, other_radius, mask,
                   static: StaticRows | None = None):
    """How deep each plan comes into the others' planning distances, or into the static
    rows (obstacles, workspace faces) by its radius, over the next CHECK_HORIZON_S: max
    over CHECK_SAMPLES instants, others and rows of rho_ij - d_ij and P (r_i - sd) (m;
    P = :data:`jaxplan.nlp.terms.STATIC_PRIORITY`: a plan into an obstacle is worse than
    one as deep into a robot's planning distance, which that robot avoids too), 0 when
    clear.  plans: (M,) trajectories starting now (holding or coasting after their
    end); others: (M, Mo) predictions; radius (M,); other_radius, mask (M, Mo).  Moving
    rows (``static.motion``, relative to now) are where their prediction puts them at
    each instant."""
    t = jnp.arange(1, CHECK_SAMPLES + 1) * (CHECK_HORIZON_S / CHECK_SAMPLES)
    me = plans.evaluate(t[:, None])  # (K, M, N)
    ot = others.evaluate(t[:, None, None])  # (K, M, Mo, N)
    d = jnp.sqrt(jnp.sum((me[:, :, None] - ot) ** 2, axis=-1))
    rho = radius[:, None] + other_radius
    pen = jnp.where(mask[None] & jnp.isfinite(d), rho[None] - d, 0.0)
    worst = jnp.maximum(jnp.max(pen, axis=(0, 2)), 0.0)
    if static is not None:
        center = static.center if static.motion is None else centres_at(static, t)[:, None]
        sd = signed_distance(static.kind, center, static.half, static.radius, me,
                             xp=jnp)  # (K, M, R)
        pen_s = jnp.where(static.mask & jnp.isfinite(sd), radius[None, :, None] - sd, 0.0)
        worst = jnp.maximum(worst, STATIC_PRIORITY * jnp.max(pen_s, axis=(0, 2), initial=0.0))
    return worst


def braking_plan(p, v, a, a_max, structure: PlannerStructure) -> Trajectory:
    """A plan that brings each robot from (p, v, a) to rest, batch (M,).

    A rest-ended quintic over T_b = max(1.5 |v| / a_max, 0.5 s) to p + v T_b / 2 (the
    stopping point of a constant deceleration), re-expressed on the planner's segments
    and degree.  Finite for any input: non-finite entries of p, v, a count as 0 (as in
    :func:`jaxplan.predict.predict_arrays`), and a lane whose quintic overflows holds at p.
    """
    p, v, a, Tb = _brake_start(p, v, a, a_max)
    one = _brake_quintic(p, v, a, Tb)
    ok = jnp.isfinite(Tb) & jnp.all(jnp.isfinite(one.coeffs), axis=(-1, -2, -3))
    hold = Trajectory.hold(p, 5, 1)
    one = tree_where(ok, one, hold)
    return resample(one, structure.nlp.segments, structure.nlp.degree)


def _brake_start(p, v, a, a_max):
    """The braking plans' start (p, v, a with non-finite entries as 0) and their
    duration T_b = max(1.5 |v| / a_max, 0.5 s), (M,)."""
    fin = lambda x: jnp.where(jnp.isfinite(x), x, 0.0)
    p, v, a = fin(p), fin(v), fin(a)
    speed = jnp.linalg.norm(v, axis=-1)
    return p, v, a, jnp.maximum(1.5 * speed / jnp.maximum(a_max, 1e-3), 0.5)


def _bernstein(n: int, dtype) -> jax.Array:
    """(n+1, n+1) B with b = B @ a: the Bernstein coefficients b of the degree-n
    polynomial with monomial coefficients a on [0, 1]."""
    return jnp.asarray([[comb(i, j) / comb(n, j) if j <= i else 0.0 for j in range(n + 1)]
                        for i in range(n + 1)], dtype)


def limit_ratio(plans: Trajectory, limits) -> jax.Array:
    """(M,) an upper bound, over every instant of [0, T], of the largest of |x'| / v_max,
    |x''| / a_max and |x'''| / j_max of each plan (after T a plan holds or coasts,
    within its end's values); non-finite plans read inf.  ``limits``: (M,) Limits.

    Each segment is cut into LIMIT_SUBDIVISIONS equal pieces; on each, a derivative is
    a polynomial curve inside the convex hull of its Bernstein control points, so its
    norm is at most theirs: the bound holds at every instant, not only at samples, and
    comes within a few per cent of the true peak."""
    c = plans.coeffs  # (M, S, N, K)
    K = c.shape[-1]
    Q = LIMIT_SUBDIVISIONS
    h = jnp.diff(plans.breaks, axis=-1)  # (M, S)
    valid = h > 0
    h_eff = jnp.where(valid, h, 1.0)
    A = jnp.stack([compose_matrix(q / Q, 1.0 / Q, K, c.dtype) for q in range(Q)])
    cq = jnp.einsum("qmi,...i->...qm", A, c)  # (M, S, N, Q, K) in each piece's own sigma
    worst = jnp.zeros(plans.duration.shape, c.dtype)
    for k, tau in ((1, limits.v_max), (2, limits.a_max), (3, limits.j_max)):
        n = K - 1 - k
        f = jnp.asarray([_falling(i, k) for i in range(k, K)], c.dtype)
        d = cq[..., k:] * f  # the k-th sigma-derivative, (M, S, N, Q, n+1)
        b = jnp.einsum("ij,...j->...i", _bernstein(n, c.dtype), d)
        norm = jnp.max(jnp.sqrt(jnp.sum(b * b, axis=-3)), axis=(-2, -1))  # (M, S)
        peak = jnp.where(valid, norm * (Q / h_eff) ** k, 0.0)
        worst = jnp.maximum(worst, jnp.max(peak, axis=-1) / tau)
    return jnp.where(jnp.isfinite(worst), worst, jnp.inf)


def _brake_quintic(p, v, a, Tb) -> Trajectory:
    """One-segment rest-ended quintics (M,) from (p, v, a) over Tb (M,) to p + v Tb / 2."""
    target = p + v * Tb[:, None] * 0.5
    N = p.shape[-1]
    ax = lambda x: [x[:, d] for d in range(N)]
    zero = [jnp.zeros_like(Tb)] * N
    rows = quintic_terms(ax(p), ax(v), ax(a), ax(target), zero, zero,
                          jnp.ones_like(Tb, bool), Tb)
    c = jnp.stack([jnp.stack(r, axis=-1) for r in rows], axis=-2)  # (M, N, 6)
    return Trajectory.from_normalized(c[:, None], Tb, coast=False)


def limited_braking_plan(p, v, a, limits, structure: PlannerStructure) -> Trajectory:
    """A plan that brings each robot from (p, v, a) to rest within its limits (hard limits).

    The braking quintic of :func:`braking_plan` over the shortest of the durations
    T_b BRAKE_GROWTH^k (k < BRAKE_CANDIDATES; T_b braking_plan's) whose speed,
    acceleration and jerk stay within ``limits`` (:func:`limit_ratio`); where none does
    (a state already beyond them) the least exceeding.  Finite for any input, as
    :func:`braking_plan`."""
    p, v, a, T0 = _brake_start(p, v, a, limits.a_max)
    grow = BRAKE_GROWTH ** jnp.arange(BRAKE_CANDIDATES, dtype=p.dtype)
    ratios = jax.vmap(lambda g: limit_ratio(_brake_quintic(p, v, a, T0 * g), limits))(grow)
    ok = ratios <= 1.0 + LIMIT_TOL  # (C, M)
    k = jnp.where(jnp.any(ok, axis=0), jnp.argmax(ok, axis=0), jnp.argmin(ratios, axis=0))
    one = _brake_quintic(p, v, a, T0 * grow[k])
    fine = jnp.all(jnp.isfinite(one.coeffs), axis=(-1, -2, -3))
    one = tree_where(fine, one, Trajectory.hold(p, 5, 1))
    return resample(one, structure.nlp.segments, structure.nlp.degree)


def resample(traj: Trajectory, segments: int, degree: int) -> Trajectory:
    """Re-express one-segment trajectories (degree <= ``degree``) on ``segments`` equal
    segments of degree ``degree``: exact (segment k is the same polynomial composed with
    s = (k + sigma) / segments)."""
    D0 = traj.degree
    if D0 > degree:
        raise ValueError(f"cannot lower the degree from {D0} to {degree}")
    c = traj.coeffs[..., 0, :, :]  # (..., N, D0+1)
    if D0 < degree:
        c = jnp.concatenate([c, jnp.zeros(c.shape[:-1] + (degree - D0,), c.dtype)], -1)
    if segments == 1:
        return Trajectory(c[..., None, :, :], traj.breaks, traj.coast)
    K = degree + 1
    mats = jnp.stack([compose_matrix(k / segments, 1.0 / segments, K, c.dtype)
                      for k in range(segments)])  # (S, K, K)
    coeffs = jnp.einsum("smi,...ni->...snm", mats, c)
    return Trajectory.from_normalized(coeffs, traj.duration, traj.coast)
