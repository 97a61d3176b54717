"""The controller's telemetry input: `StateEstimate` (NED, body FRD, SI units)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from companion._frozen import frozen_new
from companion.flatness.reference import vec3

FloatArray = npt.NDArray[np.float64]




@dataclass(frozen=True)
class StateEstimate:
    """Vehicle state from telemetry (LOCAL_POSITION_NED + ATTITUDE / ODOMETRY).

    t_s: time the estimate is valid at, in the companion clock [s].
    pos_ned [m], vel_ned [m/s], acc_ned [m/s^2, kinematic, optional]: world NED (3,).
    q_wxyz: attitude body FRD -> NED (normalised by the controller; a norm outside (0.5, 2) is
    treated as corrupt). omega_frd: body rates [rad/s].
    airborne: False on the ground (holds the hover-thrust estimator and the integrator).
    Build it from ODOMETRY (one time stamp for everything) or align the attitude to the
    position's time stamp: the controller extrapolates all of it from `t_s` to `now`.
    """

    t_s: float
    pos_ned: FloatArray
    vel_ned: FloatArray
    q_wxyz: FloatArray
    omega_frd: FloatArray
    acc_ned: FloatArray | None = None
    airborne: bool = True

    def __post_init__(self) -> None:
        object.__setattr__(self, "pos_ned", vec3(self.pos_ned, "pos_ned"))
        object.__setattr__(self, "vel_ned", vec3(self.vel_ned, "vel_ned"))
        object.__setattr__(self, "omega_frd", vec3(self.omega_frd, "omega_frd"))
        q = np.asarray(self.q_wxyz, dtype=np.float64).reshape(-1)
        if q.shape != (4,):
            raise ValueError(f"q_wxyz must have 4 components, got shape {q.shape}")
        object.__setattr__(self, "q_wxyz", q)
        if self.acc_ned is not None:
            object.__setattr__(self, "acc_ned", vec3(self.acc_ned, "acc_ned"))

    def is_finite(self) -> bool:
        """All fields finite and the quaternion not degenerate."""
        vals = [
            self.t_s,
            *self.pos_ned.tolist(),
            *self.vel_ned.tolist(),
            *self.q_wxyz.tolist(),
            *self.omega_frd.tolist(),
        ]
        if self.acc_ned is not None:
            vals += self.acc_ned.tolist()
        return all(map(math.isfinite, vals)) and self.quat_ok()

    def quat_ok(self) -> bool:
        """Quaternion finite with norm in (0.5, 2) (telemetry sends unit quaternions)."""
        n = math.hypot(*self.q_wxyz.tolist())  # NaN/inf propagate; no overflow
        return 0.5 < n < 2.0


Telemetry = StateEstimate
"""Alias: the controller's telemetry input."""


def state_estimate_of_arrays(
    t_s: float,
    pos_ned: FloatArray,
    vel_ned: FloatArray,
    q_wxyz: FloatArray,
    omega_frd: FloatArray,
    airborne: bool = True,
) -> StateEstimate:
    """`StateEstimate(...)` (without `acc_ned`) from float64 arrays of shape (3,) / (4,) (not
    checked): the per-sample fast path of the telemetry adapter, without the conversions."""
    return frozen_new(
        StateEstimate, t_s=t_s, pos_ned=pos_ned, vel_ned=vel_ned, q_wxyz=q_wxyz,
        omega_frd=omega_frd, acc_ned=None, airborne=airborne,
    )

