"""Fuzzing the public API (issue #7): more than 10,000 random inputs, no NaN escapes, no
unhandled exceptions.

Every input is counted in ``COUNTS`` (a batch of B lanes through one jitted call counts
as B inputs); the last test checks the total.  Compile time dominates, so every jitted
function here has one fixed shape and compiles once:

* predict_arrays: 3 x 2,000 random lanes (scales 1e-300 .. 1e300, zero-length moves, at
  the goal, NaN / inf entries, bad time weights); public ``predict``: hypothesis, every
  non-finite argument must raise a ValueError naming it.
* Trajectory.evaluate / shift / to_monomials: 2 x 1,000 random piecewise polynomials
  (zero-length segments, T = 0, times at breaks, before the start, after the end)
  against NumPy references of the documented semantics.
* solve.solve_batch: 2 x 128 random NLPs (NaN / inf own states and scalars,
  coincident robots, a start inside another robot, an occupied goal, huge and tiny
  scales, garbage x0 / multipliers / penalty).
* planner.replan: 2 x 32 corrupted fleets chained over two replans (NaN / inf own
  states and views, coincident robots, goals inside each other, NaN / negative / inf
  message ages; one fleet per call, LLVM -O0 to cut the compile time); braking_plan.
* config.parse_config: 2,400 mutations of valid configs plus hypothesis garbage
  documents: a Config or a one-line ConfigError naming the bad key, nothing else.
* metrics.pairwise_min_separation: 600 random piece sets against dense sampling.
"""

from __future__ import annotations

import copy
import datetime
import functools
import math
import tomllib

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

import jaxplan  # noqa: F401  (float64)
from jaxplan import config as C
from jaxplan import metrics, nlp, planner, solve
from jaxplan.nlp import Limits, Multipliers, NLPParams, NLPStructure, Weights
from jaxplan.predict import predict, predict_arrays
from jaxplan.trajectory import Trajectory
from tests.conftest import TINY_TOML

