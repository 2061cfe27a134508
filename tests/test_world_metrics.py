"""Exact clearance to the world (jaxplan.metrics.clearance) against dense sampling and a
refined minimum, on random and constructed (grazing, starting-inside) pieces; the
metrics.json keys on the tiny run."""

import dataclasses

import numpy as np
import pytest
from scipy.optimize import minimize_scalar

from jaxplan.metrics.clearance import face_names, world_clearance, world_report
from jaxplan.world import BOX, CYLINDER, SPHERE, World

GRID = 4001  # dense samples per piece


# -------------------------------------------------------------- independent reference


def ref_distance(kind, center, half, radius, p):
    """Signed distance of points p (..., N) to one obstacle by its nearest point: the
    point clamped into the solid outside, minus the distance to the nearest face inside
    (written independently of jaxplan's max-of-faces formula)."""
    d = p - center
    N = p.shape[-1]
    if kind == SPHERE or (kind == CYLINDER and N == 2):
        return np.linalg.norm(d, axis=-1) - radius
    if kind == BOX:
        near = np.clip(d, -half, half)
        out = np.linalg.norm(d - near, axis=-1)
        depth = np.min(half - np.abs(d), axis=-1)
        return np.where(out > 0, out, -depth)
    rho = np.hypot(d[..., 0], d[..., 1])
    hz = half[2]
    scale = np.where(rho > radius, radius / np.where(rho > 0, rho, 1.0), 1.0)
    near = np.stack([d[..., 0] * scale, d[..., 1] * scale, np.clip(d[..., 2], -hz, hz)], -1)
    out = np.linalg.norm(d - near, axis=-1)
    depth = np.minimum(radius - rho, hz - np.abs(d[..., 2]))
    return np.where(out > 0, out, -depth)


def eval_piece(c, tau):
    """One piece's positions (len(tau), N) at times tau after its start."""
    x = np.zeros(tau.shape + (c.shape[0],))
    for k in range(c.shape[1] - 1, -1, -1):
        x = x * tau[:, None] + c[:, k]
    return x


def clearance_fn(kind, center, half, radius, c, rr=0.0):
    """tau -> reference clearance of piece c (N, L) to one obstacle, robot radius rr."""
    return lambda tau: ref_distance(kind, center, half, radius, eval_piece(c, tau)) - rr


def dense_and_refined(f, h):
    """(dense minimum over GRID samples, refined minimum: every local minimum of the
    samples within 1e-3 of the best polished by bounded Brent on its two neighbouring
    grid cells) of f(tau) on [0, h]."""
    tau = np.linspace(0.0, h, GRID)
    v = f(tau)
    dense = v.min()
    best = dense
    loc = np.nonzero((v <= np.r_[np.inf, v[:-1]]) & (v <= np.r_[v[1:], np.inf])
                     & (v <= dense + 1e-3))[0]
    for j in loc[np.argsort(v[loc], kind="stable")][:8]:  # a flat stretch: any of it
        a, b = tau[max(j - 1, 0)], tau[min(j + 1, GRID - 1)]
        # in an offset from the sample (Brent's tolerance is relative to |x|)
        r = minimize_scalar(lambda s, j=j: f(np.array([tau[j] + s]))[0],
                            bounds=(a - tau[j], b - tau[j]), method="bounded",
                            options={"xatol": 1e-14, "maxiter": 500})
        best = min(best, r.fun)
    return dense, best


def one_piece_world(kind, center, half, radius, N=3):
    return World(np.full(N, -np.inf), np.full(N, np.inf), [kind], center[None], half[None],
                 [radius])


def single(c, h, world, radius=0.0):
    """world_clearance of one robot with one piece c (N, L) of length h."""
    return world_clearance([0], [0.0], [h], c[None], [radius], world)


def random_obstacle(rng, kind, N=3):
    center = rng.uniform(-0.5, 0.5, N)
    half = rng.uniform(0.2, 1.0, N)
    return kind, center, half, float(rng.uniform(0.2, 1.0))


def random_piece(rng, N=3, D=5, inside=False):
    """A random degree-D piece of 0.1 to 3 s that wanders over +-2 m; starts at the
    obstacle's centre region when ``inside``."""
    h = float(rng.uniform(0.1, 3.0))
    c = rng.normal(0.0, 1.0, (N, D + 1)) * (2.0 / h ** np.arange(D + 1))
    c[:, 0] = rng.uniform(-0.3, 0.3, N) if inside else rng.uniform(-2.0, 2.0, N)
    return c, h


