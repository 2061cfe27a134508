"""ORCA in 3-D: RVO2-3D's velocity selection (van den Berg, Guy, Lin and Manocha, 2011;
RVO2-3D's ``Agent::computeNewVelocity`` with its linear programs 1 to 4) in JAX, float64,
every robot's small LP at once (vmap), in jaxplan's harness (``[planner] method =
"orca3d"``; any fleet, planar or 3-D; no obstacles).

One step, for each robot i (position p, velocity v, preferred velocity v_pref, radius r,
maximum speed v_max):

- its neighbours: the other robots closer than ``orca_neighbor_dist_m`` (centre distance,
  strictly), the nearest ``orca_max_neighbors`` of them sorted by distance, as RVO2's
  kd-tree query gives them; fixed-size masked arrays of K = min(orca_max_neighbors, M - 1)
  slots, so that one program serves every step of a fleet of M robots;
- one ORCA plane per neighbour j (relative position q = p_j - p, relative velocity
  w = v - v_j, combined radius R = r + r_j): with no overlap (|q| > R), the relative
  velocity's projection u onto the boundary of the velocity obstacle truncated at time
  horizon tau = ``orca_time_horizon_s`` (onto its cut-off sphere of centre q / tau and
  radius R / tau, or onto its cone); overlapping, onto the cut-off sphere of time
  dt = ``orca_time_step_s``; the plane has normal u / |u| through v + u / 2 (the robot
  takes half the responsibility), and v' is allowed when n . (point - v') <= 0;
- the new velocity: the one nearest v_pref within the v_max sphere on the allowed side of
  every plane (RVO2-3D's linearProgram3: planes added one at a time, the optimum moved
  onto a plane it violates by the 2-D programme on that plane, linearProgram2, which
  moves onto the line of two planes by the 1-D programme on it, linearProgram1); when no
  velocity satisfies every plane, the one that least violates the worst plane from the
  first that failed onwards (linearProgram4: linearProgram3 on the planes projected onto
  each violated one, maximising speed along its normal).

The arithmetic follows RVO2-3D's (single precision there, float64 here), with its
tolerance RVO3D_EPSILON on squared cross products and directions; where RVO2-3D would
divide by zero (a relative velocity exactly on a cone's axis or at a cut-off sphere's
centre) the plane is dropped (normal 0), and a negative discriminant from round-off
counts as 0.  The loops are ``lax.while_loop``s whose trip counts are each lane's own
(a plane that holds costs no inner iterations); linearProgram4 runs only in steps where
some robot needs it.

A planar fleet runs embedded in the plane z = 0: its planes are then vertical and the
velocities' x and y are those of RVO2 (pyrvo, :mod:`jaxplan.baselines.orca`) up to its
single-precision round-off.  RVO2-3D's linearProgram1 breaks a tie along a vertical line
by its lowest point, so that where linearProgram4 runs an embedded robot may get a z
velocity, which the planar fleet drops (every x-y velocity of that vertical line is
equally optimal for the planar problem).

Around the step the harness is :mod:`jaxplan.baselines.orca`'s (:func:`orca.simulate`):
preferred velocities towards the current waypoint, the change of velocity clamped to
a_max dt, one straight piece per robot and step (in float64: p + v dt exactly), the
waypoint advance and the StepRecords, so that every exact metric and file is the
planner's.  RVO2-3D has no obstacles: a world with obstacles is refused (the workspace
faces are not given to ORCA, as for "orca"; the metrics still count them).
"""

from __future__ import annotations

import dataclasses
import time
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jaxplan.baselines import orca
from jaxplan.config import Config
from jaxplan.scenarios import Scenario
from jaxplan.timing import KeptPrograms

EPSILON = 1e-5  # RVO2-3D's RVO3D_EPSILON: squared cross products and directions below it are 0

_PROGRAMS = KeptPrograms(8)  # the compiled fleet steps, by (M, K)


def _dot(a, b):
    return jnp.sum(a * b, axis=-1)


def _safe(x):
    """x where it is not 0, else 1 (a divisor whose quotient is then discarded)."""
    return jnp.where(x == 0.0, 1.0, x)


