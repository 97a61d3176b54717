"""Rover (unicycle) flatness against finite differences of atan2 / norm and physics."""

from __future__ import annotations

import numpy as np
import pytest

from companion.flatness import RoverSetpoint, rover_setpoint, symbolic


def _curve(t: np.ndarray, n: int) -> np.ndarray:
    """Planar flat output with velocity bounded away from 0: p = b t + sum A sin(w t + ph)."""
    A = np.array([[1.5, 0.8], [0.3, -0.6]])
    w = np.array([[0.7, 1.1], [2.3, 1.9]])
    ph = np.array([[0.2, 1.0], [0.5, 2.0]])
    b = np.array([2.0, 3.0])
    t3 = np.asarray(t, dtype=float)[:, None, None]
    out = (A * w**n * np.sin(w * t3 + ph + n * np.pi / 2)).sum(axis=1)
    if n == 0:
        out = out + b * t3[:, 0]
    elif n == 1:
        out = out + b
    return out


T = np.linspace(0.0, 8.0, 60)


def _sp(t: np.ndarray) -> RoverSetpoint:
    return rover_setpoint(_curve(t, 1), _curve(t, 2), _curve(t, 3))


def test_curve_stays_away_from_rest() -> None:
    assert np.linalg.norm(_curve(np.linspace(0, 8, 2000), 1), axis=1).min() > 0.5


def test_yaw_speed_and_rates_match_finite_differences() -> None:
    sp = _sp(T)
    assert not np.any(sp.singular)
    vel = _curve(T, 1)
    d = sp.yaw - np.arctan2(vel[:, 1], vel[:, 0])
    assert np.max(np.abs(np.arctan2(np.sin(d), np.cos(d)))) < 1e-14
    np.testing.assert_allclose(sp.speed, np.hypot(vel[:, 0], vel[:, 1]), rtol=1e-15)
    h = 1e-4

    def yaw_of(t: np.ndarray) -> np.ndarray:
        v = _curve(t, 1)
        return np.arctan2(v[:, 1], v[:, 0])

    def speed_of(t: np.ndarray) -> np.ndarray:
        return np.linalg.norm(_curve(t, 1), axis=1)

    dyaw = np.angle(np.exp(1j * (yaw_of(T + h) - yaw_of(T - h)))) / (2 * h)
    np.testing.assert_allclose(sp.yaw_rate, dyaw, atol=1e-7)
    np.testing.assert_allclose(
        sp.speed_dot, (speed_of(T + h) - speed_of(T - h)) / (2 * h), atol=1e-7
    )
    h2 = 1e-3
    d2 = np.angle(np.exp(1j * (yaw_of(T + h2) - yaw_of(T)))) - np.angle(
        np.exp(1j * (yaw_of(T) - yaw_of(T - h2)))
    )
    np.testing.assert_allclose(sp.yaw_acc, d2 / h2**2, atol=2e-5)
    # yaw_acc is also the derivative of the returned yaw_rate
    ddyaw = (_sp(T + h).yaw_rate - _sp(T - h).yaw_rate) / (2 * h)
    assert sp.yaw_acc is not None
    np.testing.assert_allclose(sp.yaw_acc, ddyaw, atol=1e-7)
    assert np.max(np.abs(sp.yaw_acc)) > 0.1


def test_circle_yaw_rate_is_speed_over_radius() -> None:
    """Erratum 2: on a circle the heading turns at V / R (the manual's formula gives V^2 / R)."""
    V, R = 3.0, 2.0
    th = np.linspace(0, 2 * np.pi, 13)
    vel = V * np.stack([-np.sin(th), np.cos(th)], 1)
    acc = -(V**2 / R) * np.stack([np.cos(th), np.sin(th)], 1)
    jerk = -(V**3 / R**2) * np.stack([-np.sin(th), np.cos(th)], 1)
    sp = rover_setpoint(vel, acc, jerk)
    np.testing.assert_allclose(sp.yaw_rate, V / R, rtol=1e-14)
    np.testing.assert_allclose(sp.speed_dot, 0.0, atol=1e-14)
    np.testing.assert_allclose(sp.yaw_acc, 0.0, atol=1e-13)  # type: ignore[arg-type]


