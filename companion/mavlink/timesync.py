"""TIMESYNC: answer the vehicle's requests and estimate clock offset and round-trip time.

Request: tc1 = 0, ts1 = sender time [ns]; reply: tc1 = responder time [ns], ts1 echoed.
Replies are matched by the echoed ts1 only (PX4 fills the target ids with garbage, PX4.md).
The estimate is the sample with the smallest RTT among the last ``window`` replies (NTP-style
minimum filter): offset = remote - local [s] at the midpoint of that exchange.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mavlink2

from .codec import MavMessage


@dataclass(frozen=True)
class TimesyncUpdate:
    """New estimate: offset_s = vehicle clock - local clock [s]; rtt_s of the chosen sample."""

    t_s: float
    offset_s: float
    rtt_s: float
    samples: int


class TimeSync:
    """Sans-IO TIMESYNC peer. Local time is the injected ``now`` [s] (monotonic)."""

    def __init__(self, send: Callable[[MavMessage], None], *, interval_s: float = 1.0,
                 window: int = 10, max_outstanding: int = 16) -> None:
        self._send = send
        self.interval_s = interval_s
        self._window: deque[tuple[float, float]] = deque(maxlen=window)  # (rtt, offset)
        self._outstanding: dict[int, float] = {}
        self._max_outstanding = max_outstanding
        self._next_request: float | None = None
        self.estimate: TimesyncUpdate | None = None

    @staticmethod
    def _ns(now: float) -> int:
        return round(now * 1e9)

    def on_timesync(self, msg: MavMessage, now: float) -> list[TimesyncUpdate]:
        """Feed a TIMESYNC message (any sender)."""
        tc1, ts1 = int(msg.tc1), int(msg.ts1)
        if tc1 == 0:
            self._send(mavlink2.MAVLink_timesync_message(max(self._ns(now), 1), ts1))
            return []
        sent = self._outstanding.pop(ts1, None)
        if sent is None:
            return []
        rtt = now - sent
        if rtt < 0:
            return []
        offset = tc1 * 1e-9 - (sent + now) / 2.0
        self._window.append((rtt, offset))
        best_rtt, best_off = min(self._window)
        self.estimate = TimesyncUpdate(now, best_off, best_rtt, len(self._window))
        return [self.estimate]

    def handle_timer(self, now: float) -> None:
        """Send a request when due."""
        if self._next_request is not None and now < self._next_request:
            return
        ts1 = max(self._ns(now), 1)
        if len(self._outstanding) >= self._max_outstanding:
            self._outstanding.pop(next(iter(self._outstanding)))
        self._outstanding[ts1] = now
        self._send(mavlink2.MAVLink_timesync_message(0, ts1))
        self._next_request = now + self.interval_s

    def next_deadline(self) -> float | None:
        """Time of the next request (None before the first handle_timer)."""
        return self._next_request
