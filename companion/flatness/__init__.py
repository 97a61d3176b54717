"""Differential flatness: flat outputs (position derivatives, yaw) -> vehicle setpoints.

Multirotor: thrust and its derivatives, attitude (quaternion and DCM), body rates, angular
acceleration and moments, with linear drag (docs/theory/multirotor.md). Rover: heading, speed
and rates, and with a wheel base the curvature and steering of a car-like (Ackermann) rover
(docs/theory/rover.md).
:func:`symbolic` gives the same maps as named ``casadi.Function`` objects (for the C generator);
:func:`multirotor_setpoint` and :func:`rover_setpoint` are the fast numeric path.
"""

from companion.flatness._formulas import (
    COS_ROLL_MIN,
    FLAG_HEADING_SINGULAR,
    FLAG_INVERTED,
    FLAG_LOW_THRUST,
    ROVER_SPEED_MIN,
    THRUST_MIN_FRAC,
)
from companion.flatness.numeric import multirotor_setpoint, rover_setpoint
from companion.flatness.symbolic import SymbolicFlatness, symbolic
from companion.flatness.types import MultirotorParams, MultirotorSetpoint, RoverSetpoint

__all__ = [
    "COS_ROLL_MIN",
    "FLAG_HEADING_SINGULAR",
    "FLAG_INVERTED",
    "FLAG_LOW_THRUST",
    "ROVER_SPEED_MIN",
    "THRUST_MIN_FRAC",
    "MultirotorParams",
    "MultirotorSetpoint",
    "RoverSetpoint",
    "SymbolicFlatness",
    "multirotor_setpoint",
    "rover_setpoint",
    "symbolic",
]
