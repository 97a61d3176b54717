"""Sans-IO autopilot core on a fake clock, driven by a pymavlink client (the harness).

Expected values are PX4 v1.16 facts from shared/PX4.md (typed here independently of the
code), physical laws, or round trips through pymavlink.
"""

from __future__ import annotations

import math
import struct

import pytest
from pymavlink.dialects.v20 import common as mavlink

from tests.support.autopilot_harness import Harness

LOITER_CUSTOM = 50593792  # AUTO.LOITER: main 4, sub 3
OFFBOARD_CUSTOM = 393216
POSCTL_CUSTOM = 196608
TAKEOFF_CUSTOM = 33816576
LAND_CUSTOM = 100925440
MISSION_CUSTOM = 67371008


def hb_triplet(h: Harness) -> tuple[int, int, int]:
    hb = h.heartbeat()
    return hb.base_mode, hb.custom_mode, hb.system_status


def flying(h: Harness, alt_m: float = 2.5) -> None:
    """Ready, armed, taken off and hovering in AUTO.LOITER."""
    h.wait_ready()
    h.arm()
    h.takeoff()
    h.run_until(lambda: h.ap.mode.name == "AUTO_LOITER" and not h.ap.state.landed, 20.0)
    h.run(1.0)


def in_offboard(h: Harness, n: float = 0.0, e: float = 0.0, d: float = -2.5) -> None:
    flying(h)
    h.run(0.3, lambda: h.pos_setpoint(n, e, d))
    h.set_mode(6)
    h.run(0.05, lambda: h.pos_setpoint(n, e, d))
    assert h.ap.mode.name == "OFFBOARD"
    # the 1 Hz HEARTBEAT shows it within a second
    h.run_until(
        lambda: h.heartbeat().custom_mode == OFFBOARD_CUSTOM, 1.1, lambda: h.pos_setpoint(n, e, d)
    )


# ------------------------------------------------------------------------- identity
def test_heartbeat_identity_boot_and_ready_values() -> None:
    h = Harness()
    h.run(1.5)
    hb = h.heartbeat()
    assert (hb.type, hb.autopilot, hb.mavlink_version) == (2, 12, 3)
    assert (hb.get_srcSystem(), hb.get_srcComponent()) == (1, 1)
    assert hb_triplet(h) == (29, LOITER_CUSTOM, 0)  # estimator not ready yet
    h.run(2.5)
    assert hb_triplet(h) == (29, LOITER_CUSTOM, 3)
    assert all(raw[0] == 0xFD for raw in h.raw)  # MAVLink 2 only


def test_rover_heartbeat_type() -> None:
    h = Harness(vehicle_kind="rover")
    h.run(1.2)
    assert h.heartbeat().type == 10


def test_onboard_stream_rates_match_px4() -> None:
    h = Harness()
    h.run(10.0)
    px4_hz = {
        "ATTITUDE": 100, "ATTITUDE_QUATERNION": 50, "GLOBAL_POSITION_INT": 50,
        "LOCAL_POSITION_NED": 30, "ODOMETRY": 30, "ATTITUDE_TARGET": 10,
        "SYS_STATUS": 5, "EXTENDED_SYS_STATE": 5,
        "TIMESYNC": 10, "HEARTBEAT": 1,
    }  # fmt: skip
    for name, hz in px4_hz.items():
        n = len(h.timed(name, since=4.0))  # 6 s window, after the estimator is ready
        assert abs(n - 6 * hz) <= max(1, 0.1 * 6 * hz), (name, n)
    homes = h.timed("HOME_POSITION", since=3.5)
    assert 2 <= len(homes) <= 5  # 0.5 Hz (+1 when home is set)
    # position targets are published while a position controller runs (here: takeoff, hold)
    h.arm()
    h.takeoff()
    t = h.now_boot + 0.05
    h.run(3.0)
    assert 29 <= len(h.timed("POSITION_TARGET_LOCAL_NED", t)) <= 31


def test_sys_status_bits_when_ready_and_not() -> None:
    h = Harness()
    h.run(1.0)
    early = h.last("SYS_STATUS")
    assert not early.onboard_control_sensors_health & 268435456  # PREARM not yet
    h.run(3.0)
    s = h.last("SYS_STATUS")
    assert s.onboard_control_sensors_present == 50348079
    assert s.onboard_control_sensors_enabled == 50413615
    assert s.onboard_control_sensors_health == 320915519
    ext = h.last("EXTENDED_SYS_STATE")
    assert ext.landed_state == 1


