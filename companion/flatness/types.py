"""Value types of the flatness maps: vehicle parameters and setpoints (frozen dataclasses)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]
#: One sample: a float; a batch of N samples: an array of shape (N,).
Scalar = float | FloatArray

STANDARD_GRAVITY = 9.80665


def _matrix3(value: Any) -> tuple[tuple[float, float, float], ...]:
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"inertia must be a 3x3 matrix of numbers: {exc}") from None
    if a.shape == (3,):
        a = np.diag(a)
    if a.shape != (3, 3):
        raise ValueError(f"inertia must be a 3x3 matrix (kg m^2) or its diagonal, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError("inertia contains a non-finite value")
    if not np.allclose(a, a.T, rtol=1e-9, atol=1e-12 * float(np.max(np.abs(a)) or 1.0)):
        raise ValueError("inertia must be symmetric")
    a = 0.5 * (a + a.T)
    if float(np.min(np.linalg.eigvalsh(a))) <= 0.0:
        raise ValueError("inertia must be positive definite (all principal moments > 0 kg m^2)")
    return tuple((float(r[0]), float(r[1]), float(r[2])) for r in a)


@dataclass(frozen=True)
class MultirotorParams:
    """Multirotor parameters for the flatness map.

    mass: kg (> 0). inertia: body FRD inertia about the centre of mass, kg m^2, a symmetric
    positive-definite 3x3 (a length-3 diagonal is accepted); stored as a tuple of rows.
    g: gravity, m/s^2 (> 0). hover_thrust: normalised thrust (0, 1] that holds hover
    (PX4 MPC_THR_HOVER). drag: linear drag coefficient D >= 0, N/(m/s), world frame, force
    ``-D v`` (PX4 SIH model; 0 disables it).
    """

    mass: float
    inertia: Any
    g: float = STANDARD_GRAVITY
    hover_thrust: float = 0.5
    drag: float = 0.0

    def __post_init__(self) -> None:
        for name in ("mass", "g", "hover_thrust", "drag"):
            try:
                val = float(getattr(self, name))
            except (TypeError, ValueError):
                raise ValueError(f"{name} must be a number, got {getattr(self, name)!r}") from None
            if not math.isfinite(val):
                raise ValueError(f"{name} must be finite, got {val}")
            object.__setattr__(self, name, val)
        if self.mass <= 0.0:
            raise ValueError(f"mass must be positive (kg), got {self.mass}")
        if self.g <= 0.0:
            raise ValueError(f"g must be positive (m/s^2), got {self.g}")
        if not 0.0 < self.hover_thrust <= 1.0:
            raise ValueError(f"hover_thrust must be in (0, 1], got {self.hover_thrust}")
        if self.drag < 0.0:
            raise ValueError(f"drag must be >= 0 N/(m/s), got {self.drag}")
        object.__setattr__(self, "inertia", _matrix3(self.inertia))

    @property
    def inertia_matrix(self) -> FloatArray:
        """Inertia as a (3, 3) array, kg m^2."""
        return np.array(self.inertia, dtype=np.float64)

    @property
    def hover_thrust_n(self) -> float:
        """Thrust (N) that balances gravity, ``m g``."""
        return self.mass * self.g


@dataclass(frozen=True)
class MultirotorSetpoint:
    """Multirotor setpoint from the flat outputs. One sample: floats and (4,), (3, 3), (3,)
    arrays; a batch of N: arrays with a leading N.

    thrust: T (N), along -z_b. thrust_dot, thrust_ddot: dT/dt (N/s), d2T/dt2 (N/s^2).
    thrust_norm: ``hover_thrust * T / (m g)`` clamped to [0, 1] (MAVLink SET_ATTITUDE_TARGET).
    q_wxyz: attitude body FRD -> world NED, Hamilton, unit, w >= 0. C_eb: the same as a DCM
    (columns: body axes in NED). omega_frd: body rates (rad/s). omega_dot_frd: body angular
    acceleration (rad/s^2). moment_frd: ``J omega' + omega x J omega`` (N m).
    singular: True where a fallback was used or the vehicle is inverted (see ``flags``).
    flags: bit set, 1 low thrust (rates zeroed, level attitude if no direction), 2 heading
    singular (z_b parallel to y_c: yaw-only attitude, rates zeroed), 4 inverted (z_b . e3 <= 0,
    PX4 flip of x_b; rates valid).
    """

    thrust: Scalar
    thrust_dot: Scalar
    thrust_ddot: Scalar
    thrust_norm: Scalar
    q_wxyz: FloatArray
    C_eb: FloatArray
    omega_frd: FloatArray
    omega_dot_frd: FloatArray
    moment_frd: FloatArray
    singular: bool | BoolArray
    flags: int | npt.NDArray[np.int64]


@dataclass(frozen=True)
class RoverSetpoint:
    """Rover setpoint (unicycle, plus the Ackermann steering of a car-like rover when a wheel base
    is given). One sample: floats; a batch of N: (N,) arrays. NED: x north, y east.

    yaw: heading (rad, (-pi, pi], 0 north, +pi/2 east). speed: ground speed (m/s, >= 0).
    speed_dot: m/s^2. yaw_rate: rad/s. yaw_acc: rad/s^2 (None when no jerk was given).
    singular: True where the rover is (nearly) stopped: heading from the velocity, else the
    acceleration, else 0; speed_dot, the rates and the four Ackermann fields are 0 there.

    Ackermann fields (bicycle model about the rear axle; None without a wheel base):
    curvature: signed path curvature kappa (1/m, > 0 turning right = clockwise seen from
    above, the sign of yaw_rate = speed * kappa). curvature_rate: d(kappa)/dt (1/(m s); None
    without jerk). steer_angle: front-wheel angle delta = atan(L kappa) (rad, in (-pi/2,
    pi/2), > 0 right). steer_rate: d(delta)/dt (rad/s; None without jerk).
    """

    yaw: Scalar
    speed: Scalar
    speed_dot: Scalar
    yaw_rate: Scalar
    yaw_acc: Scalar | None
    singular: bool | BoolArray = False
    curvature: Scalar | None = None
    curvature_rate: Scalar | None = None
    steer_angle: Scalar | None = None
    steer_rate: Scalar | None = None
