"""QGC WPL 110 text <-> :class:`Mission`: :func:`parse_wpl` reads the tab-separated rows (row 0
is home), :func:`mission_to_wpl` writes them. Every problem raises :class:`MissionError` naming
the file, the item and the line."""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Callable
from pathlib import Path

from companion.mission.checks import as_int, check_home, finish_mission, show_value
from companion.mission.errors import MissionError
from companion.mission.geodesy import GeoPoint
from companion.mission.model import (
    CMD_DO_JUMP,
    CMD_WAYPOINT,
    FRAMES_AMSL,
    FRAMES_GLOBAL,
    POSITION_COMMANDS,
    Mission,
    MissionItem,
    command_name,
)

__all__ = ["mission_to_wpl", "parse_wpl"]

_log = logging.getLogger("companion.mission")

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
    home = check_home(home, src, "home position (line with INDEX 0)")
    return finish_mission(src, home, items, by_do_jump_id=False, wheres=wheres, file_format="wpl",
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
        if it.has_latlon and it.frame in FRAMES_GLOBAL:
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
        raise fail(f"{what} must be an integer, got {show_value(tok)}") from None
    return as_int(v, what, fail, lo, hi)


def _wpl_float(tok: str, what: str, fail: Callable[[str], MissionError]) -> float:
    try:
        return float(tok)
    except ValueError:
        raise fail(f"{what} must be a number, got {show_value(tok)}") from None


def mission_to_wpl(mission: Mission) -> str:
    """``mission`` as QGC WPL 110 text that :func:`parse_wpl` reads back to the same items: row 0
    is home (AMSL), then one row per item, numbered 1.. in order (DO_JUMP targets renumbered with
    them), every number written exactly (``repr``; NaN as ``nan``). A WPL file has no geofence,
    rally points, doJumpIds or complex items: those are not written."""
    new_index = {it.index: k for k, it in enumerate(mission.items, start=1)}
    h = mission.home
    rows = ["QGC WPL 110", f"0\t1\t0\t{CMD_WAYPOINT}\t0\t0\t0\t0\t{h.lat_deg!r}\t{h.lon_deg!r}\t"
                           f"{h.alt_amsl_m!r}\t1"]
    for k, it in enumerate(mission.items, start=1):
        params = list(it.params)
        if it.command == CMD_DO_JUMP and math.isfinite(params[0]) and params[0] in new_index:
            params[0] = float(new_index[int(params[0])])
        cols = [k, int(it.current), it.frame, it.command, *(repr(float(p)) for p in params),
                int(it.autocontinue)]
        rows.append("\t".join(str(c) for c in cols))
    return "\n".join(rows) + "\n"
