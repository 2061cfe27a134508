"""The benchmark generators (antipodal sphere, random box, grid swap, stacked, antipodal
circle), each with the parameter model that declares its ``[scenario]`` keys once:
jaxplan/config/ validates a config's ``[scenario]`` table with it, and the generator's
defaults are the model's.  Deterministic for a seed (``numpy.random.default_rng(seed)``)."""


from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import ClassVar

import numpy as np
from pydantic import ConfigDict
from pydantic.dataclasses import dataclass as pydantic_dataclass

from jaxplan.fields import (
    END_STATES,
    MAX_ROBOTS,
    Corners,
    Count,
    Dimension,
    EndState,
    NonNegativeLength,
    Position,
    PositiveLength,
    Tries,
    VehicleNames,
    number,
    one_of,
    string,
)
from jaxplan.scenarios.params import GeneratorParams, generates
from jaxplan.scenarios.scenario import (
    SAFETY_MARGIN,
    Scenario,
    ScenarioError,
    cycle_vehicles,
    make_scenario,
)
from jaxplan.vehicles import ROBOTS

# ----------------------------------------------------------------------------- helpers


def check_seed(seed) -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ScenarioError(f"seed: expected a non-negative integer, got {seed!r}", key="seed")
    return int(seed)


def _check_count(count, key="count") -> int:
    if isinstance(count, bool) or not isinstance(count, (int, np.integer)) or count < 1:
        raise ScenarioError(f"{key}: expected a positive integer, got {count!r}", key=key)
    if count > MAX_ROBOTS:
        raise ScenarioError(f"{key}: at most {MAX_ROBOTS} robots, got {count}", key=key)
    return int(count)


def _check_pos(x, key, lo=0.0, strict=True) -> float:
    x = float(x)
    if not math.isfinite(x) or (x <= lo if strict else x < lo):
        raise ScenarioError(f"{key}: expected a {'positive' if strict else 'non-negative'} "
                            f"number, got {x!r}", key=key)
    return x


def _check_dim(dim) -> int:
    if dim not in (2, 3):
        raise ScenarioError(f"dim: expected 2 or 3, got {dim!r}", key="dim")
    return int(dim)


def _check_vec(x, dim, key) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if a.shape != (dim,) or not np.all(np.isfinite(a)):
        raise ScenarioError(f"{key}: expected {dim} finite numbers, got {x!r}", key=key)
    return a


def _end_flags(end_state) -> dict[str, bool]:
    """make_scenario's ``rest`` and ``auto`` for one end state of the whole fleet."""
    if end_state not in END_STATES:
        raise ScenarioError(f"end_state: expected one of {', '.join(map(repr, END_STATES))}, "
                            f"got {end_state!r}", key="end_state")
    return {"rest": end_state == "rest", "auto": end_state == "auto"}


def random_in_ball(rng: np.random.Generator, n: int, dim: int, r: float) -> np.ndarray:
    """(n, dim) points uniform in a ball of radius r (always draws, so streams stay aligned)."""
    d = rng.normal(size=(n, dim))
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)
    return d * (r * rng.uniform(size=(n, 1)) ** (1.0 / dim))


def _random_rotation(rng: np.random.Generator, dim: int) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(dim, dim)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


def _max_rho(vehicles: Sequence[str]) -> float:
    return 2.0 * max(ROBOTS[v].radius for v in set(vehicles))


