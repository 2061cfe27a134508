"""A validated :class:`Config` back out: as plain data and as the resolved config.toml
(every default written out), and as the :class:`Scenario` it describes."""

from __future__ import annotations

from typing import Any

import numpy as np
import tomli_w

from jaxplan import scenarios
from jaxplan.config.errors import (
    adapter_for,
)
from jaxplan.config.model import Config
from jaxplan.config.robots import RobotConfig
from jaxplan.config.schema import ConfigError
from jaxplan.scenarios import PAPER_SCENARIOS, Scenario
from jaxplan.vehicles import ROBOTS
from jaxplan.world import World, obstacle_arrays


def _dump(model: Any, **kw: Any) -> dict[str, Any]:
    """A section model as TOML-ready plain data (tuples become lists)."""
    return adapter_for(type(model)).dump_python(model, mode="json", **kw)


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
    if not r.cooperative:
        row["cooperative"] = False
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
    ws = _dump(config.workspace, exclude_none=True)
    if ws:
        d["workspace"] = ws
    if config.obstacles:
        d["obstacles"] = [_dump(o, exclude_none=True) for o in config.obstacles]
    if config.tune is not None:
        tune = _dump(config.tune)
        tune["weights"] = tune.pop("weights")  # a sub-table: after the scalar keys
        d["tune"] = tune
    return d


def config_to_toml(config: Config) -> str:
    """The fully resolved config as TOML text; ``load`` of it gives an equal Config."""
    lines = ["# jaxplan resolved config: every default written out."]
    if any(getattr(config.limits, k) is None for k in ("v_max", "a_max", "j_max")):
        used = sorted({r.vehicle for r in config.robots} | _scenario_vehicles(config))
        per = "; ".join(f"{v} v_max={ROBOTS[v].v_max:g} a_max={ROBOTS[v].a_max:g} "
                        f"j_max={ROBOTS[v].j_max:g}" for v in used)
        lines.append(f"# [limits] not given are per vehicle: {per}")
    d = config_to_dict(config)
    lines += [f"{k} = {_toml_value(v)}" for k, v in d.items()
              if not isinstance(v, (dict, list))]
    for k, v in d.items():
        if isinstance(v, dict):  # a section; a dict in it is a sub-table ([tune.weights])
            lines += ["", f"[{k}]"] + [f"{kk} = {_toml_value(vv)}" for kk, vv in v.items()
                                       if not isinstance(vv, dict)]
            for kk, vv in v.items():
                if isinstance(vv, dict):
                    lines += ["", f"[{k}.{kk}]"] + [f"{kkk} = {_toml_value(x)}"
                                                    for kkk, x in vv.items()]
        elif isinstance(v, list):  # array of tables
            for row in v:
                lines += ["", f"[[{k}]]"] + [f"{kk} = {_toml_value(vv)}" for kk, vv in row.items()]
    return "\n".join(lines) + "\n"


def _toml_value(v: Any) -> str:
    """One TOML value: scalars by tomli_w, arrays and tables inline (an array one entry
    per line when long)."""
    if isinstance(v, dict):
        return "{" + ", ".join(f"{k} = {_toml_value(x)}" for k, x in v.items()) + "}"
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


def assemble_scenario(config: Config, validate: bool) -> Scenario:
    """The fleet: generated robots, then [[robots]], with the [limits] overrides."""
    parts: list[Scenario] = []
    if config.scenario is not None:
        if config.scenario.params is None:
            parts.append(PAPER_SCENARIOS[config.scenario.kind](seed=config.seed))
        else:  # validated below, as a whole fleet together with [[robots]]
            parts.append(config.scenario.params.build(seed=config.seed, validate=False))
    starts, wps, rests, autos, gvs, names, coop = [], [], [], [], [], [], []
    for p in parts:
        for i in range(p.num_robots):
            names.append(p.vehicles[i])
            starts.append(p.start[i])
            wps.append(p.waypoints[i])
            rests.append(p.rest[i])
            autos.append(p.auto[i])
            coop.append(bool(p.cooperative[i]))
            gvs.append([p.goal_velocity[i, w] if p.has_goal_velocity[i, w] else None
                        for w in range(p.num_waypoints)])
    for r in config.robots:
        names.append(r.vehicle)
        starts.append(np.array(r.start))
        wps.append(np.array(r.waypoints))
        rests.append([e == "rest" for e in r.end_state])
        autos.append([e == "auto" for e in r.end_state])
        coop.append(r.cooperative)
        gvs.append(list(r.goal_velocity))
    lim = config.limits
    N = len(starts[0])
    return scenarios.make_scenario(config.name, names, np.array(starts), wps, rests, gvs,
                                   auto=autos, v_max=lim.v_max, a_max=lim.a_max, j_max=lim.j_max,
                                   world=config_world(config, parts[0].world if parts else None,
                                                      N),
                                   validate=validate, cooperative=coop)


def config_world(config: Config, generated: World | None, N: int) -> World:
    """The world of a config: the generator's (or :meth:`jaxplan.world.World.default`),
    its workspace bounds replaced by those [workspace] gives, [[obstacles]] appended."""
    base = generated if generated is not None else World.default(N)
    ws = config.workspace
    lo = np.array(ws.min, float) if ws.min is not None else base.lo
    hi = np.array(ws.max, float) if ws.max is not None else base.hi
    obstacles = base.obstacles() + [o.as_dict() for o in config.obstacles]
    return World(lo, hi, *obstacle_arrays([], N)).with_obstacles(obstacles)


def build_scenario(config: Config) -> Scenario:
    """The fleet of a config: generated robots (seeded by ``config.seed``) then
    [[robots]], limits overridden by [limits].  Named ``config.name``.

    Returns: a validated :class:`jaxplan.scenarios.Scenario`.
    """
    fleet = assemble_scenario(config, validate=True)
    fr = config.faults.frozen_robot
    if fr >= fleet.num_robots:
        raise ConfigError(f"{config.source}: faults.frozen_robot: robot {fr} does not exist "
                          f"(the fleet has {fleet.num_robots} robots, numbered from 0)")
    return fleet
