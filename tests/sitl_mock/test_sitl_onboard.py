"""The onboard module hosted by the mock (sitl_mock/onboard.py) behind MAVLink, as ecca_onboard.c
hosts it in PX4: DEBUG_FLOAT_ARRAY in, COMMAND_ACK out to the module's peer, the offboard
signal while it holds a verified trajectory, its setpoints flown in OFFBOARD, the start report
on the autopilot's clock, a corrupted upload refused and never flown, OFFBOARD left stops it.

The companion's side here is its sans-IO protocol (companion.onboard.protocol) over the test
harness's pymavlink client (sysid 255, compid 190) on a fake clock."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

import companion.onboard.protocol as P
from tests.support.autopilot_harness import Harness

LAW = P.LawParams(kp=(2.0, 2.0, 3.0), kd=(2.5, 2.5, 3.0), ki=(0.2, 0.2, 0.3),
                  i_max=(2.0, 2.0, 3.0), hover=0.49, drag=1.0, mass=1.0, g=9.80665,
                  thrust_min=0.08, thrust_max=1.0, max_tilt_rad=math.radians(40.0))
PEER = (255, 190)


def climb_upload(final_action: str = "land") -> P.Upload:
    """A 4 s climb from the ground to 2 m up, then a 2 s hold there (two segments)."""
    cp = np.array([[0.0, 0.0, -2.0 * s] for s in (0, 0, 0, 0.5, 1, 1, 1, 1)])
    cp[:4, 2] = 0.0
    hold = np.tile([0.0, 0.0, -2.0], (2, 1))
    return P.encode_upload([0.0, 4.0, 6.0], [cp, hold], None, LAW, sysid=PEER[0],
                           compid=PEER[1], final_action=final_action, hold_s=1.0)


def send_part(h: Harness, op: int, data: tuple[float, ...] | list[float]) -> None:
    h.send(mavlink.MAVLink_debug_float_array_message(
        int(h.now_boot * 1e6), b"ecca", op, [float(x) for x in data]))


def module_acks(h: Harness, since: float = -math.inf) -> list[tuple[mavlink.MAVLink_message,
                                                                        P.Ack]]:
    out = []
    for m in h.msgs("COMMAND_ACK", since):
        a = P.decode_ack(m.command, m.result, m.progress, m.result_param2)
        if a is not None:
            out.append((m, a))
    return out


def upload(h: Harness, up: P.Upload) -> P.Uploader:
    """The companion's stop-and-wait upload over the harness (10 ms cycles, bounded)."""
    u = P.Uploader(up)
    seen = len(module_acks(h))
    for _ in range(1000):
        if u.done:
            break
        msg = u.poll(h.now_boot)
        if msg is not None:
            send_part(h, *msg)
        h.run(0.01)
        acks = module_acks(h)
        for _, a in acks[seen:]:
            u.on_ack(a, h.now_boot)
        seen = len(acks)
    return u


@pytest.fixture
def h() -> Harness:
    pytest.importorskip("gen_c.onboard_native")
    h = Harness(onboard=True)
    h.wait_ready()
    return h


def test_a_mock_without_the_module_does_not_answer() -> None:
    h = Harness()
    h.wait_ready()
    t = h.now_boot
    send_part(h, P.OP_STATUS, [*PEER] + [0.0] * 56)
    h.run(1.2)
    assert module_acks(h, t) == []
    assert h.ap.stats["rx_unhandled"] >= 1


def test_status_query_answered_to_the_sender_then_every_half_second(h: Harness) -> None:
    t = h.now_boot
    assert module_acks(h) == []  # no peer yet: no unsolicited status
    send_part(h, P.OP_STATUS, [*PEER] + [0.0] * 56)
    h.run(0.01)
    (m, a), *_ = module_acks(h, t)
    assert (m.command, m.progress, m.target_system, m.target_component) == (
        P.ACK_CMD, P.STATE_READY, *PEER)
    assert (a.op, a.state, a.result) == (P.OP_STATUS, P.STATE_READY, 0)
    h.run(2.0)
    assert 4 <= len(module_acks(h, t)) <= 6  # its status every 0.5 s from then on
    # a message of another name is not the module's
    t = h.now_boot
    h.send(mavlink.MAVLink_debug_float_array_message(0, b"other", P.OP_BEGIN, [0.0] * 58))
    h.run(0.1)
    assert [a.op for _, a in module_acks(h, t) if a.op != P.OP_STATUS] == []


