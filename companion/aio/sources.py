"""Per-cycle setpoint sources for ``Vehicle.fly``.

A setpoint source is any callable ``source(t_s, telemetry) -> SetpointCommand`` where ``t_s`` is
the trajectory time [s] (0 while priming; starts running when OFFBOARD is confirmed) and
``telemetry`` the latest :class:`~companion.mavlink.TelemetrySnapshot` (its ``now_s`` is the
local monotonic time of the cycle, the clock of every ``t_s`` inside it, for latency
compensation). It runs in the sender thread at the stream rate: keep it short and pure.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Callable
from typing import Any, Protocol

from companion.mavlink import PositionSetpoint, SetpointCommand, TelemetrySnapshot

SetpointSource = Callable[[float, TelemetrySnapshot], SetpointCommand]


class TrajectoryLike(Protocol):
    """What ``fly`` needs from a trajectory (duck-typed ``companion.trajectory.PiecewiseBezier``):
    ``duration`` [s], ``evaluate(t, order)`` -> NED vector (m, m/s, m/s^2), optional ``yaw``
    (an object with ``evaluate(t, order)`` returning [rad] / [rad/s] in element 0)."""

    @property
    def duration(self) -> float: ...

    def evaluate(self, t: float, order: int = 0) -> Any: ...


def _vec3(v: Any) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))


class _FastPiecewise:
    """Pure-Python Horner evaluation of a piecewise polynomial (per-cycle cost ~10 us instead of
    numpy's per-call overhead). Built from ``segments[i].to_monomial()`` (local-time ascending
    coefficients) and ``breaks``; checked against ``evaluate`` at construction."""

    def __init__(self, traj: Any, max_order: int = 2) -> None:
        self.breaks = [float(b) for b in traj.breaks]
        self.duration = float(traj.duration)
        self.coeffs: list[list[list[list[float]]]] = []  # [order][segment][dim][k]
        mono = [[[float(x) for x in row] for row in seg.to_monomial()] for seg in traj.segments]
        for r in range(max_order + 1):
            per_seg = []
            for c in mono:  # c[k][d]
                n1, dim = len(c), len(c[0])
                per_dim = []
                for d in range(dim):
                    ks = []
                    for k in range(n1 - r):
                        f = 1.0
                        for j in range(k + 1, k + r + 1):
                            f *= j
                        ks.append(c[k + r][d] * f)
                    per_dim.append(ks or [0.0])
                per_seg.append(per_dim)
            self.coeffs.append(per_seg)
        for t in (0.0, 0.37 * self.duration, 0.81 * self.duration, self.duration):
            for r in range(max_order + 1):
                ref = traj.evaluate(t, r)
                got = self.evaluate(t, r)
                if any(abs(float(a) - b) > 1e-6 * (1.0 + abs(float(a)))
                       for a, b in zip(ref, got, strict=True)):
                    raise ValueError("fast evaluator disagrees with trajectory.evaluate")

    def evaluate(self, t: float, order: int) -> list[float]:
        t = min(max(t, 0.0), self.duration)
        i = bisect.bisect_right(self.breaks, t) - 1
        i = min(max(i, 0), len(self.breaks) - 2)
        tau = t - self.breaks[i]
        out = []
        for ks in self.coeffs[order][i]:
            acc = 0.0
            for c in reversed(ks):
                acc = acc * tau + c
            out.append(acc)
        return out


def _fast_or_none(traj: Any) -> _FastPiecewise | None:
    if not (hasattr(traj, "segments") and hasattr(traj, "breaks")):
        return None
    try:
        return _FastPiecewise(traj)
    except Exception:  # unknown layout: use the trajectory's own evaluate
        return None


class TrajectoryPositionSource:
    """``position`` mode: SET_POSITION_TARGET_LOCAL_NED from a trajectory.

    feedforward: "acc" (position + velocity + acceleration, the default), "vel" (position +
    velocity) or "none" (position only: the naive baseline). Yaw and yaw rate come from
    ``trajectory.yaw`` if present, else the fixed ``yaw`` [rad] (None: PX4 keeps its heading).
    """

    def __init__(self, trajectory: TrajectoryLike, *, yaw: float | None = None,
                 feedforward: str = "acc") -> None:
        if feedforward not in ("acc", "vel", "none"):
            raise ValueError("feedforward must be 'acc', 'vel' or 'none'")
        self.trajectory = trajectory
        self.duration = float(trajectory.duration)
        self._fast = _fast_or_none(trajectory)
        self._yaw_traj = getattr(trajectory, "yaw", None)
        self._yaw_fast = None if self._yaw_traj is None else _fast_or_none(self._yaw_traj)
        self._yaw = yaw
        self._ff = feedforward

    def __call__(self, t_s: float, telemetry: TelemetrySnapshot) -> PositionSetpoint:
        t = min(max(t_s, 0.0), self.duration)
        ev = self._fast.evaluate if self._fast is not None else self.trajectory.evaluate
        pos = _vec3(ev(t, 0))
        vel = _vec3(ev(t, 1)) if self._ff in ("acc", "vel") else None
        acc = _vec3(ev(t, 2)) if self._ff == "acc" else None
        if t_s >= self.duration:  # hold the end point
            vel = (0.0, 0.0, 0.0) if vel is not None else None
            acc = (0.0, 0.0, 0.0) if acc is not None else None
        yaw: float | None = self._yaw
        yaw_rate: float | None = None
        if self._yaw_traj is not None:
            yev = self._yaw_fast.evaluate if self._yaw_fast is not None else self._yaw_traj.evaluate
            yaw = float(yev(t, 0)[0])
            yaw = math.atan2(math.sin(yaw), math.cos(yaw))
            if self._ff != "none":
                yaw_rate = 0.0 if t_s >= self.duration else float(yev(t, 1)[0])
        return PositionSetpoint(pos_ned=pos, vel_ned=vel, acc_ned=acc, yaw=yaw, yaw_rate=yaw_rate)


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
