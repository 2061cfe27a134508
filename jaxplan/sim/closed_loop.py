"""Backend "mjx": the receding-horizon planner closed around simulated quadrotors.

Every replan period the planner (:func:`jaxplan.planner.replan`) runs on the MEASURED
states of the simulated vehicles (:func:`jaxplan.sim.fleet.measured_state`): every robot
sees the others as measured.  For its own start state a robot uses its reference (its
previous plan evaluated now) while the measurement agrees with it to REF_POS_TOL and
REF_VEL_TOL, and the measurement otherwise.  Re-planning every period from the measured
acceleration of a vehicle whose attitude loop lags its reference restarts every plan from
the lagging state, and the fleet crawls (docs/SOLVER.md, "Measurements behind the
code"); starting from the reference keeps plans continuous while the
controller removes the tracking error, the usual practice on real quadrotors.  Then the
SE(3) controllers track the new plans at ``control_hz`` under MJX physics at
``physics_hz`` for one period (:func:`jaxplan.sim.fleet.simulate_period`), all vehicles
in lockstep.  Goals are checked on the simulated samples (at control rate) with the
same definition of "reached" as the ideal backend (:mod:`jaxplan.rollout`).

Periods follow the simulation's tick grid: 1 / replan_hz is not always a whole number
of control ticks (8 Hz at 250 Hz is 31.25 ticks), so periods alternate between the two
nearest tick counts and never drift from the nominal grid by more than one tick; every
replan is stamped with the simulation's own time.

``mjx_step`` is one pure, jit-able period; ``mjx_rollout`` scans it for a whole run (a
batch of worlds vmaps it).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxplan.planner import FleetParams, FleetState, fresh_views, replan
from jaxplan.rollout import (
    RolloutState,
    RolloutStructure,
    StepRecord,
    Task,
    current_goals,
    executed_pieces,
    goal_update,
    initial_state,
    own_goals,
    own_plans,
    publish,
)
from jaxplan.sim import fleet as sf

REF_POS_TOL = 0.10  # m: replan from the reference while the measured position is this close
REF_VEL_TOL = 0.50  # m/s: ... and the measured velocity this close


class MjxRecord(NamedTuple):
    """One period: the planner's StepRecord (executed plan pieces, solver info) and the
    simulation's PeriodRecord (samples at control rate, per-physics-step separation)."""

    step: StepRecord
    period: sf.PeriodRecord


def mjx_step(fp: FleetParams, task: Task, st: RolloutState, sim_state: sf.SimState,
             structure: RolloutStructure, sim: sf.SimModel, period_s: float):
    """Measure, replan, fly one period.  Returns ((RolloutState, SimState), MjxRecord)."""
    pm, vm, am = sf.measured_state(sim, sim_state)
    t = sf.sim_time(sim, sim_state)
    # Each robot plans from its reference state (its previous plan, now) while the
    # measurement agrees with it, else from the measurement (module docstring).
    M = pm.shape[0]
    elapsed = jnp.broadcast_to(t - st.t, (M,))
    pr, vr, ar = st.plans.plan.state_at(elapsed)
    agree = (st.plans.has_plan & (jnp.linalg.norm(pr - pm, axis=-1) <= REF_POS_TOL)
             & (jnp.linalg.norm(vr - vm, axis=-1) <= REF_VEL_TOL))
    agree = agree & jnp.all(jnp.isfinite(pr) & jnp.isfinite(vr) & jnp.isfinite(ar), axis=-1)
    pick = lambda r, m: jnp.where(agree[:, None], r, m)
    p, v, a = pick(pr, pm), pick(vr, vm), pick(ar, am)
    st = st._replace(t=t, p=p, v=v, a=a)
    goals = own_goals(task, t, fp.dt, current_goals(task, st.wp, st.reached, p, fp.limits))
    # the others are seen as measured
    views = fresh_views(pm, vm, am, *publish(task, t, fp.dt, st.plans, goals))
    plans, info = replan(fp, st.plans, FleetState(p, v, a, views), goals, structure.planner,
                         t)
    plans = own_plans(task, t, fp.dt, plans)
    new_sim, prec = sf.simulate_period(sim, sim_state, plans.plan, 0.0, period_s)
    t1 = sf.sim_time(sim, new_sim)
    pt0, pt1, pc = executed_pieces(plans.plan, t, t1 - t)
    # goal checks on the simulated samples of the period (and the state at its end)
    p_end, v_end, _ = sf.measured_state(sim, new_sim)
    pos = jnp.concatenate([prec.pos, p_end[:, None]], axis=1)
    speed = jnp.linalg.norm(jnp.concatenate([prec.vel, v_end[:, None]], axis=1), axis=-1)
    times = jnp.concatenate([prec.t, t1[None]])
    valid = jnp.concatenate([prec.valid, jnp.ones((1,), bool)])
    reached, reach_time, wp = goal_update(fp, task, st, goals.goal_p, pos, speed, times,
                                         valid)
    rec = MjxRecord(StepRecord(t, p, v, a, pt0, pt1, pc, st.wp, info, jnp.zeros((3,))), prec)
    # t stays the start time of the current plans (the next step measures elapsed time)
    new = RolloutState(t, p_end, v_end, st.a, plans, wp, reached, reach_time, st.comm)
    return (new, new_sim), rec


def mjx_initial_state(task: Task, structure: RolloutStructure, sim: sf.SimModel):
    """(RolloutState, SimState): every vehicle hovering at rest at its start."""
    return initial_state(task, structure), sf.initial_state(sim, task.start)


def mjx_rollout(fp: FleetParams, task: Task, structure: RolloutStructure, sim: sf.SimModel,
                period_s: float):
    """A whole run as one ``lax.scan`` of :func:`mjx_step` (jit at the call site)."""
    carry0 = mjx_initial_state(task, structure, sim)

    def body(carry, _):
        st, ss = carry
        return mjx_step(fp, task, st, ss, structure, sim, period_s)

    return jax.lax.scan(body, carry0, None, length=structure.steps)
