"""Scenarios with robots that do not cooperate (``Scenario.cooperative`` False: they run
no planner and fly their own straight legs, jaxplan/rollout.py "Non-cooperative
robots"): ``intruder``, a drone crossing a swarm mid-swap.  Deterministic for a seed."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import ClassVar

import numpy as np
from pydantic import ConfigDict
from pydantic.dataclasses import dataclass as pydantic_dataclass

from jaxplan.fields import (
    Count,
    EndState,
    NonNegativeLength,
    Position,
    PositiveLength,
    VehicleName,
    VehicleNames,
    integer,
)
from jaxplan.scenarios.generators import (
    _check_pos,
    _check_vec,
    _end_flags,
    antipodal_sphere,
    check_seed,
)
from jaxplan.scenarios.params import GeneratorParams, generates
from jaxplan.scenarios.scenario import Scenario, make_scenario


@pydantic_dataclass(frozen=True, config=ConfigDict(extra="forbid"))
class IntruderParams(GeneratorParams):
    """``kind = "intruder"`` (:func:`intruder`)."""

    kind: ClassVar[str] = "intruder"
    count: Count = 10
    dim: integer(ge=3, le=3) = None  # 3-D: the intruder flies a horizontal line
    radius: PositiveLength = 4.0
    center: Position = (0.0, 0.0, 5.0)
    perturbation: NonNegativeLength = 0.05
    vehicles: VehicleNames = ("firefly", "neo11")
    end_state: EndState = None
    intruder_distance: PositiveLength = 6.0
    intruder_height: NonNegativeLength = 1.0
    intruder_vehicle: VehicleName = "firefly"


@generates(IntruderParams)
def intruder(
    count: int = IntruderParams.count,
    radius: float = IntruderParams.radius,
    vehicles: Sequence[str] = IntruderParams.vehicles,
    seed: int = 0,
    *,
    center=IntruderParams.center,
    perturbation: float = IntruderParams.perturbation,
    intruder_distance: float = IntruderParams.intruder_distance,
    intruder_height: float = IntruderParams.intruder_height,
    intruder_vehicle: str = IntruderParams.intruder_vehicle,
    end_state: str = "rest",
    validate: bool = True,
) -> Scenario:
    """A swarm swaps across a sphere (:func:`antipodal_sphere`, "even" placement) while a
    non-cooperative drone (the last robot, ``cooperative`` False) crosses it in a straight
    line at its own limits, through the swarm's centre, so that it arrives there mid-swap.

    Args:
        count, radius, vehicles, center, perturbation, end_state: the swarm's, as
            :func:`antipodal_sphere` takes them (3-D).
        seed: the swarm's rotation and goal offsets, and the intruder's heading (uniform
            in the horizontal plane) and height offset (uniform in +-intruder_height).
        intruder_distance: m, the intruder starts this far from the centre (horizontally)
            and flies to the point opposite.
        intruder_height: m, the largest height offset of its line from the centre's.
        intruder_vehicle: its vehicle.
    Returns: a one-waypoint Scenario named "intruder", count + 1 robots.
    """
    seed = check_seed(seed)
    swarm = antipodal_sphere(count, radius, vehicles, seed, center=center,
                             perturbation=perturbation, end_state=end_state, validate=False)
    c = _check_vec(center, 3, "center")
    d = _check_pos(intruder_distance, "intruder_distance")
    h = _check_pos(intruder_height, "intruder_height", strict=False)
    rng = np.random.default_rng([seed, 1])  # its own stream: the swarm is antipodal_sphere's
    ang = rng.uniform(0.0, 2.0 * math.pi)
    dz = rng.uniform(-h, h)
    u = np.array([math.cos(ang), math.sin(ang), 0.0])
    off = np.array([0.0, 0.0, dz])
    names = (*swarm.vehicles, str(intruder_vehicle))
    start = np.concatenate([swarm.start, (c - d * u + off)[None]])
    goal = np.concatenate([swarm.waypoints[:, 0], (c + d * u + off)[None]])
    coop = np.append(np.ones(count, bool), False)
    return make_scenario("intruder", names, start, goal, **_end_flags(end_state),
                         cooperative=coop, validate=validate)
