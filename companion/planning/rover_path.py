"""A car-like rover's trajectory through waypoints: straight legs joined by circular arcs at the
corners, driven at a speed profile that keeps the rover's limits (pure: no I/O).

A minimum-snap polynomial through a right-angle corner swings out before it and overshoots
after it (0.5 m off the legs on the bundled rover square) and, under one time scaling for the
whole path, crawls along the straight legs at the speed the corners allow (rover_corners.plan:
1.2 m/s on 2 m/s legs, 110 s where PX4's AUTO.MISSION takes 57 s). A car turns on an arc:

- each corner is a turn tangent to both legs, inside the corner: its curvature ramps up from
  the leg (over ``RAMP_SHARE`` of its radius), holds 1 / radius, and ramps down again (a
  clothoid-like turn), as tight as the rover steers comfortably (``STEER_MARGIN`` times its
  smallest radius, RA_WHEEL_BASE / tan(RA_MAX_STR_ANG)) or wider while it passes within
  ``CORNER_SHARE`` of the waypoint's acceptance radius, and never taking more than half of
  either leg; a turn that must pass farther from the waypoint than ``CORNER_SHARE_MAX`` of its
  acceptance radius is refused (:class:`SteeringError`);
- the speed along the path is the fastest profile (forward and backward passes over arc
  length) within the legs' speeds, the lateral acceleration and yaw rate on the arcs, and the
  acceleration limit (less the lateral part on the arcs), from rest to rest;
- the path at its profile is sampled every ``KNOT_S`` seconds and stored as the project's
  trajectory form: degree-7 Bezier segments matching position, velocity, acceleration and jerk
  at each knot (Hermite), with the heading as the yaw channel.
"""

from __future__ import annotations

import collections
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from companion.trajectory import PiecewiseBezier, RoverLimits
from companion.trajectory.bezier import hermite_batch

FloatArray = NDArray[np.float64]

__all__ = ["CORNER_SHARE", "CORNER_SHARE_MAX", "KNOT_S", "STEER_MARGIN", "SteeringError",
           "rover_arc_trajectory"]

#: Arcs are at least this many times the rover's smallest turning radius.
STEER_MARGIN = 1.15
#: An arc is as wide as passes within this share of the waypoint's acceptance radius ...
CORNER_SHARE = 0.4
#: ... and one that must pass farther than this share (a rover that cannot steer that tight) is
#: refused.
CORNER_SHARE_MAX = 0.8
#: Time between the knots of the stored trajectory [s].
KNOT_S = 0.2
#: Arc-length step of the speed profile [m]; a straight leg gets at most LINE_SAMPLES samples
#: (its profile is exact in the squared speed at any step), and a trajectory at most MAX_KNOTS
#: knots (on a leg of kilometres they lie on straight motion).
PROFILE_DS_M = 0.02
LINE_SAMPLES = 2000
MAX_KNOTS = 4000
#: The speed profile is smoothed over this much path [m] (`_smooth`).
SMOOTH_M = 0.6
#: The profile keeps this share of every limit (the stored polynomials between knots overshoot
#: the sampled profile by up to ~0.2 %).
PROFILE_MARGIN = 0.99
#: The lateral acceleration takes at most this share of the limit on the acceleration's norm.
LAT_SHARE = 0.94
#: The profile's speeding up and braking keep this share of the acceleration limit (the stored
#: polynomials smooth the profile's acceleration steps and overshoot them by up to ~5 %).
ACC_MARGIN = 0.93
#: Turns smaller than this [rad] are driven straight through.
MIN_TURN_RAD = 1e-4


class SteeringError(ValueError):
    """A rover's path turns tighter than it can steer (stopping at the corners would not help:
    a car-like rover cannot turn in place)."""


#: The curvature of a corner ramps up from the leg over this share of its radius, then holds
#: 1 / radius, then ramps down (a clothoid-like turn: a car cannot step its steering, and a
#: curvature step made the stored polynomials overshoot it by 1.7x).
RAMP_SHARE = 0.5
#: Arc-length step of the corner shapes [m per metre of radius].
SHAPE_DS = 0.002


