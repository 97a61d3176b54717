"""`VelocityCorrection`: the horizontal velocity error of the autopilot's estimate, seen from its
own position. Oracles: an analytic trajectory (position and its exact derivative), a known
velocity bias, white position noise of known size, and the telemetry path from real MAVLink
messages to the controller's estimate."""

from __future__ import annotations

import math
import random

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as mavlink2

from companion.flight.tracking import estimate_from_telemetry
from companion.mavlink.telemetry import (
    POSITION_RESET_M,
    VELOCITY_CORRECTION_MAX_M_S,
    TelemetryState,
    VelocityCorrection,
)

RATE_HZ = 50.0


def figure8(t: float, speed: float = 6.0) -> tuple[tuple[float, float], tuple[float, float]]:
    """A lemniscate-like path at up to ~`speed` m/s: position [m] and its exact derivative."""
    w = speed / 20.0
    p = (20.0 * math.sin(w * t), 10.0 * math.sin(2.0 * w * t))
    v = (20.0 * w * math.cos(w * t), 20.0 * w * math.cos(2.0 * w * t))
    return p, v


def samples(seconds: float, rate_hz: float = RATE_HZ) -> list[float]:
    """Sample times on the autopilot's clock, quantised to whole milliseconds like
    LOCAL_POSITION_NED's time_boot_ms, with a little jitter in the period."""
    rng = random.Random(1)
    t, out = 5.0, []
    while t < 5.0 + seconds:
        out.append(round(t * 1000.0) / 1000.0)
        t += (1.0 + rng.uniform(-0.1, 0.1)) / rate_hz
    return out


def test_a_velocity_that_agrees_with_its_position_gets_no_correction() -> None:
    vc = VelocityCorrection()
    worst = 0.0
    for t in samples(60.0):
        p, v = figure8(t)
        c = vc.update(t, (p[0], p[1], -5.0), (v[0], v[1], 0.0))
        worst = max(worst, math.hypot(c[0], c[1]))
        assert c[2] == 0.0
    assert worst < 0.01  # m/s, at 6 m/s and ~3.6 m/s^2 on the whole path


@settings(max_examples=25, deadline=None)
@given(bx=st.floats(-0.8, 0.8), by=st.floats(-0.8, 0.8))
def test_a_velocity_bias_is_removed_within_a_few_time_constants(bx: float, by: float) -> None:
    vc = VelocityCorrection()
    for t in samples(6.0):
        p, v = figure8(t)
        c = vc.update(t, (p[0], p[1], 0.0), (v[0] + bx, v[1] + by, 0.0))
    # the reported velocity plus the correction is the true one
    assert math.hypot(c[0] + bx, c[1] + by) < 0.02


@pytest.mark.parametrize("f_hz", [0.02, 0.05, 0.2])
def test_a_varying_bias_is_followed_as_the_linear_filter_predicts(f_hz: float) -> None:
    """A bias swinging at ``f_hz``: the correction's error is the bias through the filter's
    error transfer function s (s + k1) / (s^2 + k1 s + k2) (linear theory, not the code): a
    bias that changes over many 1 / w is removed, a quick one is not."""
    vc = VelocityCorrection()
    w = 2.0 * math.pi * f_hz
    s_ = complex(0.0, w)
    gain = abs(s_ * (s_ + vc.k1) / (s_ * s_ + vc.k1 * s_ + vc.k2))
    errs = []
    for t in samples(20.0 + 3.0 / f_hz):
        p, v = figure8(t)
        b = 0.4 * math.sin(w * t)
        c = vc.update(t, (p[0], p[1], 0.0), (v[0] + b, v[1], 0.0))
        if t > 15.0 + 1.0 / f_hz:
            errs.append(abs(c[0] + b))
    assert max(errs) == pytest.approx(gain * 0.4, rel=0.1)


