"""A run's report: metrics.json and trajectories.npz from its records (host, NumPy;
docs/DESIGN.md "A run directory" names every key).

    compute_metrics(config, scenario, records, final, solve_ms) -> (metrics, arrays)
    merge_sim_metrics(metrics, arrays, scenario, period)     backend "mjx": what the
                                                             simulation measures
    sim_metrics(...), sim_world_report(...)    those measures, on the simulated states
    pieces_from_records(records)               the executed pieces
    goal_departure(t, pos, goal, reach_time)   how far robots went from a reached goal
    limit_metrics(scenario, pieces, kin, ...)  peaks over the limits, goal excursion, escape

The numbers come from the exact measures of :mod:`jaxplan.metrics` (separation,
kinematics, clearance, excursion) on the executed pieces, and from the planner's records
(stalls, fallbacks, statuses, faults).  :func:`jaxplan.experiment.run` calls it after a run;
a sweep calls :func:`compute_metrics` on each run of a batch.
"""

from __future__ import annotations

import math

import numpy as np

from jaxplan import solve
from jaxplan.config import Config
from jaxplan.metrics.clearance import world_clearance, world_report
from jaxplan.metrics.excursion import escape_pieces, fleet_box, goal_excursion_pieces
from jaxplan.metrics.motion import (
    kinematics,
    makespan_bound,
    parked_robots,
    sample_pieces,
    solver_summary,
    time_to_goal,
)
from jaxplan.metrics.separation import pairwise_min_separation, separation_report
from jaxplan.planner import ACCEPTED, BEST_EFFORT, BRAKING, KEPT_PREVIOUS
from jaxplan.planner.stall import stall_summary
from jaxplan.scenarios import Scenario
from jaxplan.world import World, face_names, world_arrays

__all__ = ["SAMPLE_HZ", "ESCAPE_MARGIN_M", "SIM_WORLD_KEYS", "compute_metrics",
           "merge_sim_metrics", "sim_metrics", "sim_world_report", "pieces_from_records",
           "goal_departure", "limit_metrics"]

SAMPLE_HZ = 100.0  # trajectories.npz sampling rate
ESCAPE_MARGIN_M = 1.0  # escape_m: the fleet's box of starts and waypoints grown by this, m


# the world keys of metrics.json that the mjx backend measures (sim_metrics)
SIM_WORLD_KEYS = ("obstacle_collisions", "min_obstacle_clearance_m", "worst_obstacle",
                  "workspace_violations", "min_workspace_clearance_m", "worst_workspace")


def sim_world_report(world: World, static_dist, static_t, radius) -> dict:
    """The world's contacts on the simulated states (SIM_WORLD_KEYS).

    Args:
        world: the scenario's World (its static_rows: K obstacles, then the finite faces).
        static_dist: (P, M, R) per period, each robot's minimum centre signed distance to
            each row over every physics state (PeriodRecord.static_dist), m.
        static_t: (P, M, R) when, s.  radius: (M,) collision radii, m.
    Returns:
        obstacle_collisions / workspace_violations: (robot, obstacle) / (robot, face)
        pairs whose clearance (signed distance - radius) fell below 0;
        min_obstacle_clearance_m / min_workspace_clearance_m: the minimum clearance (None
        without obstacles / finite faces); worst_obstacle {robot, obstacle, t} /
        worst_workspace {robot, face ("z_min", ...), t} of that minimum (None likewise).
    """
    sd = np.asarray(static_dist, np.float64)
    ts = np.asarray(static_t, np.float64)
    P, M, R = sd.shape
    K = world.num_obstacles
    faces = face_names(world)
    if R != K + len(faces):
        raise ValueError(f"static_dist has {R} rows, the world {K} obstacles and "
                         f"{len(faces)} faces")
    filled = np.where(np.isnan(sd), np.inf, sd)
    p = np.argmin(filled, axis=0) if P else np.zeros((M, R), int)  # (M, R) period of the min
    dmin = np.take_along_axis(filled, p[None], axis=0)[0] if P else np.full((M, R), np.inf)
    tmin = np.take_along_axis(ts, p[None], axis=0)[0] if P else np.full((M, R), np.nan)
    clear = dmin - np.asarray(radius, np.float64)[:, None]
    out = {}
    for what, cols, label, name in (("obstacle", slice(0, K), "obstacle", list(range(K))),
                                    ("workspace", slice(K, R), "face", faces)):
        c, t = clear[:, cols], tmin[:, cols]
        hits = int(np.sum(c < 0))
        count = "obstacle_collisions" if what == "obstacle" else "workspace_violations"
        out[count] = hits
        if c.size and np.any(np.isfinite(c)):
            i, k = np.unravel_index(int(np.argmin(c)), c.shape)
            out[f"min_{what}_clearance_m"] = _num(c[i, k])
            out[f"worst_{what}"] = {"robot": int(i), label: name[k], "t": _num(t[i, k])}
        else:
            out[f"min_{what}_clearance_m"] = None
            out[f"worst_{what}"] = None
    return out