@dataclass(frozen=True)
class _Corner:
    """The turn replacing corner ``k`` of the polyline: radius [m] (1 / the largest curvature),
    signed turn [rad] (> 0: to the right, north to east), tangent length [m] along each leg
    (where it leaves the incoming leg before the waypoint, and joins the outgoing one after it)
    and its closest approach to the waypoint [m]."""

    radius: float
    turn: float
    tangent: float
    miss: float


def _unit_turn(turn: float) -> tuple[FloatArray, FloatArray, FloatArray, float, float]:
    """A turn of ``turn`` rad at radius 1 (curvature ramps over RAMP_SHARE, then 1): arc length
    (N,), local position (N, 2) from the entry at the origin heading +x, heading (N,), the
    tangent length (entry to the legs' intersection) and the closest approach to that
    intersection. Every length scales with the radius."""
    side = 1.0 if turn > 0.0 else -1.0
    a = abs(turn)
    ramp = min(RAMP_SHARE, a)  # ramps alone turn `ramp` rad at curvature 1
    hold = a - ramp
    total = 2.0 * ramp + hold
    n = max(math.ceil(total / SHAPE_DS), 16)
    sig = np.linspace(0.0, total, n + 1)
    kap = np.clip(np.minimum(sig, total - sig) / ramp, 0.0, 1.0) * side
    psi = np.concatenate([[0.0], np.cumsum(0.5 * (kap[1:] + kap[:-1]) * np.diff(sig))])
    c, sn = np.cos(psi), np.sin(psi)
    x = np.concatenate([[0.0], np.cumsum(0.5 * (c[1:] + c[:-1]) * np.diff(sig))])
    y = np.concatenate([[0.0], np.cumsum(0.5 * (sn[1:] + sn[:-1]) * np.diff(sig))])
    pe = np.array([x[-1], y[-1]])
    lam = float(pe[1] / math.sin(psi[-1]))  # back along the exit heading to the entry line
    vertex = np.array([pe[0] - lam * math.cos(psi[-1]), 0.0])
    pos = np.column_stack([x, y])
    miss = float(np.min(np.linalg.norm(pos - vertex, axis=1)))
    return sig, pos, psi, float(vertex[0]), miss


def _corners(pts: FloatArray, acceptance: Sequence[float], lim: RoverLimits,
             items: Sequence[int | None]) -> list[_Corner]:
    legs = np.diff(pts, axis=0)
    lengths = np.linalg.norm(legs, axis=1)
    unit = legs / lengths[:, None]
    r_steer = (STEER_MARGIN / lim.max_curvature_1_m if lim.max_curvature_1_m is not None
               else 0.0)
    out = [_Corner(math.inf, 0.0, 0.0, 0.0)]
    for k in range(1, len(pts) - 1):
        u_in, u_out = unit[k - 1], unit[k]
        cross = float(u_in[0] * u_out[1] - u_in[1] * u_out[0])
        turn = math.atan2(cross, float(u_in @ u_out))
        if abs(turn) < MIN_TURN_RAD:
            out.append(_Corner(math.inf, 0.0, 0.0, 0.0))
            continue
        if abs(turn) > math.pi - 0.05:
            raise SteeringError(f"the rover's path turns back on itself at item "
                                f"{items[k]}: a car-like rover cannot reverse on the spot")
        _s, _p, _h, t1, d1 = _unit_turn(turn)  # tangent and miss per metre of radius
        acc = float(acceptance[k])
        r_share = CORNER_SHARE * acc / d1
        r_room = 0.5 * min(float(lengths[k - 1]), float(lengths[k])) / t1
        radius = min(max(r_share, r_steer), r_room)
        if radius < r_steer or radius * d1 > CORNER_SHARE_MAX * acc:
            why = ("its legs are too short for the turn" if radius < r_steer else
                   f"the turn would pass {radius * d1:.2f} m from it, beyond "
                   f"{CORNER_SHARE_MAX:g} of its {acc:g} m acceptance radius")
            raise SteeringError(
                f"the rover cannot turn {math.degrees(abs(turn)):.0f} deg at item {items[k]} "
                f"on a radius of at least {r_steer:.2f} m ({STEER_MARGIN:g} x its smallest "
                f"turning radius, RA_WHEEL_BASE / tan(RA_MAX_STR_ANG)): {why}; add waypoints "
                f"that round the corner or widen its acceptance radius")
        out.append(_Corner(radius, turn, radius * t1, radius * d1))
    out.append(_Corner(math.inf, 0.0, 0.0, 0.0))
    return out


