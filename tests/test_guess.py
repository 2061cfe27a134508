"""Tests of jaxplan.solve.initial_guess: the horizon and shape grid, the rest end's
shape and the swerve stage.  Split from test_solver.py so that the two test workers
share the solver's tests evenly."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplan import nlp, solve
from jaxplan.nlp import NLPStructure
from jaxplan.testing import index_params, random_problem, stack_params


@pytest.mark.parametrize("segments", [1, 3])
def test_rest_shape_is_the_rest_ends_path_in_the_free_parametrization(segments):
    """solve.guess.rest_shape: z = G e(h) in the free-end parametrization gives exactly the
    rest end's minimum-jerk path (the rest kind at z = 0): the same coefficients, and
    the goal's end velocity and acceleration at T."""
    st = NLPStructure(segments=segments)
    p = random_problem(np.random.default_rng(3), n_others=2, rest=False)
    p = p._replace(goal_v=jnp.asarray([0.3, -0.2, 0.1]), goal_a=jnp.asarray([0.0, 0.4, -0.1]))
    tau = jnp.log(4.0)
    e = nlp.boundary_vector(p, jnp.exp(tau) / segments)
    z = (jnp.asarray(solve.guess.rest_shape(st)) @ e).T
    c_free, _ = nlp.coefficients(nlp.pack(z, tau), p, st)
    c_rest, _ = nlp.coefficients(nlp.pack(jnp.zeros_like(z), tau), p._replace(rest=True), st)
    np.testing.assert_allclose(c_free, c_rest, rtol=0, atol=1e-10)
    tr = nlp.to_trajectory(nlp.pack(z, tau), p, st)
    np.testing.assert_allclose(tr.state_at(jnp.asarray(4.0 - 1e-12))[1], p.goal_v, atol=1e-8)
    np.testing.assert_allclose(tr.state_at(jnp.asarray(4.0 - 1e-12))[2], p.goal_a, atol=1e-8)


def _across_np(p0, goal):
    """Right and up across the path p0 -> goal, computed here in NumPy (3-D)."""
    u = np.asarray(goal) - np.asarray(p0)
    u = u / np.linalg.norm(u)
    up = np.array([0.0, 0.0, 1.0]) - u[2] * u
    if np.linalg.norm(up) <= 0.1:
        up = np.array([1.0, 0.0, 0.0]) - u[0] * u
    up = up / np.linalg.norm(up)
    return np.cross(u, up), up


@pytest.mark.parametrize("segments", [pytest.param(1, marks=pytest.mark.slow), 2])
def test_initial_guess_swerve_is_the_best_of_its_candidates(segments):
    """The swerve stage: the guess is the grid's x or x plus 1.5 rho_max along the
    smoothest shape mode to the right, left, up or down, whichever has the least merit
    (zero multipliers, penalty mu0), by a brute force over the same candidates with
    nlp.merit; on these crossing NLPs some lanes swerve, and a lane whose others are
    all masked keeps the grid's x."""
    st = NLPStructure(segments=segments)
    rng = np.random.default_rng(5)
    ps = [random_problem(rng, n_others=int(rng.integers(2, 11)), rest=bool(i % 2))
          for i in range(24)]
    ps[-1] = ps[-1]._replace(other_mask=jnp.zeros_like(ps[-1].other_mask))
    P = stack_params(ps)
    grid = np.asarray(jax.jit(jax.vmap(lambda q: solve.initial_guess(q, st, swerve=False)))(P))
    got = np.asarray(solve.initial_guess_batch(P, st))
    # a lane's candidates in one call, on the batch's padded lane (one program for all)
    merit = jax.jit(jax.vmap(lambda x, p: nlp.merit(x, p, st, nlp.kind_constants(p.rest, st),
                                                    solve.zero_multipliers(p, st), 10.0),
                             in_axes=(0, None)))
    swerved = 0
    for i, p in enumerate(ps):
        x = grid[i]
        rho = float(p.radius) + max([float(r) for r, m in zip(p.other_radius, p.other_mask,
                                                              strict=True) if m], default=0.0)
        right, up = _across_np(p.p0, p.goal_p)
        cands = [x]
        for w in (right, up):
            for sg in (1.0, -1.0):
                z = x[:-1].reshape(3, st.nz).copy()
                z[:, 0] += sg * 1.5 * rho * w
                cands.append(np.concatenate([z.ravel(), x[-1:]]))
        vals = np.asarray(merit(jnp.asarray(np.stack(cands)), index_params(P, i)))
        k = int(np.argmin(vals))
        np.testing.assert_allclose(got[i], cands[k], rtol=1e-12, atol=1e-12)
        swerved += k > 0
        if i == len(ps) - 1:
            assert k == 0 and np.array_equal(got[i], x)
    assert swerved >= 4, swerved


