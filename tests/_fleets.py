"""Fleets several test modules run."""

import tomllib
from pathlib import Path

from jaxplan.config import Config, parse_config

RANDOM_BOX_20 = Path(__file__).parents[1] / "experiments" / "benchmarks" / "random_box_20.toml"


def frozen_random_box_20_seed_8(planner: dict | None = None, **sim) -> Config:
    """experiments/benchmarks/random_box_20.toml at seed 8 with robot 0 frozen (silent)
    at 2 s: the fly-away case of docs/SOLVER.md "Hard limits".  ``planner``: [planner]
    keys to set; ``sim``: [sim] keys to set."""
    with open(RANDOM_BOX_20, "rb") as f:
        doc = tomllib.load(f)
    doc["seed"] = 8
    doc["sim"].update(sim)
    doc["planner"] = {**doc.get("planner", {}), **(planner or {})}
    doc["faults"] = {"enabled": True, "frozen_robot": 0, "frozen_at_s": 2.0,
                     "frozen_mode": "silent"}
    return parse_config(doc, source=RANDOM_BOX_20.name)
