"""Checks shared by every conversion into the mission model (``.plan``, QGC WPL, downloaded
MISSION_ITEM_INTs): PX4's ranges, item-level validation, DO_JUMP resolution and the final
:class:`Mission`. Every problem raises :class:`MissionError` naming the source and the item."""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from companion.mission.errors import MissionError
from companion.mission.geodesy import GeoPoint, geodetic_to_ned
from companion.mission.geofence import Geofence
from companion.mission.model import (
    CMD_DO_CHANGE_SPEED,
    CMD_DO_JUMP,
    CMD_LAND,
    CMD_LOITER_TIME,
    CMD_LOITER_UNLIM,
    CMD_NAV_DELAY,
    CMD_TAKEOFF,
    CMD_VTOL_LAND,
    CMD_VTOL_TAKEOFF,
    CMD_WAYPOINT,
    FRAME_MISSION,
    FRAMES_AMSL,
    FRAMES_GLOBAL,
    FRAMES_RELATIVE,
    FRAMES_TERRAIN,
    OTHER_COMMANDS,
    POSITION_COMMANDS,
    Mission,
    MissionItem,
    RallyPoint,
    command_name,
    frame_name,
)

__all__ = [
    "FLOAT32_MAX",
    "HOME_ALT_RANGE_M",
    "MAX_ACCEPT_RADIUS_M",
    "MAX_HEIGHT_M",
    "MAX_HOLD_S",
    "MAX_RANGE_M",
    "MAX_SPEED_M_S",
    "as_float",
    "as_int",
    "check_home",
    "check_latlon",
    "finish_mission",
    "is_num",
    "ne_of",
    "resolve_jumps",
    "show_value",
    "validate_item",
]

_log = logging.getLogger("companion.mission")

FLOAT32_MAX = 3.4028234663852886e38
"""Largest float32: mission item parameters travel as float32 (MISSION_ITEM_INT)."""
MAX_RANGE_M = 100_000.0
"""Positions farther than this from home are rejected (usually swapped lat/lon or a wrong home);
PX4's MIS_DIST_1WP allows at most 100 km too."""
MAX_HEIGHT_M = 10_000.0
"""Largest altitude above or below home [m]: the maximum of PX4's GF_MAX_VER_DIST."""
HOME_ALT_RANGE_M = (-1_000.0, 10_000.0)
"""Accepted home altitudes AMSL [m] (below the Dead Sea shore to above Everest)."""
MAX_SPEED_M_S = 40.0
"""Largest DO_CHANGE_SPEED [m/s]: the maximum of PX4's GND_SPEED_MAX (rover); a multicopter's
MPC_XY_VEL_MAX tops out at 20 m/s and the planner caps the speed at the vehicle's limit."""
MAX_ACCEPT_RADIUS_M = 200.0
"""Largest waypoint acceptance radius [m]: the maximum of PX4's NAV_ACC_RAD."""
MAX_HOLD_S = 3_600.0
"""Longest hold / loiter time of one item [s]. PX4 has no limit of its own (a float32); an hour
is beyond any multicopter's endurance, and a longer hold would stall a replay."""

_POSITION_OPTIONAL = frozenset(
    {CMD_LOITER_UNLIM, CMD_LOITER_TIME, CMD_LAND, CMD_TAKEOFF, CMD_VTOL_TAKEOFF, CMD_VTOL_LAND}
)
"""Lat/lon may be NaN or (0, 0): "at the current position"."""
_UNSUPPORTED_POSITIONAL = frozenset({18, 30, 31, 80, 82, 94, 201})
"""NAV commands (and the deprecated DO_SET_ROI) that always move or point the vehicle."""
_MAX_REPEAT = 65_535

Params7 = tuple[float, float, float, float, float, float, float]


# ------------------------------------------------------------------------------- value helpers
def is_num(x: Any) -> bool:
    """A JSON number (int or float, not bool)."""
    return isinstance(x, int | float) and not isinstance(x, bool)


