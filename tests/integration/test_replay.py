"""Replay of a bundled mission in lockstep: waypoints reached (judged from the tlog's
GLOBAL_POSITION_INT against the file's own coordinates), tlog integrity, report and plot."""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pymavlink import mavutil

from companion.app.cli import main as cli_main

ROOT = Path(__file__).resolve().parents[2]
MISSION = ROOT / "examples" / "missions" / "ten_waypoints.plan"
R_EARTH = 6_371_000.0


def _flat_ne(lat: float, lon: float, lat0: float, lon0: float) -> tuple[float, float]:
    """Independent local projection (equirectangular about the home point) [m]."""
    north = math.radians(lat - lat0) * R_EARTH
    east = math.radians(lon - lon0) * R_EARTH * math.cos(math.radians(lat0))
    return north, east


_OPEN_LOGS: list[Any] = []


def _open_tlog(path: str) -> Any:
    """A pymavlink tlog reader, closed by the autouse fixture below after the test."""
    conn = mavutil.mavlink_connection(path)
    _OPEN_LOGS.append(conn)
    return conn


@pytest.fixture(autouse=True)
def _close_tlogs() -> Iterator[None]:
    try:
        yield
    finally:
        while _OPEN_LOGS:
            _OPEN_LOGS.pop().close()


