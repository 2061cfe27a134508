"""TOML configs -> frozen, validated dataclasses, every default resolved (DESIGN.md, Config).

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
               | "stacked", and the generator's keys (see GENERATOR_KEYS)
    [sweep]    q_obs, q_lim (lists or {log_min, log_max, num}, base-10 exponents),
               seeds (list or {start, num}), scenarios (registry names)
    [faults]   enabled, message_loss, latency_s, noise_sigma_m, frozen_robot, frozen_at_s,
               frozen_mode (jaxplan.faults; off by default)

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

Every error is a :class:`ConfigError` whose message is one line,
``<file>: <key>: <problem>``, raised before any computation.
"""

from __future__ import annotations

import difflib
import math
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

from jaxplan import scenarios as _sc
from jaxplan.scenarios import END_STATES, MAX_ROBOTS, Scenario, ScenarioError
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
DEFAULT_COLLISION = "barrier+constraint"  # the literal "paper" term cannot avoid (MATH.md 2)
DEFAULT_DEGREE = 5
DEFAULT_SEGMENTS = 2                     # rest ends need shape freedom (MATH.md 2); paper: 1
DEFAULT_END_STATE = "free"               # the paper's position-only end state
DEFAULT_MAX_ITERS = 50                   # solver iterations per replan (bounded loop)
DEFAULT_TOL = 1e-6                       # solver stationarity / feasibility tolerance
DEFAULT_N_SAMPLES = 32                   # collision samples / quadrature nodes per horizon
DEFAULT_SAFETY_MARGIN_M = 0.05           # m added to every radius when planning (not in metrics)
DEFAULT_MAX_NEIGHBORS = 0                # 0: every other robot is in each robot's NLP
DEFAULT_SOLVER_POOL = 0                  # 0: automatic (jaxplan.solver.default_pool)
DEFAULT_COAST_SAMPLES = 8                # constraint samples on a free end's coast after T
MAX_COAST_SAMPLES = 256

DEFAULT_BACKEND = "ideal"
DEFAULT_DURATION_S = 30.0
DEFAULT_PHYSICS_HZ = 500.0
DEFAULT_CONTROL_HZ = 250.0
DEFAULT_GOAL_TOLERANCE_M = 0.1
DEFAULT_GOAL_SPEED_TOLERANCE_MPS = 0.1   # residual speed allowed at a rest goal

COLLISION_MODES = ("paper", "barrier", "constraint", "barrier+constraint")
BACKENDS = ("ideal", "mjx")
MAX_DEGREE = 15
MAX_SEGMENTS = 64
MAX_SAMPLES = 4096
MAX_SWEEP_POINTS = 10000
MAX_SEED = 2**63 - 1
MAX_COORD = 1e6                          # m or m/s: larger coordinates are a typo, not a plan


class ConfigError(ValueError):
    """An invalid config: one line ``<file>: <key>: <problem>``."""


