"""SO(3) and frame helpers: quaternions, direction cosine matrices, Euler 3-2-1, exp/log.

Conventions (the project contract, see docs/theory/geometry.md):

* ``C_eb`` (3x3) maps body FRD components to world NED components, ``v_e = C_eb @ v_b``; its
  columns are the body axes in world components.
* Quaternions are Hamilton, scalar first ``(w, x, y, z)``, and represent the same rotation as
  ``C_eb``. Every function returning a quaternion returns a unit quaternion with ``w >= 0``.
* Euler angles are body 3-2-1: ``C_eb = Rz(psi) @ Ry(theta) @ Rx(phi)`` with yaw ``psi``, pitch
  ``theta`` and roll ``phi`` in radians.
* Rotation vectors (the Lie-algebra coordinates used by ``so3_exp``/``so3_log`` and
  ``quat_exp``/``quat_log``) are axis times angle in radians, angle in ``[0, pi]``.

Every function accepts a single element (``(4,)`` quaternion, ``(3, 3)`` matrix, ``(3,)`` vector,
scalar angle) or a batch with any leading shape (``(N, 4)``, ``(N, 3, 3)``, ...) and returns the
same leading shape. All are NaN-free at the edges (angle 0, angle pi, gimbal lock).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

__all__ = [
    "dcm_enu_flu_to_ned_frd",
    "dcm_ned_frd_to_enu_flu",
    "dcm_to_euler321",
    "dcm_to_quat",
    "dcm_to_quat_f",
    "euler321_to_dcm",
    "euler321_to_quat",
    "hat",
    "quat_conjugate",
    "quat_enu_flu_to_ned_frd",
    "quat_exp",
    "quat_inverse",
    "quat_log",
    "quat_multiply",
    "quat_ned_frd_to_enu_flu",
    "quat_normalize",
    "quat_rotate",
    "quat_to_dcm",
    "quat_to_euler321",
    "rot2",
    "se2_compose",
    "se2_inverse",
    "so3_exp",
    "so3_log",
    "vec_enu_to_ned",
    "vec_ned_to_enu",
    "vee",
    "wrap_pi",
]

FloatArray = npt.NDArray[np.float64]
ArrayLike = npt.ArrayLike

# Below this rotation angle (rad) exp/log use the Taylor expansion of sin(x)/x.
_SMALL_ANGLE = 1e-6


def _as_float(x: ArrayLike) -> FloatArray:
    return np.asarray(x, dtype=np.float64)


def _check_last(x: FloatArray, n: int, what: str) -> None:
    if x.ndim == 0 or x.shape[-1] != n:
        raise ValueError(f"{what} must have shape (..., {n}), got {x.shape}")


def _check_mat(C: FloatArray) -> None:
    if C.ndim < 2 or C.shape[-2:] != (3, 3):
        raise ValueError(f"rotation matrix must have shape (..., 3, 3), got {C.shape}")


# ----------------------------------------------------------------------------- skew matrices


def hat(v: ArrayLike) -> FloatArray:
    """Skew-symmetric matrix of ``v`` (..., 3) -> (..., 3, 3), ``hat(v) @ w == cross(v, w)``."""
    a = _as_float(v)
    _check_last(a, 3, "vector")
    out = np.zeros((*a.shape[:-1], 3, 3))
    x, y, z = a[..., 0], a[..., 1], a[..., 2]
    out[..., 0, 1] = -z
    out[..., 0, 2] = y
    out[..., 1, 0] = z
    out[..., 1, 2] = -x
    out[..., 2, 0] = -y
    out[..., 2, 1] = x
    return out


def vee(M: ArrayLike) -> FloatArray:
    """Inverse of :func:`hat`: (..., 3, 3) -> (..., 3), using the antisymmetric part of ``M``."""
    a = _as_float(M)
    _check_mat(a)
    return 0.5 * np.stack(
        [a[..., 2, 1] - a[..., 1, 2], a[..., 0, 2] - a[..., 2, 0], a[..., 1, 0] - a[..., 0, 1]],
        axis=-1,
    )


# ----------------------------------------------------------------------------- quaternions


def _positive_w(q: FloatArray) -> FloatArray:
    sign = np.where(q[..., :1] < 0.0, -1.0, 1.0)
    return q * sign


def quat_normalize(q: ArrayLike) -> FloatArray:
    """Unit quaternion (w >= 0) from any non-zero ``q`` (..., 4); zero input gives identity."""
    a = _as_float(q)
    _check_last(a, 4, "quaternion")
    n = np.linalg.norm(a, axis=-1, keepdims=True)
    ok = n > 0.0
    out = np.where(ok, a / np.where(ok, n, 1.0), np.array([1.0, 0.0, 0.0, 0.0]))
    return _positive_w(out)


def quat_conjugate(q: ArrayLike) -> FloatArray:
    """Conjugate ``(w, -x, -y, -z)`` of ``q`` (..., 4) (the inverse for unit quaternions)."""
    a = _as_float(q)
    _check_last(a, 4, "quaternion")
    return _as_float(a * np.array([1.0, -1.0, -1.0, -1.0]))


def quat_inverse(q: ArrayLike) -> FloatArray:
    """Inverse ``q^-1 = conj(q) / |q|^2`` of a non-zero quaternion (..., 4)."""
    a = _as_float(q)
    _check_last(a, 4, "quaternion")
    n2 = np.sum(a * a, axis=-1, keepdims=True)
    if np.any(n2 == 0.0):
        raise ValueError("cannot invert a zero quaternion")
    return _as_float(quat_conjugate(a) / n2)


def quat_multiply(q1: ArrayLike, q2: ArrayLike) -> FloatArray:
    """Hamilton product ``q1 * q2`` (..., 4); as rotations: apply ``q2`` first, then ``q1``.

    Not renormalised and the sign is kept (so that ``q * q^-1 = (1, 0, 0, 0)`` exactly).
    """
    a = _as_float(q1)
    b = _as_float(q2)
    _check_last(a, 4, "quaternion")
    _check_last(b, 4, "quaternion")
    w1, x1, y1, z1 = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    w2, x2, y2, z2 = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return np.stack(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ],
        axis=-1,
    )


def quat_rotate(q: ArrayLike, v: ArrayLike) -> FloatArray:
    """Rotate vector(s) ``v`` (..., 3) by unit quaternion(s) ``q`` (..., 4): ``C(q) @ v``.

    With ``q = q_eb`` this maps body components to world components.
    """
    a = _as_float(q)
    b = _as_float(v)
    _check_last(a, 4, "quaternion")
    _check_last(b, 3, "vector")
    w = a[..., :1]
    u = a[..., 1:]
    t = 2.0 * np.cross(u, b)
    return _as_float(b + w * t + np.cross(u, t))


def quat_to_dcm(q: ArrayLike) -> FloatArray:
    """DCM ``C_eb`` (..., 3, 3) of quaternion(s) (..., 4); the quaternion is normalised first."""
    a = quat_normalize(q)
    w, x, y, z = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    C = np.empty((*a.shape[:-1], 3, 3))
    C[..., 0, 0] = 1.0 - 2.0 * (y * y + z * z)
    C[..., 0, 1] = 2.0 * (x * y - w * z)
    C[..., 0, 2] = 2.0 * (x * z + w * y)
    C[..., 1, 0] = 2.0 * (x * y + w * z)
    C[..., 1, 1] = 1.0 - 2.0 * (x * x + z * z)
    C[..., 1, 2] = 2.0 * (y * z - w * x)
    C[..., 2, 0] = 2.0 * (x * z - w * y)
    C[..., 2, 1] = 2.0 * (y * z + w * x)
    C[..., 2, 2] = 1.0 - 2.0 * (x * x + y * y)
    return C


def dcm_to_quat(C: ArrayLike) -> FloatArray:
    """Unit quaternion (w >= 0) of rotation matrix/matrices ``C`` (..., 3, 3).

    Shepperd's method: the largest of ``4w^2, 4x^2, 4y^2, 4z^2`` picks the branch, so the result
    is accurate everywhere including rotations by pi.
    """
    M = _as_float(C)
    _check_mat(M)
    if M.shape == (3, 3):
        q1 = _dcm_to_quat_single(M)
        if q1 is not None:
            return q1
    m00, m01, m02 = M[..., 0, 0], M[..., 0, 1], M[..., 0, 2]
    m10, m11, m12 = M[..., 1, 0], M[..., 1, 1], M[..., 1, 2]
    m20, m21, m22 = M[..., 2, 0], M[..., 2, 1], M[..., 2, 2]
    tr = m00 + m11 + m22
    # 4 * (w^2, x^2, y^2, z^2) - 1 up to a common offset: pick the largest.
    cand = np.stack([tr, m00, m11, m22], axis=-1)
    k = np.argmax(cand, axis=-1)
    qs = np.empty((*M.shape[:-2], 4, 4))
    # Branch w: s = 4w
    s0 = 2.0 * np.sqrt(np.maximum(1.0 + tr, 1e-300))
    qs[..., 0, :] = np.stack([0.25 * s0, (m21 - m12) / s0, (m02 - m20) / s0, (m10 - m01) / s0], -1)
    s1 = 2.0 * np.sqrt(np.maximum(1.0 + m00 - m11 - m22, 1e-300))
    qs[..., 1, :] = np.stack([(m21 - m12) / s1, 0.25 * s1, (m01 + m10) / s1, (m02 + m20) / s1], -1)
    s2 = 2.0 * np.sqrt(np.maximum(1.0 - m00 + m11 - m22, 1e-300))
    qs[..., 2, :] = np.stack([(m02 - m20) / s2, (m01 + m10) / s2, 0.25 * s2, (m12 + m21) / s2], -1)
    s3 = 2.0 * np.sqrt(np.maximum(1.0 - m00 - m11 + m22, 1e-300))
    qs[..., 3, :] = np.stack([(m10 - m01) / s3, (m02 + m20) / s3, (m12 + m21) / s3, 0.25 * s3], -1)
    q = np.take_along_axis(qs, k[..., None, None], axis=-2)[..., 0, :]
    return quat_normalize(q)


def _dcm_to_quat_single(M: FloatArray) -> FloatArray | None:
    """`dcm_to_quat` of one (3, 3) array through `dcm_to_quat_f`; None if it is not finite."""
    q = dcm_to_quat_f(M.tolist())
    return None if q is None else np.array(q)


def dcm_to_quat_f(
    M: Sequence[Sequence[float]],
) -> tuple[float, float, float, float] | None:
    """`dcm_to_quat` of one finite 3x3 matrix given as rows of floats: the same branch (the first
    largest candidate, as argmax), the same operations in the same order, numpy's sum of squares
    order for the norm (sequential over w, x, y, z) and the same w >= 0 sign, so the same bits,
    ~10x faster (the rates-mode controller calls it every setpoint). None for a non-finite
    matrix (the array path handles it)."""
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = M
    isfinite = math.isfinite
    if not (isfinite(m00) and isfinite(m01) and isfinite(m02) and isfinite(m10)
            and isfinite(m11) and isfinite(m12) and isfinite(m20) and isfinite(m21)
            and isfinite(m22)):
        return None
    tr = m00 + m11 + m22
    k, best = 0, tr
    if m00 > best:
        k, best = 1, m00
    if m11 > best:
        k, best = 2, m11
    if m22 > best:
        k = 3
    if k == 0:
        s = 2.0 * math.sqrt(max(1.0 + tr, 1e-300))
        w, x, y, z = 0.25 * s, (m21 - m12) / s, (m02 - m20) / s, (m10 - m01) / s
    elif k == 1:
        s = 2.0 * math.sqrt(max(1.0 + m00 - m11 - m22, 1e-300))
        w, x, y, z = (m21 - m12) / s, 0.25 * s, (m01 + m10) / s, (m02 + m20) / s
    elif k == 2:
        s = 2.0 * math.sqrt(max(1.0 - m00 + m11 - m22, 1e-300))
        w, x, y, z = (m02 - m20) / s, (m01 + m10) / s, 0.25 * s, (m12 + m21) / s
    else:
        s = 2.0 * math.sqrt(max(1.0 - m00 - m11 + m22, 1e-300))
        w, x, y, z = (m10 - m01) / s, (m02 + m20) / s, (m12 + m21) / s, 0.25 * s
    n = math.sqrt(w * w + x * x + y * y + z * z)  # > 0: one component is >= 0.25 s > 0
    w, x, y, z = w / n, x / n, y / n, z / n
    if w < 0.0:
        w, x, y, z = w * -1.0, x * -1.0, y * -1.0, z * -1.0
    return (w, x, y, z)


def quat_exp(rotvec: ArrayLike) -> FloatArray:
    """Unit quaternion (w >= 0) of rotation vector(s) (..., 3) (axis * angle, rad)."""
    v = _as_float(rotvec)
    _check_last(v, 3, "rotation vector")
    theta = np.linalg.norm(v, axis=-1, keepdims=True)
    # sin(theta/2)/theta = 0.5 * sinc(theta / (2 pi)), numpy's sinc is exact at 0.
    k = 0.5 * np.sinc(theta / (2.0 * np.pi))
    q = np.concatenate([np.cos(0.5 * theta), k * v], axis=-1)
    return quat_normalize(q)


def quat_log(q: ArrayLike) -> FloatArray:
    """Rotation vector (..., 3), angle in [0, pi], of quaternion(s) (..., 4) (normalised first).

    ``q`` and ``-q`` give the same result (the shortest rotation).
    """
    a = quat_normalize(q)  # also makes w >= 0
    w = a[..., :1]
    u = a[..., 1:]
    s = np.linalg.norm(u, axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(s, w)  # in [0, pi]
    small = s < _SMALL_ANGLE
    # angle / s = 2 atan2(s, w) / s -> 2 / w (1 - s^2/(3 w^2)) for small s (w ~ 1 there)
    # both branches are evaluated: keep each one's divisor away from 0 where it is not used
    safe_s = np.where(small, 1.0, s)
    safe_w = np.where(small, w, 1.0)  # w = 0 at a half turn (s = 1, not small)
    ratio = np.where(small, 2.0 / safe_w * (1.0 - s * s / (3.0 * safe_w * safe_w)),
                     angle / safe_s)
    return _as_float(ratio * u)


# ----------------------------------------------------------------------------- SO(3) exp / log


def so3_exp(rotvec: ArrayLike) -> FloatArray:
    """Rotation matrix (..., 3, 3) ``expm(hat(rotvec))`` of rotation vector(s) (..., 3)."""
    return quat_to_dcm(quat_exp(rotvec))


def so3_log(C: ArrayLike) -> FloatArray:
    """Rotation vector (..., 3) with angle in [0, pi] such that ``so3_exp(so3_log(C)) == C``."""
    return quat_log(dcm_to_quat(C))


# ----------------------------------------------------------------------------- Euler 3-2-1


def euler321_to_dcm(psi: ArrayLike, theta: ArrayLike, phi: ArrayLike) -> FloatArray:
    """``C_eb = Rz(psi) Ry(theta) Rx(phi)`` (..., 3, 3) from yaw, pitch, roll (rad, broadcast)."""
    ps, th, ph = np.broadcast_arrays(_as_float(psi), _as_float(theta), _as_float(phi))
    cps, sps = np.cos(ps), np.sin(ps)
    cth, sth = np.cos(th), np.sin(th)
    cph, sph = np.cos(ph), np.sin(ph)
    C = np.empty((*ps.shape, 3, 3))
    C[..., 0, 0] = cps * cth
    C[..., 0, 1] = cps * sth * sph - sps * cph
    C[..., 0, 2] = cps * sth * cph + sps * sph
    C[..., 1, 0] = sps * cth
    C[..., 1, 1] = sps * sth * sph + cps * cph
    C[..., 1, 2] = sps * sth * cph - cps * sph
    C[..., 2, 0] = -sth
    C[..., 2, 1] = cth * sph
    C[..., 2, 2] = cth * cph
    return C


def dcm_to_euler321(C: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(psi, theta, phi) of ``C_eb = Rz(psi) Ry(theta) Rx(phi)``; psi, phi in (-pi, pi].

    theta is in [-pi/2, pi/2]. At gimbal lock (|theta| = pi/2) only psi -/+ phi is defined:
    phi is set to 0 and psi carries the whole rotation about the vertical.
    """
    M = _as_float(C)
    _check_mat(M)
    # Yaw from the first column; at (or within 1e-13 rad of) gimbal lock from the second column
    # with phi = 0. Pitch and roll are then computed from Rz(psi)^T C, which keeps the
    # reconstruction exact to rounding even arbitrarily close to the lock.
    c_th = np.hypot(M[..., 0, 0], M[..., 1, 0])
    lock = c_th < 1e-13
    psi = np.where(
        lock, np.arctan2(-M[..., 0, 1], M[..., 1, 1]), np.arctan2(M[..., 1, 0], M[..., 0, 0])
    )
    cps, sps = np.cos(psi), np.sin(psi)
    theta = np.arctan2(-M[..., 2, 0], cps * M[..., 0, 0] + sps * M[..., 1, 0])
    phi = np.arctan2(
        sps * M[..., 0, 2] - cps * M[..., 1, 2], cps * M[..., 1, 1] - sps * M[..., 0, 1]
    )
    return psi, theta, phi


