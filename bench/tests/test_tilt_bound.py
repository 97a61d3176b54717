"""bench/tilt_bound.py against the case solved by hand: a circle flown too fast. Its best
periodic path is the concentric circle whose demand is exactly the limit (the problem is convex
and symmetric under rotation with a time shift, so its unique optimum is too), of radius
r* = g tan(limit) / (omega sqrt(omega^2 + (D/m)^2)); the least error is R - r* at every moment.
A circle within the limit costs nothing."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tilt_bound import G, tilt_bound


def circle(radius: float, omega: float):
    def ref(t: float):
        c, s = math.cos(omega * t), math.sin(omega * t)
        w = omega
        return (np.array([radius * c, radius * s]), np.array([-radius * w * s, radius * w * c]),
                np.array([-radius * w**2 * c, -radius * w**2 * s]))

    return ref


@pytest.mark.parametrize("dm", [0.0, 1.25])
def test_a_circle_too_fast_costs_the_distance_to_the_circle_at_the_limit(dm: float) -> None:
    radius, omega, tilt = 5.0, 1.6, 45.0
    r_star = G * math.tan(math.radians(tilt)) / (omega * math.hypot(omega, dm))
    assert r_star < radius - 0.5
    b = tilt_bound(circle(radius, omega), 2 * math.pi / omega, dm, tilt, n=200)
    assert b.rms_m == pytest.approx(radius - r_star, rel=0.02)
    assert b.max_m == pytest.approx(radius - r_star, rel=0.02)
    assert b.share_over == 1.0
    assert np.allclose(np.linalg.norm(b.path, axis=1), r_star, rtol=0.02)


def test_a_circle_within_the_limit_costs_nothing() -> None:
    b = tilt_bound(circle(5.0, 1.0), 2 * math.pi, 1.0, 45.0, n=200)
    assert b.share_over == 0.0
    assert b.rms_m < 1e-3
