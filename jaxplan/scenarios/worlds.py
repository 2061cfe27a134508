"""Scenarios in worlds with obstacles (experiments/worlds/): ``pillars``, ``wall_gap``,
``low_ceiling`` and the ``random_obstacles`` generator, each with its parameter model
(its ``[scenario]`` keys), like the benchmark generators of
jaxplan/scenarios/generators.py.  3-D, on the ground (z >= 0); deterministic for a seed.

``pillars``
    ``count`` robots (default 12) in two groups cross a field of vertical cylinders
    (floor to ``height``): one group from x = -``half_length`` to +, the other back,
    each robot at a seeded height and lateral place; pillars of ``pillar_radius`` on a
    staggered grid ``pillar_spacing`` apart over x, y in [-3, 3] m, each moved by a
    seeded offset of up to ``jitter`` m.
``wall_gap``
    two groups of ``count`` / 2 (default 6 + 6) swap sides through a ``gap`` m wide
    (default 1.5 m) vertical slot, floor to ceiling, in a wall at x = 0 (0.2 m thick)
    that spans the workspace y in [-``half_width``, ``half_width``], z in [0, ``height``]:
    there is no way round.  Robots start on a 2 x (count / 4) grid in the y-z plane at
    x = -/+ ``distance`` and end mirrored at the other side; seeded jitter.
``low_ceiling``
    ``count`` robots (default 10) on a horizontal circle of ``radius`` (4 m) fly to
    the antipodal point under a ceiling at ``ceiling`` (2.5 m; floor at 0): starts at
    z = ceiling / 2 with a seeded jitter of up to ``jitter`` m in height and angle.
``random_obstacles``
    ``count`` robots and ``obstacles`` static obstacles (seeded kinds: vertical
    cylinders floor to ``height``, boxes on the floor, floating spheres) in a square
    arena whose side makes their footprints cover ``density`` of its floor; starts
    and goals drawn uniformly, ``min_spacing`` apart, clear of every obstacle by the
    robot's radius plus ``clearance``, each goal at least half the arena's side from
    its start.  The workspace is the arena (walls at its sides, a ceiling at
    ``height``).
``crossing_traffic``
    ``count`` robots (default 8) fly along a corridor ``length`` m long (14 m, x from
    -length / 2 to length / 2), ``width`` m wide (4 m) and ``height`` m high (2.5 m: the
    workspace, its walls, floor and ceiling faces) from one end to the other (starts on
    a 2 x (count / 2) grid in the y-z plane 1 m from the x_min end, goals mirrored 1 m
    from the x_max end, seeded jitter), while ``people`` (6) person-sized vertical
    cylinders (``person_radius`` 0.3 m, ``person_height`` 1.8 m, standing on the floor,
    so no robot passes over one under the ceiling) cross it: each waits ``approach`` m
    (1 m) outside a side wall (so that the robots see it walking before it enters) at
    a seeded x in the middle of the corridor, starts at a seeded time in
    [0, ``start_window``] s (6 s) and walks straight across at a seeded speed in
    [``speed_min``, ``speed_max``] m/s (0.5 to 1: up to v_max / 2), then waits outside
    the other wall as far out (a path of two timed points: jaxplan/world.py, "Motion");
    ``known_path``: whether the robots know the people's paths (default false: their
    position and velocity at each replan).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Annotated, ClassVar

import numpy as np
from pydantic import ConfigDict, Strict
from pydantic.dataclasses import dataclass as pydantic_dataclass

from jaxplan.fields import (
    Count,
    EndState,
    NonNegativeLength,
    PositiveLength,
    Tries,
    VehicleNames,
    integer,
    number,
)
from jaxplan.scenarios.generators import (
    _check_count,
    _check_pos,
    _end_flags,
    check_seed,
    default_spacing,
)
from jaxplan.scenarios.params import GeneratorParams, generates
from jaxplan.scenarios.scenario import Scenario, ScenarioError, cycle_vehicles, make_scenario
from jaxplan.vehicles import ROBOTS
from jaxplan.world import World, point_problems

_PARAMS_CONFIG = ConfigDict(extra="forbid")
ObstacleCount = integer(ge=0, le=1000)
ThreeD = integer(ge=3, le=3)  # the worlds are 3-D (a ground, heights)
Fraction = number(gt=0.0, lt=1.0)
# a random_obstacles arena's floor covered by obstacles: below 1e-3 its side (sqrt of
# the footprints over the density) grows without useful bound
Density = number(ge=1e-3, lt=1.0)
# m between pillar rows: a smaller spacing would place more than ~10^4 pillars
PillarSpacing = number(ge=0.1, le=1e3)
Speed = number(ge=0.01, le=100.0)  # m/s of a walking obstacle
Window = number(ge=0.0, le=1e3)  # s


def _world(lo, hi, obstacles) -> World:
    return World(np.asarray(lo, float), np.asarray(hi, float), np.zeros(0, np.int32),
                 np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0)).with_obstacles(obstacles)


def _jitter(rng, n, r) -> np.ndarray:
    return rng.uniform(-r, r, size=(n, 3)) if r > 0 else np.zeros((n, 3))


# ------------------------------------------------------------------------------ pillars
@pydantic_dataclass(frozen=True, config=_PARAMS_CONFIG)
class PillarsParams(GeneratorParams):
    """``kind = "pillars"`` (:func:`pillars`)."""

    kind: ClassVar[str] = "pillars"
    count: Count = 12
    dim: ThreeD = None
    half_length: PositiveLength = 5.5
    pillar_radius: PositiveLength = 0.25
    pillar_spacing: PillarSpacing = 2.2
    jitter: NonNegativeLength = 0.2
    height: PositiveLength = 4.0
    vehicles: VehicleNames = ("firefly",)
    end_state: EndState = None


@generates(PillarsParams)
def pillars(count: int = 12, seed: int = 0, *, half_length: float = 5.5,
            pillar_radius: float = 0.25, pillar_spacing: float = 2.2, jitter: float = 0.2,
            height: float = 4.0, vehicles: Sequence[str] = ("firefly",),
            end_state: str = "free", validate: bool = True) -> Scenario:
    """Two groups cross a field of pillars (module doc)."""
    count = _check_count(count)
    seed = check_seed(seed)
    ends = _end_flags(end_state)
    rng = np.random.default_rng(seed)
    names = cycle_vehicles(vehicles, count)
    obstacles = []
    xs = np.arange(-3.0, 3.0 + 1e-9, pillar_spacing * math.sqrt(3) / 2)
    for i, x in enumerate(xs):
        off = 0.5 * pillar_spacing * (i % 2)
        for y in np.arange(-3.0 - off, 3.0 + 1e-9, pillar_spacing) + off:
            c = np.array([x, y, height / 2]) + _jitter(rng, 1, jitter)[0] * [1, 1, 0]
            obstacles.append(dict(kind="cylinder", center=c, radius=pillar_radius,
                                  half_height=height / 2))
    side = np.where(np.arange(count) % 2 == 0, -1.0, 1.0)
    k = np.arange(count) // 2
    per = math.ceil(count / 2)
    lateral = (k - (per - 1) / 2) * (6.0 / max(per, 1))
    z = 1.0 + (k % 3) * 0.8
    start = np.stack([side * half_length, lateral, z], 1) + _jitter(rng, count, 0.15)
    goal = np.stack([-side * half_length, -lateral, z], 1) + _jitter(rng, count, 0.15)
    world = _world([-np.inf, -np.inf, 0.0], [np.inf, np.inf, height], obstacles)
    return make_scenario("pillars", names, start, goal, **ends, world=world, validate=validate)


# ------------------------------------------------------------------------------ wall_gap
@pydantic_dataclass(frozen=True, config=_PARAMS_CONFIG)
class WallGapParams(GeneratorParams):
    """``kind = "wall_gap"`` (:func:`wall_gap`)."""

    kind: ClassVar[str] = "wall_gap"
    count: Count = 12
    dim: ThreeD = None
    gap: PositiveLength = 1.5
    distance: PositiveLength = 4.0
    half_width: PositiveLength = 5.0
    height: PositiveLength = 3.5
    jitter: NonNegativeLength = 0.1
    vehicles: VehicleNames = ("firefly",)
    end_state: EndState = None


@generates(WallGapParams)
def wall_gap(count: int = 12, seed: int = 0, *, gap: float = 1.5, distance: float = 4.0,
             half_width: float = 5.0, height: float = 3.5, jitter: float = 0.1,
             vehicles: Sequence[str] = ("firefly",), end_state: str = "free",
             validate: bool = True) -> Scenario:
    """Two groups swap through a gap in a wall (module doc)."""
    count = _check_count(count)
    if count % 2:
        raise ScenarioError(f"count: must be even (two equal groups), got {count}", key="count")
    seed = check_seed(seed)
    ends = _end_flags(end_state)
    gap = _check_pos(gap, "gap")
    if gap >= 2 * half_width:
        raise ScenarioError(f"gap: must be narrower than the wall ({2 * half_width:g} m)",
                            key="gap")
    rng = np.random.default_rng(seed)
    names = cycle_vehicles(vehicles, count)
    t = 0.1  # half the wall's thickness
    wing = (half_width - gap / 2) / 2
    obstacles = [dict(kind="box", center=[0.0, s * (gap / 2 + wing), height / 2],
                      half_extents=[t, wing, height / 2]) for s in (-1.0, 1.0)]
    g = count // 2
    cols = math.ceil(g / 2)
    j = np.arange(g)
    y = (j % cols - (cols - 1) / 2) * min(1.2, 2 * (half_width - 0.6) / max(cols, 1))
    z = np.where(j < cols, 1.0, 2.2) * height / 3.5
    a = np.stack([np.full(g, -distance), y, z], 1)
    b = a * [-1, 1, 1]
    start = np.concatenate([a, b]) + _jitter(rng, count, jitter)
    goal = np.concatenate([b * [1, -1, 1], a * [1, -1, 1]]) + _jitter(rng, count, jitter)
    world = _world([-np.inf, -half_width, 0.0], [np.inf, half_width, height], obstacles)
    return make_scenario("wall_gap", names, start, goal, **ends, world=world, validate=validate)


# ---------------------------------------------------------------------------- low_ceiling
@pydantic_dataclass(frozen=True, config=_PARAMS_CONFIG)
class LowCeilingParams(GeneratorParams):
    """``kind = "low_ceiling"`` (:func:`low_ceiling`)."""

    kind: ClassVar[str] = "low_ceiling"
    count: Count = 10
    dim: ThreeD = None
    radius: PositiveLength = 4.0
    ceiling: PositiveLength = 2.5
    jitter: NonNegativeLength = 0.1
    vehicles: VehicleNames = ("firefly",)
    end_state: EndState = None


@generates(LowCeilingParams)
def low_ceiling(count: int = 10, seed: int = 0, *, radius: float = 4.0, ceiling: float = 2.5,
                jitter: float = 0.1, vehicles: Sequence[str] = ("firefly",),
                end_state: str = "free", validate: bool = True) -> Scenario:
    """An antipodal circle under a low ceiling (module doc)."""
    count = _check_count(count)
    seed = check_seed(seed)
    ends = _end_flags(end_state)
    radius = _check_pos(radius, "radius")
    ceiling = _check_pos(ceiling, "ceiling")
    rng = np.random.default_rng(seed)
    names = cycle_vehicles(vehicles, count)
    ang = 2 * math.pi * np.arange(count) / count + rng.uniform(-jitter, jitter, count) / radius
    unit = np.stack([np.cos(ang), np.sin(ang), np.zeros(count)], 1)
    c = np.array([0.0, 0.0, ceiling / 2])
    dz = rng.uniform(-jitter, jitter, (count, 1)) * [0, 0, 1]
    start = c + radius * unit + dz
    goal = c - radius * unit + rng.uniform(-jitter, jitter, (count, 1)) * [0, 0, 1]
    world = _world([-np.inf, -np.inf, 0.0], [np.inf, np.inf, ceiling], [])
    return make_scenario("low_ceiling", names, start, goal, **ends, world=world, validate=validate)


# ---------------------------------------------------------------------- random_obstacles
@pydantic_dataclass(frozen=True, config=_PARAMS_CONFIG)
class RandomObstaclesParams(GeneratorParams):
    """``kind = "random_obstacles"`` (:func:`random_obstacles`)."""

    kind: ClassVar[str] = "random_obstacles"
    count: Count = 12
    dim: ThreeD = None
    obstacles: ObstacleCount = 15
    density: Density = 0.08
    height: PositiveLength = 3.5
    min_spacing: PositiveLength = None
    clearance: NonNegativeLength = 0.2
    max_tries: Tries = 10000
    vehicles: VehicleNames = ("firefly",)
    end_state: EndState = None

    def resolved(self) -> RandomObstaclesParams:
        return dataclasses.replace(self, min_spacing=self.min_spacing or round(
            default_spacing(self.vehicles), 6))


@generates(RandomObstaclesParams)
def random_obstacles(count: int = 12, obstacles: int = 15, seed: int = 0, *,
                     density: float = 0.08, height: float = 3.5,
                     min_spacing: float | None = None, clearance: float = 0.2,
                     max_tries: int = 10000, vehicles: Sequence[str] = ("firefly",),
                     end_state: str = "free", validate: bool = True) -> Scenario:
    """Random robots among random obstacles (module doc)."""
    count = _check_count(count)
    seed = check_seed(seed)
    ends = _end_flags(end_state)
    if not 0.0 < density < 1.0:
        raise ScenarioError(f"density: must lie in (0, 1), got {density}", key="density")
    rng = np.random.default_rng(seed)
    names = cycle_vehicles(vehicles, count)
    spacing = default_spacing(names) if min_spacing is None else _check_pos(
        min_spacing, "min_spacing")
    rmax = max(ROBOTS[v].radius for v in set(names))
    if height <= 2.0 * (rmax + clearance) or height < 2.0:
        raise ScenarioError(f"height: {height} m leaves no room for a robot (radius {rmax} m) "
                            f"{clearance} m from the floor and the ceiling, nor for the "
                            f"floating spheres (1 m from each); raise height or lower "
                            f"clearance", key="height")
    kinds = rng.choice(["cylinder", "box", "sphere"], size=obstacles, p=[0.5, 0.3, 0.2])
    sizes = rng.uniform(0.25, 0.6, size=(obstacles, 3))
    foot = np.where(kinds == "box", 4 * sizes[:, 0] * sizes[:, 1], math.pi * sizes[:, 0] ** 2)
    # the arena: obstacles' footprints cover `density` of its floor (and room for robots)
    side = max(math.sqrt(foot.sum() / density) if obstacles else 0.0,
               2.0 * spacing * math.ceil(math.sqrt(count)) + 2.0)
    half = side / 2
    obs = []
    for kd, s in zip(kinds, sizes, strict=True):
        xy = rng.uniform(-half + 0.5, half - 0.5, 2)
        if kd == "cylinder":
            obs.append(dict(kind="cylinder", center=[*xy, height / 2], radius=s[0],
                            half_height=height / 2))
        elif kd == "box":
            hz = rng.uniform(0.5, height / 2)
            obs.append(dict(kind="box", center=[*xy, hz], half_extents=[s[0], s[1], hz]))
        else:
            obs.append(dict(kind="sphere", center=[*xy, rng.uniform(1.0, height - 1.0)],
                            radius=s[0]))
    world = _world([-half, -half, 0.0], [half, half, height], obs)
    lo = np.array([-half, -half, 0.0]) + rmax + clearance
    hi = np.array([half, half, height]) - rmax - clearance
    if not np.all(lo < hi):  # no room for a robot's centre between the arena's walls
        key = "clearance"
        raise ScenarioError(f"random_obstacles: no room for a robot (radius {rmax} m) "
                            f"{clearance} m from the arena's faces (side {side:.3g} m, "
                            f"height {height} m); raise height or lower clearance", key=key)

    def draw(placed, avoid_near=None):
        for _ in range(max_tries):
            p = rng.uniform(lo, hi)
            if point_problems(world, p, rmax + clearance):
                continue
            if placed and np.min(np.linalg.norm(np.array(placed) - p, axis=1)) < spacing:
                continue
            if avoid_near is not None and np.linalg.norm(p - avoid_near) < half:
                continue
            return p
        raise ScenarioError(f"random_obstacles could not place robot {len(placed) + 1} of "
                            f"{count} after {max_tries} tries; lower count, obstacles or "
                            f"density", key="max_tries")

    start, goal = [], []
    for _ in range(count):
        start.append(draw(start))
    for i in range(count):
        goal.append(draw(goal, start[i]))
    return make_scenario("random_obstacles", names, np.array(start), np.array(goal), **ends,
                         world=world, validate=validate)


# ---------------------------------------------------------------------- crossing_traffic
@pydantic_dataclass(frozen=True, config=_PARAMS_CONFIG)
class CrossingTrafficParams(GeneratorParams):
    """``kind = "crossing_traffic"`` (:func:`crossing_traffic`)."""

    kind: ClassVar[str] = "crossing_traffic"
    count: Count = 8
    dim: ThreeD = None
    length: PositiveLength = 14.0
    width: PositiveLength = 4.0
    height: PositiveLength = 2.5
    people: ObstacleCount = 6
    person_radius: PositiveLength = 0.3
    person_height: PositiveLength = 1.8
    speed_min: Speed = 0.5
    speed_max: Speed = 1.0
    start_window: Window = 6.0
    approach: NonNegativeLength = 1.0
    known_path: Annotated[bool, Strict()] = False
    jitter: NonNegativeLength = 0.05
    vehicles: VehicleNames = ("firefly",)
    end_state: EndState = None


@generates(CrossingTrafficParams)
def crossing_traffic(count: int = 8, seed: int = 0, *, length: float = 14.0,
                     width: float = 4.0, height: float = 2.5, people: int = 6,
                     person_radius: float = 0.3, person_height: float = 1.8,
                     speed_min: float = 0.5, speed_max: float = 1.0,
                     start_window: float = 6.0, approach: float = 1.0,
                     known_path: bool = False,
                     jitter: float = 0.05, vehicles: Sequence[str] = ("firefly",),
                     end_state: str = "free", validate: bool = True) -> Scenario:
    """Robots fly along a corridor that people cross (module doc)."""
    count = _check_count(count)
    seed = check_seed(seed)
    ends = _end_flags(end_state)
    length = _check_pos(length, "length")
    width = _check_pos(width, "width")
    height = _check_pos(height, "height")
    if speed_max < speed_min:
        raise ScenarioError(f"speed_max: {speed_max} m/s is below speed_min = {speed_min} m/s",
                            key="speed_max")
    rng = np.random.default_rng(seed)
    names = cycle_vehicles(vehicles, count)
    # the robots: two rows (heights) of ceil(count / 2) across the corridor
    cols = math.ceil(count / 2)
    j = np.arange(count)
    y = ((j % cols) - (cols - 1) / 2) * (width / cols)
    z = np.where(j < cols, 0.32, 0.68) * height
    x0 = -length / 2 + min(1.0, length / 4)
    start = np.stack([np.full(count, x0), y, z], 1) + _jitter(rng, count, jitter)
    goal = np.stack([np.full(count, -x0), y, z], 1) + _jitter(rng, count, jitter)
    # the people: from ``approach`` outside one side wall (so that they are seen walking
    # before they enter) straight across to as far outside the other
    off = width / 2 + person_radius + _check_pos(approach, "approach", strict=False)
    xs = rng.uniform(-0.35, 0.35, people) * length
    side = rng.choice([-1.0, 1.0], people)
    t0 = rng.uniform(0.0, start_window, people)
    speed = rng.uniform(speed_min, speed_max, people)
    zc = person_height / 2
    obstacles = [dict(kind="cylinder", radius=person_radius, half_height=zc,
                      known_path=known_path,
                      path=[{"t": float(t0[k]), "p": [float(xs[k]), float(side[k] * off), zc]},
                            {"t": float(t0[k] + 2 * off / speed[k]),
                             "p": [float(xs[k]), float(-side[k] * off), zc]}])
                 for k in range(people)]
    world = _world([-length / 2, -width / 2, 0.0], [length / 2, width / 2, height], obstacles)
    return make_scenario("crossing_traffic", names, start, goal, **ends, world=world,
                         validate=validate)
