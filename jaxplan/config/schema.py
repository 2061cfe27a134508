"""The config's defaults and bounds, and the models of its plain sections ([planner],
[limits], [sim], [faults], [workspace], [[obstacles]]): one frozen pydantic dataclass
per TOML section (unknown keys forbidden; field types from jaxplan/fields.py), each
numeric key's range declared once, on its field (read back by
:func:`jaxplan.fields.range_of`, :func:`weight_bounds`).  The sections whose TOML form
differs from their resolved one have their own modules: robots.py, scenario.py,
sweep.py, tune.py; model.py holds the whole :class:`Config`."""

from __future__ import annotations

import math
import typing
from typing import Annotated, Any, NamedTuple

from pydantic import (
    AfterValidator,
    BeforeValidator,
    ConfigDict,
    Strict,
    model_validator,
)
from pydantic.dataclasses import dataclass

from jaxplan.config.errors import unknown_key
from jaxplan.fields import (
    MAX_COORD,
    MAX_ROBOTS,
    EndState,
    FieldProblem,
    Position,
    PositiveLength,
    auto_or_number,
    integer,
    number,
    one_of,
    range_of,
    show,
    string,
)
from jaxplan.nlp import PLANNER_COLLISION_MODES
from jaxplan.planner import PREDICTIONS
from jaxplan.planner.guide import GUIDE_MODES
from jaxplan.planner.stall import RESOLUTIONS

