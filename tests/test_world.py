"""The world (jaxplan/world.py): signed distances against dense surface samples, the NLP's
static rows against autodiff, config errors, and a robot going round an obstacle."""

import tomllib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxplan  # noqa: F401  (float64)
from jaxplan import nlp, planner, solve
from jaxplan import run_setup as rs
from jaxplan.config import ConfigError, build_scenario, config_to_toml, parse_config
from jaxplan.nlp import Multipliers, NLPParams, NLPStructure
from jaxplan.nlp.terms import STATIC_PRIORITY
from jaxplan.testing import limits, random_obstacles, random_problem, weights
from jaxplan.trajectory import Trajectory
from jaxplan.world import (
    ALL_KINDS,
    BOX,
    CYLINDER,
    MOTION_KEYS,
    PLANE,
    SPHERE,
    World,
    centres_at,
    obstacle_arrays,
    rows_as_jax,
    rows_at,
    signed_distance,
    signed_distance_jet,
    static_rows,
    world_arrays,
    world_from_arrays,
)


# ---------------------------------------------------------------------- distances
def _surface_points(kind, c, half, r, n=200_000, seed=0):
    """Dense uniform-ish samples of an obstacle's surface (the reference)."""
    rng = np.random.default_rng(seed)
    N = len(c)
    if kind == SPHERE or (kind == CYLINDER and N == 2):
        u = rng.normal(size=(n, N))
        return c + r * u / np.linalg.norm(u, axis=1, keepdims=True)
    if kind == BOX:
        p = rng.uniform(-1, 1, size=(n, N)) * half
        ax = rng.integers(0, N, n)
        p[np.arange(n), ax] = np.sign(rng.uniform(-1, 1, n)) * half[ax]
        return c + p
    # cylinder: side and caps by area
    H = half[2]
    side, cap = 2 * np.pi * r * 2 * H, np.pi * r * r
    k = rng.uniform(size=n) * (side + 2 * cap)
    ang = rng.uniform(0, 2 * np.pi, n)
    rad = np.where(k < side, r, r * np.sqrt(rng.uniform(size=n)))
    z = np.where(k < side, rng.uniform(-H, H, n), np.where(k < side + cap, H, -H))
    return c + np.stack([rad * np.cos(ang), rad * np.sin(ang), z], 1)


def _inside(kind, c, half, r, p):
    d = p - c
    if kind == SPHERE or (kind == CYLINDER and len(c) == 2):
        return np.linalg.norm(d, axis=-1) < r
    if kind == BOX:
        return np.all(np.abs(d) < half, axis=-1)
    return (np.linalg.norm(d[:, :2], axis=-1) < r) & (np.abs(d[:, 2]) < half[2])


@pytest.mark.parametrize("N", [2, 3])
@pytest.mark.parametrize("kind", [SPHERE, BOX, CYLINDER])
def test_signed_distance_matches_dense_surface_samples(kind, N):
    rng = np.random.default_rng(kind + 10 * N)
    c = rng.normal(size=N)
    half = rng.uniform(0.3, 1.0, N)
    r = rng.uniform(0.3, 1.0)
    surf = _surface_points(kind, c, half, r)
    p = c + rng.normal(size=(200, N)) * 1.2
    sd = signed_distance(np.array([kind]), c[None], half[None], np.array([r]), p)[:, 0]
    ref = np.concatenate([np.min(np.linalg.norm(q[:, None] - surf[None], axis=-1), axis=1)
                          for q in np.split(p, 10)])
    inside = _inside(kind, c, half, r, p)
    assert 0 < inside.sum() < len(p)
    # a sampled surface only ever lies farther than the nearest surface point: outside,
    # sd <= the sampled distance; inside, -sd <= it; and within the sampling's spacing
    # (~0.02 m on these bodies) of it; the smoothing moves sd down by at most 1e-6 m
    np.testing.assert_array_less(sd[~inside], ref[~inside] + 1e-12)
    np.testing.assert_array_less(-sd[inside], ref[inside] + 1e-6)
    np.testing.assert_allclose(np.abs(sd), ref, atol=0.03)


@pytest.mark.parametrize("N", [2, 3])
def test_signed_distance_jet_matches_autodiff(N):
    """The closed-form gradient and Hessian of every kind (obstacles and a tilted
    plane) equal JAX's autodiff of signed_distance at random points inside and outside;
    none is NaN under the test suite's compiler flags (the max reduction's derivative
    was 0/0 there)."""
    rng = np.random.default_rng(7 + N)
    kind = np.array([SPHERE, BOX, CYLINDER, 3, BOX])
    center = rng.normal(size=(5, N))
    half = rng.uniform(0.3, 1.0, (5, N))
    n = rng.normal(size=N)
    half[3] = n / np.linalg.norm(n)
    radius = rng.uniform(0.3, 1.0, 5)
    p = center[rng.integers(0, 5, 64)] + rng.normal(size=(64, N)) * 0.8
    f = lambda q: signed_distance(kind, center, half, radius, q, xp=jnp)
    ref = jax.jit(jax.vmap(lambda q: (f(q), jax.jacfwd(f)(q), jax.hessian(f)(q))))(p)
    sd, g, H = signed_distance_jet(kind, center, half, radius, p)
    inside = sd < 0
    assert inside[:, [0, 1, 2, 4]].any() and (~inside).any()
    for a, b in zip((sd, g, H), ref, strict=True):
        assert np.all(np.isfinite(b))
        np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("kinds", [(PLANE,), (BOX, PLANE), (SPHERE, CYLINDER), ALL_KINDS])
