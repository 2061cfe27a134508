"""Every numeric config key at its bounds and just beyond, at 0, negative, huge (1e308)
and inf / nan: each value either gives a config that parses, builds its fleet and runs,
or fails with the one-line error naming the key (`jaxplan` exits 2 on it).

The walk reads each key's range from its one declaration (jaxplan.fields.range_of);
the parse-level walk compiles nothing.  The runs: the keys the planner takes as traced
inputs (weights, tolerances, rates, limits, ...) share one compiled replan period, so
that every accepted bound value of theirs runs in this process at the cost of one
compilation; the keys that change the compiled program at their upper bounds are the
slow tier (their lower bounds are the fast tier's base).
"""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest

from jaxplan import config as C
from jaxplan.config import ConfigError, build_scenario, parse_config
from jaxplan.config.robots import RobotConfig
from jaxplan.config.schema import MAX_KEEP_RIGHT_M, MIN_REPLAN_HZ, Seed, field_type
from jaxplan.config.sweep import LogRange, SeedRange
from jaxplan.fields import MAX_COORD, Coordinate, PositiveLength, Range, range_of
from jaxplan.scenarios import GENERATOR_PARAMS

SRC = "bounds.toml"
# the runs' fleet: two robots swapping places; the structural keys at their lower bounds
# (a smaller program to compile, and those bounds run too)
BASE = {
    "name": "bounds", "sim": {"duration_s": 1.0},
    "planner": {"n_samples": 4, "segments": 1, "coast_samples": 0},
    "robots": [{"vehicle": "firefly", "start": [0.0, 0.0, 1.5], "goal": [2.0, 0.0, 1.5]},
               {"vehicle": "firefly", "start": [2.0, 0.1, 1.5], "goal": [0.0, 0.1, 1.5]}],
}
SECTIONS = {"planner": C.PlannerConfig, "limits": C.LimitsConfig, "sim": C.SimConfig,
            "faults": C.FaultsConfig}
# keys the planner takes as traced inputs: any value of theirs runs on one program
TRACED = {
    "planner": ("replan_hz", "q_dynm", "q_obs", "q_lim", "k_t", "k_p", "max_iters", "tol",
                "safety_margin_m", "stall_window_s", "stall_progress_m", "stall_near_m",
                "sidestep_hold_s", "sidestep_step_m", "sidestep_angle_deg",
                "sidestep_wait_3d_s", "stall_window_mutual_s", "sidestep_hold_mutual_s",
                "region_margin_m"),
    "limits": ("v_max", "a_max", "j_max"),
    "sim": ("duration_s", "goal_tolerance_m", "goal_speed_tolerance_mps"),
}
# keys that change the compiled program (or the simulator's), run in the slow tier
# (keep_right_m: 0 is no shift, any other value one traced shift)
STRUCTURAL = {
    "planner": ("degree", "segments", "n_samples", "max_neighbors", "max_static_rows",
                "coast_samples", "solver_pool", "keep_right_m"),
    "sim": ("physics_hz", "control_hz"),
    "faults": ("message_loss", "latency_s", "noise_sigma_m", "frozen_robot", "frozen_at_s"),
}
# keys of the ORCA baseline ([planner] method = "orca", jaxplan/baselines/orca.py): no
# compiled program; each accepted bound value runs on a planar fleet
ORCA = {"planner": ("orca_neighbor_dist_m", "orca_max_neighbors", "orca_time_horizon_s",
                    "orca_time_horizon_obst_s", "orca_time_step_s")}
# what a key's walk sets besides it: the rate ratio physics_hz / control_hz stays whole;
# a run of sim.duration_s = 3600 s at 0.1 Hz is 360 replans
WALK_BASE = {("sim", "physics_hz"): {"control_hz": 100.0},
             ("sim", "control_hz"): {"physics_hz": 10_000.0}}
