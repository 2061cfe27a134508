"""Hard limits ([planner] limits = "hard", jaxplan/planner/choice.py): the peak bound a
plan must meet to fly, against a dense sample of random plans; the braking plan kept
within the limits from states within them; the key's config errors; and (slow) a
planar crowd flown within its limits at every instant (the exact metrics)."""

from __future__ import annotations

import tomllib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplan import planner
from jaxplan.config import ConfigError, parse_config
from jaxplan.nlp import Limits, NLPStructure
from jaxplan.planner import PlannerStructure
from jaxplan.planner.choice import BRAKE_GROWTH, LIMIT_TOL, limit_ratio
from jaxplan.planner.types import Fallback
from jaxplan.trajectory import Trajectory


def _dense_ratio(traj: Trajectory, lim: Limits, samples: int = 20001) -> np.ndarray:
    """(M,) the largest sampled |x^(k)| / tau_k over [0, T] (samples per plan)."""
    T = np.asarray(traj.duration)
    t = np.linspace(0.0, 1.0, samples)[:, None] * T[None]
    out = np.zeros(T.shape)
    for k, tau in ((1, lim.v_max), (2, lim.a_max), (3, lim.j_max)):
        x = np.asarray(traj.evaluate(jnp.asarray(t), k))
        out = np.maximum(out, np.linalg.norm(x, axis=-1).max(axis=0) / np.asarray(tau))
    return out


def test_the_peak_bound_holds_everywhere_and_is_close():
    """Random two- and three-segment plans (C2 or not: the bound is per segment), per-robot
    limits: the bound is >= the dense sample's peak (0.1 ms apart or finer) and within
    3% of it."""
    rng = np.random.default_rng(5)
    fn = jax.jit(limit_ratio)
    for S, N in ((2, 3), (3, 2)):
        M = 40
        c = rng.normal(size=(M, S, N, 6)) * rng.uniform(0.2, 3.0, (M, 1, 1, 1))
        T = rng.uniform(0.3, 2.0, M)
        traj = Trajectory.from_normalized(jnp.asarray(c), jnp.asarray(T))
        lim = Limits(*(jnp.asarray(rng.uniform(lo, hi, M)) for lo, hi in
                       ((1.0, 3.0), (2.0, 6.0), (6.0, 20.0))))
        bound = np.asarray(fn(traj, lim))
        dense = _dense_ratio(traj, lim)
        assert np.all(bound >= dense * (1 - 1e-12))
        assert np.all(bound <= dense * 1.03), np.max(bound / dense)
    bad = traj._replace(coeffs=traj.coeffs.at[0, 0, 0, 2].set(jnp.nan))
    assert np.isinf(np.asarray(fn(bad, lim))[0])


def test_the_braking_plan_keeps_to_the_limits():
    """From states within the limits (speed up to v_max, acceleration up to a_max
    against the motion), the plan starts at the state, ends at rest, stays within the
    limits at every instant, and is the shortest braking duration that does."""
    rng = np.random.default_rng(8)
    M, N = 64, 3
    structure = PlannerStructure(nlp=NLPStructure(n_dim=N, degree=5, segments=2))
    lim = Limits(jnp.full(M, 2.0), jnp.full(M, 4.0), jnp.full(M, 12.0))
    u = rng.normal(size=(M, N))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    p = rng.normal(size=(M, N))
    v = u * rng.uniform(0.0, 2.0, (M, 1))
    a = -u * rng.uniform(0.0, 4.0, (M, 1)) + 0.3 * rng.normal(size=(M, N))
    a *= np.minimum(1.0, 4.0 / np.linalg.norm(a, axis=1, keepdims=True))
    brake = jax.jit(planner.limited_braking_plan, static_argnames="structure")(
        p, v, a, lim, structure=structure)
    brake = Trajectory(*jax.device_get(brake))
    np.testing.assert_allclose(np.asarray(brake.evaluate(0.0)), p, atol=1e-12)
    np.testing.assert_allclose(np.asarray(brake.evaluate(0.0, 1)), v, atol=1e-9)
    np.testing.assert_allclose(np.asarray(brake.evaluate(0.0, 2)), a, atol=1e-9)
    T = np.asarray(brake.duration)
    assert np.allclose(np.asarray(brake.evaluate(jnp.asarray(T), 1)), 0.0, atol=1e-9)
    assert np.all(_dense_ratio(brake, lim) <= 1.0 + LIMIT_TOL)
    # one step shorter exceeds the limits (unless it is the first duration tried)
    T0 = np.maximum(1.5 * np.linalg.norm(v, axis=1) / 4.0, 0.5)
    first = np.isclose(T, T0, rtol=1e-12)
    shorter = planner.choice._brake_quintic(jnp.asarray(p), jnp.asarray(v), jnp.asarray(a),
                                            jnp.asarray(T / BRAKE_GROWTH))
    over = np.asarray(limit_ratio(shorter, lim)) > 1.0 + LIMIT_TOL
    assert np.all(over | first) and not np.all(first)