def test_stopped_vehicle_is_finite_and_flagged() -> None:
    sp = rover_setpoint([0.0, 0.0], [0.0, 0.0], [0.0, 0.0])
    assert (sp.yaw, sp.speed, sp.speed_dot, sp.yaw_rate, sp.yaw_acc) == (0, 0, 0, 0, 0)
    assert sp.singular
    # starting from rest: heading of the first non-zero derivative (acceleration)
    sp = rover_setpoint([0.0, 0.0], [0.0, 2.0])
    assert sp.yaw == pytest.approx(np.pi / 2) and sp.yaw_acc is None and sp.singular
    # ... which is the limit of the heading just after the start (p = a t^2 / 2)
    a = np.array([-1.0, 0.5])
    t = np.array([0.0, 1e-9, 1e-6, 1e-4, 1e-2])
    sp = rover_setpoint(a * t[:, None], np.tile(a, (5, 1)), np.zeros((5, 2)))
    np.testing.assert_allclose(sp.yaw, np.arctan2(a[1], a[0]), atol=1e-15)
    assert all(
        np.all(np.isfinite(np.asarray(x)))
        for x in (sp.yaw, sp.speed, sp.speed_dot, sp.yaw_rate, sp.yaw_acc)
    )
    np.testing.assert_array_equal(sp.singular, np.abs(t) * np.linalg.norm(a) < 1e-3)
    # heading continuous through the low-speed band edge
    v_dir = np.array([np.cos(2.0), np.sin(2.0)])
    speeds = np.array([0.9e-3, 1.1e-3, 1e-8, 0.0])
    sp = rover_setpoint(speeds[:, None] * v_dir, np.tile([0.3, 0.1], (4, 1)))
    np.testing.assert_allclose(sp.yaw[:3], 2.0, atol=1e-15)  # type: ignore[index]
    assert sp.yaw[3] == pytest.approx(np.arctan2(0.1, 0.3))  # type: ignore[index]


def test_casadi_matches_numeric() -> None:
    n = len(T)
    sp = _sp(T)
    f = symbolic().rover.map(n)
    out = f(vel_xy=_curve(T, 1).T, acc_xy=_curve(T, 2).T, jerk_xy=_curve(T, 3).T)
    for key in ("yaw", "speed", "speed_dot", "yaw_rate", "yaw_acc"):
        ref = np.asarray(out[key])[0]
        np.testing.assert_allclose(getattr(sp, key), ref, rtol=1e-12, atol=1e-12)
    out0 = symbolic().rover(vel_xy=[0, 0], acc_xy=[0, 2.0], jerk_xy=[0, 0])
    assert float(out0["yaw"]) == pytest.approx(np.pi / 2)
    assert float(out0["singular"]) == 1.0


def test_shapes_and_validation() -> None:
    sp = rover_setpoint([1.0, 0.0], [0.0, 1.0], [0.0, 0.0])
    assert isinstance(sp.yaw, float) and isinstance(sp.singular, bool)
    sp = rover_setpoint(np.ones((4, 2)), np.zeros((4, 2)))
    assert sp.yaw.shape == (4,) and sp.yaw_acc is None  # type: ignore[union-attr]
    with pytest.raises(ValueError, match="NaN"):
        rover_setpoint([np.nan, 0.0], [0.0, 0.0])
    with pytest.raises(ValueError, match="same shape"):
        rover_setpoint(np.ones((4, 2)), np.zeros(2))
    with pytest.raises(ValueError, match=r"\(2,\)"):
        rover_setpoint([1.0, 0.0, 0.0], [0.0, 0.0, 0.0])