# ---------------------------------------------------------------------------------------
# Dataclasses
# ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
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
    (jaxplan.solver.solve_lanes); 0 = automatic (jaxplan.solver.default_pool): 2 on a
    CPU (12 for more than 32 robots with at most 16 others per NLP), all M elsewhere.
    Speed only: every NLP takes the same iterations whatever the pool (results equal to
    rounding, which a closed loop can amplify into slightly different runs).
    """

    replan_hz: float = DEFAULT_REPLAN_HZ
    q_dynm: float = DEFAULT_Q_DYNM
    q_obs: float = DEFAULT_Q_OBS
    q_lim: float = DEFAULT_Q_LIM
    k_t: float = DEFAULT_K_T
    k_p: float = DEFAULT_K_P
    collision: str = DEFAULT_COLLISION
    degree: int = DEFAULT_DEGREE
    segments: int = DEFAULT_SEGMENTS
    end_state: str = DEFAULT_END_STATE
    max_iters: int = DEFAULT_MAX_ITERS
    tol: float = DEFAULT_TOL
    n_samples: int = DEFAULT_N_SAMPLES
    safety_margin_m: float = DEFAULT_SAFETY_MARGIN_M
    max_neighbors: int = DEFAULT_MAX_NEIGHBORS
    coast_samples: int = DEFAULT_COAST_SAMPLES
    solver_pool: int = DEFAULT_SOLVER_POOL


@dataclass(frozen=True)
class LimitsConfig:
    """[limits]: m/s, m/s^2, m/s^3 overrides for every robot; None = per-vehicle default."""

    v_max: float | None = None
    a_max: float | None = None
    j_max: float | None = None


@dataclass(frozen=True)
class SimConfig:
    """[sim]: backend "ideal" | "mjx"; duration_s (s); physics_hz, control_hz (Hz,
    physics_hz / control_hz a whole number); goal_tolerance_m (m);
    goal_speed_tolerance_mps (m/s, residual speed allowed at a rest goal)."""

    backend: str = DEFAULT_BACKEND
    duration_s: float = DEFAULT_DURATION_S
    physics_hz: float = DEFAULT_PHYSICS_HZ
    control_hz: float = DEFAULT_CONTROL_HZ
    goal_tolerance_m: float = DEFAULT_GOAL_TOLERANCE_M
    goal_speed_tolerance_mps: float = DEFAULT_GOAL_SPEED_TOLERANCE_MPS


@dataclass(frozen=True)
class RobotConfig:
    """One [[robots]] entry, resolved.

    vehicle: name; start: (N,) m; waypoints: W goals of (N,) m; end_state: W of
    "free" | "rest"; goal_velocity: W entries, each (N,) m/s or None.
    """

    vehicle: str
    start: tuple[float, ...]
    waypoints: tuple[tuple[float, ...], ...]
    end_state: tuple[str, ...]
    goal_velocity: tuple[tuple[float, ...] | None, ...]


@dataclass(frozen=True)
class ScenarioConfig:
    """[scenario], resolved: kind and every generator parameter (defaults filled in).

    params: (key, value) pairs in GENERATOR_KEYS order; vectors are tuples.
    """

    kind: str
    params: tuple[tuple[str, Any], ...] = ()

    def as_dict(self) -> dict[str, Any]:
        return dict(self.params)

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


@dataclass(frozen=True)
class FaultsConfig:
    """[faults] (jaxplan.faults): all off by default; ``enabled`` switches the faulty
    channel on (a different compiled program)."""

    enabled: bool = False
    message_loss: float = 0.0  # probability per (observer, sender, period), in [0, 1)
    latency_s: float = 0.0  # s, rounded to whole replan periods
    noise_sigma_m: float = 0.0  # m per axis on every received position
    frozen_robot: int = -1  # index of the robot that stops responding; -1: none
    frozen_at_s: float = 0.0  # s
    frozen_mode: str = "silent"  # "silent" (stops sending) | "stale" (keeps sending)


@dataclass(frozen=True)
class Config:
    """A whole experiment, validated and resolved.  ``source`` is where it came from
    (not part of equality)."""

    name: str
    description: str
    seed: int
    planner: PlannerConfig
    limits: LimitsConfig
    sim: SimConfig
    robots: tuple[RobotConfig, ...]
    scenario: ScenarioConfig | None
    sweep: SweepConfig
    faults: FaultsConfig
    source: str = field(default="<string>", compare=False)

    @property
    def dim(self) -> int:
        """N, the number of spatial dimensions."""
        if self.scenario is not None:
            return self.scenario.dim
        return len(self.robots[0].start)


# ---------------------------------------------------------------------------------------
# Primitive checks
# ---------------------------------------------------------------------------------------


def _show(v: Any) -> str:
    try:
        s = repr(v)
    except Exception:  # noqa: BLE001 - a hostile __repr__ must not escape
        s = f"<{type(v).__name__}>"
    s = " ".join(s.split())
    return s if len(s) <= 60 else s[:57] + "..."


def _type_name(v: Any) -> str:
    return {bool: "a boolean", int: "an integer", float: "a number", str: "a string",
            list: "an array", dict: "a table"}.get(type(v), type(v).__name__)


class _Ctx:
    def __init__(self, source: str):
        self.source = source if source.isprintable() else _show(source)

    def err(self, key: str, msg: str) -> ConfigError:
        msg = " ".join(str(msg).split())
        key = key if key.isprintable() else _show(key)
        return ConfigError(f"{self.source}: {key}: {msg}" if key else f"{self.source}: {msg}")

    def table(self, v: Any, key: str) -> dict:
        if not isinstance(v, dict):
            raise self.err(key, f"expected a table, got {_show(v)}")
        for k in v:
            if not isinstance(k, str):
                raise self.err(key, f"expected string keys, got {_show(k)}")
        return v

    def keys(self, table: dict, allowed, prefix: str) -> None:
        allowed = list(allowed)
        for k in table:
            if k not in allowed:
                near = difflib.get_close_matches(k, allowed, n=1, cutoff=0.6)
                hint = f"; did you mean {near[0]!r}?" if near else \
                    f"; valid keys: {', '.join(allowed)}"
                shown = k if re.fullmatch(r"[A-Za-z0-9_-]+", k) else _show(k)
                raise self.err(_join(prefix, shown), f"unknown key{hint}")

    def number(self, v: Any, key: str, *, gt: float | None = None, ge: float | None = None,
               le: float | None = None) -> float:
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise self.err(key, f"expected a number, got {_show(v)}")
        try:
            x = float(v)
        except OverflowError:
            raise self.err(key, f"number out of range: {_show(v)}") from None
        if not math.isfinite(x):
            raise self.err(key, f"expected a finite number, got {_show(v)}")
        if gt is not None and not x > gt:
            raise self.err(key, f"must be > {gt:g}, got {_show(v)}")
        if ge is not None and not x >= ge:
            raise self.err(key, f"must be >= {ge:g}, got {_show(v)}")
        if le is not None and not x <= le:
            raise self.err(key, f"must be <= {le:g}, got {_show(v)}")
        return x

    def integer(self, v: Any, key: str, *, ge: int | None = None, le: int | None = None) -> int:
        if isinstance(v, bool) or not isinstance(v, int):
            raise self.err(key, f"expected an integer, got {_show(v)}")
        if ge is not None and v < ge:
            raise self.err(key, f"must be >= {ge}, got {_show(v)}")
        if le is not None and v > le:
            raise self.err(key, f"must be <= {le}, got {_show(v)}")
        return int(v)

    def string(self, v: Any, key: str, choices=None) -> str:
        if not isinstance(v, str):
            raise self.err(key, f"expected a string, got {_show(v)}")
        if choices is not None and v not in choices:
            near = difflib.get_close_matches(v, list(choices), n=1, cutoff=0.6)
            hint = f" (did you mean {near[0]!r}?)" if near else ""
            raise self.err(key, f"unknown value {_show(v)}{hint}; choose one of "
                                f"{', '.join(repr(c) for c in choices)}")
        return v

    def boolean(self, v: Any, key: str) -> bool:
        if not isinstance(v, bool):
            raise self.err(key, f"expected true or false, got {_show(v)}")
        return v

    def vector(self, v: Any, key: str, dim: int | None = None) -> tuple[float, ...]:
        """A position/velocity: 2 or 3 finite numbers (exactly dim when given)."""
        if not isinstance(v, (list, tuple)):
            raise self.err(key, f"expected an array of 2 or 3 numbers, got {_show(v)}")
        if dim is not None and len(v) != dim:
            raise self.err(key, f"expected {dim} coordinates (the config is {dim}-D; "
                                f"mixing 2-D and 3-D positions is not allowed), got {len(v)}")
        if len(v) not in (2, 3):
            raise self.err(key, f"expected 2 or 3 coordinates, got {len(v)}")
        return tuple(self.number(x, f"{key}[{i}]", ge=-MAX_COORD, le=MAX_COORD)
                     for i, x in enumerate(v))

    def vehicle(self, v: Any, key: str) -> str:
        return self.string(v, key, choices=tuple(VEHICLES))

    def name_list(self, v: Any, key: str, choices) -> tuple[str, ...]:
        if isinstance(v, str):
            v = [v]
        if not isinstance(v, (list, tuple)) or not v:
            raise self.err(key, f"expected a non-empty array of names, got {_show(v)}")
        return tuple(self.string(x, f"{key}[{i}]", choices) for i, x in enumerate(v))


def _join(prefix: str, key: str) -> str:
    return f"{prefix}.{key}" if prefix else key


# ---------------------------------------------------------------------------------------
# Sections
# ---------------------------------------------------------------------------------------

_TOP_KEYS = ("name", "description", "seed", "planner", "limits", "sim", "robots",
             "scenario", "sweep", "faults")


def _parse_planner(c: _Ctx, raw: Any) -> PlannerConfig:
    t = c.table(raw, "planner")
    c.keys(t, PlannerConfig.__dataclass_fields__, "planner")
    d = PlannerConfig()
    g = lambda k: t.get(k, getattr(d, k))  # noqa: E731
    return PlannerConfig(
        replan_hz=c.number(g("replan_hz"), "planner.replan_hz", gt=0),
        q_dynm=c.number(g("q_dynm"), "planner.q_dynm", ge=0),
        q_obs=c.number(g("q_obs"), "planner.q_obs", ge=0),
        q_lim=c.number(g("q_lim"), "planner.q_lim", ge=0),
        k_t=c.number(g("k_t"), "planner.k_t", ge=0),
        k_p=c.number(g("k_p"), "planner.k_p", gt=0),
        collision=c.string(g("collision"), "planner.collision", COLLISION_MODES),
        degree=c.integer(g("degree"), "planner.degree", ge=5, le=MAX_DEGREE),
        segments=c.integer(g("segments"), "planner.segments", ge=1, le=MAX_SEGMENTS),
        end_state=c.string(g("end_state"), "planner.end_state", END_STATES),
        max_iters=c.integer(g("max_iters"), "planner.max_iters", ge=1, le=1_000_000),
        tol=c.number(g("tol"), "planner.tol", gt=0),
        n_samples=c.integer(g("n_samples"), "planner.n_samples", ge=2, le=MAX_SAMPLES),
        safety_margin_m=c.number(g("safety_margin_m"), "planner.safety_margin_m", ge=0, le=10),
        max_neighbors=c.integer(g("max_neighbors"), "planner.max_neighbors", ge=0,
                                le=MAX_ROBOTS),
        coast_samples=c.integer(g("coast_samples"), "planner.coast_samples", ge=0,
                                le=MAX_COAST_SAMPLES),
        solver_pool=c.integer(g("solver_pool"), "planner.solver_pool", ge=0, le=MAX_ROBOTS),
    )


def _parse_limits(c: _Ctx, raw: Any) -> LimitsConfig:
    t = c.table(raw, "limits")
    c.keys(t, LimitsConfig.__dataclass_fields__, "limits")
    return LimitsConfig(**{k: (c.number(t[k], f"limits.{k}", gt=0) if k in t else None)
                           for k in ("v_max", "a_max", "j_max")})


def _parse_sim(c: _Ctx, raw: Any) -> SimConfig:
    t = c.table(raw, "sim")
    c.keys(t, SimConfig.__dataclass_fields__, "sim")
    d = SimConfig()
    g = lambda k: t.get(k, getattr(d, k))  # noqa: E731
    s = SimConfig(
        backend=c.string(g("backend"), "sim.backend", BACKENDS),
        duration_s=c.number(g("duration_s"), "sim.duration_s", gt=0),
        physics_hz=c.number(g("physics_hz"), "sim.physics_hz", gt=0),
        control_hz=c.number(g("control_hz"), "sim.control_hz", gt=0),
        goal_tolerance_m=c.number(g("goal_tolerance_m"), "sim.goal_tolerance_m", gt=0),
        goal_speed_tolerance_mps=c.number(g("goal_speed_tolerance_mps"),
                                          "sim.goal_speed_tolerance_mps", gt=0),
    )
    ratio = s.physics_hz / s.control_hz
    if ratio < 1.0 - 1e-9 or abs(ratio - round(ratio)) > 1e-9 * ratio:
        raise c.err("sim.control_hz", f"physics_hz / control_hz must be a whole number >= 1 "
                                      f"(the controller runs every k-th physics step), got "
                                      f"{s.physics_hz:g} / {s.control_hz:g}")
    return s


FAULT_KEYS = ("enabled", "message_loss", "latency_s", "noise_sigma_m", "frozen_robot",
              "frozen_at_s", "frozen_mode")


def _parse_faults(c: _Ctx, raw: Any) -> FaultsConfig:
    t = c.table(raw, "faults")
    c.keys(t, FAULT_KEYS, "faults")
    d = FaultsConfig()
    enabled = c.boolean(t.get("enabled", d.enabled), "faults.enabled")
    loss = c.number(t.get("message_loss", d.message_loss), "faults.message_loss", ge=0.0)
    if loss >= 1.0:
        raise c.err("faults.message_loss", f"must be < 1 (a probability), got {loss}")
    lat = c.number(t.get("latency_s", d.latency_s), "faults.latency_s", ge=0.0)
    if lat > 10.0:
        raise c.err("faults.latency_s", f"must be <= 10 s, got {lat}")
    noise = c.number(t.get("noise_sigma_m", d.noise_sigma_m), "faults.noise_sigma_m", ge=0.0)
    frozen = c.integer(t.get("frozen_robot", d.frozen_robot), "faults.frozen_robot", ge=-1)
    at = c.number(t.get("frozen_at_s", d.frozen_at_s), "faults.frozen_at_s", ge=0.0)
    mode = c.string(t.get("frozen_mode", d.frozen_mode), "faults.frozen_mode",
                    ("silent", "stale"))
    return FaultsConfig(enabled, loss, lat, noise, frozen, at, mode)


_ROBOT_KEYS = ("vehicle", "start", "goal", "waypoints", "goal_velocity", "end_state")


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


def _parse_robot(c: _Ctx, raw: Any, i: int, dim: int | None, default_end: str):
    p = f"robots[{i}]"
    t = c.table(raw, p)
    c.keys(t, _ROBOT_KEYS, p)
    if "vehicle" not in t:
        raise c.err(f"{p}.vehicle", f"missing; choose one of {', '.join(VEHICLES)}")
    vehicle = c.vehicle(t["vehicle"], f"{p}.vehicle")
    if "start" not in t:
        raise c.err(f"{p}.start", "missing; give the start position [x, y, z]")
    start = c.vector(t["start"], f"{p}.start", dim)
    dim = len(start)
    if ("goal" in t) == ("waypoints" in t):
        raise c.err(f"{p}.goal", "give exactly one of 'goal' (one position) or 'waypoints' "
                                 "(a list of positions)")
    if "goal" in t:
        wps = (c.vector(t["goal"], f"{p}.goal", dim),)
        goal_key = "goal"
    else:
        raw_w = t["waypoints"]
        if not isinstance(raw_w, (list, tuple)) or not raw_w:
            raise c.err(f"{p}.waypoints", f"expected a non-empty array of positions, got "
                                          f"{_show(raw_w)}")
        wps = tuple(c.vector(w, f"{p}.waypoints[{k}]", dim) for k, w in enumerate(raw_w))
        goal_key = "waypoints"
    W = len(wps)

    ends_raw = t.get("end_state", default_end)
    if isinstance(ends_raw, str):
        ends = (c.string(ends_raw, f"{p}.end_state", END_STATES),) * W
    elif isinstance(ends_raw, (list, tuple)):
        if len(ends_raw) != W:
            raise c.err(f"{p}.end_state", f"expected one entry per waypoint ({W}), got "
                                          f"{len(ends_raw)}")
        ends = tuple(c.string(e, f"{p}.end_state[{k}]", END_STATES)
                     for k, e in enumerate(ends_raw))
    else:
        raise c.err(f"{p}.end_state", f"expected 'free', 'rest' or a list of them, got "
                                      f"{_show(ends_raw)}")

    gv: list[tuple[float, ...] | None] = [None] * W
    if "goal_velocity" in t:
        g = t["goal_velocity"]
        key = f"{p}.goal_velocity"
        if not isinstance(g, (list, tuple)) or not g:
            raise c.err(key, f"expected [vx, vy, vz] or one entry per waypoint, got {_show(g)}")
        if all(isinstance(x, (list, tuple)) for x in g):
            if goal_key == "goal":
                raise c.err(key, f"expected one vector [vx, vy, vz], got {_show(g)}")
            if len(g) != W:
                raise c.err(key, f"expected one vector, or one entry per waypoint ({W}; [] for "
                                 f"none), got {len(g)} entries")
            for k, x in enumerate(g):
                gv[k] = None if len(x) == 0 else c.vector(x, f"{key}[{k}]", dim)
        else:
            gv[-1] = c.vector(g, key, dim)
        for k in range(W):
            if gv[k] is not None and ends[k] == "rest":
                if any(x != 0.0 for x in gv[k]):
                    raise c.err(key, f"waypoint {k} has end_state 'rest' (v = 0) but a non-zero "
                                     f"goal velocity; drop one of them")
                gv[k] = None
    return RobotConfig(vehicle, start, wps, ends, tuple(gv)), _RobotKeys(p, goal_key)


def _parse_robots(c: _Ctx, raw: Any, default_end: str, dim: int | None):
    if not isinstance(raw, (list, tuple)):
        raise c.err("robots", f"expected an array of tables [[robots]], got {_show(raw)}")
    if len(raw) > MAX_ROBOTS:
        raise c.err("robots", f"at most {MAX_ROBOTS} robots, got {len(raw)}")
    robots, keys = [], []
    for i, r in enumerate(raw):
        rc, rk = _parse_robot(c, r, i, dim, default_end)
        dim = len(rc.start)
        robots.append(rc)
        keys.append(rk)
    return tuple(robots), keys


# Generator keys, in the order they are written out.  Each entry: kind of value and a
# default (None = computed by the generator from other keys; resolved by _resolve_gen).
# Types: "count" (1..MAX_ROBOTS), "pos" (> 0), "nonneg" (>= 0), "vec", "box", "dim",
# "vehicles", "end", ("choice", ...), "tries".
GENERATOR_KEYS: dict[str, dict[str, tuple[Any, Any]]] = {
    "antipodal_sphere": {
        "count": ("count", "required"), "radius": ("pos", 4.0), "dim": ("dim", None),
        "center": ("vec", None), "placement": (("choice", "even", "random"), "even"),
        "perturbation": ("nonneg", 0.05), "min_spacing": ("pos", None),
        "max_tries": ("tries", 1000), "vehicles": ("vehicles", ("firefly",)),
        "end_state": ("end", None),
    },
    "random_box": {
        "count": ("count", "required"), "dim": ("dim", None), "box": ("box", None),
        "min_spacing": ("pos", None), "goal_spacing": ("pos", None),
        "min_travel": ("nonneg", 0.0), "max_tries": ("tries", 1000),
        "vehicles": ("vehicles", ("firefly",)), "end_state": ("end", None),
    },
    "grid_swap": {
        "rows": ("count", "required"), "cols": ("count", "required"), "spacing": ("pos", 1.5),
        "dim": ("dim", None), "center": ("vec", None), "jitter": ("nonneg", 0.05),
        "vehicles": ("vehicles", ("firefly",)), "end_state": ("end", None),
    },
    "stacked": {
        "count": ("count", "required"), "spacing": ("pos", 0.5), "dim": ("dim", None),
        "base": ("vec", None), "row_spacing": ("pos", 1.0), "row_center": ("vec", None),
        "jitter": ("nonneg", 0.02), "vehicles": ("vehicles", ("firefly",)),
        "end_state": ("end", None),
    },
}


def _parse_scenario(c: _Ctx, raw: Any, default_end: str) -> ScenarioConfig:
    t = c.table(raw, "scenario")
    if "kind" not in t:
        raise c.err("scenario.kind", f"missing; choose one of {', '.join(_sc.SCENARIOS)}")
    kind = c.string(t["kind"], "scenario.kind", tuple(_sc.SCENARIOS))
    if kind in _sc.PAPER_SCENARIOS:
        c.keys(t, ("kind",), "scenario")
        return ScenarioConfig(kind, ())
    schema = GENERATOR_KEYS[kind]
    c.keys(t, ("kind", *schema), "scenario")
    vals: dict[str, Any] = {}
    # Dimension first: explicit, or from any vector given, else 3.
    dim = None
    if "dim" in t:
        dim = c.integer(t["dim"], "scenario.dim", ge=2, le=3)
    for k, (typ, _) in schema.items():
        if k in t and typ in ("vec", "box"):
            if typ == "vec":
                v = c.vector(t[k], f"scenario.{k}", dim)
            else:
                v = _parse_box(c, t[k], f"scenario.{k}", dim)
            vals[k] = v
            dim = len(v) if typ == "vec" else len(v[0])
    dim = 3 if dim is None else dim
    for k, (typ, default) in schema.items():
        key = f"scenario.{k}"
        if k in vals:
            continue
        if k not in t:
            if default == "required":
                raise c.err(key, "missing; give a positive integer")
            vals[k] = default_end if typ == "end" else (
                dim if typ == "dim" else default)
            continue
        v = t[k]
        if typ == "count":
            vals[k] = c.integer(v, key, ge=1, le=MAX_ROBOTS)
        elif typ == "tries":
            vals[k] = c.integer(v, key, ge=1, le=1_000_000)
        elif typ == "pos":
            vals[k] = c.number(v, key, gt=0, le=MAX_COORD)
        elif typ == "nonneg":
            vals[k] = c.number(v, key, ge=0, le=MAX_COORD)
        elif typ == "dim":
            vals[k] = dim
        elif typ == "vehicles":
            vals[k] = c.name_list(v, key, tuple(VEHICLES))
        elif typ == "end":
            vals[k] = c.string(v, key, END_STATES)
        elif isinstance(typ, tuple) and typ[0] == "choice":
            vals[k] = c.string(v, key, typ[1:])
        else:  # pragma: no cover - schema typo
            raise AssertionError(typ)
    if kind == "grid_swap" and vals["rows"] * vals["cols"] > MAX_ROBOTS:
        raise c.err("scenario.rows", f"rows * cols must be <= {MAX_ROBOTS}, got "
                                     f"{vals['rows'] * vals['cols']}")
    _resolve_gen(kind, vals)
    return ScenarioConfig(kind, tuple((k, vals[k]) for k in schema))


def _parse_box(c: _Ctx, v: Any, key: str, dim: int | None):
    if not isinstance(v, (list, tuple)) or len(v) != 2:
        raise c.err(key, f"expected [[lower corner], [upper corner]], got {_show(v)}")
    lo = c.vector(v[0], f"{key}[0]", dim)
    hi = c.vector(v[1], f"{key}[1]", len(lo))
    for d in range(len(lo)):
        if hi[d] < lo[d]:
            raise c.err(key, f"upper corner {_show(hi)} is below lower corner {_show(lo)} "
                             f"on axis {d}")
    return (lo, hi)


def _resolve_gen(kind: str, vals: dict[str, Any]) -> None:
    """Fill the dimension-dependent defaults (None) with the generator's own defaults."""
    dim = vals["dim"]
    names = vals["vehicles"]
    rho = 2.0 * max(VEHICLES[v].radius for v in names) + _sc.SAFETY_MARGIN
    if kind == "antipodal_sphere":
        if vals["center"] is None:
            vals["center"] = tuple(float(x) for x in _sc._antipodal_defaults(vals["radius"], dim))
        if vals["min_spacing"] is None:
            vals["min_spacing"] = round(rho, 6)
    elif kind == "random_box":
        if vals["box"] is None:
            b = _sc._box_default(dim)
            vals["box"] = (tuple(map(float, b[0])), tuple(map(float, b[1])))
        if vals["min_spacing"] is None:
            vals["min_spacing"] = round(rho, 6)
        if vals["goal_spacing"] is None:
            vals["goal_spacing"] = vals["min_spacing"]
    elif kind == "grid_swap":
        if vals["center"] is None:
            vals["center"] = (0.0, 0.0, 2.0) if dim == 3 else (0.0, 0.0)
    elif kind == "stacked":
        if vals["base"] is None:
            vals["base"] = (-3.0, 0.0, 1.2) if dim == 3 else (-3.0, 0.0)
        if vals["row_center"] is None:
            vals["row_center"] = (3.0, 0.0, 2.0) if dim == 3 else (3.0, 0.0)