def sim_metrics(scenario: Scenario, period, duration: float) -> tuple[dict, dict]:
    """Metrics measured on the simulated states (backend "mjx").

    Separation: the minimum centre distance over every physics step (PeriodRecord.min_dist).
    World contacts: the minimum signed distance of every robot's centre to every obstacle
    and workspace face over every physics step (PeriodRecord.static_dist) minus its
    collision radius (:func:`sim_world_report`).  Kinematics and tracking: the
    control-rate samples (tracked_peak_speed_ratio, tracked_peak_acc_ratio: the largest
    simulated speed and acceleration (qacc) over each robot's own v_max, a_max).
    Returns (metric overrides, arrays).
    """
    valid = np.asarray(period.valid)  # (P, K)
    t = np.asarray(period.t)[valid]
    take = lambda x: np.swapaxes(np.asarray(x), 1, 2)[valid].transpose(1, 0, 2)  # (M, T, 3)
    pos, vel, acc = take(period.pos), take(period.vel), take(period.acc)
    err = np.swapaxes(np.asarray(period.track_err), 1, 2)[valid].T  # (M, T)
    min_dist = np.min(np.asarray(period.min_dist), axis=0)
    sep = separation_report(min_dist, scenario.radius)
    speed = np.linalg.norm(vel, axis=-1)
    accn = np.linalg.norm(acc, axis=-1)
    path = np.sum(np.linalg.norm(np.diff(pos, axis=1), axis=-1), axis=1)
    sat = np.asarray(period.saturated).sum(axis=0)
    ticks = valid.sum()
    out = {
        "collisions": int(sep["collisions"]),
        "min_separation_ratio": _num(sep["min_separation_ratio"]),
        "worst_pair": list(sep["worst_pair"]) if sep["worst_pair"] is not None else None,
        "separation_source": "simulated states at physics rate",
        **sim_world_report(scenario.world, period.static_dist, period.static_t,
                           scenario.radius),
        "peak_speed": _num(speed.max()),
        "peak_speed_over_limit": _num(np.max(speed.max(axis=1) / scenario.v_max)),
        "tracked_peak_speed_ratio": _num(np.max(speed.max(axis=1) / scenario.v_max)),
        "tracked_peak_acc_ratio": _num(np.max(accn.max(axis=1) / scenario.a_max)),
        "tracking": {"rms_m": _num(np.sqrt(np.mean(err**2))), "max_m": _num(err.max()),
                     "per_robot_rms_m": [_num(x) for x in np.sqrt(np.mean(err**2, axis=1))]},
        "rotor_saturation": {"ticks": [int(x) for x in sat],
                             "fraction": _num(sat.sum() / max(1, ticks * len(sat)))},
        "nonfinite_vehicles": int(np.any(np.asarray(period.nonfinite), axis=0).sum()),
        "bad_references": int(np.asarray(period.bad_reference).sum()),
    }
    per_robot = [{"max_speed": _num(speed[i].max()), "max_acc": _num(accn[i].max()),
                  "path_length_m": _num(path[i]),
                  "tracked_peak_speed_ratio": _num(speed[i].max() / scenario.v_max[i]),
                  "tracked_peak_acc_ratio": _num(accn[i].max() / scenario.a_max[i])}
                 for i in range(pos.shape[0])]
    arrays = {"t": t, "pos": pos, "vel": vel, "acc": acc,
              "min_dist": np.where(np.isfinite(min_dist), min_dist, np.nan),
              "track_err": err}
    del duration
    return {"sim": out, "per_robot": per_robot}, arrays


