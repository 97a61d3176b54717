"""Deadline-based fixed-rate sender thread.

A dedicated thread serves the absolute deadlines ``t0 + k / rate_hz`` (no drift). For each
deadline it wakes ``lead_s`` early (default 1 ms, half a period with ``wait="busy"``; at most
half a period), calls the producer
with the deadline time (the producer returns the frame due at that time: the setpoint computed
from the latest telemetry, extrapolated to the deadline), waits for the deadline and sends.
A cycle that starts more than one period late skips the missed deadlines, and a frame that is
ready only more than a period after its deadline is dropped (both counted in ``missed``)
instead of bursting. The asyncio side feeds it by swapping the producer
(``set_producer``) or the latest frame (``feed``) and drains ``sent_times`` (a thread-safe
deque) to follow the stream.

The final wait and the send run in a small C helper (``deadline.py``; ctypes releases the GIL)
when it can be built and the clock is the real one: the send then never waits for the
interpreter, and with ``target`` returning a UDP socket and peer the datagram leaves from C.
``wait="sleep"`` (default) sleeps until ``spin_s`` (200 us) before each wake-up and busy-waits
the rest, including the time between the producer's return and the deadline (so the thread
spins about ``(lead_s + spin_s) * rate_hz`` of a core: 12 % at 100 Hz); ``wait="busy"``
busy-waits the whole period, off the GIL, which keeps a core awake:
the choice for a dedicated core, and on virtual machines, where waking a halted vCPU can take
milliseconds (measured in BENCHMARKS.md "Stream"). Without the C helper the waits are Python
``sleep`` + spin, and ``busy`` falls back to ``sleep``.

While running, the interpreter's GIL switch interval is lowered (``gil_switch_interval_s``,
default 0.1 ms; restored on stop) so that the sender thread waits at most that long for the GIL
to run the producer. This is a process-wide setting. ``realtime_priority`` (Linux, needs
CAP_SYS_NICE) puts the sender thread in SCHED_FIFO at that priority (not with ``busy``: the
kernel throttles a spinning real-time thread for 50 ms every second); ``cpu`` pins it to one
core. Failures of either are reported in ``last_error`` and the thread runs on.
"""

from __future__ import annotations

import collections
import os
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

from .deadline import NativeDeadline, load_deadline_library

Producer = Callable[[float], bytes | None]
Clock = Callable[[], float]
#: Returns (socket fd, packed peer sockaddr) to send from C, or None to use ``send``.
Target = Callable[[], tuple[int, bytes] | None]


@dataclass(frozen=True)
class StreamStats:
    """Counters of a streamer; ``periods_s`` are the recent intervals between sends, ``lateness_s``
    send time minus deadline, ``compute_s`` the producer's time per cycle [s]."""

    rate_hz: float
    sent: int
    missed: int
    send_errors: int
    producer_errors: int
    last_error: str
    periods_s: tuple[float, ...]
    lateness_s: tuple[float, ...]
    compute_s: tuple[float, ...]
    native: bool = False
    wait: str = "sleep"


