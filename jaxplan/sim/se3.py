"""Geometric SE(3) tracking controller and rotor allocation, pure JAX.

The control law is the one in RotorS ``lee_position_controller`` (Lee, Leok and
McClamroch 2010, "Geometric tracking control of a quadrotor UAV on SE(3)"), written
in force/torque units with the RotorS gains of :mod:`jaxplan.vehicles` (docs/ROBOTS.md).
z is up, gravity is ``-g e3``.  For one vehicle with state (p, v, R, w) and reference
(p_d, v_d, a_d, j_d, yaw_d, yawrate_d)::

    F    = -k_x * (p - p_d) - k_v * (v - v_d) + m g e3 + m a_d          (world, N)
    b3d  = F / |F|,  b2d = normalize(b3d x [cos yaw_d, sin yaw_d, 0]),  b1d = b2d x b3d
    R_d  = [b1d b2d b3d]
    f    = F . (R e3)                                                   (thrust, N)
    e_R  = 0.5 vee(R_d^T R - R^T R_d)
    W_d  = [-h . b2d, h . b1d, yawrate_d],  h = m / |F| (j_d - (b3d . j_d) b3d)
    e_w  = w - R^T R_d W_d
    M    = -k_R * e_R - k_w * e_w + w x (J w)                           (body, N m)

Differences from RotorS, all deliberate:

* ``w x J w`` (the gyroscopic term of the full Lee 2010 law) is included.  RotorS
  writes ``w x w`` (= 0) there; rotorpy includes ``w x J w``.
* The jerk feed-forward ``h`` adds the roll/pitch rates of the desired frame
  (Mellinger and Kumar 2011, from the derivative of b3d under the feed-forward force
  only).  With ``jerk = 0`` the law is exactly RotorS's ``W_d = [0, 0, yawrate_d]``.
  The angular-acceleration feed-forward of Lee 2010 is not included.
* The rotor speeds squared are clamped to ``[0, w_max^2]`` here (RotorS clamps below
  at 0 in the controller and above in the Gazebo motor plugin), and the thrust and
  moments returned are recomputed from the clamped speeds: that is the wrench the
  vehicle actually gets.

Allocation (docs/ROBOTS.md): rotor ``i`` at azimuth ``th_i`` with spin direction ``d_i``
contributes column ``[l k_f sin th_i, -l k_f cos th_i, -d_i k_f kappa, k_f]`` to the
(4, R) matrix mapping ``w_i^2`` to (roll, pitch, yaw moment, thrust).  Every vehicle
is padded to :data:`MAX_ROTORS` = 6 rotors (zero columns, ``rotor_mask`` False), so
the 4-rotor Hummingbird and the 6-rotor Firefly/Neo stack into one batch and one
``jax.vmap`` runs a heterogeneous fleet.  The pseudo-inverse of a padded matrix is
the pseudo-inverse of the real one padded with zero rows.

Non-finite inputs (docs/DESIGN.md: "caught at the step that makes them").  The controller
never returns NaN or inf, and its gradient stays finite too (inputs are replaced
before any arithmetic, the double-``where`` trick):

* finite state, non-finite reference -> ``status = STATUS_BAD_REFERENCE``: the
  reference is replaced by "hold here": p_d = current position, v_d = a_d = j_d = 0,
  yaw_d = current yaw, yawrate_d = 0.  The vehicle brakes, levels and hovers, which
  is the safest thing to do when the planner hands over garbage.
* non-finite state -> ``status = STATUS_BAD_STATE``: all rotor speeds are 0 (motors
  off), thrust and moments are 0, ``saturated`` is False.  Without a finite attitude
  there is no direction in which a hover thrust would be safe to apply; zero is the
  only output that pushes nowhere, and the status tells the caller to stop the lane.

Everything works on one vehicle; batch with ``jax.vmap`` over params, state and
reference together (see :func:`controller_params`).  Units are SI throughout.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.vehicles import GRAVITY, Vehicle, get_vehicle

MAX_ROTORS = 6
"""Rotor count every vehicle's allocation is padded to."""

