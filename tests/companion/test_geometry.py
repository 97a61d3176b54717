"""companion.geometry against scipy.spatial.transform.Rotation (an independent implementation)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from companion import geometry as geo

RNG = np.random.default_rng(12345)
N = 200


def _scipy_quat_wxyz(r: Rotation) -> np.ndarray:
    return np.asarray(r.as_quat(scalar_first=True))


def _same_up_to_sign(q1: np.ndarray, q2: np.ndarray, tol: float = 1e-12) -> bool:
    d = np.minimum(np.abs(q1 - q2).max(axis=-1), np.abs(q1 + q2).max(axis=-1))
    return bool(np.all(d <= tol))


def _random_euler(n: int) -> np.ndarray:
    psi = RNG.uniform(-np.pi, np.pi, n)
    theta = RNG.uniform(-np.pi / 2, np.pi / 2, n)
    phi = RNG.uniform(-np.pi, np.pi, n)
    return np.stack([psi, theta, phi], axis=-1)


EDGE_EULER = np.array(
    [
        [0.0, 0.0, 0.0],
        [np.pi, 0.0, 0.0],
        [0.0, 0.0, np.pi],
        [0.0, np.pi / 2, 0.0],
        [0.3, np.pi / 2, -0.7],
        [-2.0, -np.pi / 2, 1.1],
        [np.pi / 2, 0.0, 0.0],
        [1e-12, -1e-12, 1e-12],
        [np.pi, np.pi / 2 - 1e-9, np.pi],
    ]
)


# ----------------------------------------------------------------------------- absolute oracles


def test_euler321_matches_scipy_intrinsic_zyx() -> None:
    e = np.concatenate([_random_euler(N), EDGE_EULER])
    C = geo.euler321_to_dcm(e[:, 0], e[:, 1], e[:, 2])
    C_ref = Rotation.from_euler("ZYX", e).as_matrix()
    np.testing.assert_allclose(C, C_ref, atol=1e-14)


def test_euler321_quat_matches_scipy_up_to_sign() -> None:
    e = np.concatenate([_random_euler(N), EDGE_EULER])
    q = geo.euler321_to_quat(e[:, 0], e[:, 1], e[:, 2])
    assert _same_up_to_sign(q, _scipy_quat_wxyz(Rotation.from_euler("ZYX", e)))
    assert np.all(q[:, 0] >= 0.0)


def test_yaw_plus_90_maps_body_x_to_east() -> None:
    C = geo.euler321_to_dcm(np.pi / 2, 0.0, 0.0)
    np.testing.assert_allclose(C @ np.array([1.0, 0.0, 0.0]), [0.0, 1.0, 0.0], atol=1e-15)
    q = geo.euler321_to_quat(np.pi / 2, 0.0, 0.0)
    np.testing.assert_allclose(geo.quat_rotate(q, [1.0, 0.0, 0.0]), [0.0, 1.0, 0.0], atol=1e-15)
    # and a 3-2-1 pitch up (theta > 0) raises the nose: body x gets a negative Down component
    C = geo.euler321_to_dcm(0.0, 0.2, 0.0)
    assert (C @ np.array([1.0, 0.0, 0.0]))[2] < 0.0
    # third row of C_eb (docs/theory/geometry.md: the manual's erratum)
    psi, th, ph = 0.4, -0.3, 1.2
    row = np.array([-np.sin(th), np.sin(ph) * np.cos(th), np.cos(ph) * np.cos(th)])
    np.testing.assert_allclose(geo.euler321_to_dcm(psi, th, ph)[2], row, atol=1e-15)


def test_quat_to_dcm_and_back_match_scipy() -> None:
    r = Rotation.random(N, random_state=1)
    q = _scipy_quat_wxyz(r)
    np.testing.assert_allclose(geo.quat_to_dcm(q), r.as_matrix(), atol=1e-14)
    q2 = geo.dcm_to_quat(r.as_matrix())
    assert _same_up_to_sign(q2, q)
    assert np.all(q2[:, 0] >= 0.0)


def test_quat_multiply_is_rotation_composition() -> None:
    r1 = Rotation.random(N, random_state=2)
    r2 = Rotation.random(N, random_state=3)
    q = geo.quat_multiply(_scipy_quat_wxyz(r1), _scipy_quat_wxyz(r2))
    assert _same_up_to_sign(q, _scipy_quat_wxyz(r1 * r2))


def test_quat_rotate_matches_scipy_apply() -> None:
    r = Rotation.random(N, random_state=4)
    v = RNG.normal(size=(N, 3))
    np.testing.assert_allclose(geo.quat_rotate(_scipy_quat_wxyz(r), v), r.apply(v), atol=1e-13)


def test_quat_inverse_and_conjugate() -> None:
    q = RNG.normal(size=(N, 4))  # not unit on purpose
    ident = geo.quat_multiply(q, geo.quat_inverse(q))
    np.testing.assert_allclose(ident, np.tile([1.0, 0.0, 0.0, 0.0], (N, 1)), atol=1e-14)
    qu = geo.quat_normalize(q)
    np.testing.assert_allclose(geo.quat_conjugate(qu), geo.quat_inverse(qu), atol=1e-15)
    with pytest.raises(ValueError, match="zero quaternion"):
        geo.quat_inverse([0.0, 0.0, 0.0, 0.0])


def test_quat_normalize_unit_positive_w_and_zero() -> None:
    q = geo.quat_normalize(RNG.normal(size=(N, 4)))
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-15)
    assert np.all(q[:, 0] >= 0.0)
    np.testing.assert_array_equal(geo.quat_normalize([0.0, 0.0, 0.0, 0.0]), [1.0, 0, 0, 0])


def test_so3_exp_log_match_scipy_rotvec() -> None:
    r = Rotation.random(N, random_state=5)
    rv = r.as_rotvec()  # angle in [0, pi]
    np.testing.assert_allclose(geo.so3_exp(rv), r.as_matrix(), atol=1e-14)
    np.testing.assert_allclose(geo.so3_log(r.as_matrix()), rv, atol=1e-12)
    np.testing.assert_allclose(geo.quat_log(geo.quat_exp(rv)), rv, atol=1e-12)
    np.testing.assert_allclose(geo.quat_to_dcm(geo.quat_exp(rv)), r.as_matrix(), atol=1e-14)


@pytest.mark.parametrize(
    "angle", [0.0, 1e-14, 1e-9, 1e-7, 1e-6, 1e-5, 1e-3, 1.0, np.pi - 1e-9, np.pi]
)
def test_exp_log_edges_against_scipy(angle: float) -> None:
    axes = RNG.normal(size=(20, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    rv = axes * angle
    C = geo.so3_exp(rv)
    assert np.all(np.isfinite(C))
    np.testing.assert_allclose(C, Rotation.from_rotvec(rv).as_matrix(), atol=1e-14)
    log = geo.so3_log(C)
    assert np.all(np.isfinite(log))
    if angle < np.pi - 1e-6:
        np.testing.assert_allclose(log, rv, atol=1e-12, rtol=1e-12)
    else:  # at pi, axis and -axis are the same rotation
        assert np.all(np.minimum(np.abs(log - rv).max(1), np.abs(log + rv).max(1)) < 1e-7)
    np.testing.assert_allclose(geo.so3_exp(log), C, atol=1e-12)


def test_hat_vee() -> None:
    a = RNG.normal(size=(N, 3))
    b = RNG.normal(size=(N, 3))
    np.testing.assert_allclose(np.einsum("nij,nj->ni", geo.hat(a), b), np.cross(a, b), atol=1e-14)
    np.testing.assert_allclose(geo.vee(geo.hat(a)), a, atol=0.0)
    H = geo.hat(a)
    np.testing.assert_allclose(H, -np.swapaxes(H, -1, -2), atol=0.0)


def test_dcm_to_euler321_recovers_angles_and_gimbal_lock() -> None:
    e = _random_euler(N)
    psi, th, ph = geo.dcm_to_euler321(Rotation.from_euler("ZYX", e).as_matrix())
    np.testing.assert_allclose(np.stack([psi, th, ph], -1), e, atol=1e-10)
    # at gimbal lock only the matrix is defined: compare matrices
    for row in EDGE_EULER:
        C = Rotation.from_euler("ZYX", row).as_matrix()
        a = geo.dcm_to_euler321(C)
        assert all(np.isfinite(x) for x in a)
        np.testing.assert_allclose(geo.euler321_to_dcm(*a), C, atol=1e-12)


def test_single_and_batched_shapes() -> None:
    q = geo.euler321_to_quat(0.1, 0.2, 0.3)
    assert q.shape == (4,)
    assert geo.quat_to_dcm(q).shape == (3, 3)
    assert geo.quat_to_dcm(np.tile(q, (5, 2, 1))).shape == (5, 2, 3, 3)
    assert geo.so3_log(np.eye(3)).shape == (3,)
    np.testing.assert_array_equal(geo.so3_log(np.eye(3)), [0.0, 0.0, 0.0])
    psi, th, ph = geo.dcm_to_euler321(np.eye(3))
    assert np.shape(psi) == np.shape(th) == np.shape(ph) == ()
    with pytest.raises(ValueError):
        geo.quat_to_dcm([1.0, 0.0, 0.0])
    with pytest.raises(ValueError):
        geo.dcm_to_quat(np.eye(2))


def test_ned_enu_vectors_and_attitudes() -> None:
    # 1 m north, 2 m east, 3 m down -> ENU (east, north, up) = (2, 1, -3)
    np.testing.assert_array_equal(geo.vec_ned_to_enu([1.0, 2.0, 3.0]), [2.0, 1.0, -3.0])
    v = RNG.normal(size=(N, 3))
    np.testing.assert_array_equal(geo.vec_enu_to_ned(geo.vec_ned_to_enu(v)), v)
    # A vehicle facing east (NED yaw +90 deg) has ROS ENU yaw 0: FLU x along ENU x (east).
    q_ned = geo.euler321_to_quat(np.pi / 2, 0.0, 0.0)
    q_enu = geo.quat_ned_frd_to_enu_flu(q_ned)
    np.testing.assert_allclose(q_enu, [1.0, 0.0, 0.0, 0.0], atol=1e-15)
    # facing north in NED (yaw 0) is ENU yaw +90 deg (scipy as the oracle)
    q_enu = geo.quat_ned_frd_to_enu_flu([1.0, 0.0, 0.0, 0.0])
    ref = _scipy_quat_wxyz(Rotation.from_euler("z", np.pi / 2))
    assert _same_up_to_sign(q_enu[None], ref[None])
    # general: a body vector expressed both ways gives the same physical vector
    r = Rotation.random(N, random_state=7)
    v_frd = RNG.normal(size=(N, 3))
    v_ned = r.apply(v_frd)
    C_enu_flu = geo.dcm_ned_frd_to_enu_flu(r.as_matrix())
    v_flu = v_frd * np.array([1.0, -1.0, -1.0])
    np.testing.assert_allclose(
        np.einsum("nij,nj->ni", C_enu_flu, v_flu), geo.vec_ned_to_enu(v_ned), atol=1e-13
    )
    np.testing.assert_allclose(geo.dcm_enu_flu_to_ned_frd(C_enu_flu), r.as_matrix(), atol=1e-15)
    q_back = geo.quat_enu_flu_to_ned_frd(geo.quat_ned_frd_to_enu_flu(_scipy_quat_wxyz(r)))
    assert _same_up_to_sign(q_back, _scipy_quat_wxyz(r))


def test_se2_and_wrap() -> None:
    a = RNG.normal(size=(N, 3)) * np.array([10.0, 10.0, 3.0])
    b = RNG.normal(size=(N, 3)) * np.array([10.0, 10.0, 3.0])
    ab = geo.se2_compose(a, b)
    # oracle: homogeneous 3x3 matrices

    def mat(p: np.ndarray) -> np.ndarray:
        c, s = np.cos(p[..., 2]), np.sin(p[..., 2])
        M = np.zeros((*p.shape[:-1], 3, 3))
        M[..., 0, 0], M[..., 0, 1], M[..., 0, 2] = c, -s, p[..., 0]
        M[..., 1, 0], M[..., 1, 1], M[..., 1, 2] = s, c, p[..., 1]
        M[..., 2, 2] = 1.0
        return M

    np.testing.assert_allclose(mat(ab), mat(a) @ mat(b), atol=1e-12)
    np.testing.assert_allclose(
        mat(geo.se2_compose(a, geo.se2_inverse(a))),
        np.broadcast_to(np.eye(3), (N, 3, 3)),
        atol=1e-12,
    )
    w = geo.wrap_pi(np.linspace(-20, 20, 101))
    assert np.all((w >= -np.pi) & (w < np.pi))
    np.testing.assert_allclose(np.cos(w), np.cos(np.linspace(-20, 20, 101)), atol=1e-12)
    np.testing.assert_allclose(geo.rot2(0.3) @ [1.0, 0.0], [np.cos(0.3), np.sin(0.3)])


def test_log_of_a_half_turn_is_pi_about_the_axis_without_a_warning() -> None:
    """w = 0 (a rotation by pi): the small-angle branch must not divide by w (pytest turns the
    project's warnings into errors)."""
    import warnings

    from companion.geometry import quat_log

    axis = np.array([0.6, 0.0, 0.8])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        v = quat_log(np.array([0.0, *axis]))
    np.testing.assert_allclose(np.abs(v), np.pi * axis, atol=1e-12)