def merge_sim_metrics(metrics: dict, arrays: dict, scenario: Scenario, period) -> None:
    """Backend "mjx": put what the simulation measures into a run's report, in place.

    metrics, arrays: :func:`compute_metrics`'s, from the planned pieces; period: the
    stacked PeriodRecords (jaxplan.sim.closed_loop).  The separation, the world's
    contacts, the peak speed and the per-robot kinematics become the simulated states'
    (:func:`sim_metrics`; the planned maxima stay as ``planned_max_*``, and ``max_jerk``
    is None: no jerk sensor), tracking and rotor saturation are added, ``success`` is
    judged again, and the samples of ``arrays`` become the control-rate samples.  The
    keys of :func:`limit_metrics` stay the planned pieces'; the simulated vehicles' own
    peaks are added beside them (``tracked_peak_speed_ratio``, ``tracked_peak_acc_ratio``,
    fleet-wide and per robot; ``peak_speed_over_limit`` is the tracked one, as before).
    """
    over, sim_arrays = sim_metrics(scenario, period, metrics["duration_s"])
    s = over["sim"]
    for k in ("collisions", "min_separation_ratio", "worst_pair", "peak_speed",
              "peak_speed_over_limit", *SIM_WORLD_KEYS):
        metrics[k] = s.pop(k)
    metrics.update(s)
    for r, o in zip(metrics["per_robot"], over["per_robot"], strict=True):
        r["planned_max_speed"], r["planned_max_acc"] = r["max_speed"], r["max_acc"]
        r["planned_max_jerk"] = r.pop("max_jerk")
        r["max_jerk"] = None  # not measured on the simulation (no jerk sensor)
        r.update(o)
    metrics["success"] = _success(metrics)
    metrics["solver"]["timing"] = "wall time of each period: replan + physics + control"
    arrays.update(sim_arrays)


def pieces_from_records(records):
    """Flatten the executed pieces: seg_robot, seg_t0, seg_t1, seg_coeffs (non-empty only)."""
    t0 = np.asarray(records.piece_t0)  # (K, M, S+1)
    t1 = np.asarray(records.piece_t1)
    c = np.asarray(records.piece_coeffs)  # (K, M, S+1, N, D+1)
    K, M, P = t0.shape
    robot = np.broadcast_to(np.arange(M)[None, :, None], (K, M, P))
    keep = t1 > t0
    order = np.lexsort((t0[keep], robot[keep]))
    return (robot[keep][order].astype(np.int32), t0[keep][order], t1[keep][order],
            c[keep][order])