# ---------------------------------------------------------------------------------------
# Defaults: the one place to tune them.  The weights are placeholders for the solver.
# ---------------------------------------------------------------------------------------
DEFAULT_REPLAN_HZ = 8.0                  # Hz, the paper's rate
DEFAULT_Q_DYNM = 1.0                     # smoothness weight on |x'''|^2
DEFAULT_Q_OBS = 10.0                     # collision weight
DEFAULT_Q_LIM = 2.0                      # soft-limit weight (tuned with k_t: peak speed ~ v_max)
DEFAULT_K_T = 6.0                        # time weight (k_t / q_lim = 3: cruise at ~v_max)
DEFAULT_K_P = 5.0                        # 1/m, collision decay rate exp(-K_p (d - rho))
DEFAULT_COLLISION = "barrier+constraint"  # the literal "paper" term cannot avoid (docs/MATH.md 2)
DEFAULT_DEGREE = 5
DEFAULT_SEGMENTS = 2                     # rest ends need shape freedom (docs/MATH.md 2); paper: 1
DEFAULT_END_STATE = "free"               # the paper's position-only end state
DEFAULT_MAX_ITERS = 50                   # solver iterations per replan (bounded loop)
DEFAULT_TOL = 1e-8                       # solver feasibility (m^2) / complementarity tolerance
DEFAULT_N_SAMPLES = 32                   # collision samples / quadrature nodes per horizon
DEFAULT_SAFETY_MARGIN_M = 0.05           # m added to every radius when planning (not in metrics)
DEFAULT_MAX_NEIGHBORS = 0                # 0: every other robot is in each robot's NLP
DEFAULT_MAX_STATIC_ROWS = 8              # static rows per NLP, the nearest (docs/SOLVER.md)
MAX_STATIC_ROWS = 100_000
DEFAULT_SOLVER_POOL = 0                  # 0: automatic (jaxplan.solve.default_pool)
DEFAULT_COAST_SAMPLES = 8                # constraint samples on a free end's coast after T
MAX_COAST_SAMPLES = 256
# stalls and their resolution (jaxplan/planner/stall.py)
DEFAULT_DEADLOCK = "auto"                # "auto" | "sidestep" | "off" (detection runs either way);
# auto: the sidestep, at once for planar fleets (without it they do not arrive:
# docs/RESULTS.md), after sidestep_wait_3d_s more in 3-D (a robot of a 3-D fleet waiting
# for another to pass stalls a few seconds: sidestepping then made the tests' tiny 3-D
# swap 20% longer, 6.43 s against 5.34 s)
# the way round a wall (jaxplan/planner/guide.py): "auto" (on in a world with obstacles) |
# "on" | "off"
DEFAULT_GUIDE = "auto"
# what each robot predicts the others will do (jaxplan/planner/views.py): the paper's
# closed form; "constant_velocity" and "static" are ablations of it
DEFAULT_PREDICTION = "min_time_jerk"
# the dynamic limits: "soft" (the paper's penalty, q_lim) or "hard" (constraints, and only
# plans within them fly: jaxplan/planner/choice.py)
LIMIT_MODES = ("soft", "hard")
DEFAULT_LIMITS = "soft"
# where each robot's NLP keeps its body: inside the world's workspace alone ("workspace"),
# or also inside the fleet's region, the box of the starts and waypoints grown by
# region_margin_m ("fleet": jaxplan.run_setup.planner_world), which escape_m measures
# against (jaxplan.metrics.report.ESCAPE_MARGIN_M)
REGION_MODES = ("workspace", "fleet")
DEFAULT_REGION = "workspace"
DEFAULT_REGION_MARGIN_M = 1.0
# m: each robot predicts every other this far to that other's right, its radius grown as
# much (jaxplan.planner.views), so that robots meeting head on pass on their own right;
# 0: off (the paper's prediction)
DEFAULT_KEEP_RIGHT_M = 0.0
MAX_KEEP_RIGHT_M = 1.0
# the planner: the paper's ("krishnan"), or the ORCA baseline: RVO2 through pyrvo ("orca",
# jaxplan/baselines/orca.py), RVO2-3D in JAX ("orca3d", jaxplan/baselines/orca3d.py)
PLANNER_METHODS = ("krishnan", "orca", "orca3d")
DEFAULT_METHOD = "krishnan"
DEFAULT_ORCA_NEIGHBOR_DIST_M = 5.0       # m: ORCA's neighbour distance (RVO2's neighborDist)
DEFAULT_ORCA_MAX_NEIGHBORS = 10          # RVO2's maxNeighbors
DEFAULT_ORCA_TIME_HORIZON_S = 2.0        # s: RVO2's timeHorizon (other agents)
DEFAULT_ORCA_TIME_HORIZON_OBST_S = 2.0   # s: RVO2's timeHorizonObst (obstacles)
DEFAULT_ORCA_TIME_STEP_S = 0.05          # s: one ORCA step, one linear executed piece
# s without progress before a robot is stalled; "auto": 1 s for a planar fleet, 2 s in
# 3-D (jaxplan.planner.stall.stall_window)
DEFAULT_STALL_WINDOW_S = "auto"
DEFAULT_STALL_PROGRESS_M = 0.2           # m: less progress than this over the window
DEFAULT_STALL_NEAR_M = 1.0               # m of clearance to another robot that counts as near
DEFAULT_SIDESTEP_HOLD_S = 2.0            # s a stalled robot sidesteps
DEFAULT_SIDESTEP_STEP_M = 1.0            # m from the robot to its sidestep sub-goal
DEFAULT_SIDESTEP_ANGLE_DEG = 60.0        # deg to the right of the direction to its goal
DEFAULT_SIDESTEP_WAIT_3D_S = 4.0         # s more a 3-D robot stays stalled before it sidesteps
# ... unless no robot near it is on its way (a mutual stall, none waiting for another to
# pass): then at once (3-D circles in one plane: makespan / bound 3.99 -> 2.84, 8 robots)
DEFAULT_SIDESTEP_MUTUAL_AT_ONCE = True
# ... and, in 3-D, a mutual stall of a robot not on its way itself is one after this
# window (not within stall_window_s of the goal being set or the last sidestep), and the
# sidestep it starts lasts sidestep_hold_mutual_s (3-D circles in one plane, 8 / 16
# robots: makespan / bound 2.44 / 2.60 with 0.5 s and 2 s, 2.36 / 2.48 with these)
DEFAULT_STALL_WINDOW_MUTUAL_S = 0.25
DEFAULT_SIDESTEP_HOLD_MUTUAL_S = 1.5

DEFAULT_BACKEND = "ideal"
DEFAULT_DURATION_S = 30.0
DEFAULT_PHYSICS_HZ = 500.0
DEFAULT_CONTROL_HZ = 250.0
DEFAULT_GOAL_TOLERANCE_M = 0.1
DEFAULT_GOAL_SPEED_TOLERANCE_MPS = 0.1   # residual speed allowed at a rest goal

COLLISION_MODES = PLANNER_COLLISION_MODES  # the NLP's modes but "none" (jaxplan/nlp/types.py)
BACKENDS = ("ideal", "mjx")
SWEEP_ENGINES = ("local", "ray")  # where `jaxplan sweep` runs its batches (jaxplan/sweep/)
DEFAULT_SWEEP_ENGINE = "local"
FROZEN_MODES = ("silent", "stale")

