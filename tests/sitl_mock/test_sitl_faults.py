"""Fault injection (network + scenario) and bad input on the sans-IO core; lockstep determinism."""

from __future__ import annotations

import math

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v10 import common as mavlink1
from pymavlink.dialects.v20 import common as mavlink

from sitl_mock.faults import FaultyChannel, LinkFaults, ScenarioFaults, parse_blackouts
from sitl_mock.lockstep import LockstepSim
from tests.sitl_mock.test_sitl_autopilot_core import flying, in_offboard
from tests.support.autopilot_harness import Harness


def _faulty(out: LinkFaults | None = None, inp: LinkFaults | None = None, **kw: object) -> Harness:
    return Harness(link_faults={"offboard": (inp, out)}, **kw)  # type: ignore[arg-type]


# ------------------------------------------------------------------------- channel unit
def test_channel_passthrough_keeps_order_and_counts() -> None:
    ch: FaultyChannel[int] = FaultyChannel()
    for i in range(5):
        ch.push(i, now=1.0, t_boot=1.0)
    assert ch.pop_due(1.0) == [0, 1, 2, 3, 4]
    assert ch.stats.passed == 5 and ch.stats.dropped == 0


def test_channel_loss_is_seeded_and_near_the_configured_rate() -> None:
    def run(seed: int) -> list[int]:
        ch: FaultyChannel[int] = FaultyChannel(LinkFaults(loss_pct=30.0), seed)
        for i in range(2000):
            ch.push(i, 0.0, 0.0)
        return ch.pop_due(0.0)

    a, b, c = run(1), run(1), run(2)
    assert a == b and a != c
    assert abs(len(a) / 2000 - 0.7) < 0.04  # binomial: sd ~ 0.01


def test_channel_latency_duplication_reorder_and_blackout() -> None:
    ch: FaultyChannel[int] = FaultyChannel(LinkFaults(latency_s=0.2))
    ch.push(1, 10.0, 0.0)
    assert ch.pop_due(10.19) == [] and ch.pop_due(10.2) == [1]
    dup: FaultyChannel[int] = FaultyChannel(LinkFaults(duplicate_pct=100.0))
    dup.push(7, 0.0, 0.0)
    assert dup.pop_due(0.0) == [7, 7]
    ro: FaultyChannel[int] = FaultyChannel(LinkFaults(reorder_pct=50.0, reorder_delay_s=0.05), 3)
    for i in range(200):
        ro.push(i, i * 0.001, 0.0)
    out = ro.pop_due(1.0)
    assert sorted(out) == list(range(200)) and out != list(range(200))
    bo: FaultyChannel[int] = FaultyChannel(LinkFaults(blackouts=((1.0, 2.0),)))
    for t in (0.5, 1.0, 1.5, 2.0):
        bo.push(int(t * 10), t, t)
    assert bo.pop_due(3.0) == [5, 20]


def test_link_faults_validation_and_blackout_parsing() -> None:
    with pytest.raises(ValueError, match="percentage"):
        LinkFaults(loss_pct=120.0)
    with pytest.raises(ValueError, match="delay"):
        LinkFaults(latency_s=math.nan)
    assert parse_blackouts("10-12, 30-31.5") == ((10.0, 12.0), (30.0, 31.5))
    with pytest.raises(ValueError, match="START-END"):
        parse_blackouts("abc")


# ------------------------------------------------------------------------- link faults
def test_outbound_latency_delays_the_ack() -> None:
    h = _faulty(out=LinkFaults(latency_s=0.2), step_s=0.01)
    h.run(3.5)
    t = h.now_boot
    h.arm()
    h.run(0.15)
    assert h.acks(400, t) == []
    h.run(0.1)
    assert h.acks(400, t) == [0]


def test_blackout_silences_both_directions_then_recovers() -> None:
    h = _faulty(out=LinkFaults(blackouts=((4.0, 6.0),)), inp=LinkFaults(blackouts=((4.0, 6.0),)))
    h.run(4.0)
    h.arm()  # lost inbound
    h.run(2.0)
    assert [t for t, _m in h.timed("HEARTBEAT", 4.01) if t < 5.99] == [] and not h.ap.armed
    h.run(1.5)
    assert len(h.timed("HEARTBEAT", 6.0)) >= 1
    h.arm()
    assert h.ap.armed


