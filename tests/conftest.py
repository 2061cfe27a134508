"""Shared fixtures: one small fleet problem compiled once per test process."""

import os

import numpy as np
import pytest

# One JAX CPU device per test process: `make test` runs two pytest workers on two cores,
# and two devices in each oversubscribed them (the suite took ~1.5 min longer).  The
# tests of the split over devices run child processes with JAXPLAN_CPU_DEVICES=2.
os.environ.setdefault("JAXPLAN_CPU_DEVICES", "1")
# `jaxplan run` / `sweep` called in-process must not write a compilation cache into the
# home directory (the test of the cache gives its children their own directory)
os.environ.setdefault("JAXPLAN_CACHE_DIR", "")

import jaxplan  # noqa: E402, F401  (float64)

TINY_TOML = """
name = "tiny"
seed = 0
[sim]
duration_s = 12.0
[[robots]]
vehicle = "firefly"
start = [0.0, 0.0, 1.5]
goal = [4.0, 0.0, 1.5]
[[robots]]
vehicle = "firefly"
start = [4.0, 0.1, 1.5]
goal = [0.0, 0.1, 1.5]
[[robots]]
vehicle = "neo11"
start = [2.0, -2.0, 1.5]
goal = [2.0, 2.0, 1.5]
"""


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
