"""[[robots]]: one table per robot, validated into a resolved :class:`RobotConfig`.

A table gives ``goal`` (one position) or ``waypoints`` (several), an ``end_state`` (one
for every waypoint, or a list) and a ``goal_velocity`` (one vector, the end velocity at
the last waypoint, or one entry per waypoint, ``[]`` for none); the resolved robot has
one entry of each per waypoint.  The validation context gives ``dim`` (the N of the
config, None before its first position) and ``end_state`` ([planner] end_state, the
default).
"""

from __future__ import annotations

from typing import Annotated, Any, ClassVar

from pydantic import BeforeValidator, ValidationInfo, model_validator
from pydantic.dataclasses import dataclass

from jaxplan.config.errors import sub_value, table_keys
from jaxplan.config.schema import SECTION_CONFIG
from jaxplan.fields import EndState, FieldProblem, Position, VehicleName, show
from jaxplan.vehicles import ROBOTS

__all__ = ["ROBOT_KEYS", "RobotConfig"]


def _non_empty_positions(v: Any) -> tuple:
    if not isinstance(v, (list, tuple)) or not v:
        raise FieldProblem(f"expected a non-empty array of positions, got {show(v)}")
    return tuple(v)


_Waypoints = Annotated[tuple[Position, ...], BeforeValidator(_non_empty_positions)]


@dataclass(frozen=True, config=SECTION_CONFIG)
class RobotConfig:
    """One [[robots]] entry, resolved.

    vehicle: name; start: (N,) m; waypoints: W goals of (N,) m; end_state: W of
    "free" | "rest" | "auto"; goal_velocity: W entries, each (N,) m/s or None (none given, or a
    rest end's zero one); cooperative: False = the robot runs no planner and flies its own
    waypoints (:class:`jaxplan.scenarios.Scenario` ``cooperative``).
    """

    KEYS: ClassVar[tuple[str, ...]] = ("vehicle", "start", "goal", "waypoints",
                                       "goal_velocity", "end_state",
                                       "cooperative")  # the table's

    vehicle: VehicleName
    start: Position
    waypoints: tuple[Position, ...]
    end_state: tuple[EndState, ...]
    goal_velocity: tuple[Position | None, ...]
    cooperative: bool = True

    @model_validator(mode="before")
    @classmethod
    def _from_table(cls, t: Any, info: ValidationInfo) -> Any:
        """A [[robots]] table -> the resolved fields, checked in the order a reader
        fixes them: keys, vehicle, start, goal or waypoints, end_state, goal_velocity."""
        if not isinstance(t, dict):
            return t  # the constructor's arguments, or not a table (pydantic says so)
        table_keys(t, cls.KEYS)
        if "vehicle" not in t:
            raise FieldProblem(f"missing; choose one of {', '.join(ROBOTS)}", key="vehicle")
        vehicle = sub_value(VehicleName, t["vehicle"], "vehicle", info)
        if "start" not in t:
            raise FieldProblem("missing; give the start position [x, y, z]", key="start")
        start = sub_value(Position, t["start"], "start", info)
        dim = len(start)
        if ("goal" in t) == ("waypoints" in t):
            raise FieldProblem("give exactly one of 'goal' (one position) or 'waypoints' (a "
                               "list of positions)", key="goal")
        if "goal" in t:
            waypoints = (sub_value(Position, t["goal"], "goal", info, dim=dim),)
        else:
            waypoints = sub_value(_Waypoints, t["waypoints"], "waypoints", info, dim=dim)
        default = (info.context or {}).get("end_state", "free")
        ends = _end_states(t.get("end_state", default), len(waypoints), info)
        coop = t.get("cooperative", True)
        if not isinstance(coop, bool):
            raise FieldProblem(f"expected true or false, got {show(coop)}", key="cooperative")
        return {"vehicle": vehicle, "start": start, "waypoints": waypoints, "end_state": ends,
                "goal_velocity": _goal_velocities(t, ends, dim, info), "cooperative": coop}


ROBOT_KEYS = RobotConfig.KEYS


def _end_states(raw: Any, W: int, info: ValidationInfo) -> tuple[str, ...]:
    if isinstance(raw, str):
        return (sub_value(EndState, raw, "end_state", info),) * W
    if isinstance(raw, (list, tuple)):
        if len(raw) != W:
            raise FieldProblem(f"expected one entry per waypoint ({W}), got {len(raw)}",
                               key="end_state")
        return tuple(sub_value(EndState, e, f"end_state[{k}]", info) for k, e in enumerate(raw))
    raise FieldProblem(f"expected 'free', 'rest', 'auto' or a list of them, got {show(raw)}",
                       key="end_state")


def _goal_velocities(t: dict, ends: tuple[str, ...], dim: int,
                     info: ValidationInfo) -> tuple[tuple[float, ...] | None, ...]:
    """One entry per waypoint: the given end velocity, or None (none given, or a rest end
    with a zero one)."""
    W, key = len(ends), "goal_velocity"
    gv: list[tuple[float, ...] | None] = [None] * W
    if key not in t:
        return tuple(gv)
    g = t[key]
    if not isinstance(g, (list, tuple)) or not g:
        raise FieldProblem(f"expected [vx, vy, vz] or one entry per waypoint, got {show(g)}",
                           key=key)
    if all(isinstance(x, (list, tuple)) for x in g):
        if "goal" in t:
            raise FieldProblem(f"expected one vector [vx, vy, vz], got {show(g)}", key=key)
        if len(g) != W:
            raise FieldProblem(f"expected one vector, or one entry per waypoint ({W}; [] for "
                               f"none), got {len(g)} entries", key=key)
        for k, x in enumerate(g):
            gv[k] = None if len(x) == 0 else sub_value(Position, x, f"{key}[{k}]", info, dim=dim)
    else:
        gv[-1] = sub_value(Position, g, key, info, dim=dim)
    for k in range(W):
        if gv[k] is not None and ends[k] == "rest":
            if any(x != 0.0 for x in gv[k]):
                raise FieldProblem(f"waypoint {k} has end_state 'rest' (v = 0) but a non-zero "
                                   f"goal velocity; drop one of them", key=key)
            gv[k] = None
    return tuple(gv)
