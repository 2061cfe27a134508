"""Tests of jaxplan.solve against the done-when list (and NLopt SLSQP as reference).

Compile time dominates: every solve_batch call uses a batch of B = 50 and one of a
few structures, so each structure compiles once for the whole module.
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplan import nlp, solve
from jaxplan.nlp import NLPStructure
from jaxplan.reference import solve_slsqp
from jaxplan.solve.types import max_violation
from jaxplan.testing import index_params, random_problem, stack_params
from jaxplan.trajectory import Trajectory
from jaxplan.world import StaticRows

B = 50
MODES = ("paper", "barrier", "constraint", "barrier+constraint")
# a structure's batch program compiles in ~6-10 s (2 cores): `make test` solves the
# random NLPs in the paper's mode and the planner's default; the two modes whose terms
# barrier+constraint combines under `make test-slow`
MODE_PARAMS = [pytest.param(m, marks=pytest.mark.slow) if m in ("barrier", "constraint") else m
               for m in MODES]
S2 = {m: NLPStructure(collision=m, segments=2) for m in MODES}
S1 = NLPStructure(collision="barrier+constraint", segments=1)
_one = jax.jit(lambda p, x: solve.solve(p, x, S1))
_warm = jax.jit(lambda tr, p: solve.warm_start(tr, 0.125, p, S1))


def _problems(seed, n=B):
    rng = np.random.default_rng(seed)
    return [random_problem(rng, n_others=int(rng.integers(2, 11)), rest=bool(i % 2))
            for i in range(n)]


@functools.cache
def _random_results(mode):
    ps = _problems(100 + MODES.index(mode))
    P = stack_params(ps)
    st = S2[mode]
    x0 = solve.initial_guess_batch(P, st)
    sol = solve.solve_batch(P, x0, st)
    return ps, P, x0, jax.device_get(sol)


@pytest.mark.parametrize("mode", MODE_PARAMS)
def test_random_nlps_converge_and_satisfy_constraints(mode):
    ps, P, x0, sol = _random_results(mode)
    st = S2[mode]
    conv = sol.status == solve.CONVERGED
    assert not np.any(sol.status == solve.NON_FINITE)
    # >= 99 % over the problems of the modes: at most one failure per mode
    assert np.sum(~conv) <= 1, (mode, sol.status)
    assert np.max(sol.eq_violation) <= 1e-8
    assert np.all(np.isfinite(sol.traj.coeffs))
    # the reported objective and violation (formed from the solver's last L_A value and
    # constraints) equal a fresh evaluation at the solution
    x = jnp.asarray(sol.x)
    # jitted: op by op (eager) these cost seconds per mode
    obj, g = jax.jit(jax.vmap(lambda x, p: (nlp.objective(x, p, st),
                                            nlp.constraints(x, p, st))))(x, P)
    np.testing.assert_allclose(sol.objective, obj, rtol=1e-9, atol=1e-9)
    viol = np.maximum(np.max(-np.asarray(g.collision), axis=(1, 2), initial=0.0),
                      np.max(-np.asarray(g.limits), axis=(1, 2), initial=0.0))
    np.testing.assert_allclose(sol.ineq_violation, viol, rtol=1e-9, atol=1e-12)
    if st.collision_constraints:
        rho = (P.radius[:, None] + P.other_radius)[:, None, :]
        d = jnp.sqrt(jnp.maximum(g.collision + rho**2, 0.0))
        short = jnp.where(P.other_mask[:, None, :], rho - d, -1.0)
        assert float(jnp.max(jnp.where(conv[:, None, None], short, -1.0))) <= 1e-6


@pytest.mark.parametrize("mode", MODE_PARAMS)
def test_objective_no_worse_than_slsqp(mode):
    ps, P, x0, sol = _random_results(mode)
    st = S2[mode]
    worse = []
    for i in range(4):
        ref = solve_slsqp(ps[i], np.asarray(x0[i]), st)
        if ref.converged and ref.ineq_violation <= 1e-7 and sol.status[i] == solve.CONVERGED:
            gap = (sol.objective[i] - ref.objective) / max(1.0, abs(ref.objective))
            worse.append(gap)
    assert worse, "no pair converged"
    assert max(worse) <= 1e-3, worse


@functools.cache
def _s1_batch():
    ps = _problems(7)
    bad = ps[3]._replace(p0=ps[3].p0.at[0].set(jnp.nan))
    ps = ps[:3] + [bad] + ps[4:]
    return ps, stack_params(ps)


def test_vmapped_batch_equals_single_solves_and_nan_lane():
    ps, P = _s1_batch()
    x0 = solve.initial_guess_batch(P, S1)
    sol = jax.device_get(solve.solve_batch(P, x0, S1))
    for i in (0, 1, 2):
        s = jax.device_get(_one(ps[i], x0[i]))
        np.testing.assert_allclose(s.x, sol.x[i], rtol=1e-9, atol=1e-9)
        assert s.status == sol.status[i] and s.iterations == sol.iterations[i]
    # NaN policy: the bad lane is reported, finite, and does not poison the batch
    assert sol.status[3] == solve.NON_FINITE
    assert np.all(np.isfinite(sol.x[3])) and np.all(np.isfinite(sol.traj.coeffs[3]))
    assert np.mean(sol.status == solve.CONVERGED) >= 0.9


def test_cold_batch_forms_the_initial_guesses_itself():
    """solve_batch(P, None): every problem from its initial_guess, formed in the solve's
    own program: the results of solving from initial_guess_batch; an x0 whose leading
    axes are not the problems' is refused before anything compiles."""
    ps, P = _s1_batch()
    x0 = solve.initial_guess_batch(P, S1)
    ref = jax.device_get(solve.solve_batch(P, x0, S1))
    cold = jax.device_get(solve.solve_batch(P, None, S1))
    np.testing.assert_array_equal(cold.status, ref.status)
    np.testing.assert_array_equal(cold.iterations, ref.iterations)
    ok = ref.status != solve.NON_FINITE  # the NaN lane reports x0 (None here: its guess)
    np.testing.assert_allclose(cold.x[ok], ref.x[ok], rtol=1e-9, atol=1e-9)
    with pytest.raises(ValueError, match="leading axes"):
        solve.solve_batch(P, x0[:3], S1)