STATUS_OK = 0
STATUS_BAD_REFERENCE = 1
STATUS_BAD_STATE = 2

_EPS = 1e-9  # norms below this are treated as zero (N or dimensionless)

Array = jax.Array


class SE3Params(NamedTuple):
    """Controller and allocation parameters of one vehicle (leading batch axes allowed).

    Attributes (SI units, shapes for one vehicle):
        mass: () kg.
        inertia: (3,) principal moments Ixx, Iyy, Izz, kg m^2.
        k_x: (3,) position gain, N/m.
        k_v: (3,) velocity gain, N s/m.
        k_R: (3,) attitude gain, N m.
        k_w: (3,) angular-rate gain, N m s.
        allocation: (4, MAX_ROTORS) maps w^2 (rad^2/s^2) to (roll, pitch, yaw moment N m,
            thrust N); zero columns for absent rotors.
        allocation_pinv: (MAX_ROTORS, 4) its Moore-Penrose pseudo-inverse (zero rows for
            absent rotors).
        rotor_mask: (MAX_ROTORS,) bool, True for rotors that exist.
        w_max_sq: () maximum rotor speed squared, rad^2/s^2.
        tau_up, tau_down: () first-order motor time constants (speeding up / slowing down), s.
        gravity: () m/s^2.
    """

    mass: Array
    inertia: Array
    k_x: Array
    k_v: Array
    k_R: Array
    k_w: Array
    allocation: Array
    allocation_pinv: Array
    rotor_mask: Array
    w_max_sq: Array
    tau_up: Array
    tau_down: Array
    gravity: Array


class VehicleState(NamedTuple):
    """Rigid-body state of one vehicle (leading batch axes allowed).

    Attributes:
        position: (3,) world frame, m.
        velocity: (3,) world frame, m/s.
        quat: (4,) body-to-world orientation, unit quaternion (w, x, y, z) as MuJoCo stores
            it in a free joint's qpos[3:7].  Normalized inside the controller.
        ang_vel: (3,) angular velocity in the BODY frame, rad/s (MuJoCo's free-joint
            qvel[3:6] is in the body frame; qvel[0:3] is the world-frame linear velocity).
    """

    position: Array
    velocity: Array
    quat: Array
    ang_vel: Array


class Reference(NamedTuple):
    """Desired flat outputs for one vehicle (leading batch axes allowed).

    Attributes:
        position: (3,) m.  velocity: (3,) m/s.  acceleration: (3,) m/s^2.
        jerk: (3,) m/s^3 (feed-forward of the roll/pitch rates; zeros give RotorS's law).
        yaw: () rad.  yaw_rate: () rad/s.
    """

    position: Array
    velocity: Array
    acceleration: Array
    jerk: Array
    yaw: Array
    yaw_rate: Array


class SE3Output(NamedTuple):
    """What the controller commands (leading batch axes follow the inputs).

    Attributes:
        rotor_speeds_sq: (MAX_ROTORS,) w_i^2 after clamping to [0, w_max^2], rad^2/s^2;
            0 for absent rotors.
        thrust: () total thrust from the clamped rotor speeds, N (along body z).
        moments: (3,) body moments from the clamped rotor speeds, N m.
        saturated: () bool, True when some rotor's unclamped w^2 left [0, w_max^2].
        thrust_cmd: () thrust the control law asked for before allocation, N.
        moments_cmd: (3,) moments the control law asked for before allocation, N m.
        status: () int32, STATUS_OK | STATUS_BAD_REFERENCE | STATUS_BAD_STATE.
    """

    rotor_speeds_sq: Array
    thrust: Array
    moments: Array
    saturated: Array
    thrust_cmd: Array
    moments_cmd: Array
    status: Array


# ----------------------------------------------------------------------------- params


