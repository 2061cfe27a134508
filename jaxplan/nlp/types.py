"""The NLP's data: weights, limits, the static structure, the per-robot parameters and
the augmented-Lagrangian multipliers (docs/MATH.md section 2; the decision variables and
terms are described in :mod:`jaxplan.nlp`).

COLLISION_MODES lists the collision treatments the NLP knows; PLANNER_COLLISION_MODES
those a planner config may choose (every mode but "none").
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import jax

from jaxplan.trajectory import Trajectory
from jaxplan.world import ALL_KINDS, StaticRows

# the collision treatments of the NLP ("none": no collision terms) and those a planner
# config may choose
COLLISION_MODES = ("paper", "barrier", "constraint", "barrier+constraint", "none")
PLANNER_COLLISION_MODES = tuple(m for m in COLLISION_MODES if m != "none")
# hard limits: equal pieces per segment on which the derivatives' Bernstein control
# points are bounded (the NLP's constraints and the bound a plan must meet to fly)
LIMIT_SUBDIVISIONS = 4
SEXP_KNEE = 30.0
DIST_EPS2 = 1e-12  # m^2, smooths |dx| at 0


# ---------------------------------------------------------------------- data
class Weights(NamedTuple):
    """Objective weights (scalars, traced: changing them does not recompile)."""

    q_dynm: jax.Array  # smoothness, per (m/s^3)^2 s
    q_obs: jax.Array  # collision cost
    q_lim: jax.Array  # soft dynamic limits
    k_t: jax.Array  # price of one second
    k_p: jax.Array  # 1/m, collision decay rate


class Limits(NamedTuple):
    """Dynamic limits (norms over axes), traced scalars."""

    v_max: jax.Array  # m/s
    a_max: jax.Array  # m/s^2
    j_max: jax.Array  # m/s^3


@dataclass(frozen=True)
class NLPStructure:
    """Static shape of the NLP (hashable; a change recompiles).

    Attributes:
        n_dim: spatial axes N.
        degree: polynomial degree D per segment (>= 5 for C^2 joints with freedom).
        segments: number of equal segments S (C^2 joints).
        collision: one of COLLISION_MODES ("none" disables collision terms).
        n_collision_samples: collision samples (a multiple of 4: composite 4-point
            Gauss-Legendre panels over [0, T]).
        n_quadrature: Gauss-Legendre nodes per segment for the soft-limit integral.
        hard_limits: add the constraints |b| <= tau_k on every Bernstein control point b
            of each derivative x^(k), k = 1..3, on each of ``limit_subdivisions`` equal
            pieces of every segment: a polynomial curve lies in the convex hull of its
            control points, so the limits then hold at every instant of [0, T].
        limit_subdivisions: the pieces per segment of the hard limits (the more, the
            closer the control points to the curve); the peak bound a plan must meet to
            fly under hard limits (:func:`jaxplan.planner.choice.limit_ratio`) is the same.
        n_coast_samples: collision constraints on a FREE-end plan's coast after T (what
            it flies if nothing replaced it: p(T) + v(T) t), at t = t_c k / n for
            k = 1..n, with t_c = :func:`jaxplan.nlp.terms.coast_time` (long enough to stop from
            v_max). Only in the modes with collision constraints; no barrier there; inactive on
            rest lanes (their coast is a hold, checked by the last samples).  0 = off
            (the paper's NLP).
        n_static: static rows R (obstacles and workspace faces, :mod:`jaxplan.world`),
            padded to a fixed count; their terms sit at the same collision rows as the
            robots' (barrier in the barrier modes and "paper", AL constraints
            4 P r (sd(p) - r) >= 0 in the constraint modes, P = STATIC_PRIORITY, coast
            rows included); 0 = none.
        static_kinds: the kinds of static rows (jaxplan.world SPHERE, BOX, CYLINDER,
            PLANE; sorted) the derivatives form: only these are computed, and a row of
            another kind has a NaN distance (its lane ends NON_FINITE, never with a wrong
            one).  Default every kind; :func:`jaxplan.run_setup.structures` gives a run
            its world's kinds (:func:`jaxplan.world.row_kinds`; the 3-D default world, the
            ground alone: PLANE), which makes a warm replan faster (docs/SOLVER.md).
    """

    n_dim: int = 3
    degree: int = 5
    segments: int = 1
    collision: str = "barrier+constraint"
    n_collision_samples: int = 32
    n_quadrature: int = 8
    hard_limits: bool = False
    limit_subdivisions: int = LIMIT_SUBDIVISIONS
    n_coast_samples: int = 0
    n_static: int = 0
    static_kinds: tuple = ALL_KINDS

    def __post_init__(self):
        if self.collision not in COLLISION_MODES:
            raise ValueError(f"collision must be one of {COLLISION_MODES}, got {self.collision!r}")
        if self.degree < 5:
            raise ValueError("degree must be >= 5 (a rest end needs 6 conditions per segment)")
        if self.segments < 1 or self.n_dim < 1:
            raise ValueError("segments and n_dim must be >= 1")
        if self.n_collision_samples % 4 or self.n_collision_samples < 4:
            raise ValueError("n_collision_samples must be a positive multiple of 4")
        if self.n_coast_samples < 0:
            raise ValueError("n_coast_samples must be >= 0")
        if self.n_static < 0:
            raise ValueError("n_static must be >= 0")
        kinds = tuple(self.static_kinds)
        if not kinds or kinds != tuple(sorted(set(kinds))) or not set(kinds) <= set(ALL_KINDS):
            raise ValueError(f"static_kinds must be a sorted, non-empty subset of {ALL_KINDS}, "
                             f"got {self.static_kinds!r}")

    @property
    def barrier(self) -> bool:
        """Whether the objective has the sampled collision barrier."""
        return self.collision in ("barrier", "barrier+constraint")

    @property
    def paper(self) -> bool:
        """Whether the collision term is the paper's (integrated exactly)."""
        return self.collision == "paper"

    @property
    def collision_constraints(self) -> bool:
        """Whether the NLP has hard collision constraints (augmented Lagrangian)."""
        return self.collision in ("constraint", "barrier+constraint")

    @property
    def static_terms(self) -> bool:
        """Whether the NLP has terms of static rows (obstacles, workspace faces)."""
        return self.n_static > 0 and self.collision != "none"

    @property
    def static_barrier(self) -> bool:
        """Whether the static rows have the sampled barrier (every mode with a barrier,
        and "paper": its exp(-k_p (d - rho)) form, sampled, as a static obstacle has no
        closed-form integral)."""
        return self.static_terms and (self.barrier or self.paper)

    @property
    def n_coast(self) -> int:
        """Coast samples in use (0 unless the mode has collision constraints)."""
        return self.n_coast_samples if self.collision_constraints else 0

    @property
    def n_col(self) -> int:
        """Rows of the collision constraints: the samples in [0, T], then the coast."""
        return self.n_collision_samples + self.n_coast

    @property
    def nz(self) -> int:
        """Shape variables per axis (free-end count; rest lanes use nz - 2)."""
        return self.segments * (self.degree - 2) - 1

    @property
    def n_x(self) -> int:
        """Length of the decision vector x = (z (N, nz) flattened, tau)."""
        return self.n_dim * self.nz + 1


