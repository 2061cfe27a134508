"""TOML documents -> a validated :class:`Config`: the robots, the scenario and the sweep
grid, each section checked in the order a reader would fix them, and the fleet as a
whole (:func:`parse_config`, :func:`load_config`)."""

from __future__ import annotations

import dataclasses
import functools
import os
import tomllib
import typing
from pathlib import Path
from typing import Annotated, Any

import numpy as np
from pydantic import (
    BeforeValidator,
    Strict,
    ValidationInfo,
    field_validator,
    model_validator,
)
from pydantic.dataclasses import dataclass

from jaxplan import scenarios
from jaxplan.config.errors import (
    InvalidValue,
    as_table,
    check_keys,
    validate_value,
)
from jaxplan.config.resolve import (
    assemble_scenario,
)
from jaxplan.config.schema import (
    DEFAULT_SWEEP_ENGINE,
    DEFAULT_TUNE_BATCH,
    DEFAULT_TUNE_MIN_SEPARATION_RATIO,
    DEFAULT_TUNE_MIN_SUCCESS_RATE,
    DEFAULT_TUNE_OBJECTIVE,
    DEFAULT_TUNE_SAMPLER,
    DEFAULT_TUNE_TRIALS,
    MAX_SEED,
    MAX_SWEEP_POINTS,
    MAX_TUNE_TRIALS,
    OBSTACLE_KEYS,
    OBSTACLE_KINDS,
    ROBOT_KEYS,
    SECTION_CONFIG,
    SWEEP_ENGINES,
    TOP_KEYS,
    TUNABLE_WEIGHTS,
    TUNE_KEYS,
    TUNE_OBJECTIVES,
    TUNE_SAMPLERS,
    Config,
    ConfigError,
    FaultsConfig,
    LimitsConfig,
    Name,
    ObstacleConfig,
    PlannerConfig,
    RobotConfig,
    ScenarioConfig,
    Seed,
    SimConfig,
    SweepConfig,
    TuneConfig,
    WeightRange,
    WorkspaceConfig,
)
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
from jaxplan.scenarios import GENERATOR_PARAMS, PAPER_SCENARIOS, SCENARIOS, ScenarioError
from jaxplan.vehicles import GROUND_ROBOTS, ROBOTS

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
    t = as_table(raw, p)
    check_keys(t, ROBOT_KEYS, p)
    if "vehicle" not in t:
        raise InvalidValue(f"{p}.vehicle", f"missing; choose one of {', '.join(ROBOTS)}")
    vehicle = validate_value(VehicleName, t["vehicle"], f"{p}.vehicle")
    if "start" not in t:
        raise InvalidValue(f"{p}.start", "missing; give the start position [x, y, z]")
    start = validate_value(Position, t["start"], f"{p}.start", dim=dim)
    dim = len(start)
    if ("goal" in t) == ("waypoints" in t):
        raise InvalidValue(f"{p}.goal", "give exactly one of 'goal' (one position) or "
                                    "'waypoints' (a list of positions)")
    if "goal" in t:
        waypoints = (validate_value(Position, t["goal"], f"{p}.goal", dim=dim),)
    else:
        waypoints = validate_value(_Waypoints, t["waypoints"], f"{p}.waypoints", dim=dim)
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
        return (validate_value(EndState, raw, key),) * W
    if isinstance(raw, (list, tuple)):
        if len(raw) != W:
            raise InvalidValue(key, f"expected one entry per waypoint ({W}), got {len(raw)}")
        return tuple(validate_value(EndState, e, f"{key}[{k}]") for k, e in enumerate(raw))
    raise InvalidValue(key, f"expected 'free', 'rest' or a list of them, got {show(raw)}")


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
        raise InvalidValue(key, f"expected [vx, vy, vz] or one entry per waypoint, got {show(g)}")
    if all(isinstance(x, (list, tuple)) for x in g):
        if "goal" in t:
            raise InvalidValue(key, f"expected one vector [vx, vy, vz], got {show(g)}")
        if len(g) != W:
            raise InvalidValue(key, f"expected one vector, or one entry per waypoint ({W}; [] for "
                                f"none), got {len(g)} entries")
        for k, x in enumerate(g):
            gv[k] = None if len(x) == 0 else validate_value(Position, x, f"{key}[{k}]", dim=dim)
    else:
        gv[-1] = validate_value(Position, g, key, dim=dim)
    for k in range(W):
        if gv[k] is not None and ends[k] == "rest":
            if any(x != 0.0 for x in gv[k]):
                raise InvalidValue(key, f"waypoint {k} has end_state 'rest' (v = 0) but a non-zero "
                                    f"goal velocity; drop one of them")
            gv[k] = None
    return tuple(gv)


