"""The RotorS vehicle table (docs/ROBOTS.md): Hummingbird, Firefly and Neo 11.

Everything here is plain Python / NumPy data; nothing is traced.  Units are SI:
kg, kg m^2, m, rad/s, s, N.

``VEHICLES[name]`` is a frozen :class:`Vehicle`.  The collision radius is the arm
length plus the rotor radius (docs/ROBOTS.md, "computed").  The planner's default dynamic
limits (``v_max``, ``a_max``, ``j_max``) are the paper's 2 m/s top speed and
conservative acceleration and jerk limits well inside each vehicle's thrust envelope;
a config's ``[limits]`` table overrides them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

GRAVITY = 9.81  # m/s^2, as in RotorS


@dataclass(frozen=True)
class Vehicle:
    """One RotorS multirotor.

    Attributes (SI units):
        name: "hummingbird" | "firefly" | "neo11".
        mass: kg (the mass the controller uses).
        inertia: (3,) principal moments Ixx, Iyy, Izz, kg m^2.
        arm_length: m.
        rotor_angles_deg: (R,) rotor azimuths in the body frame, degrees.
        rotor_directions: (R,) +1 counter-clockwise, -1 clockwise.
        rotor_tilt_deg: tilt of each rotor in the URDF (Neo: 5 deg), informational.
        motor_constant: k_f, thrust = k_f w^2 (N s^2).
        moment_constant: kappa, m (yaw moment = -d kappa k_f w^2).
        max_rotor_speed: rad/s.
        time_constant_up, time_constant_down: first-order motor lag, s.
        rotor_radius: m.
        gains: Lee controller gains in force/torque units, keys k_x, k_v, k_R, k_w, each (3,).
        v_max, a_max, j_max: default planner limits (m/s, m/s^2, m/s^3).
    """

    name: str
    mass: float
    inertia: tuple[float, float, float]
    arm_length: float
    rotor_angles_deg: tuple[float, ...]
    rotor_directions: tuple[int, ...]
    motor_constant: float
    moment_constant: float
    max_rotor_speed: float
    time_constant_up: float
    time_constant_down: float
    rotor_radius: float
    gains: dict = field(hash=False, compare=False)
    rotor_tilt_deg: float = 0.0
    v_max: float = 2.0
    a_max: float = 4.0
    j_max: float = 12.0

    @property
    def n_rotors(self) -> int:
        return len(self.rotor_angles_deg)

    @property
    def radius(self) -> float:
        """Collision radius, m: arm length + rotor radius."""
        return self.arm_length + self.rotor_radius

    @property
    def max_thrust(self) -> float:
        """Total thrust at maximum rotor speed, N."""
        return self.n_rotors * self.motor_constant * self.max_rotor_speed**2

    @property
    def max_acceleration(self) -> float:
        """Maximum specific thrust (including gravity), m/s^2."""
        return self.max_thrust / self.mass

    def allocation_matrix(self) -> np.ndarray:
        """(4, R) matrix mapping rotor speeds squared w_i^2 to (roll, pitch, yaw torque, thrust).

        Column i is [l k_f sin th_i, -l k_f cos th_i, -d_i k_f kappa, k_f] (docs/ROBOTS.md).
        """
        th = np.deg2rad(np.asarray(self.rotor_angles_deg, dtype=np.float64))
        d = np.asarray(self.rotor_directions, dtype=np.float64)
        kf, l, kap = self.motor_constant, self.arm_length, self.moment_constant
        return np.stack(
            [l * kf * np.sin(th), -l * kf * np.cos(th), -d * kf * kap, kf * np.ones_like(th)]
        )


_HEX_ANGLES = (30.0, 90.0, 150.0, -150.0, -90.0, -30.0)
_HEX_DIRS = (1, -1, 1, -1, 1, -1)

VEHICLES: dict[str, Vehicle] = {
    "hummingbird": Vehicle(
        name="hummingbird",
        mass=0.716,
        inertia=(0.007, 0.007, 0.012),
        arm_length=0.17,
        rotor_angles_deg=(0.0, 90.0, 180.0, -90.0),
        rotor_directions=(-1, 1, -1, 1),
        motor_constant=8.54858e-6,
        moment_constant=0.016,
        max_rotor_speed=838.0,
        time_constant_up=0.0125,
        time_constant_down=0.025,
        rotor_radius=0.1,
        gains=dict(k_x=(4.0, 4.0, 4.0), k_v=(2.2, 2.2, 2.2), k_R=(0.7, 0.7, 0.035),
                   k_w=(0.1, 0.1, 0.025)),
    ),
    "firefly": Vehicle(
        name="firefly",
        mass=1.56779,
        inertia=(0.0347563, 0.0458929, 0.0977),
        arm_length=0.215,
        rotor_angles_deg=_HEX_ANGLES,
        rotor_directions=_HEX_DIRS,
        motor_constant=8.54858e-6,
        moment_constant=0.016,
        max_rotor_speed=838.0,
        time_constant_up=0.0125,
        time_constant_down=0.025,
        rotor_radius=0.1,
        gains=dict(k_x=(6.0, 6.0, 6.0), k_v=(4.7, 4.7, 4.7), k_R=(3.0, 3.0, 0.15),
                   k_w=(0.52, 0.52, 0.18)),
    ),
    "neo11": Vehicle(
        name="neo11",
        mass=3.42,
        inertia=(0.0608, 0.0688, 0.1489),
        arm_length=0.2895,
        rotor_angles_deg=_HEX_ANGLES,
        rotor_directions=_HEX_DIRS,
        motor_constant=1.269e-5,
        moment_constant=0.016754,
        max_rotor_speed=1047.2,
        time_constant_up=0.0182,
        time_constant_down=0.0182,
        rotor_radius=0.1397,
        rotor_tilt_deg=5.0,
        gains=dict(k_x=(8.0, 8.0, 17.0), k_v=(6.0, 6.0, 10.0), k_R=(4.0, 4.0, 2.0),
                   k_w=(0.7, 0.7, 0.7)),
    ),
}


@dataclass(frozen=True)
class GroundRobot:
    """A disc robot that moves in the plane (2-D configs only; no MJX model).

    Attributes: name; radius (m), the disc's collision radius; v_max, a_max, j_max: the
    default planner limits (m/s, m/s^2, m/s^3; a config's ``[limits]`` overrides them).
    """

    name: str
    radius: float
    v_max: float = 2.0
    a_max: float = 4.0
    j_max: float = 12.0


GROUND_ROBOTS: dict[str, GroundRobot] = {"ground": GroundRobot("ground", radius=0.3)}

# every robot kind a config can name: the RotorS multirotors and the ground robot
ROBOTS: dict[str, Vehicle | GroundRobot] = {**VEHICLES, **GROUND_ROBOTS}


def get_vehicle(name: str) -> Vehicle:
    """Look a vehicle up by name; a clear ValueError names the unknown name and the choices."""
    try:
        return VEHICLES[name]
    except KeyError:
        raise ValueError(
            f"unknown vehicle {name!r}; choose one of {', '.join(sorted(VEHICLES))}"
        ) from None


assert all(math.isclose(v.radius, r, abs_tol=1e-9) for v, r in
           zip(VEHICLES.values(), (0.27, 0.315, 0.4292), strict=True))