RUN_BASE = {("sim", "duration_s"): {"planner": {"replan_hz": MIN_REPLAN_HZ}}}
# in range, but refused by a check across keys (naming the key): robot 2.. do not exist
REFUSED_IN_RANGE = {("faults", "frozen_robot")}


def numeric_keys(model: type) -> list[tuple[str, Range, bool]]:
    """(name, range, integer) of every field of ``model`` with a declared range."""
    out = []
    for name in model.__dataclass_fields__:
        tp = field_type(model, name)
        r = range_of(tp)
        if r is not None:
            out.append((name, r, _is_int(tp)))
    return out


def _is_int(tp) -> bool:
    return getattr(tp, "__origin__", tp) is int


def walk(r: Range, integer: bool) -> list[tuple[object, bool]]:
    """(value, inside the range) at each bound and just beyond it, at 0, -1, huge and
    inf / nan; for an integer also a float (TOML's inf)."""
    vals: list[object] = []
    if integer:
        if r.ge is not None:
            vals += [r.ge, r.ge - 1]
        if r.le is not None:
            vals += [r.le, r.le + 1]
        if r.multiple_of:
            vals += [r.ge + 2 if r.ge is not None else 2]
        vals += [0, -1, 2**63 - 1, -(2**63), 1.0, math.inf, math.nan]
    else:
        for closed, opened, out in ((r.ge, r.gt, -math.inf), (r.le, r.lt, math.inf)):
            if closed is not None:
                vals += [float(closed), float(np.nextafter(closed, out))]
            if opened is not None:
                vals += [float(opened), float(np.nextafter(opened, -out))]
        vals += [0.0, -1.0, 1e308, -1e308, math.inf, -math.inf, math.nan]
    return [(v, _inside(v, r, integer)) for v in vals]


def _inside(v, r: Range, integer: bool) -> bool:
    if integer:
        return type(v) is int and v in r
    return isinstance(v, (int, float)) and math.isfinite(v) and v in r


def with_value(doc: dict, path: tuple, value) -> dict:
    """A copy of ``doc`` with ``value`` at ``path`` (tables made where missing)."""
    doc = copy.deepcopy(doc)
    node = doc
    for p in path[:-1]:
        node = node.setdefault(p, {}) if isinstance(node, dict) else node[p]
    node[path[-1]] = value
    return doc


def outcome(doc: dict, key: str) -> str:
    """"ok" (parses and builds its fleet) or "error" (a ConfigError naming ``key``)."""
    try:
        build_scenario(parse_config(doc, SRC))
        return "ok"
    except ConfigError as e:
        msg = str(e)
        assert "\n" not in msg and msg.startswith(f"{SRC}: {key}"), (key, msg)
        rest = msg[len(f"{SRC}: {key}"):]
        assert rest[:1] in (":", ".", "["), (key, msg)
        return "error"


def check_walk(doc: dict, path: tuple, key: str, r: Range, integer: bool,
               refused_in_range: bool = False) -> list:
    """Walk one key; returns the accepted values."""
    accepted = []
    for v, inside in walk(r, integer):
        got = outcome(with_value(doc, path, v), key)
        if got == "ok":
            assert inside, f"{key} = {v!r} is outside {r} but was accepted"
            accepted.append(v)
        else:
            assert not inside or refused_in_range, f"{key} = {v!r} is inside {r} but refused"
    return accepted


PLAIN_KEYS = [(s, name, r, i) for s, m in SECTIONS.items() for name, r, i in numeric_keys(m)]


# ------------------------------------------------------------------------- parse level


def test_every_numeric_key_is_classified():
    """Each numeric key of the plain sections is traced (fast runs), structural or the
    ORCA baseline's."""
    for s, name, _, _ in PLAIN_KEYS:
        kinds = [name in group.get(s, ()) for group in (TRACED, STRUCTURAL, ORCA)]
        assert sum(kinds) == 1, (s, name)