def test_home_position_and_autopilot_version_on_request() -> None:
    h = Harness(home=(47.0, 8.0, 500.0))
    h.wait_ready()
    t = h.now_boot
    h.command_long(512, 148)
    h.command_long(512, 242)
    h.command_long(520, 1)
    assert h.acks(512, t) == [0, 0] and h.acks(520, t) == [0]
    versions = h.msgs("AUTOPILOT_VERSION", t)
    assert len(versions) == 2 and all(v.capabilities & 4 for v in versions)  # MISSION_INT
    home = h.msgs("HOME_POSITION", t)[-1]
    assert (home.latitude, home.longitude, home.altitude) == (470000000, 80000000, 500000)


# ------------------------------------------------------------------------- arming
def test_arming_refused_until_estimator_ready_then_accepted() -> None:
    h = Harness()
    h.run(1.0)
    h.arm()
    assert h.acks(400) == [1]  # TEMPORARILY_REJECTED
    assert any("Resolve system health failures" in t for t in h.texts())
    assert not h.ap.armed
    h.wait_ready()
    assert 2.0 <= h.now_boot <= 4.0  # PX4 SIH: ~2-4 s after start
    t = h.now_boot
    h.arm()
    assert h.acks(400, t) == [0]
    h.run(1.1)
    assert hb_triplet(h) == (157, LOITER_CUSTOM, 4)
    # forced arming still runs the preflight checks: a fresh mock refuses it too
    h2 = Harness()
    h2.run(0.5)
    h2.arm(force=True)
    assert h2.acks(400) == [1]


def test_arming_in_posctl_without_rc_denied_until_pilot_present() -> None:
    h = Harness()
    h.wait_ready()
    h.set_mode(3)
    h.run(1.05)
    assert h.acks(176) == [0, 0]  # disarmed: any mode is accepted
    assert hb_triplet(h)[2] == 0  # cannot arm in this mode: UNINIT
    h.arm()
    assert h.acks(400)[-1] == 1
    h.ap.set_rc_present(True)
    h.arm()
    assert h.acks(400)[-1] == 0


def test_arm_param_out_of_range_is_denied() -> None:
    h = Harness()
    h.wait_ready()
    h.command_long(400, 2.0)
    h.command_long(400, math.nan)
    assert h.acks(400) == [2, 2]  # DENIED
    assert not h.ap.armed


@pytest.mark.parametrize("prflt", [10.0, 4.0])
def test_auto_disarm_without_takeoff_after_com_disarm_prflt(prflt: float) -> None:
    h = Harness(params={"COM_DISARM_PRFLT": prflt})
    h.wait_ready()
    t_arm = h.now_boot
    h.arm()
    elapsed = h.run_until(lambda: not h.ap.armed, prflt + 3.0)
    assert abs(elapsed - prflt) <= 0.05
    assert any("Disarmed" in t for t in h.texts(t_arm))
    assert h.now_boot - t_arm >= prflt - 0.05


def test_disarm_in_air_rejected_unless_forced() -> None:
    h = Harness()
    flying(h)
    t = h.now_boot
    h.command_long(400, 0.0)
    assert h.acks(400, t) == [1]
    assert h.ap.armed
    h.command_long(400, 0.0, 21196.0)
    assert h.acks(400, t) == [1, 0]
    assert not h.ap.armed


# ------------------------------------------------------------------------- takeoff / land
def test_takeoff_climbs_to_mis_takeoff_alt_then_hold_with_px4_timing() -> None:
    h = Harness()
    h.wait_ready()
    t_arm = h.now_boot
    h.arm()
    h.takeoff()
    h.run(0.5)
    assert hb_triplet(h) == (157, TAKEOFF_CUSTOM, 4) or h.ap.mode.name == "AUTO_TAKEOFF"
    assert h.last("EXTENDED_SYS_STATE").landed_state == 3  # MAV_LANDED_STATE_TAKEOFF
    h.run_until(lambda: -h.ap.state.pos_ned[2] > 1.5, 15.0)
    t_up = h.now_boot - t_arm
    assert 6.6 * 0.7 <= t_up <= 6.6 * 1.3, t_up  # PX4 SITL: ~6.6 s from the arm command
    h.run_until(lambda: h.ap.mode.name == "AUTO_LOITER", 15.0)
    assert 6.0 * 0.7 <= h.now_boot - t_arm <= 6.0 * 1.5
    h.run(1.5)
    assert abs(-h.ap.state.pos_ned[2] - 2.5) < 0.3
    assert h.last("EXTENDED_SYS_STATE").landed_state == 2
    assert hb_triplet(h) == (157, LOITER_CUSTOM, 4)