def as_int(x: Any, what: str, fail: Callable[[str], MissionError], lo: int, hi: int) -> int:
    """``x`` as an integer in ``lo..hi``, else ``fail(reason)`` is raised."""
    if isinstance(x, bool) or not is_num(x):
        raise fail(f"{what} must be an integer, got {show_value(x)}")
    try:
        f = float(x)
    except OverflowError:
        raise fail(f"{what} {show_value(x)} out of range {lo}..{hi}") from None
    if not math.isfinite(f) or not f.is_integer():
        raise fail(f"{what} must be an integer, got {show_value(x)}")
    v = int(f)
    if not lo <= v <= hi:
        raise fail(f"{what} {v} out of range {lo}..{hi}")
    return v


def as_float(x: Any, what: str, fail: Callable[[str], MissionError], *, nullable: bool) -> float:
    """``x`` as a float (``None`` -> NaN if ``nullable``), else ``fail(reason)`` is raised."""
    if x is None and nullable:
        return math.nan
    if not is_num(x):
        raise fail(f"{what} must be a number{' or null' if nullable else ''}, got {show_value(x)}")
    try:
        return float(x)
    except OverflowError:
        raise fail(f"{what} is too large: {show_value(x)}") from None


def show_value(x: Any) -> str:
    """``x`` for an error message (JSON-like, at most 40 characters)."""
    s = json.dumps(x) if isinstance(x, str | bool) or x is None else repr(x)
    return s if len(s) <= 40 else s[:37] + "..."


def check_latlon(
    lat: float, lon: float, home: GeoPoint, what: str, fail: Callable[[str], MissionError]
) -> None:
    """Latitude/longitude [deg] finite, in range and within :data:`MAX_RANGE_M` of ``home``."""
    if not (math.isfinite(lat) and math.isfinite(lon)):
        raise fail(f"{what} latitude/longitude must be finite numbers")
    if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
        raise fail(f"{what} latitude {lat} / longitude {lon} out of range")
    ne = geodetic_to_ned(lat, lon, home.alt_amsl_m, home)
    dist = float(np.hypot(ne[0], ne[1]))  # NaN exactly opposite home: rejected too
    if not dist <= MAX_RANGE_M:
        far = f"{dist / 1000.0:.1f} km" if math.isfinite(dist) else "about 20000 km"
        raise fail(
            f"{what} is {far} from home ({home.lat_deg:.6f}, {home.lon_deg:.6f}); "
            "check the latitude/longitude order and the home position"
        )


def ne_of(lat: float, lon: float, home: GeoPoint) -> tuple[float, float]:
    """North/east [m] of latitude/longitude [deg] about ``home`` (PX4's projection)."""
    p = geodetic_to_ned(lat, lon, home.alt_amsl_m, home)
    return float(p[0]), float(p[1])

