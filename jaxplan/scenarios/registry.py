"""The registry of named scenarios (`jaxplan scenarios`): the paper's four and the
generators, each built by name with :func:`build`; the generators' kinds -> their
parameter models (GENERATOR_PARAMS) and their functions (GENERATORS, each the one that
declared its model)."""


from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from jaxplan.scenarios.generators import (
    AntipodalCircleParams,
    AntipodalSphereParams,
    GridSwapParams,
    RandomBoxParams,
    StackedParams,
    antipodal_circle,
    antipodal_sphere,
    grid_swap,
    random_box,
    stacked,
)
from jaxplan.scenarios.paper import (
    paper_eight_fireflys_stacked,
    paper_eight_mixed_transitions,
    paper_six_neos,
    paper_ten_mixed_rest,
)
from jaxplan.scenarios.params import GeneratorParams
from jaxplan.scenarios.scenario import Scenario, ScenarioError
from jaxplan.scenarios.traffic import IntruderParams, intruder
from jaxplan.scenarios.worlds import (
    CrossingTrafficParams,
    LowCeilingParams,
    PillarsParams,
    RandomObstaclesParams,
    WallGapParams,
    crossing_traffic,
    low_ceiling,
    pillars,
    random_obstacles,
    wall_gap,
)

# ----------------------------------------------------------------------------- registry


@dataclass(frozen=True)
class ScenarioSpec:
    """A registered scenario: ``build(seed=0, **params) -> Scenario``.

    name: registry key (also the config's ``[scenario] kind``); description: one line;
    paper: True for the paper's four (no parameters besides the seed).
    """

    name: str
    description: str
    build: Callable[..., Scenario]
    paper: bool = False


PAPER_SCENARIOS: dict[str, Callable[..., Scenario]] = {
    "paper:six_neos": paper_six_neos,
    "paper:eight_fireflys_stacked": paper_eight_fireflys_stacked,
    "paper:eight_mixed_transitions": paper_eight_mixed_transitions,
    "paper:ten_mixed_rest": paper_ten_mixed_rest,
}

GENERATOR_PARAMS: dict[str, type[GeneratorParams]] = {
    p.kind: p for p in (AntipodalSphereParams, RandomBoxParams, GridSwapParams, StackedParams,
                        AntipodalCircleParams, PillarsParams, WallGapParams, LowCeilingParams,
                        RandomObstaclesParams, CrossingTrafficParams, IntruderParams)
}
# each generator declared its model (jaxplan.scenarios.params.generates)
GENERATORS: dict[str, Callable[..., Scenario]] = {
    kind: p.generator for kind, p in GENERATOR_PARAMS.items()}
AnyGeneratorParams = (AntipodalSphereParams | RandomBoxParams | GridSwapParams | StackedParams
                      | AntipodalCircleParams | PillarsParams | WallGapParams | LowCeilingParams
                      | RandomObstaclesParams | CrossingTrafficParams | IntruderParams)

_MIXED = ("firefly", "neo11")

SCENARIOS: dict[str, ScenarioSpec] = {
    "paper:six_neos": ScenarioSpec(
        "paper:six_neos", "six Neos at random starts and goals, rest start, free end",
        paper_six_neos, True),
    "paper:eight_fireflys_stacked": ScenarioSpec(
        "paper:eight_fireflys_stacked",
        "eight Fireflys from two tight stacks (closer than r_i + r_j) to a grid, free end",
        paper_eight_fireflys_stacked, True),
    "paper:eight_mixed_transitions": ScenarioSpec(
        "paper:eight_mixed_transitions",
        "five Fireflys + three Neos, four ring transitions (rest, then three free-end)",
        paper_eight_mixed_transitions, True),
    "paper:ten_mixed_rest": ScenarioSpec(
        "paper:ten_mixed_rest",
        "five Fireflys + five Neos swap across a 3.5 m ring, rest-to-rest",
        paper_ten_mixed_rest, True),
    "antipodal_sphere": ScenarioSpec(
        "antipodal_sphere",
        "robots on a sphere fly to the antipodal point (default 10 mixed, 4 m radius)",
        functools.partial(antipodal_sphere, count=10, radius=4.0, vehicles=_MIXED)),
    "random_box": ScenarioSpec(
        "random_box", "random starts and goals in a box with minimum spacing (default 20)",
        functools.partial(random_box, count=20, box=[[-4.0, -4.0, 1.0], [4.0, 4.0, 4.0]],
                          vehicles=_MIXED)),
    "grid_swap": ScenarioSpec(
        "grid_swap", "a grid swaps with its mirror through the centre (default 3 x 4)",
        functools.partial(grid_swap, rows=3, cols=4)),
    "stacked": ScenarioSpec(
        "stacked", "a vertical stack flies to a spread-out row (default 6)",
        functools.partial(stacked, count=6)),
    "antipodal_circle": ScenarioSpec(
        "antipodal_circle",
        "ground robots on a 4 m circle in the plane swap to the antipodal point (default 12)",
        functools.partial(antipodal_circle, count=12, radius=4.0, vehicles=("ground",))),
    "pillars": ScenarioSpec(
        "pillars", "two groups cross a field of vertical cylinders (default 12 robots)",
        pillars),
    "wall_gap": ScenarioSpec(
        "wall_gap", "two groups of 6 swap through a 1.5 m slot in a wall", wall_gap),
    "low_ceiling": ScenarioSpec(
        "low_ceiling", "10 robots swap across a 4 m circle under a 2.5 m ceiling", low_ceiling),
    "random_obstacles": ScenarioSpec(
        "random_obstacles", "random starts and goals among random obstacles "
        "(default 12 robots, 15 obstacles)", random_obstacles),
    "crossing_traffic": ScenarioSpec(
        "crossing_traffic", "8 robots fly along a corridor that 6 people (moving cylinders) "
        "cross at up to 1 m/s", crossing_traffic),
    "intruder": ScenarioSpec(
        "intruder", "a non-cooperative drone crosses a swarm of 10 mid-swap", intruder),
}


def build(name: str, seed: int = 0, **params: Any) -> Scenario:
    """Build a registered scenario by name (see SCENARIOS), e.g. build("paper:six_neos", 3)."""
    try:
        spec = SCENARIOS[name]
    except KeyError:
        raise ScenarioError(f"unknown scenario {name!r}; choose one of "
                            f"{', '.join(SCENARIOS)}") from None
    return spec.build(seed=seed, **params)