def _place(rng, count, sample, spacing, max_tries, what, ok=None, chunk=64):
    """Sequential rejection sampling: count points, pairwise >= spacing apart.

    sample(n) -> (n, dim) candidates; ok(i, cand) -> (n,) bool extra acceptance test.
    Raises ScenarioError after max_tries candidates for one point.
    """
    pts: list[np.ndarray] = []
    for i in range(count):
        tried = 0
        placed = np.array(pts).reshape(len(pts), -1) if pts else None
        while True:
            n = min(chunk, max_tries - tried)
            if n <= 0:
                raise ScenarioError(
                    f"random_box could not place the {what} of robot {i + 1} of {count} with "
                    f"spacing {spacing:.3g} m after {max_tries} tries; enlarge the box or lower "
                    f"the spacing, min_travel or count", key="min_spacing")
            cand = sample(n)
            tried += n
            good = np.ones(n, dtype=bool)
            if placed is not None:
                d = np.linalg.norm(cand[:, None, :] - placed[None, :, :], axis=-1)
                good &= np.all(d >= spacing, axis=1)
            if ok is not None:
                good &= ok(i, cand)
            if np.any(good):
                pts.append(cand[int(np.argmax(good))])
                break
    return np.array(pts)



# -------------------------------------------------------------------------- generators
#
# Each generator's [scenario] keys are declared once, by the parameter model above it
# (jaxplan/scenarios/params.py): the config (jaxplan/config/) validates a [scenario]
# table with that model, the generator's own defaults are the model's, and the
# generator declares the model its own (@generates).

_PARAMS_CONFIG = ConfigDict(extra="forbid")
PLACEMENTS = ("even", "random")


def default_spacing(vehicles: Sequence[str]) -> float:
    """max(r_i + r_j) + SAFETY_MARGIN over ``vehicles``, m: the generators' default
    minimum spacing of starts and goals."""
    return _max_rho(vehicles) + SAFETY_MARGIN


def _resolved_spacing(vehicles: Sequence[str]) -> float:
    """:func:`default_spacing` as the resolved config writes it (6 decimals)."""
    return round(default_spacing(vehicles), 6)


def _floats(a) -> tuple:
    """A NumPy vector or (2, N) array as (nested) tuples of floats."""
    a = np.asarray(a, dtype=np.float64)
    return tuple(float(x) for x in a) if a.ndim == 1 else tuple(_floats(r) for r in a)


def _antipodal_center(radius: float, dim: int) -> np.ndarray:
    return np.zeros(2) if dim == 2 else np.array([0.0, 0.0, radius + 1.0])


@pydantic_dataclass(frozen=True, config=_PARAMS_CONFIG)
class AntipodalSphereParams(GeneratorParams):
    """``kind = "antipodal_sphere"`` (:func:`antipodal_sphere`)."""

    kind: ClassVar[str] = "antipodal_sphere"
    count: Count
    radius: PositiveLength = 4.0
    dim: Dimension = None
    center: Position = None
    placement: string(one_of(PLACEMENTS)) = "even"
    perturbation: NonNegativeLength = 0.05
    min_spacing: PositiveLength = None
    max_tries: Tries = 1000
    vehicles: VehicleNames = ("firefly",)
    end_state: EndState = None

    def resolved(self) -> AntipodalSphereParams:
        return dataclasses.replace(
            self,
            center=self.center or _floats(_antipodal_center(self.radius, self.dim)),
            min_spacing=self.min_spacing or _resolved_spacing(self.vehicles))