@pytest.mark.parametrize("section,key,r,integer", PLAIN_KEYS,
                         ids=[f"{s}.{k}" for s, k, _, _ in PLAIN_KEYS])
def test_plain_keys_at_their_bounds(section, key, r, integer):
    doc = copy.deepcopy(BASE)
    doc.setdefault(section, {}).update(WALK_BASE.get((section, key), {}))
    accepted = check_walk(doc, (section, key), f"{section}.{key}", r, integer,
                          (section, key) in REFUSED_IN_RANGE)
    assert accepted


def test_weights_and_rates_have_finite_ranges():
    """Every weight, rate, count and length has an upper bound (a huge value is refused
    before it overflows), and q_dynm, which the predictions divide by, a positive floor."""
    for s, name, r, _ in PLAIN_KEYS:
        assert r.le is not None or r.lt is not None, f"{s}.{name}: no upper bound"
    assert C.weight_bounds("q_dynm").low > 0.0


def test_n_samples_is_used_as_given():
    """A multiple of 4 is the collision samples the NLP has; any other count is refused
    (it used to be rounded up silently)."""
    from jaxplan.run_setup import structures

    cfg = parse_config(with_value(BASE, ("planner", "n_samples"), 12), SRC)
    assert structures(cfg).planner.nlp.n_collision_samples == 12
    with pytest.raises(ConfigError, match=r"^bounds.toml: planner.n_samples: must be a "
                                          r"multiple of 4, got 30$"):
        parse_config(with_value(BASE, ("planner", "n_samples"), 30), SRC)


def test_the_largest_polynomials_have_a_well_conditioned_basis():
    """degree and segments at their upper bounds together: the NLP's basis (a generalized
    eigenproblem on the positions' Gram matrix) builds, and is finite."""
    import importlib

    from jaxplan.nlp import NLPStructure

    basis = importlib.import_module("jaxplan.nlp.basis")
    b = basis.basis(NLPStructure(degree=C.MAX_DEGREE, segments=C.MAX_SEGMENTS))
    for kind in (b.free, b.rest):
        assert all(np.all(np.isfinite(np.asarray(x))) for x in kind)


def test_seed_at_its_bounds():
    accepted = check_walk(BASE, ("seed",), "seed", range_of(Seed), True)
    assert 2**63 - 1 in accepted


def test_positions_at_their_bounds():
    r = range_of(Coordinate)
    for path, key in ((("robots", 0, "start", 0), "robots[0].start[0]"),
                      (("robots", 1, "goal", 0), "robots[1].goal[0]")):
        check_walk(BASE, path, key, r, False)
    doc = with_value(BASE, ("robots", 0, "goal_velocity"), [0.0, 0.0, 0.0])
    check_walk(doc, ("robots", 0, "goal_velocity", 0), "robots[0].goal_velocity[0]", r, False)
    assert RobotConfig.KEYS == C.ROBOT_KEYS


def test_workspace_at_its_bounds():
    """Each coordinate of a bound is within +-MAX_COORD or +-inf (unbounded), never nan."""
    beyond = float(np.nextafter(MAX_COORD, math.inf))
    for side, values, sign in (("min", [-math.inf, -math.inf, 0.0], -1.0),
                               ("max", [math.inf, math.inf, math.inf], 1.0)):
        doc = with_value(BASE, ("workspace", side), values)
        for v, ok in ((MAX_COORD, True), (math.inf, True), (beyond, False), (1e308, False),
                      (math.nan, False)):
            got = outcome(with_value(doc, ("workspace", side, 0), sign * v), f"workspace.{side}")
            assert (got == "ok") == ok, (side, v, got)


