"""Benchmark of the MJX closed loop: planning + SE(3) control + physics, and their parts.

    jaxplan bench sim [--json FILE]
    .venv/bin/python -m jaxplan.benchmarks.sim [--json FILE] [--quick]

The full closed loop (the target: >= 5x real time for one 10-vehicle world):

* ``closed_loop_rtf``: simulated seconds per wall second of ``jaxplan run`` on the
  antipodal_10 benchmark fleet (10 Fireflys and Neos, 8 m antipodal transits) under the
  "mjx" backend: the planner replanning all ten robots at 8 Hz on the simulated states,
  the controller at 250 Hz, physics at 500 Hz; compile time apart (``closed_loop_
  compile_s``).  ``closed_loop_rtf_transit``: the same over the first
  TRANSIT_S seconds only, while every robot is still flying (the busiest part; the
  30 s figure includes hovering at the goals, where replans are cheap).

The parts (10 mixed vehicles, 500 Hz physics, 250 Hz control, 8 Hz periods,
float64; every figure is the median of several repetitions, compile time apart):

* ``physics_control_rtf``: simulated seconds per wall second of ONE 10-vehicle world
  tracking fixed minimum-jerk plans, one jitted :func:`simulate_period` call per
  0.125 s period from Python (what a host-side receding-horizon loop pays, dispatch
  included), per layout; and ``..._in_scan``: the same periods inside one jitted
  ``lax.scan`` (what a fully jitted receding-horizon loop pays).  Planning is NOT
  included: the closed-loop figure is this time plus the planner's.
* ``worlds64_world_steps_per_s``: physics steps x worlds per wall second for 64 worlds
  (``vmap`` of ``simulate_period`` over a world axis), controller included.
* ``mjx_physics_only_steps_per_s``: a ``lax.scan`` of the layout's physics step alone
  (constant hover controls), to compare with the C engine like for like.
* ``c_mj_step_steps_per_s``: plain ``mujoco.mj_step`` on the same MuJoCo model (one
  world, constant controls), measured in the same run; ``c_rollout_64_world_steps_per_s``:
  ``mujoco.rollout`` of 64 worlds on 2 threads.  Ratios are MJX / C.
* ``world_cost``: what measuring the world costs: the in-scan figure of the default
  layout with no world, with the ground only (what every 3-D run measures) and with
  the ground and WORLD_OBSTACLES obstacles (spheres, boxes, cylinders), every
  vehicle's distance to each of them taken after every physics step
  (:mod:`jaxplan.sim.fleet`); the three compiled first, then timed in turn, so that
  their ratios come from the same minutes of the machine.  Beside it, why the world's
  geoms do not collide in MuJoCo: ``world_cost_physics_steps_per_s_{none,geoms,
  colliding}``, mjx.step alone for one Firefly without geoms, with the world's geoms
  (non-colliding) and the collision sphere, and with them colliding (MJX contacts and
  constraint solver).
* ``headroom``: with a closed-loop target of 5x real time for one world, the wall time
  per 0.125 s period left for planning = 0.125 / 5 - (physics + control per period).

CPU time (``time.process_time``) is reported beside wall time as a cross-check: the
machine is shared, so wall-clock figures are noisy; compare ratios taken in one run.
"""

from __future__ import annotations

import argparse
import json
import time

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

import jaxplan  # noqa: F401  (x64)
from jaxplan.sim import fleet
from jaxplan.sim import model as sim_model_lib
from jaxplan.timing import timed
from jaxplan.trajectory import Trajectory
from jaxplan.vehicles import GRAVITY, get_vehicle

NAMES = ("hummingbird", "firefly", "neo11") * 3 + ("hummingbird",)
PERIOD_S = 0.125


