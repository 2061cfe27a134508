"""Problem generators shared by the tests, the examples and the benchmarks: default
weights and limits, random single-robot NLPs, the NLPs of one fleet replan, antipodal
fleets, and stacking / indexing of NLPParams batches.  Importing this module builds
nothing heavy (no compilation until a generator is called).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

import jaxplan  # noqa: F401  (float64)
from jaxplan import planner as _planner
from jaxplan.nlp import Limits, NLPParams, Weights
from jaxplan.predict import predict_arrays

_predict = jax.jit(predict_arrays)  # eager predict_arrays is slow (op by op)

DEFAULT_WEIGHTS = dict(q_dynm=1.0, q_obs=10.0, q_lim=1.0, k_t=1.0, k_p=4.0)
DEFAULT_LIMITS = dict(v_max=2.0, a_max=4.0, j_max=15.0)


def weights(**kw) -> Weights:
    """Weights (float64 scalars): DEFAULT_WEIGHTS with the keywords replaced."""
    d = {**DEFAULT_WEIGHTS, **kw}
    return Weights(*(jnp.asarray(d[k], jnp.float64) for k in Weights._fields))


def limits(**kw) -> Limits:
    """Limits (float64 scalars): DEFAULT_LIMITS with the keywords replaced."""
    d = {**DEFAULT_LIMITS, **kw}
    return Limits(*(jnp.asarray(d[k], jnp.float64) for k in Limits._fields))


def _unit(rng, N):
    u = rng.normal(size=N)
    return u / np.linalg.norm(u)


def random_problem(rng, *, n_others: int, mo: int = 10, rest: bool = False, N: int = 3,
                   radius: float = 0.25, w: Weights | None = None, lim: Limits | None = None,
                   t_min: float = 0.1) -> NLPParams:
    """One random single-robot NLP: a moving start, a goal 4-9 m away, and ``n_others``
    other robots (padded to ``mo``) whose predicted straight paths cross the robot's
    straight path at 25-75 % of its length, at about the time it gets there.  Others
    cross at >= 35 degrees and start / end >= 2 m from the crossing, so the problem is
    feasible with shape freedom."""
    p0 = rng.uniform(-1, 1, N)
    dirn = _unit(rng, N)
    L = rng.uniform(4, 9)
    pf = p0 + L * dirn
    v0 = dirn * rng.uniform(0, 1.0) + rng.normal(size=N) * 0.3
    a0 = rng.normal(size=N) * 0.3
    T = float(_predict(p0, v0, a0, pf, np.zeros(N), np.zeros(N), rest, 1.0).duration) * 1.3
    ps, vs, gs = [], [], []
    for _ in range(mo):
        u = rng.uniform(0.25, 0.75)
        cross = p0 + u * L * dirn
        while True:
            dj = _unit(rng, N)
            if abs(dj @ dirn) < np.cos(np.radians(35)):
                break
        sp = rng.uniform(0.6, 1.6)
        back = max(sp * u * T, 2.0)
        ps.append(cross - dj * back)
        vs.append(dj * sp * rng.uniform(0.3, 1.0))
        gs.append(cross + dj * rng.uniform(2.5, 6.0))
    ps, vs, gs = map(np.array, (ps, vs, gs))
    z = np.zeros_like(ps)
    others = _predict(ps, vs, z, gs, z, z, rng.uniform(size=mo) < 0.5, 1.0)
    mask = np.arange(mo) < n_others
    f = lambda a: jnp.asarray(a, jnp.float64)
    return NLPParams(f(p0), f(v0), f(a0), f(pf), f(np.zeros(N)), f(np.zeros(N)), jnp.asarray(rest),
                     others, f(np.full(mo, radius)), jnp.asarray(mask), f(radius),
                     w if w is not None else weights(), lim if lim is not None else limits(),
                     f(t_min))


def stack_params(ps: list[NLPParams]) -> NLPParams:
    """The NLPParams of a list stacked on a new leading axis."""
    return jax.tree.map(lambda *a: jnp.stack(a), *ps)


def index_params(p: NLPParams, i) -> NLPParams:
    """Problem ``i`` (an index or a slice) of a batch of NLPParams."""
    return jax.tree.map(lambda a: a[i], p)


def fleet_params(pos, vel, acc, goals, *, rest=False, radius=0.25, w=None, lim=None,
                 t_min=0.1, max_neighbors: int = 0, return_neighbors: bool = False,
                 prediction_weight: float = 1.0, static=None):
    """The M NLPs of one fleet replan: robot i sees the other M - 1 robots' predictions
    (time weight ``prediction_weight``, default 1: the paper's prediction; the planner
    uses k_t / q_dynm), in the planner's slots
    (:func:`jaxplan.planner.all_others`).  pos, vel, acc, goals: (M, N).

    max_neighbors K > 0: each NLP holds only the K others that
    :func:`jaxplan.planner.nearest_neighbors` picks (as the planner does with
    ``[planner] max_neighbors``).  return_neighbors: also return the (M, K) indices.
    static: the world's :class:`jaxplan.world.StaticRows` (the same for every robot, as
    the planner's), or None.
    """
    M, N = pos.shape
    z = jnp.zeros((M, N))
    restv = jnp.broadcast_to(jnp.asarray(rest), (M,))
    pred = _predict(pos, vel, acc, goals, z, z, restv, prediction_weight)
    if 0 < max_neighbors < M - 1:
        others = jax.tree.map(lambda a: jnp.broadcast_to(a, (M,) + a.shape), pred)
        orad = jnp.full((M, M), radius, jnp.float64)  # strong: a weak one costs a conversion
        others, orad, mask, idx = _select(others, orad, ~jnp.eye(M, dtype=bool), max_neighbors)
    else:
        others, orad, mask, idx = _every_other(pred, radius)
    w = w if w is not None else weights()
    lim = lim if lim is not None else limits()
    radius, w, lim, t_min = _per_robot((radius, w, lim, t_min), M)
    P = NLPParams(jnp.asarray(pos), jnp.asarray(vel), jnp.asarray(acc), jnp.asarray(goals), z, z,
                  restv, others, orad, mask, radius, w, lim, t_min,
                  None if static is None else jax.tree.map(
                      lambda a: jnp.broadcast_to(jnp.asarray(a), (M,) + np.shape(a)), static))
    return (P, idx) if return_neighbors else P


# fleet_params' array work in compiled programs (once per fleet size): op by op (eager)
# every new size would compile each of its ~25 operations on its own
_select = jax.jit(_planner.select_neighbors, static_argnums=3)


@jax.jit
def _every_other(pred, radius):
    """Every robot's M - 1 others in the planner's slots (:func:`jaxplan.planner.all_others`):
    their predictions, radii, mask and indices."""
    M = pred.coeffs.shape[0]
    others = jax.tree.map(lambda a: jnp.broadcast_to(a, (M,) + a.shape), pred)
    orad = jnp.full((M, M), radius, jnp.float64)  # strong: a weak leaf costs a conversion
    idx = jnp.asarray(_planner.all_others(M))
    others, orad, mask = _planner.take_slots((others, orad, ~jnp.eye(M, dtype=bool)), idx)
    return others, orad, mask, idx


@functools.partial(jax.jit, static_argnums=1)
def _per_robot(tree, M: int):
    """Every leaf of ``tree`` (scalars) as a float64 (M,) array."""
    return jax.tree.map(lambda a: jnp.broadcast_to(jnp.asarray(a, jnp.float64), (M,)), tree)


def antipodal(M: int, radius_m: float, rng, N: int = 3):
    """M robots on a circle (jittered along it and in z), goals antipodal (jittered).

    The jitters (+-0.05 rad along the circle, +-0.3 m in z and on the goals) are those
    of 10 robots; with more robots they shrink with the spacing (x 10 / M), so that
    neighbours start at least ~0.84 of the spacing apart (unscaled, 100 robots on a 15 m
    circle started pairs 0.08 m apart, inside one another's radii)."""
    k = min(1.0, 10.0 / M)
    ang = 2 * np.pi * np.arange(M) / M + k * rng.uniform(-0.05, 0.05, M)
    pos = np.stack([radius_m * np.cos(ang), radius_m * np.sin(ang),
                    1.5 + k * rng.uniform(-0.3, 0.3, M)], -1)
    goals = np.stack([-pos[:, 0], -pos[:, 1], 1.5 + k * rng.uniform(-0.3, 0.3, M)], -1)
    goals[:, :2] += k * rng.uniform(-0.3, 0.3, (M, 2))
    return pos[:, :N], goals[:, :N]




def random_obstacles(rng, repeats: int, spread: float, half_min: float,
                     radius_min: float) -> list[dict]:
    """``repeats`` each of a sphere, a box and a cylinder (3-D, config dicts as
    ``[[obstacles]]`` holds them): centres uniform in [-spread, spread]^3, box half
    extents in [half_min, 0.8], radii in [radius_min, 0.8], half heights in [0.3, 1.5]."""
    obs = []
    for kind in ["sphere", "box", "cylinder"] * repeats:
        o = dict(kind=kind, center=rng.uniform(-spread, spread, 3))
        if kind == "box":
            o["half_extents"] = rng.uniform(half_min, 0.8, 3)
        else:
            o["radius"] = rng.uniform(radius_min, 0.8)
        if kind == "cylinder":
            o["half_height"] = rng.uniform(0.3, 1.5)
        obs.append(o)
    return obs
