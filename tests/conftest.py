"""Shared fixtures: one small fleet problem compiled once per test process."""

import os
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest

# One JAX CPU device per test process: `make test` runs two pytest workers on two cores,
# and two devices in each oversubscribed them (the suite took ~1.5 min longer).  The
# tests of the split over devices run child processes with JAXPLAN_CPU_DEVICES=2.
os.environ.setdefault("JAXPLAN_CPU_DEVICES", "1")
# `jaxplan run` / `sweep` called in-process must not write a compilation cache into the
# home directory (the test of the cache gives its children their own directory)
os.environ.setdefault("JAXPLAN_CACHE_DIR", "")
# One persistent compilation cache for the whole test session: made by the first process
# that imports this file (the controller under pytest-xdist, which starts its workers
# after, with this environment), so the workers share it; a program one test or worker
# compiled, the next loads.  That process removes it at the end of the session.
_SESSION_CACHE = None
if "JAX_COMPILATION_CACHE_DIR" not in os.environ:
    _SESSION_CACHE = tempfile.mkdtemp(prefix="jaxplan-tests-xla-")
    os.environ["JAX_COMPILATION_CACHE_DIR"] = _SESSION_CACHE

# XLA's CPU compiler at its lowest effort: the suite compiles a few hundred programs and
# runs most of them for milliseconds, so compiling is most of its time.  These flags cut
# the compile of the tiny scenario's rollout about 3x (~22 s -> ~7 s of CPU) at the same
# run time; results differ from the default flags by round-off only.  One XLA thread per
# process (as `jaxplan bench`'s one-core rows): two workers on two cores, running small
# computations, gain nothing from thread pools of their own (the suite: 481 -> 443 s of
# CPU, 2-core machine).  Set JAXPLAN_TEST_XLA_DEFAULT=1 to test with the flags a user's
# run gets.
FAST_COMPILE_FLAGS = ("--xla_backend_optimization_level=0 "
                      "--xla_llvm_disable_expensive_passes=true "
                      "--xla_cpu_use_fusion_emitters=false "
                      "--xla_cpu_multi_thread_eigen=false")
if os.environ.get("JAXPLAN_TEST_XLA_DEFAULT") != "1" and \
        "--xla_cpu_use_fusion_emitters" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " " + FAST_COMPILE_FLAGS).strip()

import jaxplan  # noqa: E402, F401  (float64)


def pytest_sessionfinish(session, exitstatus):
    """The process that made the session's compilation cache removes it."""
    if _SESSION_CACHE:
        shutil.rmtree(_SESSION_CACHE, ignore_errors=True)


# the tiny scenario, shared with examples/run_scenario.py (its default config)
TINY_TOML = (Path(__file__).resolve().parents[1] / "examples" / "tiny.toml").read_text()


# Test modules that share one pytest-xdist worker under `make test` (--dist loadfile):
# the tiny scenario's users, so that its programs compile once (in-process, by the first
# test that asks for `tiny_run`; the crash test's `jaxplan run` children then load them
# from the session's compilation cache; test_sweep's in-process `jaxplan sweep` and
# test_tune's in-process tune share one batch program in memory).  Every other module
# is its own unit, as usual.
SHARED_WORKER = {f"tests/{m}.py": "tiny" for m in
                 ("test_cli", "test_crash", "test_examples", "test_planner", "test_sweep",
                  "test_world_metrics", "test_tune", "test_export", "test_limit_metrics",
                  "test_noncooperative")}


# The units in order of their test time (2-core CPU, seconds: tiny 117, test_solver 106,
# test_costs 45, test_world 45, test_fuzz 28, test_guess 24, test_solver_devices 20,
# test_sim_model 15, test_hard_limits 13, test_predict 12, test_fleet_sim 12, test_plots 12,
# test_guide 9, test_config 8, test_trajectory 6; the others 6 and under;
# test_config_bounds and test_sweep_engines about 40 and 45), handed out longest first:
# the last units to run are then short ones, and neither worker waits long for the
# other at the end.  Only the order changes; a unit missing here runs after.
LONGEST_FIRST = ("tiny", "tests/test_solver.py", "tests/test_costs.py", "tests/test_world.py",
                 "tests/test_config_bounds.py", "tests/test_sweep_engines.py",
                 "tests/test_fuzz.py", "tests/test_guess.py", "tests/test_hard_limits.py",
                 "tests/test_solver_devices.py",
                 "tests/test_sim_model.py", "tests/test_predict.py", "tests/test_fleet_sim.py",
                 "tests/test_plots.py", "tests/test_guide.py", "tests/test_config.py",
                 "tests/test_trajectory.py")


def pytest_xdist_make_scheduler(config, log):
    """--dist loadfile, with the modules of SHARED_WORKER in one unit (in file order),
    the units of LONGEST_FIRST handed out first."""
    if config.getvalue("dist") != "loadfile":
        return None
    from xdist.scheduler import LoadFileScheduling

    class SharedWorkerScheduling(LoadFileScheduling):
        def _split_scope(self, nodeid: str) -> str:
            module = super()._split_scope(nodeid)
            return SHARED_WORKER.get(module, module)

        def _assign_work_unit(self, node) -> None:
            for scope in LONGEST_FIRST:
                if scope in self.workqueue:
                    self.workqueue.move_to_end(scope, last=False)
                    break
            super()._assign_work_unit(node)

    return SharedWorkerScheduling(config, log)


@pytest.fixture(scope="session")
def tiny_config():
    from jaxplan.config import parse_config

    return parse_config(__import__("tomllib").loads(TINY_TOML), source="tiny.toml")


@pytest.fixture(scope="session")
def tiny_run(tiny_config):
    """The tiny scenario run end to end once (ideal backend)."""
    from jaxplan.experiment import run

    return run(tiny_config)


@pytest.fixture
def rng():
    return np.random.default_rng(0)

