"""Property tests: projection vs a great-circle oracle and round trips; random valid missions
expand to flight plans whose waypoints are the items' positions and whose chunks tile the path."""

from __future__ import annotations

import json
import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.mission import (
    GeoPoint,
    geodetic_to_ned,
    mission_to_flight_plan,
    ned_to_geodetic,
    parse_plan,
    parse_wpl,
)
from tests.support.mission_checks import check_chunks
from tests.support.mission_oracle import distance_bearing, expected_ne

SETTINGS = settings(max_examples=200, deadline=None)

homes = st.builds(
    GeoPoint,
    st.floats(-80.0, 80.0),
    st.floats(-180.0, 180.0),
    st.floats(-400.0, 5000.0),
)


@SETTINGS
@given(homes, st.floats(0.0, 150_000.0), st.floats(-math.pi, math.pi), st.floats(-500, 500))
def test_projection_radius_and_bearing(home: GeoPoint, r: float, brg: float, up: float) -> None:
    # place a point at (r, brg) in the plane, reproject it, and ask the oracle where it is
    ned = np.array([r * math.cos(brg), r * math.sin(brg), -up])
    lat, lon, alt = ned_to_geodetic(ned, home)
    dist, bearing = distance_bearing(home.lat_deg, home.lon_deg, float(lat), float(lon))
    assert abs(float(dist) - r) <= 1e-6 + 1e-9 * r
    if r > 1.0:
        d_brg = (float(bearing) - brg + math.pi) % (2 * math.pi) - math.pi
        assert abs(d_brg) * r <= 1e-5
    assert float(alt) == np.float64(home.alt_amsl_m + up)
    back = geodetic_to_ned(lat, lon, alt, home)
    np.testing.assert_allclose(back, ned, atol=1e-6)


@SETTINGS
@given(homes, st.floats(-1.0, 1.0), st.floats(-1.0, 1.0))
def test_geodetic_round_trip(home: GeoPoint, dlat: float, dlon: float) -> None:
    lat = float(np.clip(home.lat_deg + dlat, -89.0, 89.0))
    lon = (home.lon_deg + dlon + 180.0) % 360.0 - 180.0
    p = geodetic_to_ned(lat, lon, 100.0, home)
    np.testing.assert_allclose(p[:2], expected_ne(home.lat_deg, home.lon_deg, lat, lon), atol=1e-6)
    la, lo, _ = ned_to_geodetic(p, home)
    assert abs(float(la) - lat) < 1e-9
    assert abs((float(lo) - lon + 180.0) % 360.0 - 180.0) < 1e-9


HOME = GeoPoint(47.397742, 8.545594, 488.0)

waypoint = st.tuples(
    st.floats(-0.004, 0.004),  # dlat deg (~450 m)
    st.floats(-0.006, 0.006),  # dlon deg
    st.floats(3.0, 60.0),  # alt above home [m]
    st.sampled_from([3, 6, 0, 5]),  # frame
    st.sampled_from([0.0, 0.0, 2.0]),  # hold s
    st.sampled_from([0.0, 1.0, 5.0]),  # acceptance m
    st.booleans(),  # autoContinue
)


def _params(w: tuple[float, float, float, int, float, float, bool]) -> list[float | None]:
    dlat, dlon, alt, frame, hold, acc, _ = w
    z = alt + HOME.alt_amsl_m if frame in (0, 5) else alt
    return [hold, acc, 0, None, HOME.lat_deg + dlat, HOME.lon_deg + dlon, z]


@settings(max_examples=100, deadline=None)
@given(st.lists(waypoint, min_size=1, max_size=12), st.sampled_from([None, 20, 21]))
def test_random_missions_fly_their_waypoints(
    wps: list[tuple[float, float, float, int, float, float, bool]], end: int | None
) -> None:
    items = [
        {"type": "SimpleItem", "command": 16, "frame": w[3], "autoContinue": w[6],
         "doJumpId": i + 1, "params": _params(w)}
        for i, w in enumerate(wps)
    ]  # fmt: skip
    if end is not None:
        items.append({"type": "SimpleItem", "command": end, "frame": 3, "doJumpId": 99,
                      "params": [0, 0, 0, None, None, None, 0]})  # fmt: skip
    doc = {
        "fileType": "Plan",
        "version": 1,
        "mission": {
            "version": 2,
            "items": items,
            "plannedHomePosition": [HOME.lat_deg, HOME.lon_deg, HOME.alt_amsl_m],
        },
    }
    fp = mission_to_flight_plan(parse_plan(json.dumps(doc)))
    # the same mission as QGC WPL loads to the same flight plan
    lines = ["QGC WPL 110", f"0\t1\t0\t16\t0\t0\t0\t0\t{HOME.lat_deg}\t{HOME.lon_deg}\t488.0\t1"]
    for i, it in enumerate(items, start=1):
        p = ["nan" if v is None else repr(float(v)) for v in it["params"]]
        ac = int(it.get("autoContinue", True))
        lines.append("\t".join([str(i), "0", str(it["frame"]), str(it["command"]), *p, str(ac)]))
    assert mission_to_flight_plan(parse_wpl("\n".join(lines))).waypoints == fp.waypoints

    mission_pts = [w for w in fp.waypoints if w.command == 16]
    assert len(mission_pts) == len(wps)
    first_alt = wps[0][2]
    assert abs(fp.takeoff_alt_m - max(first_alt, 2.5)) < 1e-9
    for w, src in zip(mission_pts, wps, strict=True):
        dlat, dlon, alt, _, hold, acc, ac = src
        ne = expected_ne(HOME.lat_deg, HOME.lon_deg, HOME.lat_deg + dlat, HOME.lon_deg + dlon)
        np.testing.assert_allclose(w.pos_ned_m[:2], ne, atol=1e-6)
        assert abs(w.pos_ned_m[2] + alt) < 1e-6
        assert w.hold_s == hold and w.acceptance_radius_m == (acc if acc > 0 else 2.0)
        assert w.stop == (hold > 0 or not ac or w is fp.waypoints[-1] or (end == 20
                          and w is mission_pts[-1]))  # fmt: skip
    assert fp.final_action == {None: "loiter", 20: "rtl", 21: "land"}[end]
    check_chunks(fp)
