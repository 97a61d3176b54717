"""Fault injection for the mock: per-link network faults and vehicle-level scenario faults.

Sans-IO and seeded: a `FaultyChannel` is a delay line for datagrams driven by the caller's
clock (`now`, simulated seconds), with its own `random.Random(seed)`, so a run with the same
seed and the same inputs drops, delays, duplicates and reorders the same datagrams.
"""

from __future__ import annotations

import heapq
import math
import random
from dataclasses import dataclass, field
from typing import Generic, TypeVar

T = TypeVar("T")


@dataclass(frozen=True)
class LinkFaults:
    """Network faults applied to one direction of one link (times in simulated seconds).

    loss_pct: probability [%] that a datagram is dropped.
    latency_s: fixed one-way delay [s]; jitter_s: extra uniform delay in [0, jitter_s].
    duplicate_pct: probability [%] that a datagram is delivered twice.
    reorder_pct: probability [%] that a datagram is held back by `reorder_delay_s`, so later
    datagrams overtake it.
    blackouts: (start_s, end_s) windows (time since boot) in which every datagram is dropped.
    """

    loss_pct: float = 0.0
    latency_s: float = 0.0
    jitter_s: float = 0.0
    duplicate_pct: float = 0.0
    reorder_pct: float = 0.0
    reorder_delay_s: float = 0.03
    blackouts: tuple[tuple[float, float], ...] = ()

    def __post_init__(self) -> None:
        for name in ("loss_pct", "duplicate_pct", "reorder_pct"):
            v = getattr(self, name)
            if not (math.isfinite(v) and 0.0 <= v <= 100.0):
                raise ValueError(f"{name} must be a percentage in [0, 100], got {v!r}")
        for name in ("latency_s", "jitter_s", "reorder_delay_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0.0):
                raise ValueError(f"{name} must be a finite delay >= 0 s, got {v!r}")
        for start, end in self.blackouts:
            if not (math.isfinite(start) and math.isfinite(end) and end > start):
                raise ValueError(f"blackout window ({start}, {end}) must have end > start")

    @property
    def active(self) -> bool:
        """True if any fault is configured (otherwise the channel is a pass-through)."""
        return bool(
            self.loss_pct
            or self.latency_s
            or self.jitter_s
            or self.duplicate_pct
            or self.reorder_pct
            or self.blackouts
        )

    def in_blackout(self, t_s: float) -> bool:
        """True if time since boot `t_s` falls in a blackout window."""
        return any(start <= t_s < end for start, end in self.blackouts)


@dataclass(frozen=True)
class ScenarioFaults:
    """Vehicle-level faults at given times since boot [s] (None = never).

    pilot_takeover_s: an RC pilot appears and switches to POSCTL (position hold with sticks
    centred), like a safety pilot taking over.
    local_position_loss: (start_s, end_s) window with no local position estimate.
    low_battery_s / low_battery_remaining: at that time the battery drops to that fraction (0..1).
    """

    pilot_takeover_s: float | None = None
    local_position_loss: tuple[float, float] | None = None
    low_battery_s: float | None = None
    low_battery_remaining: float = 0.12


@dataclass
class ChannelStats:
    """Counters of what a `FaultyChannel` did."""

    passed: int = 0
    dropped: int = 0
    duplicated: int = 0
    reordered: int = 0


@dataclass(order=True)
class _Queued(Generic[T]):
    due_s: float
    order: int
    item: T = field(compare=False)


class FaultyChannel(Generic[T]):
    """A seeded delay line: `push(item, now, t_boot)` then `pop_due(now)` returns due items.

    `now` is the absolute simulated clock, `t_boot` the time since boot used for blackouts.
    With no faults configured items pass straight through in order.
    """

    def __init__(self, faults: LinkFaults | None = None, seed: int = 0) -> None:
        self.faults = faults or LinkFaults()
        self._rng = random.Random(seed)
        self._heap: list[_Queued[T]] = []
        self._order = 0
        self.stats = ChannelStats()

    def _put(self, due_s: float, item: T) -> None:
        self._order += 1
        heapq.heappush(self._heap, _Queued(due_s, self._order, item))

    def push(self, item: T, now: float, t_boot: float) -> None:
        """Offer one datagram to the channel at time `now`."""
        f = self.faults
        if not f.active:
            self._put(now, item)
            self.stats.passed += 1
            return
        rng = self._rng
        if f.in_blackout(t_boot) or (f.loss_pct and rng.random() * 100.0 < f.loss_pct):
            self.stats.dropped += 1
            return
        delay = f.latency_s + (rng.random() * f.jitter_s if f.jitter_s else 0.0)
        if f.reorder_pct and rng.random() * 100.0 < f.reorder_pct:
            delay += f.reorder_delay_s
            self.stats.reordered += 1
        self._put(now + delay, item)
        self.stats.passed += 1
        if f.duplicate_pct and rng.random() * 100.0 < f.duplicate_pct:
            self._put(now + delay, item)
            self.stats.duplicated += 1

    def pop_due(self, now: float) -> list[T]:
        """Items whose delivery time is <= now, in delivery order."""
        out: list[T] = []
        heap = self._heap
        while heap and heap[0].due_s <= now:
            out.append(heapq.heappop(heap).item)
        return out

    def next_due(self) -> float:
        """Delivery time of the next queued item (inf if empty)."""
        return self._heap[0].due_s if self._heap else math.inf

    def __len__(self) -> int:
        return len(self._heap)


def parse_blackouts(text: str) -> tuple[tuple[float, float], ...]:
    """Parse "10-12,30-31.5" into ((10, 12), (30, 31.5)) [s since boot]."""
    windows = []
    for part in text.split(","):
        part = part.strip()
        if not part:
            continue
        try:
            a, b = part.split("-", 1)
            windows.append((float(a), float(b)))
        except ValueError as exc:
            raise ValueError(
                f"blackout window {part!r} must look like START-END in seconds"
            ) from exc
    return tuple(windows)