# ---------------------------------------------------------------------------------------
# Bounds: each numeric key's range is declared once, on its field below (read back by
# jaxplan.fields.range_of, weight_bounds); these are the ones that need a reason.
# ---------------------------------------------------------------------------------------
MAX_WEIGHT = 1e6       # q_dynm, q_obs, q_lim, k_t: the objective's terms stay in float range
MIN_Q_DYNM = 1e-6      # the predictions' time weight is k_t / q_dynm (<= 1e12)
MIN_K_P, MAX_K_P = 1e-3, 1e3  # 1/m: "paper" divides by k_p; exp(-k_p (d - rho)) overflows
MIN_REPLAN_HZ, MAX_REPLAN_HZ = 0.1, 100.0  # Hz: a period of at most 10 s, at least 10 ms
MAX_TOL = 1e-3         # m^2: run_setup.ACCEPT_VIOLATION, what a plan at max_iters may violate
# the NLP's basis (jaxplan/nlp/basis.py) solves a generalized eigenproblem on the Gram
# matrix of the positions: its smallest relative eigenvalue is 4.6e-13 at degree 9 and 16
# segments, 3e-16 at degree 11; degree 12 fails outright at 16 segments, 13 at 2, 14 at 1
MAX_DEGREE = 9
MAX_SEGMENTS = 16      # each segment adds (degree + 1) N unknowns to every robot's NLP
MAX_SAMPLES = 4096
MAX_SWEEP_POINTS = 10000
MAX_SEED = 2**63 - 1
MAX_ITERS = 10_000     # solver iterations per replan: a replan's time stays bounded
MAX_SAFETY_MARGIN_M = 10.0
MAX_DURATION_S = 3600.0  # s: at most 360,000 replans (MAX_REPLAN_HZ) kept in memory
MIN_CONTROL_HZ = 100.0   # Hz: the simulator samples its records at control ticks
MAX_PHYSICS_HZ = 10_000.0
# [limits] v_max, a_max, j_max (m/s, m/s^2, m/s^3): their squares (the soft-limit term)
# and the stopping time v_max / a_max (the coast samples) stay well inside float range
MIN_LIMIT, MAX_LIMIT = 1e-3, 1e4
MAX_LATENCY_S = 10.0

# [tune] (jaxplan/tune/)
TUNABLE_WEIGHTS = ("q_dynm", "q_obs", "q_lim", "k_t", "k_p", "safety_margin_m")
TUNE_SAMPLERS = ("tpe", "cmaes")
TUNE_OBJECTIVES = ("median_makespan_s", "mean_makespan_s", "max_makespan_s")
DEFAULT_TUNE_TRIALS = 50
DEFAULT_TUNE_BATCH = 4                   # trials asked, run and told together
DEFAULT_TUNE_SAMPLER = "tpe"             # why: docs/TUNING.md, "Choosing the sampler"
DEFAULT_TUNE_OBJECTIVE = "median_makespan_s"
DEFAULT_TUNE_MIN_SUCCESS_RATE = 1.0
DEFAULT_TUNE_MIN_SEPARATION_RATIO = 1.1
MAX_TUNE_TRIALS = 100_000


class ConfigError(ValueError):
    """An invalid config: one line ``<file>: <key>: <problem>``."""


SECTION_CONFIG = ConfigDict(extra="forbid")  # every section model: unknown keys are errors

# ---------------------------------------------------------------------------------------
# Section models
# ---------------------------------------------------------------------------------------