# ------------------------------------------------------------------------- item-level validation
def validate_item(it: MissionItem, home: GeoPoint, src: Path, where: str = "") -> bool:
    """Reject items the companion cannot fly; True for an unknown non-position item (skipped)."""
    suffix = f" ({where})" if where else ""

    def fail(msg: str) -> MissionError:
        return MissionError(src, msg + suffix, item=it.index)

    cmd, frame = it.command, it.frame
    name = command_name(cmd)
    if any(math.isinf(v) for v in it.params):
        raise fail(f"{name}: parameters must be finite (NaN/null means 'not set')")
    known = cmd in POSITION_COMMANDS or cmd in OTHER_COMMANDS
    if not known:
        positional = cmd in _UNSUPPORTED_POSITIONAL or (frame in FRAMES_GLOBAL and it.has_latlon)
        if positional:
            raise fail(
                f"command {cmd} ({name}) is not supported and carries a position; "
                "replace it with a waypoint (16) or remove it"
            )
        return True
    if cmd in POSITION_COMMANDS:
        if frame in FRAMES_TERRAIN:
            raise fail(
                f"frame {frame} (terrain) needs terrain data, which the companion does not have; "
                "use a relative-altitude (3) or AMSL (0) frame"
            )
        if frame == FRAME_MISSION:
            raise fail(f"{name} in frame 2 (MISSION) has no position; use frame 3 or 0")
        if frame not in FRAMES_AMSL | FRAMES_RELATIVE:
            raise fail(
                f"frame {frame} ({frame_name(frame)}) is not supported for {name}; "
                "use 0/5 (AMSL) or 3/6 (relative to home)"
            )
        if it.has_latlon or cmd not in _POSITION_OPTIONAL:
            if not it.has_latlon:
                raise fail(f"{name} needs a latitude and longitude")
            check_latlon(it.lat_deg, it.lon_deg, home, name, fail)
        if cmd == CMD_WAYPOINT and not math.isfinite(it.alt_m):
            raise fail("NAV_WAYPOINT needs an altitude")
        height = it.alt_rel_home_m(home)
        if math.isfinite(height) and abs(height) > MAX_HEIGHT_M:
            raise fail(
                f"{name}: altitude {it.alt_m:g} m is {height:g} m from home's altitude; PX4 "
                f"allows at most {MAX_HEIGHT_M:g} m (GF_MAX_VER_DIST); check the frame "
                "(0 AMSL, 3 relative)"
            )
        hold = it.params[0]
        if cmd in (CMD_WAYPOINT, CMD_LOITER_TIME) and math.isfinite(hold):
            if hold < 0:
                raise fail(f"{name}: hold time {it.params[0]} s must not be negative")
            if hold > MAX_HOLD_S:
                raise fail(f"{name}: hold time {hold:g} s exceeds {MAX_HOLD_S:g} s")
        radius = it.params[1]
        if cmd == CMD_WAYPOINT and math.isfinite(radius):
            if radius < 0:
                raise fail(f"NAV_WAYPOINT: acceptance radius {radius} m must not be negative")
            if radius > MAX_ACCEPT_RADIUS_M:
                raise fail(
                    f"NAV_WAYPOINT: acceptance radius {radius:g} m exceeds PX4's largest "
                    f"NAV_ACC_RAD, {MAX_ACCEPT_RADIUS_M:g} m"
                )
    elif cmd == CMD_DO_CHANGE_SPEED:
        speed = it.params[1]
        if math.isfinite(speed) and speed > MAX_SPEED_M_S:
            raise fail(
                f"DO_CHANGE_SPEED: {speed:g} m/s exceeds PX4's largest speed limit, "
                f"{MAX_SPEED_M_S:g} m/s (GND_SPEED_MAX; multicopters MPC_XY_VEL_MAX <= 20 m/s)"
            )
    elif cmd == CMD_NAV_DELAY:
        delay = it.params[0]
        clock = [v for v in it.params[1:4] if math.isfinite(v) and v >= 0.0]
        if not (math.isfinite(delay) and delay >= 0.0) and clock:
            raise fail(
                "NAV_DELAY until a time of day (param2-4 hour/minute/second) is not supported: "
                "PX4 ignores the time of day and goes on at once; give the delay in seconds "
                "(param1)"
            )
        if math.isfinite(delay) and delay > MAX_HOLD_S:
            raise fail(f"NAV_DELAY: delay {delay:g} s exceeds {MAX_HOLD_S:g} s")
    elif cmd == CMD_DO_JUMP:
        rep = it.params[1]
        if not math.isfinite(rep) or not float(rep).is_integer():
            raise fail(f"DO_JUMP: repeat count must be an integer, got {rep}")
        if rep < 0:
            raise fail(
                f"DO_JUMP: repeat count {int(rep)} (repeat forever) cannot be flown; "
                "give a finite repeat count"
            )
        if rep > _MAX_REPEAT:
            raise fail(f"DO_JUMP: repeat count {int(rep)} exceeds {_MAX_REPEAT}")
    for k in (0, 1, 2, 3, 6):  # float32 on the wire (MISSION_ITEM_INT param1-4, z)
        if abs(it.params[k]) > FLOAT32_MAX:
            raise fail(f"{name}: param{k + 1} {it.params[k]:g} does not fit MAVLink's float32")
    return False


