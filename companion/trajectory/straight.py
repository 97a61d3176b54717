"""Rest-to-rest motion along one straight line with a speed cap per band (pure numpy).

A chunk whose waypoints all lie on one straight line (a vertical climb or descent, a
straight horizontal leg such as RTL's return) is a one-dimensional problem: the path is the
line, only the speed profile along it is free. Its time-optimal profile under a speed cap per
band and an acceleration limit is a trapezoid per band; this module builds the jerk-limited
version of it directly instead of leaving it to the minimum-snap time allocation (which on such
chunks ends 10-15 % above the time-optimal bound: its speed ripples below the cap during the
cruise and its ramps are slow).

Profile. The arc length s(t) goes through bands (consecutive waypoints) of length L_i with a
speed cap c_i. The speed at each band boundary is the largest that the forward and backward
passes allow (speeds up inside a band only after entering it, slows down before leaving it, so
the speed never exceeds a band's cap inside that band); inside a band it ramps to the highest
cruise speed that still leaves room to ramp to the next boundary speed. A ramp from v_a to v_b
raises the acceleration from 0 to A with the quintic smoothstep S(x) = 10x^3 - 15x^4 + 6x^5
over T_j = 1.875 A / J (its peak jerk is then J), holds it, and lowers it the same way; A is
the acceleration limit for speeding up or for slowing down along the line (NED: PX4's up and
down limits differ), reduced when the speed change is too small to reach it. The velocity is
then symmetric about the ramp's midpoint, so a ramp covers (v_a + v_b) / 2 times its duration.
Acceleration, jerk and snap are zero at each ramp's ends: the position is C4, degree 7, like
the minimum-snap plans (``planner.plan``), and starts and ends at rest.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from companion.trajectory.bezier import FloatArray, PiecewiseBezier

__all__ = [
    "LineLimits", "collinear_direction", "straight_profile", "straight_trajectory",
    "yaw_peak_rate",
]

#: Polynomial degree of every segment (as the minimum-snap planner's).
DEGREE = 7
#: Peak of the quintic smoothstep's derivative: a ramp of the acceleration from 0 to A over
#: T_j has peak jerk 1.875 A / T_j.
_SMOOTH_PEAK = 1.875
#: Bisection steps of the speed searches (relative resolution 2^-60).
_BISECT = 60
#: Pieces shorter than this are dropped [s] (their motion is below round-off).
_MIN_PIECE_S = 1e-9
#: Speed changes below this are not ramped [m/s] (the speed steps by at most this much).
_MIN_SPEED_STEP = 1e-6

# ascending monomial coefficients (in x = t / T_j, x in [0, 1]) of the smoothstep and of its
# first and second integrals (each from 0)
_S = np.array([0.0, 0.0, 0.0, 10.0, -15.0, 6.0, 0.0, 0.0])
_I1 = np.array([0.0, 0.0, 0.0, 0.0, 2.5, -3.0, 1.0, 0.0])
_I2 = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.5, -0.5, 1.0 / 7.0])
_TO_BERNSTEIN = np.array([[math.comb(i, k) / math.comb(DEGREE, k) if k <= i else 0.0
                           for k in range(DEGREE + 1)] for i in range(DEGREE + 1)])


@dataclass(frozen=True)
class LineLimits:
    """Limits along the line: acceleration when speeding up and when slowing down [m/s^2],
    jerk [m/s^3] (all > 0), and a speed-dependent cap on speeding up,
    ``speedup_cap_m_s2 - drag_per_s * v`` (a tilt limit against linear drag: the thrust's
    horizontal part pays for the acceleration and the drag at speed v; inf and 0: none)."""

    acc_up_m_s2: float
    acc_down_m_s2: float
    jerk_m_s3: float
    speedup_cap_m_s2: float = math.inf
    drag_per_s: float = 0.0

    def __post_init__(self) -> None:
        for name in ("acc_up_m_s2", "acc_down_m_s2", "jerk_m_s3", "speedup_cap_m_s2"):
            v = float(getattr(self, name))
            if math.isnan(v) or v <= 0.0:
                raise ValueError(f"{name} must be > 0, got {v}")
        if not (math.isfinite(self.drag_per_s) and self.drag_per_s >= 0.0):
            raise ValueError(f"drag_per_s must be finite and >= 0, got {self.drag_per_s}")
        if not (math.isfinite(self.acc_up_m_s2) and math.isfinite(self.acc_down_m_s2)
                and math.isfinite(self.jerk_m_s3)):
            raise ValueError("accelerations and jerk must be finite")

    def speedup_acc(self, v: float) -> float:
        """Acceleration allowed when speeding up at speed v [m/s^2] (<= 0: none)."""
        return min(self.acc_up_m_s2, self.speedup_cap_m_s2 - self.drag_per_s * v)

    def top_speed(self) -> float:
        """Speed above which speeding up leaves less than a fifth of the cap [m/s]."""
        if self.drag_per_s <= 0.0 or not math.isfinite(self.speedup_cap_m_s2):
            return math.inf
        return 0.8 * self.speedup_cap_m_s2 / self.drag_per_s


def collinear_direction(points: ArrayLike, tol_m: float = 1e-6) -> FloatArray | None:
    """Unit direction (d,) of `points` (M, d) when they lie on one straight line within `tol_m`
    [m] and run monotonically along it from the first to the last (no reversal, no repeated
    point); else None."""
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[0] < 2:
        return None
    d = p[-1] - p[0]
    length = float(np.linalg.norm(d))
    if length <= 10.0 * tol_m:
        return None
    u = d / length
    rel = p - p[0]
    s = rel @ u
    off = rel - s[:, None] * u
    if float(np.max(np.linalg.norm(off, axis=1))) > tol_m:
        return None
    if not bool(np.all(np.diff(s) > tol_m)):
        return None
    return np.asarray(u, dtype=np.float64)


def _ramp_shape(dv: float, acc: float, jerk: float) -> tuple[float, float, float]:
    """(peak acceleration A, smoothstep time T_j, plateau time T_p) of a one-level ramp
    changing the speed by |dv| >= 0."""
    dv = abs(dv)
    if dv <= 0.0:
        return 0.0, 0.0, 0.0
    tj = _SMOOTH_PEAK * acc / jerk
    if dv >= acc * tj:
        return acc, tj, dv / acc - tj
    a = math.sqrt(dv * jerk / _SMOOTH_PEAK)
    return a, _SMOOTH_PEAK * a / jerk, 0.0


def _highest(fits: Callable[[float], bool], lo: float, hi: float) -> float:
    """The largest v in [lo, hi] with fits(v) (fits(lo) holds, fits is monotone)."""
    if fits(hi):
        return hi
    for _ in range(_BISECT):
        mid = 0.5 * (lo + hi)
        if fits(mid):
            lo = mid
        else:
            hi = mid
    return lo


@dataclass(frozen=True)
class _Piece:
    duration_s: float
    coeffs: FloatArray
    """Ascending monomial coefficients of s(tau) [m], tau in [0, duration_s] seconds."""


def _transition(v0: float, a0: float, a1: float, jerk: float) -> tuple[_Piece, float]:
    """The acceleration from a0 to a1 by the smoothstep (peak jerk `jerk`), from s = 0 at
    speed v0: the piece and its end speed."""
    t = _SMOOTH_PEAK * abs(a1 - a0) / jerk
    # acc = a0 + (a1 - a0) S(x): s = v0 t x + a0 t^2 x^2 / 2 + (a1 - a0) t^2 I2(x)
    c = (a1 - a0) * t * t * _I2
    c[1] += v0 * t
    c[2] += 0.5 * a0 * t * t
    return _Piece(t, _to_time(c, t)), v0 + a0 * t + (a1 - a0) * t * float(np.sum(_I1))


def _plateau(v0: float, a: float, t: float) -> tuple[_Piece, float]:
    c = np.zeros(DEGREE + 1)
    c[1], c[2] = v0, 0.5 * a
    return _Piece(t, c), v0 + a * t


#: Acceleration levels of a drag-limited speed-up (each for an equal share of the speed
#: change, at the cap of its upper end).
_SPEEDUP_LEVELS = 4


def _level_ramp(va: float, vb: float, levels: list[float], jerk: float) -> list[_Piece] | None:
    """Speed va -> vb (> va) through the acceleration `levels` (each held until its share of
    the speed change is done, the transitions centred on the shares' ends); None when a
    plateau would be negative (the levels are too far apart for the change)."""
    k = len(levels)
    shares = [va + (vb - va) * (i + 1) / k for i in range(k)]
    acc = [0.0, *levels, 0.0]
    for i in range(2, k + 1):
        # levels equal up to round-off (both at the acceleration cap) are one level: their
        # transition would last ~1e-16 s, and its polynomial's snap is round-off over h^4
        if abs(acc[i] - acc[i - 1]) <= 1e-12 * max(1.0, abs(acc[i])):
            acc[i] = acc[i - 1]
    gains = [0.5 * (acc[i] + acc[i + 1]) * _SMOOTH_PEAK * abs(acc[i + 1] - acc[i]) / jerk
             for i in range(k + 1)]
    out: list[_Piece] = []
    v = va
    for i in range(k + 1):
        if i > 0:
            # plateau at levels[i - 1] until the next transition, centred on the share's end
            end = shares[i - 1] - (gains[i] if i == k else 0.5 * gains[i])
            t = (end - v) / acc[i]
            if t < -1e-9:
                return None
            if t > _MIN_PIECE_S:
                piece, v = _plateau(v, acc[i], t)
                out.append(piece)
        if abs(acc[i + 1] - acc[i]) > 0.0:
            piece, v = _transition(v, acc[i], acc[i + 1], jerk)
            out.append(piece)
    return out


def _ramp(va: float, vb: float, lim: LineLimits) -> list[_Piece]:
    """Pieces from speed va to vb, each with s = 0 at its start (:func:`_ramp_pieces` chains
    them)."""
    if abs(vb - va) <= _MIN_SPEED_STEP:
        return []  # too small to ramp (its pieces would last nanoseconds)
    if vb < va:
        a, tj, tp = _ramp_shape(vb - va, lim.acc_down_m_s2, lim.jerk_m_s3)
        return _level_ramp_down(va, -a, tj, tp, lim.jerk_m_s3)
    if lim.drag_per_s > 0.0 and math.isfinite(lim.speedup_cap_m_s2):
        for k in range(_SPEEDUP_LEVELS, 1, -1):
            step = (vb - va) / k
            levels = [lim.speedup_acc(min(vb, va + step * (i + 1.5))) for i in range(k)]
            if min(levels) > 0.0:
                got = _level_ramp(va, vb, levels, lim.jerk_m_s3)
                if got is not None:
                    return got
    a_top = lim.speedup_acc(vb)
    if a_top <= 0.0:
        raise ValueError(f"no acceleration left at {vb:.2f} m/s along the line")
    a, tj, tp = _ramp_shape(vb - va, a_top, lim.jerk_m_s3)
    got = _level_ramp(va, vb, [a], lim.jerk_m_s3)
    assert got is not None
    return got


def _level_ramp_down(va: float, a: float, tj: float, tp: float, jerk: float) -> list[_Piece]:
    out: list[_Piece] = []
    v = va
    piece, v = _transition(v, 0.0, a, jerk)
    out.append(piece)
    if tp > _MIN_PIECE_S:
        piece, v = _plateau(v, a, tp)
        out.append(piece)
    piece, v = _transition(v, a, 0.0, jerk)
    out.append(piece)
    return out


def _ramp_time_dist(va: float, vb: float, lim: LineLimits) -> tuple[float, float]:
    """Duration [s] and length [m] of the ramp from va to vb."""
    t = d = 0.0
    for p in _ramp(va, vb, lim):
        t += p.duration_s
        d += float(np.sum(p.coeffs * p.duration_s ** np.arange(len(p.coeffs))))
    return t, d


def _ramp_dist(va: float, vb: float, lim: LineLimits) -> float:
    return _ramp_time_dist(va, vb, lim)[1]


def _ramp_pieces(s0: float, va: float, vb: float, lim: LineLimits) -> list[_Piece]:
    """The ramp from va to vb starting at arc length s0 (absolute coefficients)."""
    out: list[_Piece] = []
    s = s0
    for p in _ramp(va, vb, lim):
        c = p.coeffs.copy()
        c[0] += s
        s = float(np.sum(c * p.duration_s ** np.arange(len(c))))
        out.append(_Piece(p.duration_s, c))
    return out


def _to_time(c_x: FloatArray, scale: float) -> FloatArray:
    """Coefficients in x = tau / scale -> coefficients in tau."""
    return np.asarray(c_x / scale ** np.arange(len(c_x)), dtype=np.float64)


def _fits(
    va: float | None, vb: float | None, band: float, lim: LineLimits
) -> Callable[[float], bool]:
    """Whether speed x fits in a band of length `band` [m]: ramping from va to x and from x to
    vb (a None end: no ramp on that side)."""

    def fits(x: float) -> bool:
        d = 0.0 if va is None else _ramp_dist(va, x, lim)
        return d + (0.0 if vb is None else _ramp_dist(x, vb, lim)) <= band

    return fits


def straight_profile(
    lengths_m: ArrayLike, caps_m_s: ArrayLike, lim: LineLimits
) -> tuple[list[tuple[float, FloatArray]], float]:
    """The rest-to-rest speed profile along bands of `lengths_m` (> 0) with speed caps
    `caps_m_s` (> 0): a list of (duration [s], ascending monomial coefficients of the arc
    length s(tau) [m] in the piece's own time tau [s]) and the total length [m]."""
    lengths = np.asarray(lengths_m, dtype=np.float64).reshape(-1)
    caps = np.asarray(caps_m_s, dtype=np.float64).reshape(-1)
    n = len(lengths)
    if n == 0 or caps.shape != lengths.shape:
        raise ValueError("need one speed cap per band and at least one band")
    if not (np.all(lengths > 0.0) and np.all(caps > 0.0) and np.all(np.isfinite(caps))):
        raise ValueError("band lengths and speed caps must be positive and finite")
    # boundary speeds: at most the lower of the two neighbouring caps, rest at both ends
    u = np.zeros(n + 1)
    u[1:-1] = np.minimum(caps[:-1], caps[1:])
    for k in range(n):  # forward: reachable by speeding up inside band k
        if u[k + 1] > u[k]:
            u[k + 1] = _highest(_fits(float(u[k]), None, float(lengths[k]), lim), float(u[k]),
                                float(u[k + 1]))
    for k in range(n - 1, -1, -1):  # backward: able to slow down inside band k
        if u[k] > u[k + 1]:
            u[k] = _highest(_fits(None, float(u[k + 1]), float(lengths[k]), lim),
                            float(u[k + 1]), float(u[k]))
    for k in range(n):  # equal where a ramp between them would be skipped (see _ramp)
        if abs(u[k + 1] - u[k]) <= _MIN_SPEED_STEP:
            u[k + 1] = u[k] = min(u[k], u[k + 1])
    pieces: list[_Piece] = []
    s = 0.0
    for k in range(n):
        va, vb, band, cap = float(u[k]), float(u[k + 1]), float(lengths[k]), float(caps[k])
        lo = max(va, vb)
        w = _highest(_fits(va, vb, band, lim), lo, max(cap, lo))
        if w - lo <= _MIN_SPEED_STEP:
            w = lo
        up = _ramp_pieces(s, va, w, lim)
        s_up = s + _ramp_dist(va, w, lim)
        down_len = _ramp_dist(w, vb, lim)
        cruise = band - (s_up - s) - down_len
        pieces.extend(up)
        if w > 0.0 and cruise / w > _MIN_PIECE_S:
            c = np.zeros(DEGREE + 1)
            c[0], c[1] = s_up, w
            pieces.append(_Piece(cruise / w, c))
        s_dn = s + band - down_len
        pieces.extend(_ramp_pieces(s_dn, w, vb, lim))
        s += band
    return [(p.duration_s, p.coeffs) for p in pieces], float(np.sum(lengths))


def _bezier_points(coeffs_tau: FloatArray, h: float) -> FloatArray:
    """Bezier control points (DEGREE + 1,) of the polynomial with ascending coefficients in
    tau on [0, h]."""
    c = np.zeros(DEGREE + 1)
    c[: len(coeffs_tau)] = coeffs_tau
    a = c * h ** np.arange(DEGREE + 1)  # in x = tau / h
    # monomial -> Bernstein: b_i = sum_{k <= i} C(i, k) / C(n, k) a_k (no solve: a straight
    # piece gets exactly collinear points)
    return np.asarray(_TO_BERNSTEIN @ a, dtype=np.float64)


def straight_trajectory(
    points: ArrayLike,
    caps_m_s: ArrayLike,
    lim: LineLimits,
    yaw: float | tuple[float, float] | None = None,
) -> PiecewiseBezier:
    """Rest-to-rest trajectory through collinear `points` (M, d) (see
    :func:`collinear_direction`; ValueError otherwise) with the speed cap `caps_m_s` (M-1,) on
    each leg. `yaw`: None (no yaw channel), a constant heading [rad], or (start, end) [rad]
    turned with a quintic smoothstep over the whole duration (rest to rest)."""
    p = np.asarray(points, dtype=np.float64)
    u = collinear_direction(p)
    if u is None:
        raise ValueError("the points are not on one straight line, in order")
    s_pts = (p - p[0]) @ u
    pieces, _ = straight_profile(np.diff(s_pts), caps_m_s, lim)
    h = np.array([d for d, _ in pieces])
    s_cp = np.stack([_bezier_points(c, d) for d, c in pieces])  # (K, DEGREE + 1)
    # the last control point of the last piece is the end of the line (round-off)
    cp = p[0][None, None, :] + s_cp[:, :, None] * u[None, None, :]
    cp[-1, -1] = p[-1]
    yaw_ch: PiecewiseBezier | None = None
    if yaw is not None:
        y0, y1 = (float(yaw), float(yaw)) if isinstance(yaw, (int, float)) else (
            float(yaw[0]), float(yaw[1]))
        yaw_ch = _yaw_channel(y0, y1, h)
    return PiecewiseBezier.from_control_points(cp, h, yaw_ch)


def _yaw_channel(y0: float, y1: float, h: FloatArray) -> PiecewiseBezier:
    """y0 + (y1 - y0) S(t / T) over the whole duration T, cut at the segments `h`."""
    breaks = np.concatenate(([0.0], np.cumsum(h)))
    total = float(breaks[-1])
    cps = []
    for t0, d in zip(breaks[:-1], h, strict=True):
        # S((t0 + tau) / T) as a polynomial in tau: expand around t0
        c = _shifted(_S[:6] * (y1 - y0), float(t0), total)
        c[0] += y0
        cps.append(_bezier_points(c, float(d)))
    return PiecewiseBezier.from_control_points(np.stack(cps)[:, :, None], h)


def _shifted(c_x: FloatArray, t0: float, scale: float) -> FloatArray:
    """Coefficients in tau of sum_k c_k ((t0 + tau) / scale)^k."""
    out = np.zeros(len(c_x))
    for k, ck in enumerate(c_x):
        for j in range(k + 1):
            out[j] += ck * math.comb(k, j) * t0 ** (k - j) / scale ** k
    return out


def yaw_peak_rate(y0: float, y1: float, duration_s: float) -> float:
    """Peak yaw rate [rad/s] of :func:`straight_trajectory`'s turn from y0 to y1."""
    return _SMOOTH_PEAK * abs(y1 - y0) / duration_s
