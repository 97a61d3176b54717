"""QGroundControl ``.plan`` (JSON) -> :class:`Mission`: the plan's items (complex items by their
pre-expanded items), geofence and rally points. Every problem raises :class:`MissionError`
naming the file and, where it applies, the item (JSON errors are translated)."""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from companion.mission.checks import (
    MAX_HEIGHT_M,
    MAX_RANGE_M,
    as_float,
    as_int,
    check_home,
    check_latlon,
    finish_mission,
    is_num,
    ne_of,
    show_value,
)
from companion.mission.errors import MissionError
from companion.mission.geodesy import GeoPoint
from companion.mission.geofence import FenceCircle, FencePolygon, Geofence
from companion.mission.model import FRAME_MISSION, Mission, MissionItem, RallyPoint

__all__ = ["parse_plan"]


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
        raise fail(f'fileType is {show_value(doc.get("fileType"))}, expected "Plan"')
    if doc.get("version") != 1 or isinstance(doc.get("version"), bool):
        raise fail(f"plan version {show_value(doc.get('version'))} is not supported (expected 1)")
    mission = doc.get("mission")
    if not isinstance(mission, dict):
        raise fail('"mission" must be an object')
    mver = mission.get("version")
    if mver != 2 or isinstance(mver, bool):
        raise fail(f"mission version {show_value(mver)} is not supported (expected 2)")

    file_home = _plan_home(mission.get("plannedHomePosition"), fail)
    if home is None:
        if file_home is None:
            raise fail("no plannedHomePosition; give the home position explicitly")
        home = file_home
    home = check_home(home, src, "home position")

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
                raise fail(f"complex item type {show_value(ctype)} is not supported", item=seq)
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
            raise fail(f"{where}: unknown item type {show_value(kind)}", item=seq)

    vtype = mission.get("vehicleType")
    hover = mission.get("hoverSpeed")
    geofence = _plan_geofence(doc.get("geoFence"), home, fail)
    rally = _plan_rally(doc.get("rallyPoints"), home, fail)
    return finish_mission(
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
    if isinstance(ver, bool) or not is_num(ver) or not float(ver).is_integer() or int(
            ver) not in accepted:
        raise fail(
            f"{ctype} ({where}) version {show_value(ver)} is not supported: QGroundControl loads "
            f"{ctype} version {shown} only (and MAVSDK survey version 5 only); re-save the "
            "plan in QGroundControl", item=seq,
        )
    tsci = raw.get("TransectStyleComplexItem")
    if isinstance(tsci, dict):
        tver = tsci.get("version", 0)
        if isinstance(tver, bool) or not is_num(tver) or not float(tver).is_integer() or int(
                tver) not in _TRANSECT_VERSIONS:
            raise fail(
                f"{ctype} ({where}): TransectStyleComplexItem version {show_value(tver)} is not "
                "supported: QGroundControl loads version 1 or 2 only; re-save the plan in "
                "QGroundControl", item=seq,
            )


def _opt_speed(x: Any) -> float | None:
    if not is_num(x):
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

    lat = as_float(raw[0], "latitude", f, nullable=False)
    lon = as_float(raw[1], "longitude", f, nullable=False)
    alt = as_float(raw[2], "altitude", f, nullable=True)
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
        raise fail(f"unknown item type {show_value(kind)}")
    if "command" not in raw:
        raise fail("missing command")
    cmd = as_int(raw.get("command"), "command", fail, 0, 65_535)
    frame = as_int(raw.get("frame", FRAME_MISSION), "frame", fail, 0, 255)
    params = raw.get("params")
    if not isinstance(params, list) or len(params) != 7:
        raise fail("params must be a list of 7 numbers (null = not set)")
    vals = [as_float(v, f"param{i + 1}", fail, nullable=True) for i, v in enumerate(params)]
    ac = raw.get("autoContinue", True)
    if not isinstance(ac, bool) and ac not in (0, 1):
        raise fail(f"autoContinue must be true or false, got {show_value(ac)}")
    jid = raw.get("doJumpId")
    do_jump_id = None if jid is None else as_int(jid, "doJumpId", fail, 0, 2**31 - 1)
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

    lat = as_float(raw[0], "latitude", f, nullable=False)
    lon = as_float(raw[1], "longitude", f, nullable=False)
    check_latlon(lat, lon, home, "position", f)
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
        ne = tuple(ne_of(lat, lon, home) for lat, lon in deg)
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

        radius = as_float(circ.get("radius"), "radius", f, nullable=False)
        if not (math.isfinite(radius) and 0.0 < radius <= 2 * MAX_RANGE_M):
            raise fail(
                f"{what}: radius must be a positive number of metres up to "
                f"{2 * MAX_RANGE_M:g}, got {radius}"
            )
        circles.append(FenceCircle(inclusion, lat, lon, ne_of(lat, lon, home), radius))
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

        alt = as_float(rp[2], "altitude", f, nullable=False)
        if not (math.isfinite(alt) and abs(alt) <= MAX_HEIGHT_M):
            raise fail(f"{what}: altitude must be finite and within {MAX_HEIGHT_M:g} m of home")
        n, e = ne_of(lat, lon, home)
        out.append(RallyPoint(lat, lon, alt, (n, e, -alt)))
    return tuple(out)