def _sample_path(pts: FloatArray, corners: list[_Corner], caps: FloatArray
                 ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    """Arc-length samples of the path: (s [m], position (N, 2), heading [rad, unwrapped],
    signed curvature [1/m], speed cap [m/s])."""
    legs = np.diff(pts, axis=0)
    lengths = np.linalg.norm(legs, axis=1)
    unit = legs / lengths[:, None]
    xs: list[FloatArray] = []
    psis: list[FloatArray] = []
    kappas: list[FloatArray] = []
    cap_s: list[FloatArray] = []
    ss: list[FloatArray] = []
    s0 = 0.0
    psi_prev: float | None = None
    for k in range(len(legs)):
        a = pts[k] + corners[k].tangent * unit[k]
        b = pts[k + 1] - corners[k + 1].tangent * unit[k]
        length = float(np.linalg.norm(b - a))
        n = max(math.ceil(length / max(PROFILE_DS_M, length / LINE_SAMPLES)), 1)
        last = k + 1 == len(legs)
        sig = np.linspace(0.0, length, n + 1) if last else np.linspace(0.0, length, n + 1)[:-1]
        psi = math.atan2(float(unit[k][1]), float(unit[k][0]))
        if psi_prev is not None:
            psi = psi_prev + math.remainder(psi - psi_prev, 2.0 * math.pi)
        xs.append(a + sig[:, None] * unit[k])
        psis.append(np.full(len(sig), psi))
        kappas.append(np.zeros(len(sig)))
        cap_s.append(np.full(len(sig), float(caps[k])))
        ss.append(s0 + sig)
        s0 += length
        psi_prev = psi
        c = corners[k + 1]
        if last or not math.isfinite(c.radius):
            continue
        sig_u, pos_u, psi_u, _t1, _d1 = _unit_turn(c.turn)
        step = max(1, math.ceil(PROFILE_DS_M / (SHAPE_DS * c.radius)))
        idx = np.arange(0, len(sig_u) - 1, step)  # the exit point starts the next leg
        rot = np.array([[math.cos(psi), -math.sin(psi)], [math.sin(psi), math.cos(psi)]])
        xs.append(b + (c.radius * pos_u[idx]) @ rot.T)
        psis.append(psi + psi_u[idx])
        kap = np.gradient(psi_u, sig_u)[idx] / c.radius
        kappas.append(kap)
        cap_s.append(np.full(len(idx), float(min(caps[k], caps[k + 1]))))
        ss.append(s0 + c.radius * sig_u[idx])
        s0 += c.radius * float(sig_u[-1])
        psi_prev = psi + float(psi_u[-1])
    return (np.concatenate(ss), np.concatenate(xs), np.concatenate(psis),
            np.concatenate(kappas), np.concatenate(cap_s))


def _profile(s: FloatArray, kappa: FloatArray, cap: FloatArray, lim: RoverLimits,
             erode_m: float = 0.0) -> FloatArray:
    """Speed [m/s] at each arc-length sample: the fastest rest-to-rest profile within the
    limits (forward and backward passes), the speed limits eroded over ``erode_m`` [m] either
    side."""
    k = np.abs(kappa)
    m = PROFILE_MARGIN
    a_lat = min(lim.max_lat_acc_m_s2, LAT_SHARE * _amax(lim))
    with np.errstate(divide="ignore"):
        v_lat = np.where(k > 0.0, np.sqrt(m * a_lat / np.maximum(k, 1e-12)), np.inf)
        v_yaw = np.where(k > 0.0, m * lim.max_yaw_rate_rad_s / np.maximum(k, 1e-12), np.inf)
    v_lim = _erode(s, np.minimum.reduce([m * cap, np.full(len(s), m * lim.max_speed_m_s),
                                         v_lat, v_yaw]), erode_m)
    return _passes(s, v_lim, _a_lon(v_lim, k, lim))


def _amax(lim: RoverLimits) -> float:
    """The limit on the norm of the acceleration [m/s^2] (the lateral one if none)."""
    return lim.max_acc_m_s2 if lim.max_acc_m_s2 is not None else lim.max_lat_acc_m_s2


def _a_lon(v_lim: FloatArray, k: FloatArray, lim: RoverLimits) -> FloatArray:
    """Speeding-up and braking allowed at each sample [m/s^2]: within ACC_MARGIN of the
    acceleration limit, less the lateral part at the limiting speed (that part is at most
    LAT_SHARE of the limit, so this leaves at least a third)."""
    amax = ACC_MARGIN * _amax(lim)
    a_lat = np.minimum(v_lim**2 * k, LAT_SHARE * amax)
    return np.asarray(np.sqrt(amax**2 - a_lat**2), dtype=np.float64)


def _passes(s: FloatArray, v_lim: FloatArray, a_lon: FloatArray) -> FloatArray:
    """The fastest rest-to-rest speeds within ``v_lim`` and the along-path acceleration
    ``a_lon`` (forward and backward passes over arc length)."""
    ds = np.diff(s)
    v = v_lim.copy()
    v[0] = v[-1] = 0.0
    for i in range(len(ds)):
        v[i + 1] = min(v[i + 1], math.sqrt(v[i] ** 2 + 2.0 * a_lon[i] * ds[i]))
    for i in range(len(ds) - 1, -1, -1):
        v[i] = min(v[i], math.sqrt(v[i + 1] ** 2 + 2.0 * a_lon[i + 1] * ds[i]))
    return np.asarray(v, dtype=np.float64)


def _erode(s: FloatArray, v: FloatArray, half: float) -> FloatArray:
    """Running minimum of ``v`` over the samples within ``half`` [m] of arc length either side
    (a monotone queue: one pass, any sample spacing)."""
    n = len(v)
    out = np.empty(n)
    q: collections.deque[int] = collections.deque()  # indices, values increasing
    hi = 0
    for i in range(n):
        while hi < n and s[hi] <= s[i] + half:
            while q and v[q[-1]] >= v[hi]:
                q.pop()
            q.append(hi)
            hi += 1
        while s[q[0]] < s[i] - half:
            q.popleft()
        out[i] = v[q[0]]
    return out


def _mean(s: FloatArray, v: FloatArray, half: float) -> FloatArray:
    """Running mean of ``v`` over ``half`` [m] of arc length either side (the values beyond the
    ends taken as the ends' own), the ends kept at rest."""
    c = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(s))])
    lo, hi = s - half, s + half
    inner = np.interp(np.minimum(hi, s[-1]), s, c) - np.interp(np.maximum(lo, s[0]), s, c)
    outer = np.maximum(s[0] - lo, 0.0) * v[0] + np.maximum(hi - s[-1], 0.0) * v[-1]
    out = (inner + outer) / (2.0 * half)
    out[0] = out[-1] = 0.0
    return np.asarray(out, dtype=np.float64)