@generates(AntipodalSphereParams)
def antipodal_sphere(
    count: int,
    radius: float = AntipodalSphereParams.radius,
    vehicles: Sequence[str] = AntipodalSphereParams.vehicles,
    seed: int = 0,
    *,
    center=None,
    dim: int = 3,
    placement: str = AntipodalSphereParams.placement,
    perturbation: float = AntipodalSphereParams.perturbation,
    min_spacing: float | None = None,
    max_tries: int = AntipodalSphereParams.max_tries,
    end_state: str = "free",
    validate: bool = True,
) -> Scenario:
    """Robots on a sphere (circle for dim = 2) fly to the antipodal point.

    Args:
        count: M robots.
        radius: sphere radius, m.
        vehicles: names cycled over the robots.
        seed: numpy Generator seed.
        center: (dim,) sphere centre, m; default (0, 0, radius + 1) in 3-D (lowest point
            1 m above ground), (0, 0) in 2-D.
        placement: "even" (Fibonacci lattice / equal angles, randomly rotated by the
            seed) or "random" (uniform with starts >= min_spacing apart).
        perturbation: each goal is 2 c - start plus a seeded offset uniform in a ball of
            this radius, m (breaks exact symmetry; seeds differ).
        min_spacing: start spacing for "random", m; default max(r_i + r_j) + SAFETY_MARGIN.
        max_tries: candidate budget per robot for "random".
        end_state: "free" | "rest" | "auto" at the goal.
        validate: check the result with validate_scenario (raises ScenarioError).
    Returns: a one-waypoint Scenario named "antipodal_sphere".
    """
    count = _check_count(count)
    radius = _check_pos(radius, "radius")
    seed = check_seed(seed)
    dim = _check_dim(dim)
    ends = _end_flags(end_state)
    perturbation = _check_pos(perturbation, "perturbation", strict=False)
    names = cycle_vehicles(vehicles, count)
    c = _antipodal_center(radius, dim) if center is None else _check_vec(center, dim, "center")
    rng = np.random.default_rng(seed)
    if placement == "even":
        if dim == 3:
            k = np.arange(count) + 0.5
            z = 1.0 - 2.0 * k / count
            phi = k * math.pi * (3.0 - math.sqrt(5.0))
            rxy = np.sqrt(np.maximum(0.0, 1.0 - z**2))
            unit = np.stack([rxy * np.cos(phi), rxy * np.sin(phi), z], axis=1)
            unit = unit @ _random_rotation(rng, 3).T
        else:
            ang = 2.0 * math.pi * np.arange(count) / count + rng.uniform(0.0, 2.0 * math.pi)
            unit = np.stack([np.cos(ang), np.sin(ang)], axis=1)
    elif placement == "random":
        sp = default_spacing(names) if min_spacing is None else _check_pos(
            min_spacing, "min_spacing")

        def sample(n):
            d = rng.normal(size=(n, dim))
            return radius * d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)

        unit = _place(rng, count, sample, sp, max_tries, "start") / radius
    else:
        raise ScenarioError(f"placement: expected 'even' or 'random', got {placement!r}",
                            key="placement")
    start = c + radius * unit
    goal = c - radius * unit + random_in_ball(rng, count, dim, perturbation)
    return make_scenario("antipodal_sphere", names, start, goal, **ends, validate=validate)


def _default_box(dim: int) -> np.ndarray:
    return np.array([[-3.0, -3.0, 1.0], [3.0, 3.0, 3.0]]) if dim == 3 else np.array(
        [[-3.0, -3.0], [3.0, 3.0]])


@pydantic_dataclass(frozen=True, config=_PARAMS_CONFIG)
class RandomBoxParams(GeneratorParams):
    """``kind = "random_box"`` (:func:`random_box`; N follows the box)."""

    kind: ClassVar[str] = "random_box"
    count: Count
    dim: Dimension = None
    box: Corners = None
    min_spacing: PositiveLength = None
    goal_spacing: PositiveLength = None
    min_travel: NonNegativeLength = 0.0
    max_tries: Tries = 1000
    vehicles: VehicleNames = ("firefly",)
    end_state: EndState = None

    def resolved(self) -> RandomBoxParams:
        spacing = self.min_spacing or _resolved_spacing(self.vehicles)
        return dataclasses.replace(self, box=self.box or _floats(_default_box(self.dim)),
                                   min_spacing=spacing, goal_spacing=self.goal_spacing or spacing)


