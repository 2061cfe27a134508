"""Goals another robot occupies (planner.free_goals and a run beside a frozen robot).

The runs beside a frozen robot compile a closed loop of their own (~21 s of the 2-core
suite for the four, ~30 s for the 20-robot fleet): behind the slow marker, as the other
closed loops with programs of their own (tests/test_deadlock.py, test_guide.py,
test_neighbors.py)."""

import tomllib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplan.config import parse_config
from jaxplan.experiment import run
from jaxplan.planner import GOAL_CLEARANCE, MAX_INFLATION
from jaxplan.planner import free_goals as _free_goals
from tests._fleets import frozen_random_box_20_seed_8

R = 0.4  # planning radius of each robot in the unit tests
# one program per shape, as in the planner's: op by op (eager) each new shape compiled
# every operation on its own (~1.5 s a test)
free_goals = jax.jit(_free_goals)


def _call(goal, p, occupants, inflate=MAX_INFLATION, mask=None):
    """One observer (robot 0) and len(occupants) others."""
    M = 1 + len(occupants)
    occ = np.zeros((M, M, 3))
    occ[0, 1:] = occupants
    goals = np.zeros((M, 3))
    goals[0] = goal
    pos = np.zeros((M, 3))
    pos[0] = p
    m = np.ones((M, M), bool) & ~np.eye(M, dtype=bool) if mask is None else mask
    g, inf, moved = free_goals(jnp.asarray(goals), jnp.asarray(pos), jnp.asarray(occ),
                               jnp.full((M,), R), jnp.full((M, M), inflate), jnp.asarray(m))
    return np.asarray(g)[0], np.asarray(inf)[0], bool(np.asarray(moved)[0])


def test_free_goal_is_left_alone():
    g, inf, moved = _call([3.0, 0, 0], [5.0, 0, 0], [[0.0, 0, 0]])
    np.testing.assert_array_equal(g, [3.0, 0, 0])
    assert inf[1] == MAX_INFLATION and not moved


def test_inflation_shrinks_so_the_goal_stays_reachable():
    d = 2 * R + 0.2  # outside both radii, inside the inflated distance
    g, inf, moved = _call([d, 0, 0], [5.0, 0, 0], [[0.0, 0, 0]])
    np.testing.assert_array_equal(g, [d, 0, 0])
    assert not moved
    assert inf[1] == pytest.approx(d - 2 * R - GOAL_CLEARANCE, abs=1e-12)
    # the goal is then GOAL_CLEARANCE outside the planning distance
    assert d - (2 * R + inf[1]) == pytest.approx(GOAL_CLEARANCE, abs=1e-12)


def test_floor_of_a_held_robot_is_never_given_up():
    # inflation 0.5 of which 0.15 is a floor (where a silent robot can be): a goal 2R + 0.3
    # from it keeps 0.25 of inflation (0.3 - clearance), one at 2R + 0.1 moves out to
    # 2R + 0.15 + clearance and the inflation stays at the floor
    M = 2
    occ = np.zeros((M, M, 3))
    m = np.ones((M, M), bool) & ~np.eye(M, dtype=bool)
    floor = jnp.full((M, M), 0.15)
    for gap, want_inf, want_d in ((0.3, 0.3 - GOAL_CLEARANCE, 2 * R + 0.3),
                                  (0.1, 0.15, 2 * R + 0.15 + GOAL_CLEARANCE)):
        goals = np.zeros((M, 3))
        goals[0] = [2 * R + gap, 0, 0]
        pos = np.array([[5.0, 0, 0], [0, 0, 0]])
        g, inf, moved = free_goals(jnp.asarray(goals), jnp.asarray(pos), jnp.asarray(occ),
                                   jnp.full((M,), R), jnp.full((M, M), MAX_INFLATION),
                                   jnp.asarray(m), floor)
        assert float(inf[0, 1]) == pytest.approx(want_inf)
        assert float(jnp.linalg.norm(g[0])) == pytest.approx(want_d)
        assert bool(moved[0]) == (gap < 0.15 + GOAL_CLEARANCE)


