"""MJCF for the RotorS fleet, the MuJoCo model, and its MJX copy.

Each vehicle is one free body carrying the vehicle's mass and diagonal inertia
(:mod:`jaxplan.vehicles`, docs/ROBOTS.md) at its origin, and one site ``actuation``
at that origin where four motor actuators act (the mujoco_menagerie crazyflie pattern):

    ctrl[4 i + 0]  thrust along body z, N          gear [0 0 1 0 0 0]
    ctrl[4 i + 1]  moment about body x, N m        gear [0 0 0 1 0 0]
    ctrl[4 i + 2]  moment about body y, N m        gear [0 0 0 0 1 0]
    ctrl[4 i + 3]  moment about body z, N m        gear [0 0 0 0 0 1]

The controls are unlimited (``ctrllimited="false"``): the rotor-speed saturation
belongs to the controller (:func:`jaxplan.sim.se3.allocate`), which hands the thrust
and moments of the CLAMPED rotor speeds to these actuators.  The rotor geoms are for
pictures only: every geom has ``contype = conaffinity = 0``, so nothing ever collides
(separation is measured, not collided), no contact is ever generated, and the
constraint solver has nothing to do.  With a world (:func:`world_geoms`) its floor,
walls, ceiling and obstacles are geoms too, also non-colliding: a robot touching them
is a collision measured from the simulated states at every physics step (the exact
signed distance of the robot's collision sphere, as robot pairs are measured;
:mod:`jaxplan.sim.fleet`), not a contact force.  A moving obstacle is a mocap body
(``obstacle<k>_body``) whose position the simulation sets from the obstacle's motion at
every physics step (:mod:`jaxplan.sim.obstacles`).  Without one there is a ground plane at
z = 0 for pictures.  No air: density and viscosity are 0, so the only forces are gravity
(9.81 m/s^2, as in RotorS) and the actuators.

Integrator.  ``integrator="Euler"`` (the default; MuJoCo's semi-implicit Euler: the
velocity is updated first, the position with the new velocity; without joint damping
it is plain explicit symplectic Euler) or ``"RK4"``.  Both run in MJX and in the C
engine.  Measured (tests/test_sim_model.py; 3 vehicles, 500 Hz, 2 s of sinusoidal
thrust and moments, float64): max |qpos_MJX - qpos_C| is 7e-15 with Euler and 6e-8
with RK4 (MJX's RK4 is not bit-compatible with C's); with the controller in the loop
(Euler) 1e-15.  Euler is the default because MJX and C agree to rounding, and it costs
one dynamics evaluation per step instead of four (docs/SOLVER.md, "Measurements behind
the code", for what a step costs).  Its
own discretisation error in that open-loop test is 2.2 mm after 2 s against RK4 at
10 kHz (first order: 1.1 mm at 1 kHz); under feedback it is far below the controller's
tracking error.  RK4 at 500 Hz is accurate to 2e-12 m there: pick it for accuracy
studies with the C engine.

Free-joint conventions (checked in the tests): qpos[7 i : 7 i + 7] = position (world,
m) and quaternion (w, x, y, z), qvel[6 i : 6 i + 3] = linear velocity in the WORLD
frame, qvel[6 i + 3 : 6 i + 6] = angular velocity in the BODY frame.  This is what
:class:`jaxplan.sim.se3.VehicleState` expects, so :func:`fleet_state` only reshapes.

Inertia: the Firefly's and Neo 11's RotorS inertias violate A + B >= C, which MuJoCo's
compiler rejects; the XML carries the nearest compilable values and
:func:`fleet_model` writes the table's exact values into the compiled model (see
there).  Build models with :func:`fleet_model`, not from the XML string alone.

MJX: ``mjx.put_model`` keeps float64 when JAX x64 is enabled (importing jaxplan does
that); :func:`to_mjx` checks it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import mujoco
import numpy as np

from jaxplan.sim.se3 import VehicleState
from jaxplan.vehicles import GRAVITY, Vehicle, get_vehicle
from jaxplan.world import BOX, CYLINDER, SPHERE, World, face_names

INTEGRATORS = ("Euler", "RK4")
N_CONTROLS = 4  # per vehicle: thrust, moment x, moment y, moment z

_RGBA = {"hummingbird": "0.2 0.4 0.9 1", "firefly": "0.9 0.5 0.1 1", "neo11": "0.3 0.7 0.3 1"}


def _f(x: float) -> str:
    return repr(float(x))


def _compilable_inertia(inertia) -> tuple[float, float, float]:
    """The nearest diagonal inertia MuJoCo's compiler accepts (A + B >= C for all axes).

    Each principal moment is lowered, if needed, to the sum of the other two.  Only
    the XML string carries this; :func:`fleet_model` restores the table's values.
    """
    ix, iy, iz = (float(c) for c in inertia)
    return min(ix, iy + iz), min(iy, ix + iz), min(iz, ix + iy)


def _vehicle_body(vehicle: Vehicle, prefix: str, pos, yaw: float, visual: bool = True,
                  hull: float | None = None) -> str:
    """<body> element of one vehicle (free joint, inertial, site, picture geoms if
    ``visual``, the collision sphere ``{prefix}hull`` of radius ``hull`` if given)."""
    px, py, pz = (float(c) for c in pos)
    ix, iy, iz = _compilable_inertia(vehicle.inertia)
    l, rr = vehicle.arm_length, vehicle.rotor_radius
    rgba = _RGBA.get(vehicle.name, "0.5 0.5 0.5 1")
    quat = f"{_f(math.cos(yaw / 2))} 0 0 {_f(math.sin(yaw / 2))}"
    nocol = 'contype="0" conaffinity="0" group="1"'
    geoms = [f'<geom name="{prefix}core" type="box" size="0.06 0.06 0.025" rgba="{rgba}" {nocol}/>']
    rotors = zip(vehicle.rotor_angles_deg, vehicle.rotor_directions, strict=True)
    for k, (ang, d) in enumerate(rotors):
        th = math.radians(ang)
        x, y = l * math.cos(th), l * math.sin(th)
        geoms.append(f'<geom name="{prefix}arm{k}" type="capsule" size="0.008" '
                     f'fromto="0 0 0 {_f(x)} {_f(y)} 0" rgba="0.2 0.2 0.2 1" {nocol}/>')
        col = "0.1 0.1 0.1 0.5" if d > 0 else "0.8 0.1 0.1 0.5"
        geoms.append(f'<geom name="{prefix}rotor{k}" type="cylinder" size="{_f(rr)} 0.004" '
                     f'pos="{_f(x)} {_f(y)} 0.02" rgba="{col}" {nocol}/>')
    if not visual:
        geoms = []
    if hull is not None:
        geoms.append(f'<geom name="{prefix}hull" type="sphere" size="{_f(hull)}" '
                     f'rgba="{rgba[:-1]}0.15" {nocol}/>')
    body = "\n      ".join(geoms)
    return f"""
    <body name="{prefix}body" pos="{_f(px)} {_f(py)} {_f(pz)}" quat="{quat}">
      <freejoint name="{prefix}joint"/>
      <inertial pos="0 0 0" mass="{_f(vehicle.mass)}" diaginertia="{_f(ix)} {_f(iy)} {_f(iz)}"/>
      <site name="{prefix}actuation" pos="0 0 0"/>
      {body}
    </body>"""


def _vehicle_actuators(prefix: str) -> str:
    site = f'site="{prefix}actuation" ctrllimited="false"'
    return "\n".join([
        f'    <motor name="{prefix}thrust" {site} gear="0 0 1 0 0 0"/>',
        f'    <motor name="{prefix}mx" {site} gear="0 0 0 1 0 0"/>',
        f'    <motor name="{prefix}my" {site} gear="0 0 0 0 1 0"/>',
        f'    <motor name="{prefix}mz" {site} gear="0 0 0 0 0 1"/>',
    ])


def world_geoms(world: World) -> str:
    """MJCF geoms and bodies (children of <worldbody>) of a 3-D
    :class:`~jaxplan.world.World`.

    Every finite workspace face is a plane named ``ws_<face>`` (``ws_z_min`` is the
    floor; :func:`jaxplan.world.face_names`) through the bound, its normal (the plane's
    local z axis) pointing into the workspace; obstacle k is the geom ``obstacle<k>``: a
    sphere (size = radius), a box (size = half extents) or a vertical cylinder (size =
    radius, half height) at its centre.  A moving obstacle's geom sits in a mocap body
    ``obstacle<k>_body`` (:func:`mocap_bodies`) at its centre at t = 0, so that setting
    its ``mocap_pos`` moves it; a static one is a geom of the world body.  None of them
    collides (contype = conaffinity = 0, as every geom of the fleet): contact is measured
    from the simulated states (:mod:`jaxplan.sim.fleet`).
    """
    _check_3d(world, "world_geoms")
    nocol = 'contype="0" conaffinity="0" group="2"'
    out = []
    for name, (c, n) in zip(face_names(world), _faces(world), strict=True):
        rgba = "0.8 0.8 0.8 1" if name == "z_min" else "0.6 0.7 0.8 0.25"
        out.append(f'<geom name="ws_{name}" type="plane" size="0 0 1" pos="{_v(c)}" '
                   f'zaxis="{_v(n)}" rgba="{rgba}" {nocol}/>')
    moving = world.moving
    for k in range(world.num_obstacles):
        kind = int(world.kind[k])
        if kind == SPHERE:
            typ, size = "sphere", _f(world.radius[k])
        elif kind == BOX:
            typ, size = "box", _v(world.half[k])
        elif kind == CYLINDER:
            typ, size = "cylinder", f"{_f(world.radius[k])} {_f(world.half[k, 2])}"
        else:
            raise ValueError(f"world_geoms: obstacle {k} has unknown kind {kind}")
        geom = (f'<geom name="obstacle{k}" type="{typ}" size="{size}" '
                f'rgba="0.55 0.45 0.35 0.8" {nocol}/>')
        if moving[k]:  # placed by its mocap body
            out.append(_mocap_body(k, world.center[k], geom))
        else:
            out.append(geom.replace(" rgba=", f' pos="{_v(world.center[k])}" rgba=', 1))
    return "".join(f"\n    {g}" for g in out)


def mocap_bodies(world: World) -> str:
    """MJCF of a 3-D world's moving obstacles as bare mocap bodies (children of
    <worldbody>, no geoms): obstacle k that moves is ``obstacle<k>_body`` at its centre
    at t = 0, in the order of k, so that mocap index j is the j-th moving obstacle.
    What the stepped models of :mod:`jaxplan.sim.fleet` carry: the simulation sets
    their ``mocap_pos`` from the motion at every physics step; nothing else reads them
    (they have no mass and nothing collides).  Empty for a static world."""
    _check_3d(world, "mocap_bodies")
    return "".join(f"\n    {_mocap_body(k, world.center[k])}" for k in mocap_rows(world))


def mocap_rows(world: World) -> tuple[int, ...]:
    """The obstacles that are mocap bodies (:func:`world_geoms`, :func:`mocap_bodies`):
    the moving ones, in mocap order (index j is obstacle ``mocap_rows(world)[j]``)."""
    return tuple(int(k) for k in np.flatnonzero(world.moving))


def _mocap_body(k: int, c, inner: str = "") -> str:
    return f'<body name="obstacle{k}_body" mocap="true" pos="{_v(c)}">{inner}</body>'


def _check_3d(world: World, what: str) -> None:
    if world.dim != 3:
        raise ValueError(f"{what}: the world is {world.dim}-D; MuJoCo needs 3-D")


def _v(x) -> str:
    return " ".join(_f(c) for c in x)


def _faces(world: World):
    """(point on the face, unit inward normal) of each finite face, face_names' order."""
    out = []
    for bound, sign in ((world.lo, 1.0), (world.hi, -1.0)):
        for i in np.flatnonzero(np.isfinite(bound)):
            c = np.zeros(world.dim)
            c[i] = bound[i]
            n = np.zeros(world.dim)
            n[i] = sign
            out.append((c, n))
    return out