def test_inbound_loss_breaks_offboard_proof_of_life_statistically() -> None:
    h = _faulty(inp=LinkFaults(loss_pct=50.0), seed=3)
    h.run(3.5)
    for _ in range(200):
        h.pos_setpoint(0, 0, -2)
    assert 70 <= h.ap.stats["rx_setpoints"] <= 130


# ------------------------------------------------------------------------- scenario faults
def test_pilot_takeover_switches_to_posctl_and_holds() -> None:
    h = Harness(scenario=ScenarioFaults(pilot_takeover_s=14.0))
    in_offboard(h)  # offboard reached well before t = 14 s
    h.run_until(lambda: h.ap.mode.name == "POSCTL", 20.0, lambda: h.pos_setpoint(0, 0, -2.5))
    assert any("Pilot took over" in t for t in h.texts())
    z0 = h.ap.state.pos_ned[2]
    h.run(3.0)
    assert abs(h.ap.state.pos_ned[2] - z0) < 0.3  # RC present: holds, no failsafe descent
    assert h.ap.armed and not h.ap.failsafe and h.heartbeat().system_status == 4


def test_local_position_loss_stops_lpos_and_triggers_descent() -> None:
    h = Harness(scenario=ScenarioFaults(local_position_loss=(13.0, 100.0)))
    flying(h)
    assert h.now_boot < 13.0
    h.run_until(lambda: h.now_boot >= 13.5, 5.0)
    assert h.timed("LOCAL_POSITION_NED", 13.05) == []
    assert any("no local position" in t for t in h.texts())
    assert h.ap.mode.name == "AUTO_LAND" and h.ap.failsafe
    health = h.last("SYS_STATUS").onboard_control_sensors_health
    assert not health & mavlink.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
    h.run_until(lambda: not h.ap.armed, 20.0)


def test_low_battery_warning_and_land_action() -> None:
    h = Harness(
        params={"COM_LOW_BAT_ACT": 2},
        scenario=ScenarioFaults(low_battery_s=12.0, low_battery_remaining=0.06),
    )
    flying(h)
    h.run_until(lambda: h.now_boot >= 13.5, 5.0)
    bat = h.last("BATTERY_STATUS")
    assert bat.battery_remaining <= 6
    assert any("Critical battery level" in t for t in h.texts())
    assert h.ap.mode.name == "AUTO_LAND"


# ------------------------------------------------------------------------- bad input
def test_garbage_bad_crc_and_mavlink1_are_dropped_and_counted() -> None:
    h = Harness()
    h.run(3.5)
    good = mavlink.MAVLink_command_long_message(1, 1, 31999, 0, 0, 0, 0, 0, 0, 0, 0)
    frame = bytearray(good.pack(mavlink.MAVLink(None, 255, 190)))
    bad = bytes(frame[:-1]) + bytes([frame[-1] ^ 0xFF])
    h.send_bytes(bad)
    h.send_bytes(b"\x00\x01garbage\xfd\xfd\xfe")
    v1 = mavlink1.MAVLink(None, 255, 190)
    h.send_bytes(mavlink1.MAVLink_command_long_message(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0).pack(v1))
    h.send_bytes(bytes(frame[:12]))  # truncated
    assert h.acks(31999) == [] and not h.ap.armed
    assert h.ap.stats["rx_mavlink1"] == 1 and h.ap.stats["rx_bad_data"] >= 2
    assert h.ap.errors_comm >= 3
    h.send_bytes(bytes(frame))
    assert h.acks(31999) == [3]  # still alive and answering
    assert h.ap.stats["handler_errors"] == 0