def padded_allocation(vehicle: Vehicle, max_rotors: int = MAX_ROTORS):
    """Allocation matrix, pseudo-inverse and rotor mask padded to ``max_rotors`` (NumPy).

    Args:
        vehicle: a :class:`jaxplan.vehicles.Vehicle`.
        max_rotors: padded rotor count (>= vehicle.n_rotors).
    Returns:
        (A (4, max_rotors), A_pinv (max_rotors, 4), mask (max_rotors,) bool), float64;
        A maps w^2 (rad^2/s^2) to (roll, pitch, yaw moment N m, thrust N).
    """
    a = vehicle.allocation_matrix()
    r = a.shape[1]
    if r > max_rotors:
        raise ValueError(f"{vehicle.name} has {r} rotors, more than max_rotors={max_rotors}")
    a_pad = np.zeros((4, max_rotors))
    a_pad[:, :r] = a
    pinv_pad = np.zeros((max_rotors, 4))
    pinv_pad[:r] = np.linalg.pinv(a)
    mask = np.zeros(max_rotors, dtype=bool)
    mask[:r] = True
    return a_pad, pinv_pad, mask


def se3_params(vehicle: Vehicle | str) -> SE3Params:
    """Controller parameters of one vehicle (a Vehicle or its name), as float64 JAX arrays.

    Returns:
        SE3Params with the shapes documented there (no batch axis).
    """
    if isinstance(vehicle, str):
        vehicle = get_vehicle(vehicle)
    a, a_pinv, mask = padded_allocation(vehicle)
    g = vehicle.gains
    f64 = lambda x: jnp.asarray(np.asarray(x, dtype=np.float64))
    return SE3Params(
        mass=f64(vehicle.mass),
        inertia=f64(vehicle.inertia),
        k_x=f64(g["k_x"]),
        k_v=f64(g["k_v"]),
        k_R=f64(g["k_R"]),
        k_w=f64(g["k_w"]),
        allocation=f64(a),
        allocation_pinv=f64(a_pinv),
        rotor_mask=jnp.asarray(mask),
        w_max_sq=f64(vehicle.max_rotor_speed**2),
        tau_up=f64(vehicle.time_constant_up),
        tau_down=f64(vehicle.time_constant_down),
        gravity=f64(GRAVITY),
    )


def controller_params(vehicles: Sequence[Vehicle | str]) -> SE3Params:
    """Stack the parameters of M (possibly different) vehicles along a leading axis.

    Returns:
        SE3Params whose leaves have a leading axis of size M; ``jax.vmap(se3_control)``
        over it, a (M, ...) VehicleState and a (M, ...) Reference runs the whole fleet.
    """
    ps = [se3_params(v) for v in vehicles]
    return jax.tree.map(lambda *xs: jnp.stack(xs), *ps)


def make_reference(position, velocity=None, acceleration=None, jerk=None, yaw=0.0,
                   yaw_rate=0.0) -> Reference:
    """A :class:`Reference` with zeros for what is not given.

    Args:
        position: (..., 3) m.  velocity, acceleration, jerk: (..., 3) or None (zeros).
        yaw, yaw_rate: scalars or (...,) rad, rad/s.
    Returns:
        Reference with float64 leaves broadcast to the batch shape of ``position``.
    """
    p = jnp.asarray(position, dtype=jnp.float64)
    z = jnp.zeros_like(p)
    vec = lambda x: z if x is None else jnp.broadcast_to(jnp.asarray(x, jnp.float64), p.shape)
    sca = lambda x: jnp.broadcast_to(jnp.asarray(x, jnp.float64), p.shape[:-1])
    return Reference(p, vec(velocity), vec(acceleration), vec(jerk), sca(yaw), sca(yaw_rate))


# ----------------------------------------------------------------------------- geometry


def quat_to_rotmat(q: Array) -> Array:
    """Rotation matrix of a quaternion (w, x, y, z).

    Args:
        q: (..., 4), any nonzero norm (it is normalized).
    Returns:
        (..., 3, 3) body-to-world rotation matrix.
    """
    q = q / jnp.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    r = jnp.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], axis=-1)
    return r.reshape(q.shape[:-1] + (3, 3))


def yaw_to_quat(yaw) -> Array:
    """Quaternion (w, x, y, z) of a rotation by ``yaw`` rad about world z; (...,) -> (..., 4)."""
    yaw = jnp.asarray(yaw, jnp.float64)
    z = jnp.zeros_like(yaw)
    return jnp.stack([jnp.cos(yaw / 2), z, z, jnp.sin(yaw / 2)], axis=-1)