def compute_metrics(config: Config, scenario: Scenario, records, final,
                    solve_ms) -> tuple[dict, dict]:
    """metrics.json dict and trajectories.npz dict of a finished run.

    records: the stacked StepRecords (numpy, leading axis the replans); final: the final
    RolloutState (its reached, reach_time); solve_ms: (R,) ms, each timed replan's wall
    time (empty when none was timed, as in a sweep's batch).  Every measure of the
    executed pieces is exact (:mod:`jaxplan.metrics`); trajectories.npz samples them at
    SAMPLE_HZ.
    """
    M = scenario.start.shape[0]
    duration = records.t.shape[0] * (1.0 / config.planner.replan_hz)
    pieces = pieces_from_records(records)
    min_dist, _ = pairwise_min_separation(*pieces, num_robots=M)
    sep = separation_report(min_dist, scenario.radius)
    kin = kinematics(*pieces, num_robots=M)
    world = world_report(world_clearance(*pieces, scenario.radius, scenario.world,
                                         num_robots=M))
    frozen_robot = config.faults.frozen_robot if config.faults.enabled else -1
    # the robots whose arrival counts: not the frozen one, not a non-cooperative one
    responsive = (np.arange(M) != frozen_robot) & np.asarray(scenario.cooperative)
    reached, ttg, all_reached, makespan = _goals(final, duration, responsive)
    limits, limits_per_robot = limit_metrics(scenario, pieces, kin, final.reach_time, reached,
                                             config.sim.goal_tolerance_m)
    info = records.info
    stalls = _stalls(config, scenario, records, reached, ttg, responsive)
    arrays = _run_arrays(scenario, records, pieces, min_dist, duration)
    departure = goal_departure(arrays["t"], arrays["pos"], scenario.waypoints[:, -1], ttg)
    # from when each robot stays at its last waypoint to the end: within goal_tolerance_m
    # (and, for a rest or auto waypoint, at most goal_speed_tolerance_mps)
    goal, tol = scenario.waypoints[:, -1], config.sim.goal_tolerance_m
    still = time_to_goal(arrays["t"], arrays["pos"], goal, tol, vel=arrays["vel"],
                            speed_tol=config.sim.goal_speed_tolerance_mps)
    settled = np.where(np.asarray(scenario.rest)[:, -1] | np.asarray(scenario.auto)[:, -1],
                       still,
                       time_to_goal(arrays["t"], arrays["pos"], goal, tol))
    settled = np.where(reached[:, -1], settled, np.nan)
    dep = departure[responsive & np.isfinite(departure)]
    parked_at = np.array([np.nan if x["parked_at_s"] is None else x["parked_at_s"]
                          for x in stalls["per_robot"]])
    settled_all = np.where(np.isfinite(settled), settled, parked_at)[responsive]
    metrics = {
        "name": config.name,
        "backend": config.sim.backend,
        "success": False,  # _success below
        "success_reached": all_reached,
        "collisions": int(sep["collisions"]),
        "min_separation_ratio": _num(sep["min_separation_ratio"]),
        "worst_pair": list(sep["worst_pair"]) if sep["worst_pair"] is not None else None,
        **{k: v for k, v in world.items() if not k.startswith("per_robot")},
        "makespan_s": stalls["makespan_s"],
        "makespan_over_bound": stalls["makespan_over_bound"],
        "max_goal_departure_m": _num(dep.max()) if dep.size else None,
        "settled_makespan_s": _num(settled_all.max())
        if settled_all.size and np.all(np.isfinite(settled_all)) else None,
        "parked": stalls["parked"],
        "stalls": stalls["stalls"],
        "stalled_s": stalls["stalled_s"],
        "sidestep_s": stalls["sidestep_s"],
        "duration_s": duration,
        "replans": int(records.t.shape[0]),
        "robots": M,
        "peak_speed": _num(np.nanmax(kin.max_speed)),
        "peak_speed_over_limit": _num(np.nanmax(kin.max_speed / scenario.v_max)),
        **limits,
        "per_robot": [{**r, **x, "goal_departure_m": _num(d) if np.isfinite(d) else None,
                       "settled_s": _num(s) if np.isfinite(s) else None, **lim}
                      for r, x, d, s, lim in zip(_per_robot(scenario, reached, ttg, kin, world),
                                                 stalls["per_robot"], departure, settled,
                                                 limits_per_robot, strict=True)],
        "solver": _solver(info, solve_ms),
        "faults": _fault_summary(config, records, sep, min_dist, scenario, frozen_robot),
        "fallbacks": {
            **_fallback_counts(info.fallback),
            "accepted": int(np.sum(np.asarray(info.fallback) == ACCEPTED)),
            "goal_occupied": int(np.sum(np.asarray(info.goal_moved))),
        },
    }
    metrics["success"] = _success(metrics)
    return metrics, arrays