def _parse_grid(c: _Ctx, raw: Any, key: str, default: float) -> tuple[float, ...]:
    if raw is None:
        return (default,)
    if isinstance(raw, dict):
        c.table(raw, key)
        c.keys(raw, ("log_min", "log_max", "num"), key)
        for k in ("log_min", "log_max", "num"):
            if k not in raw:
                raise c.err(f"{key}.{k}", "missing; a log range needs log_min, log_max, num "
                                          "(base-10 exponents)")
        lo = c.number(raw["log_min"], f"{key}.log_min", ge=-300, le=300)
        hi = c.number(raw["log_max"], f"{key}.log_max", ge=lo, le=300)
        num = c.integer(raw["num"], f"{key}.num", ge=1, le=MAX_SWEEP_POINTS)
        if num == 1 and hi != lo:
            raise c.err(f"{key}.num", "num = 1 needs log_min == log_max")
        return tuple(float(x) for x in np.logspace(lo, hi, num))
    if not isinstance(raw, (list, tuple)) or not raw:
        raise c.err(key, f"expected a non-empty array of numbers or a table "
                         f"{{log_min, log_max, num}}, got {_show(raw)}")
    if len(raw) > MAX_SWEEP_POINTS:
        raise c.err(key, f"at most {MAX_SWEEP_POINTS} values, got {len(raw)}")
    return tuple(c.number(x, f"{key}[{i}]", ge=0) for i, x in enumerate(raw))