def _fleet_setup(M: int, world: int = 0):
    """Start positions on a circle (radius 4 m) and min-jerk lines of 3 m toward the centre."""
    ang = 2 * np.pi * np.arange(M) / M + 0.1 * world
    p0 = np.stack([4 * np.cos(ang), 4 * np.sin(ang), 1.5 + 0.1 * np.arange(M)], 1)
    p1 = p0 * np.array([0.25, 0.25, 1.0])
    L = p1 - p0
    T = 1.875 * np.linalg.norm(L, axis=1).max() / 2.0  # peak speed 2 m/s
    c = np.zeros((M, 1, 3, 6))
    c[:, 0, :, 0] = p0
    c[:, 0, :, 3], c[:, 0, :, 4], c[:, 0, :, 5] = 10 * L, -15 * L, 6 * L
    return p0, Trajectory.from_normalized(jnp.asarray(c), jnp.full(M, T))


def _median_wall_cpu(fn, reps):
    """Median wall and CPU seconds of fn() (which blocks) over reps calls."""
    wall, cpu = [], []
    for _ in range(reps):
        t, p = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - t)
        cpu.append(time.process_time() - p)
    return float(np.median(wall)), float(np.median(cpu))


def _bench_host_loop(sim, st0, plans, sim_seconds: float, reps: int) -> dict:
    """One world, one jitted call of simulate_period per period from Python."""
    n_periods = int(round(sim_seconds / PERIOD_S))
    _, compile_s = timed(fleet.simulate_period, sim, st0, plans, 0.0, PERIOD_S)

    def host_loop():
        st = st0
        for k in range(n_periods):
            st, rec = fleet.simulate_period(sim, st, plans, k * PERIOD_S, PERIOD_S)
        jax.block_until_ready(st)

    wall, cpu = _median_wall_cpu(host_loop, reps)
    return {"compile_s_period": compile_s,
            "physics_control_rtf": sim_seconds / wall,
            "physics_control_rtf_cpu": sim_seconds / cpu,
            "physics_control_ms_per_period": 1e3 * wall / n_periods}


def _bench_scan(sim, st0, plans, sim_seconds: float, reps: int) -> dict:
    """One world, all periods in one jitted lax.scan."""
    n_periods = int(round(sim_seconds / PERIOD_S))

    @jax.jit
    def scan_loop(st):
        def body(st, k):
            st, rec = fleet.simulate_period(sim, st, plans, k * PERIOD_S, PERIOD_S)
            return st, rec.track_err.max()
        return jax.lax.scan(body, st, jnp.arange(n_periods))

    _, compile_s = timed(scan_loop, st0)
    wall, cpu = _median_wall_cpu(lambda: jax.block_until_ready(scan_loop(st0)), reps)
    return {"compile_s_scan": compile_s,
            "physics_control_rtf_in_scan": sim_seconds / wall,
            "physics_control_rtf_in_scan_cpu": sim_seconds / cpu}


def _bench_physics_only(sim, st0, sim_seconds: float, reps: int) -> dict:
    """The layout's physics step alone (constant hover controls), one world."""
    n_steps = int(round(sim_seconds * sim.physics_hz))
    thrust = jnp.asarray([get_vehicle(n).mass * GRAVITY for n in NAMES])
    moments = jnp.zeros((len(NAMES), 3))

    @jax.jit
    def physics_only(data):
        return jax.lax.scan(lambda d, _: (fleet._physics_step(sim, d, thrust, moments), None),
                            data, length=n_steps)[0]

    jax.block_until_ready(physics_only(st0.data))
    wall, _ = _median_wall_cpu(lambda: jax.block_until_ready(physics_only(st0.data)), reps)
    return {"mjx_physics_only_steps_per_s": n_steps / wall}


