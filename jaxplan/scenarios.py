"""Scenarios: the :class:`Scenario` fleet task, the paper's four simulations, the four
benchmark generators with their parameter models, and the registry (their config keys:
docs/DESIGN.md, "Config (TOML)").

A generator's ``[scenario]`` keys are declared once, by the parameter model next to it
(:class:`AntipodalSphereParams`, :class:`RandomBoxParams`, :class:`GridSwapParams`,
:class:`StackedParams`, field types from jaxplan/fields.py): jaxplan/config.py validates a
config's ``[scenario]`` table with it, and the generator's defaults are the model's.

Everything here is host-side NumPy (float64), deterministic for a seed: every random
choice draws from ``numpy.random.default_rng(seed)``.  Units are SI (m, m/s, m/s^2,
m/s^3).  A :class:`Scenario` holds ``M`` robots in ``N`` = 2 or 3 dimensions with ``W``
waypoints each; the fleet moves to waypoint ``w + 1`` when ALL robots have reached
waypoint ``w`` (the paper's multi-transition protocol).  Starts are rest states
(v = a = 0).

The paper (Krishnan et al.) gives no coordinates for its four simulations; the ones
below are our choice, inside a ~8 m x 8 m x 4 m arena, every start and goal at
z >= 1 m, goals at least r_i + r_j + 0.2 m apart, and every transit at least 3 m long
(a single rest-to-rest quintic under a_max = 4 m/s^2, j_max = 12 m/s^3 needs about
2.5 m to reach 2 m/s; a free end needs less), so that the 2 m/s top speed is reached.
A small seeded jitter (``PAPER_JITTER`` m, uniform in a ball) is added to every paper
start and goal, so that seeds differ and exact symmetries are broken.

``paper:six_neos``
    six Neo 11s at random (seeded) starts and goals in the box x, y in [-3, 3] m,
    z in [1, 3] m; starts and goals at least 1.2 m apart, each transit >= 3 m;
    rest start, free end.
``paper:eight_fireflys_stacked``
    eight Fireflys in two stacks of four at x = -3 m, y = -0.4 / +0.4 m,
    z = 1.2, 1.7, 2.2, 2.7 m (vertical neighbours 0.5 m apart, closer than the 0.63 m
    safety distance); goals on a 4 x 2 grid at x = +3 m, y = -2.25, -0.75, 0.75, 2.25 m,
    z = 1.5, 2.5 m; free end.  Transits ~6 m.
``paper:eight_mixed_transitions``
    five Fireflys and three Neos (F N F N F N F F) on eight slots of a ring of radius
    3 m about (0, 0) (slot k at 45 k degrees); robot k starts in slot k, then visits
    slots k+4 (rest end), k+2, k+6, k (free ends), alternating altitude 1.5 / 2.5 m
    per transition (start 1.5 m).  Transits 4.4 - 6.1 m.
``paper:ten_mixed_rest``
    five Fireflys and five Neos (alternating) on a ring of radius 3.5 m, z = 1.7 m
    (even k) / 2.3 m (odd k), each flying rest-to-rest to the antipodal slot at the same
    altitude (~7 m transits, all crossing near the centre).
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar, NamedTuple

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
    one_of,
    string,
)
from jaxplan.vehicles import VEHICLES

__all__ = [
    "Scenario",
    "ScenarioError",
    "ScenarioSpec",
    "Problem",
    "SCENARIOS",
    "PAPER_SCENARIOS",
    "GENERATORS",
    "GENERATOR_PARAMS",
    "PLACEMENTS",
    "default_spacing",
    "GeneratorParams",
    "AnyGeneratorParams",
    "AntipodalSphereParams",
    "RandomBoxParams",
    "GridSwapParams",
    "StackedParams",
    "END_STATES",
    "MAX_ROBOTS",
    "SAFETY_MARGIN",
    "PAPER_JITTER",
    "make_scenario",
    "scenario_problems",
    "validate_scenario",
    "antipodal_sphere",
    "random_box",
    "grid_swap",
    "stacked",
    "paper_six_neos",
    "paper_eight_fireflys_stacked",
    "paper_eight_mixed_transitions",
    "paper_ten_mixed_rest",
    "build",
]

SAFETY_MARGIN = 0.2        # m, added to r_i + r_j by generators that choose spacings
PAPER_JITTER = 0.02        # m, seeded jitter of every paper start and goal


class ScenarioError(ValueError):
    """A scenario cannot be built or is invalid.

    ``key`` names the generator argument (or config key under ``[scenario]``) at fault,
    or is None when the problem is the scenario as a whole.
    """

    def __init__(self, message: str, key: str | None = None):
        super().__init__(message)
        self.key = key


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.array(a)  # own copy
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class Scenario:
    """A fleet's task: M robots in N = 2 or 3 dimensions, W waypoints each.

    Attributes (arrays are float64 or bool, read-only):
        name: scenario name.
        vehicles: (M,) vehicle names (keys of ``jaxplan.vehicles.VEHICLES``).
        start: (M, N) start positions, m (rest: v = a = 0).
        waypoints: (M, W, N) goals in order, m; shorter lists padded by repeating the last.
        rest: (M, W) True = rest end state (v = a = 0) at that waypoint, False = free end.
        goal_velocity: (M, W, N) m/s, zeros unless ``has_goal_velocity``.
        has_goal_velocity: (M, W) True = free end with the given end velocity.
        radius: (M,) collision radius, m.
        v_max, a_max, j_max: (M,) planner limits, m/s, m/s^2, m/s^3.

    Equality is identity (arrays); compare fields with numpy.
    """

    name: str
    vehicles: tuple[str, ...]
    start: np.ndarray
    waypoints: np.ndarray
    rest: np.ndarray
    goal_velocity: np.ndarray
    has_goal_velocity: np.ndarray
    radius: np.ndarray
    v_max: np.ndarray
    a_max: np.ndarray
    j_max: np.ndarray

    @property
    def num_robots(self) -> int:
        """M."""
        return int(self.start.shape[0])

    @property
    def dim(self) -> int:
        """N, the number of spatial dimensions."""
        return int(self.start.shape[1])

    @property
    def num_waypoints(self) -> int:
        """W."""
        return int(self.waypoints.shape[1])

    @property
    def goal(self) -> np.ndarray:
        """(M, N) final goals, m."""
        return self.waypoints[:, -1]

    @property
    def safety_distance(self) -> np.ndarray:
        """(M, M) rho_ij = r_i + r_j, m."""
        return self.radius[:, None] + self.radius[None, :]

    def with_limits(self, v_max=None, a_max=None, j_max=None) -> Scenario:
        """A copy with the given limits (scalars or (M,) arrays) replacing the current ones."""
        M = self.num_robots
        new = {}
        for key, val in (("v_max", v_max), ("a_max", a_max), ("j_max", j_max)):
            if val is not None:
                new[key] = _readonly(np.broadcast_to(np.asarray(val, np.float64), (M,)))
        return Scenario(**{**self.__dict__, **new})

    def with_name(self, name: str) -> Scenario:
        """A copy with another name."""
        return Scenario(**{**self.__dict__, "name": name})


class Problem(NamedTuple):
    """One violated scenario invariant (see :func:`scenario_problems`).

    kind: "coincident_start" | "goal_spacing" | "ground"; robot / other: robot indices
    (other is None for "ground"); waypoint: index or None (a start); message: a sentence.
    """

    kind: str
    robot: int
    other: int | None
    waypoint: int | None
    message: str


def _cycle(vehicles: Sequence[str] | str, count: int) -> tuple[str, ...]:
    if isinstance(vehicles, str):
        vehicles = (vehicles,)
    vehicles = tuple(vehicles)
    if not vehicles:
        raise ScenarioError("vehicles: give at least one vehicle name", key="vehicles")
    for v in vehicles:
        if v not in VEHICLES:
            raise ScenarioError(
                f"vehicles: unknown vehicle {v!r}; choose one of {', '.join(sorted(VEHICLES))}",
                key="vehicles",
            )
    return tuple(vehicles[i % len(vehicles)] for i in range(count))


def _pad(items: Sequence) -> list:
    """Pad per-robot lists to a common length by repeating each list's last entry."""
    W = max(len(x) for x in items)
    return [list(x) + [x[-1]] * (W - len(x)) for x in items]


