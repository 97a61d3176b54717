"""The flight sequence driven with fake events (sans-IO: no link, no clock)."""

from __future__ import annotations

from companion.flight.sequence import (
    EndPolicy,
    Failure,
    Finished,
    FlightSequence,
    Phase,
    PhaseChanged,
    SendCommand,
    SequenceAction,
    SequenceConfig,
    Stream,
    VehicleView,
)
from companion.mavlink.commands import (
    MAV_CMD_COMPONENT_ARM_DISARM,
    MAV_CMD_DO_SET_MODE,
    MAV_CMD_NAV_LAND,
)
from companion.mavlink.px4_mode import FlightMode

RATE = 50.0
DT = 1.0 / RATE
READY = VehicleView(mode=FlightMode.HOLD)


def commands(actions: list[SequenceAction]) -> list[SendCommand]:
    return [a for a in actions if isinstance(a, SendCommand)]


def run(seq: FlightSequence, t0: float, t1: float, view: VehicleView) -> tuple[
        float, list[SequenceAction]]:
    """Cycles from t0 to t1, every Stream counted as sent."""
    out: list[SequenceAction] = []
    t = t0
    while t < t1 and not seq.finished:
        t += DT
        acts = seq.update(t, view)
        for a in acts:
            if isinstance(a, Stream):
                seq.on_setpoint_sent(t)
        out += acts
    return t, out


def to_offboard(seq: FlightSequence) -> float:
    """Prime and ask for OFFBOARD; returns the time of the request."""
    t, acts = run(seq, 0.0, 1.0, READY)
    assert seq.phase is Phase.REQUEST_OFFBOARD
    assert commands(acts) == [SendCommand.set_mode(FlightMode.OFFBOARD)]
    return t


def test_primes_before_requesting_offboard() -> None:
    seq = FlightSequence(SequenceConfig(rate_hz=RATE, duration_s=5.0))
    _, acts = run(seq, 0.0, 1.0, READY)
    streams = [a for a in acts if isinstance(a, Stream)]
    assert len(streams) >= 0.5 * RATE - 1 and all(s.t_s is None for s in streams)
    assert seq.streaming


def test_offboard_refused_sends_no_arm_and_stops_streaming() -> None:
    seq = FlightSequence(SequenceConfig(rate_hz=RATE, duration_s=5.0))
    t = to_offboard(seq)
    acts = seq.on_command_result(MAV_CMD_DO_SET_MODE, False, "DENIED", t + DT, 2)
    assert not commands(acts)
    fin = [a for a in acts if isinstance(a, Finished)]
    assert fin and not fin[0].ok and fin[0].failure is Failure.OFFBOARD_REFUSED
    assert fin[0].result == 2 and not seq.streaming
    _, later = run(seq, t + DT, t + 1.0, READY)
    assert not later  # nothing more, no arm


def test_link_loss_stops_the_stream() -> None:
    seq = FlightSequence(SequenceConfig(rate_hz=RATE, duration_s=5.0))
    t = to_offboard(seq)
    acts = seq.update(t + DT, VehicleView(link_ok=False, mode=FlightMode.HOLD))
    assert seq.failure is Failure.LINK_LOST and not seq.streaming
    assert not commands(acts)


def fly(seq: FlightSequence) -> float:
    t = to_offboard(seq)
    t += DT
    acts = seq.on_command_result(MAV_CMD_DO_SET_MODE, True, "ok", t)
    assert commands(acts) == [SendCommand.arm_disarm(True)]
    t += DT
    seq.on_command_result(MAV_CMD_COMPONENT_ARM_DISARM, True, "ok", t)
    assert seq.phase is Phase.FLY and seq.t_fly0 == t
    return t


def test_left_offboard_fails_without_fighting_back() -> None:
    seq = FlightSequence(SequenceConfig(rate_hz=RATE, duration_s=5.0))
    t = fly(seq)
    t, _ = run(seq, t, t + 0.5, VehicleView(armed=True, mode=FlightMode.OFFBOARD))
    acts = seq.update(t + DT, VehicleView(armed=True, mode=FlightMode.POSCTL))
    assert seq.failure is Failure.LEFT_OFFBOARD and "POSCTL" in seq.reason
    assert not commands(acts) and not seq.streaming


def test_land_detected_disarms_once_then_done() -> None:
    seq = FlightSequence(SequenceConfig(rate_hz=RATE, duration_s=2.0, end=EndPolicy(
        handover_mode=FlightMode.LAND, touchdown_from_s=1.0)))
    t = fly(seq)
    airborne = VehicleView(armed=True, mode=FlightMode.OFFBOARD)
    t, acts = run(seq, t, t + 1.5, airborne)
    assert not commands(acts)  # not on the ground yet: no disarm
    landed = VehicleView(armed=True, mode=FlightMode.OFFBOARD, on_ground=True)
    t, acts = run(seq, t, t + 0.5, landed)
    assert commands(acts) == [SendCommand.arm_disarm(False)]  # once
    assert seq.streaming  # still streaming through the disarm
    acts = seq.update(t + DT, VehicleView(armed=False, mode=FlightMode.OFFBOARD, on_ground=True))
    assert seq.phase is Phase.DONE and not seq.streaming
    assert any(isinstance(a, Finished) and a.ok for a in acts)