def vee(s: Array) -> Array:
    """Vector of a skew-symmetric matrix: (..., 3, 3) -> (..., 3), vee(hat(x)) = x."""
    return jnp.stack([s[..., 2, 1], s[..., 0, 2], s[..., 1, 0]], axis=-1)


def _safe_normalize(x: Array, fallback: Array) -> tuple[Array, Array]:
    """x / |x|, or ``fallback`` (assumed unit) where |x| < _EPS; gradient-safe."""
    n2 = jnp.sum(x * x)
    ok = n2 > _EPS**2
    n = jnp.sqrt(jnp.where(ok, n2, 1.0))
    return jnp.where(ok, x / n, fallback), jnp.where(ok, n, 0.0)


# ----------------------------------------------------------------------------- control


def allocate(params: SE3Params, thrust: Array, moments: Array):
    """Rotor speeds squared for a wrench, clamped, and the wrench they really produce.

    Args:
        params: SE3Params of one vehicle.
        thrust: () N.  moments: (3,) body moments, N m.
    Returns:
        (w_sq (MAX_ROTORS,) rad^2/s^2 clamped to [0, w_max^2] and 0 on absent rotors,
         thrust () N, moments (3,) N m recomputed from w_sq,
         saturated () bool: some present rotor's unclamped w^2 was outside [0, w_max^2]).
    """
    wrench = jnp.concatenate([moments, thrust[None]])
    w_sq_cmd = params.allocation_pinv @ wrench
    saturated = jnp.any(params.rotor_mask & ((w_sq_cmd < 0.0) | (w_sq_cmd > params.w_max_sq)))
    w_sq = jnp.where(params.rotor_mask, jnp.clip(w_sq_cmd, 0.0, params.w_max_sq), 0.0)
    out = params.allocation @ w_sq
    return w_sq, out[3], out[:3], saturated


def wrench_from_rotor_speeds(params: SE3Params, w: Array):
    """Thrust and body moments produced by rotor speeds (no clamping).

    Args:
        params: SE3Params of one vehicle.  w: (MAX_ROTORS,) rotor speeds, rad/s.
    Returns:
        (thrust () N, moments (3,) N m); absent rotors contribute nothing.
    """
    out = params.allocation @ jnp.where(params.rotor_mask, w * w, 0.0)
    return out[3], out[:3]


def motor_lag(params: SE3Params, w: Array, w_sq_cmd: Array, dt) -> Array:
    """One exact step of the RotorS first-order motor model, w' = (w_cmd - w) / tau.

    tau is ``tau_up`` where the command is above the current speed and ``tau_down``
    otherwise; the step is exact for a command held over ``dt``.

    Args:
        params: SE3Params of one vehicle.
        w: (MAX_ROTORS,) current rotor speeds, rad/s (>= 0).
        w_sq_cmd: (MAX_ROTORS,) commanded speeds squared (e.g. SE3Output.rotor_speeds_sq).
        dt: () step, s.
    Returns:
        (MAX_ROTORS,) rotor speeds after dt, rad/s, 0 on absent rotors.
    """
    w_cmd = jnp.sqrt(jnp.clip(w_sq_cmd, 0.0, params.w_max_sq))
    tau = jnp.where(w_cmd > w, params.tau_up, params.tau_down)
    w_new = w_cmd + (w - w_cmd) * jnp.exp(-dt / tau)
    return jnp.where(params.rotor_mask, w_new, 0.0)


def _all_finite(tree) -> Array:
    leaves = jax.tree.leaves(tree)
    return jnp.all(jnp.stack([jnp.all(jnp.isfinite(x)) for x in leaves]))


