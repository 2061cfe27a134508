"""Tests of jaxplan.sim.se3: the Lee SE(3) controller, allocation, saturation, motor lag.

References:
* rotorpy's SE3Control (an independent implementation of the same Lee 2010 law) for
  the Hummingbird, with RotorS's gains converted as shared/ROBOTS.md says (rotorpy's
  position gains are per unit mass, its attitude gains per principal inertia).  The two
  laws agree exactly when the desired yaw rate is 0: rotorpy then uses e_w = w, as
  RotorS does.  With a yaw rate they differ by design (rotorpy: e_w = w - [0, 0, r],
  "oversimplified" in its own comment; RotorS: e_w = w - R^T R_d [0, 0, r]), so
  yaw-rate (and jerk) references are checked against an independent NumPy/SciPy
  transcription of the RotorS law below (`_rotors_law_numpy`) instead.
* finite differences of R_d(t) along a flat trajectory for the jerk feed-forward.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import jaxplan  # noqa: F401  (x64)
from jaxplan.sim import se3
from jaxplan.vehicles import GRAVITY, VEHICLES, get_vehicle

NAMES = ("hummingbird", "firefly", "neo11")

control = jax.jit(se3.se3_control)


def _random_case(rng, tilt_max=1.0):
    """A random state near a random reference; returns (state, ref) of NumPy arrays."""
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    rot = Rotation.from_rotvec(axis * rng.uniform(0, tilt_max)) * Rotation.from_euler(
        "z", rng.uniform(-np.pi, np.pi))
    q_xyzw = rot.as_quat()
    state = se3.VehicleState(
        position=rng.uniform(-0.5, 0.5, 3),
        velocity=rng.uniform(-1, 1, 3),
        quat=np.r_[q_xyzw[3], q_xyzw[:3]],
        ang_vel=rng.uniform(-2, 2, 3),
    )
    ref = se3.Reference(
        position=rng.uniform(-0.5, 0.5, 3),
        velocity=rng.uniform(-1, 1, 3),
        acceleration=rng.uniform(-3, 3, 3),
        jerk=np.zeros(3),
        yaw=np.asarray(rng.uniform(-np.pi, np.pi)),
        yaw_rate=np.asarray(0.0),
    )
    return state, ref


# ----------------------------------------------------------------------------- rotorpy


def _rotorpy_controller(v):
    from rotorpy.controllers.quadrotor_control import SE3Control

    J = np.asarray(v.inertia)
    g = {k: np.asarray(x) for k, x in v.gains.items()}
    rotor_pos = {
        f"r{i + 1}": v.arm_length * np.array([math.cos(th), math.sin(th), 0.0])
        for i, th in enumerate(np.deg2rad(v.rotor_angles_deg))
    }
    params = dict(
        mass=v.mass, Ixx=J[0], Iyy=J[1], Izz=J[2], Ixy=0.0, Ixz=0.0, Iyz=0.0,
        c_Dx=0.0, c_Dy=0.0, c_Dz=0.0, num_rotors=v.n_rotors, rotor_pos=rotor_pos,
        # rotorpy's yaw moment is k_m * dir * w^2; ours is -d kappa k_f w^2.
        rotor_directions=-np.asarray(v.rotor_directions, dtype=float),
        rotor_speed_min=0.0, rotor_speed_max=v.max_rotor_speed,
        k_eta=v.motor_constant, k_m=v.motor_constant * v.moment_constant,
        k_d=0.0, k_z=0.0, k_flap=0.0, tau_m=v.time_constant_up,
        kp_att=g["k_R"] / J, kd_att=g["k_w"] / J,   # per inertia (ROBOTS.md)
    )
    ctrl = SE3Control(params)
    ctrl.kp_pos = g["k_x"] / v.mass                  # per unit mass (ROBOTS.md)
    ctrl.kd_pos = g["k_v"] / v.mass
    ctrl.g = GRAVITY
    return ctrl


def test_matches_rotorpy_hummingbird():
    import rotorpy  # noqa: F401  (a dev dependency: fail, never skip, without it)
    v = get_vehicle("hummingbird")
    rp = _rotorpy_controller(v)
    params = se3.se3_params(v)
    rng = np.random.default_rng(0)
    n_unsat = 0
    for _ in range(200):
        state, ref = _random_case(rng)
        out = control(params, state, ref)
        q = state.quat
        rstate = dict(x=state.position, v=state.velocity, q=np.r_[q[1:], q[0]], w=state.ang_vel)
        flat = dict(x=ref.position, x_dot=ref.velocity, x_ddot=ref.acceleration,
                    x_dddot=np.zeros(3), x_ddddot=np.zeros(3), yaw=float(ref.yaw),
                    yaw_dot=0.0)
        r = rp.update(0.0, rstate, flat)
        np.testing.assert_allclose(out.thrust_cmd, r["cmd_thrust"], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(out.moments_cmd, r["cmd_moment"], rtol=1e-11, atol=1e-13)
        # Per-rotor thrusts: rotorpy does not clamp, so compare where we did not either.
        if not bool(out.saturated):
            n_unsat += 1
            np.testing.assert_allclose(v.motor_constant * np.asarray(out.rotor_speeds_sq[:4]),
                                       r["cmd_motor_thrusts"], rtol=1e-10, atol=1e-12)
            np.testing.assert_allclose(out.thrust, r["cmd_thrust"], rtol=1e-11)
            np.testing.assert_allclose(out.moments, r["cmd_moment"], rtol=1e-9, atol=1e-12)
    assert n_unsat > 50


# ----------------------------------------------------------------------------- NumPy RotorS law


def _rotors_law_numpy(v, p, vel, quat_wxyz, w, p_d, v_d, a_d, j_d, yaw, yaw_rate):
    """The RotorS law written out independently (scipy rotations, explicit components).

    Follows lee_position_controller.cpp: acceleration = (e_x k_x + e_v k_v)/m - g e3 - a_d,
    b3_des = -acceleration / |acceleration|, thrust = -m acceleration . R e3,
    angle_error = 0.5 vee(R_d^T R - R^T R_d), angular_rate_error = w - R_d^T... (see below),
    plus our documented additions: w x J w, and the jerk feed-forward of the desired
    roll/pitch rates.
    """
    m, J = v.mass, np.asarray(v.inertia)
    g = {k: np.asarray(x) for k, x in v.gains.items()}
    R = Rotation.from_quat([*quat_wxyz[1:], quat_wxyz[0]]).as_matrix()
    acc = (g["k_x"] * (p - p_d) + g["k_v"] * (vel - v_d)) / m - np.array([0, 0, GRAVITY]) - a_d
    thrust = -m * acc @ R[:, 2]
    b1_des = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    b3_des = -acc / np.linalg.norm(acc)
    b2_des = np.cross(b3_des, b1_des)
    b2_des /= np.linalg.norm(b2_des)
    R_des = np.column_stack([np.cross(b2_des, b3_des), b2_des, b3_des])
    S = 0.5 * (R_des.T @ R - R.T @ R_des)
    e_R = np.array([S[2, 1], S[0, 2], S[1, 0]])
    # jerk feed-forward: d b3_des / dt = (I - b3 b3^T) m j / |F|
    F = m * np.linalg.norm(acc)
    b3dot = (np.eye(3) - np.outer(b3_des, b3_des)) @ (m * j_d) / F
    w_des = np.array([-b3dot @ R_des[:, 1], b3dot @ R_des[:, 0], yaw_rate])
    e_w = w - R.T @ R_des @ w_des
    moments = -g["k_R"] * e_R - g["k_w"] * e_w + np.cross(w, J * w)
    return thrust, moments


@pytest.mark.parametrize("name", NAMES)
def test_matches_numpy_rotors_law_with_yaw_rate_and_jerk(name):
    v = get_vehicle(name)
    params = se3.se3_params(v)
    rng = np.random.default_rng(1)
    for _ in range(100):
        state, ref = _random_case(rng)
        ref = ref._replace(jerk=rng.uniform(-5, 5, 3), yaw_rate=np.asarray(rng.uniform(-2, 2)))
        out = control(params, state, ref)
        f, M = _rotors_law_numpy(v, *state, *ref[:4], float(ref.yaw), float(ref.yaw_rate))
        np.testing.assert_allclose(out.thrust_cmd, f, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(out.moments_cmd, M, rtol=1e-10, atol=1e-12)


def test_jerk_feedforward_is_desired_frame_rate():
    """Along a flat trajectory tracked exactly, W_d's roll/pitch rates equal R_d's."""
    v = get_vehicle("firefly")
    params = se3.se3_params(v)

    amp, om, ph = np.array([1.0, 0.5, 0.3]), np.array([1.3, 0.9, 2.1]), np.array([0, 1.5, 0])

    def flat(t):  # p = amp sin(om t + ph) and its derivatives: m, m/s, m/s^2, m/s^3
        s, c = np.sin(om * t + ph), np.cos(om * t + ph)
        return amp * s, amp * om * c, -amp * om**2 * s, -amp * om**3 * c

    def rd(t):
        p, vel, a, _ = flat(t)
        F = v.mass * (a + np.array([0, 0, GRAVITY]))
        b3 = F / np.linalg.norm(F)
        b2 = np.cross(b3, [np.cos(0.4), np.sin(0.4), 0.0])
        b2 /= np.linalg.norm(b2)
        return np.column_stack([np.cross(b2, b3), b2, b3])

    for t in (0.1, 0.7, 1.9):
        p, vel, a, j = flat(t)
        R = rd(t)
        q = Rotation.from_matrix(R).as_quat()
        h = 1e-5
        Omega = R.T @ (rd(t + h) - rd(t - h)) / (2 * h)
        w_true = np.array([Omega[2, 1], Omega[0, 2], Omega[1, 0]])
        # Flying exactly at the reference and rotating at the true rate: e_R = 0, and the
        # rate error vanishes in roll and pitch only if W_d is right.
        state = se3.VehicleState(p, vel, np.r_[q[3], q[:3]], w_true)
        ref = se3.make_reference(p, vel, a, j, yaw=0.4, yaw_rate=w_true[2])
        out = control(params, state, ref)
        gyro = np.cross(w_true, np.asarray(v.inertia) * w_true)
        np.testing.assert_allclose(out.moments_cmd, gyro, atol=1e-8)


# ----------------------------------------------------------------------------- allocation


@pytest.mark.parametrize("name", NAMES)
def test_padded_pseudo_inverse_reproduces_feasible_wrench(name):
    v = get_vehicle(name)
    params = se3.se3_params(v)
    A, Ap = np.asarray(params.allocation), np.asarray(params.allocation_pinv)
    mask = np.asarray(params.rotor_mask)
    assert mask.sum() == v.n_rotors and A.shape == (4, 6) and Ap.shape == (6, 4)
    np.testing.assert_allclose(A @ Ap, np.eye(4), atol=1e-12)
    assert np.all(A[:, ~mask] == 0) and np.all(Ap[~mask] == 0)
    rng = np.random.default_rng(2)
    for _ in range(20):
        w_sq = np.zeros(6)
        w_sq[mask] = rng.uniform(0.3, 0.7, v.n_rotors) * v.max_rotor_speed**2
        wrench = A @ w_sq
        w_out, f, M, sat = se3.allocate(params, jnp.asarray(wrench[3]), jnp.asarray(wrench[:3]))
        assert not bool(sat)
        np.testing.assert_allclose(f, wrench[3], rtol=1e-13)
        np.testing.assert_allclose(M, wrench[:3], rtol=1e-9, atol=1e-14 * wrench[3])
        assert np.all(np.asarray(w_out)[~mask] == 0)


@pytest.mark.parametrize("name", NAMES)
def test_saturation_clamps_and_flags(name):
    v = get_vehicle(name)
    params = se3.se3_params(v)
    w2max = v.max_rotor_speed**2
    mask = np.asarray(params.rotor_mask)
    # too much thrust: every rotor at its maximum
    w, f, M, sat = se3.allocate(params, jnp.asarray(2.0 * v.max_thrust), jnp.zeros(3))
    assert bool(sat)
    np.testing.assert_allclose(np.asarray(w)[mask], w2max, rtol=1e-15)
    np.testing.assert_allclose(f, v.max_thrust, rtol=1e-12)
    # negative thrust: motors off
    w, f, M, sat = se3.allocate(params, jnp.asarray(-1.0), jnp.zeros(3))
    assert bool(sat) and np.all(np.asarray(w) == 0) and float(f) == 0
    # hover plus a huge roll moment: some rotors clamp at 0 and/or w_max
    w, f, M, sat = se3.allocate(params, jnp.asarray(v.mass * GRAVITY), jnp.array([50.0, 0, 0]))
    w = np.asarray(w)
    assert bool(sat) and np.all(w >= 0) and np.all(w <= w2max) and np.all(w[~mask] == 0)
    assert np.isclose(w[mask].min(), 0) or np.isclose(w[mask].max(), w2max)
    # what is returned is what the clamped speeds produce
    np.testing.assert_allclose(np.r_[M, f], np.asarray(params.allocation) @ w,
                               rtol=1e-13, atol=1e-12)
    assert float(M[0]) < 50.0


@pytest.mark.parametrize("name", NAMES)
def test_hover_exact(name):
    v = get_vehicle(name)
    p = np.array([1.0, -2.0, 3.0])
    state = se3.VehicleState(p, np.zeros(3), se3.yaw_to_quat(0.3), np.zeros(3))
    out = control(se3.se3_params(v), state, se3.make_reference(p, yaw=0.3))
    hover_w2 = v.mass * GRAVITY / (v.n_rotors * v.motor_constant)
    np.testing.assert_allclose(np.asarray(out.rotor_speeds_sq)[: v.n_rotors], hover_w2, rtol=1e-12)
    np.testing.assert_allclose(out.thrust, v.mass * GRAVITY, rtol=1e-14)
    np.testing.assert_allclose(out.moments, 0.0, atol=1e-12)  # rounding of A @ pinv(A)
    assert not bool(out.saturated) and int(out.status) == se3.STATUS_OK


def test_heterogeneous_vmap_matches_single():
    names = ["neo11", "hummingbird", "firefly", "hummingbird"]
    fp = se3.controller_params(names)
    rng = np.random.default_rng(3)
    cases = [_random_case(rng) for _ in names]
    states = jax.tree.map(lambda *x: jnp.stack([jnp.asarray(y) for y in x]), *[c[0] for c in cases])
    refs = jax.tree.map(lambda *x: jnp.stack([jnp.asarray(y) for y in x]), *[c[1] for c in cases])
    batch = jax.jit(se3.fleet_control)(fp, states, refs)
    for i, n in enumerate(names):
        one = control(se3.se3_params(n), *cases[i])
        lane = [x[i] for x in jax.tree.leaves(batch)]
        for a, b in zip(jax.tree.leaves(one), lane, strict=True):
            np.testing.assert_allclose(a, b, rtol=1e-13, atol=1e-15)


# ----------------------------------------------------------------------------- non-finite inputs


def _loss(params, state, ref):
    out = se3.se3_control(params, state, ref)
    return out.thrust + jnp.sum(out.moments) + jnp.sum(out.rotor_speeds_sq) * 1e-6


_grad = jax.jit(jax.grad(_loss, argnums=(1, 2)))


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_bad_reference_holds_position(bad):
    params = se3.se3_params("firefly")
    rng = np.random.default_rng(4)
    state, ref = _random_case(rng)
    ref_bad = ref._replace(acceleration=np.array([0.0, bad, 0.0]))
    out = control(params, state, ref_bad)
    assert int(out.status) == se3.STATUS_BAD_REFERENCE
    assert all(np.all(np.isfinite(x)) for x in jax.tree.leaves(out))
    R = Rotation.from_quat([*state.quat[1:], state.quat[0]]).as_matrix()
    hold = se3.make_reference(state.position, yaw=np.arctan2(R[1, 0], R[0, 0]))
    expect = control(params, state, hold)
    np.testing.assert_allclose(out.rotor_speeds_sq, expect.rotor_speeds_sq, rtol=1e-13)
    grads = _grad(params, state, ref_bad)
    assert all(np.all(np.isfinite(x)) for x in jax.tree.leaves(grads))


@pytest.mark.parametrize("field", ["position", "velocity", "quat", "ang_vel"])
def test_bad_state_motors_off(field):
    params = se3.se3_params("neo11")
    state, ref = _random_case(np.random.default_rng(5))
    x = np.array(getattr(state, field), dtype=float)
    x[1] = np.nan
    state = state._replace(**{field: x})
    out = control(params, state, ref)
    assert int(out.status) == se3.STATUS_BAD_STATE
    for leaf in jax.tree.leaves(out._replace(status=0)):
        assert np.all(np.asarray(leaf) == 0)
    grads = _grad(params, state, ref)
    assert all(np.all(np.isfinite(x)) for x in jax.tree.leaves(grads))


def test_degenerate_geometry_is_finite():
    """Free fall (F = 0), heading along b3d, zero quaternion: finite, no NaN gradient."""
    params = se3.se3_params("hummingbird")
    p = np.zeros(3)
    cases = [
        (se3.VehicleState(p, np.zeros(3), np.array([1.0, 0, 0, 0]), np.zeros(3)),
         se3.make_reference(p, acceleration=[0, 0, -GRAVITY])),
        (se3.VehicleState(p, np.zeros(3), np.array([1.0, 0, 0, 0]), np.zeros(3)),
         se3.make_reference(p, acceleration=[30.0, 0, -GRAVITY], yaw=0.0)),
        (se3.VehicleState(p, np.zeros(3), np.zeros(4), np.zeros(3)), se3.make_reference(p)),
    ]
    for state, ref in cases:
        out = control(params, state, ref)
        assert all(np.all(np.isfinite(x)) for x in jax.tree.leaves(out))
        grads = _grad(params, state, ref)
        assert all(np.all(np.isfinite(x)) for x in jax.tree.leaves(grads))


# ----------------------------------------------------------------------------- motor lag


@pytest.mark.parametrize("name", NAMES)
def test_motor_lag(name):
    v = get_vehicle(name)
    params = se3.se3_params(v)
    mask = np.asarray(params.rotor_mask)
    w0 = jnp.where(params.rotor_mask, 300.0, 0.0)
    cmd_up = jnp.full(6, 600.0**2)
    # exact first-order response, and two half steps equal one step
    w1 = se3.motor_lag(params, w0, cmd_up, 0.01)
    expect_up = 600 - 300 * np.exp(-0.01 / v.time_constant_up)
    np.testing.assert_allclose(np.asarray(w1)[mask], expect_up, rtol=1e-14)
    w_half = se3.motor_lag(params, se3.motor_lag(params, w0, cmd_up, 0.005), cmd_up, 0.005)
    np.testing.assert_allclose(w_half, w1, rtol=1e-13)
    assert np.all(np.asarray(w1)[~mask] == 0)
    w_dn = se3.motor_lag(params, w0, jnp.full(6, 100.0**2), 0.01)
    expect_dn = 100 + 200 * np.exp(-0.01 / v.time_constant_down)
    np.testing.assert_allclose(np.asarray(w_dn)[mask], expect_dn, rtol=1e-14)
    # the wrench of the lagged speeds
    f, M = se3.wrench_from_rotor_speeds(params, w1)
    np.testing.assert_allclose(f, v.motor_constant * float(w1[0]) ** 2 * v.n_rotors, rtol=1e-13)
    np.testing.assert_allclose(M, 0.0, atol=1e-12)


def test_params_shapes_and_units():
    fp = se3.controller_params(list(VEHICLES))
    assert fp.allocation.shape == (3, 4, 6) and fp.allocation_pinv.shape == (3, 6, 4)
    assert fp.k_x.shape == (3, 3) and fp.mass.shape == (3,)
    assert fp.mass.dtype == jnp.float64
    np.testing.assert_allclose(fp.w_max_sq, [v.max_rotor_speed**2 for v in VEHICLES.values()])
