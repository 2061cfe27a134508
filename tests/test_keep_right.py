"""Passing on the right ([planner] keep_right_m): two quadrotors swapping head on in 3-D
under hard limits and a high time weight."""

import pytest

from jaxplan.config import parse_config


def _swap(keep_right: float) -> dict:
    from jaxplan.experiment import run

    robots = [{"vehicle": "firefly", "start": [0.0, 0.0, 1.5], "goal": [8.0, 0.0, 1.5],
               "end_state": "rest"},
              {"vehicle": "firefly", "start": [8.0, 0.0, 1.5], "goal": [0.0, 0.0, 1.5],
               "end_state": "rest"}]
    doc = {"name": "swap", "sim": {"duration_s": 10.0}, "robots": robots,
           "planner": {"limits": "hard", "k_t": 100.0, "keep_right_m": keep_right}}
    return run(parse_config(doc)).metrics


@pytest.mark.slow  # two closed loops with programs of their own (~25 s): `make test-slow`
def test_a_head_on_swap_passes_on_the_right():
    # both robots see the other straight ahead and dodge the same way (up): they meet
    plain = _swap(0.0)
    assert plain["collisions"] > 0 and plain["min_separation_ratio"] < 1.0
    # each predicts the other 0.1 m to its right: each passes on its own right
    kept = _swap(0.1)
    assert kept["success"] and kept["collisions"] == 0, kept["min_separation_ratio"]
    assert kept["min_separation_ratio"] > 1.2
    # and as fast as one robot alone flies it (1.24 x its bound)
    assert kept["makespan_over_bound"] < 1.3
    assert kept["peak_speed_ratio"] <= 1.0 + 1e-6
