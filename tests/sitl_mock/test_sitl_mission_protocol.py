"""Mission protocol (upload / download / clear) and AUTO.MISSION flight on the sans-IO core.

The client side of the protocol is written here by hand from the MAVLink mission protocol
description (shared/PX4.md), independent of sitl_mock.mission_server.
"""

from __future__ import annotations

import math
import struct

from pymavlink.dialects.v20 import common as mavlink

from tests.support.autopilot_harness import Harness

HOME = (47.397742, 8.545594, 488.0)
M_PER_DEG_LAT = 6371000.0 * math.pi / 180.0


def item(
    seq: int,
    cmd: int,
    lat: float = 0.0,
    lon: float = 0.0,
    alt: float = 0.0,
    frame: int = 6,
    p1: float = 0.0,
    p2: float = 0.0,
    p4: float = math.nan,
) -> object:
    return mavlink.MAVLink_mission_item_int_message(
        1, 1, seq, frame, cmd, 1 if seq == 0 else 0, 1, p1, p2, 0.0, p4,
        round(lat * 1e7), round(lon * 1e7), alt, 0,
    )  # fmt: skip


def north_of_home(m: float) -> float:
    return HOME[0] + m / M_PER_DEG_LAT


def east_of_home(m: float) -> float:
    return HOME[1] + m / (M_PER_DEG_LAT * math.cos(math.radians(HOME[0])))


def requests(h: Harness, since: float = -math.inf) -> list[tuple[str, int]]:
    out = []
    for _t, m in h.log:
        if _t >= since and m.get_type() in ("MISSION_REQUEST", "MISSION_REQUEST_INT"):
            out.append((m.get_type(), m.seq))
    return out


def upload(h: Harness, items: list[object]) -> int:
    """Answer every request of the autopilot with the item asked for; return the ACK type."""
    h.run(0.01)
    t = h.now_boot
    h.send(mavlink.MAVLink_mission_count_message(1, 1, len(items), 0))
    answered = 0
    for _ in range(4 * len(items) + 4):
        reqs = requests(h, t)
        if answered < len(reqs):
            _kind, seq = reqs[answered]
            answered += 1
            h.send(items[seq])
            continue
        acks = h.msgs("MISSION_ACK", t)
        if acks:
            return int(acks[-1].type)
        h.run(0.01)
    raise AssertionError("upload did not finish")


def start_auto_mission(items: list[object]) -> Harness:
    """A fresh mock with `items` uploaded, armed and in AUTO.MISSION."""
    h = Harness(step_s=0.02)
    h.run(0.1)
    assert upload(h, items) == 0
    h.wait_ready()
    h.arm()
    h.set_mode(4, 4)
    return h


def download(h: Harness, use_int: bool = True) -> list[object]:
    h.run(0.01)
    t = h.now_boot
    h.send(mavlink.MAVLink_mission_request_list_message(1, 1, 0))
    count = h.msgs("MISSION_COUNT", t)[-1].count
    got = []
    for seq in range(count):
        if use_int:
            h.send(mavlink.MAVLink_mission_request_int_message(1, 1, seq, 0))
            got.append(h.msgs("MISSION_ITEM_INT", t)[-1])
        else:
            h.send(mavlink.MAVLink_mission_request_message(1, 1, seq, 0))
            got.append(h.msgs("MISSION_ITEM", t)[-1])
    h.send(mavlink.MAVLink_mission_ack_message(1, 1, 0, 0))
    return got


SIMPLE = [
    item(0, 22, HOME[0], HOME[1], 5.0),
    item(1, 16, north_of_home(20.0), HOME[1], 5.0),
    item(2, 16, north_of_home(20.0), east_of_home(10.0), 5.0),
]


# ------------------------------------------------------------------------- transfer
def test_upload_first_request_is_float_then_int_and_download_round_trip() -> None:
    h = Harness()
    h.run(0.1)
    assert upload(h, SIMPLE) == mavlink.MAV_MISSION_ACCEPTED
    kinds = requests(h)
    assert kinds[0] == ("MISSION_REQUEST", 0)
    assert kinds[1:] == [("MISSION_REQUEST_INT", 1), ("MISSION_REQUEST_INT", 2)]
    back = download(h)
    for a, b in zip(back, SIMPLE, strict=True):
        assert (a.seq, a.command, a.frame, a.x, a.y) == (b.seq, b.command, b.frame, b.x, b.y)
        assert a.z == b.z
    floats = download(h, use_int=False)
    assert math.isclose(floats[1].x, north_of_home(20.0), abs_tol=1e-5)  # float32 degrees