def test_no_landing_detected_hands_over_to_land() -> None:
    seq = FlightSequence(SequenceConfig(rate_hz=RATE, duration_s=1.0, end=EndPolicy(
        handover_mode=FlightMode.LAND, touchdown_from_s=1.0, touchdown_timeout_s=2.0)))
    t = fly(seq)
    t, acts = run(seq, t, t + 3.5, VehicleView(armed=True, mode=FlightMode.OFFBOARD))
    assert commands(acts) == [SendCommand(MAV_CMD_NAV_LAND)]
    assert seq.phase is Phase.HANDOVER
    t, _ = run(seq, t, t + 0.5, VehicleView(armed=True, mode=FlightMode.LAND))
    assert seq.phase is Phase.WAIT_DISARM
    t, acts = run(seq, t, t + 0.5, VehicleView(armed=True, mode=FlightMode.LAND, on_ground=True))
    assert commands(acts) == [SendCommand.arm_disarm(False)]
    run(seq, t, t + 0.5, VehicleView(armed=False, mode=FlightMode.LAND, on_ground=True))
    assert seq.phase is Phase.DONE


def test_hold_handover_streams_until_the_mode_is_confirmed() -> None:
    seq = FlightSequence(SequenceConfig(rate_hz=RATE, duration_s=1.0, end=EndPolicy(
        stream_handover=True, land_and_disarm=False)))
    t = fly(seq)
    t, acts = run(seq, t, t + 1.1, VehicleView(armed=True, mode=FlightMode.OFFBOARD))
    assert commands(acts) == [SendCommand.set_mode(FlightMode.HOLD)]
    assert seq.streaming
    acts = seq.on_command_result(MAV_CMD_DO_SET_MODE, True, "ok", t + DT)
    assert seq.phase is Phase.DONE and not seq.streaming


def test_land_handover_then_landing_and_disarm_within_the_timeout() -> None:
    """`fly`'s end: AUTO.LAND by DO_SET_MODE while streaming, then landed and disarmed."""
    seq = FlightSequence(SequenceConfig(rate_hz=RATE, duration_s=1.0, end=EndPolicy(
        handover_mode=FlightMode.LAND, land_command=False, stream_handover=True,
        land_timeout_s=5.0)))
    t = fly(seq)
    t, acts = run(seq, t, t + 1.1, VehicleView(armed=True, mode=FlightMode.OFFBOARD))
    assert commands(acts) == [SendCommand.set_mode(FlightMode.LAND)] and seq.streaming
    t += DT
    seq.on_command_result(MAV_CMD_DO_SET_MODE, True, "ok", t)
    assert not seq.streaming and seq.phase is Phase.HANDOVER
    t, _ = run(seq, t, t + 0.1, VehicleView(armed=True, mode=FlightMode.LAND))
    assert seq.phase is Phase.WAIT_DISARM
    t, acts = run(seq, t, t + 4.0, VehicleView(armed=True, mode=FlightMode.LAND))
    assert not commands(acts) and not seq.finished  # still descending
    t, acts = run(seq, t, t + 2.0, VehicleView(armed=True, mode=FlightMode.LAND))
    assert seq.failure is Failure.NO_LAND and "waiting for the landing" in seq.reason


def test_refused_auto_land_falls_back_to_nav_land() -> None:
    seq = FlightSequence(SequenceConfig(rate_hz=RATE, duration_s=1.0, end=EndPolicy(
        handover_mode=FlightMode.LAND, land_command=False, stream_handover=True)))
    t = fly(seq)
    t, _ = run(seq, t, t + 1.1, VehicleView(armed=True, mode=FlightMode.OFFBOARD))
    t += DT
    seq.on_command_result(MAV_CMD_DO_SET_MODE, False, "DENIED", t)
    t, acts = run(seq, t, t + 3.5, VehicleView(armed=True, mode=FlightMode.HOLD))
    assert commands(acts) == [SendCommand.land()] and seq.phase is Phase.HANDOVER
    t, _ = run(seq, t, t + 0.1, VehicleView(armed=True, mode=FlightMode.LAND))
    assert seq.phase is Phase.WAIT_DISARM


def test_rover_disarmed_in_hold_and_a_refusal_fails() -> None:
    def rover() -> tuple[FlightSequence, float]:
        seq = FlightSequence(SequenceConfig(rate_hz=RATE, duration_s=1.0, end=EndPolicy(
            stream_handover=True, disarm_at_hold=True, disarm_on_ground=False)))
        t = fly(seq)
        t, _ = run(seq, t, t + 1.1, VehicleView(armed=True, mode=FlightMode.OFFBOARD))
        t += DT
        seq.on_command_result(MAV_CMD_DO_SET_MODE, True, "ok", t)
        t, acts = run(seq, t, t + 0.1, VehicleView(armed=True, mode=FlightMode.HOLD,
                                                    on_ground=True))
        assert commands(acts) == [SendCommand.arm_disarm(False)]  # once
        return seq, t

    seq, t = rover()
    run(seq, t, t + 0.1, VehicleView(armed=False, mode=FlightMode.HOLD))
    assert seq.phase is Phase.DONE
    seq, t = rover()
    acts = seq.on_command_result(MAV_CMD_COMPONENT_ARM_DISARM, False, "DENIED", t + DT, 4)
    fin = [a for a in acts if isinstance(a, Finished)]
    assert fin and fin[0].failure is Failure.DISARM_REFUSED and fin[0].result == 4


