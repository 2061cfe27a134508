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
point GOAL_CLEARANCE outside it, and outside every other occupant's where their spheres
overlap (:func:`free_goals`; ``ReplanInfo.goal_moved``), with a rest end, and waits
there (with a free end it would fly through that point at speed and back, replan after
replan); it takes the goal again once it is free.  Otherwise such a robot's solves are
infeasible every replan and the plans it flies wander off.
"""

from __future__ import annotations

from itertools import combinations

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.planner.guide import guide_goals
from jaxplan.planner.stall import Stalls, planning_goals
from jaxplan.planner.types import FleetParams, FleetState, Goals, PlannerStructure
from jaxplan.planner.views import Predictions, sender_mask
from jaxplan.world import StaticRows, signed_distance

# m: clearance a robot keeps between its goal and the planning distance of a robot that
# occupies it (module docstring)
GOAL_CLEARANCE = 0.05
GOAL_PROJECTIONS = 4  # fixed passes of the goal projection (several occupants)
# where the passes end inside an occupant (overlapping spheres): the nearest clear point
# among candidates (_nearest_clear): the pairwise and triple intersections of the
# GOAL_NEAR spheres nearest the goal, and the first clear point along GOAL_DIRECTIONS
# fixed rays, found in RAY_HOPS hops from sphere to sphere
GOAL_NEAR = 6
GOAL_DIRECTIONS = 32
RAY_HOPS = 8
CLEAR_TOL = 1e-9  # m: a point this close to a sphere's surface is outside it
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
    static = fp.static
    if static.motion is not None:  # the guide goes round the static world only
        static = static._replace(mask=static.mask & ~static.motion.moving)
    point, use = guide_goals(*goals.guide, static, fp.radius, fleet.p, goals.goal_p)
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

    A goal inside the sphere of an occupant (its planning distance never given up, plus
    GOAL_CLEARANCE) is projected out of the occupant it is deepest in, GOAL_PROJECTIONS
    passes.  Where occupants' spheres overlap the passes can alternate and end inside
    one; then the goal is the nearest point clear of every occupant among the candidates
    of :func:`_nearest_clear` (exact where at most GOAL_NEAR spheres bound it).  The
    passes' point is kept wherever it is clear and no candidate is nearer (always, with
    a single occupant).  The inflations are shrunk for the goal planned to: a moved goal
    keeps GOAL_CLEARANCE outside every occupant's inflated distance but the floor.

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
    first = g
    for k in range(GOAL_PROJECTIONS):
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
        first = g if k == 0 else first
    # the passes' point where it is clear of every occupant and no candidate is nearer
    occ = jnp.where(ok[..., None], occupant, 0.0)  # non-finite or masked: never counted
    rad = jnp.where(ok, target, 0.0)
    pass_clear = jax.vmap(_clear)(g, occ, rad, ok)
    finite = jnp.all(jnp.isfinite(goal_p), axis=-1)
    # the candidates only where the first projection is inside another occupant (where
    # it is clear it is the nearest clear point: the common case costs nothing)
    best, best_d = jax.lax.cond(
        jnp.any(~jax.vmap(_clear)(first, occ, rad, ok) & finite),
        lambda: jax.vmap(_nearest_clear)(goal_p, p, occ, rad, ok),
        lambda: (goal_p, jnp.full(goal_p.shape[:1], jnp.inf, goal_p.dtype)))
    keep = ((pass_clear & (jnp.linalg.norm(g - goal_p, axis=-1) <= best_d + CLEAR_TOL))
            | ~jnp.isfinite(best_d) | ~finite)
    g = jnp.where(keep[:, None], g, best)
    moved = jnp.any(g != goal_p, axis=-1) & finite
    # the inflations for the goal planned to (unchanged where it did not move)
    d1 = jnp.linalg.norm(g[:, None, :] - occupant, axis=-1)
    room1 = jnp.where(ok & moved[:, None], d1 - radii - GOAL_CLEARANCE, jnp.inf)
    inflate = jnp.where(ok, jnp.maximum(jnp.minimum(inflate, room1), floor), inflate)
    return g, inflate, moved


def _clear(x, c, r, ok):
    """Points x (..., N) at least r (M,) (to CLEAR_TOL) from every counted centre c
    (M, N) (ok (M,) bool): (...,) bool."""
    d = jnp.linalg.norm(x[..., None, :] - c, axis=-1)
    return jnp.all(~ok | (d >= r - CLEAR_TOL), axis=-1)


def _ray_directions(N: int) -> np.ndarray:
    """GOAL_DIRECTIONS fixed unit vectors (N = 2: evenly round the circle; N = 3: a
    Fibonacci lattice on the sphere; otherwise the 2N axis directions)."""
    k = np.arange(GOAL_DIRECTIONS)
    if N == 2:
        a = 2 * np.pi * k / GOAL_DIRECTIONS
        return np.stack([np.cos(a), np.sin(a)], -1)
    if N == 3:
        z = 1 - (2 * k + 1) / GOAL_DIRECTIONS
        a = np.pi * (3 - np.sqrt(5)) * k
        s = np.sqrt(1 - z * z)
        return np.stack([s * np.cos(a), s * np.sin(a), z], -1)
    return np.concatenate([np.eye(N), -np.eye(N)])


def _unit(v, fallback):
    """v (..., N) normalised; where it is (near) zero or non-finite, ``fallback``."""
    n = jnp.linalg.norm(v, axis=-1, keepdims=True)
    good = (n > 1e-12) & jnp.isfinite(n)
    return jnp.where(good, v / jnp.where(good, n, 1.0), fallback)


def _nearest_clear(g, p, c, r, ok):
    """The nearest point to g (N,) outside every counted sphere (centres c (M, N),
    radii r (M,), ok (M,) bool) among the candidates, and its distance (inf where none
    is clear).

    The nearest such point lies on the spheres' boundary where one, two or (N = 3) three
    of them meet (the constraints active there): the candidates are the goal's radial
    projection onto every sphere (from a centre, towards ``p``, the robot), the
    nearest and farthest points of every pairwise intersection (a circle; two points
    for N = 2) and the two points of every triple intersection (N = 3) of the GOAL_NEAR
    spheres whose surfaces come nearest the goal, and along each of GOAL_DIRECTIONS
    fixed directions (and the one towards the robot) the first point outside the union
    (RAY_HOPS hops from sphere to sphere).  So a clear point is found wherever the rays
    leave the occupants, and it is the nearest one where at most GOAL_NEAR spheres
    bound it.  Fixed shapes; the masked spheres' centres must be finite."""
    M, N = c.shape
    dtype = c.dtype
    e0 = jnp.zeros((N,), dtype).at[0].set(1.0)
    points, valid = [], []
    # projections onto each sphere (as the passes make them)
    u = _unit(g - c, _unit(p - c, e0))
    points.append(c + r[:, None] * u)
    valid.append(ok)
    K = min(GOAL_NEAR, M)
    gap = jnp.where(ok, jnp.linalg.norm(g - c, axis=-1) - r, jnp.inf)
    near = jax.lax.top_k(-gap, K)[1]
    cn, rn, okn = c[near], r[near], ok[near]
    if K >= 2:  # pairwise intersections
        ia, ib = np.array(list(combinations(range(K), 2))).T
        ca, ra = cn[ia], rn[ia]
        dab = jnp.linalg.norm(cn[ib] - ca, axis=-1)
        e = _unit(cn[ib] - ca, e0)
        a = (dab ** 2 + ra ** 2 - rn[ib] ** 2) / (2 * jnp.maximum(dab, 1e-12))
        h2 = ra ** 2 - a ** 2
        m = ca + a[:, None] * e
        w = g - m
        w = w - jnp.sum(w * e, -1, keepdims=True) * e
        # g on the axis: any direction across it (the axis least along e)
        k = jnp.argmin(jnp.abs(e), axis=-1)
        ek = jax.nn.one_hot(k, N, dtype=dtype)
        w = _unit(w, _unit(ek - jnp.take_along_axis(e, k[:, None], 1) * e, e0))
        h = jnp.sqrt(jnp.maximum(h2, 0.0))[:, None]
        ok2 = okn[ia] & okn[ib] & (dab > 1e-12) & (h2 > 0)
        points += [m + h * w, m - h * w]
        valid += [ok2, ok2]
    if K >= 3 and N == 3:  # triple intersections
        i1, i2, i3 = np.array(list(combinations(range(K), 3))).T
        c1, r1 = cn[i1], rn[i1]
        d12 = jnp.linalg.norm(cn[i2] - c1, axis=-1)
        ex = _unit(cn[i2] - c1, e0)
        v13 = cn[i3] - c1
        i = jnp.sum(ex * v13, -1)
        ey_ = v13 - i[:, None] * ex
        j = jnp.linalg.norm(ey_, axis=-1)
        ey = _unit(ey_, e0)
        ez = jnp.cross(ex, ey)
        x = (r1 ** 2 - rn[i2] ** 2 + d12 ** 2) / (2 * jnp.maximum(d12, 1e-12))
        y = ((r1 ** 2 - rn[i3] ** 2 + i ** 2 + j ** 2) / (2 * jnp.maximum(j, 1e-12))
             - i / jnp.maximum(j, 1e-12) * x)
        z2 = r1 ** 2 - x ** 2 - y ** 2
        b = c1 + x[:, None] * ex + y[:, None] * ey
        z = jnp.sqrt(jnp.maximum(z2, 0.0))[:, None]
        ok3 = okn[i1] & okn[i2] & okn[i3] & (d12 > 1e-12) & (j > 1e-12) & (z2 >= 0)
        points += [b + z * ez, b - z * ez]
        valid += [ok3, ok3]
    # rays: from t = 0, hop to the far end of every sphere the point is inside
    dirs = jnp.asarray(_ray_directions(N), dtype)
    dirs = jnp.concatenate([dirs, _unit(p - g, dirs[0])[None]])
    gc = g - c
    b = dirs @ gc.T  # (D, M)
    disc = b ** 2 - (jnp.sum(gc ** 2, -1) - r ** 2)
    sq = jnp.sqrt(jnp.maximum(disc, 0.0))
    hit = ok & (disc > 0)
    t1, t2 = jnp.where(hit, -b - sq, jnp.inf), jnp.where(hit, -b + sq, -jnp.inf)
    t = jnp.zeros(dirs.shape[0], dtype)
    for _ in range(RAY_HOPS):
        inside = (t1 < t[:, None]) & (t[:, None] < t2)
        t = jnp.maximum(t, jnp.max(jnp.where(inside, t2, -jnp.inf), axis=-1))
    points.append(g + t[:, None] * dirs)
    valid.append(jnp.ones(dirs.shape[0], bool))
    X = jnp.concatenate(points)
    V = jnp.concatenate(valid) & _clear(X, c, r, ok) & jnp.all(jnp.isfinite(X), -1)
    dist = jnp.where(V, jnp.linalg.norm(X - g, axis=-1), jnp.inf)
    k = jnp.argmin(dist)
    return jnp.where(jnp.isfinite(dist[k]), X[k], g), dist[k]