def test_nack_of_float_request_switches_to_int_requests() -> None:
    h = Harness()
    h.run(0.1)
    h.send(mavlink.MAVLink_mission_count_message(1, 1, 2, 0))
    h.send(mavlink.MAVLink_mission_ack_message(1, 1, mavlink.MAV_MISSION_UNSUPPORTED, 0))
    assert requests(h) == [("MISSION_REQUEST", 0), ("MISSION_REQUEST_INT", 0)]


def test_a_duplicated_nack_or_count_does_not_end_the_upload() -> None:
    """As PX4 (mavlink_mission.cpp, GETLIST), what a duplicating link delivers twice does not
    end an upload: a second UNSUPPORTED toggles back to float requests (the client NACKs
    again), a non-cancelling ACK is ignored, the count again before any item asks again, the
    count again after items is refused as busy (MAV_MISSION_ERROR) while the upload goes on.
    Only CANCELLED ends it."""
    h = Harness()
    h.run(0.1)
    count = mavlink.MAVLink_mission_count_message(1, 1, 3, 0)
    nack = mavlink.MAVLink_mission_ack_message(1, 1, mavlink.MAV_MISSION_UNSUPPORTED, 0)
    h.send(count)
    h.send(nack)
    h.send(nack)  # the duplicate
    h.send(count)  # the duplicate, before any item
    assert requests(h) == [("MISSION_REQUEST", 0), ("MISSION_REQUEST_INT", 0),
                           ("MISSION_REQUEST", 0), ("MISSION_REQUEST", 0)]
    h.send(nack)
    assert requests(h)[-1] == ("MISSION_REQUEST_INT", 0)
    h.send(SIMPLE[0])
    h.send(mavlink.MAVLink_mission_ack_message(1, 1, mavlink.MAV_MISSION_ERROR, 0))
    assert not h.msgs("MISSION_ACK")
    h.send(count)  # the duplicate, after an item
    assert [a.type for a in h.msgs("MISSION_ACK")] == [mavlink.MAV_MISSION_ERROR]
    assert requests(h)[-1] == ("MISSION_REQUEST_INT", 1)
    h.send(SIMPLE[1])
    h.send(SIMPLE[2])
    assert h.msgs("MISSION_ACK")[-1].type == mavlink.MAV_MISSION_ACCEPTED
    assert [m.seq for m in download(h)] == [0, 1, 2]

    h.send(count)
    h.send(mavlink.MAVLink_mission_ack_message(1, 1, mavlink.MAV_MISSION_OPERATION_CANCELLED, 0))
    h.send(SIMPLE[0])  # no transfer any more
    assert h.msgs("MISSION_ACK")[-1].type == mavlink.MAV_MISSION_ERROR


def test_wrong_sequence_is_ignored_and_the_retry_timer_asks_again() -> None:
    """As PX4 (mavlink_mission.cpp, MAVLINK_WPM_STATE_GETLIST): an item out of sequence is
    ignored; the 250 ms retry asks for the expected one again."""
    h = Harness()
    h.run(0.1)
    h.send(mavlink.MAVLink_mission_count_message(1, 1, 3, 0))
    h.send(SIMPLE[0])
    n = len(requests(h))
    h.send(SIMPLE[2])  # out of order: seq 1 expected
    assert len(requests(h)) == n and not h.msgs("MISSION_ACK")
    h.run(0.3)
    assert requests(h)[-1] == ("MISSION_REQUEST_INT", 1)
    h.send(SIMPLE[1])
    h.send(SIMPLE[2])
    assert h.msgs("MISSION_ACK")[-1].type == mavlink.MAV_MISSION_ACCEPTED
    assert [m.seq for m in download(h)] == [0, 1, 2]


def test_the_last_item_again_after_the_upload_is_accepted_again() -> None:
    """As PX4: a client whose ACK was lost sends the last item again and gets ACCEPTED again,
    not an error; any other item without a transfer is an error."""
    h = Harness()
    h.run(0.1)
    assert upload(h, SIMPLE) == mavlink.MAV_MISSION_ACCEPTED
    n = len(h.msgs("MISSION_ACK"))
    h.send(SIMPLE[2])
    acks = h.msgs("MISSION_ACK")
    assert len(acks) == n + 1 and acks[-1].type == mavlink.MAV_MISSION_ACCEPTED
    h.send(SIMPLE[1])
    assert h.msgs("MISSION_ACK")[-1].type == mavlink.MAV_MISSION_ERROR
    assert [m.seq for m in download(h)] == [0, 1, 2]