def resolve_jumps(items: list[MissionItem], src: Path, by_do_jump_id: bool) -> list[MissionItem]:
    """Rewrite DO_JUMP param1 to the target item's ``index`` (``.plan`` stores a doJumpId)."""
    indices = {it.index for it in items}
    jump_ids: dict[int, int] = {}
    for it in items:
        if it.do_jump_id is not None:
            jump_ids.setdefault(it.do_jump_id, it.index)
    out: list[MissionItem] = []
    for it in items:
        if it.command != CMD_DO_JUMP:
            out.append(it)
            continue
        t = it.params[0]
        if not math.isfinite(t) or not float(t).is_integer():
            raise MissionError(src, f"DO_JUMP: target must be an integer, got {t}", item=it.index)
        target = int(t)
        if by_do_jump_id:
            if target not in jump_ids:
                raise MissionError(
                    src, f"DO_JUMP: target doJumpId {target} not found", item=it.index
                )
            target_index = jump_ids[target]
        else:
            if target not in indices:
                raise MissionError(
                    src, f"DO_JUMP: target item {target} does not exist", item=it.index
                )
            target_index = target
        p = list(it.params)
        p[0] = float(target_index)
        out.append(_replace_params(it, p))
    return out


def _replace_params(it: MissionItem, p: Sequence[float]) -> MissionItem:
    params: Params7 = (p[0], p[1], p[2], p[3], p[4], p[5], p[6])
    return replace(it, params=params)


def finish_mission(
    src: Path,
    home: GeoPoint,
    items: list[MissionItem],
    *,
    by_do_jump_id: bool,
    wheres: dict[int, str],
    file_format: str,
    geofence: Geofence | None = None,
    rally: tuple[RallyPoint, ...] = (),
    vehicle_type: int | None = None,
    hover_speed_m_s: float | None = None,
    warnings: list[str] | None = None,
) -> Mission:
    """Validate ``items`` (unknown commands without a position: a warning), resolve DO_JUMP
    targets (``by_do_jump_id``: param1 is a ``.plan`` doJumpId, else an item ``index``) and build
    the :class:`Mission`. ``wheres``: index -> location shown in error messages."""
    warns = warnings if warnings is not None else []
    ignored: dict[int, list[int]] = {}
    for it in items:
        if validate_item(it, home, src, wheres.get(it.index, "")):
            ignored.setdefault(it.command, []).append(it.index)
    for cmd, idx in ignored.items():
        shown = ", ".join(str(i) for i in idx[:20]) + (", ..." if len(idx) > 20 else "")
        label = f"item {shown}" if len(idx) == 1 else f"items {shown}"
        msg = f"{src}: {label}: command {cmd} ({command_name(cmd)}) ignored (no position)"
        warns.append(msg)
        _log.warning(msg)
    items = resolve_jumps(items, src, by_do_jump_id)
    return Mission(
        source=src,
        home=home,
        items=tuple(items),
        geofence=geofence if geofence is not None else Geofence(),
        rally=rally,
        file_format=file_format,
        vehicle_type=vehicle_type,
        hover_speed_m_s=hover_speed_m_s,
        warnings=tuple(warns),
    )


def check_home(home: GeoPoint, src: Path, what: str) -> GeoPoint:
    """``home`` if finite and within range, else :class:`MissionError` naming ``what``."""
    def fail(msg: str) -> MissionError:
        return MissionError(src, msg)

    if not (math.isfinite(home.lat_deg) and math.isfinite(home.lon_deg)):
        raise fail(f"{what}: latitude/longitude must be finite numbers")
    if not (-90.0 <= home.lat_deg <= 90.0 and -180.0 <= home.lon_deg <= 180.0):
        raise fail(f"{what}: latitude {home.lat_deg} / longitude {home.lon_deg} out of range")
    if not math.isfinite(home.alt_amsl_m):
        raise fail(f"{what}: altitude must be a finite number")
    lo, hi = HOME_ALT_RANGE_M
    if not lo <= home.alt_amsl_m <= hi:
        raise fail(f"{what}: altitude {home.alt_amsl_m:g} m AMSL out of range {lo:g}..{hi:g} m")
    return home