# -------------------------------------------------------------- random pieces


@pytest.mark.parametrize("kind,N", [(SPHERE, 3), (BOX, 3), (CYLINDER, 3), (BOX, 2),
                                    (CYLINDER, 2)])
def test_exact_clearance_matches_dense_and_refined_minimum(kind, N):
    rng = np.random.default_rng(100 + 10 * kind + N)
    worst_gap = 0.0
    for trial in range(40):
        k, center, half, radius = random_obstacle(rng, kind, N)
        w = one_piece_world(k, center, half, radius, N)
        c, h = random_piece(rng, N, D=int(rng.integers(1, 8)), inside=trial % 4 == 0)
        rr = float(rng.uniform(0.0, 0.4))
        wc = single(c, h, w, rr)
        got, t = wc.obstacle[0, 0], wc.obstacle_t[0, 0]
        f = clearance_fn(k, center, half, radius, c, rr)
        dense, refined = dense_and_refined(f, h)
        scale = 1.0 + np.abs(c).sum()
        # a value the piece really takes, at the reported time
        assert abs(f(np.array([t]))[0] - got) <= 1e-12 * scale
        assert got <= dense + 1e-12 * scale, (trial, got, dense)
        assert got <= refined + 1e-12 * scale, (trial, got, refined)
        assert abs(got - refined) <= 1e-9 * scale, (trial, got, refined)
        worst_gap = max(worst_gap, refined - got)
    assert worst_gap >= 0.0


def test_many_pieces_many_obstacles_one_call():
    """Several robots and obstacles at once (the pruning and the per-pair scatter)
    against the per-pair dense minimum."""
    rng = np.random.default_rng(7)
    M, per, K, N = 4, 6, 6, 3
    kinds = np.array([SPHERE, BOX, CYLINDER] * 2)
    center = rng.uniform(-2, 2, (K, N))
    half = rng.uniform(0.2, 0.8, (K, N))
    rad = rng.uniform(0.2, 0.8, K)
    w = World(np.full(N, -np.inf), np.full(N, np.inf), kinds, center, half, rad)
    robot, t0, t1, cs = [], [], [], []
    for i in range(M):  # continuous-ish random walks of `per` pieces
        t = 0.0
        for _ in range(per):
            c, h = random_piece(rng, N, D=5)
            c *= 0.3
            c[:, 0] = rng.uniform(-2.5, 2.5, N)
            robot.append(i)
            t0.append(t)
            t1.append(t + h)
            cs.append(c)
            t += h
    radius = rng.uniform(0.1, 0.3, M)
    wc = world_clearance(robot, t0, t1, np.array(cs), radius, w)
    for i in range(M):
        for k in range(K):
            dense = refined = np.inf
            for s in np.nonzero(np.array(robot) == i)[0]:
                f = clearance_fn(kinds[k], center[k], half[k], rad[k], cs[s], radius[i])
                dn, rf = dense_and_refined(f, t1[s] - t0[s])
                dense, refined = min(dense, dn), min(refined, rf)
            assert wc.obstacle[i, k] <= dense + 1e-12
            assert abs(wc.obstacle[i, k] - refined) <= 1e-9


def test_a_piece_behind_a_loose_bound_is_still_solved():
    """Pruning: a long arc round a sphere has a bounding box that holds the centre (the
    smallest lower bound, solved first), a short straight piece of the same robot comes
    10 mm closer than the arc ever does: its minimum is the robot's."""
    w = one_piece_world(SPHERE, np.zeros(3), np.zeros(3), 1.0)
    arc = np.array([[2.5, -5.0, 0.0], [0.0, 10.0, -10.0], [0.0, 0.0, 0.0]])
    f = clearance_fn(SPHERE, np.zeros(3), np.zeros(3), 1.0, arc)
    _, arc_min = dense_and_refined(f, 1.0)
    line = np.array([[0.0, 0.05], [-(arc_min + 1.0 - 0.01), 0.0], [0.0, 0.0]])
    pieces = np.zeros((2, 3, 3))
    pieces[0], pieces[1, :, :2] = arc, line
    wc = world_clearance([0, 0], [0.0, 1.0], [1.0, 1.1], pieces, [0.0], w)
    assert abs(wc.obstacle[0, 0] - (arc_min - 0.01)) <= 1e-12
    assert 1.0 <= wc.obstacle_t[0, 0] <= 1.1


