"""Tracking control: the multirotor tracking law (attitude or rates + thrust), the rover's path
following, and the estimators they use (hover thrust, drag). Pure: time is passed in, no IO.

The flat API below is the package's public surface; the modules behind it are private to it.
"""

from companion.control.commands import (
    AttitudeCommand,
    PositionCommand,
    RateCommand,
    position_command,
)
from companion.control.gains import (
    AttitudeGains,
    TrackingConfig,
    TrackingDiagnostics,
    TrackingGains,
    rates_mode_gains,
)
from companion.control.law import TrackingController
from companion.control.rover import RoverController, RoverGains
from companion.control.shaping import ShapedReference, ShapingConfig
from companion.control.so3 import (
    attitude_error,
    quat_integrate,
    quat_to_dcm,
    so3_rate_command,
    so3_rate_command_dcm,
    yaw_quat,
)
from companion.control.state import StateEstimate, Telemetry, state_estimate_of_arrays
from companion.flatness.reference import Reference, reference_from_trajectory, reference_of_arrays

__all__ = [
    "AttitudeCommand",
    "AttitudeGains",
    "PositionCommand",
    "RateCommand",
    "Reference",
    "RoverController",
    "RoverGains",
    "ShapedReference",
    "ShapingConfig",
    "StateEstimate",
    "Telemetry",
    "TrackingConfig",
    "TrackingController",
    "TrackingDiagnostics",
    "TrackingGains",
    "attitude_error",
    "position_command",
    "quat_integrate",
    "quat_to_dcm",
    "rates_mode_gains",
    "reference_from_trajectory",
    "reference_of_arrays",
    "so3_rate_command",
    "so3_rate_command_dcm",
    "state_estimate_of_arrays",
    "yaw_quat",
]