@generates(RandomBoxParams)
def random_box(
    count: int,
    box=None,
    min_spacing: float | None = None,
    vehicles: Sequence[str] = RandomBoxParams.vehicles,
    seed: int = 0,
    *,
    goal_spacing: float | None = None,
    min_travel: float = RandomBoxParams.min_travel,
    max_tries: int = RandomBoxParams.max_tries,
    end_state: str = "free",
    validate: bool = True,
) -> Scenario:
    """Random starts and goals in a box (the online-DMPC benchmark protocol).

    Args:
        count: M robots.
        box: (2, N) lower and upper corners, m; default x, y in [-3, 3], z in [1, 3]
            (N = 3).  N follows the box.
        min_spacing: minimum start-start distance, m; default max(r_i + r_j) + SAFETY_MARGIN.
        vehicles: names cycled over the robots.
        seed: numpy Generator seed.
        goal_spacing: minimum goal-goal distance, m; default min_spacing.
        min_travel: minimum distance from each robot's start to its goal, m.
        max_tries: candidate budget per point; a ScenarioError says which robot failed.
        end_state: "free" | "rest" | "auto" at the goal.
    """
    count = _check_count(count)
    seed = check_seed(seed)
    ends = _end_flags(end_state)
    names = cycle_vehicles(vehicles, count)
    b = _default_box(3) if box is None else np.asarray(box, dtype=np.float64)
    if b.ndim != 2 or b.shape[0] != 2 or b.shape[1] not in (2, 3) or not np.all(np.isfinite(b)):
        raise ScenarioError(f"box: expected [[lower corner], [upper corner]] of 2 or 3 numbers "
                            f"each, got {box!r}", key="box")
    if np.any(b[1] < b[0]):
        raise ScenarioError("box: the upper corner must not be below the lower corner", key="box")
    dim = b.shape[1]
    sp = default_spacing(names) if min_spacing is None else _check_pos(
        min_spacing, "min_spacing")
    gsp = sp if goal_spacing is None else _check_pos(goal_spacing, "goal_spacing")
    travel = _check_pos(min_travel, "min_travel", strict=False)
    if isinstance(max_tries, bool) or not isinstance(max_tries, (int, np.integer)) or max_tries < 1:
        raise ScenarioError(f"max_tries: expected a positive integer, got {max_tries!r}",
                            key="max_tries")
    rng = np.random.default_rng(seed)

    def sample(n):
        return b[0] + (b[1] - b[0]) * rng.uniform(size=(n, dim))

    start = _place(rng, count, sample, sp, int(max_tries), "start")

    def far(i, cand):
        return np.linalg.norm(cand - start[i], axis=1) >= travel

    goal = _place(rng, count, sample, gsp, int(max_tries), "goal", ok=far)
    return make_scenario("random_box", names, start, goal, **ends, validate=validate)


def _grid_center(dim: int) -> np.ndarray:
    return np.array([0.0, 0.0, 2.0]) if dim == 3 else np.zeros(2)


@pydantic_dataclass(frozen=True, config=_PARAMS_CONFIG)
class GridSwapParams(GeneratorParams):
    """``kind = "grid_swap"`` (:func:`grid_swap`)."""

    kind: ClassVar[str] = "grid_swap"
    rows: Count
    cols: Count
    spacing: PositiveLength = 1.5
    dim: Dimension = None
    center: Position = None
    jitter: NonNegativeLength = 0.05
    vehicles: VehicleNames = ("firefly",)
    end_state: EndState = None

    def resolved(self) -> GridSwapParams:
        return dataclasses.replace(self, center=self.center or _floats(_grid_center(self.dim)))


