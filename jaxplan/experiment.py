"""From a Config to a finished run: set-up, the jitted rollout, metrics.

``run(config)`` is what ``jaxplan run`` does, without writing files (that is
:mod:`jaxplan.results`).  A single run steps through one compiled replan
period per call (:func:`simulate`), which times every fleet replan individually
(``solver.median_ms / p95_ms / max_ms`` in metrics.json: wall time of the whole jitted
replan + execution period, i.e. predictions, all NLP solves and bookkeeping) and drives
the progress bar.  Batches of runs use the single ``lax.scan`` of
:mod:`jaxplan.rollout`, vmapped.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan import metrics as mt
from jaxplan import solve
from jaxplan import world_metrics as wm
from jaxplan.config import Config, build_scenario
from jaxplan.deadlock import (
    announces_plan_ends,
    mutual_hold,
    mutual_window,
    resolution_enabled,
    sidestep_wait,
    stall_summary,
    stall_window,
)
from jaxplan.deadlock import default_params as deadlock_params
from jaxplan.faults import FaultParams, no_faults
from jaxplan.guide import GuideField, guide_enabled, guide_field
from jaxplan.nlp import Limits, NLPStructure, Weights
from jaxplan.planner import (
    ACCEPTED,
    BEST_EFFORT,
    BRAKING,
    KEPT_PREVIOUS,
    FleetParams,
    PlannerStructure,
)
from jaxplan.rollout import RolloutStructure, Task, initial_state, step
from jaxplan.scenarios import Scenario
from jaxplan.timing import KeptPrograms, arg_key, timed
from jaxplan.world import (
    ALL_KINDS,
    PLANE,
    StaticRows,
    World,
    face_names,
    row_kinds,
    static_rows,
    world_arrays,
)

# lower bound on every plan's horizon: two replan periods, so that a plan ends after the
# next replan.  A shorter one is flown to its end within the period: a ground robot 0.19 m
# from its goal at 2.37 m/s planned T = 0.175 s, braked at 13 m/s^2 (3 a_max) within it,
# and the replans that started from that acceleration flew it 15 m away at 3 v_max
# (planar box 10, seed 12, batched; 0.05 s before)
T_MIN_PERIODS = 2.0
ACCEPT_VIOLATION = 1e-3  # m^2: largest collision-constraint violation accepted at max-iters
SAMPLE_HZ = 100.0  # trajectories.npz sampling rate


@dataclass
class RunResult:
    """Everything a run produced (host arrays).

    metrics: the metrics.json dict.  arrays: the trajectories.npz dict.  records: the
    stacked StepRecord (numpy).  compile_s, run_s: seconds.  scenario: the Scenario.
    """

    config: Config
    scenario: Scenario
    metrics: dict
    arrays: dict
    records: object
    compile_s: float
    run_s: float


def structures(config: Config, *, only_needed: bool = True,
               n_static: int | None = None,
               static_kinds: tuple[int, ...] | None = None) -> RolloutStructure:
    """Static structures of a config (shapes other than M, N, W).

    only_needed: leave out the coast constraints when no robot of the config's own
    scenario ever has a free end (they would be inactive rows; measured: 14% of the
    closed loop's time on antipodal_10).  A sweep, whose grid may hold other scenarios,
    passes False.  n_static: the world's static rows (obstacles and workspace faces);
    default: those of the config's own world (a sweep passes the most of its grid); each
    NLP holds ``max_static_rows`` of them (PlannerStructure.static_slots).
    static_kinds: the kinds of static rows the NLP's derivatives form
    (NLPStructure.static_kinds); default: the config's own world's, with PLANE (its
    workspace faces and the padding rows); a sweep, whose grid may hold other worlds,
    passes jaxplan.world.ALL_KINDS.
    """
    pc = config.planner
    sc = build_scenario(config)
    free = ~(np.asarray(sc.rest) | np.asarray(sc.has_goal_velocity))
    coast = pc.coast_samples if (np.any(free) or not only_needed) else 0
    R = static_rows(sc.world).mask.shape[0] if n_static is None else n_static
    # a world of at most max_static_rows rows: no selection (the same program as 0)
    planner = PlannerStructure(max_neighbors=pc.max_neighbors, solver_pool=pc.solver_pool,
                               max_static_rows=pc.max_static_rows
                               if pc.max_static_rows < R else 0)
    nlp = NLPStructure(
        n_dim=sc.start.shape[1], degree=pc.degree, segments=pc.segments,
        collision=pc.collision, n_collision_samples=_round_up_to_4(pc.n_samples),
        n_coast_samples=coast, n_static=planner.static_slots(R),
        # the kinds matter only to static rows: without, the default (one program)
        static_kinds=ALL_KINDS if planner.static_slots(R) == 0 else
        world_kinds(sc.world) if static_kinds is None else tuple(static_kinds),
    )
    steps = max(1, math.ceil(config.sim.duration_s * pc.replan_hz - 1e-9))
    fc = config.faults
    return RolloutStructure(planner=dataclasses.replace(planner, nlp=nlp),
                            steps=steps, faults=fc.enabled,
                            latency_periods=round(fc.latency_s * pc.replan_hz) if fc.enabled
                            else 0)


def world_kinds(world: World) -> tuple[int, ...]:
    """The kinds of static rows an NLP in ``world`` holds (NLPStructure.static_kinds):
    its obstacles' and PLANE (its workspace faces, and the padding rows)."""
    return row_kinds(np.append(static_rows(world).kind, PLANE))


def _round_up_to_4(n: int) -> int:
    """n rounded up to a multiple of 4, at least 4."""
    return max(4, 4 * math.ceil(n / 4))


def fleet_params(config: Config, scenario: Scenario, weights: Weights | None = None,
                 n_static: int | None = None) -> FleetParams:
    """Traced fleet parameters from a config and its scenario (the world's static rows
    padded to ``n_static``, default exactly its own)."""
    pc = config.planner
    w = weights or Weights(*(jnp.asarray(float(x)) for x in
                             (pc.q_dynm, pc.q_obs, pc.q_lim, pc.k_t, pc.k_p)))
    lim = Limits(jnp.asarray(scenario.v_max), jnp.asarray(scenario.a_max),
                 jnp.asarray(scenario.j_max))
    M = scenario.start.shape[0]
    window = stall_window(pc.stall_window_s, scenario.dim)
    # on the device as strongly typed arrays, as every other leaf: a Python scalar leaf
    # is copied to the device at every call of a compiled step (18 of them: ~0.28 ms of
    # a ~6.5 ms warm 10-robot replan, one core)
    settings = jax.device_put(solve.as_strong_dtypes(solve.SolverSettings(
        max_iters=pc.max_iters, tol_feasibility=pc.tol, tol_complementarity=pc.tol)))
    return FleetParams(
        weights=w, limits=lim, radius=jnp.asarray(scenario.radius) + pc.safety_margin_m,
        robot_mask=jnp.ones((M,), bool), dt=jnp.asarray(1.0 / pc.replan_hz),
        t_min=jnp.asarray(T_MIN_PERIODS / pc.replan_hz),
        prediction_weight=jnp.asarray(pc.k_t / pc.q_dynm),
        accept_violation=jnp.asarray(ACCEPT_VIOLATION), settings=settings,
        static=_static(scenario, n_static),
        deadlock=deadlock_params(
            enabled=resolution_enabled(pc.deadlock, scenario.dim), window=window,
            progress=pc.stall_progress_m, near=pc.stall_near_m, hold=pc.sidestep_hold_s,
            step=pc.sidestep_step_m, angle_deg=pc.sidestep_angle_deg,
            wait=sidestep_wait(pc.deadlock, scenario.dim, pc.sidestep_wait_3d_s),
            announce=announces_plan_ends(pc.deadlock, scenario.dim),
            mutual=pc.sidestep_mutual_at_once,
            window_mutual=mutual_window(pc.deadlock, scenario.dim, window,
                                        pc.stall_window_mutual_s),
            hold_mutual=mutual_hold(pc.deadlock, scenario.dim, pc.sidestep_hold_s,
                                    pc.sidestep_hold_mutual_s)),
    )


def _static(scenario: Scenario, n_static: int | None):
    rows = static_rows(scenario.world, n_static)
    if rows.mask.shape[0] == 0:
        return None
    return StaticRows(*(jnp.asarray(a) for a in rows))


def task_of(config: Config, scenario: Scenario) -> Task:
    """Traced task arrays of a scenario."""
    full = scenario.rest | scenario.has_goal_velocity
    gv = np.where(scenario.has_goal_velocity[..., None], scenario.goal_velocity, 0.0)
    return Task(
        start=jnp.asarray(scenario.start), waypoints=jnp.asarray(scenario.waypoints),
        rest=jnp.asarray(full), goal_velocity=jnp.asarray(gv),
        goal_tolerance=jnp.asarray(config.sim.goal_tolerance_m),
        speed_tolerance=jnp.asarray(config.sim.goal_speed_tolerance_mps),
        faults=fault_params(config, scenario.start.shape[0]),
        guide=_guide(config, scenario),
    )


def _guide(config: Config, scenario: Scenario):
    """The scenario's guide field (jaxplan.guide) where [planner] guide turns it on."""
    if not guide_enabled(config.planner.guide, scenario.world):
        return None
    g = guide_field(scenario.world, scenario.waypoints,
                    np.asarray(scenario.radius) + config.planner.safety_margin_m,
                    scenario.start)
    return GuideField(*(jnp.asarray(a) for a in g))


def fault_params(config: Config, M: int) -> FaultParams:
    """Traced fault settings of a config (all zero when [faults] is off)."""
    fc = config.faults
    if not fc.enabled:
        return no_faults(M)._replace(seed=jnp.asarray(config.seed % 2**32, jnp.uint32))
    frozen = np.zeros(M, bool)
    if fc.frozen_robot >= 0:
        frozen[fc.frozen_robot] = True
    return FaultParams(jnp.asarray(fc.message_loss), jnp.asarray(fc.noise_sigma_m),
                       jnp.asarray(frozen), jnp.asarray(fc.frozen_at_s),
                       jnp.asarray(fc.frozen_mode == "stale"),
                       jnp.asarray(config.seed % 2**32, jnp.uint32))


_STEP_CACHE: dict = {}


def step_runner(structure: RolloutStructure):
    """The jitted replan period (cached per structure: one compilation per shape)."""
    key = dataclasses.replace(structure, steps=0)  # the step does not depend on steps
    if key not in _STEP_CACHE:
        _STEP_CACHE[key] = jax.jit(lambda fp, task, st: step(fp, task, st, key))
    return _STEP_CACHE[key]


# this process's compiled replan periods (backend "ideal"): another run of the same
# structure and shapes in this process (a notebook's, the tests') reuses one
_PROGRAMS = KeptPrograms(8)


def _program_key(structure: RolloutStructure, fp, task, st):
    """What a compiled replan period is kept under: the structure but its steps, and its
    arguments' shapes (:func:`jaxplan.timing.arg_key`)."""
    return dataclasses.replace(structure, steps=0), arg_key(fp, task, st)


def compiled_step(fp: FleetParams, task: Task, st, structure: RolloutStructure):
    """(the compiled replan period of :func:`step_runner`, seconds spent compiling it):
    compiled once per structure and shapes in this process and kept (the last 8); a kept
    one costs 0 s."""
    key = _program_key(structure, fp, task, st)
    compiled = _PROGRAMS.get(key)
    if compiled is not None:
        return compiled, 0.0
    compiled, compile_s = timed(lambda: step_runner(structure).lower(fp, task, st).compile())
    return _PROGRAMS.put(key, compiled), compile_s


def simulate(fp: FleetParams, task: Task, structure: RolloutStructure, progress=None):
    """Run one scenario, one jitted replan period per call, timing every replan.

    Each call is the same compiled computation as one iteration of
    :func:`jaxplan.rollout.rollout`'s scan (batches use that scan); stepping from the
    host costs ~0.1 ms per replan and gives every replan's wall time and a live
    progress bar.

    Returns (final state, records stacked over ``structure.steps``, compile_s (0 where
    this process compiled the same program before: :func:`compiled_step`), run_s,
    replan_ms (steps,)).  ``progress``: optional callable(n_steps_done).
    """
    st = initial_state(task, structure)
    compiled, compile_s = compiled_step(fp, task, st, structure)
    st, records, run_s, ms = _run_periods(lambda st: compiled(fp, task, st), st,
                                          structure.steps, progress)
    return st, records, compile_s, run_s, ms


# this process's compiled MJX periods: another run of the same structure, vehicles,
# rates and shapes in this process (a notebook's loop over weights) reuses one
_MJX_PROGRAMS = KeptPrograms(4)


def _sim_key(sim) -> tuple:
    """A simulated fleet (jaxplan.sim.fleet.SimModel) as a key: its tree (the static
    fields: vehicle names, layout, rates, ...) and a digest of its arrays' shapes, dtypes
    and bytes (~5 kB for a fleet; the starts are not in it)."""
    leaves, tree = jax.tree.flatten(sim)
    h = hashlib.sha256()
    for x in leaves:
        x = np.ascontiguousarray(np.asarray(x))
        h.update(f"{x.shape}{x.dtype.str};".encode())
        h.update(x.tobytes())
    return tree, h.hexdigest()


@dataclass(frozen=True)
class MjxSetup:
    """What a run on the MJX backend simulates: the fleet (jaxplan.sim.fleet.SimModel),
    the replan period (s), the initial planner and simulator states, and the key its
    compiled period is kept under in this process (:data:`_MJX_PROGRAMS`)."""

    sim: object
    period: float
    state: object
    sim_state: object
    key: tuple


def mjx_setup(config: Config, scenario: Scenario, fp: FleetParams, task: Task,
              structure: RolloutStructure) -> MjxSetup:
    """The simulated fleet and initial states of a run on the MJX backend (3-D only)."""
    from jaxplan.sim import closed_loop as cl
    from jaxplan.sim import fleet as sf

    if scenario.start.shape[1] != 3:
        raise ValueError(f"{config.source or config.name}: sim.backend = 'mjx' needs 3-D "
                         "positions")
    sim, _ = sf.init_sim(list(scenario.vehicles), scenario.start,
                         physics_hz=config.sim.physics_hz, control_hz=config.sim.control_hz,
                         world=scenario.world)
    period = 1.0 / config.planner.replan_hz
    st, ss = cl.mjx_initial_state(task, structure, sim)
    # the period closes over the simulated fleet (its model's arrays are constants of
    # the program): kept under the fleet's tree and bytes as well as the arguments' shapes
    key = (dataclasses.replace(structure, steps=0), period, _sim_key(sim),
           arg_key(fp, task, st, ss))
    return MjxSetup(sim, period, st, ss, key)


def simulate_mjx(config: Config, scenario: Scenario, fp: FleetParams, task: Task,
                 structure: RolloutStructure, progress=None, setup: MjxSetup | None = None):
    """Backend "mjx": the planner closed around MJX quadrotors, one jitted period per call.

    ``setup``: :func:`mjx_setup`'s (made here when None).  Returns (final RolloutState,
    StepRecords (numpy, stacked), PeriodRecords (numpy, stacked), compile_s (0 where this
    process compiled the same period before: the same structure but its steps, vehicles,
    rates and shapes), run_s, period_ms (steps,): wall time of each period, planning and
    physics together).
    """
    from jaxplan.sim import closed_loop as cl

    s = setup or mjx_setup(config, scenario, fp, task, structure)
    compiled, compile_s = _MJX_PROGRAMS.get(s.key), 0.0
    if compiled is None:
        fn = jax.jit(lambda fp, task, st, ss: cl.mjx_step(fp, task, st, ss, structure, s.sim,
                                                           s.period))
        compiled, compile_s = timed(lambda: fn.lower(fp, task, s.state, s.sim_state).compile())
        _MJX_PROGRAMS.put(s.key, compiled)
    (st, ss), stacked, run_s, ms = _run_periods(lambda c: compiled(fp, task, *c),
                                                (s.state, s.sim_state), structure.steps,
                                                progress)
    return st, stacked.step, stacked.period, compile_s, run_s, ms


def stack_trees(items):
    """Stack a list of equally shaped pytrees into one pytree of numpy arrays (leading
    axis: the list)."""
    return jax.tree.map(lambda *xs: np.stack([np.asarray(x) for x in xs]), *items)


def _run_periods(call, carry, steps: int, progress):
    """``carry, record = call(carry)`` ``steps`` times, timing every call.

    Returns (final carry, the records stacked (numpy), run_s: seconds of the whole loop,
    ms (steps,): milliseconds of each call).  ``progress``: optional callable(n_done).
    """
    def loop(carry):
        recs = []
        ms = np.empty(steps)
        for k in range(steps):
            (carry, rec), seconds = timed(call, carry)
            ms[k] = 1e3 * seconds
            recs.append(rec)
            if progress:
                progress(k + 1)
        return carry, stack_trees(recs), ms

    (carry, records, ms), run_s = timed(loop, carry)
    return carry, records, run_s, ms


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
    control-rate samples.  Returns (metric overrides, arrays).
    """
    valid = np.asarray(period.valid)  # (P, K)
    t = np.asarray(period.t)[valid]
    take = lambda x: np.swapaxes(np.asarray(x), 1, 2)[valid].transpose(1, 0, 2)  # (M, T, 3)
    pos, vel, acc = take(period.pos), take(period.vel), take(period.acc)
    err = np.swapaxes(np.asarray(period.track_err), 1, 2)[valid].T  # (M, T)
    min_dist = np.min(np.asarray(period.min_dist), axis=0)
    sep = mt.separation_report(min_dist, scenario.radius)
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
        "tracking": {"rms_m": _num(np.sqrt(np.mean(err**2))), "max_m": _num(err.max()),
                     "per_robot_rms_m": [_num(x) for x in np.sqrt(np.mean(err**2, axis=1))]},
        "rotor_saturation": {"ticks": [int(x) for x in sat],
                             "fraction": _num(sat.sum() / max(1, ticks * len(sat)))},
        "nonfinite_vehicles": int(np.any(np.asarray(period.nonfinite), axis=0).sum()),
        "bad_references": int(np.asarray(period.bad_reference).sum()),
    }
    per_robot = [{"max_speed": _num(speed[i].max()), "max_acc": _num(accn[i].max()),
                  "path_length_m": _num(path[i])} for i in range(pos.shape[0])]
    arrays = {"t": t, "pos": pos, "vel": vel, "acc": acc,
              "min_dist": np.where(np.isfinite(min_dist), min_dist, np.nan),
              "track_err": err}
    del duration
    return {"sim": out, "per_robot": per_robot}, arrays


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
    """metrics.json dict and trajectories.npz dict of a finished run."""
    M = scenario.start.shape[0]
    duration = records.t.shape[0] * (1.0 / config.planner.replan_hz)
    pieces = pieces_from_records(records)
    min_dist, _ = mt.pairwise_min_separation(*pieces, num_robots=M)
    sep = mt.separation_report(min_dist, scenario.radius)
    kin = mt.kinematics(*pieces, num_robots=M)
    world = wm.world_report(wm.world_clearance(*pieces, scenario.radius, scenario.world,
                                               num_robots=M))
    frozen_robot = config.faults.frozen_robot if config.faults.enabled else -1
    reached, ttg, all_reached, makespan = _goals(final, duration, M, frozen_robot)
    info = records.info
    stalls = _stalls(config, scenario, records, reached, ttg, frozen_robot)
    arrays = _run_arrays(scenario, records, pieces, min_dist, duration)
    departure = goal_departure(arrays["t"], arrays["pos"], scenario.waypoints[:, -1], ttg)
    # from when each robot stays at its last waypoint to the end: within goal_tolerance_m
    # (and, for a rest waypoint, at most goal_speed_tolerance_mps), as "reached" counts it
    goal, tol = scenario.waypoints[:, -1], config.sim.goal_tolerance_m
    still = mt.time_to_goal(arrays["t"], arrays["pos"], goal, tol, vel=arrays["vel"],
                            speed_tol=config.sim.goal_speed_tolerance_mps)
    settled = np.where(np.asarray(scenario.rest)[:, -1], still,
                       mt.time_to_goal(arrays["t"], arrays["pos"], goal, tol))
    settled = np.where(reached[:, -1], settled, np.nan)
    responsive = np.arange(M) != frozen_robot
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
        "per_robot": [{**r, **x, "goal_departure_m": _num(d) if np.isfinite(d) else None,
                       "settled_s": _num(s) if np.isfinite(s) else None}
                      for r, x, d, s in zip(_per_robot(scenario, reached, ttg, kin, world),
                                            stalls["per_robot"], departure, settled,
                                            strict=True)],
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
                  for i, r in enumerate(metrics["per_robot"]) if i != frozen)
    return bool(arrived and metrics["collisions"] == 0
                and metrics["obstacle_collisions"] == 0 and metrics["workspace_violations"] == 0)


def _goals(final, duration: float, M: int, frozen_robot: int):
    """(reached (M, W) within the run, time to the last waypoint (M,) NaN if not reached,
    every responsive robot reached every waypoint, makespan s or None)."""
    reach_time = np.asarray(final.reach_time)
    reached = np.asarray(final.reached) & (reach_time <= duration + 1e-9)
    responsive = np.arange(M) != frozen_robot
    all_reached = bool(np.all(reached[responsive]))
    ttg = np.where(reached[:, -1], reach_time[:, -1], np.nan)
    makespan = float(np.nanmax(ttg[responsive])) if all_reached else None
    return reached, ttg, all_reached, makespan


def _stalls(config: Config, scenario: Scenario, records, reached, ttg, frozen_robot: int):
    """Stalls, parked robots and the makespan (metrics.json ``stalls``, ``stalled_s``,
    ``sidestep_s``, ``parked``, ``makespan_s``, ``makespan_over_bound`` and per robot
    ``stalls``, ``stalled_s``, ``sidestep_s``, ``parked``, ``parked_at_s``)."""
    info = records.info
    M = scenario.num_robots
    dt = 1.0 / config.planner.replan_hz
    n_stalls, stalled_s, side_s = stall_summary(info.stalled, info.sidestep, dt)
    last_wp = np.asarray(records.wp) == scenario.num_waypoints - 1
    parked, parked_at = mt.parked_robots(
        records.t, records.p, records.v, info.goal_moved, info.goal_point, last_wp,
        config.sim.goal_tolerance_m, config.sim.goal_speed_tolerance_mps)
    done = reached[:, -1]
    parked = parked & ~done
    responsive = np.arange(M) != frozen_robot
    arrived = bool(np.all((done | parked)[responsive]))
    times = np.where(done, ttg, parked_at)
    makespan = float(np.nanmax(times[responsive])) if arrived and np.any(responsive) else None
    bound = mt.makespan_bound(scenario.start[responsive], scenario.waypoints[responsive],
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
    solver = mt.solver_summary(solve_ms, status == solve.CONVERGED)
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
    pos, vel, acc = mt.sample_pieces(seg_robot, seg_t0, seg_t1, seg_c, t, num_robots=M,
                                     outside="clamp")
    return {
        "t": t, "pos": pos, "vel": vel, "acc": acc,
        "radius": np.asarray(scenario.radius, np.float64),
        "goal": np.asarray(scenario.waypoints[:, -1], np.float64),
        "waypoints": np.asarray(scenario.waypoints, np.float64),
        "start": np.asarray(scenario.start, np.float64),
        "vehicle": np.asarray(scenario.vehicles, dtype=f"U{_width(scenario.vehicles)}"),
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


def run(config: Config, *, progress: bool = False) -> RunResult:
    """Run one experiment (backend "ideal" or "mjx"); no files are written.

    Args:
        config: a validated Config (jaxplan.config.load_config / parse_config).
        progress: say on stderr that the planner compiles, then show progress over
            replans from the first one (a tqdm bar on a terminal, a line every 30 s
            otherwise: jaxplan.progress).
    """
    scenario = build_scenario(config)
    structure = structures(config)
    fp = fleet_params(config, scenario)
    task = task_of(config, scenario)
    bar = setup = None
    if progress:  # opened at the first replan, after the compile (its ETA is the run's)
        import sys

        from jaxplan.progress import AfterFirstUpdate

        if config.sim.backend == "mjx":
            setup = mjx_setup(config, scenario, fp, task, structure)
            kept = setup.key in _MJX_PROGRAMS
        else:
            kept = _program_key(structure, fp, task, initial_state(task, structure)) in _PROGRAMS
        print(f"{config.name}: " + ("the planner is compiled already (in this process)" if kept
                                    else "compiling the planner") +
              f" ({scenario.start.shape[0]} robots, {structure.steps} replans, backend "
              f"{config.sim.backend})", file=sys.stderr, flush=True)
        bar = AfterFirstUpdate(structure.steps, config.name, "replan", leave=False)

    def _prog(n):
        if bar is not None:
            bar.set(n)

    if config.sim.backend == "mjx":
        final, records, period, compile_s, run_s, solve_ms = simulate_mjx(
            config, scenario, fp, task, structure, _prog, setup)
    else:
        final, records, compile_s, run_s, solve_ms = simulate(fp, task, structure, _prog)
    if bar is not None:
        bar.close()
    metrics, arrays = compute_metrics(config, scenario, records, final, solve_ms)
    if config.sim.backend == "mjx":
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
    metrics["compile_s"] = compile_s
    metrics["run_s"] = run_s
    return RunResult(config, scenario, metrics, arrays, records, compile_s, run_s)