def test_signed_distance_jet_forms_only_the_given_kinds(kinds):
    """signed_distance_jet(kinds=...) gives the full jet's values at the rows of those
    kinds and NaN at a row of another (never a wrong distance); NumPy exactly, jitted to
    rounding.  Bad ``kinds`` are refused."""
    rng = np.random.default_rng(11)
    kind = np.array([SPHERE, BOX, CYLINDER, PLANE, BOX, PLANE])
    center = rng.normal(size=(6, 3))
    half = rng.uniform(0.3, 1.0, (6, 3))
    half[[3, 5]] = np.eye(3)[[2, 0]]
    radius = rng.uniform(0.3, 1.0, 6)
    p = rng.normal(size=(40, 3)) * 1.5
    full = signed_distance_jet(kind, center, half, radius, p)
    some = signed_distance_jet(kind, center, half, radius, p, kinds=kinds)
    on = np.isin(kind, kinds)
    jit = jax.jit(lambda q, ks: signed_distance_jet(kind, center, half, radius, q, xp=jnp,
                                                    kinds=ks), static_argnums=1)
    for a, b, c in zip(full, some, jit(p, kinds), strict=True):
        np.testing.assert_array_equal(b[:, on], a[:, on])
        np.testing.assert_allclose(np.asarray(c)[:, on], a[:, on], rtol=1e-14, atol=1e-14)
        assert np.all(np.isnan(b[:, ~on])) and np.all(np.isnan(np.asarray(c)[:, ~on]))
    for bad in ((), (PLANE, 7)):
        with pytest.raises(ValueError, match="kinds"):
            signed_distance_jet(kind, center, half, radius, p, kinds=bad)


def test_static_kinds_of_structures():
    """A run's NLP forms its world's kinds of static rows (PLANE: the faces and padding);
    the default 3-D world (the ground) PLANE alone; a world without static rows and a
    sweep's grid every kind; NLPStructure refuses kinds it does not know."""
    from jaxplan.sweep import structure_for

    kinds = lambda text: rs.structures(_cfg(text)).planner.nlp.static_kinds
    assert kinds(SELECT.format(K=0)) == ALL_KINDS  # all three obstacle kinds and faces
    assert kinds(BASE) == (CYLINDER, PLANE)
    assert kinds(BASE.split("[[obstacles]]")[0]) == (PLANE,)
    ground = rs.structures(_cfg(BASE.split("[workspace]")[0])).planner.nlp
    assert ground.n_static == 1 and ground.static_kinds == (PLANE,)
    assert structure_for(_cfg(BASE), 3).planner.nlp.static_kinds == ALL_KINDS
    for bad in ((), (PLANE, BOX), (0, 9)):
        with pytest.raises(ValueError, match="static_kinds"):
            NLPStructure(n_static=2, static_kinds=bad)


def test_merit_derivs_with_the_worlds_kinds_equal_every_kinds():
    """The NLP's derivatives with NLPStructure.static_kinds = the world's kinds equal
    those that form every kind (to rounding), and a structure that lacks a row's kind
    gives a NaN value (the solver's NON_FINITE), not a wrong one."""
    rng = np.random.default_rng(4)
    p = random_problem(rng, n_others=3)
    p0, pf = np.asarray(p.p0), np.asarray(p.goal_p)
    mid = (p0 + pf) / 2
    w = World(np.array([-np.inf, -np.inf, min(p0[2], pf[2]) - 0.5]), np.full(3, np.inf),
              *obstacle_arrays([dict(kind="box", center=mid, half_extents=[0.3, 0.3, 0.4])], 3))
    rows = rows_as_jax(static_rows(w, 3))  # box, ground, padding
    p = p._replace(static=rows)
    st = NLPStructure(segments=2, n_coast_samples=4, n_static=3)
    mult = Multipliers(jnp.asarray(rng.uniform(0, 5, (st.n_col, p.other_mask.shape[-1]))),
                       jnp.asarray(rng.uniform(0, 5, (len(nlp.basis(st).lim_s), 3))),
                       jnp.asarray(rng.uniform(0, 5, (st.n_col, 3))))
    kc = nlp.kind_constants(p.rest, st)
    x = jnp.asarray(np.append(rng.normal(size=st.n_x - 1) * 0.05, np.log(4.0)))
    derivs = jax.jit(lambda s: nlp.merit_derivs(x, p, s, kc, mult, 30.0, with_g=True),
                     static_argnums=0)
    ref = derivs(st)
    got = derivs(NLPStructure(segments=2, n_coast_samples=4, n_static=3,
                              static_kinds=(BOX, PLANE)))
    for a, b in zip(jax.tree.leaves(got), jax.tree.leaves(ref), strict=True):
        assert np.all(np.isfinite(a))
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12 * float(np.max(np.abs(b))))
    lacking = derivs(NLPStructure(segments=2, n_coast_samples=4, n_static=3,
                                  static_kinds=(PLANE,)))
    assert np.isnan(float(lacking[0]))


def test_workspace_faces_are_half_spaces():
    w = World(np.array([-1.0, -np.inf, 0.0]), np.array([np.inf, 2.0, 3.0]),
              np.zeros(0, np.int32), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))
    rows = static_rows(w, 6)
    assert rows.mask.tolist() == [True] * 4 + [False] * 2
    p = np.array([[0.5, 1.0, 1.0], [-2.0, 5.0, 4.0]])
    sd = signed_distance(rows.kind, rows.center, rows.half, rows.radius, p)[:, :4]
    # faces: x >= -1, z >= 0, y <= 2, z <= 3
    np.testing.assert_allclose(sd, [[1.5, 1.0, 1.0, 2.0], [-1.0, 4.0, -3.0, -1.0]])


# ---------------------------------------------------------------------- the NLP's rows
def _world_near(p, rng, rows=10):
    p0, pf = np.asarray(p.p0), np.asarray(p.goal_p)
    obs = []
    for kind in ("sphere", "box", "cylinder", "box", "sphere"):
        c = p0 + (pf - p0) * rng.uniform(0.2, 0.8) + rng.normal(size=3) * 0.4
        if kind == "sphere":
            obs.append(dict(kind=kind, center=c, radius=rng.uniform(0.2, 0.6)))
        elif kind == "box":
            obs.append(dict(kind=kind, center=c, half_extents=rng.uniform(0.1, 0.5, 3)))
        else:
            obs.append(dict(kind=kind, center=c, radius=rng.uniform(0.2, 0.5),
                            half_height=rng.uniform(0.3, 1.0)))
    w = World(np.array([-10.0, -10.0, min(p0[2], pf[2]) - 0.5]), np.array([np.inf, 10.0, np.inf]),
              *obstacle_arrays(obs, 3))
    return rows_as_jax(static_rows(w, rows))


