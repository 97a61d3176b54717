"""Issue 24 (mission meaning lost, reported as ok): NAV_DELAY, items after a NAV_LAND, complex
item versions, VTOL plans, mission-item counts and MAVSDK "Mission Planner" QGC WPL files.

Expectations come from the PX4 / QGroundControl / MAVSDK sources (named per test) and from the
files' own JSON or text, never from the companion's output.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from companion.flatness import MultirotorParams
from companion.mission import MissionError, load_mission, loads_mission, mission_to_flight_plan
from companion.planning.legs import plan_legs
from companion.planning.schedule import VehicleLimits, build_schedule
from tests.support.mission_oracle import expected_ne

EXAMPLES = Path(__file__).resolve().parents[3] / "examples" / "missions"
HOME = (47.397742, 8.545594, 488.0)
M_PER_DEG_LAT = 6371000.0 * math.pi / 180.0
PARAMS = MultirotorParams(mass=1.0, inertia=(0.025, 0.025, 0.03), drag=1.0)


def _north(m: float) -> float:
    return HOME[0] + m / M_PER_DEG_LAT


def _east(m: float) -> float:
    return HOME[1] + m / (M_PER_DEG_LAT * math.cos(math.radians(HOME[0])))


def _simple(cmd: int, params: list[Any], frame: int = 3) -> dict[str, Any]:
    return {"type": "SimpleItem", "command": cmd, "frame": frame, "params": params,
            "autoContinue": True}


def _plan(items: list[dict[str, Any]], vehicle_type: int = 2) -> str:
    return json.dumps({
        "fileType": "Plan", "version": 1, "groundStation": "QGroundControl",
        "geoFence": {"circles": [], "polygons": [], "version": 2},
        "rallyPoints": {"points": [], "version": 2},
        "mission": {"version": 2, "firmwareType": 12, "vehicleType": vehicle_type,
                    "hoverSpeed": 5, "plannedHomePosition": list(HOME), "items": items},
    })


TAKEOFF = _simple(22, [0, 0, 0, None, HOME[0], HOME[1], 10])
WP_A = _simple(16, [0, 0, 0, None, _north(30.0), HOME[1], 10])
WP_B = _simple(16, [0, 0, 0, None, _north(30.0), _east(30.0), 10])
LAND = _simple(21, [0, 0, 0, None, HOME[0], HOME[1], 0])


def _dwell_s(t: np.ndarray, p: np.ndarray, point: np.ndarray, radius_m: float,
             speed_max_m_s: float) -> float:
    """Longest continuous time [s] within ``radius_m`` of ``point`` at a speed below
    ``speed_max_m_s`` (speed from finite differences of the samples)."""
    v = np.linalg.norm(np.diff(p, axis=0), axis=1) / np.diff(t)
    near = (np.linalg.norm(p[1:] - point, axis=1) <= radius_m) & (v <= speed_max_m_s)
    best = run = 0.0
    for k in range(len(near)):
        run = run + (t[k + 1] - t[k]) if near[k] else 0.0
        best = max(best, run)
    return best


# ------------------------------------------------------------------------------ NAV_DELAY
def test_nav_delay_holds_the_plan_at_the_point_for_the_delay() -> None:
    """PX4 (mission_block.cpp get_time_inside: NAV_CMD_DELAY's time_inside = param1) waits the
    delay at the last position setpoint: the planned reference rests at waypoint A >= 5 s."""
    delay = _simple(93, [5, -1, -1, -1, 0, 0, 0], frame=2)
    m = loads_mission(_plan([TAKEOFF, WP_A, delay, WP_B, LAND]), source="delay.plan")
    sched = build_schedule(mission_to_flight_plan(m), PARAMS, VehicleLimits())
    t = np.arange(0.0, sched.duration_s, 0.02)
    p = sched.sample(t)[:, :3]
    ne = expected_ne(HOME[0], HOME[1], _north(30.0), HOME[1])
    point = np.array([ne[0], ne[1], -10.0])
    assert _dwell_s(t, p, point, 0.1, 0.05) >= 5.0 - 0.05
    # without the delay the plan flies through A
    m0 = loads_mission(_plan([TAKEOFF, WP_A, WP_B, LAND]), source="nodelay.plan")
    s0 = build_schedule(mission_to_flight_plan(m0), PARAMS, VehicleLimits())
    t0 = np.arange(0.0, s0.duration_s, 0.02)
    assert _dwell_s(t0, s0.sample(t0)[:, :3], point, 0.1, 0.05) < 1.0
    assert sched.duration_s >= s0.duration_s + 5.0


def test_nav_delay_until_a_time_of_day_is_refused_naming_the_item() -> None:
    """param1 -1 with hour/min/sec: PX4 ignores the time of day (time_inside = max(param1, 0))."""
    delay = _simple(93, [-1, 14, 30, 0, 0, 0, 0], frame=2)
    with pytest.raises(MissionError) as exc:
        loads_mission(_plan([TAKEOFF, WP_A, delay, LAND]), source="tod.plan")
    assert exc.value.item == 3
    assert "time of day" in str(exc.value) and "item 3" in str(exc.value)


def test_nav_delay_before_the_takeoff_is_refused() -> None:
    delay = _simple(93, [5, -1, -1, -1, 0, 0, 0], frame=2)
    m = loads_mission(_plan([delay, TAKEOFF, WP_A, LAND]), source="early.plan")
    with pytest.raises(MissionError) as exc:
        mission_to_flight_plan(m)
    assert exc.value.item == 1 and "NAV_DELAY" in str(exc.value)


# ------------------------------------------------------------------------- after a NAV_LAND
def test_position_items_after_a_land_are_refused_not_dropped() -> None:
    """PX4 v1.16 goes on after a mid-mission NAV_LAND (Commander::handleAutoDisarm: no
    auto-disarm while AUTO.MISSION is unfinished; Mission::do_need_vertical_takeoff takes off
    again when landed): the companion, which cannot, must refuse rather than fly 4 of 6."""
    items = [TAKEOFF, WP_A, LAND, TAKEOFF, WP_B, LAND]
    m = loads_mission(_plan(items), source="twice.plan")
    with pytest.raises(MissionError) as exc:
        mission_to_flight_plan(m)
    assert exc.value.item == 4  # the first item PX4 would fly after landing
    assert "land" in str(exc.value).lower()
    # only non-position items after the landing: PX4 ends the mission there ("Mission
    # finished, landed"), and so does the plan
    speed = _simple(178, [1, 3, -1, 0, 0, 0, 0], frame=2)
    m = loads_mission(_plan([TAKEOFF, WP_A, LAND, speed]), source="tail.plan")
    assert mission_to_flight_plan(m).final_action == "land"


# --------------------------------------------------------------------- complex item versions
def _survey_doc(version: Any, tsci_version: Any = 2, ctype: str = "survey") -> str:
    doc = json.loads((EXAMPLES / "survey.plan").read_text())
    for it in doc["mission"]["items"]:
        if it.get("type") == "ComplexItem":
            it["complexItemType"] = ctype
            it["version"] = version
            it["TransectStyleComplexItem"]["version"] = tsci_version
    return json.dumps(doc)


def _complex_seq(text: str) -> int:
    """QGC sequence number of the complex item (simple items before it count one each)."""
    seq = 1
    for it in json.loads(text)["mission"]["items"]:
        if it.get("type") == "ComplexItem":
            return seq
        seq += 1
    raise AssertionError("no complex item")


@pytest.mark.parametrize(
    ("ctype", "version", "tsci"),
    [("survey", 6, 2), ("survey", 1, 2), ("survey", 5, 3), ("survey", "5", 2),
     ("CorridorScan", 3, 2), ("CorridorScan", 1, 2), ("StructureScan", 2, 2)],
)
def test_complex_item_of_a_version_qgc_rejects_is_refused_naming_it(
        ctype: str, version: Any, tsci: Any) -> None:
    """QGroundControl loads survey 2-5 (SurveyComplexItem.cc), CorridorScan 2
    (CorridorScanComplexItem.cc), StructureScan 3 (StructureScanComplexItem.cc) and a
    TransectStyleComplexItem of version 1-2 (TransectStyleComplexItem.cc); MAVSDK survey 5.
    The versions QGroundControl loads still load."""
    text = _survey_doc(version, tsci, ctype)
    with pytest.raises(MissionError) as exc:
        loads_mission(text, source="versions.plan")
    assert exc.value.item == _complex_seq(text)
    assert ctype in str(exc.value) and "version" in str(exc.value)
    for ok_type, ok_version, ok_tsci in (("survey", 4, 1), ("survey", 5, 2),
                                         ("CorridorScan", 2, 2)):
        m = loads_mission(_survey_doc(ok_version, ok_tsci, ok_type), source="ok.plan")
        assert any(it.complex_type == ok_type for it in m.items)


# ------------------------------------------------------------------------------- VTOL plans
def test_vtol_plan_flies_as_a_multicopter_with_a_warning() -> None:
    """README: a plan for another vehicle kind flies with a warning. PX4 flies NAV_VTOL_TAKEOFF
    / NAV_VTOL_LAND on a rotary-wing vehicle as takeoff (altitude reached) and land
    (mission_block.cpp); QGroundControl writes them into plans for VTOL vehicleTypes."""
    items = [_simple(84, [0, 0, 0, None, HOME[0], HOME[1], 12]), WP_A,
             _simple(3000, [3, 0, 0, 0, 0, 0, 0], frame=2),
             _simple(85, [0, 0, 0, None, HOME[0], HOME[1], 0])]
    m = loads_mission(_plan(items, vehicle_type=20), source="vtol.plan")
    fp = mission_to_flight_plan(m)
    assert fp.takeoff_alt_m == pytest.approx(12.0)
    assert fp.final_action == "land" and fp.touchdown_ned_m is not None
    assert [w.item_index for w in fp.waypoints if w.item_index is not None] == [1, 2, 4]
    assert any("VTOL" in w and "multicopter" in w for w in fp.warnings)
    assert any("3000" in w for w in m.warnings)  # the transition: ignored, said so


def test_readme_sentence_on_other_vehicles_matches_the_code() -> None:
    """README: "A plan written for another kind of vehicle ... is flown with a warning": a
    fixed-wing plan and a VTOL plan as QGroundControl writes it (VTOL takeoff/land items)."""
    root = Path(__file__).resolve().parents[3]
    pages = [root / "README.md", *sorted((root / "docs").rglob("*.md"))]  # README + the manual
    readme = " ".join(" ".join(p.read_text() for p in pages).split())
    assert "written for another kind of vehicle" in readme
    assert "is flown with a warning" in readme
    vtol = [_simple(84, [0, 0, 0, None, HOME[0], HOME[1], 10]), WP_A,
            _simple(85, [0, 0, 0, None, HOME[0], HOME[1], 0])]
    for vtype, items in ((1, [TAKEOFF, WP_A, LAND]), (20, vtol)):
        fp = mission_to_flight_plan(loads_mission(_plan(items, vtype), source="other.plan"))
        assert any(f"vehicleType {vtype}" in w for w in fp.warnings)


# --------------------------------------------------------------------------- counts and legs
_POSITION_COMMANDS = {16, 17, 19, 21, 22}


def test_ten_waypoints_points_to_reach_are_its_position_items_once_each() -> None:
    path = EXAMPLES / "ten_waypoints.plan"
    raw = json.loads(path.read_text())["mission"]["items"]
    expected = [k + 1 for k, it in enumerate(raw) if it["command"] in _POSITION_COMMANDS]
    fp = mission_to_flight_plan(load_mission(path))
    sched = build_schedule(fp, PARAMS, VehicleLimits())
    assert list(sched.item_indices) == expected
    assert len(sched.waypoints_ned) == len(expected)


def test_legs_are_named_by_real_items_never_an_item_to_itself() -> None:
    """A takeoff item away from home: PX4 climbs first and reports the item reached at its own
    position (the climb top is not the item); an implicit takeoff is not the waypoint either."""
    away = _simple(22, [0, 0, 0, None, _north(20.0), HOME[1], 10])
    for items in ([away, WP_B, LAND], [WP_A, WP_B, LAND]):
        fp = mission_to_flight_plan(loads_mission(_plan(items), source="legs.plan"))
        names = [leg.name for leg in plan_legs(fp)]
        assert all(leg.start_item is None or leg.start_item != leg.end_item
                   for leg in plan_legs(fp)), names
        counted = [w.item_index for w in fp.waypoints if w.item_index is not None]
        assert counted == [1, 2, 3], names


# --------------------------------------------------------- MAVSDK "Mission Planner" QGC WPL
MP_RELATIVE = (
    "QGC WPL 110\n"
    f"0\t1\t3\t22\t0\t0\t0\t0\t{HOME[0]:.8f}\t{HOME[1]:.8f}\t15\t1\n"
    f"1\t0\t3\t16\t0\t0\t0\t0\t{_north(25.0):.8f}\t{HOME[1]:.8f}\t15\t1\n"
    f"2\t0\t3\t16\t0\t0\t0\t0\t{_north(25.0):.8f}\t{_east(20.0):.8f}\t15\t1\n"
    f"3\t0\t3\t21\t0\t0\t0\t0\t{HOME[0]:.8f}\t{HOME[1]:.8f}\t0\t1\n"
)


def test_mavsdk_mission_planner_file_row0_is_a_mission_item() -> None:
    """MAVSDK's mission_import.cpp parse_mission_planner reads every row after the header as a
    mission item (for PX4): row 0 here is the NAV_TAKEOFF, not a home row."""
    m = loads_mission(MP_RELATIVE, source="mp.waypoints")
    assert [(it.index, it.command) for it in m.items] == [(0, 22), (1, 16), (2, 16), (3, 21)]
    fp = mission_to_flight_plan(m)
    assert fp.takeoff_alt_m == pytest.approx(15.0)
    ne = expected_ne(HOME[0], HOME[1], _north(25.0), _east(20.0))
    wp2 = next(w for w in fp.waypoints if w.item_index == 2)
    np.testing.assert_allclose(wp2.pos_ned_m, (ne[0], ne[1], -15.0), atol=0.01)
    assert any("row 0" in w for w in m.warnings)


def test_mavsdk_mission_planner_file_with_amsl_altitudes_is_refused_accurately() -> None:
    """MAVSDK's own sample (mission_planner_sample.txt): row 0 a NAV_TAKEOFF in frame 0 (AMSL)
    at 15 m. Without a home row the ground altitude is unknown: refused, saying so (not the
    ground-rover hint)."""
    text = ("QGC WPL 110\n0\t1\t0\t22\t0\t0\t0\t0\t47.39781011\t8.54553801\t15\t1\n"
            "1\t0\t0\t16\t0\t0\t0\t0\t47.39779921\t8.54546693\t15\t1\n")
    with pytest.raises(MissionError) as exc:
        mission_to_flight_plan(loads_mission(text, source="mp_amsl.waypoints"))
    msg = str(exc.value)
    assert "rover" not in msg
    assert "home" in msg and "AMSL" in msg