@pytest.fixture(scope="module")
def replayed(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("replay")
    code = cli_main(["replay", str(MISSION), "--out", str(out)])
    assert code == 0
    return out / MISSION.stem


def test_every_waypoint_reached_from_tlog_positions(replayed: Path) -> None:
    plan = json.loads(MISSION.read_text())
    lat0, lon0, alt0 = plan["mission"]["plannedHomePosition"]
    wps = []
    for it in plan["mission"]["items"]:
        if it["command"] == 16:  # NAV_WAYPOINT, relative altitude frame 3
            lat, lon, rel = it["params"][4:7]
            n, e = _flat_ne(lat, lon, lat0, lon0)
            radius = it["params"][1] or 2.0
            wps.append((n, e, -rel, radius))
    assert len(wps) == 10
    mlog = _open_tlog(str(replayed / "flight.tlog"))
    flown = []
    while True:
        m = mlog.recv_match(type="GLOBAL_POSITION_INT")
        if m is None:
            break
        n, e = _flat_ne(m.lat * 1e-7, m.lon * 1e-7, lat0, lon0)
        flown.append((n, e, -(m.alt * 1e-3 - alt0)))
    assert len(flown) > 100
    p = np.asarray(flown)
    for i, (n, e, d, radius) in enumerate(wps):
        closest = float(np.min(np.linalg.norm(p - np.array([n, e, d]), axis=1)))
        assert closest <= radius, f"waypoint {i + 1}: closest approach {closest:.2f} m > {radius} m"


def test_tlog_carries_the_mission_items_at_the_file_coordinates(replayed: Path) -> None:
    """QGroundControl and MAVExplorer show a log's mission from its MISSION_ITEM_INT frames."""
    from pymavlink import mavwp

    plan = json.loads(MISSION.read_text())
    in_file = [it for it in plan["mission"]["items"] if it["command"] in (16, 22, 21)]
    mlog = _open_tlog(str(replayed / "flight.tlog"))
    # one type set per connection: pymavlink's indexed tlog reader keeps the first one
    kinds = ["MISSION_COUNT", "MISSION_ITEM_INT"]
    count = mlog.recv_match(type=kinds)
    assert count is not None and count.get_type() == "MISSION_COUNT"
    assert count.count == len(plan["mission"]["items"])
    loader = mavwp.MAVWPLoader()
    items = []
    while len(items) < count.count:
        m = mlog.recv_match(type=kinds)
        assert m is not None and m.get_type() == "MISSION_ITEM_INT"
        items.append(m)
        loader.set(m, m.seq)
    assert loader.count() == count.count
    assert [m.seq for m in items] == list(range(count.count))
    positional = [m for m in items if m.command in (16, 22, 21)]
    assert len(positional) == len(in_file)
    for m, it in zip(positional, in_file, strict=True):
        lat, lon, rel = it["params"][4:7]
        assert m.command == it["command"]
        assert abs(m.x * 1e-7 - lat) < 1e-7 and abs(m.y * 1e-7 - lon) < 1e-7
        assert m.z == pytest.approx(rel, abs=1e-3) and m.frame == 3


def test_tlog_reads_back_with_expected_message_counts(replayed: Path) -> None:
    report = json.loads((replayed / "report.json").read_text())
    mlog = _open_tlog(str(replayed / "flight.tlog"))
    hb_px4 = 0
    setpoints = []
    stamps = []
    while True:
        m = mlog.recv_match()
        if m is None:
            break
        stamps.append(m._timestamp)
        if m.get_type() == "HEARTBEAT" and m.get_srcSystem() == 1 and m.get_srcComponent() == 1:
            hb_px4 += 1
        if m.get_type() in ("SET_ATTITUDE_TARGET", "SET_POSITION_TARGET_LOCAL_NED"):
            setpoints.append(m._timestamp)
    assert stamps == sorted(stamps)  # timestamps monotonic
    span = stamps[-1] - stamps[0]
    assert abs(hb_px4 - span) <= 2.0  # PX4 HEARTBEAT at 1 Hz over the whole log
    streamed = setpoints[-1] - setpoints[0]
    rate = report["setpoint_rate_hz"]
    assert len(setpoints) == pytest.approx(rate * streamed, rel=0.05)
    assert report["setpoints_sent"] == len(setpoints)


def test_companion_lands_itself_and_disarms_once_px4_reports_on_ground(replayed: Path) -> None:
    """Attitude mode lands the quad itself: no NAV_LAND, the setpoints go on until PX4's land
    detector says "on ground" after the flight (EXTENDED_SYS_STATE), the companion's DISARM
    follows at once, and it is what disarms the vehicle (not COM_DISARM_LAND)."""
    mlog = _open_tlog(str(replayed / "flight.tlog"))
    airborne = False
    on_ground_t = disarm_t = last_setpoint_t = None
    lands = 0
    texts = []
    while True:
        m = mlog.recv_match()
        if m is None:
            break
        kind, t = m.get_type(), m._timestamp
        if kind == "COMMAND_LONG" and m.command == 21:
            lands += 1
        elif kind == "EXTENDED_SYS_STATE" and m.landed_state == 2:
            airborne = True
        elif kind == "EXTENDED_SYS_STATE" and airborne and m.landed_state == 1:
            on_ground_t = t if on_ground_t is None else on_ground_t
        elif kind == "COMMAND_LONG" and m.command == 400 and m.param1 == 0.0 and disarm_t is None:
            disarm_t = t
        elif kind == "SET_ATTITUDE_TARGET":
            last_setpoint_t = t
        elif kind == "STATUSTEXT" and "Disarmed" in m.text:
            texts.append(m.text)
    assert lands == 0
    assert on_ground_t is not None and disarm_t is not None and last_setpoint_t is not None
    assert on_ground_t <= disarm_t < on_ground_t + 0.5
    assert last_setpoint_t >= disarm_t  # still streaming while it disarms
    assert texts == ["Disarmed by external command"]


def test_report_duration_runs_from_the_accepted_arm_to_the_disarmed_heartbeat(
        replayed: Path) -> None:
    """The report's armed time starts at the accepted ARM (COMMAND_ACK), as the AUTO.MISSION
    flight it is compared with: the 1 Hz HEARTBEAT shows "armed" up to 1 s later, and starting
    there cut the takeoff short (flown takeoff legs quicker than their time-optimal bound)."""
    mlog = _open_tlog(str(replayed / "flight.tlog"))
    ack_t = disarmed_t = None
    armed_seen = False
    while True:
        m = mlog.recv_match(type=["COMMAND_ACK", "HEARTBEAT"])
        if m is None:
            break
        if m.get_type() == "COMMAND_ACK":
            if m.command == 400 and m.result == 0 and ack_t is None:
                ack_t = m._timestamp
        elif m.get_srcComponent() == 1 and m.type == 2:  # the quad's own heartbeat
            armed = bool(m.base_mode & 128)
            armed_seen = armed_seen or armed
            if armed_seen and not armed and disarmed_t is None:
                disarmed_t = m._timestamp
    assert ack_t is not None and disarmed_t is not None
    report = json.loads((replayed / "report.json").read_text())
    assert report["duration_s"] == pytest.approx(disarmed_t - ack_t, abs=0.05)
    takeoff = report["legs"][0]
    assert takeoff["time_over_bound"] >= 1.0, takeoff  # rest on the ground until lift-off


def test_report_and_plot(replayed: Path) -> None:
    import matplotlib.image as mpimg

    report = json.loads((replayed / "report.json").read_text())
    for key in (
        "duration_s",
        "path_length_m",
        "rms_error_m",
        "max_error_m",
        "max_speed_m_s",
        "max_tilt_deg",
        "max_thrust_norm",
        "max_body_rate_rad_s",
        "geofence_violations",
        "failsafes",
        "waypoints",
    ):
        assert key in report
    assert report["result"] == "ok"
    assert report["failsafes"] == []
    assert all("closest_approach_m" in w for w in report["waypoints"])
    img = mpimg.imread(replayed / "flight.png")
    assert img.ndim == 3 and img.shape[0] > 200 and img.shape[1] > 400
    assert float(np.std(img[..., :3])) > 0.01  # not blank
    # nothing half-written left behind
    assert not [p for p in replayed.parent.iterdir() if p.name.startswith(".")]


def test_malformed_file_exits_2_and_others_still_run(tmp_path: Path) -> None:
    bad = tmp_path / "broken.plan"
    bad.write_text('{"fileType": "Plan", "version": 1, "mission": {"items": [}')
    good = ROOT / "examples" / "missions" / "square.plan"
    out = tmp_path / "out"
    code = cli_main(["replay", str(bad), str(good), "--out", str(out)])
    assert code == 2
    assert (out / "square" / "report.json").is_file()
    assert not (out / "broken").exists()


# ----------------------------------------------------------------------------- rover
ROVER_MISSION = ROOT / "examples" / "missions" / "rover_square.plan"


def _rover_track(tlog: Path, lat0: float, lon0: float) -> tuple[np.ndarray, np.ndarray]:
    """(north, east) positions [m] and ground speeds [m/s] from the tlog's GLOBAL_POSITION_INT."""
    mlog = _open_tlog(str(tlog))
    pos, speed = [], []
    while True:
        m = mlog.recv_match(type="GLOBAL_POSITION_INT")
        if m is None:
            break
        pos.append(_flat_ne(m.lat * 1e-7, m.lon * 1e-7, lat0, lon0))
        speed.append(math.hypot(m.vx, m.vy) * 0.01)
    return np.asarray(pos), np.asarray(speed)


def _commanded_speeds(tlog: Path) -> np.ndarray:
    """Horizontal speeds [m/s] of the velocity setpoints the companion sent."""
    mlog = _open_tlog(str(tlog))
    out = []
    while True:
        m = mlog.recv_match(type="SET_POSITION_TARGET_LOCAL_NED")
        if m is None:
            break
        out.append(math.hypot(m.vx, m.vy))
    return np.asarray(out)


def test_rover_replay_reaches_every_corner_within_its_top_speed(tmp_path: Path) -> None:
    """The rover is planned and commanded within the mock rover's RO_SPEED_LIM (3 m/s): judged
    from the tlog against the file's own coordinates, every corner is reached within the
    rover's NAV_ACC_RAD (0.5 m), no setpoint asks more than 3 m/s, and the rover drives at most
    PX4's open-loop overshoot above it (real PX4's rover: 15-18 %)."""
    plan = json.loads(ROVER_MISSION.read_text())
    lat0, lon0, _ = plan["mission"]["plannedHomePosition"]
    corners = [
        _flat_ne(*it["params"][4:6], lat0, lon0)
        for it in plan["mission"]["items"]
        if it["command"] == 16
    ]
    assert len(corners) == 4
    code = cli_main(["replay", str(ROVER_MISSION), "--vehicle", "rover", "--out", str(tmp_path)])
    assert code == 0
    pos, speed = _rover_track(tmp_path / ROVER_MISSION.stem / "flight.tlog", lat0, lon0)
    assert len(pos) > 100
    for i, c in enumerate(corners):
        closest = float(np.min(np.linalg.norm(pos - np.asarray(c), axis=1)))
        assert closest <= 0.5, f"corner {i + 1}: closest approach {closest:.2f} m"
    sent = _commanded_speeds(tmp_path / ROVER_MISSION.stem / "flight.tlog")
    assert len(sent) > 100 and float(np.max(sent)) <= 3.0 + 1e-6
    assert float(np.max(speed)) <= 3.0 * 1.18


def test_rover_slower_than_its_plan_is_waited_for_and_passes_every_corner(
    tmp_path: Path
) -> None:
    """A rover whose throttle gives half the speed PX4 expects (RO_MAX_THR_SPEED 6.4 m/s for a
    drive that gives 3.2: at the full 3 m/s command it drives under 2 m/s, planned at 2.7 m/s)
    is waited for (`ProgressGovernor`) instead of being run away from: it passes every
    waypoint of the square within NAV_ACC_RAD, takes longer than planned (the 120 m of legs
    alone take 60 s at 2 m/s), and its error against the reference it was given stays within
    the governor's stop lag plus the controller's slack."""
    code = cli_main(["replay", str(ROVER_MISSION), "--vehicle", "rover", "--out", str(tmp_path),
                     "--no-plot", "--mock-param", "RO_MAX_THR_SPEED=6.4"])
    assert code == 0
    report = json.loads((tmp_path / ROVER_MISSION.stem / "report.json").read_text())
    assert report["waypoints_reached"] == len(report["waypoints"])
    assert all(w["acceptance_radius_m"] == 0.5 for w in report["waypoints"])
    assert report["duration_s"] > 60.0 > report["planned_duration_s"]
    assert report["max_error_m"] < 4.0


def test_replay_in_wind_lands_and_completes_both_flights(tmp_path: Path) -> None:
    """4 m/s of wind: the companion's flight and the mock's AUTO.MISSION both finish (landed and
    disarmed, not timed out) with every waypoint reached."""
    square = ROOT / "examples" / "missions" / "square.plan"
    code = cli_main(
        ["replay", str(square), "--wind", "4", "--compare-px4-mission", "--out", str(tmp_path)]
    )
    assert code == 0
    report = json.loads((tmp_path / "square" / "report.json").read_text())
    assert report["result"] == "ok"
    assert report["px4_mission"]["result"] == "ok"
    assert report["px4_mission"]["waypoints_reached"] == len(report["px4_mission"]["waypoints"])


# ----------------------------------------------------------------------------- issue 24
_POSITION_COMMANDS = {16, 17, 19, 21, 22}


def test_report_counts_the_mission_items_not_the_points_the_plan_adds(replayed: Path) -> None:
    """ten_waypoints.plan has 12 position items (takeoff, 10 waypoints, land): the report lists
    each once, by its QGC item number, and no leg runs from an item to itself."""
    items = json.loads(MISSION.read_text())["mission"]["items"]
    expected = [k + 1 for k, it in enumerate(items) if it["command"] in _POSITION_COMMANDS]
    report = json.loads((replayed / "report.json").read_text())
    assert [w["item_index"] for w in report["waypoints"]] == expected
    assert report["waypoints_reached"] <= len(expected)
    for leg in report["legs"]:
        assert leg["from_item"] is None or leg["from_item"] != leg["to_item"], leg["leg"]


def _delay_plan(path: Path, delay_s: float) -> tuple[float, float, float]:
    """square.plan with a NAV_DELAY of ``delay_s`` after its second waypoint; returns that
    waypoint (lat, lon, relative altitude) as written in the file."""
    doc = json.loads((ROOT / "examples" / "missions" / "square.plan").read_text())
    items = doc["mission"]["items"]
    k = [i for i, it in enumerate(items) if it["command"] == 16][1]
    wp = items[k]["params"]
    delay = {"type": "SimpleItem", "command": 93, "frame": 2, "autoContinue": True,
             "params": [delay_s, -1, -1, -1, 0, 0, 0]}
    items.insert(k + 1, delay)
    for n, it in enumerate(items):
        it["doJumpId"] = n + 1
    path.write_text(json.dumps(doc))
    return float(wp[4]), float(wp[5]), float(wp[6])


def test_replay_dwells_at_the_point_for_a_nav_delay(tmp_path: Path) -> None:
    """PX4's navigator waits NAV_DELAY's param1 at the last setpoint (mission_block.cpp,
    get_time_inside): judged from the tlog, the vehicle rests (< 0.3 m/s) within 1 m of the
    waypoint before the delay for at least the 5 s of the delay."""
    plan = tmp_path / "delay.plan"
    lat, lon, rel = _delay_plan(plan, 5.0)
    doc = json.loads(plan.read_text())
    lat0, lon0, alt0 = doc["mission"]["plannedHomePosition"]
    code = cli_main(["replay", str(plan), "--out", str(tmp_path / "out")])
    assert code == 0
    n0, e0 = _flat_ne(lat, lon, lat0, lon0)
    mlog = _open_tlog(str(tmp_path / "out" / "delay" / "flight.tlog"))
    t, near = [], []
    while True:
        m = mlog.recv_match(type="GLOBAL_POSITION_INT")
        if m is None:
            break
        n, e = _flat_ne(m.lat * 1e-7, m.lon * 1e-7, lat0, lon0)
        d = math.hypot(n - n0, e - e0, -(m.alt * 1e-3 - alt0) + rel)
        speed = math.sqrt(m.vx**2 + m.vy**2 + m.vz**2) * 0.01
        t.append(m._timestamp)
        near.append(d <= 1.0 and speed < 0.3)
    best = run_start = None
    longest = 0.0
    for ti, ok in zip(t, near, strict=True):
        if ok and run_start is None:
            run_start = ti
        elif not ok:
            run_start = None
        if run_start is not None and ti - run_start > longest:
            longest, best = ti - run_start, run_start
    assert best is not None and longest >= 5.0 - 0.1, f"dwell {longest:.2f} s"
