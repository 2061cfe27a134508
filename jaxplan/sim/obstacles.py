"""The world in the MJX simulation (:mod:`jaxplan.sim.fleet`): the rows it measures
(:func:`sim_world`: the obstacles, then the finite workspace faces), where they are at a
time (:func:`obstacle_centres`: a moving obstacle where its motion puts it), the mocap
bodies of the moving obstacles placed there (:func:`set_mocap`), and the signed
distances from the vehicles' centres to them at every physics step with their running
minimum (:func:`static_dists`, :func:`static_min`).

Moving obstacles (:mod:`jaxplan.motion`) are mocap bodies of the stepped models
(:func:`jaxplan.sim.model.mocap_bodies`: no geoms, no mass).  The simulation sets their
``mocap_pos`` at the start of a period and after every physics step to the centres the
motion gives at the data's time (the planner's piecewise-linear evaluation of the
traced knots, ``SimModel.world.motion``), and takes that step's distances to the same
centres: an ``mjx.Data`` always holds the obstacles where they are at its time, and the
next step's kinematics place the bodies there.  A static world has no motion and no
mocap bodies: its rows sit still.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxplan.world import StaticRows, World, centres_at, rows_as_jax, signed_distance, static_rows

Array = jax.Array


def sim_world(world: World) -> StaticRows:
    """The rows of a 3-D world that the simulation measures (``SimModel.world``)."""
    if world.dim != 3:
        raise ValueError(f"the simulated world must be 3-D, got {world.dim}-D")
    return rows_as_jax(static_rows(world))


def obstacle_centres(rows: StaticRows, t) -> Array:
    """(R, 3) m: the rows (jax arrays) where they are at time t (s; traced): a moving
    obstacle where its motion puts it (:func:`jaxplan.motion.centres_at`), the others at
    rest."""
    return rows.center if rows.motion is None else centres_at(rows, t)


def set_mocap(sim, data, centres: Array):
    """``data`` (``SimState.data`` of the simulated fleet ``sim``) with the mocap bodies
    (the moving obstacles, ``sim.mocap_rows``) at ``centres`` (R, 3); unchanged in a
    static world."""
    if not sim.mocap_rows:
        return data
    c = centres[jnp.asarray(sim.mocap_rows)]  # (J, 3)
    if sim.layout != "fleet":  # every vehicle's model holds the same bodies
        c = jnp.broadcast_to(c, (sim.num_vehicles,) + c.shape)
    return data.replace(mocap_pos=c)


def static_dists(rows: StaticRows, p: Array, centres: Array) -> Array:
    """(M, R) signed distances from the centres p (M, 3) to the rows at ``centres``."""
    return signed_distance(rows.kind, centres, rows.half, rows.radius, p, xp=jnp)


def static_min(smin, rows: StaticRows, p: Array, centres: Array, t):
    """Running (minimum (M, R), its time (M, R)) updated with the centres p at time t,
    the rows at ``centres`` (R, 3) (a non-finite distance never replaces a finite
    minimum)."""
    dmin, tmin = smin
    d = static_dists(rows, p, centres)
    lower = d < dmin
    return jnp.where(lower, d, dmin), jnp.where(lower, t, tmin)
