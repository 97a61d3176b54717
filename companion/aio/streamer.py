"""Deadline-based fixed-rate sender thread.

A dedicated thread sleeps until ``spin_s`` (default 200 us) before each deadline
``t0 + k / rate_hz`` and busy-waits the rest, then calls the producer (which returns the frame
to send: the latest setpoint, computed from the latest telemetry) and sends it. Deadlines are
absolute, so there is no drift; a cycle that starts more than one period late skips the missed
deadlines (counted in ``missed``) instead of bursting. The asyncio side feeds it by swapping the
producer (``set_producer``) or the latest frame (``feed``) and drains ``sent_times`` (a
thread-safe deque) to follow the stream.

While running, the interpreter's GIL switch interval is lowered (``gil_switch_interval_s``,
default 0.1 ms; restored on stop) so that the waking sender thread waits at most that long for
the GIL when the asyncio thread is busy. This is a process-wide setting. ``realtime_priority``
(Linux, needs CAP_SYS_NICE) puts the sender thread in SCHED_FIFO at that priority; if refused it
runs at normal priority and says so in ``last_error``.
"""

from __future__ import annotations

import collections
import os
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

Producer = Callable[[float], bytes | None]
Clock = Callable[[], float]


@dataclass(frozen=True)
class StreamStats:
    """Counters of a streamer; ``periods_s`` are the recent intervals between sends [s]."""

    rate_hz: float
    sent: int
    missed: int
    send_errors: int
    producer_errors: int
    last_error: str
    periods_s: tuple[float, ...]
    lateness_s: tuple[float, ...]
    compute_s: tuple[float, ...]


class FixedRateStreamer:
    """Fixed-rate sender thread (see module doc)."""

    def __init__(
        self,
        rate_hz: float,
        send: Callable[[bytes], bool],
        producer: Producer | None = None,
        *,
        spin_s: float = 200e-6,
        clock: Clock = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
        history: int = 4096,
        on_sent: Callable[[bytes, float], None] | None = None,
        gil_switch_interval_s: float | None = 0.0001,
        realtime_priority: int | None = None,
        name: str = "setpoint-streamer",
    ) -> None:
        if not rate_hz > 0:
            raise ValueError("rate must be positive")
        self.rate_hz = rate_hz
        self.period_s = 1.0 / rate_hz
        self._send = send
        self._producer: Producer | None = producer
        self.spin_s = spin_s
        self._clock = clock
        self._sleep = sleep
        self._on_sent = on_sent
        self._gil = gil_switch_interval_s
        self._rt_prio = realtime_priority
        self.realtime = False
        self._old_gil: float | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self.sent_times: collections.deque[float] = collections.deque(maxlen=history)
        self._periods: collections.deque[float] = collections.deque(maxlen=history)
        self._lateness: collections.deque[float] = collections.deque(maxlen=history)
        self._compute: collections.deque[float] = collections.deque(maxlen=history)
        self.sent = 0
        self.missed = 0
        self.send_errors = 0
        self.producer_errors = 0
        self.last_error = ""
        self._last_frame: bytes | None = None

    # -- feeding --------------------------------------------------------------------------
    def set_producer(self, producer: Producer | None) -> None:
        """Replace the per-cycle producer (atomic; takes effect at the next deadline)."""
        self._producer = producer

    def feed(self, frame: bytes) -> None:
        """Send this frame every cycle from now on (replaces the producer)."""
        self._last_frame = frame
        self._producer = self._latest

    def _latest(self, _now: float) -> bytes | None:
        return self._last_frame

    # -- lifecycle --------------------------------------------------------------------------
    def start(self) -> None:
        """Start the sender thread."""
        if self._gil is not None:
            self._old_gil = sys.getswitchinterval()
            sys.setswitchinterval(min(self._gil, self._old_gil))
        self._thread.start()

    def stop(self, timeout_s: float = 2.0) -> None:
        """Stop the thread (returns after it exited or the timeout)."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout_s)
        if self._old_gil is not None:
            sys.setswitchinterval(self._old_gil)
            self._old_gil = None

    @property
    def running(self) -> bool:
        """True while the thread runs."""
        return self._thread.is_alive() and not self._stop.is_set()

    def __enter__(self) -> FixedRateStreamer:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def stats(self) -> StreamStats:
        """Snapshot of counters and recent timing samples."""
        return StreamStats(self.rate_hz, self.sent, self.missed, self.send_errors,
                           self.producer_errors, self.last_error, tuple(self._periods),
                           tuple(self._lateness), tuple(self._compute))

    # -- thread -------------------------------------------------------------------------------
    def _set_realtime(self) -> None:
        if self._rt_prio is None or not hasattr(os, "sched_setscheduler"):
            return
        try:  # pid 0 = the calling thread on Linux
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(self._rt_prio))
            self.realtime = True
        except (OSError, AttributeError) as exc:
            self.last_error = f"SCHED_FIFO unavailable ({exc}); running at normal priority"

    def _run(self) -> None:
        self._set_realtime()
        clock, sleep, period, spin = self._clock, self._sleep, self.period_s, self.spin_s
        t0 = clock() + period
        k = 0
        last_send: float | None = None
        while not self._stop.is_set():
            deadline = t0 + k * period
            remaining = deadline - clock()
            if remaining > spin:
                sleep(remaining - spin)
            while clock() < deadline:
                pass
            if self._stop.is_set():
                break
            t_send = clock()
            producer = self._producer
            frame: bytes | None = None
            if producer is not None:
                try:
                    frame = producer(t_send)
                except Exception as exc:  # never let a bad setpoint kill the stream silently
                    self.producer_errors += 1
                    self.last_error = f"{type(exc).__name__}: {exc}"
                    frame = None
            t_built = clock()
            if frame:
                if self._send(frame):
                    self.sent += 1
                    self.sent_times.append(t_send)
                    if last_send is not None:
                        self._periods.append(t_send - last_send)
                    last_send = t_send
                    self._lateness.append(t_send - deadline)
                    self._compute.append(t_built - t_send)
                    if self._on_sent is not None:
                        self._on_sent(frame, t_send)
                else:
                    self.send_errors += 1
            k += 1
            behind = clock() - (t0 + k * period)
            if behind > period:
                skip = int(behind / period)
                k += skip
                self.missed += skip