def test_takeoff_accepted_while_disarmed_starts_when_armed() -> None:
    h = Harness()
    h.wait_ready()
    h.takeoff(488.0 + 4.0)  # AMSL: 4 m above home
    assert h.acks(22) == [0]
    h.run(1.0)
    assert h.ap.mode.name == "AUTO_TAKEOFF" and h.ap.state.landed
    h.arm()
    h.run_until(lambda: h.ap.mode.name == "AUTO_LOITER", 20.0)
    h.run(2.0)
    assert abs(-h.ap.state.pos_ned[2] - 4.0) < 0.4


def test_land_reports_landing_and_disarms_two_seconds_after_touchdown() -> None:
    h = Harness()
    flying(h)
    h.command_long(21)
    h.run(1.05)
    assert hb_triplet(h) == (157, LAND_CUSTOM, 4)
    assert h.last("EXTENDED_SYS_STATE").landed_state == 4
    h.run_until(lambda: h.ap.state.landed, 20.0)
    t_land = h.now_boot
    h.run_until(lambda: not h.ap.armed, 5.0)
    assert abs(h.now_boot - t_land - 2.0) <= 0.05  # COM_DISARM_LAND
    h.run(0.5)
    assert h.last("EXTENDED_SYS_STATE").landed_state == 1


# ------------------------------------------------------------------------- modes / commands
def test_do_set_mode_double_ack_10ms_apart() -> None:
    h = Harness(step_s=0.001)
    h.wait_ready()
    t = h.now_boot
    h.set_mode(4, 4)  # AUTO.MISSION with no mission, disarmed: accepted
    h.run(0.05)
    acks = [(tt, m.result) for tt, m in h.timed("COMMAND_ACK", t) if m.command == 176]
    assert [r for _tt, r in acks] == [0, 0]
    assert 0.008 <= acks[1][0] - acks[0][0] <= 0.015
    h.run(1.1)
    assert h.heartbeat().custom_mode == MISSION_CUSTOM


def test_unknown_command_single_unsupported_ack_and_wrong_target_ignored() -> None:
    h = Harness()
    h.wait_ready()
    h.command_long(31999)
    assert h.acks(31999) == [3]
    h.command_long(400, 1.0, target=(2, 1))
    h.command_long(400, 1.0, target=(1, 55))
    h.run(0.2)
    assert h.acks(400) == [] and not h.ap.armed
    assert h.ap.stats["rx_wrong_target"] == 2
    h.send(mavlink.MAVLink_command_int_message(1, 1, 0, 31999, 0, 0, 0, 0, 0, 0, 0, 0, 0))
    assert h.acks(31999) == [3, 3]


def test_command_int_takeoff_relative_altitude() -> None:
    h = Harness()
    h.wait_ready()
    h.arm()
    h.send(
        mavlink.MAVLink_command_int_message(
            1, 1, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, 22, 0, 0, 0, 0, 0, math.nan,
            0x7FFFFFFF, 0x7FFFFFFF, 3.5,
        )
    )  # fmt: skip
    assert h.acks(22) == [0]
    h.run_until(lambda: h.ap.mode.name == "AUTO_LOITER", 20.0)
    h.run(2.0)
    assert abs(-h.ap.state.pos_ned[2] - 3.5) < 0.4


def test_set_message_interval_rules() -> None:
    h = Harness()
    h.run(1.0)
    h.command_long(511, 0, 100000)  # HEARTBEAT: refused
    h.command_long(511, mavlink.MAVLINK_MSG_ID_ATTITUDE, 100000)  # 10 Hz
    h.command_long(511, mavlink.MAVLINK_MSG_ID_ODOMETRY, -1)  # disable
    assert h.acks(511) == [4, 0, 0]  # FAILED, ACCEPTED, ACCEPTED
    t = h.now_boot + 0.05
    h.run(3.0)
    n_att = len(h.timed("ATTITUDE", t))
    assert 29 <= n_att <= 31
    assert h.timed("ODOMETRY", t) == []
    assert 2 <= len(h.timed("HEARTBEAT", t)) <= 4  # unchanged at 1 Hz


