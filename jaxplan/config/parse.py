"""TOML documents -> a validated :class:`Config`: each section validated by its model
in the order a reader would fix them (a section's defaults from those before it, given
as the validation context), then the fleet as a whole (:func:`parse_config`,
:func:`load_config`)."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

import numpy as np

from jaxplan import scenarios
from jaxplan.config.errors import InvalidValue, as_table, check_keys, validate_value
from jaxplan.config.model import TOP_KEYS, Config
from jaxplan.config.resolve import assemble_scenario
from jaxplan.config.robots import RobotConfig
from jaxplan.config.scenario import ScenarioConfig
from jaxplan.config.schema import (
    OBSTACLE_KEYS,
    OBSTACLE_KINDS,
    ConfigError,
    FaultsConfig,
    LimitsConfig,
    Name,
    ObstacleConfig,
    PlannerConfig,
    Seed,
    SimConfig,
    WorkspaceConfig,
)
from jaxplan.config.sweep import SweepConfig
from jaxplan.config.tune import TuneConfig
from jaxplan.fields import MAX_ROBOTS, show, string
from jaxplan.scenarios import ScenarioError
from jaxplan.vehicles import GROUND_ROBOTS

__all__ = ["load_config", "parse_config"]


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


def _section(t: dict, key: str, model: type, **context: Any) -> Any:
    """Section ``key`` of the document validated by ``model`` (an empty table when
    absent); ``context``: what its defaults and checks take from the sections before."""
    return validate_value(model, as_table(t.get(key, {}), key), key,
                          dim=context.pop("dim", None), context=context)


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
    scenario = (_section(t, "scenario", ScenarioConfig, end_state=planner.end_state)
                if "scenario" in t else None)
    dim = scenario.dim if scenario is not None else None
    robots = _robots(t.get("robots", []), planner.end_state, dim)
    if scenario is None and not robots:
        raise InvalidValue("robots", "the fleet is empty; give [[robots]] entries or a [scenario] "
                                     "table")
    N = dim or len(robots[0].start)
    if sim.backend == "mjx" and N != 3:
        raise InvalidValue("sim.backend", "'mjx' simulates quadrotors and needs 3-D positions; "
                                          "use 'ideal' for a 2-D config")
    if planner.method == "orca3d" and sim.backend != "ideal":
        raise InvalidValue("sim.backend", "[planner] method 'orca3d' moves the robots itself; "
                                          "use 'ideal'")
    if planner.method == "orca" and N != 2:
        raise InvalidValue("planner.method", "'orca' is planar-only for now (RVO2 works in "
                                             "the plane); give 2-D positions or use "
                                             "'krishnan'")
    sweep = _section(t, "sweep", SweepConfig, planner=planner, seed=seed)
    workspace = _section(t, "workspace", WorkspaceConfig, dim=N)
    obstacles = _obstacles(t.get("obstacles", []), N)
    tune = _section(t, "tune", TuneConfig, seed=seed, source=source,
                    load_config=load_config) if "tune" in t else None
    config = Config(name=name, description=description, seed=seed, planner=planner,
                    limits=limits, sim=sim, robots=robots, scenario=scenario, sweep=sweep,
                    faults=faults, workspace=workspace, obstacles=obstacles, tune=tune,
                    source=source)
    _check_fleet(config, _goal_keys(t.get("robots", [])))
    return config


def _robots(raw: Any, default_end: str, dim: int | None) -> tuple[RobotConfig, ...]:
    """[[robots]]: each table by RobotConfig; the first position fixes N for the rest."""
    if not isinstance(raw, (list, tuple)):
        raise InvalidValue("robots", f"expected an array of tables [[robots]], got {show(raw)}")
    if len(raw) > MAX_ROBOTS:
        raise InvalidValue("robots", f"at most {MAX_ROBOTS} robots, got {len(raw)}")
    robots = []
    for i, r in enumerate(raw):
        robot = validate_value(RobotConfig, r, f"robots[{i}]", dim=dim,
                               context={"end_state": default_end})
        dim = len(robot.start)
        robots.append(robot)
    return tuple(robots)


def _obstacles(raw: Any, dim: int) -> tuple[ObstacleConfig, ...]:
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


def _goal_keys(raw: list) -> list[str]:
    """Each [[robots]] table's goal key: "goal" or "waypoints" (for error keys)."""
    return ["goal" if "goal" in r else "waypoints" for r in raw]


def _check_fleet(config: Config, goal_keys: list[str]) -> None:
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
    if config.planner.method == "orca3d" and fleet.world.num_obstacles > 0:
        raise InvalidValue("planner.method", f"'orca3d' takes no obstacles (RVO2-3D has none), "
                                             f"and this world has {fleet.world.num_obstacles}; "
                                             "remove them, or use 'krishnan' (or 'orca' for "
                                             "a planar fleet)")

    if fleet.world.has_motion and config.planner.method != "krishnan":
        k = int(np.flatnonzero(fleet.world.moving)[0])
        raise InvalidValue("planner.method", f"moving obstacles (obstacles[{k}] moves) fly "
                                             "with method 'krishnan' only for now")

    pc = config.planner
    if pc.region == "fleet":
        body = float(np.max(fleet.radius)) + pc.safety_margin_m
        if pc.region_margin_m <= body:
            raise InvalidValue("planner.region_margin_m",
                               f"{pc.region_margin_m:g} m leaves no room for a robot's body "
                               f"inside the fleet's region (the largest robot's radius plus "
                               f"safety_margin_m is {body:g} m); give more")

    problems = scenarios.scenario_problems(fleet, max_problems=1, label=label)
    if problems:
        p = problems[0]
        key = "scenario"
        if p.robot >= n_gen:
            i = p.robot - n_gen
            key = f"robots[{i}].start"
            if p.waypoint is not None:
                w = min(p.waypoint, len(config.robots[i].waypoints) - 1)
                key = (f"robots[{i}].goal" if goal_keys[i] == "goal"
                       else f"robots[{i}].waypoints[{w}]")
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
