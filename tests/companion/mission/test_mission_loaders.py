"""Loader tests on hand-written .plan / QGC WPL files: every command and frame, every error."""

from __future__ import annotations

import json
import logging
import math
import re
from pathlib import Path

import numpy as np
import pytest

from companion.mission import (
    GeoPoint,
    Mission,
    MissionError,
    load_mission,
    loads_mission,
    mission_to_flight_plan,
    parse_plan,
    parse_wpl,
)
from tests.support.mission_oracle import expected_ne

DATA = Path(__file__).resolve().parents[2] / "data" / "missions"
EXAMPLES = Path(__file__).resolve().parents[3] / "examples" / "missions"
HOME = GeoPoint(47.397742, 8.545594, 488.0)


def _same_items(a: Mission, b: Mission) -> None:
    assert len(a.items) == len(b.items)
    for x, y in zip(a.items, b.items, strict=True):
        assert (x.index, x.command, x.frame, x.autocontinue) == (
            y.index,
            y.command,
            y.frame,
            y.autocontinue,
        )
        np.testing.assert_array_equal(np.asarray(x.params), np.asarray(y.params))


def test_all_commands_plan_items() -> None:
    m = load_mission(DATA / "all_commands.plan")
    assert m.file_format == "plan"
    assert m.home == HOME
    assert [it.index for it in m.items] == list(range(1, 15))
    assert [it.command for it in m.items] == [
        22, 16, 16, 16, 16, 178, 19, 177, 195, 16, 197, 206, 2000, 21
    ]  # fmt: skip
    assert [it.frame for it in m.items[:5]] == [3, 3, 0, 5, 6]
    # null params are NaN, numbers are kept
    assert math.isnan(m.items[1].params[3])
    assert m.items[2].params[:4] == (3.0, 4.0, 0.0, 45.0)
    assert m.items[2].alt_rel_home_m(m.home) == pytest.approx(20.0)
    assert m.items[3].alt_rel_home_m(m.home) == pytest.approx(10.0)
    assert m.items[4].alt_rel_home_m(m.home) == pytest.approx(14.0)
    assert m.items[2].altitude_mode == 2
    assert m.items[1].do_jump_id == 2
    # DO_JUMP param1 (a doJumpId in a .plan) is normalised to the target item's index
    assert m.items[7].params[0] == 2.0 and m.items[7].params[1] == 1.0
    assert m.vehicle_type == 2 and m.hover_speed_m_s == 5.0
    # unknown commands without a position are skipped with a warning naming them
    assert len(m.warnings) == 2
    assert "item 12: command 206 (DO_SET_CAM_TRIGG_DIST) ignored" in m.warnings[0]
    assert "item 13: command 2000" in m.warnings[1]
    assert "all_commands.plan" in m.warnings[0]


def test_all_commands_wpl_equals_plan() -> None:
    plan = load_mission(DATA / "all_commands.plan")
    wpl = load_mission(DATA / "all_commands.waypoints")
    assert wpl.file_format == "wpl"
    assert wpl.home == plan.home
    _same_items(plan, wpl)
    assert [w.split(":", 1)[1] for w in wpl.warnings] == [w.split(":", 1)[1] for w in plan.warnings]


def test_unknown_command_warning_is_logged(caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.WARNING, logger="companion.mission"):
        load_mission(DATA / "all_commands.waypoints")
    assert any("DO_SET_CAM_TRIGG_DIST" in r.getMessage() for r in caplog.records)


def test_square_plan_and_wpl_give_the_same_flight() -> None:
    a = mission_to_flight_plan(load_mission(EXAMPLES / "square.plan"))
    b = mission_to_flight_plan(load_mission(EXAMPLES / "square.waypoints"))
    np.testing.assert_allclose(a.points_ned_m(), b.points_ned_m(), atol=1e-9)
    assert a.final_action == b.final_action == "land"