def make_scenario(
    name: str,
    vehicles: Sequence[str],
    start,
    waypoints,
    rest=False,
    goal_velocity=None,
    *,
    v_max=None,
    a_max=None,
    j_max=None,
    validate: bool = True,
) -> Scenario:
    """Assemble (and by default validate) a :class:`Scenario`.

    Args:
        name: scenario name.
        vehicles: (M,) vehicle names.
        start: (M, N) start positions, m.
        waypoints: (M, N) one goal each, (M, W, N), or a length-M sequence of per-robot
            (W_i, N) goal lists (shorter lists are padded by repeating the last goal).
        rest: a bool for all, (M,) per robot, (M, W), or per-robot sequences of W_i bools.
        goal_velocity: None, or per robot a length-W_i sequence of (N,) velocities or
            None (no end velocity at that waypoint), or an (M, W, N) array (all given).
        v_max, a_max, j_max: scalar or (M,) limit overrides; default per vehicle.
        validate: run :func:`validate_scenario` (raises ScenarioError).
    """
    vehicles = tuple(str(v) for v in vehicles)
    M = len(vehicles)
    if M == 0:
        raise ScenarioError("the fleet is empty")
    for v in vehicles:
        if v not in VEHICLES:
            raise ScenarioError(
                f"unknown vehicle {v!r}; choose one of {', '.join(sorted(VEHICLES))}")
    start = np.asarray(start, dtype=np.float64)
    if start.ndim != 2 or start.shape[0] != M or start.shape[1] not in (2, 3):
        raise ScenarioError(f"start: expected shape ({M}, 2 or 3), got {start.shape}")
    wp, lengths = _waypoint_array(waypoints, M, start.shape[1])
    rest_arr = _rest_array(rest, lengths)
    gv, has = _goal_velocity_arrays(goal_velocity, rest_arr, wp.shape[2])
    limits = {key: _limit_array(val, key, vehicles)
              for key, val in (("v_max", v_max), ("a_max", a_max), ("j_max", j_max))}
    sc = Scenario(
        name=str(name),
        vehicles=vehicles,
        start=_readonly(start),
        waypoints=_readonly(wp),
        rest=_readonly(rest_arr),
        goal_velocity=_readonly(gv),
        has_goal_velocity=_readonly(has),
        radius=_readonly(np.array([VEHICLES[v].radius for v in vehicles], dtype=np.float64)),
        **{k: _readonly(v) for k, v in limits.items()},
    )
    if validate:
        validate_scenario(sc)
    return sc


