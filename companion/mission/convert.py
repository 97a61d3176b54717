"""Every mission conversion, file <-> model <-> wire, in one place.

- file -> model: :func:`load_mission` / :func:`loads_mission` (``.plan`` JSON or QGC WPL 110,
  detected from the content; the parsers are :mod:`.plan_file` and :mod:`.wpl_file`);
- model -> file: :func:`mission_to_wpl` (QGC WPL 110 text);
- model -> wire: :func:`mission_upload_items`, the MISSION_ITEM_INTs PX4 would receive;
- wire -> model: :func:`mission_from_wire` (the vehicle's downloaded mission, checked like a
  mission file) and :func:`geofence_from_wire` (its fence items).

The wire record is ``companion.mavlink.WireMissionItem`` (the protocol layer's own type; the
mavlink layer never imports the mission model). Every problem raises :class:`MissionError`.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from companion.mavlink.mission_client import WireMissionItem
from companion.mission.checks import check_home, finish_mission, ne_of
from companion.mission.errors import MissionError
from companion.mission.geodesy import GeoPoint
from companion.mission.geofence import FenceCircle, FencePolygon, Geofence
from companion.mission.model import (
    CMD_DO_JUMP,
    CMD_DO_SET_ROI_LOCATION,
    CMD_TAKEOFF,
    CMD_VTOL_TAKEOFF,
    FRAME_MISSION,
    FRAMES_GLOBAL,
    OTHER_COMMANDS,
    POSITION_COMMANDS,
    Mission,
    MissionItem,
)
from companion.mission.plan_file import parse_plan
from companion.mission.wpl_file import mission_to_wpl, parse_wpl

__all__ = [
    "FRAME_GLOBAL_RELATIVE_ALT",
    "UploadItem",
    "geofence_from_wire",
    "load_mission",
    "loads_mission",
    "mission_from_wire",
    "mission_to_wpl",
    "mission_upload_items",
    "rehome_mission",
]

FRAME_GLOBAL_RELATIVE_ALT = 3
"""MAV_FRAME of every uploaded position item (altitude relative to home)."""


# ----------------------------------------------------------------------------- file -> model
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


def rehome_mission(mission: Mission, lat_deg: float, lon_deg: float) -> Mission:
    """`mission` with its home moved to latitude/longitude [deg] (its altitude kept): every item,
    fence vertex and rally point keeps its own latitude/longitude, so a flight planned about
    the new home starts there and still goes to the file's positions. `fly` re-homes a mission
    where the vehicle stands (PX4's AUTO.MISSION flies the items' coordinates wherever it took
    off; planned about the file's home and placed where the vehicle stood, every waypoint moved
    with the vehicle's distance from that home)."""
    home = GeoPoint(float(lat_deg), float(lon_deg), mission.home.alt_amsl_m)
    fence = mission.geofence
    polygons = tuple(dataclasses.replace(p, vertices_ne_m=tuple(ne_of(la, lo, home)
                                                                for la, lo in p.vertices_deg))
                     for p in fence.polygons)
    circles = tuple(dataclasses.replace(c, center_ne_m=ne_of(c.center_lat_deg, c.center_lon_deg,
                                                             home))
                    for c in fence.circles)
    rally = tuple(dataclasses.replace(r, pos_ned_m=(*ne_of(r.lat_deg, r.lon_deg, home),
                                                    r.pos_ned_m[2]))
                  for r in mission.rally)
    return dataclasses.replace(mission, home=home,
                               geofence=dataclasses.replace(fence, polygons=polygons,
                                                            circles=circles),
                               rally=rally)


# ----------------------------------------------------------------------------- model -> wire
@dataclass(frozen=True)
class UploadItem(WireMissionItem):
    """One MISSION_ITEM_INT as uploaded (a :class:`~companion.mavlink.WireMissionItem`,
    mission_type 0), plus ``source_index``: the :class:`MissionItem` index it comes from.

    ``x``/``y`` are latitude/longitude in degE7 for position items (0 otherwise); ``z`` is the
    altitude above home [m].
    """

    source_index: int = -1


def _deg_e7(v: float) -> int:
    return round(v * 1e7)


def mission_upload_items(
    mission: Mission, *, takeoff_alt_default: float = 2.5
) -> tuple[UploadItem, ...]:
    """The mission as PX4 would receive it, for AUTO.MISSION: 0-based ``seq`` without the home
    item (QGroundControl does not upload home to PX4), DO_JUMP targets as ``seq``, positions in
    frame 3 (relative to home) with every latitude, longitude and altitude filled in, items the
    companion ignores left out. Position items with no latitude/longitude get the previous
    position (home for the first); no altitude: the previous altitude (``takeoff_alt_default``
    [m] for a takeoff)."""
    kept = [it for it in mission.items if it.command in POSITION_COMMANDS | OTHER_COMMANDS]
    seq_of = {it.index: k for k, it in enumerate(kept)}
    # a DO_JUMP onto a dropped item lands on the next kept one
    all_indices = [it.index for it in mission.items]

    def target_seq(index: int, jump_index: int) -> int:
        start = all_indices.index(index)
        for later in all_indices[start:]:
            if later in seq_of:
                return seq_of[later]
        raise MissionError(
            mission.source, "DO_JUMP: no flyable item at or after its target", item=jump_index
        )

    home = mission.home
    last_lat, last_lon, last_alt = home.lat_deg, home.lon_deg, takeoff_alt_default
    out: list[UploadItem] = []
    for seq, it in enumerate(kept):
        p1, p2, p3, p4 = it.params[:4]
        x = y = 0
        z = 0.0
        frame = FRAME_MISSION
        if it.command in POSITION_COMMANDS:
            frame = FRAME_GLOBAL_RELATIVE_ALT
            lat, lon = (it.lat_deg, it.lon_deg) if it.has_latlon else (last_lat, last_lon)
            alt = it.alt_rel_home_m(home)
            if not math.isfinite(alt):
                alt = (takeoff_alt_default if it.command in (CMD_TAKEOFF, CMD_VTOL_TAKEOFF)
                       else last_alt)
            x, y, z = _deg_e7(lat), _deg_e7(lon), alt
            if it.command != CMD_DO_SET_ROI_LOCATION:
                last_lat, last_lon, last_alt = lat, lon, alt
        elif it.command == CMD_DO_JUMP:
            p1 = float(target_seq(int(p1), it.index))
        out.append(
            UploadItem(
                seq=seq,
                frame=frame,
                command=it.command,
                current=1 if seq == 0 else 0,
                autocontinue=int(it.autocontinue),
                param1=p1,
                param2=p2,
                param3=p3,
                param4=p4,
                x=x,
                y=y,
                z=z,
                source_index=it.index,
            )
        )
    return tuple(out)


# ----------------------------------------------------------------------------- wire -> model
def _model_item(k: int, w: WireMissionItem) -> MissionItem:
    """The ``k``-th downloaded item (0-based) as the model's item ``k + 1``."""
    scale = 1e7 if w.frame in FRAMES_GLOBAL else 1e4  # degE7, or local metres * 1e4
    p1 = float(w.param1)
    if w.command == CMD_DO_JUMP and math.isfinite(p1) and p1.is_integer():
        p1 += 1.0  # target seq -> the target's index (seq + 1)
    return MissionItem(
        index=k + 1,
        command=int(w.command),
        frame=int(w.frame),
        # z to the millimetre: the wire's float32 adds ~1e-6 m of noise to the written value
        params=(p1, float(w.param2), float(w.param3), float(w.param4), w.x / scale,
                w.y / scale, round(float(w.z), 3)),
        autocontinue=bool(w.autocontinue),
        where=f"seq {w.seq}",
    )


def mission_from_wire(
    items: Sequence[WireMissionItem], home: GeoPoint, *,
    source: str | os.PathLike[str] = "vehicle mission",
) -> Mission:
    """A downloaded mission (MISSION_ITEM_INT, 0-based ``seq``, no home item) as a
    :class:`Mission` about ``home``, with every check a mission file gets (:class:`MissionError`
    naming ``source`` and the item ``seq + 1``, as QGroundControl numbers it). Latitude and
    longitude are degE7 / 1e7 [deg] in the global frames (0, 3, 5, 6, 10, 11), else x/y / 1e4;
    DO_JUMP's target seq becomes the target's index."""
    src = Path(source)
    home = check_home(home, src, "home position")
    model = [_model_item(k, w) for k, w in enumerate(items)]
    wheres = {it.index: it.where for it in model}
    return finish_mission(src, home, model, by_do_jump_id=False, wheres=wheres,
                          file_format="wire")


#: MAV_CMD_NAV_FENCE_*: polygon vertex (inclusion, exclusion), circle (inclusion, exclusion).
_FENCE_VERTEX = {5001: True, 5002: False}
_FENCE_CIRCLE = {5003: True, 5004: False}


def geofence_from_wire(items: Sequence[WireMissionItem], home: GeoPoint) -> Geofence:
    """The vehicle's fence items (mission_type FENCE, MAV_CMD_NAV_FENCE_*: a polygon is
    ``param1`` consecutive vertex items, a circle's radius is ``param1`` [m]; x/y in degE7) as a
    :class:`Geofence` about ``home``. :class:`MissionError` on a malformed fence (safety: no
    guessing)."""

    def ne(it: WireMissionItem) -> tuple[tuple[float, float], tuple[float, float]]:
        lat, lon = it.x / 1e7, it.y / 1e7
        return (lat, lon), ne_of(lat, lon, home)

    polygons: list[FencePolygon] = []
    circles: list[FenceCircle] = []
    k = 0
    while k < len(items):
        it = items[k]
        if it.command in _FENCE_VERTEX:
            n = int(it.param1)
            group = items[k:k + n]
            if n < 3 or len(group) < n or any(g.command != it.command for g in group):
                raise MissionError("vehicle geofence",
                                   f"fence item {it.seq}: a polygon of {n} vertices is incomplete")
            pts = [ne(g) for g in group]
            polygons.append(FencePolygon(_FENCE_VERTEX[it.command], tuple(d for d, _ in pts),
                                         tuple(m for _, m in pts)))
            k += n
            continue
        if it.command in _FENCE_CIRCLE:
            if not (math.isfinite(it.param1) and it.param1 > 0.0):
                raise MissionError("vehicle geofence",
                                   f"fence item {it.seq}: circle radius {it.param1} m")
            (lat, lon), c = ne(it)
            circles.append(FenceCircle(_FENCE_CIRCLE[it.command], lat, lon, c, float(it.param1)))
        k += 1  # a return point (5000) or anything else: no zone
    return Geofence(tuple(polygons), tuple(circles))
