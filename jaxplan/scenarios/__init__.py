"""Scenarios: the :class:`Scenario` fleet task, the paper's four simulations, the five
benchmark generators with their parameter models, and the registry (their config keys:
docs/DESIGN.md, "Config (TOML)").

A generator's ``[scenario]`` keys are declared once, by the parameter model next to it
(:class:`AntipodalSphereParams`, :class:`RandomBoxParams`, :class:`GridSwapParams`,
:class:`StackedParams`, :class:`AntipodalCircleParams`, field types from
jaxplan/fields.py): jaxplan/config/ validates a config's ``[scenario]`` table with it,
the generator's defaults are the model's, and the generator declares the model its own
(:func:`generates`, jaxplan/scenarios/params.py), by which the model builds its scenario.

Everything here is host-side NumPy (float64), deterministic for a seed: every random
choice draws from ``numpy.random.default_rng(seed)``.  Units are SI (m, m/s, m/s^2,
m/s^3).  A :class:`Scenario` holds ``M`` robots in ``N`` = 2 or 3 dimensions with ``W``
waypoints each; the fleet moves to waypoint ``w + 1`` when ALL robots have reached
waypoint ``w`` (the paper's multi-transition protocol).  Starts are rest states
(v = a = 0).

The paper (Krishnan et al.) gives no coordinates for its four simulations; the ones
below are our choice, inside a ~8 m x 8 m x 4 m arena, every start and goal at
z >= 1 m, goals at least r_i + r_j + 0.2 m apart, and every transit at least 3 m long
(a single rest-to-rest quintic under a_max = 4 m/s^2, j_max = 12 m/s^3 needs about
2.5 m to reach 2 m/s; a free end needs less), so that the 2 m/s top speed is reached.
A small seeded jitter (``PAPER_JITTER`` m, uniform in a ball) is added to every paper
start and goal, so that seeds differ and exact symmetries are broken.

``paper:six_neos``
    six Neo 11s at random (seeded) starts and goals in the box x, y in [-3, 3] m,
    z in [1, 3] m; starts and goals at least 1.2 m apart, each transit >= 3 m;
    rest start, free end.
``paper:eight_fireflys_stacked``
    eight Fireflys in two stacks of four at x = -3 m, y = -0.4 / +0.4 m,
    z = 1.2, 1.7, 2.2, 2.7 m (vertical neighbours 0.5 m apart, closer than the 0.63 m
    safety distance); goals on a 4 x 2 grid at x = +3 m, y = -2.25, -0.75, 0.75, 2.25 m,
    z = 1.5, 2.5 m; free end.  Transits ~6 m.
``paper:eight_mixed_transitions``
    five Fireflys and three Neos (F N F N F N F F) on eight slots of a ring of radius
    3 m about (0, 0) (slot k at 45 k degrees); robot k starts in slot k, then visits
    slots k+4 (rest end), k+2, k+6, k (free ends), alternating altitude 1.5 / 2.5 m
    per transition (start 1.5 m).  Transits 4.4 - 6.1 m.
``paper:ten_mixed_rest``
    five Fireflys and five Neos (alternating) on a ring of radius 3.5 m, z = 1.7 m
    (even k) / 2.3 m (odd k), each flying rest-to-rest to the antipodal slot at the same
    altitude (~7 m transits, all crossing near the centre).
"""

from jaxplan.fields import END_STATES, MAX_ROBOTS
from jaxplan.scenarios.generators import (
    PLACEMENTS,
    AntipodalCircleParams,
    AntipodalSphereParams,
    GridSwapParams,
    RandomBoxParams,
    StackedParams,
    antipodal_circle,
    antipodal_sphere,
    default_spacing,
    grid_swap,
    random_box,
    stacked,
)
from jaxplan.scenarios.paper import (
    STACKED_START,
    paper_eight_fireflys_stacked,
    paper_eight_mixed_transitions,
    paper_six_neos,
    paper_ten_mixed_rest,
)
from jaxplan.scenarios.params import GeneratorParams, generates
from jaxplan.scenarios.registry import (
    GENERATOR_PARAMS,
    GENERATORS,
    PAPER_SCENARIOS,
    SCENARIOS,
    AnyGeneratorParams,
    ScenarioSpec,
    build,
)
from jaxplan.scenarios.scenario import (
    PAPER_JITTER,
    SAFETY_MARGIN,
    Problem,
    Scenario,
    ScenarioError,
    make_scenario,
    scenario_problems,
    validate_scenario,
)

__all__ = [
    "Scenario",
    "ScenarioError",
    "ScenarioSpec",
    "Problem",
    "SCENARIOS",
    "PAPER_SCENARIOS",
    "GENERATORS",
    "GENERATOR_PARAMS",
    "PLACEMENTS",
    "default_spacing",
    "GeneratorParams",
    "generates",
    "AnyGeneratorParams",
    "AntipodalSphereParams",
    "RandomBoxParams",
    "GridSwapParams",
    "StackedParams",
    "AntipodalCircleParams",
    "END_STATES",
    "MAX_ROBOTS",
    "SAFETY_MARGIN",
    "PAPER_JITTER",
    "STACKED_START",
    "make_scenario",
    "scenario_problems",
    "validate_scenario",
    "antipodal_sphere",
    "random_box",
    "grid_swap",
    "stacked",
    "antipodal_circle",
    "paper_six_neos",
    "paper_eight_fireflys_stacked",
    "paper_eight_mixed_transitions",
    "paper_ten_mixed_rest",
    "build",
]
