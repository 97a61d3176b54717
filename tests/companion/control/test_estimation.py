"""Hover-thrust and drag estimators against an independent point-mass simulation.

The simulated plant is written from Newton's law directly (thrust = u / h_true * m g along
the body z axis, linear drag), integrated with small Euler steps; the estimators see only noisy
finite-difference accelerations, as the companion does from LOCAL_POSITION_NED.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.control.estimation import (
    DragConfig,
    DragEstimator,
    HoverThrustConfig,
    HoverThrustEstimator,
)

G = 9.80665


def _vertical_flight(h_true: float, h_est: HoverThrustEstimator, seconds: float, seed: int,
                     k_drag: float = 0.0, tilt_deg: float = 0.0, noise_v: float = 0.02,
                     change_at: float | None = None, h_after: float | None = None
                     ) -> list[float]:
    """Hover-ish flight with a crude altitude loop; returns the estimate after each sample."""
    rng = np.random.default_rng(seed)
    dt_phys, period = 0.002, 1.0 / 30.0
    z, vz, t = 0.0, 0.0, 0.0
    cos_t = math.cos(math.radians(tilt_deg))
    next_sample = period
    vz_meas_prev = 0.0
    t_prev = 0.0
    out: list[float] = []
    u = 0.5
    while t < seconds:
        h = h_after if (change_at is not None and t >= change_at and h_after) else h_true
        # controller uses the *estimate* (closed loop like the companion) plus a sine excitation
        a_des = -2.0 * z - 2.0 * vz + 0.5 * math.sin(2.0 * t)
        u = h_est.hover_thrust * (1.0 - a_des / G) / cos_t
        az = G - G * u * cos_t / h - k_drag * vz
        vz += az * dt_phys
        z += vz * dt_phys
        t += dt_phys
        if t >= next_sample:
            next_sample += period
            vz_meas = vz + rng.normal(0.0, noise_v)
            acc = (vz_meas - vz_meas_prev) / (t - t_prev)
            h_est.update(t, acc, u, cos_t, vz_meas)
            vz_meas_prev, t_prev = vz_meas, t
            out.append(h_est.hover_thrust)
    return out


def test_converges_to_true_hover_thrust() -> None:
    est = HoverThrustEstimator(HoverThrustConfig(initial_hover_thrust=0.5))
    hist = _vertical_flight(0.6, est, 6.0, seed=1)
    assert abs(hist[-1] - 0.6) < 0.01 * 0.6
    # within 5 % after 3 s
    assert all(abs(h - 0.6) < 0.05 * 0.6 for h in hist[90:])


def test_converges_tilted_with_drag() -> None:
    cfg = HoverThrustConfig(initial_hover_thrust=0.5, drag_over_mass=0.8)
    est = HoverThrustEstimator(cfg)
    hist = _vertical_flight(0.42, est, 6.0, seed=2, k_drag=0.8, tilt_deg=25.0)
    assert abs(hist[-1] - 0.42) < 0.02 * 0.42


def test_recovers_after_step_change() -> None:
    est = HoverThrustEstimator(HoverThrustConfig(initial_hover_thrust=0.5))
    hist = _vertical_flight(0.5, est, 14.0, seed=3, change_at=4.0, h_after=0.7)
    assert abs(hist[int(3.9 * 30)] - 0.5) < 0.02
    assert abs(hist[-1] - 0.7) < 0.03 * 0.7


def test_gate_rejects_outlier() -> None:
    est = HoverThrustEstimator(HoverThrustConfig(initial_hover_thrust=0.5, initial_std=0.01))
    # consistent sample: hover at 0.5 -> zero acceleration
    s = est.update(0.0, 0.0, 0.5, 1.0)
    assert s.fused
    before = est.hover_thrust
    s = est.update(0.03, 4.9, 0.5, 1.0)  # an impossible jump for the current uncertainty
    assert not s.fused and s.reason == "innovation gate" and s.test_ratio > 1.0
    assert est.hover_thrust == before


@pytest.mark.parametrize(
    ("kwargs", "reason"),
    [
        ({"airborne": False}, "not airborne"),
        ({"thrust_norm": 0.0}, "thrust too low"),
        ({"cos_tilt": math.cos(math.radians(80.0))}, "tilt too large"),
        ({"acc_z_ned": 8.0}, "vertical acceleration too large"),
        ({"acc_z_ned": math.nan}, "non-finite input"),
    ],
)
def test_holds_when_not_informative(kwargs: dict[str, object], reason: str) -> None:
    est = HoverThrustEstimator(HoverThrustConfig(initial_hover_thrust=0.5))
    args: dict[str, object] = {"acc_z_ned": -2.0, "thrust_norm": 0.6, "cos_tilt": 1.0}
    args.update(kwargs)
    s = est.update(1.0, **args)  # type: ignore[arg-type]
    assert not s.fused and s.reason == reason
    assert est.hover_thrust == 0.5


def test_predicted_acceleration_matches_newton() -> None:
    # Independent oracle: thrust force from the linear model, Newton in NED.
    est = HoverThrustEstimator(HoverThrustConfig(initial_hover_thrust=0.4, drag_over_mass=0.5))
    m, u, cos_t, vz = 1.3, 0.55, 0.9, -1.2
    thrust_n = u / 0.4 * m * G
    az = (m * G - thrust_n * cos_t - 0.5 * m * vz) / m
    assert est.predict_acc_z(u, cos_t, vz) == pytest.approx(az, rel=1e-12)


def test_config_validation() -> None:
    with pytest.raises(ValueError, match="initial hover thrust"):
        HoverThrustConfig(initial_hover_thrust=0.95)
    with pytest.raises(ValueError, match="gate_sigma"):
        HoverThrustConfig(gate_sigma=0.0)


def test_drag_estimator_converges() -> None:
    rng = np.random.default_rng(4)
    k_true, h = 0.9, 0.5
    est = DragEstimator(DragConfig(initial_drag_over_mass=0.0))
    for i in range(300):
        t = i / 30.0
        v = np.array([4.0 * math.cos(0.7 * t), 3.0 * math.sin(0.5 * t), 0.0])
        # some tilt, some thrust; acceleration from Newton with drag
        zb = np.array([0.2 * math.sin(t), -0.1, -1.0])
        zb /= np.linalg.norm(zb)
        u = 0.55
        a = G * np.array([0.0, 0.0, 1.0]) - G * u / h * zb - k_true * v
        a_meas = a + rng.normal(0.0, 0.3, 3)
        est.update(t, a_meas, v, u, zb, h)
    assert est.drag_over_mass == pytest.approx(k_true, rel=0.05)


def _wind_samples(k_true: float, d: tuple[float, float], n: int = 600) -> list[tuple[float, ...]]:
    """A weaving flight north (velocity 4 m/s north with a 2 m/s swing: not zero mean, as on a
    mission's leg) in a steady force d [m/s^2] (wind on the drag): Newton's horizontal balance
    a = -(g u / h) z_b,h - k v + d, exact (no noise)."""
    out = []
    h, u = 0.5, 0.55
    for i in range(n):
        t = i / 30.0
        v = (4.0 + 2.0 * math.cos(0.6 * t), 2.0 * math.sin(0.6 * t), 0.0)
        zb = np.array([0.3 * math.sin(0.6 * t), -0.3 * math.cos(0.6 * t), -1.0])
        zb /= np.linalg.norm(zb)
        a = (-G * u / h * zb[0] - k_true * v[0] + d[0], -G * u / h * zb[1] - k_true * v[1] + d[1])
        out.append((t, a[0], a[1], v[0], v[1], zb[0], zb[1], zb[2], u, h))
    return out


def test_drag_estimator_takes_the_given_disturbance_out_of_the_balance() -> None:
    """In a steady force d the drag per mass is found when d is given, and not without it (the
    control: the same samples, d left in the balance, read as drag)."""
    k_true, d = 1.25, (1.8, -1.2)
    given = DragEstimator(DragConfig(initial_drag_over_mass=1.0))
    ignored = DragEstimator(DragConfig(initial_drag_over_mass=1.0))
    for t, ax, ay, vx, vy, zx, zy, zz, u, h in _wind_samples(k_true, d):
        a, v, zb = np.array([ax, ay, 0.0]), np.array([vx, vy, 0.0]), np.array([zx, zy, zz])
        given.update(t, a, v, u, zb, h, True, d)
        ignored.update(t, a, v, u, zb, h, True)
    assert given.drag_over_mass == pytest.approx(k_true, rel=0.01)
    assert abs(ignored.drag_over_mass - k_true) > 0.05
