"""The flat-output reference the planner produces and the controller tracks: NED position and
its derivatives with 3-2-1 yaw (`Reference`)."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from companion._frozen import frozen_new

FloatArray = npt.NDArray[np.float64]



def vec3(x: object, name: str) -> FloatArray:
    """`x` as a float64 array of shape (3,); ValueError naming `name` otherwise."""
    if type(x) is np.ndarray and x.dtype == np.float64 and x.shape == (3,):
        return x  # the common case, already what the reshape below would give (a view)
    a = np.asarray(x, dtype=np.float64).reshape(-1)
    if a.shape != (3,):
        raise ValueError(f"{name} must have 3 components, got shape {a.shape}")
    return a



@dataclass(frozen=True)
class Reference:
    """Flat-output reference at one time: NED position and derivatives, 3-2-1 yaw and derivatives.

    pos_ned [m], vel_ned [m/s], acc_ned [m/s^2], jerk_ned [m/s^3], snap_ned [m/s^4] (3,);
    yaw [rad], yaw_rate = d(yaw)/dt [rad/s], yaw_acc [rad/s^2].
    """

    pos_ned: FloatArray
    vel_ned: FloatArray = field(default_factory=lambda: np.zeros(3))
    acc_ned: FloatArray = field(default_factory=lambda: np.zeros(3))
    jerk_ned: FloatArray = field(default_factory=lambda: np.zeros(3))
    snap_ned: FloatArray = field(default_factory=lambda: np.zeros(3))
    yaw: float = 0.0
    yaw_rate: float = 0.0
    yaw_acc: float = 0.0

    def __post_init__(self) -> None:
        for name in ("pos_ned", "vel_ned", "acc_ned", "jerk_ned", "snap_ned"):
            object.__setattr__(self, name, vec3(getattr(self, name), name))

    def is_finite(self) -> bool:
        """All fields finite."""
        return all(
            map(
                math.isfinite,
                [
                    *self.pos_ned.tolist(),
                    *self.vel_ned.tolist(),
                    *self.acc_ned.tolist(),
                    *self.jerk_ned.tolist(),
                    *self.snap_ned.tolist(),
                    self.yaw,
                    self.yaw_rate,
                    self.yaw_acc,
                ],
            )
        )


def reference_of_arrays(
    pos_ned: FloatArray,
    vel_ned: FloatArray,
    acc_ned: FloatArray,
    jerk_ned: FloatArray,
    snap_ned: FloatArray,
    yaw: float,
    yaw_rate: float,
    yaw_acc: float,
) -> Reference:
    """`Reference(...)` from vectors that are already float64 arrays of shape (3,) (what its
    `__post_init__` would make of them; not checked) and float scalars: the per-setpoint fast
    path of the schedule, without the constructor's conversions."""
    return frozen_new(
        Reference, pos_ned=pos_ned, vel_ned=vel_ned, acc_ned=acc_ned, jerk_ned=jerk_ned,
        snap_ned=snap_ned, yaw=yaw, yaw_rate=yaw_rate, yaw_acc=yaw_acc,
    )


def reference_from_trajectory(traj: object, t: float, yaw: float = 0.0) -> Reference:
    """Sample a `PiecewiseBezier`-like trajectory (NED, 3-D) at time `t` [s].

    Needs `.duration`, `.evaluate(t, order)` and `.yaw` (a 1-D trajectory or None). Beyond the
    ends the position holds and the derivatives are zero. Without a yaw channel `yaw` is used.
    """
    duration = float(getattr(traj, "duration"))  # noqa: B009
    evaluate: Callable[[float, int], FloatArray] = getattr(traj, "evaluate")  # noqa: B009
    tc = min(max(t, 0.0), duration)
    inside = 0.0 <= t <= duration
    d = [np.asarray(evaluate(tc, k), dtype=np.float64).reshape(3) for k in range(5)]
    if not inside:
        d[1:] = [np.zeros(3)] * 4
    yaw_traj = getattr(traj, "yaw", None)
    psi, psi_d, psi_dd = yaw, 0.0, 0.0
    if yaw_traj is not None:
        ev: Callable[[float, int], FloatArray] = getattr(yaw_traj, "evaluate")  # noqa: B009
        psi = float(np.asarray(ev(tc, 0)).reshape(-1)[0])
        if inside:
            psi_d = float(np.asarray(ev(tc, 1)).reshape(-1)[0])
            psi_dd = float(np.asarray(ev(tc, 2)).reshape(-1)[0])
    return Reference(d[0], d[1], d[2], d[3], d[4], psi, psi_d, psi_dd)

