"""One replanning step of the whole fleet (docs/MATH.md section 3): the stages in the
order they run, state in, state out (the package docstring, :mod:`jaxplan.planner`,
says what each stage does).

Everything here is pure and jit-able; shapes are fixed by (M, N, structure).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxplan import solve
from jaxplan.nlp import Limits, NLPParams, Weights
from jaxplan.planner.choice import choose_plans
from jaxplan.planner.fleet_solve import solve_fleet
from jaxplan.planner.goals import guided_goals, sidestep_goals, unoccupied_goals
from jaxplan.planner.nlps import fleet_nlps
from jaxplan.planner.stall import after_replan, initial_state, stall_step
from jaxplan.planner.types import (
    Fallback,
    FleetParams,
    FleetState,
    Goals,
    PlannerStructure,
    PlanState,
    ReplanInfo,
)
from jaxplan.planner.views import view_predictions
from jaxplan.trajectory import Trajectory
from jaxplan.world import rows_at


def replan(fp: FleetParams, ps: PlanState, fleet: FleetState, goals: Goals,
           structure: PlannerStructure, t=None) -> tuple[PlanState, ReplanInfo]:
    """One receding-horizon replan of the whole fleet.

    Args:
        fp: FleetParams.  ps: PlanState from the previous replan (plans start at the
        previous replan time, i.e. ``fp.dt`` ago).  fleet: each robot's own state now,
        (M, N) each, and what it knows of the others (``fleet.views``).  goals: its
        current goals, (M, N), (M, N), (M,), and the guide field to them (or None).
        structure: static PlannerStructure.  t: () s, the time now (traced): where the
        world's moving obstacles are and what the robots predict of them
        (:func:`jaxplan.world.rows_at`); needed only where ``fp.static`` moves.
    Returns:
        (new PlanState with every plan starting now, ReplanInfo).
    """
    # 0. the moving obstacles where they are now, their predictions from now on
    if fp.static is not None and fp.static.motion is not None:
        if t is None:
            raise ValueError("replan: a world with moving obstacles needs the time t")
        fp = fp._replace(static=rows_at(fp.static, t))
    # 1. views.py: each robot's predictions of the others, from its views
    preds = view_predictions(fp, fleet.views, structure.prediction)
    # 2. stall.py: who is stalled, who sidesteps
    stalls = stall_step(fp, ps, fleet, goals)
    # 3. goals.py: the end point each robot plans to: its sidestep sub-goal, its guide
    #    point round a wall (guide.py), the free point beside a goal another occupies
    goals = sidestep_goals(fp, goals, stalls)
    goals = guided_goals(fp, fleet, goals, stalls)
    goals, preds, moved = unoccupied_goals(fp, fleet, preds, goals, structure)
    # 4. nlps.py: each robot's NLP, with its nearest others and static rows
    nlps = fleet_nlps(fp, ps, fleet, preds, goals, structure)
    # 5. fleet_solve.py: all of them solved in one call, warm-started
    sol = solve_fleet(fp, ps, nlps, stalls, structure)
    # 6. choice.py: each robot's solve, or its least violating fallback
    choice = choose_plans(fp, ps, nlps.params, sol, fleet, structure)
    # 7. the state out: the plans flown, the next warm starts, the stall memory and what
    #    each robot broadcasts next (stall.py)
    deadlock = after_replan(fp, stalls, moved, nlps.params, choice.plan, choice.fallback)
    mask = fp.robot_mask
    M = mask.shape[0]
    new_ps = PlanState(choice.plan, jnp.ones((M,), bool), choice.multipliers, choice.penalty,
                       nlps.neighbors.astype(jnp.int32), nlps.static_ids,
                       ((choice.fallback != Fallback.ACCEPTED) | stalls.idle) & mask,
                       deadlock)
    info = ReplanInfo(sol.status, sol.iterations, sol.objective, sol.eq_violation,
                      sol.ineq_violation, choice.fallback.astype(jnp.int32), moved & mask,
                      stalls.stalled & mask, stalls.sidestep & mask, nlps.params.goal_p)
    return new_ps, info


def initial_plan_state(p, structure: PlannerStructure, n_others: int) -> PlanState:
    """Planner memory before the first replan: no plans (first solves start cold).

    Args: p (M, N) start positions; n_others: M, the fleet size (each NLP holds
    ``structure.others(M)`` other-robot slots).
    """
    M = p.shape[0]
    Mo = structure.others(n_others)
    nlp = structure.nlp
    plan = Trajectory.hold(p, nlp.degree, nlp.segments)
    dummy = _dummy_params(p.shape[-1], Mo)
    mult = solve.zero_multipliers(dummy, nlp)
    mult = jax.tree.map(lambda m: jnp.zeros((M,) + m.shape), mult)
    return PlanState(plan, jnp.zeros((M,), bool), mult, jnp.zeros((M,)),
                     jnp.full((M, Mo), -1, jnp.int32), jnp.full((M, nlp.n_static), -1, jnp.int32),
                     jnp.zeros((M,), bool), initial_state(p))


def _dummy_params(N: int, Mo: int) -> NLPParams:
    z = jnp.zeros((N,))
    others = Trajectory.hold(jnp.zeros((Mo, N)))
    one = jnp.asarray(1.0)
    return NLPParams(z, z, z, z, z, z, jnp.asarray(False), others, jnp.ones((Mo,)),
                     jnp.ones((Mo,), bool), one, Weights(one, one, one, one, one),
                     Limits(one, one, one), one)
