"""Fast numeric evaluation of the flatness maps (numpy, vectorised over samples).

The formulas are those of :mod:`companion.flatness._formulas` (the same code the CasADi
functions are built from), evaluated on Python floats for one sample and on numpy arrays, one per
vector component, for a batch.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from companion.flatness import _formulas as fm
from companion.flatness.types import FloatArray, MultirotorParams, MultirotorSetpoint, RoverSetpoint

__all__ = ["multirotor_setpoint", "rover_setpoint"]


def _vec_input(x: npt.ArrayLike, d: int, name: str) -> FloatArray:
    a = np.asarray(x, dtype=np.float64)
    if a.ndim not in (1, 2) or a.shape[-1] != d:
        raise ValueError(f"{name} must have shape ({d},) or (N, {d}), got {a.shape}")
    return a


def _check_finite(arrays: dict[str, FloatArray]) -> None:
    for name, a in arrays.items():
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{name} contains NaN or inf: refusing to compute a setpoint from it")


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
    """Multirotor setpoint from the flat outputs (MATH.md), drag-aware.

    vel, acc, jerk, snap: derivatives of the NED position (m/s, m/s^2, m/s^3, m/s^4), shape (3,)
    for one sample or (N, 3) for a batch. yaw, yaw_rate, yaw_acc: the 3-2-1 yaw and its first two
    time derivatives (rad, rad/s, rad/s^2; not body rates), scalars or (N,) (scalars broadcast
    over a batch). Raises ValueError on shape mismatch or non-finite input; never returns NaN.
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
        _check_finite(
            {
                "vel": v,
                "acc": a,
                "jerk": j,
                "snap": s,
                "yaw": psi,
                "yaw_rate": dpsi,
                "yaw_acc": ddpsi,
            }
        )
        r = fm.multirotor(
            fm.FLOAT,
            (float(v[0]), float(v[1]), float(v[2])),
            (float(a[0]), float(a[1]), float(a[2])),
            (float(j[0]), float(j[1]), float(j[2])),
            (float(s[0]), float(s[1]), float(s[2])),
            float(psi),
            float(dpsi),
            float(ddpsi),
            params.mass,
            J,
            params.g,
            params.hover_thrust,
            params.drag,
        )
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
    _check_finite(
        {
            "vel": v,
            "acc": a,
            "jerk": j,
            "snap": s,
            "yaw": yaws[0],
            "yaw_rate": yaws[1],
            "yaw_acc": yaws[2],
        }
    )
    vT, aT, jT, sT = (np.ascontiguousarray(x.T) for x in (v, a, j, s))
    r = fm.multirotor(
        fm.NUMPY,
        (vT[0], vT[1], vT[2]),
        (aT[0], aT[1], aT[2]),
        (jT[0], jT[1], jT[2]),
        (sT[0], sT[1], sT[2]),
        yaws[0],
        yaws[1],
        yaws[2],
        params.mass,
        J,
        params.g,
        params.hover_thrust,
        params.drag,
    )
    Crows = r["C_eb"]
    C = np.stack([c for row in Crows for c in row], axis=-1).reshape(n, 3, 3)
    flags_arr = r["flags"].astype(np.int64)
    return MultirotorSetpoint(
        thrust=r["thrust"],
        thrust_dot=r["thrust_dot"],
        thrust_ddot=r["thrust_ddot"],
        thrust_norm=r["thrust_norm"],
        q_wxyz=np.stack(r["q_wxyz"], axis=-1),
        C_eb=C,
        omega_frd=np.stack(r["omega_frd"], axis=-1),
        omega_dot_frd=np.stack(r["omega_dot_frd"], axis=-1),
        moment_frd=np.stack(r["moment_frd"], axis=-1),
        singular=r["singular"] != 0.0,
        flags=flags_arr,
    )


def rover_setpoint(
    vel_xy: npt.ArrayLike,
    acc_xy: npt.ArrayLike,
    jerk_xy: npt.ArrayLike | None = None,
) -> RoverSetpoint:
    """Rover (unicycle) setpoint from the derivatives of the planar NED position (x north,
    y east): vel_xy (m/s), acc_xy (m/s^2), optional jerk_xy (m/s^3), each (2,) or (N, 2).

    ``yaw_acc`` is None when ``jerk_xy`` is None. Never returns NaN (stopped rover: see
    :class:`RoverSetpoint`).
    """
    v = _vec_input(vel_xy, 2, "vel_xy")
    a = _vec_input(acc_xy, 2, "acc_xy")
    j = np.zeros_like(v) if jerk_xy is None else _vec_input(jerk_xy, 2, "jerk_xy")
    if not v.shape == a.shape == j.shape:
        raise ValueError(
            f"vel_xy, acc_xy, jerk_xy must have the same shape, got {v.shape}, {a.shape}, {j.shape}"
        )
    _check_finite({"vel_xy": v, "acc_xy": a, "jerk_xy": j})
    r: dict[str, Any]
    if v.ndim == 1:
        r = fm.rover(
            fm.FLOAT,
            (float(v[0]), float(v[1])),
            (float(a[0]), float(a[1])),
            (float(j[0]), float(j[1])),
        )
        return RoverSetpoint(
            yaw=float(r["yaw"]),
            speed=float(r["speed"]),
            speed_dot=float(r["speed_dot"]),
            yaw_rate=float(r["yaw_rate"]),
            yaw_acc=None if jerk_xy is None else float(r["yaw_acc"]),
            singular=bool(r["singular"]),
        )
    vT, aT, jT = (np.ascontiguousarray(x.T) for x in (v, a, j))
    r = fm.rover(fm.NUMPY, (vT[0], vT[1]), (aT[0], aT[1]), (jT[0], jT[1]))
    return RoverSetpoint(
        yaw=r["yaw"],
        speed=r["speed"],
        speed_dot=r["speed_dot"],
        yaw_rate=r["yaw_rate"],
        yaw_acc=None if jerk_xy is None else r["yaw_acc"],
        singular=r["singular"] != 0.0,
    )
