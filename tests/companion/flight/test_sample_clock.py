"""`SampleClock`: vehicle sample times (time_boot) mapped to the local clock.

Oracle: a simulated link where the true local time of every sample is known: the vehicle clock
runs at `rate` local seconds per boot second from an arbitrary epoch, and every sample arrives
after a random latency; one sample per second meets the minimum latency. The mapping must
recover the true sample time; a plain sliding minimum (the previous method, written out here)
does not when the clocks drift, which is what real PX4 SITL's lockstep clock does (0.73 % slow).
"""

from __future__ import annotations

import math
import random

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.flight.clock import CHANGE_SLEW, OFFSET_SLEW, SampleClock


def simulated_link(drift: float, seconds: float, seed: int, hz: float = 30.0,
                   min_latency: float = 0.004) -> list[tuple[float, float, float]]:
    """(t_boot, t_receive, t_true_local) triples; offset(t_boot) = 1000 + drift * t_boot."""
    rng = random.Random(seed)
    out = []
    n = int(seconds * hz)
    for k in range(n):
        boot = 12.0 + k / hz
        true_local = boot + 1000.0 + drift * boot
        jitter = 0.0 if k % int(hz) == 7 else rng.expovariate(1 / 0.003)
        out.append((boot, true_local + min_latency + jitter, true_local))
    return out


def sliding_minimum(samples: list[tuple[float, float, float]], window: int) -> list[float]:
    offs: list[float] = []
    out = []
    for boot, rx, _ in samples:
        offs.append(rx - boot)
        out.append(boot + min(offs[-window:]))
    return out


@pytest.mark.parametrize("drift", [0.0, 0.0073, -0.0073, 0.05])
def test_mapping_recovers_sample_times_under_clock_drift(drift: float) -> None:
    samples = simulated_link(drift, 40.0, seed=1)
    clock = SampleClock()
    errors = [clock.local_time(boot, rx) - true - 0.004 for boot, rx, true in samples]
    settled = errors[(5 * 30):]  # after 5 s (enough blocks for the drift fit)
    assert max(abs(e) for e in settled) < 1e-3 + abs(drift) * 1.0
    assert clock.drift == pytest.approx(drift, abs=2e-4)
    if drift > 0.005:
        old = sliding_minimum(samples, 200)
        old_err = max(abs(m - true - 0.004) for m, (_, _, true) in zip(old, samples, strict=True))
        assert old_err > 0.02  # what the drift did to a plain minimum over 200 samples


def test_no_drift_gives_the_plain_minimum_offset_exactly() -> None:
    clock = SampleClock()
    for k in range(100):
        boot = k * 0.033
        got = clock.local_time(boot, boot + 5.0 + (0.0 if k % 10 == 0 else 0.002 * (k % 7)))
        assert got == pytest.approx(boot + 5.0, abs=1e-9)


def test_repeated_sample_changes_nothing() -> None:
    clock = SampleClock()
    for k in range(200):
        clock.local_time(k * 0.1, k * 0.1 + 3.0 + 0.001 * (k % 5))
    a = clock.local_time(20.0, 23.5)
    assert clock.local_time(20.0, 23.5) == a


def test_reboot_starts_over() -> None:
    clock = SampleClock()
    for k in range(300):
        clock.local_time(100.0 + k * 0.05, 1000.0 + k * 0.05)
    # the autopilot rebooted: boot time restarts at 0 while local time goes on
    t = clock.local_time(0.05, 1016.0)
    assert t == pytest.approx(1016.0, abs=1e-9)


def test_rejects_bad_settings() -> None:
    with pytest.raises(ValueError):
        SampleClock(block_s=0.0)
    with pytest.raises(ValueError):
        SampleClock(blocks=0)


@settings(max_examples=60, deadline=None)
@given(st.floats(-0.02, 0.02), st.integers(0, 10_000), st.floats(0.0, 0.05))
def test_mapped_time_is_never_later_than_the_receive_time_and_close_to_the_truth(
    drift: float, seed: int, min_latency: float
) -> None:
    samples = simulated_link(drift, 12.0, seed, min_latency=min_latency)
    clock = SampleClock()
    for i, (boot, rx, true) in enumerate(samples):
        got = clock.local_time(boot, rx)
        assert got <= rx + 1e-9 + abs(drift) * clock.block_s
        if i > 4 * 30:
            assert math.isclose(got, true + min_latency, abs_tol=1e-3 + abs(drift) * 1.0)