@dataclass(frozen=True, config=SECTION_CONFIG)
class PlannerConfig:
    """[planner]: rates, NLP weights, collision treatment, trajectory shape, solver.
    Each numeric key's range is its field's (the bounds above say why).

    replan_hz (Hz); q_dynm, q_obs, q_lim, k_t objective weights; k_p (1/m);
    collision in COLLISION_MODES; degree and segments of the polynomial per axis;
    end_state "free" | "rest" | "auto" (default for robots; "auto": free far from the
    goal, rest near it, jaxplan.rollout.current_goals); max_iters (the solver's iteration
    cap per replan); tol: the solver's feasibility tolerance (m^2, on d^2 - rho^2) and
    complementarity tolerance (SolverSettings.tol_feasibility and tol_complementarity);
    n_samples: collision samples per horizon, a multiple of 4 (4-point Gauss-Legendre
    panels: jaxplan.nlp.NLPStructure.n_collision_samples, used as given);
    safety_margin_m (m): added to every robot's radius in the planner's collision
    terms only, so that rho_ij is planned with r_i + r_j + 2 margin while metrics still
    count a collision below r_i + r_j (covers sampling between collision samples and
    the others' replanning).  max_neighbors (>= 0): 0 puts every other robot in each
    robot's NLP; K >= 1 only the K that come nearest to its own prediction (the NLP's
    cost then stays flat as the fleet grows; jaxplan.planner.nearest_neighbors).
    max_static_rows (>= 0): each robot's NLP holds only the K static rows (obstacles and
    finite workspace faces) nearest to where it is and is headed at each replan
    (jaxplan.planner.nearest_static_rows); 0, or a world of at most K rows: every row.
    coast_samples (>= 0): a free-end plan must also keep clear of the others on its coast
    after T (p(T) + v(T) t, for t up to the time a stop from v_max takes) at this many
    sample times (hard constraints; only in the "constraint" modes; 0 = off, the paper's
    NLP: a free-end plan may then arrive at speed with a robot just beyond its goal).
    solver_pool (>= 0): how many robots' NLPs the solver steps at once in a replan
    (jaxplan.solve.solve_lanes); 0 = automatic (jaxplan.solve.default_pool): 2 on a
    CPU (all M for at most 3 robots; for more than 32 robots 12 with at most 16 others
    per NLP, else 4), all M elsewhere.
    Speed only: every NLP takes the same iterations whatever the pool (results equal to
    rounding, which a closed loop can amplify into slightly different runs).
    deadlock "auto" | "sidestep" | "off" and stall_window_s, stall_progress_m, stall_near_m,
    sidestep_hold_s, sidestep_step_m, sidestep_angle_deg, sidestep_wait_3d_s,
    sidestep_mutual_at_once, stall_window_mutual_s, sidestep_hold_mutual_s: stall detection
    (always on) and the sidestep that resolves a stall (jaxplan/planner/stall.py); auto:
    sidestep, in 3-D only after sidestep_wait_3d_s more of the stall, unless
    (sidestep_mutual_at_once) no robot near is on its way: a mutual stall, detected after
    stall_window_mutual_s, whose sidestep lasts sidestep_hold_mutual_s.  stall_window_s
    "auto": 1 s for a planar fleet, 2 s in 3-D (jaxplan.planner.stall.stall_window).
    guide "auto" | "on" | "off": a robot whose straight line to its goal passes through
    an obstacle plans to a point of the shortest way round instead (jaxplan/planner/guide.py);
    auto: on in a world with obstacles.
    prediction "min_time_jerk" | "constant_velocity" | "static": what each robot predicts
    the others will do (jaxplan/planner/views.py): the paper's closed form, or ablations.
    limits "soft" | "hard": the paper's soft limits (the q_lim penalty alone), or hard
    ones: the NLP bounds the Bernstein control points of v, a and j (so the curves at
    every instant; jaxplan/nlp/basis.py), and a robot flies only a
    plan whose speed, acceleration and jerk stay within its vehicle's limits at every
    instant (a Bernstein bound), else its braking plan kept within them
    (jaxplan/planner/choice.py).
    region "workspace" | "fleet": each robot's NLP keeps its body inside the world's
    workspace, or also inside the fleet's region: the box spanned by every robot's start
    and waypoints grown by region_margin_m (m) on every side (its faces are static rows
    of the planner's world only: jaxplan.run_setup.planner_world; the metrics' world is
    the workspace).
    keep_right_m (m, >= 0): each robot predicts every other shifted this far to that
    other's right of its way to its goal (horizontal in 3-D), its radius grown as much,
    so that two robots meeting head on each pass on their own right (0: off).
    method "krishnan" | "orca" | "orca3d": the paper's planner, or the ORCA baseline:
    "orca" through RVO2 (pyrvo; jaxplan/baselines/orca.py; planar fleets, obstacles as
    polygons), "orca3d" RVO2-3D's algorithm in JAX (jaxplan/baselines/orca3d.py; planar
    or 3-D fleets, no obstacles, backend "ideal"); both with orca_neighbor_dist_m,
    orca_max_neighbors, orca_time_horizon_s, orca_time_horizon_obst_s ("orca" only) and
    orca_time_step_s (RVO2's neighborDist, maxNeighbors, timeHorizon, timeHorizonObst and
    timeStep).
    """

    replan_hz: number(ge=MIN_REPLAN_HZ, le=MAX_REPLAN_HZ) = DEFAULT_REPLAN_HZ
    q_dynm: number(ge=MIN_Q_DYNM, le=MAX_WEIGHT) = DEFAULT_Q_DYNM
    q_obs: number(ge=0.0, le=MAX_WEIGHT) = DEFAULT_Q_OBS
    q_lim: number(ge=0.0, le=MAX_WEIGHT) = DEFAULT_Q_LIM
    k_t: number(ge=0.0, le=MAX_WEIGHT) = DEFAULT_K_T
    k_p: number(ge=MIN_K_P, le=MAX_K_P) = DEFAULT_K_P
    collision: string(one_of(COLLISION_MODES)) = DEFAULT_COLLISION
    degree: integer(ge=5, le=MAX_DEGREE) = DEFAULT_DEGREE
    segments: integer(ge=1, le=MAX_SEGMENTS) = DEFAULT_SEGMENTS
    end_state: EndState = DEFAULT_END_STATE
    max_iters: integer(ge=1, le=MAX_ITERS) = DEFAULT_MAX_ITERS
    tol: number(gt=0.0, le=MAX_TOL) = DEFAULT_TOL
    n_samples: integer(ge=4, le=MAX_SAMPLES, multiple_of=4) = DEFAULT_N_SAMPLES
    safety_margin_m: number(ge=0.0, le=MAX_SAFETY_MARGIN_M) = DEFAULT_SAFETY_MARGIN_M
    max_neighbors: integer(ge=0, le=MAX_ROBOTS) = DEFAULT_MAX_NEIGHBORS
    max_static_rows: integer(ge=0, le=MAX_STATIC_ROWS) = DEFAULT_MAX_STATIC_ROWS
    coast_samples: integer(ge=0, le=MAX_COAST_SAMPLES) = DEFAULT_COAST_SAMPLES
    solver_pool: integer(ge=0, le=MAX_ROBOTS) = DEFAULT_SOLVER_POOL
    deadlock: string(one_of(RESOLUTIONS)) = DEFAULT_DEADLOCK
    stall_window_s: auto_or_number(gt=0.0, le=1e4) = DEFAULT_STALL_WINDOW_S
    stall_progress_m: number(gt=0.0, le=1e3) = DEFAULT_STALL_PROGRESS_M
    stall_near_m: number(ge=0.0, le=1e3) = DEFAULT_STALL_NEAR_M
    sidestep_hold_s: number(gt=0.0, le=1e4) = DEFAULT_SIDESTEP_HOLD_S
    sidestep_step_m: number(gt=0.0, le=1e3) = DEFAULT_SIDESTEP_STEP_M
    sidestep_angle_deg: number(ge=0.0, le=90.0) = DEFAULT_SIDESTEP_ANGLE_DEG
    sidestep_wait_3d_s: number(ge=0.0, le=1e4) = DEFAULT_SIDESTEP_WAIT_3D_S
    sidestep_mutual_at_once: Annotated[bool, Strict()] = DEFAULT_SIDESTEP_MUTUAL_AT_ONCE
    stall_window_mutual_s: number(gt=0.0, le=1e4) = DEFAULT_STALL_WINDOW_MUTUAL_S
    sidestep_hold_mutual_s: number(gt=0.0, le=1e4) = DEFAULT_SIDESTEP_HOLD_MUTUAL_S
    guide: string(one_of(GUIDE_MODES)) = DEFAULT_GUIDE
    prediction: string(one_of(PREDICTIONS)) = DEFAULT_PREDICTION
    limits: string(one_of(LIMIT_MODES)) = DEFAULT_LIMITS
    region: string(one_of(REGION_MODES)) = DEFAULT_REGION
    region_margin_m: number(ge=0.0, le=MAX_COORD) = DEFAULT_REGION_MARGIN_M
    keep_right_m: number(ge=0.0, le=MAX_KEEP_RIGHT_M) = DEFAULT_KEEP_RIGHT_M
    method: string(one_of(PLANNER_METHODS)) = DEFAULT_METHOD
    orca_neighbor_dist_m: number(gt=0.0, le=MAX_COORD) = DEFAULT_ORCA_NEIGHBOR_DIST_M
    orca_max_neighbors: integer(ge=1, le=MAX_ROBOTS) = DEFAULT_ORCA_MAX_NEIGHBORS
    orca_time_horizon_s: number(ge=0.01, le=1e3) = DEFAULT_ORCA_TIME_HORIZON_S
    orca_time_horizon_obst_s: number(ge=0.01, le=1e3) = DEFAULT_ORCA_TIME_HORIZON_OBST_S
    orca_time_step_s: number(ge=0.01, le=1.0) = DEFAULT_ORCA_TIME_STEP_S


