"""Tests of jaxplan.metrics: exact separation vs dense sampling, hand cases, kinematics,
path length, sampling, time to goal, solver summary and degenerate inputs."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.polynomial import polynomial as P

import jaxplan  # noqa: F401  (float64 for jax; metrics itself is NumPy)
from jaxplan import metrics as M

# ---------------------------------------------------------------------------- helpers


def taylor_shift(c, s):
    """Coefficients (N, L) in tau -> coefficients in tau' = tau - s (independent of M)."""
    out = np.zeros_like(c)
    for n in range(c.shape[0]):
        # p(tau' + s): compose with the polynomial [s, 1]
        acc = np.zeros(1)
        for k in range(c.shape[1] - 1, -1, -1):
            acc = P.polyadd(P.polymul(acc, [s, 1.0]), [c[n, k]])
        out[n, : acc.size] = acc[: c.shape[1]]
    return out


def pieces_from_global(gc, breaks):
    """Split global polynomials gc (N, L) in t at breaks -> (t0, t1, coeffs (S, N, L))."""
    t0 = np.asarray(breaks[:-1], float)
    t1 = np.asarray(breaks[1:], float)
    co = np.stack([taylor_shift(gc, a) for a in t0])
    return t0, t1, co


def random_robot(rng, t_end, n_pieces, n_dims, degree, scale=1.0):
    """Random C2 pieces (position, velocity, acceleration continuous at the breaks, as
    executed plans are) tiling [0, t_end] with random breaks."""
    inner = np.sort(rng.uniform(0, t_end, n_pieces - 1))
    br = np.concatenate([[0.0], inner, [t_end]])
    t0, t1 = br[:-1], br[1:]
    h = np.maximum(t1 - t0, 1e-3)
    # coefficients scaled so that each power contributes O(scale) over the piece
    co = rng.normal(size=(n_pieces, n_dims, degree + 1)) * scale
    co = co / h[:, None, None] ** np.arange(degree + 1)
    for k in range(1, n_pieces):  # carry p, v, a/2 over from the end of the previous piece
        prev = co[k - 1]
        for d in range(min(3, degree + 1)):
            der = P.polyder(prev, d, axis=1) if d else prev
            co[k, :, d] = P.polyval(t1[k - 1] - t0[k - 1], der.T) / math.factorial(d)
    return t0, t1, co


def eval_ref(t0, t1, co, t):
    """Independent evaluation of one robot's pieces at times t (later piece at breaks)."""
    out = np.full((t.size, co.shape[1]), np.nan)
    for k in range(t0.size):
        last = k == t0.size - 1
        sel = (t >= t0[k]) & ((t < t1[k]) | (last & (t <= t1[k])))
        for n in range(co.shape[1]):
            out[sel, n] = P.polyval(t[sel] - t0[k], co[k, n])
    return out


def stack(robots):
    r = np.concatenate([np.full(len(x[0]), i) for i, x in enumerate(robots)])
    t0 = np.concatenate([x[0] for x in robots])
    t1 = np.concatenate([x[1] for x in robots])
    co = np.concatenate([x[2] for x in robots])
    return r, t0, t1, co


def dense_pair_min(ri, rj, n=100_001):
    a = max(ri[0][0], rj[0][0])
    b = min(ri[1][-1], rj[1][-1])
    t = np.concatenate([np.linspace(a, b, n), ri[0], rj[0]])
    t = t[(t >= a) & (t <= b)]
    d = np.linalg.norm(eval_ref(*ri, t) - eval_ref(*rj, t), axis=1)
    k = np.nanargmin(d)
    return d[k], t[k], (b - a) / (n - 1)


def max_speed_bound(robot):
    t0, t1, co = robot
    best = 0.0
    for k in range(t0.size):
        h = t1[k] - t0[k]
        dc = co[k, :, 1:] * np.arange(1, co.shape[2])
        best = max(best, float(np.sum(np.abs(dc) * h ** np.arange(dc.shape[1]))))
    return best


# ------------------------------------------------------------ separation vs dense sampling


