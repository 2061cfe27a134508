"""The :class:`Scenario` fleet task (starts, waypoints, end states, vehicles and limits
of M robots in N = 2 or 3 dimensions), how one is made and validated, and the
per-robot NLP problems of its first replan (:func:`scenario_problems`)."""


from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from jaxplan.vehicles import ROBOTS
from jaxplan.world import World, point_problems

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
        vehicles: (M,) vehicle names (keys of ``jaxplan.vehicles.ROBOTS``).
        start: (M, N) start positions, m (rest: v = a = 0).
        waypoints: (M, W, N) goals in order, m; shorter lists padded by repeating the last.
        rest: (M, W) True = rest end state (v = a = 0) at that waypoint, False = free end.
        auto: (M, W) True = "auto" end: a free end while the robot is far from that
            waypoint, a rest end near it (:func:`jaxplan.rollout.current_goals`); never
            True where ``rest`` or ``has_goal_velocity`` is.  Default: none.
        goal_velocity: (M, W, N) m/s, zeros unless ``has_goal_velocity``.
        has_goal_velocity: (M, W) True = free end with the given end velocity.
        radius: (M,) collision radius, m.
        v_max, a_max, j_max: (M,) planner limits, m/s, m/s^2, m/s^3.
        world: the :class:`jaxplan.world.World` (workspace and obstacles); default
            :meth:`jaxplan.world.World.default` (in 3-D the ground z >= 0).
        cooperative: (M,) bool, False = a robot that runs no planner: it flies its own
            waypoints in straight lines within its limits, stopping at each
            (:func:`jaxplan.run_setup.own_legs`), and neither predicts nor avoids the
            others (they see it as any robot).  Default: every robot cooperates.

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
    world: World | None = None
    auto: np.ndarray | None = None
    cooperative: np.ndarray | None = None

    def __post_init__(self):
        if self.auto is None:
            object.__setattr__(self, "auto", _readonly(np.zeros(np.shape(self.rest), bool)))
        M = int(self.start.shape[0])
        if self.cooperative is None:
            object.__setattr__(self, "cooperative", _readonly(np.ones(M, bool)))
        else:
            coop = np.asarray(self.cooperative, bool).reshape(-1)
            if coop.shape != (M,):
                raise ScenarioError(f"cooperative: expected {M} flags, got {coop.shape[0]}")
            if not np.any(coop):
                raise ScenarioError("cooperative: every robot is non-cooperative; at least one "
                                    "must run the planner")
            object.__setattr__(self, "cooperative", _readonly(coop))
        if self.world is None:
            object.__setattr__(self, "world", World.default(int(self.start.shape[1])))
        elif self.world.dim != self.start.shape[1]:
            raise ScenarioError(f"the world is {self.world.dim}-D, the robots "
                                f"{self.start.shape[1]}-D")

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

    def with_world(self, world: World) -> Scenario:
        """A copy in another world (not validated: see :func:`validate_scenario`)."""
        return Scenario(**{**self.__dict__, "world": world})


class Problem(NamedTuple):
    """One violated scenario invariant (see :func:`scenario_problems`).

    kind: "coincident_start" | "goal_spacing" | "ground" | "workspace" | "obstacle";
    robot / other: robot indices (other is None for the world's kinds); waypoint: index
    or None (a start); message: a sentence.
    """

    kind: str
    robot: int
    other: int | None
    waypoint: int | None
    message: str


def cycle_vehicles(vehicles: Sequence[str] | str, count: int) -> tuple[str, ...]:
    """``count`` vehicle names, cycling through ``vehicles`` (checked against the table)."""
    if isinstance(vehicles, str):
        vehicles = (vehicles,)
    vehicles = tuple(vehicles)
    if not vehicles:
        raise ScenarioError("vehicles: give at least one vehicle name", key="vehicles")
    for v in vehicles:
        if v not in ROBOTS:
            raise ScenarioError(
                f"vehicles: unknown vehicle {v!r}; choose one of {', '.join(sorted(ROBOTS))}",
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
    auto=False,
    v_max=None,
    a_max=None,
    j_max=None,
    world: World | None = None,
    validate: bool = True,
    cooperative=None,
) -> Scenario:
    """Assemble (and by default validate) a :class:`Scenario`.

    Args:
        name: scenario name.
        vehicles: (M,) vehicle names.
        start: (M, N) start positions, m.
        waypoints: (M, N) one goal each, (M, W, N), or a length-M sequence of per-robot
            (W_i, N) goal lists (shorter lists are padded by repeating the last goal).
        rest: a bool for all, (M,) per robot, (M, W), or per-robot sequences of W_i bools.
        auto: the waypoints with an "auto" end (:class:`Scenario`), given as ``rest`` is;
            where ``rest`` or a goal velocity is given too, those win.
        goal_velocity: None, or per robot a length-W_i sequence of (N,) velocities or
            None (no end velocity at that waypoint), or an (M, W, N) array (all given).
        v_max, a_max, j_max: scalar or (M,) limit overrides; default per vehicle.
        world: workspace and obstacles (default: :meth:`jaxplan.world.World.default`).
        validate: run :func:`validate_scenario` (raises ScenarioError).
        cooperative: None (every robot) or (M,) bools (:class:`Scenario`).
    """
    vehicles = tuple(str(v) for v in vehicles)
    M = len(vehicles)
    if M == 0:
        raise ScenarioError("the fleet is empty")
    for v in vehicles:
        if v not in ROBOTS:
            raise ScenarioError(
                f"unknown vehicle {v!r}; choose one of {', '.join(sorted(ROBOTS))}")
    start = np.asarray(start, dtype=np.float64)
    if start.ndim != 2 or start.shape[0] != M or start.shape[1] not in (2, 3):
        raise ScenarioError(f"start: expected shape ({M}, 2 or 3), got {start.shape}")
    wp, lengths = _waypoint_array(waypoints, M, start.shape[1])
    rest_arr = _rest_array(rest, lengths)
    gv, has = _goal_velocity_arrays(goal_velocity, rest_arr, wp.shape[2])
    auto_arr = _rest_array(auto, lengths, "auto") & ~rest_arr & ~has
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
        radius=_readonly(np.array([ROBOTS[v].radius for v in vehicles], dtype=np.float64)),
        **{k: _readonly(v) for k, v in limits.items()},
        world=world,
        auto=_readonly(auto_arr),
        cooperative=None if cooperative is None else np.asarray(cooperative, bool),
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


