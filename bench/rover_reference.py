"""The reference of bench_rover_interfaces.py (see its doc) and the errors of one drive against
it: the path (straight, turn, straight), its speed profile, the closest point of the path to a
position, the inverse of PX4's stopping profile; the cross-track, along-track, heading and end
errors of PX4's estimate or of the ground truth, as a rover_link.RoverLink recorded them.
Tested in bench/tests/test_rover_reference.py."""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:
    from rover_link import RoverLink

FloatArray = npt.NDArray[np.float64]
SETTLE_S = 4.0  # after the reference stopped: the end point held this long, then the end error


@dataclass(frozen=True)
class Path2:
    """Straight `leg1_m`, a turn of `turn_rad` (+ = right, clockwise seen from above, NED) on
    radius `radius_m`, straight `leg2_m`; starts at `start` (N, E) [m] heading `heading` [rad]."""

    start: tuple[float, float] = (0.0, 0.0)
    heading: float = 0.0
    leg1_m: float = 20.0
    radius_m: float = 3.0
    turn_rad: float = math.pi / 2
    leg2_m: float = 10.0

    @property
    def arc_m(self) -> float:
        return self.radius_m * abs(self.turn_rad)

    @property
    def length_m(self) -> float:
        return self.leg1_m + self.arc_m + self.leg2_m

    def heading_at(self, s: float) -> float:
        """Tangent angle [rad] at arc length s (clamped to the path)."""
        s = min(max(s, 0.0), self.length_m)
        u = min(max(s - self.leg1_m, 0.0), self.arc_m) / self.arc_m
        return self.heading + self.turn_rad * u

    def curvature_at(self, s: float) -> float:
        """Signed curvature [1/m] (+ = turning right)."""
        inside = self.leg1_m <= s <= self.leg1_m + self.arc_m
        return math.copysign(1.0 / self.radius_m, self.turn_rad) if inside else 0.0

    def point_at(self, s: float) -> tuple[float, float]:
        """(N, E) [m] at arc length s (beyond the ends: along the end tangents)."""
        n0, e0 = self.start
        h = self.heading
        if s <= self.leg1_m:
            return n0 + s * math.cos(h), e0 + s * math.sin(h)
        n1, e1 = n0 + self.leg1_m * math.cos(h), e0 + self.leg1_m * math.sin(h)
        sgn = math.copysign(1.0, self.turn_rad)
        # centre of the turn: to the right (sgn +) or left of the heading
        cn, ce = n1 + self.radius_m * math.cos(h + sgn * math.pi / 2), \
            e1 + self.radius_m * math.sin(h + sgn * math.pi / 2)
        a = min(s - self.leg1_m, self.arc_m) / self.radius_m * sgn
        ang0 = h - sgn * math.pi / 2  # direction centre -> start of the turn
        n2, e2 = cn + self.radius_m * math.cos(ang0 + a), ce + self.radius_m * math.sin(ang0 + a)
        if s <= self.leg1_m + self.arc_m:
            return n2, e2
        h2 = self.heading_at(s)
        d = s - self.leg1_m - self.arc_m
        return n2 + d * math.cos(h2), e2 + d * math.sin(h2)

    def dense(self, step_m: float = 0.02) -> tuple[FloatArray, FloatArray]:
        """(arc lengths (K,), points (K, 2)) every `step_m` along the path."""
        s = np.linspace(0.0, self.length_m, int(self.length_m / step_m) + 1)
        return s, np.array([self.point_at(float(v)) for v in s])


@dataclass(frozen=True)
class SpeedProfile:
    """Speed along the path: from 0 to `speed` over `ramp_s` (smoothstep 3x^2 - 2x^3), constant,
    back to 0 over `ramp_s`, ending at arc length `length_m`."""

    length_m: float
    speed: float = 2.0
    ramp_s: float = 2.5

    @property
    def cruise_s(self) -> float:
        return (self.length_m - self.speed * self.ramp_s) / self.speed

    @property
    def duration_s(self) -> float:
        return 2 * self.ramp_s + self.cruise_s

    def _ramp(self, t: float) -> tuple[float, float]:
        """(distance, speed) of the ramp-up at time t in [0, ramp_s]."""
        x = t / self.ramp_s
        v = self.speed * (3 * x**2 - 2 * x**3)
        d = self.speed * self.ramp_s * (x**3 - 0.5 * x**4)
        return d, v

    def at(self, t: float) -> tuple[float, float]:
        """(arc length [m], speed [m/s]) at time t [s] from the start."""
        r, c = self.ramp_s, self.cruise_s
        if t <= 0.0:
            return 0.0, 0.0
        if t < r:
            return self._ramp(t)
        d_r = 0.5 * self.speed * r
        if t < r + c:
            return d_r + self.speed * (t - r), self.speed
        if t < 2 * r + c:
            d, v = self._ramp(2 * r + c - t)
            return self.length_m - d, v
        return self.length_m, 0.0