def _parse_robots(raw: Any, default_end: str,
                  dim: int | None) -> tuple[tuple[RobotConfig, ...], list[_RobotKeys]]:
    if not isinstance(raw, (list, tuple)):
        raise InvalidValue("robots", f"expected an array of tables [[robots]], got {show(raw)}")
    if len(raw) > MAX_ROBOTS:
        raise InvalidValue("robots", f"at most {MAX_ROBOTS} robots, got {len(raw)}")
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
    t = as_table(raw, "scenario")
    if "kind" not in t:
        raise InvalidValue("scenario.kind", f"missing; choose one of {', '.join(SCENARIOS)}")
    kind = validate_value(ScenarioKind, t["kind"], "scenario.kind")
    if kind in PAPER_SCENARIOS:
        check_keys(t, ("kind",), "scenario")
        return ScenarioConfig(kind)
    model = GENERATOR_PARAMS[kind]
    check_keys(t, ("kind", *model.keys()), "scenario")
    values = {k: v for k, v in t.items() if k != "kind"}
    dim = _scenario_dim(model, values)
    if _ground_fleet(model, values):
        dim = 2  # ground robots move in the plane: no dim and no vector given means 2-D
    values["dim"] = dim
    values.setdefault("end_state", default_end)
    params = validate_value(model, values, "scenario", dim=dim,
                       missing="missing; give a positive integer")
    if kind == "grid_swap" and params.rows * params.cols > MAX_ROBOTS:
        raise InvalidValue("scenario.rows", f"rows * cols must be <= {MAX_ROBOTS}, got "
                                        f"{params.rows * params.cols}")
    return ScenarioConfig(kind, params.resolved())


def _ground_fleet(model: type, values: dict[str, Any]) -> bool:
    """The table names only ground robots and gives neither ``dim`` nor a vector."""
    vehicles = values.get("vehicles")
    return ("dim" not in values and not any(k in values for k, _ in _vector_keys(model))
            and isinstance(vehicles, (list, tuple)) and len(vehicles) > 0
            and all(isinstance(v, str) and v in GROUND_ROBOTS for v in vehicles))


@functools.cache
def _vector_keys(model: type) -> tuple[tuple[str, Any], ...]:
    """The model's position and box keys, with their types, in declaration order."""
    hints = typing.get_type_hints(model, include_extras=True)
    return tuple((k, hints[k]) for k in model.keys()
                 if hints[k] is Position or hints[k] is Corners)


def _scenario_dim(model: type, values: dict[str, Any]) -> int:
    """N of a generator's table: ``dim`` when given, else the length of its first vector,
    else 3.  Validates ``dim`` and the vectors (in place), in that order."""
    dim = validate_value(Dimension, values["dim"], "scenario.dim") if "dim" in values else None
    for k, schema in _vector_keys(model):
        if k not in values:
            continue
        raw = values[k]
        if schema is Corners and dim is None:  # the upper corner must match the lower one
            lower = raw[0] if isinstance(raw, (list, tuple)) and len(raw) == 2 else None
            if isinstance(lower, (list, tuple)) and len(lower) in (2, 3):
                dim = len(lower)
        v = validate_value(schema, raw, f"scenario.{k}", dim=dim)
        values[k] = v
        dim = len(v) if schema is Position else len(v[0])
    return 3 if dim is None else dim


# ---------------------------------------------------------------------------------------
# Sweep
# ---------------------------------------------------------------------------------------


@dataclass(frozen=True, config=SECTION_CONFIG)
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


@dataclass(frozen=True, config=SECTION_CONFIG, kw_only=True)
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
_SweepEngine = string(one_of(SWEEP_ENGINES))
_ScenarioNames = Annotated[tuple[ScenarioKind, ...], BeforeValidator(_scenario_names)]


