"""mission -> flight plan: PX4 mission semantics checked against hand-derived expectations, with
positions from an independent great-circle oracle applied to the file's own coordinates."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from companion.mission import (
    GeoPoint,
    MissionError,
    expand_jumps,
    load_mission,
    mission_to_flight_plan,
    mission_upload_items,
    parse_plan,
    split_flight_plan,
)
from tests.support.mission_checks import check_chunks
from tests.support.mission_oracle import distance_bearing, expected_ne

DATA = Path(__file__).resolve().parents[2] / "data" / "missions"
EXAMPLES = Path(__file__).resolve().parents[3] / "examples" / "missions"
HOME = GeoPoint(47.397742, 8.545594, 488.0)


def _raw_items(path: Path) -> dict[int, dict[str, Any]]:
    """The file's simple items by QGC sequence number (read with json, not the loader)."""
    doc = json.loads(path.read_text())
    out: dict[int, dict[str, Any]] = {}
    seq = 1
    for it in doc["mission"]["items"]:
        subs = it.get("TransectStyleComplexItem", {}).get("Items", [it])
        for s in subs:
            out[seq] = s
            seq += 1
    return out


def _ned(raw: dict[str, Any], alt_rel: float) -> np.ndarray:
    lat, lon = raw["params"][4], raw["params"][5]
    ne = expected_ne(HOME.lat_deg, HOME.lon_deg, lat, lon)
    return np.array([ne[0], ne[1], -alt_rel])


def test_all_commands_flight_plan() -> None:
    path = DATA / "all_commands.plan"
    raw = _raw_items(path)
    fp = mission_to_flight_plan(load_mission(path))
    got = [w.item_index for w in fp.waypoints]
    # takeoff, loop 2..7 twice (DO_JUMP repeat 1), ROI waypoint, land approach
    assert got == [1, 2, 3, 4, 5, 7, 2, 3, 4, 5, 7, 10, 14]
    alt_rel = {1: 12.0, 2: 15.0, 3: 20.0, 4: 10.0, 5: 14.0, 7: 14.0, 10: 12.0, 14: 12.0}
    for w in fp.waypoints:
        assert w.item_index is not None
        exp = _ned(raw[w.item_index], alt_rel[w.item_index])
        np.testing.assert_allclose(w.pos_ned_m, exp, atol=1e-6)
    by = fp.waypoints
    assert by[0].phase == "takeoff" and by[0].stop and by[0].speed_m_s == 1.5
    assert fp.takeoff_alt_m == 12.0
    # item 3: hold 3 s, acceptance 4 m, yaw 45 deg; defaults elsewhere
    assert (by[2].hold_s, by[2].acceptance_radius_m, by[2].yaw_deg, by[2].stop) == (3, 4, 45, True)
    assert (by[1].hold_s, by[1].acceptance_radius_m, by[1].yaw_deg, by[1].stop) == (
        0,
        2.0,
        None,
        False,
    )
    # item 7: loiter 4 s
    assert by[5].hold_s == 4.0 and by[5].stop
    # DO_CHANGE_SPEED 3.5 m/s at item 6 applies from the leg to item 7 on (also after the jump)
    assert [w.speed_m_s for w in by[1:12]] == [5.0] * 4 + [3.5] * 7
    # ROI at item 9: item 10 faces it (bearing from the oracle); ROI_NONE before the land
    r9, r10 = raw[9]["params"], raw[10]["params"]
    _, brg = distance_bearing(r10[4], r10[5], r9[4], r9[5])
    assert by[11].yaw_deg == pytest.approx(math.degrees(float(brg)), abs=0.01)
    assert by[12].yaw_deg is None
    assert fp.final_action == "land" and by[12].stop
    assert fp.touchdown_ned_m == pytest.approx((by[12].pos_ned_m[0], by[12].pos_ned_m[1], 0.0))
    check_chunks(fp)
    chunks = split_flight_plan(fp)
    assert [c.phase for c in chunks] == ["takeoff"] + ["mission"] * 5 + ["land"]
    assert [c.hold_after_s for c in chunks] == [0, 3, 4, 3, 4, 0, 0]
    assert [len(c.points_ned_m) for c in chunks] == [2, 3, 4, 3, 4, 3, 2]
    assert chunks[0].leg_speed_m_s == (1.5,) and chunks[-1].leg_speed_m_s == (0.7,)