@dataclass(frozen=True, config=SECTION_CONFIG)
class LimitsConfig:
    """[limits]: m/s, m/s^2, m/s^3 overrides for every robot; None (not given) = the
    per-vehicle default.  TOML has no null: a given value must be a number in
    [MIN_LIMIT, MAX_LIMIT]."""

    v_max: number(ge=MIN_LIMIT, le=MAX_LIMIT) = None
    a_max: number(ge=MIN_LIMIT, le=MAX_LIMIT) = None
    j_max: number(ge=MIN_LIMIT, le=MAX_LIMIT) = None


@dataclass(frozen=True, config=SECTION_CONFIG)
class SimConfig:
    """[sim]: backend "ideal" | "mjx"; duration_s (s); physics_hz, control_hz (Hz,
    physics_hz / control_hz a whole number; the simulator's controller runs at >= 100 Hz:
    jaxplan.sim.fleet.init_sim); goal_tolerance_m (m); goal_speed_tolerance_mps (m/s,
    residual speed allowed at a rest goal)."""

    backend: string(one_of(BACKENDS)) = DEFAULT_BACKEND
    duration_s: number(gt=0.0, le=MAX_DURATION_S) = DEFAULT_DURATION_S
    physics_hz: number(ge=MIN_CONTROL_HZ, le=MAX_PHYSICS_HZ) = DEFAULT_PHYSICS_HZ
    control_hz: number(ge=MIN_CONTROL_HZ, le=MAX_PHYSICS_HZ) = DEFAULT_CONTROL_HZ
    goal_tolerance_m: number(gt=0.0, le=MAX_COORD) = DEFAULT_GOAL_TOLERANCE_M
    goal_speed_tolerance_mps: number(gt=0.0, le=MAX_COORD) = DEFAULT_GOAL_SPEED_TOLERANCE_MPS

    @model_validator(mode="after")
    def _whole_steps_per_control(self) -> SimConfig:
        ratio = self.physics_hz / self.control_hz
        if ratio < 1.0 - 1e-9 or abs(ratio - round(ratio)) > 1e-9 * ratio:
            raise FieldProblem(f"physics_hz / control_hz must be a whole number >= 1 (the "
                               f"controller runs every k-th physics step), got "
                               f"{self.physics_hz:g} / {self.control_hz:g}", key="control_hz")
        return self


