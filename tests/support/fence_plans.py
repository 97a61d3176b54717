"""QGroundControl .plan files with a geofence, written from local north/east metres (tests).

Items: TAKEOFF (item 1) above home, one WAYPOINT per point (items 2, 3, ...), then LAND at home
(the last item) unless ``land=False``. Zones are (inclusion, vertices NE) polygons and
(inclusion, centre NE, radius) circles. The NE -> lat/lon conversion is the spherical small-offset
formula of tests/support/gcs.py, not the companion's projection.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

from tests.support.gcs import offset_deg

HOME = (47.397742, 8.545594, 488.0)
NE = tuple[float, float]


def latlon(ne: NE) -> list[float]:
    dlat, dlon = offset_deg(HOME[0], ne[0], ne[1])
    return [HOME[0] + dlat, HOME[1] + dlon]


def _item(seq: int, command: int, ne: NE, alt_m: float) -> dict[str, object]:
    lat, lon = latlon(ne)
    return {"type": "SimpleItem", "command": command, "frame": 3, "autoContinue": True,
            "doJumpId": seq, "params": [0, 0, 0, None, lat, lon, alt_m]}


def write_plan(
    path: Path,
    points_ne: Sequence[NE],
    *,
    alt_m: float = 10.0,
    polygons: Sequence[tuple[bool, Sequence[NE]]] = (),
    circles: Sequence[tuple[bool, NE, float]] = (),
    land: bool = True,
) -> Path:
    """Write the .plan (see the module doc) and return its path."""
    items = [_item(1, 22, (0.0, 0.0), alt_m)]
    for k, p in enumerate(points_ne):
        items.append(_item(k + 2, 16, p, alt_m))
    if land:
        items.append(_item(len(items) + 1, 21, (0.0, 0.0), 0.0))
    doc = {
        "fileType": "Plan", "version": 1, "groundStation": "QGroundControl",
        "geoFence": {
            "version": 2,
            "polygons": [{"inclusion": inc, "version": 1, "polygon": [latlon(v) for v in verts]}
                         for inc, verts in polygons],
            "circles": [{"inclusion": inc, "version": 1,
                         "circle": {"center": latlon(c), "radius": r}}
                        for inc, c, r in circles],
        },
        "rallyPoints": {"version": 2, "points": []},
        "mission": {"version": 2, "firmwareType": 12, "vehicleType": 2,
                    "plannedHomePosition": list(HOME), "items": items},
    }
    path.write_text(json.dumps(doc), encoding="utf-8")
    return path


def box(n0: float, n1: float, e0: float, e1: float) -> list[NE]:
    """A rectangle's vertices (north n0..n1, east e0..e1) [m]."""
    return [(n0, e0), (n1, e0), (n1, e1), (n0, e1)]