def _waypoint_array(waypoints, M: int, N: int) -> tuple[np.ndarray, list[int]]:
    """(M, W, N) goals, shorter lists padded with their last goal; and each robot's W_i."""
    if isinstance(waypoints, np.ndarray) and waypoints.ndim == 2:
        waypoints = waypoints[:, None, :]
    if len(waypoints) != M:
        raise ScenarioError(f"waypoints: expected {M} robots, got {len(waypoints)}")
    wp_lists = []
    for i, w in enumerate(waypoints):
        w = np.asarray(w, dtype=np.float64)
        if w.ndim == 1:
            w = w[None]
        if w.ndim != 2 or w.shape[0] < 1 or w.shape[1] != N:
            raise ScenarioError(f"waypoints: robot {i}: expected shape (W, {N}), got {w.shape}")
        wp_lists.append(list(w))
    lengths = [len(w) for w in wp_lists]
    return np.array(_pad(wp_lists), dtype=np.float64).reshape(M, max(lengths), N), lengths


def _rest_array(rest, lengths: list[int]) -> np.ndarray:
    """(M, W) rest flags from a bool, per-robot flags or per-robot per-waypoint flags."""
    M, W = len(lengths), max(lengths)
    if isinstance(rest, (bool, np.bool_, int, np.integer)):
        rest_lists = [[bool(rest)] * n for n in lengths]
    else:
        rest_lists = []
        for i, r in enumerate(rest):
            r = np.atleast_1d(np.asarray(r, dtype=bool))
            if r.shape == (1,) and lengths[i] > 1:
                r = np.repeat(r, lengths[i])
            if r.ndim != 1 or len(r) not in (lengths[i], W):
                raise ScenarioError(f"rest: robot {i}: expected {lengths[i]} flags, got {r.shape}")
            rest_lists.append(list(r))
        if len(rest_lists) != M:
            raise ScenarioError(f"rest: expected {M} robots, got {len(rest_lists)}")
    return np.array(_pad(rest_lists), dtype=bool).reshape(M, W)


