"""Loaders for QGroundControl ``.plan`` (JSON) and ``QGC WPL 110`` (text) mission files.

Every problem with the input raises :class:`MissionError` naming the file and, where it applies,
the item; nothing else escapes (JSON/UTF-8/number-format errors are translated).
"""

from __future__ import annotations

import json
import logging
import math
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from companion.mission.geodesy import GeoPoint, geodetic_to_ned
from companion.mission.geofence import FenceCircle, FencePolygon, Geofence
from companion.mission.model import (
    CMD_DO_CHANGE_SPEED,
    CMD_DO_JUMP,
    CMD_DO_SET_ROI_LOCATION,
    CMD_DO_SET_ROI_NONE,
    CMD_LAND,
    CMD_LOITER_TIME,
    CMD_LOITER_UNLIM,
    CMD_NAV_DELAY,
    CMD_RETURN_TO_LAUNCH,
    CMD_TAKEOFF,
    CMD_VTOL_LAND,
    CMD_VTOL_TAKEOFF,
    CMD_WAYPOINT,
    FRAME_MISSION,
    FRAMES_AMSL,
    FRAMES_RELATIVE,
    FRAMES_TERRAIN,
    Mission,
    MissionError,
    MissionItem,
    RallyPoint,
    command_name,
    frame_name,
)

__all__ = [
    "MAX_ACCEPT_RADIUS_M",
    "MAX_HEIGHT_M",
    "MAX_HOLD_S",
    "MAX_RANGE_M",
    "MAX_SPEED_M_S",
    "load_mission", "loads_mission", "parse_plan", "parse_wpl"]

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
_POSITION_OPTIONAL = frozenset(
    {CMD_LOITER_UNLIM, CMD_LOITER_TIME, CMD_LAND, CMD_TAKEOFF, CMD_VTOL_TAKEOFF, CMD_VTOL_LAND}
)
"""Lat/lon may be NaN or (0, 0): "at the current position"."""
_UNSUPPORTED_POSITIONAL = frozenset({18, 30, 31, 80, 82, 94, 201})
"""NAV commands (and the deprecated DO_SET_ROI) that always move or point the vehicle."""
_GLOBAL_FRAMES = FRAMES_AMSL | FRAMES_RELATIVE | FRAMES_TERRAIN
_MAX_REPEAT = 65_535

Params7 = tuple[float, float, float, float, float, float, float]


# ----------------------------------------------------------------------------------- entry points
def load_mission(path: str | os.PathLike[str], *, home: GeoPoint | None = None) -> Mission:
    """Load a ``.plan`` or ``QGC WPL 110`` file (format detected from the content).

    ``home`` overrides the file's home (``plannedHomePosition`` / WPL line 0); it is required
    when the file has none. Raises :class:`MissionError` for any problem, including I/O errors.
    """
    p = Path(path)
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise MissionError(p, f"cannot read the file: {exc.strerror or exc}") from None
    return loads_mission(data, source=p, home=home)


def loads_mission(
    data: str | bytes, *, source: str | os.PathLike[str] = "<string>", home: GeoPoint | None = None
) -> Mission:
    """Parse mission text or bytes (``.plan`` JSON or ``QGC WPL``, detected from the content)."""
    src = Path(source)
    if isinstance(data, bytes):
        try:
            text = data.decode("utf-8-sig")
        except UnicodeDecodeError as exc:
            raise MissionError(src, f"not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    else:
        text = data.removeprefix("\ufeff")
    head = text.lstrip()
    if not head:
        raise MissionError(src, "the file is empty")
    if head.startswith("QGC WPL"):
        return parse_wpl(text, source=src, home=home)
    if head.startswith("{") or src.suffix.lower() == ".plan":
        return parse_plan(text, source=src, home=home)
    raise MissionError(
        src, 'not a mission file: expected a QGroundControl .plan (JSON) or "QGC WPL 110" text'
    )


# ------------------------------------------------------------------------------- value helpers
def _is_num(x: Any) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool)


def _as_int(x: Any, what: str, fail: Callable[[str], MissionError], lo: int, hi: int) -> int:
    if isinstance(x, bool) or not _is_num(x):
        raise fail(f"{what} must be an integer, got {_show(x)}")
    try:
        f = float(x)
    except OverflowError:
        raise fail(f"{what} {_show(x)} out of range {lo}..{hi}") from None
    if not math.isfinite(f) or not f.is_integer():
        raise fail(f"{what} must be an integer, got {_show(x)}")
    v = int(f)
    if not lo <= v <= hi:
        raise fail(f"{what} {v} out of range {lo}..{hi}")
    return v