def _parse_weights(raw: Any, key: str, default: float) -> tuple[float, ...]:
    if raw is None:
        return (default,)
    if isinstance(raw, dict):
        as_table(raw, key)
        return validate_value(_LogRange, raw, key, missing_first=True,
                         missing="missing; a log range needs log_min, log_max, num (base-10 "
                                 "exponents)").values()
    return validate_value(_Weights, raw, key)


def _parse_seeds(raw: Any, default: int, key: str = "sweep.seeds") -> tuple[int, ...]:
    if raw is None:
        return (default,)
    if isinstance(raw, dict):
        as_table(raw, key)
        seeds = validate_value(_SeedRange, raw, key, missing_first=True,
                          missing="missing; a seed range needs num (and start = 0)")
        return tuple(range(seeds.start, seeds.start + seeds.num))
    return validate_value(_Seeds, raw, key)


def _parse_sweep(raw: Any, planner: PlannerConfig, seed: int) -> SweepConfig:
    t = as_table(raw, "sweep")
    check_keys(t, tuple(SweepConfig.__dataclass_fields__), "sweep")
    return SweepConfig(
        q_obs=_parse_weights(t.get("q_obs"), "sweep.q_obs", planner.q_obs),
        q_lim=_parse_weights(t.get("q_lim"), "sweep.q_lim", planner.q_lim),
        seeds=_parse_seeds(t.get("seeds"), seed),
        scenarios=validate_value(_ScenarioNames, t.get("scenarios", []), "sweep.scenarios"),
        engine=validate_value(_SweepEngine, t.get("engine", DEFAULT_SWEEP_ENGINE), "sweep.engine"))


# ---------------------------------------------------------------------------------------
# Tune
# ---------------------------------------------------------------------------------------

# each tunable weight's domain: what [planner] accepts, and q_dynm > 0 (the prediction's
# time weight is k_t / q_dynm)
_WEIGHT_DOMAIN = {"q_dynm": (0.0, False, None), "q_obs": (0.0, True, None),
                  "q_lim": (0.0, True, None), "k_t": (0.0, True, None),
                  "k_p": (0.0, False, None), "safety_margin_m": (0.0, True, 10.0)}


@dataclass(frozen=True, config=SECTION_CONFIG, kw_only=True)
class _Range:
    """A weight's range ``{low, high, log = false}``."""

    low: number()
    high: number()
    log: Annotated[bool, Strict()] = False


def _parse_range(raw: Any, name: str) -> WeightRange:
    key = f"tune.weights.{name}"
    r = validate_value(_Range, as_table(raw, key), key, missing_first=True,
                       missing="missing; a range needs low and high (and log = false)")
    lo, closed, hi = _WEIGHT_DOMAIN[name]
    if r.low < lo or (r.low == lo and not closed):
        raise InvalidValue(f"{key}.low", f"must be {'>=' if closed else '>'} {lo:g} "
                                         f"(planner.{name}'s domain), got {show(r.low)}")
    if hi is not None and r.high > hi:
        raise InvalidValue(f"{key}.high", f"must be <= {hi:g} (planner.{name}'s domain), "
                                          f"got {show(r.high)}")
    if not r.high > r.low:
        raise InvalidValue(f"{key}.high", f"must be > low = {r.low:g}, got {show(r.high)}")
    if r.log and r.low <= 0.0:
        raise InvalidValue(f"{key}.low", f"a log range needs low > 0, got {show(r.low)}")
    return WeightRange(float(r.low), float(r.high), bool(r.log))


def _parse_tune_scenarios(raw: Any, source: str) -> tuple[str, ...]:
    """Registry names, or paths of TOML configs (relative to the config file; made
    absolute) whose fleet is used; each file must load."""
    names = list(validate_value(_TuneScenarios, raw, "tune.scenarios"))
    for i, name in enumerate(names):
        if name.endswith(".toml"):
            path = tune_scenario_path(name, source)
            try:
                load_config(path)
            except ConfigError as e:
                raise InvalidValue(f"tune.scenarios[{i}]", str(e)) from None
            names[i] = os.path.abspath(path)  # resolved: config.toml loads anywhere
        elif name not in SCENARIOS:
            raise InvalidValue(f"tune.scenarios[{i}]", f"unknown scenario {show(name)}; give "
                               f"a registry name ({', '.join(SCENARIOS)}) or a .toml config "
                               "path")
    if len(set(names)) != len(names):
        raise InvalidValue("tune.scenarios", "a scenario is named twice")
    return tuple(names)


