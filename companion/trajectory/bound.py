"""Time-optimal bound: the shortest time to fly the same path under the same speed and
acceleration limits (a lower bound on any trajectory along that path).

Method (time-optimal path parameterisation, TOPP, in the discretised form of TOPP-RA): the
path p(s) is sampled by arc length s; with x = s'^2 and u = s'' the velocity is p_s s' and the
acceleration ``a = p_s u + p_ss x``, so every limit below is linear in (u, x) at each grid
point. A backward pass computes the largest x from which the rest of the path can still stop
at the end (``x_{i+1} = x_i + 2 u_i ds_i``); a forward pass then accelerates as hard as allowed
while staying below it. Each step is a two-variable linear programme solved exactly by
enumerating the vertices of its feasible polygon.

Limits: horizontal speed (per point, e.g. per-leg mission speeds), climb and descent rate,
horizontal acceleration (the disc ``|a_xy| <= a_h`` replaced by the octagon that contains it),
upward and downward acceleration. Jerk, tilt, thrust and body rate are left out: dropping
constraints (and widening the disc) only lowers the optimum, so the result stays a lower
bound for a trajectory that respects all of them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

from companion.trajectory.bezier import PiecewiseBezier

FloatArray = NDArray[np.float64]

__all__ = ["KinematicLimits", "time_optimal_duration", "time_optimal_profile"]

#: Samples per trajectory segment used to discretise the path.
BOUND_SAMPLES_PER_SEGMENT = 40
_OCTAGON = [(math.cos(k * math.pi / 4), math.sin(k * math.pi / 4)) for k in range(8)]


@dataclass(frozen=True)
class KinematicLimits:
    """Kinematic limits of the bound (NED, SI): speeds [m/s] and accelerations [m/s^2]."""

    max_speed_xy_m_s: float
    max_climb_m_s: float
    max_descent_m_s: float
    max_acc_xy_m_s2: float
    max_acc_up_m_s2: float
    max_acc_down_m_s2: float


@lru_cache(maxsize=8)
def _pairs(n: int) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """`np.triu_indices(n, 1)`, computed once per size (read-only)."""
    i, j = np.triu_indices(n, 1)
    i.setflags(write=False)
    j.setflags(write=False)
    return i, j


def _max_x(rows: FloatArray) -> float:
    """Largest x over {(u, x): rows[:, 0] u + rows[:, 1] x <= rows[:, 2]} (a bounded polygon
    containing (0, 0)), by vertex enumeration."""
    a, b, c = rows[:, 0], rows[:, 1], rows[:, 2]
    i, j = _pairs(rows.shape[0])
    det = a[i] * b[j] - a[j] * b[i]
    ok = np.abs(det) > 1e-12
    i, j, det = i[ok], j[ok], det[ok]
    u = (c[i] * b[j] - c[j] * b[i]) / det
    x = (a[i] * c[j] - a[j] * c[i]) / det
    slack = c[None, :] + 1e-9 * (1.0 + np.abs(c[None, :])) - (
        a[None, :] * u[:, None] + b[None, :] * x[:, None]
    )
    feas = np.all(slack >= 0.0, axis=1)
    return float(np.max(x[feas], initial=0.0))


def time_optimal_duration(
    traj: PiecewiseBezier,
    limits: KinematicLimits,
    speed_caps: FloatArray | None = None,
    samples_per_segment: int = BOUND_SAMPLES_PER_SEGMENT,
) -> float:
    """Shortest time [s] to fly the path of `traj` (3-D, NED) from rest to rest under
    `limits` (see the module docstring). ``speed_caps`` (M,): a speed limit along the path
    per segment of `traj` [m/s] (e.g. the planner's per-leg caps)."""
    t, _, _ = time_optimal_profile(traj, limits, speed_caps, samples_per_segment)
    return float(t[-1]) if t.shape[0] else 0.0


def time_optimal_profile(
    traj: PiecewiseBezier,
    limits: KinematicLimits,
    speed_caps: FloatArray | None = None,
    samples_per_segment: int = BOUND_SAMPLES_PER_SEGMENT,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The time-optimal traversal of :func:`time_optimal_duration`: times (N,) [s] from 0,
    points (N, 3) of the path [m] and speeds (N,) [m/s] at them."""
    if traj.dim != 3:
        raise ValueError("the bound needs a 3-D (NED) trajectory")
    n = samples_per_segment
    tau = np.linspace(0.0, 1.0, n, endpoint=False)
    t = np.concatenate(
        [(traj.breaks[:-1, None] + tau[None, :] * traj.durations[:, None]).reshape(-1),
         [traj.duration]]
    )
    seg = np.minimum(np.searchsorted(traj.breaks, t, side="right") - 1, traj.num_segments - 1)
    p = traj.evaluate(t, 0)
    v = traj.evaluate(t, 1)
    a = traj.evaluate(t, 2)
    speed = np.linalg.norm(v, axis=1)
    ds = np.linalg.norm(np.diff(p, axis=0), axis=1)
    keep = np.concatenate([[True], ds > 1e-6])  # drop repeated points (rest at the ends)
    p, v, a, speed, seg = p[keep], v[keep], a[keep], speed[keep], seg[keep]
    if p.shape[0] < 2:
        return np.zeros(1), p[:1], np.zeros(1)
    ds = np.linalg.norm(np.diff(p, axis=0), axis=1)
    # unit tangent and curvature vector d2p/ds2 from the time derivatives
    moving = speed > 1e-6 * max(float(speed.max()), 1e-12)
    tan = np.zeros_like(v)
    tan[moving] = v[moving] / speed[moving, None]
    chord = np.diff(p, axis=0) / np.maximum(ds, 1e-12)[:, None]
    tan[~moving] = np.vstack([chord, chord[-1:]])[~moving]
    curv = np.zeros_like(a)
    along = np.einsum("ij,ij->i", a, tan)
    curv[moving] = (a[moving] - along[moving, None] * tan[moving]) / (speed[moving, None] ** 2)
    vcap_xy = np.full(p.shape[0], limits.max_speed_xy_m_s)
    big = 1e12
    n_pts = p.shape[0]
    x_cap = np.full(n_pts, big)
    if speed_caps is not None:
        x_cap = np.minimum(x_cap, np.asarray(speed_caps, dtype=np.float64)[seg] ** 2)
    t_xy2 = tan[:, 0] ** 2 + tan[:, 1] ** 2
    x_cap = np.where(t_xy2 > 1e-12, np.minimum(x_cap, vcap_xy**2 / np.maximum(t_xy2, 1e-12)), x_cap)
    vz = np.where(tan[:, 2] > 0.0, limits.max_descent_m_s, limits.max_climb_m_s)
    x_cap = np.where(
        tan[:, 2] ** 2 > 1e-12, np.minimum(x_cap, vz**2 / np.maximum(tan[:, 2] ** 2, 1e-12)), x_cap
    )

    def rows_at(i: int) -> list[tuple[float, float, float]]:
        tx, ty, tz = tan[i]
        kx, ky, kz = curv[i]
        rows = [(ex * tx + ey * ty, ex * kx + ey * ky, limits.max_acc_xy_m_s2)
                for ex, ey in _OCTAGON]
        rows.append((tz, kz, limits.max_acc_down_m_s2))
        rows.append((-tz, -kz, limits.max_acc_up_m_s2))
        rows.append((0.0, 1.0, float(x_cap[i])))
        rows.append((0.0, -1.0, 0.0))
        return rows

    # backward pass: largest x at each point from which the end can still be reached at rest
    x_hi = np.zeros(n_pts)
    for i in range(n_pts - 2, -1, -1):
        d2 = 2.0 * float(ds[i])
        rows = rows_at(i)
        rows.append((d2, 1.0, float(x_hi[i + 1])))  # x + 2 u ds <= x_hi[i+1]
        rows.append((-d2, -1.0, 0.0))  # x + 2 u ds >= 0
        rows.append((1.0, 0.0, big))  # keep u bounded
        rows.append((-1.0, 0.0, big))
        x_hi[i] = _max_x(np.asarray(rows, dtype=np.float64))
    # forward pass: as fast as allowed below x_hi
    x = np.zeros(n_pts)
    times = np.zeros(n_pts)
    total = 0.0
    for i in range(n_pts - 1):
        d2 = 2.0 * float(ds[i])
        u_hi = big
        for ca, cb, cc in rows_at(i):
            if ca > 1e-12:
                u_hi = min(u_hi, (cc - cb * x[i]) / ca)
        nxt = min(x[i] + d2 * u_hi, float(x_hi[i + 1]))
        x[i + 1] = max(nxt, 0.0)
        vs = math.sqrt(x[i]) + math.sqrt(x[i + 1])
        total = math.inf if vs <= 0.0 else total + d2 / vs
        times[i + 1] = total
    return times, p, np.sqrt(np.maximum(x, 0.0))