def fleet_xml(names: Sequence[str], positions, *, yaws=None, timestep: float = 0.002,
              integrator: str = "Euler", visual: bool = True, world: World | None = None,
              hull_radii=None, mocap_world: World | None = None) -> str:
    """MJCF of a (heterogeneous) fleet: one non-colliding free body per vehicle.

    Args:
        names: M vehicle names ("hummingbird" | "firefly" | "neo11"), any mix.
        positions: (M, 3) initial positions, m (world; z up).
        yaws: (M,) initial yaw angles, rad, or None (zeros).
        timestep: physics step, s (0.002 = 500 Hz).
        integrator: "Euler" (MuJoCo semi-implicit Euler) or "RK4".
        visual: True (default) adds the picture geoms (core box, arms, rotors, ground
            plane, light); False gives bodies with no geoms at all, whose structure is
            the same for every vehicle kind (only mass and inertia differ) and which
            MJX steps faster (no geom kinematics): what :mod:`jaxplan.sim.fleet` uses.
            The dynamics are identical (geoms never collide and carry no mass).
        world: a 3-D :class:`~jaxplan.world.World` whose workspace faces and obstacles
            become geoms (:func:`world_geoms`; the floor ``ws_z_min`` replaces the
            picture ground), or None (no world geoms; the picture ground at z = 0 when
            ``visual``).
        hull_radii: (M,) m or None: a sphere geom ``r{i}_hull`` of this radius on each
            vehicle (its collision radius, for pictures and distance queries such as
            ``mujoco.mj_geomDistance``; non-colliding, massless).
        mocap_world: a 3-D World whose moving obstacles become bare mocap bodies
            (:func:`mocap_bodies`; what :mod:`jaxplan.sim.fleet` steps), or None; not
            with ``world`` (whose moving obstacles are mocap bodies with their geoms).
    Returns:
        The MJCF string.  Vehicle i is body ``r{i}_body`` with joint ``r{i}_joint``,
        site ``r{i}_actuation`` and actuators ``r{i}_thrust, r{i}_mx, r{i}_my, r{i}_mz``
        (ctrl[4 i : 4 i + 4] = thrust N, body moments N m).  The world's moving
        obstacles (``world`` or ``mocap_world``) are mocap bodies ``obstacle<k>_body``,
        before the vehicles: mocap index j is the j-th moving obstacle.
    """
    vehicles = [get_vehicle(n) for n in names]
    pos = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    if pos.shape[0] != len(vehicles):
        raise ValueError(f"{len(vehicles)} vehicle names but {pos.shape[0]} positions")
    if not np.all(np.isfinite(pos)):
        raise ValueError("fleet_xml: positions must be finite")
    yaw = np.zeros(len(vehicles)) if yaws is None else np.asarray(yaws, np.float64).reshape(-1)
    if yaw.shape[0] != len(vehicles):
        raise ValueError(f"{len(vehicles)} vehicle names but {yaw.shape[0]} yaws")
    if integrator not in INTEGRATORS:
        raise ValueError(f"integrator must be one of {INTEGRATORS}, got {integrator!r}")
    if not (timestep > 0 and math.isfinite(timestep)):
        raise ValueError(f"timestep must be a positive number of seconds, got {timestep!r}")
    if hull_radii is None:
        hull = [None] * len(vehicles)
    else:
        hull = [float(r) for r in np.asarray(hull_radii, np.float64).reshape(-1)]
        if len(hull) != len(vehicles) or not all(r > 0 and math.isfinite(r) for r in hull):
            raise ValueError(f"hull_radii must be {len(vehicles)} positive radii, got "
                             f"{hull_radii!r}")
    bodies = "".join(_vehicle_body(v, f"r{i}_", pos[i], yaw[i], visual, hull[i])
                     for i, v in enumerate(vehicles))
    scenery = """
    <light pos="0 0 10" dir="0 0 -1" directional="true"/>""" if visual else ""
    if world is not None and mocap_world is not None:
        raise ValueError("fleet_xml: give world or mocap_world, not both")
    if world is not None:
        scenery += world_geoms(world)
    elif mocap_world is not None:
        scenery += mocap_bodies(mocap_world)
    if world is None and visual:
        scenery += """
    <geom name="ground" type="plane" size="50 50 0.1" rgba="0.8 0.8 0.8 1"
          contype="0" conaffinity="0"/>"""
    acts = "\n".join(_vehicle_actuators(f"r{i}_") for i in range(len(vehicles)))
    return f"""<mujoco model="jaxplan_fleet">
  <option timestep="{_f(timestep)}" integrator="{integrator}" gravity="0 0 {_f(-GRAVITY)}"
          density="0" viscosity="0"/>
  <worldbody>{scenery}{bodies}
  </worldbody>
  <actuator>
{acts}
  </actuator>
</mujoco>
"""