def _bench_worlds(sim, sim_seconds: float, reps: int, worlds: int) -> dict:
    """A batch of worlds: vmap of simulate_period over a leading world axis."""
    setups = [_fleet_setup(len(NAMES), w) for w in range(worlds)]
    P0 = jnp.asarray(np.stack([s[0] for s in setups]))
    plans_w = jax.tree.map(lambda *x: jnp.stack(x), *[s[1] for s in setups])
    states = jax.vmap(lambda p: fleet.initial_state(sim, p))(P0)

    @jax.jit
    def worlds_period(st, t0):
        return jax.vmap(lambda s, p: fleet.simulate_period(sim, s, p, t0, PERIOD_S))(
            st, plans_w)

    _, compile_s = timed(worlds_period, states, 0.0)
    n_w = max(2, int(round(sim_seconds / PERIOD_S)) // 4)

    def worlds_loop():
        st = states
        for k in range(n_w):
            st, _ = worlds_period(st, k * PERIOD_S)
        jax.block_until_ready(st)

    wall, cpu = _median_wall_cpu(worlds_loop, max(2, reps // 2))
    steps = n_w * PERIOD_S * sim.physics_hz * worlds
    return {"compile_s_worlds": compile_s,
            f"worlds{worlds}_world_steps_per_s": steps / wall,
            f"worlds{worlds}_world_steps_per_s_cpu": steps / cpu,
            f"worlds{worlds}_rtf_per_world": n_w * PERIOD_S * worlds / wall}


def _bench_layout(layout: str, sim_seconds: float, reps: int, worlds: int) -> dict:
    """Every figure of one layout ("vmap" or "fleet"); ``worlds`` 0 skips the batch."""
    p0, plans = _fleet_setup(len(NAMES))
    sim, st0 = fleet.init_sim(NAMES, p0, layout=layout)
    out = _bench_host_loop(sim, st0, plans, sim_seconds, reps)
    out.update(_bench_scan(sim, st0, plans, sim_seconds, reps))
    out.update(_bench_physics_only(sim, st0, sim_seconds, reps))
    if worlds:
        out.update(_bench_worlds(sim, sim_seconds, reps, worlds))
    return out


WORLD_OBSTACLES = 20


def bench_world(n_obstacles: int = WORLD_OBSTACLES):
    """The ground and ``n_obstacles`` obstacles (spheres, boxes, cylinders in turn) around
    the benchmark fleet, away from its paths."""
    from jaxplan.world import World

    obs = []
    for k in range(n_obstacles):
        ang = 2 * np.pi * k / max(1, n_obstacles)
        c = [6.5 * np.cos(ang), 6.5 * np.sin(ang), 1.5]
        obs.append([dict(kind="sphere", center=c, radius=0.4),
                    dict(kind="box", center=c, half_extents=[0.3, 0.4, 1.0]),
                    dict(kind="cylinder", center=c, radius=0.3, half_height=1.5)][k % 3])
    return World.default(3).with_obstacles(obs)


def _bench_world_cost(sim_seconds: float, reps: int) -> dict:
    """The in-scan figure with no world, the ground, the ground + WORLD_OBSTACLES."""
    from jaxplan.world import World

    n_periods = int(round(sim_seconds / PERIOD_S))
    p0, plans = _fleet_setup(len(NAMES))
    runs = {}
    for label, world in (("none", World.unbounded(3)), ("ground", World.default(3)),
                         (f"ground_{WORLD_OBSTACLES}", bench_world())):
        sim, st0 = fleet.init_sim(NAMES, p0, world=world)

        def scan_loop(st, sim=sim):
            def body(st, k):
                st, rec = fleet.simulate_period(sim, st, plans, k * PERIOD_S, PERIOD_S)
                return st, rec.static_dist.min(initial=jnp.inf)
            return jax.lax.scan(body, st, jnp.arange(n_periods))

        fn = jax.jit(scan_loop)
        jax.block_until_ready(fn(st0))
        runs[label] = (fn, st0, [])
    for _ in range(reps):
        for fn, st0, times in runs.values():
            t = time.perf_counter()
            jax.block_until_ready(fn(st0))
            times.append(time.perf_counter() - t)
    out = {f"world_cost_rtf_in_scan_{k}": sim_seconds / float(np.median(v[2]))
           for k, v in runs.items()}
    out.update(_bench_contact_cost(reps))
    base = out["world_cost_rtf_in_scan_none"]
    for k in ("ground", f"ground_{WORLD_OBSTACLES}"):
        out[f"world_cost_slowdown_{k}"] = base / out[f"world_cost_rtf_in_scan_{k}"]
    return out


def _bench_contact_cost(reps: int, steps: int = 1000) -> dict:
    """mjx.step of one hovering Firefly: no geoms / the bench world's geoms and its
    collision sphere, non-colliding / the same, colliding."""
    mjx = fleet.mjx
    xml0 = sim_model_lib.fleet_xml(["firefly"], [[0.0, 0.0, 1.5]], visual=False)
    xml1 = sim_model_lib.fleet_xml(["firefly"], [[0.0, 0.0, 1.5]], visual=False,
                                   world=bench_world(), hull_radii=[0.3])
    xml2 = xml1.replace('contype="0" conaffinity="0"', 'contype="1" conaffinity="1"')
    runs = {}
    for label, xml in (("none", xml0), ("geoms", xml1), ("colliding", xml2)):
        mx = mjx.put_model(mujoco.MjModel.from_xml_string(xml))
        dx = mjx.make_data(mx).replace(
            ctrl=jnp.array([get_vehicle("firefly").mass * GRAVITY, 0.0, 0.0, 0.0]))
        fn = jax.jit(lambda d, mx=mx: jax.lax.scan(
            lambda d, _: (mjx.step(mx, d), None), d, length=steps)[0])
        jax.block_until_ready(fn(dx))
        runs[label] = (fn, dx, [])
    for _ in range(reps):
        for fn, dx, times in runs.values():
            t = time.perf_counter()
            jax.block_until_ready(fn(dx))
            times.append(time.perf_counter() - t)
    return {f"world_cost_physics_steps_per_s_{k}": steps / float(np.median(v[2]))
            for k, v in runs.items()}


def _bench_c(sim_seconds: float, reps: int, worlds: int) -> dict:
    M = len(NAMES)
    p0, _ = _fleet_setup(M)
    m = sim_model_lib.fleet_model(NAMES, p0, visual=False)
    d = mujoco.MjData(m)
    ctrl = np.concatenate([[get_vehicle(n).mass * GRAVITY, 0, 0, 0] for n in NAMES])
    d.ctrl[:] = ctrl
    n_steps = int(round(sim_seconds / m.opt.timestep))

    def loop():
        for _ in range(n_steps):
            mujoco.mj_step(m, d)

    wall, _ = _median_wall_cpu(loop, reps)
    out = {"c_mj_step_steps_per_s": n_steps / wall}
    try:
        from mujoco import rollout
    except ImportError:  # pragma: no cover
        return out
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    s0 = np.empty(mujoco.mj_stateSize(m, spec))
    d2 = mujoco.MjData(m)
    mujoco.mj_getState(m, d2, s0, spec)
    n_r = int(round(sim_seconds / 4 / m.opt.timestep))
    init = np.tile(s0, (worlds, 1))
    ctrls = np.tile(ctrl, (worlds, n_r, 1))
    datas = [mujoco.MjData(m) for _ in range(2)]
    rollout.rollout(m, datas, init, ctrls)  # warm-up
    wall, _ = _median_wall_cpu(lambda: rollout.rollout(m, datas, init, ctrls), reps)
    out[f"c_rollout_{worlds}_world_steps_per_s"] = worlds * n_r / wall
    return out


TRANSIT_S = 10.0  # s: antipodal_10's robots are all still moving until about 10 s


def closed_loop_config(duration_s: float):
    """The antipodal_10 benchmark fleet (experiments/benchmarks/antipodal_10.toml) under
    the "mjx" backend for ``duration_s`` seconds."""
    from jaxplan.config import parse_config

    doc = {
        "name": "antipodal_10_mjx", "seed": 0,
        "sim": {"backend": "mjx", "duration_s": float(duration_s)},
        "scenario": {"kind": "antipodal_sphere", "count": 10, "radius": 4.0,
                     "center": [0.0, 0.0, 5.0], "placement": "even", "perturbation": 0.05,
                     "vehicles": ["firefly", "neo11"], "end_state": "rest"},
    }
    return parse_config(doc, source="bench:antipodal_10_mjx")


def _bench_closed_loop(duration_s: float) -> dict:
    from jaxplan.experiment import run as run_experiment

    r = run_experiment(closed_loop_config(duration_s))
    m = r.metrics
    return {"sim_s": duration_s, "run_s": float(r.run_s), "compile_s": float(r.compile_s),
            "rtf": duration_s / float(r.run_s), "success": bool(m["success"]),
            "collisions": int(m["collisions"]),
            "tracking_rms_m": float(m["tracking"]["rms_m"]) if "tracking" in m else None}


def run(json_path=None, *, quick: bool = False, layouts=("vmap", "fleet")) -> dict:
    """Run the benchmark, print it, optionally write JSON.

    Args:
        json_path: file to write the results to (JSON), or None.
        quick: shorter runs (fewer repetitions, 2 s instead of 4 s simulated).
        layouts: the layouts to measure.
    Returns:
        dict of figures (module docstring); the default layout's under plain keys, each
        layout's under ``layouts[<name>]``.
    """
    sim_seconds = 2.0 if quick else 4.0
    reps = 3 if quick else 5
    worlds = 64
    res = {"vehicles": len(NAMES), "physics_hz": 500, "control_hz": 250, "period_s": PERIOD_S,
           "sim_seconds": sim_seconds, "repetitions": reps, "default_layout": fleet.DEFAULT_LAYOUT,
           "jax": jax.__version__, "mujoco": mujoco.__version__, "layouts": {}}
    full = _bench_closed_loop(TRANSIT_S if quick else 30.0)
    print(f"[closed loop, {full['sim_s']:.0f} s] " + ", ".join(
        f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in full.items()),
        flush=True)
    res["closed_loop"] = full
    res["closed_loop_rtf"] = full["rtf"]
    res["closed_loop_compile_s"] = full["compile_s"]
    if not quick:
        tr = _bench_closed_loop(TRANSIT_S)
        print(f"[closed loop, {tr['sim_s']:.0f} s transit] " + ", ".join(
            f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in tr.items()),
            flush=True)
        res["closed_loop_transit"] = tr
        res["closed_loop_rtf_transit"] = tr["rtf"]
    c = _bench_c(sim_seconds, reps, worlds)
    for lay in layouts:
        res["layouts"][lay] = _bench_layout(lay, sim_seconds, reps, worlds)
        print(f"[{lay}] " + ", ".join(f"{k}={v:.4g}" for k, v in res["layouts"][lay].items()),
              flush=True)
    res["world_cost"] = _bench_world_cost(sim_seconds, reps)
    print("[world cost] " + ", ".join(f"{k}={v:.4g}" for k, v in res["world_cost"].items()),
          flush=True)
    res.update(res["world_cost"])
    c2 = _bench_c(sim_seconds, reps, worlds)  # again after, to see the machine's drift
    for k in c:
        res[k] = float(np.median([c[k], c2[k]]))
    best = res["layouts"].get(fleet.DEFAULT_LAYOUT) or next(iter(res["layouts"].values()))
    res.update({k: v for k, v in best.items()})
    res["ratio_mjx_physics_only_vs_c_mj_step"] = (
        best["mjx_physics_only_steps_per_s"] / res["c_mj_step_steps_per_s"])
    key = f"worlds{worlds}_world_steps_per_s"
    rkey = f"c_rollout_{worlds}_world_steps_per_s"
    if key in best and rkey in res:
        res[f"ratio_worlds{worlds}_vs_c_rollout"] = best[key] / res[rkey]
    per_period = best["physics_control_ms_per_period"] / 1e3
    res["headroom_planning_ms_per_period_at_5x"] = 1e3 * (PERIOD_S / 5.0 - per_period)
    res["headroom_planning_ms_per_period_at_5x_in_scan"] = 1e3 * (
        PERIOD_S / 5.0 - PERIOD_S / best["physics_control_rtf_in_scan"])
    for k in sorted(res):
        if k not in ("layouts", "closed_loop", "closed_loop_transit", "world_cost"):
            v = res[k]
            print(f"{k:50s} {v:.4g}" if isinstance(v, float) else f"{k:50s} {v}")
    if json_path:
        with open(json_path, "w") as f:
            json.dump(res, f, indent=2)
    return res


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", default=None)
    ap.add_argument("--quick", action="store_true")
    a = ap.parse_args(argv)
    run(a.json, quick=a.quick)


if __name__ == "__main__":
    main()
