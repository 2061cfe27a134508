"""The solution differentiable with respect to the weights, by implicit differentiation:
:func:`solve_differentiable`.  The only module that imports jaxopt (which is no longer
maintained upstream), so that it could be swapped.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxplan import nlp
from jaxplan.nlp import Multipliers, NLPParams, NLPStructure
from jaxplan.pytree import tree_where
from jaxplan.solve.alsqp import solve
from jaxplan.solve.types import NON_FINITE, Solution, SolverSettings, sanitize


def solve_differentiable(params: NLPParams, x0, structure: NLPStructure,
                         settings: SolverSettings = SolverSettings(),
                         multipliers: Multipliers | None = None, penalty=None) -> Solution:
    """:func:`solve`, with ``x``, ``traj`` and ``objective`` differentiable with respect
    to ``params.weights`` (q_dynm, q_obs, q_lim, k_t, k_p) by implicit differentiation
    (jaxopt ``custom_root``): for tuning weights by gradient.

    The forward pass is :func:`solve` (no gradient flows through its iterations).  The
    derivative is that of the root of the optimality condition at the solution: the
    gradient of the augmented Lagrangian in x, with the solution's multipliers and
    penalty held fixed (and, where T sits at its lower bound t_min, T held there).
    Exact for the modes without collision constraints ("barrier", "paper", "none").  With
    collision constraints it is the derivative of the augmented-Lagrangian subproblem, in
    which an active constraint acts as a spring of stiffness ``penalty`` rather than a
    rigid wall: an approximation, closer the larger the penalty.  Meaningful where
    ``status`` is CONVERGED.  Pure; jit/vmap at the call site.
    """
    from jaxopt.implicit_diff import custom_root
    from jaxopt.linear_solve import solve_lu

    sol = jax.lax.stop_gradient(solve(jax.lax.stop_gradient(params), x0, structure, settings,
                                      multipliers, penalty))
    p_s, _ = sanitize(params)
    kind = nlp.kind_constants(p_s.rest, structure)
    tau_min = jnp.log(jnp.maximum(jax.lax.stop_gradient(p_s.t_min), 1e-6))

    def grad_al(x, weights):
        return jax.grad(nlp.merit)(x, p_s._replace(weights=weights), structure, kind,
                                     sol.multipliers, sol.penalty)

    g_end = jax.lax.stop_gradient(grad_al(sol.x, p_s.weights))
    held = (sol.x[-1] <= tau_min + 1e-12) & (g_end[-1] > 0)

    def optimality(x, weights):
        g = grad_al(x, weights)
        return g.at[-1].set(jnp.where(held, x[-1] - tau_min, g[-1]))

    @custom_root(optimality, solve=solve_lu)
    def root(x_init, weights):
        del weights  # the forward solution is sol.x (computed above)
        return x_init

    x = root(sol.x, p_s.weights)
    traj = nlp.to_trajectory(x, p_s, structure)
    traj = tree_where(jnp.all(jnp.isfinite(sol.traj.coeffs)) & (sol.status != NON_FINITE),
                       traj, sol.traj)
    obj = nlp.evaluate_terms(x, p_s, structure, kind, None, 1.0)
    return sol._replace(x=x, traj=traj, objective=jnp.where(jnp.isnan(obj), jnp.inf, obj))