def _parse_sweep(c: _Ctx, raw: Any, planner: PlannerConfig, seed: int) -> SweepConfig:
    t = c.table(raw, "sweep")
    c.keys(t, SweepConfig.__dataclass_fields__, "sweep")
    q_obs = _parse_grid(c, t.get("q_obs"), "sweep.q_obs", planner.q_obs)
    q_lim = _parse_grid(c, t.get("q_lim"), "sweep.q_lim", planner.q_lim)
    s = t.get("seeds")
    if s is None:
        seeds: tuple[int, ...] = (seed,)
    elif isinstance(s, dict):
        c.keys(s, ("start", "num"), "sweep.seeds")
        if "num" not in s:
            raise c.err("sweep.seeds.num", "missing; a seed range needs num (and start = 0)")
        start = c.integer(s.get("start", 0), "sweep.seeds.start", ge=0, le=MAX_SEED)
        num = c.integer(s["num"], "sweep.seeds.num", ge=1, le=MAX_SWEEP_POINTS)
        if start + num - 1 > MAX_SEED:
            raise c.err("sweep.seeds", "seeds must be < 2**63")
        seeds = tuple(range(start, start + num))
    elif isinstance(s, (list, tuple)) and s:
        if len(s) > MAX_SWEEP_POINTS:
            raise c.err("sweep.seeds", f"at most {MAX_SWEEP_POINTS} seeds, got {len(s)}")
        seeds = tuple(c.integer(x, f"sweep.seeds[{i}]", ge=0, le=MAX_SEED)
                      for i, x in enumerate(s))
    else:
        raise c.err("sweep.seeds", f"expected a non-empty array of integers or a table "
                                   f"{{start, num}}, got {_show(s)}")
    sc = t.get("scenarios", [])
    if not isinstance(sc, (list, tuple)):
        raise c.err("sweep.scenarios", f"expected an array of scenario names, got {_show(sc)}")
    scen = tuple(c.string(x, f"sweep.scenarios[{i}]", tuple(_sc.SCENARIOS))
                 for i, x in enumerate(sc))
    return SweepConfig(q_obs=q_obs, q_lim=q_lim, seeds=seeds, scenarios=scen)


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
    c = _Ctx(str(source))
    try:
        return _parse(c, data)
    except ConfigError:
        raise
    except (RecursionError, MemoryError) as e:  # absurdly nested or huge input
        raise c.err("", f"input too large or too deeply nested ({type(e).__name__})") from None