def tune_scenario_path(name: str, source: str) -> Path:
    """A [tune] scenarios entry that names a TOML file, resolved against the directory
    of the config file ``source`` (the working directory for a config from a string)."""
    p = Path(name)
    if p.is_absolute() or source.startswith("<"):
        return p
    return Path(source).parent / p


def _tune_seeds(t: dict, key: str, default: tuple[int, ...]) -> tuple[int, ...]:
    if key not in t:
        return default
    return _parse_seeds(t[key], 0, f"tune.{key}")


def _parse_tune(raw: Any, planner: PlannerConfig, seed: int, source: str) -> TuneConfig:
    t = as_table(raw, "tune")
    check_keys(t, TUNE_KEYS, "tune")
    weights_raw = as_table(t.get("weights", {}), "tune.weights")
    check_keys(weights_raw, TUNABLE_WEIGHTS, "tune.weights")
    if not weights_raw:
        raise InvalidValue("tune.weights", "name at least one weight to tune, e.g. "
                                           "q_obs = {low = 1.0, high = 100.0, log = true}; "
                                           f"tunable: {', '.join(TUNABLE_WEIGHTS)}")
    weights = {k: _parse_range(v, k) for k, v in weights_raw.items()}
    scenario_names = _parse_tune_scenarios(t.get("scenarios", []), source)
    seeds = _tune_seeds(t, "seeds", (seed,))
    holdout = () if t.get("holdout_seeds") == [] else _tune_seeds(t, "holdout_seeds", ())
    if set(seeds) & set(holdout):
        raise InvalidValue("tune.holdout_seeds", f"seed {min(set(seeds) & set(holdout))} is "
                                                 "also a training seed; held-out seeds must "
                                                 "be others")
    rest = {k: v for k, v in t.items()
            if k not in ("weights", "scenarios", "seeds", "holdout_seeds")}
    options = validate_value(_TuneOptions, rest, "tune")
    return TuneConfig(weights=weights, scenarios=scenario_names, seeds=seeds,
                      holdout_seeds=holdout, **dataclasses.asdict(options))


@dataclass(frozen=True, config=SECTION_CONFIG)
class _TuneOptions:
    """[tune]'s scalar keys."""

    objective: string(one_of(TUNE_OBJECTIVES)) = DEFAULT_TUNE_OBJECTIVE
    min_success_rate: number(ge=0.0, le=1.0) = DEFAULT_TUNE_MIN_SUCCESS_RATE
    min_separation_ratio: number(ge=0.0, le=100.0) = DEFAULT_TUNE_MIN_SEPARATION_RATIO
    trials: integer(ge=1, le=MAX_TUNE_TRIALS) = DEFAULT_TUNE_TRIALS
    batch: integer(ge=1, le=MAX_TUNE_TRIALS) = DEFAULT_TUNE_BATCH
    sampler: string(one_of(TUNE_SAMPLERS)) = DEFAULT_TUNE_SAMPLER
    enqueue_defaults: Annotated[bool, Strict()] = True


_TuneScenarios = Annotated[tuple[string(), ...], BeforeValidator(_scenario_names)]


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
    except InvalidValue as e:
        key = e.key if e.key.isprintable() else show(e.key)
        message = " ".join(e.message.split())
        raise ConfigError(f"{shown}: {key}: {message}" if key else f"{shown}: {message}") \
            from None
    except (RecursionError, MemoryError) as e:  # absurdly nested or huge input
        raise ConfigError(f"{shown}: input too large or too deeply nested "
                          f"({type(e).__name__})") from None


def _section(t: dict, key: str, model: type) -> Any:
    return validate_value(model, as_table(t.get(key, {}), key), key)


