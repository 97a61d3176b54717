"""The joints of a time-allocated plan: where the extra joints go on the straight waypoint legs
(:func:`ramp_fractions`) and the planning problem over a joint set (:class:`PlanProblem`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from companion.trajectory.allocation import Planner
from companion.trajectory.bezier import FloatArray, PiecewiseBezier
from companion.trajectory.limits import Limits, RoverLimits
from companion.trajectory.yaw import YawSpec

__all__ = [
    "ALLOCATION_PIECES",
    "RAMP_JOINTS",
    "ROVER_ALLOCATION_PIECES",
    "PlanProblem",
    "ramp_fractions",
]

#: Pieces per waypoint leg used by the time allocation (intermediate joints on the straight leg
#: give the speed profile room to accelerate, cruise and brake).
ALLOCATION_PIECES = 3

#: Pieces per waypoint leg of a time-allocated rover plan: joints pinned on the straight legs
#: force tight turns at sharp corners, which the yaw-rate limit then slows down (about 2.7x
#: longer plans with 3 pieces on random 8-10 waypoint sets).
ROVER_ALLOCATION_PIECES = 1


@dataclass(frozen=True)
class PlanProblem:
    """What stays fixed while joints are added on the legs: the waypoints `wp`, the half order
    `s`, the start / end / interior derivative specs, the yaw spec, the per-leg speed caps and
    the limits."""

    wp: FloatArray
    s: int
    start: dict[int, FloatArray | None]
    end: dict[int, FloatArray | None]
    interior: dict[int, dict[int, FloatArray | None]]
    yaw: YawSpec
    yaw_wp: FloatArray | None
    caps: FloatArray | None
    limits: Limits | RoverLimits | None

    def planner(
        self, fracs: list[list[float]]
    ) -> tuple[Planner, NDArray[np.intp], NDArray[np.bool_]]:
        """The planner with extra joints on each straight leg at the fractions `fracs[leg]`
        (each list starts with 0): (planner, leg of each segment, which joints are
        waypoints)."""
        wp = self.wp
        d = wp.shape[1]
        pts: list[FloatArray] = []
        seg_leg: list[int] = []
        for leg, f in enumerate(fracs):
            fa = np.asarray(f, dtype=np.float64)
            pts.append(wp[leg][None, :] + fa[:, None] * (wp[leg + 1] - wp[leg])[None, :])
            seg_leg += [leg] * len(f)
        joints = np.concatenate([*pts, wp[-1:]]).reshape(-1, d)
        is_waypoint = np.zeros(joints.shape[0], dtype=bool)
        starts = np.concatenate([[0], np.cumsum([len(f) for f in fracs])]).astype(np.intp)
        is_waypoint[starts] = True
        interior_j = {int(starts[idx]): spec for idx, spec in self.interior.items()}
        seg_leg_a = np.asarray(seg_leg, dtype=np.intp)
        scale: FloatArray | None = None
        caps, limits = self.caps, self.limits
        if caps is not None and limits is not None and caps.shape[0] == len(fracs):
            scale = np.minimum(caps / limits.max_speed_m_s, 1.0)[seg_leg_a]
        planner = Planner(
            joints, is_waypoint, self.s, self.start, self.end, interior_j, self.yaw,
            self.yaw_wp, speed_scale=scale,
        )
        return planner, seg_leg_a, is_waypoint

    def plan(
        self, fracs: list[list[float]], params: Any, h_in: FloatArray | None
    ) -> tuple[Planner, PiecewiseBezier, float, NDArray[np.intp], NDArray[np.bool_]]:
        """Plan with the joints of :meth:`planner` (durations `h_in`, or allocated under the
        limits): (planner, trajectory, cost, leg of each segment, which joints are
        waypoints)."""
        planner, seg_leg_a, is_waypoint = self.planner(fracs)
        if h_in is None:
            assert self.limits is not None
            h = planner.allocate(self.limits, params)
        else:
            h = h_in
        traj, cost = planner.build(h)
        return planner, traj, cost, seg_leg_a, is_waypoint


#: Joints placed on a leg with a cruise part, at these multiples of the distance the
#: trapezoidal profile needs to accelerate (and, mirrored, to brake): short pieces where the
#: speed changes and one long piece where it cruises.
RAMP_JOINTS = (0.6, 1.4)


def ramp_fractions(
    wp: FloatArray, limits: Limits, params: Any, caps: FloatArray | None
) -> list[list[float]]:
    """Joint fractions per leg for the time allocation: where the leg has a cruise part (the
    trapezoidal speed profile of the polyline, at the real acceleration limit, reaches the
    leg's speed), joints at ``RAMP_JOINTS`` times the acceleration and braking distances from
    its ends; otherwise ``ALLOCATION_PIECES`` equal pieces. The cruise speed also respects the
    steady tilt limit of a vehicle with drag (``g tan(tilt) m / D``)."""
    n_legs = wp.shape[0] - 1
    vmax = np.full(n_legs, limits.max_speed_m_s) if caps is None else np.minimum(
        caps, limits.max_speed_m_s
    )
    amax = limits.max_acc_m_s2
    if limits.max_tilt_rad is not None and params is not None:
        drag = float(getattr(params, "drag", 0.0))
        if drag > 0.0:
            v_tilt = float(params.g) * math.tan(limits.max_tilt_rad) * float(params.mass) / drag
            vmax = np.minimum(vmax, v_tilt)
        amax = min(amax, float(params.g) * math.tan(limits.max_tilt_rad))
    legs = np.diff(wp, axis=0)
    lengths = np.linalg.norm(legs, axis=1)
    unit = legs / np.maximum(lengths, 1e-12)[:, None]
    acc_leg = np.full(n_legs, amax)
    if limits.max_acc_axes_m_s2 is not None and wp.shape[1] == 3:
        # along a leg the per-axis limits allow min(A_h / |u_xy|, A_z / |u_z|)
        a_h, a_up, a_dn = limits.max_acc_axes_m_s2
        u_h = np.hypot(unit[:, 0], unit[:, 1])
        u_z = np.abs(unit[:, 2])
        with np.errstate(divide="ignore"):
            acc_leg = np.minimum(acc_leg, np.minimum(a_h / u_h, min(a_up, a_dn) / u_z))
    # speed at each waypoint: rest at the ends, a corner speed from the turn angle, then the
    # forward-backward acceleration passes
    v = np.zeros(n_legs + 1)
    if n_legs > 1:
        cos_turn = np.clip(np.sum(unit[1:] * unit[:-1], axis=1), -1.0, 1.0)
        v[1:-1] = np.minimum(vmax[1:], vmax[:-1]) * 0.5 * (1.0 + cos_turn)
    for i in range(1, n_legs + 1):
        v[i] = min(v[i], math.sqrt(v[i - 1] ** 2 + 2.0 * acc_leg[i - 1] * lengths[i - 1]))
    for i in range(n_legs - 1, -1, -1):
        v[i] = min(v[i], math.sqrt(v[i + 1] ** 2 + 2.0 * acc_leg[i] * lengths[i]))
    out: list[list[float]] = []
    lo_f, hi_f = RAMP_JOINTS
    for i in range(n_legs):
        length, vc = float(lengths[i]), float(vmax[i])
        base = list(np.arange(ALLOCATION_PIECES, dtype=np.float64) / ALLOCATION_PIECES)
        # ramp joints only where the leg starts or ends at rest (corners keep the equal
        # pieces: short pieces round a corner force a tight turn that slows the whole plan)
        d_acc = vc * vc / (2.0 * acc_leg[i]) if v[i] == 0.0 else 0.0
        d_dec = vc * vc / (2.0 * acc_leg[i]) if v[i + 1] == 0.0 else 0.0
        if length <= 0.0 or hi_f * (d_acc + d_dec) >= 0.9 * length or d_acc + d_dec == 0.0:
            out.append(base)
            continue
        lo_cut = hi_f * d_acc / length
        hi_cut = 1.0 - hi_f * d_dec / length
        f = [x for x in base if x == 0.0 or lo_cut + 0.05 < x < hi_cut - 0.05]
        if d_acc > 0.0:
            f += [lo_f * d_acc / length, lo_cut]
        if d_dec > 0.0:
            f += [hi_cut, 1.0 - lo_f * d_dec / length]
        out.append(sorted(f))
    return out