@dataclass(frozen=True, config=SECTION_CONFIG)
class FaultsConfig:
    """[faults] (jaxplan/faults.py): all off by default; ``enabled`` switches the faulty
    channel on (a different compiled program)."""

    enabled: Annotated[bool, Strict()] = False
    message_loss: number(ge=0.0, lt=1.0) = 0.0  # a probability per (observer, sender, period)
    latency_s: number(ge=0.0, le=MAX_LATENCY_S) = 0.0  # s, rounded to whole replan periods
    noise_sigma_m: number(ge=0.0, le=MAX_COORD) = 0.0  # m per axis on every received position
    # index of the robot that stops responding; -1: none
    frozen_robot: integer(ge=-1, le=MAX_ROBOTS - 1) = -1
    frozen_at_s: number(ge=0.0, le=MAX_DURATION_S) = 0.0  # s
    frozen_mode: string(one_of(FROZEN_MODES)) = "silent"  # "silent" | "stale" (keeps sending)


def _bound_vector(v: Any, info) -> tuple:
    """A workspace bound: N numbers, each +-inf (TOML's inf) or within +-MAX_COORD (a
    finite one is a face of the world: a static row), never nan."""
    if not isinstance(v, (list, tuple)):
        raise FieldProblem(f"expected an array of 2 or 3 numbers (inf for unbounded), got "
                           f"{show(v)}")
    dim = (info.context or {}).get("dim")
    if dim is not None and len(v) != dim:
        raise FieldProblem(f"expected {dim} coordinates (the config is {dim}-D), got {len(v)}")
    for k, x in enumerate(v):
        if isinstance(x, bool) or not isinstance(x, (int, float)) or math.isnan(x):
            raise FieldProblem(f"expected a number or +-inf, got {show(x)}", key=f"[{k}]")
        if not math.isinf(x) and abs(x) > MAX_COORD:
            raise FieldProblem(f"must be within +-{MAX_COORD:g} (or +-inf: unbounded), got "
                               f"{show(x)}", key=f"[{k}]")
    return tuple(float(x) for x in v)


