"""Fixed-rate streamer: deadline grid (no drift), miss skipping, no bursts; fake clock for the
exact properties, the real clock only for count bounds (never for timing assertions)."""

from __future__ import annotations

import itertools
import threading
import time

import pytest

from companion.aio import FixedRateStreamer


class FakeClock:
    """Monotonic fake time; sleeping advances it; every read advances it by ``tick``."""

    def __init__(self, tick: float = 1e-6) -> None:
        self.t = 100.0
        self.tick = tick
        self.lock = threading.Lock()

    def __call__(self) -> float:
        with self.lock:
            self.t += self.tick
            return self.t

    def sleep(self, dt: float) -> None:
        with self.lock:
            self.t += max(dt, 0.0)


def run_until(streamer: FixedRateStreamer, cond: object, timeout_s: float = 10.0) -> None:
    streamer.start()
    try:
        end = time.monotonic() + timeout_s
        while not cond() and time.monotonic() < end:  # type: ignore[operator]
            time.sleep(0.001)
    finally:
        streamer.stop()


@pytest.mark.parametrize("rate", [100.0, 250.0])
def test_sends_on_the_absolute_deadline_grid(rate: float) -> None:
    clk = FakeClock()
    sent: list[tuple[bytes, float]] = []
    n = [0]

    def producer(now: float) -> bytes:
        n[0] += 1
        return b"sp%d" % n[0]

    st = FixedRateStreamer(rate, lambda b: sent.append((b, clk.t)) is None, producer,
                           clock=clk, sleep=clk.sleep, gil_switch_interval_s=None)
    run_until(st, lambda: len(st.sent_times) >= 500)
    times = list(st.sent_times)[:500]
    period = 1.0 / rate
    t0 = times[0]
    # every send within a few fake ticks after its deadline: no accumulated drift over 500 cycles
    for k, t in enumerate(times):
        assert 0.0 <= t - (t0 + k * period) < 20e-6 + 1e-9 * k
    assert st.missed == 0 and st.producer_errors == 0
    assert [b for b, _ in sent[:3]] == [b"sp1", b"sp2", b"sp3"]


def test_late_cycle_skips_missed_deadlines_instead_of_bursting() -> None:
    clk = FakeClock()
    rate = 100.0
    period = 1.0 / rate
    calls = [0]

    def producer(now: float) -> bytes:
        calls[0] += 1
        if calls[0] == 10:
            clk.sleep(3.5 * period)  # a stall (e.g. GC pause) inside one cycle
        return b"x"

    st = FixedRateStreamer(rate, lambda b: True, producer, clock=clk, sleep=clk.sleep,
                           gil_switch_interval_s=None)
    run_until(st, lambda: len(st.sent_times) >= 30)
    times = list(st.sent_times)[:30]
    # the producer of deadline k stalled until k + 3.4 periods (it runs lead_s = 0.1 period
    # early): frame k is stale and dropped, k+1 and k+2 get no send, k+3 is served 0.4 period
    # late; all three misses are counted
    assert st.missed == 3
    assert max(st.stats().lateness_s) < period
    gaps = [b - a for a, b in itertools.pairwise(times)]
    assert min(gaps) > 0.4 * period  # never two sends back to back
    t0 = times[0]
    for t in times[11:]:  # back on the original grid after the stall
        k = round((t - t0) / period)
        assert 0.0 <= t - (t0 + k * period) < 50e-6


def test_producer_errors_counted_and_none_skips() -> None:
    clk = FakeClock()
    calls = [0]

    def producer(now: float) -> bytes | None:
        calls[0] += 1
        if calls[0] % 3 == 0:
            raise ValueError("bad setpoint")
        if calls[0] % 3 == 1:
            return None
        return b"ok"

    st = FixedRateStreamer(50.0, lambda b: True, producer, clock=clk, sleep=clk.sleep,
                           gil_switch_interval_s=None)
    run_until(st, lambda: calls[0] >= 30)
    assert st.producer_errors >= 9 and "bad setpoint" in st.last_error
    assert abs(st.sent - calls[0] / 3) <= 2


def test_feed_replaces_producer() -> None:
    clk = FakeClock()
    got: list[bytes] = []
    st = FixedRateStreamer(100.0, lambda b: got.append(b) is None, lambda now: b"a",
                           clock=clk, sleep=clk.sleep, gil_switch_interval_s=None)
    st.feed(b"latest")
    run_until(st, lambda: len(got) >= 5)
    assert set(got) == {b"latest"}


def test_real_clock_count_is_bounded_by_elapsed_deadlines() -> None:
    """With the real clock: the number of sends never exceeds the deadlines elapsed (+1)."""
    rate = 200.0
    st = FixedRateStreamer(rate, lambda b: True, lambda now: b"x")
    t_start = time.monotonic()
    run_until(st, lambda: st.sent >= 100)
    elapsed = time.monotonic() - t_start
    assert st.sent >= 100
    assert st.sent + st.missed <= elapsed * rate + 1
    times = list(st.sent_times)
    assert all(b > a for a, b in itertools.pairwise(times))
