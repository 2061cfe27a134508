"""Exact clearance of the executed plan pieces to the world (host, NumPy): the obstacles
and the workspace faces of a :class:`jaxplan.world.World` (docs/DESIGN.md "A run
directory").

    world_clearance(seg_robot, seg_t0, seg_t1, seg_coeffs, radius, world) -> WorldClearance
    world_report(clearance) -> dict        the metrics.json keys

The pieces are those of :mod:`jaxplan.metrics` (its docstring).  The clearance of robot
i to obstacle k at time t is ``sd_k(x_i(t)) - r_i``: the exact Euclidean signed
distance from the robot's centre to the obstacle's surface (negative inside) minus the
robot's radius, so that a clearance below 0 means the body overlaps the obstacle.  The
clearance to a workspace face is the distance from the centre to the face's plane,
inwards, minus the radius (below 0: the body leaves the workspace).

Method.  Every minimum is the minimum of the exact clearance over a finite set of
candidate times per piece that is proven to contain the minimiser; the candidates are
points of the piece, evaluated from the ORIGINAL coefficients (Horner in t - seg_t0,
then the exact distance, no smoothing), so the reported value is always one the
trajectory really takes (never below the true minimum by more than round-off) and, the
minimiser being a candidate, equal to it up to the accuracy of the roots.  Roots come
from the machinery of the pairwise separation (:mod:`jaxplan.metrics.pieces`: each piece
re-expressed in u in [0, 1], batched companion eigenvalues, the real part of every
eigenvalue clipped to [0, 1] a candidate, Bernstein exclusion), each root polished by
two Newton steps on its own polynomial (polished copies added, not substituted).
Extra candidates never hurt (each is a real point of the piece); a missed minimiser
would, and the cases below show that none is missed.

- Workspace face (a plane): the clearance is a polynomial g(u); its minimum on [0, 1]
  is at 0, 1 or a root of g'.
- Sphere (and a 2-D cylinder, a disc): sd = |d| - R with d = x - c; the minimum of
  |d|^2 is at 0, 1 or a root of d . d' (as for a robot pair).
- Box (half extents h): the piece is cut at the roots of d_i -+ h_i (the times it
  crosses a face's plane).  On each cut the set of axes outside the slab |d_i| <= h_i
  and their sides s_i are fixed.  Some axis outside: sd^2 = sum_{outside} (d_i - s_i
  h_i)^2, a polynomial, minimal at the cut's ends or at a root of sum (d_i - s_i h_i)
  d_i'.  Every axis inside: sd = max over (i, s) of s d_i - h_i, an upper envelope of
  2N polynomials, whose minimum lies where one active branch is stationary (a root of
  d_i') or two branches are equal (roots of d_i, the kink of |d_i|, and of s d_i -
  s' d_j - h_i + h_j).
- Cylinder (3-D, vertical axis, radius R, half height H): with P = dx^2 + dy^2 (rho^2)
  and dz, the piece is cut at the roots of P - R^2 and dz -+ H.  Beside the cylinder
  (rho > R, |dz| <= H) sd = rho - R, minimal where P' = 0; above or below it (rho <=
  R) sd = s dz - H, minimal where dz' = 0; inside sd = max(rho - R, |dz| - H), minimal
  where a branch is stationary (P' = 0, dz' = 0, dz = 0) or the branches cross: rho =
  s dz - H + R, squared P - (s dz - H + R)^2 = 0 (a polynomial).  At the rim (rho > R,
  |dz| > H) sd = sqrt((rho - R)^2 + w^2) with w = s dz - H, and sqrt(P) is not a
  polynomial; the stationary condition (rho - R) P' / (2 rho) + w w' = 0 rearranges to
  rho (P' + 2 w w') = R P', and squaring both sides gives the polynomial equation
  P (P' + 2 w w')^2 - R^2 P'^2 = 0 (degree 6D - 2) whose roots contain every
  stationary point of the rim distance (squaring only adds roots, harmless extra
  candidates).  So the cylinder is exact as well, with no bound-and-refine step.

Moving obstacles (:mod:`jaxplan.world`, "Motion": a piecewise-linear centre c(t)).
Each piece is cut at the obstacle's knot times; on each cut [a, b] the centre moves
linearly, c(t) = c(a) + v (t - a), so the relative position x(t) - c(t) is again a
polynomial: the piece's coefficients re-expressed in t - a (the Taylor shift of
:func:`jaxplan.metrics.pieces.to_unit`), minus c(a) in the constant term and v in the
linear one.  The relative pieces then go through the machinery above against the
obstacle centred at the origin (so the candidates and the values are those of the
relative polynomials: exact up to the round-off of the shift, ~1e-15 relative).  A
static obstacle (a world without motion, or the static obstacles of one with) is solved
exactly as before, on the original pieces.

Speed.  Only the (piece, obstacle) and (piece, face) pairs that can hold their (robot,
obstacle) or (robot, face) minimum are solved: a lower bound per pair (the distance from
the piece's Bernstein bounding box, which encloses the piece, to the obstacle or the
plane) is compared with an upper bound per robot pair (the smallest clearance at the
end points of that robot's pieces), as :mod:`jaxplan.metrics.separation` prunes robot
pairs.  For obstacles a second pass then solves, per (robot, obstacle), the piece of the
smallest lower bound first; its exact minimum is attained, so the other pieces are
solved only where their lower bound lies below it (by more than 1e-13 x the piece's
coefficient size, far above the round-off of the bounds: a robot at rest beside an
obstacle is one piece, not all of them).  Duplicate candidates are dropped before the
evaluation.
Cost: docs/SOLVER.md, "Metrics".
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from jaxplan.metrics.candidates import box_candidates, compact, cylinder_candidates, roots
from jaxplan.metrics.pieces import (
    CHUNK,
    bernstein,
    check_pieces,
    deriv,
    horner,
    stationary_candidates,
    to_unit,
)
from jaxplan.world import BOX, CYLINDER, SPHERE, World, path_at

__all__ = ["WorldClearance", "world_clearance", "world_report", "face_names",
           "exact_signed_distance"]

_AXES = "xyz"


def face_names(N: int) -> tuple[str, ...]:
    """The 2N workspace faces in :class:`WorldClearance` order: x_min, x_max, y_min, ..."""
    return tuple(f"{_AXES[i] if N <= 3 else f'x{i}'}_{side}"
                 for i in range(N) for side in ("min", "max"))


class WorldClearance(NamedTuple):
    """Exact minimum clearances of M robots to a world with K obstacles in N-D.

    obstacle (M, K) m: min over time of sd_k(x_i(t)) - r_i (inf: robot i has no piece).
    obstacle_t (M, K) s: a time attaining it (NaN where inf).
    face (M, 2N) m: min over time of the clearance to each workspace face (faces in
        :func:`face_names` order; inf for an unbounded face or a robot without pieces).
    face_t (M, 2N) s: a time attaining it (NaN where inf).
    face_finite (2N,) bool: which faces bound the workspace.
    """

    obstacle: np.ndarray
    obstacle_t: np.ndarray
    face: np.ndarray
    face_t: np.ndarray
    face_finite: np.ndarray


# ---------------------------------------------------------------------- distances


def exact_signed_distance(kind, center, half, radius, p):
    """Exact signed distance (m, negative inside) of points p (B, C, N) to one obstacle
    per row (kind (B,), center (B, N), half (B, N), radius (B,)) -> (B, C).  No
    smoothing (unlike :func:`jaxplan.world.signed_distance`, made for the SQP)."""
    out = np.empty(p.shape[:2])
    for code in (SPHERE, BOX, CYLINDER):
        sel = np.nonzero(kind == code)[0]
        if sel.size:
            out[sel] = _sd_kind(code, center[sel], half[sel], radius[sel], p[sel])
    return out


def _sd_kind(code, center, half, radius, p):
    """:func:`exact_signed_distance` for rows of one kind."""
    d = p - center[:, None, :]
    if code == SPHERE or (code == CYLINDER and p.shape[-1] != 3):
        return np.sqrt(np.sum(d * d, axis=-1)) - radius[:, None]
    if code == BOX:
        q = np.abs(d) - half[:, None, :]
    else:
        q = np.stack([np.hypot(d[..., 0], d[..., 1]) - radius[:, None],
                      np.abs(d[..., 2]) - half[:, None, 2]], axis=-1)
    return np.sqrt(np.sum(np.maximum(q, 0.0) ** 2, axis=-1)) + np.minimum(q.max(axis=-1), 0.0)


# ---------------------------------------------------------------------- bounds


def _obstacle_lower_bounds(lo, hi, world: World):
    """Lower bounds (S, K) of the signed distance of pieces enclosed in the boxes
    [lo, hi] (S, N) to each obstacle; -inf where the box may reach inside."""
    c, h, R = world.center, world.half, world.radius  # (K, N), (K, N), (K,)
    N = world.dim
    # gap per axis between [lo, hi] and [c - a, c + a]
    def gaps(a):
        return np.maximum(np.maximum(lo[:, None, :] - (c + a)[None],
                                     (c - a)[None] - hi[:, None, :]), 0.0)

    sph = np.sqrt(np.sum(gaps(np.zeros_like(c)) ** 2, axis=-1)) - R  # (S, K), >= -R
    g = gaps(h)
    box = np.sqrt(np.sum(g**2, axis=-1))
    box = np.where(box > 0.0, box, -np.inf)
    if N == 3:
        rad = np.sqrt(np.sum(gaps(np.zeros_like(c))[..., :2] ** 2, axis=-1)) - R
        g = gaps(h)[..., 2]
        cyl = np.sqrt(np.maximum(rad, 0.0) ** 2 + g**2)
        cyl = np.where(cyl > 0.0, cyl, -np.inf)
    else:
        cyl = sph
    k = world.kind[None, :]
    return np.where(k == SPHERE, sph, np.where(k == BOX, box, cyl))


def _keep(lb, ub_row, scale):
    """Rows whose lower bound can reach their robot pair's upper bound (exact pruning)."""
    return lb <= ub_row + 1e-9 * (1.0 + scale + np.abs(ub_row))


