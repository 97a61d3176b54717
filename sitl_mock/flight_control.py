"""PX4-like multicopter control cascade, written independently of PX4 and of `companion`.

position P -> velocity PID (+ feed-forward) -> acceleration -> thrust vector (hover thrust
MPC_THR_HOVER, linear mapping, tilt limit) -> attitude (body z + yaw) -> quaternion attitude P
(reduced yaw weight) -> body-rate PID -> normalised torque -> quad-X mixing with saturation.

Everything works on plain Python floats (tuples) for speed: the mock steps at up to 1 kHz and
must run far faster than real time. Frames: world NED, body FRD; quaternions (w, x, y, z) rotate
body FRD -> NED (Hamilton).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

from sitl_mock.setpoints import PositionTarget, Quat, Vec3

G = 9.80665  # standard gravity [m/s^2] (PX4 CONSTANTS_ONE_G)
VEL_SP_ABS_MAX = 1000.0  # sanity clamp of absurd (finite) setpoints [m/s]
ACC_FF_ABS_MAX = 100.0  # sanity clamp of acceleration feed-forward [m/s^2]
_SQRT1_2 = math.sqrt(0.5)
_isfinite = math.isfinite

# ---------------------------------------------------------------------------------------------
# Quaternion helpers (w, x, y, z), body -> world
# ---------------------------------------------------------------------------------------------


def quat_mul(a: Quat, b: Quat) -> Quat:
    """Hamilton product a * b."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


def quat_conj(q: Quat) -> Quat:
    """Conjugate (inverse of a unit quaternion)."""
    return (q[0], -q[1], -q[2], -q[3])


#: PX4's matrix::Quaternion::canonical() decides the sign by the first component whose magnitude
#: exceeds the float epsilon (w, then x, y, z): a 180-degree rotation (w ~ 0) is not left to the
#: sign of a rounding error
QUAT_CANON_EPS = 1.1920929e-07


def quat_canonical_sign(w: float, x: float, y: float, z: float) -> float:
    """+1 or -1: the sign that makes (w, x, y, z) canonical in PX4's sense (see QUAT_CANON_EPS)."""
    for c in (w, x, y, z):
        if c > QUAT_CANON_EPS:
            return 1.0
        if c < -QUAT_CANON_EPS:
            return -1.0
    return 1.0


def quat_normalize(q: Quat) -> Quat:
    """Unit quaternion, canonical as PX4's (w > 0, or the first clearly non-zero component > 0);
    identity if degenerate."""
    w, x, y, z = q
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if not n > 1e-12 or not _isfinite(n):
        return (1.0, 0.0, 0.0, 0.0)
    n *= quat_canonical_sign(w / n, x / n, y / n, z / n)
    return (w / n, x / n, y / n, z / n)


def quat_rotate(q: Quat, v: Vec3) -> Vec3:
    """Rotate body vector v to the world frame: R(q) v."""
    w, x, y, z = q
    vx, vy, vz = v
    # t = 2 * cross(q_vec, v); v' = v + w t + cross(q_vec, t)
    tx = 2.0 * (y * vz - z * vy)
    ty = 2.0 * (z * vx - x * vz)
    tz = 2.0 * (x * vy - y * vx)
    return (
        vx + w * tx + (y * tz - z * ty),
        vy + w * ty + (z * tx - x * tz),
        vz + w * tz + (x * ty - y * tx),
    )


def quat_body_z(q: Quat) -> Vec3:
    """Body z axis expressed in the world frame (third column of R)."""
    w, x, y, z = q
    return (2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y))


def quat_yaw(q: Quat) -> float:
    """Yaw (heading) of the 3-2-1 Euler decomposition [rad]."""
    w, x, y, z = q
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def quat_from_yaw(yaw: float) -> Quat:
    """Level attitude with the given heading."""
    return (math.cos(0.5 * yaw), 0.0, 0.0, math.sin(0.5 * yaw))


def quat_from_euler(roll: float, pitch: float, yaw: float) -> Quat:
    """Quaternion from 3-2-1 (yaw, pitch, roll) Euler angles [rad]."""
    cr, sr = math.cos(0.5 * roll), math.sin(0.5 * roll)
    cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
    cy, sy = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def quat_from_two_vectors(a: Vec3, b: Vec3) -> Quat:
    """Shortest rotation taking direction a to direction b (both non-zero)."""
    cx = a[1] * b[2] - a[2] * b[1]
    cy = a[2] * b[0] - a[0] * b[2]
    cz = a[0] * b[1] - a[1] * b[0]
    d = a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
    na = math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])
    nb = math.sqrt(b[0] * b[0] + b[1] * b[1] + b[2] * b[2])
    w = d + na * nb
    if w < 1e-9 * na * nb:
        # opposite: rotate by pi about any axis perpendicular to a
        if abs(a[0]) < abs(a[2]):
            return quat_normalize((0.0, 0.0, -a[2], a[1]))
        return quat_normalize((0.0, -a[1], a[0], 0.0))
    return quat_normalize((w, cx, cy, cz))