@pytest.mark.parametrize("seed,n_dims", [(0, 3), (1, 3), (2, 2), (3, 1)])
def test_exact_min_vs_dense(seed, n_dims):
    rng = np.random.default_rng(seed)
    robots = [random_robot(rng, 10.0, int(rng.integers(2, 6)), n_dims, 5) for _ in range(4)]
    # a later start for one robot: the common span is then a proper sub-interval
    t0, t1, co = robots[3]
    robots[3] = (t0 * 0.8 + 2.0, t1 * 0.8 + 2.0, co)
    dmin, tmin = M.pairwise_min_separation(*stack(robots))
    assert dmin.shape == (4, 4) and np.all(np.isinf(np.diag(dmin)))
    assert np.array_equal(dmin, dmin.T)
    for i in range(4):
        for j in range(i + 1, 4):
            dd, _, dt = dense_pair_min(robots[i], robots[j])
            vrel = max_speed_bound(robots[i]) + max_speed_bound(robots[j])
            # never above a real sample by more than round-off
            assert dmin[i, j] <= dd + 1e-12 * (1 + vrel)
            # and the dense grid cannot beat it by more than its resolution
            assert dd - dmin[i, j] <= vrel * dt
            # the reported time attains the reported distance
            ti = np.array([tmin[i, j]])
            dt_ = np.linalg.norm(eval_ref(*robots[i], ti) - eval_ref(*robots[j], ti))
            assert abs(dt_ - dmin[i, j]) <= 1e-10 * (1 + vrel)


def test_near_zero_distance_misaligned_breaks():
    """Robot 1 follows robot 0 at a 1e-9 m offset; breaks differ; absolute accuracy."""
    rng = np.random.default_rng(7)
    gc = rng.normal(size=(3, 6)) * np.array([1, 1, 0.3, 0.05, 0.005, 0.0003])
    r0 = pieces_from_global(gc, [0, 1.3, 4.1, 7.7, 12.0])
    gc1 = gc.copy()
    off = np.array([1e-9, -2e-9, 0.0])
    gc1[:, 0] += off
    r1 = pieces_from_global(gc1, [0, 0.4, 2.5, 2.6, 9.0, 12.0])
    dmin, tmin = M.pairwise_min_separation(*stack([r0, r1]))
    assert abs(dmin[0, 1] - np.linalg.norm(off)) < 1e-13
    # crossing in 1-D: the exact minimum is 0 and is found to round-off
    g2 = np.zeros((1, 6))
    g2[0, :2] = [0.0, 1.0]  # x = t
    g3 = np.zeros((1, 6))
    g3[0, :3] = [3.0, -1.0, 0.01]  # crosses x = t near t = 1.52
    dmin, tmin = M.pairwise_min_separation(
        *stack([pieces_from_global(g2, [0, 0.7, 5]), pieces_from_global(g3, [0, 2, 3, 5])])
    )
    t_star = (2 - math.sqrt(4 - 4 * 0.01 * 3)) / (2 * 0.01)
    assert dmin[0, 1] < 1e-14
    assert abs(tmin[0, 1] - t_star) < 1e-12


@pytest.mark.parametrize("delta", [1e-2, 1e-6, 1e-10, 0.0])
@pytest.mark.parametrize("tscale", [0.1, 1.0, 100.0])
def test_known_closest_approach_near_zero(delta, tscale):
    """x_j = x_i + delta n + v (t - t*), v orthogonal to n: min delta at t*, for random
    quintic x_i, breaks that differ between the robots, piece lengths ~ tscale."""
    rng = np.random.default_rng(int(1e6 * delta) + int(tscale * 10))
    T = 10.0 * tscale
    gc = rng.normal(size=(3, 6)) / T ** np.arange(6)  # O(1) m over [0, T]
    n = rng.normal(size=3)
    n /= np.linalg.norm(n)
    v = np.cross(n, rng.normal(size=3))
    v *= 2.0 / (T * np.linalg.norm(v))
    t_star = rng.uniform(0.1, 0.9) * T
    gj = gc.copy()
    gj[:, 0] += delta * n - v * t_star
    gj[:, 1] += v
    bi = np.concatenate([[0], np.sort(rng.uniform(0, T, 5)), [T]])
    bj = np.concatenate([[0], np.sort(rng.uniform(0, T, 7)), [T]])
    dmin, tmin = M.pairwise_min_separation(
        *stack([pieces_from_global(gc, bi), pieces_from_global(gj, bj)])
    )
    assert abs(dmin[0, 1] - delta) < 1e-13
    if delta > 1e-6:
        assert abs(tmin[0, 1] - t_star) < 1e-6 * T