def limit_metrics(scenario: Scenario, pieces, kin, reach_time, reached,
                  goal_tolerance_m: float) -> tuple[dict, list[dict]]:
    """What a real vehicle would have to fly: the peaks over each robot's own limits, how
    far it strayed from its goal after reaching it, and how far it left its task's region;
    every value exact, from the executed pieces (:mod:`jaxplan.metrics.excursion`).

    Args:
        scenario: the run's Scenario (its limits, starts, waypoints, world).
        pieces: (seg_robot, seg_t0, seg_t1, seg_coeffs), the executed pieces.
        kin: their :class:`jaxplan.metrics.motion.Kinematics`.
        reach_time: (M, W) s, when each waypoint was reached (the rollout's; inf: not).
        reached: (M, W) bool, each waypoint reached within the run.
        goal_tolerance_m: m, the goal tolerance.
    Returns:
        (the fleet's keys, each robot's keys (M dicts)), None for NaN; the fleet's value
        is the largest over the robots that have one (all robots, a frozen one too):
        peak_speed_ratio, peak_acc_ratio, peak_jerk_ratio: max over time of |x'| / v_max,
        |x''| / a_max, |x'''| / j_max with the robot's own limits;
        goal_excursion_m: the largest |x - g| (g the last waypoint) from the first instant
        within goal_tolerance_m of g (position only; searched from the rollout's reach
        time of the waypoint before it, if any); null where that never happened;
        escape_m: the largest of the centre's distance outside the fleet's box of starts
        and waypoints grown by ESCAPE_MARGIN_M on every side and its distance outside the
        world's workspace (its finite bounds); 0: never outside.
    """
    M = scenario.num_robots
    per = {"peak_speed_ratio": kin.max_speed / scenario.v_max,
           "peak_acc_ratio": kin.max_acc / scenario.a_max,
           "peak_jerk_ratio": kin.max_jerk / scenario.j_max}
    reach_time = np.asarray(reach_time, np.float64)
    t_from = None
    if reach_time.shape[1] > 1:
        t_from = np.where(np.asarray(reached, bool)[:, -2], reach_time[:, -2], np.nan)
    goal = np.asarray(scenario.waypoints[:, -1], np.float64)
    per["goal_excursion_m"], _ = goal_excursion_pieces(*pieces, goal, goal_tolerance_m,
                                                       t_from=t_from, num_robots=M)
    lo, hi = fleet_box(scenario.start, scenario.waypoints, ESCAPE_MARGIN_M)
    escape = escape_pieces(*pieces, lo, hi, num_robots=M)
    world = scenario.world
    if np.any(np.isfinite(world.lo)) or np.any(np.isfinite(world.hi)):
        escape = np.fmax(escape, escape_pieces(*pieces, world.lo, world.hi, num_robots=M))
    per["escape_m"] = escape
    fleet = {k: _num(np.max(v[np.isfinite(v)])) if np.any(np.isfinite(v)) else None
             for k, v in per.items()}
    per_robot = [{k: _num(v[i]) if np.isfinite(v[i]) else None for k, v in per.items()}
                 for i in range(M)]
    return fleet, per_robot


def goal_departure(t, pos, goal, reach_time):
    """(M,) m: how far each robot went from its last waypoint after it first reached it
    (the largest distance over the samples from its reach time on; NaN where it never
    reached it).  "Reached" is the first instant within goal_tolerance_m: a robot may
    give way afterwards, and this says how far.  t: (K,) s; pos: (M, K, N) sampled
    positions (trajectories.npz, SAMPLE_HZ); goal: (M, N); reach_time: (M,) s, NaN: not
    reached."""
    t, pos, goal = np.asarray(t), np.asarray(pos), np.asarray(goal)
    reach_time = np.asarray(reach_time, np.float64)
    d = np.linalg.norm(pos - goal[:, None, :], axis=-1)  # (M, K)
    after = t[None, :] >= reach_time[:, None]  # NaN compares False
    out = np.max(np.where(after, d, -np.inf), axis=1, initial=-np.inf)
    return np.where(np.isfinite(reach_time) & np.isfinite(out), out, np.nan)


