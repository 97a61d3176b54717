"""A tracking law that flies its hover fallback for long is handed over to PX4 (BLIND_S).

The fallback (level, hover thrust) is for a glitch of a few setpoints. On real PX4 SITL at 0.7x
real time a sample clock that fell behind kept every sample stale: 20 s of fallback in OFFBOARD
while the vehicle sank to the ground, and nothing ended the flight. Oracles: the run of
fallbacks is timed from the first one (the telemetry's age passing `stale_after_s`) and ends with
the first regular command; the sequence hands over to the final mode at BLIND_S and the flight
ends failed, saying why."""

from __future__ import annotations

import numpy as np
import pytest

from companion.control import Reference
from companion.control.gains import TrackingConfig
from companion.flatness import MultirotorParams
from companion.flight.policy import BLIND_S
from companion.flight.sequence import (
    EndPolicy,
    Failure,
    Finished,
    FlightSequence,
    SendCommand,
    SequenceConfig,
    VehicleView,
)
from companion.flight.tracking import TrackingSource
from companion.mavlink.px4_mode import FlightMode
from companion.mavlink.setpoints import AttitudeSetpoint, RatesSetpoint
from companion.mavlink.telemetry import Attitude, ExtendedState, LocalPosition, TelemetrySnapshot

PARAMS = MultirotorParams(mass=1.0, inertia=(0.025, 0.025, 0.030), hover_thrust=0.5, drag=1.0)
HOVER = np.array([0.0, 0.0, -5.0])
STALE = TrackingConfig(params=PARAMS).stale_after_s


def hover(t: float) -> Reference:
    return Reference(HOVER.copy())


def snap(now: float, t_sample: float, z: float = -5.0, x: float = 0.0) -> TelemetrySnapshot:
    """The vehicle hovering level at (`x`, 0, `z`) [m, NED], its newest sample taken (and
    received) at `t_sample`."""
    return TelemetrySnapshot(
        position=LocalPosition(t_sample, t_sample, (x, 0.0, z), (0.0, 0.0, 0.0),
                               "LOCAL_POSITION_NED"),
        attitude=Attitude(t_sample, (1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0)),
        extended=ExtendedState(t_sample, 2, 0), now_s=now)


@pytest.mark.parametrize("mode", ["attitude", "rates"])
def test_a_run_of_fallbacks_on_arriving_samples_is_timed_from_its_first_to_its_last(
        mode: str) -> None:
    src = TrackingSource(hover, mode, PARAMS, time_scaling=False)  # type: ignore[arg-type]
    dt = 0.01
    t = 0.0
    for _ in range(300):  # 3 s of fresh telemetry: regular commands
        t += dt
        src(t, snap(t, t))
        assert src.blind_s == 0.0
    seen = []
    for i in range(300):  # samples keep arriving, but the law cannot use them (not finite)
        t += dt
        if i == 0:
            t_first = t
        src(t, snap(t, t, z=float("nan")))
        seen.append((t, src.blind_s))
    for now, blind in seen:
        assert blind == pytest.approx(now - t_first, abs=1e-9)
    assert seen[-1][1] > BLIND_S
    t += dt
    src(t, snap(t, t))  # usable again: the run is over
    assert src.blind_s == 0.0


@pytest.mark.parametrize("mode", ["attitude", "rates"])
def test_a_silent_link_is_a_link_loss_not_blindness(mode: str) -> None:
    """No sample for longer than the stale age: the law falls back, but that is PX4's offboard
    failsafe and the link monitor's business (a relinked flight resumes its mission). The
    vehicle is 3 m behind its reference, so the regular command leans and the fallback is
    level."""
    src = TrackingSource(hover, mode, PARAMS, time_scaling=False)  # type: ignore[arg-type]
    dt = 0.01
    t = 0.0
    for _ in range(300):
        t += dt
        src(t, snap(t, t, x=-3.0))
    t_frozen = t
    fallbacks = 0
    for _ in range(500):  # the telemetry stops for 5 s
        t += dt
        cmd = src(t, snap(t, t_frozen, x=-3.0))
        if isinstance(cmd, AttitudeSetpoint):
            level = abs(cmd.q_wxyz[1]) + abs(cmd.q_wxyz[2]) < 1e-12
        else:
            assert isinstance(cmd, RatesSetpoint)
            level = abs(cmd.omega_frd[0]) + abs(cmd.omega_frd[1]) < 1e-12
        fallbacks += level == (t - t_frozen > STALE)
        assert src.blind_s == 0.0
    assert fallbacks == 500  # the law flew its fallback exactly while the samples were stale


def test_the_sequence_hands_over_at_blind_s_and_the_flight_fails_saying_why() -> None:
    seq = FlightSequence(SequenceConfig(
        rate_hz=50.0, duration_s=60.0, pilot_start=True,
        end=EndPolicy(handover_mode=FlightMode.HOLD)))
    flying = dict(armed=True, mode=FlightMode.OFFBOARD)
    seq.update(0.0, VehicleView(**flying))  # type: ignore[arg-type]
    acts = seq.update(5.0, VehicleView(**flying, blind_s=BLIND_S - 0.01))  # type: ignore[arg-type]
    assert not any(isinstance(a, SendCommand) for a in acts)
    acts = seq.update(5.02, VehicleView(**flying, blind_s=BLIND_S))  # type: ignore[arg-type]
    assert [a for a in acts if isinstance(a, SendCommand)] == [
        SendCommand.set_mode(FlightMode.HOLD)]
    acts = seq.update(5.5, VehicleView(armed=True, mode=FlightMode.HOLD))
    fin = [a for a in acts if isinstance(a, Finished)]
    assert fin and not fin[0].ok and fin[0].failure is Failure.BLIND
    assert "tracking blind" in fin[0].reason and seq.finished


def test_no_blind_limit_never_hands_over() -> None:
    seq = FlightSequence(SequenceConfig(
        rate_hz=50.0, duration_s=60.0, pilot_start=True,
        end=EndPolicy(handover_mode=FlightMode.HOLD, blind_s=None)))
    flying = dict(armed=True, mode=FlightMode.OFFBOARD)
    seq.update(0.0, VehicleView(**flying))  # type: ignore[arg-type]
    acts = seq.update(5.0, VehicleView(**flying, blind_s=30.0))  # type: ignore[arg-type]
    assert not any(isinstance(a, SendCommand) for a in acts)