def test_obstacles_at_their_bounds():
    """Obstacle sizes within (0, MAX_COORD]; a huge one that swallows a robot is refused
    naming the robot."""
    far = {"kind": "cylinder", "center": [50.0, 50.0, 0.0], "radius": 1.0, "half_height": 2.0}
    doc = with_value(BASE, ("obstacles",), [far])
    for name in ("radius", "half_height"):
        r = range_of(PositiveLength)
        for v, inside in walk(r, False):
            try:
                build_scenario(parse_config(with_value(doc, ("obstacles", 0, name), v), SRC))
            except ConfigError as e:
                msg = str(e)
                assert msg.startswith((f"{SRC}: obstacles[0].{name}: ", f"{SRC}: robots[")), msg
                assert not inside or f"obstacles[0].{name}:" not in msg, msg
            else:
                assert inside, (name, v)


def test_sweep_grids_at_their_bounds():
    """A weight grid's values lie in the [planner] key's range, given as a list or as a
    log range; the log range's, seeds' and counts' own bounds."""
    for name in ("q_obs", "q_lim"):
        r = range_of(field_type(C.PlannerConfig, name))
        check_walk(with_value(BASE, ("sweep", name), [1.0]), ("sweep", name, 0),
                   f"sweep.{name}[0]", r, False)
        lo, hi = C.weight_bounds(name)
        grid = {"log_min": 0.0, "log_max": math.log10(hi), "num": 3}
        assert outcome(with_value(BASE, ("sweep", name), grid), f"sweep.{name}") == "ok"
        grid["log_max"] = float(np.nextafter(math.log10(hi), math.inf))
        assert outcome(with_value(BASE, ("sweep", name), grid),
                       f"sweep.{name}.log_max") == "error"
        doc = with_value(BASE, ("sweep", name), {"log_min": 0.0, "log_max": 1.0, "num": 2})
        for field, rr, integer in numeric_keys(LogRange):  # log_min <= log_max besides
            check_walk(doc, ("sweep", name, field), f"sweep.{name}", rr, integer, True)
    doc = with_value(BASE, ("sweep", "seeds"), {"start": 0, "num": 2})
    for field, rr, integer in numeric_keys(SeedRange):  # start + num - 1 < 2**63 besides
        check_walk(doc, ("sweep", "seeds", field), "sweep.seeds", rr, integer, True)
    check_walk(with_value(BASE, ("sweep", "seeds"), [0]), ("sweep", "seeds", 0),
               "sweep.seeds[0]", range_of(Seed), True)


def test_tune_ranges_lie_within_the_planner_ranges():
    """[tune] weights: low and high within weight_bounds(name), which is the [planner]
    field's own range; the scalar options at their bounds."""
    doc = with_value(BASE, ("tune", "weights"), {})
    for name in C.TUNABLE_WEIGHTS:
        lo, hi = C.weight_bounds(name)
        r = range_of(field_type(C.PlannerConfig, name))
        assert (r.ge, r.le) == (lo, hi) and r.gt is None and r.lt is None
        ok = with_value(doc, ("tune", "weights", name), {"low": lo, "high": hi})
        assert parse_config(ok, SRC).tune.weights[name] == C.WeightRange(low=lo, high=hi)
        for side, v in (("low", float(np.nextafter(lo, -math.inf))),
                        ("high", float(np.nextafter(hi, math.inf))), ("high", 1e308),
                        ("low", -1.0)):
            bad = with_value(ok, ("tune", "weights", name, side), v)
            assert outcome(bad, f"tune.weights.{name}.{side}") == "error"
    base = with_value(doc, ("tune", "weights", "q_obs"), {"low": 1.0, "high": 2.0})
    for field, r, integer in numeric_keys(C.TuneConfig):
        check_walk(base, ("tune", field), f"tune.{field}", r, integer)


GENERATOR_KEYS = [(kind, name, r, integer) for kind in sorted(GENERATOR_PARAMS)
                  for name, r, integer in numeric_keys(GENERATOR_PARAMS[kind])]


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
@pytest.mark.parametrize("kind,key,r,integer", GENERATOR_KEYS,
    ids=[f"{k}.{n}" for k, n, _, _ in GENERATOR_KEYS])