class Projector:
    """Closest point of a dense path to a position, optionally searched near a previous one."""

    def __init__(self, path: Path2, step_m: float = 0.02) -> None:
        self.path = path
        self.s, self.pts = path.dense(step_m)

    def closest(self, n: float, e: float, near: float | None = None,
                window_m: tuple[float, float] = (-2.0, 6.0)) -> tuple[float, float]:
        """(arc length of the closest point, signed cross-track error [m], + = right of the
        path). Beyond the ends the error is measured to the extended end tangents."""
        if near is None:
            lo, hi = 0, len(self.s)
        else:
            lo = bisect.bisect_left(self.s, near + window_m[0])
            hi = max(bisect.bisect_right(self.s, near + window_m[1]), lo + 1)
        d = self.pts[lo:hi] - np.array([n, e])
        k = lo + int(np.argmin(np.einsum("ij,ij->i", d, d)))
        s = float(self.s[k])
        h = self.path.heading_at(s)
        pn, pe = self.pts[k]
        dn, de = n - pn, e - pe
        along = dn * math.cos(h) + de * math.sin(h)
        if (k == 0 and along < 0) or (k == len(self.s) - 1 and along > 0):
            s += along  # before the start / after the end: along the end tangent
        cross = -dn * math.sin(h) + de * math.cos(h)  # + = right of the tangent (NED)
        return s, cross


def wrap_angle(a: float) -> float:
    """`a` [rad] in [-pi, pi)."""
    return (a + math.pi) % (2 * math.pi) - math.pi


def stopping_distance(speed: float, decel: float, jerk: float) -> float:
    """Distance [m] to a target at which PX4's rover position control (AckermannPosControl:
    math::trajectory::computeMaxSpeedFromDistance with RO_DECEL_LIM, RO_JERK_LIM, arrival speed
    0) allows `speed`: the inverse of v^2 + (4 a^2 / j) v = 2 a d."""
    return speed * (speed / (2.0 * decel) + 2.0 * decel / jerk)


# ----------------------------------------------------------------------------- errors


def truth_ned(L: RoverLink) -> tuple[FloatArray, FloatArray]:
    """(receive times, (N, 2) true N, E in PX4's local frame) from HIL_STATE_QUATERNION."""
    from companion.mission import GeoPoint, geodetic_to_ned

    if not L.truth or L.home is None:
        return np.zeros(0), np.zeros((0, 2))
    a = np.array(L.truth)
    h = L.home
    g = GeoPoint(h.latitude * 1e-7, h.longitude * 1e-7, h.altitude * 1e-3)
    ned = np.asarray(geodetic_to_ned(a[:, 1], a[:, 2], a[:, 3], g), dtype=np.float64)
    return a[:, 0], ned[:, :2] + np.array([h.x, h.y])