BUDGET_LANES = (solve.MAX_ITERS, solve.INFEASIBLE)


def _assert_same_lanes(sol, ref):
    """``sol`` has every lane of ``ref``: the same iterations everywhere, the same status
    and the same floats to rounding wherever ``ref`` converged (or went NON_FINITE); a
    lane that spent the whole budget in ``ref`` (MAX_ITERS or INFEASIBLE) also spent it
    in ``sol`` without converging, but which of the two it ends in may differ (see
    test_pool_size_does_not_change_results)."""
    np.testing.assert_array_equal(sol.iterations, ref.iterations)
    out = np.isin(ref.status, BUDGET_LANES)
    np.testing.assert_array_equal(np.where(out, -1, sol.status), np.where(out, -1, ref.status))
    assert np.all(np.isin(sol.status[out], BUDGET_LANES))
    conv = ref.status == solve.CONVERGED
    for a, b in zip(jax.tree.leaves(sol), jax.tree.leaves(ref), strict=True):
        assert np.all(np.isfinite(a) | np.isinf(b))
        np.testing.assert_allclose(np.asarray(a)[conv], np.asarray(b)[conv],
                                   rtol=1e-9, atol=1e-9)


def test_pool_size_does_not_change_results():
    """solve_batch steps ``pool`` lanes at a time, refilling finished slots (the work is
    the sum of the lanes' iterations, not B x the largest): every lane must come out as
    with the plain vmap (pool = B), whatever the pool; a lane whose x0 is not finite
    starts from initial_guess as solve() does.

    The pools run the same iterations, but XLA vectorizes different batch widths
    differently, so the floats can differ in the last bit.  That stays rounding (checked
    below on EVERY lane with the budget cut to 12 iterations, where no penalty has
    passed 1e6) until an infeasible lane's penalty reaches 1e10: there its Hessian's
    condition (~1e12) turns last-bit differences into ~1e-9 in one step, and its
    multipliers, growing by mu x violation each iteration, amplify them ~1.6x per
    iteration.  Lane 23 of this batch on a CPU with AVX-512: identical to
    <= 2.2e-16 for 18 iterations, 1e-9 at the 19th, 1e-3 at the 51st, and after 60 it
    ends feasible (MAX_ITERS, objective 52.5) with the plain vmap but INFEASIBLE
    (violation 0.14, objective 27.0) with pools 1, 2, 7 and 12 and in solve() alone;
    perturbing its x0 by 1e-15 .. 1e-13 changes neither.  So lanes that spend the
    whole budget are compared by iterations and by not converging only
    (_assert_same_lanes); converged lanes by status, iterations and floats."""
    ps, P = _s1_batch()
    x0 = solve.initial_guess_batch(P, S1)
    x0 = x0.at[5].set(jnp.nan)
    short = solve.SolverSettings(max_iters=12)
    ref12 = jax.device_get(solve.solve_batch(P, x0, S1, short, pool=B))
    assert np.max(ref12.penalty) <= 1e6  # the premise: no lane ill-conditioned yet
    ref = jax.device_get(solve.solve_batch(P, x0, S1, pool=B))
    assert len(set(ref.iterations.tolist())) > 3  # uneven: the pool has work to balance
    assert np.sum(ref.status == solve.CONVERGED) >= 40
    # the default pool (12 lanes a step: 50 = 4 x 12 + 2, slots refilled to the last):
    # the program test_vmapped_batch_equals_single_solves_and_nan_lane compiled; other
    # pools and batches are replayed by test_pool_steps_replays_the_pool
    pool = solve.default_pool(B, n_others=P.other_mask.shape[-1])
    assert 2 < pool < B and B % pool
    sol12 = jax.device_get(solve.solve_batch(P, x0, S1, short, pool=pool))
    for f in ("status", "iterations", "penalty", "evaluations"):
        np.testing.assert_array_equal(getattr(sol12, f), getattr(ref12, f))
    for f in ("x", "traj", "objective", "eq_violation", "ineq_violation", "multipliers"):
        for a, b in zip(jax.tree.leaves(getattr(sol12, f)), jax.tree.leaves(getattr(ref12, f)),
                        strict=True):
            np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-9, err_msg=f)
    # the gradient's max-norm and the Newton decrement sum terms up to ~mu (1e6 here)
    # times larger than themselves: rounding shows at ~1e-11 absolute
    for f in ("kkt_residual", "decrement"):
        np.testing.assert_allclose(getattr(sol12, f), getattr(ref12, f), rtol=1e-6,
                                   atol=1e-9, err_msg=f)
    _assert_same_lanes(jax.device_get(solve.solve_batch(P, x0, S1, pool=pool)), ref)
    one = jax.device_get(_one(ps[5], jnp.full(S1.n_x, jnp.nan)))
    np.testing.assert_allclose(one.x, ref.x[5], rtol=1e-9, atol=1e-9)
    assert one.iterations == ref.iterations[5] and ref.status[5] == solve.CONVERGED
    assert one.evaluations == ref.evaluations[5]
    # an iteration's base point is an evaluation, and a converged lane was evaluated at
    # its last iterate too (where the tests passed)
    assert np.all(ref.evaluations >= ref.iterations)
    conv = ref.status == solve.CONVERGED
    assert np.all(ref.evaluations[conv] >= ref.iterations[conv] + 1)
    assert np.sum(ref.evaluations) > np.sum(ref.iterations) + np.sum(conv)  # some trials


@pytest.mark.slow  # a program of its own (~8 s on 2 cores): `make test-slow`; the planner's
# fleets (the tiny scenario's 3 robots, pool 2) take this path in every closed-loop test
def test_lockstep_then_slots_gives_the_plain_vmaps_lanes():
    """A batch of <= LOCKSTEP_MAX lanes starts in lockstep, then hands its stragglers to
    the slots (solve.pool._pooled): the lanes of the plain vmap (pool = B) again."""
    ps, P = _s1_batch()
    x0 = solve.initial_guess_batch(P, S1).at[5].set(jnp.nan)
    n = 20
    assert n <= solve.LOCKSTEP_MAX < B
    sub = lambda t: jax.tree.map(lambda a: a[:n], t)
    ref = jax.device_get(solve.solve_batch(sub(P), x0[:n], S1, pool=n))
    sol = jax.device_get(solve.solve_batch(sub(P), x0[:n], S1, pool=3))
    assert max(sol.iterations) > 2 * np.median(sol.iterations)  # stragglers for the slots
    _assert_same_lanes(sol, ref)