def orca_planes(p, v, radius, p_n, v_n, radius_n, valid, inv_horizon, inv_step):
    """One robot's ORCA planes (RVO2-3D's computeNewVelocity, the planes' part).

    p, v (3,) m, m/s; radius () m; p_n, v_n (K, 3), radius_n (K,) its neighbours;
    valid (K,) bool; inv_horizon 1 / tau, inv_step 1 / dt (1/s).  Returns normal (K, 3)
    (unit, 0 in an invalid or dropped slot) and point (K, 3) m/s: v' is allowed by plane
    k when normal[k] . (point[k] - v') <= 0.
    """
    rel_p = p_n - p
    rel_v = v - v_n
    dist_sq = _dot(rel_p, rel_p)
    comb = radius + radius_n
    comb_sq = comb * comb
    apart = dist_sq > comb_sq
    # no collision: the cut-off sphere of time tau, or the cone
    w = rel_v - inv_horizon * rel_p
    w_len_sq = _dot(w, w)
    dot_w = _dot(w, rel_p)
    cut = (dot_w < 0.0) & (dot_w * dot_w > comb_sq * w_len_sq)
    w_len = jnp.sqrt(w_len_sq)
    unit_w = w / _safe(w_len)[:, None]
    u_cut = (comb * inv_horizon - w_len)[:, None] * unit_w
    a = dist_sq
    b = _dot(rel_p, rel_v)
    cr = jnp.cross(rel_p, rel_v)
    c = _dot(rel_v, rel_v) - _dot(cr, cr) / _safe(jnp.where(apart, dist_sq - comb_sq, 1.0))
    t = (b + jnp.sqrt(jnp.maximum(b * b - a * c, 0.0))) / _safe(a)
    ww = rel_v - t[:, None] * rel_p
    ww_len = jnp.sqrt(_dot(ww, ww))
    unit_ww = ww / _safe(ww_len)[:, None]
    u_cone = (comb * t - ww_len)[:, None] * unit_ww
    # collision: the cut-off sphere of time dt
    wc = rel_v - inv_step * rel_p
    wc_len = jnp.sqrt(_dot(wc, wc))
    unit_wc = wc / _safe(wc_len)[:, None]
    u_coll = (comb * inv_step - wc_len)[:, None] * unit_wc
    normal = jnp.where(apart[:, None], jnp.where(cut[:, None], unit_w, unit_ww), unit_wc)
    u = jnp.where(apart[:, None], jnp.where(cut[:, None], u_cut, u_cone), u_coll)
    normal = jnp.where(valid[:, None], normal, 0.0)
    point = jnp.where(valid[:, None], v + 0.5 * u, 0.0)
    return normal, point


def linear_program1(normal, point, mask, line_point, line_dir, radius, opt, direction_opt):
    """RVO2-3D's linearProgram1: the 1-D programme on a line (point line_point, unit
    direction line_dir, (3,)) inside the sphere of ``radius`` subject to the planes in
    ``mask`` ((K,) bool over normal, point (K, 3)).  The bounds from the planes are a max
    and a min (RVO2-3D's early exits fail exactly when the final bounds cross).  Returns
    (ok, result (3,)): the point nearest ``opt``, or (direction_opt) the extreme along
    ``opt``."""
    dot = line_point @ line_dir
    disc = dot * dot + radius * radius - line_point @ line_point
    sq = jnp.sqrt(jnp.maximum(disc, 0.0))
    num = _dot(point - line_point, normal)
    den = normal @ line_dir
    par = den * den <= EPSILON
    t = num / jnp.where(par, 1.0, den)
    left = mask & ~par & (den >= 0.0)
    right = mask & ~par & (den < 0.0)
    t_left = jnp.maximum(-dot - sq, jnp.max(jnp.where(left, t, -jnp.inf)))
    t_right = jnp.minimum(-dot + sq, jnp.min(jnp.where(right, t, jnp.inf)))
    ok = (disc >= 0.0) & ~jnp.any(mask & par & (num > 0.0)) & (t_left <= t_right)
    if direction_opt:
        s = jnp.where(opt @ line_dir > 0.0, t_right, t_left)
    else:
        s = line_dir @ (opt - line_point)
        s = jnp.where(s < t_left, t_left, jnp.where(s > t_right, t_right, s))
    return ok, line_point + s * line_dir


