"""The rover interface bench's reference and metrics (rover_reference.py): path geometry,
speed profile, closest-point projection and the inverse of PX4's stopping profile, checked
against geometry and arithmetic done here independently."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))

from rover_reference import (
    Path2,
    Projector,
    SpeedProfile,
    stopping_distance,
)


def test_path_is_leg_quarter_circle_leg() -> None:
    p = Path2(start=(1.0, 2.0), heading=0.0, leg1_m=20.0, radius_m=3.0, leg2_m=10.0)
    assert p.length_m == pytest.approx(20.0 + 1.5 * math.pi + 10.0)
    assert p.point_at(20.0) == pytest.approx((21.0, 2.0))
    # a right turn (NED: towards east) about the centre (21, 5): the arc ends at (24, 5)
    assert p.point_at(20.0 + 1.5 * math.pi) == pytest.approx((24.0, 5.0), abs=1e-9)
    mid = p.point_at(20.0 + 0.75 * math.pi)
    assert math.hypot(mid[0] - 21.0, mid[1] - 5.0) == pytest.approx(3.0)
    assert p.point_at(p.length_m) == pytest.approx((24.0, 15.0), abs=1e-9)
    assert p.heading_at(0.0) == 0.0 and p.heading_at(p.length_m) == pytest.approx(math.pi / 2)
    assert p.curvature_at(10.0) == 0.0 and p.curvature_at(22.0) == pytest.approx(1 / 3)


def test_left_turn_mirrors_the_right_turn() -> None:
    r = Path2(heading=0.3, turn_rad=math.pi / 2)
    left = Path2(heading=0.3, turn_rad=-math.pi / 2)
    for s in (5.0, 21.0, 23.0, 30.0):
        # mirror about the first leg's line
        a, b = np.array(r.point_at(s)), np.array(left.point_at(s))
        u = np.array([math.cos(0.3), math.sin(0.3)])
        assert float(a @ u) == pytest.approx(float(b @ u))
        n = np.array([-u[1], u[0]])
        assert float(a @ n) == pytest.approx(-float(b @ n))


def test_dense_path_is_parametrised_by_arc_length() -> None:
    s, pts = Path2(heading=1.0).dense(0.05)
    steps = np.hypot(*np.diff(pts, axis=0).T)
    ds = np.diff(s)
    assert np.allclose(steps, ds, rtol=1e-3)  # chords of 5 cm on a 3 m radius


def test_speed_profile_integrates_to_its_distance() -> None:
    prof = SpeedProfile(length_m=34.7, speed=2.0, ramp_s=2.5)
    t = np.linspace(0.0, prof.duration_s, 20001)
    s_v = np.array([prof.at(float(x)) for x in t])
    # the distance is the integral of the speed (trapezoids), continuous and monotonic
    integral = np.concatenate([[0.0], np.cumsum(0.5 * (s_v[1:, 1] + s_v[:-1, 1]) * np.diff(t))])
    assert np.allclose(integral, s_v[:, 0], atol=1e-4)
    assert np.all(np.diff(s_v[:, 0]) >= 0.0)
    assert prof.at(prof.duration_s) == pytest.approx((34.7, 0.0))
    assert max(s_v[:, 1]) == pytest.approx(2.0)
    assert np.max(np.abs(np.diff(s_v[:, 1]) / np.diff(t))) <= 1.5 * 2.0 / 2.5 + 1e-6


def test_projection_signs_and_ends() -> None:
    proj = Projector(Path2(heading=0.0))
    s, c = proj.closest(10.0, 0.5)
    assert s == pytest.approx(10.0, abs=0.02) and c == pytest.approx(0.5, abs=1e-6)  # right
    s, c = proj.closest(10.0, -0.4)
    assert c == pytest.approx(-0.4, abs=1e-6)  # left
    s, c = proj.closest(-2.0, 0.0)  # before the start: along the first tangent
    assert s == pytest.approx(-2.0, abs=1e-6) and c == pytest.approx(0.0, abs=1e-6)
    # inside the turn (towards its centre (20, 3)) is right of a right turn
    s, c = proj.closest(20.0 + 2.0 * math.sin(0.5), 3.0 - 2.0 * math.cos(0.5))
    assert c > 0.0


@pytest.mark.parametrize("speed", [0.2, 1.0, 2.0, 2.9])
def test_stopping_distance_inverts_px4s_profile(speed: float) -> None:
    a, j = 3.0, 10.0
    d = stopping_distance(speed, a, j)
    # PX4 (math::trajectory::computeMaxSpeedFromDistance, arrival speed 0): the positive root
    # of v^2 + b v - 2 a d = 0 with b = 4 a^2 / j
    b = 4.0 * a * a / j
    v = 0.5 * (-b + math.sqrt(b * b + 8.0 * a * d))
    assert v == pytest.approx(speed)