def test_wpl_and_plan_fly_identically() -> None:
    a = mission_to_flight_plan(load_mission(DATA / "all_commands.plan"))
    b = mission_to_flight_plan(load_mission(DATA / "all_commands.waypoints"))
    assert a.waypoints == b.waypoints


def test_hold_and_jump_example() -> None:
    path = EXAMPLES / "hold_and_jump.plan"
    raw = _raw_items(path)
    m = load_mission(path)
    fp = mission_to_flight_plan(m)
    # DO_JUMP (item 7) back to item 2, repeat 2: the loop 2, 3, 5 is flown three times
    assert [w.item_index for w in fp.waypoints] == [1, 2, 3, 5, 2, 3, 5, 2, 3, 5, 9, 10, 12, 13]
    assert [it.index for it in expand_jumps(m)] == [
        1, 2, 3, 4, 5, 6, 2, 3, 4, 5, 6, 2, 3, 4, 5, 6, 8, 9, 10, 11, 12, 13
    ]  # fmt: skip
    holds = {3: 5.0, 5: 2.0}
    for w in fp.waypoints:
        assert w.hold_s == holds.get(w.item_index or 0, 0.0)
        assert w.item_index is not None
        r = raw[w.item_index]
        if w.item_index not in (1, 13):
            np.testing.assert_allclose(w.pos_ned_m, _ned(r, r["params"][6]), atol=1e-6)
    # speed 3 m/s for the leg to item 5 only (item 6 restores the default: -2)
    assert [w.speed_m_s for w in fp.waypoints[1:10]] == [5.0, 5.0, 3.0] * 3
    # ROI at (10 N, 10 E): from (-10, 10) due north, from (-10, -10) north-east; then yaw 90
    yaws = [w.yaw_deg for w in fp.waypoints[10:]]
    assert yaws[0] == pytest.approx(0.0, abs=0.05)
    assert yaws[1] == pytest.approx(45.0, abs=0.05)
    assert yaws[2] == 90.0 and yaws[3] is None
    check_chunks(fp)


def test_rtl_climbs_returns_and_lands() -> None:
    fp = mission_to_flight_plan(load_mission(DATA / "rtl.plan"))
    raw = _raw_items(DATA / "rtl.plan")
    wp2 = _ned(raw[2], 10.0)
    pts = [np.asarray(w.pos_ned_m) for w in fp.waypoints]
    np.testing.assert_allclose(pts[1], wp2, atol=1e-6)
    # RTL_RETURN_ALT: 30 m on PX4's multicopter airframes (rc.mc_defaults)
    np.testing.assert_allclose(pts[2], [wp2[0], wp2[1], -30.0], atol=1e-9)
    np.testing.assert_allclose(pts[3], [0.0, 0.0, -30.0], atol=1e-9)
    assert fp.final_action == "rtl" and fp.touchdown_ned_m == (0.0, 0.0, 0.0)
    assert all(w.stop for w in fp.waypoints[1:])
    assert [w.item_index for w in fp.waypoints] == [1, 2, None, 3]
    assert any("item 4: ignored: the mission already ended at item 3" in s for s in fp.warnings)
    assert [c.phase for c in split_flight_plan(fp)] == ["takeoff", "mission", "rtl", "rtl", "land"]
    check_chunks(fp)
    low = mission_to_flight_plan(load_mission(DATA / "rtl.plan"), rtl_return_alt_m=5.0)
    np.testing.assert_allclose(low.waypoints[-1].pos_ned_m, [0.0, 0.0, -10.0], atol=1e-9)
    assert len(low.waypoints) == 3
    check_chunks(low)


