"""Multirotor flatness map against independent oracles (issue 2 acceptance (a)-(g)).

Flat trajectories are analytic (sums of sinusoids plus a quadratic), so every derivative fed to
the map is exact and the oracles are physics (Newton), scipy's Rotation, central finite
differences of the *returned* attitude/rates/thrust, and forward integration of Euler's
equations with the returned moments.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.spatial.transform import Rotation

from companion.flatness import (
    FLAG_INVERTED,
    MultirotorParams,
    MultirotorSetpoint,
    multirotor_setpoint,
    symbolic,
)

G = 9.80665
E3 = np.array([0.0, 0.0, 1.0])
J_FULL = np.array([[0.011, 0.0005, -0.0003], [0.0005, 0.013, 0.0002], [-0.0003, 0.0002, 0.021]])


@dataclass(frozen=True)
class FlatTrajectory:
    """p_i(t) = c_i + b_i t + a0_i t^2 / 2 + sum_k A_ki sin(w_ki t + ph_ki); yaw likewise (1-D)."""

    A: np.ndarray  # (K, 3)
    w: np.ndarray  # (K, 3)
    ph: np.ndarray  # (K, 3)
    c: np.ndarray  # (3,)
    b: np.ndarray  # (3,)
    a0: np.ndarray  # (3,)
    yaw_A: np.ndarray  # (K,)
    yaw_w: np.ndarray  # (K,)
    yaw_ph: np.ndarray  # (K,)
    yaw_rate0: float = 0.0

    def pos_deriv(self, t: np.ndarray, n: int) -> np.ndarray:
        t = np.asarray(t, dtype=float)[:, None, None]
        out = (self.A * self.w**n * np.sin(self.w * t + self.ph + n * np.pi / 2)).sum(axis=1)
        if n == 0:
            out = out + self.c + self.b * t[:, 0] + 0.5 * self.a0 * t[:, 0] ** 2
        elif n == 1:
            out = out + self.b + self.a0 * t[:, 0]
        elif n == 2:
            out = out + self.a0
        return out

    def yaw_deriv(self, t: np.ndarray, n: int) -> np.ndarray:
        t = np.asarray(t, dtype=float)[:, None]
        out = self.yaw_A * self.yaw_w**n * np.sin(self.yaw_w * t + self.yaw_ph + n * np.pi / 2)
        out = out.sum(axis=1)
        if n == 0:
            out = out + self.yaw_rate0 * t[:, 0]
        elif n == 1:
            out = out + self.yaw_rate0
        return out

    def setpoint(self, t: np.ndarray, params: MultirotorParams) -> MultirotorSetpoint:
        t = np.atleast_1d(np.asarray(t, dtype=float))
        return multirotor_setpoint(
            self.pos_deriv(t, 1),
            self.pos_deriv(t, 2),
            self.pos_deriv(t, 3),
            self.pos_deriv(t, 4),
            self.yaw_deriv(t, 0),
            self.yaw_deriv(t, 1),
            self.yaw_deriv(t, 2),
            params,
        )


def random_trajectory(
    rng: np.random.Generator, acc_scale: float = 4.0, K: int = 3
) -> FlatTrajectory:
    """Smooth random 3-D trajectory; |a| stays below about acc_scale (and below g vertically)."""
    w = rng.uniform(0.3, 2.0, size=(K, 3))
    A = rng.normal(size=(K, 3)) * acc_scale / (K * w**2)
    A[:, 2] *= 0.3
    return FlatTrajectory(
        A=A,
        w=w,
        ph=rng.uniform(0, 2 * np.pi, (K, 3)),
        c=rng.normal(size=3),
        b=rng.normal(size=3),
        a0=np.zeros(3),
        yaw_A=rng.normal(size=K),
        yaw_w=rng.uniform(0.2, 1.5, K),
        yaw_ph=rng.uniform(0, 2 * np.pi, K),
        yaw_rate0=float(rng.normal()),
    )


def aggressive_trajectory() -> FlatTrajectory:
    """Horizontal circle with 2 g centripetal acceleration, vertical wobble and yaw spin."""
    R = 2.5
    w = np.sqrt(2.0 * G / R)
    return FlatTrajectory(
        A=np.array([[R, R, 0.4], [0.2, -0.1, 0.0]]),
        w=np.array([[w, w, 2.0], [3.0, 2.5, 1.0]]),
        ph=np.array([[np.pi / 2, 0.0, 0.3], [0.1, 0.2, 0.0]]),
        c=np.zeros(3),
        b=np.array([0.5, 0.0, 0.0]),
        a0=np.zeros(3),
        yaw_A=np.array([0.8]),
        yaw_w=np.array([1.3]),
        yaw_ph=np.array([0.0]),
        yaw_rate0=0.7,
    )


def inverted_trajectory() -> FlatTrajectory:
    """Pushed down at 2 g (thrust points up: z_b . e3 < 0), with lateral motion and yaw."""
    return FlatTrajectory(
        A=np.array([[1.0, 0.7, 0.2]]),
        w=np.array([[1.1, 1.6, 2.0]]),
        ph=np.array([[0.0, 1.0, 2.0]]),
        c=np.zeros(3),
        b=np.zeros(3),
        a0=np.array([0.0, 0.0, 2.0 * G]),
        yaw_A=np.array([0.5]),
        yaw_w=np.array([0.9]),
        yaw_ph=np.array([0.4]),
        yaw_rate0=0.2,
    )


def figure8(peak_speed: float = 6.0) -> FlatTrajectory:
    """Benchmark figure-8: x = 5 sin(phi), y = 2.5 sin(2 phi), z = -5 (NED), yaw 0, phi = w t."""
    w = peak_speed / (5.0 * np.sqrt(2.0))  # |v| = 5 w sqrt(cos^2 phi + cos^2 2phi), max at 0
    return FlatTrajectory(
        A=np.array([[5.0, 2.5, 0.0]]),
        w=np.array([[w, 2 * w, 1.0]]),
        ph=np.zeros((1, 3)),
        c=np.array([0.0, 0.0, -5.0]),
        b=np.zeros(3),
        a0=np.zeros(3),
        yaw_A=np.zeros(1),
        yaw_w=np.ones(1),
        yaw_ph=np.zeros(1),
        yaw_rate0=0.0,
    )


def params(drag: float = 0.0, mass: float = 1.0, hover: float = 0.5) -> MultirotorParams:
    return MultirotorParams(mass=mass, inertia=J_FULL, drag=drag, hover_thrust=hover)


TRAJ = {
    "random0": random_trajectory(np.random.default_rng(0)),
    "random1": random_trajectory(np.random.default_rng(1), acc_scale=8.0),
    "random2": random_trajectory(np.random.default_rng(2), acc_scale=2.0),
    "aggressive_2g": aggressive_trajectory(),
    "inverted": inverted_trajectory(),
}
CASES = [(name, drag) for name in TRAJ for drag in (0.0, 1.0)]
T_EVAL = np.linspace(0.05, 6.0, 40)


def _rel_err(x: np.ndarray, ref: np.ndarray, floor: float = 1.0) -> float:
    return float(np.max(np.abs(x - ref)) / max(float(np.max(np.abs(ref))), floor))


def test_aggressive_trajectory_really_reaches_2g() -> None:
    acc = aggressive_trajectory().pos_deriv(T_EVAL, 2)
    assert np.max(np.linalg.norm(acc, axis=1)) > 2.0 * G


@pytest.mark.parametrize(("name", "drag"), CASES)
def test_a_newton_and_b_yaw(name: str, drag: float) -> None:
    tr, P = TRAJ[name], params(drag)
    sp = tr.setpoint(T_EVAL, P)
    vel, acc = tr.pos_deriv(T_EVAL, 1), tr.pos_deriv(T_EVAL, 2)
    z_b = sp.C_eb[:, :, 2]
    force = P.mass * P.g * E3 - sp.thrust[:, None] * z_b - drag * vel
    assert _rel_err(force, P.mass * acc, floor=P.mass * G) < 1e-13
    assert np.all(sp.thrust > 0.0)
    # (b) 3-2-1 yaw of C_eb (scipy) equals the commanded yaw
    yaw_c = Rotation.from_matrix(sp.C_eb).as_euler("ZYX")[:, 0]
    d = tr.yaw_deriv(T_EVAL, 0) - yaw_c
    assert np.max(np.abs(np.arctan2(np.sin(d), np.cos(d)))) < 1e-12
    inverted = z_b[:, 2] <= 0.0
    assert np.array_equal(sp.singular, inverted)
    assert np.array_equal((sp.flags & FLAG_INVERTED) != 0, inverted)
    if name == "inverted":
        assert inverted.all()


@pytest.mark.parametrize(("name", "drag"), CASES)
def test_c_body_rates_are_derivative_of_attitude(name: str, drag: float) -> None:
    tr, P, h = TRAJ[name], params(drag), 1e-4
    sp = tr.setpoint(T_EVAL, P)
    Cm, Cp = tr.setpoint(T_EVAL - h, P).C_eb, tr.setpoint(T_EVAL + h, P).C_eb
    # omega = vee(C^T dC/dt): second-order central difference on the group
    omega_fd = Rotation.from_matrix(np.swapaxes(Cm, 1, 2) @ Cp).as_rotvec() / (2 * h)
    assert _rel_err(sp.omega_frd, omega_fd) < 1e-5
    # and the plain matrix form vee(C^T (C+ - C-) / 2h)
    dC = (Cp - Cm) / (2 * h)
    W = np.swapaxes(sp.C_eb, 1, 2) @ dC
    omega_fd2 = 0.5 * np.stack(
        [W[:, 2, 1] - W[:, 1, 2], W[:, 0, 2] - W[:, 2, 0], W[:, 1, 0] - W[:, 0, 1]], axis=1
    )
    assert _rel_err(sp.omega_frd, omega_fd2) < 1e-5


@pytest.mark.parametrize(("name", "drag"), CASES)
def test_d_derivatives_of_rates_and_thrust(name: str, drag: float) -> None:
    tr, P, h = TRAJ[name], params(drag), 1e-4
    sp = tr.setpoint(T_EVAL, P)
    sm, sp_ = tr.setpoint(T_EVAL - h, P), tr.setpoint(T_EVAL + h, P)
    assert _rel_err(sp.omega_dot_frd, (sp_.omega_frd - sm.omega_frd) / (2 * h)) < 1e-6
    assert _rel_err(sp.thrust_dot, (sp_.thrust - sm.thrust) / (2 * h)) < 1e-6
    assert _rel_err(sp.thrust_ddot, (sp_.thrust_dot - sm.thrust_dot) / (2 * h)) < 1e-6
    h2 = 1e-3
    s2m, s2p = tr.setpoint(T_EVAL - h2, P), tr.setpoint(T_EVAL + h2, P)
    ddT = (s2p.thrust - 2 * sp.thrust + s2m.thrust) / h2**2
    assert _rel_err(sp.thrust_ddot, ddT) < 1e-5


@pytest.mark.parametrize(("name", "drag"), CASES)
def test_e_casadi_and_numeric_agree(name: str, drag: float) -> None:
    tr, P = TRAJ[name], params(drag)
    sp = tr.setpoint(T_EVAL, P)
    n = len(T_EVAL)
    f = symbolic().multirotor.map(n)
    out = f(
        vel_ned=tr.pos_deriv(T_EVAL, 1).T,
        acc_ned=tr.pos_deriv(T_EVAL, 2).T,
        jerk_ned=tr.pos_deriv(T_EVAL, 3).T,
        snap_ned=tr.pos_deriv(T_EVAL, 4).T,
        yaw=tr.yaw_deriv(T_EVAL, 0)[None],
        yaw_rate=tr.yaw_deriv(T_EVAL, 1)[None],
        yaw_acc=tr.yaw_deriv(T_EVAL, 2)[None],
        mass=P.mass,
        inertia=P.inertia_matrix,
        g=P.g,
        hover_thrust=P.hover_thrust,
        drag=P.drag,
    )
    cas = {k: np.asarray(v) for k, v in out.items()}
    for key in ("thrust", "thrust_dot", "thrust_ddot", "thrust_norm"):
        assert _rel_err(getattr(sp, key), cas[key][0]) < 1e-12, key
    for key in ("q_wxyz", "omega_frd", "omega_dot_frd", "moment_frd"):
        assert _rel_err(getattr(sp, key), cas[key].T) < 1e-12, key
    # mapped matrix outputs are horizontally stacked 3x3 blocks
    C_cas = cas["C_eb"].reshape(3, n, 3).transpose(1, 0, 2)
    assert _rel_err(sp.C_eb, C_cas) < 1e-12
    np.testing.assert_array_equal(sp.singular, cas["singular"][0] != 0)
    np.testing.assert_array_equal(sp.flags, cas["flags"][0].astype(int))


@pytest.mark.parametrize(("name", "drag"), CASES)
def test_f_quaternion_represents_dcm(name: str, drag: float) -> None:
    sp = TRAJ[name].setpoint(T_EVAL, params(drag))
    np.testing.assert_allclose(np.linalg.norm(sp.q_wxyz, axis=1), 1.0, atol=1e-15)
    assert np.all(sp.q_wxyz[:, 0] >= 0.0)
    C_q = Rotation.from_quat(sp.q_wxyz, scalar_first=True).as_matrix()
    np.testing.assert_allclose(C_q, sp.C_eb, atol=1e-14)
    np.testing.assert_allclose(
        sp.C_eb @ np.swapaxes(sp.C_eb, 1, 2), np.broadcast_to(np.eye(3), sp.C_eb.shape), atol=1e-14
    )
    np.testing.assert_allclose(np.linalg.det(sp.C_eb), 1.0, atol=1e-14)


def test_f_thrust_norm_is_linear_in_thrust_and_clamped() -> None:
    zero = np.zeros(3)
    for hover in (0.5, 0.6):
        P = params(hover=hover, mass=1.7)
        # hovering: thrust = m g and thrust_norm = hover_thrust (the PX4 MPC_THR_HOVER meaning)
        sp = multirotor_setpoint(zero, zero, zero, zero, 0.3, 0.0, 0.0, P)
        assert sp.thrust == pytest.approx(1.7 * G, rel=1e-15)
        assert sp.thrust_norm == pytest.approx(hover, rel=1e-15)
        # climbing at 0.5 g needs 1.5 m g: 1.5 x hover throttle (linear model)
        sp = multirotor_setpoint(zero, [0, 0, -0.5 * G], zero, zero, 0.0, 0.0, 0.0, P)
        assert sp.thrust_norm == pytest.approx(1.5 * hover, rel=1e-14)
        # beyond full throttle: clamped to 1
        sp = multirotor_setpoint(zero, [0, 0, -3.0 * G], zero, zero, 0.0, 0.0, 0.0, P)
        assert sp.thrust_norm == 1.0
        # free fall: zero thrust
        sp = multirotor_setpoint(zero, [0, 0, G], zero, zero, 0.0, 0.0, 0.0, P)
        assert sp.thrust_norm == 0.0


@pytest.mark.parametrize(("name", "drag"), [("random0", 0.0), ("aggressive_2g", 1.0)])
def test_f_moments_reproduce_rates_through_euler_equations(name: str, drag: float) -> None:
    tr, P = TRAJ[name], params(drag)
    J = P.inertia_matrix
    Jinv = np.linalg.inv(J)

    def rhs(t: float, w: np.ndarray) -> np.ndarray:
        M = tr.setpoint(np.array([t]), P).moment_frd[0]
        return Jinv @ (M - np.cross(w, J @ w))

    t0, t1 = 0.2, 2.2
    t_out = np.linspace(t0, t1, 11)
    w0 = tr.setpoint(np.array([t0]), P).omega_frd[0]
    sol = solve_ivp(rhs, (t0, t1), w0, method="DOP853", t_eval=t_out, rtol=1e-11, atol=1e-12)
    assert sol.success
    ref = tr.setpoint(t_out, P).omega_frd
    assert _rel_err(sol.y.T, ref) < 1e-7
    assert np.max(np.abs(ref)) > 0.3  # the check is not vacuous


def test_g_figure8_yaw_rate_shortcut_is_wrong() -> None:
    """Benchmark figure-8, 6 m/s peak, 1 kg, drag 1 N/(m/s), yaw 0 (psi' = 0, shortcut r = 0)."""
    tr = figure8(6.0)
    t = np.linspace(0.0, 2 * np.pi / (6.0 / (5.0 * np.sqrt(2.0))), 400)
    speed = np.linalg.norm(tr.pos_deriv(t, 1), axis=1)
    assert speed.max() == pytest.approx(6.0, rel=1e-6)
    sp = tr.setpoint(t, params(drag=1.0))
    shortcut = tr.yaw_deriv(t, 1) * sp.C_eb[:, 2, 2]  # r = psi' (z_b . e3)
    assert np.max(np.abs(shortcut - sp.omega_frd[:, 2])) > 0.2
    # and the flatness r is the true one: it matches the attitude's finite difference
    h = 1e-4
    Cm, Cp = tr.setpoint(t - h, params(1.0)).C_eb, tr.setpoint(t + h, params(1.0)).C_eb
    r_fd = Rotation.from_matrix(np.swapaxes(Cm, 1, 2) @ Cp).as_rotvec()[:, 2] / (2 * h)
    np.testing.assert_allclose(sp.omega_frd[:, 2], r_fd, atol=1e-6)
    assert not sp.singular.any()
