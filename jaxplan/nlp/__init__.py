"""The per-robot NLP (docs/MATH.md section 2): objective, constraints and their derivatives.

Modules: :mod:`~jaxplan.nlp.types` (the data), :mod:`~jaxplan.nlp.basis` (static bases,
variables), :mod:`~jaxplan.nlp.terms` (reference values of each term),
:mod:`~jaxplan.nlp.derivs` (structured derivatives, what the solver evaluates).  Import
from the package: its names below are the public surface.

Decision variables
------------------
Robot i's trajectory has ``S`` equal segments of degree ``D`` per axis (paper: D = 5,
S = 1) joined C^2, and a horizon T.  Every equality constraint of the NLP is LINEAR in
the normalized-time coefficients c (per axis, stacked over segments) for a given
segment length h = T / S:

    start      x(0) = p0, x'(0) = v0, x''(0) = a0         ->  rows of A c = e(h)
    joints     C^2 continuity between segments             ->  A c = 0
    end        x(T) = pf  (and v(T) = vf, a(T) = af when ``rest``)
    with  e(h) = [p0, v0 h, a0 h^2, pf, vf h, af h^2]  and A CONSTANT.

So the feasible coefficients are exactly  c = P e(h) + Z z  (a null-space, i.e. reduced
KKT, parametrization), where

* P e(h) is the minimum-jerk trajectory through the boundary conditions for this T
  (z = 0 *is* the closed-form prediction of docs/MATH.md section 1 for that T), and
* Z spans null(A), chosen so that Z' Q Z = diag(q) (Q the jerk Gram matrix) and the
  positions of Z z at dense samples are orthonormal: one unit of z moves the path by
  about one metre RMS.  The smoothness term is then exactly
  h^-5 (sum_d e_d' M e_d + sum q_i z_di^2)  with M = P' Q P.

The decision vector is  x = (z (N, nz) flattened, tau = log T):  N nz + 1 numbers
(paper, free end: 7; the rest end of the paper has nz_rest = 0 shape freedom, docs/MATH.md).
The equality constraints hold to rounding at every iterate (see
:func:`equality_residual`).  Free and rest ends share the size nz = nz_free; a rest lane
uses two fewer shape variables per axis and its spare ones are inert (they carry only
the cost h^-5 z^2, so they stay 0).  The end-state kind is a traced per-lane flag.

Objective terms (all integrals over [0, T], T = exp(tau)):
  smoothness  q_dynm * int |x'''|^2 dt             exact (analytic)
  time        k_t * T
  limits      q_lim * int sum_k sexp(|x^(k)|^2 - tau_k^2) dt, k = 1, 2, 3 (norms over
              axes), Gauss-Legendre per segment.  sexp = exp below 30 and its quadratic
              Taylor continuation above (keeps the value finite; documented deviation).
  collision   per ``NLPStructure.collision``:
     "paper"       q_obs * int sum_j (dx . dv) / (d exp(k_p (d - rho_j))) dt  (the printed
                   term).  It is a total derivative (docs/MATH.md), so it is integrated
                   exactly, as q_obs sum_j (exp(-k_p (d_j(0) - rho_j)) - exp(-k_p (d_j(T)
                   - rho_j))) / k_p: path independent.  (Quadrature of the printed
                   integrand is path dependent only through its error, which a solver
                   then exploits: objective unbounded in the nodes, no convergence.)
     "barrier"     q_obs * int sum_j exp(-k_p (d_j - rho_j)) dt
     "constraint"  d_j(t_k)^2 >= rho_j^2 at the collision samples (hard; augmented
                   Lagrangian in the solver)
     "barrier+constraint"  both.
  Integrals over collision terms use composite 4-point Gauss-Legendre panels; the
  same nodes are the constraint samples (t = 0 and t = T excluded: both are fixed).
Optional hard limits (``hard_limits``): 1 - |b|^2 / tau_k^2 >= 0 for every Bernstein
control point b of x^(k), k = 1..3, on each of ``limit_subdivisions`` equal pieces of
every segment (a fixed linear map of the derivative at nodes in the piece): the curve
lies in the hull of its control points, so the limits hold at every instant.  Bound: T >= t_min.

Derivatives
-----------
All derivatives come from JAX autodiff; structure makes them cheap.  Every sampled term
is  sum_k F_k(P_1k, .., P_mk, T)  with a few feature groups P_g (N, K) (the own
position at the collision samples; velocity, acceleration and jerk at the limit
samples) and T.  Each axis's features are affine in that axis's shape variables for a
fixed tau:  P_g = b_g(tau) + z C_g(tau)^T  (C_g the same for every axis; constant except
on the coast rows).  So, with the local gradient and Hessian of F_k in its few
features (autodiff of the scalar functions: ``_elementwise_derivs``) and the tau jets of b_g and
C_g (nested jvp: ``_affine_jets``), the gradient and Hessian in x are sums of
small per-sample blocks (``_chain``, one for every sample set: each (group, sample) pair
is a row, and the shape block of the Hessian is one product over the rows): no (n x n)
Hessian per sample.  The other robots' positions at t_k = T s_k depend on T; their
second-order Taylor jet in T (exact value, first and second derivative at the current
T) is formed at every evaluation from their coefficients, laid out once per solve
(:func:`prepare_others`).  Checked against jax.hessian in tests/test_costs.py.
"""

from jaxplan.nlp.basis import (
                               Basis,
                               KindConstants,
                               basis,
                               boundary_vector,
                               coefficients,
                               equality_residual,
                               falling,
                               kind_constants,
                               pack,
                               to_trajectory,
                               unpack,
)
from jaxplan.nlp.derivs import OthersPrep, merit_derivs, merit_shapes, others_jet, prepare_others
from jaxplan.nlp.terms import (
                               al_term,
                               coast_time,
                               collision_rows,
                               constraints,
                               evaluate_terms,
                               has_sampled_collision,
                               merit,
                               merit_and_constraints,
                               objective,
                               others_derivs,
                               paper_collision,
                               sexp,
                               smooth_time,
)
from jaxplan.nlp.types import (
                               COLLISION_MODES,
                               DIST_EPS2,
                               PLANNER_COLLISION_MODES,
                               SEXP_KNEE,
                               Limits,
                               Multipliers,
                               NLPParams,
                               NLPStructure,
                               Weights,
)

__all__ = [
    "COLLISION_MODES", "DIST_EPS2", "PLANNER_COLLISION_MODES", "SEXP_KNEE", "Basis",
    "KindConstants", "Limits", "Multipliers", "NLPParams", "NLPStructure", "OthersPrep",
    "Weights", "al_term", "basis", "boundary_vector", "coast_time", "coefficients",
    "collision_rows", "constraints", "equality_residual", "evaluate_terms", "falling",
    "has_sampled_collision", "kind_constants", "merit", "merit_and_constraints", "merit_derivs",
    "merit_shapes", "objective", "others_derivs", "others_jet", "pack", "paper_collision",
    "prepare_others", "sexp", "smooth_time", "to_trajectory", "unpack",
]