def test_nan_and_out_of_range_fields_never_crash() -> None:
    h = Harness()
    flying(h)
    nan, inf = math.nan, math.inf
    h.command_long(176, nan, nan, nan)
    h.command_long(176, 1.0, 99.0, 0.0)
    h.command_long(22, nan, nan, nan, nan, nan, nan, inf)
    h.command_long(511, nan, nan)
    h.command_long(512, inf)
    h.send(mavlink.MAVLink_set_attitude_target_message(0, 1, 1, 7, [inf, 0, 0, 0], 0, 0, 0, nan))
    h.send(mavlink.MAVLink_param_set_message(1, 1, b"MPC_THR_HOVER", nan, 9))
    h.send(mavlink.MAVLink_mission_count_message(1, 1, 65535, 0))
    h.run(1.0)
    assert h.ap.stats["handler_errors"] == 0
    assert h.ap.params["MPC_THR_HOVER"] == 0.5
    # NaN/inf takeoff altitude means "not given" (MIS_TAKEOFF_ALT), as in PX4
    assert h.ap.mode.name in ("AUTO_TAKEOFF", "AUTO_LOITER") and h.ap.armed
    assert all(math.isfinite(c) for c in h.ap.state.pos_ned)
    assert h.msgs("MISSION_ACK")[-1].type == mavlink.MAV_MISSION_NO_SPACE


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.binary(min_size=0, max_size=300), min_size=1, max_size=8))
def test_fuzzed_datagrams_never_stop_the_autopilot(datagrams: list[bytes]) -> None:
    sim = LockstepSim(estimator_ready_s=0.0)
    sim.step(0.05)
    for d in datagrams:
        sim.send(d)
        sim.step(0.01)
    sim.step(1.1)
    beats = [d for d in sim.recv() if len(d) > 9 and d[7] == 0 and d[8] == 0 and d[9] == 0]
    assert beats  # heartbeats keep coming
    assert sim.autopilot.stats["handler_errors"] == 0


# ------------------------------------------------------------------------- lockstep
def _script(seed: int) -> list[bytes]:
    sim = LockstepSim(seed=seed, faults=(LinkFaults(loss_pct=10.0), LinkFaults(loss_pct=10.0)))
    mav = mavlink.MAVLink(None, 255, 190)
    out: list[bytes] = []

    def send(m: object) -> None:
        sim.send(m.pack(mav))  # type: ignore[attr-defined]
        mav.seq = (mav.seq + 1) & 0xFF

    sim.step_until(3.5)
    for _ in range(3):
        send(mavlink.MAVLink_command_long_message(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0))
        sim.step(0.5)
    send(
        mavlink.MAVLink_command_long_message(1, 1, 22, 0, math.nan, 0, 0, math.nan, 0, 0, math.nan)
    )
    sim.step_until(8.0)
    out.extend(sim.recv())
    return out


def test_lockstep_is_deterministic_for_a_seed() -> None:
    a, b = _script(5), _script(5)
    assert a == b and len(a) > 1000
    assert _script(6) != a


def test_extreme_but_finite_setpoints_keep_the_state_finite() -> None:
    """Seeded barrage of extreme setpoints in OFFBOARD: no exception, no NaN, limits hold."""
    import random

    rng = random.Random(11)
    h = Harness()
    in_offboard(h)
    big = (1e30, -1e30, 1e6, -1e6, 0.0, 3.4e38, -3.4e38, 1e-30)

    def barrage() -> None:
        mask = rng.choice((0, 2552, 3527, 3135, 2048, 448 | 2048))
        v = [rng.choice(big) for _ in range(10)]
        h.send(
            mavlink.MAVLink_set_position_target_local_ned_message(
                0, 1, 1, rng.choice((1, 8)), mask, *v, rng.uniform(-10, 10)
            )
        )
        if rng.random() < 0.3:
            q = [rng.choice(big) for _ in range(4)]
            thrust = rng.choice((-5.0, 0.0, 0.5, 1.0, 7.0, 1e30))
            h.send(
                mavlink.MAVLink_set_attitude_target_message(
                    0,
                    1,
                    1,
                    rng.choice((7, 3, 128, 0)),
                    q,
                    *[rng.choice(big) for _ in range(3)],
                    thrust,
                )
            )

    h.run(5.0, barrage)
    s = h.ap.state
    values = (*s.pos_ned, *s.vel_ned, *s.q_wxyz, *s.omega_frd)
    assert all(math.isfinite(v) for v in values)
    assert math.hypot(s.vel_ned[0], s.vel_ned[1]) < 30.0  # bounded by tilt/thrust limits
    assert h.ap.stats["handler_errors"] == 0
    assert h.ap.stats["rx_setpoints"] > 100
