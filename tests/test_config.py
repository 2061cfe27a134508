"""Config parsing: errors name the file, the key and the problem; round trips; fuzzing."""

from __future__ import annotations

import dataclasses
import glob
import math
import os
import tomllib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxplan import config as C
from jaxplan import scenarios as S
from jaxplan.config import ConfigError, build_scenario, config_to_toml, load_config, parse_config

ROOT = Path(__file__).resolve().parents[1]
SRC = "experiments/x.toml"
FUZZ_EXAMPLES = int(os.environ.get("JAXPLAN_FUZZ_EXAMPLES", "400"))  # more: a longer fuzz run


def robot(**kw):
    r = {"vehicle": "firefly", "start": [0.0, 0.0, 1.0], "goal": [3.0, 0.0, 1.0]}
    r.update(kw)
    return {k: v for k, v in r.items() if v is not None}


def two(**kw):
    return {"robots": [robot(), robot(start=[0.0, 3.0, 1.0], goal=[3.0, 3.0, 1.0])], **kw}


def err(data) -> str:
    with pytest.raises(ConfigError) as e:
        parse_config(data, SRC)
    msg = str(e.value)
    assert "\n" not in msg
    assert type(e.value) is ConfigError and isinstance(e.value, ValueError)
    return msg


# (data, key, problem fragment)
ERRORS = [
    # wrong types
    (two(planner={"q_obs": "abc"}), "planner.q_obs", "expected a number, got 'abc'"),
    (two(planner={"q_obs": True}), "planner.q_obs", "expected a number, got True"),
    (two(planner={"degree": 5.0}), "planner.degree", "expected an integer"),
    (two(planner={"degree": True}), "planner.degree", "expected an integer"),
    (two(planner=5), "planner", "expected a table"),
    (two(seed="0"), "seed", "expected an integer"),
    (two(name=3), "name", "expected a string"),
    (two(sim={"backend": 1}), "sim.backend", "expected a string"),
    ({"robots": {"vehicle": "firefly"}}, "robots", "expected an array of tables"),
    ({"robots": [robot(start="here")]}, "robots[0].start", "expected an array"),
    ({"robots": [robot(start=[0, "a", 1])]}, "robots[0].start[1]", "expected a number"),
    # unknown keys, with suggestions
    (two(planner={"q_ob": 1.0}), "planner.q_ob", "unknown key; did you mean 'q_obs'?"),
    (two(plannner={}), "plannner", "did you mean 'planner'?"),
    ({"robots": [robot(strat=[0, 0, 1])]}, "robots[0].strat", "did you mean 'start'?"),
    (two(sim={"physic_hz": 1}), "sim.physic_hz", "did you mean 'physics_hz'?"),
    (two(sweep={"seed": [1]}), "sweep.seed", "did you mean 'seeds'?"),
    (two(faults={"rate": 0.1}), "faults.rate", "unknown key"),
    ({"scenario": {"kind": "paper:six_neos", "count": 3}}, "scenario.count", "unknown key"),
    ({"scenario": {"kind": "random_box", "count": 3, "spacing": 1}}, "scenario.spacing",
     "unknown key"),
    # impossible values
    (two(planner={"replan_hz": 0}), "planner.replan_hz", "must be >= 0.1"),
    (two(planner={"replan_hz": -8.0}), "planner.replan_hz", "must be >= 0.1"),
    (two(planner={"q_dynm": 0}), "planner.q_dynm", "must be >= 1e-06, got 0"),
    (two(planner={"n_samples": 30}), "planner.n_samples", "must be a multiple of 4, got 30"),
    (two(planner={"degree": 12}), "planner.degree", "must be <= 9, got 12"),
    (two(planner={"degree": 4}), "planner.degree", "must be >= 5, got 4"),
    (two(planner={"segments": 0}), "planner.segments", "must be >= 1, got 0"),
    (two(planner={"q_obs": -1.0}), "planner.q_obs", "must be >= 0"),
    (two(planner={"coast_samples": -1}), "planner.coast_samples", "must be >= 0"),
    (two(planner={"coast_samples": 2.5}), "planner.coast_samples", "expected an integer"),
    (two(planner={"solver_pool": -1}), "planner.solver_pool", "must be >= 0"),
    (two(planner={"solver_pool": 1.5}), "planner.solver_pool", "expected an integer"),
    (two(planner={"k_p": 0.0}), "planner.k_p", "must be >= 0.001"),
    (two(planner={"collision": "barier"}), "planner.collision",
     "unknown value 'barier' (did you mean 'barrier'?)"),
    (two(planner={"end_state": "stop"}), "planner.end_state", "unknown value 'stop'"),
    (two(limits={"v_max": 0.0}), "limits.v_max", "must be >= 0.001"),
    (two(limits={"a_max": -2.0}), "limits.a_max", "must be >= 0.001"),
    (two(limits={"j_max": math.inf}), "limits.j_max", "finite"),
    (two(planner={"q_lim": math.nan}), "planner.q_lim", "finite"),
    (two(sim={"backend": "gazebo"}), "sim.backend", "unknown value 'gazebo'"),
    (two(sim={"duration_s": 0}), "sim.duration_s", "must be > 0"),
    (two(sim={"control_hz": 300.0}), "sim.control_hz", "whole number"),
    (two(seed=-1), "seed", "must be >= 0"),
    (two(faults={"enabled": True, "message_loss": 1.5}), "faults.message_loss", "< 1"),
    ({"robots": [robot(vehicle="crazyflie")]}, "robots[0].vehicle", "unknown value 'crazyflie'"),
    ({"robots": [robot(cooperative="no")]}, "robots[0].cooperative", "expected true or false"),
    ({"robots": [robot(vehicle=None)]}, "robots[0].vehicle", "missing"),
    ({"robots": [robot(start=None)]}, "robots[0].start", "missing"),
    ({"robots": [robot(goal=None)]}, "robots[0].goal", "exactly one of 'goal'"),
    ({"robots": [robot(waypoints=[[1, 1, 1]])]}, "robots[0].goal", "exactly one of 'goal'"),
    ({"robots": [robot(goal=None, waypoints=[])]}, "robots[0].waypoints", "non-empty"),
    ({"robots": [robot(end_state="halt")]}, "robots[0].end_state", "unknown value 'halt'"),
    ({"robots": [robot(end_state=["rest", "free"])]}, "robots[0].end_state",
     "one entry per waypoint"),
    ({"robots": [robot(goal_velocity=[1.0, 0.0, 0.0], end_state="rest")]},
     "robots[0].goal_velocity", "non-zero goal velocity"),
    ({"robots": [robot(goal_velocity=[1.0, 0.0])]}, "robots[0].goal_velocity",
     "expected 3 coordinates"),
    # wrong vector lengths / mixing 2-D and 3-D
    ({"robots": [robot(start=[0, 0, 1, 2])]}, "robots[0].start", "expected 2 or 3 coordinates"),
    ({"robots": [robot(start=[0])]}, "robots[0].start", "expected 2 or 3 coordinates"),
    ({"robots": [robot(goal=[1, 1])]}, "robots[0].goal", "mixing 2-D and 3-D"),
    ({"robots": [robot(), robot(start=[5, 5], goal=[6, 6])]}, "robots[1].start",
     "mixing 2-D and 3-D"),
    ({"scenario": {"kind": "stacked", "count": 3}, "robots": [robot(start=[9, 9], goal=[9, 0])]},
     "robots[0].start", "mixing 2-D and 3-D"),
    ({"scenario": {"kind": "stacked", "count": 3, "dim": 2, "base": [0, 0, 1]}}, "scenario.base",
     "expected 2 coordinates"),
    ({"robots": [robot(goal=[1.0, math.nan, 1.0])]}, "robots[0].goal[1]", "finite"),
    ({"robots": [robot(start=[1.0, -math.inf, 1.0])]}, "robots[0].start[1]", "finite"),
    # geometry
    ({"robots": [robot(), robot(goal=[3.0, 0.5, 1.0], start=[0, 3, 1])]}, "robots[1].goal",
     "closer than their safety distance r_i + r_j = 0.63 m"),
    ({"robots": [robot(), robot(goal=None, start=[0, 3, 1],
                               waypoints=[[3, 3, 1], [3.3, 0, 1]])]},
     "robots[1].waypoints[1]", "goals (waypoint 1) 0.3 m apart"),
    ({"robots": [robot(), robot(goal=[3, 3, 1])]}, "robots[1].start", "start at the same point"),
    ({"robots": [robot(start=[0, 0, 0.2])]}, "robots[0].start", "inside the ground"),
    ({"robots": [robot(vehicle="neo11", goal=[3, 0, 0.4])]}, "robots[0].goal",
     "inside the ground"),
    ({"scenario": {"kind": "antipodal_sphere", "count": 10, "radius": 0.5}}, "scenario",
     "closer than their safety distance"),
    ({"scenario": {"kind": "stacked", "count": 3}, "robots": [robot(start=[3, 0, 2],
                                                                    goal=[3.1, 0, 2])]},
     "robots[0].goal", "generated robot 1 and robots[0] have goals"),
    ({"scenario": {"kind": "random_box", "count": 300}}, "scenario.min_spacing",
     "could not place the start of robot"),
    ({"scenario": {"kind": "grid_swap", "rows": 3, "cols": 5}}, "scenario.rows", "both odd"),
    ({"scenario": {"kind": "antipodal_sphere", "count": 4, "radius": 0}}, "scenario.radius",
     "must be > 0"),
    ({"scenario": {"kind": "antipodal_sphere", "count": 4, "radius": -2.0}}, "scenario.radius",
     "must be > 0"),
    ({"scenario": {"kind": "antipodal_sphere", "count": 4, "radius": "big"}}, "scenario.radius",
     "expected a number, got 'big'"),
    ({"scenario": {"kind": "stacked", "count": 4, "spacing": 0.0}}, "scenario.spacing",
     "must be > 0"),
    ({"scenario": {"kind": "stacked", "count": 4, "jitter": 0.3}}, "scenario.jitter",
     "below half the stack spacing"),
    ({"robots": [robot(start=[1e9, 0, 1])]}, "robots[0].start[0]", "must be <= 1e+06"),
    # the fleet and the scenario table
    ({}, "robots", "the fleet is empty"),
    ({"robots": []}, "robots", "the fleet is empty"),
    ({"scenario": {"count": 3}}, "scenario.kind", "missing"),
    ({"scenario": {"kind": "paper:six_neo"}}, "scenario.kind", "did you mean 'paper:six_neos'?"),
    ({"scenario": {"kind": "random_box"}}, "scenario.count", "missing"),
    ({"scenario": {"kind": "random_box", "count": 0}}, "scenario.count", "must be >= 1"),
    ({"scenario": {"kind": "random_box", "count": 3, "box": [[0, 0, 1], [-1, 1, 2]]}},
     "scenario.box", "below lower corner"),
    ({"scenario": {"kind": "random_box", "count": 3, "vehicles": []}}, "scenario.vehicles",
     "non-empty"),
    ({"scenario": {"kind": "random_box", "count": 3, "vehicles": ["fire"]}},
     "scenario.vehicles[0]", "did you mean 'firefly'?"),
    ({"robots": [robot(start=[0, 0], goal=[3, 0])], "sim": {"backend": "mjx"}}, "sim.backend",
     "needs 3-D positions"),
    # sweep
    (two(sweep={"q_obs": []}), "sweep.q_obs", "non-empty"),
    (two(sweep={"q_obs": ["a"]}), "sweep.q_obs[0]", "expected a number"),
    (two(sweep={"q_lim": {"log_min": -1, "log_max": 1}}), "sweep.q_lim.num", "missing"),
    (two(sweep={"q_lim": {"log_min": 1, "log_max": -1, "num": 3}}), "sweep.q_lim.log_max",
     "must be >= 1"),
    (two(sweep={"q_lim": {"log_min": -1, "log_max": 1, "num": 3, "base": 2}}),
     "sweep.q_lim.base", "unknown key"),
    (two(sweep={"seeds": [0, -3]}), "sweep.seeds[1]", "must be >= 0"),
    (two(sweep={"seeds": 5}), "sweep.seeds", "expected a non-empty array"),
    (two(sweep={"scenarios": ["antipodal"]}), "sweep.scenarios[0]", "unknown value"),
    (two(sweep={"seeds": {1: 2}}), "sweep.seeds", "expected string keys, got 1"),
    (two(sweep={"seeds": {"start": 2**63 - 2, "num": 3}}), "sweep.seeds", "must be < 2**63"),
    (two(faults={"enabled": 1}), "faults.enabled", "expected true or false, got 1"),
    (two(faults={"latency_s": 11}), "faults.latency_s", "must be <= 10, got 11"),
    (two(planner={"q_obs": 2**2000}), "planner.q_obs", "number out of range"),
    ({"scenario": {"kind": "random_box", "count": 3, "box": [[0, 0], [1, 1, 1]]}},
     "scenario.box[1]", "expected 2 coordinates"),
]