def rover_arc_trajectory(pts: FloatArray, caps: FloatArray, acceptance_m: Sequence[float],
                         lim: RoverLimits, items: Sequence[int | None] | None = None
                         ) -> PiecewiseBezier:
    """The rover's trajectory through ``pts`` (M, 2) north/east [m], at rest at both ends, legs
    capped at ``caps`` (M-1,) [m/s], corners rounded within ``acceptance_m`` (M,) [m] (see the
    module doc); 2-D with the heading as its yaw channel. ``items``: the mission item of each
    point, for messages. SteeringError for a corner the rover cannot drive."""
    p = np.asarray(pts, dtype=np.float64)[:, :2]
    keep = np.concatenate([[True], np.linalg.norm(np.diff(p, axis=0), axis=1) > 1e-6])
    p = p[keep]
    caps_k = np.asarray(caps, dtype=np.float64)[keep[1:]]
    acc = [a for a, kp in zip(acceptance_m, keep, strict=True) if kp]
    names = list(items) if items is not None else [None] * len(keep)
    names = [n for n, kp in zip(names, keep, strict=True) if kp]
    if len(p) < 2:
        raise ValueError("a rover path needs two distinct points")
    corners = _corners(p, acc, lim, names)
    s, xy, psi, kappa, cap = _sample_path(p, corners, caps_k)
    # jerk-limited: the fastest profile within the speed limits eroded over SMOOTH_M, then
    # its running mean over SMOOTH_M (a mean of speeds that are each within every limit
    # anywhere in the window stays within the limit at its centre)
    half = 0.5 * SMOOTH_M
    v = _mean(s, _profile(s, kappa, cap, lim, half), half)
    v = _passes(s, v, _a_lon(v, np.abs(kappa), lim))  # the ends of the mean: from rest again
    ds = np.diff(s)
    dt = 2.0 * ds / np.maximum(v[:-1] + v[1:], 1e-9)
    t = np.concatenate([[0.0], np.cumsum(dt)])
    a_seg = (v[1:] ** 2 - v[:-1] ** 2) / (2.0 * np.maximum(ds, 1e-12))  # dv/dt per interval
    # knots every KNOT_S, at most MAX_KNOTS (the last interval stretched to end at the end)
    n = min(max(math.ceil(t[-1] / KNOT_S), 1), MAX_KNOTS)
    tk = np.linspace(0.0, float(t[-1]), n + 1)
    # the profile is the speed linear in time between its samples (constant acceleration
    # a_seg): distance, speed and acceleration at the knots from that one motion, so they agree
    i = np.clip(np.searchsorted(t, tk, side="right") - 1, 0, len(ds) - 1)
    tau = tk - t[i]
    ak = a_seg[i]
    vk = np.maximum(v[i] + ak * tau, 0.0)
    sk = s[i] + v[i] * tau + 0.5 * ak * tau**2
    vk[0] = vk[-1] = 0.0
    xk = np.column_stack([np.interp(sk, s, xy[:, 0]), np.interp(sk, s, xy[:, 1])])
    hk = np.interp(sk, s, psi)
    kk = np.interp(sk, s, kappa)
    tang = np.column_stack([np.cos(hk), np.sin(hk)])
    norm = np.column_stack([-np.sin(hk), np.cos(hk)])
    ks = np.interp(sk, s, np.gradient(kappa, s))  # dkappa/ds
    vel = vk[:, None] * tang
    accel = ak[:, None] * tang + (vk**2 * kk)[:, None] * norm
    # j = (a' - v^3 k^2) T + (3 v a k + v^3 dk/ds) N, a' from the knots' accelerations
    a_dot = np.gradient(ak, tk)
    jerk = ((a_dot - vk**3 * kk**2)[:, None] * tang
            + (3.0 * vk * ak * kk + vk**3 * ks)[:, None] * norm)
    rate = vk * kk
    rate_d = ak * kk + vk**2 * ks
    rate_dd = np.gradient(rate_d, tk)
    h = np.diff(tk)
    # knot k's position, velocity, acceleration and jerk (k, 4, 2); heading and its rates
    d_xy = np.stack([xk, vel, accel, jerk], axis=1)
    d_yaw = np.stack([hk, rate, rate_d, rate_dd], axis=1)[:, :, None]
    yaw = hermite_batch(d_yaw[:-1], d_yaw[1:], h)
    return hermite_batch(d_xy[:-1], d_xy[1:], h).with_yaw(yaw)
