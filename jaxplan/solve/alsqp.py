"""Augmented-Lagrangian SQP for one robot's NLP (docs/MATH.md section 2, docs/SOLVER.md),
in JAX: one lane's :func:`init_lane`, :func:`step_lanes` and :func:`finish_lane`, and
:func:`solve` (their loop for one problem).

Method (per problem; ``solve`` is pure, jit- and vmap-able)
------------------------------------------------------------
* Variables: x = (z, tau = log T) of :mod:`jaxplan.nlp`.  The equality constraints
  (start state, C^2 joints, end state) are eliminated exactly by the null-space
  parametrization c = P e(h) + Z z, i.e. each step's KKT system is solved in its
  reduced (null-space) form; they hold to rounding at every iterate.
* Inequalities g(x) >= 0 (collision samples d^2 >= rho^2, optional hard limits) enter
  an augmented Lagrangian  L_A = f + sum psi(g; lam, mu).  Multipliers are updated
  (lam <- max(0, lam - mu g)) whenever the inner problem is nearly solved (Newton
  decrement <= ``inner_tol``); the penalty mu grows (x ``mu_growth``) only when the
  violation did not shrink by ``stall_ratio`` since the previous update.
* Step: exact Hessian of L_A (structured autodiff, jaxplan.nlp.merit_derivs), eigenvalues
  floored at |lambda| >= reg * max|lambda| (eigh; negative curvature flipped), so the
  step is a descent direction (where the Hessian is provably positive definite with no
  eigenvalue below that floor, the same step by Cholesky:
  :func:`jaxplan.solve.linalg.directions`); with ``warm_convex_step`` (the default), a
  warm-started lane's first step keeps to the Hessian's positive-curvature part (docs/SOLVER.md,
  "Starting points"; the stopping test still reads the full decrement); T >= t_min by
  projection (tau at its bound with an outward gradient is held); the step is capped
  (|dtau| <= max_step_tau, |dz|_inf <= max_step_z); backtracking Armijo line search on
  L_A (a failed trial is cut back to just past the first constraint it pushed into the
  steep AL branch, else halved).
* Stopping: Newton decrement^2 <= tol_stationarity (1 + |L_A|), max violation <=
  tol_feasibility, max lam~ |g| <= tol_complementarity (1 + |L_A|), where
  lam~ = max(0, lam - mu g) (the multiplier estimate whose Lagrangian gradient is the
  AL gradient).  A bounded loop (``max_iters``); per-lane status, never raised.

Evaluations: a solver step (:func:`step_lanes`) is ONE evaluation of L_A's value,
derivatives and constraints per lane, at the lane's next point: its iterate, or a
line-search trial.  An accepted trial's derivatives start the next iteration (unless
its multipliers change there), so the usual iteration (derivatives at x, then merit
trials) costs one evaluation when the first trial is accepted, and a rejected trial
costs derivatives that go unused.  In exchange no lane ever waits for another's
backtracking: under vmap a nested line-search loop runs every lane for as many trials
as the slowest needs.  The iterates are those of the textbook loop above.

Batches: :func:`jaxplan.solve.batch.solve_batch` / :func:`jaxplan.solve.pool.solve_lanes`
step a pool of lanes at a time and hand each finished slot the next lane, so a batch
costs about the sum of its lanes' evaluations rather than B times the largest (each
lane's iterations are those of :func:`solve`).
:func:`jaxplan.solve.implicit.solve_differentiable`: the solution differentiable with
respect to the weights by implicit differentiation (jaxopt ``custom_root``).

Status codes (``Solution.status``, int32):
    0 CONVERGED      all three tests passed.
    1 MAX_ITERS      iteration budget spent, constraints satisfied to tolerance.
    2 NON_FINITE     a non-finite value appeared; x = x0 (finite), traj finite.
    3 INFEASIBLE     violation > tol_feasibility when the budget was spent, or
                     detected early: ``infeasible_updates`` multiplier updates in a row,
                     at a penalty >= ``infeasible_penalty``, each left the violation above
                     ``infeasible_shrink`` x the previous update's (e.g. a start inside
                     another robot's radius, or a goal occupied).
    4 LINE_SEARCH_FAILED  ``max_backtracks`` trials found no Armijo step and the
                     multiplier update left L_A unchanged, so the next iteration would
                     repeat the same search: the lane stops at its iterate (its last
                     accepted point; constraints as ``ineq_violation`` says).
"""


