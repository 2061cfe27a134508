"""Scenario construction: determinism, invariants, the paper's four, the generators."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxplan import scenarios as S
from jaxplan.scenarios import ScenarioError
from jaxplan.vehicles import ROBOTS

FIELDS = ("start", "waypoints", "rest", "goal_velocity", "has_goal_velocity", "radius",
          "v_max", "a_max", "j_max")


def same(a: S.Scenario, b: S.Scenario) -> bool:
    return a.vehicles == b.vehicles and all(
        np.array_equal(getattr(a, f), getattr(b, f)) for f in FIELDS)


def pair_dists(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    i, j = np.triu_indices(len(x), k=1)
    return np.linalg.norm(x[i] - x[j], axis=-1), i, j


def transits(sc: S.Scenario) -> np.ndarray:
    pts = np.concatenate([sc.start[:, None], sc.waypoints], axis=1)
    return np.linalg.norm(np.diff(pts, axis=1), axis=-1)


# ------------------------------------------------------------------ every registered one


@pytest.mark.parametrize("name", list(S.SCENARIOS))
def test_deterministic_for_a_seed_and_different_across_seeds(name):
    spec = S.SCENARIOS[name]
    a, b = spec.build(seed=3), spec.build(seed=3)
    assert same(a, b)
    c = spec.build(seed=4)
    assert not np.array_equal(a.start, c.start) or not np.array_equal(a.waypoints, c.waypoints)
    assert S.build(name, 3).vehicles == a.vehicles


@pytest.mark.parametrize("name", list(S.SCENARIOS))
@pytest.mark.parametrize("seed", [0, 1, 7])
def test_invariants(name, seed):
    sc = S.SCENARIOS[name].build(seed=seed)
    M, N, W = sc.num_robots, sc.dim, sc.num_waypoints
    assert sc.start.shape == (M, N) and sc.waypoints.shape == (M, W, N)
    assert sc.rest.shape == (M, W) and sc.rest.dtype == bool
    assert sc.goal_velocity.shape == (M, W, N) and sc.has_goal_velocity.shape == (M, W)
    for f in ("radius", "v_max", "a_max", "j_max"):
        assert getattr(sc, f).shape == (M,) and np.all(getattr(sc, f) > 0)
    np.testing.assert_allclose(sc.radius, [ROBOTS[v].radius for v in sc.vehicles])
    for f in FIELDS:
        assert not getattr(sc, f).flags.writeable
    rho = sc.safety_distance
    for w in range(W):
        d, i, j = pair_dists(sc.waypoints[:, w])
        assert np.all(d >= rho[i, j]), (w, d.min())
    assert len({tuple(p) for p in sc.start}) == M  # no coincident starts
    if N == 3:
        assert np.all(sc.start[:, 2] >= sc.radius)
        assert np.all(sc.waypoints[..., 2] >= sc.radius[:, None])
    assert S.scenario_problems(sc) == []


# ----------------------------------------------------------------------- paper scenarios

PAPER = list(S.PAPER_SCENARIOS)


@pytest.mark.parametrize("name", PAPER)
@pytest.mark.parametrize("seed", range(5))
def test_paper_geometry(name, seed):
    sc = S.SCENARIOS[name].build(seed=seed)
    assert sc.dim == 3
    pts = np.concatenate([sc.start[:, None], sc.waypoints], axis=1)
    # Inside an ~8 x 8 x 4 m arena, at least 1 m above ground.
    assert np.all(np.abs(pts[..., :2]) <= 4.0) and np.all(pts[..., 2] >= 1.0)
    assert np.all(pts[..., 2] <= 4.0)
    # Goal spacing with a margin.
    for w in range(sc.num_waypoints):
        d, i, j = pair_dists(sc.waypoints[:, w])
        assert np.all(d >= sc.safety_distance[i, j] + 0.15)
    # Long enough to reach 2 m/s (a rest-to-rest quintic needs ~2.5 m under the limits).
    assert transits(sc).min() >= 3.0


def test_six_neos():
    sc = S.paper_six_neos(0)
    assert sc.vehicles == ("neo11",) * 6 and sc.num_waypoints == 1
    assert not sc.rest.any() and not sc.has_goal_velocity.any()
    d, _, _ = pair_dists(sc.start)
    assert d.min() >= 1.2


def test_eight_fireflys_stacked():
    sc = S.paper_eight_fireflys_stacked(0)
    assert sc.vehicles == ("firefly",) * 8
    assert not sc.rest.any()
    d, i, j = pair_dists(sc.start)
    rho = sc.safety_distance[i, j]
    # tightly packed but not overlapping: vertical neighbours within 15% of r_i + r_j
    assert np.all(d > rho) and np.sum(d < 1.15 * rho) >= 6
    # stacked above each other: robots share (x, y) columns
    xy = np.round(S.STACKED_START[:, :2], 6)
    assert len({tuple(p) for p in xy}) == 2


def test_eight_mixed_transitions():
    sc = S.paper_eight_mixed_transitions(0)
    assert sorted(sc.vehicles).count("firefly") == 5 and sc.vehicles.count("neo11") == 3
    assert sc.num_waypoints == 4
    assert np.all(sc.rest[:, 0]) and not sc.rest[:, 1:].any()


def test_ten_mixed_rest():
    sc = S.paper_ten_mixed_rest(0)
    assert sc.vehicles.count("firefly") == 5 and sc.vehicles.count("neo11") == 5
    assert sc.rest.all() and sc.num_waypoints == 1


# ---------------------------------------------------------------------------- generators


@pytest.mark.parametrize("seed", range(4))
def test_antipodal_sphere_goal_is_minus_start_about_centre(seed):
    c = np.array([0.5, -0.5, 5.0])
    sc = S.antipodal_sphere(10, 4.0, ["firefly", "neo11"], seed, center=c, perturbation=0.05)
    np.testing.assert_allclose(np.linalg.norm(sc.start - c, axis=1), 4.0)
    off = (sc.goal - c) + (sc.start - c)
    assert np.all(np.linalg.norm(off, axis=1) <= 0.05 + 1e-12)
    assert np.any(np.linalg.norm(off, axis=1) > 0)  # symmetry broken
    assert sc.vehicles == ("firefly", "neo11") * 5


def test_antipodal_circle_and_random_placement():
    sc = S.antipodal_sphere(8, 3.0, ["hummingbird"], 2, dim=2, perturbation=0.0)
    assert sc.dim == 2
    np.testing.assert_allclose(np.linalg.norm(sc.start, axis=1), 3.0)
    np.testing.assert_allclose(sc.goal, -sc.start, atol=1e-12)
    r = S.antipodal_sphere(12, 4.0, ["neo11"], 5, placement="random", min_spacing=1.5)
    d, _, _ = pair_dists(r.start)
    assert d.min() >= 1.5
    with pytest.raises(ScenarioError, match="placement"):
        S.antipodal_sphere(4, 4.0, placement="spiral")


def test_antipodal_default_centre_keeps_robots_above_ground():
    sc = S.antipodal_sphere(40, 4.0, ["neo11"], 0)
    assert sc.start[:, 2].min() >= 1.0 - 1e-9


@given(seed=st.integers(0, 2**32), count=st.integers(1, 25))
@settings(max_examples=40, deadline=None)
def test_random_box_spacing(seed, count):
    box = np.array([[-4.0, -4.0, 1.0], [4.0, 4.0, 4.0]])
    sc = S.random_box(count, box, 1.2, ["firefly", "neo11"], seed, goal_spacing=1.1,
                      min_travel=2.0)
    assert np.all(sc.start >= box[0]) and np.all(sc.start <= box[1])
    assert np.all(sc.goal >= box[0]) and np.all(sc.goal <= box[1])
    if count > 1:
        assert pair_dists(sc.start)[0].min() >= 1.2
        assert pair_dists(sc.goal)[0].min() >= 1.1
    assert np.all(np.linalg.norm(sc.goal - sc.start, axis=1) >= 2.0)


def test_random_box_fails_clearly_when_crowded():
    with pytest.raises(ScenarioError, match="could not place the start of robot"):
        S.random_box(50, [[0, 0, 1], [1, 1, 2]], 1.0, ["firefly"], 0, max_tries=200)
    with pytest.raises(ScenarioError, match="could not place the goal"):
        S.random_box(2, [[0, 0, 1], [1.5, 0.1, 1.1]], 0.7, ["firefly"], 0, min_travel=5.0)


def test_random_box_2d():
    sc = S.random_box(5, [[0, 0], [5, 5]], 1.0, ["firefly"], 1)
    assert sc.dim == 2


def test_grid_swap_mirrors_through_centre():
    c = np.array([1.0, 2.0, 2.5])
    sc = S.grid_swap(2, 3, 1.5, ["firefly"], 0, center=c, jitter=0.0)
    assert sc.num_robots == 6
    np.testing.assert_allclose(sc.goal - c, -(sc.start - c) * np.array([1, 1, 1]), atol=1e-12)
    # every goal is another robot's start (a permutation of the grid)
    for g in sc.goal:
        assert np.min(np.linalg.norm(sc.start - g, axis=1)) < 1e-9
    j = S.grid_swap(2, 3, 1.5, ["firefly"], 0, center=c, jitter=0.05)
    assert np.all(np.linalg.norm(j.start - sc.start, axis=1) <= 0.05 + 1e-12)
    with pytest.raises(ScenarioError, match="both odd"):
        S.grid_swap(3, 3)


def test_stacked_is_a_vertical_stack_to_a_row():
    sc = S.stacked(5, 0.5, ["firefly"], 0, jitter=0.0)
    assert np.ptp(sc.start[:, 0]) == 0 and np.ptp(sc.start[:, 1]) == 0
    np.testing.assert_allclose(np.diff(sc.start[:, 2]), 0.5)
    np.testing.assert_allclose(np.diff(sc.goal[:, 1]), 1.0)
    d, i, j = pair_dists(sc.start)
    assert np.any(d < sc.safety_distance[i, j])  # allowed: tightly packed start
    assert S.stacked(4, dim=2).dim == 2


def test_vehicles_are_cycled():
    sc = S.stacked(5, vehicles=["firefly", "neo11", "hummingbird"])
    assert sc.vehicles == ("firefly", "neo11", "hummingbird", "firefly", "neo11")
    with pytest.raises(ScenarioError, match="unknown vehicle"):
        S.stacked(3, vehicles=["crazyflie"])


@pytest.mark.parametrize("bad", [0, -1, 2.5, True, S.MAX_ROBOTS + 1])
def test_generators_reject_bad_counts(bad):
    with pytest.raises(ScenarioError, match="count"):
        S.antipodal_sphere(bad)


# ------------------------------------------------------------------------- make_scenario


def test_make_scenario_pads_waypoints_and_flags():
    sc = S.make_scenario(
        "pad", ["firefly", "neo11"], [[0, 0, 1], [0, 3, 1]],
        [[[3, 0, 1]], [[3, 3, 1], [5, 3, 1], [5, 5, 2]]],
        rest=[[True], [False, False, True]],
        goal_velocity=[None, [None, [1.0, 0, 0], None]],
    )
    assert sc.waypoints.shape == (2, 3, 3)
    np.testing.assert_array_equal(sc.waypoints[0], [[3, 0, 1]] * 3)
    np.testing.assert_array_equal(sc.rest, [[True] * 3, [False, False, True]])
    np.testing.assert_array_equal(sc.has_goal_velocity, [[False] * 3, [False, True, False]])
    np.testing.assert_array_equal(sc.goal_velocity[1, 1], [1, 0, 0])
    lim = sc.with_limits(v_max=1.5)
    np.testing.assert_array_equal(lim.v_max, [1.5, 1.5])
    np.testing.assert_array_equal(lim.a_max, sc.a_max)


def test_validation_problems():
    with pytest.raises(ScenarioError, match="start at the same point"):
        S.make_scenario("x", ["firefly"] * 2, [[0, 0, 1], [0, 0, 1]], [[3, 0, 1], [3, 3, 1]])
    with pytest.raises(ScenarioError, match="safety distance"):
        S.make_scenario("x", ["firefly"] * 2, [[0, 0, 1], [0, 1, 1]], [[3, 0, 1], [3, 0.5, 1]])
    with pytest.raises(ScenarioError, match="inside the ground"):
        S.make_scenario("x", ["neo11"], [[0, 0, 0.3]], [[3, 0, 1]])
    with pytest.raises(ScenarioError, match="rest end state has v = 0"):
        S.make_scenario("x", ["neo11"], [[0, 0, 1]], [[3, 0, 1]], rest=True,
                        goal_velocity=[[[1.0, 0, 0]]])
    # closer-than-rho STARTS are allowed (paper's stacked scenario)
    S.make_scenario("x", ["firefly"] * 2, [[0, 0, 1], [0, 0, 1.3]], [[3, 0, 1], [3, 3, 1]])
    # a 2-D scenario has no ground
    S.make_scenario("x", ["firefly"], [[0, -5]], [[3, -5]])


def test_registry_has_descriptions():
    for name, spec in S.SCENARIOS.items():
        assert spec.name == name and spec.description and "\n" not in spec.description
    assert set(S.PAPER_SCENARIOS) <= set(S.SCENARIOS)
    assert set(S.GENERATORS) <= set(S.SCENARIOS)
    assert all(S.SCENARIOS[n].paper for n in S.PAPER_SCENARIOS)


def test_seeds_are_independent_streams():
    a = [S.paper_six_neos(s).start for s in range(6)]
    for x, y in itertools.combinations(a, 2):
        assert not np.allclose(x, y)


def test_each_generator_has_a_parameter_model_with_its_defaults():
    """The [scenario] keys are declared once, by the generator's parameter model: every
    generator argument (besides seed and validate) is one of its keys, and a default the
    model gives is the generator's."""
    import dataclasses
    import inspect

    assert set(S.GENERATOR_PARAMS) == set(S.GENERATORS)
    for kind, model in S.GENERATOR_PARAMS.items():
        assert model.kind == kind
        assert S.GENERATORS[kind] is model.generator and model.generator.__name__ == kind
        args = inspect.signature(S.GENERATORS[kind]).parameters
        assert set(args) - {"seed", "validate"} <= set(model.keys())
        for f in dataclasses.fields(model):
            if f.name in args and f.default not in (None, dataclasses.MISSING):
                assert args[f.name].default == f.default, (kind, f.name)


def test_a_parameter_model_builds_what_its_generator_builds():
    p = S.GridSwapParams(rows=2, cols=3, dim=2, end_state="rest").resolved()
    assert p.center == (0.0, 0.0)
    assert same(p.build(seed=4), S.grid_swap(2, 3, seed=4, dim=2, end_state="rest"))
    b = S.RandomBoxParams(count=4, dim=3, end_state="free").resolved()
    assert b.goal_spacing == b.min_spacing == round(S.default_spacing(["firefly"]), 6)
    assert same(b.build(seed=1), S.random_box(4, seed=1, min_spacing=b.min_spacing))