def linear_program2(normal, point, valid, i, radius, opt, direction_opt, active):
    """RVO2-3D's linearProgram2: the 2-D programme on plane ``i`` inside the sphere,
    subject to the valid planes before it.  ``active`` False: nothing to do (no inner
    iterations).  Returns (ok, result (3,))."""
    K = normal.shape[0]
    n, pt = normal[i], point[i]
    plane_dist = pt @ n
    plane_dist_sq = plane_dist * plane_dist
    radius_sq = radius * radius
    ok = active & ~(plane_dist_sq > radius_sq)
    plane_radius_sq = radius_sq - plane_dist_sq
    center = plane_dist * n
    if direction_opt:
        pov = opt - (opt @ n) * n
        pov_sq = pov @ pov
        small = pov_sq <= EPSILON
        result = jnp.where(small, center,
                           center + jnp.sqrt(plane_radius_sq / jnp.where(small, 1.0, pov_sq)) * pov)
    else:
        result = opt + ((pt - opt) @ n) * n
        rel = result - center
        rel_sq = rel @ rel
        result = jnp.where(result @ result > radius_sq,
                           center + jnp.sqrt(plane_radius_sq / _safe(rel_sq)) * rel, result)
    index = jnp.arange(K)

    def cond(s):
        j, ok, _ = s
        return ok & (j < i)

    def body(s):
        j, ok, result = s
        nj, pj = normal[j], point[j]
        violated = valid[j] & (nj @ (pj - result) > 0.0)
        cross = jnp.cross(nj, n)
        cross_sq = cross @ cross
        par = cross_sq <= EPSILON
        line_dir = cross / jnp.sqrt(jnp.where(par, 1.0, cross_sq))
        line_normal = jnp.cross(line_dir, n)
        line_point = pt + ((pj - pt) @ nj) / _safe(line_normal @ nj) * line_normal
        ok1, r1 = linear_program1(normal, point, valid & (index < j), line_point, line_dir,
                                  radius, opt, direction_opt)
        moved = violated & ~par & ok1
        return j + 1, jnp.where(violated, moved, ok), jnp.where(moved, r1, result)

    _, ok, result = lax.while_loop(cond, body, (jnp.zeros((), jnp.int32), ok, result))
    return ok, result


def linear_program3(normal, point, valid, count, radius, opt, direction_opt, active=True):
    """RVO2-3D's linearProgram3: the 3-D programme inside the sphere of ``radius``
    subject to the valid planes among the first ``count``.  Returns (fail, result (3,)):
    fail the plane it failed on (result then the optimum before it), ``count`` on
    success.  ``active`` False: no iterations (fail = count)."""
    if direction_opt:
        result = opt * radius
    else:
        opt_sq = opt @ opt
        result = jnp.where(opt_sq > radius * radius, opt / jnp.sqrt(_safe(opt_sq)) * radius,
                           opt)

    def cond(s):
        i, failed, _ = s
        return active & ~failed & (i < count)

    def body(s):
        i, _, result = s
        violated = valid[i] & (normal[i] @ (point[i] - result) > 0.0)
        ok2, r2 = linear_program2(normal, point, valid, i, radius, opt, direction_opt,
                                  violated)
        return i + 1, violated & ~ok2, jnp.where(violated & ok2, r2, result)

    i, failed, result = lax.while_loop(
        cond, body, (jnp.zeros((), jnp.int32), jnp.zeros((), bool), result))
    return jnp.where(failed, i - 1, count), result


