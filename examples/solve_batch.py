"""Solve a small batch of robot NLPs at once (jaxplan's batched AL-SQP solver).

Shows: building the NLPs of one fleet replan (robots on a circle flying to the
antipodal points; each robot's NLP holds the other robots' closed-form predictions as
moving obstacles), solving them all in one call from their initial guesses, and
reading each lane's status, objective and horizon.  The first call compiles (~10 s).

Run:  .venv/bin/python examples/solve_batch.py [--robots M]
"""

import argparse

import numpy as np

# importing jaxplan turns on float64 in JAX; then the solver, the NLP's structure and a
# helper that builds a fleet's NLPParams (robot i's NLP sees the other M - 1 robots'
# predictions).
import jaxplan  # noqa: F401
from jaxplan.nlp import NLPStructure
from jaxplan.solve import STATUS_NAMES, SolverSettings, initial_guess_batch, solve_batch
from jaxplan.testing import antipodal, fleet_params, limits, weights


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robots", type=int, default=4, help="NLPs in the batch (default 4)")
    args = ap.parse_args(argv)
    M = args.robots

    # M robots on a 3 m circle at ~1.5 m height, goals on the opposite side, starting at
    # rest.  Free ends (rest=False, the paper's NLP): with one quintic segment a rest end
    # has no shape freedom left to swerve around the others (see docs/MATH.md, section 2).
    pos, goals = antipodal(M, 3.0, np.random.default_rng(0))
    zero = np.zeros_like(pos)
    # NLPParams with a leading batch axis (M,): weights (objective terms) and limits
    # (v_max, a_max, j_max) as jaxplan.nlp.Weights / Limits; robots 0.25 m in radius.
    params = fleet_params(pos, zero, zero, goals, rest=False, radius=0.25,
                          w=weights(k_t=1.0), lim=limits(v_max=2.0))
    structure = NLPStructure()  # static: one quintic segment, collision samples, 3-D
    settings = SolverSettings(max_iters=60)  # traced: new values do not recompile

    x0 = initial_guess_batch(params, structure)  # (M, n_x); solve_batch(params, None, ..)
    sol = solve_batch(params, x0, structure, settings)  # would form the same guesses

    status = [STATUS_NAMES[int(s)] for s in np.asarray(sol.status)]
    objective = np.asarray(sol.objective)
    horizon = np.asarray(sol.traj.duration)  # T of each plan, seconds
    iterations = np.asarray(sol.iterations)
    for i in range(M):
        print(f"robot {i}: {status[i]:<14} objective {objective[i]:9.4f}  "
              f"T {horizon[i]:6.3f} s  {iterations[i]:3d} iterations")
    return {"solution": sol, "params": params, "status": status, "objective": objective,
            "horizon": horizon, "goals": goals}


if __name__ == "__main__":
    main()
