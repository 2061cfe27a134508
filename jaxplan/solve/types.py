"""The solver's public data and the small helpers every part of it shares: status codes,
:class:`SolverSettings`, :class:`Solution`, the constraint violation, zero multipliers
and the sanitizing of a problem's parameters (docs/SOLVER.md).
"""

from __future__ import annotations

import enum
import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxplan import nlp
from jaxplan.nlp import Multipliers, NLPParams, NLPStructure
from jaxplan.pytree import max_all
from jaxplan.trajectory import Trajectory


class Status(enum.IntEnum):
    """How a lane's solve ended (``Solution.status``, an int32 array of these values;
    each is defined in :mod:`jaxplan.solve.alsqp`'s docstring): CONVERGED, MAX_ITERS
    (the budget spent, constraints satisfied to tolerance), NON_FINITE, INFEASIBLE (the
    violation stays above tolerance), LINE_SEARCH_FAILED (no Armijo step, and the next
    iteration would repeat the same search)."""

    CONVERGED = 0
    MAX_ITERS = 1
    NON_FINITE = 2
    INFEASIBLE = 3
    LINE_SEARCH_FAILED = 4


CONVERGED, MAX_ITERS, NON_FINITE, INFEASIBLE, LINE_SEARCH_FAILED = Status
STATUS_NAMES = {CONVERGED: "converged", MAX_ITERS: "max-iterations", NON_FINITE: "non-finite",
                INFEASIBLE: "infeasible", LINE_SEARCH_FAILED: "line-search-failed"}


class SolverSettings(NamedTuple):
    """Solver settings; all traced (changing them does not recompile)."""

    max_iters: int = 50  # the planner's default too ([planner] max_iters)
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
    kink_overshoot: float = 1.1  # backtracking past an AL branch crossing (step_lanes)
    reg: float = 1e-13  # eigenvalue floor / max|eigenvalue| (direction)
    # early infeasibility: a lane stops INFEASIBLE after this many multiplier updates in
    # a row, at a penalty of at least infeasible_penalty, that each left the violation
    # above infeasible_shrink x the previous one's
    infeasible_updates: int = 3
    infeasible_shrink: float = 0.9
    infeasible_penalty: float = 1e6
    # a warm-started lane's first step on its Hessian's positive-curvature part (the
    # lanes the caller marks ``warm``; docs/SOLVER.md, "Starting points"; off: every
    # first step flipped, as a cold lane's)
    warm_convex_step: bool = True


class Solution(NamedTuple):
    """Result of one solve (leading batch axes under vmap).

    x: (n_x,) decision vector (z, log T).  traj: the plan (S segments; coasts after T
    unless ``rest``).  objective: f(x) without constraint terms.  status: int32 (see
    module doc).  iterations: int32.  kkt_residual: |projected grad of L_A|_inf at the
    last derivative evaluation (= Lagrangian gradient with lam~).  eq_violation: max
    residual of the equality constraints (m, m/s, m/s^2).  ineq_violation: max(0, -g)
    (m^2 for collisions, dimensionless for hard limits).  multipliers, penalty: warm-
    start the next solve.  decrement: last Newton decrement^2.  evaluations: int32, the
    evaluations of L_A's derivatives the solve took (one per pool step in which the lane
    was active: an iteration's base point, each line-search trial, the re-evaluation after
    a multiplier update; docs/SOLVER.md "One evaluation per step").  Never NaN: objective,
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
    evaluations: jax.Array


def max_violation(g: Multipliers):
    """The largest violation max(0, -g) of the inequality constraints g >= 0."""
    return functools.reduce(jnp.maximum, [max_all(-a, initial=0.0) for a in jax.tree.leaves(g)])


def zero_multipliers(params: NLPParams, structure: NLPStructure) -> Multipliers:
    """Multipliers of zeros, shaped for one problem's constraints."""
    b = nlp.basis(structure)
    Mo = params.other_mask.shape[-1]
    return Multipliers(jnp.zeros((structure.n_col, Mo)), jnp.zeros((len(b.lim_s), 3)),
                       jnp.zeros((structure.n_col, structure.n_static)))


def sanitize(params: NLPParams) -> tuple[NLPParams, jax.Array]:
    """Replace non-finite own-state entries and t_min by 0; report whether all own-state
    entries and scalars were finite."""
    own = (params.p0, params.v0, params.a0, params.goal_p, params.goal_v, params.goal_a)
    ok = jnp.all(jnp.stack([jnp.all(jnp.isfinite(a)) for a in own]))
    scal = jax.tree.leaves((params.weights, params.limits, params.t_min, params.radius))
    ok = ok & jnp.all(jnp.stack([jnp.isfinite(a) for a in scal]))
    fz = lambda a: jnp.where(jnp.isfinite(a), a, 0.0)
    params = params._replace(**{k: fz(getattr(params, k)) for k in
                                ("p0", "v0", "a0", "goal_p", "goal_v", "goal_a", "t_min")})
    if params.static is not None:  # a non-finite static row is ignored
        st = params.static
        fin = (jnp.all(jnp.isfinite(st.center), -1) & jnp.all(jnp.isfinite(st.half), -1)
               & jnp.isfinite(st.radius))
        motion = st.motion
        if motion is not None:  # a row whose motion is not finite is ignored too
            fin = (fin & jnp.all(jnp.isfinite(motion.t), -1)
                   & jnp.all(jnp.isfinite(motion.p), (-1, -2))
                   & jnp.all(jnp.isfinite(motion.v), -1))
            motion = motion._replace(t=fz(motion.t), p=fz(motion.p), v=fz(motion.v))
        params = params._replace(static=st._replace(
            mask=st.mask & fin, center=fz(st.center), half=fz(st.half), radius=fz(st.radius),
            motion=motion))
    return params, ok
