"""COMMAND_LONG client with fake time: retries, ack matching, IN_PROGRESS, double mode acks."""

from __future__ import annotations

from collections.abc import Sequence

import pytest

from companion.mavlink import CommandBusyError, CommandClient, CommandFinished, CommandProgress
from companion.mavlink.commands import UnsolicitedAck
from companion.mavlink.px4_mode import FlightMode, custom_mode_of
from tests.support.mavlink_fakes import Outbox, Px4Side, command_ack

ARM = 400
SET_MODE = 176
OFFBOARD = custom_mode_of(FlightMode.OFFBOARD)
POSCTL = 196608  # observed PX4 HEARTBEAT custom_mode for POSCTL (PX4.md)


@pytest.fixture
def px4() -> Px4Side:
    return Px4Side()


def make() -> tuple[CommandClient, Outbox]:
    out = Outbox()
    return CommandClient(out, own_sysid=1, own_compid=191), out


def finished(events: Sequence[object]) -> list[CommandFinished]:
    return [e for e in events if isinstance(e, CommandFinished)]


def test_retries_increment_confirmation_then_time_out() -> None:
    cc, out = make()
    cc.send_command(ARM, [1.0], now=10.0)
    assert [m.confirmation for m in out.take()] == [0]
    assert cc.handle_timer(10.49) == [] and out.take() == []  # not yet due
    for k, t in enumerate([10.5, 11.0, 11.5], start=1):
        assert cc.handle_timer(t) == []
        (msg,) = out.take()
        assert msg.get_type() == "COMMAND_LONG" and msg.command == ARM
        assert msg.confirmation == k and msg.param1 == 1.0
        assert (msg.target_system, msg.target_component) == (1, 1)
    (fin,) = finished(cc.handle_timer(12.0))
    assert not fin.ok and fin.result is None and fin.attempts == 4
    assert out.take() == [] and not cc.is_pending(ARM)


def test_ack_after_retry_finishes_and_stops_resending(px4: Px4Side) -> None:
    cc, out = make()
    cc.send_command(ARM, [1.0], now=0.0)
    cc.handle_timer(0.5)
    (fin,) = finished(cc.on_command_ack(px4.msg(command_ack(ARM, 0)), 0.6))
    assert fin.ok and fin.result == 0 and fin.attempts == 2
    out.take()
    assert cc.handle_timer(5.0) == [] and out.take() == []


@pytest.mark.parametrize(
    ("ack_kwargs", "src"),
    [
        ({"target_system": 7}, (1, 1)),          # addressed to another system
        ({"target_component": 5}, (1, 1)),       # addressed to another component
        ({}, (2, 1)),                            # from another vehicle
        ({}, (1, 100)),                          # from a camera on our vehicle
    ],
)
def test_ack_matching_ignores_foreign_acks(ack_kwargs: dict[str, int],
                                           src: tuple[int, int]) -> None:
    cc, _ = make()
    cc.send_command(ARM, [1.0], now=0.0)
    side = Px4Side(*src)
    assert cc.on_command_ack(side.msg(command_ack(ARM, 0, **ack_kwargs)), 0.1) == []
    assert cc.is_pending(ARM)


def test_ack_for_other_command_ignored_and_broadcast_target_accepted(px4: Px4Side) -> None:
    cc, _ = make()
    cc.send_command(ARM, [1.0], now=0.0)
    # an answer to no pending command: reported as such (a module's report), ARM still waits
    (other,) = cc.on_command_ack(px4.msg(command_ack(22, 0)), 0.1)
    assert isinstance(other, UnsolicitedAck) and (other.command, other.result) == (22, 0)
    assert cc.is_pending(ARM)
    (fin,) = finished(cc.on_command_ack(px4.msg(command_ack(ARM, 2, 0, 0)), 0.2))
    assert not fin.ok and fin.result == 2  # DENIED, carried through