def _goal_velocity_arrays(goal_velocity, rest: np.ndarray,
                          N: int) -> tuple[np.ndarray, np.ndarray]:
    """(M, W, N) end velocities and (M, W) has-one flags; none at a rest end."""
    M, W = rest.shape
    gv = np.zeros((M, W, N))
    has = np.zeros((M, W), dtype=bool)
    if goal_velocity is not None:
        if isinstance(goal_velocity, np.ndarray) and goal_velocity.ndim == 2:
            goal_velocity = goal_velocity[:, None, :]
        if len(goal_velocity) != M:
            raise ScenarioError(f"goal_velocity: expected {M} robots, got {len(goal_velocity)}")
        for i, per in enumerate(goal_velocity):
            if per is None:
                continue
            if len(per) > W:
                raise ScenarioError(f"goal_velocity: robot {i}: more entries than waypoints")
            entries = list(per) + [per[-1]] * (W - len(per)) if len(per) else []
            for w, v in enumerate(entries):
                if v is None:
                    continue
                v = np.asarray(v, dtype=np.float64)
                if v.shape != (N,):
                    raise ScenarioError(f"goal_velocity: robot {i}: expected ({N},), got {v.shape}")
                gv[i, w] = v
                has[i, w] = True
    if np.any(has & rest & np.any(gv != 0.0, axis=-1)):
        raise ScenarioError(
            "goal_velocity: a rest end state has v = 0; drop the velocity or the rest")
    has &= ~rest
    gv[~has] = 0.0
    return gv, has


def _limit_array(value, key: str, vehicles: tuple[str, ...]) -> np.ndarray:
    """(M,) limit ``key``: the override (scalar or (M,)) or each vehicle's own."""
    if value is None:
        return np.array([getattr(VEHICLES[v], key) for v in vehicles], dtype=np.float64)
    return np.broadcast_to(np.asarray(value, np.float64), (len(vehicles),))