def est_vs_truth(L: RoverLink, t0u: float, t1u: float) -> dict[str, float]:
    """Horizontal distance [m] between PX4's estimate and the truth (interpolated to the
    estimate's receive times) in [t0u, t1u]: RMS and max."""
    tt, tr = truth_ned(L)
    te = np.array([s.t for s in L.lpos])
    pe = np.array([(s.x, s.y) for s in L.lpos]).reshape(-1, 2)
    w = (te >= t0u) & (te <= t1u)
    if len(tt) < 2 or not np.any(w):
        return {}
    d = np.hypot(pe[w, 0] - np.interp(te[w], tt, tr[:, 0]),
                 pe[w, 1] - np.interp(te[w], tt, tr[:, 1]))
    out = {"rms_m": float(np.sqrt(np.mean(d**2))), "max_m": float(np.max(d))}
    # the last 3 s (the reference ended 1 s before): how far estimate and truth travel
    ws = (te >= t1u - 3.0) & (te <= t1u)
    wt = (tt >= t1u - 3.0) & (tt <= t1u)
    if np.count_nonzero(ws) > 1 and np.count_nonzero(wt) > 1:
        out["end_est_travel_m"] = float(np.sum(np.hypot(*np.diff(pe[ws], axis=0).T)))
        out["end_true_travel_m"] = float(np.sum(np.hypot(*np.diff(tr[wt], axis=0).T)))
    ta = np.array([a[0] for a in L.att])
    wa = (ta >= t0u) & (ta <= t1u)
    if np.any(wa):  # PX4's yaw estimate (ATTITUDE) minus the simulator's yaw
        yt = np.unwrap(np.array([r[4] for r in L.truth]))
        ye = np.array([a[2] for a in L.att])[wa]
        dy = np.degrees((ye - np.interp(ta[wa], tt, yt) + np.pi) % (2 * np.pi) - np.pi)
        out.update(yaw_rms_deg=float(np.sqrt(np.mean(dy**2))),
                   yaw_max_deg=float(np.max(np.abs(dy))), yaw_mean_deg=float(np.mean(dy)))
    return out


def errors(L: RoverLink, path: Path2, prof: SpeedProfile, proj: Projector, t0u: float,
           truth: bool) -> dict[str, Any]:
    """Cross-track, along-track and heading errors (RMS, max) over the reference, end error."""
    if truth:
        tt, pos = truth_ned(L)
        if len(tt) == 0:
            return {"error": "no HIL_STATE_QUATERNION / HOME_POSITION"}
    else:
        tt = np.array([s.t for s in L.lpos])
        pos = np.array([(s.x, s.y) for s in L.lpos]).reshape(-1, 2)
    att_t = np.array([a[0] for a in L.att])
    att_yaw = np.unwrap(np.array([a[2] for a in L.att]))
    cross, along, head, speed_ratio = [], [], [], []
    sel = (tt >= t0u) & (tt <= t0u + prof.duration_s)
    idx = np.nonzero(sel)[0]
    s_prev: float | None = None
    for i in idx:
        t = float(tt[i] - t0u)
        s_ref, v_ref = prof.at(t)
        s_c, c = proj.closest(float(pos[i, 0]), float(pos[i, 1]), near=s_prev)
        s_prev = s_c
        cross.append(c)
        along.append(s_ref - s_c)
        if v_ref > 0.5 and len(att_t):
            yaw = float(np.interp(tt[i], att_t, att_yaw))
            head.append(math.degrees(wrap_angle(yaw - path.heading_at(s_c))))
    # speed on the first leg's constant part (true or estimated, from positions)
    r0, r1 = prof.ramp_s + 1.0, min(prof.ramp_s + prof.cruise_s, path.leg1_m / prof.speed)
    w = (tt >= t0u + r0) & (tt <= t0u + r1)
    if np.count_nonzero(w) > 5:
        d = np.linalg.norm(pos[w][-1] - pos[w][0])
        speed_ratio.append(float(d / (tt[w][-1] - tt[w][0]) / prof.speed))
    end = (tt >= t0u + prof.duration_s + SETTLE_S - 0.5) & (tt <= t0u + prof.duration_s + SETTLE_S)
    end_err = (float(np.linalg.norm(pos[end].mean(axis=0) - np.array(path.point_at(
        path.length_m))))) if np.any(end) else math.nan
    arr = [np.asarray(x, dtype=np.float64) for x in (cross, along, head)]

    def rms_max(a: FloatArray) -> tuple[float, float]:
        if len(a) == 0:
            return math.nan, math.nan
        return float(np.sqrt(np.mean(a**2))), float(np.max(np.abs(a)))

    (c_rms, c_max), (a_rms, a_max), (h_rms, h_max) = (rms_max(a) for a in arr)
    return {"samples": len(idx), "cross_rms_m": c_rms, "cross_max_m": c_max,
            "along_rms_m": a_rms, "along_max_m": a_max,
            "along_mean_m": float(np.mean(arr[1])) if len(arr[1]) else math.nan,
            "heading_rms_deg": h_rms, "heading_max_deg": h_max, "end_m": end_err,
            "speed_ratio_leg1": speed_ratio[0] if speed_ratio else math.nan}
