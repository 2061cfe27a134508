"""TOML configs -> frozen, validated pydantic dataclasses, every default resolved
(docs/DESIGN.md, "Config (TOML)").

    name = "six_neos"                 # default: the file's stem ("config" for strings)
    description = ""                  # free text
    seed = 0                          # 0 <= seed < 2**63; seeds every random choice
    [planner]  replan_hz, q_dynm, q_obs, q_lim, k_t, k_p, collision, degree, segments,
               end_state, max_iters, tol, n_samples, safety_margin_m, max_neighbors,
               max_static_rows, coast_samples, solver_pool
    [limits]   v_max, a_max, j_max    (optional overrides of the per-vehicle defaults)
    [sim]      backend, duration_s, physics_hz, control_hz, goal_tolerance_m,
               goal_speed_tolerance_mps
    [[robots]] vehicle, start, goal | waypoints, goal_velocity, end_state
    [scenario] kind = "paper:<name>" | "antipodal_sphere" | "random_box" | "grid_swap"
               | "stacked" | "pillars" | "wall_gap" | "low_ceiling" | "random_obstacles"
               | "crossing_traffic",
               and the generator's keys (its parameter model in
               jaxplan/scenarios/generators.py or worlds.py, e.g. RandomBoxParams)
    [sweep]    q_obs, q_lim (lists or {log_min, log_max, num}, base-10 exponents),
               seeds (list or {start, num}), scenarios (registry names),
               engine = "local" | "ray" (where the batches run)
    [faults]   enabled, message_loss, latency_s, noise_sigma_m, frozen_robot, frozen_at_s,
               frozen_mode (jaxplan/faults.py; off by default)
    [workspace] min, max              (per axis, inf = unbounded; 3-D default: z >= 0)
    [[obstacles]] kind = "sphere" | "box" | "cylinder", center, radius, half_extents,
               half_height, axis; moving: velocity | path = [{t, p}, ...], known_path
                                      (jaxplan/world.py)
    [tune]     weights (a table: name = {low, high, log}), scenarios, seeds, holdout_seeds,
               objective, min_success_rate, min_separation_ratio, trials, batch, sampler,
               enqueue_defaults (read by `jaxplan tune`, jaxplan/tune/)

Robots: ``goal = [x, y, z]`` (one goal) or ``waypoints = [[x, y, z], ...]`` (several, in
order; the fleet moves on when every robot reached waypoint w).  ``goal_velocity`` is
one vector (the end velocity at the final waypoint) or a list with one entry per
waypoint, ``[]`` meaning none there.  ``end_state`` is "free" | "rest" | "auto" (all
waypoints) or a list with one entry per waypoint; default ``planner.end_state``.  Robot indices in
messages count from 0 (``robots[0]`` is the first ``[[robots]]``).  Positions have 2
(planar robots) or 3 coordinates; one config uses one N throughout.

``[scenario]`` builds robots from a generator or one of the paper's four
(``kind = "paper:six_neos"``, ``"paper:eight_fireflys_stacked"``,
``"paper:eight_mixed_transitions"``, ``"paper:ten_mixed_rest"``; these take no other
key).  ``[[robots]]`` entries, if any, are appended after the generated robots.  The
top-level ``seed`` seeds the generator.

Each section is a pydantic dataclass validated from its TOML table (unknown keys
forbidden, frozen, hashable; the field types are in jaxplan/fields.py), every default
and every numeric key's range declared once, on its field (:func:`weight_bounds`: a
[planner] weight's, which a [tune] range must lie within).  Every error is a
:class:`ConfigError` whose message is one line, ``<file>: <key>: <problem>``, raised
before any computation: pydantic's validation errors are translated into that form in
errors.py.

The package: schema.py (defaults, bounds, the plain sections' models), robots.py,
scenario.py, sweep.py, tune.py (the models of the sections whose TOML form differs from
their resolved one), model.py (Config), errors.py (one-line errors), parse.py
(documents -> Config), resolve.py (Config -> config.toml, Scenario).
"""

