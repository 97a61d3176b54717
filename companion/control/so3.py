"""Small SO(3) kit of the tracking law on single samples: quaternions (w, x, y, z), DCMs
(C_eb maps body FRD to world NED), the attitude error. Floats and (3,)/(4,) arrays."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from companion.control.gains import AttitudeGains
from companion.geometry import dcm_to_quat

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


# ----------------------------------------------------------------------------- SO(3) loop


def so3_rate_command(
    q_wxyz: FloatArray,
    q_des_wxyz: FloatArray,
    omega_ff_frd: FloatArray,
    gains: AttitudeGains,
) -> tuple[FloatArray, FloatArray]:
    """Geometric attitude controller: body-rate command and the attitude error.

    omega_cmd = R^T R_d omega_ff - K e_R (optionally e_R / cos(angle/2)), limited per axis.
    q_wxyz: actual attitude; q_des_wxyz: desired; omega_ff_frd: desired body rates (in the
    desired body frame) [rad/s]. Returns (omega_cmd_frd [rad/s], e_R).
    """
    R = quat_to_dcm(q_wxyz)
    Rd = quat_to_dcm(q_des_wxyz)
    return so3_rate_command_dcm(R, Rd, omega_ff_frd, gains)


def so3_rate_command_dcm(
    R: FloatArray, Rd: FloatArray, omega_ff_frd: FloatArray, gains: AttitudeGains
) -> tuple[FloatArray, FloatArray]:
    """`so3_rate_command` with the attitudes given as DCMs C_eb (actual R, desired Rd)."""
    Rt_Rd = R.T @ Rd
    e_R = attitude_error(R, Rd)
    k = np.array([gains.k_roll, gains.k_pitch, gains.k_yaw])
    err = e_R
    if gains.tilt_priority:
        err = tilt_priority_error(R, Rd, gains.yaw_weight)
        k[2] = gains.k_yaw / gains.yaw_weight
    elif gains.large_angle:
        # 1 + tr(R_d^T R) = 4 cos^2(angle / 2)
        c_half = 0.5 * math.sqrt(max(1.0 + float(np.trace(Rt_Rd)), 0.0))
        err = e_R / max(c_half, 0.05)
    ff = np.asarray(omega_ff_frd, dtype=np.float64)
    if not all_finite(ff):
        ff = np.zeros(3)
    omega = Rt_Rd @ ff - k * err
    lim = np.array([gains.max_rate_rp, gains.max_rate_rp, gains.max_rate_yaw])
    omega = np.minimum(np.maximum(omega, -lim), lim)
    return omega, e_R


#: `tilt_guard`: near the tilt limit the body rates may tilt the vehicle further at most
#: TILT_GUARD_GAIN [1/s] times the angle left to the limit, counted from the tilt the vehicle
#: reaches TILT_GUARD_LEAD_S [s] on at its measured tilt rate (it follows a rate command ~0.1 s
#: late: mock, 0.8 kg on a 6 m/s figure-8, 80 deg/s of tilt rate ran 5 deg past the limit after
#: the command had stopped it)
TILT_GUARD_GAIN = 5.0
TILT_GUARD_LEAD_S = 0.1


def tilt_guard(R: FloatArray, omega_frd: FloatArray, max_tilt_rad: float,
               omega_now_frd: FloatArray | None = None, gain: float = TILT_GUARD_GAIN,
               lead_s: float = TILT_GUARD_LEAD_S) -> FloatArray:
    """Body rates `omega_frd` [rad/s, FRD] with the part that tilts the vehicle (attitude `R`,
    DCM C_eb; measured body rates `omega_now_frd`) faster than ``gain * (max_tilt_rad - tilt
    - lead_s * tilt rate now)`` taken out (beyond the limit that bound is negative: the rates
    bring the tilt back). Only roll and pitch change.

    The tilt rate of body rates w is w . n with n = (g x e3) / sin(tilt), g = R^T e3 the world's
    down axis in the body (d cos(tilt)/dt = w . (e3 x g)). The rates-mode attitude loop closes
    over the link: a tilt-limited attitude setpoint alone let the vehicle overshoot it (mock,
    figure-8 at 6 m/s against 45 deg: 48-49 deg flown; real PX4: 48.4 deg)."""
    g0, g1 = float(R[2, 0]), float(R[2, 1])  # R^T e3: the third row of R
    s = math.hypot(g0, g1)
    if s < 1e-9:
        return omega_frd
    tilt = math.atan2(s, float(R[2, 2]))
    n0, n1 = g1 / s, -g0 / s
    if omega_now_frd is not None:
        now = float(omega_now_frd[0]) * n0 + float(omega_now_frd[1]) * n1
        if math.isfinite(now):
            tilt += lead_s * now
    rate = float(omega_frd[0]) * n0 + float(omega_frd[1]) * n1
    allowed = gain * (max_tilt_rad - tilt)
    if rate <= allowed:
        return omega_frd
    out = np.array(omega_frd, dtype=np.float64)
    out[0] -= (rate - allowed) * n0
    out[1] -= (rate - allowed) * n1
    return out


def tilt_priority_error(R: FloatArray, Rd: FloatArray, yaw_weight: float) -> FloatArray:
    """PX4's attitude error (mc_att_control's AttitudeControl; Brescianini, Hehn and D'Andrea
    2013) between the actual attitude `R` and the desired `Rd` (DCMs C_eb), body FRD: the
    rotation to a desired attitude whose thrust axis is `Rd`'s, reached from `R` by the
    shortest tilt, then turned about that axis by `yaw_weight` times the remaining yaw; the
    error is 2 sin(angle / 2) times the unit axis of the rotation from it to `R` (the sign of
    `attitude_error`: the rate command is -K err; the short way round). With it the thrust axis
    converges first and the yaw only at `yaw_weight` of its gain, so a yaw the vehicle cannot
    follow never tilts it."""
    ez = R[:, 2]
    ezd = Rd[:, 2]
    axis = np.cross(ez, ezd)
    s_ang = float(np.linalg.norm(axis))
    c_ang = float(ez @ ezd)
    if c_ang < -1.0 + 1e-9 and s_ang < 1e-5:
        R_red = Rd  # thrust axes opposite: no unique shortest tilt (PX4 takes the full attitude)
    else:
        R_red = _axis_angle_dcm(axis, s_ang, c_ang) @ R
    mix = R_red.T @ Rd  # a rotation about the (common) body z axis
    psi = math.atan2(float(mix[1, 0]), float(mix[0, 0]))
    cw, sw = math.cos(yaw_weight * psi), math.sin(yaw_weight * psi)
    Rd_w = R_red @ np.array([[cw, -sw, 0.0], [sw, cw, 0.0], [0.0, 0.0, 1.0]])
    w, x, y, z = dcm_to_quat(R.T @ Rd_w).tolist()  # w >= 0: the short way
    return np.array([-2.0 * x, -2.0 * y, -2.0 * z]) * (1.0 if w >= 0.0 else -1.0)


def _axis_angle_dcm(axis: FloatArray, s_ang: float, c_ang: float) -> FloatArray:
    """Rotation about `axis` (|axis| = sin(angle) = `s_ang`, cos(angle) = `c_ang`), Rodrigues;
    the identity for a vanishing axis."""
    if s_ang < 1e-12:
        return np.eye(3)
    kx, ky, kz = (axis / s_ang).tolist()
    K = np.array([[0.0, -kz, ky], [kz, 0.0, -kx], [-ky, kx, 0.0]])
    out: FloatArray = np.eye(3) + s_ang * K + (1.0 - c_ang) * (K @ K)
    return out