def _random_point(rng, st, p, n_others: int, n_static: int, T: float):
    """Random AL multipliers (collision 0-50, limits 0-5, static 0-50), the end-kind
    constants and a point near the zero shape at horizon T (s) for the NLP p."""
    b = nlp.basis(st)
    mult = Multipliers(jnp.asarray(rng.uniform(0, 50, (st.n_col, n_others))),
                       jnp.asarray(rng.uniform(0, 5, (len(b.lim_s), 3))),
                       jnp.asarray(rng.uniform(0, 50, (st.n_col, n_static))))
    kc = nlp.kind_constants(p.rest, st)
    x = np.zeros(st.n_x)
    x[:-1] = rng.normal(size=st.n_x - 1) * 0.05
    x[-1] = np.log(T)
    return mult, kc, jnp.asarray(x)


@pytest.mark.parametrize("st,rest", [
    (NLPStructure(collision="barrier+constraint", segments=2, n_coast_samples=6, n_static=10),
     False),
    pytest.param(NLPStructure(collision="paper", segments=2, n_static=10), True,
                 marks=pytest.mark.slow),  # the paper's term: `make test-slow`
])
def test_static_rows_structured_derivatives_match_autodiff(st, rest):
    """Obstacles near the straight line, random multipliers: value, gradient, Hessian
    and the constraints of merit_derivs equal autodiff of the reference terms, some of
    the static constraints violated (their AL branch reached)."""
    rng = np.random.default_rng(1)
    p = random_problem(rng, n_others=6, rest=rest, w=weights(q_lim=0.5))
    p = p._replace(static=_world_near(p, rng))
    mult, kc, x = _random_point(rng, st, p, 10, 10, 5.0)
    f = lambda xx: nlp.merit(xx, p, st, kc, mult, 30.0)

    @jax.jit
    def both(xx):
        return (nlp.merit_derivs(xx, p, st, kc, mult, 30.0, with_g=True),
                (f(xx), jax.grad(f)(xx), jax.hessian(f)(xx)), nlp.constraints(xx, p, st))

    (v, g, H, gg), (vr, gr, Hr), c = both(x)
    assert np.all(np.isfinite(Hr)) and np.all(np.isfinite(H))
    np.testing.assert_allclose(v, vr, rtol=1e-12)
    np.testing.assert_allclose(g, gr, rtol=1e-9, atol=1e-9 * np.max(np.abs(g)))
    np.testing.assert_allclose(H, Hr, rtol=1e-8, atol=1e-9 * np.max(np.abs(Hr)))
    np.testing.assert_allclose(gg.static, c.static, rtol=1e-12, atol=1e-12)
    if st.collision_constraints:
        assert int(jnp.sum(c.static < 0)) > 0  # the straight line goes through obstacles
        # the constraint is 4 P r (sd - r) at the sampled positions (P: STATIC_PRIORITY)
        traj = nlp.to_trajectory(x, p, st)
        s, off, _, _ = nlp.collision_rows(p, st)
        T = traj.duration
        pos = np.asarray(traj.evaluate(T * s[:st.n_collision_samples]))
        rows = p.static
        sd = signed_distance(*(np.asarray(a) for a in rows[:4]), pos)
        r = float(p.radius)
        # a row the start already lacks clearance to allows that much (static_allowance)
        sd0 = signed_distance(*(np.asarray(a) for a in rows[:4]), np.asarray(p.p0)[None])[0]
        scale = 4 * STATIC_PRIORITY * r
        want = np.where(np.asarray(rows.mask), scale * (sd - r - np.minimum(sd0 - r, 0.0)), 1.0)
        np.testing.assert_allclose(np.asarray(c.static)[:st.n_collision_samples], want,
                                   atol=1e-9)


