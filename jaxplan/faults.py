"""Fault injection between the robots (config ``[faults]``; off by default).

The paper assumes reliable communication.  Here each observer's view of each sender
(:class:`jaxplan.planner.Views`) is built from broadcast messages that may be

* lost: each (observer, sender, period) message is dropped with probability
  ``message_loss``; the observer keeps what it had, which ages;
* late: every message arrives ``latency_periods`` replan periods after it was sent
  (``latency_s`` rounded to whole periods);
* noisy: each received position gets Gaussian noise of ``noise_sigma_m`` per axis,
  drawn independently per observer (robots know their own state exactly);
* from a robot that stops responding: robot ``frozen_robot`` freezes at
  ``frozen_at_s`` (it stops planning, brakes to rest within its a_max and hovers there:
  :func:`jaxplan.rollout.freeze`) and either stops sending
  (``frozen_mode = "silent"``) or keeps sending its last message with a fresh time stamp
  (``"stale"``: the others are told it is still flying its old plan).

Draws come from a JAX PRNG key derived from the run's seed: a run is reproducible.
The planner's answer to stale information (:mod:`jaxplan.planner.views`): predictions are
advanced by the message's age and the sender's radius is inflated by a_max age^2 / 2;
a view older than STALE_AFTER_S is taken as a robot holding its last known position,
inflated by v_max age; inflation is at most MAX_INFLATION (0.5 m).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxplan.planner import Views


class FaultParams(NamedTuple):
    """Traced fault settings of one run (no recompilation when they change).

    loss: () probability in [0, 1).  noise: () m.  frozen: (M,) bool, the robot that stops
    responding.  frozen_at: () s.  stale: () bool, a frozen robot keeps sending its last
    message (True) or goes silent (False).  seed: () int, the PRNG seed.
    """

    loss: jax.Array
    noise: jax.Array
    frozen: jax.Array
    frozen_at: jax.Array
    stale: jax.Array
    seed: jax.Array


def no_faults(M: int) -> FaultParams:
    z = jnp.asarray(0.0)
    return FaultParams(z, z, jnp.zeros((M,), bool), z, jnp.asarray(False),
                       jnp.asarray(0, jnp.uint32))


class Message(NamedTuple):
    """What each sender broadcasts, arrays (M, ...): state, goal, end kind, time stamp,
    and whether anything was sent at all."""

    p: jax.Array
    v: jax.Array
    a: jax.Array
    goal_p: jax.Array
    goal_v: jax.Array
    rest: jax.Array
    t_sent: jax.Array
    sent: jax.Array


class CommState(NamedTuple):
    """Communication memory carried by the rollout.

    views: Views (M, M, ...) each observer's last received message of each sender (age
    filled in per replan).  t_sent: (M, M) time stamps of those messages.  inbox: Message
    with a leading (L+1,) axis, the messages in flight (index 0 = sent now).
    last: Message, each sender's last message before it froze.  key: PRNG key.
    """

    views: Views
    t_sent: jax.Array
    inbox: Message
    last: Message
    key: jax.Array


def initial_comm(p, goal_p, goal_v, rest, latency_periods: int, seed) -> CommState:
    """Everyone knows everyone's start state (all at rest) at t = 0."""
    M, N = p.shape
    z = jnp.zeros_like(p)
    msg = Message(p, z, z, goal_p, goal_v, rest, jnp.zeros((M,)), jnp.ones((M,), bool))
    b = lambda x: jnp.broadcast_to(x[None], (M,) + x.shape)
    views = Views(b(p), b(z), b(z), b(goal_p), b(goal_v), b(rest), jnp.zeros((M, M)),
                  jnp.ones((M, M), bool))
    inbox = jax.tree.map(lambda x: jnp.broadcast_to(x[None], (latency_periods + 1,) + x.shape),
                         msg)
    return CommState(views, jnp.zeros((M, M)), inbox, msg, jax.random.PRNGKey(seed))


def communicate(comm: CommState, f: FaultParams, t, p, v, a, goal_p, goal_v, rest):
    """One period of messages: send, deliver (late, lossy, noisy), update every view.

    Returns (new CommState, Views with ages at time t, stats dict of (,) arrays:
    delivered, lost).
    """
    M = p.shape[0]
    frozen_now = f.frozen & (t >= f.frozen_at)
    now = Message(p, v, a, goal_p, goal_v, rest, jnp.full((M,), t), jnp.ones((M,), bool))
    sel = lambda c, x, y: jax.tree.map(
        lambda u, w: jnp.where(c.reshape(c.shape + (1,) * (u.ndim - c.ndim)), u, w), x, y)
    last = sel(frozen_now, comm.last, now)
    stale_msg = last._replace(t_sent=jnp.full((M,), t))
    out = sel(frozen_now & f.stale, stale_msg, now)
    out = out._replace(sent=~(frozen_now & ~f.stale))
    inbox = jax.tree.map(lambda buf, x: jnp.concatenate([x[None], buf[:-1]], axis=0),
                         comm.inbox, out)
    arrived = jax.tree.map(lambda buf: buf[-1], inbox)  # sent latency periods ago
    key, k_loss, k_noise = jax.random.split(comm.key, 3)
    keep = jax.random.uniform(k_loss, (M, M)) >= f.loss
    eye = jnp.eye(M, dtype=bool)
    recv = arrived.sent[None, :] & keep & ~eye
    noise = f.noise * jax.random.normal(k_noise, (M, M) + p.shape[1:])
    b = lambda x: jnp.broadcast_to(x[None], (M,) + x.shape)
    got = Views(b(arrived.p) + noise, b(arrived.v), b(arrived.a), b(arrived.goal_p),
                b(arrived.goal_v), b(arrived.rest), jnp.zeros((M, M)), jnp.ones((M, M), bool))
    views = sel(recv, got, comm.views)
    t_sent = jnp.where(recv, arrived.t_sent[None, :], comm.t_sent)
    # an observer always knows itself exactly
    own = Views(b(p), b(v), b(a), b(goal_p), b(goal_v), b(rest), jnp.zeros((M, M)),
                jnp.ones((M, M), bool))
    views = sel(eye, own, views)
    t_sent = jnp.where(eye, t, t_sent)
    views = views._replace(age=jnp.maximum(t - t_sent, 0.0))
    stats = {"delivered": jnp.sum(recv), "lost": jnp.sum(arrived.sent[None, :] & ~keep & ~eye)}
    return CommState(views, t_sent, inbox, last, key), views, stats
