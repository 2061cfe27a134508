"""The planner: one replanning step of the whole fleet, as a pipeline of stages.

:func:`replan` (pipeline.py) takes the fleet's parameters (:class:`FleetParams`), the
memory of the previous replan (:class:`PlanState`), what the fleet knows now
(:class:`FleetState`: each robot's own state and its views of the others) and where it
is going (:class:`Goals`), and returns the new PlanState (a plan per robot, starting
now) and a :class:`ReplanInfo`.  Its stages run in this order, one module each:

1. views.py: each robot predicts the others in closed form from its views (the last
   message it received from each), advanced by the message's age; an old message costs
   a larger radius, a silent robot is held where it can have braked to.
2. stall.py: each robot tracks its progress to its goal; one that makes none with
   another robot near is stalled, and resolves the stall by a sidestep to its right.
3. goals.py: the end point each robot plans to: its goal, or its sidestep sub-goal, or
   a guide point on the way round a wall (guide.py: the field built on the host once
   per run), or the free point beside a goal that another robot occupies.
4. nlps.py: each robot's NLP (:mod:`jaxplan.nlp`) from its state, its goal, the others'
   predictions (all, or its ``max_neighbors`` nearest) and the world's static rows (all,
   or its ``max_static_rows`` nearest).
5. fleet_solve.py: all the NLPs solved in one call (:mod:`jaxplan.solve`, a pool of
   lanes), warm-started from the previous plans.
6. choice.py: each robot flies its solve where accepted, else the least violating of its
   best-effort solve, its previous plan and a braking plan (:class:`Fallback`).
7. pipeline.py: the new PlanState: the plans, the next warm starts, the stall memory and
   what each robot broadcasts next (stall.py).

types.py holds the data every stage shares.  Everything is pure and jit-able; shapes
are fixed by (M robots, N dimensions, :class:`PlannerStructure`), traced values
(weights, tolerances, limits) never recompile.  How a run builds these inputs from a
config: :mod:`jaxplan.run_setup`; the loop that calls :func:`replan` every period:
:mod:`jaxplan.rollout` (ideal tracking) and :mod:`jaxplan.sim.closed_loop` (MJX).
"""

from __future__ import annotations

from jaxplan.planner.choice import (
    CHECK_HORIZON_S,
    CHECK_SAMPLES,
    Choice,
    braking_plan,
    choose_plans,
    limited_braking_plan,
    pick_fallback,
    plan_violation,
    resample,
)
from jaxplan.planner.fleet_solve import solve_fleet
from jaxplan.planner.goals import (
    GOAL_CLEARANCE,
    GOAL_PROJECTIONS,
    STATIC_PROJECTIONS,
    clear_of_static,
    free_goals,
    guided_goals,
    sidestep_goals,
    unoccupied_goals,
)
from jaxplan.planner.nlps import (
    NEIGHBOR_HORIZON_S,
    NEIGHBOR_SAMPLES,
    STATIC_PATH_SAMPLES,
    FleetNLPs,
    all_others,
    fleet_nlps,
    heading_points,
    nearest_neighbors,
    nearest_static_rows,
    nlp_static_rows,
    remap_slots,
    select_neighbors,
    select_static,
    take_slots,
)
from jaxplan.planner.pipeline import initial_plan_state, replan
from jaxplan.planner.stall import Stalls, stall_step
from jaxplan.planner.types import (
    DeadlockParams,
    DeadlockState,
    Fallback,
    FleetParams,
    FleetState,
    Goals,
    GuideField,
    PlannerStructure,
    PlanState,
    ReplanInfo,
    Views,
)
from jaxplan.planner.views import (
    MAX_INFLATION,
    PREDICTIONS,
    STALE_AFTER_S,
    Predictions,
    fresh_views,
    predict_views,
    sender_mask,
    view_predictions,
)

# the fallback codes by their names (ReplanInfo.fallback)
ACCEPTED = Fallback.ACCEPTED
KEPT_PREVIOUS = Fallback.KEPT_PREVIOUS
BRAKING = Fallback.BRAKING
BEST_EFFORT = Fallback.BEST_EFFORT

__all__ = [
    "ACCEPTED", "BEST_EFFORT", "BRAKING", "CHECK_HORIZON_S", "CHECK_SAMPLES",
    "GOAL_CLEARANCE", "GOAL_PROJECTIONS", "KEPT_PREVIOUS", "MAX_INFLATION",
    "NEIGHBOR_HORIZON_S", "NEIGHBOR_SAMPLES", "PREDICTIONS", "STALE_AFTER_S",
    "STATIC_PATH_SAMPLES", "STATIC_PROJECTIONS", "Choice", "DeadlockParams", "DeadlockState",
    "Fallback",
    "FleetNLPs", "FleetParams", "FleetState", "Goals", "GuideField", "PlanState",
    "PlannerStructure", "Predictions", "ReplanInfo", "Stalls", "Views", "all_others",
    "braking_plan", "choose_plans", "limited_braking_plan", "clear_of_static", "fleet_nlps",
    "free_goals",
    "fresh_views", "guided_goals", "heading_points", "initial_plan_state",
    "nearest_neighbors", "nearest_static_rows", "nlp_static_rows", "pick_fallback",
    "plan_violation", "predict_views", "remap_slots", "replan", "resample",
    "select_neighbors", "select_static", "sender_mask", "sidestep_goals", "solve_fleet",
    "stall_step", "take_slots", "unoccupied_goals", "view_predictions",
]
