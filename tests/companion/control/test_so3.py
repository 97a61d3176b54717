"""The rates-mode tilt guard (`companion.control.so3.tilt_guard`) against finite differences of
the tilt of the attitude it is applied at."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.control.so3 import (
    TILT_GUARD_GAIN,
    TILT_GUARD_LEAD_S,
    quat_integrate,
    quat_to_dcm,
    tilt_guard,
)


def test_tilt_guard_bounds_the_tilt_rate_near_the_limit_and_leaves_the_rest() -> None:
    """Finite differences of the tilt under the guarded rates: never faster than
    gain * (limit - tilt - lead * tilt rate now); far from the limit the rates are untouched;
    only roll and pitch change."""
    def tilt(R: np.ndarray) -> float:
        return math.atan2(math.hypot(R[2, 0], R[2, 1]), R[2, 2])

    rng = np.random.default_rng(7)
    limit = math.radians(45.0)
    checked = untouched = 0
    for _ in range(400):
        ang = rng.uniform(0.0, math.radians(60.0))
        axis = np.array([*rng.normal(size=2), 0.0])
        axis /= np.linalg.norm(axis)
        yaw = rng.uniform(-math.pi, math.pi)
        q_tilt = np.array([math.cos(ang / 2), *(math.sin(ang / 2) * axis)])
        q_yaw = np.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])
        q = np.array([
            q_yaw[0] * q_tilt[0] - q_yaw[3] * q_tilt[3],
            q_yaw[0] * q_tilt[1] - q_yaw[3] * q_tilt[2],
            q_yaw[0] * q_tilt[2] + q_yaw[3] * q_tilt[1],
            q_yaw[0] * q_tilt[3] + q_yaw[3] * q_tilt[0],
        ])
        R = quat_to_dcm(q)
        w = rng.normal(0.0, 2.0, 3)
        w_now = rng.normal(0.0, 1.0, 3)
        out = tilt_guard(R, w, limit, w_now)
        assert out[2] == w[2]
        dt = 1e-7
        rate_out = (tilt(quat_to_dcm(quat_integrate(q, out, dt))) - tilt(R)) / dt
        rate_now = (tilt(quat_to_dcm(quat_integrate(q, w_now, dt))) - tilt(R)) / dt
        bound = TILT_GUARD_GAIN * (limit - tilt(R) - TILT_GUARD_LEAD_S * rate_now)
        assert rate_out <= bound + 1e-5
        if not np.array_equal(out, w):
            checked += 1
            assert rate_out == pytest.approx(bound, abs=1e-5)  # clipped to the bound exactly
        else:
            untouched += 1
    assert checked > 50 and untouched > 50