def hermite_fleet(m, t_end, hz, rng):
    """Smooth wandering robots (sinusoids) as C2 quintic Hermite pieces at hz, with
    per-robot clock offsets (misaligned breaks), as a receding-horizon run produces."""
    robots = []
    for _ in range(m):
        c0 = rng.uniform(-1, 1, 3)
        w, ph, amp = rng.uniform(0.5, 2, 3), rng.uniform(0, 6.3, 3), rng.uniform(0.5, 1, 3)
        f = lambda t, c0=c0, w=w, ph=ph, amp=amp: (
            c0 + amp * np.sin(w * t + ph),
            amp * w * np.cos(w * t + ph),
            -amp * w * w * np.sin(w * t + ph),
        )
        off = rng.uniform(0, 1 / hz)
        br = np.unique(np.concatenate([[0.0], np.arange(off, t_end, 1 / hz)[1:], [t_end]]))
        co = np.zeros((br.size - 1, 3, 6))
        for k in range(br.size - 1):
            h = br[k + 1] - br[k]
            (p0, v0, a0), (p1, v1, a1) = f(br[k]), f(br[k + 1])
            A = np.array(
                [[h**3, h**4, h**5], [3 * h**2, 4 * h**3, 5 * h**4], [6 * h, 12 * h**2, 20 * h**3]]
            )
            co[k, :, :3] = np.stack([p0, v0, a0 / 2], 1)
            rhs = np.stack([p1 - p0 - v0 * h - a0 * h * h / 2, v1 - v0 - a0 * h, a1 - a0], 1)
            co[k, :, 3:] = np.linalg.solve(A, rhs.T).T
        robots.append((br[:-1], br[1:], co))
    return robots


def test_fleet_vs_dense():
    rng = np.random.default_rng(4)
    robots = hermite_fleet(6, 6.0, 8.0, rng)
    dmin, _ = M.pairwise_min_separation(*stack(robots))
    t = np.linspace(0, 6.0, 200_001)
    pos = np.stack([eval_ref(*rb, t) for rb in robots])
    for i in range(6):
        for j in range(i + 1, 6):
            dense = np.linalg.norm(pos[i] - pos[j], axis=1).min()
            assert dmin[i, j] <= dense + 1e-12
            assert dense - dmin[i, j] <= 20.0 * (t[1] - t[0])  # speeds < 10 m/s


@pytest.mark.parametrize("h", [0.1, 1.0, 100.0])
def test_interval_lengths(h):
    """Closest approach of two straight lines over pieces of 0.1 s to 100 s."""

    # x_i = (-5 + s, 0, 0), x_j = (0, -3 + s, 1) with s = 10 t / (10 h): min sqrt(3) at s = 4
    def line(p0, v, breaks):
        gc = np.zeros((3, 6))
        gc[:, 0] = p0
        gc[:, 1] = np.asarray(v) / h
        return pieces_from_global(gc, breaks)

    ri = line([-5, 0, 0], [1, 0, 0], h * np.array([0, 2.5, 7, 10]))
    rj = line([0, -3, 1], [0, 1, 0], h * np.array([0, 1, 3.9, 4.2, 10]))
    dmin, tmin = M.pairwise_min_separation(*stack([ri, rj]))
    assert abs(dmin[0, 1] - math.sqrt(3)) < 1e-13
    assert abs(tmin[0, 1] - 4 * h) < 1e-9 * max(h, 1)


# ------------------------------------------------------------------------- hand cases