def test_survey_complex_item_is_expanded() -> None:
    m = load_mission(EXAMPLES / "survey.plan")
    raw = json.loads((EXAMPLES / "survey.plan").read_text())
    sub = raw["mission"]["items"][1]["TransectStyleComplexItem"]["Items"]
    survey_items = [it for it in m.items if it.complex_type == "survey"]
    assert len(survey_items) == len(sub) > 0
    # consecutive QGC sequence numbers after the takeoff (1), RTL after the pattern
    assert [it.index for it in survey_items] == list(range(2, 2 + len(sub)))
    assert m.items[-1].command == 20 and m.items[-1].index == 2 + len(sub)
    for it, s in zip(survey_items, sub, strict=True):
        assert it.command == s["command"]
        if s["command"] == 16:
            assert (it.lat_deg, it.lon_deg, it.alt_m) == tuple(s["params"][4:7])
    # geofence: one inclusion polygon, one exclusion circle; rally points with NED
    assert len(m.geofence.polygons) == 1 and m.geofence.polygons[0].inclusion
    assert len(m.geofence.circles) == 1 and not m.geofence.circles[0].inclusion
    assert len(m.rally) == 2
    # the example's rally points are usable: inside the fence
    assert m.geofence.contains(np.array([r.pos_ned_m for r in m.rally])).all()
    for rp, r in zip(m.rally, raw["rallyPoints"]["points"], strict=True):
        ne = expected_ne(HOME.lat_deg, HOME.lon_deg, r[0], r[1])
        np.testing.assert_allclose(rp.pos_ned_m[:2], ne, atol=1e-6)
        assert rp.pos_ned_m[2] == -r[2] == -rp.alt_rel_home_m


def test_corridor_scan_is_expanded() -> None:
    m = load_mission(DATA / "corridor.plan")
    assert [it.complex_type for it in m.items] == [None, *["CorridorScan"] * 5, None, None]
    assert [it.index for it in m.items] == list(range(1, 9))
    assert "items 3, 5: command 206" in m.warnings[0]
    assert "in CorridorScan" not in m.warnings[0]


def test_geofence_is_projected() -> None:
    m = load_mission(DATA / "geofence.plan")
    raw = json.loads((DATA / "geofence.plan").read_text())
    for poly, rp in zip(m.geofence.polygons, raw["geoFence"]["polygons"], strict=True):
        assert poly.inclusion == rp["inclusion"]
        v = np.asarray(rp["polygon"])
        np.testing.assert_allclose(
            poly.vertices_ne_m,
            expected_ne(HOME.lat_deg, HOME.lon_deg, v[:, 0], v[:, 1]),
            atol=1e-6,
        )
    for circ, rc in zip(m.geofence.circles, raw["geoFence"]["circles"], strict=True):
        c = rc["circle"]["center"]
        np.testing.assert_allclose(
            circ.center_ne_m, expected_ne(HOME.lat_deg, HOME.lon_deg, c[0], c[1]), atol=1e-6
        )
        assert circ.radius_m == rc["circle"]["radius"]


def test_geofence_version1_single_polygon() -> None:
    doc = json.loads((EXAMPLES / "square.plan").read_text())
    doc["geoFence"] = {"version": 1, "polygon": [[47.3970, 8.5445], [47.3990, 8.5445],
                                                 [47.3990, 8.5475]]}  # fmt: skip
    m = parse_plan(json.dumps(doc), source="v1.plan")
    assert len(m.geofence.polygons) == 1 and m.geofence.polygons[0].inclusion


@pytest.mark.parametrize("path", sorted(EXAMPLES.iterdir()), ids=lambda p: p.name)
def test_examples_load_and_fly(path: Path) -> None:
    m = load_mission(path)
    vehicle = "rover" if m.vehicle_type == 10 else "quad"
    fp = mission_to_flight_plan(m, vehicle=vehicle)
    assert len(fp.waypoints) >= 4
    assert np.all(np.isfinite(fp.points_ned_m()))
    assert not [w for w in fp.warnings if "geofence" in w]