def body_z_to_attitude(body_z: Vec3, yaw: float) -> Quat:
    """Attitude whose body z axis is `body_z` (unit, world) and whose heading is `yaw`."""
    bzx, bzy, bzz = body_z
    ycx, ycy = -math.sin(yaw), math.cos(yaw)  # y axis of the yaw-only frame
    # body_x = y_C x body_z
    bxx = ycy * bzz
    bxy = -ycx * bzz
    bxz = ycx * bzy - ycy * bzx
    if bzz < 0.0:
        bxx, bxy, bxz = -bxx, -bxy, -bxz
    n = math.sqrt(bxx * bxx + bxy * bxy + bxz * bxz)
    if n < 1e-6:
        bxx, bxy, bxz, n = 0.0, 0.0, 1.0, 1.0
    bxx, bxy, bxz = bxx / n, bxy / n, bxz / n
    # body_y = body_z x body_x
    byx = bzy * bxz - bzz * bxy
    byy = bzz * bxx - bzx * bxz
    byz = bzx * bxy - bzy * bxx
    return dcm_to_quat(((bxx, byx, bzx), (bxy, byy, bzy), (bxz, byz, bzz)))


def dcm_to_quat(r: tuple[Vec3, Vec3, Vec3]) -> Quat:
    """Quaternion of a rotation matrix given as rows (Shepperd's method)."""
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = r
    tr = r00 + r11 + r22
    if tr > 0.0:
        s = math.sqrt(tr + 1.0) * 2.0
        q = (0.25 * s, (r21 - r12) / s, (r02 - r20) / s, (r10 - r01) / s)
    elif r00 > r11 and r00 > r22:
        s = math.sqrt(1.0 + r00 - r11 - r22) * 2.0
        q = ((r21 - r12) / s, 0.25 * s, (r01 + r10) / s, (r02 + r20) / s)
    elif r11 > r22:
        s = math.sqrt(1.0 + r11 - r00 - r22) * 2.0
        q = ((r02 - r20) / s, (r01 + r10) / s, 0.25 * s, (r12 + r21) / s)
    else:
        s = math.sqrt(1.0 + r22 - r00 - r11) * 2.0
        q = ((r10 - r01) / s, (r02 + r20) / s, (r12 + r21) / s, 0.25 * s)
    return quat_normalize(q)