def linear_program4(normal, point, valid, count, begin, radius, result):
    """RVO2-3D's linearProgram4: from plane ``begin`` (where linearProgram3 failed) on,
    each plane violated by more than the worst so far: linearProgram3 on the earlier
    planes projected onto it (maximising speed along its normal).  Returns result (3,)."""
    K = normal.shape[0]
    index = jnp.arange(K)

    def cond(s):
        i, _, _ = s
        return i < count

    def body(s):
        i, distance, result = s
        ni, pi = normal[i], point[i]
        violated = valid[i] & (ni @ (pi - result) > distance)
        cross = jnp.cross(normal, ni)
        par = _dot(cross, cross) <= EPSILON
        keep = valid & (index < i) & ~(par & (normal @ ni > 0.0))
        line_normal = jnp.cross(cross, ni)
        s = _dot(point - pi, normal) / _safe(_dot(line_normal, normal))
        proj_point = jnp.where(par[:, None], 0.5 * (pi + point), pi + s[:, None] * line_normal)
        diff = normal - ni
        proj_normal = diff / _safe(jnp.sqrt(_dot(diff, diff)))[:, None]
        fail, r3 = linear_program3(proj_normal, proj_point, keep, i, radius, ni, True,
                                   active=violated)
        result = jnp.where(violated & (fail >= i), r3, result)
        distance = jnp.where(violated, ni @ (pi - result), distance)
        return i + 1, distance, result

    _, _, result = lax.while_loop(cond, body, (begin, jnp.zeros(()), result))
    return result


def neighbours(p, neighbor_dist, max_neighbors, k):
    """Each robot's neighbours as RVO2's query gives them: the others strictly within
    ``neighbor_dist`` (m), the nearest ``max_neighbors`` (at most the k slots), sorted by
    distance.  p (M, 3).  Returns index (M, k) int and valid (M, k) bool (valid slots
    first)."""
    M = p.shape[0]
    d = p[:, None, :] - p[None, :, :]
    dist_sq = _dot(d, d)
    dist_sq = jnp.where(jnp.eye(M, dtype=bool), jnp.inf, dist_sq)
    neg, index = lax.top_k(-dist_sq, k)
    valid = (-neg < neighbor_dist * neighbor_dist) & (jnp.arange(k) < max_neighbors)
    return index, valid


@partial(jax.jit, static_argnames=("k",))
def new_velocities(p, v, pref, radius, v_max, neighbor_dist, max_neighbors, time_horizon,
                   time_step, *, k):
    """One ORCA step of the fleet: every robot's new velocity (module docstring).

    p, v, pref: (M, 3) m, m/s, m/s; radius, v_max: (M,) m, m/s; neighbor_dist m,
    max_neighbors (int), time_horizon s, time_step s (scalars); k (static) the neighbour
    slots, at most M - 1, at least 1 (neighbours beyond k or max_neighbors are left
    out).  Returns (velocity (M, 3) m/s, infeasible (M,) bool: no velocity satisfied
    every plane, and linearProgram4 chose it).
    """
    index, valid = neighbours(p, neighbor_dist, max_neighbors, k)
    count = jnp.sum(valid, axis=-1)
    planes = jax.vmap(orca_planes, in_axes=(0, 0, 0, 0, 0, 0, 0, None, None))
    normal, point = planes(p, v, radius, p[index], v[index], radius[index], valid,
                           1.0 / time_horizon, 1.0 / time_step)
    kept = valid & jnp.any(normal != 0.0, axis=-1)  # a dropped plane (normal 0) holds always
    lp3 = jax.vmap(partial(linear_program3, direction_opt=False))
    fail, result = lp3(normal, point, kept, count, v_max, pref)
    infeasible = fail < count
    result = lax.cond(jnp.any(infeasible),
                      lambda r: jax.vmap(linear_program4)(normal, point, kept, count, fail,
                                                          v_max, r),
                      lambda r: r, result)
    return result, infeasible


def neighbour_slots(config: Config, M: int) -> int:
    """K: the neighbour slots of a fleet of M robots (min(orca_max_neighbors, M - 1),
    at least 1)."""
    return max(1, min(int(config.planner.orca_max_neighbors), M - 1))


def compiled_step(M: int, k: int):
    """(the compiled :func:`new_velocities` for M robots and k slots, its compile
    seconds: 0 when this process has it already)."""
    key = (M, k)
    program = _PROGRAMS.get(key)
    if program is not None:
        return program, 0.0
    z3, z = jnp.zeros((M, 3)), jnp.zeros((M,))
    s, n = jnp.zeros(()), jnp.zeros((), jnp.int64)
    t0 = time.perf_counter()
    program = new_velocities.lower(z3, z3, z3, z, z, s, n, s, s, k=k).compile()
    return _PROGRAMS.put(key, program), time.perf_counter() - t0