Bound = Annotated[tuple[float, ...], BeforeValidator(_bound_vector)]


@dataclass(frozen=True, config=SECTION_CONFIG)
class WorkspaceConfig:
    """[workspace]: every robot's whole body stays in min <= p <= max (m, per axis;
    -inf / inf: unbounded).  None (not given): the default, in 3-D min = [-inf, -inf,
    0] (the ground) and max = [inf, inf, inf]; in 2-D unbounded; a generator's world
    (e.g. low_ceiling's ceiling) where the scenario has one."""

    min: Bound = None
    max: Bound = None

    @model_validator(mode="after")
    def _ordered(self) -> WorkspaceConfig:
        if self.min is not None and self.max is not None:
            if len(self.min) != len(self.max):
                raise FieldProblem(f"max has {len(self.max)} coordinates, min "
                                   f"{len(self.min)}", key="max")
            for d, (a, b) in enumerate(zip(self.min, self.max, strict=True)):
                if not a < b:
                    raise FieldProblem(f"max[{d}] = {b:g} must be above min[{d}] = {a:g}",
                                       key="max")
        return self


OBSTACLE_KINDS = ("sphere", "box", "cylinder")
OBSTACLE_KEYS = ("kind", "center", "radius", "half_extents", "half_height", "axis",
                 "velocity", "path", "known_path")
MAX_PATH_POINTS = 64  # timed points of a moving obstacle's path
PathTime = number(ge=-MAX_COORD, le=MAX_COORD)  # s


@dataclass(frozen=True, config=SECTION_CONFIG)
class PathPoint:
    """One timed point of a moving obstacle's ``path``: t (s), p (m, N coordinates)."""

    t: PathTime
    p: Position


def _path_list(v: Any) -> Any:
    if not isinstance(v, (list, tuple)) or not v:
        raise FieldProblem(f"expected a non-empty array of tables {{t = ..., p = [...]}}, got "
                           f"{show(v)}")
    if len(v) > MAX_PATH_POINTS:
        raise FieldProblem(f"at most {MAX_PATH_POINTS} points, got {len(v)}")
    for i, q in enumerate(v):
        if not isinstance(q, dict):
            raise FieldProblem(f"expected a table {{t = ..., p = [...]}}, got {show(q)}",
                               key=f"[{i}]")
        for k in q:
            if k not in ("t", "p"):
                shown, problem = unknown_key(str(k), ("t", "p"))
                raise FieldProblem(problem, key=f"[{i}].{shown}")
    return v


Path = Annotated[tuple[PathPoint, ...], BeforeValidator(_path_list)]