def _success(metrics: dict) -> bool:
    """Every responsive robot reached every waypoint or is parked beside its occupied
    last goal (per_robot ``parked``), and no robot touched another, an obstacle or the
    workspace's boundary."""
    frozen = metrics["faults"]["frozen_robot"]
    arrived = all(r["reached"] or r.get("parked", False)
                  for i, r in enumerate(metrics["per_robot"])
                  if i != frozen and r.get("cooperative", True))
    return bool(arrived and metrics["collisions"] == 0
                and metrics["obstacle_collisions"] == 0 and metrics["workspace_violations"] == 0)


def _goals(final, duration: float, responsive):
    """(reached (M, W) within the run, time to the last waypoint (M,) NaN if not reached,
    every responsive robot ((M,) mask) reached every waypoint, makespan s or None)."""
    reach_time = np.asarray(final.reach_time)
    reached = np.asarray(final.reached) & (reach_time <= duration + 1e-9)
    all_reached = bool(np.all(reached[responsive]))
    ttg = np.where(reached[:, -1], reach_time[:, -1], np.nan)
    makespan = float(np.nanmax(ttg[responsive])) if all_reached else None
    return reached, ttg, all_reached, makespan


def _stalls(config: Config, scenario: Scenario, records, reached, ttg, responsive):
    """Stalls, parked robots and the makespan (metrics.json ``stalls``, ``stalled_s``,
    ``sidestep_s``, ``parked``, ``makespan_s``, ``makespan_over_bound`` and per robot
    ``stalls``, ``stalled_s``, ``sidestep_s``, ``parked``, ``parked_at_s``)."""
    info = records.info
    M = scenario.num_robots
    dt = 1.0 / config.planner.replan_hz
    n_stalls, stalled_s, side_s = stall_summary(info.stalled, info.sidestep, dt)
    last_wp = np.asarray(records.wp) == scenario.num_waypoints - 1
    parked, parked_at = parked_robots(
        records.t, records.p, records.v, info.goal_moved, info.goal_point, last_wp,
        config.sim.goal_tolerance_m, config.sim.goal_speed_tolerance_mps)
    done = reached[:, -1]
    parked = parked & ~done
    arrived = bool(np.all((done | parked)[responsive]))
    times = np.where(done, ttg, parked_at)
    makespan = float(np.nanmax(times[responsive])) if arrived and np.any(responsive) else None
    bound = makespan_bound(scenario.start[responsive], scenario.waypoints[responsive],
                              scenario.v_max[responsive], scenario.a_max[responsive]) \
        if np.any(responsive) else math.nan
    ratio = makespan / bound if makespan is not None and bound > 0 else None
    per_robot = [{"stalls": int(n_stalls[i]), "stalled_s": float(stalled_s[i]),
                  "sidestep_s": float(side_s[i]), "parked": bool(parked[i]),
                  "parked_at_s": _num(parked_at[i]) if parked[i] else None}
                 for i in range(M)]
    return {"arrived": arrived, "makespan_s": makespan,
            "makespan_over_bound": None if ratio is None else _num(ratio),
            "parked": int(np.sum(parked[responsive])), "stalls": int(np.sum(n_stalls)),
            "stalled_s": float(np.sum(stalled_s)), "sidestep_s": float(np.sum(side_s)),
            "per_robot": per_robot}


def _per_robot(scenario: Scenario, reached, ttg, kin, world: dict) -> list[dict]:
    """metrics.json ``per_robot``."""
    return [{
        "vehicle": scenario.vehicles[i],
        "reached": bool(np.all(reached[i])),
        "cooperative": bool(scenario.cooperative[i]),
        "waypoints_reached": int(np.sum(reached[i])),
        "time_to_goal_s": _num(ttg[i]),
        "path_length_m": _num(kin.path_length_m[i]),
        "max_speed": _num(kin.max_speed[i]),
        "max_acc": _num(kin.max_acc[i]),
        "max_jerk": _num(kin.max_jerk[i]),
        "v_max": float(scenario.v_max[i]),
        "a_max": float(scenario.a_max[i]),
        "j_max": float(scenario.j_max[i]),
        "min_obstacle_clearance_m": world["per_robot_obstacle_m"][i],
        "min_workspace_clearance_m": world["per_robot_workspace_m"][i],
    } for i in range(len(reached))]


