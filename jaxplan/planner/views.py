"""Stage 1 of a replan: each robot's predictions of the others, from its views
(docs/MATH.md section 3).

Each robot i has its own *view* of every other robot j: the last state and goal it
received from j (:class:`~jaxplan.planner.types.Views`, arrays (M, M, ...) indexed
[observer, sender]).  By default every view is fresh (:func:`fresh_views`); the views
also carry an age and a validity flag, so that stale or missing messages can be
injected (:mod:`jaxplan.faults`).

From its view each robot predicts the others in closed form (:mod:`jaxplan.predict`; as
ablations, ``[planner] prediction``: flying on at constant velocity, or standing still:
:func:`predict_views`), advanced by the age of the message it came from.  An old message
costs a larger radius (at most MAX_INFLATION): a view up to STALE_AFTER_S old is a
prediction advanced from the sent state, which can be off by what the sender's
acceleration could change since, a_max age^2 / 2; an older view is a robot holding
still, which can be off by how far it could have flown since, v_max age.  It is held at
the middle of the stretch from its last message to where that message predicted it one
period later and on to where it comes to rest braking from there (it fell silent
somewhere on the way, and a robot that stops responding brakes to rest:
:func:`jaxplan.rollout.freeze`), and it is never taken to be known better than that
stretch allows: half its length plus a_max dt^2 / 8 (``floor``; docs/SOLVER.md, "Why the
planner's safeguards are there").
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxplan.planner.types import FleetParams, Views
from jaxplan.predict import predict_arrays
from jaxplan.pytree import tree_where
from jaxplan.trajectory import Trajectory

# m: the most a sender's radius grows for an old message.  A silent robot is taken to
# hold its last known position within this much: a larger ball round a robot frozen
# mid-course can wall off another robot's goal (docs/SOLVER.md)
MAX_INFLATION = 0.5
STALE_AFTER_S = 0.5  # s: an older view is a robot holding its last known position
# what a robot predicts the others will do ([planner] prediction, PlannerStructure):
# the paper's closed form, or, as ablations, flying on at constant velocity or standing
# still (predict_views)
PREDICTIONS = ("min_time_jerk", "constant_velocity", "static")
PREDICTION_DEGREE = 5  # the closed-form predictions' degree (one segment)


class Predictions(NamedTuple):
    """Each observer's predictions of each sender, indexed [i, j].

    traj: Trajectory (M, M), advanced to now by the message's age (a held robot: a
    hold).  inflate: (M, M) m, how far the sender could be from where the view puts it
    (added to its radius).  floor: (M, M) m, the part of ``inflate`` that a held robot
    is certainly within, never given up (:func:`jaxplan.planner.goals.free_goals`).
    """

    traj: Trajectory
    inflate: jax.Array
    floor: jax.Array


def fresh_views(p, v, a, goal_p, goal_v, rest) -> Views:
    """Every observer sees every sender's current state and goal.

    Args: p, v, a, goal_p, goal_v (M, N); rest (M,) bool.
    """
    M = p.shape[0]
    b = lambda x: jnp.broadcast_to(x[None], (M,) + x.shape)
    return Views(b(p), b(v), b(a), b(goal_p), b(goal_v), b(rest),
                 jnp.zeros((M, M)), jnp.ones((M, M), bool))


def sender_mask(fp: FleetParams, views: Views):
    """(M, M) bool: the senders each observer counts, indexed [i, j]: another robot (not
    padding) from which it received something (``views.valid``)."""
    M = views.valid.shape[0]
    eye = jnp.eye(M, dtype=bool)
    return views.valid & ~eye & fp.robot_mask[None, :] & fp.robot_mask[:, None]


def predict_views(views: Views, w, prediction: str = "min_time_jerk") -> Trajectory:
    """Predictions of every sender from every observer's view: batch (M, M).

    prediction (PREDICTIONS; a static choice, ``PlannerStructure.prediction``):
    "min_time_jerk", the closed-form prediction (:mod:`jaxplan.predict`, degree 5, one
    segment); "constant_velocity", the sender flies on at the velocity of its view,
    p + v t, for ever; "static", it holds the position of its view.  The last two are
    trajectories of the same shape and degree as the first (T = 0: a zero-length
    segment is a Taylor expansion in seconds, coasting or holding after it), so that
    everything downstream is unchanged; where such a trajectory ends, where
    :func:`jaxplan.planner.goals.unoccupied_goals` looks for occupants, is the view's
    position.  Non-finite views become a hold at the finite part of the position, as
    the closed form's do.
    """
    if prediction == "min_time_jerk":
        return predict_arrays(views.p, views.v, views.a, views.goal_p, views.goal_v,
                              jnp.zeros_like(views.p), views.rest, w)
    if prediction not in PREDICTIONS:
        raise ValueError(f"prediction must be one of {PREDICTIONS}, got {prediction!r}")
    ok = jnp.all(jnp.isfinite(views.p), axis=-1) & jnp.all(jnp.isfinite(views.v), axis=-1)
    p = jnp.where(jnp.isfinite(views.p), views.p, 0.0)
    held = Trajectory.hold(p, PREDICTION_DEGREE, 1)
    if prediction == "static":
        return held
    v = jnp.where(ok[..., None], views.v, 0.0)
    return Trajectory(held.coeffs.at[..., 0, :, 1].set(v), held.breaks, ok)


def view_predictions(fp: FleetParams, views: Views,
                     prediction: str = "min_time_jerk") -> Predictions:
    """The others' predictions from each robot's views (:func:`predict_views` of the
    kind ``prediction``), advanced to now by the message's age (module docstring).  A
    view older than STALE_AFTER_S is taken as a robot holding its last known position;
    ``inflate`` is how far the other could be from where its view puts it, ``floor``
    the part of it that a held robot is certainly within."""
    # an age from the future counts as 0, an unknown (NaN) age as infinitely old
    age = jnp.where(jnp.isnan(views.age), jnp.inf, jnp.maximum(views.age, 0.0))
    fresh = age <= STALE_AFTER_S
    preds0 = predict_views(views, fp.prediction_weight, prediction)
    preds = preds0.shift(jnp.where(fresh, age, 0.0))
    # a silent robot stopped somewhere between its last message and where it comes to
    # rest braking (as braking_plan does) from the next one due, one period later along
    # its prediction: held at the middle of that stretch's chord, which it is within
    # floor of (half the stretch's length, plus a_max dt^2 / 8 for the bend)
    nxt, v_nxt = preds0.evaluate(fp.dt), preds0.evaluate(fp.dt, 1)
    a_max = jnp.maximum(fp.limits.a_max[None, :], 1e-3)
    t_stop = jnp.maximum(1.5 * jnp.linalg.norm(v_nxt, axis=-1) / a_max, 0.5)
    stop = nxt + 0.5 * v_nxt * t_stop[..., None]
    held_p = 0.5 * (views.p + stop)
    held = Trajectory.hold(held_p, preds.degree, preds.num_segments)
    preds = tree_where(fresh, preds, held)
    floor = jnp.where(fresh, 0.0, 0.5 * (jnp.linalg.norm(nxt - views.p, axis=-1)
                                         + jnp.linalg.norm(stop - nxt, axis=-1))
                      + fp.limits.a_max[None, :] * fp.dt**2 / 8)
    floor = jnp.where(jnp.isfinite(floor), floor, 0.0)
    # old information: inflate the other's radius by how far it could be from where the
    # view puts it (unmodelled acceleration for a prediction, any motion for a hold)
    grow = jnp.where(fresh, 0.5 * fp.limits.a_max * age**2, fp.limits.v_max * age)
    inflate = jnp.maximum(jnp.minimum(grow, MAX_INFLATION), floor)
    if fp.keep_right is not None:
        preds, inflate = _kept_right(preds, inflate, views, fp.keep_right)
    return Predictions(preds, inflate, floor)


def _kept_right(preds: Trajectory, inflate, views: Views, offset):
    """The predictions shifted ``offset`` m to each sender's right of the way from its
    view's position to its goal (horizontal in 3-D: the way crossed with +z; none for a
    way that is vertical or shorter than 1 cm), the radius grown by as much: the shifted
    ball holds the unshifted one, and reaches 2 offset further on the sender's right."""
    h = views.goal_p - views.p
    if h.shape[-1] == 2:
        right = jnp.stack([h[..., 1], -h[..., 0]], axis=-1)
    else:
        right = jnp.stack([h[..., 1], -h[..., 0], jnp.zeros_like(h[..., 0])], axis=-1)
    n = jnp.linalg.norm(right, axis=-1, keepdims=True)
    unit = jnp.where((n > 0.01) & jnp.isfinite(n), right / jnp.where(n > 0.01, n, 1.0), 0.0)
    shift = offset * unit
    coeffs = preds.coeffs.at[..., :, :, 0].add(shift[..., None, :])
    return preds._replace(coeffs=coeffs), inflate + offset