@pytest.mark.parametrize("data,key,problem", ERRORS, ids=[f"{k}:{p[:30]}" for _, k, p in ERRORS])
def test_error_names_file_key_and_problem(data, key, problem):
    msg = err(data)
    assert msg.startswith(f"{SRC}: {key}: "), msg
    assert problem in msg, msg


def test_errors_from_a_file_name_the_file(tmp_path):
    p = tmp_path / "bad.toml"
    p.write_text('[planner]\nq_obs = "abc"\n\n[[robots]]\nvehicle = "firefly"\n'
                 'start = [0, 0, 1]\ngoal = [1, 1, 1]\n')
    with pytest.raises(ConfigError, match=rf"^{p}: planner.q_obs: expected a number, got 'abc'$"):
        load_config(p)
    p.write_text("name = \n")
    with pytest.raises(ConfigError, match=rf"^{p}: invalid TOML"):
        load_config(p)
    with pytest.raises(ConfigError, match="cannot read the file"):
        load_config(tmp_path / "missing.toml")


def test_defaults_are_resolved():
    cfg = parse_config(two(), "dir/my_run.toml")
    assert cfg.name == "my_run" and cfg.seed == 0 and cfg.source == "dir/my_run.toml"
    p = cfg.planner
    assert (p.replan_hz, p.degree, p.segments, p.end_state) == (8.0, 5, 2, "free")
    assert p.safety_margin_m == C.DEFAULT_SAFETY_MARGIN_M
    assert (p.q_dynm, p.q_obs, p.q_lim, p.k_t, p.k_p) == (
        C.DEFAULT_Q_DYNM, C.DEFAULT_Q_OBS, C.DEFAULT_Q_LIM, C.DEFAULT_K_T, C.DEFAULT_K_P)
    assert p.collision in C.COLLISION_MODES
    assert cfg.sim.backend == "ideal" and cfg.faults.enabled is False
    assert cfg.sweep.q_obs == (p.q_obs,) and cfg.sweep.seeds == (0,)
    assert cfg.robots[0].end_state == ("free",) and cfg.robots[0].goal_velocity == (None,)
    assert isinstance(p.replan_hz, float)
    assert parse_config(two()).name == "config"