def test_parallel_constant_distance():
    rng = np.random.default_rng(3)
    gc = rng.normal(size=(3, 6))
    gc2 = gc.copy()
    gc2[:, 0] += [1.0, 2.0, 2.0]
    r0 = pieces_from_global(gc, [0, 0.5, 1, 2])
    r1 = pieces_from_global(gc2, [0, 0.25, 1.75, 2])
    dmin, tmin = M.pairwise_min_separation(*stack([r0, r1]))
    assert abs(dmin[0, 1] - 3.0) < 1e-12
    assert 0.0 <= tmin[0, 1] <= 2.0


def test_touching_exactly_at_rho_and_collisions():
    co = np.zeros((2, 3, 6))
    co[0, :, 0] = [-1, 0.5, 0]
    co[0, 0, 1] = 1
    co[1, :, 0] = [1, -0.5, 0]
    co[1, 0, 1] = -1
    dmin, tmin = M.pairwise_min_separation([0, 1], [0, 0], [2, 2], co)
    assert dmin[0, 1] == 1.0 and tmin[0, 1] == 1.0
    rep = M.separation_report(dmin, np.array([0.5, 0.5]))
    assert rep["collisions"] == 0 and rep["min_separation_ratio"] == 1.0
    assert rep["worst_pair"] == (0, 1) and rep["worst_distance_m"] == 1.0
    rep = M.separation_report(dmin, np.array([0.5, 0.5 + 1e-9]))
    assert rep["collisions"] == 1 and rep["min_separation_ratio"] < 1.0
    rep = M.separation_report(dmin, np.array([0.5, 0.5 + 1e-9]), rtol=1e-6)
    assert rep["collisions"] == 0


def test_identical_robots_and_report():
    rng = np.random.default_rng(5)
    t0, t1, co = random_robot(rng, 5.0, 4, 3, 5)
    far = co.copy()
    far[:, :, 0] += 100.0
    r, a, b, c = stack([(t0, t1, co), (t0, t1, co), (t0, t1, far)])
    dmin, _ = M.pairwise_min_separation(r, a, b, c)
    assert dmin[0, 1] == 0.0
    assert dmin[0, 2] > 50 and dmin[1, 2] > 50
    rep = M.separation_report(dmin, np.full(3, 0.3))
    assert rep["collisions"] == 1 and rep["min_separation_ratio"] == 0.0
    assert rep["worst_pair"] == (0, 1)


# ------------------------------------------------------------------------- kinematics


def test_kinematic_maxima_vs_dense():
    rng = np.random.default_rng(11)
    robots = [random_robot(rng, 6.0, 5, 3, 5), random_robot(rng, 6.0, 3, 3, 5)]
    kin = M.kinematics(*stack(robots))
    for i, (t0, t1, co) in enumerate(robots):
        for deriv, got in ((1, kin.max_speed[i]), (2, kin.max_acc[i]), (3, kin.max_jerk[i])):
            best = 0.0
            for k in range(t0.size):
                tau = np.linspace(0, t1[k] - t0[k], 100_001)
                dc = [P.polyder(co[k, n], deriv) for n in range(3)]
                val = np.sqrt(sum(P.polyval(tau, d) ** 2 for d in dc))
                best = max(best, val.max())
            assert got >= best * (1 - 1e-12)
            assert got <= best * (1 + 1e-6)


def test_path_length_straight_and_stop():
    # min-jerk rest-to-rest along a direction: length exactly L
    L, T = 7.0, 3.0
    s = np.array([0, 0, 0, 10, -15, 6]) * L / T ** np.arange(6)
    direction = np.array([1.0, 2.0, 2.0]) / 3.0
    gc = direction[:, None] * s[None, :]
    gc[:, 0] += [1.0, -2.0, 0.5]
    kin = M.kinematics(*stack([pieces_from_global(gc, [0, 1.0, 2.2, 3.0])]))
    assert abs(kin.path_length_m[0] - L) < 1e-12 * L
    assert abs(kin.max_speed[0] - 1.875 * L / T) < 1e-12  # peak of min-jerk speed
    # there and back along a line within ONE piece (speed kink at the turn): length 2
    g2 = np.zeros((3, 6))
    g2[0, :3] = [0.0, 4.0, -4.0]  # x = 4t(1-t), t in [0, 1]: 0 -> 1 -> 0
    kin = M.kinematics(*stack([pieces_from_global(g2, [0.0, 1.0])]))
    assert abs(kin.path_length_m[0] - 2.0) < 1e-12
    assert abs(kin.max_speed[0] - 4.0) < 1e-12 and abs(kin.max_acc[0] - 8.0) < 1e-12
    assert kin.max_jerk[0] == 0.0


