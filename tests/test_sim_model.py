"""Tests of jaxplan.sim.model: the MJCF fleet, MuJoCo conventions, MJX vs the C engine,
and the closed loop with the SE(3) controller (hover and recovery).

Measured on the 2-core CPU (mujoco 4.0.0, mujoco-mjx 3.17.0, jax 0.10.2, float64), three
vehicles (hummingbird, firefly, neo11), 500 Hz, 2 s of sinusoidal thrust and moments:
    max |qpos_MJX - qpos_C|:  Euler 7e-15,  RK4 6e-8
    Euler's own error vs. RK4 at 10 kHz: 2.2 mm (1.1 mm at 1 kHz); RK4 at 500 Hz: 2e-12.
    closed loop (controller in the scan, 250 Hz), 1 s from 10 cm offsets: 1e-15 (Euler).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx

import jaxplan  # noqa: F401  (x64)
from jaxplan.sim import model as sm
from jaxplan.sim import se3
from jaxplan.vehicles import GRAVITY, get_vehicle
from jaxplan.world import World, face_names, signed_distance, static_rows

NAMES = ["hummingbird", "firefly", "neo11"]
POS = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 1.5], [2.0, 0.5, 2.0]])


def test_fleet_model_structure():
    names = NAMES + ["hummingbird"]
    pos = np.vstack([POS, [[0.0, 0.0, 1.0]]])   # two vehicles in the same place
    m = sm.fleet_model(names, pos, yaws=[0.0, 0.5, -1.0, 2.0], timestep=0.004, integrator="RK4")
    assert (m.nq, m.nv, m.nu) == (28, 24, 16)
    assert m.opt.timestep == 0.004 and m.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4
    assert np.all(m.geom_contype == 0) and np.all(m.geom_conaffinity == 0)
    for i, n in enumerate(names):
        v = get_vehicle(n)
        bid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f"r{i}_body")
        assert m.body_mass[bid] == v.mass
        np.testing.assert_array_equal(m.body_inertia[bid], v.inertia)  # table, not balanced
        np.testing.assert_array_equal(m.body_ipos[bid], 0.0)
        np.testing.assert_array_equal(m.body_iquat[bid], [1, 0, 0, 0])
        for k, nm in enumerate(["thrust", "mx", "my", "mz"]):
            aid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, f"r{i}_{nm}")
            assert aid == 4 * i + k and m.actuator_ctrllimited[aid] == 0
    d = mujoco.MjData(m)
    d.qpos[2] = -0.5  # below the ground, overlapping vehicle 3: still no contact
    for _ in range(10):
        mujoco.mj_step(m, d)
        assert d.ncon == 0
    np.testing.assert_allclose(sm.fleet_state(d.qpos, d.qvel).quat[2],
                               se3.yaw_to_quat(-1.0), atol=1e-12)


WORLD_OBSTACLES = [
    dict(kind="sphere", center=[1.0, 2.0, 3.0], radius=0.5),
    dict(kind="box", center=[0.0, 0.0, 1.0], half_extents=[0.1, 0.2, 0.3]),
    dict(kind="cylinder", center=[2.0, 0.0, 1.5], radius=0.3, half_height=1.5),
]


def test_world_geoms_match_signed_distance():
    """Every obstacle kind and workspace face is a geom with the right type, size and
    pose: MuJoCo's own geom distance (mj_geomDistance, the C engine's collision code)
    from the vehicle's collision sphere to each of them equals the world's signed distance
    minus the radius, outside and inside."""
    base = World.default(3).with_obstacles(WORLD_OBSTACLES)
    w = World(np.array([-5.0, -np.inf, 0.0]), np.array([np.inf, 6.0, 2.5]), base.kind,
              base.center, base.half, base.radius)
    m = sm.fleet_model(["firefly"], [[0.0, 0.0, 1.0]], world=w, hull_radii=[0.3],
                       visual=False)
    names = ["obstacle0", "obstacle1", "obstacle2", "ws_x_min", "ws_z_min", "ws_y_max",
             "ws_z_max"]
    assert face_names(w) == ["x_min", "z_min", "y_max", "z_max"]
    gid = lambda n: mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, n)
    G = mujoco.mjtGeom
    types = [G.mjGEOM_SPHERE, G.mjGEOM_BOX, G.mjGEOM_CYLINDER] + [G.mjGEOM_PLANE] * 4
    assert [int(m.geom_type[gid(n)]) for n in names] == [int(t) for t in types]
    np.testing.assert_array_equal(m.geom_size[gid("obstacle2")], [0.3, 1.5, 0.0])
    np.testing.assert_array_equal(m.geom_pos[gid("obstacle1")], [0.0, 0.0, 1.0])
    assert np.all(m.geom_contype == 0) and np.all(m.geom_conaffinity == 0)
    rows = static_rows(w)
    d = mujoco.MjData(m)
    hull = gid("r0_hull")
    rng = np.random.default_rng(0)
    inside = 0
    for p in rng.uniform([-1.0, -1.0, -0.5], [3.0, 3.0, 3.0], size=(40, 3)):
        d.qpos[:3] = p
        mujoco.mj_forward(m, d)
        ref = [mujoco.mj_geomDistance(m, d, hull, gid(n), 10.0, None) for n in names]
        ours = signed_distance(rows.kind, rows.center, rows.half, rows.radius, p) - 0.3
        np.testing.assert_allclose(ours, ref, atol=1e-5)   # measured: 2e-6
        inside += int(np.sum(np.asarray(ref) < 0))
    assert inside >= 10   # penetrations too, not only gaps
    # no world: the picture ground at z = 0; the default world: the floor only
    m0 = sm.fleet_model(["firefly"], [[0.0, 0.0, 1.0]])
    assert mujoco.mj_name2id(m0, mujoco.mjtObj.mjOBJ_GEOM, "ground") >= 0
    m1 = sm.fleet_model(["firefly"], [[0.0, 0.0, 1.0]], world=World.default(3), visual=False)
    assert [m1.geom(g).name for g in range(m1.ngeom)] == ["ws_z_min"]
    with pytest.raises(ValueError, match="3-D"):
        sm.fleet_xml(["firefly"], [[0.0, 0.0, 1.0]], world=World.default(2))
    with pytest.raises(ValueError, match="hull_radii"):
        sm.fleet_xml(["firefly"], [[0.0, 0.0, 1.0]], hull_radii=[0.3, 0.4])


def test_moving_obstacle_geoms_sit_in_mocap_bodies():
    """A moving obstacle's geom sits in its mocap body (a static one stays a geom of the
    world body): with mocap_pos set from the motion at time t, MuJoCo's geom distance
    is the world's signed distance to the obstacle where it is then.  The stepped
    models' bare bodies (mocap_world) carry no geoms."""
    w = World.default(3).with_obstacles([
        WORLD_OBSTACLES[0],
        dict(kind="cylinder", radius=0.3, half_height=0.9,
             path=[dict(t=0.0, p=[0.0, -2.0, 0.9]), dict(t=4.0, p=[0.0, 2.0, 0.9])]),
        dict(kind="sphere", center=[2.0, 0.0, 1.0], radius=0.4, velocity=[0.0, 0.5, 0.0])])
    m = sm.fleet_model(["firefly"], [[1.0, 0.0, 1.0]], world=w, hull_radii=[0.3],
                       visual=False)
    assert m.nmocap == 2
    body = lambda n: mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, n)
    gid = lambda n: mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, n)
    assert [int(m.body_mocapid[body(f"obstacle{k}_body")]) for k in (1, 2)] == [0, 1]
    assert [int(m.geom_bodyid[gid(f"obstacle{k}")]) for k in range(3)] == [
        0, body("obstacle1_body"), body("obstacle2_body")]
    np.testing.assert_array_equal(m.body_pos[body("obstacle1_body")], [0.0, -2.0, 0.9])
    d = mujoco.MjData(m)
    hull = gid("r0_hull")
    for t in (0.0, 1.5, 6.0):
        c = w.center_at(t)[0]
        d.mocap_pos[:] = c[1:]
        mujoco.mj_forward(m, d)
        ours = signed_distance(w.kind, c, w.half, w.radius, np.array([1.0, 0.0, 1.0]))
        ref = [mujoco.mj_geomDistance(m, d, hull, gid(f"obstacle{k}"), 10.0, None)
               for k in range(3)]
        np.testing.assert_allclose(ours - 0.3, ref, atol=1e-5)
    bare = sm.fleet_model(["firefly"], [[1.0, 0.0, 1.0]], visual=False, mocap_world=w)
    assert bare.nmocap == 2 and bare.ngeom == 0
    with pytest.raises(ValueError, match="not both"):
        sm.fleet_xml(["firefly"], [[0.0, 0.0, 1.0]], world=w, mocap_world=w)


