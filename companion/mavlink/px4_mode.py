"""PX4 flight modes: ``custom_mode`` encoding of commander/px4_custom_mode.h.

``custom_mode = main_mode << 16 | sub_mode << 24``; ``base_mode`` flags are informative only
(clients decode the mode from ``custom_mode``).
"""

from __future__ import annotations

from enum import Enum, IntEnum

MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1
MAV_MODE_FLAG_SAFETY_ARMED = 128
MAV_AUTOPILOT_PX4 = 12


class Px4MainMode(IntEnum):
    """PX4 main modes (px4_custom_mode.h)."""

    MANUAL = 1
    ALTCTL = 2
    POSCTL = 3
    AUTO = 4
    ACRO = 5
    OFFBOARD = 6
    STABILIZED = 7


class Px4AutoSubMode(IntEnum):
    """PX4 AUTO sub modes (px4_custom_mode.h)."""

    READY = 1
    TAKEOFF = 2
    LOITER = 3
    MISSION = 4
    RTL = 5
    LAND = 6


class FlightMode(Enum):
    """User-facing PX4 flight mode; value = (main_mode, sub_mode)."""

    MANUAL = (1, 0)
    ALTCTL = (2, 0)
    POSCTL = (3, 0)
    ACRO = (5, 0)
    OFFBOARD = (6, 0)
    STABILIZED = (7, 0)
    READY = (4, 1)
    TAKEOFF = (4, 2)
    HOLD = (4, 3)
    MISSION = (4, 4)
    RTL = (4, 5)
    LAND = (4, 6)
    UNKNOWN = (0, 0)

    @property
    def main_mode(self) -> int:
        """PX4 main mode number."""
        return self.value[0]

    @property
    def sub_mode(self) -> int:
        """PX4 sub mode number (0 for modes without sub modes)."""
        return self.value[1]


def encode_custom_mode(main_mode: int, sub_mode: int = 0) -> int:
    """Pack PX4 main/sub mode into the 32-bit HEARTBEAT ``custom_mode``."""
    if not (0 <= main_mode <= 255 and 0 <= sub_mode <= 255):
        raise ValueError(f"PX4 mode numbers must be 0..255, got main {main_mode} sub {sub_mode}")
    return (main_mode << 16) | (sub_mode << 24)


def decode_custom_mode(custom_mode: int) -> tuple[int, int]:
    """Unpack HEARTBEAT ``custom_mode`` into (main_mode, sub_mode)."""
    return (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF


def flight_mode_from_custom_mode(custom_mode: int) -> FlightMode:
    """Map a PX4 ``custom_mode`` to a :class:`FlightMode` (UNKNOWN if not a known mode).

    Non-AUTO main modes ignore the sub mode (e.g. POSCTL sub modes ORBIT/SLOW -> POSCTL).
    """
    main, sub = decode_custom_mode(custom_mode)
    if main != Px4MainMode.AUTO:
        sub = 0
    for mode in FlightMode:
        if mode.value == (main, sub) and mode is not FlightMode.UNKNOWN:
            return mode
    return FlightMode.UNKNOWN


def custom_mode_of(mode: FlightMode) -> int:
    """HEARTBEAT ``custom_mode`` value for a :class:`FlightMode`."""
    if mode is FlightMode.UNKNOWN:
        raise ValueError("cannot encode FlightMode.UNKNOWN")
    return encode_custom_mode(mode.main_mode, mode.sub_mode)


def is_armed(base_mode: int) -> bool:
    """Armed flag of HEARTBEAT ``base_mode`` (MAV_MODE_FLAG_SAFETY_ARMED)."""
    return bool(base_mode & MAV_MODE_FLAG_SAFETY_ARMED)


def set_mode_params(mode: FlightMode, armed: bool) -> tuple[float, float, float]:
    """MAV_CMD_DO_SET_MODE param1..3 for ``mode`` (param1 = CUSTOM_MODE_ENABLED | 128 if armed)."""
    if mode is FlightMode.UNKNOWN:
        raise ValueError("cannot request FlightMode.UNKNOWN")
    base = MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (MAV_MODE_FLAG_SAFETY_ARMED if armed else 0)
    return float(base), float(mode.main_mode), float(mode.sub_mode)