# -------------------------------------------------------------- constructed grazing


def _graze(tau_m, h, base, quad, lin):
    """The quadratic piece base + quad (t - tau_m)^2 + lin (t - tau_m) as (N, 3)
    monomial coefficients in t."""
    c = np.zeros((base.size, 3))
    c[:, 0] = base - lin * tau_m + quad * tau_m**2
    c[:, 1] = lin - 2 * quad * tau_m
    c[:, 2] = quad
    return c


def _grazing_cases(rng):
    """(kind, center, half, radius, piece, h, exact minimum distance, time) pieces that
    touch the surface at one instant from outside (min 0), tangentially or at an edge,
    a rim or a corner, plus ones that pass through the centre (min -depth)."""
    out = []
    for _ in range(6):
        c0 = rng.uniform(-1, 1, 3)
        hx = rng.uniform(0.3, 1.0, 3)
        R = float(rng.uniform(0.3, 1.0))
        h = float(rng.uniform(0.5, 2.0))
        tm = float(rng.uniform(0.1, 0.9) * h)
        a = float(rng.uniform(0.2, 2.0))
        s = float(rng.uniform(0.2, 2.0))
        n = rng.normal(size=3)
        n /= np.linalg.norm(n)
        e = np.cross(n, rng.normal(size=3))
        e /= np.linalg.norm(e)
        # sphere: tangent at c0 + R n
        out.append((SPHERE, c0, hx, R, _graze(tm, h, c0 + R * n, a * n, s * e), h, 0.0, tm))
        # box face x = +hx: grazes it, y and z stay well inside the slab
        base = c0 + np.array([hx[0], 0.2 * hx[1], -0.3 * hx[2]])
        out.append((BOX, c0, hx, R, _graze(tm, h, base, np.array([a, 0, 0]),
                                           np.array([0, 0.1, 0.1]) * s), h, 0.0, tm))
        # box edge (x = +hx, y = +hy): passes the edge diagonally
        d = np.array([1.0, 1.0, 0.0]) / np.sqrt(2)
        g = np.array([1.0, -1.0, 0.0]) / np.sqrt(2)
        out.append((BOX, c0, hx, R, _graze(tm, h, c0 + hx * [1, 1, 0.3], a * d, s * g), h, 0.0,
                    tm))
        # box corner: from outside, touching the vertex only
        out.append((BOX, c0, hx, R, _graze(tm, h, c0 + hx, a * np.ones(3) / np.sqrt(3),
                                           s * g), h, 0.0, tm))
        # cylinder side: tangent to the mantle at mid height
        m = np.array([n[0], n[1], 0.0])
        m /= np.linalg.norm(m)
        tg = np.array([-m[1], m[0], 0.0])
        out.append((CYLINDER, c0, hx, R, _graze(tm, h, c0 + R * m + [0, 0, 0.3 * hx[2]], a * m,
                                                s * tg), h, 0.0, tm))
        # cylinder rim: touching the top circle, tangentially to it
        out.append((CYLINDER, c0, hx, R, _graze(tm, h, c0 + R * m + [0, 0, hx[2]],
                                                a * (m + [0, 0, 1]) / np.sqrt(2), s * tg), h, 0.0,
                    tm))
        # cylinder top face: touching it from above inside the disc
        out.append((CYLINDER, c0, hx, R, _graze(tm, h, c0 + 0.5 * R * m + [0, 0, hx[2]],
                                                np.array([0, 0, a]), s * tg * 0.2), h, 0.0, tm))
        # straight through the centre: the deepest point is the centre
        out.append((SPHERE, c0, hx, R, _graze(tm, h, c0, 0 * n, s * n), h, -R, tm))
        out.append((BOX, c0, hx, R, _graze(tm, h, c0, 0 * n, s * n), h, -hx.min(), tm))
        out.append((CYLINDER, c0, hx, R, _graze(tm, h, c0, 0 * n, s * n), h, -min(R, hx[2]), tm))
    return out