from jaxplan.config.model import TOP_KEYS, Config
from jaxplan.config.parse import load_config, parse_config
from jaxplan.config.resolve import build_scenario, config_to_dict, config_to_toml
from jaxplan.config.robots import ROBOT_KEYS, RobotConfig
from jaxplan.config.scenario import GENERATOR_KEYS, ScenarioConfig
from jaxplan.config.schema import (
    BACKENDS,
    COLLISION_MODES,
    DEFAULT_BACKEND,
    DEFAULT_COAST_SAMPLES,
    DEFAULT_COLLISION,
    DEFAULT_CONTROL_HZ,
    DEFAULT_DEGREE,
    DEFAULT_DURATION_S,
    DEFAULT_END_STATE,
    DEFAULT_GOAL_SPEED_TOLERANCE_MPS,
    DEFAULT_GOAL_TOLERANCE_M,
    DEFAULT_K_P,
    DEFAULT_K_T,
    DEFAULT_MAX_ITERS,
    DEFAULT_MAX_NEIGHBORS,
    DEFAULT_MAX_STATIC_ROWS,
    DEFAULT_N_SAMPLES,
    DEFAULT_PHYSICS_HZ,
    DEFAULT_Q_DYNM,
    DEFAULT_Q_LIM,
    DEFAULT_Q_OBS,
    DEFAULT_REPLAN_HZ,
    DEFAULT_SAFETY_MARGIN_M,
    DEFAULT_SEGMENTS,
    DEFAULT_SOLVER_POOL,
    DEFAULT_SWEEP_ENGINE,
    DEFAULT_TOL,
    FAULT_KEYS,
    MAX_COAST_SAMPLES,
    MAX_DEGREE,
    MAX_ITERS,
    MAX_SAMPLES,
    MAX_SEED,
    MAX_SEGMENTS,
    MAX_SWEEP_POINTS,
    SWEEP_ENGINES,
    TUNABLE_WEIGHTS,
    TUNE_OBJECTIVES,
    TUNE_SAMPLERS,
    Bounds,
    ConfigError,
    FaultsConfig,
    LimitsConfig,
    PlannerConfig,
    SimConfig,
    weight_bounds,
)
from jaxplan.config.sweep import SweepConfig
from jaxplan.config.tune import TUNE_KEYS, TuneConfig, WeightRange, tune_scenario_path

__all__ = [
    "BACKENDS",
    "Bounds",
    "COLLISION_MODES",
    "Config",
    "ConfigError",
    "DEFAULT_BACKEND",
    "DEFAULT_COAST_SAMPLES",
    "DEFAULT_COLLISION",
    "DEFAULT_CONTROL_HZ",
    "DEFAULT_DEGREE",
    "DEFAULT_DURATION_S",
    "DEFAULT_END_STATE",
    "DEFAULT_GOAL_SPEED_TOLERANCE_MPS",
    "DEFAULT_GOAL_TOLERANCE_M",
    "DEFAULT_K_P",
    "DEFAULT_K_T",
    "DEFAULT_MAX_ITERS",
    "DEFAULT_MAX_NEIGHBORS",
    "DEFAULT_MAX_STATIC_ROWS",
    "DEFAULT_N_SAMPLES",
    "DEFAULT_PHYSICS_HZ",
    "DEFAULT_Q_DYNM",
    "DEFAULT_Q_LIM",
    "DEFAULT_Q_OBS",
    "DEFAULT_REPLAN_HZ",
    "DEFAULT_SAFETY_MARGIN_M",
    "DEFAULT_SEGMENTS",
    "DEFAULT_SOLVER_POOL",
    "DEFAULT_SWEEP_ENGINE",
    "DEFAULT_TOL",
    "FAULT_KEYS",
    "FaultsConfig",
    "GENERATOR_KEYS",
    "LimitsConfig",
    "MAX_COAST_SAMPLES",
    "MAX_DEGREE",
    "MAX_ITERS",
    "MAX_SAMPLES",
    "MAX_SEED",
    "MAX_SEGMENTS",
    "MAX_SWEEP_POINTS",
    "PlannerConfig",
    "ROBOT_KEYS",
    "RobotConfig",
    "ScenarioConfig",
    "SimConfig",
    "SweepConfig",
    "SWEEP_ENGINES",
    "TOP_KEYS",
    "TUNABLE_WEIGHTS",
    "TUNE_KEYS",
    "TUNE_OBJECTIVES",
    "TUNE_SAMPLERS",
    "TuneConfig",
    "WeightRange",
    "build_scenario",
    "config_to_dict",
    "config_to_toml",
    "load_config",
    "parse_config",
    "tune_scenario_path",
    "weight_bounds",
]