def test_silent_client_gets_retries_every_250ms_then_operation_timeout() -> None:
    h = Harness()
    h.run(0.1)
    t = h.now_boot
    h.send(mavlink.MAVLink_mission_count_message(1, 1, 3, 0))
    h.send(SIMPLE[0])
    h.run(1.0)
    retries = [r for r in requests(h, t) if r == ("MISSION_REQUEST_INT", 1)]
    assert 4 <= len(retries) <= 6  # 1 request + 4 retries in 1 s
    h.run(4.5)
    assert "Operation timeout" in h.texts(t)
    n = len(requests(h, t))
    h.run(1.0)
    assert len(requests(h, t)) == n  # given up
    assert download(h) == []  # nothing stored


def test_terrain_frame_and_unknown_command_are_rejected_with_mission_results() -> None:
    h = Harness()
    h.run(0.1)
    bad_frame = [item(0, 16, HOME[0], HOME[1], 5.0, frame=10)]
    assert upload(h, bad_frame) == mavlink.MAV_MISSION_UNSUPPORTED_FRAME
    assert any("Mission item 0" in t for t in h.texts())
    bad_cmd = [item(0, 16, HOME[0], HOME[1], 5.0), item(1, 31337, frame=2)]
    assert upload(h, bad_cmd) == mavlink.MAV_MISSION_UNSUPPORTED
    assert download(h) == []


def test_item_without_transfer_and_out_of_range_request_get_errors() -> None:
    h = Harness()
    h.run(0.1)
    h.send(SIMPLE[0])
    assert h.msgs("MISSION_ACK")[-1].type == mavlink.MAV_MISSION_ERROR
    h.send(mavlink.MAVLink_mission_request_int_message(1, 1, 7, 0))
    assert h.msgs("MISSION_ACK")[-1].type == mavlink.MAV_MISSION_INVALID_SEQUENCE


def test_clear_all_and_count_zero_clear_the_mission() -> None:
    h = Harness()
    h.run(0.1)
    upload(h, SIMPLE)
    h.send(mavlink.MAVLink_mission_clear_all_message(1, 1, 0))
    assert h.msgs("MISSION_ACK")[-1].type == mavlink.MAV_MISSION_ACCEPTED
    assert download(h) == []
    h.run(1.1)
    cur = h.last("MISSION_CURRENT")
    # PX4 v1.16 reports "no mission" as total 65535 (measured)
    assert cur.total == 65535 and cur.mission_state == mavlink.MISSION_STATE_NO_MISSION
    assert _mission_id(cur) == 0
    upload(h, SIMPLE)
    assert upload(h, []) == mavlink.MAV_MISSION_ACCEPTED
    assert download(h) == []


def _ext_u32(msg: object, offset: int) -> int:
    """A uint32 extension field at payload ``offset`` from the raw (zero-trimmed) frame."""
    buf = bytes(msg.get_msgbuf())  # type: ignore[attr-defined]
    payload = buf[10:10 + buf[1]] + bytes(32)
    return int(struct.unpack_from("<I", payload, offset)[0])


def _mission_id(msg: object) -> int:
    """MISSION_CURRENT.mission_id from the raw frame (uint32 at payload offset 6, zero-trimmed)."""
    buf = bytes(msg.get_msgbuf())  # type: ignore[attr-defined]
    payload = buf[10:10 + buf[1]] + bytes(18)
    return int(struct.unpack_from("<I", payload, 6)[0])


def test_mission_current_carries_an_id_that_changes_with_the_mission() -> None:
    """Like PX4 v1.16 (MISSION_CURRENT.mission_id = the plan's CRC32): 0 without a mission, new
    with a different upload, unchanged by an identical re-upload."""
    h = Harness()
    h.run(1.1)
    assert _mission_id(h.last("MISSION_CURRENT")) == 0
    upload(h, SIMPLE)
    h.run(1.1)
    first = _mission_id(h.last("MISSION_CURRENT"))
    assert first != 0
    # the accepting MISSION_ACK and a download's MISSION_COUNT carry the same id (opaque_id)
    assert _ext_u32(h.msgs("MISSION_ACK")[-1], 4) == first
    assert download(h) and _ext_u32(h.msgs("MISSION_COUNT")[-1], 5) == first
    upload(h, SIMPLE)
    h.run(1.1)
    assert _mission_id(h.last("MISSION_CURRENT")) == first
    upload(h, SIMPLE[:2])
    h.run(1.1)
    second = _mission_id(h.last("MISSION_CURRENT"))
    assert second not in (0, first)


# ------------------------------------------------------------------------- flight
def _dist_to(h: Harness, n: float, e: float) -> float:
    p = h.ap.state.pos_ned
    return math.hypot(p[0] - n, p[1] - e)