def test_ints_accepted_for_floats():
    cfg = parse_config(two(planner={"q_obs": 3, "replan_hz": 10}))
    assert cfg.planner.q_obs == 3.0 and isinstance(cfg.planner.q_obs, float)


def test_limits_override_and_vehicle_defaults():
    data = two(limits={"v_max": 1.5})
    data["robots"][1]["vehicle"] = "neo11"
    sc = build_scenario(parse_config(data))
    np.testing.assert_array_equal(sc.v_max, [1.5, 1.5])
    np.testing.assert_array_equal(sc.a_max, [4.0, 4.0])
    np.testing.assert_allclose(sc.radius, [0.315, 0.4292])


def test_waypoints_goal_velocity_and_end_states():
    data = {"planner": {"end_state": "rest"}, "robots": [
        robot(goal=None, waypoints=[[3, 0, 1], [3, 3, 2], [0, 3, 2]], end_state=[
            "rest", "free", "free"], goal_velocity=[[], [1.0, 0.0, 0.0], []]),
        robot(start=[0, 5, 1], goal=[5, 5, 1], goal_velocity=[0.0, 0.0, 0.0]),
        robot(start=[0, 8, 1], goal=[5, 8, 1], end_state="free", goal_velocity=[0.5, 0, 0]),
    ]}
    cfg = parse_config(data)
    sc = build_scenario(cfg)
    assert sc.waypoints.shape == (3, 3, 3)
    np.testing.assert_array_equal(sc.rest, [[True, False, False], [True] * 3, [False] * 3])
    np.testing.assert_array_equal(sc.has_goal_velocity,
                                  [[False, True, False], [False] * 3, [True] * 3])
    np.testing.assert_array_equal(sc.waypoints[1], [[5, 5, 1]] * 3)  # padded
    np.testing.assert_array_equal(sc.goal_velocity[2, 0], [0.5, 0, 0])