def wrap_pi(a: float) -> float:
    """Wrap an angle to [-pi, pi)."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def _clamp(v: float, lo: float, hi: float) -> float:
    return lo if v < lo else hi if v > hi else v


# ---------------------------------------------------------------------------------------------
# Gains (cached from the ParamStore; refreshed at the position-loop rate)
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class McGains:
    """Multicopter controller parameters, in SI units (rates in rad/s, angles in rad)."""

    hover: float
    thr_min: float
    thr_max: float
    xy_marg: float
    pos_p: Vec3
    vel_p: Vec3
    vel_i: Vec3
    vel_d: Vec3
    vel_xy_max: float
    vel_up_max: float
    vel_dn_max: float
    tilt_max: float
    tilt_max_land: float
    att_p: Vec3
    yaw_w: float
    rate_max: Vec3
    rate_p: Vec3
    rate_i: Vec3
    rate_d: Vec3
    rate_int_lim: float
    tko_ramp_t: float
    spoolup_t: float
    tko_speed: float
    airmode: int

    @staticmethod
    def from_params(p: Mapping[str, float]) -> McGains:
        """Read every gain the cascade needs from a parameter mapping (PX4 names/units)."""
        d2r = math.pi / 180.0
        xy_p, z_p = p["MPC_XY_P"], p["MPC_Z_P"]
        yaw_w = _clamp(p["MC_YAW_WEIGHT"], 0.0, 1.0)
        yaw_p = p["MC_YAW_P"] / yaw_w if yaw_w > 1e-4 else p["MC_YAW_P"]
        return McGains(
            hover=_clamp(p["MPC_THR_HOVER"], 0.05, 0.95),
            thr_min=p["MPC_THR_MIN"],
            thr_max=p["MPC_THR_MAX"],
            xy_marg=p["MPC_THR_XY_MARG"],
            pos_p=(xy_p, xy_p, z_p),
            vel_p=(p["MPC_XY_VEL_P_ACC"], p["MPC_XY_VEL_P_ACC"], p["MPC_Z_VEL_P_ACC"]),
            vel_i=(p["MPC_XY_VEL_I_ACC"], p["MPC_XY_VEL_I_ACC"], p["MPC_Z_VEL_I_ACC"]),
            vel_d=(p["MPC_XY_VEL_D_ACC"], p["MPC_XY_VEL_D_ACC"], p["MPC_Z_VEL_D_ACC"]),
            vel_xy_max=p["MPC_XY_VEL_MAX"],
            vel_up_max=p["MPC_Z_VEL_MAX_UP"],
            vel_dn_max=p["MPC_Z_VEL_MAX_DN"],
            tilt_max=_clamp(p["MPC_TILTMAX_AIR"], 1.0, 89.0) * d2r,
            tilt_max_land=_clamp(min(p["MPC_TILTMAX_LND"], p["MPC_TILTMAX_AIR"]), 1.0, 89.0) * d2r,
            att_p=(p["MC_ROLL_P"], p["MC_PITCH_P"], yaw_p),
            yaw_w=yaw_w,
            rate_max=(
                p["MC_ROLLRATE_MAX"] * d2r,
                p["MC_PITCHRATE_MAX"] * d2r,
                p["MC_YAWRATE_MAX"] * d2r,
            ),
            rate_p=(p["MC_ROLLRATE_P"], p["MC_PITCHRATE_P"], p["MC_YAWRATE_P"]),
            rate_i=(p["MC_ROLLRATE_I"], p["MC_PITCHRATE_I"], p["MC_YAWRATE_I"]),
            rate_d=(p["MC_ROLLRATE_D"], p["MC_PITCHRATE_D"], p["MC_YAWRATE_D"]),
            rate_int_lim=0.3,
            tko_ramp_t=p["MPC_TKO_RAMP_T"],
            spoolup_t=p["COM_SPOOLUP_TIME"],
            tko_speed=p["MPC_TKO_SPEED"],
            airmode=int(p["MC_AIRMODE"]),
        )


def constrain_xy(
    v0x: float, v0y: float, v1x: float, v1y: float, vmax: float
) -> tuple[float, float]:
    """Limit v0 + v1 to norm vmax, keeping v0 (position part) first, then as much of v1 as fits."""
    sx, sy = v0x + v1x, v0y + v1y
    if sx * sx + sy * sy <= vmax * vmax:
        return sx, sy
    n0 = math.hypot(v0x, v0y)
    if n0 >= vmax:
        return v0x * vmax / n0, v0y * vmax / n0
    n1 = math.hypot(v1x, v1y)  # > 0 here since |v0| < vmax < |v0 + v1|
    ux, uy = v1x / n1, v1y / n1
    m = ux * v0x + uy * v0y
    s = -m + math.sqrt(max(m * m - (n0 * n0 - vmax * vmax), 0.0))
    return v0x + ux * s, v0y + uy * s


# ---------------------------------------------------------------------------------------------
# Position / velocity controller
# ---------------------------------------------------------------------------------------------


class PositionVelocityController:
    """PX4-style position P + velocity PID producing a thrust vector and an attitude."""

    def __init__(self) -> None:
        self.vel_int: list[float] = [0.0, 0.0, 0.0]
        self.vel_sp: Vec3 = (0.0, 0.0, 0.0)
        self.acc_sp: Vec3 = (0.0, 0.0, 0.0)

    def reset(self) -> None:
        """Zero the velocity integrators."""
        self.vel_int = [0.0, 0.0, 0.0]

    def velocity_setpoint(
        self, g: McGains, pos: Vec3, tgt: PositionTarget, up_limit: float
    ) -> tuple[float, float, float]:
        """Velocity setpoint [m/s NED] from position error + feed-forward (NaN = acc only).

        The horizontal limit MPC_XY_VEL_MAX keeps the position-error part first and fills the
        rest with the feed-forward (PX4's ControlMath::constrainXY).
        """
        out = [0.0, 0.0, 0.0]
        p_part = [0.0, 0.0, 0.0]
        tp, tv, ta = tgt.pos_ned, tgt.vel_ned, tgt.acc_ned
        for i in range(3):
            ps, vs = tp[i], tv[i]
            if _isfinite(ps):
                p_part[i] = _clamp(g.pos_p[i] * (ps - pos[i]), -VEL_SP_ABS_MAX, VEL_SP_ABS_MAX)
                out[i] = p_part[i] + (
                    _clamp(vs, -VEL_SP_ABS_MAX, VEL_SP_ABS_MAX) if _isfinite(vs) else 0.0
                )
            elif _isfinite(vs):
                out[i] = _clamp(vs, -VEL_SP_ABS_MAX, VEL_SP_ABS_MAX)
            elif _isfinite(ta[i]):
                out[i] = math.nan  # acceleration only on this axis
            else:
                out[i] = 0.0  # nothing given on this axis: hold (zero velocity)
        vx, vy, vz = out
        if _isfinite(vx) and _isfinite(vy):
            vx, vy = constrain_xy(
                p_part[0], p_part[1], vx - p_part[0], vy - p_part[1], g.vel_xy_max
            )
        if _isfinite(vz):
            vz = _clamp(vz, -up_limit, g.vel_dn_max)
        return (vx, vy, vz)

    def update(
        self,
        g: McGains,
        dt: float,
        pos: Vec3,
        vel: Vec3,
        vel_dot: Vec3,
        tgt: PositionTarget,
        up_limit: float,
        flying: bool = True,
    ) -> tuple[Vec3, float]:
        """One position-loop update. Returns (body_z unit vector in NED, collective thrust 0..1).

        While not `flying` (takeoff ramp) the thrust may go down to zero and the tilt is limited to
        MPC_TILTMAX_LND, as in PX4.
        """
        tilt_max = g.tilt_max if flying else g.tilt_max_land
        thr_min = g.thr_min if flying else 0.0
        vsp = self.velocity_setpoint(g, pos, tgt, up_limit)
        self.vel_sp = vsp
        ta = tgt.acc_ned
        acc = [0.0, 0.0, 0.0]
        err = [0.0, 0.0, 0.0]
        vi = self.vel_int
        for i in range(3):
            if _isfinite(vsp[i]):
                e = vsp[i] - vel[i]
                err[i] = e
                acc[i] = g.vel_p[i] * e + vi[i] - g.vel_d[i] * vel_dot[i]
            if _isfinite(ta[i]):
                acc[i] += _clamp(ta[i], -ACC_FF_ABS_MAX, ACC_FF_ABS_MAX)
        ax, ay, az = acc
        self.acc_sp = (ax, ay, az)
        # acceleration -> body z direction (thrust points along -body_z) with tilt limit
        bzx, bzy, bzz = -ax, -ay, G - az
        n = math.sqrt(bzx * bzx + bzy * bzy + bzz * bzz)
        if n < 1e-9:
            bzx, bzy, bzz = 0.0, 0.0, 1.0
        else:
            bzx, bzy, bzz = bzx / n, bzy / n, bzz / n
        ang = math.acos(_clamp(bzz, -1.0, 1.0))
        if ang > tilt_max:
            rej = math.hypot(bzx, bzy)
            if rej < 1e-9:
                rx, ry = 1.0, 0.0
            else:
                rx, ry = bzx / rej, bzy / rej
            s = math.sin(tilt_max)
            bzx, bzy, bzz = s * rx, s * ry, math.cos(tilt_max)
        # linear hover-thrust mapping of the vertical acceleration (NED: negative = up)
        thr_z = az * (g.hover / G) - g.hover
        coll = min(thr_z / bzz, -thr_min)
        tx, ty, tz = bzx * coll, bzy * coll, bzz * coll
        # vertical anti-windup
        if (tz >= -thr_min and err[2] >= 0.0) or (tz <= -g.thr_max and err[2] <= 0.0):
            err[2] = 0.0
        # keep a horizontal margin, then saturate the horizontal thrust
        txy = math.hypot(tx, ty)
        tmax2 = g.thr_max * g.thr_max
        alloc_xy = min(txy, g.xy_marg)
        tz = max(tz, -math.sqrt(max(tmax2 - alloc_xy * alloc_xy, 0.0)))
        txy_max = math.sqrt(max(tmax2 - tz * tz, 0.0))
        if txy > txy_max:
            s = txy_max / txy
            tx, ty = tx * s, ty * s
        # tracking anti-windup for the horizontal integrator
        k = G / g.hover
        px, py = tx * k, ty * k
        if ax * ax + ay * ay > px * px + py * py and g.vel_p[0] > 0.0:
            arw = 2.0 / g.vel_p[0]
            err[0] -= arw * (ax - px)
            err[1] -= arw * (ay - py)
        for i in range(3):
            vi[i] += err[i] * g.vel_i[i] * dt
        vi[2] = _clamp(vi[2], -G, G)
        thrust = math.sqrt(tx * tx + ty * ty + tz * tz)
        if thrust < 1e-6:
            return (0.0, 0.0, 1.0), 0.0
        return (-tx / thrust, -ty / thrust, -tz / thrust), thrust


# ---------------------------------------------------------------------------------------------
# Attitude and rate control
# ---------------------------------------------------------------------------------------------


def attitude_control(g: McGains, q: Quat, q_sp: Quat, yaw_rate_ff: float) -> Vec3:
    """Quaternion attitude P with reduced yaw weight; returns body rate setpoint [rad/s FRD].

    Like PX4's AttitudeControl: the thrust-axis (roll/pitch) correction is the shortest rotation
    of the body z axis onto the desired one; the remaining yaw rotation is scaled by MC_YAW_WEIGHT
    before the P gains act on 2 * vector part of q^-1 q_desired. Written out with floats for speed
    (same result as the quat_* helpers; see tests).
    """
    qw, qx, qy, qz = q
    sw, sx, sy, sz = q_sp
    # body z axes in the world (third column of R)
    ax = 2.0 * (qx * qz + qw * qy)
    ay = 2.0 * (qy * qz - qw * qx)
    az = 1.0 - 2.0 * (qx * qx + qy * qy)
    bx = 2.0 * (sx * sz + sw * sy)
    by = 2.0 * (sy * sz - sw * sx)
    bz = 1.0 - 2.0 * (sx * sx + sy * sy)
    # shortest rotation a -> b (unit vectors): (1 + a.b, a x b), normalised
    rw = 1.0 + ax * bx + ay * by + az * bz
    rx = ay * bz - az * by
    ry = az * bx - ax * bz
    rz = ax * by - ay * bx
    n = math.sqrt(rw * rw + rx * rx + ry * ry + rz * rz)
    use_full = rw < 1e-9
    if not use_full:
        rw, rx, ry, rz = rw / n, rx / n, ry / n, rz / n
        use_full = abs(rx) > 1.0 - 1e-5 or abs(ry) > 1.0 - 1e-5
    if use_full:
        dw, dx, dy, dz = sw, sx, sy, sz  # body z flipped: use the full attitude
    else:
        # reduced attitude qr = r * q
        pw = rw * qw - rx * qx - ry * qy - rz * qz
        px = rw * qx + rx * qw + ry * qz - rz * qy
        py = rw * qy - rx * qz + ry * qw + rz * qx
        pz = rw * qz + rx * qy - ry * qx + rz * qw
        # q_mix = qr^-1 * q_sp (a pure yaw rotation up to rounding), canonical (w >= 0)
        mw = pw * sw + px * sx + py * sy + pz * sz
        mz = pw * sz - px * sy + py * sx - pz * sw
        if mw < QUAT_CANON_EPS and (mw < -QUAT_CANON_EPS or mz < -QUAT_CANON_EPS):
            mw, mz = -mw, -mz  # canonical (q_mix is a pure yaw: its x, y are rounding)
        mw = 1.0 if mw > 1.0 else mw
        mz = 1.0 if mz > 1.0 else -1.0 if mz < -1.0 else mz
        yw = g.yaw_w
        cw, cz = math.cos(yw * math.acos(mw)), math.sin(yw * math.asin(mz))
        # qd = qr * (cw, 0, 0, cz)
        dw = pw * cw - pz * cz
        dx = px * cw + py * cz
        dy = py * cw - px * cz
        dz = pz * cw + pw * cz
    # qe = q^-1 * qd, canonical
    ew = qw * dw + qx * dx + qy * dy + qz * dz
    ex = qw * dx - qx * dw - qy * dz + qz * dy
    ey = qw * dy + qx * dz - qy * dw - qz * dx
    ez = qw * dz - qx * dy + qy * dx - qz * dw
    k = 2.0 / math.sqrt(ew * ew + ex * ex + ey * ey + ez * ez)
    if ew < QUAT_CANON_EPS * 2.0:  # only a w near or below zero can need the sign flipped
        k *= quat_canonical_sign(ew * k * 0.5, ex * k * 0.5, ey * k * 0.5, ez * k * 0.5)
    ap = g.att_p
    r0 = ex * k * ap[0]
    r1 = ey * k * ap[1]
    r2 = ez * k * ap[2]
    if _isfinite(yaw_rate_ff):
        # world z axis in body coordinates = third row of R
        r0 += 2.0 * (qx * qz - qw * qy) * yaw_rate_ff
        r1 += 2.0 * (qy * qz + qw * qx) * yaw_rate_ff
        r2 += az * yaw_rate_ff
    rm = g.rate_max
    return (
        rm[0] if r0 > rm[0] else -rm[0] if r0 < -rm[0] else r0,
        rm[1] if r1 > rm[1] else -rm[1] if r1 < -rm[1] else r1,
        rm[2] if r2 > rm[2] else -rm[2] if r2 < -rm[2] else r2,
    )


def attitude_control_reference(g: McGains, q: Quat, q_sp: Quat, yaw_rate_ff: float) -> Vec3:
    """Readable version of `attitude_control` built from the quaternion helpers (for tests)."""
    ez = quat_body_z(q)
    ezd = quat_body_z(q_sp)
    qd_red = quat_from_two_vectors(ez, ezd)
    flipped = qd_red[0] == 0.0  # quat_from_two_vectors' opposite case (an arbitrary axis)
    if flipped or abs(qd_red[1]) > 1.0 - 1e-5 or abs(qd_red[2]) > 1.0 - 1e-5:
        # body z opposite to the desired one: the full attitude
        qd = q_sp
    else:
        qd_red = quat_mul(qd_red, q)
        q_mix = quat_normalize(quat_mul(quat_conj(qd_red), q_sp))
        w0 = _clamp(q_mix[0], -1.0, 1.0)
        w3 = _clamp(q_mix[3], -1.0, 1.0)
        yw = g.yaw_w
        q_yaw = (math.cos(yw * math.acos(w0)), 0.0, 0.0, math.sin(yw * math.asin(w3)))
        qd = quat_mul(qd_red, q_yaw)
    qe = quat_normalize(quat_mul(quat_conj(q), qd))
    rx = 2.0 * qe[1] * g.att_p[0]
    ry = 2.0 * qe[2] * g.att_p[1]
    rz = 2.0 * qe[3] * g.att_p[2]
    if _isfinite(yaw_rate_ff):
        w, x, y, z = q
        rx += 2.0 * (x * z - w * y) * yaw_rate_ff
        ry += 2.0 * (y * z + w * x) * yaw_rate_ff
        rz += (1.0 - 2.0 * (x * x + y * y)) * yaw_rate_ff
    rm = g.rate_max
    return (_clamp(rx, -rm[0], rm[0]), _clamp(ry, -rm[1], rm[1]), _clamp(rz, -rm[2], rm[2]))


class AngularVelocityFilter:
    """PX4's sensors/vehicle_angular_velocity on three axes: the gyro through a second-order
    Butterworth low-pass at IMU_GYRO_CUTOFF [Hz] (the rates the rate loop and ATTITUDE use),
    and its derivative (the raw gyro differenced per sample) through one at IMU_DGYRO_CUTOFF
    [Hz] (the angular acceleration the rate loop's D term uses). A cutoff <= 0 or at or above
    the Nyquist rate passes the signal through, as PX4's LowPassFilter2p does. The design is
    the bilinear transform with pre-warping (PX4's math::LowPassFilter2p, same coefficients)."""

    def __init__(self) -> None:
        self._key: tuple[float, float, float] | None = None
        self._cv: tuple[float, float, float, float, float] = (1.0, 0.0, 0.0, 0.0, 0.0)
        self._ca: tuple[float, float, float, float, float] = (1.0, 0.0, 0.0, 0.0, 0.0)
        self._dv: list[float] = [0.0] * 6  # delay elements w1, w2 per axis (rates)
        self._da: list[float] = [0.0] * 6  # (angular acceleration)
        self._prev: Vec3 | None = None

    @staticmethod
    def _coefficients(dt: float, cutoff_hz: float) -> tuple[float, float, float, float, float]:
        """(b0, b1, b2, a1, a2) of the low-pass at `cutoff_hz` sampled every `dt` [s]."""
        fs = 1.0 / dt
        if cutoff_hz <= 0.0 or cutoff_hz >= 0.5 * fs:
            return (1.0, 0.0, 0.0, 0.0, 0.0)
        ohm = math.tan(math.pi * cutoff_hz / fs)
        k = 2.0 * math.cos(math.pi / 4.0) * ohm
        c = 1.0 + k + ohm * ohm
        b0 = ohm * ohm / c
        return (b0, 2.0 * b0, b0, 2.0 * (ohm * ohm - 1.0) / c, (1.0 - k + ohm * ohm) / c)

    def reset(self, rate: Vec3) -> None:
        """Steady state at body rates `rate` [rad/s] with zero angular acceleration."""
        self._prev = rate
        for d, c, v in ((self._dv, self._cv, rate), (self._da, self._ca, (0.0, 0.0, 0.0))):
            # 1 + a1 + a2 equals b0 + b1 + b2 (unit DC gain); the b sum has no cancellation,
            # which a cutoff far below the sample rate turns 1 + a1 + a2 into (0 at 1e-8 fs)
            den = c[0] + c[1] + c[2]
            for i in range(3):
                w = v[i] / den if den > 0.0 else math.inf
                # not representable (a cutoff below ~1e-150 fs): start from the sample
                d[2 * i] = d[2 * i + 1] = w if math.isfinite(w) else v[i]

    def update(self, raw: Vec3, dt: float, cutoff_hz: float, dcutoff_hz: float
               ) -> tuple[Vec3, Vec3]:
        """Filter one gyro sample `raw` [rad/s] taken `dt` [s] after the last: (rates [rad/s],
        angular acceleration [rad/s^2])."""
        key = (dt, cutoff_hz, dcutoff_hz)
        if key != self._key:
            self._key = key
            self._cv = self._coefficients(dt, cutoff_hz)
            self._ca = self._coefficients(dt, dcutoff_hz)
            if self._prev is None:
                self.reset(raw)
            else:  # keep the outputs continuous (PX4 resets its filters likewise)
                self.reset(self._prev)
        prev = self._prev if self._prev is not None else raw
        self._prev = raw
        inv = 1.0 / dt
        # per axis i, delay elements (w1, w2) = d[2i], d[2i + 1]: w0 = x - a1 w1 - a2 w2,
        # y = b0 w0 + b1 w1 + b2 w2, then (w1, w2) <- (w0, w1) (written out: a hot path)
        x0, x1, x2 = raw
        b0, b1, b2, a1, a2 = self._cv
        d = self._dv
        p0, q0, p1, q1, p2, q2 = d
        w0 = x0 - a1 * p0 - a2 * q0
        y0 = b0 * w0 + b1 * p0 + b2 * q0
        v0 = x1 - a1 * p1 - a2 * q1
        y1 = b0 * v0 + b1 * p1 + b2 * q1
        u0 = x2 - a1 * p2 - a2 * q2
        y2 = b0 * u0 + b1 * p2 + b2 * q2
        d[:] = (w0, p0, v0, p1, u0, p2)
        x0 = (x0 - prev[0]) * inv
        x1 = (x1 - prev[1]) * inv
        x2 = (x2 - prev[2]) * inv
        b0, b1, b2, a1, a2 = self._ca
        d = self._da
        p0, q0, p1, q1, p2, q2 = d
        w0 = x0 - a1 * p0 - a2 * q0
        z0 = b0 * w0 + b1 * p0 + b2 * q0
        v0 = x1 - a1 * p1 - a2 * q1
        z1 = b0 * v0 + b1 * p1 + b2 * q1
        u0 = x2 - a1 * p2 - a2 * q2
        z2 = b0 * u0 + b1 * p2 + b2 * q2
        d[:] = (w0, p0, v0, p1, u0, p2)
        return (y0, y1, y2), (z0, z1, z2)


class RateController:
    """Body-rate PID with PX4's integrator shaping; output is normalised torque [-1, 1]."""

    def __init__(self) -> None:
        self.integral: list[float] = [0.0, 0.0, 0.0]
        self._prev_rate: Vec3 | None = None

    def reset(self) -> None:
        """Zero the integrators and the derivative memory."""
        self.integral = [0.0, 0.0, 0.0]
        self._prev_rate = None

    def update(
        self, g: McGains, rate: Vec3, rate_sp: Vec3, dt: float, freeze_integral: bool,
        accel: Vec3 | None = None,
    ) -> Vec3:
        """Torque (normalised) for the rate error; D acts on the measured angular acceleration
        `accel` [rad/s^2] (PX4: vehicle_angular_acceleration), or if None on the difference of
        successive `rate` samples.

        The integrator is frozen while `freeze_integral` (landed), shaped by PX4's
        1 - (e / 400 deg/s)^2 factor and limited to +-0.3.
        """
        prev = self._prev_rate
        if prev is None:
            prev = rate
        self._prev_rate = rate
        wx, wy, wz = rate
        if accel is None:
            inv_dt = 1.0 / dt
            accel = ((wx - prev[0]) * inv_dt, (wy - prev[1]) * inv_dt, (wz - prev[2]) * inv_dt)
        ex, ey, ez = rate_sp[0] - wx, rate_sp[1] - wy, rate_sp[2] - wz
        kp, kd = g.rate_p, g.rate_d
        integ = self.integral
        ix, iy, iz = integ
        tx = kp[0] * ex + ix - kd[0] * accel[0]
        ty = kp[1] * ey + iy - kd[1] * accel[1]
        tz = kp[2] * ez + iz - kd[2] * accel[2]
        if not freeze_integral:
            ki, lim = g.rate_i, g.rate_int_lim
            k = 1.0 / 6.981317007977318  # 1 / (400 deg/s)
            fx, fy, fz = ex * k, ey * k, ez * k
            fx, fy, fz = 1.0 - fx * fx, 1.0 - fy * fy, 1.0 - fz * fz
            if fx > 0.0:
                ix += fx * ki[0] * ex * dt
                ix = lim if ix > lim else -lim if ix < -lim else ix
            if fy > 0.0:
                iy += fy * ki[1] * ey * dt
                iy = lim if iy > lim else -lim if iy < -lim else iy
            if fz > 0.0:
                iz += fz * ki[2] * ez * dt
                iz = lim if iz > lim else -lim if iz < -lim else iz
            integ[0], integ[1], integ[2] = ix, iy, iz
        return (
            1.0 if tx > 1.0 else -1.0 if tx < -1.0 else tx,
            1.0 if ty > 1.0 else -1.0 if ty < -1.0 else ty,
            1.0 if tz > 1.0 else -1.0 if tz < -1.0 else tz,
        )


_ROLL_V = (-_SQRT1_2, _SQRT1_2, _SQRT1_2, -_SQRT1_2)  # PX4's quad X mix columns
_PITCH_V = (_SQRT1_2, -_SQRT1_2, _SQRT1_2, -_SQRT1_2)
_YAW_V = (1.0, 1.0, -1.0, -1.0)
_THRUST_V = (-1.0, -1.0, -1.0, -1.0)  # thrust is along -z: a positive gain lowers it
Motors = tuple[float, float, float, float]


def _desaturation_gain(v: Motors, u: Motors, hi: float = 1.0) -> float:
    """PX4's computeDesaturationGain: the gain along v that best brings u into [0, hi]."""
    k_min = 0.0
    k_max = 0.0
    for vi, ui in zip(v, u, strict=True):
        if ui < 0.0:
            k = -ui / vi
        elif ui > hi:
            k = (hi - ui) / vi
        else:
            continue
        if k < k_min:
            k_min = k
        if k > k_max:
            k_max = k
    return k_min + k_max


def _desaturate(u: Motors, v: Motors, lower_only: bool = False, hi: float = 1.0) -> Motors:
    """PX4's desaturateActuators: move u along v by the gain, then by half the gain that is
    still missing; `lower_only` (its increase_only, v the thrust column) skips a move that
    would raise the collective."""
    g = _desaturation_gain(v, u, hi)
    if g == 0.0 or (lower_only and g < 0.0):
        return u
    u = (u[0] + g * v[0], u[1] + g * v[1], u[2] + g * v[2], u[3] + g * v[3])
    g = 0.5 * _desaturation_gain(v, u, hi)
    if g == 0.0:
        return u
    return (u[0] + g * v[0], u[1] + g * v[1], u[2] + g * v[2], u[3] + g * v[3])


def mix_quad_x(torque: Vec3, thrust: float, airmode: int = 0) -> Motors:
    """Normalised torque + collective -> four motor commands 0..1 (PX4 quad X order).

    Motors: 0 front-right (CCW), 1 rear-left (CCW), 2 front-left (CW), 3 rear-right (CW).
    A normalised roll/pitch torque of 1 moves each motor by 1/sqrt(2) (PX4's normalised
    effectiveness), a yaw torque of 1 by 1. Saturation is resolved as PX4's sequential
    desaturation (control_allocator, ControlAllocationSequentialDesaturation) with `airmode` =
    MC_AIRMODE. 0 (PX4's default): roll/pitch first, the collective only lowered, then
    roll/pitch scaled down to fit [0, 1]; then yaw, scaled down to fit [0, 1.15], and the
    collective lowered again to fit [0, 1]. So a low collective caps the roll/pitch torque: at
    0.4 a motor can drop 0.4 at most. 1: the collective may also rise for roll/pitch. 2: roll,
    pitch and yaw mixed at once, the collective moved either way, then yaw scaled down.
    """
    r = torque[0] * _SQRT1_2
    p = torque[1] * _SQRT1_2
    a = p - r  # motors 0 (+) and 1 (-)
    b = r + p  # motors 2 (+) and 3 (-)
    t = 0.0 if thrust < 0.0 else 1.0 if thrust > 1.0 else thrust
    y = torque[2]
    if airmode == 2:
        u: Motors = (t + a + y, t - a + y, t + b - y, t - b - y)
        if min(u) < 0.0 or max(u) > 1.0:
            u = _desaturate(u, _THRUST_V)
            u = _desaturate(u, _YAW_V)
    else:
        u = (t + a, t - a, t + b, t - b)
        if min(u) < 0.0 or max(u) > 1.0:
            u = _desaturate(u, _THRUST_V, lower_only=airmode == 0)
            if airmode == 0:
                u = _desaturate(u, _ROLL_V)
                u = _desaturate(u, _PITCH_V)
        if y != 0.0:  # PX4's mixYaw
            u = (u[0] + y, u[1] + y, u[2] - y, u[3] - y)
        if min(u) < 0.0 or max(u) > 1.0:
            u = _desaturate(u, _YAW_V, hi=1.15)
            u = _desaturate(u, _THRUST_V, lower_only=True)
    u0, u1, u2, u3 = u
    return (
        0.0 if u0 < 0.0 else 1.0 if u0 > 1.0 else u0,
        0.0 if u1 < 0.0 else 1.0 if u1 > 1.0 else u1,
        0.0 if u2 < 0.0 else 1.0 if u2 > 1.0 else u2,
        0.0 if u3 < 0.0 else 1.0 if u3 > 1.0 else u3,
    )
