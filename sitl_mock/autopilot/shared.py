"""Values every autopilot component shares: identity, result codes, the clock, the state view.

`Clock.t` is simulated time since boot [s]; the core advances it and every component reads it
(nothing here reads a wall clock). `StateView` caches the vehicle's state snapshot once per
physics step.
"""

from __future__ import annotations

import math
from collections import Counter
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from sitl_mock.vehicle_state import Vehicle, VehicleState

Msg = Any  # a pymavlink message, or a telemetry (codec, fields) pair
Addr = Any  # (host, port) for UDP, anything hashable for in-memory links

SYSID = 1
COMPID = 1
RESULT_ACCEPTED: int = int(mavlink.MAV_RESULT_ACCEPTED)
RESULT_DENIED: int = int(mavlink.MAV_RESULT_DENIED)
RESULT_FAILED: int = int(mavlink.MAV_RESULT_FAILED)
RESULT_TEMPORARILY_REJECTED: int = int(mavlink.MAV_RESULT_TEMPORARILY_REJECTED)
RESULT_UNSUPPORTED: int = int(mavlink.MAV_RESULT_UNSUPPORTED)


class Clock:
    """Simulated time since boot [s] of the last processed event (advanced by the core only)."""

    __slots__ = ("t",)

    def __init__(self) -> None:
        self.t = 0.0

    @property
    def time_boot_ms(self) -> int:
        return int(self.t * 1000.0) & 0xFFFFFFFF

    @property
    def time_usec(self) -> int:
        return int(self.t * 1e6)

    @property
    def time_ns(self) -> int:
        return int(self.t * 1e9)


class StateView:
    """The vehicle and its state snapshot, fetched lazily once per physics step (`stale`)."""

    __slots__ = ("_cache", "stale", "vehicle")

    def __init__(self, vehicle: Vehicle) -> None:
        self.vehicle = vehicle
        self._cache: VehicleState = vehicle.state
        self.stale = False

    @property
    def state(self) -> VehicleState:
        """Vehicle state snapshot (the same object until the next physics step)."""
        if self.stale:
            self._cache = self.vehicle.state
            self.stale = False
        return self._cache


def finite(*vals: float) -> bool:
    """True if every value is finite."""
    return all(math.isfinite(v) for v in vals)


def addressed_to_us(stats: Counter[str], target_system: int, target_component: int) -> bool:
    """Addressed to us (or broadcast, 0); anything else is counted and ignored, like PX4."""
    ok = target_system in (0, SYSID) and target_component in (0, COMPID)
    if not ok:
        stats["rx_wrong_target"] += 1
    return bool(ok)