@pytest.mark.parametrize("B, pool", [(10, 2), (10, 4), (20, 3), (7, 7), (40, 2), (40, 12),
                                     (33, 5)])
def test_pool_steps_replays_the_pool(B, pool):
    """solve.pool_steps (the benchmark's count of a solve's steps from its lanes'
    evaluations) against the pool itself: solve.pool._pooled run with a step whose
    lanes each end after a given number of evaluations, its steps counted.  Batches of
    at most LOCKSTEP_MAX lanes (lockstep first) and larger ones; lanes that need no
    evaluation too."""
    from jaxplan.solve.alsqp import State, is_active
    from jaxplan.solve.pool import _pooled

    rng = np.random.default_rng(B * 100 + pool)
    need = rng.integers(0, 25, size=B)
    need[rng.integers(0, B)] = 60  # a straggler
    s = solve.SolverSettings(max_iters=1000)
    z = jnp.zeros((B,))
    st = State(**{f: z for f in State._fields})._replace(
        it=z.astype(jnp.int32), evals=z.astype(jnp.int32), base=z.astype(bool),
        done=jnp.asarray(need == 0))
    steps = []

    def step(st, target):
        jax.debug.callback(lambda: steps.append(1))
        act = is_active(st, s)
        ev = st.evals + act
        return st._replace(evals=ev, done=st.done | (ev >= target))

    out = jax.jit(lambda st, t: _pooled(st, t, step, pool, s) if pool < B else
                  jax.lax.while_loop(lambda c: jnp.any(~c.done), lambda c: step(c, t), st))(
        st, jnp.asarray(need, jnp.int32))
    jax.block_until_ready(out)
    np.testing.assert_array_equal(out.evals, need)  # every lane ran to its end
    assert len(steps) == sum(solve.pool_steps(need, pool))


_tb_derivs = jax.jit(lambda x, p, st, m, mu: nlp.merit_derivs(
    x, p, st, nlp.kind_constants(p.rest, st), m, mu), static_argnums=2)
_tb_value = jax.jit(lambda x, p, st, m, mu: nlp.merit_and_constraints(
    x, p, st, nlp.kind_constants(p.rest, st), m, mu), static_argnums=2)
_tb_direction = jax.jit(solve.direction)
_guess = jax.jit(solve.initial_guess, static_argnums=1)  # eagerly: op by op, slower