def test_implicit_takeoff_autocontinue_and_loiter_unlimited() -> None:
    fp = mission_to_flight_plan(load_mission(DATA / "loiter_unlim.plan"))
    raw = _raw_items(DATA / "loiter_unlim.plan")
    w = fp.waypoints
    # no takeoff item: climb to max(first altitude 1.5 m, MIS_TAKEOFF_ALT 2.5 m) at home
    assert fp.takeoff_alt_m == 2.5
    np.testing.assert_allclose(w[0].pos_ned_m, [0.0, 0.0, -2.5])
    np.testing.assert_allclose(w[1].pos_ned_m, _ned(raw[1], 1.5), atol=1e-6)
    assert w[1].stop and w[1].acceptance_radius_m == 5.0  # autoContinue false, p2 = 5 m
    np.testing.assert_allclose(w[2].pos_ned_m, _ned(raw[2], 8.0), atol=1e-6)
    assert w[2].yaw_deg == 30.0 and fp.final_action == "loiter" and fp.touchdown_ned_m is None
    assert len(w) == 3 and any("item 3: ignored" in s for s in fp.warnings)
    check_chunks(fp)
    low = mission_to_flight_plan(load_mission(DATA / "loiter_unlim.plan"), takeoff_alt_default=1)
    assert low.takeoff_alt_m == 1.5


def test_takeoff_altitude_below_minimum_is_raised() -> None:
    doc = json.loads((EXAMPLES / "square.plan").read_text())
    doc["mission"]["items"][0]["params"][6] = 1.0
    fp = mission_to_flight_plan(parse_plan(json.dumps(doc)))
    assert fp.takeoff_alt_m == 2.5
    doc["mission"]["items"][0]["params"][6] = None
    assert mission_to_flight_plan(parse_plan(json.dumps(doc))).takeoff_alt_m == 2.5


def test_takeoff_away_from_home_climbs_first() -> None:
    doc = json.loads((EXAMPLES / "square.plan").read_text())
    doc["mission"]["items"][0]["params"][4:6] = [47.3979, 8.5458]
    fp = mission_to_flight_plan(parse_plan(json.dumps(doc)))
    np.testing.assert_allclose(fp.waypoints[0].pos_ned_m, [0.0, 0.0, -10.0])
    exp = expected_ne(HOME.lat_deg, HOME.lon_deg, 47.3979, 8.5458)
    np.testing.assert_allclose(fp.waypoints[1].pos_ned_m, [exp[0], exp[1], -10.0], atol=1e-6)
    assert fp.waypoints[1].item_index == 1
    check_chunks(fp)


@pytest.mark.parametrize(("north_m", "hop"), [(1.5, False), (1.99, False), (2.01, True),
                                              (3.0, True)])
def test_takeoff_within_nav_acc_rad_of_home_is_reached_at_the_climbs_top(
        north_m: float, hop: bool) -> None:
    """A TAKEOFF item a GPS fix from home (a mission re-homed where the vehicle stands): within
    NAV_ACC_RAD (2 m) the climb's top is the item, beyond it the plan flies to the item."""
    doc = json.loads((EXAMPLES / "square.plan").read_text())
    lat = HOME.lat_deg + math.degrees(north_m / 6_371_000.0)
    doc["mission"]["items"][0]["params"][4:6] = [lat, HOME.lon_deg]
    fp = mission_to_flight_plan(parse_plan(json.dumps(doc)), acceptance_default=2.0)
    np.testing.assert_allclose(fp.waypoints[0].pos_ned_m, [0.0, 0.0, -10.0])
    if hop:
        assert fp.waypoints[0].item_index is None and fp.waypoints[1].item_index == 1
        assert fp.waypoints[1].pos_ned_m[0] == pytest.approx(north_m, abs=1e-3)
    else:  # the climb's top is item 1; the next point is the square's first corner
        assert fp.waypoints[0].item_index == 1 and fp.waypoints[1].item_index == 2
    check_chunks(fp)


