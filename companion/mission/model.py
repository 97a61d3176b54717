"""Mission data model: the frozen values every conversion produces or consumes (files, the
vehicle's MISSION_ITEM_INTs: see :mod:`companion.mission.convert`), command and frame numbers."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from companion.mission.geodesy import GeoPoint
from companion.mission.geofence import Geofence

__all__ = [
    "CMD_DO_CHANGE_SPEED",
    "CMD_DO_JUMP",
    "CMD_DO_SET_ROI_LOCATION",
    "CMD_DO_SET_ROI_NONE",
    "CMD_LAND",
    "CMD_LOITER_TIME",
    "CMD_LOITER_UNLIM",
    "CMD_NAV_DELAY",
    "CMD_RETURN_TO_LAUNCH",
    "CMD_TAKEOFF",
    "CMD_VTOL_LAND",
    "CMD_VTOL_TAKEOFF",
    "CMD_WAYPOINT",
    "FRAMES_AMSL",
    "FRAMES_GLOBAL",
    "FRAMES_RELATIVE",
    "FRAMES_TERRAIN",
    "FRAME_MISSION",
    "OTHER_COMMANDS",
    "POSITION_COMMANDS",
    "Mission",
    "MissionItem",
    "RallyPoint",
    "command_name",
    "frame_name",
]

# MAV_CMD values handled by the companion
CMD_WAYPOINT = 16
CMD_LOITER_UNLIM = 17
CMD_LOITER_TIME = 19
CMD_RETURN_TO_LAUNCH = 20
CMD_LAND = 21
CMD_TAKEOFF = 22
CMD_VTOL_TAKEOFF = 84
CMD_VTOL_LAND = 85
CMD_NAV_DELAY = 93
CMD_DO_JUMP = 177
CMD_DO_CHANGE_SPEED = 178
CMD_DO_SET_ROI_LOCATION = 195
CMD_DO_SET_ROI_NONE = 197

# MAV_FRAME groups
FRAMES_AMSL = frozenset({0, 5})
FRAMES_RELATIVE = frozenset({3, 6})
FRAMES_TERRAIN = frozenset({10, 11})
FRAME_MISSION = 2
FRAMES_GLOBAL = FRAMES_AMSL | FRAMES_RELATIVE | FRAMES_TERRAIN
"""Frames whose x/y are latitude/longitude (MISSION_ITEM_INT: degE7)."""

POSITION_COMMANDS = frozenset(
    {
        CMD_WAYPOINT,
        CMD_LOITER_UNLIM,
        CMD_LOITER_TIME,
        CMD_LAND,
        CMD_TAKEOFF,
        CMD_VTOL_TAKEOFF,
        CMD_VTOL_LAND,
        CMD_DO_SET_ROI_LOCATION,
    }
)
"""Supported commands that carry a position (need a global frame). A multicopter flies VTOL
takeoff/land (84/85) as takeoff/land, as PX4 does on a vehicle without a fixed-wing mode."""
OTHER_COMMANDS = frozenset(
    {CMD_RETURN_TO_LAUNCH, CMD_DO_JUMP, CMD_DO_CHANGE_SPEED, CMD_DO_SET_ROI_NONE, CMD_NAV_DELAY}
)
"""Supported commands without a position (frame ignored)."""

_FRAME_NAMES = {
    0: "GLOBAL (AMSL)",
    1: "LOCAL_NED",
    2: "MISSION",
    3: "GLOBAL_RELATIVE_ALT",
    4: "LOCAL_ENU",
    5: "GLOBAL_INT (AMSL)",
    6: "GLOBAL_RELATIVE_ALT_INT",
    7: "LOCAL_OFFSET_NED",
    8: "BODY_NED",
    9: "BODY_OFFSET_NED",
    10: "GLOBAL_TERRAIN_ALT (terrain)",
    11: "GLOBAL_TERRAIN_ALT_INT (terrain)",
    12: "BODY_FRD",
}

_COMMAND_NAMES = {
    CMD_WAYPOINT: "NAV_WAYPOINT",
    CMD_LOITER_UNLIM: "NAV_LOITER_UNLIM",
    CMD_LOITER_TIME: "NAV_LOITER_TIME",
    CMD_RETURN_TO_LAUNCH: "NAV_RETURN_TO_LAUNCH",
    CMD_LAND: "NAV_LAND",
    CMD_TAKEOFF: "NAV_TAKEOFF",
    CMD_VTOL_TAKEOFF: "NAV_VTOL_TAKEOFF",
    CMD_VTOL_LAND: "NAV_VTOL_LAND",
    CMD_NAV_DELAY: "NAV_DELAY",
    CMD_DO_JUMP: "DO_JUMP",
    CMD_DO_CHANGE_SPEED: "DO_CHANGE_SPEED",
    CMD_DO_SET_ROI_LOCATION: "DO_SET_ROI_LOCATION",
    CMD_DO_SET_ROI_NONE: "DO_SET_ROI_NONE",
}


def command_name(command: int) -> str:
    """MAV_CMD name without the ``MAV_CMD_`` prefix, or ``"unknown"``."""
    if command in _COMMAND_NAMES:
        return _COMMAND_NAMES[command]
    try:
        from pymavlink.dialects.v20 import common as mavlink_common

        entry = mavlink_common.enums["MAV_CMD"].get(command)
        if entry is not None and not str(entry.name).endswith("ENUM_END"):
            return str(entry.name).removeprefix("MAV_CMD_")
    except Exception:  # pragma: no cover - pymavlink is a hard dependency; names are cosmetic
        pass
    return "unknown"


def frame_name(frame: int) -> str:
    """MAV_FRAME name (short), or ``"unknown"``."""
    return _FRAME_NAMES.get(frame, "unknown")


@dataclass(frozen=True)
class MissionItem:
    """One MAVLink mission item of a :class:`Mission`, as written in the file or downloaded (the
    one mission-item model; ``companion.mavlink.WireMissionItem`` is the raw MISSION_ITEM_INT).

    ``index`` is the item number as in the file: for ``.plan`` the QGroundControl sequence number
    (1-based; home is 0; items of a complex item are numbered consecutively), for ``QGC WPL`` the
    INDEX column, for a downloaded mission ``seq + 1`` (as QGroundControl numbers it).
    ``params`` are param1..param4, x (latitude deg), y (longitude deg), z (altitude m);
    ``null``/missing values are NaN. ``where`` locates the item in the file (JSON path or line)
    or on the wire (``seq N``).
    """

    index: int
    command: int
    frame: int
    params: tuple[float, float, float, float, float, float, float]
    autocontinue: bool = True
    current: bool = False
    do_jump_id: int | None = None
    altitude_mode: int | None = None
    complex_type: str | None = None
    where: str = ""

    @property
    def lat_deg(self) -> float:
        return self.params[4]

    @property
    def lon_deg(self) -> float:
        return self.params[5]

    @property
    def alt_m(self) -> float:
        """Altitude [m] in this item's frame (AMSL or relative to home)."""
        return self.params[6]

    @property
    def has_latlon(self) -> bool:
        """True if latitude and longitude are finite and not the (0, 0) "unset" convention."""
        lat, lon = self.lat_deg, self.lon_deg
        return math.isfinite(lat) and math.isfinite(lon) and not (lat == 0.0 and lon == 0.0)

    def alt_rel_home_m(self, home: GeoPoint) -> float:
        """Altitude above home [m] (NaN if not given or the frame has no altitude)."""
        if self.frame in FRAMES_AMSL:
            return self.alt_m - home.alt_amsl_m
        if self.frame in FRAMES_RELATIVE:
            return self.alt_m
        return math.nan


@dataclass(frozen=True)
class RallyPoint:
    """A rally (safe) point: latitude/longitude [deg], altitude above home [m], local NED [m]."""

    lat_deg: float
    lon_deg: float
    alt_rel_home_m: float
    pos_ned_m: tuple[float, float, float]


@dataclass(frozen=True)
class Mission:
    """A loaded mission file (items as written; see ``mission_to_flight_plan`` to fly it)."""

    source: Path
    home: GeoPoint
    items: tuple[MissionItem, ...]
    geofence: Geofence = field(default_factory=Geofence)
    rally: tuple[RallyPoint, ...] = ()
    file_format: str = "plan"
    """``"plan"`` (QGroundControl JSON), ``"wpl"`` (QGC WPL 110 text) or ``"wire"`` (downloaded
    MISSION_ITEM_INTs)."""
    vehicle_type: int | None = None
    """MAV_TYPE from the ``.plan`` (2 quadrotor, 10 ground rover), None if not given."""
    hover_speed_m_s: float | None = None
    """QGC's planning speed for multicopters (informational: PX4 flies at MPC_XY_CRUISE)."""
    warnings: tuple[str, ...] = ()