def test_one_delayed_block_does_not_tilt_the_drift() -> None:
    samples = simulated_link(0.0073, 30.0, seed=3)
    clock = SampleClock()
    for i, (boot, rx, _true) in enumerate(samples):
        late = 0.1 if 18 * 30 <= i < 19 * 30 else 0.0  # every sample of one second 100 ms late
        clock.local_time(boot, rx + late)
    assert clock.drift == pytest.approx(0.0073, abs=3e-4)
    boot, rx, true = samples[-1]
    assert clock.local_time(boot, rx) == pytest.approx(true + 0.004, abs=1.5e-3)


def test_a_fresh_clock_settles_within_a_second_under_drift() -> None:
    # a flight starts with a fresh clock: 1 % drift (PX4 SITL's lockstep clock under load)
    samples = simulated_link(0.01, 10.0, seed=5)
    clock = SampleClock()
    errors = [clock.local_time(boot, rx) - true - 0.004 for boot, rx, true in samples]
    assert max(abs(e) for e in errors[30:]) < 3e-3  # after 1 s: 3 ms (10 ms of drift per s)


def test_follows_a_clock_that_falls_behind_in_a_burst() -> None:
    # the vehicle clock stalls for 50 ms at boot 22 s (a busy host holds SITL's lockstep
    # back): every later sample's offset is 50 ms larger; a line touching all minima since
    # the start would stay 50 ms early for as long as it remembers the old ones
    base = simulated_link(0.0, 20.0, seed=7)
    samples = [(b, rx + (0.05 if b >= 22.0 else 0.0), true + (0.05 if b >= 22.0 else 0.0))
               for b, rx, true in base]
    clock = SampleClock()
    late = []
    for boot, rx, true in samples:
        err = clock.local_time(boot, rx) - true - 0.004
        if boot >= 22.0 + 2.5:
            late.append(err)
    assert late and max(abs(e) for e in late) < 2e-3


def test_rejects_a_recent_window_outside_the_blocks() -> None:
    with pytest.raises(ValueError):
        SampleClock(blocks=4, recent=5)
    with pytest.raises(ValueError):
        SampleClock(recent=0)


def test_a_stall_moves_the_given_offset_no_faster_than_its_slew() -> None:
    """The autopilot's clock stalls 46 ms mid-flight (real PX4 SITL in CI): the fitted line
    jumps by that when the stall's block becomes the newest minimum, which stepped the
    controller's extrapolation by 0.23 m at 5 m/s. The offset the clock gives moves at most
    OFFSET_SLEW s per second beyond the fitted drift (under 1e-3 here), and still ends on the
    new line."""
    base = simulated_link(0.0, 30.0, seed=11)
    samples = [(b, rx + (0.046 if b >= 22.0 else 0.0), true + (0.046 if b >= 22.0 else 0.0))
               for b, rx, true in base]
    clock = SampleClock()
    prev: tuple[float, float] | None = None
    fastest, late = 0.0, []
    for boot, rx, true in samples:
        off = clock.local_time(boot, rx) - boot
        if prev is not None and boot > 3.0:
            fastest = max(fastest, abs(off - prev[0]) / (rx - prev[1]))
        prev = (off, rx)
        if boot >= 22.0 + 3.0:
            late.append(clock.local_time(boot, rx) - true - 0.004)
    assert fastest <= OFFSET_SLEW + 1e-3
    assert late and max(abs(e) for e in late) < 2e-3


@pytest.mark.parametrize("drift", [0.08, 0.43, 1.0, -0.2])
def test_follows_an_autopilot_clock_that_runs_far_slower_or_faster_than_ours(
        drift: float) -> None:
    # PX4 SITL on a slow host runs at 0.7-0.93x real time: its time_boot falls behind ours by
    # 0.08-0.43 s per second (0.43: 0.7x; 1.0: half speed; -0.2: a clock 25 % fast). An offset
    # moved only at OFFSET_SLEW toward the fitted line fell behind by seconds (real PX4,
    # 2026-12-01: 7 s at the end of a 25 s flight), every sample then looked stale
    samples = simulated_link(drift, 30.0, seed=11)
    clock = SampleClock()
    errors = [clock.local_time(boot, rx) - true - 0.004 for boot, rx, true in samples]
    settled = errors[3 * 30:]
    assert max(abs(e) for e in settled) < 5e-3
    assert clock.drift == pytest.approx(drift, rel=0.01)