def _as_float(x: Any, what: str, fail: Callable[[str], MissionError], *, nullable: bool) -> float:
    if x is None and nullable:
        return math.nan
    if not _is_num(x):
        raise fail(f"{what} must be a number{' or null' if nullable else ''}, got {_show(x)}")
    try:
        return float(x)
    except OverflowError:
        raise fail(f"{what} is too large: {_show(x)}") from None


def _show(x: Any) -> str:
    s = json.dumps(x) if isinstance(x, str | bool) or x is None else repr(x)
    return s if len(s) <= 40 else s[:37] + "..."


def _latlon_check(
    lat: float, lon: float, home: GeoPoint, what: str, fail: Callable[[str], MissionError]
) -> None:
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


def _ne(lat: float, lon: float, home: GeoPoint) -> tuple[float, float]:
    p = geodetic_to_ned(lat, lon, home.alt_amsl_m, home)
    return float(p[0]), float(p[1])


# ------------------------------------------------------------------------- item-level validation
def _validate_item(it: MissionItem, home: GeoPoint, src: Path, where: str = "") -> bool:
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
        positional = cmd in _UNSUPPORTED_POSITIONAL or (frame in _GLOBAL_FRAMES and it.has_latlon)
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
            _latlon_check(it.lat_deg, it.lon_deg, home, name, fail)
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


def _resolve_jumps(items: list[MissionItem], src: Path, by_do_jump_id: bool) -> list[MissionItem]:
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
    from dataclasses import replace

    params: Params7 = (p[0], p[1], p[2], p[3], p[4], p[5], p[6])
    return replace(it, params=params)