@generates(GridSwapParams)
def grid_swap(
    rows: int,
    cols: int,
    spacing: float = GridSwapParams.spacing,
    vehicles: Sequence[str] = GridSwapParams.vehicles,
    seed: int = 0,
    *,
    center=None,
    dim: int = 3,
    jitter: float = GridSwapParams.jitter,
    end_state: str = "free",
    validate: bool = True,
) -> Scenario:
    """Robots on a rows x cols grid swap with the mirrored grid.

    The grid lies in the x-y plane (at the centre's altitude in 3-D), ``spacing`` m
    between neighbours, centred on ``center`` (default (0, 0, 2) in 3-D, (0, 0) in 2-D).
    Robot (r, c) (index r * cols + c) flies to the place of robot (rows-1-r, cols-1-c):
    the grid mirrored through its centre, so every path crosses the centre.  rows and
    cols must not both be odd (the centre robot would not move).  Starts and goals get a
    seeded jitter uniform in a ball of ``jitter`` m.
    """
    rows = _check_count(rows, "rows")
    cols = _check_count(cols, "cols")
    _check_count(rows * cols, "rows")
    if rows % 2 == 1 and cols % 2 == 1:
        raise ScenarioError(f"rows and cols ({rows} x {cols}) are both odd, so the centre "
                            f"robot would swap with itself; make one of them even", key="rows")
    spacing = _check_pos(spacing, "spacing")
    seed = check_seed(seed)
    dim = _check_dim(dim)
    ends = _end_flags(end_state)
    jitter = _check_pos(jitter, "jitter", strict=False)
    count = rows * cols
    names = cycle_vehicles(vehicles, count)
    c = _grid_center(dim) if center is None else _check_vec(center, dim, "center")
    rr, cc = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    off = np.zeros((count, dim))
    off[:, 0] = (cc.ravel() - (cols - 1) / 2.0) * spacing
    off[:, 1] = (rr.ravel() - (rows - 1) / 2.0) * spacing
    rng = np.random.default_rng(seed)
    start = c + off + random_in_ball(rng, count, dim, jitter)
    goal = c - off + random_in_ball(rng, count, dim, jitter)
    return make_scenario("grid_swap", names, start, goal, **ends, validate=validate)


def _stack_base(dim: int) -> np.ndarray:
    return np.array([-3.0, 0.0, 1.2]) if dim == 3 else np.array([-3.0, 0.0])


def _row_center(dim: int) -> np.ndarray:
    return np.array([3.0, 0.0, 2.0]) if dim == 3 else np.array([3.0, 0.0])


@pydantic_dataclass(frozen=True, config=_PARAMS_CONFIG)
class StackedParams(GeneratorParams):
    """``kind = "stacked"`` (:func:`stacked`)."""

    kind: ClassVar[str] = "stacked"
    count: Count
    spacing: PositiveLength = 0.5
    dim: Dimension = None
    base: Position = None
    row_spacing: PositiveLength = 1.0
    row_center: Position = None
    jitter: NonNegativeLength = 0.02
    vehicles: VehicleNames = ("firefly",)
    end_state: EndState = None

    def resolved(self) -> StackedParams:
        return dataclasses.replace(self, base=self.base or _floats(_stack_base(self.dim)),
                                   row_center=self.row_center or _floats(_row_center(self.dim)))


@generates(StackedParams)
def stacked(
    count: int,
    spacing: float = StackedParams.spacing,
    vehicles: Sequence[str] = StackedParams.vehicles,
    seed: int = 0,
    *,
    base=None,
    row_spacing: float = StackedParams.row_spacing,
    row_center=None,
    dim: int = 3,
    jitter: float = StackedParams.jitter,
    end_state: str = "free",
    validate: bool = True,
) -> Scenario:
    """A vertical stack flying to a spread-out row.

    Robot k starts at ``base + k * spacing`` along the last axis (z in 3-D, y in 2-D);
    a spacing below r_i + r_j is allowed (a tightly packed start).  It flies to slot k of
    a row along the y axis centred on ``row_center``, ``row_spacing`` m apart.  Defaults:
    base (-3, 0, 1.2), row_center (3, 0, 2) in 3-D; (-3, 0), (3, 0) in 2-D.  Seeded
    jitter uniform in a ball of ``jitter`` m on starts and goals.
    """
    count = _check_count(count)
    spacing = _check_pos(spacing, "spacing")
    row_spacing = _check_pos(row_spacing, "row_spacing")
    seed = check_seed(seed)
    dim = _check_dim(dim)
    ends = _end_flags(end_state)
    jitter = _check_pos(jitter, "jitter", strict=False)
    if jitter >= spacing / 2:
        raise ScenarioError(f"jitter: must be below half the stack spacing ({spacing / 2:.3g} m)"
                            f", got {jitter}", key="jitter")
    names = cycle_vehicles(vehicles, count)
    b = _stack_base(dim) if base is None else _check_vec(base, dim, "base")
    rc = _row_center(dim) if row_center is None else _check_vec(row_center, dim, "row_center")
    k = np.arange(count, dtype=np.float64)
    start = np.tile(b, (count, 1))
    start[:, -1] += k * spacing
    goal = np.tile(rc, (count, 1))
    goal[:, 1] += (k - (count - 1) / 2.0) * row_spacing
    rng = np.random.default_rng(seed)
    start = start + random_in_ball(rng, count, dim, jitter)
    goal = goal + random_in_ball(rng, count, dim, jitter)
    return make_scenario("stacked", names, start, goal, **ends, validate=validate)


