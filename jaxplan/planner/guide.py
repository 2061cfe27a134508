"""The way round a wall, a coarse global guide through the static world: built on the
host once per run, used by a replan's goals stage (:mod:`jaxplan.planner.goals`).

Each robot's NLP is local: it bends its plan round the obstacles near the straight line
to its goal, but a robot whose goal lies behind a wall, with the opening off to one
side, has no local reason to fly away from its goal to the opening: it hovers at the
wall.  The world is static and known, so its way round is computed once per run, on
the host:

    guide_field(world, waypoints, radius) -> GuideField      numpy, once per run

a grid over the workspace (its finite bounds, else the starts', goals' and obstacles'
box grown by GUIDE_MARGIN_M, in a grid of GUIDE_CELLS nodes per axis, fixed so that
every run of a dimension has one shape, and one spacing on every axis), and for each
waypoint and robot the length of the shortest grid path from every node to the robot's
goal (Dijkstra, :mod:`scipy.sparse.csgraph`, on the 8- or 26-neighbour grid; an edge
with an end whose clearance to the static rows is below the robot's planning radius
costs BLOCKED_COST times its length, so every node has a finite value and the field
leads out of an obstacle too).

Every replan, in the planner (:func:`guide_goals`, jit-able; applied by
:func:`jaxplan.planner.goals.guided_goals`): a robot whose straight line
to its goal passes through an obstacle (the segment's least clearance sd < 0,
:func:`segment_clearance`: the body itself, not the margin round it, which the NLP
handles) and whose way round is more than DETOUR_M longer than the grid path in free
space (:func:`grid_distance`) plans instead to a *guide point*: it follows the field's
descent (the multilinear interpolation's gradient, GUIDE_STEPS steps of GUIDE_STEP_M)
from where it is, and takes the farthest of the points 1, 2, 3, 4 m down that path that
it sees with its planning radius clear, else the farthest it sees at all, else the
first step.  It plans to stop there (a rest end, as a sidestep sub-goal); the point
moves on with it every replan.  A robot that sees its goal plans to it as before: in a
world without obstacles (every paper scenario) nothing changes, and the guide is not
even built ([planner] guide = "auto").
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.ndimage import map_coordinates
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from jaxplan.planner.types import GuideField
from jaxplan.world import BOX, StaticRows, World, signed_distance, static_rows

GUIDE_MODES = ("auto", "on", "off")
GUIDE_CELLS = {2: (96, 96), 3: (48, 48, 24)}  # grid nodes per axis, by dimension
GUIDE_MARGIN_M = 2.0  # m round the starts, goals and obstacles of an unbounded axis
BLOCKED_COST = 100.0  # an edge into or out of a blocked node costs this times its length
SEGMENT_ITERS = 40  # golden-section steps of a segment's clearance (0.618^40 ~ 4e-9)
# m: the guide is taken only where the way round is this much longer than the grid's
# free-space path: a pillar on the line is the NLP's to swerve round, a wall is not
# (a rest end ahead slows a robot that its NLP would take round a pillar at speed)
DETOUR_M = 1.0
GUIDE_STEPS = 16  # descent steps from the robot
GUIDE_STEP_M = 0.25  # m per step (so the guide point is at most 4 m ahead)
GUIDE_EVERY = 4  # candidate guide points: every 4th step (1, 2, 3, 4 m down the field)


def guide_enabled(mode: str, world: World) -> bool:
    """Whether a run builds and uses the guide: "on", or "auto" with static obstacles
    (the guide goes round the static world; moving obstacles are the NLP's)."""
    if mode not in GUIDE_MODES:
        raise ValueError(f"guide must be one of {GUIDE_MODES}, got {mode!r}")
    return mode == "on" or (mode == "auto" and bool(np.any(~world.moving)))


def grid_box(world: World, points) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) (N,) of the guide grid: the workspace's finite bounds, else the box of
    ``points`` (..., N) and the obstacles grown by GUIDE_MARGIN_M."""
    N = world.dim
    pts = np.asarray(points, float).reshape(-1, N)
    ext = [pts]
    if world.num_obstacles:
        size = np.where(world.kind[:, None] == BOX, world.half,
                        np.maximum(world.radius[:, None], world.half))
        ext += [world.center - size, world.center + size]
    allp = np.concatenate(ext)
    lo = np.where(np.isfinite(world.lo), world.lo, allp.min(0) - GUIDE_MARGIN_M)
    hi = np.where(np.isfinite(world.hi), world.hi, allp.max(0) + GUIDE_MARGIN_M)
    hi = np.maximum(hi, lo + 1e-3)
    return lo, hi


def _edges(shape):
    """(rows, cols, offsets) of the grid graph: every node to its neighbours in the
    positive half of {-1, 0, 1}^N (the graph is undirected)."""
    N = len(shape)
    idx = np.arange(int(np.prod(shape))).reshape(shape)
    offs = [np.array(o) - 1 for o in np.ndindex(*(3,) * N)]
    offs = [o for o in offs if next((x for x in o if x != 0), 0) > 0]
    rows, cols, which = [], [], []
    for k, o in enumerate(offs):
        src = tuple(slice(max(0, -x), s - max(0, x)) for x, s in zip(o, shape, strict=True))
        dst = tuple(slice(max(0, x), s + min(0, x)) for x, s in zip(o, shape, strict=True))
        a, b = idx[src].ravel(), idx[dst].ravel()
        rows.append(a)
        cols.append(b)
        which.append(np.full(a.shape, k))
    return np.concatenate(rows), np.concatenate(cols), np.concatenate(which), np.array(offs)


def guide_field(world: World, waypoints, radius, starts=None) -> GuideField:
    """The guide of a run (module doc): waypoints (M, W, N) each robot's goals, radius
    (M,) m its planning radius; starts (M, N) (grid extent only).  numpy arrays."""
    wp = np.asarray(waypoints, float)
    M, W, N = wp.shape
    shape = GUIDE_CELLS[N]
    lo, hi = grid_box(world, wp if starts is None else np.concatenate(
        [wp.reshape(-1, N), np.asarray(starts, float).reshape(-1, N)]))
    # one spacing on every axis (a grid path is then at most 8.3% (2-D) longer than
    # the straight line it stands for), the box centred in the grid
    n1 = np.array(shape) - 1
    spacing = np.full(N, np.max((hi - lo) / n1))
    lo = 0.5 * (lo + hi) - 0.5 * spacing * n1
    axes = [lo[i] + spacing[i] * np.arange(shape[i]) for i in range(N)]
    nodes = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, N)
    rows = static_rows(world.static_part())  # the moving obstacles are not in the way
    if rows.mask.shape[0]:
        sd = signed_distance(rows.kind, rows.center, rows.half, rows.radius, nodes).min(-1)
    else:
        sd = np.full(nodes.shape[0], np.inf)
    a, b, which, offs = _edges(shape)
    length = np.linalg.norm(offs * spacing, axis=-1)[which]
    radius = np.asarray(radius, float).reshape(M)
    value = np.zeros((W, M) + tuple(shape))
    for r in np.unique(radius):
        free = sd >= r
        cost = length * np.where(free[a] & free[b], 1.0, BLOCKED_COST)
        n = nodes.shape[0]
        graph = coo_matrix((cost, (a, b)), shape=(n, n)).tocsr()
        who = np.flatnonzero(radius == r)
        goals = wp[who].reshape(-1, N)
        cell = np.rint((np.clip(goals, lo, hi) - lo) / spacing).astype(int)
        src = np.ravel_multi_index(tuple(cell.T), shape)
        dist = dijkstra(graph, directed=False, indices=src)  # (len(who) W, n)
        dist = np.where(np.isfinite(dist), dist, np.nanmax(dist[np.isfinite(dist)]))
        value[:, who] = dist.reshape(len(who), W, *shape).swapaxes(0, 1)
    return GuideField(value, lo, spacing)


def field_value(value, origin, spacing, p):
    """The multilinear interpolation of one field ``value`` (*G) at p (N,) (clamped to
    the grid)."""
    shape = jnp.asarray(value.shape, p.dtype)
    u = jnp.clip((p - origin) / spacing, 0.0, shape - 1.0)
    return map_coordinates(value, [u[i] for i in range(p.shape[0])], order=1, mode="nearest")


def _row_sd(static: StaticRows, pts):
    """Signed distance of row r to point r: pts (R, N) -> (R,)."""
    one = lambda k, c, h, rad, q: signed_distance(  # noqa: E731
        k[None], c[None], h[None], rad[None], q, xp=jnp)[0]
    return jax.vmap(one)(static.kind, static.center, static.half, static.radius, pts)


def segment_clearance(static: StaticRows, a, b):
    """Least signed distance (m) of the segment a -> b (N,) to the static rows: each
    row's minimum along it by golden-section search (SEGMENT_ITERS steps; a convex
    body's signed distance is convex along a line, a face's is linear), the endpoints
    included, so that no thin wall slips between samples."""
    R = static.mask.shape[0]
    at = lambda t: a[None] + t[:, None] * (b - a)[None]  # noqa: E731
    f = lambda t: _row_sd(static, at(t))  # noqa: E731
    lo, hi = jnp.zeros(R, a.dtype), jnp.ones(R, a.dtype)
    g = 0.5 * (np.sqrt(5.0) - 1.0)

    def body(_, lh):
        lo, hi = lh
        m1, m2 = hi - g * (hi - lo), lo + g * (hi - lo)
        left = f(m1) < f(m2)
        return jnp.where(left, lo, m1), jnp.where(left, m2, hi)

    lo, hi = jax.lax.fori_loop(0, SEGMENT_ITERS, body, (lo, hi))
    best = jnp.minimum(jnp.minimum(f(lo), f(hi)),
                       jnp.minimum(f(jnp.zeros(R, a.dtype)), f(jnp.ones(R, a.dtype))))
    return jnp.min(jnp.where(static.mask, best, jnp.inf))


def grid_distance(d):
    """The length of the shortest path along the grid's 8 or 26 directions for a step
    d (N,) in free space (equal spacing): with |d| sorted a >= b (>= c), (a - b) +
    sqrt(2) b in the plane, (a - b) + sqrt(2) (b - c) + sqrt(3) c in 3-D; what the field
    holds where no obstacle is in the way."""
    a = jnp.sort(jnp.abs(d))[::-1]
    if a.shape[0] == 2:
        return (a[0] - a[1]) + np.sqrt(2.0) * a[1]
    return (a[0] - a[1]) + np.sqrt(2.0) * (a[1] - a[2]) + np.sqrt(3.0) * a[2]


def guide_goals(value, origin, spacing, static: StaticRows, radius, p, goal_p):
    """Each robot's guide point and whether it uses it (module doc).  value: (M, *G) the
    fields of the current waypoint; radius (M,) planning radii; p, goal_p (M, N).
    Returns (point (M, N), use (M,) bool).  The descent and the views are computed only
    in a replan where some robot uses the guide (a fleet-wide cond): most replans pay
    one segment's clearance per robot."""
    val = lambda F, q: field_value(F, origin, spacing, q)  # noqa: E731

    def needs(F, p, g):
        g = jnp.where(jnp.isfinite(g), g, p)
        detour = val(F, p) - grid_distance(g - p)
        return (segment_clearance(static, p, g) < 0.0) & (detour > DETOUR_M)

    def point(F, r, p):
        grad = jax.grad(lambda q: val(F, q))

        def step(q, _):
            d = grad(q)
            n = jnp.linalg.norm(d)
            q = jnp.where(n > 1e-9, q - GUIDE_STEP_M * d / jnp.maximum(n, 1e-9), q)
            return q, q

        _, path = jax.lax.scan(step, p, None, length=GUIDE_STEPS)  # (S, N)
        cand = path[GUIDE_EVERY - 1::GUIDE_EVERY]  # (C, N)
        seen = jax.vmap(lambda q: segment_clearance(static, p, q))(cand)  # (C,)
        k = jnp.arange(cand.shape[0])
        k_clear = jnp.max(jnp.where(seen >= r, k, -1))
        k_any = jnp.max(jnp.where(seen >= 0.0, k, -1))
        q = jnp.where(k_clear >= 0, cand[k_clear], jnp.where(k_any >= 0, cand[k_any], path[0]))
        return jnp.where(jnp.all(jnp.isfinite(q)), q, p)

    use = jax.vmap(needs)(value, p, goal_p)
    pts = jax.lax.cond(jnp.any(use), lambda: jax.vmap(point)(value, radius, p), lambda: p)
    return pts, use