def test_in_progress_stops_retries_and_waits_for_final(px4: Px4Side) -> None:
    cc, out = make()
    cc.send_command(22, [], now=0.0)
    out.take()
    (prog,) = cc.on_command_ack(px4.msg(command_ack(22, 5, progress=40)), 0.1)
    assert isinstance(prog, CommandProgress) and prog.progress == 40
    assert cc.handle_timer(1.0) == [] and out.take() == []  # no re-send while in progress
    (fin,) = finished(cc.on_command_ack(px4.msg(command_ack(22, 0)), 2.0))
    assert fin.ok


def test_in_progress_then_silence_fails() -> None:
    cc, _out = make()
    px4 = Px4Side()
    cc.send_command(22, [], now=0.0)
    cc.on_command_ack(px4.msg(command_ack(22, 5)), 0.1)
    assert cc.handle_timer(3.0) == []
    (fin,) = finished(cc.handle_timer(3.1))
    assert not fin.ok and fin.result is None


def test_duplicate_command_is_busy() -> None:
    cc, _ = make()
    cc.send_command(ARM, [1.0], now=0.0)
    with pytest.raises(CommandBusyError):
        cc.send_command(ARM, [0.0], now=0.1)
    cc.send_command(22, [], now=0.1)  # a different command may run concurrently


def _mode_client() -> tuple[CommandClient, Outbox]:
    cc, out = make()
    cc.on_heartbeat_mode(POSCTL, 0.0)
    cc.send_command(SET_MODE, [129.0, 6.0, 0.0], now=1.0, mode_custom=OFFBOARD)
    return cc, out


def test_mode_double_ack_last_verdict_wins(px4: Px4Side) -> None:
    """PX4: ACCEPTED on receipt, then the commander's TEMPORARILY_REJECTED ~10 ms later."""
    cc, _ = _mode_client()
    assert cc.on_command_ack(px4.msg(command_ack(SET_MODE, 0)), 1.02) == []
    assert cc.on_command_ack(px4.msg(command_ack(SET_MODE, 1)), 1.03) == []
    assert cc.on_heartbeat_mode(POSCTL, 1.5) == []
    assert cc.handle_timer(2.0) == []  # window of 1 s from the first ack still open
    (fin,) = finished(cc.handle_timer(2.03))
    assert not fin.ok and fin.result == 1


def test_mode_accepted_needs_heartbeat_confirmation(px4: Px4Side) -> None:
    cc, _ = _mode_client()
    cc.on_command_ack(px4.msg(command_ack(SET_MODE, 0)), 1.02)
    cc.on_command_ack(px4.msg(command_ack(SET_MODE, 0)), 1.03)
    assert cc.on_heartbeat_mode(POSCTL, 1.4) == []
    assert cc.handle_timer(2.1) == []  # verdict ACCEPTED but not confirmed yet
    (fin,) = finished(cc.on_heartbeat_mode(OFFBOARD, 2.3))
    assert fin.ok and fin.result == 0


def test_mode_accepted_but_never_confirmed_fails(px4: Px4Side) -> None:
    cc, _ = _mode_client()
    cc.on_command_ack(px4.msg(command_ack(SET_MODE, 0)), 1.02)
    assert cc.handle_timer(2.1) == []
    assert cc.handle_timer(3.5) == []
    (fin,) = finished(cc.handle_timer(3.52))
    assert not fin.ok and fin.result == 0 and "HEARTBEAT" in fin.reason


def test_mode_single_ack_then_heartbeat_succeeds_early(px4: Px4Side) -> None:
    cc, out = _mode_client()
    (msg,) = out.take()
    assert (msg.param1, msg.param2, msg.param3) == (129.0, 6.0, 0.0)
    cc.on_command_ack(px4.msg(command_ack(SET_MODE, 0)), 1.02)
    (fin,) = finished(cc.on_heartbeat_mode(OFFBOARD, 1.2))
    assert fin.ok and fin.t_s == 1.2


def test_mode_heartbeat_without_ack_is_not_success() -> None:
    cc, _out = _mode_client()
    assert cc.on_heartbeat_mode(OFFBOARD, 1.2) == []
    # without any ack the command keeps being retried and finally times out
    for t in (1.5, 2.0, 2.5):
        cc.handle_timer(t)
    (fin,) = finished(cc.handle_timer(3.0))
    assert not fin.ok and fin.result is None