def test_xml_errors():
    with pytest.raises(ValueError, match="unknown vehicle"):
        sm.fleet_xml(["blimp"], [[0, 0, 1]])
    with pytest.raises(ValueError, match="positions"):
        sm.fleet_xml(["firefly", "neo11"], [[0, 0, 1]])
    with pytest.raises(ValueError, match="integrator"):
        sm.fleet_xml(["firefly"], [[0, 0, 1]], integrator="implicit")
    with pytest.raises(ValueError, match="timestep"):
        sm.fleet_xml(["firefly"], [[0, 0, 1]], timestep=0.0)
    # the single-vehicle XML compiles on its own (with the compilable inertia)
    m = mujoco.MjModel.from_xml_string(sm.vehicle_xml("neo11"))
    assert m.nu == 4 and m.body_inertia[1, 2] <= m.body_inertia[1, 0] + m.body_inertia[1, 1]


def test_free_joint_and_actuator_frames():
    """qvel[3:6] is the BODY angular velocity, qvel[0:3] the world linear velocity;
    thrust acts along body z and the moment actuators about body axes."""
    v = get_vehicle("firefly")
    m = sm.fleet_model(["firefly"], [[0, 0, 1]])
    d = mujoco.MjData(m)
    q = np.array([0.9, 0.2, 0.3, 0.1])
    d.qpos[3:7] = q / np.linalg.norm(q)
    d.qvel[:] = [0.1, 0.2, 0.3, 1.0, 0.5, -0.3]
    mujoco.mj_forward(m, d)
    R = d.xmat[1].reshape(3, 3)
    vel = np.zeros(6)
    mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_BODY, 1, vel, 0)  # world: (rot, lin)
    np.testing.assert_allclose(R.T @ vel[:3], d.qvel[3:6], atol=1e-14)
    np.testing.assert_allclose(vel[3:], d.qvel[0:3], atol=1e-14)
    # accelerations from rest
    d.qvel[:] = 0
    d.ctrl[:] = [10.0, 0.01, -0.02, 0.03]
    mujoco.mj_forward(m, d)
    np.testing.assert_allclose(d.qacc[:3], R[:, 2] * 10.0 / v.mass - [0, 0, GRAVITY], atol=1e-12)
    np.testing.assert_allclose(d.qacc[3:], np.array([0.01, -0.02, 0.03]) / np.array(v.inertia),
                               rtol=1e-12)


