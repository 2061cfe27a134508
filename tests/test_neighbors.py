"""Neighbour selection (planner.max_neighbors): the K nearest others, against brute force."""

import tomllib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplan import experiment as ex
from jaxplan import run_setup as rs
from jaxplan.config import build_scenario, parse_config
from jaxplan.planner import (
    NEIGHBOR_HORIZON_S,
    NEIGHBOR_SAMPLES,
    PlannerStructure,
    all_others,
    fresh_views,
    nearest_neighbors,
    predict_views,
    remap_slots,
)
from jaxplan.rollout import initial_state

# jitted: op by op (eager), every operation compiles on its own for each new shape
# (about half of this module's time)
_predict_fresh = jax.jit(lambda p, v, a, g, gv, rest, w: predict_views(
    fresh_views(p, v, a, g, gv, rest), w))
_nearest = jax.jit(nearest_neighbors, static_argnums=3)


def _fleet(M, seed):
    rng = np.random.default_rng(seed)
    p = rng.uniform(-6, 6, (M, 3))
    g = rng.uniform(-6, 6, (M, 3))
    v = rng.normal(size=(M, 3)) * 0.5
    rest = rng.uniform(size=M) < 0.5
    preds = _predict_fresh(jnp.asarray(p), jnp.asarray(v), jnp.zeros((M, 3)), jnp.asarray(g),
                           jnp.zeros((M, 3)), jnp.asarray(rest), 1.0)
    return preds, rng


def test_nearest_neighbors_match_brute_force():
    M, K = 12, 4
    preds, rng = _fleet(M, 0)
    radius = jnp.asarray(rng.uniform(0.2, 0.5, (M, M)))
    mask = ~np.eye(M, dtype=bool)
    mask[3, 7] = False  # an other that must never be picked
    idx = np.asarray(_nearest(preds, radius, jnp.asarray(mask), K))
    lo, hi = NEIGHBOR_HORIZON_S
    host = jax.device_get(preds)  # sliced on the host; one compiled evaluation for all
    evaluate = jax.jit(lambda tr, t: tr.evaluate(t[:, None]))
    for i in range(M):
        own = jax.tree.map(lambda u, i=i: u[i, i], host)
        H = float(np.clip(own.duration, lo, hi))
        t = np.linspace(0, H, NEIGHBOR_SAMPLES)
        xi = np.asarray(evaluate(own, t)).reshape(-1, 3)
        score = []
        for j in range(M):
            if not mask[i, j]:
                score.append(np.inf)
                continue
            oj = jax.tree.map(lambda u, i=i, j=j: u[i, j], host)
            xj = np.asarray(evaluate(oj, t)).reshape(-1, 3)
            score.append(np.min(np.linalg.norm(xj - xi, axis=-1)) - float(radius[i, j]))
        want = np.argsort(score, kind="stable")[:K]
        assert set(idx[i]) == set(want), (i, idx[i], want)
        assert i not in idx[i]
    assert 7 not in idx[3]


def test_structure_slots():
    s = PlannerStructure(max_neighbors=4)
    assert s.others(10) == 4 and s.others(5) == 4 and s.others(4) == 3
    assert PlannerStructure().others(100) == 99 and PlannerStructure().others(1) == 1
    # without a neighbour limit robot i's slots hold every other robot, in order
    for M in (1, 2, 5):
        idx = all_others(M)
        assert idx.shape == (M, max(M - 1, 1))
        for i in range(M):
            assert list(idx[i]) == ([j for j in range(M) if j != i] or [0])


BOX = """
name = "box_k"
seed = 3
[sim]
duration_s = 6.0
[planner]
max_neighbors = {K}
[scenario]
kind = "random_box"
count = 8
"""


@pytest.mark.slow  # a closed loop with max_neighbors compiled (~29 s on 2 cores)
def test_run_with_neighbors_is_finite_and_follows_multipliers():
    cfg = parse_config(tomllib.loads(BOX.format(K=3)), source="box_k.toml")
    sc = build_scenario(cfg)
    st = rs.structures(cfg)
    assert st.planner.max_neighbors == 3
    fp, task = rs.fleet_params(cfg, sc), rs.task_of(cfg, sc)
    f = ex.step_runner(st)
    s = initial_state(task, st)
    assert s.plans.multipliers.collision.shape[-1] == 3
    assert np.all(np.asarray(s.plans.neighbors) == -1)
    for _ in range(6):
        s, rec = f(fp, task, s)
        nb = np.asarray(s.plans.neighbors)
        assert nb.shape == (8, 3)
        assert not np.any(nb == np.arange(8)[:, None])  # never itself
        assert np.all(np.isfinite(np.asarray(s.plans.plan.coeffs)))


@pytest.mark.slow  # its own closed-loop program (~18 s of the 2-core suite): `make test-slow`
def test_neighbors_run_end_to_end():
    from jaxplan.experiment import run

    res = run(parse_config(tomllib.loads(BOX.format(K=3)), source="box_k.toml"))
    m = res.metrics
    assert m["collisions"] == 0, m["worst_pair"]
    assert m["success"], [r["reached"] for r in m["per_robot"]]


def test_multipliers_follow_their_robot():
    rng = np.random.default_rng(1)
    lam = rng.uniform(size=(2, 5, 3))
    old = np.array([[4, 1, 6], [2, -1, 0]])
    new = np.array([[6, 2, 4], [0, 2, 5]])
    out = np.asarray(remap_slots(jnp.asarray(lam), jnp.asarray(old), jnp.asarray(new)))
    want = np.zeros_like(lam)
    for m in range(2):
        for n in range(3):
            hit = np.flatnonzero(old[m] == new[m, n])
            if len(hit):
                want[m, :, n] = lam[m, :, hit[0]]
    np.testing.assert_array_equal(out, want)
    assert np.all(out[0, :, 1] == 0) and np.all(out[1, :, 2] == 0)  # robots 2, 5: new