COUNTS: dict[str, int] = {}
MIN_TOTAL = 10_000
HYPOTHESIS = dict(deadline=None, derandomize=True, database=None,
                  suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def _count(name: str, n: int) -> None:
    COUNTS[name] = COUNTS.get(name, 0) + int(n)


def _no_nan_leaves(tree, what: str) -> None:
    """Every floating leaf of a pytree is NaN-free."""
    for path, leaf in jax.tree_util.tree_leaves_with_path(tree):
        x = np.asarray(leaf)
        if x.dtype.kind in "fc":
            bad = np.isnan(x)
            assert not bad.any(), (what, jax.tree_util.keystr(path), np.argwhere(bad)[:5])


def _fin(x):
    x = np.asarray(x, dtype=np.float64)
    return np.where(np.isfinite(x), x, 0.0)


# ============================================================= predict_arrays (jitted)
PB = 2000  # lanes per batch
_predict = jax.jit(predict_arrays)


def _predict_lanes(seed):
    """PB random lanes of every kind; returns the inputs and the kind of each lane."""
    rng = np.random.default_rng(seed)
    kind = rng.integers(0, 10, PB)
    scale = 10.0 ** rng.uniform(-6, 6, PB)
    scale = np.where(kind == 5, 10.0 ** rng.uniform(50, 300, PB), scale)
    scale = np.where(kind == 6, 10.0 ** rng.uniform(-300, -50, PB), scale)
    x = [rng.normal(size=(PB, 3)) * scale[:, None] for _ in range(6)]
    p0, v0, a0, pf, vf, af = x
    full = rng.uniform(size=PB) < 0.5
    w = 10.0 ** rng.uniform(-3, 3, PB)
    move = kind == 3  # zero-length move, moving start: the lane must still correct v, a
    pf[move] = p0[move]
    at = kind == 4  # at the goal, nothing to correct
    pf[at] = p0[at]
    for arr in (v0, a0, vf, af):
        arr[at] = 0.0
    mixed = kind == 9  # far from the origin, a small move; or fast and close
    pf[mixed] = p0[mixed] + rng.normal(size=(mixed.sum(), 3)) * 1e-6 * scale[mixed, None]
    p0[mixed] += 1e6 * scale[mixed, None]
    pf[mixed] += 1e6 * scale[mixed, None]
    bad = kind == 7  # one non-finite entry in one argument
    for i in np.nonzero(bad)[0]:
        x[rng.integers(6)][i, rng.integers(3)] = rng.choice([np.nan, np.inf, -np.inf])
    badw = kind == 8
    w[badw] = rng.choice([0.0, -1.0, np.nan, np.inf, -np.inf, -1e-300], badw.sum())
    return x, full, w, kind


def _check_predict_lanes(x, full, w, kind, out):
    c = np.asarray(out.coeffs)[:, 0]  # (PB, 3, 6) normalized time
    br = np.asarray(out.breaks)
    T = br[:, -1]
    coast = np.asarray(out.coast)
    p0, v0, a0, pf, vf, af = x
    assert np.all(np.isfinite(c)) and np.all(np.isfinite(br)), "NaN / inf escaped"
    assert np.all(br[:, 0] == 0.0) and np.all(T >= 0.0)
    finite_in = np.all([np.all(np.isfinite(a), axis=1) for a in x], axis=0)
    finite_in &= np.isfinite(w) & (w > 0)
    hold = T == 0.0
    # every T = 0 lane is a hold at p0, non-finite entries replaced by 0
    np.testing.assert_array_equal(c[hold][..., 0], _fin(p0[hold]))
    assert np.all(c[hold][..., 1:] == 0.0) and not np.any(coast[hold])
    assert np.all(hold[~finite_in]), "non-finite input must give a hold"
    assert np.all(hold[kind == 4]), "at the goal: a hold"
    moderate = np.isin(kind, (0, 1, 2, 3, 9))
    assert np.all(~hold[moderate]), np.nonzero(moderate & hold)[0][:5]
    # every moving lane meets its boundary conditions (normalized time: x^(r) = c^(r) / T^r)
    m = ~hold
    Tm = T[m][:, None]
    cm = c[m]
    k = np.arange(6)
    tol = lambda ref, mag: 1e-9 * (np.abs(ref) + mag + 1e-300)
    mag0 = np.abs(cm).sum(-1)
    assert np.all(np.abs(cm[..., 0] - p0[m]) <= tol(p0[m], 0.0))
    assert np.all(np.abs(cm[..., 1] / Tm - v0[m]) <= tol(v0[m], np.abs(cm[..., 1]) / Tm))
    acc0 = 2 * cm[..., 2] / Tm**2
    assert np.all(np.abs(acc0 - a0[m]) <= tol(a0[m], np.abs(acc0)))
    assert np.all(np.abs(cm.sum(-1) - pf[m]) <= tol(pf[m], mag0))
    fm = full[m]
    vel_end = (cm * k).sum(-1) / Tm
    mag1 = (np.abs(cm) * k).sum(-1) / Tm
    assert np.all(np.abs(vel_end - vf[m])[fm] <= tol(vf[m], mag1)[fm])
    acc_end = (cm * k * (k - 1)).sum(-1) / Tm**2
    mag2 = (np.abs(cm) * k * (k - 1)).sum(-1) / Tm**2
    assert np.all(np.abs(acc_end - af[m])[fm] <= tol(af[m], mag2)[fm])
    # coast after the end: free ends, and fully defined ends with a goal velocity
    want_coast = ~hold & (~full | np.any(vf != 0.0, axis=1))
    np.testing.assert_array_equal(coast, want_coast)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_predict_arrays_batches(seed):
    x, full, w, kind = _predict_lanes(seed)
    out = jax.device_get(_predict(*x, full, w))
    with np.errstate(over="ignore"):  # bounds of 1e300-scale lanes may overflow to inf
        _check_predict_lanes(x, full, w, kind, out)
    _count("predict_arrays", PB)


# =================================================================== public predict
_nice = st.floats(-1e3, 1e3, allow_nan=False)
_any_finite = st.floats(allow_nan=False, allow_infinity=False)
_nonfinite = st.sampled_from([math.nan, math.inf, -math.inf])
_ARGS = ("p0", "v0", "a0", "goal", "goal_velocity")


@settings(max_examples=200, **HYPOTHESIS)
@given(data=st.data())
def test_public_predict_raises_or_is_finite(data):
    huge = data.draw(st.booleans())
    arrays = {name: data.draw(hnp.arrays(np.float64, (2, 3), elements=_any_finite if huge
                                         else _nice), label=name) for name in _ARGS}
    end = data.draw(st.sampled_from(["free", "rest"]))
    with_gv = data.draw(st.booleans())
    tw = data.draw(st.one_of(st.floats(1e-3, 1e3), st.sampled_from(
        [0.0, -1.0, math.nan, math.inf, 1e-300, 1e300])), label="time_weight")
    n_bad = data.draw(st.integers(0, 2))
    for _ in range(n_bad):
        name = data.draw(st.sampled_from(_ARGS))
        arrays[name][data.draw(st.integers(0, 1)), data.draw(st.integers(0, 2))] = data.draw(
            _nonfinite)
    kw = dict(end=end, time_weight=tw)
    if with_gv:
        kw["goal_velocity"] = arrays["goal_velocity"]
    args = [arrays[n] for n in _ARGS[:4]]
    _count("predict", 1)
    if with_gv and end != "rest":
        with pytest.raises(ValueError, match="goal_velocity"):
            predict(*args, **kw)
        return
    checked = _ARGS if with_gv else _ARGS[:4]
    first_bad = next((n for n in checked if not np.all(np.isfinite(arrays[n]))), None)
    if first_bad is not None:
        with pytest.raises(ValueError, match=f"^{first_bad} contains non-finite"):
            predict(*args, **kw)
        return
    if not (math.isfinite(tw) and tw > 0):
        with pytest.raises(ValueError, match="time_weight"):
            predict(*args, **kw)
        return
    traj = jax.device_get(predict(*args, **kw))
    assert traj.coeffs.shape == (2, 1, 3, 6) and traj.breaks.shape == (2, 2)
    assert np.all(np.isfinite(traj.coeffs)) and np.all(np.isfinite(traj.breaks))
    assert np.all(traj.duration >= 0)
    np.testing.assert_array_equal(traj.coeffs[:, 0, :, 0], arrays["p0"])  # starts at p0


def test_public_predict_rejects_bad_shapes_and_names():
    z = np.zeros(3)
    cases = [
        (dict(p0=0.0, v0=z, a0=z, goal=z), "p0 must have a trailing spatial axis"),
        (dict(p0=np.zeros((2, 3)), v0=np.zeros((3, 3)), a0=z, goal=z), "do not broadcast"),
        (dict(p0=np.zeros(2), v0=z, a0=z, goal=z), "spatial dimension differs|broadcast"),
    ]
    for kw, msg in cases:
        with pytest.raises(ValueError, match=msg):
            predict(**kw)
    with pytest.raises(ValueError, match="end must be"):
        predict(z, z, z, z, end="stop")
    _count("predict", len(cases) + 1)


# ======================================================================= Trajectory
TB, TS, TN, TD, TK = 1000, 3, 3, 5, 6  # lanes, segments, axes, degree, times per lane


def _taylor(G, b):
    """Coefficients (B, N, L) of p(t) -> coefficients of p(b + tau) in tau (b (B,))."""
    q = np.array(G, dtype=np.float64, copy=True)
    L = q.shape[-1]
    s = b[:, None]
    for i in range(L - 1):
        for j in range(L - 2, i - 1, -1):
            q[:, :, j] += s * q[:, :, j + 1]
    return q


def _falling(k, d):
    return math.factorial(k) // math.factorial(k - d) if k >= d else 0


def _poly_eval(G, t, d):
    """d-th derivative of the global polynomials G (B, N, L) at t (B, K) -> (B, K, N)."""
    L = G.shape[-1]
    out = np.zeros(t.shape + (G.shape[1],))
    for k in range(L - 1, d - 1, -1):
        out = out * t[..., None] + _falling(k, d) * G[:, None, :, k]
    return out


def _poly_mag(G, R, d):
    """A bound on the size of the terms of the d-th derivative for |t| <= R (B, K)."""
    L = G.shape[-1]
    A = np.abs(G)
    out = np.zeros(R.shape)
    for k in range(d, L):
        out = out + _falling(k, d) * A[:, None, :, k].max(-1) * (2 * R) ** (k - d)
    return out


def _traj_lanes(seed):
    """TB smooth random trajectories (one global quintic per lane, cut at random breaks,
    so the shift identity holds at every break), times and shifts of every kind."""
    rng = np.random.default_rng(seed)
    h = 10.0 ** rng.uniform(-3, 2, (TB, TS))
    h[rng.uniform(size=(TB, TS)) < 0.2] = 0.0  # zero-length segments
    h[rng.uniform(size=TB) < 0.05] = 0.0  # T = 0 lanes
    br = np.concatenate([np.zeros((TB, 1)), np.cumsum(h, axis=1)], axis=1)
    T = br[:, -1]
    Lt = np.maximum(T, 1.0)
    scale = 10.0 ** rng.uniform(-20, 20, TB)
    G = rng.normal(size=(TB, TN, TD + 1)) * scale[:, None, None] / (
        Lt[:, None, None] ** np.arange(TD + 1))
    heff = np.where(h > 0, h, 1.0)
    coeffs = np.stack([_taylor(G, br[:, k]) * heff[:, k, None, None] ** np.arange(TD + 1)
                       for k in range(TS)], axis=1)
    coast = rng.uniform(size=TB) < 0.5

    def times(n):
        pick = rng.integers(0, 6, (TB, n))
        kb = rng.integers(0, TS + 1, (TB, n))
        opts = [rng.uniform(-0.5, 1.5, (TB, n)) * Lt[:, None],  # anywhere
                np.take_along_axis(br, kb, axis=1),  # exactly at a break
                np.broadcast_to(T[:, None], (TB, n)),  # exactly at the end
                np.zeros((TB, n)),
                T[:, None] + 10.0 ** rng.uniform(-9, 3, (TB, n)),  # after the end
                -(10.0 ** rng.uniform(-9, 3, (TB, n)))]  # before the start
        return np.choose(pick, opts)

    t = times(TK)
    dt = times(1)[:, 0]
    return coeffs, br, coast, t, dt, G


@jax.jit
def _traj_outputs(coeffs, breaks, coast, t, dt):
    tr = Trajectory(coeffs, breaks, coast)
    ev = [tr.sample(t, d) for d in range(4)]
    sh = tr.shift(dt)
    tp = jnp.maximum(t, 0.0)
    dtp = jnp.maximum(dt, 0.0)[:, None]
    shv = [sh.sample(tp, d) for d in range(4)]
    ref = [tr.sample(tp + dtp, d) for d in range(4)]
    cm, b = tr.to_monomials()
    back = Trajectory.from_monomials(cm, b, coast).coeffs
    return ev, sh, shv, ref, cm, b, back


def _reference_eval(G, br, coast, t, d):
    """The documented semantics from the global polynomial: clamp to [0, T]; after T hold
    (v = 0) or coast at v(T); a, j = 0 after T."""
    T = br[:, -1:]
    tc = np.clip(t, 0.0, T)
    val = _poly_eval(G, tc, d)
    after = (t > T)[..., None]
    co = coast[:, None, None]
    if d == 0:
        vel = _poly_eval(G, np.broadcast_to(T, t.shape), 1)
        return val + np.where(after & co, vel * (t - T)[..., None], 0.0)
    if d == 1:
        return np.where(after & ~co, 0.0, val)
    return np.where(after, 0.0, val)


@pytest.mark.parametrize("seed", [0, 1])
def test_trajectory_evaluate_shift_monomials(seed):
    coeffs, br, coast, t, dt, G = _traj_lanes(seed)
    ev, sh, shv, ref, cm, b, back = jax.device_get(_traj_outputs(coeffs, br, coast, t, dt))
    T = br[:, -1]
    for x in (*ev, *shv, *ref, sh.coeffs, sh.breaks, cm, b, back):
        assert np.all(np.isfinite(x)), "NaN / inf escaped"
    R = np.maximum(np.maximum(np.abs(t), T[:, None]), 1.0)
    for d in range(4):
        want = _reference_eval(G, br, coast, t, d)
        tol = 1e-10 * (_poly_mag(G, R, d) + _poly_mag(G, R, 1) * R * (d == 0))[..., None]
        err = np.abs(ev[d] - want)
        assert np.all(err <= tol), (d, np.unravel_index(np.argmax(err / tol), err.shape))
    # shift(dt).evaluate(t) == evaluate(t + dt) for t >= 0 (negative dt counts as 0)
    tp = np.maximum(t, 0.0)
    dtp = np.maximum(dt, 0.0)
    np.testing.assert_allclose(sh.breaks, np.maximum(br - dtp[:, None], 0.0), rtol=1e-12,
                               atol=1e-12 * T.max())
    # where the two sides disagree by round-off about being past the end (t + dt vs T in
    # the original, t vs T - dt in the shifted one), a hold's velocity and every a, j jump
    ambiguous = ((tp + dtp[:, None]) > T[:, None]) != (tp > sh.breaks[:, -1:])
    ambiguous &= np.abs(tp + dtp[:, None] - T[:, None]) <= 1e-12 * np.maximum(T, 1.0)[:, None]
    R2 = np.maximum(tp + dtp[:, None], np.maximum(T[:, None], 1.0))
    for d in range(4):
        skip = ambiguous & (~coast[:, None] if d == 1 else d >= 2)
        tol = 1e-9 * (_poly_mag(G, R2, d) + _poly_mag(G, R2, 1) * R2 * (d == 0))[..., None]
        err = np.where(skip[..., None], 0.0, np.abs(shv[d] - ref[d]))
        assert np.all(err <= tol), (d, np.unravel_index(np.argmax(err / tol), err.shape))
    # monomials in seconds are the Taylor expansions at the breaks; and they round-trip
    R3 = np.maximum(T, 1.0)[:, None]
    tol = np.stack([_poly_mag(G, R3, m)[:, 0] / math.factorial(m) for m in range(TD + 1)], -1)
    for k in range(TS):
        err = np.abs(cm[:, k] - _taylor(G, br[:, k]))
        assert np.all(err <= 1e-10 * tol[:, None, :]), k
    np.testing.assert_array_equal(b, br)
    assert np.all(np.abs(back - coeffs) <= 1e-12 * np.abs(coeffs).max(axis=(1, 2, 3),
                                                                      keepdims=True))
    _count("trajectory", TB)


# ========================================================================== solver
SB, MO, SN = 128, 4, 3
S_NLP = NLPStructure(collision="barrier+constraint", segments=2, n_collision_samples=16)
NONFINITE = np.array([np.nan, np.inf, -np.inf])
SOLVER_KINDS = 14


def _solver_lanes(seed):
    """SB random single-robot NLPs, one corruption kind per lane (see ``kind``)."""
    rng = np.random.default_rng(seed)
    kind = np.arange(SB) % SOLVER_KINDS
    rng.shuffle(kind)
    p0 = rng.uniform(-3, 3, (SB, SN))
    dirn = rng.normal(size=(SB, SN))
    dirn /= np.linalg.norm(dirn, axis=1, keepdims=True)
    gp = p0 + dirn * rng.uniform(0.5, 8.0, (SB, 1))
    v0, a0 = rng.normal(size=(2, SB, SN)) * 0.5
    gv, ga = np.zeros((2, SB, SN))
    rest = rng.uniform(size=SB) < 0.5
    # others: quadratic paths (normalized time) from op over To seconds, hold or coast after
    op = p0[:, None] + rng.uniform(-4, 4, (SB, MO, SN))
    ov = rng.normal(size=(SB, MO, SN)) * 0.5
    og = gp[:, None] + rng.uniform(-4, 4, (SB, MO, SN))
    To = rng.uniform(0.5, 10.0, (SB, MO))
    o_coast = rng.uniform(size=(SB, MO)) < 0.5
    orad = rng.uniform(0.1, 0.5, (SB, MO))
    rad = rng.uniform(0.1, 0.5, SB)
    mask = rng.uniform(size=(SB, MO)) < 0.8
    w = {k: np.full(SB, v) for k, v in dict(q_dynm=1.0, q_obs=10.0, q_lim=1.0, k_t=1.0,
                                           k_p=4.0).items()}
    lim = {k: np.full(SB, v) for k, v in dict(v_max=2.0, a_max=4.0, j_max=15.0).items()}
    tmin = np.full(SB, 0.1)
    parked = np.zeros((SB, MO), bool)
    bad_other = np.zeros((SB, MO), bool)
    for i in range(SB):
        k = kind[i]
        if k == 1:  # a non-finite own-state entry
            arr = (p0, v0, a0, gp, gv, ga)[rng.integers(6)]
            arr[i, rng.integers(SN)] = rng.choice(NONFINITE)
        elif k == 2:  # another robot parked exactly at the start (coincident)
            op[i, 0], parked[i, 0], mask[i, 0] = p0[i], True, True
        elif k == 3:  # start inside another robot's radius, the other moving
            op[i, 0] = p0[i] + rng.normal(size=SN) * 0.05
            mask[i, 0] = True
        elif k == 4:  # goal occupied by a parked robot
            op[i, 0], parked[i, 0], mask[i, 0] = gp[i], True, True
        elif k == 5:  # zero-length move, at rest: at the goal
            gp[i], v0[i], a0[i] = p0[i], 0.0, 0.0
        elif k == 6:  # another scale, 1e-8 .. 1e8 m
            s = 10.0 ** rng.uniform(-8, 8)
            p0[i] *= s
            gp[i] *= s
            op[i] *= s
            og[i] *= s
        elif k == 7:  # absurd scales
            s = 10.0 ** rng.uniform(100, 300)
            (p0, gp, v0)[rng.integers(3)][i] *= s
        elif k == 8:  # garbage other radius
            orad[i, rng.integers(MO)] = rng.choice([np.nan, np.inf, -1.0, 0.0, 1e300])
        elif k == 9:  # a non-finite or absurd weight / limit
            d = (w, lim)[rng.integers(2)]
            key = list(d)[rng.integers(len(d))]
            d[key][i] = rng.choice([np.nan, np.inf, -np.inf, 0.0, -1.0, 1e300, 1e-300])
        elif k == 10:  # garbage t_min / radius
            tmin[i] = rng.choice([np.nan, np.inf, 0.0, -1.0, 1e300, 1e-300])
            rad[i] = rng.choice([np.nan, np.inf, 0.0, -0.3, 1e3])
        elif k == 11:  # fully defined end with a goal velocity / acceleration
            gv[i] = rng.normal(size=SN) * rng.choice([1.0, 1e8])
            ga[i] = rng.normal(size=SN)
            rest[i] = True
        elif k == 12:  # non-finite others (coefficients or breaks)
            bad_other[i, rng.integers(MO)] = True
        elif k == 13:  # every other robot coincident with the start, all masked in
            op[i], parked[i], mask[i] = p0[i], True, True
    co = np.zeros((SB, MO, 1, SN, 6))
    co[..., 0, :, 0] = op
    co[..., 0, :, 1] = np.where(parked[..., None], 0.0, ov * To[..., None])
    co[..., 0, :, 2] = np.where(parked[..., None], 0.0, og - op - ov * To[..., None])
    obr = np.stack([np.zeros((SB, MO)), np.where(parked, 0.0, To)], axis=-1)
    for i, j in zip(*np.nonzero(bad_other), strict=True):
        if rng.uniform() < 0.5:
            co[i, j, 0, rng.integers(SN), rng.integers(6)] = rng.choice(NONFINITE)
        else:
            obr[i, j, 1] = rng.choice(NONFINITE)
    others = Trajectory(co, obr, o_coast & ~parked)
    f = lambda a: np.asarray(a, np.float64)
    P = NLPParams(f(p0), f(v0), f(a0), f(gp), f(gv), f(ga), rest, others, f(orad), mask,
                  f(rad), Weights(*(f(w[k]) for k in Weights._fields)),
                  Limits(*(f(lim[k]) for k in Limits._fields)), f(tmin))
    # x0: NaN (the solver's own initial guess), a straight guess, random, absurd tau
    x0 = np.zeros((SB, S_NLP.n_x))
    x0[:, -1] = np.log(rng.uniform(0.5, 10.0, SB))
    pick = rng.integers(0, 8, SB)
    x0[pick <= 3] = np.nan
    x0[pick == 4, :-1] = rng.normal(size=((pick == 4).sum(), S_NLP.n_x - 1)) * 3
    x0[pick == 5, -1] = rng.choice([800.0, -800.0, 50.0], (pick == 5).sum())
    x0[pick == 6, 0] = rng.choice([np.inf, 1e300], (pick == 6).sum())
    Kc, Kh = S_NLP.n_collision_samples, len(nlp.basis(S_NLP).lim_s)
    mult = Multipliers(rng.uniform(0, 10, (SB, Kc, MO)), rng.uniform(0, 1, (SB, Kh, 3)))
    mult.collision[rng.uniform(size=SB) < 0.1] = np.nan
    mult.limits[rng.uniform(size=SB) < 0.1] = -5.0
    pen = rng.choice([10.0, 1e3, 0.0, -1.0, np.nan, np.inf, 1e300], SB)
    sane_x0 = pick <= 3
    own = np.stack([np.all(np.isfinite(a), axis=1) for a in (p0, v0, a0, gp, gv, ga)])
    scal = np.stack([np.isfinite(a) for a in (*w.values(), *lim.values(), tmin, rad)])
    finite_in = own.all(0) & scal.all(0)
    return P, x0, mult, pen, kind, finite_in, sane_x0


@pytest.mark.parametrize("seed", [0, 1])
def test_solve_batch_random_nlps(seed):
    P, x0, mult, pen, kind, finite_in, sane_x0 = _solver_lanes(seed)
    sol = jax.device_get(solve.solve_batch(P, x0, S_NLP, multipliers=mult, penalty=pen))
    assert np.all(np.isfinite(sol.x)), np.nonzero(~np.all(np.isfinite(sol.x), axis=1))
    assert np.all(np.isfinite(sol.traj.coeffs)) and np.all(np.isfinite(sol.traj.breaks))
    _no_nan_leaves(sol, "Solution")
    assert np.all(np.isfinite(sol.multipliers.collision)) and np.all(np.isfinite(sol.penalty))
    s = sol.status
    assert set(np.unique(s)) <= {solve.CONVERGED, solve.MAX_ITERS, solve.NON_FINITE,
                                 solve.INFEASIBLE, solve.LINE_SEARCH_FAILED}
    # documented status meanings
    assert np.all(s[~finite_in] == solve.NON_FINITE), "non-finite input must be reported"
    tol = solve.SolverSettings().tol_feasibility
    ok = (s == solve.CONVERGED) | (s == solve.MAX_ITERS)
    assert np.all(sol.ineq_violation[ok] <= tol)
    assert np.all(sol.ineq_violation[s == solve.INFEASIBLE] > tol)
    # every plan (the hold of a NON_FINITE lane included) starts at the robot
    start = np.asarray(Trajectory(*sol.traj).evaluate(0.0))
    p0 = _fin(P.p0)
    assert np.all(np.abs(start - p0) <= 1e-9 * (1.0 + np.abs(p0)) + 1e-12 * np.abs(
        sol.traj.coeffs).max(axis=(1, 2, 3))[:, None])
    conv = s == solve.CONVERGED
    size = np.abs(np.concatenate([P.p0, P.goal_p], axis=1)).max(axis=1)
    assert np.all(sol.eq_violation[conv] <= 1e-8 * (1.0 + size[conv]))
    # on ordinary lanes (from the solver's own initial guess) the solver is still a solver
    plain = (kind == 0) & sane_x0
    assert np.mean(conv[plain]) >= 0.5, s[plain]
    _count("solve_batch", SB)


# ========================================================================= planner
RK = 32  # fleets per replan step
CLEAN = 4  # of which the first CLEAN are not corrupted


@functools.cache
def _fleet():
    from jaxplan import run_setup as rs
    from jaxplan.config import build_scenario, parse_config

    cfg = parse_config(tomllib.loads(TINY_TOML), source="tiny.toml")
    sc = build_scenario(cfg)
    structure = rs.structures(cfg).planner
    return sc, rs.fleet_params(cfg, sc), structure


O0 = {"xla_backend_optimization_level": 0}  # the same XLA program, LLVM at -O0
_COMPILED: dict = {}


def _compiled(name, fn, *args):
    """fn jitted and compiled once, LLVM at -O0 (the replan: ~25 % less compile time
    on a 2-core CPU, while the solver's lanes run ~2x slower at -O0: not worth it there)."""
    if name not in _COMPILED:
        _COMPILED[name] = jax.jit(fn).lower(*args).compile(compiler_options=O0)
    return _COMPILED[name](*args)


def _replan_cases(fp, ps, views, p, v, a, gp, gv, rest, structure):
    """Each case through the compiled replan (one fleet per call: compiles faster than a
    vmap over the cases); outputs stacked over the cases."""
    fn = lambda fp, ps, views, p, v, a, gp, gv, rest: planner.replan(
        fp, ps, planner.FleetState(p, v, a, views), planner.Goals(gp, gv, rest), structure)
    outs = []
    for c in range(p.shape[0]):
        at = lambda x, c=c: x[c]
        args = (fp, jax.tree.map(at, ps), jax.tree.map(at, views), p[c], v[c], a[c], gp[c],
                gv[c], rest[c])
        outs.append(jax.device_get(_compiled(("replan", structure), fn, *args)))
    return jax.tree.map(lambda *x: np.stack(x), *outs)


def _fleet_cases(rng, sc):
    """RK fleet states and views: CLEAN cases as they are, the others with one to three
    corruptions each."""
    M, N = sc.start.shape
    p = sc.start[None] + rng.normal(size=(RK, M, N)) * 0.2
    v = rng.normal(size=(RK, M, N)) * 0.5
    a = rng.normal(size=(RK, M, N)) * 0.5
    gp = sc.waypoints[None, :, 0] + rng.normal(size=(RK, M, N)) * 0.2
    gv = np.zeros((RK, M, N))
    rest = rng.uniform(size=(RK, M)) < 0.3
    per = [rng.choice(np.arange(1, 12), size=rng.integers(1, 4), replace=False) if c >= CLEAN
           else [] for c in range(RK)]
    view_edits = []
    for c in range(RK):
        i, j = rng.choice(M, 2, replace=False)
        for k in per[c]:
            if k == 1:  # a non-finite own state entry (others receive it too)
                (p, v, a)[rng.integers(3)][c, i, rng.integers(N)] = rng.choice(NONFINITE)
            elif k == 2:  # coincident robots
                p[c, j] = p[c, i]
            elif k == 3:  # goals inside each other
                gp[c, j] = gp[c, i] + rng.normal(size=N) * 0.01
            elif k == 4:  # start inside another robot's radius
                p[c, j] = p[c, i] + rng.normal(size=N) * 0.05
            elif k == 5:  # absurd scales
                (p, v, a)[rng.integers(3)][c] *= 10.0 ** rng.uniform(6, 300)
            elif k == 6:  # at the goal, at rest
                gp[c, i], v[c, i], a[c, i] = p[c, i], 0.0, 0.0
            elif k == 7:  # a fully defined end with a goal velocity
                rest[c, i] = True
                gv[c, i] = rng.normal(size=N)
            elif k == 8:  # a non-finite goal
                (gp, gv)[rng.integers(2)][c, i, rng.integers(N)] = rng.choice(NONFINITE)
            else:  # corrupt only what observer i received from sender j
                view_edits.append((c, i, j, k))
    views = planner.Views(
        *(np.broadcast_to(x[:, None], (RK, M) + x.shape[1:]).copy() for x in
          (p, v, a, gp, gv, rest)),
        np.zeros((RK, M, M)), np.ones((RK, M, M), bool))
    for c, i, j, k in view_edits:
        if k == 9:  # a non-finite received state or goal
            getattr(views, ("p", "v", "a", "goal_p", "goal_v")[rng.integers(5)])[
                c, i, j, rng.integers(N)] = rng.choice(NONFINITE)
        elif k == 10:  # a garbage age
            views.age[c, i, j] = rng.choice([np.nan, np.inf, -1.0, 1e300, 0.3, 5.0])
        else:  # nothing received
            views.valid[c, i, j] = False
    return p, v, a, gp, gv, rest, views


def _check_replan(fp, structure, prev, new, info, p, v, a, gp, gv):
    _no_nan_leaves(new, "PlanState")
    _no_nan_leaves(info, "ReplanInfo")
    plan = new.plan
    assert np.all(np.isfinite(plan.coeffs)) and np.all(np.isfinite(plan.breaks)), (
        np.argwhere(~np.all(np.isfinite(plan.coeffs), axis=(-1, -2, -3))))
    assert np.all(np.isfinite(new.multipliers.collision)) and np.all(np.isfinite(new.penalty))
    fb = info.fallback
    kinds = {planner.ACCEPTED, planner.KEPT_PREVIOUS, planner.BRAKING,
             getattr(planner, "BEST_EFFORT", planner.BRAKING)}
    assert set(np.unique(fb)) <= kinds
    own_ok = np.all(np.isfinite(np.stack([p, v, a, gp, gv])), axis=(0, -1))
    assert np.all(info.status[~own_ok] == solve.NON_FINITE)
    assert np.all(fb[~own_ok] != planner.ACCEPTED)
    # every plan but a kept one starts at the robot's (sanitized) state
    start = np.asarray(Trajectory(*plan).evaluate(0.0))
    pf = _fin(p)
    near = np.abs(start - pf) <= 1e-9 * (1.0 + np.abs(pf))
    fresh = fb != planner.KEPT_PREVIOUS
    assert np.all(near.all(-1)[fresh]), np.argwhere(~near.all(-1) & fresh)[:5]
    moderate = np.all(np.abs(np.stack([p, v, a])) < 1e6, axis=(0, -1))
    vel0 = np.asarray(Trajectory(*plan).evaluate(0.0, 1))
    close = np.abs(vel0 - v) <= 1e-9 * (1.0 + np.abs(v))
    assert np.all(close.all(-1)[fresh & moderate & own_ok])
    # the clean fleets plan as usual
    assert np.mean(fb[:CLEAN] == planner.ACCEPTED) >= 0.75, info.status[:CLEAN]
    # a kept plan is the previous plan one period later
    kept = fb == planner.KEPT_PREVIOUS
    if prev is not None and kept.any():
        old = np.asarray(Trajectory(*prev.plan).evaluate(float(fp.dt)))
        np.testing.assert_allclose(start[kept], old[kept], rtol=1e-9, atol=1e-9)


@pytest.mark.slow  # its own replan program (~18 s of the 2-core suite): `make test-slow`
def test_replan_with_corrupted_views():
    sc, fp, structure = _fleet()
    rng = np.random.default_rng(0)
    M = sc.start.shape[0]
    ps0 = planner.initial_plan_state(jnp.asarray(sc.start), structure, M)
    ps = jax.tree.map(lambda x: np.broadcast_to(x, (RK,) + x.shape), ps0)
    prev = None
    for _ in range(2):  # the second replan warm-starts from the first one's plans
        p, v, a, gp, gv, rest, views = _fleet_cases(rng, sc)
        new, info = _replan_cases(fp, ps, views, p, v, a, gp, gv, rest, structure)
        _check_replan(fp, structure, prev, new, info, p, v, a, gp, gv)
        prev, ps = new, new
        _count("replan", RK)


def test_braking_plan_is_finite_for_any_state():
    sc, fp, structure = _fleet()
    rng = np.random.default_rng(3)
    n = 64
    p, v, a = rng.normal(size=(3, n, 3)) * 10.0 ** rng.uniform(-3, 305, (3, n, 1))
    for arr in (p, v, a):
        arr[rng.uniform(size=(n, 3)) < 0.1] = rng.choice(NONFINITE)
    b = jax.device_get(jax.jit(planner.braking_plan, static_argnames="structure")(
        p, v, a, np.full(n, 4.0), structure=structure))
    assert np.all(np.isfinite(b.coeffs)) and np.all(np.isfinite(b.breaks))
    np.testing.assert_allclose(np.asarray(Trajectory(*b).evaluate(0.0)), _fin(p), rtol=1e-12)
    # the hard limits' braking plan too (limits per robot)
    lim = Limits(np.full(n, 2.0), np.full(n, 4.0), np.full(n, 12.0))
    b = jax.device_get(jax.jit(planner.limited_braking_plan, static_argnames="structure")(
        p, v, a, lim, structure=structure))
    assert np.all(np.isfinite(b.coeffs)) and np.all(np.isfinite(b.breaks))
    np.testing.assert_allclose(np.asarray(Trajectory(*b).evaluate(0.0)), _fin(p), rtol=1e-12)
    _count("braking_plan", 2 * n)


# ====================================================================== config
TWO_D_TOML = """
name = "planar"
[planner]
end_state = "rest"
[[robots]]
vehicle = "hummingbird"
start = [0.0, 0.0]
waypoints = [[3.0, 0.0], [3.0, 3.0]]
end_state = ["free", "rest"]
goal_velocity = [[0.5, 0.0], []]
[[robots]]
vehicle = "firefly"
start = [3.0, 3.0]
goal = [0.0, 3.0]
"""

SCENARIO_TOML = """
name = "gen"
seed = 3
description = "fuzz base"
[planner]
q_obs = 3.0
collision = "barrier"
segments = 2
[limits]
v_max = 1.5
[sim]
duration_s = 5.0
physics_hz = 500.0
control_hz = 250.0
[scenario]
kind = "antipodal_sphere"
count = 4
radius = 3.0
vehicles = ["firefly", "neo11"]
[sweep]
q_obs = {log_min = -1, log_max = 1, num = 3}
q_lim = [0.5, 1.0]
seeds = {start = 0, num = 2}
[faults]
enabled = true
message_loss = 0.1
latency_s = 0.25
frozen_robot = 1
frozen_at_s = 2.0
frozen_mode = "stale"
"""

BOX_TOML = """
[scenario]
kind = "random_box"
count = 5
box = [[-4.0, -4.0, 0.5], [4.0, 4.0, 3.0]]
end_state = "rest"
[sweep]
scenarios = ["stacked", "paper:six_neos"]
seeds = [0, 1, 2]
"""

BASES = [tomllib.loads(t) for t in (TINY_TOML, TWO_D_TOML, SCENARIO_TOML, BOX_TOML)]

HUGE_INT = 10**5000  # beyond Python's int -> str limit: repr() itself raises
GARBAGE = [
    None, True, False, 0, 1, -1, 2, 3, 7, 10**6, 2**63, -(2**63), 10**400, HUGE_INT,
    0.0, -0.0, 0.5, -2.5, 1e-320, 1e308, -1e308, math.nan, math.inf, -math.inf,
    "", "x", "free", "rest", "paper", "firefly", "neo11", "ideal", "mjx", "barrier",
    "antipodal_sphere", "paper:six_neos", "a/b", "\x00", "\n", "é" * 3, "1.0",
    [], [1], [1.0, 2.0], [0.0, 0.0, 1.0], [1, 2, 3, 4], [[0.0, 0.0, 1.0]], [math.nan, 0, 0],
    [1e300, 0.0, 0.0], ["free"], ["rest", "free"], [[]], [{}], {}, {"a": 1}, {"kind": 1},
    {"log_min": 0, "log_max": 1, "num": 10**6}, {"start": 2**63, "num": 2},
    datetime.date(2020, 1, 1), datetime.time(1, 2), datetime.datetime(2020, 1, 1, 1, 2),
]


def _key(path) -> str:
    out = ""
    for p in path:
        out += f"[{p}]" if isinstance(p, int) else (f".{p}" if out else p)
    return out


def _paths(doc, prefix=()):
    yield prefix, doc
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from _paths(v, prefix + (k,))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            yield from _paths(v, prefix + (i,))


def _get(doc, path):
    for p in path:
        doc = doc[p]
    return doc


def _is_number(x):
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def _finite_number(x):
    if not _is_number(x):
        return False
    try:
        return math.isfinite(float(x))
    except OverflowError:
        return False


def _mutate(rng, base):
    """One random mutation of a valid document.  Returns (doc, path, strict): a
    ConfigError must name ``_key(path)`` exactly when ``strict``; otherwise it must
    name a key of the same section or the fleet (robots / scenario)."""
    doc = copy.deepcopy(base)
    paths = [p for p, _ in _paths(doc) if p]
    op = rng.integers(0, 4)
    if op == 0:  # an unknown key in a random table
        tables = [p for p, x in _paths(doc) if isinstance(x, dict)]
        path = tables[rng.integers(len(tables))]
        name = "zz_" + "".join(rng.choice(list("abcdefgh_"), 5))
        _get(doc, path)[name] = GARBAGE[rng.integers(len(GARBAGE))]
        return doc, path + (name,), True
    path = paths[rng.integers(len(paths))]
    parent, last = _get(doc, path[:-1]), path[-1]
    old = parent[last]
    if op == 1:  # delete
        del parent[last]
        return doc, path, False
    new = copy.deepcopy(GARBAGE[rng.integers(len(GARBAGE))])
    if op == 3 and _is_number(old):  # a nearby or extreme number of the same kind
        new = rng.choice([old * 10.0 ** rng.uniform(-3, 3), -old, old + 1, 0, old * 1e300])
        new = int(new) if isinstance(old, int) and math.isfinite(new) and abs(new) < 1e18 \
            else float(new)
    parent[last] = new
    if _is_number(old):
        strict = not _finite_number(new)
    elif isinstance(old, bool):
        strict = not isinstance(new, bool)
    elif isinstance(old, str):
        strict = not isinstance(new, (str, list))
    else:  # a list or a table given a scalar other than a string
        strict = not isinstance(new, (str, list, dict))
    return doc, path, strict


def _check_config_outcome(doc, path=None, strict=False):
    src = "fuzz.toml"
    try:
        cfg = C.parse_config(doc, source=src)
    except C.ConfigError as e:
        msg = str(e)
        assert "\n" not in msg and msg.startswith(f"{src}: "), msg
        if path is not None:
            key = _key(path)
            if strict:  # this key, or its array when the problem is a sibling element
                names = [key] + ([_key(path[:-1])] if isinstance(path[-1], int) else [])
                assert any(f"{src}: {k}" in msg for k in names), (key, msg)
            else:
                section = _key(path[:1])
                assert any(s in msg for s in (f"{src}: {section}", "robots[", "scenario",
                                               "generated robot")), (key, msg)
        return "error"
    assert isinstance(cfg, C.Config)
    # an accepted config round-trips through its resolved TOML and builds its fleet
    again = C.parse_config(tomllib.loads(C.config_to_toml(cfg)), source=src)
    assert again == cfg
    try:
        sc = C.build_scenario(cfg)
        assert sc.num_robots >= 1
    except C.ConfigError as e:
        assert "faults.frozen_robot" in str(e), str(e)
    return "ok"


def test_bases_are_valid():
    for doc in BASES:
        assert _check_config_outcome(doc) == "ok"
    _count("parse_config", len(BASES))


def test_parse_config_mutations():
    rng = np.random.default_rng(0)
    outcomes = {"ok": 0, "error": 0}
    n = 2400
    for i in range(n):
        doc, path, strict = _mutate(rng, BASES[i % len(BASES)])
        outcomes[_check_config_outcome(doc, path, strict)] += 1
    assert outcomes["ok"] >= n // 20 and outcomes["error"] >= n // 2, outcomes
    _count("parse_config", n)


_KNOWN = sorted(set(C.TOP_KEYS) | set(C.PlannerConfig.__dataclass_fields__)
                | set(C.SimConfig.__dataclass_fields__) | set(C.FAULT_KEYS)
                | {k for g in C.GENERATOR_KEYS.values() for k in g}
                | set(C.ROBOT_KEYS) | {"kind", "log_min", "log_max", "num", "start"})
_scalar = st.one_of(
    st.none(), st.booleans(), st.integers(), st.floats(), st.text(max_size=6),
    st.sampled_from([g for g in GARBAGE if g is not HUGE_INT]), st.dates(),
    st.binary(max_size=3), st.complex_numbers(),
)
_doc = st.recursive(_scalar, lambda ch: st.lists(ch, max_size=4) | st.dictionaries(
    st.sampled_from(_KNOWN) | st.text(max_size=4), ch, max_size=5), max_leaves=25)


@settings(max_examples=300, **HYPOTHESIS)
@given(doc=st.one_of(_doc, st.dictionaries(st.sampled_from(C.TOP_KEYS), _doc, max_size=6)))
def test_parse_config_garbage_documents(doc):
    _count("parse_config", 1)
    _check_config_outcome(doc)


def test_parse_config_hostile_nesting_and_keys():
    deep: list = []
    for _ in range(100_000):
        deep = [deep]
    docs = [
        {"planner": deep}, {"robots": [{"vehicle": "firefly", "start": deep}]},
        {1: 2}, {"planner": {3.5: 1}}, {"name": "a\tb"}, {"\x00": 1}, {"planner": {"\n": 1}},
        "not a table", [1, 2], None, 42,
    ]
    for d in docs:
        _check_config_outcome(d)
    _count("parse_config", len(docs))


# ======================================================================= metrics
ND = 2001  # dense samples per pair


def _random_robot(rng, t_start, t_end, n_pieces, N, D, scale, gaps):
    """Random pieces, position-continuous within each contiguous run; zero-length pieces
    and gaps (no pieces) allowed.  Returns (t0, t1, coeffs (P, N, D+1) in t - t0)."""
    cuts = np.sort(rng.uniform(t_start, t_end, 2 * n_pieces - 2))
    if rng.uniform() < 0.3 and n_pieces > 1:
        cuts[rng.integers(len(cuts))] = cuts[0]  # a zero-length piece somewhere
        cuts = np.sort(cuts)
    br = np.concatenate([[t_start], cuts, [t_end]]).reshape(n_pieces, 2)
    if not gaps:  # tile the span: piece k starts where piece k - 1 ends
        br[1:, 0] = br[:-1, 1]
    t0, t1 = br[:, 0], br[:, 1]
    h = np.maximum(t1 - t0, 1e-3)
    co = rng.normal(size=(n_pieces, N, D + 1)) * scale / h[:, None, None] ** np.arange(D + 1)
    for k in range(1, n_pieces):
        if t0[k] == t1[k - 1]:  # contiguous: continuous position
            co[k, :, 0] = np.polynomial.polynomial.polyval(t1[k - 1] - t0[k - 1],
                                                           co[k - 1].T)
    return t0, t1, co


def _dense(robot, t):
    """Positions of one robot at times t (NaN where it has no piece)."""
    t0, t1, co = robot
    out = np.full((t.size, co.shape[1]), np.nan)
    for k in range(t0.size):
        sel = (t >= t0[k]) & (t <= t1[k])
        if sel.any():
            out[sel] = np.polynomial.polynomial.polyval(t[sel] - t0[k], co[k].T).T
    return out


def _speed_bound(robot):
    t0, t1, co = robot
    h = (t1 - t0)[:, None, None]
    k = np.arange(1, co.shape[2])
    return float(np.max(np.sum(np.abs(co[:, :, 1:]) * k * h ** (k - 1), axis=2).sum(-1),
                        initial=0.0))


def _metrics_case(rng):
    M = int(rng.integers(2, 5))
    N = int(rng.integers(1, 4))
    D = int(rng.integers(0, 8))
    L = 10.0 ** rng.uniform(-2, 2)
    scale = 10.0 ** rng.uniform(-3, 3)
    robots = []
    for _ in range(M):
        a, b = (0.0, L) if rng.uniform() < 0.6 else np.sort(rng.uniform(-0.5, 1.5, 2) * L)
        robots.append(_random_robot(rng, a, b, int(rng.integers(1, 5)), N, D, scale,
                                    gaps=rng.uniform() < 0.2))
    special = rng.integers(0, 4)
    if special == 1:  # an identical twin: distance 0 all along
        robots[1] = tuple(np.copy(x) for x in robots[0])
    elif special == 2:  # a rigidly offset copy: distance |offset| all along
        t0, t1, co = (np.copy(x) for x in robots[0])
        co[:, :, 0] += rng.normal(size=N) * scale
        robots[1] = (t0, t1, co)
    seg_r = np.concatenate([np.full(r[0].size, i) for i, r in enumerate(robots)])
    t0 = np.concatenate([r[0] for r in robots])
    t1 = np.concatenate([r[1] for r in robots])
    co = np.concatenate([r[2] for r in robots])
    return robots, (seg_r, t0, t1, co), special


def test_pairwise_min_separation_against_dense_sampling():
    rng = np.random.default_rng(0)
    n_cases, n_raised = 600, 0
    for _ in range(n_cases):
        robots, (seg_r, t0, t1, co), special = _metrics_case(rng)
        M = len(robots)
        if rng.uniform() < 0.05:  # non-finite pieces are refused, clearly
            (t0, t1, co)[rng.integers(3)].flat[0] = rng.choice(NONFINITE)
            with pytest.raises(ValueError, match="finite|seg_t1 >= seg_t0"):
                metrics.pairwise_min_separation(seg_r, t0, t1, co, num_robots=M)
            n_raised += 1
            continue
        dmin, tmin = metrics.pairwise_min_separation(seg_r, t0, t1, co, num_robots=M)
        assert dmin.shape == (M, M) and np.array_equal(dmin, dmin.T)
        assert not np.any(np.isnan(dmin)) and np.all(np.isinf(np.diag(dmin)))
        for i in range(M):
            for j in range(i + 1, M):
                ri, rj = robots[i], robots[j]
                a = max(ri[0].min(), rj[0].min())
                b = min(ri[1].max(), rj[1].max())
                t = np.concatenate([np.linspace(a, b, ND), ri[0], ri[1], rj[0], rj[1]]) \
                    if b >= a else np.zeros(0)
                t = np.unique(t[(t >= a) & (t <= b)])
                d = np.linalg.norm(_dense(ri, t) - _dense(rj, t), axis=1)
                d = d[np.isfinite(d)]
                if d.size == 0:  # never both present
                    assert np.isinf(dmin[i, j]) and np.isnan(tmin[i, j])
                    continue
                mag = 1.0 + max(np.nanmax(np.abs(_dense(r, t))) for r in (ri, rj))
                rtol = 1e-9 * mag
                vrel = _speed_bound(ri) + _speed_bound(rj)
                gap = np.max(np.diff(t), initial=0.0)
                assert np.isfinite(dmin[i, j]) and a <= tmin[i, j] <= b
                assert dmin[i, j] <= d.min() + rtol, "above a real sample"
                assert d.min() - dmin[i, j] <= vrel * gap + rtol, "missed the minimum"
                at = np.array([tmin[i, j]])
                d_at = np.linalg.norm(_dense(ri, at) - _dense(rj, at))
                assert abs(d_at - dmin[i, j]) <= rtol, "the time does not attain it"
        if special == 1:
            assert dmin[0, 1] <= 1e-12 * (1.0 + np.abs(co).max())
        elif special == 2:
            off = np.linalg.norm(robots[1][2][0, :, 0] - robots[0][2][0, :, 0])
            assert abs(dmin[0, 1] - off) <= 1e-9 * (1.0 + np.abs(co).max())
    assert n_raised >= 10
    _count("pairwise_min_separation", n_cases)


# ======================================================================= the total
EXPECTED = {"predict_arrays", "predict", "trajectory", "solve_batch", "replan",
            "braking_plan", "parse_config", "pairwise_min_separation"}
SLOW = {"replan"}  # test_replan_with_corrupted_views runs under `make test-slow` only


def test_zz_total_fuzzed_inputs(request):
    """Runs last (file order): the whole file fuzzed at least MIN_TOTAL inputs."""
    slow_deselected = "not slow" in (request.config.getoption("-m") or "")
    if not (EXPECTED - (SLOW if slow_deselected else set())) <= set(COUNTS):
        pytest.skip(f"only part of the file ran: {sorted(COUNTS)}")
    total = sum(COUNTS.values())
    print(f"\nfuzzed inputs: {total} {dict(sorted(COUNTS.items()))}")
    assert total >= MIN_TOTAL, COUNTS