def vehicle_xml(name: str, position=(0.0, 0.0, 1.0), **kwargs) -> str:
    """MJCF of a single vehicle; ``fleet_xml([name], [position], **kwargs)``.

    Args:
        name: vehicle name.  position: (3,) initial position, m.
        kwargs: yaws, timestep (s), integrator, as in :func:`fleet_xml`.
    Returns:
        The MJCF string (the vehicle is ``r0_``).
    """
    return fleet_xml([name], [position], **kwargs)


def fleet_model(names: Sequence[str], positions, **kwargs) -> mujoco.MjModel:
    """Compiled MuJoCo model of a fleet: ``MjModel.from_xml_string(fleet_xml(...))``.

    After compiling, each body's principal inertia is set to the vehicle table's exact
    value.  The RotorS Firefly (.0348 + .0459 < .0977) and Neo 11 (.0608 + .0688 <
    .1489) inertias violate the triangle inequality A + B >= C that every rigid body
    satisfies, so MuJoCo's compiler rejects them; Gazebo (ODE) never checked, and the
    paper's vehicles flew with these numbers.  The XML therefore carries the nearest
    compilable inertia (:func:`_compilable_inertia`: Izz lowered to Ixx + Iyy) and the
    compiled model gets the table's values back (Euler's rigid-body equations are well
    posed for any positive diagonal inertia; with no contacts nothing else reads it
    except derived constants, which ``mj_setConst`` recomputes).

    Args and kwargs as :func:`fleet_xml`.  Returns an ``mujoco.MjModel`` (float64).
    """
    model = mujoco.MjModel.from_xml_string(fleet_xml(names, positions, **kwargs))
    for i, name in enumerate(names):
        bid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, f"r{i}_body")
        model.body_inertia[bid] = np.asarray(get_vehicle(name).inertia, dtype=np.float64)
    mujoco.mj_setConst(model, mujoco.MjData(model))
    return model