def test_two_dimensional_config():
    cfg = parse_config({"robots": [robot(start=[0, 0], goal=[3, 0]),
                                   robot(start=[0, 0.1], goal=[3, 3])]})
    sc = build_scenario(cfg)
    assert sc.dim == 2 and cfg.dim == 2
    # starts closer than r_i + r_j are allowed (only exact coincidence is an error)


def test_scenario_plus_robots_and_seed():
    data = {"seed": 4, "scenario": {"kind": "random_box", "count": 5},
            "robots": [robot(start=[0, 0, 3.8], goal=[0, 0, 3.9])]}
    data["scenario"]["box"] = [[-3, -3, 1], [3, 3, 3]]
    cfg = parse_config(data)
    sc = build_scenario(cfg)
    assert sc.num_robots == 6 and sc.name == "config"
    ref = S.random_box(5, [[-3, -3, 1], [3, 3, 3]], cfg.scenario.get("min_spacing"),
                       ["firefly"], 4)
    np.testing.assert_array_equal(sc.start[:5], ref.start)
    other = build_scenario(dataclasses.replace(cfg, seed=5))
    assert not np.array_equal(other.start[:5], sc.start[:5])


def test_generator_end_state_follows_planner():
    cfg = parse_config({"planner": {"end_state": "rest"},
                        "scenario": {"kind": "grid_swap", "rows": 2, "cols": 2}})
    assert cfg.scenario.get("end_state") == "rest"
    assert build_scenario(cfg).rest.all()