from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxplan import nlp
from jaxplan.nlp import Multipliers, NLPParams, NLPStructure
from jaxplan.pytree import any_all, max_all, min_all, sum_all, tree_where
from jaxplan.solve.guess import initial_guess
from jaxplan.solve.linalg import directions
from jaxplan.solve.types import (
    CONVERGED,
    INFEASIBLE,
    LINE_SEARCH_FAILED,
    MAX_ITERS,
    NON_FINITE,
    Solution,
    SolverSettings,
    max_violation,
    sanitize,
    zero_multipliers,
)
from jaxplan.trajectory import Trajectory


class State(NamedTuple):
    """One lane's solver state between evaluations (:func:`step_lanes`).

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
    alpha: jax.Array  # the step length of y along d
    trials: jax.Array  # int32: trials before y in this line search
    obj0: jax.Array  # the objective at x0 (from the first evaluation; reported where the
    viol0: jax.Array  # lane ends NON_FINITE) and the constraint violation there
    stalls: jax.Array  # int32: multiplier updates in a row that hardly shrank the violation
    why: jax.Array  # int32: 0, or the status a lane stopped early with (LINE_SEARCH_FAILED,
    # INFEASIBLE)
    evals: jax.Array  # int32: evaluations (step_lanes calls in which the lane was active)


def next_trial(a, g_x: Multipliers, g_a: Multipliers, thr: Multipliers, overshoot):
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
    r = functools.reduce(jnp.minimum, [min_all(f, initial=1.0) for f in jax.tree.leaves(frac)])
    return jnp.where(r < 1.0, jnp.clip(overshoot * r, 1e-3, 0.5), 0.5) * a


class Lane(NamedTuple):
    """What a lane's iterations read besides its state: the sanitized params and the
    bound on tau (the end-kind constants are recomputed from params.rest: cheap)."""

    params: NLPParams
    tau_min: jax.Array
    others: nlp.OthersPrep  # the others' predictions as the derivatives read them
    warm: jax.Array  # bool: x0 is a warm start (the previous plan; warm_convex_step)


def init_lane(params: NLPParams, x0, structure: NLPStructure, s: SolverSettings,
             multipliers, penalty, x_fallback, warm=False):
    """(lane, start state, finite_in, x0 as used) of one solve (see :func:`solve`)."""
    params, finite_in = sanitize(params)
    x0 = x0_given = jnp.asarray(x0, jnp.float64)
    if x_fallback is None:
        x_fallback = initial_guess(params, structure)
    x0 = jnp.where(jnp.all(jnp.isfinite(x0)), x0, x_fallback)
    tau_min = jnp.log(jnp.maximum(params.t_min, 1e-6))
    x0 = x0.at[-1].set(jnp.maximum(x0[-1], tau_min))
    kind = nlp.kind_constants(params.rest, structure)
    mult0 = zero_multipliers(params, structure) if multipliers is None else multipliers
    if mult0.static is None:  # given without static rows' multipliers: zeros
        mult0 = mult0._replace(static=zero_multipliers(params, structure).static)
    mult0 = jax.tree.map(lambda a: jnp.where(jnp.isfinite(a), jnp.maximum(a, 0.0), 0.0), mult0)
    mu0 = jnp.asarray(s.mu0 if penalty is None else penalty, jnp.float64)
    mu0 = jnp.where(jnp.isfinite(mu0) & (mu0 > 0), mu0, s.mu0)
    # L_A and the constraints at x0 come with the first evaluation; only a solve allowed
    # no iteration at all evaluates them here (for its report)
    unset = (jnp.asarray(jnp.inf, jnp.float64),
             jax.tree.map(jnp.ones_like, zero_multipliers(params, structure)))
    f0, g0 = jax.lax.cond(s.max_iters > 0, lambda: unset, lambda: nlp.merit_and_constraints(
        x0, params, structure, kind, mult0, mu0))
    F = lambda v: jnp.asarray(v, jnp.float64)
    st0 = State(x0, mult0, mu0, g0, f0, F(jnp.inf), jnp.asarray(False), jnp.asarray(0, jnp.int32),
                 jnp.asarray(False), jnp.asarray(False), F(jnp.inf), F(jnp.inf),
                 base=jnp.asarray(True), y=x0, d=jnp.zeros_like(x0), grad=jnp.zeros_like(x0),
                 alpha=F(0.0), trials=jnp.asarray(-1, jnp.int32),
                 obj0=_objective_from_merit(f0, g0, mult0, mu0, params, structure),
                 viol0=max_violation(g0), stalls=jnp.asarray(0, jnp.int32),
                 why=jnp.asarray(0, jnp.int32), evals=jnp.asarray(0, jnp.int32))
    # a start replaced by the fallback is not the warm start it was said to be
    warm = jnp.asarray(warm, bool) & jnp.all(jnp.isfinite(x0_given))
    lane = Lane(params, tau_min, nlp.prepare_others(params.others, params.other_mask), warm)
    return lane, st0, finite_in, x0


def _objective_from_merit(f, g: Multipliers, mult: Multipliers, mu, params: NLPParams,
               structure: NLPStructure):
    """The objective at a point from its L_A value f and constraints g there: f less
    the AL terms (as nlp.evaluate_terms adds them), so that results need no second pass over
    the other robots."""
    al = 0.0
    if structure.collision_constraints:
        _, _, _, on = nlp.collision_rows(params, structure)
        use = params.other_mask[None, :] & on[:, None]
        al = al + sum_all(jnp.where(use, nlp.al_term(g.collision, mult.collision, mu), 0.0))
    if structure.hard_limits:
        al = al + sum_all(nlp.al_term(g.limits, mult.limits, mu))
    if structure.static_terms and structure.collision_constraints:
        _, _, _, on = nlp.collision_rows(params, structure)
        use = params.static.mask[None, :] & on[:, None]
        al = al + sum_all(jnp.where(use, nlp.al_term(g.static, mult.static, mu), 0.0))
    return f - al


class _Evaluation(NamedTuple):
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
    grad_proj: jax.Array
    hess_proj: jax.Array
    a_next: jax.Array
    obj0: jax.Array
    viol0: jax.Array
    stalls: jax.Array
    why: jax.Array  # 0, or the status the lane stops with here


def is_active(st: State, s: SolverSettings):
    """Whether the lane takes another evaluation: not converged, and in a line search or
    with iterations left."""
    return (~st.done) & ~(st.base & (st.it >= s.max_iters))


def _evaluate(st: State, lane: Lane, structure: NLPStructure, s: SolverSettings) -> _Evaluation:
    """The first half of :func:`step_lanes` for one lane: the evaluation at st.y and what it
    decides before the Newton direction (which :func:`directions` forms for a batch);
    see :func:`step_lanes` for how trials and iterations share evaluations."""
    params, tau_min = lane.params, lane.tau_min
    kind = nlp.kind_constants(params.rest, structure)
    n = st.x.shape[0]
    fy, gr, H, gy = nlp.merit_derivs(st.y, params, structure, kind, st.mult, st.mu,
                                       with_g=True, others=lane.others)
    # 1. the trial: accepted, another one, or the line search failed
    trial = ~st.base
    ok = trial & jnp.isfinite(fy) & (fy <= st.f + s.armijo * (st.grad @ (st.y - st.x)))
    more = trial & ~ok & (st.trials < s.max_backtracks)
    failed = trial & ~ok & ~more
    thr = jax.tree.map(lambda l: l / st.mu, st.mult)  # g < thr: the AL term is active
    a_next = next_trial(st.alpha, st.g, gy, thr, s.kink_overshoot)
    # the iterate after this evaluation (an accepted trial, else x) and its constraints
    x = jnp.where(ok, st.y, st.x)
    g = tree_where(ok | st.base, gy, st.g)
    f_x = jnp.where(ok | st.base, fy, st.f)
    # 2. a line search that ended: the multiplier / penalty update it calls for
    ended = ok | failed
    pending = jnp.where(ended, (st.theta <= s.inner_tol * (1.0 + jnp.abs(st.f))) | failed,
                        st.pending)
    upd = ended & pending & (st.it < s.max_iters)
    lam_new = jax.tree.map(lambda l, gg: jnp.maximum(0.0, l - st.mu * gg), st.mult, g)
    viol = max_violation(g)
    grow = upd & (viol > s.tol_feasibility) & (viol > s.stall_ratio * st.viol_ref)
    mu = jnp.where(grow, jnp.minimum(st.mu * s.mu_growth, s.mu_max), st.mu)
    mult = tree_where(upd, lam_new, st.mult)
    viol_ref = jnp.where(upd, viol, st.viol_ref)
    changed = grow | jnp.any(jnp.stack([any_all(m != l) for m, l in
                                        zip(jax.tree.leaves(mult), jax.tree.leaves(st.mult),
                                            strict=True)]))
    # early stops: a failed line search whose L_A is unchanged would be repeated from
    # the same x along the same direction (so the lane stops: LINE_SEARCH_FAILED); a lane
    # whose violation hardly shrinks over several updates in a row, however the penalty
    # and multipliers grow, cannot become feasible from here (INFEASIBLE)
    # (only at a large penalty: lanes of a 100-robot crossing that converge hardly
    # shrink their violation over several updates at penalties of 1e3-1e4)
    hardly = (viol > s.tol_feasibility) & (viol > s.infeasible_shrink * st.viol_ref) & (
        st.mu >= s.infeasible_penalty)
    stalls = jnp.where(upd, jnp.where(hardly, st.stalls + 1, 0), st.stalls).astype(jnp.int32)
    infeasible = upd & (stalls >= s.infeasible_updates)
    why = jnp.where(failed & ~changed, LINE_SEARCH_FAILED, jnp.where(infeasible, INFEASIBLE, 0)
                    ).astype(jnp.int32)
    # a lane that stops here keeps the multipliers and penalty its L_A value at x has
    mult = tree_where(infeasible, st.mult, mult)
    mu = jnp.where(infeasible, st.mu, mu)
    # 3. an iteration starts at x from this evaluation: at the base, or at an accepted
    # trial whose L_A is unchanged; after a failed search or changed multipliers the
    # next evaluation is at x
    start = st.base | (ok & ~changed & (st.it < s.max_iters))
    held = (x[-1] <= tau_min + 1e-12) & (gr[-1] > 0)
    grad_proj = gr.at[-1].set(jnp.where(held, 0.0, gr[-1]))
    hess_proj = jnp.where(held, H.at[-1, :].set(0.0).at[:, -1].set(0.0).at[-1, -1].set(1.0), H)
    finite = jnp.isfinite(fy) & jnp.all(jnp.isfinite(grad_proj)) & jnp.all(jnp.isfinite(hess_proj))
    grad_proj = jnp.where(finite, grad_proj, 0.0)
    hess_proj = jnp.where(finite, hess_proj, jnp.eye(n))
    first = st.base & (st.it == 0)  # the evaluation at x0
    obj0 = jnp.where(first, _objective_from_merit(fy, gy, st.mult, st.mu, params, structure),
                     st.obj0)
    viol0 = jnp.where(first, max_violation(gy), st.viol0)
    return _Evaluation(more=more, x=x, g=g, f_x=f_x, fy=fy, pending=pending, mult=mult, mu=mu,
                       viol_ref=viol_ref, start=start, finite=finite, grad_proj=grad_proj,
                       hess_proj=hess_proj, a_next=a_next, obj0=obj0, viol0=viol0,
                       stalls=stalls, why=why)


def _advance(st: State, lane: Lane, ev: _Evaluation, d, ds, s: SolverSettings) -> State:
    """The second half of :func:`step_lanes` for one lane: the tests at the iterate, and the
    next evaluation point, given the Newton direction d there (-|H|_reg^-1 grad) and
    the step ds to take (d, or d on the positive-curvature part: :func:`step_lanes`)."""
    tau_min = lane.tau_min
    more, x, g, f_x, fy, pending, mult, mu, viol_ref, start, finite, grad_proj = (
        ev.more, ev.x, ev.g, ev.f_x, ev.fy, ev.pending, ev.mult, ev.mu, ev.viol_ref, ev.start,
        ev.finite, ev.grad_proj)
    a_next = ev.a_next
    theta = -grad_proj @ d
    scale = 1.0 + jnp.abs(fy)
    lam_t = jax.tree.map(lambda l, gg: jnp.maximum(0.0, l - mu * gg), mult, g)
    compl = functools.reduce(jnp.maximum, [max_all(lt * jnp.abs(gg), initial=0.0) for lt, gg in
                                           zip(jax.tree.leaves(lam_t), jax.tree.leaves(g),
                                               strict=True)])
    conv = (theta <= s.tol_stationarity * scale) & (max_violation(g) <= s.tol_feasibility) & (
        compl <= s.tol_complementarity * scale)
    d = ds
    cap = jnp.minimum(1.0, s.max_step_tau / jnp.maximum(jnp.abs(d[-1]), 1e-300))
    cap = jnp.minimum(
        cap, s.max_step_z / jnp.maximum(jnp.max(jnp.abs(d[:-1]), initial=0.0), 1e-300))
    d = d * cap
    early = ev.why != 0  # a failed search that would repeat, or infeasible: no step
    stop = start & (conv | ~finite) | early  # converged at x (or non-finite): no step
    search = start & ~stop
    point = lambda xb, dd, a: (xb + a * dd).at[-1].max(tau_min)
    # 4. the next evaluation: the first trial of a new search, the next trial, or x
    a_new = jnp.where(search, 1.0, jnp.where(more, a_next, 0.0))
    d_new = jnp.where(search, d, st.d)
    y_new = jnp.where(search | more, point(x, d_new, a_new), x)
    new = State(
        x=x, mult=mult, mu=mu, g=g, f=f_x, viol_ref=viol_ref, pending=pending,
        it=jnp.where(search, st.it + 1, st.it), done=stop, bad=start & ~finite,
        kkt=jnp.where(start, jnp.max(jnp.abs(grad_proj)), st.kkt),
        theta=jnp.where(start, theta, st.theta), base=~(search | more), y=y_new, d=d_new,
        grad=jnp.where(search, grad_proj, st.grad), alpha=a_new,
        trials=jnp.where(search, 0, jnp.where(more, st.trials + 1, -1)).astype(jnp.int32),
        obj0=ev.obj0, viol0=ev.viol0, stalls=ev.stalls, why=ev.why, evals=st.evals + 1)
    return tree_where(is_active(st, s), new, st)  # an inactive lane is returned as is


def step_lanes(st: State, lane: Lane, structure: NLPStructure, s: SolverSettings) -> State:
    """One evaluation of a batch of lanes (leading axis): the derivatives of L_A (and the
    constraints) at each lane's st.y, then what they decide (module doc); an inactive
    lane (:func:`is_active`) is returned as is.

    In a line search, y is a trial: it is accepted (Armijo on L_A) or the next trial
    is set (cut back past the first AL branch crossing, else halved: next_trial).  An
    accepted trial is the next iterate, and its derivatives, already at hand, start the
    next iteration unless the multipliers change there (then the next evaluation is at
    the iterate again, with the new ones).  So a trial costs the derivatives (a merit
    value alone would do for a rejected one), and no lane waits for another's
    backtracking: a pool step is one evaluation per lane.  The iterates are those of an
    SQP iteration "multiplier update, derivatives at x, step, backtracking line search".

    A warm lane's first step (``lane.warm``, ``s.warm_convex_step``, the iterate x0):
    the Newton step on the Hessian's positive-curvature part, the flipped negative
    curvature left out (docs/SOLVER.md, "Starting points"); its decrement for the
    stopping test is the full direction's."""
    ev = jax.vmap(lambda a, b: _evaluate(a, b, structure, s))(st, lane)
    convex = lane.warm & s.warm_convex_step & (st.it == 0)  # a warm lane's first step
    d, ds = directions(ev.hess_proj, ev.grad_proj, ev.start & is_active(st, s), s.reg, convex)
    return jax.vmap(lambda a, b, e, dd, dds: _advance(a, b, e, dd, dds, s))(st, lane, ev, d, ds)