def test_directions_by_cholesky_where_it_settles_them_else_eigh(monkeypatch):
    """solve.directions gives what _direction (eigh, eigenvalues floored at reg x the
    largest) gives, for positive definite, nearly singular, indefinite and non-finite
    Hessians alike; Cholesky is used only where no eigenvalue would be floored (checked
    against numpy's eigenvalues), the rest goes to eigh."""
    rng = np.random.default_rng(5)
    n, reg = 7, 1e-13
    mats = []
    for kind in range(5):
        for _ in range(6):
            A = rng.normal(size=(n, n))
            if kind == 0:  # positive definite, well conditioned
                H = A @ A.T + 0.5 * np.eye(n)
            elif kind == 1:  # positive definite, eigenvalues 1e-16 .. 1 (some floored)
                Q = np.linalg.qr(A)[0]
                H = Q @ np.diag(np.logspace(-16, 0, n)) @ Q.T
            elif kind == 2:  # indefinite
                H = A + A.T
            elif kind == 3:  # positive definite with a large penalty direction
                u = rng.normal(size=n)
                H = A @ A.T + 0.1 * np.eye(n) + 1e10 * np.outer(u, u)
            else:  # positive semidefinite: singular
                B = rng.normal(size=(n, 3))
                H = B @ B.T
            mats.append(H)
    H = jnp.asarray(np.stack(mats))
    g = jnp.asarray(rng.normal(size=(len(mats), n)))
    need = jnp.asarray(rng.uniform(size=len(mats)) < 0.8)
    convex = jnp.asarray(rng.uniform(size=len(mats)) < 0.5)
    d, step = (np.asarray(a) for a in jax.jit(solve.directions)(H, g, need, reg, convex))
    ref = np.asarray(jax.jit(jax.vmap(lambda h, gg: solve.direction(h, gg, reg)))(H, g))
    assert np.all(np.isfinite(d)) and np.all(np.isfinite(step))
    # the Cholesky test is sufficient: where it passes, no eigenvalue is floored
    _, well = jax.vmap(solve.linalg.newton_cholesky, in_axes=(0, 0, None))(H, g, reg)
    well = np.asarray(well)
    w = np.linalg.eigvalsh(np.asarray(H))
    assert np.all(w[well].min(axis=1) >= reg * np.abs(w[well]).max(axis=1))
    assert well[:6].all() and not well[12:18].any()  # kinds 0 and 2
    assert 0 < well.sum() < len(mats)
    Hn, gn = np.asarray(H), np.asarray(g)
    for i in np.flatnonzero(np.asarray(need)):
        if well[i]:  # the Newton step -H^-1 g, to the rounding of a backward-stable solve
            res = np.linalg.norm(Hn[i] @ d[i] + gn[i])
            assert res <= 1e-12 * (np.linalg.norm(Hn[i]) * np.linalg.norm(d[i])
                                   + np.linalg.norm(gn[i]))
            assert np.linalg.norm(d[i] - ref[i]) <= 1e-4 * np.linalg.norm(ref[i])  # (cond 1e11)
        else:  # eigh's own step
            np.testing.assert_allclose(d[i], ref[i], rtol=1e-12, atol=0)
    # the step: d, except where convex and H is indefinite: the Newton step on H's
    # positive-curvature part alone (numpy's eigenvectors), a descent direction
    # (clearly indefinite lanes: the signs of eigenvalues at rounding level are LAPACK's)
    wv, V = np.linalg.eigh(Hn)
    top = np.abs(wv).max(axis=1)
    sure = wv.min(axis=1) < -1e-8 * top
    on = np.asarray(need) & np.asarray(convex)
    assert (on & sure)[12:18].any()  # some indefinite lanes take it
    for i in range(len(mats)):
        if not on[i] or not (wv[i].min() < 0 or sure[i]):
            np.testing.assert_array_equal(step[i], d[i])
        elif sure[i]:
            pos = wv[i] > 0
            wm = np.maximum(wv[i][pos], reg * top[i])
            want = -V[i][:, pos] @ ((V[i][:, pos].T @ gn[i]) / wm)
            np.testing.assert_allclose(step[i], want, rtol=1e-10,
                                       atol=1e-12 * np.abs(want).max())
            assert gn[i] @ step[i] < 0 and not np.allclose(step[i], d[i])
    # a Hessian with no positive curvature keeps the flipped step
    neg = -jnp.eye(n)[None] * jnp.arange(1.0, 3.0)[:, None, None]
    d_neg, s_neg = jax.jit(solve.directions)(neg, g[:2], jnp.ones(2, bool), reg,
                                             jnp.ones(2, bool))
    np.testing.assert_array_equal(np.asarray(s_neg), np.asarray(d_neg))
    np.testing.assert_allclose(np.asarray(d_neg), -np.asarray(g[:2]) / np.array([[1.0], [2.0]]),
                               rtol=1e-14)
    # on a CPU the lanes eigh takes are decomposed one by one (EIGH_CHUNK_CPU): in calls
    # of two or three the directions are bitwise the same (so the choice is speed alone)
    for chunk in (2, 3):
        monkeypatch.setattr(solve.linalg, "EIGH_CHUNK_CPU", chunk)
        d_c, s_c = jax.jit(lambda *a: solve.directions(*a))(H, g, need, reg, convex)
        np.testing.assert_array_equal(np.asarray(d_c), d)
        np.testing.assert_array_equal(np.asarray(s_c), step)
    # under an outer vmap (a sweep's runs) they are formed in chunks of EIGH_CHUNK
    # lanes, the program the sweeps' rows come from
    runs = lambda a: jnp.stack([a, a[::-1]])
    dv = jax.jit(jax.vmap(solve.directions, in_axes=(0, 0, 0, None, 0)))(
        runs(H), runs(g), runs(need), reg, runs(convex))
    ref_v = jax.jit(jax.vmap(lambda *a: solve.linalg._directions(
        *a, solve.linalg.EIGH_CHUNK), in_axes=(0, 0, 0, None, 0)))(
        runs(H), runs(g), runs(need), reg, runs(convex))
    for a, b in zip(dv, ref_v, strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    np.testing.assert_allclose(np.asarray(dv[0][0]), d, rtol=1e-12, atol=1e-300)
    np.testing.assert_allclose(np.asarray(dv[1][0]), step, rtol=1e-12, atol=1e-300)
    # non-finite lanes never reach it (the step sanitizes H), but it stays finite
    Hb = H.at[0].set(jnp.nan)
    assert all(np.all(np.isfinite(np.asarray(a))) for a in solve.directions(
        Hb, g, need.at[0].set(False), reg, convex))


def _textbook(p, x0, st, s=solve.SolverSettings()):
    """The AL-SQP loop of solver's module doc written plainly for one NLP: multiplier
    update, derivatives at x, direction and tests, then merit trials (costs'
    value path, not the derivatives') until Armijo holds.  (iterations, converged, x)."""
    p, _ = solve.types.sanitize(p)
    tau_min = float(np.log(max(float(p.t_min), 1e-6)))
    derivs = lambda x, m, mu: _tb_derivs(x, p, st, m, mu)
    value = lambda x, m, mu: _tb_value(x, p, st, m, mu)
    direction = _tb_direction
    x = jnp.asarray(x0).at[-1].max(tau_min)
    mult, mu = solve.zero_multipliers(p, st), s.mu0
    _, g = value(x, mult, mu)
    viol_ref, pending = np.inf, False
    for it in range(s.max_iters):
        if pending:  # lam <- max(0, lam - mu g) with the old mu; mu grows on a stall
            viol = float(solve.types.max_violation(g))
            mult = jax.tree.map(lambda l, gg, m0=mu: jnp.maximum(0.0, l - m0 * gg), mult, g)
            if viol > s.tol_feasibility and viol > s.stall_ratio * viol_ref:
                mu = min(mu * s.mu_growth, s.mu_max)
            viol_ref = viol
        f, gr, H = derivs(x, mult, mu)
        if x[-1] <= tau_min + 1e-12 and gr[-1] > 0:
            gr = gr.at[-1].set(0.0)
            H = H.at[-1, :].set(0.0).at[:, -1].set(0.0).at[-1, -1].set(1.0)
        d = direction(H, gr, s.reg)
        theta = float(-gr @ d)
        scale = 1.0 + abs(float(f))
        lam_t = jax.tree.map(lambda l, gg, m0=mu: jnp.maximum(0.0, l - m0 * gg), mult, g)
        compl = max(float(jnp.max(lam_t.collision * jnp.abs(g.collision))),
                    float(jnp.max(lam_t.limits * jnp.abs(g.limits))))
        if (theta <= s.tol_stationarity * scale
                and solve.types.max_violation(g) <= s.tol_feasibility
                and compl <= s.tol_complementarity * scale):
            return it, True, np.asarray(x)
        d = d * min(1.0, s.max_step_tau / max(abs(float(d[-1])), 1e-300),
                    s.max_step_z / max(float(jnp.max(jnp.abs(d[:-1]))), 1e-300))
        a, ok = 1.0, False
        thr = jax.tree.map(lambda l, m0=mu: l / m0, mult)
        for _ in range(s.max_backtracks + 1):
            xt = (x + a * d).at[-1].max(tau_min)
            ft, gt = value(xt, mult, mu)
            if np.isfinite(ft) and ft <= f + s.armijo * float(gr @ (xt - x)):
                ok = True
                break
            a = float(solve.alsqp.next_trial(a, g, gt, thr, s.kink_overshoot))
        if ok:
            x, g = xt, gt
        pending = theta <= s.inner_tol * scale or not ok
    return s.max_iters, False, np.asarray(x)


@pytest.mark.parametrize("mode", [pytest.param("barrier+constraint", marks=pytest.mark.slow),
                                  "constraint"])
def test_one_evaluation_steps_take_the_textbook_iterates(mode):
    """solve.alsqp.step_lanes evaluates each lane once per step (an accepted trial's derivatives
    start the next iteration): its iterates, iteration counts and convergence are those
    of the plain loop, which evaluates derivatives at each iterate and merit values at
    each trial ("constraint": the multipliers and the penalty change on the way)."""
    st = NLPStructure(collision=mode)
    ps = _problems(21, n=4)
    one = jax.jit(lambda p, x: solve.solve(p, x, st))
    for p in ps:
        x0 = _guess(p, st)
        sol = jax.device_get(one(p, x0))
        it, conv, x = _textbook(p, x0, st)
        assert (int(sol.iterations), bool(sol.status == solve.CONVERGED)) == (it, conv)
        np.testing.assert_allclose(sol.x, x, rtol=1e-8, atol=1e-8)


def test_default_pool_follows_the_batch_and_its_others():
    """The automatic pool (measured rule, solve.default_pool): on a CPU, for a large batch
    12 lanes if its NLPs have few others each, else 4; the whole batch of at most 3, 2
    otherwise; the whole batch elsewhere; never more lanes than the batch has."""
    L, F = solve.LOCKSTEP_MAX, solve.FEW_OTHERS
    assert solve.default_pool(640, "cpu", n_others=10) == solve.POOL_CPU_FEW == 12
    assert solve.default_pool(L + 1, "cpu", n_others=F) == 12
    assert solve.default_pool(L, "cpu", n_others=10) == solve.POOL_CPU == 2
    assert solve.default_pool(640, "cpu", n_others=F + 1) == solve.POOL_CPU_MANY == 4
    assert solve.default_pool(L + 1, "cpu", n_others=99) == 4
    assert solve.default_pool(L, "cpu", n_others=99) == 2
    assert solve.default_pool(640, "cpu") == 4
    assert solve.default_pool(1, "cpu", n_others=1) == 1
    assert solve.default_pool(solve.SMALL_BATCH, "cpu", n_others=2) == solve.SMALL_BATCH == 3
    assert solve.default_pool(solve.SMALL_BATCH + 1, "cpu", n_others=3) == 2
    assert solve.default_pool(640, "gpu", n_others=10) == 640


def test_changing_weights_does_not_recompile():
    ps, P = _s1_batch()
    x0 = solve.initial_guess_batch(P, S1)
    jax.block_until_ready(solve.solve_batch(P, x0, S1))
    before = solve.batch._solve_batch_jit._cache_size()
    for q_obs, q_lim in ((3.0, 0.5), (30.0, 2.0)):
        w = P.weights._replace(q_obs=jnp.full(B, q_obs), q_lim=jnp.full(B, q_lim))
        sol = jax.block_until_ready(solve.solve_batch(P._replace(weights=w), x0, S1))
        assert np.mean(np.asarray(sol.status) == solve.CONVERGED) >= 0.9
    settings = solve.SolverSettings(tol_stationarity=1e-9, mu0=5.0)
    jax.block_until_ready(solve.solve_batch(P, x0, S1, settings))
    assert solve.batch._solve_batch_jit._cache_size() == before


def _parked(rest_structure):
    """Rest-to-rest 8 m along x; a robot parked (hold) 0.1 m off the path at its middle."""
    rng = np.random.default_rng(0)
    p = random_problem(rng, n_others=1, rest=True)
    N = 3
    start = jnp.asarray([0.0, 0.0, 1.0])
    goal = jnp.asarray([8.0, 0.0, 1.0])
    others = Trajectory.hold(jnp.tile(jnp.asarray([[4.0, 0.1, 1.0]]), (10, 1)))
    z = jnp.zeros(N)
    return p._replace(p0=start, v0=z, a0=z, goal_p=goal, goal_v=z, goal_a=z, others=others)


def test_more_segments_let_a_rest_to_rest_plan_swerve():
    p = _parked(None)
    P = stack_params([p] * B)
    out = {}
    for st in (S1, S2["barrier+constraint"]):
        x0 = solve.initial_guess_batch(P, st)
        sol = jax.device_get(solve.solve_batch(P, x0, st))
        tr = index_params(sol.traj, 0)
        t = np.linspace(0, float(tr.duration), 2001)
        d = np.linalg.norm(np.asarray(tr.evaluate(t)) - np.array([4.0, 0.1, 1.0]), axis=-1)
        out[st.segments] = (int(sol.status[0]), d.min(), float(sol.eq_violation[0]))
    rho = float(p.radius + p.other_radius[0])
    # one quintic with a rest end: only T is free, the path is the straight line
    assert out[1][1] < 0.11 and out[1][0] != solve.CONVERGED
    # two segments: the plan swerves around the parked robot
    assert out[2][0] == solve.CONVERGED and out[2][1] >= rho - 0.02, out
    assert out[2][2] < 1e-8


def test_warm_start_is_finite_for_degenerate_previous_plans():
    ps, P = _s1_batch()
    p = ps[0]
    prev = Trajectory.hold(p.p0, 5, 1)
    nan = prev._replace(coeffs=prev.coeffs * jnp.nan)
    for tr in (prev, nan):
        x = _warm(tr, p)
        assert np.all(np.isfinite(x))
    sol = _one(p, _guess(p, S1))
    x = _warm(sol.traj, p)
    assert (np.all(np.isfinite(x))
            and abs(float(jnp.exp(x[-1]) - (sol.traj.duration - 0.125))) < 1e-9)


def test_solution_is_differentiable_in_the_weights():
    """solve_differentiable: d(log T*, objective*)/d(q_obs, q_lim) by implicit
    differentiation (jaxopt custom_root) equals central finite differences of solves
    run to machine precision (barrier mode: exact there, see its docstring)."""
    st = NLPStructure(collision="barrier", segments=2)
    rng = np.random.default_rng(11)
    p = random_problem(rng, n_others=4, rest=False)
    x0 = _guess(p, st)
    tight = solve.SolverSettings(tol_stationarity=0.0, max_iters=80)

    def out(q_obs, q_lim, x_start):
        w = p.weights._replace(q_obs=q_obs, q_lim=q_lim)
        s = solve.solve_differentiable(p._replace(weights=w), x_start, st, tight)
        y = jnp.stack([s.x[-1], s.objective])
        return y, (y, s)

    # one program (the solve, and the derivative by the implicit function theorem)
    # gives the derivatives and the values the finite differences take
    jac_and_value = jax.jit(jax.jacrev(out, argnums=(0, 1), has_aux=True))
    f = lambda a, b, x_start: jac_and_value(a, b, x_start)[1]
    q = (jnp.asarray(10.0), jnp.asarray(1.0))
    (y, sol) = f(*q, x0)
    assert sol.status == solve.MAX_ITERS and sol.decrement < 1e-20  # converged to rounding
    jac = jac_and_value(*q, sol.x)[0]
    for k, qk in enumerate(q):
        # central differences: truncation ~ (h / q)^2 ~ 1e-7 relative; rounding ~ the
        # solves' own error (up to ~1e-10 in log T at tol 0 after 80 iterations) / h:
        # ~3e-6 relative here (with h = 1e-4 q it reached 2e-5, at the tolerance)
        h = 3e-4 * float(qk)
        up = list(q)
        dn = list(q)
        up[k], dn[k] = qk + h, qk - h
        fd = (f(*up, sol.x)[0] - f(*dn, sol.x)[0]) / (2 * h)
        assert float(jnp.max(jnp.abs(fd))) > 1e-4  # the weight matters here
        np.testing.assert_allclose(jac[k], fd, rtol=1e-5, atol=1e-8)


def test_backtracking_goes_just_past_the_first_al_branch_crossing():
    """_next_trial: after a failed trial at step a, the constraint that was inactive at
    x (g >= lam / mu) and is active at the trial bounds the next step: with g linear
    along the step, the next trial lies kink_overshoot past its crossing; constraints
    already active at x, or still inactive at the trial, do not count; no crossing:
    a / 2; the step shrinks by at least 2 and at most 1000 per trial."""
    M = nlp.Multipliers

    def nxt(a, gx, ga, lam, mu=10.0, over=1.1):
        gx, ga, lam = (M(jnp.asarray(v, float).reshape(1, -1), jnp.ones((1, 3)))
                       for v in (gx, ga, lam))
        thr = jax.tree.map(lambda v: v / mu, lam)
        return float(solve.alsqp.next_trial(a, gx, ga, thr, over))

    # g(a) = 1 - 4 a crosses 0 at a = 0.25; the other constraint (0.5 -> 0.4) does not
    assert nxt(1.0, [1.0, 0.5], [-3.0, 0.4], [0.0, 0.0]) == pytest.approx(1.1 * 0.25)
    # the threshold is lam / mu: g(a) = 1 - 4 a crosses 0.5 (lam 5, mu 10) at 0.125
    assert nxt(0.8, [1.0], [1.0 - 4 * 0.8], [5.0]) == pytest.approx(1.1 * 0.125)
    # the earliest of two crossings; an already active constraint (-0.1) is ignored
    assert nxt(1.0, [1.0, 2.0, -0.1], [-3.0, -2.0, -5.0], [0, 0, 0]) == pytest.approx(0.275)
    assert nxt(1.0, [1.0, 0.5], [0.9, 0.4], [0.0, 0.0]) == 0.5  # no crossing: halve
    assert nxt(0.5, [1e-9], [-1.0], [0.0]) == pytest.approx(0.5e-3)  # at most / 1000
    assert nxt(1.0, [1.0], [-0.01], [0.0]) == 0.5  # at least / 2
    assert nxt(1.0, [1.0], [jnp.nan], [0.0]) == 0.5  # a non-finite trial: halve


def _load_lane(path, st: NLPStructure):
    """A saved lane (params, start, multipliers, penalty) for structure ``st``.  The
    saved lanes' structures have no hard limits: their limit multipliers (the shape of
    the limit rows when they were saved) are unused, and are zeros of ``st``'s shape."""
    assert not st.hard_limits
    z = np.load(path)
    g = lambda k: jnp.asarray(z[k])
    # (fields added after the file was made, e.g. the static rows, take their defaults)
    sub = lambda cls, pre: cls(*(g(f"{pre}.{f}") for f in cls._fields if f"{pre}.{f}" in z))
    own = {f: g(f"P.{f}") for f in nlp.NLPParams._fields
           if f not in ("others", "weights", "limits", "static") and f"P.{f}" in z}
    static = sub(StaticRows, "P.static") if "P.static.kind" in z else None
    P = nlp.NLPParams(**own, others=sub(Trajectory, "P.others"),
                        weights=sub(nlp.Weights, "P.weights"),
                        limits=sub(nlp.Limits, "P.limits"), static=static)
    m = sub(nlp.Multipliers, "m")
    rows = (len(nlp.basis(st).lim_s), 3)
    m = m._replace(limits=jnp.zeros(m.limits.shape[:-2] + rows, m.limits.dtype))
    return P, g("x0"), m, g("mu")


def test_warm_replan_with_a_large_penalty_converges():
    """A warm replan of one robot of the 100-robot bench fleet (`jaxplan bench solver`,
    all 99 others, its AL warm start carrying mu = 1e10).  With the former eigenvalue
    floor (reg = 1e-10 x the largest eigenvalue, ~1e12 here) the floor swamped the
    objective's own curvature: Newton fell to linear convergence and the lane ran to
    max_iters (MAX_ITERS after 60).  With reg = 1e-13 it converges in a few iterations."""
    from pathlib import Path

    P, x0, m, mu = _load_lane(Path(__file__).parent / "data" / "warm_lane_large_penalty.npz",
                              NLPStructure())
    assert float(mu) == 1e10 and int(P.other_mask.sum()) == 99
    sol = jax.device_get(jax.jit(lambda P, x0, m, mu: solve.solve(P, x0, NLPStructure(),
                                                                   multipliers=m, penalty=mu))(
        P, x0, m, mu))
    assert sol.status == solve.CONVERGED and sol.iterations <= 15, (sol.status, sol.iterations)
    assert sol.ineq_violation <= 1e-8 and np.isfinite(sol.objective)



def _warm_fleet10():
    """The first warm replan of `jaxplan bench solver`'s 10-robot product fleet (the
    bench's NLPs, its warm starts, multipliers and penalties), and the product's
    structure."""
    from pathlib import Path

    from jaxplan.benchmarks.solver import nlp_setup

    st = nlp_setup("product")[0]
    P, x0, m, mu = _load_lane(Path(__file__).parent / "data" / "warm_fleet10_product.npz", st)
    return st, P, x0, m, mu


def _same(a, b):
    return all(np.array_equal(np.asarray(u), np.asarray(v), equal_nan=True)
               for u, v in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True))