def test_auto_end_states_reach_the_scenario():
    """"auto" from [planner] (generators and robots without their own), per robot and
    per waypoint; a waypoint with a goal velocity keeps it (auto never where rest or a
    goal velocity is)."""
    cfg = parse_config({"planner": {"end_state": "auto"},
                        "scenario": {"kind": "grid_swap", "rows": 2, "cols": 2},
                        "robots": [robot(start=[0, 8, 1], goal=[5, 8, 1]),
                                   robot(start=[0, 9, 1], goal=None,
                                         waypoints=[[3, 9, 1], [5, 9, 1], [6, 9, 1]],
                                         end_state=["auto", "rest", "auto"],
                                         goal_velocity=[[], [], [0.5, 0, 0]])]})
    sc = build_scenario(cfg)
    assert sc.auto[:5].all() and not sc.rest[:5].any()
    assert sc.auto[5].tolist() == [True, False, False]
    assert sc.rest[5].tolist() == [False, True, False] and sc.has_goal_velocity[5, 2]
    assert not (sc.auto & (sc.rest | sc.has_goal_velocity)).any()


def test_sweep_ranges():
    cfg = parse_config(two(sweep={"q_obs": {"log_min": -1, "log_max": 2, "num": 4},
                                  "q_lim": [0, 1, 10], "seeds": {"start": 3, "num": 3},
                                  "scenarios": ["paper:six_neos", "antipodal_sphere"]}))
    np.testing.assert_allclose(cfg.sweep.q_obs, [0.1, 1.0, 10.0, 100.0])
    assert cfg.sweep.q_lim == (0.0, 1.0, 10.0)
    assert cfg.sweep.seeds == (3, 4, 5)
    assert cfg.sweep.scenarios == ("paper:six_neos", "antipodal_sphere")