def test_grazing_and_through_the_centre_are_exact():
    rng = np.random.default_rng(3)
    for i, (k, c0, hx, R, piece, h, want, tm) in enumerate(_grazing_cases(rng)):
        w = one_piece_world(k, c0, hx, R)
        wc = single(piece, h, w, radius=0.0)
        f = clearance_fn(k, c0, hx, R, piece)
        dense, _ = dense_and_refined(f, h)
        assert want <= dense + 1e-12, (i, want, dense)  # the construction is right
        assert abs(wc.obstacle[0, 0] - want) <= 1e-10, (i, k, wc.obstacle[0, 0], want)
        if want == 0.0:  # a touch at a single instant
            assert abs(wc.obstacle_t[0, 0] - tm) <= 1e-4, (i, wc.obstacle_t[0, 0], tm)


def test_touching_is_not_a_contact_and_overlap_is():
    """Clearance exactly 0 (grazing, robot radius included) counts no contact; 1 um
    deeper counts one, for that (robot, obstacle) pair only."""
    c0 = np.array([0.0, 0.0, 1.0])
    w = World(np.array([-np.inf, -np.inf, 0.0]), np.full(3, np.inf), [SPHERE, BOX],
              [c0, [5.0, 5.0, 1.0]], [[0, 0, 0], [0.5, 0.5, 0.5]], [1.0, 0.0])
    piece = _graze(0.5, 1.0, c0 + [1.25, 0, 0], np.array([1.0, 0, 0]), np.array([0, 1.0, 0]))
    for gap, contacts in ((0.0, 0), (-1e-6, 1)):
        wc = world_clearance([0, 1], [0.0, 0.0], [1.0, 1.0],
                             np.stack([piece, _graze(0.5, 1.0, np.array([-5.0, 0, 1]),
                                                     np.zeros(3), np.zeros(3))]),
                             [0.25 - gap, 0.25], w)
        rep = world_report(wc)
        assert rep["obstacle_collisions"] == contacts
        assert abs(rep["min_obstacle_clearance_m"] - gap) <= 1e-12
        assert rep["worst_obstacle"]["robot"] == 0 and rep["worst_obstacle"]["obstacle"] == 0
        assert abs(rep["worst_obstacle"]["t"] - 0.5) <= 1e-6


# -------------------------------------------------------------- workspace


def test_workspace_faces_exact_on_random_pieces():
    rng = np.random.default_rng(11)
    lo, hi = np.array([-3.0, -np.inf, 0.0]), np.array([3.0, 2.5, 4.0])
    w = World(lo, hi, np.zeros(0, np.int32), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))
    names = face_names(3)
    assert names == ("x_min", "x_max", "y_min", "y_max", "z_min", "z_max")
    for _ in range(30):
        c, h = random_piece(rng, 3, D=int(rng.integers(0, 8)))
        rr = float(rng.uniform(0, 0.4))
        wc = single(c, h, w, rr)
        assert not np.isfinite(wc.face[0, 2]) and not wc.face_finite[2]
        for f in (0, 1, 3, 4, 5):
            ax, sgn = f // 2, 1.0 if f % 2 == 0 else -1.0
            b = (lo if f % 2 == 0 else hi)[ax]
            def g(tau, c=c, ax=ax, sgn=sgn, b=b, rr=rr):
                return sgn * (eval_piece(c, tau)[:, ax] - b) - rr
            dense, refined = dense_and_refined(g, h)
            assert wc.face[0, f] <= dense + 1e-12
            assert abs(wc.face[0, f] - refined) <= 1e-9 * (1 + np.abs(c).sum())
            assert abs(g(np.array([wc.face_t[0, f]]))[0] - wc.face[0, f]) <= 1e-12 * (
                1 + np.abs(c).sum())


def test_floor_grazing_and_crossing():
    """z(t) = r + a (t - 0.4)^2 touches the ground exactly; lowered by 1 mm it crosses."""
    w = World.default(3)
    for drop, viol in ((0.0, 0), (1e-3, 1)):
        piece = _graze(0.4, 1.0, np.array([0.0, 0.0, 0.3 - drop]), np.array([0, 0, 2.0]),
                       np.array([1.0, 0, 0]))
        rep = world_report(single(piece, 1.0, w, radius=0.3))
        assert rep["workspace_violations"] == viol
        assert abs(rep["min_workspace_clearance_m"] + drop) <= 1e-12
        assert rep["worst_workspace"]["face"] == "z_min"
        assert abs(rep["worst_workspace"]["t"] - 0.4) <= 1e-9
        assert rep["min_obstacle_clearance_m"] is None and rep["worst_obstacle"] is None
    # unbounded: no workspace keys
    rep = world_report(single(piece, 1.0, World.unbounded(3), radius=0.3))
    assert rep["min_workspace_clearance_m"] is None and rep["workspace_violations"] == 0