def _scatter_min(M, W, pair, val, t):
    """Per-(robot, x) minimum and a time attaining it: (M, W), (M, W)."""
    flat = np.full(M * W, np.inf)
    np.minimum.at(flat, pair, val)
    tt = np.full(M * W, np.nan)
    hit = val == flat[pair]
    tt[pair[hit]] = t[hit]
    return flat.reshape(M, W), tt.reshape(M, W)


# ---------------------------------------------------------------------- public


def world_clearance(seg_robot, seg_t0, seg_t1, seg_coeffs, radius, world: World,
                    num_robots=None) -> WorldClearance:
    """Exact minimum clearance of every robot to every obstacle and workspace face.

    Args:
        seg_robot, seg_t0, seg_t1, seg_coeffs: the executed pieces (:mod:`jaxplan.metrics`).
        radius: (M,) m, each robot's body radius.
        world: the :class:`jaxplan.world.World` (N-D, as the pieces).
        num_robots: M (default ``len(radius)``).

    Returns:
        :class:`WorldClearance`.  Method and cost: the module docstring.
    """
    radius = np.asarray(radius, np.float64)
    if num_robots is None:
        num_robots = radius.shape[0]
    r, t0, t1, c, M, _ = check_pieces(seg_robot, seg_t0, seg_t1, seg_coeffs, num_robots)
    N = c.shape[1]
    if radius.shape != (M,):
        raise ValueError(f"radius must be (M,) = ({M},); got {radius.shape}")
    if world.dim != N:
        raise ValueError(f"the world is {world.dim}-D, the pieces {N}-D")
    K = world.num_obstacles
    bounds = np.stack([world.lo, world.hi], axis=1).reshape(-1)  # (2N,) in face order
    finite = np.isfinite(bounds)
    res = WorldClearance(np.full((M, K), np.inf), np.full((M, K), np.nan),
                         np.full((M, 2 * N), np.inf), np.full((M, 2 * N), np.nan), finite)
    S = r.size
    if S == 0:
        return res
    cu, lo, hi, scale, ends = _prepare(t0, t1, c)
    moving = world.moving
    if K and not moving.any():
        _obstacles(res, r, t0, t1, c, cu, lo, hi, scale, ends, radius, world)
    elif K:
        fixed = np.flatnonzero(~moving)
        if fixed.size:  # the static obstacles: as in a static world
            part = _empty(M, fixed.size, N)
            _obstacles(part, r, t0, t1, c, cu, lo, hi, scale, ends, radius, world.static_part())
            res.obstacle[:, fixed], res.obstacle_t[:, fixed] = part.obstacle, part.obstacle_t
        for k in np.flatnonzero(moving):
            res.obstacle[:, k], res.obstacle_t[:, k] = _moving_obstacle(r, t0, t1, c, radius,
                                                                        world, k)
    if finite.any():
        _faces(res, r, t0, t1, c, cu, lo, hi, scale, ends, radius, bounds, finite)
    return res


