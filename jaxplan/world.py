"""The world the robots move in: a workspace box and axis-aligned obstacles, static or
moving (the ``[workspace]`` and ``[[obstacles]]`` config sections, docs/DESIGN.md).

A :class:`World` holds, on the host (numpy, read-only):

    lo, hi   (N,)     m, the workspace: every robot's whole body stays in lo <= p <= hi
                      (-inf / inf: unbounded); in 3-D the default is the ground,
                      lo = [-inf, -inf, 0], hi = [inf, inf, inf]
    kind     (K,)     SPHERE, BOX or CYLINDER (OBSTACLE_KINDS names them)
    center   (K, N)   m, where the obstacle is at t = 0
    half     (K, N)   m, a box's half extents; a cylinder's half height in its last
                      entry (3-D; its axis is vertical); unused for a sphere
    radius   (K,)     m, a sphere's or a cylinder's radius; unused for a box
    knot_t   (K, P)   s, the knot times of each obstacle's motion (non-decreasing)
    knot_p   (K, P, N) m, its centre at those times
    knot_v   (K, N)   m/s, its velocity after its last knot
    known    (K,)     bool, the robots know its future path (``known_path``)

In 2-D a cylinder is a disc (its radius only) and a sphere is the same disc.

Motion.  Every obstacle's centre is a piecewise-linear function of time
(:func:`path_at`, :meth:`World.center_at`): at rest at knot_p[0] before knot_t[0],
linear between knots, and knot_p[-1] + knot_v (t - knot_t[-1]) after the last knot.  A
static obstacle is one knot at t = 0 with knot_v = 0 (the default when no motion is
given); a constant velocity v (``velocity``) is one knot at t = 0, at its centre, with
knot_v = v; a timed path (``path``) is its points as knots with knot_v = 0 (at rest
after its last point).  Obstacles with fewer knots than P are padded by repeating their
last knot (same time, same point), which changes nothing.  Only spheres and cylinders
move (a moving box is refused by the config).  The robots see a moving obstacle's
current position and velocity at each replan and predict it flying on at that velocity,
or know its whole future path (``known``): :func:`rows_at`.

Distances (:func:`signed_distance`) are the exact Euclidean signed distances to the
obstacle's surface (negative inside), written so that they are smooth enough for the
SQP: outside a convex body the distance is C^1 (its gradient is the unit normal of the
nearest surface point) with a bounded, piecewise continuous Hessian; the square roots
are taken as sqrt(s + e) - sqrt(e) with e = SQRT_EPS2 (1e-12 m^2), which is smooth at 0
and never above the exact value (so it errs on the safe side by at most 1e-6 m); inside
a box or a cylinder the distance is the largest face distance (a max: its gradient
points out through the nearest face).  The workspace's faces are half-spaces with
signed distance n . (p - c).

The planner's NLP sees the world as "static rows" (:class:`StaticRows`): the obstacles
followed by the finite workspace faces (:func:`static_rows`), each with the same
signed-distance function (:func:`signed_distance`; its derivatives
in closed form: :func:`signed_distance_jet`), padded with masked rows to a fixed
count so that a run with K obstacles compiles once.  In a world with a moving obstacle
the rows carry their motion (:class:`RowMotion`, traced data: knot times, points and the
final velocity per row, the faces and padding at rest), and a replan moves them to its
time (:func:`rows_at`): each row's ``center`` is then where it is now and its motion
the prediction from now on (times relative to the replan); the NLP evaluates the
distance at sample time tau to the centre :func:`path_at` gives at tau.  A static world
has ``motion = None``: its programs and results are those of a world without motion.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

# the motion's names, here too: the world's rows carry it (jaxplan/motion.py)
from jaxplan.motion import (  # noqa: F401
    RowMotion,
    centres_at,
    obstacle_motion,
    path_at,
    rows_at,
)

SPHERE, BOX, CYLINDER, PLANE = 0, 1, 2, 3
ALL_KINDS = (SPHERE, BOX, CYLINDER, PLANE)
OBSTACLE_KINDS = ("sphere", "box", "cylinder")  # index = kind code
SQRT_EPS2 = 1e-12  # m^2: the smoothing of the square roots (module doc)


def _readonly(a) -> np.ndarray:
    a = np.array(a, dtype=np.float64)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class World:
    """Workspace bounds and obstacles, static or moving (module doc for the fields;
    knot_t, knot_p, knot_v, known default to every obstacle at rest at its centre)."""

    lo: np.ndarray
    hi: np.ndarray
    kind: np.ndarray
    center: np.ndarray
    half: np.ndarray
    radius: np.ndarray
    knot_t: np.ndarray | None = None
    knot_p: np.ndarray | None = None
    knot_v: np.ndarray | None = None
    known: np.ndarray | None = None

    def __post_init__(self):
        N = np.asarray(self.lo).shape[0]
        for name in ("lo", "hi", "center", "half", "radius"):
            object.__setattr__(self, name, _readonly(getattr(self, name)))
        kind = np.array(self.kind, dtype=np.int32).reshape(-1)
        kind.setflags(write=False)
        object.__setattr__(self, "kind", kind)
        K = kind.shape[0]
        if self.hi.shape != (N,) or self.center.shape != (K, N) or self.half.shape != (K, N) \
                or self.radius.shape != (K,):
            raise ValueError(f"World: inconsistent shapes lo {self.lo.shape}, hi "
                             f"{self.hi.shape}, kind {kind.shape}, center {self.center.shape}, "
                             f"half {self.half.shape}, radius {self.radius.shape}")
        # motion: default every obstacle at rest at its centre (one knot at t = 0)
        if self.knot_t is None:
            object.__setattr__(self, "knot_t", np.zeros((K, 1)))
        if self.knot_p is None:
            object.__setattr__(self, "knot_p", self.center[:, None, :])
        if self.knot_v is None:
            object.__setattr__(self, "knot_v", np.zeros((K, N)))
        known = np.zeros(K, bool) if self.known is None else np.array(self.known, bool)
        known = known.reshape(-1)
        known.setflags(write=False)
        object.__setattr__(self, "known", known)
        for name in ("knot_t", "knot_p", "knot_v"):
            object.__setattr__(self, name, _readonly(getattr(self, name)))
        kt, kp, kv = self.knot_t, self.knot_p, self.knot_v
        P = kt.shape[1] if kt.ndim == 2 else -1
        if kt.shape != (K, P) or P < 1 or kp.shape != (K, P, N) or kv.shape != (K, N) \
                or known.shape != (K,):
            raise ValueError(f"World: inconsistent motion shapes knot_t {kt.shape}, knot_p "
                             f"{kp.shape}, knot_v {kv.shape}, known {known.shape} for "
                             f"{K} obstacles in {N}-D")
        if not (np.all(np.isfinite(kt)) and np.all(np.isfinite(kp))
                and np.all(np.isfinite(kv))):
            raise ValueError("World: the obstacles' motion must be finite")
        if np.any(np.diff(kt, axis=1) < 0.0):
            raise ValueError("World: knot_t must be non-decreasing")
        same = np.diff(kt, axis=1) == 0.0
        if np.any(same & np.any(np.diff(kp, axis=1) != 0.0, axis=-1)):
            raise ValueError("World: knots at the same time must be at the same point")
        if K and np.max(np.abs(self.center_at(0.0)[0] - self.center)) > 1e-9 * (
                1.0 + np.max(np.abs(self.center))):
            raise ValueError("World: center must be where the motion puts each obstacle "
                             "at t = 0")

    @staticmethod
    def default(N: int) -> World:
        """No obstacles; in 3-D the ground (z >= 0), in 2-D unbounded."""
        lo = np.full(N, -np.inf)
        if N == 3:
            lo[2] = 0.0
        return World(lo, np.full(N, np.inf), np.zeros(0, np.int32), np.zeros((0, N)),
                     np.zeros((0, N)), np.zeros(0))

    @staticmethod
    def unbounded(N: int) -> World:
        """No obstacles and no workspace (the paper's empty space)."""
        return World(np.full(N, -np.inf), np.full(N, np.inf), np.zeros(0, np.int32),
                     np.zeros((0, N)), np.zeros((0, N)), np.zeros(0))

    @property
    def dim(self) -> int:
        return int(self.lo.shape[0])

    @property
    def num_obstacles(self) -> int:
        return int(self.kind.shape[0])

    @property
    def num_knots(self) -> int:
        """P, the knots of the motions (padded)."""
        return int(self.knot_t.shape[1])

    @property
    def moving(self) -> np.ndarray:
        """(K,) bool: the obstacle moves at some time."""
        return (np.any(self.knot_p != self.knot_p[:, :1], axis=(1, 2))
                | np.any(self.knot_v != 0.0, axis=1))

    @property
    def has_motion(self) -> bool:
        """Whether some obstacle moves."""
        return bool(np.any(self.moving))

    def center_at(self, t):
        """Every obstacle's centre and velocity at time(s) t (s; (...,)): (centre
        (..., K, N) m, velocity (..., K, N) m/s) (:func:`path_at`)."""
        return path_at(self.knot_t, self.knot_p, self.knot_v, np.asarray(t, np.float64))

    def static_part(self) -> World:
        """The world without its moving obstacles (what the guide plans round)."""
        keep = ~self.moving
        return World(self.lo, self.hi, self.kind[keep], self.center[keep], self.half[keep],
                     self.radius[keep], self.knot_t[keep], self.knot_p[keep],
                     self.knot_v[keep], self.known[keep])

    @property
    def num_faces(self) -> int:
        """Finite workspace faces (the half-spaces the NLP constrains)."""
        return int(np.sum(np.isfinite(self.lo)) + np.sum(np.isfinite(self.hi)))

    def with_obstacles(self, obstacles) -> World:
        """A copy with these obstacles (dicts as in the config: kind, center, radius,
        half_extents, half_height, and for a moving one velocity or path = [{t, p}, ...]
        and known_path) in place of the current ones."""
        kind, center, half, radius = obstacle_arrays(obstacles, self.dim)
        knot_t, knot_p, knot_v, known = obstacle_motion(obstacles, center)
        center = path_at(knot_t, knot_p, knot_v, np.float64(0.0))[0]
        return World(self.lo, self.hi, kind, center, half, radius, knot_t, knot_p, knot_v,
                     known)

    def within(self, lo, hi) -> World:
        """A copy whose workspace is this one's intersected with the box [lo, hi] ((N,)
        m each, +-inf: unbounded on that side): the tighter bound of each face."""
        lo = np.maximum(self.lo, np.asarray(lo, np.float64))
        hi = np.minimum(self.hi, np.asarray(hi, np.float64))
        if np.any(lo >= hi):
            raise ValueError(f"World.within: the box [{lo}, {hi}] leaves no workspace")
        return dataclasses.replace(self, lo=lo, hi=hi)

    def obstacles(self) -> list[dict]:
        """The obstacles as config dicts (what ``[[obstacles]]`` holds; a moving one with
        its velocity or its path and known_path)."""
        out = []
        moving = self.moving
        for k in range(self.num_obstacles):
            kd = OBSTACLE_KINDS[int(self.kind[k])]
            d = {"kind": kd, "center": [float(x) for x in self.center[k]]}
            if kd == "box":
                d["half_extents"] = [float(x) for x in self.half[k]]
            else:
                d["radius"] = float(self.radius[k])
                if kd == "cylinder" and self.dim == 3:
                    d["half_height"] = float(self.half[k, -1])
            if moving[k]:
                t, p = self.knot_t[k], self.knot_p[k]
                keep = np.r_[True, (np.diff(t) > 0.0)]  # padding repeats its last knot
                if keep.sum() == 1 and t[0] == 0.0:  # one knot at t = 0: a velocity
                    d["velocity"] = [float(x) for x in self.knot_v[k]]
                else:
                    del d["center"]
                    d["path"] = [{"t": float(tt), "p": [float(x) for x in pp]}
                                 for tt, pp in zip(t[keep], p[keep], strict=True)]
                d["known_path"] = bool(self.known[k])
            out.append(d)
        return out

    def describe(self, k: int) -> str:
        """Obstacle k for a message: 'obstacles[3] (cylinder at [1, 2, 1.5])'."""
        c = ", ".join(f"{float(x):.4g}" for x in self.center[k])
        return f"obstacles[{k}] ({OBSTACLE_KINDS[int(self.kind[k])]} at [{c}])"


def obstacle_arrays(obstacles, N: int):
    """(kind (K,), center (K, N), half (K, N), radius (K,)) of config obstacle dicts."""
    K = len(obstacles)
    kind = np.zeros(K, np.int32)
    center = np.zeros((K, N))
    half = np.zeros((K, N))
    radius = np.zeros(K)
    for k, o in enumerate(obstacles):
        kd = OBSTACLE_KINDS.index(o["kind"])
        kind[k] = kd
        # a path's obstacle has no centre: its first point (where it rests before it)
        center[k] = o["center"] if o.get("center") is not None else o["path"][0]["p"]
        if kd == BOX:
            half[k] = o["half_extents"]
        else:
            radius[k] = o["radius"]
            if kd == CYLINDER and N == 3:
                half[k, -1] = o["half_height"]
    return kind, center, half, radius


# trajectories.npz keys of the world (docs/DESIGN.md "A run directory"); MOTION_KEYS
# only where an obstacle moves (a run without them has static obstacles)
WORLD_KEYS = ("world_lo", "world_hi", "obstacle_kind", "obstacle_center", "obstacle_half",
              "obstacle_radius")
MOTION_KEYS = ("obstacle_knot_t", "obstacle_knot_p", "obstacle_knot_v", "obstacle_known_path")


def world_arrays(world: World) -> dict[str, np.ndarray]:
    """The world as trajectories.npz stores it (WORLD_KEYS, and MOTION_KEYS where an
    obstacle moves)."""
    out = {"world_lo": world.lo, "world_hi": world.hi, "obstacle_kind": world.kind,
           "obstacle_center": world.center, "obstacle_half": world.half,
           "obstacle_radius": world.radius}
    if world.has_motion:
        out.update(obstacle_knot_t=world.knot_t, obstacle_knot_p=world.knot_p,
                   obstacle_knot_v=world.knot_v, obstacle_known_path=world.known)
    return out


def world_from_arrays(raw, N: int) -> World:
    """The world of a run's arrays (WORLD_KEYS, MOTION_KEYS where given); a run without
    them was planned in unbounded empty space (:meth:`World.unbounded`).  Raises
    ValueError on bad shapes."""
    if not all(k in raw for k in WORLD_KEYS):
        return World.unbounded(N)
    kind = np.asarray(raw["obstacle_kind"])
    if kind.size and (kind.min() < 0 or kind.max() >= len(OBSTACLE_KINDS)):
        raise ValueError(f"obstacle_kind: codes must lie in [0, {len(OBSTACLE_KINDS)})")
    motion = [np.asarray(raw[k]) for k in MOTION_KEYS] if all(k in raw for k in MOTION_KEYS) \
        else []
    w = World(*(np.asarray(raw[k]) for k in WORLD_KEYS), *motion)
    if w.dim != N:
        raise ValueError(f"world_lo: the world is {w.dim}-D, the run {N}-D")
    return w


# ---------------------------------------------------------------------- distances
def _safe_norm(x, xp, axis=-1):
    """sqrt(|x|^2 + e) - sqrt(e): smooth, within 1e-6 below |x| (module doc)."""
    return xp.sqrt(xp.sum(x * x, axis=axis) + SQRT_EPS2) - np.sqrt(SQRT_EPS2)


def _rounded(q, xp):
    """Signed distance from face distances q (..., m): |max(q, 0)| + min(max_i q_i, 0)."""
    out = _safe_norm(xp.maximum(q, 0.0), xp)
    inside = xp.minimum(_largest(q, xp), 0.0)
    return out + inside


def _largest(q, xp):
    """max(q, axis=-1), differentiated (in JAX) as the entry argmax picks (the first on
    a tie).  JAX's own derivative of a max reduction divides by the count of entries
    equal to the max, and a compiler that rounds the two computations of q differently
    (XLA CPU at --xla_backend_optimization_level=0) finds none: 0 / 0, a NaN Hessian."""
    return np.max(q, axis=-1) if xp is np else _max_last(q)


@jax.custom_jvp
def _max_last(q):
    return jnp.max(q, axis=-1)


@_max_last.defjvp
def _max_last_jvp(primals, tangents):
    (q,), (t,) = primals, tangents
    i = jnp.argmax(q, axis=-1)[..., None]
    return _max_last(q), jnp.take_along_axis(t, i, axis=-1)[..., 0]


def signed_distance(kind, center, half, radius, p, xp=np):
    """Signed distance (m, negative inside) from points p (..., N) to the rows
    (kind (R,), center (R, N), half (R, N), radius (R,)): (..., R).  ``kind`` may hold
    PLANE rows: a half-space {n . (x - c) >= 0} with unit normal n = half, distance
    n . (p - c) (positive on the free side).  ``xp``: numpy or jax.numpy."""
    N = p.shape[-1]
    d = p[..., None, :] - center  # (..., R, N)
    sph = _safe_norm(d, xp) - radius
    box = _rounded(xp.abs(d) - half, xp)
    if N == 3:
        rho = _safe_norm(d[..., :2], xp)
        q = xp.stack([rho - radius, xp.abs(d[..., 2]) - half[..., 2]], axis=-1)
        cyl = _rounded(q, xp)
    else:
        cyl = sph
    pln = xp.sum(d * half, axis=-1)
    return xp.where(kind == SPHERE, sph, xp.where(kind == BOX, box,
                                                  xp.where(kind == CYLINDER, cyl, pln)))


def _norm_jet(x, xp):
    """sqrt(|x|^2 + e) - sqrt(e) of x (..., m) with its gradient (..., m) and Hessian
    (..., m, m): x / s and (I - x x^T / s^2) / s, s = sqrt(|x|^2 + e)."""
    s = xp.sqrt(xp.sum(x * x, axis=-1) + SQRT_EPS2)[..., None]
    u = x / s
    H = (xp.eye(x.shape[-1]) - u[..., :, None] * u[..., None, :]) / s[..., None]
    return s[..., 0] - np.sqrt(SQRT_EPS2), u, H


def _rounded_jet(q, xp):
    """:func:`_rounded` of q (..., m) with its gradient and Hessian in q: outside, the
    norm of max(q, 0) (its jet restricted to the positive entries); inside, the largest
    entry (a one-hot gradient, no curvature)."""
    pos = q > 0.0
    v, u, H = _norm_jet(xp.where(pos, q, 0.0), xp)
    H = xp.where(pos[..., :, None] & pos[..., None, :], H, 0.0)
    i = xp.argmax(q, axis=-1)[..., None]
    top = xp.take_along_axis(q, i, axis=-1)[..., 0]  # the max, found once
    hot = (np.arange(q.shape[-1]) == i) & (top < 0.0)[..., None]
    return v + xp.minimum(top, 0.0), u + hot, H


def row_kinds(kind) -> tuple[int, ...]:
    """The kinds of static rows ``kind`` holds (padding included), sorted: what
    :func:`signed_distance_jet` must form for them (``kinds``)."""
    return tuple(sorted({int(k) for k in np.asarray(kind).reshape(-1)}))


def signed_distance_jet(kind, center, half, radius, p, xp=np, kinds=ALL_KINDS):
    """:func:`signed_distance` with its derivatives in p in closed form: (sd (..., R),
    gradient (..., R, N), Hessian (..., R, N, N)) at points p (..., N).  Where the
    distance is not twice differentiable (an edge of max(q, 0), a tie of the inside's
    max, d_i = 0) it is the derivative of one side (autodiff may take the other, or 0 for
    |d_i| at 0); elsewhere it equals autodiff of :func:`signed_distance`
    (tests/test_world.py).  What the NLP's static rows need per sample
    (:func:`jaxplan.nlp.derivs`): the kinds in ``kinds`` (static: the NLP's
    ``NLPStructure.static_kinds``) are formed and each row's selected; a row of
    another kind gets NaN (never a wrong distance).  A 10-lane evaluation of the product
    NLP (one static row) is ~70 us (~11%) cheaper than with a Hessian by autodiff through
    the selection, and a warm 10-robot replan ~16-18% faster with only the ground's kind
    (PLANE) formed than with all four (docs/SOLVER.md, Derivatives)."""
    kinds = tuple(sorted(set(kinds)))
    if not kinds or not set(kinds) <= set(ALL_KINDS):
        raise ValueError(f"kinds must be a non-empty subset of {ALL_KINDS}, got {kinds}")
    N = p.shape[-1]
    d = p[..., None, :] - center  # (..., R, N)
    jets = {}
    if SPHERE in kinds or (CYLINDER in kinds and N != 3):
        sv, sg, sH = _norm_jet(d, xp)
        jets[SPHERE] = (sv - radius, sg, sH)
    if BOX in kinds:
        sgn = xp.where(d < 0.0, -1.0, 1.0)
        bv, bg, bH = _rounded_jet(xp.abs(d) - half, xp)
        jets[BOX] = (bv, bg * sgn, bH * sgn[..., :, None] * sgn[..., None, :])
    if CYLINDER in kinds:
        jets[CYLINDER] = _cylinder_jet(d, half, radius, xp) if N == 3 else jets[SPHERE]
    if PLANE in kinds:
        jets[PLANE] = (xp.sum(d * half, axis=-1), xp.broadcast_to(half, d.shape),
                       xp.zeros(d.shape + (N,)))
    nan = np.nan
    val, grad, hess = nan, nan, nan
    for k in reversed(kinds):  # each row's kind selected; a kind not formed: NaN
        kv, kg, kH = jets[k]
        on = kind == k
        val = xp.where(on, kv, val)
        grad = xp.where(on[..., None], kg, grad)
        hess = xp.where(on[..., None, None], kH, hess)
    return val, grad, hess


def _cylinder_jet(d, half, radius, xp):
    """The signed distance's jet (value, gradient, Hessian) to vertical cylinders from
    offsets d (..., R, 3) to their centres (:func:`signed_distance_jet`)."""
    sgn = xp.where(d < 0.0, -1.0, 1.0)
    rv, rg, rH = _norm_jet(d[..., :2], xp)  # the distance from the axis
    q = xp.stack([rv - radius, xp.abs(d[..., 2]) - half[..., 2]], axis=-1)
    cv, cq, cH = _rounded_jet(q, xp)
    J = xp.concatenate([  # dq/dp (..., R, 2, 3)
        xp.concatenate([rg, xp.zeros_like(rg[..., :1])], axis=-1)[..., None, :],
        xp.concatenate([xp.zeros_like(rg), sgn[..., 2:]], axis=-1)[..., None, :]],
        axis=-2)
    cg = xp.sum(cq[..., :, None] * J, axis=-2)
    cH = xp.sum(J[..., :, :, None, None] * cH[..., :, None, :, None]
                * J[..., None, None, :, :], axis=(-4, -2))
    # the axis distance's own curvature, in the horizontal block
    cH = cH + cq[..., 0, None, None] * xp.pad(
        rH, [(0, 0)] * (rH.ndim - 2) + [(0, 1), (0, 1)])
    return cv, cg, cH


# ---------------------------------------------------------------------- NLP rows
class StaticRows(NamedTuple):
    """The world as the NLP sees it (a pytree): R rows, obstacles then workspace faces,
    padded; mask False = padding (ignored).  motion: :class:`RowMotion` in a world with
    a moving obstacle (``center`` is then where each row is at time 0: of the run, or of
    the replan after :func:`rows_at`), None in a static world."""

    kind: object  # (R,) int32
    center: object  # (R, N)
    half: object  # (R, N)
    radius: object  # (R,)
    mask: object  # (R,) bool
    motion: RowMotion | None = None


def rows_as_jax(rows: StaticRows) -> StaticRows:
    """The rows' arrays as JAX arrays (motion None stays None)."""
    return jax.tree.map(jnp.asarray, rows)


def static_rows(world: World, rows: int | None = None, knots: int | None = None) -> StaticRows:
    """The obstacles and the finite workspace faces of ``world`` as R = ``rows`` static
    rows (default: exactly those; more: masked padding; numpy arrays).  ``knots``: the
    rows' motion padded to that many knots (at least the world's; faces and padding at
    rest); default: the world's own, and no motion (None) in a static world."""
    N = world.dim
    kinds = [world.kind]
    centers = [world.center]
    halves = [world.half]
    radii = [world.radius]
    for bound, sign in ((world.lo, 1.0), (world.hi, -1.0)):
        for i in np.flatnonzero(np.isfinite(bound)):
            c = np.zeros(N)
            c[i] = bound[i]
            n = np.zeros(N)
            n[i] = sign
            kinds.append(np.array([PLANE], np.int32))
            centers.append(c[None])
            halves.append(n[None])
            radii.append(np.zeros(1))
    kind = np.concatenate(kinds).astype(np.int32)
    center = np.concatenate(centers, axis=0).reshape(-1, N)
    half = np.concatenate(halves, axis=0).reshape(-1, N)
    radius = np.concatenate(radii)
    n = kind.shape[0]
    R = n if rows is None else rows
    if R < n:
        raise ValueError(f"static_rows: the world has {n} rows, more than {R}")
    pad = R - n
    mask = np.concatenate([np.ones(n, bool), np.zeros(pad, bool)])
    kind = np.concatenate([kind, np.full(pad, PLANE, np.int32)])
    center = np.concatenate([center, np.zeros((pad, N))])
    # padding: a far-away plane (finite distances everywhere)
    pad_half = np.zeros((pad, N))
    if pad:
        pad_half[:, 0] = 1.0
    half = np.concatenate([half, pad_half])
    radius = np.concatenate([radius, np.zeros(pad)])
    if knots is None and not world.has_motion:
        return StaticRows(kind, center, half, radius, mask)
    P = world.num_knots if knots is None else knots
    if P < world.num_knots:
        raise ValueError(f"static_rows: the world's motions have {world.num_knots} knots, "
                         f"more than {P}")
    K, extra = world.num_obstacles, R - world.num_obstacles
    # obstacles' knots padded by repeating the last one; faces and padding at rest
    kt = np.concatenate([world.knot_t, np.repeat(world.knot_t[:, -1:], P - world.num_knots,
                                                 axis=1)], axis=1)
    kp = np.concatenate([world.knot_p, np.repeat(world.knot_p[:, -1:], P - world.num_knots,
                                                 axis=1)], axis=1)
    motion = RowMotion(
        np.concatenate([kt, np.zeros((extra, P))]).reshape(R, P),
        np.concatenate([kp, np.repeat(center[K:, None, :], P, axis=1)]).reshape(R, P, N),
        np.concatenate([world.knot_v, np.zeros((extra, N))]).reshape(R, N),
        np.concatenate([world.known, np.zeros(extra, bool)]),
        np.concatenate([world.moving, np.zeros(extra, bool)]))
    return StaticRows(kind, center, half, radius, mask, motion)


def face_names(world: World) -> list[str]:
    """The finite workspace faces in :func:`static_rows`' order: "x_min", ..., "z_max"
    (the lower bounds by axis, then the upper ones)."""
    axes = "xyz"[:world.dim] if world.dim <= 3 else [f"x{i}" for i in range(world.dim)]
    return [f"{axes[i]}_{side}" for bound, side in ((world.lo, "min"), (world.hi, "max"))
            for i in np.flatnonzero(np.isfinite(bound))]


def no_static_rows(N: int) -> StaticRows:
    """Zero static rows (an NLP without a world)."""
    return static_rows(World.unbounded(N))


def fleet_box(start, waypoints, margin=1.0):
    """(lo, hi) (N,) m: the axis-aligned box spanned by every robot's start and waypoints
    (its goal the last), grown by ``margin`` m on every side.

    Args: start (M, N) m; waypoints (M, W, N) m; margin m."""
    start = np.asarray(start, np.float64)
    pts = np.concatenate([start[:, None], np.asarray(waypoints, np.float64)], axis=1)
    pts = pts.reshape(-1, start.shape[1])
    return pts.min(axis=0) - margin, pts.max(axis=0) + margin


# ---------------------------------------------------------------------- checks
def point_problems(world: World, p, radius, start: bool = True
                   ) -> list[tuple[str, int | None, float]]:
    """Where a robot of ``radius`` at point p (N,) overlaps the world: a list of
    (what, obstacle index or None for the workspace, clearance m < 0).  A moving
    obstacle counts where it is at t = 0 for a ``start``, else (a goal) where it comes
    to rest, if it does (a constant velocity never does)."""
    p = np.asarray(p, np.float64)
    out = []
    for i in range(world.dim):
        for bound, gap in ((world.lo[i], p[i] - world.lo[i]), (world.hi[i], world.hi[i] - p[i])):
            if np.isfinite(bound) and gap - radius < 0:
                out.append(("workspace", None, float(gap - radius)))
    if world.num_obstacles:
        center, there = world.center, np.ones(world.num_obstacles, bool)
        if not start:  # a goal: where each obstacle stays (one that never rests: nowhere)
            there = np.all(world.knot_v == 0.0, axis=1)
            center = world.knot_p[:, -1]
        sd = signed_distance(world.kind, center, world.half, world.radius, p)
        sd = np.where(there, sd, np.inf)
        for k in np.flatnonzero(sd - radius < 0):
            out.append(("obstacle", int(k), float(sd[k] - radius)))
    return out