def test_mission_flight_reached_messages_and_finish_loiter() -> None:
    h = start_auto_mission(SIMPLE)
    track: list[tuple[float, tuple[float, float, float]]] = []
    h.run_until(
        lambda: any("Mission finished" in t for t in h.texts()),
        60.0,
        lambda: track.append((h.now_boot, h.ap.state.pos_ned)),
    )
    goals = {1: (20.0, 0.0), 2: (20.0, 10.0)}
    first_reached = {}
    for t_msg, m in h.timed("MISSION_ITEM_REACHED"):
        first_reached.setdefault(m.seq, t_msg)
    assert set(first_reached) == {0, 1, 2}
    for seq, goal in goals.items():
        pos = min(track, key=lambda tp: abs(tp[0] - first_reached[seq]))[1]
        # PX4: each waypoint reported reached ~2 m out (NAV_ACC_RAD 2)
        assert math.hypot(pos[0] - goal[0], pos[1] - goal[1]) <= 2.3
    h.run(1.2)
    assert h.ap.mode.name == "AUTO_LOITER"
    assert h.heartbeat().custom_mode == 50593792
    cur = h.last("MISSION_CURRENT")
    assert (cur.seq, cur.total, cur.mission_state) == (2, 3, mavlink.MISSION_STATE_COMPLETE)
    t = h.now_boot
    h.run(3.0)
    repeats = [m.seq for m in h.msgs("MISSION_ITEM_REACHED", t)]
    assert repeats.count(2) in (3, 4)  # repeated at 1 Hz
    assert _dist_to(h, 20.0, 10.0) < 1.0 and abs(h.ap.state.pos_ned[2] + 5.0) < 0.5


def test_mission_land_item_reached_in_air_then_lands_and_disarms_with_do_jump() -> None:
    h = Harness(step_s=0.02)
    h.run(0.1)
    items = [
        item(0, 22, HOME[0], HOME[1], 4.0),
        item(1, 16, north_of_home(8.0), HOME[1], 4.0),
        item(2, 16, HOME[0], HOME[1], 4.0),
        item(3, 177, frame=2, p1=1.0, p2=1.0),  # DO_JUMP to seq 1, once
        item(4, 21, north_of_home(4.0), HOME[1], 0.0),
    ]
    assert upload(h, items) == 0
    h.wait_ready()
    h.arm()
    h.set_mode(4, 4)
    land_reached_alt: list[float] = []

    def watch() -> None:
        if not land_reached_alt and any(
            m.seq == 4 for m in h.msgs("MISSION_ITEM_REACHED", h.now_boot - 0.03)
        ):
            land_reached_alt.append(-h.ap.state.pos_ned[2])

    h.run_until(lambda: not h.ap.armed, 90.0, watch)
    assert land_reached_alt and land_reached_alt[0] > 2.0  # reached on arrival, in the air
    seqs = [m.seq for m in h.msgs("MISSION_ITEM_REACHED")]
    first = list(dict.fromkeys(seqs))
    assert first[:4] == [0, 1, 2, 4] or first[:3] == [0, 1, 2]
    assert seqs.count(1) >= 2  # waypoint 1 flown twice thanks to DO_JUMP
    assert _dist_to(h, 4.0, 0.0) < 1.0
    assert h.ap.mode.name == "AUTO_MISSION"  # PX4 stays in MISSION after landing


def test_mission_mode_refused_when_armed_without_mission() -> None:
    h = Harness()
    h.wait_ready()
    h.arm()
    t = h.now_boot
    h.set_mode(4, 4)
    h.run(0.05)
    assert h.acks(176, t) == [0, 1]


def test_do_change_speed_limits_the_following_leg() -> None:
    h = Harness(step_s=0.02)
    h.run(0.1)
    items = [
        item(0, 22, HOME[0], HOME[1], 3.0),
        item(1, 178, frame=2, p1=1.0, p2=2.0),  # ground speed 2 m/s
        item(2, 16, north_of_home(25.0), HOME[1], 3.0),
    ]
    assert upload(h, items) == 0
    h.wait_ready()
    h.arm()
    h.set_mode(4, 4)
    speeds: list[float] = []
    h.run_until(
        lambda: any("Mission finished" in t for t in h.texts()),
        60.0,
        lambda: speeds.append(math.hypot(*h.ap.state.vel_ned[:2])),
    )
    assert 1.7 <= max(speeds) <= 2.3  # MPC_XY_CRUISE (5 m/s) would be far above
    h.command_long(178, 1.0, 4.0)
    assert h.acks(178) == [0]