def scenario_problems(sc: Scenario, max_problems: int = 10,
                      label: Callable[[int], str] | None = None) -> list[Problem]:
    """List violated invariants, at most ``max_problems`` (first found first).

    Checks: values finite; radii and limits positive; no two starts exactly equal
    (closer than rho_ij is allowed: the paper's stacked start); for each waypoint index,
    no two goals closer than rho_ij = r_i + r_j; for N = 3, no start or goal below
    z = radius (inside the ground).  ``label(i)`` names robot i in messages
    (default "robot i").
    """
    lab = label or (lambda i: f"robot {i}")
    out: list[Problem] = []
    M, N = sc.start.shape
    for arr_name, arr in (("start", sc.start), ("waypoints", sc.waypoints),
                          ("goal_velocity", sc.goal_velocity)):
        if not np.all(np.isfinite(arr)):
            i = int(np.argwhere(~np.isfinite(arr))[0][0])
            out.append(Problem("non_finite", i, None, None, f"{lab(i)}: {arr_name} is not finite"))
    for arr_name in ("radius", "v_max", "a_max", "j_max"):
        arr = getattr(sc, arr_name)
        bad = ~(np.isfinite(arr) & (arr > 0))
        if np.any(bad):
            i = int(np.argmax(bad))
            out.append(Problem("limit", i, None, None,
                               f"{lab(i)}: {arr_name} must be positive and finite, got {arr[i]}"))
    if out:
        return out[:max_problems]
    # Coincident starts.
    _, inv, counts = np.unique(sc.start, axis=0, return_inverse=True, return_counts=True)
    inv = np.asarray(inv).reshape(-1)
    for g in np.flatnonzero(counts > 1):
        i, j = (int(x) for x in np.flatnonzero(inv == g)[:2])
        out.append(Problem("coincident_start", j, i, None,
                           f"{lab(i)} and {lab(j)} start at the same point {_fmt(sc.start[i])}"))
    if len(out) >= max_problems:
        return out[:max_problems]
    # Goal spacing per waypoint index.
    rho = sc.safety_distance
    iu, ju = np.triu_indices(M, k=1)
    for w in range(sc.num_waypoints):
        g = sc.waypoints[:, w]
        d = np.linalg.norm(g[iu] - g[ju], axis=-1)
        for k in np.flatnonzero(d < rho[iu, ju]):
            i, j = int(iu[k]), int(ju[k])
            out.append(Problem(
                "goal_spacing", j, i, w,
                f"{lab(i)} and {lab(j)} have goals (waypoint {w}) {d[k]:.3g} m apart, closer "
                f"than their safety distance r_i + r_j = {rho[i, j]:.3g} m"))
            if len(out) >= max_problems:
                return out
    # Ground.
    if N == 3:
        for i in range(M):
            r = sc.radius[i]
            if sc.start[i, 2] < r:
                out.append(Problem("ground", i, None, None,
                                   f"{lab(i)}: start z = {sc.start[i, 2]:.3g} m is inside the "
                                   f"ground (below its radius {r:.3g} m)"))
            for w in range(sc.num_waypoints):
                if sc.waypoints[i, w, 2] < r:
                    out.append(Problem("ground", i, None, w,
                                       f"{lab(i)}: goal (waypoint {w}) z = "
                                       f"{sc.waypoints[i, w, 2]:.3g} m is inside the ground "
                                       f"(below its radius {r:.3g} m)"))
                    break
    return out[:max_problems]


def validate_scenario(sc: Scenario) -> Scenario:
    """Raise :class:`ScenarioError` with the first problem of :func:`scenario_problems`."""
    probs = scenario_problems(sc, max_problems=1)
    if probs:
        raise ScenarioError(f"{sc.name}: {probs[0].message}")
    return sc


def _fmt(x) -> str:
    return "[" + ", ".join(f"{float(v):.4g}" for v in np.ravel(x)) + "]"


# ----------------------------------------------------------------------------- helpers


def _check_seed(seed) -> int:
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


def _check_end(end_state) -> bool:
    if end_state not in END_STATES:
        raise ScenarioError(f"end_state: expected 'free' or 'rest', got {end_state!r}",
                            key="end_state")
    return end_state == "rest"


def _ball(rng: np.random.Generator, n: int, dim: int, r: float) -> np.ndarray:
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
    return 2.0 * max(VEHICLES[v].radius for v in set(vehicles))


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
# Each generator's [scenario] keys are declared once, by the parameter model above it:
# the config (jaxplan/config.py) validates a [scenario] table with that model, and the
# generator's own defaults are the model's.

_PARAMS_CONFIG = ConfigDict(extra="forbid")
PLACEMENTS = ("even", "random")