def _empty(M, K, N):
    return WorldClearance(np.full((M, K), np.inf), np.full((M, K), np.nan),
                          np.full((M, 2 * N), np.inf), np.full((M, 2 * N), np.nan),
                          np.zeros(2 * N, bool))


def _prepare(t0, t1, c):
    """Pieces c (S, N, L) in t - t0 -> (cu (S, N, L) in u, the enclosing boxes lo, hi
    (S, N) (Bernstein), the coefficient sizes (S,), the end points (S, 2, N))."""
    cu = to_unit(c, np.zeros(c.shape[0]), t1 - t0)  # (S, N, L) in u
    bern = cu @ bernstein(cu.shape[2] - 1)
    lo, hi = bern.min(axis=-1), bern.max(axis=-1)  # enclosing box of each piece
    scale = np.abs(cu).sum(axis=(1, 2))
    ends = np.stack([c[:, :, 0], cu.sum(axis=2)], axis=1)  # (S, 2, N): x(t0), x(t1)
    return cu, lo, hi, scale, ends


def _moving_obstacle(r, t0, t1, c, radius, world: World, k: int):
    """(min clearance (M,), a time attaining it (M,)) of every robot to moving obstacle
    k: the pieces cut at its knot times, relative to its linear motion on each cut,
    against the obstacle at the origin (module doc)."""
    M, N = radius.shape[0], c.shape[1]
    kt = world.knot_t[k]
    cuts = np.sort(np.concatenate([t0[:, None], np.clip(kt[None, :], t0[:, None], t1[:, None]),
                                   t1[:, None]], axis=1), axis=1)  # (S, P + 2)
    a, b = cuts[:, :-1], cuts[:, 1:]
    keep = b > a
    keep[:, 0] |= t1 == t0  # a piece of no length: one point
    si, ji = np.nonzero(keep)
    A, B = a[si, ji], b[si, ji]
    # the motion on [A, B]: the segment that starts at or before A (no knot inside)
    cen, vel = path_at(kt[None], world.knot_p[k][None], world.knot_v[k][None], A)
    cen, vel = cen[:, 0], vel[:, 0]  # (n, N)
    rel = to_unit(c[si], A - t0[si], np.ones(A.size))  # in t - A seconds
    if rel.shape[2] < 2:
        rel = np.concatenate([rel, np.zeros(rel.shape[:2] + (1,))], axis=2)
    rel[:, :, 0] -= cen
    rel[:, :, 1] -= vel
    one = World(np.full(N, -np.inf), np.full(N, np.inf), world.kind[k:k + 1], np.zeros((1, N)),
                world.half[k:k + 1], world.radius[k:k + 1])
    part = _empty(M, 1, N)
    _obstacles(part, r[si], A, B, rel, *_prepare(A, B, rel), radius, one)
    return part.obstacle[:, 0], part.obstacle_t[:, 0]


