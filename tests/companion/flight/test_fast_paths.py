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
