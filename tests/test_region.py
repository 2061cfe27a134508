"""The fleet's region (``[planner] region = "fleet"``): the planner's world is the
scenario's with its workspace cut to the box of the starts and waypoints grown by
region_margin_m; the metrics keep the scenario's world."""


import numpy as np
import pytest

from jaxplan.config import ConfigError, build_scenario, parse_config
from jaxplan.run_setup import fleet_params, planner_rows, planner_world, structures
from jaxplan.world import PLANE, static_rows
from tests._fleets import frozen_random_box_20_seed_8


def _config(planner=None, workspace=None, obstacles=()):
    doc = {"name": "region", "planner": planner or {},
           "robots": [{"vehicle": "firefly", "start": [0.0, 0.0, 1.5], "goal": [4.0, 1.0, 2.5]},
                      {"vehicle": "firefly", "start": [4.0, -1.0, 2.0],
                       "waypoints": [[2.0, 3.0, 2.0], [0.0, -1.0, 1.0]]}]}
    if workspace:
        doc["workspace"] = workspace
    if obstacles:
        doc["obstacles"] = list(obstacles)
    return parse_config(doc)


def test_default_region_is_the_workspace_alone():
    cfg = _config()
    sc = build_scenario(cfg)
    assert cfg.planner.region == "workspace" and cfg.planner.region_margin_m == 1.0
    assert planner_world(cfg, sc) is sc.world


def test_fleet_region_is_the_box_of_starts_and_waypoints_grown_and_cut_by_the_workspace():
    cfg = _config({"region": "fleet", "region_margin_m": 1.5},
                  workspace={"min": [-1.0, -10.0, 0.0], "max": [10.0, 10.0, 3.0]},
                  obstacles=[{"kind": "sphere", "center": [2.0, 0.0, 2.0], "radius": 0.3}])
    sc = build_scenario(cfg)
    w = planner_world(cfg, sc)
    # starts and waypoints span x [0, 4], y [-1, 3], z [1, 2.5]; grown by 1.5 m, then the
    # workspace's tighter faces: x_min -1 (workspace), z_max 3 (workspace)
    np.testing.assert_array_equal(w.lo, [-1.0, -2.5, 0.0])
    np.testing.assert_array_equal(w.hi, [5.5, 4.5, 3.0])
    # the obstacles stay; the metrics' world is the scenario's own
    np.testing.assert_array_equal(w.center, sc.world.center)
    np.testing.assert_array_equal(sc.world.lo, [-1.0, -10.0, 0.0])
    rows = static_rows(w)
    assert planner_rows(cfg, sc) == 1 + 6 == rows.mask.shape[0]
    assert np.all(rows.kind[1:] == PLANE)


def test_fleet_region_faces_are_the_planners_static_rows():
    cfg = _config({"region": "fleet"})
    sc = build_scenario(cfg)
    fp = fleet_params(cfg, sc)
    st = fp.static
    # six planes (the default world's ground z >= 0 is the region's floor here)
    assert st.center.shape == (6, 3) and np.all(np.asarray(st.kind) == PLANE)
    n, c = np.asarray(st.half), np.asarray(st.center)
    lo = [float(c[i, a]) for a in range(3) for i in range(6) if n[i, a] == 1.0]
    hi = [float(c[i, a]) for a in range(3) for i in range(6) if n[i, a] == -1.0]
    np.testing.assert_array_equal(lo, [-1.0, -2.0, 0.0])
    np.testing.assert_array_equal(hi, [5.0, 4.0, 3.5])
    assert structures(cfg).planner.nlp.n_static == 6
    # without the region the NLP holds the ground alone
    plain = _config()
    assert fleet_params(plain, build_scenario(plain)).static.center.shape == (1, 3)


@pytest.mark.parametrize("planner, key", [
    ({"region": "box"}, "planner.region"),
    ({"region": "fleet", "region_margin_m": -1.0}, "planner.region_margin_m"),
    # a Firefly's radius (0.3 m) plus the default safety margin (0.05 m) does not fit
    ({"region": "fleet", "region_margin_m": 0.3}, "planner.region_margin_m"),
])
def test_bad_region_is_rejected_naming_its_key(planner, key):
    with pytest.raises(ConfigError, match=rf"{key}"):
        _config(planner)


@pytest.mark.slow  # a 20-robot closed loop of its own (~30 s): `make test-slow`
def test_frozen_random_box_20_seed_8_stays_in_the_region():
    # random_box_20 seed 8 with robot 0 frozen: without the region, robot 9's accepted
    # plans lift it over the crowd, 0.9 m beyond the box escape_m measures against
    # (docs/SOLVER.md, "Hard limits")
    from jaxplan.experiment import run

    m = run(frozen_random_box_20_seed_8(
        {"region": "fleet", "limits": "hard", "end_state": "auto"})).metrics
    assert m["escape_m"] == 0.0, [r["escape_m"] for r in m["per_robot"]]
    assert m["collisions"] == 0 and m["workspace_violations"] == 0
    assert m["success"], m["per_robot"]