def test_a_warm_lanes_first_step_keeps_to_positive_curvature():
    """Two lanes of a warm 10-robot product replan.  With ``warm_convex_step`` and the
    lane marked warm, its first step is the Newton step on the positive-curvature part
    of the Hessian (indefinite at these warm starts: the slow test below): the same
    optimum (to the solver's tolerance) in fewer evaluations.  The setting without
    ``warm``, or ``warm`` without the setting, gives the solve without them bitwise.  A
    lane marked warm whose start is not finite (replaced by its fallback) is not warm."""
    st, P, x0, m, mu = _warm_fleet10()
    one = jax.jit(lambda p, x, mm, u, s, w: solve.solve(p, x, st, s, mm, u, warm=w))
    assert solve.SolverSettings().warm_convex_step  # the default (docs/SOLVER.md)
    off = solve.SolverSettings(warm_convex_step=False)
    on = off._replace(warm_convex_step=True)
    for i in range(2):
        args = (index_params(P, i), x0[i], jax.tree.map(lambda a, i=i: a[i], m), mu[i])
        ref = jax.device_get(one(*args, off, False))
        assert _same(jax.device_get(one(*args, on, False)), ref)
        assert _same(jax.device_get(one(*args, off, True)), ref)
        got = jax.device_get(one(*args, on, True))
        assert got.status == ref.status == solve.CONVERGED
        assert got.evaluations < ref.evaluations, (i, got.evaluations, ref.evaluations)
        assert abs(got.objective - ref.objective) <= 1e-9 * abs(ref.objective)
        np.testing.assert_allclose(got.x, ref.x, rtol=0, atol=1e-4)
    # a start that is not finite is replaced (by x_fallback): not a warm start
    marked = jax.jit(lambda x, w: solve.alsqp.init_lane(args[0], x, st, on, args[2], args[3],
                                                       x0[1], w)[0].warm)
    assert bool(marked(x0[0], True)) and not bool(marked(jnp.full_like(x0[0], jnp.nan), True))
    assert not bool(marked(x0[0], False))