def test_a_brake_beyond_the_limits_flies_only_when_nothing_else_may():
    """Near v_max and still accelerating along the motion, a jerk-limited vehicle cannot
    stop accelerating before it passes v_max (a^2 / (2 j) more): no braking plan keeps
    to the limits (planar box 20 seed 6 flew one at 1.04 v_max, chosen as less violating
    than the previous plan, which was within them).  Such a brake yields to any other
    available plan, however violating, and flies only when there is none."""
    from jaxplan.planner import pick_fallback

    structure = PlannerStructure(nlp=NLPStructure(n_dim=2, degree=5, segments=2))
    lim = Limits(jnp.full(1, 2.0), jnp.full(1, 4.0), jnp.full(1, 12.0))
    brake = jax.jit(planner.limited_braking_plan, static_argnames="structure")(
        jnp.zeros((1, 2)), jnp.asarray([[1.995, 0.0]]), jnp.asarray([[3.0, 0.0]]), lim,
        structure=structure)
    assert float(limit_ratio(brake, lim)[0]) > 1.0 + LIMIT_TOL
    assert _dense_ratio(Trajectory(*jax.device_get(brake)), lim)[0] > 1.03
    inf, no, yes = np.inf, jnp.asarray([False] * 4), jnp.asarray([True] * 4)
    v_sol = jnp.asarray([0.5, inf, inf, 0.1])
    v_prev = jnp.asarray([inf, 0.4, inf, 0.3])
    v_brake = jnp.asarray([0.0, 0.0, 0.0, 0.2])
    np.testing.assert_array_equal(pick_fallback(v_sol, v_prev, v_brake, brake_ok=no),
                                  [Fallback.BEST_EFFORT, Fallback.KEPT_PREVIOUS, Fallback.BRAKING,
                                   Fallback.BEST_EFFORT])
    np.testing.assert_array_equal(pick_fallback(v_sol, v_prev, v_brake, brake_ok=yes),
                                  [Fallback.BRAKING] * 3 + [Fallback.BEST_EFFORT])


PLANAR = """
[planner]
limits = "{mode}"
[[robots]]
vehicle = "ground"
start = [0.0, 0.0]
goal = [1.0, 0.0]
"""


def test_the_key_and_its_errors():
    assert parse_config(tomllib.loads(PLANAR.format(mode="hard"))).planner.limits == "hard"
    assert parse_config(tomllib.loads(PLANAR.replace('limits = "{mode}"\n', ""))
                        ).planner.limits == "soft"
    with pytest.raises(ConfigError, match="planner.limits"):
        parse_config(tomllib.loads(PLANAR.format(mode="firm")))


@pytest.mark.slow
def test_a_planar_crowd_flies_within_its_limits(tmp_path):
    """experiments/deadlock/box_planar.toml (10 ground robots, free ends) seed 0 with hard
    limits: every executed piece within v_max, a_max, j_max (exact metrics), all arrive,
    no collision."""
    from pathlib import Path

    from jaxplan.experiment import run

    doc = tomllib.loads((Path(__file__).parents[1] / "experiments" / "deadlock"
                         / "box_planar.toml").read_text())
    doc["planner"] = {"limits": "hard"}
    doc.pop("sweep")
    m = run(parse_config(doc)).metrics
    assert m["success"] and m["collisions"] == 0
    for k in ("peak_speed_ratio", "peak_acc_ratio", "peak_jerk_ratio"):
        assert m[k] <= 1.0 + 1e-6, (k, m[k])


@pytest.mark.parametrize("degree,segments,rest", [(5, 2, False), (7, 3, True), (9, 1, False)])
def test_the_nlps_limit_rows_are_the_bound_a_plan_must_meet(degree, segments, rest):
    """The NLP's hard-limit constraints (P (1 - |b|^2 / tau^2) over the Bernstein control
    points b of the derivatives, jaxplan.nlp.basis; P = LIMIT_PRIORITY) give the very
    bound limit_ratio checks before a plan flies: a converged solve within its
    constraints is within the limits at every instant."""
    from jaxplan import nlp
    from jaxplan.nlp.terms import LIMIT_PRIORITY
    from jaxplan.testing import random_problem, weights

    rng = np.random.default_rng(degree)
    st = NLPStructure(degree=degree, segments=segments, hard_limits=True)
    for T in (0.6, 2.5):
        p = random_problem(rng, n_others=2, rest=rest, w=weights())
        z = rng.normal(size=(st.n_dim, st.nz)) * 0.3
        x = nlp.pack(jnp.asarray(z), jnp.log(T))
        g = np.asarray(nlp.constraints(x, p, st).limits) / LIMIT_PRIORITY
        traj = jax.tree.map(lambda a: a[None], nlp.to_trajectory(x, p, st))
        lim = jax.tree.map(lambda a: jnp.asarray(a)[None], p.limits)
        bound = float(limit_ratio(traj, lim)[0])
        assert np.sqrt(np.max(1.0 - g)) == pytest.approx(bound, rel=1e-10)
        assert bound >= _dense_ratio(traj, lim, 4001)[0] * (1 - 1e-12)
