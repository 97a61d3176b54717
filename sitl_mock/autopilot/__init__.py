"""The mock PX4 autopilot (sans-IO): `Autopilot` composes components that own their state.

- `links`: the MAVLink links (GCS / companion), parsing, dispatch, sending, stream schedules;
- `commander`: arming, flight modes, failsafes, home, the setpoint the vehicle tracks;
- `commands`: COMMAND_LONG / COMMAND_INT handling;
- `offboard`: offboard setpoint intake and its timeout;
- `param_server`: the parameter protocol; `missions`: the mission protocol and executor;
- `status` / `telemetry`: frozen status snapshots and the message builders that read them.
"""

from sitl_mock.autopilot.core import COMMANDER_PERIOD_S, Autopilot
from sitl_mock.autopilot.links import Link
from sitl_mock.autopilot.modes import AUTO_MODES, MANUAL_MODES, OFFBOARD_LOSS_ACTIONS, Mode
from sitl_mock.autopilot.shared import (
    COMPID,
    RESULT_ACCEPTED,
    RESULT_DENIED,
    RESULT_FAILED,
    RESULT_TEMPORARILY_REJECTED,
    RESULT_UNSUPPORTED,
    SYSID,
)
from sitl_mock.autopilot.status import StatusSnapshot, VehicleStatus
from sitl_mock.autopilot.telemetry import (
    AUTOPILOT_CAPABILITIES,
    FLIGHT_SW_VERSION,
    MissionCurrentV2,
)

__all__ = [
    "AUTOPILOT_CAPABILITIES",
    "AUTO_MODES",
    "COMMANDER_PERIOD_S",
    "COMPID",
    "FLIGHT_SW_VERSION",
    "MANUAL_MODES",
    "OFFBOARD_LOSS_ACTIONS",
    "RESULT_ACCEPTED",
    "RESULT_DENIED",
    "RESULT_FAILED",
    "RESULT_TEMPORARILY_REJECTED",
    "RESULT_UNSUPPORTED",
    "SYSID",
    "Autopilot",
    "Link",
    "MissionCurrentV2",
    "Mode",
    "StatusSnapshot",
    "VehicleStatus",
]