def test_a_corrupted_upload_is_refused_and_offboard_stays_closed(h: Harness) -> None:
    up = climb_upload()
    bad = list(up.segments[1])
    bad[P.S_CTRL + 2] += 1.0  # the hold 1 m lower than the CRC says
    corrupted = P.Upload(up.begin, (up.segments[0], tuple(bad)), up.crc, up.duration_s)
    u = upload(h, corrupted)
    assert u.failed and not u.verified
    crc = [a for _, a in module_acks(h) if a.crc]
    assert crc[-1].result != 0 and crc[-1].state == P.STATE_READY
    assert crc[-1].value != up.crc
    assert h.ap.stats["onboard_refused"] == 1
    # nothing verified: no offboard signal, so arming in OFFBOARD is refused
    h.set_mode(6)
    h.run(0.1)
    h.arm()
    h.run(0.05)
    assert h.acks(400)[-1] == mavlink.MAV_RESULT_TEMPORARILY_REJECTED
    assert not h.ap.armed and h.ap.stats["onboard_setpoints"] == 0


def test_the_module_flies_lands_and_reports_its_start_on_the_autopilot_clock(
        h: Harness) -> None:
    u = upload(h, climb_upload())
    assert u.verified, u.failed
    assert h.ap.offboard_fresh  # offboard_control_mode while it holds a verified trajectory
    h.set_mode(6)
    h.run(0.05)
    h.arm()  # no setpoint stream from the client: the module's signal is the proof of life
    h.run(0.05)
    assert h.acks(400)[-1] == 0 and h.ap.armed
    t_arm = h.now_boot
    h.run_until(lambda: h.ap.state.pos_ned[2] < -1.5, 8.0)
    starts = [a for _, a in module_acks(h) if a.start]
    assert starts, "no start report"
    # the trajectory's clock started at a module cycle after arming (4 ms, whole ms)
    assert t_arm - 0.06 <= starts[0].value / 1000.0 <= t_arm + 0.01
    assert starts[0].value % 4 == 0
    assert not [m for m in h.msgs("SET_ATTITUDE_TARGET")]  # (the client sent none)
    h.run_until(lambda: not h.ap.armed, 30.0)  # hold 1 s, LAND commanded, auto-disarm
    states = [a.state for _, a in module_acks(h) if not a.start and not a.crc]
    assert P.STATE_FLYING in states and P.STATE_HOLDING in states and P.STATE_DONE in states
    assert h.ap.stats["onboard_final_action"] >= 1
    assert abs(h.ap.state.pos_ned[2]) < 0.2


def test_leaving_offboard_stops_the_module_for_good(h: Harness) -> None:
    assert upload(h, climb_upload(final_action="hold")).verified
    h.set_mode(6)
    h.run(0.05)
    h.arm()
    h.run(2.0)
    assert h.ap.armed and h.ap.state.pos_ned[2] < -0.3
    h.set_mode(4, 3)  # the pilot: Hold
    h.run(1.1)
    assert module_acks(h)[-1][1].state == P.STATE_STOPPED
    n = h.ap.stats["onboard_setpoints"]
    h.set_mode(6)  # back to OFFBOARD: the module stays stopped (no signal, refused)
    h.run(1.0)
    assert h.ap.stats["onboard_setpoints"] == n
    assert h.ap.mode.name != "OFFBOARD"


def test_debug_array_holds_one_message_per_cycle(h: Harness) -> None:
    """Two parts within one 4 ms cycle: the module sees the newer only (uORB debug_array)."""
    up = climb_upload()
    t = h.now_boot
    send_part(h, P.OP_STATUS, [*PEER] + [0.0] * 56)
    send_part(h, P.OP_BEGIN, up.begin)  # the same instant: overwrites the status query
    h.run(0.01)
    answers = [a for _, a in module_acks(h, t)]
    # the BEGIN answered first (the query never was); then, the BEGIN having named the peer,
    # the module's periodic status
    assert [a.op for a in answers] == [P.OP_BEGIN, P.OP_STATUS]
    assert answers[0].state == P.STATE_RECEIVING