@dataclass(frozen=True, config=SECTION_CONFIG)
class ObstacleConfig:
    """One [[obstacles]] entry: an axis-aligned obstacle (m), static or moving.  kind =
    "sphere" (center, radius), "box" (center, half_extents) or "cylinder" (vertical
    axis: center, radius, half_height; ``axis``, if given, must be vertical; in 2-D a
    disc: center, radius).  A sphere or a cylinder may move: ``velocity`` (m/s, from
    its center at t = 0 on for ever) or ``path`` (timed points {t, p} instead of a
    center: at rest at its first point before its first time, piecewise linear between
    them, at rest at its last point after the last; the times strictly increase), and
    ``known_path`` (default false: the robots know only its position and velocity at
    each replan; true: its whole future path) (jaxplan/world.py, "Motion")."""

    kind: string(one_of(OBSTACLE_KINDS))
    center: Position = None
    radius: PositiveLength = None
    half_extents: Position = None
    half_height: PositiveLength = None
    axis: Position = None
    velocity: Position = None
    path: Path = None
    known_path: Annotated[bool, Strict()] = None

    @model_validator(mode="after")
    def _keys_of_kind(self) -> ObstacleConfig:
        if self.velocity is not None and self.path is not None:
            raise FieldProblem("give either velocity (a constant velocity) or path (timed "
                               "points), not both", key="path")
        if self.path is not None and self.center is not None:
            raise FieldProblem("a moving obstacle with a path takes its positions from the "
                               "path; give no center", key="center")
        if self.path is None and self.center is None:
            raise FieldProblem("missing; give the obstacle's center (or, for a moving one, "
                               "a path)", key="center")
        N = len(self.center if self.center is not None else self.path[0].p)
        need = {"sphere": ("radius",), "box": ("half_extents",),
                "cylinder": ("radius", "half_height") if N == 3 else ("radius",)}
        for key in need[self.kind]:
            if getattr(self, key) is None:
                raise FieldProblem(f"missing; a {self.kind} needs {' and '.join(need[self.kind])}",
                                   key=key)
        for key in ("radius", "half_extents", "half_height"):
            if key not in need[self.kind] and getattr(self, key) is not None:
                raise FieldProblem(f"a {self.kind} takes no {key} (it takes "
                                   f"{', '.join(('center',) + need[self.kind])})", key=key)
        if self.half_extents is not None and any(h <= 0 for h in self.half_extents):
            raise FieldProblem(f"must be positive, got {show(list(self.half_extents))}",
                               key="half_extents")
        self._check_axis(N)
        self._check_motion()
        if self.known_path is None and (self.velocity is not None or self.path is not None):
            object.__setattr__(self, "known_path", False)  # the default, written out
        return self

    def _check_axis(self, N: int) -> None:
        if self.axis is None:
            return
        if self.kind != "cylinder" or N != 3:
            what = "disc" if self.kind == "cylinder" else self.kind
            raise FieldProblem(f"a {what} takes no axis (only a 3-D cylinder has one, "
                               "vertical)", key="axis")
        if self.axis[0] != 0.0 or self.axis[1] != 0.0 or self.axis[2] == 0.0:
            raise FieldProblem(f"a cylinder must be vertical: its axis must be [0, 0, 1], "
                               f"got {show(list(self.axis))}", key="axis")

    def _check_motion(self) -> None:
        for key in ("velocity", "path"):
            if getattr(self, key) is not None and self.kind == "box":
                raise FieldProblem(f"a box cannot move (only spheres and cylinders move); "
                                   f"remove {key}", key=key)
        if self.path is None:
            return
        for i in range(1, len(self.path)):
            a, b = self.path[i - 1], self.path[i]
            if not b.t > a.t:
                raise FieldProblem(f"goes back in time: {b.t:g} s is not after "
                                   f"path[{i - 1}].t = {a.t:g} s (the times must strictly "
                                   "increase)", key=f"path[{i}].t")
            step = math.dist(a.p, b.p) / (b.t - a.t) if b.t - a.t > 0 else math.inf
            if not math.isfinite(step):
                raise FieldProblem(f"the speed from path[{i - 1}] is not finite "
                                   f"({step:g} m/s)", key=f"path[{i}].t")

    def as_dict(self) -> dict[str, Any]:
        d = {k: getattr(self, k) for k in OBSTACLE_KEYS if getattr(self, k) is not None}
        if self.path is not None:
            d["path"] = [{"t": q.t, "p": list(q.p)} for q in self.path]
        return d


def _plain_name(name: str) -> str:
    if not name.strip() or any(ch in name for ch in "/\\\n\r\t\0"):
        raise FieldProblem(f"must be a non-empty name without slashes or control "
                           f"characters, got {show(name)}")
    return name


Name = string(AfterValidator(_plain_name))
Seed = integer(ge=0, le=MAX_SEED)
FAULT_KEYS = tuple(FaultsConfig.__dataclass_fields__)


def field_type(model: type, name: str) -> Any:
    """The declared type of a section model's field (bounds included: range_of)."""
    return typing.get_type_hints(model, include_extras=True)[name]


class Bounds(NamedTuple):
    """A closed range [low, high] of a [planner] weight."""

    low: float
    high: float


def weight_bounds(name: str) -> Bounds:
    """The closed range [low, high] that [planner] ``name`` (one of TUNABLE_WEIGHTS)
    accepts, as its field declares it: a [tune] range must lie within it."""
    if name not in TUNABLE_WEIGHTS:
        raise ValueError(f"not a tunable weight: {name!r} (tunable: "
                         f"{', '.join(TUNABLE_WEIGHTS)})")
    r = range_of(field_type(PlannerConfig, name))
    return Bounds(float(r.ge), float(r.le))
