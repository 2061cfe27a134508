"""The paper's four simulations as scenarios (coordinates chosen here: the paper gives
none; see jaxplan/scenarios/__init__.py), with a small seeded jitter of every start
and goal."""


from __future__ import annotations

import math

import numpy as np

from jaxplan.scenarios.generators import check_seed, random_box, random_in_ball
from jaxplan.scenarios.scenario import PAPER_JITTER, Scenario, make_scenario

# ---------------------------------------------------------------------- paper scenarios

# paper:eight_fireflys_stacked: two stacks of four, vertical neighbours 0.7 m apart (11%
# over 2 r = 0.63 m; with jitter >= 0.66 m).  The paper starts some robots "closer than
# their safety distance"; with rho_ij = r_i + r_j that would be a collision at t = 0 by
# the run directory's definition, so the stacks are as tight as a collision-free start
# allows: every start pair is within 1.15 rho_ij of touching.
STACKED_START = np.array(
    [[-3.0, y, z] for y in (-0.4, 0.4) for z in (1.1, 1.8, 2.5, 3.2)], dtype=np.float64)
# robot (stack s, level l) -> y = (-2.25, -0.75) + 1.5 * 2 s ..., z = 1.5 + (l // 2)
STACKED_GOAL = np.array(
    [[3.0, (-2.25, -0.75, 0.75, 2.25)[2 * s + (lvl % 2)], (1.5, 2.5)[lvl // 2]]
     for s in (0, 1) for lvl in range(4)], dtype=np.float64)

MIXED_VEHICLES = ("firefly", "neo11", "firefly", "neo11", "firefly", "neo11", "firefly",
                  "firefly")
MIXED_RING_RADIUS = 3.0
MIXED_SLOTS = (4, 2, 6, 0)        # waypoint w: robot k goes to slot (k + MIXED_SLOTS[w]) % 8
MIXED_ALTITUDES = (2.5, 1.5, 2.5, 1.5)   # waypoint altitudes; starts at 1.5 m
MIXED_REST = (True, False, False, False)

TEN_RING_RADIUS = 3.5
TEN_ALTITUDES = (1.7, 2.3)        # even / odd robot index


def _ring(slot, n, radius, z):
    ang = 2.0 * math.pi * np.asarray(slot, dtype=np.float64) / n
    return np.stack([radius * np.cos(ang), radius * np.sin(ang),
                     np.broadcast_to(np.asarray(z, np.float64), ang.shape)], axis=-1)


def paper_six_neos(seed: int = 0) -> Scenario:
    """Paper simulation 1: six Neo 11s spawned at random; rest start, free end.

    random_box in x, y in [-3, 3] m, z in [1, 3] m; starts and goals >= 1.2 m apart
    (r_i + r_j = 0.86 m), each goal >= 3 m from its start.
    """
    sc = random_box(6, box=[[-3.0, -3.0, 1.0], [3.0, 3.0, 3.0]], min_spacing=1.2,
                    vehicles=("neo11",), seed=seed, min_travel=3.0, end_state="free")
    return sc.with_name("six_neos")


def paper_eight_fireflys_stacked(seed: int = 0) -> Scenario:
    """Paper simulation 2: eight Fireflys from two tight stacks to a 4 x 2 grid; free end.

    Starts STACKED_START (vertical neighbours 0.7 m apart, within 11% of 2 r = 0.63 m),
    goals STACKED_GOAL; seeded jitter of PAPER_JITTER m.
    """
    rng = np.random.default_rng(check_seed(seed))
    start = STACKED_START + random_in_ball(rng, 8, 3, PAPER_JITTER)
    goal = STACKED_GOAL + random_in_ball(rng, 8, 3, PAPER_JITTER)
    return make_scenario("eight_fireflys_stacked", ("firefly",) * 8, start, goal, False)


def paper_eight_mixed_transitions(seed: int = 0) -> Scenario:
    """Paper simulation 3: five Fireflys and three Neos through four transitions.

    Ring of radius MIXED_RING_RADIUS with 8 slots; robot k starts at slot k, z = 1.5 m,
    then visits slots k + MIXED_SLOTS[w] at MIXED_ALTITUDES[w]; the first transition
    ends at rest, the other three are free-end.  Seeded jitter of PAPER_JITTER m.
    """
    rng = np.random.default_rng(check_seed(seed))
    k = np.arange(8)
    start = _ring(k, 8, MIXED_RING_RADIUS, 1.5) + random_in_ball(rng, 8, 3, PAPER_JITTER)
    wps = np.stack([_ring((k + s) % 8, 8, MIXED_RING_RADIUS, z)
                    for s, z in zip(MIXED_SLOTS, MIXED_ALTITUDES, strict=True)], axis=1)
    wps = wps + random_in_ball(rng, 8 * 4, 3, PAPER_JITTER).reshape(8, 4, 3)
    rest = np.tile(np.array(MIXED_REST), (8, 1))
    return make_scenario("eight_mixed_transitions", MIXED_VEHICLES, start, wps, rest)


def paper_ten_mixed_rest(seed: int = 0) -> Scenario:
    """Paper simulation 4: five Fireflys and five Neos (alternating), rest-to-rest.

    Ring of radius TEN_RING_RADIUS, 10 slots, z = TEN_ALTITUDES[k % 2]; robot k flies to
    the antipodal slot k + 5 at its own altitude.  Seeded jitter of PAPER_JITTER m.
    """
    rng = np.random.default_rng(check_seed(seed))
    k = np.arange(10)
    z = np.array(TEN_ALTITUDES)[k % 2]
    start = _ring(k, 10, TEN_RING_RADIUS, z) + random_in_ball(rng, 10, 3, PAPER_JITTER)
    goal = _ring(k + 5, 10, TEN_RING_RADIUS, z) + random_in_ball(rng, 10, 3, PAPER_JITTER)
    return make_scenario("ten_mixed_rest", ("firefly", "neo11") * 5, start, goal, True)
