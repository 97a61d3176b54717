"""Fast numeric evaluation of the flatness maps (numpy, vectorised over samples).

The formulas are those of :mod:`companion.flatness._formulas` (the same code the CasADi
functions are built from), evaluated on Python floats for one sample and on numpy arrays, one per
vector component, for a batch.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

import companion.flatness._formulas as fm
from companion.flatness.types import FloatArray, MultirotorParams, MultirotorSetpoint, RoverSetpoint

__all__ = [
    "multirotor_attitude_scalar",
    "multirotor_setpoint",
    "multirotor_setpoint_scalar",
    "rover_setpoint",
]


def _vec_input(x: npt.ArrayLike, d: int, name: str) -> FloatArray:
    a = np.asarray(x, dtype=np.float64)
    if a.ndim not in (1, 2) or a.shape[-1] != d:
        raise ValueError(f"{name} must have shape ({d},) or (N, {d}), got {a.shape}")
    return a


#: Inputs beyond this magnitude (SI units) are rejected: physically meaningless, and they could
#: overflow the intermediate squares.
INPUT_LIMIT = 1e12
#: Samples per vectorised chunk of the batched path.
_CHUNK = 8192


def _check_finite(arrays: dict[str, FloatArray]) -> None:
    for name, a in arrays.items():
        if not np.all(np.abs(a) <= INPUT_LIMIT):  # False for NaN as well
            raise ValueError(
                f"{name} contains NaN, inf or a value beyond {INPUT_LIMIT:g}: refusing to "
                "compute a setpoint from it"
            )


_NAMES = ("vel", "acc", "jerk", "snap")


def multirotor_setpoint_scalar(
    vel: Sequence[float],
    acc: Sequence[float],
    jerk: Sequence[float],
    snap: Sequence[float],
    yaw: float,
    yaw_rate: float,
    yaw_acc: float,
    params: MultirotorParams,
) -> dict[str, Any]:
    """One-sample multirotor setpoint on plain Python floats (no numpy): the fast path of
    :func:`multirotor_setpoint` for callers running at the setpoint rate.

    Same inputs and units as :func:`multirotor_setpoint` for one sample, given as 3-sequences
    of floats and float scalars. Returns the formula dict of :func:`_formulas.multirotor`:
    ``thrust, thrust_dot, thrust_ddot, thrust_norm`` (float), ``q_wxyz`` (4-tuple), ``C_eb``
    (3 row tuples), ``omega_frd, omega_dot_frd, moment_frd`` (3-tuples), ``flags`` and
    ``singular`` (float). Raises ValueError on a wrong length or a NaN, inf or |value| > 1e12
    input (the same check as the array path); never returns NaN.
    """
    if not len(vel) == len(acc) == len(jerk) == len(snap) == 3:
        for name, x in zip(_NAMES, (vel, acc, jerk, snap), strict=True):
            if len(x) != 3:
                raise ValueError(f"{name} must have shape (3,) or (N, 3), got ({len(x)},)")
    v = (float(vel[0]), float(vel[1]), float(vel[2]))
    a = (float(acc[0]), float(acc[1]), float(acc[2]))
    j = (float(jerk[0]), float(jerk[1]), float(jerk[2]))
    s = (float(snap[0]), float(snap[1]), float(snap[2]))
    y = (float(yaw), float(yaw_rate), float(yaw_acc))
    # float.__ge__ is False for NaN: every |value| must be <= the limit
    if not all(map(INPUT_LIMIT.__ge__, map(abs, (*v, *a, *j, *s, *y)))):
        for name, x in (*zip(_NAMES, (v, a, j, s), strict=True), ("yaw", y[:1]),
                        ("yaw_rate", y[1:2]), ("yaw_acc", y[2:])):
            if not all(abs(c) <= INPUT_LIMIT for c in x):
                _refuse(name)
    return fm.multirotor(
        fm.FLOAT, v, a, j, s, y[0], y[1], y[2],
        params.mass, params.inertia, params.g, params.hover_thrust, params.drag,
    )


def multirotor_attitude_scalar(
    vel: Sequence[float],
    acc: Sequence[float],
    jerk: Sequence[float],
    snap: Sequence[float],
    yaw: float,
    yaw_rate: float,
    yaw_acc: float,
    params: MultirotorParams,
) -> tuple[float, float, float, float, float, float, float, float, bool]:
    """The attitude part of :func:`multirotor_setpoint_scalar`, for the tracking controller.

    Same inputs, input checks and errors. Returns ``(qw, qx, qy, qz, thrust [N], p, q, r
    [rad/s FRD], singular)``: the ``q_wxyz``, ``thrust``, ``omega_frd`` and ``singular != 0``
    of :func:`_formulas.multirotor` evaluated on floats, with the same operations in the same
    order (bit-identical; tests compare the two), but with ``if`` in place of the evaluate-both
    ``where`` and without the outputs the controller does not use (thrust derivatives, angular
    acceleration, moments, flags). `snap` and `yaw_acc` only enter those, so here they are
    only checked.
    """
    if not len(vel) == len(acc) == len(jerk) == len(snap) == 3:
        for name, x in zip(_NAMES, (vel, acc, jerk, snap), strict=True):
            if len(x) != 3:
                raise ValueError(f"{name} must have shape (3,) or (N, 3), got ({len(x)},)")
    vx, vy, vz = float(vel[0]), float(vel[1]), float(vel[2])
    ax, ay, az = float(acc[0]), float(acc[1]), float(acc[2])
    jx, jy, jz = float(jerk[0]), float(jerk[1]), float(jerk[2])
    yaw, yaw_rate = float(yaw), float(yaw_rate)
    s = (float(snap[0]), float(snap[1]), float(snap[2]))
    if not all(map(INPUT_LIMIT.__ge__, map(abs, (vx, vy, vz, ax, ay, az, jx, jy, jz, *s,
                                                 yaw, yaw_rate, float(yaw_acc))))):
        multirotor_setpoint_scalar(vel, acc, jerk, snap, yaw, yaw_rate, yaw_acc, params)
        raise AssertionError("unreachable: the input check above raises")  # pragma: no cover
    sqrt = math.sqrt
    m = params.mass
    D = params.drag
    g = params.g
    # thrust vector t and its first derivative (the second only enters what is not returned)
    t0, t1, t2 = -m * ax - D * vx, -m * ay - D * vy, m * (g - az) - D * vz
    d0, d1, d2 = -m * jx - D * ax, -m * jy - D * ay, -m * jz - D * az
    T = sqrt(t0 * t0 + t1 * t1 + t2 * t2)
    mg = m * g
    low = fm.THRUST_MIN_FRAC * mg > T
    if fm.THRUST_DIR_FRAC * mg > T:
        z0, z1, z2 = 0.0, 0.0, 1.0
    else:
        z0, z1, z2 = t0 / T, t1 / T, t2 / T
    cy = math.cos(yaw)
    sy = math.sin(yaw)
    zc = z0 * cy + z1 * sy
    u0, u1, u2 = cy * z2, sy * z2, -zc
    n = sqrt(z2 * z2 + zc * zc)
    sing = n < fm.COS_ROLL_MIN
    if sing:
        w0, w1, w2 = cy - zc * z0, sy - zc * z1, -zc * z2
        k_w = 1.0 / sqrt(w0 * w0 + w1 * w1 + w2 * w2)
        x0, x1, x2 = w0 * k_w, w1 * k_w, w2 * k_w
    else:
        if abs(z2) < fm.HORIZONTAL_EPS:
            sigma = -1.0 if u2 < 0.0 else 1.0
        else:
            sigma = -1.0 if z2 < 0.0 else 1.0
        k_n = sigma / n
        x0, x1, x2 = u0 * k_n, u1 * k_n, u2 * k_n
    y0, y1, y2 = z1 * x2 - z2 * x1, z2 * x0 - z0 * x2, z0 * x1 - z1 * x0
    if low or sing:
        p = q = r = 0.0
    else:
        p = -(d0 * y0 + d1 * y1 + d2 * y2) / T
        q = (d0 * x0 + d1 * x1 + d2 * x2) / T
        xc_xb = cy * x0 + sy * x1 + 0.0 * x2
        yc_yb = -sy * y0 + cy * y1 + 0.0 * y2
        yc_zb = -sy * z0 + cy * z1
        r = (yaw_rate * xc_xb + q * yc_zb) / yc_yb
    # quaternion of C_eb = [x_b y_b z_b] (columns), Shepperd's method as fm.dcm_to_quat
    e0 = 1.0 + x0 + y1 + z2
    e1 = 1.0 + x0 - y1 - z2
    e2 = 1.0 - x0 + y1 - z2
    e3 = 1.0 - x0 - y1 + z2
    wx, wy, wz = y2 - z1, z0 - x2, x1 - y0
    xy, xz, yz = y0 + x1, z0 + x2, z1 + y2
    e23 = e2 if e2 >= e3 else e3
    if e0 >= (e1 if e1 >= e23 else e23):
        qw, qx, qy, qz = e0, wx, wy, wz
    elif e1 >= e23:
        qw, qx, qy, qz = wx, e1, xy, xz
    elif e2 >= e3:
        qw, qx, qy, qz = wy, xy, e2, yz
    else:
        qw, qx, qy, qz = wz, xz, yz, e3
    n2 = qw * qw + qx * qx + qy * qy + qz * qz
    k = (-1.0 if qw < 0.0 else 1.0) / sqrt(n2 if n2 >= 1e-300 else 1e-300)
    return (qw * k, qx * k, qy * k, qz * k, T, p, q, r, low or sing or z2 <= 0.0)


def _refuse(name: str) -> None:
    raise ValueError(
        f"{name} contains NaN, inf or a value beyond {INPUT_LIMIT:g}: refusing to "
        "compute a setpoint from it"
    )


def multirotor_setpoint(
    vel: npt.ArrayLike,
    acc: npt.ArrayLike,
    jerk: npt.ArrayLike,
    snap: npt.ArrayLike,
    yaw: npt.ArrayLike,
    yaw_rate: npt.ArrayLike,
    yaw_acc: npt.ArrayLike,
    params: MultirotorParams,
) -> MultirotorSetpoint:
    """Multirotor setpoint from the flat outputs (docs/theory/multirotor.md), drag-aware.

    vel, acc, jerk, snap: derivatives of the NED position (m/s, m/s^2, m/s^3, m/s^4), shape (3,)
    for one sample or (N, 3) for a batch. yaw, yaw_rate, yaw_acc: the 3-2-1 yaw and its first two
    time derivatives (rad, rad/s, rad/s^2; not body rates), scalars or (N,) (scalars broadcast
    over a batch). Raises ValueError on shape mismatch or on a NaN, inf or |value| > 1e12 input;
    never returns NaN.
    """
    v = _vec_input(vel, 3, "vel")
    a = _vec_input(acc, 3, "acc")
    j = _vec_input(jerk, 3, "jerk")
    s = _vec_input(snap, 3, "snap")
    psi = np.asarray(yaw, dtype=np.float64)
    dpsi = np.asarray(yaw_rate, dtype=np.float64)
    ddpsi = np.asarray(yaw_acc, dtype=np.float64)
    shapes = {v.shape, a.shape, j.shape, s.shape}
    if len(shapes) != 1:
        raise ValueError(f"vel, acc, jerk, snap must have the same shape, got {sorted(shapes)}")
    J = params.inertia
    if v.ndim == 1:
        for name, y in (("yaw", psi), ("yaw_rate", dpsi), ("yaw_acc", ddpsi)):
            if y.ndim != 0:
                raise ValueError(f"{name} must be a scalar for a single sample, got {y.shape}")
        vl, al, jl, sl = v.tolist(), a.tolist(), j.tolist(), s.tolist()
        yl = (float(psi), float(dpsi), float(ddpsi))
        r = multirotor_setpoint_scalar(vl, al, jl, sl, yl[0], yl[1], yl[2], params)
        flags = int(r["flags"])
        return MultirotorSetpoint(
            thrust=float(r["thrust"]),
            thrust_dot=float(r["thrust_dot"]),
            thrust_ddot=float(r["thrust_ddot"]),
            thrust_norm=float(r["thrust_norm"]),
            q_wxyz=np.array(r["q_wxyz"], dtype=np.float64),
            C_eb=np.array(r["C_eb"], dtype=np.float64),
            omega_frd=np.array(r["omega_frd"], dtype=np.float64),
            omega_dot_frd=np.array(r["omega_dot_frd"], dtype=np.float64),
            moment_frd=np.array(r["moment_frd"], dtype=np.float64),
            singular=bool(r["singular"]),
            flags=flags,
        )
    n = v.shape[0]
    yaws = []
    for name, y in (("yaw", psi), ("yaw_rate", dpsi), ("yaw_acc", ddpsi)):
        if y.ndim == 0:
            y = np.full(n, float(y))
        elif y.shape != (n,):
            raise ValueError(f"{name} must be a scalar or have shape ({n},), got {y.shape}")
        yaws.append(y)
    thrust = np.empty(n)
    thrust_dot = np.empty(n)
    thrust_ddot = np.empty(n)
    thrust_norm = np.empty(n)
    q = np.empty((n, 4))
    C = np.empty((n, 3, 3))
    omega = np.empty((n, 3))
    omega_dot = np.empty((n, 3))
    moment = np.empty((n, 3))
    flag_bits = np.empty(n, dtype=np.int64)
    # Chunks keep the ~250 numpy temporaries in cache (about 2x faster than one pass at 1e5).
    for start in range(0, n, _CHUNK):
        sl = slice(start, start + _CHUNK)
        vc, ac, jc, sc = v[sl], a[sl], j[sl], s[sl]
        yc, yrc, yac = yaws[0][sl], yaws[1][sl], yaws[2][sl]
        _check_finite(
            {
                "vel": vc,
                "acc": ac,
                "jerk": jc,
                "snap": sc,
                "yaw": yc,
                "yaw_rate": yrc,
                "yaw_acc": yac,
            }
        )
        r = fm.multirotor(
            fm.NUMPY,
            (vc[:, 0], vc[:, 1], vc[:, 2]),
            (ac[:, 0], ac[:, 1], ac[:, 2]),
            (jc[:, 0], jc[:, 1], jc[:, 2]),
            (sc[:, 0], sc[:, 1], sc[:, 2]),
            yc,
            yrc,
            yac,
            params.mass,
            J,
            params.g,
            params.hover_thrust,
            params.drag,
        )
        thrust[sl] = r["thrust"]
        thrust_dot[sl] = r["thrust_dot"]
        thrust_ddot[sl] = r["thrust_ddot"]
        thrust_norm[sl] = r["thrust_norm"]
        for k in range(4):
            q[sl, k] = r["q_wxyz"][k]
        for i in range(3):
            omega[sl, i] = r["omega_frd"][i]
            omega_dot[sl, i] = r["omega_dot_frd"][i]
            moment[sl, i] = r["moment_frd"][i]
            for k in range(3):
                C[sl, i, k] = r["C_eb"][i][k]
        flag_bits[sl] = r["flags"]
    return MultirotorSetpoint(
        thrust=thrust,
        thrust_dot=thrust_dot,
        thrust_ddot=thrust_ddot,
        thrust_norm=thrust_norm,
        q_wxyz=q,
        C_eb=C,
        omega_frd=omega,
        omega_dot_frd=omega_dot,
        moment_frd=moment,
        singular=flag_bits != 0,
        flags=flag_bits,
    )


def _wheel_base(wheel_base_m: float | None) -> float | None:
    """The wheel base as a float (m), or ValueError unless finite, > 0 and <= INPUT_LIMIT."""
    if wheel_base_m is None:
        return None
    try:
        L = float(wheel_base_m)
    except (TypeError, ValueError):
        raise ValueError(f"wheel_base_m must be a number (m), got {wheel_base_m!r}") from None
    if not 0.0 < L <= INPUT_LIMIT:  # False for NaN
        raise ValueError(
            f"wheel_base_m must be a finite length > 0 m (at most {INPUT_LIMIT:g}), got {L}"
        )
    return L


def rover_setpoint(
    vel_xy: npt.ArrayLike,
    acc_xy: npt.ArrayLike,
    jerk_xy: npt.ArrayLike | None = None,
    wheel_base_m: float | None = None,
) -> RoverSetpoint:
    """Rover setpoint from the derivatives of the planar NED position (x north, y east):
    vel_xy (m/s), acc_xy (m/s^2), optional jerk_xy (m/s^3), each (2,) or (N, 2).

    Unicycle map (heading, speed, yaw rate); with ``wheel_base_m`` (L > 0, m: rear to front
    axle) also the Ackermann map of a car-like rover (bicycle model about the rear axle):
    curvature, steering angle and their rates (docs/theory/rover.md). ``yaw_acc``,
    ``curvature_rate`` and ``steer_rate`` are None when ``jerk_xy`` is None; the four Ackermann
    fields are None without a wheel base. Raises ValueError on a shape mismatch, a NaN, inf or
    |value| > 1e12 input or a wheel base that is not a finite length > 0. Never returns NaN
    (stopped rover: see :class:`RoverSetpoint`).
    """
    v = _vec_input(vel_xy, 2, "vel_xy")
    a = _vec_input(acc_xy, 2, "acc_xy")
    j = np.zeros_like(v) if jerk_xy is None else _vec_input(jerk_xy, 2, "jerk_xy")
    if not v.shape == a.shape == j.shape:
        raise ValueError(
            f"vel_xy, acc_xy, jerk_xy must have the same shape, got {v.shape}, {a.shape}, {j.shape}"
        )
    _check_finite({"vel_xy": v, "acc_xy": a, "jerk_xy": j})
    L = _wheel_base(wheel_base_m)
    no_jerk = jerk_xy is None
    r: dict[str, Any]
    if v.ndim == 1:
        r = fm.rover(
            fm.FLOAT,
            (float(v[0]), float(v[1])),
            (float(a[0]), float(a[1])),
            (float(j[0]), float(j[1])),
            L,
        )
        if L is None:
            return RoverSetpoint(
                yaw=float(r["yaw"]),
                speed=float(r["speed"]),
                speed_dot=float(r["speed_dot"]),
                yaw_rate=float(r["yaw_rate"]),
                yaw_acc=None if no_jerk else float(r["yaw_acc"]),
                singular=bool(r["singular"]),
            )
        return RoverSetpoint(
            yaw=float(r["yaw"]),
            speed=float(r["speed"]),
            speed_dot=float(r["speed_dot"]),
            yaw_rate=float(r["yaw_rate"]),
            yaw_acc=None if no_jerk else float(r["yaw_acc"]),
            singular=bool(r["singular"]),
            curvature=float(r["curvature"]),
            curvature_rate=None if no_jerk else float(r["curvature_rate"]),
            steer_angle=float(r["steer_angle"]),
            steer_rate=None if no_jerk else float(r["steer_rate"]),
        )
    vT, aT, jT = (np.ascontiguousarray(x.T) for x in (v, a, j))
    r = fm.rover(fm.NUMPY, (vT[0], vT[1]), (aT[0], aT[1]), (jT[0], jT[1]), L)
    return RoverSetpoint(
        yaw=r["yaw"],
        speed=r["speed"],
        speed_dot=r["speed_dot"],
        yaw_rate=r["yaw_rate"],
        yaw_acc=None if no_jerk else r["yaw_acc"],
        singular=r["singular"] != 0.0,
        curvature=r.get("curvature"),
        curvature_rate=None if no_jerk else r.get("curvature_rate"),
        steer_angle=r.get("steer_angle"),
        steer_rate=None if no_jerk else r.get("steer_rate"),
    )