def test_occupied_goal_moves_to_the_nearest_free_point():
    g, inf, moved = _call([0.3, 0.1, 0], [5.0, 0, 0], [[0.0, 0, 0]])
    assert moved and inf[1] == 0.0
    u = np.array([0.3, 0.1, 0]) / np.linalg.norm([0.3, 0.1, 0])
    np.testing.assert_allclose(g, (2 * R + GOAL_CLEARANCE) * u, atol=1e-12)


def test_coincident_goal_moves_towards_the_robot():
    g, _, moved = _call([1.0, 1.0, 1.0], [1.0, 4.0, 1.0], [[1.0, 1.0, 1.0]])
    assert moved
    np.testing.assert_allclose(g, [1.0, 1.0 + 2 * R + GOAL_CLEARANCE, 1.0], atol=1e-12)
    # robot, goal and occupant all coincident: a fixed direction, still finite
    g, _, moved = _call([0.0, 0, 0], [0.0, 0, 0], [[0.0, 0, 0]])
    assert moved and np.all(np.isfinite(g))
    assert np.linalg.norm(g) == pytest.approx(2 * R + GOAL_CLEARANCE)


def test_two_occupants_goal_ends_outside_both():
    occ = [[0.0, 0, 0], [0.0, 1.0, 0]]
    g, _, moved = _call([0.2, 0.5, 0], [5.0, 0.5, 0], occ)
    assert moved
    for c in occ:
        assert np.linalg.norm(g - np.asarray(c)) >= 2 * R + GOAL_CLEARANCE - 1e-9


def test_masked_or_nonfinite_occupants_are_ignored():
    mask = np.zeros((2, 2), bool)
    g, inf, moved = _call([0.1, 0, 0], [5.0, 0, 0], [[0.0, 0, 0]], mask=mask)
    np.testing.assert_array_equal(g, [0.1, 0, 0])
    assert not moved and inf[1] == MAX_INFLATION
    g, _, moved = _call([0.1, 0, 0], [5.0, 0, 0], [[np.nan, 0, 0]])
    np.testing.assert_array_equal(g, [0.1, 0, 0])
    assert not moved


FROZEN = """
name = "beside_frozen"
seed = 0
[sim]
duration_s = 10.0
[faults]
enabled = true
frozen_robot = 0
frozen_at_s = 0.0
frozen_mode = "silent"
[planner]
end_state = "{end}"
coast_samples = {coast}
[[robots]]
vehicle = "firefly"
start = [0.0, 0.0, 1.5]
goal = [0.0, -3.0, 1.5]
end_state = "free"
[[robots]]
vehicle = "firefly"
start = [4.0, 0.0, 1.5]
goal = [{gx}, 0.0, 1.5]
end_state = "{end}"
"""


@pytest.fixture(scope="module")
def beside_frozen():
    """Robot 1 flies to a goal gx m from robot 0, which never moves and never talks.
    Robot 0 has a free end in every case, so that the rest and free cases compile one
    closed loop (the coast rows are there for both; tests/conftest.py on compile time)."""
    def go(gx, end="rest", coast=8):
        doc = tomllib.loads(FROZEN.format(gx=gx, end=end, coast=coast))
        return run(parse_config(doc, source="frozen.toml"))
    return go


@pytest.mark.slow  # the closed loop beside a frozen robot, its own program (~21 s for the
# four): `make test-slow`
def test_goal_inside_the_inflation_of_a_silent_robot_is_reached(beside_frozen):
    # planning distance 0.73 m (two 0.315 m Fireflys + 0.05 m margins); a silent robot
    # is inflated by up to MAX_INFLATION: 0.95 m lies inside that, outside the radii
    res = beside_frozen(0.95)
    m = res.metrics
    assert m["per_robot"][1]["reached"], m["per_robot"][1]
    assert m["collisions"] == 0
    assert m["faults"]["collisions_involving_responsive"] == 0


