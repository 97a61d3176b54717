"""Mission items as PX4 would receive them (MISSION_ITEM_INT fields), for an AUTO.MISSION
comparison flight: 0-based ``seq`` without the home item (QGroundControl does not upload home to
PX4), DO_JUMP targets as ``seq``, positions in frame 3 (relative to home) with every latitude,
longitude and altitude filled in, items the companion ignores left out."""

from __future__ import annotations

import math
from dataclasses import dataclass

from companion.mavlink.mission_client import MissionItem
from companion.mission.loaders import OTHER_COMMANDS, POSITION_COMMANDS
from companion.mission.model import (
    CMD_DO_JUMP,
    CMD_DO_SET_ROI_LOCATION,
    CMD_TAKEOFF,
    CMD_VTOL_TAKEOFF,
    FRAME_MISSION,
    Mission,
    MissionError,
)

__all__ = ["FRAME_GLOBAL_RELATIVE_ALT", "UploadItem", "mission_upload_items"]

FRAME_GLOBAL_RELATIVE_ALT = 3


@dataclass(frozen=True)
class UploadItem(MissionItem):
    """One MISSION_ITEM_INT as uploaded (the wire `companion.mavlink.MissionItem`, mission_type 0),
    plus ``source_index``: the file's :class:`~companion.mission.MissionItem` index it comes from.

    ``x``/``y`` are latitude/longitude in degE7 for position items (0 otherwise); ``z`` is the
    altitude above home [m].
    """

    source_index: int = -1


def _deg_e7(v: float) -> int:
    return round(v * 1e7)


def mission_upload_items(
    mission: Mission, *, takeoff_alt_default: float = 2.5
) -> tuple[UploadItem, ...]:
    """The mission as PX4 would receive it (see module doc). Position items with no
    latitude/longitude get the previous position (home for the first); no altitude: the previous
    altitude (``takeoff_alt_default`` for a takeoff)."""
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
