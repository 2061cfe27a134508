"""The run's world in the figures: obstacles and workspace faces drawn in a 3-D view, a
top view (x-y) or a planar run, and each robot's clearance to them over time.

Drawn (light, translucent, below the paths):

* 3-D: a sphere and a vertical cylinder as coarse surfaces, a box as its six faces;
  every finite workspace face as a translucent rectangle across the view (the floor
  ``z_min`` in grey, walls and ceiling in blue-grey).
* top view and 2-D runs: a sphere's and a cylinder's disc, a box's rectangle (their
  footprints in x-y); the finite x and y faces as lines with the outside hatched.
* a moving obstacle (jaxplan/world.py, "Motion"): its body where it is at the run's
  first time, and, given the run's times (``span``), its centre's path over them as a
  dotted line with an arrowhead where it ends (:func:`obstacle_paths`).  The animation
  leaves its body out of the still scene and draws it where it is at each frame's time
  (:mod:`jaxplan.plots.animation`, :func:`moving_outlines`).

Clearances (:func:`clearances`): robot i's clearance to obstacle k at a sample is the
exact signed distance of its centre to the obstacle (:func:`jaxplan.world.signed_distance`)
minus its collision radius; negative is a contact.  Computed from the run's samples
(``RunData.pos``), so between samples they can miss a minimum; metrics.json's keys are
the exact ones.
"""

from __future__ import annotations

import numpy as np
from matplotlib.patches import Circle, Rectangle

from jaxplan.world import BOX, CYLINDER, SPHERE, World, face_names, signed_distance, static_rows

OBSTACLE_FACE = "#b08f6a"  # tan
OBSTACLE_EDGE = "#6b5138"
FLOOR = "0.55"
WALL = "#7f93b0"


def world_extent(world: World | None, near_lo, near_hi, span=None):
    """(lo, hi) (N,) m: the box [near_lo, near_hi] grown to hold the obstacles (a moving
    one along its path over ``span`` = (t0, t1) s, the run's times; at t = 0 without)
    and the finite workspace bounds, but by at most its largest side on each side (a far
    wall or a very tall pillar does not shrink the paths to a dot; what lies beyond is
    cut off)."""
    lo, hi = np.array(near_lo, np.float64), np.array(near_hi, np.float64)
    if world is None:
        return lo, hi
    reach = float(np.max(hi - lo))
    far_lo, far_hi = lo - reach, hi + reach
    paths = obstacle_paths(world, span) if span is not None else {}
    for k in range(world.num_obstacles):
        a, b = obstacle_box(world, k)
        if k in paths:  # the box swept along the path (linear between its points)
            shift = paths[k] - world.center[k]
            a, b = a + shift.min(axis=0), b + shift.max(axis=0)
        if np.any(a > far_hi) or np.any(b < far_lo):
            continue  # too far to show
        lo = np.minimum(lo, np.maximum(a, far_lo))
        hi = np.maximum(hi, np.minimum(b, far_hi))
    reach = float(np.max(hi - lo))
    for i in range(world.dim):
        if np.isfinite(world.lo[i]) and world.lo[i] >= lo[i] - reach:
            lo[i] = min(lo[i], world.lo[i])
        if np.isfinite(world.hi[i]) and world.hi[i] <= hi[i] + reach:
            hi[i] = max(hi[i], world.hi[i])
    return lo, hi


def obstacle_box(world: World, k: int, center=None):
    """The axis-aligned bounding box (lo, hi) of obstacle k (at ``center``; default
    where it is at t = 0)."""
    c = world.center[k] if center is None else np.asarray(center, np.float64)
    kind = int(world.kind[k])
    if kind == BOX:
        h = world.half[k]
    elif kind == CYLINDER and world.dim == 3:
        h = np.array([world.radius[k], world.radius[k], world.half[k, 2]])
    else:
        h = np.full(world.dim, world.radius[k])
    return c - h, c + h


