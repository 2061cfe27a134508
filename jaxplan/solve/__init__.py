"""The augmented-Lagrangian SQP solver of the per-robot NLP (docs/SOLVER.md).

Modules, one concept each: :mod:`~jaxplan.solve.types` (statuses, settings, Solution),
:mod:`~jaxplan.solve.alsqp` (one lane's iteration: init, step, finish; :func:`solve`),
:mod:`~jaxplan.solve.guess` (initial guesses, warm starts), :mod:`~jaxplan.solve.linalg`
(Newton directions, LAPACK safety), :mod:`~jaxplan.solve.pool` (the lane pool),
:mod:`~jaxplan.solve.devices` (CPU-device sharding, dtype coercion),
:mod:`~jaxplan.solve.batch` (the jitted batch entry points) and
:mod:`~jaxplan.solve.implicit` (implicit differentiation; the only jaxopt import, loaded
on first use).  Import from the package: its names below are the public surface.
"""

from jaxplan.solve.alsqp import solve
from jaxplan.solve.batch import initial_guess_batch, solve_batch
from jaxplan.solve.devices import as_strong_dtypes, default_shards, shard_lanes
from jaxplan.solve.guess import initial_guess, swerve_guess, warm_start
from jaxplan.solve.implicit import solve_differentiable
from jaxplan.solve.linalg import direction, directions, eigh_chunk
from jaxplan.solve.pool import (
                                FEW_OTHERS,
                                LOCKSTEP_MAX,
                                POOL_CPU,
                                POOL_CPU_FEW,
                                POOL_CPU_MANY,
                                SMALL_BATCH,
                                default_pool,
                                pool_steps,
                                solve_lanes,
)
from jaxplan.solve.types import (
                                CONVERGED,
                                INFEASIBLE,
                                LINE_SEARCH_FAILED,
                                MAX_ITERS,
                                NON_FINITE,
                                STATUS_NAMES,
                                Solution,
                                SolverSettings,
                                Status,
                                zero_multipliers,
)

__all__ = [
    "CONVERGED", "FEW_OTHERS", "INFEASIBLE", "LINE_SEARCH_FAILED", "LOCKSTEP_MAX", "MAX_ITERS",
    "NON_FINITE", "POOL_CPU", "POOL_CPU_FEW", "POOL_CPU_MANY", "SMALL_BATCH", "STATUS_NAMES",
    "Solution", "SolverSettings", "Status",
    "as_strong_dtypes", "default_pool", "default_shards", "direction", "directions",
    "eigh_chunk", "initial_guess", "initial_guess_batch", "pool_steps", "shard_lanes", "solve",
    "solve_batch", "solve_differentiable", "solve_lanes", "swerve_guess", "warm_start",
    "zero_multipliers",
]