def test_bad_inputs_fail_early():
    w = World.default(3)
    with pytest.raises(ValueError, match="radius"):
        world_clearance([0], [0.0], [1.0], np.zeros((1, 3, 2)), [[0.1]], w)
    with pytest.raises(ValueError, match="2-D"):
        world_clearance([0], [0.0], [1.0], np.zeros((1, 3, 2)), [0.1], World.default(2))


# -------------------------------------------------------------- metrics.json


def test_metrics_json_world_keys_on_the_tiny_run(tiny_run):
    """The tiny run flies over the ground (its default world): no contact; the same executed
    pieces in a world with a sphere on robot 2's straight line: a contact, and no
    success."""
    from jaxplan.metrics.report import compute_metrics
    from jaxplan.sweep import COLUMNS, SweepPoint, csv_row
    from jaxplan.sweep.batch import _ReachState

    m = tiny_run.metrics
    assert m["obstacle_collisions"] == 0 and m["min_obstacle_clearance_m"] is None
    assert m["worst_obstacle"] is None
    assert m["workspace_violations"] == 0
    a = tiny_run.arrays
    want = (a["pos"][..., 2] - a["radius"][:, None]).min()
    assert m["min_workspace_clearance_m"] <= want + 1e-12
    assert abs(m["min_workspace_clearance_m"] - want) <= 1e-3
    assert m["worst_workspace"]["face"] == "z_min"
    for i, r in enumerate(m["per_robot"]):  # the 100 Hz samples: never below, within 1 mm
        want = (a["pos"][i, :, 2] - a["radius"][i]).min()
        assert r["min_obstacle_clearance_m"] is None
        assert want - 1e-3 <= r["min_workspace_clearance_m"] <= want + 1e-12
    # the same pieces with a sphere where robot 2 is at t = 1 s
    sc = tiny_run.scenario
    at = a["pos"][2, np.argmin(np.abs(a["t"] - 1.0))]
    world = sc.world.with_obstacles([{"kind": "sphere", "center": [float(x) for x in at],
                                      "radius": 0.3}])
    sc2 = dataclasses.replace(sc, world=world)
    M, W = sc.waypoints.shape[:2]
    fin = _ReachState(np.ones((M, W), bool), np.full((M, W), 5.0))
    m2, _ = compute_metrics(tiny_run.config, sc2, tiny_run.records, fin, np.empty(0))
    assert m2["success_reached"] and m2["collisions"] == 0
    assert m2["obstacle_collisions"] >= 1 and not m2["success"]
    assert m2["min_obstacle_clearance_m"] <= -0.3 - a["radius"][2] + 1e-12
    assert m2["worst_obstacle"]["obstacle"] == 0
    assert m2["per_robot"][2]["min_obstacle_clearance_m"] <= -0.3 - a["radius"][2] + 1e-12
    row = csv_row(SweepPoint(1.0, 1.0, "tiny", 0), m2, W)
    assert set(row) <= set(COLUMNS)
    assert row["success"] == "0" and int(row["obstacle_collisions"]) >= 1


# -------------------------------------------------------------- moving obstacles


def _moving_world(kind, half, radius, motion, N=3):
    """One moving obstacle: motion = ("velocity", c0, v) or ("path", [(t, p), ...])."""
    o = {"kind": {SPHERE: "sphere", CYLINDER: "cylinder"}[kind], "radius": radius}
    if kind == CYLINDER and N == 3:
        o["half_height"] = float(half[2])
    if motion[0] == "velocity":
        o["center"], o["velocity"] = list(motion[1]), list(motion[2])
    else:
        o["path"] = [{"t": t, "p": list(p)} for t, p in motion[1]]
    return World.unbounded(N).with_obstacles([o])