def test_moving_rows_structured_derivatives_match_autodiff():
    """Moving rows (a sphere flying on at its velocity, a cylinder along its known path
    with knots inside the horizon, a static box) seen at t = 1.2 s: merit_derivs
    (value, gradient, Hessian, constraints) equal autodiff of the reference terms, and
    merit_shapes equals merit; the constraints are those of each sample against the
    row where its motion puts it then."""
    rng = np.random.default_rng(4)
    st = NLPStructure(collision="barrier+constraint", segments=2, n_coast_samples=4,
                      n_static=6, n_collision_samples=16, n_quadrature=4)
    p = random_problem(rng, n_others=2, mo=2, w=weights(q_lim=0.5))
    p0, pf = np.asarray(p.p0), np.asarray(p.goal_p)
    mid = (p0 + pf) / 2
    d = (pf - p0) / np.linalg.norm(pf - p0)
    side = np.cross(d, [0.0, 0.0, 1.0])
    obs = [dict(kind="sphere", center=list(mid + 1.5 * side), radius=0.4,
                velocity=list(-0.8 * side)),
           dict(kind="cylinder", radius=0.3, half_height=1.0, known_path=True,
                path=[{"t": 1.0, "p": list(p0 + 0.3 * (pf - p0) - side)},
                      {"t": 2.5, "p": list(p0 + 0.3 * (pf - p0) + side)},
                      {"t": 4.0, "p": list(p0 + 0.7 * (pf - p0))}]),
           dict(kind="box", center=list(mid + [0.0, 0.0, 1.5]), half_extents=[0.3, 0.3, 0.3])]
    w = World(np.array([-np.inf, -np.inf, min(p0[2], pf[2]) - 0.8]), np.full(3, np.inf),
              np.zeros(0, np.int32), np.zeros((0, 3)), np.zeros((0, 3)),
              np.zeros(0)).with_obstacles(obs)
    rows = rows_at(rows_as_jax(static_rows(w, 6)), 1.2)
    p = p._replace(static=rows)
    mult, kc, x = _random_point(rng, st, p, p.other_mask.shape[-1], 6, 3.0)
    f = lambda xx: nlp.merit(xx, p, st, kc, mult, 30.0)
    z, tau = nlp.unpack(x, st)
    zs = jnp.stack([z, 1.1 * z, -z])
    # (the reference's jax.hessian would cost ~8 s of compile: the structured Hessian is
    # checked against central differences of the structured gradient, which is checked
    # against autodiff)
    derivs = jax.jit(lambda xx: nlp.merit_derivs(xx, p, st, kc, mult, 30.0, with_g=True))
    ref = jax.jit(lambda xx: (f(xx), jax.grad(f)(xx), nlp.constraints(xx, p, st)))
    shapes = jax.jit(lambda: nlp.merit_shapes(zs, tau, p, st, kc, mult, 30.0))()
    v, g, H, gg = derivs(x)
    vr, gr, c = ref(x)
    assert np.all(np.isfinite(H))
    np.testing.assert_allclose(v, vr, rtol=1e-12)
    np.testing.assert_allclose(g, gr, rtol=1e-9, atol=1e-9 * np.max(np.abs(g)))
    np.testing.assert_allclose(gg.static, c.static, rtol=1e-12, atol=1e-12)
    h = 1e-6
    Hfd = np.stack([(derivs(x.at[i].add(h))[1] - derivs(x.at[i].add(-h))[1]) / (2 * h)
                    for i in range(st.n_x)], axis=1)
    np.testing.assert_allclose(H, Hfd, rtol=1e-5, atol=1e-6 * np.max(np.abs(H)))
    for zz, val in zip(zs, shapes, strict=True):
        np.testing.assert_allclose(val, derivs(nlp.pack(zz, tau))[0], rtol=1e-11)
    # the constraints: each sample against the rows where they are at 1.2 s + its time
    traj = nlp.to_trajectory(x, p, st)
    s, off, _, _ = nlp.collision_rows(p, st)
    tk = np.asarray(traj.duration * s + off)[:st.n_collision_samples]
    pos = np.asarray(traj.evaluate(tk))
    cen = w.center_at(1.2 + tk)[0]  # (K, 3, N): the truth; the sphere flies on
    cen[:, 0] = w.center_at(1.2)[0][0] + np.outer(tk, w.center_at(1.2)[1][0])
    sd = np.stack([signed_distance(w.kind, cen[k], w.half, w.radius, pos[k]) for k in
                   range(tk.size)])
    r = float(p.radius)
    sd0 = signed_distance(w.kind, w.center_at(1.2)[0], w.half, w.radius, np.asarray(p.p0))
    want = 4 * STATIC_PRIORITY * r * (sd - r - np.minimum(sd0 - r, 0.0))
    np.testing.assert_allclose(np.asarray(c.static)[:st.n_collision_samples, :3], want,
                               atol=1e-9)
    assert np.any(want < 0)  # some sample inside a moving row


_ST = NLPStructure(collision="barrier+constraint", segments=2, n_static=2)
_PILLAR = World.default(3).with_obstacles([dict(kind="cylinder", center=[3.0, 0.0, 1.5],
                                               radius=0.4, half_height=1.5)])


@jax.jit
def _solve_one(P):
    """(the initial guess, the solution from it)."""
    x0 = solve.initial_guess(P, _ST)
    return x0, solve.solve(P, x0, _ST)


def _one_robot(p0, goal, r=0.3):
    N = 3
    rows = rows_as_jax(static_rows(_PILLAR))
    z = jnp.zeros(N)
    others = Trajectory.hold(jnp.full((1, N), 100.0))
    return NLPParams(jnp.asarray(p0, float), z, z, jnp.asarray(goal, float), z, z,
                     jnp.asarray(True), others, jnp.ones((1,)), jnp.zeros((1,), bool),
                     jnp.asarray(r), weights(), limits(), jnp.asarray(0.1), rows)


def _dense_clearance(sol, r=0.3):
    t = np.linspace(0.0, float(sol.traj.duration), 4001)
    pos = np.asarray(sol.traj.evaluate(jnp.asarray(t)))
    w = _PILLAR
    return pos, signed_distance(w.kind, w.center, w.half, w.radius, pos)[:, 0] - r


def test_a_robot_goes_round_an_obstacle_on_its_straight_line():
    """One robot, rest to rest, a cylinder centred on its straight line (and the floor):
    the solve converges and its plan keeps clear of both by dense samples (to 1 cm: the
    constraints are sampled), where the straight line would pass through the axis."""
    sol = jax.device_get(_solve_one(_one_robot([0.0, 0.0, 1.0], [6.0, 0.0, 1.0]))[1])
    assert int(sol.status) == solve.CONVERGED
    pos, clear = _dense_clearance(sol)
    assert np.min(clear) > -0.01
    assert np.min(pos[:, 2]) - 0.3 > -0.01
    assert np.allclose(pos[-1], [6.0, 0.0, 1.0], atol=1e-6)


# three NLPs of _ST: a pillar and the ground (static rows), another robot held near the path
_CASES = [([0.0, 0.0, 1.0], [6.0, 0.0, 1.0], [4.6, 0.9, 1.0]),
          ([0.0, -1.0, 0.5], [6.0, 1.0, 2.0], [1.8, 0.4, 1.4]),
          ([0.5, 0.8, 1.5], [5.5, -0.6, 0.6], [1.6, -0.6, 1.0])]


def _with_other(p0, goal, other, r=0.3):
    P = _one_robot(p0, goal, r)
    return P._replace(others=Trajectory.hold(jnp.asarray([other], float)),
                      other_radius=jnp.asarray([r], float), other_mask=jnp.ones((1,), bool))


@jax.jit
def _values(P, xs):
    """The objective and the constraints (flattened; the static rows' apart) at xs."""
    def fg(x):
        g = nlp.constraints(x, P, _ST)
        return nlp.objective(x, P, _ST), jnp.concatenate([jnp.ravel(a) for a in g]), g.static

    return jax.vmap(fg)(xs)