def _time(t0, t1, h, u):
    return np.where(u >= 1.0, t1, t0 + u * h)


def _obstacles(res, r, t0, t1, c, cu, lo, hi, scale, ends, radius, world):
    M, K = res.obstacle.shape
    S, N, _ = c.shape
    kind = world.kind
    rep = lambda a: np.broadcast_to(a[None], (S,) + a.shape)  # noqa: E731
    # upper bound per (robot, obstacle): the end points of its pieces
    sd_end = exact_signed_distance(
        rep(kind).reshape(-1), rep(world.center).reshape(-1, N), rep(world.half).reshape(-1, N),
        rep(world.radius).reshape(-1), np.repeat(ends, K, axis=0)).reshape(S, K, 2).min(axis=2)
    ub = np.full((M, K), np.inf)
    np.minimum.at(ub, r, sd_end)
    lb = _obstacle_lower_bounds(lo, hi, world)
    ps, ks = np.nonzero(_keep(lb, ub[r], scale[:, None]))
    if ps.size == 0:
        return
    pair = r[ps] * K + ks
    lbk = lb[ps, ks]
    # pass 1: per (robot, obstacle) the row of the smallest lower bound; its exact minimum
    # is attained, so a row whose lower bound is not below it cannot hold a smaller value
    order = np.lexsort((lbk, pair))
    first = order[np.r_[True, pair[order][1:] != pair[order][:-1]]]
    v1, tm1 = _obstacle_rows(ps[first], ks[first], t0, t1, c, cu, world)
    best = np.full(M * K, np.inf)
    best[pair[first]] = v1
    # pass 2: the others; 1e-13 x the piece's size above the round-off of the bounds
    rest = np.ones(ps.size, bool)
    rest[first] = False
    rest &= lbk < best[pair] - 1e-13 * (1.0 + scale[ps])
    v2, tm2 = _obstacle_rows(ps[rest], ks[rest], t0, t1, c, cu, world)
    sel = np.r_[first, np.nonzero(rest)[0]]
    best, tb = _scatter_min(M, K, pair[sel], np.r_[v1, v2], np.r_[tm1, tm2])
    res.obstacle[:] = best - radius[:, None]
    res.obstacle_t[:] = tb