# ------------------------------------------------------------------------- round trips

EXPERIMENTS = sorted(glob.glob(str(ROOT / "experiments" / "*" / "*.toml")))


def test_experiment_files_exist():
    names = {Path(p).relative_to(ROOT).as_posix() for p in EXPERIMENTS}
    for n in ("paper/six_neos", "paper/eight_fireflys_stacked", "paper/eight_mixed_transitions",
              "paper/ten_mixed_rest", "benchmarks/antipodal_10", "benchmarks/random_box_20"):
        assert f"experiments/{n}.toml" in names


@pytest.mark.parametrize("path", EXPERIMENTS, ids=[Path(p).name for p in EXPERIMENTS])
def test_experiments_load_and_round_trip(path, tmp_path):
    cfg = load_config(path)
    sc = build_scenario(cfg)
    assert sc.num_robots >= 6
    text = config_to_toml(cfg)
    out = tmp_path / "config.toml"
    out.write_text(text)
    again = load_config(out)
    assert again == cfg
    assert config_to_toml(again) == text
    sc2 = build_scenario(again)
    np.testing.assert_array_equal(sc.start, sc2.start)
    np.testing.assert_array_equal(sc.waypoints, sc2.waypoints)


def test_benchmark_shapes():
    a = build_scenario(load_config(ROOT / "experiments/benchmarks/antipodal_10.toml"))
    assert a.num_robots == 10 and set(a.vehicles) == {"firefly", "neo11"}
    b = build_scenario(load_config(ROOT / "experiments/benchmarks/random_box_20.toml"))
    assert b.num_robots == 20


ROUND_TRIP = [
    two(),
    two(limits={"v_max": 1.0, "j_max": 20}, planner={"collision": "paper", "segments": 3}),
    {"robots": [robot(goal=None, waypoints=[[3, 0, 1], [3, 3, 2]], end_state=["rest", "free"],
                      goal_velocity=[[], [1.0, 0.0, 0.5]])]},
    {"robots": [robot(goal=None, waypoints=[[3, 0, 1], [3, 3, 2]], goal_velocity=[1, 2, 3])]},
    {"robots": [robot(start=[0, 0], goal=[1e-3, 7.123456789012345])]},
    {"scenario": {"kind": "antipodal_sphere", "count": 6, "dim": 2}},
    {"scenario": {"kind": "stacked", "count": 4, "vehicles": "neo11"}, "seed": 2**40},
    {"scenario": {"kind": "paper:eight_mixed_transitions"},
     "sweep": {"q_obs": {"log_min": -3, "log_max": 3, "num": 7}}},
]


@pytest.mark.parametrize("data", ROUND_TRIP)
def test_round_trip(data):
    cfg = parse_config(data)
    text = config_to_toml(cfg)
    back = parse_config(tomllib.loads(text))
    assert back == cfg
    assert config_to_toml(back) == text
    for f in C.PlannerConfig.__dataclass_fields__:
        assert f"\n{f} = " in text  # every default written out
    for f in C.SimConfig.__dataclass_fields__:
        assert f"\n{f} = " in text


def test_config_is_hashable_and_frozen():
    cfg = parse_config(two())
    hash(cfg)
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.seed = 3  # type: ignore[misc]


# ------------------------------------------------------------------------------ fuzzing

VOCAB = sorted({
    "name", "description", "seed", "planner", "limits", "sim", "robots", "scenario", "sweep",
    "faults", "kind", "count", "vehicles", "vehicle", "start", "goal", "waypoints",
    "goal_velocity", "end_state", "box", "radius", "center", "dim", "rows", "cols", "spacing",
    "q_obs", "q_lim", "seeds", "scenarios", "log_min", "log_max", "num", "enabled", "x",
    *C.PlannerConfig.__dataclass_fields__, *C.SimConfig.__dataclass_fields__,
    *(k for sch in C.GENERATOR_KEYS.values() for k in sch),
})
STRINGS = ["firefly", "neo11", "hummingbird", "rest", "free", "mjx", "ideal", "paper",
           "barrier", *S.SCENARIOS, "abc", ""]