def _controls(t):
    """(3 * 4,) sinusoidal thrust and moments for NAMES at time t (s)."""
    out = []
    for i, n in enumerate(NAMES):
        v = get_vehicle(n)
        f = v.mass * GRAVITY * (1 + 0.2 * np.sin(2 * np.pi * 0.7 * t + i))
        M = 0.9 * v.inertia[0] * np.sin(2 * np.pi * (1.3 + 0.1 * i) * t + np.arange(3))
        out.append(np.r_[f, M])
    return np.concatenate(out)


@pytest.mark.parametrize("integrator,tol", [
    ("Euler", 1e-12),
    pytest.param("RK4", 1e-6, marks=pytest.mark.slow),   # 11 s, mostly compilation
])
def test_mjx_matches_c_engine(integrator, tol):
    dt, n = 0.002, 1000   # 2 s at 500 Hz
    m = sm.fleet_model(NAMES, POS, timestep=dt, integrator=integrator)
    ctrls = np.stack([_controls(k * dt) for k in range(n)])
    d = mujoco.MjData(m)
    q_c = np.empty((n, m.nq))
    for k in range(n):
        d.ctrl[:] = ctrls[k]
        mujoco.mj_step(m, d)
        q_c[k] = d.qpos
    mx, dx = sm.to_mjx(m)
    assert mx.body_mass.dtype == jnp.float64 and dx.qpos.dtype == jnp.float64

    def body(dx, c):
        dx = mjx.step(mx, dx.replace(ctrl=c))
        return dx, dx.qpos

    q_x = np.asarray(jax.jit(lambda dx, cs: jax.lax.scan(body, dx, cs)[1])(dx, jnp.asarray(ctrls)))
    assert np.abs(q_c - q_c[0]).max() > 0.5       # the vehicles really moved and turned
    err = np.abs(q_x - q_c).max()
    assert err < tol, err


# ----------------------------------------------------------------------------- closed loop


def _closed_loop(names, start, setpoint, yaw, seconds=10.0, physics_hz=500, control_hz=250,
                 qpos_out=False):
    """C-engine closed loop under the jitted, vmapped SE(3) controller.

    Returns (t (K,), position error norms (K, M) in m, saturated-ever (M,) bool), and
    qpos after every control period (K, 7 M) if ``qpos_out``.
    """
    m = sm.fleet_model(names, start, yaws=yaw, timestep=1.0 / physics_hz)
    d = mujoco.MjData(m)
    params = se3.controller_params(names)
    ref = se3.make_reference(jnp.asarray(setpoint), yaw=jnp.asarray(yaw))
    ctrl_fn = jax.jit(lambda qp, qv: se3.fleet_control(params, sm.fleet_state(qp, qv), ref))
    sub = physics_hz // control_hz
    n = int(round(seconds * control_hz))
    errs = np.empty((n, len(names)))
    qs = np.empty((n, m.nq))
    sat = np.zeros(len(names), bool)
    for k in range(n):
        out = ctrl_fn(d.qpos, d.qvel)
        sat |= np.asarray(out.saturated)
        assert np.all(np.asarray(out.status) == se3.STATUS_OK)
        d.ctrl[:] = np.asarray(sm.fleet_ctrl(out.thrust, out.moments))
        for _ in range(sub):
            mujoco.mj_step(m, d)
        errs[k] = np.linalg.norm(d.qpos.reshape(-1, 7)[:, :3] - setpoint, axis=1)
        qs[k] = d.qpos
    t = np.arange(1, n + 1) / control_hz
    return (t, errs, sat, qs) if qpos_out else (t, errs, sat)


