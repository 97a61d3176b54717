"""Built-in flight patterns (figure8, circle, square) as planned minimum-snap trajectories.

Each pattern starts and ends at rest at `start_ned` (the vehicle's hover position), lies in the
horizontal plane through it, and is flown `laps` times at up to `speed_m_s`.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from companion.flatness.types import MultirotorParams
from companion.trajectory.bezier import PiecewiseBezier
from companion.trajectory.limits import Limits
from companion.trajectory.planner import plan

PATTERNS = ("figure8", "circle", "square")


def pattern_waypoints(
    name: str, start_ned: NDArray[np.float64], size_m: float, laps: int = 1
) -> NDArray[np.float64]:
    """Waypoints (N, 3) NED [m] of a pattern of overall size `size_m` starting at `start_ned`."""
    if name not in PATTERNS:
        raise ValueError(f"unknown pattern {name!r}: choose one of {', '.join(PATTERNS)}")
    if not (math.isfinite(size_m) and size_m > 0.0):
        raise ValueError(f"pattern size must be a positive number of metres, got {size_m}")
    if laps < 1:
        raise ValueError(f"laps must be >= 1, got {laps}")
    p0 = np.asarray(start_ned, dtype=np.float64).reshape(3)
    if name == "square":
        corners = np.array([[0, 0], [size_m, 0], [size_m, size_m], [0, size_m]], dtype=float)
        ne = np.vstack([np.tile(corners, (laps, 1)), corners[:1]])
    else:
        n = 16 * laps
        th = np.linspace(0.0, 2.0 * math.pi * laps, n + 1)
        a = 0.5 * size_m
        if name == "circle":  # start on the circle, centre to the north
            ne = np.column_stack([a * (1.0 - np.cos(th)), a * np.sin(th)])
        else:  # figure8: x = a sin(th), y = (a/2) sin(2 th)
            ne = np.column_stack([a * np.sin(th), 0.5 * a * np.sin(2.0 * th)])
    return np.column_stack([p0[0] + ne[:, 0], p0[1] + ne[:, 1], np.full(len(ne), p0[2])])


def pattern_trajectory(
    name: str,
    start_ned: NDArray[np.float64],
    *,
    size_m: float = 10.0,
    speed_m_s: float = 3.0,
    laps: int = 1,
    yaw: float = 0.0,
    params: MultirotorParams | None = None,
    max_acc_m_s2: float = 3.0,
    max_tilt_rad: float = math.radians(35.0),
) -> PiecewiseBezier:
    """Plan a pattern through `pattern_waypoints` under speed/acceleration (and, with
    `params`, tilt) limits, holding `yaw` [rad]."""
    if not (math.isfinite(speed_m_s) and speed_m_s > 0.0):
        raise ValueError(f"speed must be a positive number of m/s, got {speed_m_s}")
    wps = pattern_waypoints(name, start_ned, size_m, laps)
    limits = Limits(
        max_speed_m_s=speed_m_s,
        max_acc_m_s2=max_acc_m_s2,
        max_tilt_rad=max_tilt_rad if params is not None else None,
    )
    return plan(wps, limits=limits, params=params, yaw=float(yaw))
