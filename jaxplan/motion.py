"""How obstacles move (jaxplan/world.py, "Motion"): each one's centre is a piecewise-linear
function of time given by knots, at rest before its first knot, linear between knots,
flying on at a final velocity after its last.  The config's motions as knots
(:func:`obstacle_motion`), the centre and velocity at any times (:func:`path_at`, numpy
or jax.numpy), the static rows' motion (:class:`RowMotion`), and what a replan at time t
sees of it (:func:`rows_at`, :func:`centres_at`)."""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np


def obstacle_motion(obstacles, center):
    """(knot_t (K, P), knot_p (K, P, N), knot_v (K, N), known (K,)) of config obstacle
    dicts (module doc, "Motion"): ``velocity`` or ``path`` (a list of {t, p}), else at
    rest at ``center`` (K, N) (:func:`obstacle_arrays`' centres; a path's obstacle has
    none there); shorter paths padded by repeating their last knot."""
    center = np.asarray(center, np.float64)
    K, N = center.shape
    paths = []
    for k, o in enumerate(obstacles):
        path = o.get("path")
        if path:
            paths.append(([float(q["t"]) for q in path], [list(q["p"]) for q in path]))
        else:
            paths.append(([0.0], [center[k]]))
    P = max([len(t) for t, _ in paths], default=1)
    knot_t, knot_p = np.zeros((K, P)), np.zeros((K, P, N))
    knot_v, known = np.zeros((K, N)), np.zeros(K, bool)
    for k, (t, p) in enumerate(paths):
        n = len(t)
        knot_t[k, :n], knot_t[k, n:] = t, t[-1]
        knot_p[k, :n], knot_p[k, n:] = p, p[-1]
        v = obstacles[k].get("velocity")
        if v is not None:
            knot_v[k] = v
        known[k] = bool(obstacles[k].get("known_path", False))
    return knot_t, knot_p, knot_v, known


def path_at(knot_t, knot_p, knot_v, t, xp=np):
    """Piecewise-linear motions at times t (module doc, "Motion"): knots knot_t (R, P) s,
    knot_p (R, P, N) m, the velocity after the last knot knot_v (R, N) m/s, times t
    (...,) s -> (centre (..., R, N) m, velocity (..., R, N) m/s).  Between knots k and
    k + 1 (knot_t[k] <= t < knot_t[k + 1]) the centre moves at their chord's velocity;
    at a knot the velocity is the next segment's.  The knot a time falls in is
    piecewise constant in t, so a derivative in t (JAX) is the velocity."""
    t = xp.asarray(t)
    P = knot_t.shape[-1]
    tt = t[..., None, None]
    k = xp.sum(knot_t <= tt, axis=-1) - 1  # (..., R): the last knot at or before t
    ar = xp.arange(P)
    lo = (ar == xp.clip(k, 0, P - 1)[..., None])  # (..., R, P) one-hot
    hi = (ar == xp.clip(k + 1, 0, P - 1)[..., None])
    tl = xp.sum(xp.where(lo, knot_t, 0.0), axis=-1)
    th = xp.sum(xp.where(hi, knot_t, 0.0), axis=-1)
    pl = xp.sum(xp.where(lo[..., None], knot_p, 0.0), axis=-2)
    ph = xp.sum(xp.where(hi[..., None], knot_p, 0.0), axis=-2)
    seg = (k >= 0) & (k < P - 1)
    dt = xp.where(seg, th - tl, 1.0)
    last = (k == P - 1)[..., None]
    vel = xp.where(seg[..., None], (ph - pl) / dt[..., None], xp.where(last, knot_v, 0.0))
    return pl + vel * (t[..., None] - tl)[..., None], vel


class RowMotion(NamedTuple):
    """How the static rows move (a pytree; module doc, "Motion"): t (R, P) knot times, s;
    p (R, P, N) centres at them, m; v (R, N) velocity after the last knot, m/s; known
    (R,) bool, the robots know the row's future path; moving (R,) bool, the row moves at
    some time (the guide ignores such rows).  In ``FleetParams.static`` the times are
    the run's; after :func:`rows_at`, relative to the replan."""

    t: object
    p: object
    v: object
    known: object
    moving: object


def rows_at(static, t):
    """The rows as a replan at time t (s, traced) sees them: each row's ``center`` where
    it is at t, and its motion from t on with times relative to t: its true path where
    ``known``, else flying on at its velocity at t (one knot at 0, ``v`` that velocity).
    A world without motion (or None) is returned as it is."""
    if static is None or static.motion is None:
        return static
    m = static.motion
    t = jnp.asarray(t, jnp.float64)
    c, v = path_at(m.t, m.p, m.v, t, xp=jnp)  # (R, N)
    known = m.known[:, None]
    return static._replace(center=c, motion=m._replace(
        t=jnp.where(known, m.t - t, 0.0),
        p=jnp.where(known[..., None], m.p, c[:, None, :]),
        v=jnp.where(known, m.v, v)))


def centres_at(static, t):
    """Each row's centre at times t (...,) (relative as ``static``'s motion is): (...,
    R, N); the rows' ``center`` broadcast where they do not move (motion None)."""
    if static.motion is None:
        return jnp.broadcast_to(static.center, jnp.shape(t) + static.center.shape)
    m = static.motion
    return path_at(m.t, m.p, m.v, t, xp=jnp)[0]