@pytest.mark.slow
def test_goal_inside_a_frozen_robot_waits_beside_it(beside_frozen):
    res = beside_frozen(0.5)  # inside the planning distance: unreachable, safely
    m = res.metrics
    assert m["collisions"] == 0
    assert not m["per_robot"][1]["reached"]
    assert m["fallbacks"]["goal_occupied"] > 0
    assert m["faults"]["goal_occupied"] == m["fallbacks"]["goal_occupied"]
    end = res.arrays["pos"][1, -1]
    # it waits at the nearest free point, not somewhere else
    d = np.linalg.norm(end - np.array([0.0, 0.0, 1.5]))
    assert 0.73 - 1e-3 <= d <= 0.73 + GOAL_CLEARANCE + 0.02
    assert np.linalg.norm(end - np.array([0.5, 0.0, 1.5])) < 0.3


@pytest.mark.slow
def test_free_end_stops_short_of_a_frozen_robot_beyond_its_goal(beside_frozen):
    # a free-end plan may arrive at speed; with robot 0 just beyond the goal the coast
    # constraints (planner.coast_samples, default 8) make it arrive slowly enough to
    # stop.  Without them (coast_samples = 0) this run collided: min d / rho 0.0067.
    res = beside_frozen(0.95, end="free")
    m = res.metrics
    assert m["collisions"] == 0, m["min_separation_ratio"]
    assert m["min_separation_ratio"] > 1.0
    assert m["per_robot"][1]["reached"], m["per_robot"][1]


@pytest.mark.slow
def test_free_end_robot_waits_still_beside_a_frozen_robot_on_its_goal(beside_frozen):
    # the goal moved out of the frozen robot: the robot plans a rest end there and
    # hovers, rather than flying through the moved goal and back at speed
    res = beside_frozen(0.5, end="free")
    m = res.metrics
    assert m["collisions"] == 0
    assert m["fallbacks"]["goal_occupied"] > 0
    t = res.arrays["t"]
    late = t >= t[-1] - 3.0
    speed = np.linalg.norm(res.arrays["vel"][1, late], axis=-1)
    assert np.max(speed) < 0.05, np.max(speed)
    d = np.linalg.norm(res.arrays["pos"][1, late] - np.array([0.0, 0.0, 1.5]), axis=-1)
    assert np.all(d >= 0.73 - 1e-3) and np.all(d <= 0.73 + GOAL_CLEARANCE + 0.03), d


def test_goal_between_two_overlapping_occupants_ends_outside_both():
    # A at the origin, B 1.17 m away (their spheres of 2R + clearance overlap); the goal
    # 0.05 m from A.  A point outside both exists (e.g. on the far side of A from B).
    # The projection passes alternate between A and B and end inside one (random_box_20,
    # robot 0 frozen, seed 8: docs/RESULTS.md, faults notes)
    occ = [[0.0, 0, 0], [1.15, 0.2, 0]]
    g, _, moved = _call([0.05, 0.01, 0], [3.9, -1.3, 0], occ)
    assert moved
    for c in occ:
        assert np.linalg.norm(g - np.asarray(c)) >= 2 * R + GOAL_CLEARANCE - 1e-9


def _ray_reference(goal, centres, radii, n_dirs):
    """The nearest point outside every sphere, by brute force: along each of n_dirs
    directions (evenly round the circle, or a Fibonacci lattice on the sphere) the first
    point outside them all; the distance of the nearest.  The nearest clear point lies
    on the ray towards it, so this converges to it from above as n_dirs grows."""
    k = np.arange(n_dirs)
    if goal.shape[0] == 3:
        z = 1 - (2 * k + 1) / n_dirs
        a = np.pi * (3 - np.sqrt(5)) * k
        dirs = np.stack([np.sqrt(1 - z * z) * np.cos(a), np.sqrt(1 - z * z) * np.sin(a), z], -1)
    else:
        a = 2 * np.pi * k / n_dirs
        dirs = np.stack([np.cos(a), np.sin(a)], -1)
    gc = goal - centres
    b = dirs @ gc.T
    disc = b ** 2 - (np.sum(gc ** 2, -1) - radii ** 2)
    sq = np.sqrt(np.maximum(disc, 0.0))
    t1 = np.where(disc > 0, -b - sq, np.inf)
    t2 = np.where(disc > 0, -b + sq, -np.inf)
    t = np.concatenate([np.zeros((n_dirs, 1)), np.maximum(t2, 0.0)], 1)  # 0 or an exit
    inside = (t1[:, None, :] < t[..., None] - 1e-12) & (t[..., None] < t2[:, None, :] - 1e-12)
    return float(np.min(np.where(inside.any(-1), np.inf, t)))


