"""ORCA on a planar fleet as the issue "Baselines" describes its protocol, written
directly against pyrvo (not through jaxplan's harness, jaxplan/baselines/orca.py): an
independent check of the harness's ORCA makespans.

    python experiments/orca_protocol.py experiments/deadlock/box_planar.toml \
        --count 20 --box 4 --seeds 20

Each seed's fleet is the config's scenario (jaxplan's generator); every step of
``--dt`` s each agent (radius ``--radius``, v_max 2 m/s, neighbour distance 5 m, 10
neighbours, both time horizons 2 s) is given the preferred velocity towards its goal at
min(v_max, sqrt(2 a_max d)); RVO2 picks a velocity, its change from the last one is
clamped to a_max dt, and the agent moves at the clamped velocity.  Printed per seed and
as medians: the first-arrival makespan (the last robot's first time within 0.1 m of its
goal, jaxplan's makespan) and the time at which every robot is within 0.1 m at once,
both over the bound max_i(D_i / v_max + v_max / a_max), and the least centre distance
over 2 r.
"""

from __future__ import annotations

import argparse
import tomllib

import numpy as np

from jaxplan.baselines.orca import pyrvo_module
from jaxplan.config import build_scenario, parse_config

V_MAX, A_MAX, TOL = 2.0, 4.0, 0.1


def one_run(start, goal, radius, dt, t_end=60.0):
    """(first-arrival makespan s, all-within-at-once s (NaN: never), least distance m)."""
    pyrvo = pyrvo_module()
    M = start.shape[0]
    sim = pyrvo.RVOSimulator()
    sim.set_time_step(dt)
    for i in range(M):
        sim.add_agent(tuple(map(float, start[i])), 5.0, 10, 2.0, 2.0, radius, V_MAX, (0.0, 0.0))
    first, t, v, least = np.full(M, np.nan), 0.0, np.zeros((M, 2)), np.inf
    while t < t_end:
        p = np.array([sim.get_agent_position(i).to_tuple() for i in range(M)])
        d = np.linalg.norm(goal - p, axis=1)
        first = np.where(np.isnan(first) & (d <= TOL), t, first)
        if np.all(d <= TOL):
            return np.max(first), t, least
        gap = np.linalg.norm(p[:, None] - p[None], axis=-1) + np.diag(np.full(M, np.inf))
        least = min(least, float(gap.min()))
        pref = (goal - p) / np.maximum(d, 1e-12)[:, None] \
            * np.minimum(V_MAX, np.sqrt(2.0 * A_MAX * d))[:, None]
        for i in range(M):
            sim.set_agent_pref_velocity(i, tuple(map(float, pref[i])))
        sim.do_step()
        new = np.array([sim.get_agent_velocity(i).to_tuple() for i in range(M)])
        dv = new - v
        n = np.linalg.norm(dv, axis=1)
        v = v + dv * np.where(n > A_MAX * dt, A_MAX * dt / np.maximum(n, 1e-12), 1.0)[:, None]
        for i in range(M):  # the clamped velocity moves the agent, from where it was
            sim.set_agent_velocity(i, tuple(map(float, v[i])))
            sim.set_agent_position(i, tuple(map(float, p[i] + v[i] * dt)))
        t += dt
    return np.nanmax(first) if np.all(np.isfinite(first)) else np.nan, np.nan, least


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("config", help="a planar fleet's TOML config")
    ap.add_argument("--count", type=int, help="robots (default: the config's)")
    ap.add_argument("--box", type=float, help="half-width of the square box (m)")
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--radius", type=float, default=0.3, help="agent radius (m)")
    ap.add_argument("--dt", type=float, default=0.05, help="ORCA step (s)")
    args = ap.parse_args(argv)
    with open(args.config, "rb") as f:
        doc = tomllib.load(f)
    if args.count is not None:
        doc["scenario"]["count"] = args.count
    if args.box is not None:
        doc["scenario"]["box"] = [[-args.box, -args.box], [args.box, args.box]]
    rows = []
    for seed in range(args.seeds):
        sc = build_scenario(parse_config({**doc, "seed": seed}, source=args.config))
        start, goal = np.asarray(sc.start), np.asarray(sc.waypoints[:, -1])
        bound = float(np.max(np.linalg.norm(goal - start, axis=1) / V_MAX + V_MAX / A_MAX))
        first, once, least = one_run(start, goal, args.radius, args.dt)
        rows.append((first / bound, once / bound, least / (2.0 * args.radius)))
        print(f"seed {seed:2d}: first arrival {rows[-1][0]:.2f}, all at once {rows[-1][1]:.2f} "
              f"(x bound), least d/rho {rows[-1][2]:.3f}")
    a = np.array(rows)
    print(f"median makespan / bound: first arrival {np.nanmedian(a[:, 0]):.2f}, all at once "
          f"{np.nanmedian(a[:, 1]):.2f}; least d/rho {np.min(a[:, 2]):.3f}")


if __name__ == "__main__":
    main()