def test_path_length_circle_hermite():
    """Quintic Hermite pieces through a unit circle: length vs scipy quad and vs 2 pi."""
    from scipy.integrate import quad

    n, T = 8, 8.0
    w = 2 * np.pi / T
    br = np.linspace(0, T, n + 1)
    co = np.zeros((n, 2, 6))
    for k in range(n):
        h = br[k + 1] - br[k]

        def st(t):
            return (
                np.array([np.cos(w * t), np.sin(w * t)]),
                w * np.array([-np.sin(w * t), np.cos(w * t)]),
                -(w**2) * np.array([np.cos(w * t), np.sin(w * t)]),
            )

        p0, v0, a0 = st(br[k])
        p1, v1, a1 = st(br[k + 1])
        A = np.array(
            [
                [h**j for j in range(6)],
                [j * h ** (j - 1) if j else 0 for j in range(6)],
                [j * (j - 1) * h ** (j - 2) if j > 1 else 0 for j in range(6)],
            ]
        )
        for d in range(2):
            c012 = np.array([p0[d], v0[d], a0[d] / 2])
            rhs = np.array([p1[d], v1[d], a1[d]]) - A[:, :3] @ c012
            co[k, d, :3] = c012
            co[k, d, 3:] = np.linalg.solve(A[:, 3:], rhs)
    kin = M.kinematics(np.zeros(n, int), br[:-1], br[1:], co)
    ref = 0.0
    for k in range(n):
        dc = [P.polyder(co[k, d]) for d in range(2)]
        f = lambda tau, dc=dc: math.hypot(P.polyval(tau, dc[0]), P.polyval(tau, dc[1]))
        ref += quad(f, 0, br[k + 1] - br[k], epsabs=1e-14, epsrel=1e-14, limit=200)[0]
    assert abs(kin.path_length_m[0] - ref) < 1e-11
    assert abs(kin.path_length_m[0] - 2 * np.pi) < 1e-4  # the interpolant is close to a circle
    assert abs(kin.max_speed[0] - w) < 1e-4


# ------------------------------------------------------------------------- sampling


def test_sample_pieces_matches_reference_and_edges():
    rng = np.random.default_rng(2)
    robots = [random_robot(rng, 4.0, 3, 3, 5), random_robot(rng, 3.0, 2, 3, 5)]
    r, t0, t1, co = stack(robots)
    t = np.arange(0, 401) / 100.0  # 100 Hz, includes the breaks 0 and ends
    pos, vel, acc = M.sample_pieces(r, t0, t1, co, t)
    assert pos.shape == vel.shape == acc.shape == (2, t.size, 3)
    np.testing.assert_allclose(pos[0], eval_ref(*robots[0], t), rtol=1e-12, atol=1e-12)
    inside = t <= 3.0
    np.testing.assert_allclose(pos[1, inside], eval_ref(*robots[1], t[inside]), atol=1e-12)
    assert np.all(np.isnan(pos[1, ~inside]))
    # velocity by finite differences of the reference
    e = 1e-6
    fd = (eval_ref(*robots[0], t[1:-1] + e) - eval_ref(*robots[0], t[1:-1] - e)) / (2 * e)
    ok = np.ones(t.size - 2, bool)
    for b in robots[0][0]:
        ok &= np.abs(t[1:-1] - b) > 2 * e  # pieces may be discontinuous at breaks
    np.testing.assert_allclose(vel[0, 1:-1][ok], fd[ok], rtol=1e-5, atol=1e-5)
    pos_c, vel_c, _ = M.sample_pieces(r, t0, t1, co, t, outside="clamp")
    last = pos_c[1, inside][-1:]
    np.testing.assert_allclose(pos_c[1, ~inside], np.repeat(last, (~inside).sum(), 0))