def test_casadi_ipopt_reference_with_static_rows_is_the_same_nlp():
    """jaxplan.reference_casadi (jaxplan's objective and constraints traced to CasADi SX)
    on NLPs with static rows (a pillar and the ground) and another robot: CasADi's
    objective and constraints equal jaxplan's at points around the guesses to 1e-10
    relative, the static rows' among them (some violated there); IPOPT with CasADi's
    own derivatives and jaxplan's solver reach the same optimum from the same start
    (relative objective gap <= 1e-6, no larger violation)."""
    pytest.importorskip("casadi")
    from jaxplan import reference_casadi as rc

    rng = np.random.default_rng(5)
    static_violated = 0
    for k, (p0, goal, other) in enumerate(_CASES):
        P = _with_other(p0, goal, other)
        x0, sol = jax.device_get(_solve_one(P))
        xs = x0 + rng.normal(size=(3, _ST.n_x)) * 0.3
        fj, gj, gs = jax.device_get(_values(P, jnp.asarray(xs)))
        F = rc.casadi_functions(P, _ST)
        for x, f_ref, g_ref in zip(xs, fj, gj, strict=True):
            f, g = F(x, rc.flat_params(P))
            assert abs(float(f) - f_ref) <= 1e-10 * abs(f_ref), (k, float(f), f_ref)
            np.testing.assert_allclose(np.asarray(g).ravel(), g_ref, rtol=1e-10,
                                       atol=1e-10 * np.max(np.abs(g_ref)))
        static_violated += int(np.sum(gs < 0))
        r = rc.solve_ipopt(P, x0, _ST)
        assert int(sol.status) == solve.CONVERGED and r.converged, (k, sol.status, r)
        assert abs(float(sol.objective) - r.objective) <= 1e-6 * abs(r.objective), (
            k, float(sol.objective), r.objective)
        assert float(sol.ineq_violation) <= max(r.ineq_violation, 1e-8)
    assert static_violated > 0


def test_a_robot_that_starts_inside_its_planning_radius_plans_out():
    """A start 3 cm inside the planning radius of the cylinder (outside its body): the
    constraints allow what the start lacks (static_allowance), so the solve converges,
    never comes closer than the start, and reaches the goal behind the cylinder."""
    r = 0.3
    start = [3.0 - 0.4 - r + 0.03, 0.0, 1.0]  # sd - r = -0.03
    P = _one_robot(start, [6.0, 0.5, 1.0], r)
    w = _PILLAR
    c0 = signed_distance(w.kind, w.center, w.half, w.radius, np.asarray([start]))[0, 0] - r
    assert -0.05 < c0 < 0.0
    sol = jax.device_get(_solve_one(P)[1])
    assert int(sol.status) == solve.CONVERGED
    pos, clear = _dense_clearance(sol, r)
    assert np.min(clear) > c0 - 0.01
    assert np.allclose(pos[-1], [6.0, 0.5, 1.0], atol=1e-6)


# ---------------------------------------------------------------------- row selection
SELECT = """
name = "sel"
[planner]
max_static_rows = {K}
[[robots]]
vehicle = "firefly"
start = [0, 0, 1]
goal = [8, 0, 1]
[[robots]]
vehicle = "neo11"
start = [8, 3, 2]
goal = [0, 3, 2]
[[robots]]
vehicle = "firefly"
start = [4, 6, 1]
goal = [4, -3, 1]
[workspace]
min = [-2, -5, 0]
max = [10, 8, 4]
""" + "".join(f"""[[obstacles]]
kind = "{kd}"
center = [{x}, {y}, 1.5]
{size}
""" for kd, x, y, size in [
    ("cylinder", 2.0, 1.5, "radius = 0.3\nhalf_height = 1.5"),
    ("box", 5.0, 0.8, "half_extents = [0.4, 0.3, 0.6]"),
    ("sphere", 6.5, 4.5, "radius = 0.5"),
    ("cylinder", 1.0, -3.5, "radius = 0.4\nhalf_height = 1.0"),
    ("box", 8.5, 6.0, "half_extents = [0.3, 0.3, 1.5]"),
    ("sphere", 3.0, 3.0, "radius = 0.3")])  # 6 obstacles and 6 faces: R = 12


def _selection_setup(K):
    """(PlannerStructure, FleetParams, initial PlanState, starts) of SELECT."""
    cfg = _cfg(SELECT.format(K=K))
    sc = build_scenario(cfg)
    st, fp = rs.structures(cfg).planner, rs.fleet_params(cfg, sc)
    p = jnp.asarray(sc.start)
    return st, fp, planner.initial_plan_state(p, st, 3), p


_static_slots = jax.jit(planner.nlp_static_rows, static_argnums=3)


