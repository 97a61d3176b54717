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


_BIG = 1e12
#: rows per point: 12 of the point's own limits, then 4 of the step to the next point
_N_ROWS = 16
#: the row that holds the next point's bound: x + 2 u ds <= x_hi[i + 1]
_DYN = 12


def _rows(tan: FloatArray, curv: FloatArray, x_cap: FloatArray, ds: FloatArray,
          limits: KinematicLimits) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The limits at each point but the last as rows a u + b x <= c: arrays a, b, c of shape
    (points - 1, 16). Rows 0-7 the horizontal octagon, 8-9 the vertical accelerations, 10 the
    speed cap, 11 x >= 0 (the point's own limits); then the step to the next point (2 ds =
    d2): 12 x + d2 u <= x_hi[i + 1] (its c is left 0: the backward pass fills it in), 13
    x + d2 u >= 0, 14-15 u bounded."""
    m = tan.shape[0] - 1
    a = np.zeros((m, _N_ROWS))
    b = np.zeros((m, _N_ROWS))
    c = np.zeros((m, _N_ROWS))
    tx, ty, tz = tan[:m, 0], tan[:m, 1], tan[:m, 2]
    kx, ky, kz = curv[:m, 0], curv[:m, 1], curv[:m, 2]
    for k, (ex, ey) in enumerate(_OCTAGON):
        a[:, k] = ex * tx + ey * ty
        b[:, k] = ex * kx + ey * ky
        c[:, k] = limits.max_acc_xy_m_s2
    d2 = 2.0 * ds[:m]
    a[:, 8], b[:, 8], c[:, 8] = tz, kz, limits.max_acc_down_m_s2
    a[:, 9], b[:, 9], c[:, 9] = -tz, -kz, limits.max_acc_up_m_s2
    b[:, 10], c[:, 10] = 1.0, x_cap[:m]
    b[:, 11] = -1.0
    a[:, _DYN], b[:, _DYN] = d2, 1.0
    a[:, 13], b[:, 13] = -d2, -1.0
    a[:, 14], c[:, 14] = 1.0, _BIG
    a[:, 15], c[:, 15] = -1.0, _BIG
    return a, b, c


def _backward_pass(a: FloatArray, b: FloatArray, c: FloatArray) -> FloatArray:
    """The largest x at each point from which the rest of the path can still stop at its end:
    for each point, from the last back, the largest x over the feasible vertices of its
    polygon (every pair of its rows, `_rows`, intersected; feasible within 1e-9 relative
    slack on every row; at least 0), with row `_DYN` bounded by the next point's value.

    The vertices of pairs without row `_DYN`, and their feasibility on those rows, are computed
    for every point at once; the sequential pass takes the largest that also meets the bound,
    then the vertices on row `_DYN` (each checked on every row when it could raise the
    maximum). The same vertices, formulas and tolerance as enumerating each point's vertices
    (tests/companion/trajectory/test_fast_paths.py compares it, bit for bit, with the
    enumeration this replaced)."""
    m = a.shape[0]
    x_hi = np.zeros(m + 1)
    if m == 0:
        return x_hi
    pi, pj = _pairs(_N_ROWS)
    keep = (pi != _DYN) & (pj != _DYN)
    pi, pj = pi[keep], pj[keep]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        det = a[:, pi] * b[:, pj] - a[:, pj] * b[:, pi]
        u = (c[:, pi] * b[:, pj] - c[:, pj] * b[:, pi]) / det
        x = (a[:, pi] * c[:, pj] - a[:, pj] * c[:, pi]) / det
        feas = np.abs(det) > 1e-12
        for r in range(_N_ROWS):
            if r != _DYN:
                ar, br, cr = a[:, r:r + 1], b[:, r:r + 1], c[:, r:r + 1]
                feas &= cr + 1e-9 * (1.0 + np.abs(cr)) - (ar * u + br * x) >= 0.0
        # per point the statically feasible vertices that can matter (x > 0: the maximum
        # starts at 0), largest x first
        xs = np.where(feas & (x > 0.0), x, -np.inf)
    order = np.argsort(-xs, axis=1, kind="stable")
    xs_sorted = np.take_along_axis(xs, order, axis=1).tolist()
    us_sorted = np.take_along_axis(u, order, axis=1).tolist()
    al, bl, cl = a.tolist(), b.tolist(), c.tolist()
    tl = (c + 1e-9 * (1.0 + np.abs(c))).tolist()  # each row's c with its slack
    on_dyn = [r for r in range(_N_ROWS) if r != _DYN]
    x_next = 0.0
    for i in range(m - 1, -1, -1):
        ai, bi, ci, ti = al[i], bl[i], cl[i], tl[i]
        di = ai[_DYN]  # 2 ds (its b is 1)
        ci[_DYN] = x_next
        ti[_DYN] = tol = x_next + 1e-9 * (1.0 + abs(x_next))
        best = 0.0
        for xv, uv in zip(xs_sorted[i], us_sorted[i], strict=True):
            if not xv > best:  # sorted: -inf (not feasible, or x <= 0) from here on
                break
            if tol - (di * uv + 1.0 * xv) >= 0.0:
                best = xv
                break
        for r in on_dyn:  # the vertex of rows (r, _DYN), in the pair's order
            ar, br, cr = ai[r], bi[r], ci[r]
            if r < _DYN:
                det_r = ar * 1.0 - di * br
                if not abs(det_r) > 1e-12:
                    continue
                xv = (ar * x_next - di * cr) / det_r
                if not xv > best:
                    continue
                uv = (cr * 1.0 - x_next * br) / det_r
            else:
                det_r = di * br - ar * 1.0
                if not abs(det_r) > 1e-12:
                    continue
                xv = (di * cr - ar * x_next) / det_r
                if not xv > best:
                    continue
                uv = (x_next * br - cr * 1.0) / det_r
            for tq, aq, bq in zip(ti, ai, bi, strict=True):
                if not tq - (aq * uv + bq * xv) >= 0.0:
                    break
            else:
                best = xv
        x_hi[i] = x_next = best
    return x_hi


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
    big = _BIG
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

    ra, rb, rc = _rows(tan, curv, x_cap, ds, limits)
    # backward pass: largest x at each point from which the end can still be reached at rest
    x_hi = _backward_pass(ra, rb, rc)
    # forward pass: as fast as allowed below x_hi (the acceleration limits of the point's own
    # rows, 0-11, whose a > 0)
    accel_rows = [[(ca, cb, cc) for ca, cb, cc in zip(ar[:_DYN], br[:_DYN], cr[:_DYN],
                                                        strict=True) if ca > 1e-12]
                  for ar, br, cr in zip(ra.tolist(), rb.tolist(), rc.tolist(), strict=True)]
    x = np.zeros(n_pts)
    times = np.zeros(n_pts)
    total = 0.0
    for i in range(n_pts - 1):
        d2 = 2.0 * float(ds[i])
        u_hi = big
        for ca, cb, cc in accel_rows[i]:
            u_hi = min(u_hi, (cc - cb * x[i]) / ca)
        nxt = min(x[i] + d2 * u_hi, float(x_hi[i + 1]))
        x[i + 1] = max(nxt, 0.0)
        vs = math.sqrt(x[i]) + math.sqrt(x[i + 1])
        total = math.inf if vs <= 0.0 else total + d2 / vs
        times[i + 1] = total
    return times, p, np.sqrt(np.maximum(x, 0.0))