# ----------------------------------------------------------------------- time to goal


def _approach(stop_at=None):
    # x moves 0 -> 10 at 2 m/s on [0, 5], then rests at 10 on [5, 8] (or leaves again)
    c = np.zeros((2, 2, 6))
    c[0, 0, 1] = 2.0
    c[1, 0, 0] = 10.0
    if stop_at == "leave":
        c[1, 0, 1] = 1.0  # keeps going: leaves the 0.5 m ball at t = 5.5
    return np.zeros(2, int), np.array([0.0, 5.0]), np.array([5.0, 8.0]), c


def test_time_to_goal_exact_and_sampled():
    goal = np.array([[10.0, 0.0]])
    r, t0, t1, c = _approach()
    got = M.time_to_goal_pieces(r, t0, t1, c, goal, 0.5)
    assert abs(got[0] - 4.75) < 1e-12  # |x - 10| <= 0.5 from x = 9.5
    got = M.time_to_goal_pieces(r, t0, t1, c, goal, 0.5, speed_tol=0.1)
    assert abs(got[0] - 5.0) < 1e-12  # speed drops to 0 at t = 5
    t = np.arange(0, 801) / 100.0
    pos, vel, _ = M.sample_pieces(r, t0, t1, c, t)
    s = M.time_to_goal(t, pos, goal, 0.5)
    assert 4.75 <= s[0] <= 4.75 + 0.01 + 1e-12
    s = M.time_to_goal(t, pos, goal, 0.5, vel=vel, speed_tol=0.1)
    assert abs(s[0] - 5.0) < 1e-12
    # leaves again -> NaN; always within -> start time
    r, t0, t1, c = _approach("leave")
    assert np.isnan(M.time_to_goal_pieces(r, t0, t1, c, goal, 0.5)[0])
    pos, _, _ = M.sample_pieces(r, t0, t1, c, t)
    assert np.isnan(M.time_to_goal(t, pos, goal, 0.5)[0])
    r, t0, t1, c = _approach()
    assert M.time_to_goal_pieces(r, t0, t1, c, goal, 100.0)[0] == 0.0
    # dips in and out before arriving: the last entry counts
    g = np.zeros((1, 6))
    g[0, :4] = [0.0, 3.0, -1.5, 1.0 / 6.0]  # x = 3t - 1.5t^2 + t^3/6 on [0, 6]
    tt0, tt1, cc = pieces_from_global(g, [0, 2.3, 6])
    xs = lambda tt: P.polyval(tt, g[0])
    gx = xs(6.0) - 0.2
    got = M.time_to_goal_pieces(np.zeros(2, int), tt0, tt1, cc, np.array([[gx]]), 0.3)
    ts = np.linspace(0, 6, 600_001)
    within = np.abs(xs(ts) - gx) <= 0.3
    last_out = ts[np.nonzero(~within)[0][-1]]
    assert abs(got[0] - last_out) < 2e-5


# --------------------------------------------------------------------- solver summary


def test_solver_summary():
    s = M.solver_summary(np.arange(1, 101, dtype=float), np.array([True] * 3 + [False]))
    assert s["median_ms"] == 50.5 and s["max_ms"] == 100.0
    assert abs(s["p95_ms"] - 95.05) < 1e-12 and s["converged_frac"] == 0.75
    s = M.solver_summary([], np.zeros((0,), bool))
    assert all(math.isnan(v) for v in s.values())


# ------------------------------------------------------------------ degenerate inputs