def _parse(c: _Ctx, data: Any) -> Config:
    t = c.table(data, "")
    c.keys(t, _TOP_KEYS, "")
    default_name = Path(c.source).stem if c.source != "<string>" else "config"
    name = c.string(t.get("name", default_name or "config"), "name")
    if not name.strip() or any(ch in name for ch in "/\\\n\r\t\0"):
        raise c.err("name", f"must be a non-empty name without slashes or control "
                            f"characters, got {_show(name)}")
    description = c.string(t.get("description", ""), "description")
    seed = c.integer(t.get("seed", 0), "seed", ge=0, le=MAX_SEED)
    planner = _parse_planner(c, t.get("planner", {}))
    limits = _parse_limits(c, t.get("limits", {}))
    sim = _parse_sim(c, t.get("sim", {}))
    faults = _parse_faults(c, t.get("faults", {}))
    scenario = None
    dim = None
    if "scenario" in t:
        scenario = _parse_scenario(c, t["scenario"], planner.end_state)
        dim = scenario.dim
    robots, robot_keys = _parse_robots(c, t.get("robots", []), planner.end_state, dim)
    if scenario is None and not robots:
        raise c.err("robots", "the fleet is empty; give [[robots]] entries or a [scenario] "
                              "table")
    if dim is None:
        dim = len(robots[0].start)
    if sim.backend == "mjx" and dim != 3:
        raise c.err("sim.backend", "'mjx' simulates quadrotors and needs 3-D positions; use "
                                   "'ideal' for a 2-D config")
    sweep = _parse_sweep(c, t.get("sweep", {}), planner, seed)
    cfg = Config(name=name, description=description, seed=seed, planner=planner,
                 limits=limits, sim=sim, robots=robots, scenario=scenario, sweep=sweep,
                 faults=faults, source=c.source)
    # Build the fleet now (cheap NumPy) so geometric errors surface before any run.
    try:
        sc = _build(cfg, validate=False)
    except ScenarioError as e:
        key = f"scenario.{e.key}" if e.key else "scenario"
        msg = str(e)
        if e.key and msg.startswith(f"{e.key}: "):
            msg = msg[len(e.key) + 2:]
        raise c.err(key, msg) from None
    n_gen = sc.num_robots - len(robots)

    def label(i: int) -> str:
        return f"robots[{i - n_gen}]" if i >= n_gen else f"generated robot {i}"

    probs = _sc.scenario_problems(sc, max_problems=1, label=label)
    if probs:
        p = probs[0]
        i = p.robot
        if i >= n_gen:
            rk = robot_keys[i - n_gen]
            key = rk.start() if p.waypoint is None else rk.goal(
                min(p.waypoint, len(robots[i - n_gen].waypoints) - 1))
        else:
            key = "scenario"
        raise c.err(key, p.message)
    return cfg


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


