"""Stage 3 of a replan: the end point each robot plans to.

A robot plans to its goal, except:

* while it sidesteps a stall (:mod:`jaxplan.planner.stall`), to its sub-goal, with a
  rest end, kept out of the obstacles and workspace faces (:func:`sidestep_goals`);
* where its straight line to its goal passes through an obstacle, to the guide point on
  the way round (:mod:`jaxplan.planner.guide`, a rest end; :func:`guided_goals`);
* where another robot occupies its goal (:func:`unoccupied_goals`).

Goals another robot occupies: uncertainty never keeps a robot off its own goal.  Where
robot i's goal lies inside the inflated planning distance of where j's prediction ends
(a robot parked, frozen or silent near it), the inflation of j for i shrinks so that the
goal keeps GOAL_CLEARANCE outside it; the uninflated distance (both radii, which include
the safety margin) and the floor of a held robot (:mod:`jaxplan.planner.views`) are
never given up.  Where the goal lies inside even that, the robot plans to the nearest
point GOAL_CLEARANCE outside it (``ReplanInfo.goal_moved``) with a rest end and waits
there (with a free end it would fly through that point at speed and back, replan after
replan); it takes the goal again once it is free.  Otherwise such a robot's solves are
infeasible every replan and the plans it flies wander off.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxplan.planner.guide import guide_goals
from jaxplan.planner.stall import Stalls, planning_goals
from jaxplan.planner.types import FleetParams, FleetState, Goals, PlannerStructure
from jaxplan.planner.views import Predictions, sender_mask
from jaxplan.world import StaticRows, signed_distance

# m: clearance a robot keeps between its goal and the planning distance of a robot that
# occupies it (module docstring)
GOAL_CLEARANCE = 0.05
GOAL_PROJECTIONS = 4  # fixed passes of the goal projection (several occupants)
STATIC_PROJECTIONS = 3  # passes of clear_of_static


def sidestep_goals(fp: FleetParams, goals: Goals, stalls: Stalls) -> Goals:
    """The goals with each sidestepping robot's sub-goal in place of its goal (a rest
    end: :func:`jaxplan.planner.stall.planning_goals`), moved out of the static rows
    (:func:`clear_of_static`).  Without stall handling: the goals."""
    if fp.deadlock is None or stalls.state is None:
        return goals
    goal_p, goal_v, rest = planning_goals(stalls.state, goals.goal_p, goals.goal_v,
                                          goals.rest)
    if fp.static is not None:  # a sidestep sub-goal stays out of obstacles and walls
        goal_p = jnp.where(stalls.sidestep[:, None],
                           clear_of_static(goal_p, fp.radius, fp.static), goal_p)
    return goals._replace(goal_p=goal_p, goal_v=goal_v, rest=rest)


def guided_goals(fp: FleetParams, fleet: FleetState, goals: Goals, stalls: Stalls) -> Goals:
    """The goals with the guide point (:func:`jaxplan.planner.guide.guide_goals`, a rest
    end) in place of the goal of each robot whose line to its goal goes through an
    obstacle and that does not sidestep.  Without ``goals.guide`` or static rows: the
    goals."""
    if goals.guide is None or fp.static is None:
        return goals
    point, use = guide_goals(*goals.guide, fp.static, fp.radius, fleet.p, goals.goal_p)
    use = use & ~stalls.sidestep & fp.robot_mask
    return goals._replace(goal_p=jnp.where(use[:, None], point, goals.goal_p),
                          goal_v=jnp.where(use[:, None], 0.0, goals.goal_v),
                          rest=goals.rest | use)


def unoccupied_goals(fp: FleetParams, fleet: FleetState, preds: Predictions, goals: Goals,
                     structure: PlannerStructure):
    """Goals another robot occupies (module docstring; :func:`free_goals` against where
    each robot's predictions of the others end): the inflations shrunk, goals inside an
    occupant's planning distance moved beside it (and out of the obstacles and walls,
    :func:`clear_of_static`, where the NLPs hold static rows), with a rest end there.

    Returns (Goals, Predictions with ``inflate`` shrunk, moved (M,) bool: the goal had to
    move)."""
    goal_p, inflate, goal_moved = free_goals(goals.goal_p, fleet.p, preds.traj.end_state()[0],
                                             fp.radius, preds.inflate,
                                             sender_mask(fp, fleet.views), preds.floor)
    if fp.static is not None and structure.nlp.n_static:
        # a goal moved off an occupant must not land in an obstacle or a wall
        goal_clear = clear_of_static(goal_p, fp.radius, fp.static)
        goal_p = jnp.where(goal_moved[:, None], goal_clear, goal_p)
    # a robot whose goal moved waits there: a rest end, not a free end it would fly
    # through at speed (and back, every replan)
    rest = goals.rest | goal_moved
    # (a non-finite goal velocity stays non-finite: the solve must still report it)
    goal_v = jnp.where(goal_moved[:, None] & jnp.isfinite(goals.goal_v), 0.0, goals.goal_v)
    return (goals._replace(goal_p=goal_p, goal_v=goal_v, rest=rest),
            preds._replace(inflate=inflate), goal_moved)


def clear_of_static(goal, radius, static: StaticRows):
    """Goals (M, N) moved out of the static rows: a goal whose clearance sd - r to a row
    is below GOAL_CLEARANCE is pushed along that row's distance gradient until it is
    (STATIC_PROJECTIONS passes, the deepest row first; exact for planes and spheres,
    for boxes and cylinders outside).  Finite goals stay finite."""
    def gap(g, r):
        return signed_distance(static.kind, static.center, static.half, static.radius, g,
                               xp=jnp) - r

    def one(g, r):
        for _ in range(STATIC_PROJECTIONS):
            gp = jnp.where(static.mask, gap(g, r), jnp.inf)
            k = jnp.argmin(gp)
            short = GOAL_CLEARANCE - gp[k]
            n = jax.grad(lambda q, kk=k: gap(q, r)[kk])(g)
            n = n / jnp.maximum(jnp.linalg.norm(n), 1e-12)
            g = jnp.where((short > 0) & jnp.all(jnp.isfinite(n)), g + short * n, g)
        return g

    return jax.vmap(one)(goal, radius)


def free_goals(goal_p, p, occupant, radius, inflate, mask, floor=None):
    """Goals another robot occupies (module docstring): shrink inflations, move goals.

    Args:
        goal_p: (M, N) each robot's goal.  p: (M, N) its position now.
        occupant: (M, M, N) where observer i expects sender j to end (its prediction's
            end position).  radius: (M,) planning radii (safety margin included).
        inflate: (M, M) extra radius observer i gives sender j.  mask: (M, M) bool,
            the senders that count.  floor: (M, M) part of ``inflate`` never given up
            (default 0: where a held robot is known to be only that well).
    Returns:
        (goal (M, N) to plan to, inflate (M, M) shrunk where a goal is inside it,
        moved (M,) bool: the goal had to move).  Finite for finite input; a non-finite
        occupant never moves a goal.
    """
    floor = jnp.zeros_like(inflate) if floor is None else jnp.minimum(floor, inflate)
    radii = radius[:, None] + radius[None, :]
    base = radii + floor  # (M, M) distance never given up
    ok = mask & jnp.all(jnp.isfinite(occupant), axis=-1)
    d0 = jnp.linalg.norm(goal_p[:, None, :] - occupant, axis=-1)
    room = jnp.where(ok, d0 - radii - GOAL_CLEARANCE, jnp.inf)
    inflate = jnp.where(ok, jnp.maximum(jnp.minimum(inflate, room), floor), inflate)
    target = base + GOAL_CLEARANCE
    g = goal_p
    N = goal_p.shape[-1]
    e0 = jnp.zeros((N,)).at[0].set(1.0)
    for _ in range(GOAL_PROJECTIONS):
        u = g[:, None, :] - occupant
        d = jnp.linalg.norm(u, axis=-1)
        short = jnp.where(ok, target - d, -jnp.inf)  # > 0: inside
        j = jnp.argmax(short, axis=1)
        inside = jnp.take_along_axis(short, j[:, None], 1)[:, 0] > 0
        c = jnp.take_along_axis(occupant, j[:, None, None], 1)[:, 0]
        # away from the occupant; from a coincident goal, towards where the robot is
        away = g - c
        back = p - c
        na, nb = jnp.linalg.norm(away, axis=-1), jnp.linalg.norm(back, axis=-1)
        u = jnp.where((na > 1e-9)[:, None], away / jnp.maximum(na, 1e-300)[:, None],
                      jnp.where((nb > 1e-9)[:, None], back / jnp.maximum(nb, 1e-300)[:, None],
                                e0))
        rad = jnp.take_along_axis(target, j[:, None], 1)[:, 0]
        g = jnp.where(inside[:, None], c + rad[:, None] * u, g)
    moved = jnp.any(g != goal_p, axis=-1) & jnp.all(jnp.isfinite(goal_p), axis=-1)
    return g, inflate, moved