class FixedRateStreamer:
    """Fixed-rate sender thread (see module doc)."""

    def __init__(
        self,
        rate_hz: float,
        send: Callable[[bytes], bool],
        producer: Producer | None = None,
        *,
        target: Target | None = None,
        wait: Literal["sleep", "busy"] = "sleep",
        lead_s: float | None = None,
        spin_s: float = 200e-6,
        clock: Clock | None = None,
        sleep: Callable[[float], None] | None = None,
        native: bool | None = None,
        history: int = 4096,
        on_sent: Callable[[bytes, float], None] | None = None,
        gil_switch_interval_s: float | None = 0.0001,
        realtime_priority: int | None = None,
        cpu: int | None = None,
        name: str = "setpoint-streamer",
    ) -> None:
        if not rate_hz > 0:
            raise ValueError("rate must be positive")
        if wait not in ("sleep", "busy"):
            raise ValueError(f"wait must be 'sleep' or 'busy', not {wait!r}")
        self.rate_hz = rate_hz
        self.period_s = 1.0 / rate_hz
        self._send = send
        self._target = target
        self._producer: Producer | None = producer
        self.spin_s = spin_s
        # the C helper reads CLOCK_MONOTONIC: only with the real clock (tests inject fake ones)
        fake_time = clock is not None or sleep is not None
        self._native: NativeDeadline | None = None
        if native is not False and not fake_time:
            self._native = load_deadline_library()
            if native and self._native is None:
                raise RuntimeError("native deadline sender requested but it cannot be built "
                                   "(no C compiler?)")
        self.wait = wait if self._native is not None else "sleep"
        if lead_s is None:  # busy: the producer gets half a period to take the GIL and compute
            lead_s = 0.5 * self.period_s if self.wait == "busy" else 1e-3
        self.lead_s = min(max(lead_s, 0.0), 0.5 * self.period_s)
        self._clock: Clock = clock or time.monotonic
        self._sleep: Callable[[float], None] = sleep or time.sleep
        self._on_sent = on_sent
        self._gil = gil_switch_interval_s
        self._rt_prio = realtime_priority
        self._cpu = cpu
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
        self.last_error = "" if self.wait == wait else "busy wait needs the C helper: sleeping"
        self._last_frame: bytes | None = None

    @property
    def native(self) -> bool:
        """True when the C helper does the final wait (and the send, given a UDP ``target``)."""
        return self._native is not None

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
        if self._thread.is_alive() and self._thread is not threading.current_thread():
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
                           tuple(self._lateness), tuple(self._compute), self.native, self.wait)

    # -- thread -------------------------------------------------------------------------------
    def _configure_thread(self) -> None:
        errors = []
        if self._cpu is not None and hasattr(os, "sched_setaffinity"):
            try:  # pid 0 = the calling thread on Linux
                os.sched_setaffinity(0, {self._cpu})
            except (OSError, ValueError) as exc:
                errors.append(f"cannot pin to CPU {self._cpu} ({exc})")
        if self._rt_prio is not None and self.wait == "busy":
            errors.append("SCHED_FIFO not used with busy wait (real-time throttling)")
        elif self._rt_prio is not None and hasattr(os, "sched_setscheduler"):
            try:
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(self._rt_prio))
                self.realtime = True
            except (OSError, AttributeError) as exc:
                errors.append(f"SCHED_FIFO unavailable ({exc}); running at normal priority")
        if self._native is not None and self.wait == "sleep":
            self._native.set_timer_slack(1e-6)  # the default 50 us slack delays every wake-up
        if errors:
            self.last_error = "; ".join([self.last_error, *errors]).lstrip("; ")

    def _wait_python(self, deadline: float) -> None:
        remaining = deadline - self._clock()
        if remaining > self.spin_s:
            self._sleep(remaining - self.spin_s)
        while self._clock() < deadline:
            pass

    def _run(self) -> None:
        self._configure_thread()
        clock, period, lead = self._clock, self.period_s, self.lead_s
        native = self._native
        spin: float | None = None if self.wait == "busy" else self.spin_s
        t0 = clock() + period
        k = 0
        last_send: float | None = None
        while not self._stop.is_set():
            deadline = t0 + k * period
            if native is not None:
                native.wait_until(deadline - lead, spin)
            else:
                self._wait_python(deadline - lead)
            if self._stop.is_set():
                break
            producer = self._producer
            frame: bytes | None = None
            t_prod = clock()
            if producer is not None:
                try:
                    frame = producer(deadline)
                except Exception as exc:  # never let a bad setpoint kill the stream silently
                    self.producer_errors += 1
                    self.last_error = f"{type(exc).__name__}: {exc}"
                    frame = None
            t_built = clock()
            if frame and t_built - deadline > period:  # stalled: the frame is stale, drop it
                self.missed += 1
            elif frame:
                ok, t_send = self._send_at(deadline, frame)
                if ok:
                    self.sent += 1
                    self.sent_times.append(t_send)
                    if last_send is not None:
                        self._periods.append(t_send - last_send)
                    last_send = t_send
                    self._lateness.append(t_send - deadline)
                    self._compute.append(t_built - t_prod)
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

    def _send_at(self, deadline: float, frame: bytes) -> tuple[bool, float]:
        """Wait for the deadline and send: (sent, send time [s]). The C helper busy-waits (at
        most ``lead_s``: a second sleep would add a second wake-up delay); the Python fallback
        sleeps and spins as for the wake-up."""
        spin = None
        native = self._native
        if native is None:
            self._wait_python(deadline)
            t_send = self._clock()
            return self._send(frame), t_send
        target = self._target() if self._target is not None else None
        if target is None:
            t_send = native.wait_until(deadline, spin)
            return self._send(frame), t_send
        t_send, err = native.wait_send(deadline, spin, target[0], frame, target[1])
        if err:
            self.last_error = f"send failed: {os.strerror(err)}"
        return err == 0, t_send
