"""asyncio layer of the companion: transports, fixed-rate streamer, .tlog, ``Vehicle`` façade."""

from companion.mission import MissionError

from .errors import (
    CommandError,
    ConnectTimeoutError,
    LinkLostError,
    MissionTransferError,
    ModeChangeError,
    OffboardError,
    OffboardExitedError,
    ParamReadError,
    SetpointSourceError,
    TelemetryStaleError,
    VehicleError,
)
from .sources import SetpointSource, TrajectoryPositionSource, hold_setpoint
from .streamer import FixedRateStreamer, StreamStats
from .tlog import TlogWriter
from .transports import Endpoint, Transport, TransportError, open_transport, parse_url
from .vehicle import FlightReport, MissionAPI, Vehicle, VehicleConfig, safe_exit

__all__ = [
    "CommandError", "ConnectTimeoutError", "Endpoint", "FixedRateStreamer", "FlightReport",
    "LinkLostError", "MissionAPI", "MissionError", "MissionTransferError", "ModeChangeError",
    "OffboardError", "OffboardExitedError", "ParamReadError", "SetpointSource",
    "SetpointSourceError", "StreamStats", "TelemetryStaleError", "TlogWriter",
    "TrajectoryPositionSource", "Transport", "TransportError", "Vehicle", "VehicleConfig",
    "VehicleError", "hold_setpoint", "open_transport", "parse_url", "safe_exit",
]
