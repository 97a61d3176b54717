"""Hypothesis round trips of companion.geometry at random and edge angles (to 1e-12)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from companion import geometry as geo

EDGES = [0.0, np.pi, -np.pi, np.pi / 2, -np.pi / 2, 1e-13, -1e-13, np.pi - 1e-12, 1e-7]
angle = st.one_of(st.sampled_from(EDGES), st.floats(-np.pi, np.pi, allow_nan=False))
pitch = st.one_of(
    st.sampled_from([0.0, np.pi / 2, -np.pi / 2, np.pi / 2 - 1e-10, 1e-13]),
    st.floats(-np.pi / 2, np.pi / 2, allow_nan=False),
)
unit_axis = st.tuples(
    st.floats(-1, 1, allow_nan=False),
    st.floats(-1, 1, allow_nan=False),
    st.floats(-1, 1, allow_nan=False),
).filter(lambda v: np.linalg.norm(v) > 1e-3)
rot_angle = st.one_of(
    st.sampled_from([0.0, 1e-15, 1e-10, 1e-6, np.pi, np.pi - 1e-10]),
    st.floats(0.0, np.pi, allow_nan=False),
)
SETTINGS = settings(max_examples=150, deadline=None)


def _orthonormal(C: np.ndarray) -> None:
    np.testing.assert_allclose(C @ C.T, np.eye(3), atol=1e-13)
    assert abs(np.linalg.det(C) - 1.0) < 1e-13


@SETTINGS
@given(angle, pitch, angle)
def test_euler_dcm_quat_round_trips(psi: float, theta: float, phi: float) -> None:
    C = geo.euler321_to_dcm(psi, theta, phi)
    _orthonormal(C)
    # matrix oracle (scipy) and matrix round trips: compare matrices (gimbal lock safe)
    np.testing.assert_allclose(
        C, Rotation.from_euler("ZYX", [psi, theta, phi]).as_matrix(), atol=1e-13
    )
    np.testing.assert_allclose(geo.euler321_to_dcm(*geo.dcm_to_euler321(C)), C, atol=1e-12)
    q = geo.dcm_to_quat(C)
    assert abs(np.linalg.norm(q) - 1.0) < 1e-15 and q[0] >= 0.0
    np.testing.assert_allclose(geo.quat_to_dcm(q), C, atol=1e-12)
    q_ref = Rotation.from_matrix(C).as_quat(scalar_first=True)
    assert min(np.abs(q - q_ref).max(), np.abs(q + q_ref).max()) < 1e-12
    q2 = geo.dcm_to_quat(geo.quat_to_dcm(q))
    assert min(np.abs(q - q2).max(), np.abs(q + q2).max()) < 1e-12
    np.testing.assert_allclose(geo.euler321_to_dcm(*geo.quat_to_euler321(q)), C, atol=1e-12)
    # away from gimbal lock the angles themselves come back
    if abs(abs(theta) - np.pi / 2) > 1e-3:
        p2, t2, f2 = geo.dcm_to_euler321(C)
        assert abs(np.sin(t2 - theta)) < 1e-12 and abs(t2 - theta) < 1e-12
        assert abs(np.sin(p2 - psi)) < 1e-11 and np.cos(p2 - psi) > 0
        assert abs(np.sin(f2 - phi)) < 1e-11 and np.cos(f2 - phi) > 0


@SETTINGS
@given(unit_axis, rot_angle)
def test_exp_log_round_trips(axis: tuple[float, float, float], ang: float) -> None:
    a = np.asarray(axis) / np.linalg.norm(axis)
    rv = a * ang
    C = geo.so3_exp(rv)
    _orthonormal(C)
    np.testing.assert_allclose(C, Rotation.from_rotvec(rv).as_matrix(), atol=1e-13)
    np.testing.assert_allclose(geo.so3_exp(geo.so3_log(C)), C, atol=1e-12)
    lg = geo.so3_log(C)
    assert np.linalg.norm(lg) <= np.pi + 1e-12
    if ang < np.pi - 1e-6:
        np.testing.assert_allclose(lg, rv, atol=1e-12)
    q = geo.quat_exp(rv)
    np.testing.assert_allclose(geo.quat_to_dcm(q), C, atol=1e-13)
    q2 = geo.quat_exp(geo.quat_log(q))  # at angle pi, q and -q are the same rotation
    assert min(np.abs(q2 - q).max(), np.abs(q2 + q).max()) < 1e-12
    # exp is a homomorphism along one axis: exp(s v) exp(t v) = exp((s + t) v)
    q_half = geo.quat_exp(0.5 * rv)
    np.testing.assert_allclose(geo.quat_to_dcm(geo.quat_multiply(q_half, q_half)), C, atol=1e-12)


@SETTINGS
@given(angle, pitch, angle, angle, pitch, angle)
def test_product_inverse_and_rotate(
    p1: float, t1: float, f1: float, p2: float, t2: float, f2: float
) -> None:
    q1 = geo.euler321_to_quat(p1, t1, f1)
    q2 = geo.euler321_to_quat(p2, t2, f2)
    C1, C2 = geo.quat_to_dcm(q1), geo.quat_to_dcm(q2)
    np.testing.assert_allclose(geo.quat_to_dcm(geo.quat_multiply(q1, q2)), C1 @ C2, atol=1e-13)
    np.testing.assert_allclose(geo.quat_to_dcm(geo.quat_inverse(q1)), C1.T, atol=1e-13)
    v = np.array([0.3, -1.2, 2.0])
    np.testing.assert_allclose(geo.quat_rotate(q1, v), C1 @ v, atol=1e-13)
    # log of the relative rotation is a vector whose exp maps C1 to C2
    rel = geo.so3_log(C1.T @ C2)
    np.testing.assert_allclose(C1 @ geo.so3_exp(rel), C2, atol=1e-12)
