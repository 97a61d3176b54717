"""The rates-mode attitude law steers the thrust axis first (PX4's yaw weighting) and the commanded
yaw follows the reference at a bounded rate. Oracles: scipy's rotations, own kinematics."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from companion.control import (
    AttitudeGains,
    Reference,
    StateEstimate,
    TrackingConfig,
    TrackingController,
    so3_rate_command,
)
from companion.control.so3 import tilt_priority_error
from companion.flatness import MultirotorParams

quats = st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(
    lambda q: np.linalg.norm(q) > 1e-2)


def _wxyz(r: Rotation) -> np.ndarray:
    x, y, z, w = r.as_quat()
    return np.array([w, x, y, z])


def _thrust_axis_angle(R: Rotation, Rd: Rotation) -> float:
    c = float(R.apply([0.0, 0.0, 1.0]) @ Rd.apply([0.0, 0.0, 1.0]))
    return math.acos(min(max(c, -1.0), 1.0))


@settings(max_examples=80, deadline=None)
@given(quats, st.lists(st.floats(-1, 1), min_size=3, max_size=3).filter(
    lambda v: np.linalg.norm(v) > 1e-2), st.floats(0.0, 3.0))
def test_a_pure_tilt_gets_the_full_error(q: list[float], target: list[float],
                                         _unused: float) -> None:
    """Rd = the shortest world rotation taking R's thrust axis to `target`, applied to R: no yaw
    to weigh, so the error is -2 sin(angle / 2) axis of R^T Rd (scipy's rotation vector)."""
    R = Rotation.from_quat(q)
    z = R.apply([0.0, 0.0, 1.0])
    zd = np.asarray(target) / np.linalg.norm(target)
    if float(z @ zd) < -0.999:
        return  # no unique shortest tilt
    tilt, _ = Rotation.align_vectors([zd], [z])
    Rd = tilt * R
    rv = (R.inv() * Rd).as_rotvec()
    ang = float(np.linalg.norm(rv))
    want = np.zeros(3) if ang < 1e-12 else -2.0 * math.sin(0.5 * ang) * rv / ang
    got = tilt_priority_error(R.as_matrix(), Rd.as_matrix(), 0.4)
    np.testing.assert_allclose(got, want, atol=1e-9)


@settings(max_examples=80, deadline=None)
@given(quats, st.floats(-3.1, 3.1), st.floats(0.05, 1.0))
def test_a_pure_yaw_is_weighted(q: list[float], psi: float, w: float) -> None:
    """Rd = R turned by psi about its own thrust (body z) axis: the error is about body z, of
    the weighted angle: -2 sin(w psi / 2) e_z."""
    R = Rotation.from_quat(q)
    Rd = R * Rotation.from_rotvec([0.0, 0.0, psi])
    got = tilt_priority_error(R.as_matrix(), Rd.as_matrix(), w)
    np.testing.assert_allclose(got, [0.0, 0.0, -2.0 * math.sin(0.5 * w * psi)], atol=1e-9)


def _simulate(R0: Rotation, Rd: Rotation, gains: AttitudeGains, seconds: float,
              yaw_rate_cap: float, dt: float = 0.002, tau: float = 0.03) -> list[float]:
    """Own kinematics with a first-order rate loop whose yaw axis saturates at `yaw_rate_cap`
    [rad/s] (a quad's weak yaw axis); returns the thrust-axis angle error history [rad]."""
    R, w = R0, np.zeros(3)
    hist = []
    for _ in range(int(seconds / dt)):
        cmd, _ = so3_rate_command(_wxyz(R), _wxyz(Rd), np.zeros(3), gains)
        w = w + (cmd - w) * dt / tau
        w[2] = min(max(w[2], -yaw_rate_cap), yaw_rate_cap)
        R = R * Rotation.from_rotvec(w * dt)
        hist.append(_thrust_axis_angle(R, Rd))
    return hist


@pytest.mark.parametrize(("tilt_deg", "yaw_deg"), [(30.0, 120.0), (45.0, -150.0), (20.0, 90.0)])
def test_the_thrust_axis_converges_while_the_yaw_cannot_follow(tilt_deg: float,
                                                               yaw_deg: float) -> None:
    """A thrust-axis error and a large yaw error, on a vehicle that yaws at most 0.3 rad/s:
    the thrust axis still converges at once and monotonically (at 0.2 s within 35 % of its
    initial error). The full SO(3) error (Lee) spends roll and pitch on the yaw it cannot
    close: at 0.2 s its thrust axis is still at least twice as far off (measured 16.7 vs 5.2,
    34.9 vs 9.3, 6.8 vs 2.5 deg)."""
    Rd = Rotation.from_euler("ZYX", [0.4, math.radians(tilt_deg), 0.0])
    R0 = Rotation.from_euler("ZYX", [0.4 + math.radians(yaw_deg), 0.0, 0.0])
    tilt_first = _simulate(R0, Rd, AttitudeGains(), 1.5, 0.3)
    assert tilt_first[int(0.6 / 0.002)] < math.radians(1.0)
    assert max(tilt_first) <= math.radians(tilt_deg) + 1e-6
    coarse = tilt_first[::5]
    assert all(b <= a + 1e-4 for a, b in itertools.pairwise(coarse))
    at = int(0.2 / 0.002)
    assert tilt_first[at] < 0.35 * math.radians(tilt_deg)
    lee = _simulate(R0, Rd, AttitudeGains(tilt_priority=False), 1.5, 0.3)
    assert lee[at] > 2.0 * tilt_first[at]


def test_yaw_weight_must_be_a_fraction() -> None:
    with pytest.raises(ValueError, match="yaw_weight"):
        AttitudeGains(yaw_weight=0.0)
    with pytest.raises(ValueError, match="yaw_weight"):
        AttitudeGains(yaw_weight=1.5)


# ----------------------------------------------------------------------------- yaw slew


def _hover_controller(max_rate_deg: float = 45.0) -> TrackingController:
    params = MultirotorParams(1.0, np.diag([0.025, 0.025, 0.03]), hover_thrust=0.5, drag=0.0)
    return TrackingController(TrackingConfig(params=params,
                                             max_yaw_rate_rad_s=math.radians(max_rate_deg)))


def _yaw_of(q_wxyz: tuple[float, float, float, float] | np.ndarray) -> float:
    w, x, y, z = (float(c) for c in q_wxyz)
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


@pytest.mark.parametrize("step_deg", [90.0, -170.0, 200.0])
def test_the_commanded_yaw_follows_a_yaw_step_at_the_rate_limit(step_deg: float) -> None:
    """The reference yaw jumps by `step_deg` (200: the short way is -160): the commanded yaw
    moves the short way at exactly the limit per update, with that rate as feed-forward, and
    then holds the reference's yaw with no feed-forward."""
    ctl = _hover_controller(45.0)
    dt = 0.01
    est0 = StateEstimate(0.0, np.zeros(3), np.zeros(3), np.array([1.0, 0, 0, 0]), np.zeros(3))
    ctl.attitude(0.0, est0, Reference(np.zeros(3), yaw=0.0))
    target = math.radians(step_deg)
    short = math.remainder(target, 2 * math.pi)
    prev, yaws, ffs = 0.0, [], []
    for k in range(1, 501):
        t = k * dt
        est = StateEstimate(t, np.zeros(3), np.zeros(3), np.array([1.0, 0, 0, 0]), np.zeros(3))
        cmd = ctl.attitude(t, est, Reference(np.zeros(3), yaw=target))
        y = _yaw_of(cmd.q_wxyz)
        yaws.append(math.remainder(y - prev, 2 * math.pi))
        ffs.append(cmd.yaw_rate_ff)
        prev = y
    lim = math.radians(45.0) * dt
    assert max(abs(s) for s in yaws) <= lim + 1e-9
    n_slew = math.ceil(abs(short) / lim - 1e-9)
    assert all(math.copysign(1, s) == math.copysign(1, short) for s in yaws[:n_slew - 1])
    assert ffs[0] == pytest.approx(math.copysign(math.radians(45.0), short))
    assert abs(math.remainder(prev - target, 2 * math.pi)) < 1e-9
    assert ffs[-1] == 0.0


def test_a_slow_reference_yaw_is_followed_exactly() -> None:
    """A yaw ramp slower than the limit: commanded yaw = reference yaw, rate ff = its rate."""
    ctl = _hover_controller(45.0)
    rate = math.radians(30.0)
    for k in range(200):
        t = k * 0.01
        est = StateEstimate(t, np.zeros(3), np.zeros(3), np.array([1.0, 0, 0, 0]), np.zeros(3))
        cmd = ctl.attitude(t, est, Reference(np.zeros(3), yaw=rate * t, yaw_rate=rate))
        assert _yaw_of(cmd.q_wxyz) == pytest.approx(math.remainder(rate * t, 2 * math.pi),
                                                    abs=1e-9)
        assert cmd.yaw_rate_ff == pytest.approx(rate)


@pytest.mark.parametrize(("rtt", "want"), [(math.nan, 10.0), (0.0, 10.0), (0.02, 10.0),
                                           (0.05, 7.0), (0.1, 3.5)])
def test_attitude_gains_are_capped_by_the_link_round_trip(rtt: float, want: float) -> None:
    """k <= delay_gain_product / RTT (0.35 / 0.05 = 7); unknown or short round trips: as set."""
    g = AttitudeGains(k_roll=10.0, k_pitch=10.0, k_yaw=2.8).for_link_rtt(rtt)
    assert g.k_roll == pytest.approx(want) and g.k_pitch == pytest.approx(want)
    assert g.k_yaw == pytest.approx(min(2.8, want))
    assert (g.yaw_weight, g.tilt_priority) == (0.4, True)