def test_generator_keys_at_their_bounds(kind, key, r, integer):
    """A generator's numeric keys (declared by its parameter model): an accepted value
    builds the fleet; a refused one names the [scenario] table (a value in range may
    still leave no room for the fleet: named by the key the generator blames)."""
    base = {"scenario": {"kind": kind, "count": 4}}
    if kind == "grid_swap":
        base = {"scenario": {"kind": kind, "rows": 2, "cols": 2}}
    for v, inside in walk(r, integer):
        doc = with_value(base, ("scenario", key), v)
        try:
            build_scenario(parse_config(doc, SRC))
        except ConfigError as e:
            msg = str(e)
            assert msg.startswith(f"{SRC}: scenario"), msg
            if not inside:
                assert msg.startswith(f"{SRC}: scenario.{key}"), msg
        else:
            assert inside, (kind, key, v)


# ------------------------------------------------------------------------------- runs


def _finite(x, path="metrics"):
    """Every number in a metrics tree is finite (None allowed)."""
    if isinstance(x, dict):
        for k, v in x.items():
            _finite(v, f"{path}.{k}")
    elif isinstance(x, (list, tuple)):
        for i, v in enumerate(x):
            _finite(v, f"{path}[{i}]")
    elif isinstance(x, float):
        assert math.isfinite(x), (path, x)


def _run_values(section: str, key: str) -> list:
    """The accepted values of a key worth a run: each bound (the nearest value inside an
    open one) and 0 where accepted."""
    tp = field_type(SECTIONS[section], key)
    r = range_of(tp)
    worth = {r.ge, r.le, 0}
    if r.gt is not None:
        worth.add(float(np.nextafter(r.gt, math.inf)))
    return list(dict.fromkeys(v for v, inside in walk(r, _is_int(tp)) if inside and v in worth))


def _run(doc: dict):
    from jaxplan.experiment import run

    result = run(parse_config(doc, SRC))
    _finite(result.metrics)
    return result


def test_traced_keys_run_at_their_bounds():
    """Every accepted bound value of the traced keys runs (one compiled program, then
    none: they are traced), with finite metrics; so do positions and goal velocities at
    +-MAX_COORD."""
    _run(BASE)  # compiles the program the others reuse
    cases = [((section, key), v) for section, keys in TRACED.items() for key in keys
             for v in _run_values(section, key)]
    cases += [(("robots", 0, "start", 0), s * MAX_COORD) for s in (1.0, -1.0)]
    cases += [(("robots", 1, "goal_velocity"), [0.0, 0.0, s * MAX_COORD]) for s in (1.0, -1.0)]
    for path, v in cases:
        doc = with_value(BASE, path, v)
        for sec, values in RUN_BASE.get(path, {}).items():
            doc[sec] = {**doc.get(sec, {}), **values}
        result = _run(doc)
        assert result.compile_s == 0.0, (path, v)


@pytest.mark.slow  # ~18 s on 2 cores (a program of its own): `make test-slow`
def test_no_weight_breaks_the_hard_limits():
    """[planner] limits = "hard": every weight at each end of its accepted range (and 0
    where accepted), and each vehicle limit at its bounds, gives a run whose executed
    pieces keep within the vehicles' limits at every instant (the exact peak ratios of
    metrics.json).  With soft limits k_t = 1e6 flies the swap at 1.35 v_max and q_dynm =
    1e-6 at 4 j_max (docs/SOLVER.md "Hard limits")."""
    from jaxplan.planner.choice import LIMIT_TOL

    base = with_value(BASE, ("planner", "limits"), "hard")
    cases = [(("planner", key), v) for key in ("q_dynm", "q_obs", "q_lim", "k_t", "k_p")
             for v in _run_values("planner", key)]
    cases += [(("limits", key), v) for key in ("v_max", "a_max", "j_max")
              for v in _run_values("limits", key)]
    for path, v in cases:
        m = _run(with_value(base, path, v)).metrics
        for k in ("peak_speed_ratio", "peak_acc_ratio", "peak_jerk_ratio"):
            assert m[k] <= 1.0 + LIMIT_TOL, (path, v, k, m[k])