def _to_plain(v: Any) -> Any:
    if isinstance(v, tuple):
        return [_to_plain(x) for x in v]
    return v


def config_to_dict(config: Config) -> dict[str, Any]:
    """The fully resolved config as a TOML-ready dict (every default written out;
    limits only where overridden: their default is per vehicle)."""
    d: dict[str, Any] = {"name": config.name, "description": config.description,
                         "seed": config.seed}
    d["planner"] = {k: getattr(config.planner, k) for k in PlannerConfig.__dataclass_fields__}
    d["limits"] = {k: getattr(config.limits, k) for k in LimitsConfig.__dataclass_fields__
                   if getattr(config.limits, k) is not None}
    d["sim"] = {k: getattr(config.sim, k) for k in SimConfig.__dataclass_fields__}
    if config.scenario is not None:
        d["scenario"] = {"kind": config.scenario.kind,
                         **{k: _to_plain(v) for k, v in config.scenario.params}}
    if config.robots:
        rows = []
        for r in config.robots:
            row: dict[str, Any] = {"vehicle": r.vehicle, "start": list(r.start)}
            W = len(r.waypoints)
            if W == 1:
                row["goal"] = list(r.waypoints[0])
            else:
                row["waypoints"] = [list(w) for w in r.waypoints]
            row["end_state"] = r.end_state[0] if len(set(r.end_state)) == 1 else \
                list(r.end_state)
            if any(v is not None for v in r.goal_velocity):
                if all(v is None for v in r.goal_velocity[:-1]):
                    row["goal_velocity"] = list(r.goal_velocity[-1])
                else:
                    row["goal_velocity"] = [[] if v is None else list(v)
                                            for v in r.goal_velocity]
            rows.append(row)
        d["robots"] = rows
    d["sweep"] = {"q_obs": list(config.sweep.q_obs), "q_lim": list(config.sweep.q_lim),
                  "seeds": list(config.sweep.seeds), "scenarios": list(config.sweep.scenarios)}
    d["faults"] = {k: getattr(config.faults, k) for k in FAULT_KEYS}
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
    top = [f"{k} = {_toml_value(v)}" for k, v in d.items() if not isinstance(v, (dict, list))]
    lines += top
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
    if config.scenario.kind in _sc.PAPER_SCENARIOS:
        return {"firefly", "neo11"}
    return set(config.scenario.get("vehicles", ()))


