"""Stage 5 of a replan: every robot's NLP solved in one call (:mod:`jaxplan.solve`, a
pool of lanes), warm-started from the previous plans.

A warm start is the robot's previous plan shifted by the replan period, with its
multipliers and penalty.  A robot starts from the cold guesses
(:func:`jaxplan.solve.initial_guess`, which include swerves) where it has no usable
previous plan, or where its last solve was not accepted or it is idle
(``PlanState.retry``): a robot whose plan is pressed against an obstacle straight
between it and its goal, warm-started from that plan replan after replan, would stay
stuck there.  A robot whose sidestep starts or ends in this replan (the kind of its end
state changes) starts its multipliers and penalty afresh.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxplan import solve
from jaxplan.planner.nlps import FleetNLPs
from jaxplan.planner.stall import Stalls
from jaxplan.planner.types import FleetParams, PlannerStructure, PlanState
from jaxplan.pytree import tree_where


def solve_fleet(fp: FleetParams, ps: PlanState, nlps: FleetNLPs, stalls: Stalls,
                structure: PlannerStructure) -> solve.Solution:
    """The robots' NLPs ``nlps`` solved from warm starts (the previous plans ``ps``),
    cold guesses only where a robot has no usable previous plan or ``ps.retry``, in a
    pool of ``structure.solver_pool`` lanes (module docstring).  Returns the Solution,
    batch (M,)."""
    params, mult_prev, penalty = nlps.params, nlps.multipliers, ps.penalty
    if stalls.state is not None:  # a sidestep starts or ends: the end state's kind changes
        switched = (ps.deadlock.left > 0) != stalls.sidestep
        mult_prev = tree_where(switched, jax.tree.map(jnp.zeros_like, mult_prev), mult_prev)
        penalty = jnp.where(switched, fp.settings.mu0, penalty)
    M = params.radius.shape[0]
    nlp = structure.nlp
    # warm starts; cold guesses (20 objective and 5 merit values each) only when some robot
    # has no usable previous plan
    nan_x = jnp.full((nlp.n_x,), jnp.nan)
    x_warm = jax.vmap(lambda prev, pr: solve.warm_start(prev, fp.dt, pr, nlp, nan_x))(
        ps.plan, params)
    need_cold = ~ps.has_plan | ps.retry | ~jnp.all(jnp.isfinite(x_warm), axis=-1)
    x_cold = jax.lax.cond(
        jnp.any(need_cold), lambda: jax.vmap(lambda pr: solve.initial_guess(pr, nlp))(params),
        lambda: jnp.zeros((M, nlp.n_x)))
    x0 = jnp.where(need_cold[:, None], x_cold, x_warm)
    mult = tree_where(ps.has_plan, mult_prev, jax.tree.map(jnp.zeros_like, mult_prev))
    pen = jnp.where(ps.has_plan, penalty, fp.settings.mu0)
    # x0 is finite (initial_guess is finite for any input): no fallback guess needed
    # a pool of lanes: the replan costs about the sum of the robots' iterations, not M
    # times the largest
    pool = structure.solver_pool or solve.default_pool(M, n_others=params.other_mask.shape[-1])
    return solve.solve_lanes(params, x0, nlp, fp.settings, mult, pen, x_fallback=x0, pool=pool,
                             warm=~need_cold)