def euler321_to_quat(psi: ArrayLike, theta: ArrayLike, phi: ArrayLike) -> FloatArray:
    """Unit quaternion (w >= 0) (..., 4) of the 3-2-1 Euler angles (rad)."""
    return dcm_to_quat(euler321_to_dcm(psi, theta, phi))


def quat_to_euler321(q: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(psi, theta, phi) of quaternion(s) (..., 4), same conventions as :func:`dcm_to_euler321`."""
    return dcm_to_euler321(quat_to_dcm(q))


# ----------------------------------------------------------------------------- frames

# Permutation NED <-> ENU (its own inverse) and FRD <-> FLU (its own inverse).
_P_NED_ENU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
_P_FRD_FLU = np.diag([1.0, -1.0, -1.0])


def vec_ned_to_enu(v_ned: ArrayLike) -> FloatArray:
    """World vector(s) NED (..., 3) -> ENU (..., 3): ``(e, n, -d)``."""
    a = _as_float(v_ned)
    _check_last(a, 3, "vector")
    return _as_float(a @ _P_NED_ENU.T)


def vec_enu_to_ned(v_enu: ArrayLike) -> FloatArray:
    """World vector(s) ENU (..., 3) -> NED (..., 3): ``(n, e, -u)``."""
    return vec_ned_to_enu(v_enu)


def dcm_ned_frd_to_enu_flu(C_ned_frd: ArrayLike) -> FloatArray:
    """Attitude FRD->NED (PX4/MAVLink) -> FLU->ENU (ROS REP-103), (..., 3, 3)."""
    M = _as_float(C_ned_frd)
    _check_mat(M)
    return _as_float(_P_NED_ENU @ M @ _P_FRD_FLU)


def dcm_enu_flu_to_ned_frd(C_enu_flu: ArrayLike) -> FloatArray:
    """Attitude FLU->ENU (ROS) -> FRD->NED (PX4/MAVLink), (..., 3, 3)."""
    return dcm_ned_frd_to_enu_flu(C_enu_flu)


def quat_ned_frd_to_enu_flu(q_ned_frd: ArrayLike) -> FloatArray:
    """Quaternion FRD->NED (PX4/MAVLink) -> FLU->ENU (ROS), (..., 4), w >= 0."""
    return dcm_to_quat(dcm_ned_frd_to_enu_flu(quat_to_dcm(q_ned_frd)))


def quat_enu_flu_to_ned_frd(q_enu_flu: ArrayLike) -> FloatArray:
    """Quaternion FLU->ENU (ROS) -> FRD->NED (PX4/MAVLink), (..., 4), w >= 0."""
    return quat_ned_frd_to_enu_flu(q_enu_flu)


# ----------------------------------------------------------------------------- planar (rover)


def wrap_pi(angle: ArrayLike) -> FloatArray:
    """Angle(s) wrapped to [-pi, pi) (rad)."""
    a = _as_float(angle)
    return _as_float((a + np.pi) % (2.0 * np.pi) - np.pi)


def rot2(yaw: ArrayLike) -> FloatArray:
    """2-D rotation matrix/matrices (..., 2, 2) of yaw (rad), body -> world (x north, y east)."""
    a = _as_float(yaw)
    c, s = np.cos(a), np.sin(a)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def se2_compose(a: ArrayLike, b: ArrayLike) -> FloatArray:
    """Compose planar poses ``(x, y, yaw)`` (..., 3): ``a * b`` (``b`` expressed in ``a``)."""
    A = _as_float(a)
    B = _as_float(b)
    _check_last(A, 3, "SE(2) pose")
    _check_last(B, 3, "SE(2) pose")
    c, s = np.cos(A[..., 2]), np.sin(A[..., 2])
    x = A[..., 0] + c * B[..., 0] - s * B[..., 1]
    y = A[..., 1] + s * B[..., 0] + c * B[..., 1]
    return np.stack([x, y, wrap_pi(A[..., 2] + B[..., 2])], axis=-1)


def se2_inverse(a: ArrayLike) -> FloatArray:
    """Inverse planar pose(s) (..., 3) such that ``se2_compose(a, se2_inverse(a)) == 0``."""
    A = _as_float(a)
    _check_last(A, 3, "SE(2) pose")
    c, s = np.cos(A[..., 2]), np.sin(A[..., 2])
    x = -(c * A[..., 0] + s * A[..., 1])
    y = s * A[..., 0] - c * A[..., 1]
    return np.stack([x, y, wrap_pi(-A[..., 2])], axis=-1)