# ------------------------------------------------------------------- antipodal circle


def _circle_center(dim: int) -> np.ndarray:
    return np.zeros(2) if dim == 2 else np.array([0.0, 0.0, 2.0])


@pydantic_dataclass(frozen=True, config=_PARAMS_CONFIG)
class AntipodalCircleParams(GeneratorParams):
    """``kind = "antipodal_circle"`` (:func:`antipodal_circle`)."""

    kind: ClassVar[str] = "antipodal_circle"
    count: Count
    radius: PositiveLength = 4.0
    dim: Dimension = None
    center: Position = None
    angle_jitter_deg: number(ge=0.0, le=180.0) = 0.0
    perturbation: NonNegativeLength = 0.0
    vehicles: VehicleNames = ("firefly",)
    end_state: EndState = None

    def resolved(self) -> AntipodalCircleParams:
        return dataclasses.replace(
            self, center=self.center or _floats(_circle_center(self.dim)))


@generates(AntipodalCircleParams)
def antipodal_circle(
    count: int,
    radius: float = AntipodalCircleParams.radius,
    vehicles: Sequence[str] = AntipodalCircleParams.vehicles,
    seed: int = 0,
    *,
    center=None,
    dim: int = 2,
    angle_jitter_deg: float = AntipodalCircleParams.angle_jitter_deg,
    perturbation: float = AntipodalCircleParams.perturbation,
    end_state: str = "free",
    validate: bool = True,
) -> Scenario:
    """Robots on a circle swap to the antipodal point through its centre.

    The circle lies in the plane (dim = 2) or in the horizontal plane through ``center``
    (dim = 3: every robot starts at the same height).  Robot k sits at angle
    phi_0 + 2 pi k / count (phi_0 seeded), plus, with ``angle_jitter_deg`` > 0, a seeded
    offset uniform in +-angle_jitter_deg; its goal is the antipodal point, plus a seeded
    offset uniform in a ball of ``perturbation`` m.  With both 0 the swap is exactly
    symmetric: every straight path meets every other at the centre.

    Args:
        count: M robots.  radius: m.  vehicles: names cycled over the robots.
        seed: numpy Generator seed.  center: (dim,) m; default (0, 0) in 2-D,
            (0, 0, 2) in 3-D.  end_state: "free" | "rest" | "auto" at the goal.
    Returns: a one-waypoint Scenario named "antipodal_circle".
    """
    count = _check_count(count)
    radius = _check_pos(radius, "radius")
    seed = check_seed(seed)
    dim = _check_dim(dim)
    ends = _end_flags(end_state)
    jitter = _check_pos(angle_jitter_deg, "angle_jitter_deg", strict=False)
    perturbation = _check_pos(perturbation, "perturbation", strict=False)
    names = cycle_vehicles(vehicles, count)
    c = _circle_center(dim) if center is None else _check_vec(center, dim, "center")
    rng = np.random.default_rng(seed)
    ang = 2.0 * math.pi * np.arange(count) / count + rng.uniform(0.0, 2.0 * math.pi)
    ang = ang + np.deg2rad(jitter) * rng.uniform(-1.0, 1.0, size=count)
    unit = np.zeros((count, dim))
    unit[:, 0], unit[:, 1] = np.cos(ang), np.sin(ang)
    start = c + radius * unit
    goal = c - radius * unit + random_in_ball(rng, count, dim, perturbation)
    return make_scenario("antipodal_circle", names, start, goal, **ends, validate=validate)
