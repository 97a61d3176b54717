"""bench/estimate_jitter.py against synthetic tlogs: a vehicle in uniform circular motion whose
reported position carries white noise of a known std has a jitter of sqrt(2) times it (the
difference of two independent samples); without the noise the jitter is only the trapezoid
rule's error on the circle, (dt^3 / 12) |jerk|."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as m

from companion.aio import TlogWriter

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))

from estimate_jitter import jitter

R, W, DT = 10.0, 0.5, 0.032  # circle radius [m], angular rate [rad/s], sample step [s]


def _tlog(path: Path, noise_m: float, n: int = 4000) -> Path:
    mav = m.MAVLink(None, srcSystem=1, srcComponent=1)
    rng = np.random.default_rng(1)
    with TlogWriter(path) as tlog:
        for k in range(n):
            t = k * DT
            x, y = R * math.cos(W * t), R * math.sin(W * t)
            vx, vy = -R * W * math.sin(W * t), R * W * math.cos(W * t)
            ex, ey, ez = rng.normal(0.0, noise_m, 3) if noise_m > 0 else (0.0, 0.0, 0.0)
            msg = m.MAVLink_local_position_ned_message(
                round(t * 1000), x + ex, y + ey, -5.0 + ez, vx, vy, 0.0)
            tlog.write(bytes(msg.pack(mav)))
    return path


@pytest.mark.parametrize("noise_m", [0.01, 0.05])
def test_white_noise_gives_sqrt2_times_its_std(tmp_path: Path, noise_m: float) -> None:
    n, dt, std, _p99 = jitter(str(_tlog(tmp_path / "n.tlog", noise_m)))
    assert n > 3900 and dt == pytest.approx(DT, abs=1e-3)
    np.testing.assert_allclose(std, math.sqrt(2.0) * noise_m, rtol=0.06)


def test_a_smooth_estimate_has_only_the_trapezoid_error(tmp_path: Path) -> None:
    _n, _dt, std, p99 = jitter(str(_tlog(tmp_path / "s.tlog", 0.0)))
    bound = DT ** 3 / 12.0 * R * W ** 3  # |jerk| = R w^3 on the circle
    assert p99 <= bound * 1.5 + 2e-6  # (time_boot_ms rounds the step to 1 ms)
    assert std[2] == 0.0