def rate_step_link(rate0: float, rate1: float, step_boot: float, seconds: float, seed: int,
                   hz: float = 30.0) -> list[tuple[float, float, float]]:
    """`simulated_link` with the vehicle's clock running at `rate0` boot seconds per local second
    until boot time `step_boot` [s], then at `rate1` (samples `hz` per boot second)."""
    rng = random.Random(seed)
    out = []
    for k in range(int(seconds * hz)):
        boot = 12.0 + k / hz
        true_local = 1000.0 + (boot / rate0 if boot < step_boot
                               else step_boot / rate0 + (boot - step_boot) / rate1)
        jitter = 0.0 if k % int(hz) == 7 else rng.expovariate(1 / 0.003)
        out.append((boot, true_local + 0.004 + jitter, true_local))
    return out


@pytest.mark.parametrize(("rate0", "rate1"), [
    (0.98, 0.65),  # real PX4 SITL when its host got busy (2026-12-01)
    (0.65, 0.98),  # and back
    (1.0, 0.95),  # a mild slow-down: below CHANGE_STEP_S a block, found by the run
    (0.98, 0.5),
])
def test_follows_a_step_in_the_autopilot_clocks_rate(rate0: float, rate1: float) -> None:
    """The clock's rate steps at boot 22 s. The drift fitted over 20 s lagged: at 0.98x ->
    0.65x the mapped sample times fell 3.2 s behind (every sample stale for the law, 0.5 s);
    at 1.0x -> 0.95x they stayed 0.1 s early for 14 s. The departure from the drift is found
    within three blocks (0.75 s of boot time) and the new rate followed from there."""
    samples = rate_step_link(rate0, rate1, 22.0, 30.0, seed=13)
    jump = abs(1.0 / rate1 - 1.0 / rate0)  # the change of the drift [s/s]
    clock = SampleClock()
    prev: tuple[float, float, float, bool] | None = None
    for boot, rx, true in samples:
        got = clock.local_time(boot, rx)
        err = got - true - 0.004
        assert got <= rx
        if boot > 15.0:  # settled on the first rate
            assert abs(err) < 1e-3 + jump * 1.0, (boot, err)
            # and it never jumps: the offset moves along the drift and at most CHANGE_SLEW
            # toward the line besides (taken at once, the refitted line moved the offset by
            # 0.17-0.25 s between two samples on real PX4, and the law's extrapolation with it)
            assert prev is not None
            moved = (got - boot) - prev[0] - clock.drift * (boot - prev[1])
            if got < rx and prev[3]:  # (not held to its arrival time: a clock speeding up)
                assert abs(moved) <= CHANGE_SLEW * (rx - prev[2]) + 2e-3, (boot, moved)
        if boot > 22.0 + 2.0:
            assert abs(err) < 6e-3, (boot, err)
        prev = (got - boot, boot, rx, got < rx)
    assert clock.drift == pytest.approx(1.0 / rate1 - 1.0, rel=0.01)


@settings(max_examples=40, deadline=None)
@given(st.floats(-0.05, 0.05), st.integers(0, 10_000), st.floats(0.002, 0.02))
def test_a_steady_clock_behind_a_jittery_link_is_not_taken_for_a_rate_change(
        drift: float, seed: int, jitter_s: float) -> None:
    """Latency jitter up to 20 ms mean (a slow link) at a steady drift: the mapped times stay on
    the line (a rate change wrongly found would refit the drift from three blocks, and its
    error would show here)."""
    rng = random.Random(seed)
    clock = SampleClock()
    for k in range(30 * 30):
        boot = 12.0 + k / 30.0
        true = 1000.0 + boot * (1.0 + drift)
        late = 0.0 if k % 10 == 3 else rng.expovariate(1 / jitter_s)
        got = clock.local_time(boot, true + 0.004 + late)
        if boot > 12.0 + 5.0:
            assert abs(got - true - 0.004) < 2e-3, (boot, got - true - 0.004)
