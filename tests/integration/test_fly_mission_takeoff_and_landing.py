"""`fly MISSION` flies the takeoff itself in OFFBOARD and disarms once PX4 detects the landing.

`python -m companion fly tests/data/missions/px4_short.plan --connect udpin://...` against
`sitl_mock serve`, judged from the companion's .tlog, decoded here with pymavlink:

- no NAV_TAKEOFF is sent; the setpoint stream starts while disarmed, OFFBOARD is entered
  disarmed, and the ARM command follows (PX4 accepts both with a live stream, PX4.md);
- attitude mode lands the vehicle itself: no LAND request, the setpoints go on until after the
  DISARM; position mode hands over to LAND while the stream is still running (a setpoint after
  the request);
- the companion's DISARM is sent only after EXTENDED_SYS_STATE says "on ground" after the
  flight, and the vehicle is disarmed by it ("Disarmed by external command"), before PX4's
  COM_DISARM_LAND would have done it;
- every mission waypoint is passed within 0.5 m in attitude mode (issue 13's goal; position
  mode: within its acceptance radius), measured from the mock's
  GLOBAL_POSITION_INT against the file's own coordinates (haversine), so the plan is anchored
  where the vehicle stood, not where a takeoff drifted to.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from pymavlink import mavutil

from tests.integration.test_lossy_link_mission_passes_waypoints import haversine_m, waypoints
from tests.support.mock_process import run_companion, run_mock

# flies in wall-clock time (the mock served over a link): README's second test phase
pytestmark = pytest.mark.realtime

MISSION = Path(__file__).parents[1] / "data" / "missions" / "px4_short.plan"
OFFBOARD, LAND_SUB = 6, 6  # PX4 main mode OFFBOARD; AUTO (4) sub mode LAND
ARM_DISARM, NAV_TAKEOFF, NAV_LAND, DO_SET_MODE = 400, 22, 21, 176
ON_GROUND, IN_AIR = 1, 2
SETPOINTS = {"SET_ATTITUDE_TARGET", "SET_POSITION_TARGET_LOCAL_NED"}
WAYPOINT_GOAL_M = 0.5


def _is_land_request(msg: Any) -> bool:
    cmd = msg.command
    return bool(cmd == NAV_LAND or (cmd == DO_SET_MODE and msg.param2 == 4
                                    and msg.param3 == LAND_SUB))


@pytest.mark.parametrize("mode", ["attitude", "position"])
async def test_mission_takes_off_in_offboard_and_disarms_on_landing(tmp_path: Path,
                                                                   mode: str) -> None:
    tlog = tmp_path / "mission.tlog"
    async with run_mock("--estimator-ready", "0.5") as mock:
        code, text = await run_companion(
            "fly", str(MISSION), "--mode", mode,
            "--connect", f"udpin://127.0.0.1:{mock.client_port}", "--log", str(tlog),
            timeout_s=90.0, what="the mission flight")
        assert code == 0, text[-3000:]

    first_setpoint = offboard_disarmed = arm_sent = armed_at = None
    land_request = on_ground_after_flight = disarm_sent = disarmed_at = None
    airborne = False
    last_setpoint = None
    takeoffs = 0
    disarm_text = ""
    track: list[tuple[float, float, float, float]] = []  # t, lat, lon, relative alt (armed)
    armed = False
    conn = mavutil.mavlink_connection(str(tlog))
    try:
        for _ in range(2_000_000):
            msg = conn.recv_match()
            if msg is None:
                break
            t, kind = msg._timestamp, msg.get_type()
            from_vehicle = msg.get_srcComponent() == 1
            if kind in SETPOINTS and not from_vehicle:
                first_setpoint = first_setpoint if first_setpoint is not None else t
                last_setpoint = t
            elif kind == "COMMAND_LONG" and not from_vehicle:
                if msg.command == NAV_TAKEOFF:
                    takeoffs += 1
                elif msg.command == ARM_DISARM and msg.param1 == 1.0 and arm_sent is None:
                    arm_sent = t
                elif msg.command == ARM_DISARM and msg.param1 == 0.0 and disarm_sent is None:
                    disarm_sent = t
                elif _is_land_request(msg) and land_request is None:
                    land_request = t
            elif kind == "HEARTBEAT" and from_vehicle:
                armed = bool(msg.base_mode & 128)
                main = (msg.custom_mode >> 16) & 0xFF
                if main == OFFBOARD and not armed and offboard_disarmed is None:
                    offboard_disarmed = t
                if armed and armed_at is None:
                    armed_at = t
                if not armed and armed_at is not None and disarmed_at is None:
                    disarmed_at = t
            elif kind == "EXTENDED_SYS_STATE" and from_vehicle:
                airborne = airborne or msg.landed_state == IN_AIR
                if airborne and on_ground_after_flight is None and msg.landed_state == ON_GROUND:
                    on_ground_after_flight = t
            elif kind == "STATUSTEXT" and from_vehicle and "Disarmed" in msg.text:
                disarm_text = msg.text
            elif kind == "GLOBAL_POSITION_INT" and from_vehicle and armed:
                track.append((t, msg.lat * 1e-7, msg.lon * 1e-7, msg.relative_alt * 1e-3))
    finally:
        conn.close()

    assert takeoffs == 0, "PX4's NAV_TAKEOFF was used"
    assert first_setpoint is not None and offboard_disarmed is not None
    assert arm_sent is not None and armed_at is not None
    assert first_setpoint < offboard_disarmed < arm_sent <= armed_at
    assert on_ground_after_flight is not None and disarm_sent is not None
    assert last_setpoint is not None
    assert on_ground_after_flight <= disarm_sent, "DISARM sent before PX4 reported on ground"
    if mode == "position":
        assert land_request is not None and land_request < on_ground_after_flight
        assert last_setpoint > land_request, "the stream stopped before LAND was requested"
    else:
        assert land_request is None, "attitude mode lands by itself"
        assert last_setpoint >= disarm_sent, "the stream stopped before the DISARM"
    assert disarmed_at is not None and disarm_text == "Disarmed by external command", (
        disarm_text)
    # the takeoff starts at the arm: 1 m up within 3 s of it in attitude mode (PX4's
    # NAV_TAKEOFF path: ~6 s); position mode adds PX4's takeoff ramp (MPC_TKO_RAMP_T, 3 s)
    climbing = [t for t, _, _, alt in track if alt > 1.0]
    assert climbing, "never above 1 m"
    assert climbing[0] - armed_at < (3.0 if mode == "attitude" else 6.0), climbing[0] - armed_at

    report = []
    # attitude mode: issue 13's 0.5 m; position mode flies PX4's own position loop, which lags
    # (about 1 m on a corner in the mock, as on PX4): the acceptance radius
    for i, (lat, lon, alt, radius) in enumerate(waypoints(MISSION)):
        goal = WAYPOINT_GOAL_M if mode == "attitude" else radius
        near = [(haversine_m(lat, lon, la, lo), ra) for _, la, lo, ra in track
                if abs(ra - alt) <= 0.5]
        assert near, f"waypoint {i + 1}: never at its altitude {alt} m"
        d = min(n[0] for n in near)
        report.append(f"wp{i + 1} {d:.2f} m")
        assert d <= goal, f"waypoint {i + 1}: closest {d:.2f} m; {report}"
    print("; ".join(report), f"arm -> disarm {disarmed_at - armed_at:.1f} s,",
          f"on ground -> disarm sent {disarm_sent - on_ground_after_flight:.2f} s")
