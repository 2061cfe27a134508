"""Trajectory pytree: evaluation vs NumPy polynomials, derivatives vs finite differences,
exact time shift, monomial round trip, behaviour after the end."""

import jax
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import jaxplan  # noqa: F401  (x64)
from jaxplan.trajectory import Trajectory


def _random_traj(rng, batch=(5,), S=3, N=3, D=5, coast=None, unequal=True):
    c = rng.normal(size=batch + (S, N, D + 1))
    if unequal:
        h = rng.uniform(0.2, 3.0, size=batch + (S,))
        breaks = np.concatenate([np.zeros(batch + (1,)), np.cumsum(h, axis=-1)], axis=-1)
    else:
        breaks = np.broadcast_to(np.linspace(0, 4.0, S + 1), batch + (S + 1,))
    if coast is None:
        coast = rng.integers(0, 2, size=batch).astype(bool)
    return Trajectory(c, breaks, np.broadcast_to(coast, batch))


def _numpy_eval(coeffs_sec, breaks, coast, t, d):
    """Independent reference: numpy.polynomial on exported monomials in seconds."""
    S = coeffs_sec.shape[0]
    T = breaks[-1]
    tc = min(max(t, 0.0), T)
    k = min(max(np.searchsorted(breaks[1:S], tc, side="right"), 0), S - 1)
    out = []
    for ax in range(coeffs_sec.shape[1]):
        p = np.polynomial.Polynomial(coeffs_sec[k, ax]).deriv(d)
        val = p(tc - breaks[k])
        if t > T:
            v_end = np.polynomial.Polynomial(coeffs_sec[k, ax]).deriv(1)(T - breaks[k])
            if d == 0:
                val = val + (v_end * (t - T) if coast else 0.0)
            elif d == 1:
                val = v_end if coast else 0.0
            else:
                val = 0.0
        out.append(val)
    return np.array(out)


@pytest.mark.parametrize("d", [0, 1, 2, 3])
def test_evaluate_matches_numpy_polynomials(d):
    rng = np.random.default_rng(d)
    tr = _random_traj(rng)
    cm, b = map(np.asarray, tr.to_monomials())
    t = np.linspace(-0.5, 12.0, 57)
    got = np.asarray(tr.sample(t, d))
    for i in range(tr.batch_shape[0]):
        ref = np.stack([_numpy_eval(cm[i], b[i], bool(tr.coast[i]), tt, d) for tt in t])
        scale = 1.0 + np.abs(ref).max()
        np.testing.assert_allclose(got[i], ref, rtol=0, atol=1e-11 * scale)


def test_derivatives_match_finite_differences():
    rng = np.random.default_rng(7)
    tr = _random_traj(rng, batch=(4,), unequal=False)
    h = 1e-5
    t = np.linspace(0.05, 3.95, 40)
    t = t[np.all(np.abs(t[:, None] - np.linspace(0, 4, 4)[None]) > 3 * h, axis=1)]
    for d in range(3):
        f = lambda tt, d=d: np.asarray(tr.sample(tt, d))
        fd = (f(t + h) - f(t - h)) / (2 * h)
        ana = np.asarray(tr.sample(t, d + 1))
        np.testing.assert_allclose(fd, ana, rtol=1e-6, atol=1e-6 * (1 + np.abs(ana).max()))


@jax.jit
def _shifted_and_offset(tr, dt, t):
    """shift(dt) sampled at t, and the trajectory itself at t + dt (derivatives 0-3), in
    one compiled program for every example below (eagerly, each op dispatched alone)."""
    sh = tr.shift(dt)
    return ([sh.sample(t, d) for d in range(4)], [tr.sample(t + dt, d) for d in range(4)],
            sh.duration)


@settings(max_examples=40, deadline=None)
@given(dt=st.floats(0.0, 15.0), seed=st.integers(0, 10_000))
def test_shift_is_exact(dt, seed):
    rng = np.random.default_rng(seed)
    tr = _random_traj(rng, batch=(3,))
    t = np.linspace(0.0, 14.0, 41)
    shifted, offset, duration = jax.device_get(_shifted_and_offset(tr, dt, t))
    for a, b in zip(shifted, offset, strict=True):
        scale = 1.0 + np.abs(b).max()
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-9 * scale)
    assert np.allclose(duration, np.maximum(np.asarray(tr.duration) - dt, 0.0))


