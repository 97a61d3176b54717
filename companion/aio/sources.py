"""Per-cycle setpoint sources for ``Vehicle.fly``.

A setpoint source is any callable ``source(t_s, telemetry) -> SetpointCommand`` where ``t_s`` is
the trajectory time [s] (0 while priming; starts running when OFFBOARD is confirmed) and
``telemetry`` the latest :class:`~companion.mavlink.TelemetrySnapshot` (its ``now_s`` is the
local monotonic time of the cycle, the clock of every ``t_s`` inside it, for latency
compensation). It runs in the sender thread at the stream rate: keep it short and pure.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, Protocol

from companion.mavlink import PositionSetpoint, SetpointCommand, TelemetrySnapshot
from companion.mavlink.setpoints import make_position_setpoint

SetpointSource = Callable[[float, TelemetrySnapshot], SetpointCommand]


class TrajectoryLike(Protocol):
    """What ``fly`` needs from a trajectory (duck-typed ``companion.trajectory.PiecewiseBezier``):
    ``duration`` [s], ``evaluate(t, order)`` -> NED vector (m, m/s, m/s^2), optional ``yaw``
    (an object with ``evaluate(t, order)`` returning [rad] / [rad/s] in element 0)."""

    @property
    def duration(self) -> float: ...

    def evaluate(self, t: float, order: int = 0) -> Any: ...


def _values_fn(traj: Any, max_order: int, dim: int) -> Callable[[float], list[float]]:
    """t -> flat [order 0 (dim values), order 1, ..., order max_order] of ``traj``: the
    trajectory layer's cached scalar evaluator when it has one (``PiecewiseBezier``), else its
    ``evaluate`` (duck-typed trajectories)."""
    factory = getattr(traj, "scalar_evaluator", None)
    if factory is not None:
        ev = factory(max_order)
        if ev.dim == dim:
            fn: Callable[[float], list[float]] = ev.values
            return fn

    duration = float(traj.duration)

    def slow(t: float) -> list[float]:
        if t != t:
            raise ValueError("trajectory evaluated at a NaN time")
        t = min(max(t, 0.0), duration)
        out: list[float] = []
        for k in range(max_order + 1):
            v = traj.evaluate(t, k)
            out += [float(v[j]) for j in range(dim)]
        return out

    return slow


class TrajectoryPositionSource:
    """``position`` mode: SET_POSITION_TARGET_LOCAL_NED from a trajectory.

    feedforward: "acc" (position + velocity + acceleration, the default), "vel" (position +
    velocity) or "none" (position only: the naive baseline). Yaw and yaw rate come from
    ``trajectory.yaw`` if present, else the fixed ``yaw`` [rad] (None: PX4 keeps its heading).
    Times before 0 / after the end are clamped (after the end: the end point at rest).
    """

    def __init__(self, trajectory: TrajectoryLike, *, yaw: float | None = None,
                 feedforward: str = "acc") -> None:
        if feedforward not in ("acc", "vel", "none"):
            raise ValueError("feedforward must be 'acc', 'vel' or 'none'")
        self.trajectory = trajectory
        self.duration = float(trajectory.duration)
        orders = {"acc": 2, "vel": 1, "none": 0}[feedforward]
        self._fast = _values_fn(trajectory, orders, 3)
        self._yaw_traj = getattr(trajectory, "yaw", None)
        self._yaw_fast = (None if self._yaw_traj is None else
                          _values_fn(self._yaw_traj, 0 if feedforward == "none" else 1, 1))
        self._yaw = yaw
        self._ff = feedforward

    def __call__(self, t_s: float, telemetry: TelemetrySnapshot) -> PositionSetpoint:
        v = self._fast(t_s)  # clamps t_s to [0, duration]; ValueError on NaN
        ended = t_s >= self.duration
        pos = (v[0], v[1], v[2])
        vel: tuple[float, float, float] | None = None
        acc: tuple[float, float, float] | None = None
        ff = self._ff
        if ff != "none":
            vel = _ZERO3 if ended else (v[3], v[4], v[5])
            if ff == "acc":
                acc = _ZERO3 if ended else (v[6], v[7], v[8])
        yaw: float | None = self._yaw
        yaw_rate: float | None = None
        if self._yaw_fast is not None:
            y = self._yaw_fast(t_s)
            yaw = math.atan2(math.sin(y[0]), math.cos(y[0]))
            if ff != "none":
                yaw_rate = 0.0 if ended else y[1]
        return make_position_setpoint(pos, vel, acc, yaw, yaw_rate)


_ZERO3 = (0.0, 0.0, 0.0)


def hold_setpoint(telemetry: TelemetrySnapshot) -> PositionSetpoint | None:
    """Hold the last known position with zero velocity and the current heading."""
    pos = telemetry.position
    if pos is None:
        return None
    yaw: float | None = None
    if telemetry.attitude is not None:
        w, x, y, z = telemetry.attitude.q_wxyz
        yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return PositionSetpoint(pos_ned=pos.pos_ned, vel_ned=(0.0, 0.0, 0.0), yaw=yaw)