def _build(config: Config, validate: bool) -> Scenario:
    parts: list[Scenario] = []
    if config.scenario is not None:
        kind = config.scenario.kind
        if kind in _sc.PAPER_SCENARIOS:
            parts.append(_sc.PAPER_SCENARIOS[kind](seed=config.seed))
        else:
            params = config.scenario.as_dict()
            if kind == "random_box":
                params.pop("dim")  # random_box takes N from its box
            # Validated below, as a whole fleet together with [[robots]].
            parts.append(_sc.GENERATORS[kind](seed=config.seed, validate=False, **params))
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
    return _sc.make_scenario(config.name, names, np.array(starts), wps, rests, gvs,
                             v_max=lim.v_max, a_max=lim.a_max, j_max=lim.j_max,
                             validate=validate)


def build_scenario(config: Config) -> Scenario:
    """The fleet of a config: generated robots (seeded by ``config.seed``) then
    [[robots]], limits overridden by [limits].  Named ``config.name``.

    Returns: a validated :class:`jaxplan.scenarios.Scenario`.
    """
    sc = _build(config, validate=True)
    fr = config.faults.frozen_robot
    if fr >= sc.num_robots:
        raise ConfigError(f"{config.source}: faults.frozen_robot: robot {fr} does not exist "
                          f"(the fleet has {sc.num_robots} robots, numbered from 0)")
    return sc
