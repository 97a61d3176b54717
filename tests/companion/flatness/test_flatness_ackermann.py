"""Ackermann (car-like) rover flatness against independent oracles: circles and clothoids with
known curvature, finite differences along a Bezier path, and a kinematic bicycle model driven by
the returned steering, which must retrace the planned path."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.flatness import ROVER_SPEED_MIN, RoverSetpoint, rover_setpoint, symbolic
from companion.trajectory import Bezier

L = 0.8  # wheel base [m]


def _rot(psi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit tangent (cos, sin) and normal (-sin, cos) of the headings psi, shape (N, 2)."""
    c, s = np.cos(psi), np.sin(psi)
    return np.stack([c, s], 1), np.stack([-s, c], 1)


def _path_of_heading(
    s1: np.ndarray, s2: np.ndarray, s3: np.ndarray, psi: np.ndarray, k: np.ndarray,
    k_s: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """vel, acc, jerk of a path driven at speed s' (accel s'', jerk s''') along headings psi
    with curvature k = dpsi/ds and dk/ds = k_s (Frenet: T' = k s' N, N' = -k s' T)."""
    T, N = _rot(psi)
    w = k * s1  # heading rate
    w_d = k_s * s1 * s1 + k * s2
    vel = s1[:, None] * T
    acc = s2[:, None] * T + (s1 * w)[:, None] * N
    jerk = ((s3 - s1 * w * w)[:, None] * T
            + (s2 * w + s2 * w + s1 * w_d)[:, None] * N)
    return vel, acc, jerk


# Arc length s(t) = 1.5 t + 0.4 t^2 - 0.03 t^3 on [0, 4]: speed from 1.5 up to ~1.9 and back.
T_S = np.linspace(0.0, 4.0, 41)
S1 = 1.5 + 0.8 * T_S - 0.09 * T_S**2
S2 = 0.8 - 0.18 * T_S
S3 = np.full_like(T_S, -0.18)
S0 = 1.5 * T_S + 0.4 * T_S**2 - 0.03 * T_S**3


@pytest.mark.parametrize("R", [2.0, -5.0, 40.0])
def test_circle_has_curvature_one_over_radius_at_any_speed(R: float) -> None:
    """A circle of radius |R| driven at a varying speed (R > 0 turning right, clockwise seen
    from above in NED): kappa = 1/R, delta = atan(L/R), both constant (rates 0)."""
    psi = 0.3 + S0 / R
    k = np.full_like(T_S, 1.0 / R)
    vel, acc, jerk = _path_of_heading(S1, S2, S3, psi, k, np.zeros_like(T_S))
    sp = rover_setpoint(vel, acc, jerk, wheel_base_m=L)
    assert not np.any(sp.singular)
    np.testing.assert_allclose(sp.curvature, 1.0 / R, rtol=1e-13)  # type: ignore[arg-type]
    np.testing.assert_allclose(sp.steer_angle, math.atan(L / R), rtol=1e-13)  # type: ignore[arg-type]
    np.testing.assert_allclose(sp.curvature_rate, 0.0, atol=1e-13)  # type: ignore[arg-type]
    np.testing.assert_allclose(sp.steer_rate, 0.0, atol=1e-13)  # type: ignore[arg-type]
    # the unicycle map turns at V / R (yaw rate = speed * curvature)
    np.testing.assert_allclose(sp.yaw_rate, S1 / R, rtol=1e-13)


def test_right_turn_is_positive() -> None:
    """Heading north, accelerating east: the path bends right, clockwise seen from above."""
    sp = rover_setpoint([2.0, 0.0], [0.0, 1.0], [0.0, 0.0], wheel_base_m=L)
    assert sp.curvature == pytest.approx(1.0 / 4.0) and sp.steer_angle > 0.0  # type: ignore[operator]
    assert sp.yaw_rate > 0.0  # type: ignore[operator]


@pytest.mark.parametrize("k0, c", [(0.0, 0.05), (-0.4, 0.1), (0.3, -0.02)])
def test_clothoid_curvature_rate_is_c_times_speed(k0: float, c: float) -> None:
    """A clothoid kappa(s) = k0 + c s driven at a varying speed: kappa' = c V, and
    delta' = d/dt atan(L kappa) = L c V / (1 + (L kappa)^2) by the chain rule."""
    k = k0 + c * S0
    psi = -1.0 + k0 * S0 + 0.5 * c * S0**2
    vel, acc, jerk = _path_of_heading(S1, S2, S3, psi, k, np.full_like(T_S, c))
    sp = rover_setpoint(vel, acc, jerk, wheel_base_m=L)
    np.testing.assert_allclose(sp.curvature, k, rtol=1e-12, atol=1e-14)  # type: ignore[arg-type]
    np.testing.assert_allclose(sp.curvature_rate, c * S1, rtol=1e-12, atol=1e-14)  # type: ignore[arg-type]
    np.testing.assert_allclose(sp.steer_angle, np.arctan(L * k), rtol=1e-12, atol=1e-14)  # type: ignore[arg-type]
    np.testing.assert_allclose(
        sp.steer_rate, L * c * S1 / (1.0 + (L * k) ** 2), rtol=1e-12, atol=1e-14  # type: ignore[arg-type]
    )


# A degree-7 planar Bezier path that keeps moving (|v| > 1 m/s) and turns both ways.
_CP = np.array([[0.0, 0.0], [2.0, 0.5], [4.0, 3.0], [5.0, 6.5], [8.0, 7.0], [11.0, 5.0],
                [12.0, 2.0], [15.0, 1.0]])
PATH = Bezier(_CP, 8.0)


def _bezier_sp(t: np.ndarray, wheel_base: float = L) -> RoverSetpoint:
    return rover_setpoint(PATH.evaluate(t, 1), PATH.evaluate(t, 2), PATH.evaluate(t, 3),
                          wheel_base_m=wheel_base)


T_B = np.linspace(0.0, 8.0, 81)


def test_bezier_path_moves_and_turns_both_ways() -> None:
    sp = _bezier_sp(T_B)
    assert np.min(sp.speed) > 1.0
    assert np.min(sp.curvature) < -0.05 and np.max(sp.curvature) > 0.05  # type: ignore[arg-type]


def test_curvature_is_the_heading_change_per_metre() -> None:
    """kappa = dpsi/ds: central differences of the heading of the velocity over the arc length
    (arc length by 16-point Gauss-Legendre quadrature of the speed), independent of the formula."""
    h = 1e-3
    gx, gw = np.polynomial.legendre.leggauss(16)

    def heading(t: np.ndarray) -> np.ndarray:
        v = PATH.evaluate(t, 1)
        return np.unwrap(np.arctan2(v[:, 1], v[:, 0]))

    def arc(t0: float, t1: float) -> float:
        tq = 0.5 * (t1 - t0) * gx + 0.5 * (t1 + t0)
        return float(0.5 * (t1 - t0) * np.sum(gw * np.linalg.norm(PATH.evaluate(tq, 1), axis=1)))

    t = T_B[1:-1]
    dpsi = heading(t + h) - heading(t - h)
    ds = np.array([arc(x - h, x + h) for x in t])
    sp = _bezier_sp(t)
    np.testing.assert_allclose(sp.curvature, dpsi / ds, atol=1e-7)  # type: ignore[arg-type]
    np.testing.assert_allclose(np.tan(sp.steer_angle), L * dpsi / ds, atol=1e-6)  # type: ignore[arg-type]


def test_rates_match_central_differences_along_a_bezier_path() -> None:
    h = 1e-4
    sp, spp, spm = _bezier_sp(T_B), _bezier_sp(T_B + h), _bezier_sp(T_B - h)
    dk = (np.asarray(spp.curvature) - np.asarray(spm.curvature)) / (2 * h)
    dd = (np.asarray(spp.steer_angle) - np.asarray(spm.steer_angle)) / (2 * h)
    np.testing.assert_allclose(sp.curvature_rate, dk, atol=1e-7)  # type: ignore[arg-type]
    np.testing.assert_allclose(sp.steer_rate, dd, atol=1e-7)  # type: ignore[arg-type]
    assert np.max(np.abs(dk)) > 0.05 and np.max(np.abs(dd)) > 0.05  # not vacuous


def test_bicycle_model_driven_by_the_steering_retraces_the_path() -> None:
    """Integrate the kinematic bicycle model about the rear axle, x' = V cos psi,
    y' = V sin psi, psi' = V tan(delta) / L, with the speed and steering angle of the map
    (RK4, 4 ms): the rear axle follows the Bezier path and its heading."""
    dt = 4e-3
    t_end = 8.0
    p0 = PATH.evaluate(0.0, 0)
    sp0 = _bezier_sp(np.array([0.0]))
    x = np.array([p0[0], p0[1], float(np.asarray(sp0.yaw)[0])])

    def f(t: float, state: np.ndarray) -> np.ndarray:
        sp = rover_setpoint(PATH.evaluate(t, 1), PATH.evaluate(t, 2), wheel_base_m=L)
        V, delta = float(sp.speed), float(sp.steer_angle)  # type: ignore[arg-type]
        return np.array([V * math.cos(state[2]), V * math.sin(state[2]),
                         V * math.tan(delta) / L])

    t = 0.0
    err = 0.0
    for _ in range(round(t_end / dt)):
        k1 = f(t, x)
        k2 = f(t + dt / 2, x + dt / 2 * k1)
        k3 = f(t + dt / 2, x + dt / 2 * k2)
        k4 = f(t + dt, x + dt * k3)
        x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        t += dt
        err = max(err, float(np.linalg.norm(x[:2] - PATH.evaluate(t, 0))))
    assert err < 1e-9
    v_end = PATH.evaluate(t_end, 1)
    assert abs(math.remainder(x[2] - math.atan2(v_end[1], v_end[0]), math.tau)) < 1e-9


def test_stopped_rover_holds_zero_steering_and_is_flagged() -> None:
    for v, a, j in (([0.0, 0.0], [0.0, 0.0], [0.0, 0.0]),  # standing still
                    ([0.0, 0.0], [0.0, 2.0], [1.0, -3.0]),  # starting from rest
                    ([3e-4, -5e-4], [1.0, 2.0], [-4.0, 0.5])):  # below ROVER_SPEED_MIN
        sp = rover_setpoint(v, a, j, wheel_base_m=L)
        assert sp.singular
        assert (sp.curvature, sp.curvature_rate, sp.steer_angle, sp.steer_rate) == (0, 0, 0, 0)
        batch = rover_setpoint([v], [a], [j], wheel_base_m=L)
        for name in ("curvature", "curvature_rate", "steer_angle", "steer_rate"):
            assert np.asarray(getattr(batch, name)).tolist() == [0.0], name


def test_leaving_rest_curvature_is_large_but_finite() -> None:
    """p = a t^2/2 + j t^3/6 with j not parallel to a: the path's curvature grows like 1/t
    towards the start (kappa = (a x j) / (2 |a|^3 t) to leading order). Just above the stop
    threshold it is huge but finite, and the steering saturates below pi/2, never NaN."""
    a = np.array([1.0, 0.5])
    j = np.array([-0.5, 2.0])
    cross = a[0] * j[1] - a[1] * j[0]
    na = float(np.linalg.norm(a))
    t = np.array([2e-3, 1e-2, 3e-2])
    vel = a * t[:, None] + j * t[:, None] ** 2 / 2
    acc = a + j * t[:, None]
    sp = rover_setpoint(vel, acc, np.tile(j, (3, 1)), wheel_base_m=L)
    assert not np.any(sp.singular) and np.min(sp.speed) > ROVER_SPEED_MIN
    np.testing.assert_allclose(sp.curvature, cross / (2 * na**3 * t), rtol=0.1)  # type: ignore[arg-type]
    for name in ("curvature", "curvature_rate", "steer_angle", "steer_rate"):
        assert np.all(np.isfinite(np.asarray(getattr(sp, name)))), name
    assert np.all(np.abs(np.asarray(sp.steer_angle)) < math.pi / 2)


def test_fields_are_none_without_a_wheel_base_or_without_jerk() -> None:
    v, a, j = [1.0, 0.5], [0.25, -0.5], [0.1, 0.2]
    plain = rover_setpoint(v, a, j)
    assert (plain.curvature, plain.curvature_rate, plain.steer_angle, plain.steer_rate) == (
        None, None, None, None)
    ack = rover_setpoint(v, a, j, wheel_base_m=L)
    for name in ("yaw", "speed", "speed_dot", "yaw_rate", "yaw_acc", "singular"):
        assert getattr(ack, name) == getattr(plain, name), name  # the unicycle part unchanged
    no_jerk = rover_setpoint(v, a, wheel_base_m=L)
    assert no_jerk.curvature == ack.curvature and no_jerk.steer_angle == ack.steer_angle
    assert no_jerk.curvature_rate is None and no_jerk.steer_rate is None
    batch = rover_setpoint(np.ones((3, 2)), np.zeros((3, 2)), wheel_base_m=L)
    assert np.asarray(batch.curvature).shape == (3,) and batch.steer_rate is None


@pytest.mark.parametrize("bad", [0.0, -0.5, math.nan, math.inf, -math.inf, 2e12, "long"])
def test_bad_wheel_base_is_refused(bad: object) -> None:
    with pytest.raises(ValueError, match="wheel_base_m"):
        rover_setpoint([1.0, 0.0], [0.0, 1.0], wheel_base_m=bad)  # type: ignore[arg-type]


def test_casadi_matches_numeric_and_defaults_to_zero_steering() -> None:
    n = len(T_B)
    sp = _bezier_sp(T_B)
    f = symbolic().rover.map(n)
    out = f(vel_xy=PATH.evaluate(T_B, 1).T, acc_xy=PATH.evaluate(T_B, 2).T,
            jerk_xy=PATH.evaluate(T_B, 3).T, wheel_base=L)
    for key in ("curvature", "curvature_rate", "steer_angle", "steer_rate"):
        ref = np.asarray(out[key])[0]
        np.testing.assert_allclose(getattr(sp, key), ref, rtol=1e-12, atol=1e-12)
    # a named call without the wheel base (the pre-Ackermann call) still works: no steering
    out0 = symbolic().rover(vel_xy=[2.0, 0.0], acc_xy=[0.0, 1.0], jerk_xy=[0.0, 0.0])
    assert float(out0["curvature"]) == pytest.approx(0.25)
    assert float(out0["steer_angle"]) == 0.0 and float(out0["steer_rate"]) == 0.0
    stopped = symbolic().rover(vel_xy=[0, 0], acc_xy=[0, 0], jerk_xy=[0, 0], wheel_base=L)
    assert all(float(v) == 0.0 for k, v in stopped.items() if k != "singular")