@pytest.mark.parametrize("N", [2, 3])
def test_goal_in_a_cluster_of_occupants_moves_to_the_nearest_clear_point(N):
    # 48 clusters of up to 6 occupants 0.7 m or more apart (as robots are) within 1.5 m of
    # the goal, their spheres of 2R + floor + clearance overlapping; some masked or NaN
    # (ignored).  The goal planned to is outside every counted sphere and, against a
    # dense brute-force search, the nearest such point; the shrunk inflations leave it
    # GOAL_CLEARANCE outside every counted occupant's inflated distance
    rng = np.random.default_rng(7 + N)
    B, n = 48, 6
    M = n + 1
    goals, pos = np.zeros((B, M, N)), np.zeros((B, M, N))
    occ, floor = np.zeros((B, M, M, N)), np.zeros((B, M, M))
    mask = np.ones((B, M, M), bool) & ~np.eye(M, dtype=bool)
    for b in range(B):
        goals[b, 0] = rng.uniform(-1, 1, N)
        pos[b, 0] = goals[b, 0] + rng.normal(size=N) * 3
        cs = []
        while len(cs) < n:
            q = goals[b, 0] + rng.uniform(-1.5, 1.5, N)
            if all(np.linalg.norm(q - c) >= 0.7 for c in cs):
                cs.append(q)
        occ[b, 0, 1:] = cs
        floor[b, 0, 1:] = rng.uniform(0.0, 0.3, n)
        mask[b, 0, 1:] = rng.random(n) < 0.85
        if b % 8 == 0:
            occ[b, 0, 1, 0] = np.nan
    g, inf, moved = jax.jit(jax.vmap(_free_goals))(
        jnp.asarray(goals), jnp.asarray(pos), jnp.asarray(occ), jnp.full((B, M), R),
        jnp.full((B, M, M), MAX_INFLATION), jnp.asarray(mask), jnp.asarray(floor))
    g, inf, moved = np.asarray(g)[:, 0], np.asarray(inf)[:, 0], np.asarray(moved)[:, 0]
    n_moved = 0
    for b in range(B):
        count = mask[b, 0] & np.all(np.isfinite(occ[b, 0]), -1)
        c = occ[b, 0, count]
        target = 2 * R + floor[b, 0, count] + GOAL_CLEARANCE
        assert np.all(np.linalg.norm(g[b] - c, axis=-1) >= target - 1e-9), b
        assert np.all(np.linalg.norm(g[b] - c, axis=-1)
                      >= 2 * R + inf[b, count] + GOAL_CLEARANCE - 1e-9), b
        was_inside = bool(np.any(np.linalg.norm(goals[b, 0] - c, axis=-1) < target))
        assert moved[b] == was_inside, b
        n_moved += was_inside
        ref = _ray_reference(goals[b, 0], c, target, 20000 if N == 3 else 4000)
        assert np.linalg.norm(g[b] - goals[b, 0]) <= ref + 1e-6, b
    assert n_moved >= B // 2  # the clusters do hold most goals


@pytest.mark.slow  # a 20-robot closed loop of its own (~30 s): `make test-slow`
def test_frozen_random_box_20_seed_8_parks_beside_the_frozen_robot():
    # experiments/benchmarks/random_box_20.toml, seed 8, robot 0 frozen (silent) at 2 s:
    # robot 7's goal lies 0.25 m from where robot 0 froze, inside two overlapping
    # spheres (robot 0 held, robot 1's goal).  With the goal projection ending inside
    # one, every solve of robot 7 was infeasible and it flew its least violating plans
    # away (escape_m 40.6 m at 30 s, 12.7 m at 15 s).  It parks beside robot 0.
    m = run(frozen_random_box_20_seed_8(duration_s=15.0)).metrics
    r7 = m["per_robot"][7]
    assert r7["escape_m"] == 0.0 and r7["parked"], r7
    assert m["collisions"] == 0
    assert m["success"], m["per_robot"]