class GeneratorParams:
    """What the generators' parameter models share.

    A model's fields are its generator's ``[scenario]`` keys, in the order the resolved
    config writes them.  A default of None is resolved from the other keys by
    :meth:`resolved` (``dim`` and ``end_state`` by the config: the N of the config's
    vectors, ``planner.end_state``).
    """

    kind: ClassVar[str]

    @classmethod
    def keys(cls) -> tuple[str, ...]:
        """The ``[scenario]`` keys (besides ``kind``), in declaration order."""
        return tuple(f.name for f in dataclasses.fields(cls))

    def as_dict(self) -> dict[str, Any]:
        """The keys and their values, in declaration order."""
        return {k: getattr(self, k) for k in self.keys()}

    def resolved(self) -> GeneratorParams:
        """A copy with every None default filled in (needs ``dim`` set)."""
        return self

    def build(self, seed: int, validate: bool = True) -> Scenario:
        """The generator's scenario for these parameters (a key the generator does not
        take, random_box's dim, is left out: its box gives N)."""
        generator = GENERATORS[self.kind]
        taken = inspect.signature(generator).parameters
        args = {k: v for k, v in self.as_dict().items() if k in taken}
        return generator(seed=seed, validate=validate, **args)


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
        end_state: "free" | "rest" at the goal.
        validate: check the result with validate_scenario (raises ScenarioError).
    Returns: a one-waypoint Scenario named "antipodal_sphere".
    """
    count = _check_count(count)
    radius = _check_pos(radius, "radius")
    seed = _check_seed(seed)
    dim = _check_dim(dim)
    rest = _check_end(end_state)
    perturbation = _check_pos(perturbation, "perturbation", strict=False)
    names = _cycle(vehicles, count)
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
    goal = c - radius * unit + _ball(rng, count, dim, perturbation)
    return make_scenario("antipodal_sphere", names, start, goal, rest, validate=validate)


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
        end_state: "free" | "rest" at the goal.
    """
    count = _check_count(count)
    seed = _check_seed(seed)
    rest = _check_end(end_state)
    names = _cycle(vehicles, count)
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
    return make_scenario("random_box", names, start, goal, rest, validate=validate)


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
    seed = _check_seed(seed)
    dim = _check_dim(dim)
    rest = _check_end(end_state)
    jitter = _check_pos(jitter, "jitter", strict=False)
    count = rows * cols
    names = _cycle(vehicles, count)
    c = _grid_center(dim) if center is None else _check_vec(center, dim, "center")
    rr, cc = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    off = np.zeros((count, dim))
    off[:, 0] = (cc.ravel() - (cols - 1) / 2.0) * spacing
    off[:, 1] = (rr.ravel() - (rows - 1) / 2.0) * spacing
    rng = np.random.default_rng(seed)
    start = c + off + _ball(rng, count, dim, jitter)
    goal = c - off + _ball(rng, count, dim, jitter)
    return make_scenario("grid_swap", names, start, goal, rest, validate=validate)


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
    seed = _check_seed(seed)
    dim = _check_dim(dim)
    rest = _check_end(end_state)
    jitter = _check_pos(jitter, "jitter", strict=False)
    if jitter >= spacing / 2:
        raise ScenarioError(f"jitter: must be below half the stack spacing ({spacing / 2:.3g} m)"
                            f", got {jitter}", key="jitter")
    names = _cycle(vehicles, count)
    b = _stack_base(dim) if base is None else _check_vec(base, dim, "base")
    rc = _row_center(dim) if row_center is None else _check_vec(row_center, dim, "row_center")
    k = np.arange(count, dtype=np.float64)
    start = np.tile(b, (count, 1))
    start[:, -1] += k * spacing
    goal = np.tile(rc, (count, 1))
    goal[:, 1] += (k - (count - 1) / 2.0) * row_spacing
    rng = np.random.default_rng(seed)
    start = start + _ball(rng, count, dim, jitter)
    goal = goal + _ball(rng, count, dim, jitter)
    return make_scenario("stacked", names, start, goal, rest, validate=validate)


# ---------------------------------------------------------------------- paper scenarios

# paper:eight_fireflys_stacked: two stacks of four, vertical neighbours 0.7 m apart (11%
# over 2 r = 0.63 m; with jitter >= 0.66 m).  The paper starts some robots "closer than
# their safety distance"; with rho_ij = r_i + r_j that would be a collision at t = 0 by
# the run directory's definition, so the stacks are as tight as a collision-free start
# allows: every start pair is within 1.15 rho_ij of touching.
STACKED_START = np.array(
    [[-3.0, y, z] for y in (-0.4, 0.4) for z in (1.1, 1.8, 2.5, 3.2)], dtype=np.float64)