def test_ten_waypoints_example_geometry() -> None:
    path = EXAMPLES / "ten_waypoints.plan"
    raw = _raw_items(path)
    cmds = [r["command"] for r in raw.values()]
    assert cmds == [22] + [16] * 10 + [21]
    alts = [r["params"][6] for r in raw.values() if r["command"] == 16]
    assert min(alts) >= 10 and max(alts) <= 20
    lat = np.array([HOME.lat_deg] + [r["params"][4] for r in raw.values()])
    lon = np.array([HOME.lon_deg] + [r["params"][5] for r in raw.values()])
    d = [distance_bearing(lat[i], lon[i], lat[i + 1], lon[i + 1])[0] for i in range(len(lat) - 1)]
    assert 300.0 <= float(np.sum(d)) <= 600.0
    fp = mission_to_flight_plan(load_mission(path))
    horiz = np.linalg.norm(np.diff(fp.points_ned_m()[:, :2], axis=0), axis=1).sum()
    assert horiz == pytest.approx(float(np.sum(d)), rel=1e-6)
    mission_wps = [w for w in fp.waypoints if w.command == 16]
    assert len(mission_wps) == 10
    assert all(w.acceptance_radius_m == 2.0 for w in mission_wps)
    check_chunks(fp)


def test_five_minute_example_length() -> None:
    raw = _raw_items(EXAMPLES / "five_minute.plan")
    lat = np.array([r["params"][4] for r in raw.values()])
    lon = np.array([r["params"][5] for r in raw.values()])
    d = sum(
        float(distance_bearing(lat[i], lon[i], lat[i + 1], lon[i + 1])[0])
        for i in range(len(lat) - 1)
    )
    assert 1300.0 <= d <= 1500.0  # ~5 minutes at ~5 m/s
    fp = mission_to_flight_plan(load_mission(EXAMPLES / "five_minute.plan"))
    # straight legs at their speeds plus the climb and descent (1.5 and 0.7 m/s)
    climb = fp.takeoff_alt_m
    approx = d / 5.0 + climb / 1.5 + climb / 0.7
    assert fp.nominal_duration_s() == pytest.approx(approx, rel=0.02)
    assert 240.0 <= fp.nominal_duration_s() <= 360.0


def test_rover_ignores_altitude() -> None:
    fp = mission_to_flight_plan(load_mission(EXAMPLES / "rover_square.plan"), vehicle="rover")
    assert fp.takeoff_alt_m == 0.0 and fp.touchdown_ned_m is None
    assert all(w.pos_ned_m[2] == 0.0 for w in fp.waypoints)
    chunks = split_flight_plan(fp)
    assert len(chunks) == 1 and chunks[0].phase == "mission" and len(chunks[0].points_ned_m) == 5
    check_chunks(fp)
    sq = mission_to_flight_plan(load_mission(EXAMPLES / "square.plan"), vehicle="rover")
    assert all(w.pos_ned_m[2] == 0.0 for w in sq.waypoints) and sq.touchdown_ned_m is None
    check_chunks(sq)