@pytest.mark.parametrize("method", ["orca", "orca3d"])
def test_orca_keys_run_at_their_bounds(method):
    """Every accepted bound value of the ORCA baseline's keys runs a planar swap (RVO2:
    nothing to compile; RVO2-3D in JAX: one compiled step, its keys traced), with finite
    metrics."""
    if method == "orca":
        pytest.importorskip("pyrvo")
    doc = {"name": "bounds_orca", "sim": {"duration_s": 1.0}, "planner": {"method": method},
           "robots": [{"vehicle": "ground", "start": [0.0, 0.0], "goal": [2.0, 0.0]},
                      {"vehicle": "ground", "start": [2.0, 0.1], "goal": [0.0, 0.1]}]}
    for section, keys in ORCA.items():
        for key in keys:
            for v in _run_values(section, key):
                _run(with_value(doc, (section, key), v))


STRUCTURAL_RUNS = [
    ("planner", "degree", C.MAX_DEGREE, {}),
    ("planner", "segments", C.MAX_SEGMENTS, {}),
    ("planner", "n_samples", C.MAX_SAMPLES, {}),
    ("planner", "coast_samples", C.MAX_COAST_SAMPLES, {}),
    ("planner", "max_neighbors", 1024, {}),
    ("planner", "solver_pool", 1024, {}),
    ("planner", "max_static_rows", 1, {"workspace": {"max": [MAX_COORD] * 3}}),
    ("planner", "keep_right_m", MAX_KEEP_RIGHT_M, {}),
    ("faults", "latency_s", 10.0, {"faults": {"enabled": True}}),
    ("sim", "physics_hz", 10_000.0, {"sim": {"backend": "mjx", "control_hz": 100.0,
                                             "duration_s": 0.25}}),
]


@pytest.mark.slow
@pytest.mark.parametrize("section,key,value,extra", STRUCTURAL_RUNS,
                         ids=[f"{s}.{k}" for s, k, _, _ in STRUCTURAL_RUNS])
def test_structural_keys_run_at_their_upper_bounds(section, key, value, extra):
    doc = with_value(BASE, (section, key), value)
    for sec, values in extra.items():
        doc[sec] = {**doc.get(sec, {}), **values}
    _run(doc)


@pytest.mark.slow
def test_fault_keys_run_at_their_bounds():
    """[faults] on (one program): each accepted bound value runs."""
    doc = with_value(BASE, ("faults", "enabled"), True)
    for key in ("message_loss", "noise_sigma_m", "frozen_robot", "frozen_at_s"):
        r = range_of(field_type(C.FaultsConfig, key))
        integer = _is_int(field_type(C.FaultsConfig, key))
        for v, inside in walk(r, integer):
            if inside and outcome(with_value(doc, ("faults", key), v), f"faults.{key}") == "ok":
                _run(with_value(doc, ("faults", key), v))


# -------------------------------------------------------------------------------- CLI


def test_run_refuses_q_dynm_zero_in_one_line(tmp_path, capsys):
    """q_dynm = 0 once passed and ended in a ZeroDivisionError traceback."""
    from jaxplan.cli import main

    path = tmp_path / "zero.toml"
    path.write_text('[planner]\nq_dynm = 0.0\n[[robots]]\nvehicle = "firefly"\n'
                    'start = [0.0, 0.0, 1.5]\ngoal = [2.0, 0.0, 1.5]\n')
    assert main(["run", str(path), "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and err.startswith("jaxplan: error: ")
    assert f"{path}: planner.q_dynm: must be >= 1e-06, got 0.0" in err