scalars = st.one_of(
    st.none(), st.booleans(), st.integers(-3, 40), st.integers(-2**70, 2**70),
    st.floats(allow_nan=True, allow_infinity=True), st.sampled_from(STRINGS), st.text(max_size=8),
)
values = st.recursive(
    scalars,
    lambda ch: st.one_of(
        st.lists(ch, max_size=4),
        st.dictionaries(st.one_of(st.sampled_from(VOCAB), st.text(max_size=6)), ch, max_size=5),
    ),
    max_leaves=25,
)
vec = st.lists(st.one_of(st.floats(-6, 6), st.integers(-6, 6)), min_size=2, max_size=3)
robots = st.lists(st.fixed_dictionaries(
    {"vehicle": st.sampled_from(["firefly", "neo11", "hummingbird", "x"]), "start": vec},
    optional={"goal": vec, "waypoints": st.lists(vec, max_size=3), "end_state": values,
              "goal_velocity": st.one_of(vec, values)}), max_size=4)
scenario = st.fixed_dictionaries(
    {"kind": st.sampled_from(list(S.SCENARIOS) + ["nope"])},
    optional={k: values for k in ("count", "rows", "cols", "dim", "box", "center", "radius",
                                  "vehicles", "spacing", "jitter", "min_spacing")})
documents = st.one_of(
    values,
    st.dictionaries(st.sampled_from(VOCAB), values, max_size=6),
    st.fixed_dictionaries({}, optional={
        "robots": st.one_of(robots, values), "scenario": st.one_of(scenario, values),
        "planner": st.dictionaries(st.sampled_from(VOCAB), values, max_size=4),
        "sim": st.dictionaries(st.sampled_from(VOCAB), values, max_size=3),
        "sweep": st.dictionaries(st.sampled_from(VOCAB), values, max_size=3),
        "seed": values, "name": values}),
)


@given(documents)
@settings(max_examples=FUZZ_EXAMPLES, deadline=None, suppress_health_check=list(HealthCheck))
def test_fuzz_only_config_errors(data):
    try:
        cfg = parse_config(data, "fuzz.toml")
    except ConfigError as e:
        msg = str(e)
        assert msg.startswith("fuzz.toml: ") and "\n" not in msg
        return
    # A config that parses builds and round-trips.
    build_scenario(cfg)
    assert parse_config(tomllib.loads(config_to_toml(cfg)), "fuzz.toml") == cfg


BASES = [
    two(),
    {"robots": [robot(goal=None, waypoints=[[3, 0, 1], [3, 3, 2]], end_state=["rest", "free"],
                      goal_velocity=[[], [1.0, 0.0, 0.5]]),
                robot(start=[0, 4, 1], goal=[3, 5, 1])]},
    {"scenario": {"kind": "random_box", "count": 4, "box": [[-3, -3, 1], [3, 3, 3]],
                  "vehicles": ["firefly", "neo11"]}, "sweep": {"q_obs": [1, 2], "seeds": [1]}},
    {"scenario": {"kind": "antipodal_sphere", "count": 5, "radius": 3.0, "center": [0, 0, 4]}},
    {"scenario": {"kind": "grid_swap", "rows": 2, "cols": 3}, "limits": {"v_max": 1.0}},
    {"scenario": {"kind": "stacked", "count": 3, "dim": 2}},
    {"scenario": {"kind": "paper:ten_mixed_rest"}, "sim": {"backend": "mjx"}},
]


def _paths(d, prefix=()):
    """Every (path to a container, key) in a nested dict/list document."""
    items = d.items() if isinstance(d, dict) else enumerate(d)
    for k, v in items:
        yield prefix, k
        if isinstance(v, (dict, list)):
            yield from _paths(v, prefix + (k,))