@pytest.mark.slow  # the 10-lane pool's program of its own (~10 s)
def test_warm_convex_step_on_a_whole_warm_replan():
    """The whole warm 10-robot replan.  Its warm starts' Hessians are indefinite through
    the other robots' terms (positive definite without them), the premise of
    ``warm_convex_step``.  In the planner's pool every lane converges to the same
    optimum with the setting as without, in at least 20% fewer evaluations in all
    (82 -> 58 when measured)."""
    st, P, x0, m, mu = _warm_fleet10()
    indefinite = 0
    for i in range(10):
        p, mm = solve.types.sanitize(index_params(P, i))[0], jax.tree.map(lambda a, i=i: a[i], m)
        alone = p._replace(other_mask=jnp.zeros_like(p.other_mask))
        lo = np.linalg.eigvalsh(np.asarray(_tb_derivs(x0[i], p, st, mm, mu[i])[2]))[0]
        lo_own = np.linalg.eigvalsh(np.asarray(_tb_derivs(x0[i], alone, st, mm, mu[i])[2]))[0]
        indefinite += int(lo < 0)
        assert lo_own > 0, i
    assert indefinite >= 9
    fn = jax.jit(lambda s: solve.solve_lanes(P, x0, st, s, m, mu, x_fallback=x0,
                                             pool=solve.default_pool(10, n_others=9),
                                             warm=jnp.ones(10, bool)))
    ref = jax.device_get(fn(solve.SolverSettings(warm_convex_step=False)))
    got = jax.device_get(fn(solve.SolverSettings(warm_convex_step=True)))
    assert np.all(ref.status == solve.CONVERGED) and np.all(got.status == solve.CONVERGED)
    assert got.evaluations.sum() <= 0.8 * ref.evaluations.sum(), (got.evaluations,
                                                                   ref.evaluations)
    np.testing.assert_allclose(got.objective, ref.objective, rtol=1e-9)