def test_nearest_static_rows_match_brute_force():
    """The K rows of least clearance sd(p) - r at each robot's position, nearest first,
    masked padding never picked: against numpy on a world of every kind and its faces."""
    rng = np.random.default_rng(4)
    obs = random_obstacles(rng, 4, 5.0, 0.1, 0.2)
    w = World(np.array([-6.0, -np.inf, -1.0]), np.array([6.0, 7.0, np.inf]),
              *obstacle_arrays(obs, 3))
    rows = static_rows(w, 20)  # 12 obstacles, 4 faces, 4 masked
    M, K = 9, 5
    p = rng.uniform(-6, 6, (M, 3))
    r = rng.uniform(0.2, 0.5, M)
    jrows = rows_as_jax(rows)
    idx = np.asarray(jax.jit(planner.nearest_static_rows, static_argnums=3)(
        jrows, jnp.asarray(p), jnp.asarray(r), K))
    gap = signed_distance(*rows[:4], p) - r[:, None]
    gap = np.where(rows.mask, gap, np.inf)
    for i in range(M):
        np.testing.assert_array_equal(idx[i], np.argsort(gap[i], kind="stable")[:K])
    sel, idx2 = jax.jit(planner.select_static, static_argnums=3)(jrows, jnp.asarray(p),
                                                                 jnp.asarray(r), K)
    np.testing.assert_array_equal(idx2, idx)
    for a, b in zip(jax.tree.leaves(sel), jax.tree.leaves(rows), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b)[idx])
    # where each robot is and is headed: the previous plan's points (robots with a plan)
    # and the line to its goal; each row keyed by its least clearance over the points
    goal = rng.uniform(-6, 6, (M, 3))
    T = 2.0  # a previous plan that flies +x at 1 m/s for 2 s, then holds
    coeffs = np.zeros((M, 2, 3, 6))
    coeffs[:, :, :, 0] = p[:, None, :]
    coeffs[:, 1, 0, 0] += 1.0
    coeffs[:, :, 0, 1] = 1.0
    plan = Trajectory(jnp.asarray(coeffs), jnp.asarray(np.tile([0.0, 1.0, T], (M, 1))),
                      jnp.zeros((M,), bool))
    has = np.arange(M) % 2 == 0
    ps = planner.PlanState(plan, jnp.asarray(has), *([None] * 5))
    dt = 0.125
    pts = np.asarray(jax.jit(planner.heading_points)(ps, jnp.asarray(p), jnp.asarray(goal), dt))
    S = planner.STATIC_PATH_SAMPLES
    frac = np.arange(1, S + 1) / S
    on_plan = p[:, None] + np.where(has[:, None, None], 1.0, 0.0) * (
        (T - dt) * frac)[None, :, None] * np.array([1.0, 0, 0])
    np.testing.assert_allclose(pts[:, 0], p, atol=1e-12)
    np.testing.assert_allclose(pts[:, 1:1 + S], on_plan + dt * has[:, None, None] * [1.0, 0, 0],
                               atol=1e-12)
    np.testing.assert_allclose(pts[:, 1 + S:], p[:, None] + frac[None, :, None] *
                               (goal - p)[:, None], atol=1e-12)
    idx_h = np.asarray(jax.jit(planner.nearest_static_rows, static_argnums=3)(
        jrows, jnp.asarray(pts), jnp.asarray(r), K))
    gaps = np.stack([signed_distance(*rows[:4], pts[:, k]) for k in range(pts.shape[1])], 1)
    key = np.where(rows.mask, (gaps - r[:, None, None]).min(axis=1), np.inf)
    for i in range(M):
        np.testing.assert_array_equal(idx_h[i], np.argsort(key[i], kind="stable")[:K])
    # rows on the robots' way rank before rows as near but off it
    assert not np.array_equal(idx_h, idx)


def test_static_multipliers_follow_their_row_across_a_reselection():
    """The NLPs' static rows (fleet_nlps) with max_static_rows = 3 of 12: each NLP holds
    its 3 nearest rows (PlanState.static_ids), and a row that stays selected keeps its
    multipliers in whichever slot it moves to, a newly selected one starts at 0."""
    st, fp, ps, p = _selection_setup(3)
    assert st.nlp.n_static == 3 and fp.static.mask.shape == (12,)
    assert ps.static_ids.shape == (3, 3) and ps.multipliers.static.shape[-1] == 3
    want = np.asarray(jax.jit(planner.nearest_static_rows, static_argnums=3)(
        fp.static, p, fp.radius, 3))
    # the previous selection: robot m's nearest row in slot 2, its third nearest in slot
    # 0, and a row it has not selected now (slot 1)
    rng = np.random.default_rng(2)
    old = np.stack([[w[2], next(j for j in range(12) if j not in w), w[0]] for w in want])
    lam = rng.uniform(1, 2, ps.multipliers.static.shape)
    ps = ps._replace(static_ids=jnp.asarray(old, jnp.int32),
                     multipliers=ps.multipliers._replace(static=jnp.asarray(lam)))
    rows, sidx, out = _static_slots(fp, ps, p, st)
    np.testing.assert_array_equal(sidx, want)
    for a, b in zip(jax.tree.leaves(rows), jax.tree.leaves(fp.static), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b)[want])
    out = np.asarray(out)
    for m in range(3):
        np.testing.assert_array_equal(out[m, :, 0], lam[m, :, 2])  # the nearest row
        np.testing.assert_array_equal(out[m, :, 1], 0.0)  # new to the selection
        np.testing.assert_array_equal(out[m, :, 2], lam[m, :, 0])  # the third nearest


def test_as_many_static_rows_as_the_world_has_is_no_selection():
    """max_static_rows >= R: the same structure (so the same compiled program, the same
    results) as 0, and every NLP holds every row in order with its multipliers in place."""
    structs = [rs.structures(_cfg(SELECT.format(K=K))) for K in (0, 12, 40)]
    assert structs[0] == structs[1] == structs[2]
    assert structs[0].planner.nlp.n_static == 12
    assert rs.structures(_cfg(SELECT.format(K=11))).planner.nlp.n_static == 11
    st, fp, ps, p = _selection_setup(12)
    lam = np.random.default_rng(3).uniform(1, 2, ps.multipliers.static.shape)
    ps = ps._replace(multipliers=ps.multipliers._replace(static=jnp.asarray(lam)))
    rows, sidx, out = _static_slots(fp, ps, p, st)
    np.testing.assert_array_equal(sidx, np.broadcast_to(np.arange(12), (3, 12)))
    for a, b in zip(jax.tree.leaves(rows), jax.tree.leaves(fp.static), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.broadcast_to(b, a.shape))
    np.testing.assert_array_equal(np.asarray(out), lam)


# ---------------------------------------------------------------------- config
BASE = """
name = "w"
[[robots]]
vehicle = "firefly"
start = [0, 0, 1]
goal = [5, 0, 1]
[workspace]
max = [inf, inf, 3.0]
[[obstacles]]
kind = "cylinder"
center = [2.5, 0, 1.5]
radius = 0.3
half_height = 1.5
"""


def _cfg(text):
    return parse_config(tomllib.loads(text), source="w.toml")