def obstacle_paths(world: World | None, span) -> dict[int, np.ndarray]:
    """{k: (P, N) m} the centre of each obstacle that moves during ``span`` = (t0, t1) s,
    at t0, at its knots inside the span and at t1: the exact polyline of its
    piecewise-linear motion (jaxplan/world.py, "Motion"); an obstacle that stays put
    over the span has none."""
    if world is None or not world.has_motion:
        return {}
    t0, t1 = (float(x) for x in span)
    out = {}
    for k in np.flatnonzero(world.moving):
        kt = world.knot_t[k]
        t = np.unique(np.concatenate([[t0, t1], kt[(kt > t0) & (kt < t1)]]))
        p = world.center_at(t)[0][:, k]
        if np.any(p != p[0]):
            out[int(k)] = p
    return out


def start_centres(world: World, span) -> np.ndarray:
    """(K, N) m: the obstacles where they are at the run's first time (span[0]; t = 0
    without a span)."""
    return world.center if span is None else world.center_at(float(span[0]))[0]


def moving_outlines(world: World | None, project, span=None):
    """The outlines of the obstacles that move during ``span`` as the view shows them:
    {k: (V, 2) display points relative to the projection of the obstacle's centre},
    ``project`` mapping positions (..., N) m to display points (..., 2) (an
    orthographic view or a 2-D axes: affine, so that moving the obstacle moves its
    outline by its centre's projected motion).  The outline is the convex hull of the
    projected body (a sphere's or a cylinder's surface points): exact up to the
    sampling of its circles (48 points)."""
    from scipy.spatial import ConvexHull

    out = {}
    if world is None:
        return out
    ks = obstacle_paths(world, span) if span is not None else np.flatnonzero(world.moving)
    ring = np.linspace(0.0, 2.0 * np.pi, 48, endpoint=False)
    for k in ks:
        r = world.radius[k]
        if world.dim == 2:
            rel = np.column_stack([r * np.cos(ring), r * np.sin(ring)])
        elif int(world.kind[k]) == CYLINDER:
            h = world.half[k, 2]
            rel = np.concatenate([np.column_stack([r * np.cos(ring), r * np.sin(ring),
                                                   np.full(ring.size, z)]) for z in (-h, h)])
        else:  # a sphere: circles of latitude
            lat = np.linspace(-np.pi / 2, np.pi / 2, 13)
            u, v = np.meshgrid(ring, lat)
            rel = r * np.column_stack([(np.cos(u) * np.cos(v)).ravel(),
                                       (np.sin(u) * np.cos(v)).ravel(), np.sin(v).ravel()])
        c = world.center[k]
        px = project(c + rel) - project(c[None])[0]
        out[int(k)] = px[ConvexHull(px).vertices]
    return out


# ----------------------------------------------------------------------------- drawing