def pilot_seq(duration_s: float = 2.0, **end: object) -> FlightSequence:
    return FlightSequence(SequenceConfig(
        rate_hz=RATE, duration_s=duration_s, pilot_start=True,
        end=EndPolicy(handover_mode=FlightMode.LAND, land_command=False, land_and_disarm=False,
                      settle_s=3.0, settle_m=0.5, end_ned=(10.0, 0.0, -5.0),
                      handover_retry_s=3.0, **end)))  # type: ignore[arg-type]


OFFBOARD = VehicleView(armed=True, mode=FlightMode.OFFBOARD)


def test_pilot_start_flies_when_offboard_is_seen_without_requesting_or_arming() -> None:
    seq = pilot_seq()
    _, acts = run(seq, 0.0, 1.0, VehicleView(armed=True, mode=FlightMode.POSCTL))
    assert not acts and seq.phase is Phase.WAIT_READY and not seq.streaming
    acts = seq.update(1.5, OFFBOARD)
    assert seq.phase is Phase.FLY and seq.t_fly0 == 1.5 and not commands(acts)
    assert seq.machine.state.value == "active"  # the pilot's OFFBOARD: IDLE -> ACTIVE
    t, acts = run(seq, 1.5, 3.0, OFFBOARD)
    assert not commands(acts)
    streams = [a for a in acts if isinstance(a, Stream)]
    assert streams and all(s.t_s is not None for s in streams)
    # the pilot leaves OFFBOARD mid-trajectory: this entry ends, nothing is requested
    acts = seq.update(t + DT, VehicleView(armed=True, mode=FlightMode.POSCTL))
    assert seq.failure is Failure.LEFT_OFFBOARD and not commands(acts)


def test_pilot_start_hands_over_once_settled_near_the_end() -> None:
    seq = pilot_seq()
    seq.update(0.0, OFFBOARD)
    near = VehicleView(armed=True, mode=FlightMode.OFFBOARD, pos_ned=(10.2, 0.0, -5.0))
    _, acts = run(seq, 0.0, 2.0 - 2 * DT, near)
    assert not commands(acts)  # close, but the trajectory has not ended
    _, acts = run(seq, 2.0 - 2 * DT, 2.0 + 2 * DT, near)
    assert commands(acts) == [SendCommand.set_mode(FlightMode.LAND)]
    assert seq.phase is Phase.HANDOVER


def test_stale_position_hands_over_after_settle_s() -> None:
    seq = pilot_seq()
    seq.update(0.0, OFFBOARD)
    t, acts = run(seq, 0.0, 4.9, OFFBOARD)  # no position: only the timeout
    assert not commands(acts)
    t, acts = run(seq, t, 5.0 + 2 * DT, OFFBOARD)
    assert commands(acts) == [SendCommand.set_mode(FlightMode.LAND)]


def test_final_mode_is_retried_while_in_offboard_until_px4_switches() -> None:
    seq = pilot_seq(duration_s=0.0)
    seq.update(0.0, OFFBOARD)
    t, acts = run(seq, 0.0, 3.0 + 2 * DT, OFFBOARD)
    sent = commands(acts)
    assert sent == [SendCommand.set_mode(FlightMode.LAND)]
    t_sent = next(a.t_s for a in acts if isinstance(a, PhaseChanged) and a.new is Phase.HANDOVER)
    # the results do not matter: a refusal changes nothing
    assert not seq.on_command_result(MAV_CMD_DO_SET_MODE, False, "DENIED", t)
    t, acts = run(seq, t, t_sent + 3.0 - DT, OFFBOARD)
    assert not commands(acts)
    t, acts = run(seq, t, t_sent + 3.0 + DT, OFFBOARD)
    assert commands(acts) == [SendCommand.set_mode(FlightMode.LAND)]
    t, acts = run(seq, t, t + 6.0 + DT, OFFBOARD)
    assert len(commands(acts)) == 2 and not seq.finished
    acts = seq.update(t + DT, VehicleView(armed=True, mode=FlightMode.LAND))
    fin = [a for a in acts if isinstance(a, Finished)]
    assert fin and fin[0].ok and seq.phase is Phase.DONE and not commands(acts)


def test_without_retry_the_handover_is_sent_once() -> None:
    seq = FlightSequence(SequenceConfig(
        rate_hz=RATE, duration_s=0.0, pilot_start=True,
        end=EndPolicy(handover_mode=FlightMode.HOLD, land_and_disarm=False, settle_s=0.5)))
    seq.update(0.0, OFFBOARD)
    _, acts = run(seq, 0.0, 10.0, OFFBOARD)
    assert commands(acts) == [SendCommand.set_mode(FlightMode.HOLD)]