def to_mjx(model: mujoco.MjModel):
    """Put a MuJoCo model on MJX, keeping float64.

    Args:
        model: mujoco.MjModel.
    Returns:
        (mjx.Model, mjx.Data at the model's qpos0 with zero velocity and controls).
    Raises:
        RuntimeError if JAX x64 is off (MJX would silently compute in float32).
    """
    import jax

    from jaxplan.sim import import_mjx

    mjx = import_mjx()
    if not jax.config.jax_enable_x64:
        raise RuntimeError("to_mjx needs jax x64 (import jaxplan first)")
    mx = mjx.put_model(model)
    dx = mjx.make_data(mx)
    if mx.body_mass.dtype != np.float64 or dx.qpos.dtype != np.float64:
        raise RuntimeError(f"MJX model is {mx.body_mass.dtype}, expected float64")
    return mx, dx


def fleet_state(qpos, qvel) -> VehicleState:
    """Per-vehicle state from a fleet's qpos/qvel (NumPy or JAX arrays; reshapes only).

    Args:
        qpos: (..., 7 M) free-joint coordinates.  qvel: (..., 6 M).
    Returns:
        VehicleState with leaves (..., M, 3) / quat (..., M, 4): position m, velocity m/s
        (world), quat wxyz, ang_vel rad/s (body).
    """
    qp = qpos.reshape(qpos.shape[:-1] + (-1, 7))
    qv = qvel.reshape(qvel.shape[:-1] + (-1, 6))
    return VehicleState(qp[..., 0:3], qv[..., 0:3], qp[..., 3:7], qv[..., 3:6])


def fleet_ctrl(thrust, moments):
    """Controls vector of a fleet from per-vehicle thrust and moments.

    Args:
        thrust: (..., M) N.  moments: (..., M, 3) body moments, N m (NumPy or JAX).
    Returns:
        (..., 4 M) ctrl, vehicle-major: [f_0, Mx_0, My_0, Mz_0, f_1, ...].
    """
    if isinstance(thrust, np.ndarray) and isinstance(moments, np.ndarray):
        xp = np
    else:
        import jax.numpy as xp
    w = xp.concatenate([thrust[..., None], moments], axis=-1)
    return w.reshape(w.shape[:-2] + (-1,))