class NLPParams(NamedTuple):
    """Everything one robot's NLP depends on besides its structure (a pytree).

    Shapes for one problem (add leading batch axes for vmap):
        p0, v0, a0: (N,) start state.   goal_p, goal_v, goal_a: (N,) end state.
        rest: () bool; True: fully defined end state (goal_p, goal_v, goal_a), False:
            free end (goal_p only).
        others: Trajectory with batch (Mo,): the other robots' predictions (any S, D).
        other_radius: (Mo,) m.   other_mask: (Mo,) bool, False = ignore.
        radius: () m.   weights: Weights.   limits: Limits.   t_min: () s (> 0).
        static: :class:`jaxplan.world.StaticRows` with R = ``structure.n_static`` rows
            (obstacles and workspace faces), or None (no static rows).
        limit_priority: () the hard-limit constraints' scale
            (:data:`jaxplan.nlp.terms.LIMIT_PRIORITY`), or None: LIMIT_PRIORITY.
    """

    p0: jax.Array
    v0: jax.Array
    a0: jax.Array
    goal_p: jax.Array
    goal_v: jax.Array
    goal_a: jax.Array
    rest: jax.Array
    others: Trajectory
    other_radius: jax.Array
    other_mask: jax.Array
    radius: jax.Array
    weights: Weights
    limits: Limits
    t_min: jax.Array
    static: StaticRows | None = None
    limit_priority: jax.Array | None = None


class Multipliers(NamedTuple):
    """Augmented-Lagrangian multipliers (>= 0) of the inequality constraints (the same
    shapes hold the constraints g >= 0 themselves)."""

    collision: jax.Array  # (Kc + n_coast, Mo)
    limits: jax.Array  # (Kh, 3)
    static: jax.Array | None = None  # (Kc + n_coast, R) obstacles and workspace faces