def _obstacle_rows(ps, ks, t0, t1, c, cu, world):
    """Exact minimum signed distance (B,) of pieces ps to obstacles ks, and a time (B,)."""
    N = c.shape[1]
    kind = world.kind
    vals, times = [np.zeros(0)], [np.zeros(0)]
    for start in range(0, ps.size, CHUNK):
        p, k = ps[start:start + CHUNK], ks[start:start + CHUNK]
        d = cu[p].copy()
        d[:, :, 0] -= world.center[k]
        val, tm = np.empty(p.size), np.empty(p.size)
        for code in (SPHERE, BOX, CYLINDER):
            sel = np.nonzero(kind[k] == code)[0]
            if sel.size == 0:
                continue
            kk = k[sel]
            if code == BOX:
                u = box_candidates(d[sel], world.half[kk])
            elif code == CYLINDER and N == 3:
                u = cylinder_candidates(d[sel], world.radius[kk], world.half[kk, 2])
            else:
                u = stationary_candidates(d[sel])[0]
            pp = p[sel]
            u = compact(u)
            x = horner(c[pp], u * (t1 - t0)[pp][:, None])
            sd = _sd_kind(code, world.center[kk], world.half[kk], world.radius[kk], x)
            j = np.argmin(sd, axis=1)
            rows = np.arange(sel.size)
            val[sel] = sd[rows, j]
            tm[sel] = _time(t0[pp], t1[pp], (t1 - t0)[pp], u[rows, j])
        vals.append(val)
        times.append(tm)
    return np.concatenate(vals), np.concatenate(times)