def finish_lane(st: State, lane: Lane, finite_in, x0, structure: NLPStructure,
            s: SolverSettings) -> Solution:
    """The Solution of a lane whose iterations ended (state ``st``)."""
    params = lane.params
    bad = st.bad | ~finite_in | ~jnp.all(jnp.isfinite(st.x))
    x = jnp.where(bad, x0, st.x)
    # st.g and st.f are the constraints and L_A at st.x: no second pass over the others
    viol = jnp.where(bad, st.viol0, max_violation(st.g))
    conv = st.done & ~bad & (st.why == 0)
    status = jnp.where(bad, NON_FINITE, jnp.where(conv, CONVERGED, jnp.where(
        st.why != 0, st.why, jnp.where(viol > s.tol_feasibility, INFEASIBLE, MAX_ITERS)))
                       ).astype(jnp.int32)
    traj = nlp.to_trajectory(x, params, structure)
    traj_ok = jnp.all(jnp.isfinite(traj.coeffs)) & jnp.all(jnp.isfinite(traj.breaks))
    hold = Trajectory.hold(params.p0, structure.degree, structure.segments)
    traj = tree_where(traj_ok, traj, hold._replace(coast=traj.coast))
    obj = jnp.where(bad, st.obj0,
                    _objective_from_merit(st.f, st.g, st.mult, st.mu, params, structure))
    eq = nlp.equality_residual(x, params, structure)
    no_nan = lambda a: jnp.where(jnp.isnan(a), jnp.inf, a)
    return Solution(
        x=x, traj=traj, objective=no_nan(obj), status=status, iterations=st.it,
        kkt_residual=no_nan(st.kkt), eq_violation=no_nan(eq),
        ineq_violation=no_nan(viol), multipliers=st.mult, penalty=st.mu,
        decrement=no_nan(st.theta), evaluations=st.evals,
    )


def solve(params: NLPParams, x0, structure: NLPStructure,
          settings: SolverSettings = SolverSettings(),
          multipliers: Multipliers | None = None, penalty=None, x_fallback=None,
          warm=False) -> Solution:
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
    lane, st0, finite_in, x0 = init_lane(params, x0, structure, s, multipliers, penalty,
                                        x_fallback, warm)
    one = lambda t: jax.tree.map(lambda a: a[None], t)
    lane1 = one(lane)  # a batch of one lane, as step_lanes takes it
    st = jax.lax.while_loop(lambda st: is_active(st, s)[0],
                            lambda st: step_lanes(st, lane1, structure, s), one(st0))
    return finish_lane(jax.tree.map(lambda a: a[0], st), lane, finite_in, x0, structure, s)