def test_world_config_round_trips_and_builds():
    c = _cfg(BASE)
    assert _cfg(config_to_toml(c)) == c
    sc = build_scenario(c)
    np.testing.assert_array_equal(sc.world.lo, [-np.inf, -np.inf, 0.0])
    np.testing.assert_array_equal(sc.world.hi, [np.inf, np.inf, 3.0])
    assert sc.world.obstacles() == [dict(kind="cylinder", center=[2.5, 0.0, 1.5], radius=0.3,
                                         half_height=1.5)]
    two = _cfg('[[robots]]\nvehicle = "firefly"\nstart = [0, 0]\ngoal = [5, 0]\n'
               '[[obstacles]]\nkind = "cylinder"\ncenter = [2.5, 1]\nradius = 0.5\n')
    w2 = build_scenario(two).world
    assert w2.dim == 2 and not np.any(np.isfinite(w2.lo))  # 2-D: unbounded by default


@pytest.mark.parametrize("edit,message", [
    (("start = [0, 0, 1]", "start = [2.5, 0.2, 1]"),
     "w.toml: robots[0].start: robots[0]: start [2.5, 0.2, 1] is inside obstacles[0] "
     "(cylinder at [2.5, 0, 1.5])"),
    (("goal = [5, 0, 1]", "goal = [5, 0, 2.9]"),
     "w.toml: robots[0].goal: robots[0]: goal (waypoint 0) [5, 0, 2.9] is outside the "
     "workspace"),
    (("goal = [5, 0, 1]", "goal = [5, 0, 0.1]"),
     "w.toml: robots[0].goal: robots[0]: goal (waypoint 0) z = 0.1 m is inside the ground"),
    (("half_height = 1.5", ""),
     "w.toml: obstacles[0].half_height: missing; a cylinder needs radius and half_height"),
    (("half_height = 1.5", "half_height = 1.5\nhalf_extents = [1, 1, 1]"),
     "w.toml: obstacles[0].half_extents: a cylinder takes no half_extents"),
    (('kind = "cylinder"', 'kind = "cone"'),
     "w.toml: obstacles[0].kind: unknown value 'cone'"),
    (("radius = 0.3", "radius = -0.3"), "w.toml: obstacles[0].radius:"),
    (("max = [inf, inf, 3.0]", "max = [inf, nan, 3.0]"),
     "w.toml: workspace.max[1]: expected a number or +-inf, got nan"),
    (("max = [inf, inf, 3.0]", "max = [1.0, 1.0]"),
     "w.toml: workspace.max: expected 3 coordinates"),
    (("max = [inf, inf, 3.0]", "min = [0, 0, 5]\nmax = [9, 9, 4]"),
     "w.toml: workspace.max: max[2] = 4 must be above min[2] = 5"),
    (("center = [2.5, 0, 1.5]", "center = [2.5, 0]"),
     "w.toml: obstacles[0].center: expected 3 coordinates"),
    (("radius = 0.3", "radius = 0.3\ncolour = 1"), "w.toml: obstacles[0].colour: unknown key"),
    (('name = "w"', 'name = "w"\n[planner]\nmax_static_rows = -1'),
     "w.toml: planner.max_static_rows: must be >= 0, got -1"),
    (('name = "w"', 'name = "w"\n[planner]\nmax_static_rows = 2.5'),
     "w.toml: planner.max_static_rows: expected an integer, got 2.5"),
    # moving obstacles
    (("center = [2.5, 0, 1.5]", "path = [{t = 0, p = [2.5, 3, 1.5]}, {t = 2, p = [2.5, 1, 1.5]},"
      " {t = 1, p = [2.5, -3, 1.5]}]"),
     "w.toml: obstacles[0].path[2].t: goes back in time: 1 s is not after path[1].t = 2 s"),
    (("center = [2.5, 0, 1.5]", "path = [{t = 0, p = [2.5, 3, 1.5]}, {t = 0, p = [2.5, 1, 1.5]}]"),
     "w.toml: obstacles[0].path[1].t: goes back in time: 0 s is not after path[0].t = 0 s"),
    (("center = [2.5, 0, 1.5]", "path = [{t = 0, p = [2.5, 3, 1.5]}, {t = 2, p = [2.5, 1]}]"),
     "w.toml: obstacles[0].path[1].p: expected 3 coordinates"),
    (("center = [2.5, 0, 1.5]", "path = [{t = 0, p = [2.5, 3, 1.5], v = 1}]"),
     "w.toml: obstacles[0].path[0].v: unknown key; valid keys: t, p"),
    (("center = [2.5, 0, 1.5]", "path = []"), "w.toml: obstacles[0].path: expected a non-empty"),
    (("half_height = 1.5", "half_height = 1.5\nvelocity = [0, 1, 0]\n"
      "path = [{t = 0, p = [2.5, 3, 1.5]}]"),
     "w.toml: obstacles[0].path: give either velocity (a constant velocity) or path"),
    (("half_height = 1.5", "half_height = 1.5\npath = [{t = 0, p = [2.5, 3, 1.5]}]"),
     "w.toml: obstacles[0].center: a moving obstacle with a path takes its positions from the "
     "path; give no center"),
    (("half_height = 1.5", "half_height = 1.5\naxis = [1, 0, 0]"),
     "w.toml: obstacles[0].axis: a cylinder must be vertical: its axis must be [0, 0, 1], got "
     "[1.0, 0.0, 0.0]"),
    (("half_height = 1.5", "half_height = 1.5\nvelocity = [0, inf, 0]"),
     "w.toml: obstacles[0].velocity[1]: expected a finite number, got inf"),
    (("half_height = 1.5", "half_height = 1.5\nvelocity = [0, 1]"),
     "w.toml: obstacles[0].velocity: expected 3 coordinates"),
    (("center = [2.5, 0, 1.5]",
      "path = [{t = 0, p = [2.5, 3, 1.5]}, {t = 5e-324, p = [2.5, 1, 1.5]}]"),
     "w.toml: obstacles[0].path[1].t: the speed from path[0] is not finite"),
    (('kind = "cylinder"\ncenter = [2.5, 0, 1.5]\nradius = 0.3\nhalf_height = 1.5',
      'kind = "box"\ncenter = [2.5, 0, 1.5]\nhalf_extents = [1, 1, 1]\nvelocity = [0, 1, 0]'),
     "w.toml: obstacles[0].velocity: a box cannot move (only spheres and cylinders move)"),
])
def test_world_config_errors_name_the_key(edit, message):
    with pytest.raises(ConfigError) as e:
        _cfg(BASE.replace(*edit))
    assert str(e.value).startswith(message), str(e.value)


