"""Small SO(3) kit of the tracking law on single samples: quaternions (w, x, y, z), DCMs
(C_eb maps body FRD to world NED), the attitude error. Floats and (3,)/(4,) arrays."""

from __future__ import annotations

import math
from collections.abc import Sequence
from fractions import Fraction

import numpy as np
import numpy.typing as npt

from companion.control.gains import AttitudeGains
from companion.geometry import dcm_to_quat, dcm_to_quat_f

FloatArray = npt.NDArray[np.float64]
Vec3f = tuple[float, float, float]
#: a 3x3 matrix as its rows of floats
Mat3f = tuple[Vec3f, Vec3f, Vec3f]


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
    return np.array(quat_to_dcm_f([float(c) for c in q_wxyz]))


_EYE3: Mat3f = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))


def quat_to_dcm_f(q_wxyz: Sequence[float]) -> Mat3f:
    """`quat_to_dcm` on floats: the rows of C_eb (the same operations, the same bits)."""
    w, x, y, z = q_wxyz
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if not (math.isfinite(n) and n > 0.0):
        return _EYE3
    w, x, y, z = w / n, x / n, y / n, z / n
    return (
        (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
        (2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
        (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)),
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
    omega_t = (float(omega_frd[0]), float(omega_frd[1]), float(omega_frd[2]))
    out = tilt_guard_f(R.tolist(), omega_t, max_tilt_rad,
                       None if omega_now_frd is None else omega_now_frd.tolist(), gain, lead_s)
    return omega_frd if out is omega_t else np.array(out)


def tilt_guard_f(R: Sequence[Sequence[float]], omega_frd: Vec3f, max_tilt_rad: float,
                 omega_now_frd: Sequence[float] | None = None, gain: float = TILT_GUARD_GAIN,
                 lead_s: float = TILT_GUARD_LEAD_S) -> Vec3f:
    """`tilt_guard` on floats (`R` as rows); returns `omega_frd` itself when it is not limited."""
    g0, g1, g2 = R[2]  # R^T e3: the third row of R
    s = math.hypot(g0, g1)
    if s < 1e-9:
        return omega_frd
    tilt = math.atan2(s, g2)
    n0, n1 = g1 / s, -g0 / s
    if omega_now_frd is not None:
        now = omega_now_frd[0] * n0 + omega_now_frd[1] * n1
        if math.isfinite(now):
            tilt += lead_s * now
    w0, w1, w2 = omega_frd
    rate = w0 * n0 + w1 * n1
    allowed = gain * (max_tilt_rad - tilt)
    if rate <= allowed:
        return omega_frd
    return (w0 - (rate - allowed) * n0, w1 - (rate - allowed) * n1, w2)


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


# ----------------------------------------------------------------------------- the loop in floats
# The rates-mode controller runs the SO(3) loop above every setpoint, on 3x3 matrices where
# numpy's cost per call is most of the time. The versions below take rows of floats and give
# the numpy versions' bits: numpy hands 3x3 products and dots of 3 to OpenBLAS, whose x86-64
# kernels (Haswell and later: fused multiply-add) round each sum as a chain of FMAs; `_fma`
# does one FMA exactly, `_dot3` and `rotate_f` chain them in OpenBLAS's orders. A 1-D dot of 3
# is such a chain only in the SkylakeX kernels (AVX-512; the Haswell ones add plain products),
# and under a BLAS that rounds otherwise the two paths differ in the last bits
# (tests/support/blas.py tells which this numpy does).

_SPLIT = 134217729.0  # 2**27 + 1: Veltkamp's split of a double into two 26-bit halves
_TINY = 1e-280  # below, Dekker's partial products may underflow: exact rational arithmetic


def _fma(a: float, b: float, c: float) -> float:
    """a * b + c rounded once (an FMA), for finite a, b, c with |a|, |b| < 1e150."""
    p = a * b
    if -_TINY < p < _TINY:
        if a == 0.0 or b == 0.0:
            return p + c
        return float(Fraction(a) * Fraction(b) + Fraction(c))
    t = _SPLIT * a
    ah = t - (t - a)
    t = _SPLIT * b
    bh = t - (t - b)
    return _fma_split(p, ah, a - ah, bh, b - bh, c)


def _fma_split(p: float, ah: float, al: float, bh: float, bl: float, c: float) -> float:
    """`_fma` of a, b, c given p = a * b rounded (not tiny) and the operands' Veltkamp halves
    (a = ah + al, b = bh + bl): a * b = p + e exactly (Dekker), then p + e + c correctly
    rounded (`math.fsum`; p + c when e = 0)."""
    e = ((ah * bh - p) + ah * bl + al * bh) + al * bl
    return p + c if e == 0.0 else math.fsum((p, e, c))


def _dot3(a0: float, a1: float, a2: float, b0: float, b1: float, b2: float) -> float:
    """a . b as OpenBLAS rounds a 3x3 product's entry and a dot of 3 (`@`, `np.linalg.norm`):
    fma(a2, b2, fma(a1, b1, fma(a0, b0, +0)))."""
    return _fma(a2, b2, _fma(a1, b1, a0 * b0 + 0.0))


def _halves(v: Vec3f) -> tuple[float, float, float, float]:
    """Veltkamp's halves (hi, lo) of v[1] and of v[2], as `_fma` splits them."""
    t = _SPLIT * v[1]
    h1 = t - (t - v[1])
    t = _SPLIT * v[2]
    h2 = t - (t - v[2])
    return (h1, v[1] - h1, h2, v[2] - h2)


def _cols(M: Mat3f) -> Mat3f:
    """The columns of M (its transpose's rows)."""
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = M
    return ((m00, m10, m20), (m01, m11, m21), (m02, m12, m22))


def _mul(rows: Mat3f, cols: Mat3f) -> Mat3f:
    """The product of the matrix with rows `rows` and the one with columns `cols`: `_dot3` of
    each row and column (numpy's bits), its operands split once (each is in three products; the
    hot path of the rates-mode setpoint)."""
    cs = [(b, _halves(b)) for b in cols]
    out: list[Vec3f] = []
    for a in rows:
        a0, a1, a2 = a
        ah1, al1, ah2, al2 = _halves(a)
        entries = []
        for (b0, b1, b2), (bh1, bl1, bh2, bl2) in cs:
            r = a0 * b0 + 0.0
            p = a1 * b1
            r = _fma(a1, b1, r) if -_TINY < p < _TINY else _fma_split(p, ah1, al1, bh1, bl1, r)
            p = a2 * b2
            r = _fma(a2, b2, r) if -_TINY < p < _TINY else _fma_split(p, ah2, al2, bh2, bl2, r)
            entries.append(r)
        out.append((entries[0], entries[1], entries[2]))
    return (out[0], out[1], out[2])


def rotate_f(M: Mat3f, v: Sequence[float]) -> Vec3f:
    """M @ v with numpy's bits (OpenBLAS's dgemv order for 3 columns: fma(m2, v2, fma(m0, v0,
    m1 v1))); a non-finite `v` goes through numpy itself."""
    v0, v1, v2 = v
    if not (math.isfinite(v0) and math.isfinite(v1) and math.isfinite(v2)):
        x, y, z = (np.array(M) @ np.array([v0, v1, v2])).tolist()
        return (x, y, z)
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = M
    return (
        _fma(m02, v2, _fma(m00, v0, m01 * v1 + 0.0)),
        _fma(m12, v2, _fma(m10, v0, m11 * v1 + 0.0)),
        _fma(m22, v2, _fma(m20, v0, m21 * v1 + 0.0)),
    )


def so3_rate_command_f(
    R: Mat3f, Rd: Mat3f, omega_ff_frd: Sequence[float], gains: AttitudeGains
) -> tuple[Vec3f, Vec3f, Mat3f]:
    """`so3_rate_command_dcm` on floats, the same bits: R, Rd rotation matrices (C_eb, rows),
    omega_ff_frd [rad/s]. Returns (omega_cmd_frd [rad/s], e_R, R^T Rd)."""
    Rc, Rdc = _cols(R), _cols(Rd)
    X = _mul(Rc, Rdc)  # R^T Rd; its transpose is Rd^T R, entry for entry the same products
    (x00, x01, x02), (x10, x11, x12), (x20, x21, x22) = X
    e_R = (0.5 * (x12 - x21), 0.5 * (x20 - x02), 0.5 * (x01 - x10))
    k2 = gains.k_yaw
    err = e_R
    if gains.tilt_priority:
        err = _tilt_priority_error_cols(Rc, Rd, Rdc, x22, gains.yaw_weight)
        k2 = gains.k_yaw / gains.yaw_weight
    elif gains.large_angle:
        d = max(0.5 * math.sqrt(max(1.0 + (x00 + x11 + x22), 0.0)), 0.05)
        err = (e_R[0] / d, e_R[1] / d, e_R[2] / d)
    ff = tuple(omega_ff_frd)
    if not all(map(math.isfinite, ff)):
        ff = (0.0, 0.0, 0.0)
    f0, f1, f2 = rotate_f(X, ff)
    rp, ry = gains.max_rate_rp, gains.max_rate_yaw
    omega = (
        min(max(f0 - gains.k_roll * err[0], -rp), rp),
        min(max(f1 - gains.k_pitch * err[1], -rp), rp),
        min(max(f2 - k2 * err[2], -ry), ry),
    )
    return omega, e_R, X


def tilt_priority_error_f(R: Mat3f, Rd: Mat3f, yaw_weight: float) -> Vec3f:
    """`tilt_priority_error` on floats (R, Rd as rows), the same bits."""
    Rc, Rdc = _cols(R), _cols(Rd)
    return _tilt_priority_error_cols(Rc, Rd, Rdc, _dot3(*Rc[2], *Rdc[2]), yaw_weight)


def _tilt_priority_error_cols(
    Rc: Mat3f, Rd: Mat3f, Rdc: Mat3f, c_ang: float, yaw_weight: float
) -> Vec3f:
    """`tilt_priority_error_f` given R's columns `Rc`, Rd with its columns `Rdc`, and c_ang, the
    thrust axes' dot (`_dot3` of the last columns: (R^T Rd)[2][2])."""
    ez0, ez1, ez2 = Rc[2]
    ed0, ed1, ed2 = Rdc[2]
    axis = (ez1 * ed2 - ez2 * ed1, ez2 * ed0 - ez0 * ed2, ez0 * ed1 - ez1 * ed0)  # np.cross
    s_ang = math.sqrt(_dot3(*axis, *axis))
    if c_ang < -1.0 + 1e-9 and s_ang < 1e-5:
        R_red = Rd  # thrust axes opposite (see tilt_priority_error)
    else:
        R_red = _mul(_axis_angle_dcm_f(axis, s_ang, c_ang), Rc)
    R_red_c = _cols(R_red)
    psi = math.atan2(_dot3(*R_red_c[1], *Rdc[0]), _dot3(*R_red_c[0], *Rdc[0]))
    cw, sw = math.cos(yaw_weight * psi), math.sin(yaw_weight * psi)
    # R_red @ [[cw, -sw, 0], [sw, cw, 0], [0, 0, 1]]: `_mul` with its zero terms dropped (a
    # chain from +0 never holds -0, so adding a zero product leaves it as it is)
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = R_red
    nsw = -sw
    Rd_w_c = (
        (_fma(r01, sw, r00 * cw + 0.0), _fma(r11, sw, r10 * cw + 0.0),
         _fma(r21, sw, r20 * cw + 0.0)),
        (_fma(r01, cw, r00 * nsw + 0.0), _fma(r11, cw, r10 * nsw + 0.0),
         _fma(r21, cw, r20 * nsw + 0.0)),
        (r02 + 0.0, r12 + 0.0, r22 + 0.0),
    )
    q = dcm_to_quat_f(_mul(Rc, Rd_w_c))
    if q is None:  # not for rotation matrices
        return (math.nan, math.nan, math.nan)
    w, x, y, z = q
    sign = 1.0 if w >= 0.0 else -1.0
    return (-2.0 * x * sign, -2.0 * y * sign, -2.0 * z * sign)


def _axis_angle_dcm_f(axis: Vec3f, s_ang: float, c_ang: float) -> Mat3f:
    """`_axis_angle_dcm` on floats, the same bits."""
    if s_ang < 1e-12:
        return _EYE3
    kx, ky, kz = axis[0] / s_ang, axis[1] / s_ang, axis[2] / s_ang
    K = ((0.0, -kz, ky), (kz, 0.0, -kx), (-ky, kx, 0.0))
    # K @ K: `_mul` with its zero terms dropped (see `_tilt_priority_error_cols`)
    kxy, kxz, kyz = kx * ky + 0.0, kx * kz + 0.0, ky * kz + 0.0
    KK = (
        (_fma(ky, -ky, -kz * kz + 0.0), kxy, kxz),
        (kxy, _fma(-kx, kx, kz * -kz + 0.0), kyz),
        (kxz, kyz, _fma(kx, -kx, -ky * ky + 0.0)),
    )
    oc = 1.0 - c_ang

    def row(i: int) -> Vec3f:
        e, k, kk = _EYE3[i], K[i], KK[i]
        return ((e[0] + s_ang * k[0]) + oc * kk[0], (e[1] + s_ang * k[1]) + oc * kk[1],
                (e[2] + s_ang * k[2]) + oc * kk[2])

    return (row(0), row(1), row(2))