# robot (stack s, level l) -> y = (-2.25, -0.75) + 1.5 * 2 s ..., z = 1.5 + (l // 2)
STACKED_GOAL = np.array(
    [[3.0, (-2.25, -0.75, 0.75, 2.25)[2 * s + (lvl % 2)], (1.5, 2.5)[lvl // 2]]
     for s in (0, 1) for lvl in range(4)], dtype=np.float64)

MIXED_VEHICLES = ("firefly", "neo11", "firefly", "neo11", "firefly", "neo11", "firefly",
                  "firefly")
MIXED_RING_RADIUS = 3.0
MIXED_SLOTS = (4, 2, 6, 0)        # waypoint w: robot k goes to slot (k + MIXED_SLOTS[w]) % 8
MIXED_ALTITUDES = (2.5, 1.5, 2.5, 1.5)   # waypoint altitudes; starts at 1.5 m
MIXED_REST = (True, False, False, False)

TEN_RING_RADIUS = 3.5
TEN_ALTITUDES = (1.7, 2.3)        # even / odd robot index


def _ring(slot, n, radius, z):
    ang = 2.0 * math.pi * np.asarray(slot, dtype=np.float64) / n
    return np.stack([radius * np.cos(ang), radius * np.sin(ang),
                     np.broadcast_to(np.asarray(z, np.float64), ang.shape)], axis=-1)


def paper_six_neos(seed: int = 0) -> Scenario:
    """Paper simulation 1: six Neo 11s spawned at random; rest start, free end.

    random_box in x, y in [-3, 3] m, z in [1, 3] m; starts and goals >= 1.2 m apart
    (r_i + r_j = 0.86 m), each goal >= 3 m from its start.
    """
    sc = random_box(6, box=[[-3.0, -3.0, 1.0], [3.0, 3.0, 3.0]], min_spacing=1.2,
                    vehicles=("neo11",), seed=seed, min_travel=3.0, end_state="free")
    return sc.with_name("six_neos")


def paper_eight_fireflys_stacked(seed: int = 0) -> Scenario:
    """Paper simulation 2: eight Fireflys from two tight stacks to a 4 x 2 grid; free end.

    Starts STACKED_START (vertical neighbours 0.7 m apart, within 11% of 2 r = 0.63 m),
    goals STACKED_GOAL; seeded jitter of PAPER_JITTER m.
    """
    rng = np.random.default_rng(_check_seed(seed))
    start = STACKED_START + _ball(rng, 8, 3, PAPER_JITTER)
    goal = STACKED_GOAL + _ball(rng, 8, 3, PAPER_JITTER)
    return make_scenario("eight_fireflys_stacked", ("firefly",) * 8, start, goal, False)


def paper_eight_mixed_transitions(seed: int = 0) -> Scenario:
    """Paper simulation 3: five Fireflys and three Neos through four transitions.

    Ring of radius MIXED_RING_RADIUS with 8 slots; robot k starts at slot k, z = 1.5 m,
    then visits slots k + MIXED_SLOTS[w] at MIXED_ALTITUDES[w]; the first transition
    ends at rest, the other three are free-end.  Seeded jitter of PAPER_JITTER m.
    """
    rng = np.random.default_rng(_check_seed(seed))
    k = np.arange(8)
    start = _ring(k, 8, MIXED_RING_RADIUS, 1.5) + _ball(rng, 8, 3, PAPER_JITTER)
    wps = np.stack([_ring((k + s) % 8, 8, MIXED_RING_RADIUS, z)
                    for s, z in zip(MIXED_SLOTS, MIXED_ALTITUDES, strict=True)], axis=1)
    wps = wps + _ball(rng, 8 * 4, 3, PAPER_JITTER).reshape(8, 4, 3)
    rest = np.tile(np.array(MIXED_REST), (8, 1))
    return make_scenario("eight_mixed_transitions", MIXED_VEHICLES, start, wps, rest)


def paper_ten_mixed_rest(seed: int = 0) -> Scenario:
    """Paper simulation 4: five Fireflys and five Neos (alternating), rest-to-rest.

    Ring of radius TEN_RING_RADIUS, 10 slots, z = TEN_ALTITUDES[k % 2]; robot k flies to
    the antipodal slot k + 5 at its own altitude.  Seeded jitter of PAPER_JITTER m.
    """
    rng = np.random.default_rng(_check_seed(seed))
    k = np.arange(10)
    z = np.array(TEN_ALTITUDES)[k % 2]
    start = _ring(k, 10, TEN_RING_RADIUS, z) + _ball(rng, 10, 3, PAPER_JITTER)
    goal = _ring(k + 5, 10, TEN_RING_RADIUS, z) + _ball(rng, 10, 3, PAPER_JITTER)
    return make_scenario("ten_mixed_rest", ("firefly", "neo11") * 5, start, goal, True)


# ----------------------------------------------------------------------------- registry


@dataclass(frozen=True)
class ScenarioSpec:
    """A registered scenario: ``build(seed=0, **params) -> Scenario``.

    name: registry key (also the config's ``[scenario] kind``); description: one line;
    paper: True for the paper's four (no parameters besides the seed).
    """

    name: str
    description: str
    build: Callable[..., Scenario]
    paper: bool = False


PAPER_SCENARIOS: dict[str, Callable[..., Scenario]] = {
    "paper:six_neos": paper_six_neos,
    "paper:eight_fireflys_stacked": paper_eight_fireflys_stacked,
    "paper:eight_mixed_transitions": paper_eight_mixed_transitions,
    "paper:ten_mixed_rest": paper_ten_mixed_rest,
}

GENERATORS: dict[str, Callable[..., Scenario]] = {
    "antipodal_sphere": antipodal_sphere,
    "random_box": random_box,
    "grid_swap": grid_swap,
    "stacked": stacked,
}

GENERATOR_PARAMS: dict[str, type[GeneratorParams]] = {
    p.kind: p for p in (AntipodalSphereParams, RandomBoxParams, GridSwapParams, StackedParams)
}
AnyGeneratorParams = AntipodalSphereParams | RandomBoxParams | GridSwapParams | StackedParams

_MIXED = ("firefly", "neo11")

SCENARIOS: dict[str, ScenarioSpec] = {
    "paper:six_neos": ScenarioSpec(
        "paper:six_neos", "six Neos at random starts and goals, rest start, free end",
        paper_six_neos, True),
    "paper:eight_fireflys_stacked": ScenarioSpec(
        "paper:eight_fireflys_stacked",
        "eight Fireflys from two tight stacks (closer than r_i + r_j) to a grid, free end",
        paper_eight_fireflys_stacked, True),
    "paper:eight_mixed_transitions": ScenarioSpec(
        "paper:eight_mixed_transitions",
        "five Fireflys + three Neos, four ring transitions (rest, then three free-end)",
        paper_eight_mixed_transitions, True),
    "paper:ten_mixed_rest": ScenarioSpec(
        "paper:ten_mixed_rest",
        "five Fireflys + five Neos swap across a 3.5 m ring, rest-to-rest",
        paper_ten_mixed_rest, True),
    "antipodal_sphere": ScenarioSpec(
        "antipodal_sphere",
        "robots on a sphere fly to the antipodal point (default 10 mixed, 4 m radius)",
        functools.partial(antipodal_sphere, count=10, radius=4.0, vehicles=_MIXED)),
    "random_box": ScenarioSpec(
        "random_box", "random starts and goals in a box with minimum spacing (default 20)",
        functools.partial(random_box, count=20, box=[[-4.0, -4.0, 1.0], [4.0, 4.0, 4.0]],
                          vehicles=_MIXED)),
    "grid_swap": ScenarioSpec(
        "grid_swap", "a grid swaps with its mirror through the centre (default 3 x 4)",
        functools.partial(grid_swap, rows=3, cols=4)),
    "stacked": ScenarioSpec(
        "stacked", "a vertical stack flies to a spread-out row (default 6)",
        functools.partial(stacked, count=6)),
}


def build(name: str, seed: int = 0, **params: Any) -> Scenario:
    """Build a registered scenario by name (see SCENARIOS), e.g. build("paper:six_neos", 3)."""
    try:
        spec = SCENARIOS[name]
    except KeyError:
        raise ScenarioError(f"unknown scenario {name!r}; choose one of "
                            f"{', '.join(SCENARIOS)}") from None
    return spec.build(seed=seed, **params)