def test_home_override() -> None:
    other = GeoPoint(47.0, 8.0, 400.0)
    m = load_mission(EXAMPLES / "square.waypoints", home=GeoPoint(47.3977, 8.5456, 500.0))
    assert m.home == GeoPoint(47.3977, 8.5456, 500.0)
    text = (DATA / "bad" / "no_home.plan").read_text()
    assert parse_plan(text, home=other).home == other


def test_wpl_tolerates_crlf_spaces_and_bom() -> None:
    text = (EXAMPLES / "square.waypoints").read_text()
    variant = "\ufeff" + text.replace("\t", "  ").replace("\n", "\r\n") + "\r\n\r\n"
    _same_items(parse_wpl(text), loads_mission(variant.encode("utf-8")))


def test_loads_detects_format_and_names_source() -> None:
    text = (EXAMPLES / "square.plan").read_text()
    assert loads_mission(text, source="x.plan").file_format == "plan"
    with pytest.raises(MissionError, match=r"^x\.txt: not a mission file"):
        loads_mission("garbage", source="x.txt")


# (file, expected message parts); every message starts with the file name
BAD = [
    ("terrain_frame.plan", ["item 4: frame 10 (terrain) needs terrain data"]),
    ("terrain_frame.waypoints", ["item 2: frame 11 (terrain) needs terrain data", "line 4"]),
    ("unknown_positional.plan", ["item 3: command 82 (NAV_SPLINE_WAYPOINT) is not supported",
                                 "carries a position"]),
    ("unknown_command_with_position.plan", ["item 2: command 31000", "carries a position"]),
    ("bad_params.plan", ["item 2: params must be a list of 7"]),
    ("command_is_string.plan", ["item 2: command must be an integer"]),
    ("jump_forever.plan", ["item 3: DO_JUMP: repeat count -1 (repeat forever)"]),
    ("jump_missing_target.plan", ["item 3: DO_JUMP: target doJumpId 99 not found"]),
    ("jump_missing_target.waypoints", ["item 3: DO_JUMP: target item 7 does not exist"]),
    ("swapped_latlon.plan", ["item 2:", "km from home", "latitude/longitude order"]),
    ("waypoint_frame_mission.plan", ["item 2: NAV_WAYPOINT in frame 2 (MISSION) has no position"]),
    ("local_frame.plan", ["item 2: frame 1 (LOCAL_NED) is not supported"]),
    ("waypoint_no_altitude.plan", ["item 2: NAV_WAYPOINT needs an altitude"]),
    ("structure_scan.plan", ["item 2: StructureScan has no pre-expanded items"]),
    ("no_home.plan", ["no plannedHomePosition"]),
    ("wrong_filetype.plan", ['fileType is "Mission", expected "Plan"']),
    ("truncated.plan", ["not valid JSON", "line 5"]),
    ("fence_two_vertices.plan", ["geoFence polygon 0 needs at least 3 vertices"]),
    ("fence_negative_radius.plan", ["geoFence circle 0: radius must be a positive number"]),
    ("not_utf8.plan", ["not UTF-8"]),
    ("empty.plan", ["the file is empty"]),
    ("bad_header.waypoints", ['unsupported header "QGC WPL 120"']),
    ("not_a_mission.waypoints", ["not a mission file"]),
    ("short_line.waypoints", ["item 2: expected 12 fields", "got 11", "line 4"]),
    ("bad_number.waypoints", ["item 2: LAT must be a number", '"abc"', "line 4"]),
    ("out_of_order.waypoints", ["item 3: INDEX 3 out of order (expected 2)"]),
    ("latitude_out_of_range.waypoints", ["item 2: NAV_WAYPOINT latitude 95.0", "out of range"]),
    ("no_home.waypoints", ["the first item must be home (INDEX 0)"]),
]  # fmt: skip


@pytest.mark.parametrize(("name", "parts"), BAD, ids=[b[0] for b in BAD])
def test_bad_files_give_clear_errors(name: str, parts: list[str]) -> None:
    path = DATA / "bad" / name
    with pytest.raises(MissionError) as info:
        load_mission(path)
    msg = str(info.value)
    assert msg.startswith(str(path) + ": "), msg
    for part in parts:
        assert part in msg, msg
    assert info.value.source == str(path)
    m = re.match(r"item (\d+):", parts[0])
    if m:
        assert info.value.item == int(m.group(1))