def test_moving_obstacles_fly_under_mjx_not_under_a_baseline():
    """Backend "mjx" takes moving obstacles (mocap bodies, jaxplan/sim/fleet.py); a
    baseline method (here planar ORCA) does not."""
    c = _cfg(BASE.replace("half_height = 1.5", "half_height = 1.5\nvelocity = [0, 1, 0]\n"
                          "[sim]\nbackend = 'mjx'"))
    assert c.sim.backend == "mjx" and build_scenario(c).world.has_motion
    planar = ('[[robots]]\nvehicle = "firefly"\nstart = [0, 0]\ngoal = [5, 0]\n'
              '[planner]\nmethod = "orca"\n[[obstacles]]\nkind = "cylinder"\n'
              'center = [2.5, 1]\nradius = 0.5\nvelocity = [0, -0.5]\n')
    with pytest.raises(ConfigError) as e:
        _cfg(planar)
    assert str(e.value).startswith(
        "w.toml: planner.method: moving obstacles (obstacles[0] moves) fly with method "
        "'krishnan' only"), str(e.value)


MOVING = BASE.replace("center = [2.5, 0, 1.5]", "path = [{t = 1.0, p = [2.5, 3, 0.9]}, "
                      "{t = 4.0, p = [2.5, -3, 0.9]}]").replace("half_height = 1.5",
                                                              "half_height = 0.9") + """
[[obstacles]]
kind = "sphere"
center = [4, 2, 1]
radius = 0.3
velocity = [0, -0.5, 0]
known_path = true
"""


def test_moving_obstacles_round_trip_config_world_and_file_arrays():
    """A path and a constant velocity: the resolved config.toml reads back equal (the
    defaults written out), the world moves as they say, and its trajectories.npz arrays
    give the same world back; a static world writes no motion keys."""
    c = _cfg(MOVING)
    text = config_to_toml(c)
    assert "known_path = false" in text and "known_path = true" in text
    assert _cfg(text) == c
    w = build_scenario(c).world
    np.testing.assert_array_equal(w.moving, [True, True])
    np.testing.assert_array_equal(w.known, [False, True])
    cen, vel = w.center_at(np.array([0.0, 2.5, 9.0]))
    np.testing.assert_allclose(cen[:, 0], [[2.5, 3, 0.9], [2.5, 0, 0.9], [2.5, -3, 0.9]])
    np.testing.assert_allclose(vel[:, 0], [[0, 0, 0], [0, -2, 0], [0, 0, 0]])
    np.testing.assert_allclose(cen[:, 1], [[4, 2, 1], [4, 0.75, 1], [4, -2.5, 1]])
    np.testing.assert_allclose(vel[:, 1], [[0, -0.5, 0]] * 3)
    assert w.obstacles()[0]["path"][1] == {"t": 4.0, "p": [2.5, -3.0, 0.9]}
    arrays = world_arrays(w)
    assert set(MOTION_KEYS) <= set(arrays)
    back = world_from_arrays(arrays, 3)
    for k in ("center", "knot_t", "knot_p", "knot_v", "known"):
        np.testing.assert_array_equal(getattr(back, k), getattr(w, k))
    static = build_scenario(_cfg(BASE)).world
    assert not static.has_motion and not set(MOTION_KEYS) & set(world_arrays(static))
    assert static_rows(static).motion is None


def test_rows_at_predict_flying_on_or_the_known_path():
    """A replan at t = 2 s sees the path's obstacle (unknown path) at its position then,
    flying on at its velocity then, and the sphere (known path: a constant velocity)
    along its path; the faces stay put."""
    w = build_scenario(_cfg(MOVING)).world
    rows = rows_as_jax(static_rows(w, 6))
    assert rows.motion is not None and rows.motion.t.shape == (6, 2)
    now = jax.jit(rows_at)(rows, 2.0)
    tau = jnp.array([0.0, 1.0, 5.0])
    cen = np.asarray(jax.jit(centres_at)(now, tau))  # (3, 6, 3)
    np.testing.assert_allclose(cen[:, 0], [[2.5, 1, 0.9], [2.5, -1, 0.9], [2.5, -9, 0.9]])
    np.testing.assert_allclose(cen[:, 1], w.center_at(2.0 + np.asarray(tau))[0][:, 1])
    np.testing.assert_allclose(cen[:, 2:], np.broadcast_to(np.asarray(rows.center)[2:],
                                                           (3, 4, 3)))
    np.testing.assert_array_equal(np.asarray(now.motion.moving), [1, 1, 0, 0, 0, 0])


@pytest.mark.slow  # a run of its own program (~30 s to compile)
def test_a_robot_gives_way_to_a_moving_obstacle_it_sees():
    """A cylinder crosses a robot's straight line at about the time it gets there: the
    planner sees it (its position and velocity at each replan), the robot leaves its
    line to keep clear (exact clearance against the moving body >= 0) and arrives."""
    from jaxplan.experiment import run

    text = BASE.replace("center = [2.5, 0, 1.5]", "center = [2.5, 2.5, 1.0]").replace(
        "half_height = 1.5", "half_height = 1.0\nvelocity = [0, -1.0, 0]")
    text += "[sim]\nduration_s = 8.0\n"
    res = run(_cfg(text))
    m = res.metrics
    assert m["success"], m
    assert m["obstacle_collisions"] == 0 and m["min_obstacle_clearance_m"] >= 0.0
    # it left its straight line (y = 0) to let the cylinder pass
    assert np.max(np.abs(res.arrays["pos"][0, :, 1])) > 0.2