def _faces(res, r, t0, t1, c, cu, lo, hi, scale, ends, radius, bounds, finite):
    M, F = res.face.shape
    fi = np.nonzero(finite)[0]
    axis, sign = fi // 2, np.where(fi % 2 == 0, 1.0, -1.0)  # clearance = sign (x_axis - bound)
    b = bounds[fi]
    lb = np.where(sign > 0, lo[:, axis] - b, b - hi[:, axis])  # (S, F')
    end_cl = sign * (ends[:, :, axis] - b)  # (S, 2, F')
    ub = np.full((M, fi.size), np.inf)
    np.minimum.at(ub, r, end_cl.min(axis=1))
    ps, fs = np.nonzero(_keep(lb, ub[r], scale[:, None]))
    if ps.size == 0:
        return
    # the minimum of a polynomial coordinate: at 0, 1 or a root of its derivative
    g = cu[ps, axis[fs]]  # (B, L)
    u = np.concatenate([np.zeros((ps.size, 1)), np.ones((ps.size, 1)), roots(deriv(g))],
                       axis=1)
    x = horner(c[ps, axis[fs]][:, None, :], u * (t1 - t0)[ps][:, None])[..., 0]
    cl = sign[fs][:, None] * (x - b[fs][:, None])
    j = np.argmin(cl, axis=1)
    rows = np.arange(ps.size)
    best, tb = _scatter_min(M, fi.size, r[ps] * fi.size + fs, cl[rows, j],
                            _time(t0[ps], t1[ps], (t1 - t0)[ps], u[rows, j]))
    res.face[:, fi] = best - radius[:, None]
    res.face_t[:, fi] = tb


def _num(x):
    x = float(x)
    return x if math.isfinite(x) else None


def world_report(wc: WorldClearance) -> dict:
    """The metrics.json keys of a :class:`WorldClearance` (docs/DESIGN.md).

    Returns a dict with
        obstacle_collisions (int): (robot, obstacle) pairs whose clearance fell below 0
            (the body overlapped the obstacle; touching at exactly 0 is not a contact);
        min_obstacle_clearance_m (float | None): the smallest clearance (None: no
            obstacles, or no pieces);
        worst_obstacle ({robot, obstacle, t} | None): where and when;
        workspace_violations (int): (robot, face) pairs whose clearance fell below 0
            (the body left the workspace through that face);
        min_workspace_clearance_m (float | None): the smallest face clearance (None:
            unbounded workspace);
        worst_workspace ({robot, face, t} | None): face as "z_min", "x_max", ...;
        per_robot_obstacle_m, per_robot_workspace_m (lists of M float | None): each
            robot's smallest clearance.
    """
    M = wc.obstacle.shape[0]
    N = wc.face.shape[1] // 2
    names = face_names(N)
    out = {"obstacle_collisions": int(np.sum(wc.obstacle < 0.0)),
           "min_obstacle_clearance_m": None, "worst_obstacle": None,
           "workspace_violations": int(np.sum(wc.face < 0.0)),
           "min_workspace_clearance_m": None, "worst_workspace": None}
    if wc.obstacle.size and np.isfinite(wc.obstacle).any():
        i, k = np.unravel_index(np.argmin(wc.obstacle), wc.obstacle.shape)
        out["min_obstacle_clearance_m"] = float(wc.obstacle[i, k])
        out["worst_obstacle"] = {"robot": int(i), "obstacle": int(k),
                                 "t": float(wc.obstacle_t[i, k])}
    if np.isfinite(wc.face).any():
        i, f = np.unravel_index(np.argmin(wc.face), wc.face.shape)
        out["min_workspace_clearance_m"] = float(wc.face[i, f])
        out["worst_workspace"] = {"robot": int(i), "face": names[f],
                                  "t": float(wc.face_t[i, f])}
    ob = wc.obstacle.min(axis=1) if wc.obstacle.shape[1] else np.full(M, np.inf)
    out["per_robot_obstacle_m"] = [_num(x) for x in ob]
    out["per_robot_workspace_m"] = [_num(x) for x in wc.face.min(axis=1)]
    return out
