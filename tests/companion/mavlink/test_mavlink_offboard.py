"""Offboard state machine: priming guard, transitions, never re-entering OFFBOARD by itself."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.mavlink import (
    TRANSITIONS,
    OffboardMachine,
    OffboardNotPrimedError,
    OffboardState,
    OffboardTrigger,
)

S, T = OffboardState, OffboardTrigger


def stream(sm: OffboardMachine, t0: float, t1: float, rate: float) -> float:
    """Send setpoints at ``rate`` from t0 (inclusive) while t < t1; returns the last time."""
    n = 0
    t = t0
    while t < t1 - 1e-12:
        sm.on_setpoint_sent(t)
        n += 1
        t = t0 + n / rate
    return t0 + (n - 1) / rate


def test_happy_path() -> None:
    sm = OffboardMachine(rate_hz=100.0)
    assert sm.state is S.IDLE and not sm.streaming
    sm.start(0.0)
    assert sm.state is S.PRIMING and sm.streaming
    last = stream(sm, 0.0, 0.6, 100.0)
    sm.request(last)
    assert sm.state is S.REQUESTED
    sm.on_mode_result(True, last + 0.1)
    assert sm.state is S.ACTIVE
    assert sm.on_heartbeat_offboard(True, last + 0.5) is None
    ev = sm.on_heartbeat_offboard(False, last + 1.0, "POSCTL")
    assert ev is not None and ev.new is S.EXITED and "POSCTL" in ev.reason
    assert not sm.streaming
    assert [h.new for h in sm.history] == [S.PRIMING, S.REQUESTED, S.ACTIVE, S.EXITED]


def test_pilot_entering_offboard_activates_an_idle_machine_only() -> None:
    sm = OffboardMachine(rate_hz=50.0)
    ev = sm.fire(T.PILOT_ENTERED_OFFBOARD, 1.0, "pilot")
    assert ev is not None and ev.old is S.IDLE and ev.new is S.ACTIVE and sm.streaming
    sm.on_heartbeat_offboard(False, 2.0, "POSCTL")
    assert sm.state is S.EXITED
    assert sm.fire(T.PILOT_ENTERED_OFFBOARD, 3.0) is None  # a new entry is a new machine
    assert sm.state is S.EXITED


@pytest.mark.parametrize("rate", [20.0, 100.0, 250.0])
def test_request_refused_before_half_a_second_of_streaming(rate: float) -> None:
    sm = OffboardMachine(rate_hz=rate)
    sm.start(0.0)
    last = stream(sm, 0.0, 0.45, rate)
    assert not sm.is_primed(last)
    with pytest.raises(OffboardNotPrimedError):
        sm.request(last)
    last = stream(sm, last + 1 / rate, 0.5 + 2 / rate, rate)
    assert sm.is_primed(last)


def test_gap_restarts_priming_and_stale_stream_is_not_primed() -> None:
    sm = OffboardMachine(rate_hz=50.0)
    sm.start(0.0)
    stream(sm, 0.0, 0.4, 50.0)
    last = stream(sm, 0.6, 1.0, 50.0)  # 0.2 s gap > 3 periods: run restarts at 0.6
    assert not sm.is_primed(last)
    last = stream(sm, 1.0, 1.2, 50.0)
    assert sm.is_primed(last)
    assert not sm.is_primed(last + 0.5)  # stream stopped: proof of life gone


def test_too_sparse_stream_is_not_primed() -> None:
    sm = OffboardMachine(rate_hz=100.0)
    sm.start(0.0)
    last = stream(sm, 0.0, 1.0, 40.0)  # 40 Hz while configured for 100 Hz
    assert not sm.is_primed(last)


def test_rejection_and_link_loss() -> None:
    sm = OffboardMachine(rate_hz=50.0)
    sm.start(0.0)
    sm.request(stream(sm, 0.0, 0.6, 50.0))
    sm.on_mode_result(False, 0.7, "TEMPORARILY_REJECTED")
    assert sm.state is S.EXITED and not sm.streaming
    sm.start(1.0)
    sm.request(stream(sm, 1.0, 1.6, 50.0))
    sm.on_mode_result(True, 1.7)
    sm.on_link_lost(2.0)
    assert sm.state is S.LOST and not sm.streaming


def test_rate_must_exceed_px4_minimum() -> None:
    with pytest.raises(ValueError):
        OffboardMachine(rate_hz=2.0)


def test_table_never_leads_back_to_offboard_without_a_new_start() -> None:
    """From EXITED/LOST only START (a new session, by the user) leaves; never REQUEST/CONFIRMED.
    ACTIVE is reached by a confirmed request, or from IDLE when the pilot switched to OFFBOARD."""
    for (state, trig), new in TRANSITIONS.items():
        if state in (S.EXITED, S.LOST):
            assert trig in (T.START, T.STOP)
        if new is S.ACTIVE:
            assert (state, trig) in ((S.REQUESTED, T.CONFIRMED),
                                     (S.IDLE, T.PILOT_ENTERED_OFFBOARD))
        if new is S.REQUESTED:
            assert (state, trig) == (S.PRIMING, T.REQUEST)


@given(st.lists(st.sampled_from(list(OffboardTrigger)), max_size=30))
@settings(max_examples=200, deadline=None)
def test_random_trigger_sequences_follow_the_table(triggers: list[OffboardTrigger]) -> None:
    sm = OffboardMachine(rate_hz=50.0)
    for i, trig in enumerate(triggers):
        before = sm.state
        ev = sm.fire(trig, float(i))
        expected = TRANSITIONS.get((before, trig))
        assert sm.state is (expected if expected is not None else before)
        assert (ev is None) == (expected is None)
