"""Two links like PX4 SITL, peer locking, get_timer; RTL; the rover through the same core."""

from __future__ import annotations

import math

from pymavlink.dialects.v20 import common as mavlink

from sitl_mock.autopilot import Autopilot
from tests.sitl_mock.test_sitl_autopilot_core import flying
from tests.support.autopilot_harness import Harness

API = ("127.0.0.1", 14540)
GCS = ("127.0.0.1", 14550)


def _types(datagrams: list[tuple[bytes, object]]) -> list[str]:
    out = []
    for data, _addr in datagrams:
        out.extend(m.get_type() for m in mavlink.MAVLink(None).parse_buffer(data) or [])
    return out


def test_two_links_send_first_lock_onto_peer_and_answer_on_the_asking_link() -> None:
    ap = Autopilot(remotes={"offboard": API, "gcs": GCS}, now=100.0)
    ap.advance(101.5)
    off = ap.datagrams_to_send(101.5, "offboard")
    gcs = ap.datagrams_to_send(101.5, "gcs")
    assert {a for _d, a in off} == {API} and {a for _d, a in gcs} == {GCS}
    assert "HEARTBEAT" in _types(off) and "HEARTBEAT" in _types(gcs)
    assert len(off) > 5 * len(gcs)  # onboard rates on the API link, a light set for the GCS
    # a client on another port talks on the GCS link: replies and streams go there
    mav = mavlink.MAVLink(None, 255, 190)
    other = ("127.0.0.1", 40000)
    cmd = mavlink.MAVLink_command_long_message(1, 1, 31999, 0, 0, 0, 0, 0, 0, 0, 0)
    ap.receive_datagram(cmd.pack(mav), other, 101.6, "gcs")
    gcs = ap.datagrams_to_send(101.6, "gcs")
    assert "COMMAND_ACK" in _types(gcs) and {a for _d, a in gcs} == {other}
    assert "COMMAND_ACK" not in _types(ap.datagrams_to_send(101.6, "offboard"))
    # STATUSTEXT goes out on every link
    ap.statustext(mavlink.MAV_SEVERITY_INFO, "hello")
    assert "STATUSTEXT" in _types(ap.datagrams_to_send(101.6, "offboard"))
    assert "STATUSTEXT" in _types(ap.datagrams_to_send(101.6, "gcs"))


def test_get_timer_is_the_next_physics_step_and_handle_timer_advances() -> None:
    ap = Autopilot(remotes={"offboard": API}, now=50.0, physics_hz=500.0)
    t = ap.get_timer()
    assert math.isclose(t, 50.0 + 1.0 / 500.0)
    ap.handle_timer(t)
    assert math.isclose(ap.now, t)
    assert math.isclose(ap.get_timer(), t)  # telemetry produced at t is waiting to be sent
    assert ap.datagrams_to_send(t)
    assert math.isclose(ap.get_timer(), 50.0 + 2.0 / 500.0)
    ap.advance(40.0)  # the past: ignored
    assert math.isclose(ap.now, t)


def test_return_to_launch_flies_home_and_lands() -> None:
    h = Harness(params={"RTL_RETURN_ALT": 8.0})
    flying(h)
    h.command_long(192, -1, 1, 0, math.nan, 47.397742 + 15 / 111195.0, 8.545594, 488.0 + 5.0)
    assert h.acks(192) == [0]  # DO_REPOSITION: 15 m north, 5 m up
    h.run_until(lambda: h.ap.state.pos_ned[0] > 13.0, 20.0)
    h.command_long(20)
    assert h.acks(20) == [0]
    h.run(1.1)
    assert h.heartbeat().custom_mode == (4 << 16) | (5 << 24)
    h.run_until(lambda: not h.ap.armed, 60.0)
    n, e, _d = h.ap.state.pos_ned
    assert math.hypot(n, e) < 1.0


def test_rover_heartbeat_arming_and_offboard_velocity() -> None:
    h = Harness(vehicle_kind="rover")
    h.wait_ready()
    assert h.heartbeat().type == 10
    h.takeoff()
    assert h.acks(22) == [3]  # UNSUPPORTED for a rover
    vel_only = 0b110111000111
    sp = mavlink.MAVLink_set_position_target_local_ned_message(
        0, 1, 1, 1, vel_only, 0, 0, 0, 0.0, 1.0, 0, 0, 0, 0, 0, 0
    )
    h.run(0.3, lambda: h.send(sp))
    h.set_mode(6)
    h.arm()
    assert h.acks(400)[-1] == 0
    h.run(6.0, lambda: h.send(sp))
    vn, ve, _ = h.ap.state.vel_ned
    assert ve > 0.8 and abs(vn) < 0.2  # drives east
    assert h.last("EXTENDED_SYS_STATE").landed_state == 1  # never "in air"
    h.run(12.0, lambda: h.send(sp))
    assert h.ap.armed  # no auto-disarm on a rover
