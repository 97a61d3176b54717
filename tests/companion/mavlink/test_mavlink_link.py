"""VehicleLink end to end over real frames (bytes), heartbeat tracking, telemetry, TIMESYNC."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as m
from scipy.spatial.transform import Rotation

from companion.mavlink import (
    ArmedChanged,
    Codec,
    CommandFinished,
    FlightMode,
    LinkConfig,
    LinkLost,
    LinkUp,
    LocalPosition,
    ModeChanged,
    StatusText,
    TelemetryState,
    TimeSync,
    TimesyncUpdate,
    VehicleLink,
)
from tests.support.mavlink_fakes import Outbox, Px4Side, command_ack, heartbeat

HOLD_DISARMED = (29, 50593792)
OFFBOARD_ARMED = (145, 393216)
HOLD_ARMED = (157, 50593792)


def feed(link: VehicleLink, px4: Px4Side, msg: Any, now: float) -> list[Any]:
    return link.receive_bytes(px4.frame(msg), now)


def test_heartbeat_link_up_mode_armed_and_loss() -> None:
    link, px4 = VehicleLink(), Px4Side()
    ev = feed(link, px4, heartbeat(*HOLD_DISARMED, status=3), 0.0)
    assert any(isinstance(e, LinkUp) and not e.regained for e in ev)
    assert link.mode is FlightMode.HOLD and not link.armed
    ev = feed(link, px4, heartbeat(*OFFBOARD_ARMED), 1.0)
    (mc,) = [e for e in ev if isinstance(e, ModeChanged)]
    assert (mc.old, mc.new) == (FlightMode.HOLD, FlightMode.OFFBOARD)
    assert [e.armed for e in ev if isinstance(e, ArmedChanged)] == [True]
    assert link.get_timer() is not None
    assert not any(isinstance(e, LinkLost) for e in link.handle_timer(3.9))
    assert any(isinstance(e, LinkLost) for e in link.handle_timer(4.0))
    ev = feed(link, px4, heartbeat(*OFFBOARD_ARMED), 9.0)
    assert any(isinstance(e, LinkUp) and e.regained for e in ev)


def test_transport_loss_declares_link_lost_once() -> None:
    link, px4 = VehicleLink(), Px4Side()
    assert link.transport_lost(0.0) == []  # never up: nothing to lose
    feed(link, px4, heartbeat(*HOLD_ARMED), 1.0)
    (lost,) = link.transport_lost(1.5)
    assert isinstance(lost, LinkLost) and lost.silent_for_s == pytest.approx(0.5)
    assert link.transport_lost(1.6) == []
    assert not any(isinstance(e, LinkLost) for e in link.handle_timer(1.7))  # no second loss
    ev = feed(link, px4, heartbeat(*HOLD_ARMED), 2.0)
    assert any(isinstance(e, LinkUp) and e.regained for e in ev)


def test_telemetry_keeps_a_lossy_link_alive_and_regains_it() -> None:
    link, px4 = VehicleLink(), Px4Side()
    lpos = m.MAVLink_local_position_ned_message(0, 0, 0, 0, 0, 0, 0)
    feed(link, px4, lpos, 0.0)
    assert not link.heartbeat.link_up  # telemetry alone does not bring a link up
    feed(link, px4, heartbeat(*HOLD_ARMED), 0.5)
    for k in range(1, 60):  # heartbeats all lost for 6 s, telemetry flows at 10 Hz
        feed(link, px4, lpos, 0.5 + 0.1 * k)
        assert not any(isinstance(e, LinkLost) for e in link.handle_timer(0.5 + 0.1 * k))
    # nothing at all for 3 s: lost
    assert any(isinstance(e, LinkLost) for e in link.handle_timer(6.4 + 3.0))
    ev = feed(link, px4, lpos, 10.0)  # any message from the autopilot regains it
    assert any(isinstance(e, LinkUp) and e.regained for e in ev)
    # messages from another component do not count
    link.handle_timer(13.0)
    assert not link.heartbeat.link_up
    assert feed(link, Px4Side(1, 100), lpos, 13.5) == []
    assert not link.heartbeat.link_up


def test_gcs_and_other_vehicle_heartbeats_ignored() -> None:
    link = VehicleLink()
    assert feed(link, Px4Side(1, 190), heartbeat(0, 0, autopilot=8), 0.0) == []
    assert feed(link, Px4Side(2, 1), heartbeat(*HOLD_ARMED), 0.0) == []
    assert link.mode is None


def test_companion_sends_its_heartbeat_with_configured_ids() -> None:
    link = VehicleLink(LinkConfig(sysid=1, compid=196))
    link.handle_timer(0.0)
    msgs = Px4Side().decode(link.frames_to_send())
    hb = [x for x in msgs if x.get_type() == "HEARTBEAT"]
    assert len(hb) == 1 and hb[0].get_srcComponent() == 196 and hb[0].autopilot == 8
    assert all(x.get_msgbuf()[0] == 0xFD for x in msgs)  # MAVLink 2 only
    link.handle_timer(0.5)
    assert not [x for x in Px4Side().decode(link.frames_to_send()) if x.get_type() == "HEARTBEAT"]


def test_set_mode_over_bytes_with_double_ack_and_heartbeat() -> None:
    link, px4 = VehicleLink(), Px4Side()
    feed(link, px4, heartbeat(*HOLD_ARMED), 0.0)
    link.set_mode(FlightMode.OFFBOARD, 0.1)
    (cmd,) = [x for x in px4.decode(link.frames_to_send()) if x.get_type() == "COMMAND_LONG"]
    assert (cmd.command, cmd.param1, cmd.param2, cmd.param3) == (176, 129.0, 6.0, 0.0)
    assert feed(link, px4, command_ack(176, 0), 0.11) == []
    assert feed(link, px4, command_ack(176, 0), 0.12) == []
    ev = feed(link, px4, heartbeat(*OFFBOARD_ARMED), 0.5)
    (fin,) = [e for e in ev if isinstance(e, CommandFinished)]
    assert fin.ok and fin.command == 176


def test_mavlink1_and_corrupt_frames_are_dropped() -> None:
    codec = Codec()
    px4 = Px4Side()
    v1 = bytes(heartbeat(*HOLD_ARMED).pack(px4.mav, force_mavlink1=True))
    good = px4.frame(heartbeat(*HOLD_ARMED))
    bad = bytearray(good)
    bad[12] ^= 0xFF
    msgs = codec.decode(v1 + bytes(bad) + good)
    assert len(msgs) == 1 and msgs[0].get_type() == "HEARTBEAT"
    # fragmented input is reassembled
    assert codec.decode(good[:5]) == [] and len(codec.decode(good[5:])) == 1


def test_local_position_and_odometry_body_velocity_rotated() -> None:
    tel, px4 = TelemetryState(), Px4Side()
    tel.update(px4.msg(m.MAVLink_local_position_ned_message(1000, 1, 2, -3, 0.5, 0, 0)), 1.0)
    assert tel.position is not None and tel.position.pos_ned == (1.0, 2.0, -3.0)
    rot = Rotation.from_euler("ZYX", [0.7, 0.2, -0.3])  # yaw, pitch, roll (body 3-2-1)
    x, y, z, w = rot.as_quat()
    v_body = np.array([1.0, -0.5, 0.25])
    msg = m.MAVLink_odometry_message(5_000_000, 1, 12, 4.0, 5.0, -6.0, [w, x, y, z],
                                     *v_body, 0.1, 0.2, 0.3, [math.nan] * 21, [math.nan] * 21)
    ev = tel.update(px4.msg(msg), 2.0)
    pos = next(e for e in ev if isinstance(e, LocalPosition))
    assert pos.source == "ODOMETRY" and pos.pos_ned == (4.0, 5.0, -6.0)
    assert np.allclose(pos.vel_ned, rot.apply(v_body), atol=1e-6)
    assert tel.attitude is not None and tel.attitude.omega_frd == pytest.approx((0.1, 0.2, 0.3))


def _statustext(px4: Px4Side, text: str, sid: int, seq: int, sev: int = 4) -> Any:
    return px4.msg(m.MAVLink_statustext_message(sev, text.encode(), sid, seq))


def test_statustext_plain_and_chunked_reassembly() -> None:
    tel, px4 = TelemetryState(), Px4Side()
    (st0,) = tel.update(_statustext(px4, "Takeoff detected", 0, 0), 0.0)
    assert isinstance(st0, StatusText) and st0.text == "Takeoff detected"
    text = "".join(chr(ord("a") + i % 26) for i in range(120))
    chunks = [text[i:i + 50] for i in range(0, 120, 50)]
    assert tel.update(_statustext(px4, chunks[1], 7, 1), 0.1) == []  # out of order
    assert tel.update(_statustext(px4, chunks[0], 7, 0), 0.1) == []
    (full,) = tel.update(_statustext(px4, chunks[2], 7, 2), 0.2)
    assert isinstance(full, StatusText) and full.text == text and full.severity == 4


def test_statustext_exact_multiple_of_50_flushed_by_timer() -> None:
    tel, px4 = TelemetryState(), Px4Side()
    text = "x" * 50 + "y" * 50
    tel.update(_statustext(px4, text[:50], 9, 0), 0.0)
    tel.update(_statustext(px4, text[50:], 9, 1), 0.1)
    assert tel.handle_timer(0.9) == []
    (full,) = tel.handle_timer(1.0)
    assert isinstance(full, StatusText) and full.text == text


@given(offset_s=st.floats(-1e3, 1e3), d1=st.floats(1e-4, 0.05), d2=st.floats(1e-4, 0.05))
@settings(max_examples=60, deadline=None)
def test_timesync_offset_within_half_the_delay_asymmetry(offset_s: float, d1: float,
                                                         d2: float) -> None:
    """Vehicle clock = local + 1000 s + offset; one-way delays d1 (up) and d2 (down)."""
    out = Outbox()
    ts = TimeSync(out)
    px4 = Px4Side()
    true_offset = 1000.0 + offset_s
    t = 5.0
    ts.handle_timer(t)
    (req,) = out.take()
    assert req.tc1 == 0
    remote_ns = round((t + d1 + true_offset) * 1e9)
    # the reply's (garbage) target ids do not matter: matched by the echoed ts1 only
    (upd,) = ts.on_timesync(px4.msg(m.MAVLink_timesync_message(remote_ns, req.ts1)), t + d1 + d2)
    assert isinstance(upd, TimesyncUpdate)
    assert upd.rtt_s == pytest.approx(d1 + d2, abs=1e-6)
    assert abs(upd.offset_s - true_offset) <= abs(d1 - d2) / 2 + 1e-6


def test_timesync_answers_requests_and_ignores_unknown_replies() -> None:
    out = Outbox()
    ts = TimeSync(out)
    px4 = Px4Side()
    assert ts.on_timesync(px4.msg(m.MAVLink_timesync_message(0, 123456789)), 2.0) == []
    (reply,) = out.take()
    assert reply.ts1 == 123456789 and reply.tc1 == 2_000_000_000
    assert ts.on_timesync(px4.msg(m.MAVLink_timesync_message(99, 42)), 2.1) == []


def test_timesync_min_rtt_sample_wins() -> None:
    out = Outbox()
    ts = TimeSync(out, interval_s=0.1)
    px4 = Px4Side()
    true_offset = 50.0
    results = []
    for k, (d1, d2) in enumerate([(0.05, 0.001), (0.002, 0.002), (0.001, 0.04)]):
        t = 1.0 + k
        ts.handle_timer(t)
        (req,) = out.take()
        remote = round((t + d1 + true_offset) * 1e9)
        results += ts.on_timesync(px4.msg(m.MAVLink_timesync_message(remote, req.ts1)),
                                  t + d1 + d2)
    assert results[-1].rtt_s == pytest.approx(0.004, abs=1e-6)
    assert results[-1].offset_s == pytest.approx(true_offset, abs=1e-6)


def test_status_streams_decoded_with_px4_values() -> None:
    """SYS_STATUS/EXTENDED_SYS_STATE/GLOBAL_POSITION_INT/HOME_POSITION with values from PX4.md."""
    tel, px4 = TelemetryState(), Px4Side()
    ready = m.MAVLink_sys_status_message(50348079, 50413615, 320915519, 250, 16200, -1, 87,
                                         0, 0, 0, 0, 0, 0)
    (st,) = tel.update(px4.msg(ready), 1.0)
    assert st.armable and st.voltage_v == pytest.approx(16.2) and st.battery_remaining_pct == 87
    not_ready = m.MAVLink_sys_status_message(50348079, 50413615, 320915519 & ~268435456, 250,
                                             16200, -1, 87, 0, 0, 0, 0, 0, 0)
    (st,) = tel.update(px4.msg(not_ready), 1.1)
    assert not st.armable
    for landed, in_air in ((1, False), (3, True), (2, True), (4, True), (0, False)):
        (ext,) = tel.update(px4.msg(m.MAVLink_extended_sys_state_message(0, landed)), 1.2)
        assert ext.landed_state == landed and ext.in_air is in_air
    g = m.MAVLink_global_position_int_message(1000, 473977420, 85455940, 490500, 2500,
                                              150, -20, 35, 9000)
    (gp,) = tel.update(px4.msg(g), 1.3)
    assert gp.lat_deg == pytest.approx(47.397742) and gp.lon_deg == pytest.approx(8.545594)
    assert gp.alt_amsl_m == pytest.approx(490.5) and gp.relative_alt_m == pytest.approx(2.5)
    assert gp.vel_ned == pytest.approx((1.5, -0.2, 0.35))
    h = m.MAVLink_home_position_message(473977420, 85455940, 488000, 0, 0, 0,
                                        [1, 0, 0, 0], 0, 0, 0)
    (home,) = tel.update(px4.msg(h), 1.4)
    assert home.alt_amsl_m == pytest.approx(488.0) and tel.snapshot().home == home
