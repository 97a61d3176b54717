"""Sans-IO MAVLink core of the companion: bytes in, events out, frames to send.

No sockets, no clock: every call takes ``now`` (local monotonic seconds). The asyncio adapter is
``companion.aio``.
"""

from .codec import DEFAULT_COMPID, DEFAULT_SYSID, PX4_COMPID, PX4_SYSID, Codec, raw_frame
from .commands import (
    CommandBusyError,
    CommandClient,
    CommandFinished,
    CommandProgress,
    MavResult,
    result_name,
)
from .heartbeat import (
    ArmedChanged,
    HeartbeatTracker,
    LinkLost,
    LinkUp,
    ModeChanged,
    VehicleHeartbeat,
)
from .link import LinkConfig, LinkEvent, VehicleLink
from .mission_client import (
    MissionBusyError,
    MissionClient,
    MissionResult,
    MissionTransferDone,
    WireMissionItem,
    item_from_msg,
    item_to_msg,
)
from .offboard import (
    TRANSITIONS,
    OffboardMachine,
    OffboardNotPrimedError,
    OffboardState,
    OffboardStateChanged,
    OffboardTrigger,
)
from .params import (
    ParamBusyError,
    ParamClient,
    ParamReadDone,
    ParamType,
    decode_param_value,
    encode_param_value,
)
from .px4_mode import (
    FlightMode,
    Px4AutoSubMode,
    Px4MainMode,
    custom_mode_of,
    decode_custom_mode,
    encode_custom_mode,
    flight_mode_from_custom_mode,
)
from .setpoints import (
    AttitudeSetpoint,
    PositionSetpoint,
    RatesSetpoint,
    RoverVelocitySetpoint,
    SetpointCommand,
    SetpointError,
    build_attitude_target,
    build_position_target,
    build_rates_target,
    build_rover_velocity_target,
    build_setpoint,
)
from .signing import (
    Signer,
    SigningConfig,
    SigningKeyError,
    Verdict,
    load_signing_key,
    parse_signing_key,
)
from .telemetry import (
    Attitude,
    ExtendedState,
    GlobalPosition,
    HomePosition,
    LocalPosition,
    MissionCurrent,
    StatusText,
    SystemStatus,
    TelemetrySnapshot,
    TelemetryState,
)
from .timesync import TimeSync, TimesyncUpdate

__all__ = [
    "DEFAULT_COMPID", "DEFAULT_SYSID", "PX4_COMPID", "PX4_SYSID", "TRANSITIONS",
    "ArmedChanged", "Attitude", "AttitudeSetpoint", "Codec", "CommandBusyError", "CommandClient",
    "CommandFinished", "CommandProgress", "ExtendedState", "FlightMode", "GlobalPosition",
    "HeartbeatTracker", "HomePosition", "LinkConfig", "LinkEvent", "LinkLost", "LinkUp",
    "LocalPosition", "MavResult", "MissionBusyError", "MissionClient", "MissionCurrent",
    "MissionResult", "MissionTransferDone", "ModeChanged", "OffboardMachine",
    "OffboardNotPrimedError", "OffboardState", "OffboardStateChanged", "OffboardTrigger",
    "ParamBusyError", "ParamClient", "ParamReadDone", "ParamType",
    "PositionSetpoint", "Px4AutoSubMode", "Px4MainMode", "RatesSetpoint",
    "RoverVelocitySetpoint", "SetpointCommand", "SetpointError", "Signer", "SigningConfig",
    "SigningKeyError", "StatusText", "SystemStatus", "TelemetrySnapshot", "TelemetryState",
    "TimeSync", "TimesyncUpdate", "VehicleHeartbeat", "VehicleLink", "Verdict",
    "WireMissionItem",
    "build_attitude_target", "build_position_target", "build_rates_target",
    "build_rover_velocity_target", "build_setpoint", "custom_mode_of", "decode_custom_mode",
    "decode_param_value", "encode_custom_mode", "encode_param_value",
    "flight_mode_from_custom_mode", "item_from_msg", "item_to_msg", "load_signing_key",
    "parse_signing_key", "raw_frame", "result_name",
]