def test_monomial_round_trip():
    rng = np.random.default_rng(3)
    tr = _random_traj(rng, batch=(2, 3))
    cm, b = tr.to_monomials()
    back = Trajectory.from_monomials(cm, b, tr.coast)
    np.testing.assert_allclose(np.asarray(back.coeffs), tr.coeffs, rtol=1e-13, atol=1e-13)


def test_hold_and_coast_after_the_end():
    c = np.zeros((1, 2, 6))
    c[0, :, 1] = [1.0, -2.0]  # linear in s: velocity (1, -2) / T
    T = 2.0
    hold = Trajectory.from_normalized(c, T, coast=False)
    coast = Trajectory.from_normalized(c, T, coast=True)
    v_end = np.array([0.5, -1.0])
    p_end = np.array([1.0, -2.0])
    np.testing.assert_allclose(hold.evaluate(5.0), p_end)
    np.testing.assert_allclose(hold.evaluate(5.0, 1), 0.0)
    np.testing.assert_allclose(coast.evaluate(5.0), p_end + 3.0 * v_end)
    np.testing.assert_allclose(coast.evaluate(5.0, 1), v_end)
    np.testing.assert_allclose(coast.evaluate(5.0, 2), 0.0)
    # before the start: clamped to t = 0
    np.testing.assert_allclose(coast.evaluate(-1.0), 0.0)


def test_zero_duration_hold_is_finite():
    h = Trajectory.hold(np.array([[1.0, 2.0, 3.0]]), degree=5, segments=2)
    for d in range(4):
        v = np.asarray(h.sample(np.array([0.0, 1.0]), d))
        assert np.all(np.isfinite(v))
    np.testing.assert_allclose(h.sample(np.array([0.0, 3.0]))[0], [[1, 2, 3], [1, 2, 3]])


def test_evaluate_jit_and_vmap():
    rng = np.random.default_rng(11)
    tr = _random_traj(rng, batch=(6,))
    t = rng.uniform(0, 8, size=6)
    direct = np.asarray(tr.evaluate(t, 1))
    jitted = np.asarray(jax.jit(lambda tr, t: tr.evaluate(t, 1))(tr, t))
    vmapped = np.asarray(jax.vmap(lambda tr, t: tr.evaluate(t, 1))(tr, t))
    np.testing.assert_allclose(jitted, direct, atol=1e-13)
    np.testing.assert_allclose(vmapped, direct, atol=1e-13)


def test_calls_outside_jit_run_one_compiled_program_per_shape():
    """evaluate and shift called outside any transformation run one compiled program,
    compiled once per shape (op by op every call traced its vmap again); inside a
    transformation they add their operations to the caller's program (no nested call)."""
    from jaxplan import trajectory as tj

    tr = _random_traj(np.random.default_rng(12), batch=(7,), S=2)
    t = np.linspace(0.0, 5.0, 13)[:, None]  # shapes no other test uses
    n_eval, n_shift = tj._evaluate_jit._cache_size(), tj._shift_jit._cache_size()
    first = np.asarray(tr.evaluate(t, 2))
    again = np.asarray(tr.evaluate(t + 0.5, 2))
    assert tj._evaluate_jit._cache_size() == n_eval + 1
    np.testing.assert_array_equal(first[1:3], np.asarray(tr.evaluate(t[1:3], 2)))
    assert tj._evaluate_jit._cache_size() == n_eval + 2  # a new shape: one more program
    np.testing.assert_allclose(np.asarray(tr.shift(0.5).evaluate(t, 2)), again, rtol=1e-10,
                               atol=1e-10)
    tr.shift(0.25)
    assert tj._shift_jit._cache_size() == n_shift + 1
    tr.shift(np.full(7, 0.25))
    assert tj._shift_jit._cache_size() == n_shift + 2
    for f in (lambda tr, t: tr.evaluate(t, 2), lambda tr, t: tr.shift(t[0, 0]).coeffs):
        jaxpr = jax.make_jaxpr(f)(tr, t)
        names = {e.params.get("name") for e in jaxpr.eqns}
        assert not names & {"_evaluate", "_shift"}, names