def test_timesync_answered_without_target_filter_and_own_requests() -> None:
    h = Harness()
    h.run(2.0)
    t = h.now_boot
    h.send(mavlink.MAVLink_timesync_message(0, 123456789))
    replies = [m for m in h.msgs("TIMESYNC", t) if m.tc1 != 0]
    assert len(replies) == 1 and replies[0].ts1 == 123456789
    assert abs(replies[0].tc1 * 1e-9 - h.now_boot) < 0.02  # responder's boot time in ns
    requests = [m for m in h.msgs("TIMESYNC") if m.tc1 == 0]
    assert len(requests) >= 15  # 10 Hz


def test_ping_request_answered() -> None:
    h = Harness()
    h.run(0.5)
    h.send(mavlink.MAVLink_ping_message(987654, 42, 0, 0))
    pongs = [m for m in h.msgs("PING") if m.seq == 42]
    assert len(pongs) == 1
    assert (pongs[0].time_usec, pongs[0].target_system, pongs[0].target_component) == (
        987654, 255, 190,
    )  # fmt: skip


# ------------------------------------------------------------------------- params
def _int_from_param_value(v: float) -> int:
    return int(struct.unpack("<i", struct.pack("<f", v))[0])


def test_params_read_set_list_with_px4_bytewise_ints() -> None:
    h = Harness()
    h.run(0.2)
    h.send(mavlink.MAVLink_param_request_read_message(1, 1, b"MPC_THR_HOVER", -1))
    pv = h.last("PARAM_VALUE")
    assert pv.param_id == "MPC_THR_HOVER" and pv.param_value == pytest.approx(0.5)
    assert pv.param_type == mavlink.MAV_PARAM_TYPE_REAL32
    h.send(mavlink.MAVLink_param_request_read_message(1, 1, b"COM_OBL_RC_ACT", -1))
    pv = h.last("PARAM_VALUE")
    assert pv.param_type == mavlink.MAV_PARAM_TYPE_INT32
    assert _int_from_param_value(pv.param_value) == 0
    bits4 = struct.unpack("<f", struct.pack("<i", 4))[0]
    h.send(
        mavlink.MAVLink_param_set_message(
            1, 1, b"COM_OBL_RC_ACT", bits4, mavlink.MAV_PARAM_TYPE_INT32
        )
    )
    echo = h.last("PARAM_VALUE")
    assert echo.param_id == "COM_OBL_RC_ACT" and _int_from_param_value(echo.param_value) == 4
    assert h.ap.params["COM_OBL_RC_ACT"] == 4
    n_before = len(h.msgs("PARAM_VALUE"))
    h.send(mavlink.MAVLink_param_set_message(1, 1, b"NO_SUCH_PARAM", 1.0, 9))
    h.send(mavlink.MAVLink_param_request_read_message(1, 1, b"NO_SUCH_PARAM", -1))
    assert len(h.msgs("PARAM_VALUE")) == n_before  # unknown: silently ignored
    h.send(mavlink.MAVLink_param_request_list_message(1, 1))
    listed = h.msgs("PARAM_VALUE")[n_before:]
    assert len(listed) == listed[0].param_count == len(h.ap.params)
    assert sorted(m.param_index for m in listed) == list(range(len(listed)))


# ------------------------------------------------------------------------- statustext
def test_long_statustext_is_chunked_and_reassembles() -> None:
    h = Harness()
    h.ap.statustext(mavlink.MAV_SEVERITY_INFO, "x" * 30 + "y" * 50 + "z" * 20)
    h.ap.statustext(mavlink.MAV_SEVERITY_INFO, "a" * 100)  # exact multiple of 50
    h.run(0.02)
    chunks = h.msgs("STATUSTEXT")
    by_id: dict[int, list[tuple[int, str]]] = {}
    for c in chunks:
        assert c.id != 0
        by_id.setdefault(c.id, []).append((c.chunk_seq, c.text))
    texts = ["".join(t for _s, t in sorted(v)) for v in by_id.values()]
    assert texts == ["x" * 30 + "y" * 50 + "z" * 20, "a" * 100]
    assert [len(v) for v in by_id.values()] == [3, 3]  # the 100-char text ends with an empty chunk


def test_command_retries_with_confirmation_are_each_acknowledged() -> None:
    h = Harness()
    h.wait_ready()
    for confirmation in range(3):  # a client that did not see the ACK retries (MAVSDK: 3 times)
        h.command_long(400, 1.0, confirmation=confirmation)
    assert h.acks(400) == [0, 0, 0] and h.ap.armed
    h.command_long(400, 0.0)
    assert h.acks(400)[-1] == 0 and not h.ap.armed
