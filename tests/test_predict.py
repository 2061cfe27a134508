"""Closed-form prediction (MATH.md 1) against independent references:
boundary conditions, quadrature of the cost, a dense + scipy search for the global
minimizer of J(T), numpy.roots of the sextic, and property tests."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import minimize_scalar

import jaxplan  # noqa: F401
from jaxplan.predict import cost, cost_quartic, predict, predict_arrays, sextic

N_CASES = 1200


def _cases(n, seed=0):
    rng = np.random.default_rng(seed)
    scale = 10 ** rng.uniform(-2, 2, size=(n, 1))
    p0 = rng.normal(size=(n, 3)) * scale
    pf = rng.normal(size=(n, 3)) * scale
    moving = rng.integers(0, 2, size=(n, 1))
    v0 = rng.normal(size=(n, 3)) * np.sqrt(scale) * moving
    a0 = rng.normal(size=(n, 3)) * moving
    vf = rng.normal(size=(n, 3)) * rng.integers(0, 2, size=(n, 1))
    af = rng.normal(size=(n, 3)) * rng.integers(0, 2, size=(n, 1))
    full = rng.integers(0, 2, size=n).astype(bool)
    w = 10 ** rng.uniform(-1, 1, size=n)
    return p0, v0, a0, pf, vf, af, full, w


@pytest.fixture(scope="module")
def solved():
    args = _cases(N_CASES)
    tr = jax.jit(predict_arrays)(*args)
    cm, b = map(np.asarray, tr.to_monomials())
    return args, tr, cm[:, 0], np.asarray(tr.duration)


def _np_eval(c, t, d):
    """c (..., N, 6) monomials in seconds -> d-th derivative at t (...,)."""
    out = []
    for ax in range(c.shape[-2]):
        vals = [np.polynomial.Polynomial(ci).deriv(d)(ti)
                for ci, ti in zip(c[:, ax], t, strict=True)]
        out.append(vals)
    return np.array(out).T


def test_boundary_conditions(solved):
    (p0, v0, a0, pf, vf, af, full, w), tr, c, T = solved
    assert np.all(T > 0)
    z = np.zeros(len(T))
    scale = 1 + np.abs(np.stack([p0, pf])).max(axis=(0, 2))[:, None]
    np.testing.assert_allclose(_np_eval(c, z, 0), p0, rtol=0, atol=1e-12 * scale.max())
    for got, ref, _d in [(_np_eval(c, z, 1), v0, 1), (_np_eval(c, z, 2), a0, 2)]:
        assert np.all(np.abs(got - ref) <= 1e-9 * (1 + np.abs(ref)))
    pe = _np_eval(c, T, 0)
    assert np.all(np.abs(pe - pf) <= 1e-9 * scale)
    ve, ae = _np_eval(c, T, 1), _np_eval(c, T, 2)
    vs = 1 + np.abs(vf) + np.abs(v0) + np.abs(a0) * T[:, None] + np.abs(pf - p0) / T[:, None]
    assert np.all(np.abs(ve - vf)[full] <= (1e-9 * vs)[full])
    assert np.all(np.abs(ae - af)[full] <= (1e-9 * vs / T[:, None] * 10)[full])
    # the trajectory's own evaluation agrees with the exported monomials
    np.testing.assert_allclose(np.asarray(tr.evaluate(T, 0)), pe, rtol=1e-12, atol=1e-12)


def test_cost_equals_quadrature(solved):
    (p0, v0, a0, pf, vf, af, full, w), tr, c, T = solved
    q = np.asarray(cost_quartic(p0, v0, a0, pf, vf, af, full))
    J_closed = np.asarray(cost(T, q, w))
    # Gauss-Legendre with 8 nodes integrates |jerk|^2 (degree 4) exactly; use 12 anyway.
    x, wq = np.polynomial.legendre.leggauss(12)
    J_quad = np.empty(len(T))
    for i in range(len(T)):
        ts = 0.5 * T[i] * (x + 1)
        j = np.stack([np.polynomial.Polynomial(c[i, ax]).deriv(3)(ts) for ax in range(3)])
        J_quad[i] = 0.5 * T[i] * np.sum(wq * np.sum(j * j, axis=0)) + w[i] * T[i]
    np.testing.assert_allclose(J_closed, J_quad, rtol=1e-9)


def test_T_is_global_minimizer(solved):
    (p0, v0, a0, pf, vf, af, full, w), tr, c, T = solved
    q = np.asarray(cost_quartic(p0, v0, a0, pf, vf, af, full))
    grid = np.geomspace(1e-4, 1e4, 20001)
    worse = 0
    for i in range(len(T)):
        Jg = q[i, 0] / grid**5 + q[i, 1] / grid**4 + q[i, 2] / grid**3 + q[i, 3] / grid**2
        Jg = Jg + q[i, 4] / grid + w[i] * grid
        k = int(np.argmin(Jg))
        lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
        res = minimize_scalar(
            lambda t, i=i: float(cost(t, q[i], w[i])), bounds=(lo, hi), method="bounded",
            options={"xatol": 1e-12 * hi},
        )
        J_ref = min(res.fun, Jg[k])
        J_got = float(cost(T[i], q[i], w[i]))
        if J_got > J_ref + 1e-10 * abs(J_ref):
            worse += 1
    assert worse == 0


def test_roots_agree_with_numpy(solved):
    (p0, v0, a0, pf, vf, af, full, w), tr, c, T = solved
    q = np.asarray(cost_quartic(p0, v0, a0, pf, vf, af, full))
    a = np.asarray(sextic(jnp.asarray(q), jnp.asarray(w)))
    for i in range(len(T)):
        r = np.roots(a[i][::-1])
        r = r[(np.abs(r.imag) <= 1e-7 * np.abs(r)) & (r.real > 0)].real
        assert len(r) >= 1
        Jr = np.array([float(cost(x, q[i], w[i])) for x in r])
        best = r[np.argmin(Jr)]
        # the chosen root is numpy's least-cost positive root (or one of equal cost)
        ok = abs(T[i] - best) <= 1e-7 * best or abs(float(cost(T[i], q[i], w[i])) - Jr.min()) <= (
            1e-12 * abs(Jr.min())
        )
        assert ok, (i, T[i], r, Jr)
        # and it is a root of P
        assert abs(np.polyval(a[i][::-1], T[i])) <= 1e-8 * np.polyval(np.abs(a[i][::-1]), T[i])


def test_rest_to_rest_closed_form():
    D = np.array([[3.0, -4.0, 0.0]])
    tr = predict(np.zeros((1, 3)), np.zeros((1, 3)), np.zeros((1, 3)), D, end="rest")
    # T^6 = 3600 |D|^2 / w
    np.testing.assert_allclose(float(tr.duration[0]), (3600 * 25.0) ** (1 / 6), rtol=1e-12)
    np.testing.assert_allclose(np.asarray(tr.evaluate(tr.duration, 1)), 0.0, atol=1e-12)


@settings(max_examples=60, deadline=None)
@given(
    log_scale=st.floats(-6, 4),
    seed=st.integers(0, 2**31 - 1),
    end=st.sampled_from(["free", "rest"]),
    moving=st.booleans(),
)
def test_scale_property(log_scale, seed, end, moving):
    rng = np.random.default_rng(seed)
    L = 10.0**log_scale
    p0 = rng.normal(size=3) * L
    goal = p0 + rng.normal(size=3) * L
    # consistent scales: T ~ L^(1/3) for a move of L metres, so v ~ L^(2/3), a ~ L^(1/3)
    v0 = rng.normal(size=3) * L ** (2 / 3) if moving else np.zeros(3)
    a0 = rng.normal(size=3) * L ** (1 / 3) if moving else np.zeros(3)
    tr = predict(p0, v0, a0, goal, end=end)
    T = float(tr.duration)
    assert np.isfinite(T) and T > 0
    assert np.all(np.isfinite(np.asarray(tr.coeffs)))
    scale = L + np.abs(goal).max() + np.abs(p0).max()
    np.testing.assert_allclose(np.asarray(tr.evaluate(T)), goal, rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(np.asarray(tr.evaluate(0.0, 1)), v0, rtol=0,
                               atol=1e-9 * (L ** (2 / 3) + np.abs(v0).max()))


@settings(max_examples=30, deadline=None)
@given(p=st.lists(st.floats(-1e4, 1e4), min_size=3, max_size=3),
       end=st.sampled_from(["free", "rest"]))
def test_at_goal_gives_finite_hold(p, end):
    p = np.array(p)
    tr = predict(p, np.zeros(3), np.zeros(3), p, end=end)
    assert float(tr.duration) == 0.0
    for d in range(4):
        v = np.asarray(tr.sample(np.array([0.0, 1.0, 10.0]), d))
        assert np.all(np.isfinite(v))
    # XLA flushes subnormals
    np.testing.assert_allclose(np.asarray(tr.evaluate(3.0)), p, rtol=1e-15, atol=1e-300)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("arg", ["p0", "v0", "a0", "goal"])
def test_non_finite_input_is_a_clear_error(bad, arg):
    kw = {k: np.zeros(3) for k in ("p0", "v0", "a0")}
    kw["goal"] = np.ones(3)
    kw[arg] = np.array([0.0, bad, 0.0])
    with pytest.raises(ValueError, match=arg):
        predict(kw["p0"], kw["v0"], kw["a0"], kw["goal"])


@settings(max_examples=40, deadline=None)
@given(
    vals=st.lists(
        st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.floats(-1e3, 1e3)),
        min_size=12, max_size=12,
    ),
    full=st.booleans(),
)
def test_core_never_returns_nan(vals, full):
    x = np.array(vals).reshape(4, 3)
    tr = _core(x[0], x[1], x[2], x[3], np.zeros(3), np.zeros(3), full, 1.0)
    assert np.all(np.isfinite(np.asarray(tr.coeffs)))
    assert np.isfinite(float(tr.duration)) and float(tr.duration) >= 0
    finite = bool(np.all(np.isfinite(x)))
    if not finite:
        assert float(tr.duration) == 0.0


_core = jax.jit(predict_arrays)


def test_bad_arguments():
    z = np.zeros(3)
    with pytest.raises(ValueError, match="end"):
        predict(z, z, z, z + 1, end="sideways")
    with pytest.raises(ValueError, match="goal_velocity"):
        predict(z, z, z, z + 1, goal_velocity=z)
    with pytest.raises(ValueError, match="time_weight"):
        predict(z, z, z, z + 1, time_weight=-1.0)
    with pytest.raises(ValueError, match="shape|broadcast|dimension"):
        predict(np.zeros(3), z, z, np.ones(2))


def test_planar_and_batched_shapes():
    rng = np.random.default_rng(5)
    p0 = rng.normal(size=(4, 7, 2))
    goal = rng.normal(size=(4, 7, 2))
    tr = predict(p0, 0 * p0, 0 * p0, goal)
    assert tr.duration.shape == (4, 7)
    assert tr.coeffs.shape == (4, 7, 1, 2, 6)
    np.testing.assert_allclose(np.asarray(tr.evaluate(tr.duration)), goal, atol=1e-9)