@dataclasses.dataclass
class Orca3DEngine:
    """The JAX RVO2-3D as :func:`jaxplan.baselines.orca.simulate`'s engine: a fleet of
    dimension ``dim`` (2: embedded at z = 0, velocities returned in the plane)."""

    program: object
    radius: np.ndarray  # (M,) m: the planning radius
    v_max: np.ndarray  # (M,) m/s
    neighbor_dist: float
    max_neighbors: int
    time_horizon: float
    dt: float
    dim: int

    def velocities(self, p, v, pref):
        """(M, dim) m/s: RVO2-3D's new velocities from p, v, pref (M, dim)."""
        out = self.program(_embed(p), _embed(v), _embed(pref), self.radius, self.v_max,
                           self.neighbor_dist, self.max_neighbors, self.time_horizon,
                           self.dt)[0]
        return np.asarray(out)[:, :self.dim]

    def advance(self, p, v_cmd):
        """(p + v_cmd dt, v_cmd): the robots move straight at v_cmd for the step."""
        return p + v_cmd * self.dt, v_cmd


def _embed(x):
    """(M, 3) float64: x (M, 2) or (M, 3), planar ones at z = 0."""
    x = np.asarray(x, np.float64)
    if x.shape[-1] == 3:
        return x
    return np.concatenate([x, np.zeros(x.shape[:-1] + (1,))], axis=-1)


def make_engine(config: Config, scenario: Scenario) -> tuple[Orca3DEngine, float]:
    """(the scenario's :class:`Orca3DEngine`, the step's compile seconds).  Refuses a
    world with obstacles and a backend other than "ideal"."""
    where = config.source or config.name
    if scenario.world is not None and scenario.world.num_obstacles > 0:
        raise ValueError(f"{where}: [planner] method = 'orca3d' has no obstacles (RVO2-3D "
                         "has none); use 'krishnan', or 'orca' for a planar fleet")
    if config.sim.backend != "ideal":
        raise ValueError(f"{where}: [planner] method = 'orca3d' moves the robots itself: "
                         "sim.backend must be 'ideal'")
    pc = config.planner
    M = scenario.num_robots
    program, compile_s = compiled_step(M, neighbour_slots(config, M))
    radius = np.asarray(scenario.radius, np.float64) + pc.safety_margin_m
    engine = Orca3DEngine(program, radius, np.asarray(scenario.v_max, np.float64),
                          float(pc.orca_neighbor_dist_m), int(pc.orca_max_neighbors),
                          float(pc.orca_time_horizon_s),
                          float(pc.orca_time_step_s), scenario.dim)
    return engine, compile_s


def simulate_orca3d(config: Config, scenario: Scenario, progress=None):
    """Run the JAX RVO2-3D on the scenario for ceil(duration_s / orca_time_step_s) steps
    (compiled first, apart from the steps' timing).  Returns what
    :func:`jaxplan.baselines.orca.simulate_orca` returns (records with dim-N pieces,
    final, step_ms, run_s).  ``progress``: optional callable(steps done)."""
    engine, _ = make_engine(config, scenario)
    p0 = np.asarray(scenario.start, np.float64)
    return orca.simulate(config, scenario, engine, p0, progress)


def run_orca3d(config: Config, scenario: Scenario, progress: bool = False):
    """``jaxplan run`` with ``[planner] method = "orca3d"``: as
    :func:`jaxplan.baselines.orca.run_orca`, compile_s the step's compile.  Returns
    (metrics, arrays, records, run_s)."""
    _, compile_s = make_engine(config, scenario)
    metrics, arrays, records, run_s = orca.run_orca(config, scenario, progress,
                                                    simulator=simulate_orca3d)
    metrics["compile_s"] = compile_s
    return metrics, arrays, records, run_s


__all__ = ["EPSILON", "Orca3DEngine", "compiled_step", "linear_program1", "linear_program2",
           "linear_program3", "linear_program4", "make_engine", "neighbour_slots",
           "neighbours", "new_velocities", "orca_planes", "run_orca3d", "simulate_orca3d"]