def test_one_robot_and_no_overlap():
    rng = np.random.default_rng(0)
    r0 = random_robot(rng, 1.0, 3, 3, 5)
    dmin, tmin = M.pairwise_min_separation(*stack([r0]))
    assert dmin.shape == (1, 1) and np.isinf(dmin[0, 0]) and np.isnan(tmin[0, 0])
    rep = M.separation_report(dmin, np.array([0.2]))
    assert rep["collisions"] == 0 and rep["min_separation_ratio"] == math.inf
    assert rep["worst_pair"] is None
    # robots that never share a time: inf; an extra robot without pieces: inf / NaN
    t0, t1, co = random_robot(rng, 1.0, 2, 3, 5)
    dmin, tmin = M.pairwise_min_separation(*stack([r0, (t0 + 2, t1 + 2, co)]), num_robots=3)
    assert dmin.shape == (3, 3) and np.all(np.isinf(dmin)) and np.all(np.isnan(tmin))
    kin = M.kinematics(*stack([r0]), num_robots=2)
    assert np.isnan(kin.max_speed[1]) and np.isnan(kin.path_length_m[1])
    empty = (np.zeros(0, int), np.zeros(0), np.zeros(0), np.zeros((0, 3, 6)))
    assert M.pairwise_min_separation(*empty)[0].shape == (0, 0)


def test_zero_length_pieces_and_constant_pieces_2d():
    # robot 0: a zero-length piece in the middle of its tiling; robot 1: constant (D=0
    # equivalent) pieces; robot 2: a single zero-length piece (one instant)
    c0 = np.zeros((3, 2, 6))
    c0[0, :, :2] = [[0, 1], [0, 0]]  # x = t on [0, 1]
    c0[1, :, 0] = [1, 0]  # the instant t = 1
    c0[2, :, :2] = [[1, 1], [0, 0]]  # x = 1 + (t - 1) on [1, 3]
    c1 = np.zeros((2, 2, 6))
    c1[:, :, 0] = [[2, 1], [2, 1]]
    c2 = np.zeros((1, 2, 6))
    c2[0, :, 0] = [0, 0.5]
    r = np.array([0, 0, 0, 1, 1, 2])
    t0 = np.array([0, 1, 1, 0, 1.5, 2.0])
    t1 = np.array([1, 1, 3, 1.5, 3, 2.0])
    co = np.concatenate([c0, c1, c2])
    dmin, tmin = M.pairwise_min_separation(r, t0, t1, co)
    assert abs(dmin[0, 1] - 1.0) < 1e-15 and abs(tmin[0, 1] - 2.0) < 1e-12
    assert abs(dmin[0, 2] - math.hypot(2.0, 0.5)) < 1e-15 and tmin[0, 2] == 2.0
    assert abs(dmin[1, 2] - math.hypot(2.0, 0.5)) < 1e-15
    kin = M.kinematics(r, t0, t1, co)
    np.testing.assert_allclose(kin.path_length_m, [3.0, 0.0, 0.0], atol=1e-14)
    np.testing.assert_allclose(kin.max_speed, [1.0, 0.0, 0.0])
    pos, _, _ = M.sample_pieces(r, t0, t1, co, np.array([0.5, 1.0, 2.0]))
    np.testing.assert_allclose(pos[0], [[0.5, 0], [1, 0], [2, 0]])
    assert np.isnan(pos[2, 0, 0]) and np.allclose(pos[2, 2], [0, 0.5])
    # degree 0 and N = 1
    dmin, _ = M.pairwise_min_separation([0, 1], [0, 0], [1, 1], np.array([[[0.0]], [[2.0]]]))
    assert dmin[0, 1] == 2.0
    kin = M.kinematics([0], [0], [1], np.array([[[3.0]]]))
    assert kin.max_speed[0] == 0.0 and kin.path_length_m[0] == 0.0


def test_bad_inputs():
    co = np.zeros((2, 3, 6))
    with pytest.raises(ValueError, match="overlapping"):
        M.pairwise_min_separation([0, 0], [0, 0.5], [1, 2], co)
    with pytest.raises(ValueError, match="t1 >= "):
        M.pairwise_min_separation([0, 1], [0, 1], [1, 0.5], co)
    with pytest.raises(ValueError, match="seg_coeffs"):
        M.pairwise_min_separation([0, 1], [0, 0], [1, 1], np.zeros((2, 3)))