def test_hover_and_recovery_closed_loop():
    """Each vehicle hovers within 1 mm for 10 s from its set point, and recovers from a
    10 cm offset (back within 1 mm, and staying there, after 10 s)."""
    names = NAMES + NAMES
    setpoint = np.vstack([POS, POS + [0.0, 3.0, 0.0]])
    offset = np.array([0.06, -0.05, 0.06])
    offset *= 0.1 / np.linalg.norm(offset)
    start = setpoint.copy()
    start[3:] += offset
    yaw = np.array([0.0, 0.7, -2.0, 0.3, -1.2, 3.0])
    t, errs, sat = _closed_loop(names, start, setpoint, yaw)
    assert errs[:, :3].max() < 1e-3, errs[:, :3].max()           # at the set point: hover
    assert not sat.any()
    settle = t >= 6.0   # measured: within 1 mm after 2.7 s (hb), 3.0 s (firefly), 4.8 s (neo11)
    assert errs[settle, 3:].max() < 1e-3, errs[settle, 3:].max(axis=0)   # recovered
    assert errs[-1, 3:].max() < 1e-4


def test_mjx_closed_loop_matches_c_engine():
    """The controller inside a jitted lax.scan of mjx.step (500 Hz physics, 250 Hz
    control) flies the same trajectories as the C-engine loop."""
    setpoint = POS
    start = POS + np.array([[0.1, 0.0, 0.0], [0.0, -0.1, 0.05], [0.05, 0.05, -0.1]])
    yaw = np.array([0.2, -0.4, 1.0])
    _, _, _, q_c = _closed_loop(NAMES, start, setpoint, yaw, seconds=1.0, qpos_out=True)

    m = sm.fleet_model(NAMES, start, yaws=yaw, timestep=0.002)
    mx, dx = sm.to_mjx(m)
    params = se3.controller_params(NAMES)
    ref = se3.make_reference(jnp.asarray(setpoint), yaw=jnp.asarray(yaw))

    def control_period(dx, _):
        out = se3.fleet_control(params, sm.fleet_state(dx.qpos, dx.qvel), ref)
        dx = dx.replace(ctrl=sm.fleet_ctrl(out.thrust, out.moments))
        dx = mjx.step(mx, mjx.step(mx, dx))
        return dx, dx.qpos

    q_x = np.asarray(jax.jit(lambda dx: jax.lax.scan(control_period, dx, length=250)[1])(dx))
    assert np.abs(q_c[-1] - q_c[0]).max() > 0.05
    assert np.abs(q_x - q_c).max() < 1e-9, np.abs(q_x - q_c).max()


def test_importing_the_fleet_sim_prints_no_warp_notes():
    """mujoco.mjx prints two "Failed to import warp" lines on import when the optional
    Warp backend is missing; jaxplan's import of it (jaxplan.sim.import_mjx) drops them
    and keeps anything else (that those lines are what a plain import prints:
    test_a_plain_mjx_import_prints_only_the_warp_notes, slow)."""
    import subprocess
    import sys

    code = ("import jaxplan.sim.fleet, jaxplan.sim as s, mujoco.mjx as m;"
            "assert jaxplan.sim.fleet.mjx is m and s.import_mjx() is m")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "Failed to import" not in r.stdout + r.stderr


@pytest.mark.slow  # a second child process (~4 s): `make test-slow`
def test_a_plain_mjx_import_prints_only_the_warp_notes():
    """Where mujoco itself prints warp notes, they are the lines jaxplan drops (else
    test_importing_the_fleet_sim_prints_no_warp_notes is moot)."""
    import subprocess
    import sys

    plain = subprocess.run([sys.executable, "-c", "import mujoco.mjx"], capture_output=True,
                           text=True, timeout=300)
    assert plain.returncode == 0, plain.stderr[-2000:]
    if "Failed to import" in plain.stdout:
        assert all(ln.startswith(("Failed to import warp:", "Failed to import mujoco_warp:"))
                   for ln in plain.stdout.splitlines())