def test_initial_guess_head_on_pair_passes_on_the_right():
    """Two robots head-on, each predicting the other straight (a tie between right,
    left, up and down): both guesses swerve to their own right, so that the two guessed
    plans pass each other (the straight ones collide head-on)."""
    from jaxplan.testing import fleet_params

    pos = np.array([[-3.0, 0.0, 1.5], [3.0, 0.0, 1.5]])
    P = fleet_params(pos, np.zeros_like(pos), np.zeros_like(pos), pos[::-1].copy())
    st = NLPStructure()
    x0 = np.asarray(solve.initial_guess_batch(P, st))
    grid = np.asarray(jax.jit(jax.vmap(lambda q: solve.initial_guess(q, st, swerve=False)))(P))
    dz = (x0 - grid)[:, :-1].reshape(2, 3, st.nz)[:, :, 0]  # (robot, axis)
    assert dz[0, 1] < -0.5 and dz[1, 1] > 0.5  # robot 0 flies +x: right is -y; 1: +y
    assert np.allclose(dz[:, [0, 2]], 0.0)

    @jax.jit  # one program, not op by op
    def min_distance(x):
        ts = jnp.linspace(0.0, jnp.exp(jnp.max(x[:, -1])), 400)[:, None]
        p = [nlp.to_trajectory(x[i], index_params(P, i), st).evaluate(ts) for i in range(2)]
        return jnp.min(jnp.linalg.norm(p[0] - p[1], axis=-1))

    rho = 0.5  # fleet_params: radius 0.25 each
    assert float(min_distance(grid)) < 0.1 < rho < 2.0 * rho < float(min_distance(x0))


def test_initial_guess_is_the_best_candidate_of_the_grid():
    """initial_guess minimizes the collision-free objective over the T grid and, for a
    free end, the shapes alpha z_rest(T) (a brute-force search over the same candidates
    agrees); a rest end keeps z = 0; an antipodal free-end fleet starts from the
    halfway shape with a shorter T than the free path's (the reason for the shapes)."""
    from jaxplan.predict import predict_arrays
    from jaxplan.testing import antipodal, fleet_params

    st = NLPStructure()
    free = NLPStructure(collision="none")
    G = solve.guess.rest_shape(st)
    pos, goals = antipodal(10, 5.0, np.random.default_rng(0))
    # every candidate of a robot in one call: (shape, T) pairs, the shapes outer
    objective = jax.jit(jax.vmap(nlp.objective, in_axes=(0, None, None)), static_argnums=2)
    boundary = jax.jit(jax.vmap(nlp.boundary_vector, in_axes=(None, 0)))
    guesses = jax.jit(jax.vmap(lambda q: solve.initial_guess(q, st, swerve=False)))  # one program
    predict = jax.jit(predict_arrays)  # (op by op, each call would compile its loops again)
    for rest in (False, True):
        P = fleet_params(pos, np.zeros_like(pos), np.zeros_like(pos), goals, rest=rest)
        x0 = np.asarray(guesses(P))
        for i in range(3):
            p = index_params(P, i)
            pred = predict(p.p0, p.v0, p.a0, p.goal_p, p.goal_v, p.goal_a, p.rest, 1.0)
            Ts = float(pred.duration) * solve.guess.GUESS_T_FACTORS
            e = np.asarray(boundary(p, jnp.asarray(Ts)))  # (K, ...)
            cands, xs = [], []
            for a in solve.guess.GUESS_SHAPES:
                for k, T in enumerate(Ts):
                    z = 0.0 if rest else a * (G @ e[k]).T
                    xs.append(np.concatenate([np.broadcast_to(z, (3, st.nz)).ravel(),
                                              [np.log(T)]]))
                    cands.append((a, T))
            # the candidates and, last, the guess (one call: one program)
            vals = np.asarray(objective(jnp.asarray(np.stack(xs + [x0[i]])), p, free))
            got, vals = float(vals[-1]), vals[:-1]
            best, arg = float(vals[np.argmin(vals)]), cands[int(np.argmin(vals))]
            np.testing.assert_allclose(got, best, rtol=1e-12)
            np.testing.assert_allclose(np.exp(x0[i, -1]), arg[1], rtol=1e-12)
            if rest:
                assert np.all(x0[i, :-1] == 0.0)
            else:
                assert arg[0] == 0.5  # the halfway shape wins here
                v0 = vals[:len(Ts)]  # the shape 0 (the free path) at every T
                assert solve.guess.GUESS_SHAPES[0] == 0.0
                assert arg[1] < Ts[int(np.argmin(v0))]  # shorter than the free path's T
    # the bisection of the grid finds its minimum: random NLPs (moving starts, rest and
    # free ends, two segments), all candidates evaluated at once here
    rng = np.random.default_rng(11)
    P = stack_params([random_problem(rng, n_others=2, rest=bool(i % 2)) for i in range(40)])
    seg = 2
    st = NLPStructure(segments=seg)
    fr = NLPStructure(collision="none", segments=seg)
    G = jnp.asarray(solve.guess.rest_shape(st))

    def full_and_got(p, x):
        pred = predict_arrays(p.p0, p.v0, p.a0, p.goal_p, p.goal_v, p.goal_a, p.rest, 1.0)
        Ts = jnp.maximum(pred.duration * jnp.asarray(solve.guess.GUESS_T_FACTORS), p.t_min)

        def val(a, T):
            z = a * jnp.where(p.rest, 0.0, 1.0) * (G @ nlp.boundary_vector(p, T / seg)).T
            return nlp.objective(nlp.pack(z, jnp.log(T)), p, fr)
        want = jnp.min(jax.vmap(lambda a: jax.vmap(lambda T: val(a, T))(Ts))(
            jnp.asarray(solve.guess.GUESS_SHAPES)))
        return want, nlp.objective(x, p, fr)

    x0 = jax.jit(jax.vmap(lambda q: solve.initial_guess(q, st, swerve=False)))(P)
    want, got = jax.device_get(jax.jit(jax.vmap(full_and_got))(P, x0))
    np.testing.assert_allclose(got, want, rtol=1e-12)