def test_missing_file_is_a_mission_error(tmp_path: Path) -> None:
    with pytest.raises(MissionError, match="cannot read the file"):
        load_mission(tmp_path / "nope.plan")


def test_every_bad_file_is_covered() -> None:
    assert {p.name for p in (DATA / "bad").iterdir()} == {b[0] for b in BAD} | {
        "jump_explodes.plan",
        "land_first.plan",
    }


@pytest.mark.parametrize(
    ("mutate", "part"),
    [
        (lambda d: d.update(version=2), "plan version 2 is not supported"),
        (lambda d: d["mission"].update(version=1), "mission version 1 is not supported"),
        (lambda d: d["mission"].update(items={}), '"mission.items" must be a list'),
        (lambda d: d["mission"]["items"].append(3), "item 7: mission.items[6] must be an object"),
        (
            lambda d: d["mission"]["items"][2].update(type="Fancy"),
            "item 3: mission.items[2]: unknown item type",
        ),
        (lambda d: d["mission"]["items"][1].update(frame=2.5), "item 2: frame must be an integer"),
        (lambda d: d["mission"]["items"][1]["params"].__setitem__(0, "x"), "item 2: param1 must"),
        (lambda d: d["mission"]["items"][1]["params"].__setitem__(0, -1), "hold time -1"),
        (lambda d: d["mission"]["items"][1]["params"].__setitem__(1, -2), "acceptance radius -2"),
        (lambda d: d["mission"]["items"][1].update(autoContinue="yes"), "autoContinue must be"),
        (lambda d: d["mission"].update(plannedHomePosition=[1, 2]), "plannedHomePosition must"),
        (lambda d: d["mission"].update(plannedHomePosition=[91, 2, 3]), "out of range"),
        (lambda d: d.update(geoFence=[]), '"geoFence" must be an object'),
        (lambda d: d.update(rallyPoints={"points": [[47.39, 8.54]]}), "rally point 0 must be"),
        (lambda d: d["mission"]["items"][1]["params"].__setitem__(6, 1e400), "must be finite"),
        (
            lambda d: d["mission"]["items"].insert(
                1, {"type": "ComplexItem", "complexItemType": "spiral"}
            ),
            'item 2: complex item type "spiral" is not supported',
        ),
    ],
)
def test_plan_field_errors(mutate: object, part: str) -> None:
    doc = json.loads((EXAMPLES / "square.plan").read_text())
    assert callable(mutate)
    mutate(doc)
    with pytest.raises(MissionError) as info:
        parse_plan(json.dumps(doc), source="edited.plan")
    assert str(info.value).startswith("edited.plan: ")
    assert part in str(info.value)


def test_mission_error_pickles_with_its_parts() -> None:
    import pickle

    err = MissionError("a.plan", "frame 10 (terrain) needs terrain data", item=4)
    back = pickle.loads(pickle.dumps(err))
    assert isinstance(back, MissionError) and isinstance(back, ValueError)
    assert (str(back), back.source, back.item, back.detail) == (
        "a.plan: item 4: frame 10 (terrain) needs terrain data",
        "a.plan",
        4,
        "frame 10 (terrain) needs terrain data",
    )
    m = load_mission(EXAMPLES / "survey.plan")
    fp = mission_to_flight_plan(m)
    assert pickle.loads(pickle.dumps(fp)).waypoints == fp.waypoints


def test_point_opposite_home_is_rejected() -> None:
    text = (EXAMPLES / "square.waypoints").read_text().splitlines()
    f = text[3].split("\t")
    f[8], f[9] = str(-HOME.lat_deg), str(HOME.lon_deg - 180.0)
    text[3] = "\t".join(f)
    with pytest.raises(MissionError, match=r"item 2: NAV_WAYPOINT is .* km from home"):
        parse_wpl("\n".join(text))
