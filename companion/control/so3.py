"""Small SO(3) kit of the tracking law on single samples: quaternions (w, x, y, z), DCMs
(C_eb maps body FRD to world NED), the attitude error. Floats and (3,)/(4,) arrays."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]



def all_finite(*arrays: FloatArray) -> bool:
    isfinite = math.isfinite
    return all(all(map(isfinite, a.tolist())) for a in arrays)


def quat_normalize_f(w: float, x: float, y: float, z: float) -> tuple[float, float, float, float]:
    """`quat_normalize` on floats."""
    n = math.hypot(w, x, y, z)
    if not (math.isfinite(n) and n > 1e-12):
        return (1.0, 0.0, 0.0, 0.0)
    if w < 0.0:
        n = -n
    return (w / n, x / n, y / n, z / n)


def quat_integrate_f(
    q: list[float], omega: list[float], dt: float
) -> tuple[float, float, float, float]:
    """`quat_integrate` on floats (same operations, same rounding)."""
    rx, ry, rz = omega[0] * dt, omega[1] * dt, omega[2] * dt
    ang = math.sqrt(rx * rx + ry * ry + rz * rz)
    w1, x1, y1, z1 = q
    if ang < 1e-12:
        return quat_normalize_f(w1, x1, y1, z1)
    k = math.sin(0.5 * ang) / ang
    w2, x2, y2, z2 = math.cos(0.5 * ang), k * rx, k * ry, k * rz
    return quat_normalize_f(
        w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
        w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
        w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
    )


def body_z_down(q: FloatArray) -> float:
    """C_eb[2, 2] of a quaternion, as `quat_to_dcm` computes it (normalised; bad -> 1)."""
    w, x, y, z = q.tolist()
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if not (math.isfinite(n) and n > 0.0):
        return 1.0
    x, y = x / n, y / n
    return float(1 - 2 * (x * x + y * y))


# ----------------------------------------------------------------------------- small SO(3) kit
# Written out for (3,)/(4,) arrays: the controller runs at 100-250 Hz on single samples, where
# the batched geometry helpers' generality costs more than the arithmetic.


def quat_to_dcm(q_wxyz: FloatArray) -> FloatArray:
    """DCM C_eb (3, 3) of a quaternion (w, x, y, z) (normalised first; zero -> identity)."""
    w, x, y, z = (float(c) for c in q_wxyz)
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if not (math.isfinite(n) and n > 0.0):
        return np.eye(3)
    w, x, y, z = w / n, x / n, y / n, z / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def quat_normalize(q_wxyz: FloatArray) -> FloatArray:
    """Unit quaternion with w >= 0; non-finite or zero input gives the identity."""
    w, x, y, z = (float(c) for c in q_wxyz)
    n = math.hypot(w, x, y, z)
    if not (math.isfinite(n) and n > 1e-12):
        return np.array([1.0, 0.0, 0.0, 0.0])
    if w < 0.0:
        n = -n
    return np.array([w / n, x / n, y / n, z / n])


def quat_mul(a: FloatArray, b: FloatArray) -> FloatArray:
    """Hamilton product a * b (apply b first, then a)."""
    w1, x1, y1, z1 = (float(c) for c in a)
    w2, x2, y2, z2 = (float(c) for c in b)
    return np.array(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ]
    )


def quat_integrate(q_wxyz: FloatArray, omega_frd: FloatArray, dt: float) -> FloatArray:
    """Attitude after rotating for `dt` [s] at constant body rate `omega_frd` [rad/s]."""
    rx, ry, rz = (float(c) * dt for c in omega_frd)
    ang = math.sqrt(rx * rx + ry * ry + rz * rz)
    if ang < 1e-12:
        return quat_normalize(q_wxyz)
    k = math.sin(0.5 * ang) / ang
    dq = np.array([math.cos(0.5 * ang), k * rx, k * ry, k * rz])
    return quat_normalize(quat_mul(q_wxyz, dq))


def yaw_quat(yaw: float) -> FloatArray:
    """Level attitude with 3-2-1 yaw `yaw` [rad]."""
    return quat_normalize(np.array([math.cos(0.5 * yaw), 0.0, 0.0, math.sin(0.5 * yaw)]))


def yaw_of_dcm(C_eb: FloatArray) -> float:
    """3-2-1 yaw [rad] of C_eb (heading of the body x axis; falls back to y near gimbal lock)."""
    if math.hypot(C_eb[0, 0], C_eb[1, 0]) > 1e-6:
        return math.atan2(C_eb[1, 0], C_eb[0, 0])
    return math.atan2(-C_eb[0, 1], C_eb[1, 1])


def _vee(M: FloatArray) -> FloatArray:
    return np.array([M[2, 1], M[0, 2], M[1, 0]])


def attitude_error(C_eb: FloatArray, C_eb_des: FloatArray) -> FloatArray:
    """Lee et al. attitude error e_R = 1/2 vee(R_d^T R - R^T R_d), body FRD components.

    R = C_eb (actual), R_d = C_eb_des. |e_R| = sin(angle of R_d^T R); the rate command
    -k e_R rotates R towards R_d.
    """
    M = C_eb_des.T @ C_eb - C_eb.T @ C_eb_des
    return 0.5 * _vee(M)