def _parse(data: Any, source: str) -> Config:
    t = as_table(data, "")
    check_keys(t, TOP_KEYS, "")
    default_name = Path(source).stem if source != "<string>" else "config"
    name = validate_value(Name, t.get("name", default_name or "config"), "name")
    description = validate_value(string(), t.get("description", ""), "description")
    seed = validate_value(Seed, t.get("seed", 0), "seed")
    planner = _section(t, "planner", PlannerConfig)
    limits = _section(t, "limits", LimitsConfig)
    sim = _section(t, "sim", SimConfig)
    faults = _section(t, "faults", FaultsConfig)
    scenario = _parse_scenario(t["scenario"], planner.end_state) if "scenario" in t else None
    dim = scenario.dim if scenario is not None else None
    robots, robot_keys = _parse_robots(t.get("robots", []), planner.end_state, dim)
    if scenario is None and not robots:
        raise InvalidValue("robots", "the fleet is empty; give [[robots]] entries or a [scenario] "
                                 "table")
    if sim.backend == "mjx" and (dim or len(robots[0].start)) != 3:
        raise InvalidValue("sim.backend", "'mjx' simulates quadrotors and needs 3-D positions; "
                                      "use 'ideal' for a 2-D config")
    sweep = _parse_sweep(t.get("sweep", {}), planner, seed)
    N = dim or len(robots[0].start)
    workspace = validate_value(WorkspaceConfig, as_table(t.get("workspace", {}), "workspace"),
                               "workspace", dim=N)
    obstacles = _parse_obstacles(t.get("obstacles", []), N)
    tune = _parse_tune(t["tune"], planner, seed, source) if "tune" in t else None
    config = Config(name=name, description=description, seed=seed, planner=planner,
                    limits=limits, sim=sim, robots=robots, scenario=scenario, sweep=sweep,
                    faults=faults, workspace=workspace, obstacles=obstacles, tune=tune,
                    source=source)
    _check_fleet(config, robot_keys)
    return config


def _parse_obstacles(raw: Any, dim: int) -> tuple[ObstacleConfig, ...]:
    if not isinstance(raw, (list, tuple)):
        raise InvalidValue("obstacles", f"expected an array of tables ([[obstacles]]), got "
                                        f"{show(raw)}")
    out = []
    for k, o in enumerate(raw):
        key = f"obstacles[{k}]"
        t = as_table(o, key)
        check_keys(t, OBSTACLE_KEYS, key)
        if "kind" not in t:
            raise InvalidValue(f"{key}.kind", f"missing; choose one of "
                                              f"{', '.join(repr(x) for x in OBSTACLE_KINDS)}")
        out.append(validate_value(ObstacleConfig, t, key, dim=dim))
    return tuple(out)


def _check_fleet(config: Config, robot_keys: list[_RobotKeys]) -> None:
    """Build the fleet now (cheap NumPy) so that geometric errors surface before any run,
    named by the config key they come from."""
    try:
        fleet = assemble_scenario(config, validate=False)
    except ScenarioError as e:
        key = f"scenario.{e.key}" if e.key else "scenario"
        msg = str(e)
        if e.key and msg.startswith(f"{e.key}: "):
            msg = msg[len(e.key) + 2:]
        raise InvalidValue(key, msg) from None
    n_gen = fleet.num_robots - len(config.robots)

    def label(i: int) -> str:
        return f"robots[{i - n_gen}]" if i >= n_gen else f"generated robot {i}"

    _check_ground(fleet, n_gen)

    problems = scenarios.scenario_problems(fleet, max_problems=1, label=label)
    if problems:
        p = problems[0]
        key = "scenario"
        if p.robot >= n_gen:
            keys = robot_keys[p.robot - n_gen]
            W = len(config.robots[p.robot - n_gen].waypoints)
            key = keys.start() if p.waypoint is None else keys.goal(min(p.waypoint, W - 1))
        raise InvalidValue(key, p.message)


def _check_ground(fleet, n_gen: int) -> None:
    """Ground robots move in the plane: a fleet with one needs 2-D positions."""
    if fleet.dim == 2:
        return
    for i, v in enumerate(fleet.vehicles):
        if v in GROUND_ROBOTS:
            key = f"robots[{i - n_gen}].vehicle" if i >= n_gen else "scenario.vehicles"
            raise InvalidValue(key, f"{v!r} is a ground robot, which moves in the plane; give "
                                    "2-D positions (or dim = 2) or an aerial vehicle")


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
