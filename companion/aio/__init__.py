"""asyncio layer of the companion: transports, fixed-rate streamer, .tlog, ``Vehicle`` façade.

The names below are imported on first use (PEP 562): `companion.aio.tlog` (the replay's log
writer) does not pay for asyncio, the transports and the ``Vehicle`` façade."""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from companion.mission import MissionError

    from .base import VehicleBase, VehicleConfig
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
    from .exits import safe_exit
    from .mission import MissionAPI
    from .sources import SetpointSource, TrajectoryPositionSource, hold_setpoint
    from .streamer import FixedRateStreamer, StreamStats
    from .tlog import TlogWriter
    from .transports import Endpoint, Transport, TransportError, open_transport, parse_url
    from .vehicle import FlightReport, Vehicle

#: public name -> the module that defines it
_WHERE = {
    "MissionError": "companion.mission",
    **dict.fromkeys(("VehicleBase", "VehicleConfig"), ".base"),
    **dict.fromkeys((
        "CommandError", "ConnectTimeoutError", "LinkLostError", "MissionTransferError",
        "ModeChangeError", "OffboardError", "OffboardExitedError", "ParamReadError",
        "SetpointSourceError", "TelemetryStaleError", "VehicleError"), ".errors"),
    "safe_exit": ".exits",
    "MissionAPI": ".mission",
    **dict.fromkeys(("SetpointSource", "TrajectoryPositionSource", "hold_setpoint"), ".sources"),
    **dict.fromkeys(("FixedRateStreamer", "StreamStats"), ".streamer"),
    "TlogWriter": ".tlog",
    **dict.fromkeys(("Endpoint", "Transport", "TransportError", "open_transport", "parse_url"),
                    ".transports"),
    **dict.fromkeys(("FlightReport", "Vehicle"), ".vehicle"),
}


def __getattr__(name: str) -> Any:
    where = _WHERE.get(name)
    if where is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(where, __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_WHERE})


__all__ = [
    "CommandError", "ConnectTimeoutError", "Endpoint", "FixedRateStreamer", "FlightReport",
    "LinkLostError", "MissionAPI", "MissionError", "MissionTransferError", "ModeChangeError",
    "OffboardError", "OffboardExitedError", "ParamReadError", "SetpointSource",
    "SetpointSourceError", "StreamStats", "TelemetryStaleError", "TlogWriter",
    "TrajectoryPositionSource", "Transport", "TransportError", "Vehicle", "VehicleBase",
    "VehicleConfig", "VehicleError", "hold_setpoint", "open_transport", "parse_url", "safe_exit",
]