@given(st.data())
@settings(max_examples=FUZZ_EXAMPLES, deadline=None, suppress_health_check=list(HealthCheck))
def test_fuzz_mutated_valid_configs(data):
    import copy
    doc = copy.deepcopy(data.draw(st.sampled_from(BASES)))
    for _ in range(data.draw(st.integers(1, 2))):
        paths = list(_paths(doc))
        prefix, key = data.draw(st.sampled_from(paths))
        node = doc
        for p in prefix:
            node = node[p]
        if isinstance(node, dict) and data.draw(st.booleans()):
            new_key = data.draw(st.sampled_from(VOCAB))
            node[new_key] = data.draw(values)
        else:
            node[key] = data.draw(st.one_of(values, scalars))
    try:
        cfg = parse_config(doc, "fuzz.toml")
    except ConfigError as e:
        assert str(e).startswith("fuzz.toml: ") and "\n" not in str(e)
        return
    build_scenario(cfg)
    assert parse_config(tomllib.loads(config_to_toml(cfg)), "fuzz.toml") == cfg


@pytest.mark.parametrize("data", BASES)
def test_fuzz_bases_are_valid(data):
    build_scenario(parse_config(data))


def test_solver_keys_reach_the_solver_and_defaults_agree():
    """[planner] max_iters and tol are what the planner's solver runs with
    (FleetParams.settings), and their defaults are SolverSettings' own."""
    from jaxplan import run_setup, solve

    assert C.DEFAULT_MAX_ITERS == solve.SolverSettings().max_iters
    assert C.DEFAULT_TOL == solve.SolverSettings().tol_feasibility
    assert C.DEFAULT_TOL == solve.SolverSettings().tol_complementarity
    cfg = parse_config({**two(), "planner": {"max_iters": 17, "tol": 3e-7}})
    s = run_setup.fleet_params(cfg, build_scenario(cfg)).settings
    assert (s.max_iters, s.tol_feasibility, s.tol_complementarity) == (17, 3e-7, 3e-7)


def test_library_defaults_are_the_schemas():
    """Where a library function keeps a default of its own for API users, it is the
    config's (jaxplan/config/schema.py, the one place to change one); where it differs on
    purpose, the comment says why."""
    import inspect

    from jaxplan.nlp import NLPStructure
    from jaxplan.planner import PlannerStructure
    from jaxplan.planner.stall import STALL_WINDOW_3D_S, default_params
    from jaxplan.sim.fleet import init_sim

    d = {k: p.default for k, p in inspect.signature(default_params).parameters.items()}
    assert (d["progress"], d["near"], d["hold"], d["step"], d["angle_deg"], d["mutual"]) == (
        C.schema.DEFAULT_STALL_PROGRESS_M, C.schema.DEFAULT_STALL_NEAR_M,
        C.schema.DEFAULT_SIDESTEP_HOLD_S, C.schema.DEFAULT_SIDESTEP_STEP_M,
        C.schema.DEFAULT_SIDESTEP_ANGLE_DEG, C.schema.DEFAULT_SIDESTEP_MUTUAL_AT_ONCE)
    assert d["window"] == STALL_WINDOW_3D_S  # stall_window_s "auto" in 3-D
    # NLPStructure's segments (1) and n_coast_samples (0) are the paper's NLP, not the
    # planner's defaults
    nlp = NLPStructure()
    assert (nlp.degree, nlp.collision, nlp.n_collision_samples) == (
        C.DEFAULT_DEGREE, C.DEFAULT_COLLISION, C.DEFAULT_N_SAMPLES)
    # PlannerStructure's max_static_rows (0: every row) is the NLP's own, without a world
    ps = PlannerStructure()
    assert (ps.max_neighbors, ps.solver_pool) == (C.DEFAULT_MAX_NEIGHBORS, C.DEFAULT_SOLVER_POOL)
    sim = inspect.signature(init_sim).parameters
    assert (sim["physics_hz"].default, sim["control_hz"].default) == (
        C.DEFAULT_PHYSICS_HZ, C.DEFAULT_CONTROL_HZ)
    # tol's bound: a plan the solver calls converged is one the iteration cap accepts
    from jaxplan.run_setup import ACCEPT_VIOLATION

    assert C.schema.MAX_TOL == ACCEPT_VIOLATION
