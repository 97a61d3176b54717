"""`bend_for_tilt`: the onboard module's trajectory bent ahead of time for its tilt limit.

The module flies the segments it is given and cannot bend its reference online as the streamed
law does (`ShapedReference`). The companion bends them before the upload. Checked here against
an independent path, the streamed law's own online bend evaluated at the flight's times. Also
checked: the tilt the bent trajectory asks for, its continuity at every joint, and that a
feasible plan or one the module could not hold comes back untouched."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

import companion.planning.onboard_segments as onboard_segments
from companion.control.shaping import ShapedReference, ShapingConfig
from companion.planning.config import VehicleFile
from companion.planning.onboard_segments import (
    Segments,
    bend_for_tilt,
    law_params,
    segments_reference,
)
from companion.trajectory.bezier import Bezier, hermite

G = 9.80665
LAW = law_params(VehicleFile(), 0.5, math.radians(45.0))


def figure8(w: float, a: float = 10.0, laps: float = 1.2, seg_s: float = 0.25) -> Segments:
    """Gerono's figure-8 (a sin wt, a/2 sin 2wt) at 5 m height as degree-7 Hermite segments
    [m, s], yaw 0.3 rad; w [rad/s]."""
    n = math.ceil(laps * 2.0 * math.pi / w / seg_s)
    ts = np.arange(n + 1) * seg_s

    def derivs(t: float) -> np.ndarray:
        d = []
        for k in range(4):  # d^k/dt^k, a sin(wt + k pi/2) w^k and (a/2) (2w)^k sin(2wt + ..)
            x = a * w**k * math.sin(w * t + k * math.pi / 2.0)
            y = 0.5 * a * (2.0 * w) ** k * math.sin(2.0 * w * t + k * math.pi / 2.0)
            d.append([x, y, -5.0 if k == 0 else 0.0])
        return np.array(d)

    cps = [hermite(derivs(t0), derivs(t1), seg_s).control_points
           for t0, t1 in itertools.pairwise(ts)]
    return [float(t) for t in ts], cps, [np.full(8, 0.3) for _ in cps]


def tilt_deg(pos_acc: np.ndarray, vel: np.ndarray, drag_per_kg: float) -> float:
    """The tilt [deg] of the thrust a reference asks for (acceleration plus linear drag)."""
    h = pos_acc[:2] + drag_per_kg * vel[:2]
    return math.degrees(math.atan2(float(np.linalg.norm(h)), G - float(pos_acc[2])))


def test_a_plan_within_the_tilt_limit_comes_back_unchanged() -> None:
    segs = figure8(0.4)  # 34 deg at most
    assert bend_for_tilt(segs, LAW) is segs


def test_a_figure_too_fast_for_the_limit_is_bent_as_the_streamed_law_bends_it_online() -> None:
    segs = figure8(0.56)  # 47 deg at most, 44 deg or more for 17 % of the time
    drag = LAW.drag / LAW.mass
    bent = bend_for_tilt(segs, LAW)
    assert bent is not segs and len(bent[1]) > len(segs[1])
    assert bent[0][-1] == pytest.approx(segs[0][-1], abs=1e-9)  # the same duration
    online = ShapedReference(lambda t: segments_reference(segs, t), ShapingConfig(),
                             max_tilt_rad=LAW.max_tilt_rad, g=LAW.g)
    online.drag_per_kg = drag
    worst_plan = worst_bent = 0.0
    for t in np.arange(0.0, segs[0][-1], 0.01):
        online.advance(t)  # as a flight steps it
        want = online(t)
        got = segments_reference(bent, t)
        np.testing.assert_allclose(got.pos_ned, want.pos_ned, atol=1e-6)
        np.testing.assert_allclose(got.vel_ned, want.vel_ned, atol=1e-5)
        np.testing.assert_allclose(got.acc_ned, want.acc_ned, atol=1e-4)
        plan = segments_reference(segs, t)
        worst_plan = max(worst_plan, tilt_deg(plan.acc_ned, plan.vel_ned, drag))
        worst_bent = max(worst_bent, tilt_deg(got.acc_ned, got.vel_ned, drag))
    assert worst_plan > 46.5
    # within the limit less the bend's 1 deg margin, give or take its slack
    assert worst_bent < 44.5, worst_bent


def test_the_bent_segments_join_through_jerk_and_keep_the_yaw() -> None:
    bent = bend_for_tilt(figure8(0.56), LAW)
    breaks, cps, ycps = bent
    segs = [Bezier(cp, b - a) for cp, a, b in zip(cps, breaks[:-1], breaks[1:], strict=True)]
    for left, right in itertools.pairwise(segs):
        for k in range(4):  # position, velocity, acceleration, jerk
            np.testing.assert_allclose(left.evaluate(left.duration, k), right.evaluate(0.0, k),
                                       atol=1e-6 * 10**k)
    for y in ycps:
        np.testing.assert_allclose(y, 0.3, atol=1e-12)


def test_a_bend_the_module_could_not_hold_is_not_used(monkeypatch: pytest.MonkeyPatch) -> None:
    segs = figure8(0.56)
    monkeypatch.setattr(onboard_segments, "MAX_SEGMENTS", len(segs[1]) + 1)
    assert bend_for_tilt(segs, LAW) is segs