def draw_world_3d(ax, world: World | None, lim, span=None, moving: bool = True) -> None:
    """Obstacles and finite workspace faces on a 3-D axes whose limits are ``lim``
    (3, 2); boxes and cylinders are cut at the limits, obstacles outside them left out.
    ``span``: (t0, t1) s, the run's times: the obstacles where they are at t0, and each
    moving one's path over them (module docstring); None: at t = 0, no paths.
    ``moving``: False leaves the moving obstacles' bodies out (the animation's)."""
    if world is None:
        return
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    for i, bound, name in _faces_in_view(world, lim):
        a, b = [j for j in range(3) if j != i]
        quad = np.zeros((4, 3))
        quad[:, i] = bound
        quad[:, a] = [lim[a, 0], lim[a, 1], lim[a, 1], lim[a, 0]]
        quad[:, b] = [lim[b, 0], lim[b, 0], lim[b, 1], lim[b, 1]]
        floor = name == "z_min"
        ax.add_collection3d(Poly3DCollection(
            [quad], facecolors=FLOOR if floor else WALL, alpha=0.22 if floor else 0.10,
            edgecolors="0.35" if floor else WALL, linewidths=0.6))
    centres = start_centres(world, span)
    for p in (obstacle_paths(world, span) if span is not None else {}).values():
        _draw_path(ax, p)
    for k in range(world.num_obstacles):
        kind, c = int(world.kind[k]), centres[k]
        if world.moving[k] and not moving:
            continue
        a, b = obstacle_box(world, k, c)
        a, b = np.maximum(a, lim[:, 0]), np.minimum(b, lim[:, 1])
        if np.any(a >= b):
            continue  # outside the view
        style = dict(color=OBSTACLE_FACE, alpha=0.35, linewidth=0, shade=True)
        if kind == SPHERE:
            u, v = np.meshgrid(np.linspace(0, 2 * np.pi, 17), np.linspace(0, np.pi, 9))
            r = world.radius[k]
            ax.plot_surface(c[0] + r * np.cos(u) * np.sin(v), c[1] + r * np.sin(u) * np.sin(v),
                            c[2] + r * np.cos(v), **style)
        elif kind == CYLINDER:
            r = world.radius[k]
            u, z = np.meshgrid(np.linspace(0, 2 * np.pi, 25), np.array([a[2], b[2]]))
            ax.plot_surface(c[0] + r * np.cos(u), c[1] + r * np.sin(u), z, **style)
            ring = np.linspace(0, 2 * np.pi, 25)
            caps = [np.column_stack([c[0] + r * np.cos(ring), c[1] + r * np.sin(ring),
                                     np.full(ring.size, zc)]) for zc in (a[2], b[2])]
            ax.add_collection3d(Poly3DCollection(caps, facecolors=OBSTACLE_FACE, alpha=0.35,
                                                 edgecolors=OBSTACLE_EDGE, linewidths=0.5))
        else:
            ax.add_collection3d(Poly3DCollection(
                _box_faces((a + b) / 2, (b - a) / 2), facecolors=OBSTACLE_FACE, alpha=0.35,
                edgecolors=OBSTACLE_EDGE, linewidths=0.6))


def _box_faces(c, h):
    """The six faces (6, 4, 3) of the box centre c, half extents h."""
    s = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], np.float64)
    faces = []
    for i in range(3):
        a, b = [j for j in range(3) if j != i]
        for side in (-1.0, 1.0):
            q = np.zeros((4, 3))
            q[:, i] = c[i] + side * h[i]
            q[:, a] = c[a] + s[:, 0] * h[a]
            q[:, b] = c[b] + s[:, 1] * h[b]
            faces.append(q)
    return np.stack(faces)


def _faces_in_view(world: World, lim):
    """(axis, bound, name) of the finite faces inside the view ``lim`` (n, 2): its n
    first axes."""
    out = []
    names = iter(face_names(world))
    for bound in (world.lo, world.hi):
        for i in np.flatnonzero(np.isfinite(bound)):
            name = next(names)
            if i >= lim.shape[0]:
                continue  # not in this view (z in a top view)
            tol = 1e-9 * max(1.0, float(lim[i, 1] - lim[i, 0]))
            if lim[i, 0] - tol <= bound[i] <= lim[i, 1] + tol:
                out.append((int(i), float(bound[i]), name))
    return out