def _rest_array(rest, lengths: list[int], key: str = "rest") -> np.ndarray:
    """(M, W) flags (``key``: which) from a bool, per-robot flags or per-robot
    per-waypoint flags."""
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
                raise ScenarioError(f"{key}: robot {i}: expected {lengths[i]} flags, "
                                    f"got {r.shape}")
            rest_lists.append(list(r))
        if len(rest_lists) != M:
            raise ScenarioError(f"{key}: expected {M} robots, got {len(rest_lists)}")
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
        return np.array([getattr(ROBOTS[v], key) for v in vehicles], dtype=np.float64)
    return np.broadcast_to(np.asarray(value, np.float64), (len(vehicles),))


def scenario_problems(sc: Scenario, max_problems: int = 10,
                      label: Callable[[int], str] | None = None) -> list[Problem]:
    """List violated invariants, at most ``max_problems`` (first found first).

    Checks: values finite; radii and limits positive; no two starts exactly equal
    (closer than rho_ij is allowed: the paper's stacked start); for each waypoint index,
    no two goals closer than rho_ij = r_i + r_j; every start and goal inside the
    world's workspace and clear of its obstacles by the robot's radius (in 3-D by default:
    not below z = radius, inside the ground).  ``label(i)`` names robot i in messages
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
                           f"{lab(i)} and {lab(j)} start at the same point "
                           f"{format_vector(sc.start[i])}"))
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
    # The world: starts and goals clear of the obstacles and inside the workspace by
    # the robot's radius.
    for i in range(M):
        pts = [(None, sc.start[i])] + [(w, sc.waypoints[i, w]) for w in range(sc.num_waypoints)]
        for w, p in pts:
            probs = point_problems(sc.world, p, sc.radius[i], start=w is None)
            if probs:
                where = "start" if w is None else f"goal (waypoint {w})"
                out.append(_world_problem(sc, i, w, where, p, *probs[0], lab))
                if len(out) >= max_problems:
                    return out
                if w is not None:  # one goal per robot
                    break
    return out[:max_problems]


def _world_problem(sc, i, w, where, p, what, k, gap, lab) -> Problem:
    r = sc.radius[i]
    if what == "obstacle":
        return Problem("obstacle", i, None, w,
                       f"{lab(i)}: {where} {format_vector(p)} is inside "
                       f"{sc.world.describe(k)} (its body of radius {r:.3g} m overlaps it by "
                       f"{-gap:.3g} m)")
    N = sc.dim
    ground = N == 3 and np.isfinite(sc.world.lo[2]) and p[2] - sc.world.lo[2] < r
    if ground and sc.world.lo[2] == 0.0:
        return Problem("ground", i, None, w,
                       f"{lab(i)}: {where} z = {p[2]:.3g} m is inside the ground (below its "
                       f"radius {r:.3g} m)")
    return Problem("workspace", i, None, w,
                   f"{lab(i)}: {where} {format_vector(p)} is outside the workspace "
                   f"[{format_vector(sc.world.lo)}, {format_vector(sc.world.hi)}] by the "
                   f"robot's radius {r:.3g} m")


def validate_scenario(sc: Scenario) -> Scenario:
    """Raise :class:`ScenarioError` with the first problem of :func:`scenario_problems`."""
    probs = scenario_problems(sc, max_problems=1)
    if probs:
        raise ScenarioError(f"{sc.name}: {probs[0].message}")
    return sc


def format_vector(x) -> str:
    """A vector for an error message: [1.5, 0, 2.25] (4 significant digits)."""
    return "[" + ", ".join(f"{float(v):.4g}" for v in np.ravel(x)) + "]"
