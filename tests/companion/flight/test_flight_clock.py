"""`FlightClock`: flight time follows the autopilot's clock (time_boot of its telemetry), so a
reference timed by it never runs ahead of a vehicle whose clock is slow or stalled; at full
speed it is the local clock shifted by a constant."""

from __future__ import annotations

import numpy as np
import pytest

from companion.flight.clock import FlightClock


def _fly(speed: object, seconds: float, latency: float = 0.02, jitter: float = 0.01,
         sample_hz: float = 30.0, call_hz: float = 100.0, seed: int = 0
         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Local times, flight times and the vehicle's own time at each call. `speed(t)`: rate of
    the vehicle clock against the local one at local time t (0: stalled)."""
    rng = np.random.default_rng(seed)
    clock = FlightClock()
    dt = 1.0 / call_hz
    boot = 0.0
    next_sample = 0.0
    pending: list[tuple[float, float]] = []  # (receive local time, boot stamp)
    t_loc, t_fl, t_veh = [], [], []
    for k in range(int(seconds * call_hz)):
        t = k * dt
        boot += speed(t) * dt  # type: ignore[operator]
        if boot >= next_sample:
            pending.append((t + latency + rng.uniform(0.0, jitter), boot))
            next_sample += 1.0 / sample_hz
        for rx, b in [p for p in pending if p[0] <= t]:
            clock.observe(b, rx)
        pending = [p for p in pending if p[0] > t]
        t_loc.append(t)
        t_fl.append(clock.now(t))
        t_veh.append(boot)
    return np.array(t_loc), np.array(t_fl), np.array(t_veh)


def test_full_speed_is_the_local_clock_shifted() -> None:
    loc, fl, _ = _fly(lambda t: 1.0, 30.0)
    steady = loc > 1.0
    rate = np.diff(fl[steady]) / np.diff(loc[steady])
    assert rate.min() == pytest.approx(1.0, abs=1e-9)  # never slowed: the lead covers the link
    assert np.ptp(fl[steady] - loc[steady]) < 1e-9


@pytest.mark.parametrize("speed", [0.97, 0.7, 0.4])
def test_a_slow_vehicle_clock_slows_flight_time_as_much(speed: float) -> None:
    loc, fl, veh = _fly(lambda t: speed, 40.0)
    late = loc > 10.0
    # flight time advances at the vehicle's rate, within 1 %, and never more than the lead
    # plus the sample interval and latency ahead of the vehicle's own time
    rate = (fl[late][-1] - fl[late][0]) / (loc[late][-1] - loc[late][0])
    assert rate == pytest.approx(speed, rel=0.01)
    ahead = fl[late] - (veh[late] + (fl[0] - veh[0]))
    assert ahead.max() < 0.08 + 1.0 / 30 + 0.03 + 0.05


def test_a_stall_freezes_flight_time_without_a_jump() -> None:
    """PX4 SITL stalls 0.3 s (no simulation, no telemetry): flight time stops within ~lead +
    1 / gain of the last sample, and resumes smoothly: it is monotonic, never faster than the
    local clock, and its total loss equals the stall's (the vehicle lost that time too)."""
    def speed(t: float) -> float:
        return 0.0 if 5.0 <= t < 5.3 else 1.0
    loc, fl, _veh = _fly(speed, 10.0, jitter=0.0)
    steps = np.diff(fl)
    assert steps.min() >= 0.0
    assert steps.max() <= 0.01 + 1e-12
    during = (loc >= 5.0) & (loc < 5.3)
    gained = fl[during][-1] - fl[during][0]
    assert gained < 0.08 + 0.033 + 0.05 + 0.02  # lead + sample interval + 1 / gain + latency
    # afterwards flight time keeps the vehicle's pace: it lost the 0.3 s (within the lead)
    lost = (loc[-1] - fl[-1]) - (loc[300] - fl[300])
    assert lost == pytest.approx(0.3, abs=0.08)


def test_a_vehicle_clock_that_does_not_advance_is_not_followed() -> None:
    """Samples keep arriving, their time_boot stuck: after `frozen_s` flight time runs with the
    local clock again (a flight must not hold at its start forever)."""
    c = FlightClock(frozen_s=1.0)
    t_fl = []
    for k in range(300):  # 3 s at 100 Hz
        t = 0.01 * k
        c.observe(0.5, t)
        t_fl.append(c.now(t))
    late = np.diff(t_fl[200:])
    assert late.min() == pytest.approx(0.01)
    assert t_fl[-1] < 3.0  # it did stop while the stall was plausible


def test_before_any_sample_it_is_the_local_clock_and_never_runs_back() -> None:
    c = FlightClock()
    assert c.now(10.0) == 10.0
    assert c.now(10.5) == 10.5
    assert c.now(10.2) == 10.5  # an earlier call (another thread's) does not move it back


@pytest.mark.parametrize("kw", [{"lead_s": -1.0}, {"gain_per_s": 0.0},
                                {"lead_s": float("nan")}, {"frozen_s": 0.0}])
def test_refuses_bad_settings(kw: dict[str, float]) -> None:
    with pytest.raises(ValueError):
        FlightClock(**kw)


def test_at_full_speed_flight_time_is_the_local_clock_to_the_bit() -> None:
    """The replay runs its flights on this clock: at full speed (samples that keep up) flight
    time must be the lockstep clock itself, not a sum of its steps (which rounds)."""
    clock = FlightClock()
    dt = 0.01
    for k in range(1, 3001):
        t = k * dt
        clock.observe(t - 0.004, t)  # each sample received 4 ms after it was taken
        assert clock.now(t) == t
    assert clock.lag_s == 0.0