def test_multicopter_waypoints_at_ground_level_are_rejected_naming_the_item() -> None:
    """A ground mission (waypoints at 0 m relative) flown as a multicopter: a clear error naming
    the first such item, not a flight skimming the ground; the final LAND at 0 m is fine."""
    rover_square = load_mission(EXAMPLES / "rover_square.plan")
    with pytest.raises(MissionError, match="ground") as exc:
        mission_to_flight_plan(rover_square)
    assert exc.value.item == 1 and "0.0 m above home" in str(exc.value)
    assert "written for a ground rover" in str(exc.value)  # the file's vehicleType is 10
    mission_to_flight_plan(rover_square, vehicle="rover")  # the vehicle it was written for
    doc = json.loads((EXAMPLES / "square.plan").read_text())
    last = doc["mission"]["items"][-1]
    assert last["command"] == 21 and last["params"][6] == 0
    mission_to_flight_plan(parse_plan(json.dumps(doc)))  # LAND at 0 m: accepted
    for alt, ok in ((0.9, False), (1.0, True), (-3.0, False)):
        doc["mission"]["items"][2]["params"][6] = alt  # the second waypoint
        m = parse_plan(json.dumps(doc))
        if ok:
            mission_to_flight_plan(m)
        else:
            with pytest.raises(MissionError) as exc:
                mission_to_flight_plan(m)
            assert exc.value.item == 3
    mission_to_flight_plan(m, min_height_m=-5.0)  # the threshold is a parameter


def test_survey_example_flies_the_pattern_and_respects_the_fence() -> None:
    path = EXAMPLES / "survey.plan"
    fp = mission_to_flight_plan(load_mission(path), strict_geofence=True)
    raw = _raw_items(path)
    survey_wps = [k for k, r in raw.items() if r["command"] == 16]
    got = [w.item_index for w in fp.waypoints if w.command == 16]
    assert got == survey_wps
    assert fp.final_action == "rtl"
    check_chunks(fp)


def test_geofence_breach_warns_or_raises() -> None:
    m = load_mission(DATA / "geofence.plan")
    fp = mission_to_flight_plan(m)
    fence_w = [w for w in fp.warnings if "geofence" in w]
    assert "geofence: waypoint 2 (item 3) is inside exclusion circle 0" in fence_w[0]
    assert any("crosses exclusion circle 0" in w for w in fence_w)
    assert not any("inclusion" in w for w in fence_w)
    with pytest.raises(MissionError, match=r"geofence\.plan: geofence: waypoint 2 \(item 3\)"):
        mission_to_flight_plan(m, strict_geofence=True)


def test_jump_expansion_is_bounded() -> None:
    m = load_mission(DATA / "bad" / "jump_explodes.plan")
    with pytest.raises(MissionError) as info:
        mission_to_flight_plan(m)
    assert "item 4: DO_JUMP expansion exceeds 10000 items (repeat count 20000)" in str(info.value)
    # with a larger budget the same mission expands: 2 items x (20000 + 1) + takeoff
    assert len(expand_jumps(m, max_items=50_000)) == 1 + 2 * 20_001


def test_land_before_takeoff_is_rejected() -> None:
    with pytest.raises(MissionError, match=r"land_first\.plan: item 1: the mission lands"):
        mission_to_flight_plan(load_mission(DATA / "bad" / "land_first.plan"))


def test_speed_edge_values() -> None:
    doc = json.loads((EXAMPLES / "square.plan").read_text())
    items = doc["mission"]["items"]
    speed = {"type": "SimpleItem", "command": 178, "frame": 2, "doJumpId": 50,
             "params": [1, 0, -1, 0, 0, 0, 0]}  # fmt: skip
    items.insert(2, speed)
    fp = mission_to_flight_plan(parse_plan(json.dumps(doc), source="s.plan"))
    assert any("item 3: DO_CHANGE_SPEED: speed 0.0 m/s ignored" in w for w in fp.warnings)
    assert all(w.speed_m_s == 5.0 for w in fp.waypoints[1:])
    speed["params"][1] = -1
    fp = mission_to_flight_plan(parse_plan(json.dumps(doc)), cruise_speed_default=4.0)
    assert not fp.warnings and all(w.speed_m_s == 4.0 for w in fp.waypoints[1:])


def test_bad_defaults_are_rejected() -> None:
    m = load_mission(EXAMPLES / "square.plan")
    for kw in ("takeoff_alt_default", "acceptance_default", "cruise_speed_default"):
        with pytest.raises(ValueError, match=kw):
            mission_to_flight_plan(m, **{kw: 0.0})


