"""The scripts in examples/ run, in-process (sharing JAX's compiled programs with the
rest of the test process), and produce what they say."""

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest
import scipy.optimize

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"



def load(name):
    """examples/NAME.py as a module (examples/ is not a package)."""
    spec = importlib.util.spec_from_file_location(f"example_{name}", EXAMPLES / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _rest_quintic_cost(p0, v0, a0, goal, T, w=1.0):
    """Independent of jaxplan: the rest-to-rest quintic through the boundary states for
    horizon T (a 6x6 solve per axis) and its cost int |jerk|^2 dt + w T."""
    P = np.polynomial.polynomial

    def rows(t):  # position, velocity, acceleration of sum_k c_k t^k, as rows in c
        k = np.arange(6.0)
        return [t ** k, k * t ** np.maximum(k - 1, 0), k * (k - 1) * t ** np.maximum(k - 2, 0)]

    A = np.array(rows(0.0) + rows(T))
    J, coeffs = w * T, []
    for d in range(len(p0)):
        c = np.linalg.solve(A, [p0[d], v0[d], a0[d], goal[d], 0.0, 0.0])
        jerk = P.polyder(c, 3)
        J += P.polyval(T, P.polyint(P.polymul(jerk, jerk)))
        coeffs.append(c)
    return J, np.array(coeffs)


def test_predict_one_robot(tmp_path, monkeypatch):
    ex = load("predict_one_robot")
    out = tmp_path / "pred.png"
    r = ex.main([str(out)])
    assert r["out"] == str(out)
    assert ex.main(["--out", str(tmp_path / "opt.png")])["out"] == str(tmp_path / "opt.png")
    monkeypatch.chdir(tmp_path)
    assert ex.main([])["out"] == "predict_one_robot.png"
    import matplotlib.image

    for png in (out, tmp_path / "opt.png", tmp_path / "predict_one_robot.png"):
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        img = matplotlib.image.imread(png)
        assert img.ndim == 3 and img.shape[0] > 100 and img.shape[1] > 100
        assert np.ptp(img[..., :3]) > 0.5  # something was drawn
    traj, T, goal = r["traj"], r["duration"], r["goal"]
    assert T == float(traj.duration) > 0
    # the script's start state (read back from the trajectory) ...
    p0, v0, a0 = (np.asarray(traj.evaluate(0.0, d)) for d in range(3))
    np.testing.assert_allclose(p0, [0.0, 0.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(v0, [0.5, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(a0, 0.0, atol=1e-12)
    # ... and a rest end at the goal
    np.testing.assert_allclose(np.asarray(traj.evaluate(T, 0)), goal, rtol=0, atol=1e-9)
    np.testing.assert_allclose(np.asarray(traj.evaluate(T, 1)), 0.0, atol=1e-9)
    np.testing.assert_allclose(np.asarray(traj.evaluate(T + 3.0, 0)), goal, atol=1e-9)  # holds
    # the optimal horizon, recomputed without jaxplan: minimize the cost over T
    opt = scipy.optimize.minimize_scalar(
        lambda s: _rest_quintic_cost(p0, v0, a0, goal, s)[0], bounds=(0.5 * T, 2.0 * T),
        method="bounded", options={"xatol": 1e-10})
    assert opt.x == pytest.approx(T, rel=1e-6)
    # the same quintic at that T
    _, c = _rest_quintic_cost(p0, v0, a0, goal, T)
    ts = np.linspace(0, T, 50)
    ref = np.stack([np.polynomial.polynomial.polyval(ts, cd) for cd in c], -1)
    np.testing.assert_allclose(np.asarray(traj.evaluate(ts, 0)), ref, atol=1e-9)
    fine = np.linalg.norm(np.asarray(traj.evaluate(np.linspace(0, T, 4001), 1)), axis=-1)
    assert r["peak_speed"] == pytest.approx(fine.max(), rel=1e-3)
    assert r["peak_speed"] <= fine.max() + 1e-12


def test_solve_batch():
    from jaxplan.solve import STATUS_NAMES

    ex = load("solve_batch")
    r = ex.main(["--robots", "3"])  # 3: the whole batch steps at once (one step compiled)
    sol, P = r["solution"], r["params"]
    assert len(r["status"]) == 3
    assert set(r["status"]) <= set(STATUS_NAMES.values())
    assert r["status"] == ["converged"] * 3  # an easy batch
    assert np.all(np.asarray(sol.status) == 0)
    assert np.all(np.isfinite(r["objective"]))
    np.testing.assert_array_equal(r["objective"], np.asarray(sol.objective))
    np.testing.assert_array_equal(r["horizon"], np.asarray(sol.traj.duration))
    assert np.all(r["horizon"] > 0)
    assert np.all(np.asarray(sol.ineq_violation) <= 1e-8)
    # every plan starts at its robot and ends at its goal
    T = np.asarray(sol.traj.duration)
    np.testing.assert_allclose(np.asarray(sol.traj.evaluate(0.0, 0)), np.asarray(P.p0),
                               atol=1e-9)
    np.testing.assert_allclose(np.asarray(sol.traj.evaluate(T, 0)), r["goals"], atol=1e-6)


def test_run_scenario(tmp_path):
    from jaxplan.files import load_run
    from tests.conftest import TINY_TOML

    ex = load("run_scenario")
    # the built-in scenario is the suite's tiny one: compiled programs are shared with it
    assert ex.TINY_TOML == TINY_TOML
    res = ex.main(["--out", str(tmp_path / "run"), "--no-figures"])
    m = res.metrics
    assert m["name"] == "tiny" and m["robots"] == 3
    assert m["success"] is True and m["collisions"] == 0
    # the metrics agree with the result's own arrays
    a = res.arrays
    rho = a["radius"][:, None] + a["radius"][None, :]
    iu = np.triu_indices(3, 1)
    ratio = np.min(a["min_dist"][iu] / rho[iu])
    assert ratio > 1.0
    assert m["min_separation_ratio"] == pytest.approx(ratio, rel=1e-9)
    ttg = [r["time_to_goal_s"] for r in m["per_robot"]]
    assert all(t is not None and 0 < t <= m["duration_s"] for t in ttg)
    assert m["makespan_s"] == max(ttg)
    tol = res.config.sim.goal_tolerance_m
    for i, t in enumerate(ttg):  # at its time to goal, each robot is at its goal
        k = int(np.argmin(np.abs(a["t"] - t)))
        assert np.linalg.norm(a["pos"][i, k] - a["goal"][i]) <= tol + 0.05
    # the run directory written holds the same metrics
    disk = load_run(tmp_path / "run", complete=True)
    assert (tmp_path / "run" / "config.toml").exists()
    for k in ("success", "collisions", "min_separation_ratio", "makespan_s"):
        assert disk.metrics[k] == m[k]
    assert [r["time_to_goal_s"] for r in disk.metrics["per_robot"]] == ttg
    np.testing.assert_array_equal(disk.pos, a["pos"])
    assert json.loads((tmp_path / "run" / "metrics.json").read_text())["success"] is True
