"""The guide round walls (jaxplan/planner/guide.py): the segment clearance against dense
sampling, the field against exact shortest paths, the guide point, and a ground robot
behind a wall that reaches its goal through the opening."""

import tomllib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxplan  # noqa: F401  (float64)
from jaxplan import experiment as ex
from jaxplan.config import parse_config
from jaxplan.planner.guide import (
    grid_distance,
    guide_enabled,
    guide_field,
    guide_goals,
    segment_clearance,
)
from jaxplan.testing import random_obstacles
from jaxplan.world import (
    World,
    obstacle_arrays,
    rows_as_jax,
    signed_distance,
    static_rows,
)

# a wall at x = 0 (0.2 m thick) from y = 0.75 to y = 5, in the plane, the workspace
# y in [-1, 5]: the only way from x > 0 to x < 0 is the opening y in [-1, 0.75]
WALL = [dict(kind="box", center=[0.0, 2.875], half_extents=[0.1, 2.125])]
LO, HI = np.array([-np.inf, -1.0]), np.array([np.inf, 5.0])


def _world(obs, lo=LO, hi=HI):
    return World(lo, hi, *obstacle_arrays(obs, len(lo)))


def _rows(world):
    return rows_as_jax(static_rows(world))


_seg = jax.jit(jax.vmap(segment_clearance, in_axes=(None, 0, 0)))


def test_segment_clearance_matches_dense_sampling():
    """The least clearance of random segments to random spheres, boxes and cylinders
    (and workspace faces) equals the minimum over 20001 points of each segment to half
    a sample step (never above it: the search is exact for convex rows), thin boxes
    included, which a coarse sampling would step over."""
    rng = np.random.default_rng(3)
    obs = random_obstacles(rng, 3, 4.0, 0.02, 0.1)
    w = _world(obs, np.array([-6.0, -np.inf, -1.0]), np.array([6.0, 6.0, np.inf]))
    rows = static_rows(w)
    a, b = rng.uniform(-5, 5, (64, 3)), rng.uniform(-5, 5, (64, 3))
    got = np.asarray(_seg(_rows(w), jnp.asarray(a), jnp.asarray(b)))
    t = np.linspace(0.0, 1.0, 20001)
    want = np.array([signed_distance(*rows[:4], a[i] + t[:, None] * (b[i] - a[i])).min()
                     for i in range(64)])
    # sd is 1-Lipschitz: the true minimum is at most half a sample step below the
    # sampled one, and never above it
    half_step = np.linalg.norm(b - a, axis=1) / 20000 / 2
    assert np.all(got <= want + 1e-9)
    assert np.all(want - got <= half_step + 1e-9)
    assert np.sum(got < 0) > 10 and np.sum(got > 0) > 10  # both kinds of segment


def _path_through_opening(p, g, r):
    """Exact shortest way (2-D) from p (x > 0) to g (x < 0) past the wall's lower end
    for a disc of radius r: round the two corners (0.1 +- ..., 0.75) grown by r, i.e.
    two tangent segments and an arc, when the straight line is blocked."""
    # the grown corner region: the wall's end is a box end; a disc of radius r round
    # the corners (+-0.1, 0.75) and the segment between them
    c1, c2 = np.array([0.1, 0.75]), np.array([-0.1, 0.75])

    def tangent(q, c):
        d = np.linalg.norm(q - c)
        return np.sqrt(max(d * d - r * r, 0.0)), d

    l1, d1 = tangent(p, c1)
    l2, d2 = tangent(g, c2)
    # angles of the tangent points on each corner circle, from below the wall
    a1 = np.arctan2(p[1] - c1[1], p[0] - c1[0]) - np.arccos(min(r / d1, 1.0))
    a2 = np.arctan2(g[1] - c2[1], g[0] - c2[0]) + np.arccos(min(r / d2, 1.0))
    # the arc from the tangent on c1 round to straight below (-pi/2), the 0.2 m flat,
    # and round to the tangent on c2
    wrap = lambda x: (x + np.pi) % (2 * np.pi) - np.pi  # noqa: E731
    arc1 = abs(wrap(a1 + np.pi / 2)) * r
    arc2 = abs(wrap(a2 + np.pi / 2)) * r
    return l1 + arc1 + 0.2 + arc2 + l2