def test_rover_flies_a_multicopter_mission_on_the_ground_and_disarms_at_its_land_point() -> None:
    """A rover in AUTO.MISSION with TAKEOFF, waypoints at 10 m altitude and LAND: the takeoff
    completes at once, the waypoints are driven at ground level, LAND stops it and disarms."""
    h = Harness(step_s=0.02, vehicle_kind="rover")
    h.run(0.1)
    items = [
        item(0, 22, HOME[0], HOME[1], 10.0),
        item(1, 16, north_of_home(15.0), HOME[1], 10.0),
        item(2, 16, north_of_home(15.0), east_of_home(10.0), 10.0),
        item(3, 21, HOME[0], east_of_home(10.0), 0.0),
    ]
    assert upload(h, items) == 0
    h.wait_ready()
    h.arm()
    h.set_mode(4, 4)
    track: list[tuple[float, float, float]] = []
    h.run_until(lambda: not h.ap.armed, 90.0, lambda: track.append(h.ap.state.pos_ned))
    assert all(p[2] == 0.0 for p in track)  # on the ground throughout
    for n, e in ((15.0, 0.0), (15.0, 10.0)):
        assert min(math.hypot(p[0] - n, p[1] - e) for p in track) <= 2.0
    assert _dist_to(h, 0.0, 10.0) < 1.0  # stopped at the land point
    reached = {m.seq for m in h.msgs("MISSION_ITEM_REACHED")}
    assert reached >= {0, 1, 2, 3}
    assert any("Disarmed" in t for t in h.texts())


def _fly_mission(h: Harness, items: list[object]
                 ) -> list[tuple[float, tuple[float, float, float]]]:
    """Upload, arm, AUTO.MISSION until "Mission finished"; the track (t, NED) every step."""
    assert upload(h, items) == 0
    h.wait_ready()
    h.arm()
    h.set_mode(4, 4)
    track: list[tuple[float, tuple[float, float, float]]] = []
    h.run_until(lambda: any("Mission finished" in t for t in h.texts()), 90.0,
                lambda: track.append((h.now_boot, h.ap.state.pos_ned)))
    return track


def _first_reached(h: Harness) -> dict[int, float]:
    first: dict[int, float] = {}
    for t_msg, m in h.timed("MISSION_ITEM_REACHED"):
        first.setdefault(m.seq, t_msg)
    return first


def _pos_at(track: list[tuple[float, tuple[float, float, float]]], t: float
            ) -> tuple[float, float, float]:
    return min(track, key=lambda tp: abs(tp[0] - t))[1]


def test_takeoff_item_away_from_home_climbs_in_place_then_flies_to_its_position() -> None:
    """PX4 (navigator/mission_base.cpp checkClimbRequired, mission.cpp handleTakeoff): from the
    ground the vehicle climbs vertically where it stands to the takeoff altitude, then the
    TAKEOFF item becomes a waypoint at its own lat/lon, reported reached only there."""
    tko_n, tko_e, alt = 6.0, -4.0, 5.0  # 7.2 m from home
    h = Harness(step_s=0.02)
    h.run(0.1)
    track = _fly_mission(h, [
        item(0, 22, north_of_home(tko_n), east_of_home(tko_e), alt),
        item(1, 16, north_of_home(20.0), HOME[1], alt),
    ])
    start = track[0][1]
    climbing = [p for _t, p in track if -p[2] < 0.9 * alt]
    assert max(math.hypot(p[0] - start[0], p[1] - start[1]) for p in climbing) < 0.5
    first = _first_reached(h)
    assert set(first) == {0, 1} and first[0] < first[1]
    at_reached = _pos_at(track, first[0])
    nav_acc_rad = 2.0  # PX4's NAV_ACC_RAD default; the item gives none
    assert math.hypot(at_reached[0] - tko_n, at_reached[1] - tko_e) <= nav_acc_rad + 0.3
    assert abs(-at_reached[2] - alt) < 1.0


def test_takeoff_item_in_the_air_is_flown_as_a_waypoint() -> None:
    """PX4 (mission.cpp handleTakeoff): no climb needed, a TAKEOFF item is a waypoint."""
    h = Harness(step_s=0.02)
    h.run(0.1)
    track = _fly_mission(h, [
        item(0, 22, HOME[0], HOME[1], 5.0),
        item(1, 16, north_of_home(10.0), HOME[1], 5.0),
        item(2, 22, north_of_home(10.0), east_of_home(10.0), 5.0),
    ])
    first = _first_reached(h)
    assert set(first) == {0, 1, 2}
    at_reached = _pos_at(track, first[2])
    assert math.hypot(at_reached[0] - 10.0, at_reached[1] - 10.0) <= 2.3