def draw_world_2d(ax, world: World | None, lim, span=None, moving: bool = True) -> None:
    """Obstacle footprints and the finite x, y workspace faces on a 2-D axes (a planar
    run, or the top view of a 3-D one) whose limits are ``lim`` (>= 2, 2); ``span`` and
    ``moving`` as in :func:`draw_world_3d`."""
    if world is None:
        return
    for i, bound, name in _faces_in_view(world, lim):
        outside = (lim[i, 0], bound) if name.endswith("min") else (bound, lim[i, 1])
        span = lim[1 - i]
        if i == 0:
            ax.axvline(bound, color=WALL, lw=1.6, zorder=1)
            ax.add_patch(Rectangle((outside[0], span[0]), outside[1] - outside[0],
                                   span[1] - span[0], facecolor=WALL, alpha=0.12,
                                   hatch="//", edgecolor=WALL, lw=0, zorder=0))
        else:
            ax.axhline(bound, color=WALL, lw=1.6, zorder=1)
            ax.add_patch(Rectangle((span[0], outside[0]), span[1] - span[0],
                                   outside[1] - outside[0], facecolor=WALL, alpha=0.12,
                                   hatch="//", edgecolor=WALL, lw=0, zorder=0))
    centres = start_centres(world, span)
    for p in (obstacle_paths(world, span) if span is not None else {}).values():
        _draw_path(ax, p[:, :2])
    for k in range(world.num_obstacles):
        c = centres[k]
        if world.moving[k] and not moving:
            continue
        style = dict(facecolor=OBSTACLE_FACE, edgecolor=OBSTACLE_EDGE, alpha=0.55, lw=0.8,
                     zorder=1)
        if int(world.kind[k]) == BOX:
            h = world.half[k]
            ax.add_patch(Rectangle((c[0] - h[0], c[1] - h[1]), 2 * h[0], 2 * h[1], **style))
        else:
            ax.add_patch(Circle((c[0], c[1]), world.radius[k], **style))


PATH_STYLE = dict(color=OBSTACLE_EDGE, lw=1.6, ls=":", alpha=0.9)


def _draw_path(ax, p) -> None:
    """A moving obstacle's centre path p (P, 2 or 3) m: dotted, with an arrowhead at its
    end pointing along its last stretch."""
    ax.plot(*p.T, zorder=2, **PATH_STYLE)
    step = np.diff(p, axis=0)
    last = step[np.flatnonzero(np.any(step != 0.0, axis=1))[-1]]
    size = 0.1 * float(np.sum(np.linalg.norm(step, axis=1)))  # the head: 10 % of the path
    tail = p[-1] - last / np.linalg.norm(last) * max(size, 1e-9)
    if p.shape[1] == 3:
        ax.quiver(*tail, *(p[-1] - tail), color=OBSTACLE_EDGE, arrow_length_ratio=1.0,
                  linewidth=1.4)
    else:
        ax.annotate("", xy=p[-1], xytext=tail, zorder=2,
                    arrowprops=dict(arrowstyle="-|>", color=OBSTACLE_EDGE, lw=1.4,
                                    mutation_scale=14, shrinkA=0, shrinkB=0))


# --------------------------------------------------------------------------- clearance


def clearances(world: World | None, pos, radius, t=None):
    """Sampled clearances of a run (module docstring).

    Args:
        world: the run's World (or None).  pos: (M, K, N) m.  radius: (M,) m.  t: (K,)
        s, the samples' times: a moving obstacle where it is then (None: at t = 0).
    Returns:
        (obstacle (M, K, n_obstacles), workspace (M, K, n_faces)) m: each robot's
        clearance to each obstacle / finite face at each sample (n = 0: empty).
    """
    pos = np.asarray(pos, np.float64)
    m, k, _ = pos.shape
    if world is None:
        return np.zeros((m, k, 0)), np.zeros((m, k, 0))
    rows = static_rows(world)
    center = rows.center
    if t is not None and world.has_motion:  # (K, R, N): the obstacles where they are then
        center = np.broadcast_to(center, (k,) + center.shape).copy()
        center[:, :world.num_obstacles] = world.center_at(np.asarray(t, np.float64))[0]
    out = np.empty((m, k, rows.kind.shape[0]))
    for i in range(m):  # one robot at a time bounds the memory: (K, R, N)
        out[i] = signed_distance(rows.kind, center, rows.half, rows.radius,
                                 pos[i]) - radius[i]
    n = world.num_obstacles
    return out[..., :n], out[..., n:]