def test_white_position_noise_moves_the_correction_little() -> None:
    """A GPS-like 0.09 m of white noise on the position (the mock's SIM_POS_NOISE in
    campaigns): the correction stays small, far below what differencing the positions gives."""
    rng = np.random.default_rng(3)
    vc = VelocityCorrection()
    cs, diffs, last = [], [], None
    for t in samples(60.0):
        p, v = figure8(t)
        n = rng.normal(0.0, 0.09, 2)
        c = vc.update(t, (p[0] + n[0], p[1] + n[1], 0.0), (v[0], v[1], 0.0))
        if t > 10.0:
            cs.append(c[:2])
        if last is not None:
            diffs.append((p[0] + n[0] - last[1]) / (t - last[0]) - v[0])
        last = (t, p[0] + n[0])
    std = float(np.std(np.asarray(cs), axis=0).max())
    assert std < 0.1
    assert std < 0.05 * float(np.std(diffs))


def test_an_estimator_reset_or_a_gap_restarts_the_position_and_keeps_the_correction() -> None:
    vc = VelocityCorrection()
    ts = samples(10.0)
    for t in ts:
        p, v = figure8(t)
        c = vc.update(t, (p[0], p[1], 0.0), (v[0] + 0.3, v[1], 0.0))
    assert c[0] == pytest.approx(-0.3, abs=0.02)
    # a position step larger than POSITION_RESET_M (EKF2 resets its position)
    t = ts[-1] + 0.02
    p, v = figure8(t)
    after = vc.update(t, (p[0] + 2.0 * POSITION_RESET_M, p[1], 0.0), (v[0] + 0.3, v[1], 0.0))
    assert after == c
    t2 = t + 0.02
    p, v = figure8(t2)  # and it goes on from the new position, learning nothing from the step
    again = vc.update(t2, (p[0] + 2.0 * POSITION_RESET_M, p[1], 0.0), (v[0] + 0.3, v[1], 0.0))
    assert math.hypot(again[0] - c[0], again[1] - c[1]) < 0.01
    # a gap of 2 s: the same
    t3 = t2 + 2.0
    p, v = figure8(t3)
    assert vc.update(t3, (p[0] - 5.0, p[1], 0.0), (v[0] + 0.3, v[1], 0.0)) == again
    # the same sample again, or a non-finite one: nothing changes
    assert vc.update(t3, (p[0] + 9.0, p[1], 0.0), (v[0], v[1], 0.0)) == again
    assert vc.update(t3 + 0.02, (math.nan, p[1], 0.0), (v[0], v[1], 0.0)) == again


def test_the_correction_is_bounded() -> None:
    vc = VelocityCorrection()
    for t in samples(20.0):  # a position running away at 3 m/s that the velocity denies
        c = vc.update(t, (3.0 * t, 0.0, 0.0), (0.0, 0.0, 0.0))
        assert abs(c[0]) <= VELOCITY_CORRECTION_MAX_M_S
    assert c[0] == VELOCITY_CORRECTION_MAX_M_S


@pytest.mark.parametrize("rad_s", [2.0, 0.0])
def test_telemetry_hands_the_controller_the_corrected_velocity(rad_s: float) -> None:
    """From LOCAL_POSITION_NED messages through TelemetryState to the controller's estimate: a
    vehicle hovering still at (3, 4) whose reported velocity says (0.5, -0.25) m/s."""
    tel = TelemetryState(velocity_correction_rad_s=rad_s)
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    att = mavlink2.MAVLink_attitude_quaternion_message(0, 1.0, 0.0, 0.0, 0.0, 0, 0, 0, [0.0] * 4)
    att.pack(mav)
    tel.update(att, 0.0)
    for i, t in enumerate(samples(8.0)):
        msg = mavlink2.MAVLink_local_position_ned_message(round(t * 1000), 3.0, 4.0, -5.0,
                                                          0.5, -0.25, 0.1)
        msg.pack(mav)
        tel.update(msg, float(i) / RATE_HZ)
    snap = tel.snapshot()
    est = estimate_from_telemetry(snap)
    assert snap.position is not None and est is not None
    assert snap.position.vel_ned == pytest.approx((0.5, -0.25, 0.1))  # as the vehicle said
    if rad_s > 0.0:
        assert est.vel_ned == pytest.approx([0.0, 0.0, 0.1], abs=0.02)  # it stands still
    else:
        assert snap.position.vel_correction_ned == (0.0, 0.0, 0.0)
        assert est.vel_ned == pytest.approx([0.5, -0.25, 0.1])