def test_failed_line_search_is_its_own_status_and_stops_the_lane():
    """A line search that finds no Armijo step, on an L_A the multiplier update leaves
    unchanged, would be repeated from the same point along the same direction: the lane
    stops at once, LINE_SEARCH_FAILED, at its last accepted point.  Forced here by an
    Armijo constant of 1 (a Newton step on a convex model decreases L_A by less than its
    first-order prediction): lanes that start feasible, where the update leaves the
    zero multipliers and the penalty as they are, stop so after their first iteration,
    at x0; a lane that starts infeasible (or whose rare accepted step was infeasible)
    gets new multipliers at each failure, so it goes on and, no longer moving, is found
    INFEASIBLE.  No lane repeats failed searches until the budget runs out.  (The
    module's 50-lane batch: the same compiled program as the other tests.)"""
    ps, P = _s1_batch()
    x0 = solve.initial_guess_batch(P, S1)
    never = solve.SolverSettings(armijo=1.0, max_backtracks=3, max_iters=40)
    sol = jax.device_get(solve.solve_batch(P, x0, S1, never, pool=B))
    g0, obj0 = jax.device_get(_at_x0(x0, P))
    finite = np.arange(B) != 3  # the NaN lane of _s1_batch
    feasible = finite & (g0 == 0.0)
    assert 10 <= feasible.sum() < finite.sum()  # both kinds of lane are there
    lsf = sol.status == solve.LINE_SEARCH_FAILED
    assert lsf[feasible].mean() >= 0.9, sol.status
    assert np.all(np.isin(sol.status[finite], (solve.LINE_SEARCH_FAILED, solve.INFEASIBLE)))
    assert np.all(sol.iterations[finite] < 40)  # none spent the budget
    first = lsf & (sol.iterations == 1)
    assert first[feasible].mean() >= 0.9
    np.testing.assert_array_equal(sol.x[first], np.asarray(x0)[first])  # no step taken
    np.testing.assert_allclose(sol.objective[first], obj0[first], rtol=1e-12)
    assert solve.STATUS_NAMES[solve.LINE_SEARCH_FAILED] == "line-search-failed"


