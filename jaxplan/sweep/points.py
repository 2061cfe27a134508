"""A sweep's grid: its points and its scenarios (docs/DESIGN.md "A sweep directory").

    SweepPoint(q_obs, q_lim, scenario, seed)            one run of the grid; .key
    scenario_sources(config) -> [ScenarioSource]        the grid's scenarios: label, build(seed)
    sweep_points(config) -> [SweepPoint]                the whole grid, in run order
    build_scenarios(config, points) -> {(label, seed): Scenario}

The grid is ``[sweep] q_obs x q_lim x seeds x scenarios``; a point's key
(:func:`jaxplan.sweep.table.make_key`) keys its sweep.csv row.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

from jaxplan import scenarios
from jaxplan.config import Config, build_scenario
from jaxplan.scenarios import Scenario
from jaxplan.sweep.table import SweepError, make_key

__all__ = ["ScenarioSource", "SweepPoint", "build_scenarios", "scenario_sources", "sweep_points"]


@dataclass(frozen=True)
class SweepPoint:
    """One run of the grid: weights, scenario label, seed."""

    q_obs: float
    q_lim: float
    scenario: str
    seed: int

    @property
    def key(self) -> tuple[str, str, str, str]:
        return make_key(self.q_obs, self.q_lim, self.scenario, self.seed)


@dataclass(frozen=True)
class ScenarioSource:
    """A scenario of the grid: its label (the sweep.csv ``scenario`` column) and
    ``build(seed) -> Scenario``."""

    label: str
    build: Callable[[int], Scenario]


def scenario_sources(config: Config) -> list[ScenarioSource]:
    """The grid's scenarios: ``[sweep] scenarios`` empty: the config's own fleet, named
    by its ``[scenario] kind`` or, with ``[[robots]]``, by the config's name; given:
    those registry scenarios, built with their defaults and the config's [limits]."""
    sw = config.sweep
    if not sw.scenarios:
        if config.scenario is not None and not config.robots:
            label = config.scenario.kind
        else:
            label = config.name
        return [ScenarioSource(
            label, lambda s: build_scenario(dataclasses.replace(config, seed=int(s))))]
    lim = config.limits

    def builder(name):
        def build(seed):
            return scenarios.build(name, seed=int(seed)).with_limits(
                lim.v_max, lim.a_max, lim.j_max)
        return build

    return [ScenarioSource(n, builder(n)) for n in dict.fromkeys(sw.scenarios)]


def sweep_points(config: Config) -> list[SweepPoint]:
    """The whole grid of a config's [sweep], in run order: scenario, q_obs, q_lim, seed."""
    sw = config.sweep
    return [SweepPoint(float(qo), float(ql), src.label, int(s))
            for src in scenario_sources(config)
            for qo in dict.fromkeys(sw.q_obs)
            for ql in dict.fromkeys(sw.q_lim)
            for s in dict.fromkeys(sw.seeds)]


def build_scenarios(config: Config, points) -> dict[tuple[str, int], Scenario]:
    """Every (scenario label, seed) of the points, built once.  Raises SweepError
    naming the scenario and seed that cannot be built."""
    sources = {s.label: s for s in scenario_sources(config)}
    built: dict[tuple[str, int], Scenario] = {}
    for p in points:
        if (p.scenario, p.seed) not in built:
            try:
                built[(p.scenario, p.seed)] = sources[p.scenario].build(p.seed)
            except (scenarios.ScenarioError, ValueError) as e:
                raise SweepError(f"{config.source or config.name}: scenario "
                                 f"{p.scenario!r}, seed {p.seed}: {e}") from None
    return built