def test_upload_items_for_px4() -> None:
    path = DATA / "all_commands.plan"
    raw = _raw_items(path)
    up = mission_upload_items(load_mission(path))
    # the two ignored camera commands (items 12, 13) are not uploaded; seq is 0-based
    assert [u.source_index for u in up] == [1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 14]
    assert [u.seq for u in up] == list(range(12))
    assert [u.current for u in up] == [1] + [0] * 11
    jump = up[7]
    assert jump.command == 177 and jump.param1 == 1.0 and jump.param2 == 1.0  # item 2 -> seq 1
    alt_rel = {1: 12.0, 2: 15.0, 3: 20.0, 4: 10.0, 5: 14.0, 7: 14.0, 9: 0.0, 10: 12.0, 14: 0.0}
    for u in up:
        r = raw[u.source_index]
        if u.source_index in alt_rel:
            assert u.frame == 3
            assert u.x == round(r["params"][4] * 1e7) and u.y == round(r["params"][5] * 1e7)
            assert u.z == pytest.approx(alt_rel[u.source_index])
        else:
            assert u.frame == 2 and (u.x, u.y, u.z) == (0, 0, 0.0)
        assert u.command == r["command"]
    assert (up[2].param1, up[2].param2, up[2].param4) == (3.0, 4.0, 45.0)


def test_upload_items_fill_missing_positions() -> None:
    doc = json.loads((EXAMPLES / "square.plan").read_text())
    items = doc["mission"]["items"]
    items[0]["params"][4:7] = [None, None, None]  # takeoff here, default altitude
    items[-1]["params"][4:6] = [None, None]  # land where the last waypoint is
    up = mission_upload_items(parse_plan(json.dumps(doc)), takeoff_alt_default=3.0)
    assert (up[0].x, up[0].y, up[0].z) == (
        round(HOME.lat_deg * 1e7),
        round(HOME.lon_deg * 1e7),
        3.0,
    )
    assert (up[-1].x, up[-1].y) == (up[-2].x, up[-2].y)


def test_rover_mission_that_only_returns() -> None:
    doc = json.loads((EXAMPLES / "rover_square.plan").read_text())
    doc["mission"]["items"] = [
        {"type": "SimpleItem", "command": 20, "frame": 2, "params": [0, 0, 0, 0, 0, 0, 0]}
    ]
    fp = mission_to_flight_plan(parse_plan(json.dumps(doc)), vehicle="rover")
    assert fp.final_action == "rtl" and fp.path_length_m == 0.0
    assert split_flight_plan(fp) == ()
    with pytest.raises(MissionError, match="item 1: the mission lands/returns before taking off"):
        mission_to_flight_plan(parse_plan(json.dumps(doc)))


@pytest.mark.parametrize("name", ["square.plan", "rover_square.plan"])
def test_chunks_feed_the_planner(name: str) -> None:
    # the contract with companion.trajectory.plan: each chunk is a rest-to-rest trajectory
    # through exactly its points
    from companion.trajectory import Limits, plan_with_info

    m = load_mission(EXAMPLES / name)
    rover = m.vehicle_type == 10
    fp = mission_to_flight_plan(m, vehicle="rover" if rover else "quad")
    for c in split_flight_plan(fp):
        pts = c.points_ned_m[:, :2] if rover else c.points_ned_m
        res = plan_with_info(pts, limits=Limits(max_speed_m_s=c.max_speed_m_s, max_acc_m_s2=3.0))
        traj = res.trajectory
        np.testing.assert_allclose(traj.evaluate(res.waypoint_times), pts, atol=1e-6)
        np.testing.assert_allclose(traj.evaluate(0.0, 1), 0.0, atol=1e-9)
        np.testing.assert_allclose(traj.evaluate(traj.duration, 1), 0.0, atol=1e-9)