@jax.jit
def _at_x0(x0, P):
    """The largest constraint violation and the objective of each lane at x0."""
    return jax.vmap(lambda x, p: (max_violation(nlp.constraints(x, p, S1)),
                                  nlp.objective(x, p, S1)))(x0, P)


def _stuck_batch():
    """The module's batch with two random NLPs whose solves get stuck infeasible in
    lanes 0 and 1, lane 2 in place of the NaN lane 3: the same shapes (B lanes), the same
    compiled programs as the module's other tests."""
    ps, _ = _s1_batch()
    rng = np.random.default_rng(7)
    stuck = [random_problem(rng, n_others=int(rng.integers(1, 10)), rest=bool(i % 3 == 0))
             for i in range(7)]
    P = stack_params([stuck[0], stuck[6]] + ps[2:3] * 2 + ps[4:])
    return P, solve.initial_guess_batch(P, S1)


def test_lanes_stuck_infeasible_are_stopped_early():
    """Two random NLPs whose solves get stuck at a violation that no penalty moves (the
    violation stays within 10% from a penalty of 1e3 up to 1e10, e.g. 0.177 m^2): the
    lanes stop INFEASIBLE after ``infeasible_updates`` multiplier updates in a row at a
    penalty of at least ``infeasible_penalty`` that each left the violation above 0.9 x
    the previous one's, long before a budget of 80 iterations; with the test off
    (infeasible_updates huge) they spend the budget and end hardly less violating.  The
    lanes that converge are not touched (:func:`test_stuck_lanes_against_the_test_off`
    compares with the test off, lane by lane)."""
    P, x0 = _stuck_batch()
    s = solve.SolverSettings(max_iters=80)
    sol = jax.device_get(solve.solve_batch(P, x0, S1, s, pool=B))
    for k in (0, 1):
        assert sol.status[k] == solve.INFEASIBLE and sol.iterations[k] <= 25, (
            k, sol.status[k], sol.iterations[k])
        assert sol.ineq_violation[k] > 0.01 and np.isfinite(sol.objective[k])
    assert np.sum(sol.status == solve.CONVERGED) >= 40
    assert np.all(np.isin(sol.status, (solve.CONVERGED, solve.INFEASIBLE)))


@pytest.mark.slow
def test_stuck_lanes_against_the_test_off():
    """The batch of :func:`test_lanes_stuck_infeasible_are_stopped_early` with the early
    test off (infeasible_updates huge): the stuck lanes spend the budget of 80 and end
    hardly less violating; every lane that converges converges as with the test on, in
    the same iterations."""
    P, x0 = _stuck_batch()
    s = solve.SolverSettings(max_iters=80)
    sol = jax.device_get(solve.solve_batch(P, x0, S1, s, pool=B))
    full = jax.device_get(solve.solve_batch(P, x0, S1, s._replace(infeasible_updates=10**6),
                                            pool=B))
    for k in (0, 1):
        assert sol.status[k] == solve.INFEASIBLE and sol.iterations[k] <= 25, (
            k, sol.status[k], sol.iterations[k])
        assert full.status[k] == solve.INFEASIBLE and full.iterations[k] == 80
        assert full.ineq_violation[k] >= 0.9 * sol.ineq_violation[k]
    # every lane that converges with the test off converges as before; the others (two
    # more of the batch are stuck so) still end infeasible, sooner
    conv = full.status == solve.CONVERGED
    assert conv.sum() >= 40
    np.testing.assert_array_equal(sol.status[conv], full.status[conv])
    np.testing.assert_array_equal(sol.iterations[conv], full.iterations[conv])
    assert np.all(sol.status[~conv] == solve.INFEASIBLE)
    assert np.all(sol.iterations[~conv] <= full.iterations[~conv])


@pytest.mark.slow
def test_casadi_ipopt_reference_is_the_same_nlp_and_reaches_the_same_optimum():
    """jaxplan.reference_casadi builds the NLP in CasADi SX (from the same objective and
    constraints, term for term): its objective and constraints equal jaxplan's at
    random points near the guesses to 1e-10 relative; IPOPT with CasADi's own
    derivatives reaches jaxplan's optimum from the same starts (relative objective gap
    <= 1e-6 where both converge, no larger violation).  Nine others, no static rows;
    tests/test_world.py has the fast one with static rows."""
    pytest.importorskip("casadi")
    from jaxplan import reference_casadi as rc

    mode = "barrier+constraint"
    ps, P, x0, sol = _random_results(mode)
    st = S2[mode]
    F = rc.casadi_functions(ps[0], st)
    obj = jax.jit(nlp.objective, static_argnums=2)
    con = jax.jit(lambda x, p: jnp.concatenate(
        [jnp.ravel(a) for a in jax.tree.leaves(nlp.constraints(x, p, st))]))
    rng = np.random.default_rng(3)
    for i in range(4):
        x = np.asarray(x0[i]) + rng.normal(size=st.n_x) * 0.3
        f, g = F(x, rc.flat_params(ps[i]))
        fj, gj = float(obj(jnp.asarray(x), ps[i], st)), np.asarray(con(jnp.asarray(x), ps[i]))
        assert abs(float(f) - fj) <= 1e-10 * abs(fj), (float(f), fj)
        np.testing.assert_allclose(np.asarray(g).ravel(), gj, rtol=1e-10, atol=1e-10 * np.max(
            np.abs(gj)))
    both = 0
    for i in range(4):
        r = rc.solve_ipopt(ps[i], np.asarray(x0[i]), st)
        if r.converged and sol.status[i] == solve.CONVERGED:
            both += 1
            assert abs(sol.objective[i] - r.objective) <= 1e-6 * abs(r.objective), (
                i, sol.objective[i], r.objective)
            assert sol.ineq_violation[i] <= max(r.ineq_violation, 1e-8)
    assert both >= 3