def _solver(info, solve_ms) -> dict:
    """metrics.json ``solver``: replan wall times, convergence, iterations, statuses."""
    status = np.asarray(info.status)
    solver = solver_summary(solve_ms, status == solve.CONVERGED)
    solver.update({
        "timed_replans": int(len(solve_ms)),
        "iterations_median": float(np.median(np.asarray(info.iterations))),
        "status_counts": {name: int(np.sum(status == code))
                          for code, name in solve.STATUS_NAMES.items()},
    })
    return {k: _num(v) if isinstance(v, float) else v for k, v in solver.items()}


def _fallback_counts(fallback) -> dict:
    """Robot replans not accepted, by fallback: kept_previous, braking, best_effort."""
    fallback = np.asarray(fallback)
    return {"kept_previous": int(np.sum(fallback == KEPT_PREVIOUS)),
            "braking": int(np.sum(fallback == BRAKING)),
            "best_effort": int(np.sum(fallback == BEST_EFFORT))}


def _run_arrays(scenario: Scenario, records, pieces, min_dist, duration: float) -> dict:
    """trajectories.npz: samples at SAMPLE_HZ, the fleet, the executed pieces, replans."""
    M = scenario.start.shape[0]
    seg_robot, seg_t0, seg_t1, seg_c = pieces
    t = np.arange(0.0, duration + 1e-9, 1.0 / SAMPLE_HZ)
    pos, vel, acc = sample_pieces(seg_robot, seg_t0, seg_t1, seg_c, t, num_robots=M,
                                     outside="clamp")
    return {
        "t": t, "pos": pos, "vel": vel, "acc": acc,
        "radius": np.asarray(scenario.radius, np.float64),
        "goal": np.asarray(scenario.waypoints[:, -1], np.float64),
        "waypoints": np.asarray(scenario.waypoints, np.float64),
        "start": np.asarray(scenario.start, np.float64),
        "vehicle": np.asarray(scenario.vehicles, dtype=f"U{_width(scenario.vehicles)}"),
        "cooperative": np.asarray(scenario.cooperative, bool),
        "seg_robot": seg_robot, "seg_t0": seg_t0, "seg_t1": seg_t1, "seg_coeffs": seg_c,
        "min_dist": np.where(np.isfinite(min_dist), min_dist, np.nan),
        "replan_t": np.asarray(records.t),
        "status": np.asarray(records.info.status).astype(np.int32),
        "fallback": np.asarray(records.info.fallback).astype(np.int32),
        **world_arrays(scenario.world),
    }


def _fault_summary(config, records, sep, min_dist, scenario, frozen_robot) -> dict:
    """metrics.json ``faults``: what was injected and what it cost."""
    fc = config.faults
    comm = np.asarray(records.comm)
    rho = scenario.radius[:, None] + scenario.radius[None, :]
    hit = np.triu(min_dist < rho, 1)
    responsive_hits = int(np.sum(hit)) if frozen_robot < 0 else int(np.sum(
        hit & ((np.arange(len(rho))[:, None] != frozen_robot)
               | (np.arange(len(rho))[None, :] != frozen_robot))))
    return {
        "enabled": fc.enabled,
        "message_loss": fc.message_loss, "latency_s": fc.latency_s,
        "noise_sigma_m": fc.noise_sigma_m, "frozen_robot": frozen_robot,
        "frozen_mode": fc.frozen_mode if frozen_robot >= 0 else None,
        "messages_delivered": int(comm[:, 0].sum()),
        "messages_lost": int(comm[:, 1].sum()),
        "max_view_age_s": float(comm[:, 2].max()) if len(comm) else 0.0,
        "collisions_involving_responsive": responsive_hits,
        **{f"fallback_{k}": v for k, v in _fallback_counts(records.info.fallback).items()},
        "goal_occupied": int(np.sum(np.asarray(records.info.goal_moved))),
    }


def _width(names) -> int:
    return max(len(v) for v in names)


def _num(x):
    """A float for JSON; None for NaN / inf (strict JSON has neither)."""
    x = float(x)
    return x if math.isfinite(x) else None
