"""Shared fixtures: one small fleet problem compiled once per test process."""

import numpy as np
import pytest

import jaxplan  # noqa: F401  (float64)

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
