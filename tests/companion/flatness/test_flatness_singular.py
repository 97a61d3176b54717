"""Singularities, fallbacks, input validation and API shape of companion.flatness."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from companion.flatness import (
    FLAG_HEADING_SINGULAR,
    FLAG_INVERTED,
    FLAG_LOW_THRUST,
    MultirotorParams,
    multirotor_setpoint,
    symbolic,
)

G = 9.80665
Z3 = np.zeros(3)
P = MultirotorParams(mass=1.3, inertia=[0.012, 0.014, 0.02], drag=0.0)


def _assert_valid(sp: object) -> None:
    for name in (
        "thrust",
        "thrust_dot",
        "thrust_ddot",
        "thrust_norm",
        "q_wxyz",
        "C_eb",
        "omega_frd",
        "omega_dot_frd",
        "moment_frd",
    ):
        assert np.all(np.isfinite(getattr(sp, name))), name
    q = np.asarray(sp.q_wxyz)  # type: ignore[attr-defined]
    np.testing.assert_allclose(np.linalg.norm(q, axis=-1), 1.0, atol=1e-15)
    assert np.all(q[..., 0] >= 0.0)
    C = np.asarray(sp.C_eb)  # type: ignore[attr-defined]
    eye = np.broadcast_to(np.eye(3), C.shape)
    np.testing.assert_allclose(C @ np.swapaxes(C, -1, -2), eye, atol=1e-14)
    np.testing.assert_allclose(
        Rotation.from_quat(q.reshape(-1, 4), scalar_first=True).as_matrix(),
        C.reshape(-1, 3, 3),
        atol=1e-14,
    )


@pytest.mark.parametrize("yaw", [0.0, 0.7, -2.5, np.pi])
def test_free_fall_is_level_with_yaw_and_zero_rates(yaw: float) -> None:
    sp = multirotor_setpoint(Z3, [0.0, 0.0, G], [0.3, -0.2, 0.1], [1.0, 0.0, 0.0], yaw, 0.4, 0.1, P)
    _assert_valid(sp)
    assert sp.thrust == 0.0 and sp.thrust_norm == 0.0
    assert sp.singular and sp.flags & FLAG_LOW_THRUST
    np.testing.assert_allclose(sp.C_eb, Rotation.from_euler("z", yaw).as_matrix(), atol=1e-15)
    np.testing.assert_array_equal(sp.omega_frd, Z3)
    np.testing.assert_array_equal(sp.omega_dot_frd, Z3)
    np.testing.assert_array_equal(sp.moment_frd, Z3)
    # thrust_dot is still the exact derivative of |t| along the (level) z_b: t' = -m j
    assert sp.thrust_dot == pytest.approx(-P.mass * 0.1)


def test_sweep_through_zero_thrust_is_finite_flagged_and_attitude_continuous() -> None:
    # t = m (g e3 - a): thrust along a tilted direction d, magnitude s sweeping through 0
    d = np.array([0.3, -0.2, 0.93])
    d /= np.linalg.norm(d)
    s = np.concatenate([np.linspace(-0.05, 0.05, 2001), [0.0, 1e-300, -1e-300, 1e-12]])
    acc = G * np.array([0.0, 0.0, 1.0]) - (s[:, None] * P.mass * G * d) / P.mass
    n = len(s)
    sp = multirotor_setpoint(
        np.zeros((n, 3)),
        acc,
        np.tile([0.5, 0.1, -0.3], (n, 1)),
        np.tile([0.2, 0.0, 1.0], (n, 1)),
        np.full(n, 0.3),
        0.2,
        0.0,
        P,
    )
    _assert_valid(sp)
    T_over_mg = np.abs(s)
    low = (sp.flags & FLAG_LOW_THRUST) != 0
    assert np.array_equal(low, sp.thrust < 1e-3 * P.mass * G)
    assert low[np.abs(T_over_mg) < 0.99e-3].all() and not low[T_over_mg > 1.01e-3].any()
    assert np.all(sp.omega_frd[low] == 0.0) and np.all(sp.moment_frd[low] == 0.0)
    # the attitude follows the thrust direction into the low-thrust band (no jump at its edge)
    pos = (s > 0.5e-3) & (s < 2e-3)
    np.testing.assert_allclose(
        sp.C_eb[pos][:, :, 2], np.broadcast_to(d, (pos.sum(), 3)), atol=1e-12
    )


@pytest.mark.parametrize("yaw", [0.0, 1.0, -2.0])
@pytest.mark.parametrize("side", [1.0, -1.0])
def test_thrust_along_y_c_heading_singularity(yaw: float, side: float) -> None:
    y_c = np.array([-np.sin(yaw), np.cos(yaw), 0.0])
    acc = np.array([0.0, 0.0, G]) - side * 4.0 * y_c  # t = m (g e3 - a) = side 4 m y_c
    sp = multirotor_setpoint(
        [1.0, 2.0, 0.0], acc, [0.3, 0.3, 0.3], [1.0, 1.0, 1.0], yaw, 0.5, 0.2, P
    )
    _assert_valid(sp)
    assert sp.flags & FLAG_HEADING_SINGULAR
    np.testing.assert_allclose(sp.C_eb[:, 2], side * y_c, atol=1e-15)  # Newton still holds
    assert sp.thrust == pytest.approx(4.0 * P.mass)
    np.testing.assert_array_equal(sp.omega_frd, Z3)
    # fallback keeps the nose on the commanded heading (3-2-1 yaw = yaw, roll +-90 deg)
    ypr = Rotation.from_matrix(sp.C_eb).as_euler("ZYX")
    assert np.cos(ypr[0] - yaw) == pytest.approx(1.0, abs=1e-12)
    # a tiny vertical component: still flagged, still finite, attitude close to the limit
    sp2 = multirotor_setpoint([1.0, 2.0, 0.0], acc - [0, 0, 1e-5], Z3, Z3, yaw, 0.5, 0.2, P)
    _assert_valid(sp2)
    assert sp2.flags & FLAG_HEADING_SINGULAR
    np.testing.assert_allclose(sp2.C_eb, sp.C_eb, atol=1e-5)


def test_just_outside_heading_band_is_regular() -> None:
    # |cos(roll)| = 2e-3: not flagged, rates finite and consistent with finite differences
    yaw = 0.4
    y_c = np.array([-np.sin(yaw), np.cos(yaw), 0.0])
    z_b = np.sqrt(1 - 2e-3**2) * y_c + 2e-3 * np.array([0.0, 0.0, 1.0])
    acc = np.array([0.0, 0.0, G]) - 10.0 * z_b
    sp = multirotor_setpoint(Z3, acc, [0.01, 0, 0], Z3, yaw, 0.0, 0.0, P)
    _assert_valid(sp)
    assert sp.flags == 0 and not sp.singular
    assert np.linalg.norm(sp.omega_frd) > 0.0


@pytest.mark.parametrize("yaw", [0.0, 0.9, -3.0])
def test_inverted_follows_px4_nose_front(yaw: float) -> None:
    # PX4 ControlMath::bodyzToAttitude flips x_b when body_z(2) < 0: upside down, nose on yaw.
    sp = multirotor_setpoint(Z3, [0.0, 0.0, 3.0 * G], Z3, Z3, yaw, 0.0, 0.0, P)
    _assert_valid(sp)
    assert sp.singular and sp.flags == FLAG_INVERTED
    ref = Rotation.from_euler("ZYX", [yaw, 0.0, np.pi]).as_matrix()
    np.testing.assert_allclose(sp.C_eb, ref, atol=1e-15)
    # thrust (along -z_b) points down, magnitude 2 m g
    np.testing.assert_allclose(-sp.thrust * sp.C_eb[:, 2], [0.0, 0.0, 2 * P.mass * G], atol=1e-12)


def test_horizontal_thrust_px4_body_x_down() -> None:
    # thrust exactly horizontal along x_c: PX4 takes body_x = (0, 0, 1) (nose down)
    sp = multirotor_setpoint(Z3, [-5.0, 0.0, G], Z3, Z3, 0.0, 0.0, 0.0, P)
    _assert_valid(sp)
    np.testing.assert_allclose(sp.C_eb[:, 2], [1.0, 0.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(sp.C_eb[:, 0], [0.0, 0.0, 1.0], atol=1e-15)
    assert sp.flags & FLAG_INVERTED  # z_b . e3 <= 0 is flagged


def test_single_and_batched_paths_agree() -> None:
    rng = np.random.default_rng(7)
    n = 64
    args = [rng.normal(size=(n, 3)) * s for s in (3.0, 5.0, 5.0, 10.0)]
    args[1][:5] = [0.0, 0.0, G]  # include free fall
    yaw, yr, ya = rng.normal(size=(3, n))
    Pd = MultirotorParams(0.9, np.diag([0.01, 0.02, 0.03]), drag=0.7, hover_thrust=0.6)
    b = multirotor_setpoint(*args, yaw, yr, ya, Pd)
    for i in range(0, n, 7):
        s = multirotor_setpoint(
            args[0][i], args[1][i], args[2][i], args[3][i], yaw[i], yr[i], ya[i], Pd
        )
        assert isinstance(s.thrust, float) and isinstance(s.singular, bool)
        for key in (
            "thrust",
            "thrust_dot",
            "thrust_ddot",
            "thrust_norm",
            "q_wxyz",
            "C_eb",
            "omega_frd",
            "omega_dot_frd",
            "moment_frd",
        ):
            ref = np.asarray(getattr(b, key))[i]
            np.testing.assert_allclose(getattr(s, key), ref, rtol=1e-12, atol=1e-12)
        assert s.flags == b.flags[i] and s.singular == b.singular[i]
    # scalar yaw broadcasts over a batch
    b2 = multirotor_setpoint(*args, 0.5, 0.0, 0.0, Pd)
    assert b2.q_wxyz.shape == (n, 4) and b2.C_eb.shape == (n, 3, 3)
    assert b2.thrust.shape == (n,) and b2.singular.shape == (n,)


def test_input_validation_messages() -> None:
    with pytest.raises(ValueError, match="NaN, inf"):
        multirotor_setpoint([np.nan, 0, 0], Z3, Z3, Z3, 0.0, 0.0, 0.0, P)
    with pytest.raises(ValueError, match="NaN, inf"):
        multirotor_setpoint(
            np.zeros((3, 3)),
            np.zeros((3, 3)),
            np.zeros((3, 3)),
            np.zeros((3, 3)),
            [0.0, np.inf, 0.0],
            0.0,
            0.0,
            P,
        )
    with pytest.raises(ValueError, match="beyond"):
        multirotor_setpoint(Z3, [0.0, 0.0, 1e13], Z3, Z3, 0.0, 0.0, 0.0, P)
    with pytest.raises(ValueError, match="yaw_acc contains NaN"):
        multirotor_setpoint(Z3, Z3, Z3, Z3, 0.0, 0.0, np.nan, P)
    with pytest.raises(ValueError, match="same shape"):
        multirotor_setpoint(np.zeros((2, 3)), Z3, Z3, Z3, 0.0, 0.0, 0.0, P)
    with pytest.raises(ValueError, match="shape"):
        multirotor_setpoint(
            np.zeros((2, 3)),
            np.zeros((2, 3)),
            np.zeros((2, 3)),
            np.zeros((2, 3)),
            np.zeros(3),
            0.0,
            0.0,
            P,
        )
    with pytest.raises(ValueError, match="mass must be positive"):
        MultirotorParams(mass=0.0, inertia=np.eye(3))
    with pytest.raises(ValueError, match="positive definite"):
        MultirotorParams(mass=1.0, inertia=np.diag([1.0, -1.0, 1.0]))
    with pytest.raises(ValueError, match="symmetric"):
        MultirotorParams(mass=1.0, inertia=[[1.0, 0.5, 0], [0, 1.0, 0], [0, 0, 1.0]])
    with pytest.raises(ValueError, match="3x3"):
        MultirotorParams(mass=1.0, inertia=np.eye(2))
    with pytest.raises(ValueError, match="hover_thrust"):
        MultirotorParams(mass=1.0, inertia=np.eye(3), hover_thrust=1.5)
    with pytest.raises(ValueError, match="drag"):
        MultirotorParams(mass=1.0, inertia=np.eye(3), drag=-0.1)
    p = MultirotorParams(mass=2, inertia=[1, 2, 3])
    assert p.inertia == ((1.0, 0.0, 0.0), (0.0, 2.0, 0.0), (0.0, 0.0, 3.0))
    assert p.hover_thrust_n == pytest.approx(2 * G)
    hash(p)  # frozen and hashable


def test_symbolic_functions_are_named_and_nan_free_at_singularities() -> None:
    fs = symbolic()
    f, g = fs.multirotor, fs.rover
    assert f.name() == "multirotor_setpoint" and g.name() == "rover_setpoint"
    assert f.name_in() == [
        "vel_ned",
        "acc_ned",
        "jerk_ned",
        "snap_ned",
        "yaw",
        "yaw_rate",
        "yaw_acc",
        "mass",
        "inertia",
        "g",
        "hover_thrust",
        "drag",
    ]
    assert f.name_out() == [
        "thrust",
        "thrust_dot",
        "thrust_ddot",
        "thrust_norm",
        "q_wxyz",
        "C_eb",
        "omega_frd",
        "omega_dot_frd",
        "moment_frd",
        "singular",
        "flags",
    ]
    assert g.name_in() == ["vel_xy", "acc_xy", "jerk_xy", "wheel_base"]
    assert g.name_out() == ["yaw", "speed", "speed_dot", "yaw_rate", "yaw_acc", "singular",
                            "curvature", "curvature_rate", "steer_angle", "steer_rate"]
    assert f.is_a("SXFunction") and g.is_a("SXFunction")
    assert f.size_in("inertia") == (3, 3) and f.size_out("C_eb") == (3, 3)
    assert set(fs.as_dict()) == {"multirotor_setpoint", "rover_setpoint"}
    J = np.diag([0.01, 0.01, 0.02])
    for acc in ([0.0, 0.0, G], [0.0, -4.0, G], [0.0, 0.0, 3 * G], [-5.0, 0.0, G]):
        out = f(
            vel_ned=Z3,
            acc_ned=acc,
            jerk_ned=[0.1, 0.2, 0.3],
            snap_ned=[1, 1, 1],
            yaw=0.0,
            yaw_rate=0.3,
            yaw_acc=0.1,
            mass=1.0,
            inertia=J,
            g=G,
            hover_thrust=0.5,
            drag=0.0,
        )
        for k, v in out.items():
            assert np.all(np.isfinite(np.asarray(v))), (acc, k)
        assert float(out["singular"]) == 1.0
    out = g(vel_xy=[0, 0], acc_xy=[0, 0], jerk_xy=[0, 0])
    assert all(np.isfinite(float(v)) for v in out.values())
    out = g(vel_xy=[0, 0], acc_xy=[0, 1], jerk_xy=[1, 0], wheel_base=0.5)
    assert all(float(v) == 0.0 for k, v in out.items() if k not in ("yaw", "singular"))
    # symbolic inputs accepted (composable in larger CasADi graphs, e.g. a controller)
    x = ca.MX.sym("x", 3)
    res = f(x, Z3, Z3, Z3, 0, 0, 0, 1.0, J, G, 0.5, 1.0)
    jac = ca.Function("j", [x], [ca.jacobian(res[0], x)])
    # d|t|/dv at hover with drag 1: t = m g e3 - D v -> dT/dv = -D e3
    np.testing.assert_allclose(np.asarray(jac(Z3)).ravel(), [0.0, 0.0, -1.0], atol=1e-15)


def test_large_batch_spanning_chunks_matches_small_batches() -> None:
    rng = np.random.default_rng(11)
    n = 20_000  # several internal chunks
    args = [rng.normal(size=(n, 3)) * sc for sc in (3.0, 5.0, 5.0, 10.0)]
    args[1][n // 2] = [0.0, 0.0, G]  # one free-fall sample in the middle
    yaw, yr, ya = rng.normal(size=(3, n))
    big = multirotor_setpoint(*args, yaw, yr, ya, P)
    for lo in (0, 8191, 8192, n // 2 - 3, n - 700):
        hi = lo + 600
        small = multirotor_setpoint(*(x[lo:hi] for x in args), yaw[lo:hi], yr[lo:hi], ya[lo:hi], P)
        for key in (
            "thrust",
            "thrust_dot",
            "thrust_ddot",
            "thrust_norm",
            "q_wxyz",
            "C_eb",
            "omega_frd",
            "omega_dot_frd",
            "moment_frd",
            "flags",
            "singular",
        ):
            np.testing.assert_array_equal(getattr(big, key)[lo:hi], getattr(small, key), key)
    assert np.flatnonzero(big.flags & FLAG_LOW_THRUST).tolist() == [n // 2]
    bad = args[2].copy()
    bad[-1, 1] = np.inf
    with pytest.raises(ValueError, match="jerk contains NaN, inf"):
        multirotor_setpoint(args[0], args[1], bad, args[3], yaw, yr, ya, P)
