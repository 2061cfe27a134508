"""Stage 2 of a replan: stall detection and the right-hand sidestep (docs/DESIGN.md,
[planner] deadlock).

Local NLPs can settle into an equilibrium: a ring of robots that swap across its centre
stops where every robot's plan keeps clear of the others' predictions through the
centre, with every solve converged; robots in a cluster hold each other off their goals.
Each robot detects this from its own view and resolves it on its own (decentralized;
deterministic, no random draws).

Detection (:func:`observe`).  Robot i tracks ``best``, the smallest distance to its
current goal since its progress clock last restarted, and ``since``, the time since that
distance last fell by at least ``progress`` (m).  It is **stalled** when
``since >= window`` (s), it is more than ``progress`` from its goal, its goal is not
occupied (a robot parked beside an occupied goal waits by design,
:func:`jaxplan.planner.goals.free_goals`) and another robot it sees is within ``near``
(m) of clearance (centre distance minus both radii).  The clock restarts when its goal
changes, while it sidesteps, and while a robot that has been at its goal moves away from
it (``best`` follows it: a free end is passed at speed, and the way back is measured
from the farthest point).  In a *mutual* stall (``mutual``: no robot near it is on its
way, :func:`progressing`) of a robot that is not on its way either (``moving``) the
window is ``window_mutual`` (:func:`mutual_window`: in 3-D under "auto"), once
``window`` has passed since its goal was set or its last sidestep; the sidestep such a
stall starts lasts ``hold_mutual`` (:func:`mutual_hold`).  The two conditions keep the
short window from catching robots that are slow but on their way, robots starting from
rest and robots turning back to their goals after a sidestep (docs/SOLVER.md, "Why the
planner's safeguards are there").

Resolution (:func:`planning_goals`): a robot that has been stalled for ``wait`` seconds
(:func:`sidestep_wait`: none in the plane, a few in 3-D, where most stalls are a robot
waiting for another to pass and end by themselves; none either, with ``mutual``, where no
robot near it is on its way, :func:`progressing`: a mutual stall, which waiting does not
end) *sidesteps* for ``hold`` seconds: every replan it plans to a sub-goal ``step`` m
from where it is, at ``angle`` to the right of the direction to its goal (right:
clockwise seen from above, +z up; in 3-D the right is horizontal), with a rest end there
(a position-only end at a sub-goal that moves on every replan is chased ever faster).
Being always ``step`` ahead, it is never reached.  With the same rule in every robot,
robots that meet head on pass each other on the right and a stalled ring turns into a
roundabout; the sub-goal is what the robot broadcasts as its goal while it sidesteps
(:func:`published_goals`), so the others predict where it is going.  Then it flies to
its goal again, and its progress clock starts afresh.

Broadcast (:func:`broadcast`): with the sidestep enabled (and announce: not in a 3-D
fleet under "auto", :func:`announces_plan_ends`), each robot broadcasts the end of
the plan it flies, not only its goal: its sub-goal, the free point beside an occupied
goal, or, when it flies its braking plan, that plan's stopping point at rest (and, when it
keeps its previous plan, what it broadcast for that plan).  The others' closed-form
predictions then brake with it instead of flying on to its goal.

In a replan (:func:`jaxplan.planner.replan`): :func:`stall_step` runs the detection for
the fleet from each robot's own views, :func:`jaxplan.planner.goals.sidestep_goals`
puts the sub-goals in place of the goals, and :func:`after_replan` records what each
robot will broadcast.

Everything here is pure and jit-able; parameters are traced (:class:`DeadlockParams`:
a change does not recompile; ``enabled`` switches the sidestep off, detection stays).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxplan.nlp import NLPParams
from jaxplan.planner.types import (
    DeadlockParams,
    DeadlockState,
    Fallback,
    FleetParams,
    FleetState,
    Goals,
    PlanState,
)
from jaxplan.planner.views import sender_mask
from jaxplan.trajectory import Trajectory

RESOLUTIONS = ("auto", "sidestep", "off")


def _check(resolution: str) -> None:
    if resolution not in RESOLUTIONS:
        raise ValueError(f"deadlock resolution {resolution!r}: choose from {RESOLUTIONS}")


def resolution_enabled(resolution: str, dim: int) -> bool:
    """Whether a fleet in ``dim`` dimensions sidesteps under ``[planner] deadlock``:
    "sidestep" and "auto" (the default) always, "off" never (:func:`sidestep_wait`
    says when)."""
    _check(resolution)
    return resolution != "off"


def sidestep_wait(resolution: str, dim: int, wait_3d: float) -> float:
    """Seconds a stalled robot waits before it sidesteps: ``wait_3d`` for a 3-D fleet
    under "auto" (a 3-D fleet mostly leaves a stall through the third dimension by
    itself, in a few seconds: a robot waiting for another to pass), else 0 (a planar
    fleet cannot)."""
    _check(resolution)
    return float(wait_3d) if resolution == "auto" and dim == 3 else 0.0


# the stall window of ``stall_window_s = "auto"`` (:func:`stall_window`), s
STALL_WINDOW_PLANAR_S = 1.0
STALL_WINDOW_3D_S = 2.0


def stall_window(window: float | str, dim: int) -> float:
    """The stall window (s) of a fleet in ``dim`` dimensions: ``[planner] stall_window_s``
    as given, or for "auto" (the default) STALL_WINDOW_PLANAR_S in the plane and
    STALL_WINDOW_3D_S in 3-D.  A planar crowd stalls often and resolves each stall only
    by its sidestep, the sooner the better; a 3-D fleet mostly leaves a stall through
    the third dimension by itself, and waits (:func:`sidestep_wait`)."""
    if window == "auto":
        return STALL_WINDOW_PLANAR_S if dim == 2 else STALL_WINDOW_3D_S
    return float(window)


def mutual_window(resolution: str, dim: int, window: float, window_mutual: float) -> float:
    """The window of a mutual stall (:func:`observe`): ``window_mutual`` for a 3-D fleet
    under "auto" (the fleets that wait before they sidestep), else ``window`` (the
    fleet's stall window, :func:`stall_window`).  A planar fleet sidesteps at its first
    stall, after ``window``, mutual or not."""
    return float(window_mutual if _short_mutual(resolution, dim) else window)


def mutual_hold(resolution: str, dim: int, hold: float, hold_mutual: float) -> float:
    """How long a sidestep that starts in a short-window mutual stall lasts
    (:func:`observe`): ``hold_mutual`` for a 3-D fleet under "auto", else ``hold`` (the
    fleets for which :func:`mutual_window` shortens the window)."""
    return float(hold_mutual if _short_mutual(resolution, dim) else hold)


def _short_mutual(resolution: str, dim: int) -> bool:
    """Whether a fleet uses the mutual stall's own window and hold: a 3-D fleet under
    "auto" (:func:`mutual_window`, :func:`mutual_hold`)."""
    _check(resolution)
    return resolution == "auto" and dim == 3


def announces_plan_ends(resolution: str, dim: int) -> bool:
    """Whether each robot broadcasts the end of the plan it flies (:func:`broadcast`)
    rather than its goal: with the sidestep, except a 3-D fleet under "auto", which
    broadcasts its goals as the paper's planner does (and its sub-goal while it
    sidesteps): there the plan ends slowed the fleet without making it safer."""
    _check(resolution)
    return resolution == "sidestep" or (resolution == "auto" and dim == 2)


def default_params(enabled: bool = True, window: float = 2.0, progress: float = 0.2,
                   near: float = 1.0, hold: float = 2.0, step: float = 1.0,
                   angle_deg: float = 60.0, wait: float = 0.0,
                   announce: bool | None = None, mutual: bool = True,
                   window_mutual: float | None = None,
                   hold_mutual: float | None = None) -> DeadlockParams:
    """DeadlockParams from plain numbers (the config's defaults); announce None: as
    ``enabled``; window_mutual None: ``window``; hold_mutual None: ``hold``."""
    f = lambda x: jnp.asarray(float(x))  # noqa: E731
    announce = enabled if announce is None else announce
    return DeadlockParams(jnp.asarray(bool(enabled)), f(window), f(progress), f(near),
                          f(hold), f(step), f(jnp.deg2rad(angle_deg)), f(wait),
                          jnp.asarray(bool(announce)), jnp.asarray(bool(mutual)),
                          f(window if window_mutual is None else window_mutual),
                          f(hold if hold_mutual is None else hold_mutual))


def initial_state(p, goal=None) -> DeadlockState:
    """No robot stalled; goals unknown (NaN: the first replan restarts every clock).
    p: (M, N) positions."""
    M = p.shape[0]
    g = jnp.full_like(p, jnp.nan) if goal is None else goal
    # dtype given: a weakly typed fill would differ from the step's output state, and the
    # step program would compile twice (for the first state and for every later one)
    inf = jnp.full((M,), jnp.inf, dtype=jnp.float64)
    return DeadlockState(g, inf, jnp.zeros((M,)), jnp.zeros((M,)), jnp.asarray(p),
                         jnp.zeros((M,), bool), jnp.asarray(p),
                         jnp.zeros_like(p), jnp.zeros((M,), bool), jnp.zeros((M,), bool),
                         jnp.zeros((M,), bool), jnp.zeros((M,)))


def right_of(u):
    """The unit vector to the right of directions u (..., N), N = 2 or 3 (+z up): in the
    horizontal plane, (u_y, -u_x[, 0]) normalized; +x where u is vertical or zero."""
    r = jnp.stack([u[..., 1], -u[..., 0]], axis=-1)
    if u.shape[-1] == 3:
        r = jnp.concatenate([r, jnp.zeros_like(u[..., :1])], axis=-1)
    n = jnp.linalg.norm(r, axis=-1, keepdims=True)
    ex = jnp.zeros(u.shape[-1]).at[0].set(1.0)
    return jnp.where(n > 1e-9, r / jnp.maximum(n, 1e-300), ex)


def near_pairs(p, others_p, radius, other_radius, mask, near):
    """(M, Mo) bool: other robot k (others_p (M, Mo, N), its radius (M, Mo), mask
    (M, Mo)) is within ``near`` m of clearance of robot i (p (M, N), radius (M,))."""
    d = jnp.linalg.norm(others_p - p[:, None, :], axis=-1)
    clear = d - radius[:, None] - other_radius
    return mask & jnp.isfinite(clear) & (clear <= near)


def progressing(others_p, others_v, others_goal, prm: DeadlockParams):
    """(M, Mo) bool: as robot i sees it, other robot k is on its way: more than
    ``progress`` m from the goal it broadcasts and closing on it at more than
    ``progress / window`` m/s (the least rate that keeps a robot from being stalled).
    others_p, others_v, others_goal: (M, Mo, N)."""
    g = others_goal - others_p
    d = jnp.linalg.norm(g, axis=-1)
    rate = jnp.sum(others_v * g, axis=-1) / jnp.maximum(d, 1e-9)
    ok = jnp.isfinite(rate) & jnp.isfinite(d)
    return ok & (d > prm.progress) & (rate > prm.progress / prm.window)


def _goal_distance(p, goal_p):
    """(M,) m from p to goal_p ((M, N) each); 0 where not finite."""
    d = jnp.linalg.norm(goal_p - p, axis=-1)
    return jnp.where(jnp.isfinite(d), d, 0.0)


def observe(ds: DeadlockState, prm: DeadlockParams, dt, p, goal_p, near, mutual=None,
            moving=None):
    """One replan's stall bookkeeping.

    Args: ds: the state after the previous replan.  prm: DeadlockParams.  dt: () s since
    then.  p: (M, N) positions now.  goal_p: (M, N) current goals (the real ones).
    near: (M,) bool, another robot close (any of :func:`near_pairs`).  mutual: (M,) bool, no
    robot near i is on its way (:func:`progressing`): with ``prm.mutual`` a stalled
    robot then sidesteps without ``wait`` (None: never mutual).  moving: (M,) bool, robot
    i itself is on its way (:func:`progressing` of its own state): then not
    ``window_mutual`` but ``window`` (None: not moving).
    Returns: (new DeadlockState, stalled (M,) bool, sidestep (M,) bool: sidestepping
    in this replan, started (M,) bool: a sidestep starts now).
    """
    d = _goal_distance(p, goal_p)
    new_goal = ~jnp.all(goal_p == ds.goal, axis=-1)
    left = jnp.maximum(ds.left - dt, 0.0)
    left = jnp.where(new_goal, 0.0, left)
    side = left > 0
    improved = d <= ds.best - prm.progress
    # a robot that has been at its goal and drifts away from it (a free end is passed at
    # speed) measures its way back from the farthest point: the clock restarts while it
    # moves away (else the turn back, which cannot come 0.2 m closer than the goal it
    # passed, counted as a stall)
    away = ds.arrived & ~new_goal & (d > ds.best)
    restart = new_goal | improved | side | away
    best = jnp.where(restart, d, ds.best)
    since = jnp.where(restart, 0.0, ds.since + dt)
    arrived = jnp.where(new_goal, False, ds.arrived) | (d <= prm.progress)
    # a mutual stall (no robot near is on its way) does not end by waiting: it is one
    # after window_mutual and the sidestep starts at once
    settled = jnp.where(new_goal | side, 0.0, ds.settled + dt)
    mut = jnp.zeros_like(near) if mutual is None else mutual & prm.mutual
    short = mut & (settled >= prm.window)
    if moving is not None:
        short = short & ~moving
    window = jnp.where(short, jnp.minimum(prm.window_mutual, prm.window), prm.window)
    stalled = (since >= window) & (d > prm.progress) & near & ~ds.occupied
    started = stalled & prm.enabled & (since >= jnp.where(mut, window, prm.window + prm.wait))
    left = jnp.where(started, jnp.where(short, prm.hold_mutual, prm.hold), left)
    side = left > 0
    # the clock restarts while sidestepping (progress is measured afresh afterwards)
    best = jnp.where(side, d, best)
    since = jnp.where(side, 0.0, since)
    sub = jnp.where(side[:, None], sidestep_goal(p, goal_p, prm), p)
    # no NaN is carried: a non-finite position or goal keeps the previous entries
    fin = lambda x, old: jnp.where(jnp.isfinite(x), x, jnp.where(jnp.isfinite(old), old, 0.0))
    sub = fin(sub, ds.sub)
    goal_kept = fin(goal_p, ds.goal)
    settled = jnp.where(side, 0.0, settled)
    new = ds._replace(goal=goal_kept, best=best, since=since, left=left, sub=sub,
                      arrived=arrived, settled=settled)
    return new, stalled, side, started


def idle(ds: DeadlockState, prm: DeadlockParams, p, goal_p, near):
    """(M,) bool: robots that have made no progress to their goal (goal_p (M, N), p (M, N)
    now) for the stall window with no robot near (near (M,)), not at it, not beside an
    occupied goal and not sidestepping, where the resolution is enabled (ds: the state
    :func:`observe` returned).  Nothing holds such a robot but its own plan: a plan
    whose motion keeps starting later, replan after replan, each warm-started from the
    last, every solve converged.  The planner starts its next solve from the cold
    guesses (``PlanState.retry``)."""
    d = _goal_distance(p, goal_p)
    return (prm.enabled & (ds.since >= prm.window) & (d > prm.progress) & ~near
            & ~ds.occupied & ~(ds.left > 0))


def sidestep_goal(p, goal_p, prm: DeadlockParams):
    """(M, N) the sub-goal ``step`` m (at most the distance to the goal) from p, at
    ``angle`` to the right of the direction to the goal."""
    g = goal_p - p
    d = jnp.linalg.norm(g, axis=-1, keepdims=True)
    u = jnp.where(d > 1e-9, g / jnp.maximum(d, 1e-300), 0.0)
    u = jnp.where(d > 1e-9, u, jnp.zeros_like(u).at[..., 0].set(1.0))
    direction = jnp.cos(prm.angle) * u + jnp.sin(prm.angle) * right_of(u)
    return p + jnp.minimum(prm.step, jnp.maximum(d, 1e-3)) * direction


def planning_goals(ds: DeadlockState, goal_p, goal_v, rest):
    """The goals each robot plans to: its sub-goal (a rest end) while it sidesteps, else
    its goal.  goal_p, goal_v (M, N); rest (M,), True: fully defined end state."""
    side = ds.left > 0
    return (jnp.where(side[:, None], ds.sub, goal_p),
            jnp.where(side[:, None], 0.0, goal_v), side | rest)


def broadcast(ds: DeadlockState, prm: DeadlockParams, planned_p, planned_v, planned_rest,
              stop_p, braking, kept) -> DeadlockState:
    """Record after a replan what each robot will broadcast as its goal at the next one:
    the end of the plan it flies.  Where the sidestep is enabled: the goal it planned to
    (planned_p, planned_v, planned_rest (M, N), (M, N), (M,): its goal, its sidestep
    sub-goal or the free point beside an occupied goal); where it flies its braking plan
    (``braking`` (M,) bool), that plan's stopping point ``stop_p`` (M, N) at rest; where
    it keeps its previous plan (``kept``), what it broadcast for that plan.  Without
    ``prm.announce`` (no sidestep, or a 3-D fleet under "auto"): its goal (the planner as
    the paper has it; its sub-goal while it sidesteps).  A robot that brakes while the
    others are told it flies on can be struck."""
    sel = lambda c, a, b: jnp.where(c.reshape(c.shape + (1,) * (a.ndim - c.ndim)), a, b)  # noqa: E731
    p = sel(braking, stop_p, planned_p)
    v = sel(braking, jnp.zeros_like(planned_v), planned_v)
    rest = braking | planned_rest
    old = kept & ds.pub_ok
    p, v, rest = sel(old, ds.pub_p, p), sel(old, ds.pub_v, v), sel(old, ds.pub_rest, rest)
    on = prm.announce & jnp.all(jnp.isfinite(p), axis=-1) & jnp.all(jnp.isfinite(v), axis=-1)
    # nothing non-finite is carried: where there is nothing to broadcast, the old entries
    return ds._replace(pub_p=sel(on, p, ds.pub_p), pub_v=sel(on, v, ds.pub_v),
                       pub_rest=on & rest, pub_ok=on)


def published_goals(ds: DeadlockState | None, goal_p, goal_v, rest):
    """What each robot broadcasts as its goal before a replan (``ds``: the state after
    the previous replan; None: no deadlock handling): what :func:`broadcast` recorded
    while its goal is the one it was recorded for, else its goal (its sub-goal while it
    sidesteps)."""
    if ds is None:
        return goal_p, goal_v, rest
    use = jnp.all(ds.goal == goal_p, axis=-1) & ds.pub_ok
    goal_p, goal_v, rest = planning_goals(ds, goal_p, goal_v, rest)
    sel = lambda a, b: jnp.where(use.reshape(use.shape + (1,) * (a.ndim - 1)), a, b)  # noqa: E731
    return sel(ds.pub_p, goal_p), sel(ds.pub_v, goal_v), sel(ds.pub_rest, rest)


# ------------------------------------------------------------------ the fleet's stage


class Stalls(NamedTuple):
    """The stall stage of a replan (:func:`stall_step`).

    state: the DeadlockState after this replan's detection (its broadcast is recorded
    after the choice of plans: :func:`after_replan`), or ``PlanState.deadlock`` as it was
    where the planner has no stall handling.  stalled, sidestep, idle: (M,) bool
    (:func:`observe`, :func:`idle`), False for padding robots.
    """

    state: DeadlockState | None
    stalled: jax.Array
    sidestep: jax.Array
    idle: jax.Array


def stall_step(fp: FleetParams, ps: PlanState, fleet: FleetState, goals: Goals) -> Stalls:
    """Stall detection (:func:`observe`, :func:`idle`) for the whole fleet, each robot
    from its own view: who is near, and whether they are on their way, comes from
    ``fleet.views``; its own state is fleet.p, fleet.v (M, N), its goal goals.goal_p
    (M, N).  Without ``fp.deadlock`` (or ``ps.deadlock``): no robot is stalled."""
    p, v, views, goal_p = fleet.p, fleet.v, fleet.views, goals.goal_p
    M = p.shape[0]
    off = jnp.zeros((M,), bool)
    if fp.deadlock is None or ps.deadlock is None:
        return Stalls(ps.deadlock, off, off, off)
    pairs = near_pairs(p, views.p, fp.radius, jnp.broadcast_to(fp.radius, (M, M)),
                       sender_mask(fp, views), fp.deadlock.near)
    near = jnp.any(pairs, axis=-1)
    mutual = ~jnp.any(pairs & progressing(views.p, views.v, views.goal_p, fp.deadlock),
                      axis=-1)
    own = progressing(p[:, None], v[:, None], goal_p[:, None], fp.deadlock)[:, 0]
    ds, stalled, side, _ = observe(ps.deadlock, fp.deadlock, fp.dt, p, goal_p, near,
                                   mutual, own)
    lazy = idle(ds, fp.deadlock, p, goal_p, near) & fp.robot_mask
    stalled, side = stalled & fp.robot_mask, side & fp.robot_mask
    ds = ds._replace(left=jnp.where(fp.robot_mask, ds.left, 0.0))
    return Stalls(ds, stalled, side, lazy)


def after_replan(fp: FleetParams, stalls: Stalls, moved, params: NLPParams,
                 plan: Trajectory, fallback) -> DeadlockState | None:
    """The stall memory carried to the next replan: ``occupied``, the robot planned
    beside an occupied goal (moved (M,) bool, not while it sidesteps), and what it will
    broadcast (:func:`broadcast`): the end it planned to (params.goal_p, goal_v, rest),
    the stopping point of the plan it flies (plan (M,)) where it brakes, what it
    broadcast before where it keeps its previous plan (fallback (M,): Fallback codes).
    None where ``stalls.state`` is None."""
    ds = stalls.state
    if ds is None:
        return None
    ds = ds._replace(occupied=moved & ~stalls.sidestep)
    # the next broadcast: the end of the plan flown (a braking plan's stopping point)
    return broadcast(ds, fp.deadlock, params.goal_p, params.goal_v, params.rest,
                     plan.evaluate(plan.duration), fallback == Fallback.BRAKING,
                     fallback == Fallback.KEPT_PREVIOUS)


# ------------------------------------------------------------------ on the host (metrics)


def stall_summary(stalled, sidestep, dt: float):
    """Per robot, from the per-replan flags stalled, sidestep (R, M) bool (numpy):
    (stalls (M,) int: stall onsets (a replan stalled after one that was not),
    stalled_s (M,): time stalled, sidestep_s (M,): time sidestepping)."""
    import numpy as np

    s = np.asarray(stalled, bool)
    prev = np.concatenate([np.zeros((1,) + s.shape[1:], bool), s[:-1]], axis=0)
    onsets = np.sum(s & ~prev, axis=0)
    return (onsets.astype(int), np.sum(s, axis=0) * dt,
            np.sum(np.asarray(sidestep, bool), axis=0) * dt)
