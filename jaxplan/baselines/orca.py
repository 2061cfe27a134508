"""The ORCA baseline: optimal reciprocal collision avoidance (van den Berg, Guy, Lin and
Manocha, 2011) through RVO2's Python binding pyrvo, in jaxplan's harness (``[planner]
method = "orca"``, planar fleets).

Every ``orca_time_step_s`` (dt) each robot, an RVO2 agent (radius the planner's: the
robot's plus ``safety_margin_m``; maximum speed its v_max; neighbour distance, neighbour
count and the two time horizons from the ``orca_*`` keys), is given a preferred velocity
towards its current waypoint g,

    v_pref = (g - p) / |g - p| * min(v_max, sqrt(2 a_max |g - p|), |g - p| / dt),

the fastest speed from which it can still stop at g (the last term keeps a step from
overshooting it); RVO2 picks the new velocity nearest to it that its ORCA half-planes
allow (it keeps pairs apart down to exact contact of the agents' discs, which in single
precision would count as a contact without the margin).  The change of velocity in one
step is then clamped to a_max dt (RVO2 has no acceleration limit), and the robot moves
at that velocity for the step.  RVO2 computes in single precision: its positions are the
record, each step the straight piece from where RVO2 had the robot to where it has it
one step later (velocity the difference over dt), so that the pieces reproduce RVO2's
positions and join exactly.

Static obstacles are RVO2 polygons (vertices counter-clockwise): a box is its x-y
rectangle, a disc (a planar sphere or cylinder) the regular DISC_SIDES-gon that
circumscribes it.  The workspace faces are not given to RVO2 (the metrics still count
them).  Waypoints advance as in the planner's harness (:mod:`jaxplan.rollout`): a robot
has reached waypoint w at the first instant within goal_tolerance_m of it (at a rest
waypoint, at most goal_speed_tolerance_mps fast), found exactly on each linear piece,
and waypoint w + 1 is published once every robot has reached w.

The run's records have the planner's layout (:class:`jaxplan.rollout.StepRecord`, one
"replan" per ORCA step, one linear piece per robot and step), so that every exact metric,
trajectories.npz, the figures and the run directory are the planner's
(:func:`jaxplan.metrics.report.compute_metrics` with replan_hz = 1 / dt); a step's
status is CONVERGED (RVO2 always returns a velocity), and there are no iterations,
stalls, sidesteps or fallbacks.  The pieces are straight (the velocity jumps by at most
a_max dt at each step): peak_acc_ratio is the largest jump over dt over a_max, and
peak_jerk_ratio is None (:func:`step_limits`).  pyrvo is the
optional ``baselines`` extra.

The harness around RVO2 (:func:`simulate`: preferred velocities, the clamp, the pieces,
the waypoints, the records; :func:`run_orca`: the report) takes the velocity step as an
engine, and serves any dimension N: :mod:`jaxplan.baselines.orca3d` (``method =
"orca3d"``, RVO2-3D in JAX) runs through it too.
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import NamedTuple

import numpy as np

from jaxplan import solve
from jaxplan.config import Config
from jaxplan.metrics.report import compute_metrics
from jaxplan.planner import ACCEPTED, ReplanInfo
from jaxplan.rollout import StepRecord
from jaxplan.scenarios import Scenario
from jaxplan.world import BOX, World

DISC_SIDES = 16  # a disc obstacle: the circumscribed regular polygon of this many sides


class OrcaFinal(NamedTuple):
    """The goal checks at the end of an ORCA run (the fields of
    :class:`jaxplan.rollout.RolloutState` that the metrics read): reached (M, W) bool,
    reach_time (M, W) s (inf where not reached)."""

    reached: np.ndarray
    reach_time: np.ndarray


def pyrvo_module():
    """The pyrvo module, or a ValueError saying how to install it."""
    try:
        import pyrvo
    except ImportError:
        raise ValueError("[planner] method = 'orca' needs pyrvo (RVO2's Python binding): "
                         "pip install -e '.[baselines]'") from None
    return pyrvo


def obstacle_polygons(world: World | None, sides: int = DISC_SIDES) -> list[np.ndarray]:
    """The planar world's obstacles as RVO2 polygons: a list of (V, 2) vertex arrays,
    counter-clockwise, m.  A box: its rectangle; a sphere or cylinder (a disc in the
    plane): the regular ``sides``-gon circumscribing it (vertex radius r / cos(pi /
    sides)), so that the polygon holds the whole disc."""
    if world is None or world.num_obstacles == 0:
        return []
    out = []
    for kind, c, h, r in zip(world.kind, world.center, world.half, world.radius, strict=True):
        c = np.asarray(c, np.float64)[:2]
        if int(kind) == BOX:
            h = np.asarray(h, np.float64)[:2]
            out.append(c + h * np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]]))
        else:
            ang = 2.0 * np.pi * np.arange(sides) / sides
            R = float(r) / math.cos(math.pi / sides)
            out.append(c + R * np.stack([np.cos(ang), np.sin(ang)], axis=-1))
    return out


def preferred_velocity(p, goal, v_max, a_max, dt):
    """(M, N) m/s: towards the goal at min(v_max, sqrt(2 a_max d), d / dt), d = |goal -
    p| (module docstring); 0 at the goal.  p, goal (M, N) m, any N; v_max, a_max (M,)."""
    d = goal - p
    dist = np.linalg.norm(d, axis=-1)
    speed = np.minimum(np.minimum(v_max, np.sqrt(2.0 * a_max * dist)), dist / dt)
    unit = d / np.where(dist > 0, dist, 1.0)[:, None]
    return unit * speed[:, None]


def clamp_change(v_old, v_new, a_max, dt):
    """(M, N) m/s: v_new with its change from v_old clamped to a_max dt (per robot)."""
    dv = v_new - v_old
    n = np.linalg.norm(dv, axis=-1)
    lim = a_max * dt
    scale = np.where(n > lim, lim / np.where(n > 0, n, 1.0), 1.0)
    return v_old + dv * scale[:, None]


def first_arrival(p, v, goal, tol, dt):
    """(M,) s in [0, dt], or NaN: the first instant at which p + v s is within ``tol`` of
    ``goal`` (the root of |p + v s - goal|^2 = tol^2 where the piece enters the ball).
    p, v, goal (M, N)."""
    e = p - goal
    a = np.sum(v * v, axis=-1)
    b = 2.0 * np.sum(v * e, axis=-1)
    c = np.sum(e * e, axis=-1) - tol * tol
    disc = b * b - 4.0 * a * c
    with np.errstate(invalid="ignore", divide="ignore"):
        s = (-b - np.sqrt(np.maximum(disc, 0.0))) / (2.0 * a)
    s = np.where((a > 0) & (disc >= 0), s, np.nan)
    s = np.where(c <= 0, 0.0, s)
    return np.where((s >= 0) & (s <= dt), s, np.nan)


def new_simulator(config: Config, scenario: Scenario):
    """An RVO2 simulator (pyrvo.RVOSimulator) holding the fleet at its starts (agent i is
    robot i, its radius the planning radius: the robot's plus safety_margin_m) and the
    world's obstacles (:func:`obstacle_polygons`), processed."""
    pyrvo = pyrvo_module()
    pc = config.planner
    radius = np.asarray(scenario.radius) + pc.safety_margin_m  # the planning radius
    sim = pyrvo.RVOSimulator()
    sim.set_time_step(pc.orca_time_step_s)
    for i in range(scenario.num_robots):
        sim.add_agent(tuple(float(x) for x in scenario.start[i]), pc.orca_neighbor_dist_m,
                      pc.orca_max_neighbors, pc.orca_time_horizon_s,
                      pc.orca_time_horizon_obst_s, float(radius[i]),
                      float(scenario.v_max[i]), (0.0, 0.0))
    polygons = obstacle_polygons(scenario.world)
    for poly in polygons:
        sim.add_obstacle([tuple(float(x) for x in v) for v in poly])
    if polygons:
        sim.process_obstacles()
    return sim


def positions(sim, M: int) -> np.ndarray:
    """(M, 2) the agents' positions in ``sim``, float64 (RVO2's are single precision)."""
    return np.array([sim.get_agent_position(i).to_tuple() for i in range(M)], np.float64)


def velocities(sim, M: int) -> np.ndarray:
    """(M, 2) the agents' velocities in ``sim``, float64."""
    return np.array([sim.get_agent_velocity(i).to_tuple() for i in range(M)], np.float64)


class RVO2Engine:
    """RVO2 (pyrvo) as :func:`simulate`'s engine: ``sim`` holds the fleet (its
    single-precision positions are the record), ``M`` robots, step ``dt`` s."""

    def __init__(self, sim, M: int, dt: float):
        self.sim, self.M, self.dt = sim, M, dt

    def velocities(self, p, v, pref):
        """(M, 2) m/s: RVO2's new velocities, from its own p and v, towards pref (M, 2)."""
        sim = self.sim
        for i in range(self.M):
            sim.set_agent_pref_velocity(i, (float(pref[i, 0]), float(pref[i, 1])))
        sim.do_step()
        return velocities(sim, self.M)

    def advance(self, p, v_cmd):
        """(p1, v1): RVO2's positions after the agents move from p at v_cmd for dt, and the
        velocity of the straight piece between them (also RVO2's velocities now)."""
        sim, M, dt = self.sim, self.M, self.dt
        for i in range(M):
            q = p[i] + v_cmd[i] * dt
            sim.set_agent_position(i, (float(q[0]), float(q[1])))
        p1 = positions(sim, M)  # RVO2's single-precision positions: the record
        v1 = (p1 - p) / dt
        for i in range(M):
            sim.set_agent_velocity(i, (float(v1[i, 0]), float(v1[i, 1])))
        return p1, v1


def simulate_orca(config: Config, scenario: Scenario, progress=None):
    """Run ORCA on the scenario for ceil(duration_s / orca_time_step_s) steps.

    Returns (records: StepRecord of numpy arrays stacked over the K steps (t (K,), p, v,
    a (K, M, 2), one piece per robot and step: piece_t0, piece_t1 (K, M, 1),
    piece_coeffs (K, M, 1, 2, 2) monomials in t - piece_t0 seconds), final
    (:class:`OrcaFinal`), step_ms (K,) wall time of each step, run_s).
    ``progress``: optional callable(steps done).
    """
    where = config.source or config.name
    if scenario.dim != 2:
        raise ValueError(f"{where}: [planner] method = 'orca' is planar-only for now")
    if config.sim.backend != "ideal":
        raise ValueError(f"{where}: [planner] method = 'orca' moves the robots itself: "
                         "sim.backend must be 'ideal'")
    M = scenario.num_robots
    sim = new_simulator(config, scenario)
    engine = RVO2Engine(sim, M, float(config.planner.orca_time_step_s))
    return simulate(config, scenario, engine, positions(sim, M), progress)


def simulate(config: Config, scenario: Scenario, engine, p0: np.ndarray, progress=None):
    """The ORCA harness, shared by the engines (module docstring): from p0 (M, N) m at
    rest, ceil(duration_s / orca_time_step_s) steps of dt, each: the preferred velocities
    towards the current waypoints, ``engine.velocities(p, v, pref)`` (M, N) m/s, the
    change clamped to a_max dt, ``engine.advance(p, v_cmd)`` -> (p1, v1) where the step
    ends and the velocity of its straight piece, the goal checks on the piece, the next
    waypoint once every robot has reached the current one.

    Returns (records: StepRecord of numpy arrays stacked over the K steps (t (K,), p, v,
    a (K, M, N), one piece per robot and step: piece_t0, piece_t1 (K, M, 1),
    piece_coeffs (K, M, 1, N, 2) monomials in t - piece_t0 seconds), final
    (:class:`OrcaFinal`), step_ms (K,) wall time of each step, run_s).
    ``progress``: optional callable(steps done).
    """
    pc = config.planner
    dt = float(pc.orca_time_step_s)
    K = max(1, math.ceil(config.sim.duration_s / dt - 1e-9))
    M, W = scenario.num_robots, scenario.num_waypoints
    v_max, a_max = np.asarray(scenario.v_max), np.asarray(scenario.a_max)
    tol, speed_tol = config.sim.goal_tolerance_m, config.sim.goal_speed_tolerance_mps
    p, v = p0, np.zeros_like(p0)
    wp = 0
    reached = np.zeros((M, W), bool)
    reach_time = np.full((M, W), np.inf)
    rec = {k: [] for k in ("t", "p", "v", "c", "wp", "goal")}
    ms = np.empty(K)
    t_run = time.perf_counter()
    for k in range(K):
        t0 = k * dt
        tick = time.perf_counter()
        goal = np.asarray(scenario.waypoints[:, wp], np.float64)
        pref = preferred_velocity(p, goal, v_max, a_max, dt)
        v_cmd = clamp_change(v, engine.velocities(p, v, pref), a_max, dt)
        p1, v1 = engine.advance(p, v_cmd)
        ms[k] = 1e3 * (time.perf_counter() - tick)
        rec["t"].append(t0)
        rec["p"].append(p)
        rec["v"].append(v)
        rec["c"].append(np.stack([p, v1], axis=-1))  # (M, N, 2): p + v1 (t - t0)
        rec["wp"].append(wp)
        rec["goal"].append(goal)
        # the goal checks on the piece, then the next waypoint once all have arrived
        s = first_arrival(p, v1, goal, tol, dt)
        rest = np.asarray(scenario.rest)[:, wp]
        hit = np.isfinite(s) & (~rest | (np.linalg.norm(v1, axis=-1) <= speed_tol))
        new = hit & ~reached[:, wp]
        reach_time[new, wp] = t0 + s[new]
        reached[:, wp] |= hit
        if np.all(reached[:, wp]) and wp < W - 1:
            wp += 1
        p, v = p1, v1
        if progress:
            progress(k + 1)
    run_s = time.perf_counter() - t_run
    records = _records(rec, dt, M)
    return records, OrcaFinal(reached, reach_time), ms, run_s


def _records(rec: dict, dt: float, M: int) -> StepRecord:
    """The steps' lists as a StepRecord of stacked numpy arrays (module docstring)."""
    t = np.asarray(rec["t"], np.float64)
    K = t.shape[0]
    p, v = np.stack(rec["p"]), np.stack(rec["v"])
    zi = np.zeros((K, M), np.int32)
    zb = np.zeros((K, M), bool)
    info = ReplanInfo(status=np.full((K, M), solve.CONVERGED, np.int32), iterations=zi,
                      objective=np.zeros((K, M)), eq_violation=np.zeros((K, M)),
                      ineq_violation=np.zeros((K, M)),
                      fallback=np.full((K, M), int(ACCEPTED), np.int32), goal_moved=zb,
                      stalled=zb, sidestep=zb, goal_point=np.stack(rec["goal"]))
    t0 = np.broadcast_to(t[:, None, None], (K, M, 1)).copy()
    return StepRecord(t=t, p=p, v=v, a=np.zeros_like(p), piece_t0=t0, piece_t1=t0 + dt,
                      piece_coeffs=np.stack(rec["c"])[:, :, None], wp=np.asarray(rec["wp"],
                                                                               np.int32),
                      info=info, comm=np.zeros((K, 3)))


def run_orca(config: Config, scenario: Scenario, progress: bool = False, *,
             simulator=simulate_orca):
    """``jaxplan run`` with ``[planner] method = "orca"``: simulate, then the planner's
    report (:func:`jaxplan.metrics.report.compute_metrics`, one replan per ORCA step).

    Returns (metrics, arrays, records, run_s): metrics.json's and trajectories.npz's
    dicts (compile_s 0, run_s the simulation's seconds), the StepRecord of
    ``simulator`` (:func:`simulate_orca`, or another engine's with its signature and
    returns: :func:`jaxplan.baselines.orca3d.simulate_orca3d`).  ``progress``: a
    progress bar over the steps on stderr.
    """
    pc = config.planner
    bar = None
    if progress:
        from jaxplan.progress import AfterFirstUpdate

        steps = max(1, math.ceil(config.sim.duration_s / pc.orca_time_step_s - 1e-9))
        bar = AfterFirstUpdate(steps, config.name, "step", leave=False)
    records, final, ms, run_s = simulator(config, scenario,
                                          bar.set if bar is not None else None)
    if bar is not None:
        bar.close()
    # one "replan" per ORCA step: the report's periods are the steps
    stepped = dataclasses.replace(config, planner=dataclasses.replace(
        pc, replan_hz=1.0 / pc.orca_time_step_s))
    metrics, arrays = compute_metrics(stepped, scenario, records, final, ms)
    step_limits(metrics, records, scenario, float(pc.orca_time_step_s))
    metrics["compile_s"] = 0.0
    metrics["run_s"] = run_s
    return metrics, arrays, records, run_s


def step_limits(metrics: dict, records: StepRecord, scenario: Scenario, dt: float) -> None:
    """Set ``metrics``' acceleration and jerk peaks (fleet and per robot) to what ORCA's
    stepwise motion means: the pieces are straight, so their own accelerations read 0,
    but the velocity jumps at every step; peak_acc_ratio is the largest jump over dt
    (|v_k+1 - v_k| / dt, the step's mean acceleration, <= a_max by the clamp) over the
    robot's a_max, and peak_jerk_ratio is None (a velocity step has no finite jerk)."""
    c = np.asarray(records.piece_coeffs)[:, :, 0, :, 1]  # (K, M, N): each step's velocity
    v = np.concatenate([np.zeros_like(c[:1]), c])  # from rest
    jump = np.linalg.norm(np.diff(v, axis=0), axis=-1).max(axis=0) / dt  # (M,)
    ratio = jump / np.asarray(scenario.a_max, np.float64)
    metrics["peak_acc_ratio"] = float(ratio.max())
    metrics["peak_jerk_ratio"] = None
    for r, x in zip(metrics["per_robot"], ratio, strict=True):
        r["peak_acc_ratio"] = float(x)
        r["peak_jerk_ratio"] = None