def _finish(
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
    warns = warnings if warnings is not None else []
    ignored: dict[int, list[int]] = {}
    for it in items:
        if _validate_item(it, home, src, wheres.get(it.index, "")):
            ignored.setdefault(it.command, []).append(it.index)
    for cmd, idx in ignored.items():
        shown = ", ".join(str(i) for i in idx[:20]) + (", ..." if len(idx) > 20 else "")
        label = f"item {shown}" if len(idx) == 1 else f"items {shown}"
        msg = f"{src}: {label}: command {cmd} ({command_name(cmd)}) ignored (no position)"
        warns.append(msg)
        _log.warning(msg)
    items = _resolve_jumps(items, src, by_do_jump_id)
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


def _home_check(home: GeoPoint, src: Path, what: str) -> GeoPoint:
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


# ---------------------------------------------------------------------------------------- .plan
def parse_plan(
    text: str, *, source: str | os.PathLike[str] = "<string>", home: GeoPoint | None = None
) -> Mission:
    """Parse a QGroundControl ``.plan`` (fileType "Plan", version 1, mission version 2)."""
    src = Path(source)

    def fail(msg: str, item: int | None = None) -> MissionError:
        return MissionError(src, msg, item=item)

    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise fail(f"not valid JSON: {exc.msg} at line {exc.lineno} column {exc.colno}") from None
    except (RecursionError, ValueError) as exc:
        raise fail(f"not valid JSON: {exc}") from None
    if not isinstance(doc, dict):
        raise fail("not a QGroundControl plan: the top level must be a JSON object")
    if doc.get("fileType") != "Plan":
        raise fail(f'fileType is {_show(doc.get("fileType"))}, expected "Plan"')
    if doc.get("version") != 1 or isinstance(doc.get("version"), bool):
        raise fail(f"plan version {_show(doc.get('version'))} is not supported (expected 1)")
    mission = doc.get("mission")
    if not isinstance(mission, dict):
        raise fail('"mission" must be an object')
    mver = mission.get("version")
    if mver != 2 or isinstance(mver, bool):
        raise fail(f"mission version {_show(mver)} is not supported (expected 2)")

    file_home = _plan_home(mission.get("plannedHomePosition"), fail)
    if home is None:
        if file_home is None:
            raise fail("no plannedHomePosition; give the home position explicitly")
        home = file_home
    home = _home_check(home, src, "home position")

    raw_items = mission.get("items")
    if not isinstance(raw_items, list):
        raise fail('"mission.items" must be a list')
    items: list[MissionItem] = []
    wheres: dict[int, str] = {}
    seq = 1
    for k, raw in enumerate(raw_items):
        where = f"mission.items[{k}]"
        if not isinstance(raw, dict):
            raise fail(f"{where} must be an object", item=seq)
        kind = raw.get("type", "SimpleItem")
        if kind == "SimpleItem":
            items.append(_plan_simple(raw, seq, where, None, fail))
            seq += 1
        elif kind == "ComplexItem":
            ctype = raw.get("complexItemType")
            if ctype not in ("survey", "CorridorScan", "StructureScan"):
                raise fail(f"complex item type {_show(ctype)} is not supported", item=seq)
            _complex_version_check(raw, str(ctype), where, seq, fail)
            sub = raw.get("Items")
            tsci = raw.get("TransectStyleComplexItem")
            sub_where = f"{where}.Items"
            if sub is None and isinstance(tsci, dict):
                sub = tsci.get("Items")
                sub_where = f"{where}.TransectStyleComplexItem.Items"
            if not isinstance(sub, list) or not sub:
                raise fail(
                    f"{ctype} has no pre-expanded items (TransectStyleComplexItem.Items); "
                    "QGroundControl regenerates them on load: convert the pattern to "
                    "waypoints or save the mission as QGC WPL from QGroundControl",
                    item=seq,
                )
            for j, s in enumerate(sub):
                w = f"{sub_where}[{j}]"
                if not isinstance(s, dict):
                    raise fail(f"{w} must be an object", item=seq)
                items.append(_plan_simple(s, seq, w, str(ctype), fail))
                wheres[seq] = f"in {ctype} {where}"
                seq += 1
        else:
            raise fail(f"{where}: unknown item type {_show(kind)}", item=seq)

    vtype = mission.get("vehicleType")
    hover = mission.get("hoverSpeed")
    geofence = _plan_geofence(doc.get("geoFence"), home, fail)
    rally = _plan_rally(doc.get("rallyPoints"), home, fail)
    return _finish(
        src,
        home,
        items,
        by_do_jump_id=True,
        wheres=wheres,
        file_format="plan",
        geofence=geofence,
        rally=rally,
        vehicle_type=vtype if isinstance(vtype, int) and not isinstance(vtype, bool) else None,
        hover_speed_m_s=_opt_speed(hover),
    )


#: Complex item versions QGroundControl loads (src/MissionManager/SurveyComplexItem.cc,
#: CorridorScanComplexItem.cc, StructureScanComplexItem.cc); any other is refused there.
_COMPLEX_VERSIONS: dict[str, tuple[int, ...]] = {
    "survey": (2, 3, 4, 5),
    "CorridorScan": (2,),
    "StructureScan": (3,),
}
#: TransectStyleComplexItem (inside survey v4/v5 and CorridorScan) versions QGroundControl
#: loads: missing or 0 means 1, which it upgrades to 2 (TransectStyleComplexItem.cc).
_TRANSECT_VERSIONS = (0, 1, 2)


def _complex_version_check(
    raw: dict[str, Any], ctype: str, where: str, seq: int, fail: Callable[..., MissionError]
) -> None:
    """Refuse a complex item (and its TransectStyleComplexItem) of a version QGroundControl
    refuses to load: its meaning (and its pre-expanded items) cannot be trusted."""
    accepted = _COMPLEX_VERSIONS[ctype]
    shown = ", ".join(str(v) for v in accepted)
    ver = raw.get("version")
    if ver is None:
        raise fail(
            f"{ctype} ({where}) has no version; QGroundControl loads {ctype} version {shown} "
            "only", item=seq,
        )
    if isinstance(ver, bool) or not _is_num(ver) or not float(ver).is_integer() or int(
            ver) not in accepted:
        raise fail(
            f"{ctype} ({where}) version {_show(ver)} is not supported: QGroundControl loads "
            f"{ctype} version {shown} only (and MAVSDK survey version 5 only); re-save the "
            "plan in QGroundControl", item=seq,
        )
    tsci = raw.get("TransectStyleComplexItem")
    if isinstance(tsci, dict):
        tver = tsci.get("version", 0)
        if isinstance(tver, bool) or not _is_num(tver) or not float(tver).is_integer() or int(
                tver) not in _TRANSECT_VERSIONS:
            raise fail(
                f"{ctype} ({where}): TransectStyleComplexItem version {_show(tver)} is not "
                "supported: QGroundControl loads version 1 or 2 only; re-save the plan in "
                "QGroundControl", item=seq,
            )


def _opt_speed(x: Any) -> float | None:
    if not _is_num(x):
        return None
    try:
        v = float(x)
    except OverflowError:
        return None
    return v if math.isfinite(v) and v > 0 else None


def _plan_home(raw: Any, fail: Callable[..., MissionError]) -> GeoPoint | None:
    if raw is None:
        return None
    if not isinstance(raw, list) or len(raw) != 3:
        raise fail("plannedHomePosition must be [latitude, longitude, altitude AMSL]")

    def f(msg: str) -> MissionError:
        return fail(f"plannedHomePosition: {msg}")

    lat = _as_float(raw[0], "latitude", f, nullable=False)
    lon = _as_float(raw[1], "longitude", f, nullable=False)
    alt = _as_float(raw[2], "altitude", f, nullable=True)
    return GeoPoint(lat, lon, 0.0 if math.isnan(alt) else alt)


def _plan_simple(
    raw: dict[str, Any],
    seq: int,
    where: str,
    complex_type: str | None,
    fail_at: Callable[..., MissionError],
) -> MissionItem:
    def fail(msg: str) -> MissionError:
        return fail_at(f"{msg} ({where})", item=seq)

    kind = raw.get("type", "SimpleItem")
    if kind != "SimpleItem":
        raise fail(f"unknown item type {_show(kind)}")
    if "command" not in raw:
        raise fail("missing command")
    cmd = _as_int(raw.get("command"), "command", fail, 0, 65_535)
    frame = _as_int(raw.get("frame", FRAME_MISSION), "frame", fail, 0, 255)
    params = raw.get("params")
    if not isinstance(params, list) or len(params) != 7:
        raise fail("params must be a list of 7 numbers (null = not set)")
    vals = [_as_float(v, f"param{i + 1}", fail, nullable=True) for i, v in enumerate(params)]
    ac = raw.get("autoContinue", True)
    if not isinstance(ac, bool) and ac not in (0, 1):
        raise fail(f"autoContinue must be true or false, got {_show(ac)}")
    jid = raw.get("doJumpId")
    do_jump_id = None if jid is None else _as_int(jid, "doJumpId", fail, 0, 2**31 - 1)
    am = raw.get("AltitudeMode")
    alt_mode = am if isinstance(am, int) and not isinstance(am, bool) else None
    return MissionItem(
        index=seq,
        command=cmd,
        frame=frame,
        params=(vals[0], vals[1], vals[2], vals[3], vals[4], vals[5], vals[6]),
        autocontinue=bool(ac),
        do_jump_id=do_jump_id,
        altitude_mode=alt_mode,
        complex_type=complex_type,
        where=where,
    )


def _plan_latlon(
    raw: Any, what: str, home: GeoPoint, fail: Callable[..., MissionError]
) -> tuple[float, float]:
    if not isinstance(raw, list) or len(raw) < 2:
        raise fail(f"{what} must be [latitude, longitude]")

    def f(msg: str) -> MissionError:
        return fail(f"{what}: {msg}")

    lat = _as_float(raw[0], "latitude", f, nullable=False)
    lon = _as_float(raw[1], "longitude", f, nullable=False)
    _latlon_check(lat, lon, home, "position", f)
    return lat, lon


def _plan_geofence(raw: Any, home: GeoPoint, fail: Callable[..., MissionError]) -> Geofence:
    if raw is None:
        return Geofence()
    if not isinstance(raw, dict):
        raise fail('"geoFence" must be an object')
    polygons: list[FencePolygon] = []
    circles: list[FenceCircle] = []
    raw_polys = raw.get("polygons", [])
    if "polygons" not in raw and isinstance(raw.get("polygon"), list):
        raw_polys = [{"inclusion": True, "polygon": raw["polygon"]}]  # geoFence version 1
    if not isinstance(raw_polys, list):
        raise fail("geoFence.polygons must be a list")
    for i, rp in enumerate(raw_polys):
        what = f"geoFence polygon {i}"
        if not isinstance(rp, dict):
            raise fail(f"{what} must be an object")
        inclusion = rp.get("inclusion", True)
        if not isinstance(inclusion, bool):
            raise fail(f"{what}: inclusion must be true or false")
        verts = rp.get("polygon")
        if not isinstance(verts, list) or len(verts) < 3:
            raise fail(f"{what} needs at least 3 vertices")
        deg = tuple(_plan_latlon(v, f"{what} vertex {j}", home, fail) for j, v in enumerate(verts))
        ne = tuple(_ne(lat, lon, home) for lat, lon in deg)
        polygons.append(FencePolygon(inclusion, deg, ne))
    raw_circles = raw.get("circles", [])
    if not isinstance(raw_circles, list):
        raise fail("geoFence.circles must be a list")
    for i, rc in enumerate(raw_circles):
        what = f"geoFence circle {i}"
        if not isinstance(rc, dict) or not isinstance(rc.get("circle"), dict):
            raise fail(f'{what} must be an object with a "circle"')
        inclusion = rc.get("inclusion", True)
        if not isinstance(inclusion, bool):
            raise fail(f"{what}: inclusion must be true or false")
        circ = rc["circle"]
        lat, lon = _plan_latlon(circ.get("center"), f"{what} center", home, fail)

        def f(msg: str, what: str = what) -> MissionError:
            return fail(f"{what}: {msg}")

        radius = _as_float(circ.get("radius"), "radius", f, nullable=False)
        if not (math.isfinite(radius) and 0.0 < radius <= 2 * MAX_RANGE_M):
            raise fail(
                f"{what}: radius must be a positive number of metres up to "
                f"{2 * MAX_RANGE_M:g}, got {radius}"
            )
        circles.append(FenceCircle(inclusion, lat, lon, _ne(lat, lon, home), radius))
    return Geofence(tuple(polygons), tuple(circles))


def _plan_rally(
    raw: Any, home: GeoPoint, fail: Callable[..., MissionError]
) -> tuple[RallyPoint, ...]:
    if raw is None:
        return ()
    if not isinstance(raw, dict):
        raise fail('"rallyPoints" must be an object')
    pts = raw.get("points", [])
    if not isinstance(pts, list):
        raise fail("rallyPoints.points must be a list")
    out: list[RallyPoint] = []
    for i, rp in enumerate(pts):
        what = f"rally point {i}"
        if not isinstance(rp, list) or len(rp) != 3:
            raise fail(f"{what} must be [latitude, longitude, altitude above home]")
        lat, lon = _plan_latlon(rp[:2], what, home, fail)

        def f(msg: str, what: str = what) -> MissionError:
            return fail(f"{what}: {msg}")

        alt = _as_float(rp[2], "altitude", f, nullable=False)
        if not (math.isfinite(alt) and abs(alt) <= MAX_HEIGHT_M):
            raise fail(f"{what}: altitude must be finite and within {MAX_HEIGHT_M:g} m of home")
        n, e = _ne(lat, lon, home)
        out.append(RallyPoint(lat, lon, alt, (n, e, -alt)))
    return tuple(out)


# ------------------------------------------------------------------------------------ QGC WPL
_WPL_FIELDS = "INDEX CURRENT FRAME COMMAND P1 P2 P3 P4 LAT LON ALT AUTOCONTINUE"


def parse_wpl(
    text: str, *, source: str | os.PathLike[str] = "<string>", home: GeoPoint | None = None
) -> Mission:
    """Parse ``QGC WPL 110`` text: tab-separated INDEX CURRENT FRAME COMMAND P1..P4 LAT LON ALT
    AUTOCONTINUE; line with INDEX 0 is home (AMSL altitude) and is not a mission item."""
    src = Path(source)
    lines = text.removeprefix("\ufeff").splitlines()
    first = 0
    while first < len(lines) and not lines[first].strip():
        first += 1
    header = lines[first].split() if first < len(lines) else []
    if header[:2] != ["QGC", "WPL"]:
        raise MissionError(src, 'first line must be "QGC WPL 110"')
    if header[2:] != ["110"]:
        raise MissionError(src, f'unsupported header "{" ".join(header)}" (expected QGC WPL 110)')

    file_home: GeoPoint | None = None
    row0_item: str | None = None
    items: list[MissionItem] = []
    wheres: dict[int, str] = {}
    expected = 0
    for lineno in range(first + 2, len(lines) + 1):
        line = lines[lineno - 1].strip()
        if not line:
            continue
        fields = [f.strip() for f in line.split("\t")] if "\t" in line else line.split()
        while fields and fields[-1] == "":
            fields.pop()
        item_no = _wpl_peek_index(fields)

        def fail(msg: str, lineno: int = lineno, item_no: int | None = item_no) -> MissionError:
            return MissionError(src, f"{msg} (line {lineno})", item=item_no)

        if len(fields) != 12:
            raise fail(f"expected 12 fields ({_WPL_FIELDS}), got {len(fields)}")
        index = _wpl_int(fields[0], "INDEX", fail, 0, 65_535)
        if index != expected:
            if expected == 0:
                raise fail(f"the first item must be home (INDEX 0), got INDEX {index}")
            raise fail(f"INDEX {index} out of order (expected {expected})")
        expected += 1
        current = _wpl_int(fields[1], "CURRENT", fail, 0, 1)
        frame = _wpl_int(fields[2], "FRAME", fail, 0, 255)
        cmd = _wpl_int(fields[3], "COMMAND", fail, 0, 65_535)
        vals = [
            _wpl_float(fields[4 + i], name, fail)
            for i, name in enumerate(_WPL_FIELDS.split()[4:11])
        ]
        autocont = _wpl_int(fields[11], "AUTOCONTINUE", fail, 0, 1)
        if index == 0 and cmd != CMD_WAYPOINT:
            # not a home row (QGroundControl and Mission Planner write home as a NAV_WAYPOINT):
            # mission item 0, as MAVSDK's "Mission Planner" import reads every row of the file
            row0_item = f"row 0 is a {command_name(cmd)} mission item (line {lineno})"
        elif index == 0:
            if frame not in FRAMES_AMSL:
                _log.debug("%s: home line frame %d treated as AMSL", src, frame)
            file_home = GeoPoint(vals[4], vals[5], vals[6])
            continue
        items.append(
            MissionItem(
                index=index,
                command=cmd,
                frame=frame,
                params=(vals[0], vals[1], vals[2], vals[3], vals[4], vals[5], vals[6]),
                autocontinue=bool(autocont),
                current=bool(current),
                where=f"line {lineno}",
            )
        )
        wheres[index] = f"line {lineno}"
    warns: list[str] = []
    if home is None and file_home is None and row0_item is not None:
        home = _wpl_home_from_items(items, src, row0_item)
        warns.append(
            f"{src}: {row0_item}, not a home row (as MAVSDK's Mission Planner import reads "
            f"it): home taken at its position ({home.lat_deg:.7f}, {home.lon_deg:.7f}), "
            "altitudes relative to it (the vehicle's own home when flown)"
        )
        _log.warning(warns[-1])
    if home is None:
        if file_home is None:
            raise MissionError(src, "no home line (INDEX 0); give the home position explicitly")
        home = file_home
    home = _home_check(home, src, "home position (line with INDEX 0)")
    return _finish(src, home, items, by_do_jump_id=False, wheres=wheres, file_format="wpl",
                   warnings=warns)


def _wpl_home_from_items(items: list[MissionItem], src: Path, row0: str) -> GeoPoint:
    """Home of a QGC WPL file without a home row: the first item's latitude/longitude, at an
    arbitrary 0 m AMSL, which only relative altitudes (frame 3/6) make flyable."""
    amsl = [it for it in items if it.frame in FRAMES_AMSL
            and (it.command in POSITION_COMMANDS) and math.isfinite(it.alt_m)]
    if amsl:
        it = amsl[0]
        raise MissionError(
            src,
            f"{row0}, not a home row (MAVSDK's Mission Planner import reads every row as a "
            f"mission item), so the file has no home position, and the altitude "
            f"{it.alt_m:g} m of {command_name(it.command)} is AMSL (frame {it.frame}), which "
            "needs the ground altitude: write home as row 0 (0 1 0 16 0 0 0 0 LAT LON "
            "ALT_AMSL 1) or give altitudes relative to home (frame 3)",
            item=it.index,
        )
    for it in items:
        if it.has_latlon and it.frame in _GLOBAL_FRAMES:
            return GeoPoint(it.lat_deg, it.lon_deg, 0.0)
    raise MissionError(
        src, f"{row0}, not a home row, and no item has a position to take home from; "
        "write home as row 0 (0 1 0 16 0 0 0 0 LAT LON ALT_AMSL 1)",
    )


def _wpl_peek_index(fields: list[str]) -> int | None:
    try:
        v = int(fields[0]) if fields else None
    except ValueError:
        return None
    return v if v is not None and 0 <= v <= 65_535 else None


def _wpl_int(tok: str, what: str, fail: Callable[[str], MissionError], lo: int, hi: int) -> int:
    try:
        v = float(tok)
    except ValueError:
        raise fail(f"{what} must be an integer, got {_show(tok)}") from None
    return _as_int(v, what, fail, lo, hi)


def _wpl_float(tok: str, what: str, fail: Callable[[str], MissionError]) -> float:
    try:
        return float(tok)
    except ValueError:
        raise fail(f"{what} must be a number, got {_show(tok)}") from None