def test_field_is_the_shortest_way_round():
    """In the plane with the wall: the field at points behind the wall is the exact
    shortest way (tangents and arcs round the wall's end) to within the grid's error
    (8-neighbour paths: at most 8.3% longer, less than a cell shorter); in front of it
    (a clear line) the straight distance."""
    r = 0.3
    w = _world(WALL)
    goal = np.array([-3.0, 3.0])
    f = guide_field(w, goal[None, None], np.array([r]), starts=np.array([[4.0, 4.0]]))
    assert f.value.shape == (1, 1, 96, 96)
    from jaxplan.planner.guide import field_value
    val = jax.jit(field_value)
    cell = float(np.max(f.spacing))
    for p in ([3.0, 3.0], [1.5, 4.2], [4.0, 1.0]):
        p = np.array(p)
        want = _path_through_opening(p, goal, r)
        got = float(val(jnp.asarray(f.value[0, 0]), jnp.asarray(f.origin),
                        jnp.asarray(f.spacing), jnp.asarray(p)))
        assert want - 2 * cell < got < 1.083 * want + 2 * cell, (p, got, want)
        assert got > np.linalg.norm(p - goal) + 1.0  # the way round, not through
    p = np.array([-1.0, -0.5])  # sees the goal
    got = float(val(jnp.asarray(f.value[0, 0]), jnp.asarray(f.origin), jnp.asarray(f.spacing),
                    jnp.asarray(p)))
    d = np.linalg.norm(p - goal)
    assert d - 2 * cell < got < 1.083 * d + 2 * cell
    # where nothing is in the way the field is the grid's free-space path length
    assert abs(got - float(grid_distance(jnp.asarray(p - goal)))) < cell


def test_guide_point_leads_to_the_opening():
    """A robot behind the wall takes a guide point that it sees clear by its radius,
    on the way round, down towards the opening; one that sees its goal does not use
    the guide, nor one whose line passes through a small pillar (a short detour)."""
    r = 0.3
    w = _world(WALL + [dict(kind="cylinder", center=[3.0, 1.5], radius=0.3)])
    goals = np.array([[-3.0, 3.0], [3.0, 0.0], [1.0, 1.5]])
    starts = np.array([[2.0, 3.5], [2.0, 3.5], [4.5, 1.5]])
    f = guide_field(w, goals[:, None], np.full(3, r), starts=starts)
    rows = _rows(w)
    assert float(segment_clearance(rows, jnp.asarray(starts[2]), jnp.asarray(goals[2]))) < 0
    point, use = jax.jit(guide_goals)(jnp.asarray(f.value[0]), jnp.asarray(f.origin),
                                      jnp.asarray(f.spacing), rows, jnp.full(3, r),
                                      jnp.asarray(starts), jnp.asarray(goals))
    point, use = np.asarray(point), np.asarray(use)
    assert use.tolist() == [True, False, False]
    q = point[0]
    assert float(segment_clearance(rows, jnp.asarray(starts[0]), jnp.asarray(q))) >= r
    assert q[1] < 2.0 and np.linalg.norm(q - starts[0]) > 1.0  # down towards the opening


def test_guide_enabled_modes():
    w0, w1 = World.default(3), _world(WALL)
    assert not guide_enabled("auto", w0) and guide_enabled("auto", w1)
    assert guide_enabled("on", w0) and not guide_enabled("off", w1)
    with pytest.raises(ValueError, match="guide"):
        guide_enabled("always", w1)


GROUND = """
name = "behind_the_wall"
[sim]
duration_s = 14.0
[planner]
guide = "{guide}"
[[robots]]
vehicle = "ground"
start = [2.0, 3.5]
goal = [-2.5, 3.5]
[workspace]
min = [-4.0, -1.0]
max = [4.0, 5.0]
[[obstacles]]
kind = "box"
center = [0.0, 2.875]
half_extents = [0.1, 2.125]
"""


@pytest.mark.slow  # a planar closed loop with the guide, its own program (~14 s): make test-slow
def test_a_ground_robot_behind_a_wall_goes_through_the_opening():
    """A robot whose goal lies straight behind a wall, the opening 2.8 m off to the
    side: with the guide it reaches its goal, collision-free, by the exact checks."""
    cfg = parse_config(tomllib.loads(GROUND.format(guide="auto")), source="g.toml")
    res = ex.run(cfg)
    m = res.metrics
    assert m["obstacle_collisions"] == 0 and m["workspace_violations"] == 0
    assert m["success"], m
    assert m["makespan_s"] < 14.0
