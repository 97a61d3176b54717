"""Setpoints the vehicle model tracks: what OFFBOARD messages and AUTO modes map to.

World frame NED, body frame FRD, SI units (m, m/s, m/s^2, rad, rad/s). A NaN component means
"not given", exactly like a set MAVLink type_mask ignore bit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from sitl_mock._frozen import frozen_new

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]

NAN3: Vec3 = (math.nan, math.nan, math.nan)


def _any_finite(v: Vec3) -> bool:
    return any(math.isfinite(c) for c in v)


@dataclass(frozen=True)
class PositionTarget:
    """Local NED position/velocity/acceleration target (SET_POSITION_TARGET_LOCAL_NED semantics).

    pos_ned [m], vel_ned [m/s], acc_ned [m/s^2] (NED world), yaw [rad] (heading, 0 = north),
    yaw_rate [rad/s]. Any component may be NaN ("not given"). Per axis, a given position is
    tracked with the velocity and acceleration as feed-forward; a velocity without position is
    tracked directly; an acceleration alone is applied as an acceleration command. If yaw and
    yaw_rate are both NaN the current heading is held.
    """

    pos_ned: Vec3 = NAN3
    vel_ned: Vec3 = NAN3
    acc_ned: Vec3 = NAN3
    yaw: float = math.nan
    yaw_rate: float = math.nan

    def has_motion(self) -> bool:
        """True if at least one position, velocity or acceleration axis is finite."""
        return _any_finite(self.pos_ned) or _any_finite(self.vel_ned) or _any_finite(self.acc_ned)


@dataclass(frozen=True)
class AttitudeTarget:
    """Attitude / body-rate target with normalised collective thrust (SET_ATTITUDE_TARGET).

    q_wxyz: attitude body FRD -> NED (Hamilton, scalar first), None = attitude ignored.
    thrust_norm: collective thrust 0..1, linear in the maximum thrust, NO hover scaling.
    body_rates_frd: roll/pitch/yaw rates [rad/s], None = rates ignored.
    yaw_rate_ff: yaw rate feed-forward [rad/s] used with an attitude (NaN = none).

    When both q and body rates are given the body rates win (PX4 v1.16 publishes a competing
    rate setpoint in that case; the mock picks the rates deterministically).
    """

    q_wxyz: Quat | None
    thrust_norm: float
    body_rates_frd: Vec3 | None = None
    yaw_rate_ff: float = math.nan


def make_attitude_target(
    q_wxyz: Quat | None, thrust_norm: float, body_rates_frd: Vec3 | None, yaw_rate_ff: float
) -> AttitudeTarget:
    """`AttitudeTarget(...)` without the frozen-dataclass __init__ (one per setpoint message)."""
    return frozen_new(
        AttitudeTarget,
        {
            "q_wxyz": q_wxyz,
            "thrust_norm": thrust_norm,
            "body_rates_frd": body_rates_frd,
            "yaw_rate_ff": yaw_rate_ff,
        },
    )


@dataclass(frozen=True)
class IdleTarget:
    """Motors at idle (armed on ground) or stopped (disarmed)."""


@dataclass(frozen=True)
class RoverPositionTarget:
    """A ground rover's AUTO-mode goal (PX4's rover_position_setpoint with the acceptance radius
    its AUTO mode publishes): drive along the line start_ne -> position_ne (local NED north,
    east [m]) by pure pursuit and arrive at `arrival_speed` [m/s], at most `cruising_speed`
    [m/s]; within `acceptance_radius_m` [m] of the goal it stops.

    position_ne NaN: stop where it is (Hold). start_ne NaN: the line starts at the rover (PX4's
    fallback: it then drives straight at the goal). cruising_speed NaN: RO_SPEED_LIM.
    """

    position_ne: tuple[float, float]
    start_ne: tuple[float, float] = (math.nan, math.nan)
    cruising_speed: float = math.nan
    arrival_speed: float = 0.0
    acceptance_radius_m: float = 0.5


Target = PositionTarget | AttitudeTarget | IdleTarget | RoverPositionTarget

__all__ = [
    "NAN3",
    "AttitudeTarget",
    "IdleTarget",
    "PositionTarget",
    "Quat",
    "RoverPositionTarget",
    "Target",
    "Vec3",
    "make_attitude_target",
]
