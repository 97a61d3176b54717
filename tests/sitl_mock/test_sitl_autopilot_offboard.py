"""OFFBOARD rules of PX4 v1.16 on the sans-IO core: proof of life, refusal, loss failsafe."""

from __future__ import annotations

import math
from itertools import pairwise

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from tests.sitl_mock.test_sitl_autopilot_core import (
    OFFBOARD_CUSTOM,
    POSCTL_CUSTOM,
    flying,
    hb_triplet,
    in_offboard,
)
from tests.support.autopilot_harness import Harness


def att_setpoint(h: Harness, q: tuple[float, float, float, float], thrust: float, mask: int = 7):
    h.send(mavlink.MAVLink_set_attitude_target_message(0, 1, 1, mask, q, 0, 0, 0, thrust))


def q_from_euler(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """Hamilton quaternion for body 3-2-1 Euler angles (written out, independent of the mock)."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def test_disarmed_offboard_heartbeat_with_and_without_stream() -> None:
    h = Harness()
    h.wait_ready()
    h.set_mode(6)
    h.run(1.2)
    assert hb_triplet(h) == (1, OFFBOARD_CUSTOM, 0)
    h.arm()
    assert h.acks(400)[-1] == 1  # no proof of life: arming in OFFBOARD denied
    h.run(1.2, lambda: h.pos_setpoint(0, 0, -2))
    assert hb_triplet(h) == (17, OFFBOARD_CUSTOM, 3)
    h.arm()
    assert h.acks(400)[-1] == 0


def test_armed_switch_to_offboard_needs_proof_of_life() -> None:
    h = Harness()
    flying(h)
    t = h.now_boot
    h.set_mode(6)
    h.run(0.05)
    assert h.acks(176, t) == [0, 1]  # receiver ACCEPTED, commander TEMPORARILY_REJECTED
    assert "Switching to Offboard is currently not available" in h.texts(t)
    assert h.ap.mode.name == "AUTO_LOITER"
    h.run(0.3, lambda: h.pos_setpoint(0, 0, -2.5))
    t = h.now_boot
    h.set_mode(6)
    h.run(1.1, lambda: h.pos_setpoint(0, 0, -2.5))
    assert h.acks(176, t) == [0, 0]
    assert hb_triplet(h) == (145, OFFBOARD_CUSTOM, 4)


@pytest.mark.parametrize(
    ("mask", "frame", "counts"),
    [
        (2552, 1, True),  # MAVSDK position-only
        (3576, 1, True),  # position, yaw and yaw rate ignored
        (2048, 1, True),  # everything but yaw rate
        (3527, 8, True),  # BODY_NED velocity
        (2552, 8, False),  # BODY_NED ignores positions: nothing left
        (2559, 1, False),  # yaw only
        (1535, 1, False),  # yaw rate only
        (2560, 1, False),  # FORCE with acceleration
        (2552, 7, False),  # frame 7 unsupported
    ],
)
def test_which_setpoints_are_proof_of_life(mask: int, frame: int, counts: bool) -> None:
    h = Harness()
    h.wait_ready()
    h.pos_setpoint(1.0, 2.0, -3.0, mask=mask, frame=frame)
    assert h.ap.offboard_fresh is counts
    if frame == 7:
        assert "SET_POSITION_TARGET_LOCAL_NED coordinate frame 7 unsupported" in h.texts()
    elif not counts:
        assert any(t.startswith("SET_POSITION_TARGET_LOCAL_NED") for t in h.texts())


def test_attitude_setpoints_and_invalid_ones() -> None:
    h = Harness()
    h.wait_ready()
    att_setpoint(h, (math.nan, 0, 0, 0), 0.5)
    att_setpoint(h, (0, 0, 0, 0), 0.5)
    h.send(
        mavlink.MAVLink_set_position_target_local_ned_message(
            0, 1, 1, 1, 2552, math.nan, math.nan, math.nan, 0, 0, 0, 0, 0, 0, 0, 0
        )
    )  # position given but all NaN: no finite axis
    h.send(
        mavlink.MAVLink_set_position_target_local_ned_message(
            0, 2, 1, 1, 2552, 1, 1, 1, 0, 0, 0, 0, 0, 0, 0, 0
        )
    )  # another system
    assert not h.ap.offboard_fresh
    assert h.ap.stats["rx_invalid_setpoint"] == 3 and h.ap.stats["rx_wrong_target"] == 1
    att_setpoint(h, (1, 0, 0, 0), 0.5, mask=7)
    assert h.ap.offboard_fresh
    assert h.ap.stats["handler_errors"] == 0


def test_loss_failsafe_timing_and_position_mode_values() -> None:
    h = Harness(step_s=0.005)
    in_offboard(h)
    t_last = h.now_boot
    h.run(0.95)
    assert not any("Failsafe" in t for t in h.texts(t_last))
    h.run_until(lambda: any("Failsafe activated" in t for t in h.texts(t_last)), 1.0)
    assert abs(h.now_boot - t_last - 1.0) <= 0.02  # COM_OF_LOSS_T
    h.run_until(lambda: h.heartbeat().custom_mode != OFFBOARD_CUSTOM, 2.0)
    assert 1.3 <= h.now_boot - t_last <= 1.7  # PX4.md: heartbeat leaves OFFBOARD 1.3-1.7 s
    assert hb_triplet(h) == (209, POSCTL_CUSTOM, 5)


@pytest.mark.parametrize(
    ("action", "mode"),
    [(3, "AUTO_RTL"), (4, "AUTO_LAND"), (5, "AUTO_LOITER"), (7, None)],
)
def test_loss_failsafe_action_follows_com_obl_rc_act(action: int, mode: str | None) -> None:
    h = Harness(params={"COM_OBL_RC_ACT": action, "COM_OF_LOSS_T": 2.0})
    in_offboard(h)
    t_last = h.now_boot
    h.run(1.9)
    assert h.ap.mode.name == "OFFBOARD"
    h.run(0.7)
    if mode is None:
        assert not h.ap.armed  # 7: disarm
    else:
        assert h.ap.mode.name == mode and h.ap.failsafe
        assert h.heartbeat().system_status == 5
    assert h.now_boot - t_last < 2.7


def test_no_rc_position_failsafe_sinks_lands_and_returns_to_offboard() -> None:
    h = Harness()
    in_offboard(h, d=-3.0)
    h.run(2.0)
    assert h.ap.mode.name == "POSCTL"
    h.run(2.0)
    vz = h.ap.state.vel_ned[2]
    assert 0.4 <= vz <= 0.8  # sinks ~0.6 m/s
    h.run_until(lambda: not h.ap.armed, 20.0)
    h.run(1.1)
    # the failsafe clears on disarm and PX4 returns to the user's mode: OFFBOARD, not armable
    assert hb_triplet(h) == (1, OFFBOARD_CUSTOM, 0)
    h.arm()
    assert h.acks(400)[-1] == 1


def test_resumed_stream_before_action_cancels_failsafe() -> None:
    h = Harness()
    in_offboard(h)
    h.run(1.2)  # loss detected at 1.0 s, action due at 1.5 s
    h.run(1.0, lambda: h.pos_setpoint(0, 0, -2.5))
    assert h.ap.mode.name == "OFFBOARD" and not h.ap.failsafe


def test_body_ned_velocity_is_rotated_by_heading() -> None:
    h = Harness()
    in_offboard(h)
    # face east, then fly "forward" in the body-NED frame: the vehicle must go east
    h.run(3.0, lambda: h.pos_setpoint(0, 0, -2.5, yaw=math.pi / 2))
    assert abs(h.ap.state.yaw - math.pi / 2) < 0.05
    forward = 0b110111000111  # velocity only (vx, vy, vz); yaw rate 0
    h.run(
        3.0,
        lambda: h.send(
            mavlink.MAVLink_set_position_target_local_ned_message(
                0, 1, 1, 8, forward, 0, 0, 0, 1.0, 0, 0, 0, 0, 0, 0, 0
            )
        ),
    )
    vn, ve, _ = h.ap.state.vel_ned
    assert ve > 0.7 and abs(vn) < 0.2


def test_attitude_roll_moves_east_and_thrust_above_hover_climbs() -> None:
    h = Harness()
    in_offboard(h)
    hover = 0.5
    h.run(1.0, lambda: att_setpoint(h, q_from_euler(0, 0, 0), hover))
    v0 = h.ap.state.vel_ned
    tilt = q_from_euler(math.radians(10), 0, 0)
    h.run(2.0, lambda: att_setpoint(h, tilt, hover / math.cos(math.radians(10))))
    ve = h.ap.state.vel_ned[1] - v0[1]
    assert 1.3 * 0.7 <= ve <= 1.4 * 1.3, ve  # PX4 SIH: 1.3-1.4 m/s to the right after 2 s
    h.run(1.0, lambda: att_setpoint(h, q_from_euler(0, 0, 0), hover))
    h.run(1.5, lambda: att_setpoint(h, q_from_euler(0, 0, 0), 0.65))
    climb = -h.ap.state.vel_ned[2]
    assert 2.3 * 0.7 <= climb <= 2.7 * 1.3, climb  # PX4 SIH: 2.3-2.7 m/s after 1.5 s


def _tilt(h: Harness) -> float:
    """The vehicle's tilt [rad] from its attitude quaternion (body z against NED down)."""
    _w, x, y, _z = h.ap.state.q_wxyz
    return math.acos(max(-1.0, min(1.0, 1.0 - 2.0 * (x * x + y * y))))


def _roll_after_switch(phase_s: float) -> tuple[float, float]:
    """In OFFBOARD on position setpoints, `phase_s` after the OFFBOARD entry switch to attitude
    setpoints rolled 15 deg: (time until the vehicle has rolled 5 deg, its distance from the
    held point then [m])."""
    h = Harness(step_s=0.004)
    flying(h)
    h.run(0.3, lambda: h.pos_setpoint(0, 0, -2.5))
    h.set_mode(6)
    t_entry = h.t
    h.run(1.0 + phase_s, lambda: h.pos_setpoint(0, 0, -2.5))
    assert h.ap.mode.name == "OFFBOARD" and abs(h.t - (t_entry + 1.0 + phase_s)) < 0.01
    t0 = h.t
    tilt = q_from_euler(math.radians(15), 0, 0)
    h.run_until(lambda: _tilt(h) > math.radians(5), 1.5,
                lambda: att_setpoint(h, tilt, 0.5))
    n, e, _ = h.ap.state.pos_ned
    return h.t - t0, math.hypot(n, e)


def test_attitude_after_position_setpoints_waits_for_the_control_mode_publication() -> None:
    """PX4 v1.16 publishes vehicle_control_mode at 2 Hz (or at once on a status or mode
    change), and a new offboard setpoint kind is neither: attitude setpoints that follow
    position setpoints in OFFBOARD are flown only from the next publication, PX4's position
    control holding the point until then (real PX4 SITL, serve: applied 0.3-0.5 s late). The
    delay spreads over one period across the switch's phase; the point is held meanwhile."""
    runs = [_roll_after_switch(ph) for ph in (0.05, 0.15, 0.25, 0.35, 0.45)]
    delays = np.array([d for d, _ in runs])
    # rolling 5 deg takes PX4's attitude loop ~0.1 s once the setpoint is flown
    assert delays.min() > 0.05 and delays.max() < 0.5 + 0.25
    assert np.ptp(delays) > 0.3  # the wait depends on the phase
    assert max(dist for _, dist in runs) < 0.3  # held (an immediate 15 deg roll drifts away)


def test_entering_offboard_on_attitude_setpoints_flies_them_at_once() -> None:
    """The mode change is a publication: attitude setpoints streamed before the switch are flown
    from the OFFBOARD entry on."""
    h = Harness(step_s=0.004)
    flying(h)
    tilt = q_from_euler(math.radians(15), 0, 0)
    h.run(0.3, lambda: att_setpoint(h, q_from_euler(0, 0, 0), 0.5))
    h.set_mode(6)
    t0 = h.t
    h.run_until(lambda: _tilt(h) > math.radians(5), 1.0,
                lambda: att_setpoint(h, tilt, 0.5))
    assert h.ap.mode.name == "OFFBOARD" and h.t - t0 < 0.2


def _roll_after_step(delay_s: float) -> tuple[float, list[tuple[float, float]]]:
    """Hover in OFFBOARD, level attitude setpoints for 1 s (the commander's 2 Hz control mode
    catches up with the kind), then a 15 deg roll attitude setpoint every 10 ms: (the time the
    first was sent [s since boot], the ATTITUDE (time, roll [deg]) after it)."""
    h = Harness(params={"SIM_SP_DELAY": delay_s, "SIM_GYRO_SIH": 0.0})
    in_offboard(h)
    h.run(1.0, lambda: att_setpoint(h, (1.0, 0.0, 0.0, 0.0), 0.5))
    q = q_from_euler(math.radians(15.0), 0.0, 0.0)
    t0 = h.now_boot
    h.run(0.6, lambda: att_setpoint(h, q, 0.5 / math.cos(math.radians(15.0))))
    return t0, [(m.time_boot_ms * 1e-3, math.degrees(m.roll)) for m in h.msgs("ATTITUDE")
                if m.time_boot_ms * 1e-3 >= t0]


def _crossing(rows: list[tuple[float, float]], level: float) -> float:
    """First time [s] the roll crosses `level` [deg] (linear between samples)."""
    for (ta, ra), (tb, rb) in pairwise(rows):
        if ra < level <= rb:
            return ta + (level - ra) / (rb - ra) * (tb - ta)
    raise AssertionError(f"roll never reached {level} deg")


@pytest.mark.parametrize("delay_s", [0.008, 0.05])
def test_attitude_setpoints_are_flown_sim_sp_delay_after_they_arrive(delay_s: float) -> None:
    """SIM_SP_DELAY: the roll response to an attitude step is the undelayed one, later by the
    delay: its 20 / 50 / 80 % crossings of a 15 deg step move by the delay, within one physics
    step (4 ms: the delayed setpoint is flown from the first step after it is due)."""
    t0, base = _roll_after_step(0.0)
    t1, late = _roll_after_step(delay_s)
    assert t1 == pytest.approx(t0)
    for level in (3.0, 7.5, 12.0):
        shift = _crossing(late, level) - _crossing(base, level)
        assert shift == pytest.approx(delay_s, abs=0.0045)