def se3_control(params: SE3Params, state: VehicleState, ref: Reference) -> SE3Output:
    """The geometric SE(3) controller for ONE vehicle (vmap for a fleet).

    Args:
        params: SE3Params (no batch axis).
        state: VehicleState: position (3,) m, velocity (3,) m/s world, quat (4,) wxyz,
            ang_vel (3,) rad/s BODY frame.
        ref: Reference: position, velocity, acceleration, jerk (3,) each, yaw (), yaw_rate ().
    Returns:
        SE3Output (see there); never contains NaN or inf.  See the module docstring for
        the law and the handling of non-finite inputs.
    """
    e3 = jnp.array([0.0, 0.0, 1.0])
    state_ok = _all_finite(state)
    ref_ok = _all_finite(ref)

    # Replace bad inputs before any arithmetic (keeps values and gradients finite).
    safe_state = VehicleState(jnp.zeros(3), jnp.zeros(3), jnp.array([1.0, 0.0, 0.0, 0.0]),
                              jnp.zeros(3))
    state = jax.tree.map(lambda x, s: jnp.where(state_ok, x, s), state, safe_state)
    qn2 = jnp.sum(state.quat**2)
    quat = jnp.where(qn2 > _EPS, state.quat, jnp.array([1.0, 0.0, 0.0, 0.0]))
    R = quat_to_rotmat(quat)
    hx, hy = R[0, 0], R[1, 0]
    h_ok = hx * hx + hy * hy > _EPS
    yaw_now = jnp.arctan2(jnp.where(h_ok, hy, 0.0), jnp.where(h_ok, hx, 1.0))
    hold = Reference(state.position, jnp.zeros(3), jnp.zeros(3), jnp.zeros(3), yaw_now,
                     jnp.zeros(()))
    ref = jax.tree.map(lambda x, h: jnp.where(ref_ok, x, h), ref, hold)

    m, g = params.mass, params.gravity
    F = (-params.k_x * (state.position - ref.position)
         - params.k_v * (state.velocity - ref.velocity)
         + m * g * e3 + m * ref.acceleration)
    b3 = R[:, 2]
    thrust_cmd = jnp.dot(F, b3)
    b3d, nF = _safe_normalize(F, b3)
    c1 = jnp.stack([jnp.cos(ref.yaw), jnp.sin(ref.yaw), jnp.zeros(())])
    # Heading degenerate (b3d parallel to c1): keep the current body y axis' direction.
    b2d, _ = _safe_normalize(jnp.cross(b3d, c1), R[:, 1])
    b1d = jnp.cross(b2d, b3d)
    Rd = jnp.stack([b1d, b2d, b3d], axis=1)

    e_R = 0.5 * vee(Rd.T @ R - R.T @ Rd)
    h = jnp.where(nF > 0.0, m / jnp.where(nF > 0.0, nF, 1.0), 0.0) * (
        ref.jerk - jnp.dot(b3d, ref.jerk) * b3d)
    w_d = jnp.stack([-jnp.dot(h, b2d), jnp.dot(h, b1d), ref.yaw_rate])
    e_w = state.ang_vel - R.T @ (Rd @ w_d)
    J = params.inertia
    w = state.ang_vel
    moments_cmd = -params.k_R * e_R - params.k_w * e_w + jnp.cross(w, J * w)

    w_sq, thrust, moments, saturated = allocate(params, thrust_cmd, moments_cmd)

    off = ~state_ok
    zero3 = jnp.zeros(3)
    status = jnp.where(off, STATUS_BAD_STATE, jnp.where(ref_ok, STATUS_OK, STATUS_BAD_REFERENCE))
    return SE3Output(
        rotor_speeds_sq=jnp.where(off, jnp.zeros_like(w_sq), w_sq),
        thrust=jnp.where(off, 0.0, thrust),
        moments=jnp.where(off, zero3, moments),
        saturated=jnp.where(off, False, saturated),
        thrust_cmd=jnp.where(off, 0.0, thrust_cmd),
        moments_cmd=jnp.where(off, zero3, moments_cmd),
        status=status.astype(jnp.int32),
    )


fleet_control = jax.vmap(se3_control)
"""se3_control vmapped over a leading vehicle axis of params, state and reference:
(SE3Params (M, ...), VehicleState (M, ...), Reference (M, ...)) -> SE3Output (M, ...)."""