@pytest.mark.parametrize("kind,how", [(SPHERE, "velocity"), (SPHERE, "path"),
                                      (CYLINDER, "velocity"), (CYLINDER, "path")])
def test_exact_clearance_to_a_moving_obstacle_matches_a_dense_sample(kind, how):
    """A sphere and a vertical cylinder moving at a constant velocity, or along a timed
    path whose knots fall inside the pieces: the exact minimum against a dense sample
    (0.1 ms) of random pieces, each refined (the minimum is a value the piece takes at
    the reported time, never above the samples)."""
    rng = np.random.default_rng(200 + 10 * kind + (how == "path"))
    N = 3
    for trial in range(10):
        _, c0, half, radius = random_obstacle(rng, kind, N)
        if how == "velocity":
            motion = ("velocity", c0, rng.uniform(-1.0, 1.0, N))
        else:  # knots every ~0.3-1 s, some before the piece starts
            ts = np.cumsum(rng.uniform(0.3, 1.0, 5)) - 0.5
            motion = ("path", [(float(t), c0 + rng.uniform(-1.0, 1.0, N)) for t in ts])
        w = _moving_world(kind, half, radius, motion, N)
        c, h = random_piece(rng, N, D=int(rng.integers(1, 8)), inside=trial % 4 == 0)
        t0 = float(rng.uniform(0.0, 1.0))
        rr = float(rng.uniform(0.0, 0.3))
        wc = world_clearance([0], [t0], [t0 + h], c[None], [rr], w)
        got, t = wc.obstacle[0, 0], wc.obstacle_t[0, 0]

        def f(tau, c=c, w=w, t0=t0, rr=rr, half=half, radius=radius):
            cen = w.center_at(t0 + tau)[0][:, 0]  # (C, N): the obstacle at each instant
            return ref_distance(kind, np.zeros(N), half, radius, eval_piece(c, tau) - cen) - rr

        tau = np.linspace(0.0, h, int(h / 1e-4) + 1)  # 0.1 ms
        v = f(tau)
        j = int(np.argmin(v))
        tj = tau[j]
        r = minimize_scalar(lambda s, f=f, tj=tj: f(np.array([tj + s]))[0],
                            bounds=(tau[max(j - 1, 0)] - tj, tau[min(j + 1, tau.size - 1)] - tj),
                            method="bounded", options={"xatol": 1e-14, "maxiter": 500})
        refined = min(v.min(), r.fun)
        scale = 1.0 + np.abs(c).sum()
        assert t0 <= t <= t0 + h
        assert abs(f(np.array([t - t0]))[0] - got) <= 1e-12 * scale, (trial, got)
        assert got <= refined + 1e-12 * scale, (trial, got, refined)
        assert abs(got - refined) <= 1e-9 * scale, (trial, got, refined)


def test_a_static_obstacle_in_a_moving_world_gives_the_numbers_of_before():
    """The static obstacles of a world with a moving one: bitwise the clearances of the
    world without it; a world whose obstacles all rest: the same arrays as before."""
    rng = np.random.default_rng(5)
    c, h = random_piece(rng, 3, D=5)
    pieces = dict(seg_robot=[0, 0], seg_t0=[0.0, h], seg_t1=[h, 2 * h],
                  seg_coeffs=np.stack([c, c]), radius=[0.2])
    obs = [dict(kind="sphere", center=[0.5, 0.0, 0.0], radius=0.4),
           dict(kind="box", center=[-0.5, 0.5, 0.0], half_extents=[0.3, 0.2, 0.5]),
           dict(kind="cylinder", center=[0.0, -1.0, 0.0], radius=0.3, half_height=1.0)]
    mover = dict(kind="sphere", center=[3.0, 0.0, 0.0], radius=0.3, velocity=[-1.0, 0.0, 0.0])
    base = world_clearance(world=World.default(3).with_obstacles(obs), **pieces)
    mixed = world_clearance(world=World.default(3).with_obstacles(obs[:1] + [mover] + obs[1:]),
                            **pieces)
    np.testing.assert_array_equal(mixed.obstacle[:, [0, 2, 3]], base.obstacle)
    np.testing.assert_array_equal(mixed.obstacle_t[:, [0, 2, 3]], base.obstacle_t)
    np.testing.assert_array_equal(mixed.face, base.face)
    assert np.isfinite(mixed.obstacle[0, 1])
