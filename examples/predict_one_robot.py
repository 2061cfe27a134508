"""One robot's closed-form minimum time-jerk prediction (jaxplan.predict).

Shows: predicting a trajectory from a moving start to a goal that it reaches at rest,
reading its optimal horizon T (``traj.duration``), evaluating it at any times
(``traj.evaluate(t, derivative)``), and plotting position and speed to a PNG.

Run:  .venv/bin/python examples/predict_one_robot.py [OUT.png]
      (default OUT: predict_one_robot.png in the current directory)
"""

import argparse

import matplotlib

matplotlib.use("Agg")  # headless: write files, never open a window
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import jaxplan  # noqa: E402, F401  (importing jaxplan turns on float64 in JAX)
from jaxplan.predict import predict  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", nargs="?", default=None, help="PNG path")
    ap.add_argument("--out", dest="out_opt", default=None, help="PNG path (same as OUT)")
    args = ap.parse_args(argv)
    out = args.out_opt or args.out or "predict_one_robot.png"

    # Start state (m, m/s, m/s^2) and goal (m): 3-D arrays, one robot (no batch axis).
    p0, v0, a0 = np.array([0.0, 0.0, 1.0]), np.array([0.5, 0.0, 0.0]), np.zeros(3)
    goal = np.array([4.0, 2.0, 1.5])
    # end="rest": stop at the goal (v = a = 0); end="free" leaves the end velocity free.
    traj = predict(p0, v0, a0, goal, end="rest", time_weight=1.0)
    T = float(traj.duration)  # the optimal horizon, seconds

    t = np.linspace(0.0, T, 200)
    pos = np.asarray(traj.evaluate(t, 0))  # (200, 3) m
    vel = np.asarray(traj.evaluate(t, 1))  # (200, 3) m/s
    speed = np.linalg.norm(vel, axis=-1)
    peak = float(speed.max())
    coeffs, breaks = traj.to_monomials()  # polynomial coefficients in seconds
    print(f"duration T = {T:.3f} s, peak speed {peak:.3f} m/s, "
          f"{coeffs.shape[-3]} segment(s) of degree {coeffs.shape[-1] - 1}")

    fig, (ax_p, ax_v) = plt.subplots(2, 1, sharex=True, figsize=(6, 5))
    for d, name in enumerate("xyz"):
        ax_p.plot(t, pos[:, d], label=name)
        ax_v.plot(t, vel[:, d], label=f"v{name}")
    ax_v.plot(t, speed, "k--", label="|v|")
    ax_p.set_ylabel("position (m)")
    ax_v.set_ylabel("velocity (m/s)")
    ax_v.set_xlabel("time (s)")
    ax_p.legend()
    ax_v.legend()
    fig.tight_layout()
    fig.savefig(out, dpi=80)
    plt.close(fig)
    print(f"wrote {out}")
    return {"traj": traj, "duration": T, "peak_speed": peak, "goal": goal, "out": out}


if __name__ == "__main__":
    main()
