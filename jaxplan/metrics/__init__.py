"""Post-run analysis on the host (NumPy): what a run's numbers are and how they are
measured (docs/DESIGN.md "A run directory", docs/MATH.md 4).

Modules:

    pieces.py       the pieces' checks and the exact polynomial machinery (roots in [0, 1])
    separation.py   exact continuous-time separation of every robot pair
    motion.py       how the robots moved: kinematic maxima, path length, sampling, time
                    to goal, parked robots, the makespan's bound; the replans' times
    clearance.py    exact clearance to the world's obstacles and workspace faces
    excursion.py    how far robots strayed from a reached goal, and outside a box
    report.py       a run's metrics.json and trajectories.npz from its records
                    (``from jaxplan.metrics.report import compute_metrics``; it reads the
                    planner's and the solver's codes, so the package does not import it)

The functions of the first five work on the executed plan pieces of a run, as stored in
``trajectories.npz``:

    seg_robot  (S,)          int, the robot each piece belongs to, 0 <= r < M
    seg_t0     (S,)          s, piece start time
    seg_t1     (S,)          s, piece end time (>= seg_t0; zero-length pieces allowed)
    seg_coeffs (S, N, D+1)   m, monomial coefficients in (t - seg_t0) seconds,
                             lowest power first; N >= 1 spatial dims, D >= 0 the degree

A robot's pieces must not overlap each other in time (shared end points allowed, with a
1e-9 relative slack); they normally tile its time line without gaps, but gaps are
allowed (nothing is measured in a gap).
"""

from __future__ import annotations

from jaxplan.metrics.clearance import (
    WorldClearance,
    exact_signed_distance,
    world_clearance,
    world_report,
)
from jaxplan.metrics.excursion import escape_pieces, fleet_box, goal_excursion_pieces
from jaxplan.metrics.motion import (
    Kinematics,
    kinematics,
    makespan_bound,
    parked_robots,
    sample_pieces,
    solver_summary,
    time_to_goal,
    time_to_goal_pieces,
)
from jaxplan.metrics.separation import pairwise_min_separation, separation_report

__all__ = [
    "pairwise_min_separation",
    "separation_report",
    "Kinematics",
    "kinematics",
    "sample_pieces",
    "time_to_goal",
    "time_to_goal_pieces",
    "solver_summary",
    "parked_robots",
    "makespan_bound",
    "WorldClearance",
    "world_clearance",
    "world_report",
    "exact_signed_distance",
    "goal_excursion_pieces",
    "escape_pieces",
    "fleet_box",
]
