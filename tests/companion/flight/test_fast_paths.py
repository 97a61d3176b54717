"""The tracking source's fast path equals its general path: the estimate cache (telemetry arrives
slower than setpoints) gives exactly the setpoints of building a fresh estimate every call."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from companion.flatness import MultirotorParams

PARAMS = MultirotorParams(mass=1.3, inertia=(0.021, 0.023, 0.04), hover_thrust=0.45, drag=0.7)


@pytest.mark.parametrize("mode", ["attitude", "rates"])
def test_tracking_source_reuses_estimates_without_changing_setpoints(mode: str) -> None:
    """Telemetry arrives slower than setpoints: the source's estimate cache must give exactly
    the setpoints of building a fresh estimate every call (oracle: a source whose cache is
    bypassed)."""
    from companion.control import Reference as Ref
    from companion.flight.tracking import TrackingSource, estimate_from_telemetry
    from companion.mavlink.telemetry import (
        Attitude,
        ExtendedState,
        LocalPosition,
        TelemetrySnapshot,
    )

    def reference(t: float) -> Ref:
        return Ref(
            np.array([math.sin(t), 0.5 * t, -2.0]), np.array([math.cos(t), 0.5, 0.0]),
            np.array([-math.sin(t), 0.0, 0.0]), np.array([-math.cos(t), 0.0, 0.0]),
            np.array([math.sin(t), 0.0, 0.0]), 0.1 * t, 0.1, 0.0,
        )

    cached = TrackingSource(reference, mode, PARAMS)  # type: ignore[arg-type]
    fresh = TrackingSource(reference, mode, PARAMS)  # type: ignore[arg-type]
    fresh._estimate = lambda tel: estimate_from_telemetry(tel, fresh.clock)  # type: ignore[method-assign]
    rng = np.random.default_rng(3)
    pos = att = None
    in_air = ExtendedState(0.0, 2, 0)
    for k in range(300):
        now = 0.01 * k
        if k % 3 == 0:  # 33 Hz position, with jittered latency
            t_boot = now - 0.004
            pos = LocalPosition(
                now + float(rng.uniform(0.0, 0.01)), t_boot,
                (float(np.sin(now)), 0.5 * now, -2.0 + 0.01 * float(rng.normal())),
                (float(np.cos(now)), 0.5, 0.0), "lpos",
            )
        if k % 2 == 0:  # 50 Hz attitude
            q = Rotation.from_euler("ZYX", [0.1 * now, 0.02, -0.01]).as_quat()
            att = Attitude(now, (float(q[3]), float(q[0]), float(q[1]), float(q[2])),
                           (0.01, -0.02, 0.1))
        ext = in_air if k > 20 else ExtendedState(0.0, 1, 0)
        snap = TelemetrySnapshot(pos, att, None, None, ext, now)
        a, b = cached(now, snap), fresh(now, snap)
        assert a == b, k
    assert cached.calls == fresh.calls == 300


class _RecomputedClock:
    """Oracle for `SampleClock`'s incremental Theil-Sen slope: the same clock whose slope is
    recomputed from every pair of completed blocks each time (what it did before)."""

    @staticmethod
    def make(**kw: float) -> object:
        import statistics

        from companion.flight.clock import SampleClock

        class Recomputed(SampleClock):
            def _fit_slope(self) -> None:
                done = list(self._blocks)[:-1]
                if len(done) < 3:
                    return
                gap = 2.0 * self.block_s
                slopes = [(q[2] - p[2]) / (q[1] - p[1]) for i, p in enumerate(done)
                          for q in done[i + 1:] if q[1] - p[1] >= gap]
                if slopes:
                    self._b = statistics.median(slopes)

        return Recomputed(**kw)  # type: ignore[arg-type]


@pytest.mark.parametrize("seed,blocks,recent", [(1, 80, 8), (2, 6, 3), (3, 12, 12), (4, 5, 1)])
def test_sample_clock_incremental_slope_equals_recomputed(seed: int, blocks: int,
                                                          recent: int) -> None:
    """Blocks completing, leaving the window, samples out of order by < 0.5 s, equal offsets
    (ties in the median) and reboots (the window starts over): the same times and drift, bit
    for bit, as recomputing the median of all pairwise slopes each time."""
    from companion.flight.clock import SampleClock

    rng = np.random.default_rng(seed)
    fast = SampleClock(block_s=0.25, blocks=blocks, recent=recent)
    slow = _RecomputedClock.make(block_s=0.25, blocks=blocks, recent=recent)
    boot, epoch, drifts = 5.0, 1000.0, set()
    for k in range(6000):
        r = rng.random()
        if r < 0.001:  # reboot: the boot clock starts again
            boot = float(rng.uniform(0.0, 2.0))
        elif r < 0.02:  # a sample stamped a little earlier than the last
            boot -= float(rng.uniform(0.0, 0.4))
        else:
            boot += 1.0 / 30.0
        latency = 0.003 if rng.random() < 0.3 else float(rng.exponential(0.004))
        rx = boot + epoch + 0.007 * boot + round(latency, 3)  # rounded: ties
        a = fast.local_time(boot, rx)
        b = slow.local_time(boot, rx)  # type: ignore[attr-defined]
        assert a == b, k
        assert fast.drift == slow.drift, k  # type: ignore[attr-defined]
        drifts.add(fast.drift)
    assert len(drifts) > 50  # the slope was refitted many times
