"""TOML configs -> frozen, validated pydantic dataclasses, every default resolved
(docs/DESIGN.md, "Config (TOML)").

    name = "six_neos"                 # default: the file's stem ("config" for strings)
    description = ""                  # free text
    seed = 0                          # 0 <= seed < 2**63; seeds every random choice
    [planner]  replan_hz, q_dynm, q_obs, q_lim, k_t, k_p, collision, degree, segments,
               end_state, max_iters, tol, n_samples, safety_margin_m, max_neighbors,
               coast_samples, solver_pool
    [limits]   v_max, a_max, j_max    (optional overrides of the per-vehicle defaults)
    [sim]      backend, duration_s, physics_hz, control_hz, goal_tolerance_m,
               goal_speed_tolerance_mps
    [[robots]] vehicle, start, goal | waypoints, goal_velocity, end_state
    [scenario] kind = "paper:<name>" | "antipodal_sphere" | "random_box" | "grid_swap"
               | "stacked", and the generator's keys (its parameter model in
               jaxplan/scenarios/generators.py, e.g. RandomBoxParams)
    [sweep]    q_obs, q_lim (lists or {log_min, log_max, num}, base-10 exponents),
               seeds (list or {start, num}), scenarios (registry names)
    [faults]   enabled, message_loss, latency_s, noise_sigma_m, frozen_robot, frozen_at_s,
               frozen_mode (jaxplan/faults.py; off by default)

Robots: ``goal = [x, y, z]`` (one goal) or ``waypoints = [[x, y, z], ...]`` (several, in
order; the fleet moves on when every robot reached waypoint w).  ``goal_velocity`` is
one vector (the end velocity at the final waypoint) or a list with one entry per
waypoint, ``[]`` meaning none there.  ``end_state`` is "free" | "rest" (all waypoints)
or a list with one entry per waypoint; default ``planner.end_state``.  Robot indices in
messages count from 0 (``robots[0]`` is the first ``[[robots]]``).  Positions have 2
(planar robots) or 3 coordinates; one config uses one N throughout.

``[scenario]`` builds robots from a generator or one of the paper's four
(``kind = "paper:six_neos"``, ``"paper:eight_fireflys_stacked"``,
``"paper:eight_mixed_transitions"``, ``"paper:ten_mixed_rest"``; these take no other
key).  ``[[robots]]`` entries, if any, are appended after the generated robots.  The
top-level ``seed`` seeds the generator.

Each section is a pydantic dataclass (unknown keys forbidden, frozen, hashable; the field
types are in jaxplan/fields.py).  Every error is a :class:`ConfigError` whose message is
one line, ``<file>: <key>: <problem>``, raised before any computation: pydantic's
validation errors are translated into that form by :func:`_problem`.
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import re
import tomllib
import typing
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import tomli_w
from pydantic import (
    AfterValidator,
    BeforeValidator,
    ConfigDict,
    Strict,
    TypeAdapter,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)
from pydantic.dataclasses import dataclass

from jaxplan import scenarios
from jaxplan.fields import (
    MAX_ROBOTS,
    Corners,
    Dimension,
    EndState,
    FieldProblem,
    Position,
    VehicleName,
    integer,
    number,
    one_of,
    show,
    string,
)
from jaxplan.nlp import PLANNER_COLLISION_MODES
from jaxplan.scenarios import GENERATOR_PARAMS, PAPER_SCENARIOS, SCENARIOS, Scenario, ScenarioError
from jaxplan.vehicles import VEHICLES

__all__ = [
    "ConfigError",
    "Config",
    "PlannerConfig",
    "LimitsConfig",
    "SimConfig",
    "RobotConfig",
    "ScenarioConfig",
    "SweepConfig",
    "FaultsConfig",
    "load_config",
    "parse_config",
    "config_to_dict",
    "config_to_toml",
    "build_scenario",
    "COLLISION_MODES",
    "BACKENDS",
    "GENERATOR_KEYS",
]

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
DEFAULT_TOL = 1e-6                       # solver stationarity / feasibility tolerance
DEFAULT_N_SAMPLES = 32                   # collision samples / quadrature nodes per horizon
DEFAULT_SAFETY_MARGIN_M = 0.05           # m added to every radius when planning (not in metrics)
DEFAULT_MAX_NEIGHBORS = 0                # 0: every other robot is in each robot's NLP
DEFAULT_SOLVER_POOL = 0                  # 0: automatic (jaxplan.solve.default_pool)
DEFAULT_COAST_SAMPLES = 8                # constraint samples on a free end's coast after T
MAX_COAST_SAMPLES = 256

DEFAULT_BACKEND = "ideal"
DEFAULT_DURATION_S = 30.0
DEFAULT_PHYSICS_HZ = 500.0
DEFAULT_CONTROL_HZ = 250.0
DEFAULT_GOAL_TOLERANCE_M = 0.1
DEFAULT_GOAL_SPEED_TOLERANCE_MPS = 0.1   # residual speed allowed at a rest goal

COLLISION_MODES = PLANNER_COLLISION_MODES  # the NLP's modes but "none" (jaxplan/nlp/types.py)
BACKENDS = ("ideal", "mjx")
FROZEN_MODES = ("silent", "stale")
MAX_DEGREE = 15
MAX_SEGMENTS = 64
MAX_SAMPLES = 4096
MAX_SWEEP_POINTS = 10000
MAX_SEED = 2**63 - 1
MAX_ITERS = 1_000_000


class ConfigError(ValueError):
    """An invalid config: one line ``<file>: <key>: <problem>``."""


_SECTION = ConfigDict(extra="forbid")  # every section model: unknown keys are errors

# ---------------------------------------------------------------------------------------
# Section models
# ---------------------------------------------------------------------------------------


@dataclass(frozen=True, config=_SECTION)
class PlannerConfig:
    """[planner]: rates, NLP weights, collision treatment, trajectory shape, solver.

    replan_hz (Hz); q_dynm, q_obs, q_lim, k_t (>= 0) objective weights; k_p (1/m, > 0);
    collision in COLLISION_MODES; degree (>= 5) and segments (>= 1) of the polynomial
    per axis; end_state "free" | "rest" (default for robots); max_iters, tol, n_samples;
    safety_margin_m (m, >= 0): added to every robot's radius in the planner's collision
    terms only, so that rho_ij is planned with r_i + r_j + 2 margin while metrics still
    count a collision below r_i + r_j (covers sampling between collision samples and
    the others' replanning).  max_neighbors (>= 0): 0 puts every other robot in each
    robot's NLP; K >= 1 only the K that come nearest to its own prediction (the NLP's
    cost then stays flat as the fleet grows; jaxplan.planner.nearest_neighbors).
    coast_samples (>= 0): a free-end plan must also keep clear of the others on its coast
    after T (p(T) + v(T) t, for t up to the time a stop from v_max takes) at this many
    sample times (hard constraints; only in the "constraint" modes; 0 = off, the paper's
    NLP: a free-end plan may then arrive at speed with a robot just beyond its goal).
    solver_pool (>= 0): how many robots' NLPs the solver steps at once in a replan
    (jaxplan.solve.solve_lanes); 0 = automatic (jaxplan.solve.default_pool): 2 on a
    CPU (12 for more than 32 robots with at most 16 others per NLP), all M elsewhere.
    Speed only: every NLP takes the same iterations whatever the pool (results equal to
    rounding, which a closed loop can amplify into slightly different runs).
    """

    replan_hz: number(gt=0.0) = DEFAULT_REPLAN_HZ
    q_dynm: number(ge=0.0) = DEFAULT_Q_DYNM
    q_obs: number(ge=0.0) = DEFAULT_Q_OBS
    q_lim: number(ge=0.0) = DEFAULT_Q_LIM
    k_t: number(ge=0.0) = DEFAULT_K_T
    k_p: number(gt=0.0) = DEFAULT_K_P
    collision: string(one_of(COLLISION_MODES)) = DEFAULT_COLLISION
    degree: integer(ge=5, le=MAX_DEGREE) = DEFAULT_DEGREE
    segments: integer(ge=1, le=MAX_SEGMENTS) = DEFAULT_SEGMENTS
    end_state: EndState = DEFAULT_END_STATE
    max_iters: integer(ge=1, le=MAX_ITERS) = DEFAULT_MAX_ITERS
    tol: number(gt=0.0) = DEFAULT_TOL
    n_samples: integer(ge=2, le=MAX_SAMPLES) = DEFAULT_N_SAMPLES
    safety_margin_m: number(ge=0.0, le=10.0) = DEFAULT_SAFETY_MARGIN_M
    max_neighbors: integer(ge=0, le=MAX_ROBOTS) = DEFAULT_MAX_NEIGHBORS
    coast_samples: integer(ge=0, le=MAX_COAST_SAMPLES) = DEFAULT_COAST_SAMPLES
    solver_pool: integer(ge=0, le=MAX_ROBOTS) = DEFAULT_SOLVER_POOL


@dataclass(frozen=True, config=_SECTION)
class LimitsConfig:
    """[limits]: m/s, m/s^2, m/s^3 overrides for every robot; None (not given) = the
    per-vehicle default.  TOML has no null: a given value must be a positive number."""

    v_max: number(gt=0.0) = None
    a_max: number(gt=0.0) = None
    j_max: number(gt=0.0) = None


@dataclass(frozen=True, config=_SECTION)
class SimConfig:
    """[sim]: backend "ideal" | "mjx"; duration_s (s); physics_hz, control_hz (Hz,
    physics_hz / control_hz a whole number); goal_tolerance_m (m);
    goal_speed_tolerance_mps (m/s, residual speed allowed at a rest goal)."""

    backend: string(one_of(BACKENDS)) = DEFAULT_BACKEND
    duration_s: number(gt=0.0) = DEFAULT_DURATION_S
    physics_hz: number(gt=0.0) = DEFAULT_PHYSICS_HZ
    control_hz: number(gt=0.0) = DEFAULT_CONTROL_HZ
    goal_tolerance_m: number(gt=0.0) = DEFAULT_GOAL_TOLERANCE_M
    goal_speed_tolerance_mps: number(gt=0.0) = DEFAULT_GOAL_SPEED_TOLERANCE_MPS

    @model_validator(mode="after")
    def _whole_steps_per_control(self) -> SimConfig:
        ratio = self.physics_hz / self.control_hz
        if ratio < 1.0 - 1e-9 or abs(ratio - round(ratio)) > 1e-9 * ratio:
            raise FieldProblem(f"physics_hz / control_hz must be a whole number >= 1 (the "
                               f"controller runs every k-th physics step), got "
                               f"{self.physics_hz:g} / {self.control_hz:g}", key="control_hz")
        return self


def _below_one(x: float) -> float:
    if x >= 1.0:
        raise FieldProblem(f"must be < 1 (a probability), got {x}")
    return x


def _at_most_ten_seconds(x: float) -> float:
    if x > 10.0:
        raise FieldProblem(f"must be <= 10 s, got {x}")
    return x


Probability = Annotated[number(ge=0.0), AfterValidator(_below_one)]
ShortDelay = Annotated[number(ge=0.0), AfterValidator(_at_most_ten_seconds)]


@dataclass(frozen=True, config=_SECTION)
class FaultsConfig:
    """[faults] (jaxplan/faults.py): all off by default; ``enabled`` switches the faulty
    channel on (a different compiled program)."""

    enabled: Annotated[bool, Strict()] = False
    message_loss: Probability = 0.0  # per (observer, sender, period), in [0, 1)
    latency_s: ShortDelay = 0.0  # s, rounded to whole replan periods
    noise_sigma_m: number(ge=0.0) = 0.0  # m per axis on every received position
    frozen_robot: integer(ge=-1) = -1  # index of the robot that stops responding; -1: none
    frozen_at_s: number(ge=0.0) = 0.0  # s
    frozen_mode: string(one_of(FROZEN_MODES)) = "silent"  # "silent" | "stale" (keeps sending)


@dataclass(frozen=True)
class RobotConfig:
    """One [[robots]] entry, resolved.

    vehicle: name; start: (N,) m; waypoints: W goals of (N,) m; end_state: W of
    "free" | "rest"; goal_velocity: W entries, each (N,) m/s or None.
    """

    vehicle: VehicleName
    start: Position
    waypoints: tuple[Position, ...]
    end_state: tuple[EndState, ...]
    goal_velocity: tuple[Position | None, ...]


@dataclass(frozen=True)
class ScenarioConfig:
    """[scenario], resolved: kind and, for a generator, its parameter model with every
    default filled in (None for the paper's four, which take no parameters)."""

    kind: str
    params: scenarios.AnyGeneratorParams | None = None

    def as_dict(self) -> dict[str, Any]:
        return {} if self.params is None else self.params.as_dict()

    def get(self, key: str, default: Any = None) -> Any:
        return self.as_dict().get(key, default)

    @property
    def dim(self) -> int:
        return int(self.as_dict().get("dim", 3))


@dataclass(frozen=True)
class SweepConfig:
    """[sweep], resolved: q_obs, q_lim weight grids; seeds; scenarios (registry names,
    empty = the config's own fleet).  Defaults: the planner's weights and the seed."""

    q_obs: tuple[float, ...]
    q_lim: tuple[float, ...]
    seeds: tuple[int, ...]
    scenarios: tuple[str, ...] = ()


def _plain_name(name: str) -> str:
    if not name.strip() or any(ch in name for ch in "/\\\n\r\t\0"):
        raise FieldProblem(f"must be a non-empty name without slashes or control "
                           f"characters, got {show(name)}")
    return name


Name = string(AfterValidator(_plain_name))
Seed = integer(ge=0, le=MAX_SEED)


@dataclass(frozen=True)
class Config:
    """A whole experiment, validated and resolved.  ``source`` is where it came from
    (not part of equality)."""

    name: Name
    description: str
    seed: Seed
    planner: PlannerConfig
    limits: LimitsConfig
    sim: SimConfig
    robots: tuple[RobotConfig, ...]
    scenario: ScenarioConfig | None
    sweep: SweepConfig
    faults: FaultsConfig
    source: str = dataclasses.field(default="<string>", compare=False)

    @property
    def dim(self) -> int:
        """N, the number of spatial dimensions."""
        if self.scenario is not None:
            return self.scenario.dim
        return len(self.robots[0].start)


_TOP_KEYS = ("name", "description", "seed", "planner", "limits", "sim", "robots",
             "scenario", "sweep", "faults")
_ROBOT_KEYS = ("vehicle", "start", "goal", "waypoints", "goal_velocity", "end_state")
FAULT_KEYS = tuple(FaultsConfig.__dataclass_fields__)
# Each generator's keys, in the order they are written out (declared in
# jaxplan/scenarios/generators.py).
GENERATOR_KEYS: dict[str, tuple[str, ...]] = {
    kind: params.keys() for kind, params in GENERATOR_PARAMS.items()}

# ---------------------------------------------------------------------------------------
# Validation errors -> one line
# ---------------------------------------------------------------------------------------


class _Invalid(Exception):
    """A problem found while parsing: the key path and the problem (no file yet)."""

    def __init__(self, key: str, message: str):
        super().__init__(message)
        self.key = key
        self.message = message


def _join(prefix: str, key: str) -> str:
    if not prefix or not key:
        return prefix or key
    return prefix + key if key.startswith("[") else f"{prefix}.{key}"


def _key_path(prefix: str, loc: tuple) -> str:
    for part in loc:
        prefix = _join(prefix, f"[{part}]" if isinstance(part, int) else str(part))
    return prefix


def _bound(x: float | int) -> str:
    return str(x) if isinstance(x, int) else f"{x:g}"


_COMPARISONS = {"greater_than": ("gt", ">"), "greater_than_equal": ("ge", ">="),
                "less_than": ("lt", "<"), "less_than_equal": ("le", "<=")}
_UNKNOWN_KEY = ("unexpected_keyword_argument", "extra_forbidden")
_WRONG_TYPE = {"float_type": "a number", "int_type": "an integer", "string_type": "a string",
               "finite_number": "a finite number"}


def _unknown_key(key: str, allowed: tuple[str, ...], prefix: str) -> _Invalid:
    near = difflib.get_close_matches(key, list(allowed), n=1, cutoff=0.6)
    hint = f"; did you mean {near[0]!r}?" if near else f"; valid keys: {', '.join(allowed)}"
    shown = key if re.fullmatch(r"[A-Za-z0-9_-]+", key) else show(key)
    return _Invalid(_join(prefix, shown), f"unknown key{hint}")


def _check_keys(table: dict, allowed: tuple[str, ...], prefix: str) -> None:
    for k in table:
        if k not in allowed:
            raise _unknown_key(k, allowed, prefix)


def _table(v: Any, key: str) -> dict:
    if not isinstance(v, dict):
        raise _Invalid(key, f"expected a table, got {show(v)}")
    for k in v:
        if not isinstance(k, str):
            raise _Invalid(key, f"expected string keys, got {show(k)}")
    return v


def _problem(error: dict, key: str, allowed: tuple[str, ...], missing: str) -> _Invalid:
    """One pydantic error (of a value at ``key``) in the config's own words."""
    kind, v, loc = error["type"], error.get("input"), tuple(error["loc"])
    ctx = error.get("ctx") or {}
    if kind in _UNKNOWN_KEY:
        return _unknown_key(str(loc[-1]), allowed, _key_path(key, loc[:-1]))
    path = _key_path(key, loc)
    if kind == "value_error" and isinstance(ctx.get("error"), FieldProblem):
        return _Invalid(_join(path, ctx["error"].key), str(ctx["error"]))
    if kind == "missing":
        return _Invalid(path, missing)
    if kind == "float_type" and isinstance(v, int) and not isinstance(v, bool):
        return _Invalid(path, f"number out of range: {show(v)}")
    if kind in _WRONG_TYPE:
        return _Invalid(path, f"expected {_WRONG_TYPE[kind]}, got {show(v)}")
    if kind == "bool_type":
        return _Invalid(path, f"expected true or false, got {show(v)}")
    if kind in ("dataclass_type", "dict_type"):
        return _Invalid(path, f"expected a table, got {show(v)}")
    if kind in _COMPARISONS:
        name, op = _COMPARISONS[kind]
        return _Invalid(path, f"must be {op} {_bound(ctx[name])}, got {show(v)}")
    return _Invalid(path, f"{error['msg']}, got {show(v)}")  # pragma: no cover - a new type


def _priority(error: dict, missing_first: bool) -> int:
    """Unknown keys first, then (``missing_first``) missing ones, then the rest, each in
    declaration order."""
    if error["type"] in _UNKNOWN_KEY:
        return 0
    return 1 if missing_first and error["type"] == "missing" else 2


@functools.cache
def _adapter(schema: Any) -> TypeAdapter:
    return TypeAdapter(schema)


def _validate(schema: Any, value: Any, key: str, *, dim: int | None = None,
              missing: str = "missing", missing_first: bool = False) -> Any:
    """``value`` validated by ``schema`` (a model or an annotated type; ``dim``: the N
    vectors must have), or :class:`_Invalid` with the first problem (``missing``: the
    text for a missing key)."""
    try:
        return _adapter(schema).validate_python(value, context={"dim": dim})
    except ValidationError as e:
        first = min(e.errors(include_url=False), key=lambda x: _priority(x, missing_first))
        allowed = tuple(f.name for f in dataclasses.fields(schema)) \
            if dataclasses.is_dataclass(schema) else ()
        raise _problem(first, key, allowed, missing) from None


# ---------------------------------------------------------------------------------------
# Robots
# ---------------------------------------------------------------------------------------


class _RobotKeys:
    """Where each resolved robot's fields came from, for error keys."""

    def __init__(self, prefix: str, goal_key: str):
        self.prefix = prefix
        self.goal_key = goal_key  # "goal" or "waypoints"

    def start(self) -> str:
        return f"{self.prefix}.start"

    def goal(self, w: int) -> str:
        return f"{self.prefix}.goal" if self.goal_key == "goal" else \
            f"{self.prefix}.waypoints[{w}]"


def _parse_robot(raw: Any, i: int, dim: int | None,
                 default_end: str) -> tuple[RobotConfig, _RobotKeys]:
    p = f"robots[{i}]"
    t = _table(raw, p)
    _check_keys(t, _ROBOT_KEYS, p)
    if "vehicle" not in t:
        raise _Invalid(f"{p}.vehicle", f"missing; choose one of {', '.join(VEHICLES)}")
    vehicle = _validate(VehicleName, t["vehicle"], f"{p}.vehicle")
    if "start" not in t:
        raise _Invalid(f"{p}.start", "missing; give the start position [x, y, z]")
    start = _validate(Position, t["start"], f"{p}.start", dim=dim)
    dim = len(start)
    if ("goal" in t) == ("waypoints" in t):
        raise _Invalid(f"{p}.goal", "give exactly one of 'goal' (one position) or "
                                    "'waypoints' (a list of positions)")
    if "goal" in t:
        waypoints = (_validate(Position, t["goal"], f"{p}.goal", dim=dim),)
    else:
        waypoints = _validate(_Waypoints, t["waypoints"], f"{p}.waypoints", dim=dim)
    ends = _end_states(t.get("end_state", default_end), len(waypoints), f"{p}.end_state")
    velocities = _goal_velocities(t, ends, dim, f"{p}.goal_velocity")
    robot = RobotConfig(vehicle, start, waypoints, ends, velocities)
    return robot, _RobotKeys(p, "goal" if "goal" in t else "waypoints")


def _non_empty_positions(v: Any) -> tuple:
    if not isinstance(v, (list, tuple)) or not v:
        raise FieldProblem(f"expected a non-empty array of positions, got {show(v)}")
    return tuple(v)


_Waypoints = Annotated[tuple[Position, ...], BeforeValidator(_non_empty_positions)]


def _end_states(raw: Any, W: int, key: str) -> tuple[str, ...]:
    if isinstance(raw, str):
        return (_validate(EndState, raw, key),) * W
    if isinstance(raw, (list, tuple)):
        if len(raw) != W:
            raise _Invalid(key, f"expected one entry per waypoint ({W}), got {len(raw)}")
        return tuple(_validate(EndState, e, f"{key}[{k}]") for k, e in enumerate(raw))
    raise _Invalid(key, f"expected 'free', 'rest' or a list of them, got {show(raw)}")


def _goal_velocities(t: dict, ends: tuple[str, ...], dim: int,
                     key: str) -> tuple[tuple[float, ...] | None, ...]:
    """One entry per waypoint: the given end velocity, or None (none given, or a rest end
    with a zero one)."""
    W = len(ends)
    gv: list[tuple[float, ...] | None] = [None] * W
    if "goal_velocity" not in t:
        return tuple(gv)
    g = t["goal_velocity"]
    if not isinstance(g, (list, tuple)) or not g:
        raise _Invalid(key, f"expected [vx, vy, vz] or one entry per waypoint, got {show(g)}")
    if all(isinstance(x, (list, tuple)) for x in g):
        if "goal" in t:
            raise _Invalid(key, f"expected one vector [vx, vy, vz], got {show(g)}")
        if len(g) != W:
            raise _Invalid(key, f"expected one vector, or one entry per waypoint ({W}; [] for "
                                f"none), got {len(g)} entries")
        for k, x in enumerate(g):
            gv[k] = None if len(x) == 0 else _validate(Position, x, f"{key}[{k}]", dim=dim)
    else:
        gv[-1] = _validate(Position, g, key, dim=dim)
    for k in range(W):
        if gv[k] is not None and ends[k] == "rest":
            if any(x != 0.0 for x in gv[k]):
                raise _Invalid(key, f"waypoint {k} has end_state 'rest' (v = 0) but a non-zero "
                                    f"goal velocity; drop one of them")
            gv[k] = None
    return tuple(gv)


def _parse_robots(raw: Any, default_end: str,
                  dim: int | None) -> tuple[tuple[RobotConfig, ...], list[_RobotKeys]]:
    if not isinstance(raw, (list, tuple)):
        raise _Invalid("robots", f"expected an array of tables [[robots]], got {show(raw)}")
    if len(raw) > MAX_ROBOTS:
        raise _Invalid("robots", f"at most {MAX_ROBOTS} robots, got {len(raw)}")
    robots, keys = [], []
    for i, r in enumerate(raw):
        robot, robot_keys = _parse_robot(r, i, dim, default_end)
        dim = len(robot.start)
        robots.append(robot)
        keys.append(robot_keys)
    return tuple(robots), keys


# ---------------------------------------------------------------------------------------
# Scenario
# ---------------------------------------------------------------------------------------

ScenarioKind = string(one_of(tuple(SCENARIOS)))


def _parse_scenario(raw: Any, default_end: str) -> ScenarioConfig:
    t = _table(raw, "scenario")
    if "kind" not in t:
        raise _Invalid("scenario.kind", f"missing; choose one of {', '.join(SCENARIOS)}")
    kind = _validate(ScenarioKind, t["kind"], "scenario.kind")
    if kind in PAPER_SCENARIOS:
        _check_keys(t, ("kind",), "scenario")
        return ScenarioConfig(kind)
    model = GENERATOR_PARAMS[kind]
    _check_keys(t, ("kind", *model.keys()), "scenario")
    values = {k: v for k, v in t.items() if k != "kind"}
    dim = _scenario_dim(model, values)
    values["dim"] = dim
    values.setdefault("end_state", default_end)
    params = _validate(model, values, "scenario", dim=dim,
                       missing="missing; give a positive integer")
    if kind == "grid_swap" and params.rows * params.cols > MAX_ROBOTS:
        raise _Invalid("scenario.rows", f"rows * cols must be <= {MAX_ROBOTS}, got "
                                        f"{params.rows * params.cols}")
    return ScenarioConfig(kind, params.resolved())


@functools.cache
def _vector_keys(model: type) -> tuple[tuple[str, Any], ...]:
    """The model's position and box keys, with their types, in declaration order."""
    hints = typing.get_type_hints(model, include_extras=True)
    return tuple((k, hints[k]) for k in model.keys()
                 if hints[k] is Position or hints[k] is Corners)


def _scenario_dim(model: type, values: dict[str, Any]) -> int:
    """N of a generator's table: ``dim`` when given, else the length of its first vector,
    else 3.  Validates ``dim`` and the vectors (in place), in that order."""
    dim = _validate(Dimension, values["dim"], "scenario.dim") if "dim" in values else None
    for k, schema in _vector_keys(model):
        if k not in values:
            continue
        raw = values[k]
        if schema is Corners and dim is None:  # the upper corner must match the lower one
            lower = raw[0] if isinstance(raw, (list, tuple)) and len(raw) == 2 else None
            if isinstance(lower, (list, tuple)) and len(lower) in (2, 3):
                dim = len(lower)
        v = _validate(schema, raw, f"scenario.{k}", dim=dim)
        values[k] = v
        dim = len(v) if schema is Position else len(v[0])
    return 3 if dim is None else dim


# ---------------------------------------------------------------------------------------
# Sweep
# ---------------------------------------------------------------------------------------


@dataclass(frozen=True, config=_SECTION)
class _LogRange:
    """A weight grid ``{log_min, log_max, num}``: num values, log-spaced, base-10 exponents."""

    log_min: number(ge=-300.0, le=300.0)
    log_max: number(le=300.0)
    num: integer(ge=1, le=MAX_SWEEP_POINTS)

    @field_validator("log_max", mode="wrap")
    @classmethod
    def _not_below_log_min(cls, v: Any, handler: Any, info: ValidationInfo) -> float:
        x = handler(v)
        lo = info.data.get("log_min")
        if lo is not None and not x >= lo:
            raise FieldProblem(f"must be >= {lo:g}, got {show(v)}")
        return x

    @model_validator(mode="after")
    def _one_point_is_one_value(self) -> _LogRange:
        if self.num == 1 and self.log_max != self.log_min:
            raise FieldProblem("num = 1 needs log_min == log_max", key="num")
        return self

    def values(self) -> tuple[float, ...]:
        return tuple(float(x) for x in np.logspace(self.log_min, self.log_max, self.num))


@dataclass(frozen=True, config=_SECTION, kw_only=True)
class _SeedRange:
    """Seeds ``{start, num}``: start, start + 1, ..., start + num - 1."""

    start: Seed = 0
    num: integer(ge=1, le=MAX_SWEEP_POINTS)

    @model_validator(mode="after")
    def _below_2_63(self) -> _SeedRange:
        if self.start + self.num - 1 > MAX_SEED:
            raise FieldProblem("seeds must be < 2**63")
        return self


def _list_of(what: str, table: str, limit_name: str) -> BeforeValidator:
    def check(v: Any) -> tuple:
        if not isinstance(v, (list, tuple)) or not v:
            raise FieldProblem(f"expected a non-empty array of {what} or a table {table}, "
                               f"got {show(v)}")
        if len(v) > MAX_SWEEP_POINTS:
            raise FieldProblem(f"at most {MAX_SWEEP_POINTS} {limit_name}, got {len(v)}")
        return tuple(v)

    return BeforeValidator(check)


def _scenario_names(v: Any) -> tuple:
    if not isinstance(v, (list, tuple)):
        raise FieldProblem(f"expected an array of scenario names, got {show(v)}")
    return tuple(v)


_Weights = Annotated[tuple[number(ge=0.0), ...],
                     _list_of("numbers", "{log_min, log_max, num}", "values")]
_Seeds = Annotated[tuple[Seed, ...], _list_of("integers", "{start, num}", "seeds")]
_ScenarioNames = Annotated[tuple[ScenarioKind, ...], BeforeValidator(_scenario_names)]


def _parse_weights(raw: Any, key: str, default: float) -> tuple[float, ...]:
    if raw is None:
        return (default,)
    if isinstance(raw, dict):
        _table(raw, key)
        return _validate(_LogRange, raw, key, missing_first=True,
                         missing="missing; a log range needs log_min, log_max, num (base-10 "
                                 "exponents)").values()
    return _validate(_Weights, raw, key)


def _parse_seeds(raw: Any, default: int) -> tuple[int, ...]:
    if raw is None:
        return (default,)
    if isinstance(raw, dict):
        _table(raw, "sweep.seeds")
        seeds = _validate(_SeedRange, raw, "sweep.seeds", missing_first=True,
                          missing="missing; a seed range needs num (and start = 0)")
        return tuple(range(seeds.start, seeds.start + seeds.num))
    return _validate(_Seeds, raw, "sweep.seeds")


def _parse_sweep(raw: Any, planner: PlannerConfig, seed: int) -> SweepConfig:
    t = _table(raw, "sweep")
    _check_keys(t, tuple(SweepConfig.__dataclass_fields__), "sweep")
    return SweepConfig(
        q_obs=_parse_weights(t.get("q_obs"), "sweep.q_obs", planner.q_obs),
        q_lim=_parse_weights(t.get("q_lim"), "sweep.q_lim", planner.q_lim),
        seeds=_parse_seeds(t.get("seeds"), seed),
        scenarios=_validate(_ScenarioNames, t.get("scenarios", []), "sweep.scenarios"))


# ---------------------------------------------------------------------------------------
# Public API
# ---------------------------------------------------------------------------------------


def parse_config(data: Any, source: str = "<string>") -> Config:
    """Validate a parsed TOML document (a dict) and resolve every default.

    Args:
        data: the document, e.g. ``tomllib.loads(text)``.
        source: file name used in error messages (and for the default name).
    Returns: a frozen :class:`Config`.
    Raises: ConfigError, one line ``<source>: <key>: <problem>``, never anything else.
    """
    source = str(source)
    shown = source if source.isprintable() else show(source)
    try:
        return _parse(data, shown)
    except _Invalid as e:
        key = e.key if e.key.isprintable() else show(e.key)
        message = " ".join(e.message.split())
        raise ConfigError(f"{shown}: {key}: {message}" if key else f"{shown}: {message}") \
            from None
    except (RecursionError, MemoryError) as e:  # absurdly nested or huge input
        raise ConfigError(f"{shown}: input too large or too deeply nested "
                          f"({type(e).__name__})") from None


def _section(t: dict, key: str, model: type) -> Any:
    return _validate(model, _table(t.get(key, {}), key), key)


def _parse(data: Any, source: str) -> Config:
    t = _table(data, "")
    _check_keys(t, _TOP_KEYS, "")
    default_name = Path(source).stem if source != "<string>" else "config"
    name = _validate(Name, t.get("name", default_name or "config"), "name")
    description = _validate(string(), t.get("description", ""), "description")
    seed = _validate(Seed, t.get("seed", 0), "seed")
    planner = _section(t, "planner", PlannerConfig)
    limits = _section(t, "limits", LimitsConfig)
    sim = _section(t, "sim", SimConfig)
    faults = _section(t, "faults", FaultsConfig)
    scenario = _parse_scenario(t["scenario"], planner.end_state) if "scenario" in t else None
    dim = scenario.dim if scenario is not None else None
    robots, robot_keys = _parse_robots(t.get("robots", []), planner.end_state, dim)
    if scenario is None and not robots:
        raise _Invalid("robots", "the fleet is empty; give [[robots]] entries or a [scenario] "
                                 "table")
    if sim.backend == "mjx" and (dim or len(robots[0].start)) != 3:
        raise _Invalid("sim.backend", "'mjx' simulates quadrotors and needs 3-D positions; "
                                      "use 'ideal' for a 2-D config")
    sweep = _parse_sweep(t.get("sweep", {}), planner, seed)
    config = Config(name=name, description=description, seed=seed, planner=planner,
                    limits=limits, sim=sim, robots=robots, scenario=scenario, sweep=sweep,
                    faults=faults, source=source)
    _check_fleet(config, robot_keys)
    return config


def _check_fleet(config: Config, robot_keys: list[_RobotKeys]) -> None:
    """Build the fleet now (cheap NumPy) so that geometric errors surface before any run,
    named by the config key they come from."""
    try:
        fleet = _assemble(config, validate=False)
    except ScenarioError as e:
        key = f"scenario.{e.key}" if e.key else "scenario"
        msg = str(e)
        if e.key and msg.startswith(f"{e.key}: "):
            msg = msg[len(e.key) + 2:]
        raise _Invalid(key, msg) from None
    n_gen = fleet.num_robots - len(config.robots)

    def label(i: int) -> str:
        return f"robots[{i - n_gen}]" if i >= n_gen else f"generated robot {i}"

    problems = scenarios.scenario_problems(fleet, max_problems=1, label=label)
    if problems:
        p = problems[0]
        key = "scenario"
        if p.robot >= n_gen:
            keys = robot_keys[p.robot - n_gen]
            W = len(config.robots[p.robot - n_gen].waypoints)
            key = keys.start() if p.waypoint is None else keys.goal(min(p.waypoint, W - 1))
        raise _Invalid(key, p.message)


def load_config(path: str | Path) -> Config:
    """Read and validate a TOML config file.  Raises ConfigError (one line) on any problem,
    including a missing file or a TOML syntax error."""
    src = str(path)
    try:
        with open(path, "rb") as f:
            data = tomllib.load(f)
    except OSError as e:
        raise ConfigError(f"{src}: cannot read the file: {e.strerror or e}") from None
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{src}: invalid TOML: {' '.join(str(e).split())}") from None
    except UnicodeDecodeError as e:
        raise ConfigError(f"{src}: invalid TOML: not UTF-8 ({e.reason})") from None
    return parse_config(data, source=src)


def _dump(model: Any, **kw: Any) -> dict[str, Any]:
    """A section model as TOML-ready plain data (tuples become lists)."""
    return _adapter(type(model)).dump_python(model, mode="json", **kw)


def _robot_to_dict(r: RobotConfig) -> dict[str, Any]:
    """A robot in the shortest form that reads back equal: goal for one waypoint, one
    end_state when all agree, one goal_velocity when only the last waypoint has one."""
    row: dict[str, Any] = {"vehicle": r.vehicle, "start": list(r.start)}
    if len(r.waypoints) == 1:
        row["goal"] = list(r.waypoints[0])
    else:
        row["waypoints"] = [list(w) for w in r.waypoints]
    row["end_state"] = r.end_state[0] if len(set(r.end_state)) == 1 else list(r.end_state)
    if any(v is not None for v in r.goal_velocity):
        if all(v is None for v in r.goal_velocity[:-1]):
            row["goal_velocity"] = list(r.goal_velocity[-1])
        else:
            row["goal_velocity"] = [[] if v is None else list(v) for v in r.goal_velocity]
    return row


def config_to_dict(config: Config) -> dict[str, Any]:
    """The fully resolved config as a TOML-ready dict (every default written out;
    limits only where overridden: their default is per vehicle)."""
    d: dict[str, Any] = {"name": config.name, "description": config.description,
                         "seed": config.seed, "planner": _dump(config.planner),
                         "limits": _dump(config.limits, exclude_none=True),
                         "sim": _dump(config.sim)}
    if config.scenario is not None:
        d["scenario"] = {"kind": config.scenario.kind}
        if config.scenario.params is not None:
            d["scenario"].update(_dump(config.scenario.params))
    if config.robots:
        d["robots"] = [_robot_to_dict(r) for r in config.robots]
    d["sweep"] = _dump(config.sweep)
    d["faults"] = _dump(config.faults)
    return d


def config_to_toml(config: Config) -> str:
    """The fully resolved config as TOML text; ``load`` of it gives an equal Config."""
    lines = ["# jaxplan resolved config: every default written out."]
    if any(getattr(config.limits, k) is None for k in ("v_max", "a_max", "j_max")):
        used = sorted({r.vehicle for r in config.robots} | _scenario_vehicles(config))
        per = "; ".join(f"{v} v_max={VEHICLES[v].v_max:g} a_max={VEHICLES[v].a_max:g} "
                        f"j_max={VEHICLES[v].j_max:g}" for v in used)
        lines.append(f"# [limits] not given are per vehicle: {per}")
    d = config_to_dict(config)
    lines += [f"{k} = {_toml_value(v)}" for k, v in d.items()
              if not isinstance(v, (dict, list))]
    for k, v in d.items():
        if isinstance(v, dict):
            lines += ["", f"[{k}]"] + [f"{kk} = {_toml_value(vv)}" for kk, vv in v.items()]
        elif isinstance(v, list):  # array of tables
            for row in v:
                lines += ["", f"[[{k}]]"] + [f"{kk} = {_toml_value(vv)}" for kk, vv in row.items()]
    return "\n".join(lines) + "\n"


def _toml_value(v: Any) -> str:
    """One TOML value: scalars by tomli_w, arrays inline (one per line when long)."""
    if isinstance(v, (list, tuple)):
        items = [_toml_value(x) for x in v]
        one = "[" + ", ".join(items) + "]"
        if len(one) <= 88 or not any(isinstance(x, (list, tuple)) for x in v):
            return one
        return "[\n" + "".join(f"    {x},\n" for x in items) + "]"
    return tomli_w.dumps({"v": v})[len("v = "):].rstrip("\n")


def _scenario_vehicles(config: Config) -> set[str]:
    if config.scenario is None:
        return set()
    if config.scenario.kind in PAPER_SCENARIOS:
        return {"firefly", "neo11"}
    return set(config.scenario.get("vehicles", ()))


def _assemble(config: Config, validate: bool) -> Scenario:
    """The fleet: generated robots, then [[robots]], with the [limits] overrides."""
    parts: list[Scenario] = []
    if config.scenario is not None:
        if config.scenario.params is None:
            parts.append(PAPER_SCENARIOS[config.scenario.kind](seed=config.seed))
        else:  # validated below, as a whole fleet together with [[robots]]
            parts.append(config.scenario.params.build(seed=config.seed, validate=False))
    starts, wps, rests, gvs, names = [], [], [], [], []
    for p in parts:
        for i in range(p.num_robots):
            names.append(p.vehicles[i])
            starts.append(p.start[i])
            wps.append(p.waypoints[i])
            rests.append(p.rest[i])
            gvs.append([p.goal_velocity[i, w] if p.has_goal_velocity[i, w] else None
                        for w in range(p.num_waypoints)])
    for r in config.robots:
        names.append(r.vehicle)
        starts.append(np.array(r.start))
        wps.append(np.array(r.waypoints))
        rests.append([e == "rest" for e in r.end_state])
        gvs.append(list(r.goal_velocity))
    lim = config.limits
    return scenarios.make_scenario(config.name, names, np.array(starts), wps, rests, gvs,
                                   v_max=lim.v_max, a_max=lim.a_max, j_max=lim.j_max,
                                   validate=validate)


def build_scenario(config: Config) -> Scenario:
    """The fleet of a config: generated robots (seeded by ``config.seed``) then
    [[robots]], limits overridden by [limits].  Named ``config.name``.

    Returns: a validated :class:`jaxplan.scenarios.Scenario`.
    """
    fleet = _assemble(config, validate=True)
    fr = config.faults.frozen_robot
    if fr >= fleet.num_robots:
        raise ConfigError(f"{config.source}: faults.frozen_robot: robot {fr} does not exist "
                          f"(the fleet has {fleet.num_robots} robots, numbered from 0)")
    return fleet
