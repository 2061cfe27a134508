"""Tests of jaxplan.nlp: the NLP's terms, parametrization and structured derivatives."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxplan  # noqa: F401
from jaxplan import nlp
from jaxplan.nlp import Multipliers, NLPStructure
from jaxplan.predict import quintic_coeffs
from jaxplan.testing import random_problem, weights
from jaxplan.trajectory import Trajectory


def _x(rng, st, T, scale=0.2):
    x = np.zeros(st.n_x)
    x[:-1] = rng.normal(size=st.n_x - 1) * scale
    x[-1] = np.log(T)
    return jnp.asarray(x)


CASES = [
    (NLPStructure(collision="barrier+constraint", hard_limits=True), False),
    (NLPStructure(collision="barrier+constraint", segments=3, hard_limits=True), True),
    (NLPStructure(collision="paper", segments=2), False),
    (NLPStructure(collision="constraint", degree=7), True),
    (NLPStructure(collision="barrier+constraint", segments=2, n_coast_samples=6), False),
    (NLPStructure(collision="constraint", segments=2, n_coast_samples=6), True),
]


def _problem_and_multipliers(rng, st, rest):
    """A random NLP with 6 others (soft limits on), its end-kind constants and random
    multipliers (collision 0-50, limits 0-5)."""
    p = random_problem(rng, n_others=6, rest=rest, w=weights(q_lim=0.5))
    b = nlp.basis(st)
    mult = Multipliers(jnp.asarray(rng.uniform(0, 50, (st.n_col, 10))),
                       jnp.asarray(rng.uniform(0, 5, (len(b.lim_s), 3))))
    return p, nlp.kind_constants(p.rest, st), mult


# Every case compiles two programs (~4-7 s on 2 cores): `make test` checks three that
# between them reach every term (hard limits and three segments, degree 7, coast
# samples, rest and free ends); all six under `make test-slow`.
SLOW_CASES = (0, 2, 5)


@pytest.mark.parametrize("st,rest", [pytest.param(*c, marks=pytest.mark.slow) if i in SLOW_CASES
                                     else c for i, c in enumerate(CASES)])
def test_structured_derivatives_match_autodiff(st, rest):
    rng = np.random.default_rng(0)
    p, kc, mult = _problem_and_multipliers(rng, st, rest)
    x = _x(rng, st, 5.0, 0.05)
    f = lambda xx: nlp.merit(xx, p, st, kc, mult, 30.0)
    v, g, H = jax.jit(lambda xx: nlp.merit_derivs(xx, p, st, kc, mult, 30.0))(x)
    vr, gr, Hr = jax.jit(lambda xx: (f(xx), jax.grad(f)(xx), jax.hessian(f)(xx)))(x)
    np.testing.assert_allclose(v, vr, rtol=1e-12)
    np.testing.assert_allclose(g, gr, rtol=1e-9, atol=1e-9 * np.max(np.abs(g)))
    assert np.all(np.isfinite(Hr)) and np.all(np.isfinite(H))  # NaN would match NaN
    np.testing.assert_allclose(H, Hr, rtol=1e-8, atol=1e-9 * np.max(np.abs(Hr)))


@pytest.mark.parametrize("q_lim,rest,prio", [
    (0.5, True, None), (0.0, False, 3.0),  # the others: test-slow
    pytest.param(0.5, False, None, marks=pytest.mark.slow),
    pytest.param(0.0, True, None, marks=pytest.mark.slow)])
def test_limit_derivatives_match_autodiff_where_the_limits_bind(q_lim, rest, prio):
    """A fast plan (T = 0.8 s for a few metres): the hard-limit AL terms are active on
    their quadratic branch and the soft limits far up their exponential, the branches
    the test above (slow plans) does not reach.  With q_lim = 0 the hard limits alone
    (the soft ones would swamp them in the tolerance).  prio: the NLP's own
    limit_priority (None: LIMIT_PRIORITY)."""
    st = NLPStructure(collision="barrier+constraint", segments=2, hard_limits=True)
    rng = np.random.default_rng(3)
    p = random_problem(rng, n_others=4, rest=rest, w=weights(q_lim=q_lim))
    if prio is not None:
        p = p._replace(limit_priority=jnp.asarray(prio))
    kc = nlp.kind_constants(p.rest, st)
    b = nlp.basis(st)
    mult = Multipliers(jnp.asarray(rng.uniform(0, 5, (st.n_col, 10))),
                       jnp.asarray(rng.uniform(0, 5, (len(b.lim_s), 3))))
    x = _x(rng, st, 0.8, 0.05)
    g_lim = jax.jit(lambda xx: nlp.constraints(xx, p, st).limits)(x)  # eager: ~2 s more
    assert float(jnp.mean(mult.limits - 30.0 * g_lim > 0)) > 0.3  # active AL branch
    f = lambda xx: nlp.merit(xx, p, st, kc, mult, 30.0)
    v, g, H = jax.jit(lambda xx: nlp.merit_derivs(xx, p, st, kc, mult, 30.0))(x)
    vr, gr, Hr = jax.jit(lambda xx: (f(xx), jax.grad(f)(xx), jax.hessian(f)(xx)))(x)
    np.testing.assert_allclose(v, vr, rtol=1e-12)
    np.testing.assert_allclose(g, gr, rtol=1e-9, atol=1e-9 * np.max(np.abs(g)))
    assert np.all(np.isfinite(Hr)) and np.all(np.isfinite(H))  # NaN would match NaN
    np.testing.assert_allclose(H, Hr, rtol=1e-8, atol=1e-9 * np.max(np.abs(Hr)))


@pytest.mark.parametrize("st,rest", CASES)
@pytest.mark.parametrize("T", [5.0, 0.8])
def test_merit_shapes_equals_merit_at_each_shape(st, rest, T):
    """merit_shapes (several shapes at one horizon, shared tau parts) against merit at
    each point: a slow plan (T = 5 s) and a fast one (0.8 s: the soft limits far up
    their exponential, the hard-limit AL terms on their quadratic branch)."""
    rng = np.random.default_rng(4)
    p, kc, mult = _problem_and_multipliers(rng, st, rest)
    xs = jnp.stack([_x(rng, st, T, sc) for sc in (0.0, 0.05, 0.5, 2.0, 2.0)])
    xs = xs.at[:, -1].set(np.log(T))
    zs = jax.vmap(lambda x: nlp.unpack(x, st)[0])(xs)
    got = jax.jit(lambda z: nlp.merit_shapes(z, jnp.log(T), p, st, kc, mult, 30.0))(zs)
    ref = jax.jit(jax.vmap(lambda x: nlp.merit(x, p, st, kc, mult, 30.0)))(xs)
    assert np.all(np.isfinite(ref)) and len(set(np.round(np.asarray(ref), 6))) >= 4
    np.testing.assert_allclose(got, ref, rtol=1e-12)


@pytest.mark.parametrize("st,rest", CASES)
def test_equalities_hold_by_construction(st, rest):
    rng = np.random.default_rng(1)
    p = random_problem(rng, n_others=3, rest=rest)
    xs = jnp.stack([_x(rng, st, rng.uniform(0.5, 20.0), 3.0) for _ in range(4)])
    res = jax.jit(jax.vmap(lambda x: nlp.equality_residual(x, p, st)))(xs)
    assert float(jnp.max(res)) < 1e-9


@pytest.mark.parametrize("rest", [False, True])
def test_z0_is_closed_form_prediction_and_jerk_is_exact(rest):
    st = NLPStructure(segments=2, collision="none")
    rng = np.random.default_rng(2)
    p = random_problem(rng, n_others=2, rest=rest)
    T = 4.3
    x = jnp.zeros(st.n_x).at[-1].set(np.log(T))
    ts = np.linspace(0, T, 41)

    # each part in one program: op by op (eager) this test took ~3 s more
    @jax.jit
    def z0_and_quintic(x, p, t):
        c1 = quintic_coeffs(p.p0, p.v0, p.a0, p.goal_p, p.goal_v, p.goal_a, p.rest,
                            jnp.asarray(T))
        return (nlp.to_trajectory(x, p, st).evaluate(t),
                Trajectory.from_normalized(c1[None], T).evaluate(t))

    got, ref = z0_and_quintic(x, p, ts[:, None])
    np.testing.assert_allclose(got, ref, atol=1e-10)
    # analytic smoothness == numerical integral of |jerk|^2 (x with shape freedom)
    x = _x(rng, st, T, 0.5)
    if rest:  # a rest lane's two spare shape variables per axis are inert (cost only)
        z, tau = nlp.unpack(x, st)
        x = nlp.pack(z.at[:, -2:].set(0.0), tau)
    tq, wq = np.polynomial.legendre.leggauss(20)
    t = (np.arange(st.segments)[:, None] + (tq + 1) / 2) * T / st.segments  # (segments, 20)

    @jax.jit
    def jerk_and_smooth(x, p, t):
        ana = nlp.smooth_time(x, p._replace(weights=weights(k_t=0.0)), st,
                              nlp.kind_constants(p.rest, st))
        return nlp.to_trajectory(x, p, st).evaluate(t, 3), ana

    j, ana = jerk_and_smooth(x, p, t.reshape(-1))
    j = np.asarray(j).reshape(st.segments, len(tq), -1)
    num = sum(np.sum(wq[:, None] * j[k] ** 2) / 2 * T / st.segments for k in range(st.segments))
    np.testing.assert_allclose(ana, num, rtol=1e-10)


def test_paper_term_is_path_independent():
    """The printed collision term is a total derivative (MATH.md): its integral depends
    only on the end points, not on the path in between.  Reference: the printed
    integrand (dx . dv) / (d exp(k_p (d - rho))) integrated densely (composite Simpson,
    20,000 panels) along four different paths with the same end points; the NLP's
    "paper" term (integrated exactly) must equal each of them."""
    st = NLPStructure(collision="paper", segments=2)
    st0 = NLPStructure(collision="none", segments=2)
    rng = np.random.default_rng(3)
    q_obs, k_p = 1.0, 2.0
    p = random_problem(rng, n_others=5, w=weights(q_obs=q_obs, k_p=k_p, q_lim=0.0))
    T = 5.0
    xs = jnp.stack([_x(rng, st, T, 0.1 * i) for i in range(4)])
    via_nlp = jax.jit(jax.vmap(lambda x: nlp.objective(x, p, st) - nlp.objective(x, p, st0)))(xs)
    t = np.linspace(0.0, T, 40001)
    sw = np.ones_like(t)
    sw[1:-1:2], sw[2:-1:2] = 4.0, 2.0
    sw *= (t[1] - t[0]) / 3.0
    # the dense samples in one program: op by op (eager) this test took ~4 s more
    samples = lambda tr, t: (tr.evaluate(t), tr.evaluate(t, 1), tr.evaluate(T))
    o, ov, _ = map(np.asarray, jax.jit(samples)(p.others, t[:, None]))  # (K, Mo, N)
    rho = float(p.radius) + np.asarray(p.other_radius)
    mask = np.asarray(p.other_mask)
    dense, ends = [], []
    plan_samples = jax.jit(lambda x, t: samples(
        Trajectory.from_normalized(*nlp.coefficients(x, p, st)), t))
    for x in xs:
        xt, vt, end = plan_samples(x, t)
        dx = np.asarray(xt)[:, None, :] - o
        dv = np.asarray(vt)[:, None, :] - ov
        d = np.linalg.norm(dx, axis=-1)
        integrand = np.sum(dx * dv, axis=-1) / d * np.exp(-k_p * (d - rho))
        dense.append(q_obs * np.sum(sw @ np.where(mask, integrand, 0.0)))
        ends.append(np.asarray(end))
    np.testing.assert_allclose(np.ptp(ends, axis=0), 0.0, atol=1e-9)  # same end points
    assert np.ptp([float(np.max(np.abs(np.asarray(x[:-1])))) for x in xs]) > 0.1  # paths differ
    np.testing.assert_allclose(dense, dense[0], rtol=1e-7)  # path independent
    np.testing.assert_allclose(np.asarray(via_nlp), dense, rtol=1e-7)


def test_others_hold_or_coast_after_their_end():
    c = np.zeros((2, 1, 3, 6))
    c[:, 0, 0, 1] = 2.0  # x = 2 s (normalized), T = 2 -> 1 m/s
    tr = Trajectory.from_normalized(c, jnp.asarray([2.0, 2.0]), coast=jnp.asarray([False, True]))
    out = nlp.others_derivs(tr, jnp.asarray([True, True]), jnp.asarray([1.0, 3.0]), 1)
    np.testing.assert_allclose(out[0][1, :, 0], [2.0, 3.0])  # hold vs coast
    np.testing.assert_allclose(out[1][1, :, 0], [0.0, 1.0])
    np.testing.assert_allclose(out[0][0, :, 0], [1.0, 1.0])
    # the derivatives' layout of the same (components first, samples last)
    jet = nlp.others_jet(nlp.prepare_others(tr, jnp.asarray([True, True])), jnp.asarray([1.0, 3.0]),
                     1)
    for a, b in zip(jet, out, strict=True):
        np.testing.assert_allclose(np.moveaxis(np.asarray(a), (0, 1, 2), (2, 1, 0)), b)


@pytest.mark.parametrize("So", [1, 3])
def test_others_derivs_match_trajectory_evaluate(So):
    """The others' jet (values and two derivatives) equals Trajectory.evaluate, also at
    segment breaks, before 0 and after the end (hold or coast), for one and several
    segments (the one-segment case skips the segment look-up)."""
    rng = np.random.default_rng(11)
    Mo = 4
    c = rng.normal(size=(Mo, So, 3, 6))
    T = rng.uniform(1.0, 3.0, Mo)
    tr = Trajectory.from_normalized(c, jnp.asarray(T), coast=jnp.asarray([False, True] * 2))
    t = np.concatenate([[-0.5, 0.0], np.linspace(0.0, 3.5, 29), T[:1] * np.arange(So + 1) / So])
    mask = jnp.asarray([True, True, True, False])
    # jitted, one program: op by op (eager) this took ~3 s
    @jax.jit
    def run(tr, mask, t):
        out = nlp.others_derivs(tr, mask, t, 2)
        # the structured derivatives read the same from the prepared layout (N, Mo, K)
        jet = nlp.others_jet(nlp.prepare_others(tr, mask), t, 2)
        refs = [tr.evaluate(jnp.clip(t, 0.0, None)[:, None], r) for r in range(3)]
        return out, jet, refs

    out, jet, refs = run(tr, mask, jnp.asarray(t))
    for r in range(3):
        ref = np.array(refs[r])
        ref[:, 3] = 0.0  # masked: ignored (zeros)
        np.testing.assert_allclose(out[r], ref, rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(np.moveaxis(np.asarray(jet[r]), (0, 1, 2), (2, 1, 0)), ref,
                                   rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("rest", [False, True])
def test_coast_constraints_are_the_flown_coast(rest):
    """The coast rows of a free-end NLP are d^2 - rho^2 of the plan's own coast after T
    (Trajectory.evaluate, coast=True) against the others at T + t_c k / n; on a rest lane
    they are inactive (+1).  The rows before are unchanged by the coast."""
    n = 5
    st = NLPStructure(collision="barrier+constraint", segments=2, n_coast_samples=n)
    st0 = NLPStructure(collision="barrier+constraint", segments=2)
    rng = np.random.default_rng(7)
    p = random_problem(rng, n_others=4, rest=rest)
    x = _x(rng, st, 3.0, 0.3)
    # each in its own program (as the solver forms them): op by op (eager) this test took
    # ~5 s more
    g = jax.jit(lambda x, p: nlp.constraints(x, p, st).collision)(x, p)
    g0 = jax.jit(lambda x, p: nlp.constraints(x, p, st0).collision)(x, p)
    assert g.shape == (st0.n_collision_samples + n, 10)
    np.testing.assert_array_equal(g[: st0.n_collision_samples], g0)
    if rest:
        np.testing.assert_array_equal(g[-n:], 1.0)
        return
    tc = float(nlp.coast_time(p.limits))
    lim = p.limits
    assert tc == pytest.approx(lim.v_max / (2 * lim.a_max) + lim.a_max / (2 * lim.j_max))
    t = 3.0 + tc * np.arange(1, n + 1) / n
    me, others = jax.jit(lambda x, p, t: (nlp.to_trajectory(x, p, st).evaluate(t),
                                          p.others.evaluate(t)))(x, p, t[:, None])
    me = np.asarray(me).reshape(n, -1)  # p(T) + v(T) (t - T)
    others = np.asarray(others).reshape(n, 10, -1)  # (n, Mo, N)
    rho = float(p.radius) + np.asarray(p.other_radius)
    ref = np.sum((me[:, None] - others) ** 2, axis=-1) - rho**2
    ref = np.where(np.asarray(p.other_mask), ref, 1.0)
    np.testing.assert_allclose(g[-n:], ref, rtol=1e-10, atol=1e-10)
    # and the coast is real: the rows differ from the end sample's
    assert not np.allclose(g[-1], g[st0.n_collision_samples - 1])
