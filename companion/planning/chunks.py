"""One stop-to-stop chunk of a flight plan -> one trajectory, under the vehicle's planning limits.

:func:`plan_chunk` plans a chunk: a multirotor chunk on one straight line along the line
(:mod:`companion.trajectory.straight`), any other with the minimum-snap planner at PX4's
per-axis limits; a rover's with joints on its legs (``ROVER_JOINT_PATTERNS``) or the planner's
corridor refinement. The speed caps per leg come from the mission and PX4's parameters
(:func:`leg_speed_caps`); the final descent is cut at PX4's landing heights
(:func:`land_profile`). Pure (numpy + the planner); used by
:func:`companion.planning.schedule.build_schedule`.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from companion.flatness import MultirotorParams
from companion.mission import FlightChunk
from companion.mission.px4_params import Px4PlanningParams
from companion.planning.rover_path import SteeringError, rover_arc_trajectory
from companion.trajectory import Limits, PiecewiseBezier, RoverLimits, check, plan
from companion.trajectory.corridor import corridor_deviation
from companion.trajectory.penalty import ALLOCATION_MARGIN
from companion.trajectory.straight import (
    LineLimits,
    collinear_direction,
    straight_trajectory,
    yaw_peak_rate,
)
from companion.trajectory.yaw import velocity_heading

__all__ = [
    "AXIS_PASSES",
    "LAND_PROFILE_STEPS",
    "ROVER_CORRIDOR_SAMPLES",
    "ROVER_JOINT_MIN_M",
    "ROVER_JOINT_PATTERNS",
    "ROVER_RETRY_MAX_LEGS",
    "STRAIGHT_JERK_M_S3",
    "STRAIGHT_STRETCHES",
    "STRAIGHT_TILT_MARGIN",
    "TILT_FEEDBACK_MARGIN_DEG",
    "TURN_RATE_RAD_S",
    "VehicleLimits",
    "axis_ratios",
    "land_descent_rate",
    "land_profile",
    "leg_speed_caps",
    "level_speed_cap_m_s",
    "plan_chunk",
    "planning_tilt_rad",
]

#: The schedule's logger (a chunk's warnings are the schedule's).
_log = logging.getLogger("companion.planning.schedule")

FloatArray = NDArray[np.float64]

#: Tilt the planner leaves below PX4's MPC_TILTMAX_AIR for the tracking feedback [deg] (the
#: companion's commands are clamped at MPC_TILTMAX_AIR itself; at most half of it is kept).
TILT_FEEDBACK_MARGIN_DEG = 10.0

#: Yaw rate used for in-place turns at stops [rad/s].
TURN_RATE_RAD_S = math.radians(60.0)


@dataclass(frozen=True)
class VehicleLimits:
    """Planning limits of the vehicle (SI units). Cruise speed comes from the mission legs."""

    max_acc_m_s2: float = 5.0
    """Cap on the planned acceleration [m/s^2]; the vehicle's PX4 limits (MPC_ACC_HOR_MAX,
    MPC_ACC_UP_MAX, MPC_ACC_DOWN_MAX, ``FlightPlan.px4``) apply as well."""
    max_tilt_rad: float = math.radians(35.0)
    max_body_rate_rad_s: float = 3.0
    max_thrust_ratio: float = 1.8
    """Peak collective thrust allowed in planning, as a multiple of the hover thrust m g."""
    corridor_m: float | None = 1.0
    """Multirotor: the planned path stays within this distance of the straight mission legs
    [m], except inside a waypoint's acceptance radius; None: no corridor."""
    rover_corridor_m: float | None = None
    """A rover planned with the planner's corridor refinement at this distance [m] (each
    refinement re-runs the rover's exact-extrema allocation: seconds on a 14-waypoint mission);
    None (the default): the rover's legs get joints (``ROVER_JOINT_PATTERNS``, the second only
    on chunks of at most ``ROVER_RETRY_MAX_LEGS`` legs) and the first pattern whose path keeps
    within ``corridor_m`` is flown; if none does (e.g. legs of kilometres: the joints are
    fractions of a leg), the one closest to the legs, with a warning."""
    rover_max_yaw_rate_rad_s: float = math.radians(180.0)
    """The rover's planned yaw rate [rad/s], also capped at PX4's RO_YAW_RATE_LIM (180 deg/s on
    PX4 main's SIH Ackermann airframe, which slows its own AUTO.MISSION corners by it)."""
    rover_max_lat_acc_m_s2: float = 2.0
    """The rover's planned lateral acceleration [m/s^2] (PX4's Ackermann rover has no parameter
    for it). PX4 main's SIH rover, one flight each (its AUTO.MISSION rounds corners at 1.9-2.2
    m/s): at 3.0 the companion came out of rover_stairs.plan's corners 0.5-0.9 m wide (legs RMS
    0.34 m); at 1.5 rover_square took 1.08x AUTO.MISSION's time (1.03x at 2.0 and 3.0) and a
    stairs waypoint 0.50 m off; at 2.0 every waypoint within 0.35 m, legs RMS 0.20-0.22 m."""
    rover_max_speed_m_s: float | None = None
    """Cap on the rover's planned speed [m/s] (leave the controller headroom below the
    vehicle's top speed); None plans at the mission's leg speeds."""
    rover_planner: Literal["arcs", "minsnap"] = "arcs"
    """A rover's path: straight legs joined by arcs inside the corners at a speed profile
    (:mod:`companion.planning.rover_path`), or a minimum-snap polynomial through every
    waypoint (the joints and corridor options above)."""


def planning_tilt_rad(limits: VehicleLimits, px4: Px4PlanningParams) -> float:
    """The tilt limit plans are made with [rad]: the vehicle file's, at most MPC_TILTMAX_AIR
    less TILT_FEEDBACK_MARGIN_DEG (and at least half of MPC_TILTMAX_AIR), so the feedback that
    corrects tracking errors has room before the command clamp."""
    air = px4.MPC_TILTMAX_AIR
    return min(limits.max_tilt_rad, math.radians(max(air - TILT_FEEDBACK_MARGIN_DEG, 0.5 * air)))


def level_speed_cap_m_s(params: MultirotorParams | None, limits: VehicleLimits,
                        px4: Px4PlanningParams) -> float:
    """The fastest steady level flight within the planning tilt [m/s]: the thrust's
    horizontal part, m g tan(tilt), balances the linear drag D v (inf without drag or
    parameters). With PX4 SIH's 1 kg and D = 1 N/(m/s) at 35 deg: 6.9 m/s."""
    if params is None or params.drag <= 0.0:
        return math.inf
    return float(params.g * math.tan(planning_tilt_rad(limits, px4)) * params.mass / params.drag)


#: Climb/descent speed steps between MPC_LAND_ALT1 and MPC_LAND_ALT2 (PX4 interpolates the
#: descent rate linearly in height there; each step flies the lower end's rate).
LAND_PROFILE_STEPS = 8


def leg_speed_caps(
    chunk: FlightChunk, pts: FloatArray, px4: Px4PlanningParams, rover: bool
) -> FloatArray:
    """Speed cap along each leg of `pts` [m/s]: the leg's horizontal speed (its mission speed,
    at most MPC_XY_VEL_MAX; a rover's at most RO_SPEED_LIM) on the horizontal part and the
    climb (MPC_Z_VEL_MAX_UP, or MPC_TKO_SPEED in the takeoff) or descent rate
    (MPC_Z_VEL_MAX_DN) on the vertical part."""
    legs = np.diff(pts, axis=0)
    lengths = np.linalg.norm(legs, axis=1)
    speeds = list(chunk.leg_speed_m_s)
    caps = np.empty(len(legs))
    for i, (d, n) in enumerate(zip(legs, lengths, strict=True)):
        v_h = min(speeds[min(i, len(speeds) - 1)],
                  px4.RO_SPEED_LIM if rover else px4.MPC_XY_VEL_MAX)
        if rover or n <= 0.0:
            caps[i] = max(v_h, 0.1)
            continue
        u_h = math.hypot(float(d[0]), float(d[1])) / n
        u_z = float(d[2]) / n
        if chunk.phase == "takeoff" and u_z < 0.0:
            v_z = px4.MPC_TKO_SPEED
        else:
            v_z = px4.MPC_Z_VEL_MAX_UP if u_z < 0.0 else px4.MPC_Z_VEL_MAX_DN
        cap = math.inf
        if u_h > 1e-6:
            cap = v_h / u_h
        if abs(u_z) > 1e-6:
            cap = min(cap, v_z / abs(u_z))
        caps[i] = max(cap, 0.1)
    return caps


def land_descent_rate(height_m: float, px4: Px4PlanningParams) -> float:
    """PX4's landing descent rate at `height_m` above home [m/s]: MPC_Z_VEL_MAX_DN above
    MPC_LAND_ALT1, MPC_LAND_SPEED below MPC_LAND_ALT2, linear in height between."""
    fast, slow = px4.MPC_Z_VEL_MAX_DN, min(px4.MPC_LAND_SPEED, px4.MPC_Z_VEL_MAX_DN)
    hi, lo = max(px4.MPC_LAND_ALT1, px4.MPC_LAND_ALT2), px4.MPC_LAND_ALT2
    if height_m >= hi:
        return fast
    if height_m <= lo or hi <= lo:
        return slow
    return slow + (fast - slow) * (height_m - lo) / (hi - lo)


def land_profile(
    pts: FloatArray, caps: FloatArray, px4: Px4PlanningParams, ground_z: float
) -> tuple[FloatArray, FloatArray]:
    """The final descent (`pts`, NED) with joints added at PX4's landing heights
    (MPC_LAND_ALT1, steps to MPC_LAND_ALT2) and each piece capped at the descent rate of its
    lower end (:func:`land_descent_rate`): never faster than PX4's own landing."""
    hi, lo = max(px4.MPC_LAND_ALT1, px4.MPC_LAND_ALT2), px4.MPC_LAND_ALT2
    marks = sorted({hi, lo, *(lo + (hi - lo) * j / LAND_PROFILE_STEPS
                              for j in range(1, LAND_PROFILE_STEPS))}, reverse=True)
    out_p: list[FloatArray] = [pts[0]]
    out_c: list[float] = []
    for a, b, cap in zip(pts[:-1], pts[1:], caps, strict=True):
        ha, hb = ground_z - float(a[2]), ground_z - float(b[2])
        cuts = [h for h in marks if min(ha, hb) + 0.05 < h < max(ha, hb) - 0.05]
        # descending: the cut heights in decreasing order
        stops = [*cuts, hb] if hb < ha else [*sorted(cuts), hb]
        for h in stops:
            f = (ha - h) / (ha - hb) if ha != hb else 1.0
            p = a + f * (b - a)
            low = min(h, ground_z - float(out_p[-1][2]))
            rate = land_descent_rate(low, px4)
            dz = abs(float(p[2] - out_p[-1][2]))
            n = float(np.linalg.norm(p - out_p[-1]))
            limit = cap if dz <= 1e-9 or n <= 0.0 else min(cap, rate * n / dz)
            out_p.append(p)
            out_c.append(max(limit, 0.1))
    return np.array(out_p), np.array(out_c)


#: Joints a rover plan puts on each straight leg, as fractions of its length (where it stops
#: accelerating and starts slowing for the next turn, and where the path is pinned to the leg
#: before a corner); legs shorter than ROVER_JOINT_MIN_M get none. The patterns are tried in
#: order and the first whose path keeps within the corridor is flown (see `plan_chunk`).
#: Fewer joints cruise longer but bulge more: on the rover square (30 m legs, 1 m corridor)
#: the first fits at 5 m/s (41.3 s), the second at 2.7 and 1.2 m/s (53.9 / 120.9 s; the
#: two-joint (0.35, 0.65) of before left the corridor at every speed). Each try costs a rover
#: allocation (~30 ms per point: 1.8 s for the second pattern on 13 legs), so the second is
#: tried only on chunks of at most ROVER_RETRY_MAX_LEGS legs.
ROVER_JOINT_PATTERNS: tuple[tuple[float, ...], ...] = (
    (0.3, 0.7),
    (0.2, 0.4, 0.6, 0.8),
)
ROVER_RETRY_MAX_LEGS = 8
ROVER_JOINT_MIN_M = 4.0
#: Samples per segment of a rover plan's corridor check.
ROVER_CORRIDOR_SAMPLES = 64


def _rover_joints(pts: FloatArray, caps: FloatArray, fractions: Sequence[float],
                  ) -> tuple[FloatArray, FloatArray, NDArray[np.intp]]:
    """`pts` with joints at `fractions` of every leg of at least ROVER_JOINT_MIN_M, the speed
    cap of each new segment (its leg's), and the mission leg of each new segment."""
    out_p: list[FloatArray] = [pts[0]]
    out_c: list[float] = []
    out_l: list[int] = []
    for k, (a, b, cap) in enumerate(zip(pts[:-1], pts[1:], caps, strict=True)):
        if float(np.linalg.norm(b[:2] - a[:2])) >= ROVER_JOINT_MIN_M:
            out_p.extend(a + f * (b - a) for f in fractions)
            out_c.extend([float(cap)] * len(fractions))
            out_l.extend([k] * len(fractions))
        out_p.append(b)
        out_c.append(float(cap))
        out_l.append(k)
    return np.array(out_p), np.array(out_c), np.array(out_l, dtype=np.intp)


def _rover_corridor_deviation(traj: PiecewiseBezier, pts: FloatArray,
                              seg_leg: NDArray[np.intp], acceptance_m: Sequence[float]) -> float:
    """The largest distance [m] of the rover path `traj` (one segment per entry of `seg_leg`)
    from the straight legs through `pts` (2D), outside the points' acceptance radii, at
    ROVER_CORRIDOR_SAMPLES samples per segment (ends included)."""
    n = ROVER_CORRIDOR_SAMPLES
    starts = np.concatenate([[0.0], np.cumsum(traj.durations)[:-1]])
    t = (starts[:, None] + traj.durations[:, None] * np.linspace(0.0, 1.0, n)[None, :])
    p = traj.evaluate(t.reshape(-1), 0)
    legs = np.repeat(seg_leg, n)
    dev = corridor_deviation(p, pts[:, :2], legs, np.asarray(acceptance_m, dtype=np.float64))
    return float(np.max(dev))


#: A rover plans at this share of PX4's RO_SPEED_LIM and of its RO_ACCEL_LIM / RO_DECEL_LIM (the
#: norm of the acceleration: speeding up, braking and turning together). Both are the whole
#: limit: PX4 clamps the speed command at RO_SPEED_LIM and slews it at RO_ACCEL_LIM itself, and
#: its own AUTO.MISSION drives at them (SIH Ackermann rover, rover_square: 2.5-3.1 m/s on the
#: legs, estimate; 2.8 m/s one second after the start); its speed loop is mostly throttle
#: feed-forward (15-18 % over a 2 m/s command, truth), so the controller's learnt speed ratio
#: leaves the along-track feedback some room, and a rover that cannot keep up is waited for
#: (ProgressGovernor). At 0.9 / 0.8 (session 19) the companion took 1.17x AUTO.MISSION's time
#: on rover_square.
ROVER_SPEED_SHARE = 1.0
ROVER_ACC_SHARE = 1.0


def rover_limits(limits: VehicleLimits, px4: Px4PlanningParams, speed_m_s: float) -> RoverLimits:
    """A rover's planning limits: ``speed_m_s`` (the chunk's fastest leg) within
    ROVER_SPEED_SHARE of RO_SPEED_LIM (and the vehicle file's cap), the companion's yaw-rate and
    lateral-acceleration caps within RO_YAW_RATE_LIM, ROVER_ACC_SHARE of the smaller of
    RO_ACCEL_LIM and RO_DECEL_LIM, and the Ackermann curvature tan(RA_MAX_STR_ANG) /
    RA_WHEEL_BASE."""
    v = min(speed_m_s, ROVER_SPEED_SHARE * px4.RO_SPEED_LIM)
    if limits.rover_max_speed_m_s is not None:
        v = min(v, limits.rover_max_speed_m_s)
    return RoverLimits(
        max_speed_m_s=max(v, 0.1),
        max_yaw_rate_rad_s=min(limits.rover_max_yaw_rate_rad_s, math.radians(px4.RO_YAW_RATE_LIM)),
        max_lat_acc_m_s2=limits.rover_max_lat_acc_m_s2,
        max_acc_m_s2=ROVER_ACC_SHARE * min(px4.RO_ACCEL_LIM, px4.RO_DECEL_LIM),
        max_curvature_1_m=px4.rover_max_curvature_1_m,
    )


def _plan_rover_chunk(chunk: FlightChunk, pts: FloatArray, limits: VehicleLimits,
                      caps: FloatArray, speed: float, px4: Px4PlanningParams) -> PiecewiseBezier:
    """A rover chunk (see :func:`plan_chunk`) under :func:`rover_limits`; SteeringError when
    its path turns tighter than the rover can steer."""
    lim = rover_limits(limits, px4, speed)
    caps = np.minimum(caps, lim.max_speed_m_s)
    if limits.rover_planner == "arcs":
        traj = rover_arc_trajectory(pts[:, :2], caps, chunk.acceptance_radius_m, lim,
                                    chunk.item_indices)
        _require_steerable(traj, lim, chunk)
        return traj
    whole = len(pts) == len(chunk.points_ned_m)
    corridor = limits.rover_corridor_m if whole else None
    if corridor is not None:
        traj = plan(pts[:, :2], limits=lim, yaw="velocity", speed_caps=caps,
                    corridor_m=corridor, acceptance_m=chunk.acceptance_radius_m)
        _require_steerable(traj, lim, chunk)
        return traj
    # joints on the straight legs: one polynomial per leg has a bell-shaped speed profile (a
    # 30 m leg at 2.7 m/s took 24 s) and bulges off the leg (7.6 m on the rover square); joints
    # let it cruise between the turns and pin it to the legs. The first pattern whose path keeps
    # within the corridor (and within the steering) is flown; if none does, the closer one,
    # with a warning (the planner's corridor refinement is rover_corridor_m's: seconds per
    # chunk).
    check_m = limits.corridor_m if whole else None
    best: tuple[float, PiecewiseBezier] | None = None
    tries = (ROVER_JOINT_PATTERNS if len(pts) - 1 <= ROVER_RETRY_MAX_LEGS
             else ROVER_JOINT_PATTERNS[:1])
    steer_error: SteeringError | None = None
    for fractions in tries:
        jp, jc, seg_leg = _rover_joints(pts, caps, fractions)
        traj = plan(jp[:, :2], limits=lim, yaw="velocity", speed_caps=jc)
        try:
            _require_steerable(traj, lim, chunk)
        except SteeringError as exc:
            steer_error = exc
            continue
        if check_m is None:
            return traj
        dev = _rover_corridor_deviation(traj, pts, seg_leg, chunk.acceptance_radius_m)
        if dev <= check_m:
            return traj
        if best is None or dev < best[0]:
            best = (dev, traj)
    if best is None:
        assert steer_error is not None
        raise steer_error
    _log.warning("the rover's path leaves the %g m corridor around the legs by up to "
                 "%.1f m (legs of %.0f m at most; set VehicleLimits.rover_corridor_m "
                 "to plan it inside, slower)", check_m, best[0],
                 float(np.max(np.linalg.norm(np.diff(pts[:, :2], axis=0), axis=1))))
    return best[1]


def _require_steerable(traj: PiecewiseBezier, lim: RoverLimits, chunk: FlightChunk) -> None:
    """ValueError naming the chunk's items when `traj` turns tighter than ``lim``'s curvature
    (a car-like rover cannot follow it: it has a smallest turning radius)."""
    k_max = lim.max_curvature_1_m
    if k_max is None:
        return
    rep = check(traj, lim, only=("curvature",))["curvature"]
    if not rep.exceeded:
        return
    items = ", ".join(str(i) for i in chunk.item_indices if i is not None)
    raise SteeringError(
        f"the rover's path through items {items} turns with a radius of {1.0 / rep.worst:.2f} m "
        f"at t = {rep.time_s:.1f} s, tighter than it can steer (smallest turning radius "
        f"{1.0 / k_max:.2f} m: RA_WHEEL_BASE / tan(RA_MAX_STR_ANG)); add waypoints that "
        f"round the corner")


def plan_chunk(
    chunk: FlightChunk,
    pts: FloatArray,
    params: MultirotorParams | None,
    limits: VehicleLimits,
    rover: bool,
    yaw_spec: object,
    caps: FloatArray,
    px4: Px4PlanningParams,
) -> PiecewiseBezier:
    """The trajectory of one stop-to-stop `chunk` through `pts` (NED [m]; the chunk's points,
    with the final descent cut and profiled by the caller), at rest at both ends, with the
    leg speed caps `caps` [m/s] (one per leg of `pts`) under `limits` and PX4's `px4` limits;
    `yaw_spec` as ``plan``'s ``yaw``. ValueError when the planner cannot plan it."""
    speed = max(float(np.max(caps)), 0.1)
    lim: Limits | RoverLimits
    if rover:
        return _plan_rover_chunk(chunk, pts, limits, caps, speed, px4)
    vertical = chunk.phase in ("takeoff", "land")
    hover_n = params.mass * params.g if params is not None else None
    acc = limits.max_acc_m_s2
    lim = Limits(
        max_speed_m_s=speed,
        max_acc_m_s2=min(acc, 1.5) if vertical else acc,
        max_acc_axes_m_s2=(px4.MPC_ACC_HOR_MAX, px4.MPC_ACC_UP_MAX, px4.MPC_ACC_DOWN_MAX),
        max_vel_axes_m_s=(
            px4.MPC_XY_VEL_MAX,
            px4.MPC_TKO_SPEED if chunk.phase == "takeoff" else px4.MPC_Z_VEL_MAX_UP,
            px4.MPC_Z_VEL_MAX_DN,
        ),
        max_tilt_rad=planning_tilt_rad(limits, px4) if params is not None else None,
        max_thrust_n=limits.max_thrust_ratio * hover_n if hover_n is not None else None,
        max_body_rate_rad_s=limits.max_body_rate_rad_s if params is not None else None,
    )
    yaw: object = yaw_spec
    if isinstance(yaw_spec, Sequence) and not isinstance(yaw_spec, str):
        yaw = [float(v) for v in yaw_spec]
    # a straight chunk at PX4's own accelerations (the vertical cap above is for the
    # minimum-snap plans of climbs and descents)
    straight = _straight_chunk(pts, caps, dataclasses.replace(lim, max_acc_m_s2=acc), params,
                               px4, yaw, chunk.phase)
    if straight is not None:
        return straight
    with_corridor = (
        limits.corridor_m is not None and not vertical and len(pts) == len(chunk.points_ned_m)
    )
    # a heading that follows the velocity is fitted after the position: the body-rate limit
    # then bounds the translation, and tight corners are not slowed down for the yaw
    follow = isinstance(yaw, str) and yaw == "velocity"
    for _ in range(AXIS_PASSES):
        traj = plan(
            pts,
            limits=lim,
            params=params,
            yaw=None if follow else yaw,  # type: ignore[arg-type]
            speed_caps=caps,
            corridor_m=limits.corridor_m if with_corridor else None,
            acceptance_m=chunk.acceptance_radius_m if with_corridor else None,
        )
        # the planner bounds the norms; PX4's limits are per axis (horizontal, up, down):
        # lower the acceleration or the speed caps until each axis is within its own
        r_vel, r_acc = axis_ratios(traj, px4, climb_m_s=(
            px4.MPC_TKO_SPEED if chunk.phase == "takeoff" else px4.MPC_Z_VEL_MAX_UP))
        if r_vel <= 1.0 + 1e-3 and r_acc <= 1.0 + 1e-3:
            break
        if r_acc > 1.0 + 1e-3:
            axes = lim.max_acc_axes_m_s2
            lim = dataclasses.replace(
                lim, max_acc_m_s2=lim.max_acc_m_s2 / r_acc,
                max_acc_axes_m_s2=None if axes is None else (
                    axes[0] / r_acc, axes[1] / r_acc, axes[2] / r_acc),
            )
        if r_vel > 1.0 + 1e-3:
            caps = caps / r_vel
            vax = lim.max_vel_axes_m_s
            lim = dataclasses.replace(
                lim, max_speed_m_s=lim.max_speed_m_s / r_vel,
                max_vel_axes_m_s=None if vax is None else (
                    vax[0] / r_vel, vax[1] / r_vel, vax[2] / r_vel),
            )
    if not follow:
        return traj
    # the heading turns no faster than the planned body-rate limit (below PX4's MC_YAWRATE_MAX)
    rate = None if lim.max_body_rate_rad_s is None else min(
        lim.max_body_rate_rad_s, math.radians(px4.MC_YAWRATE_MAX))
    return traj.with_yaw(velocity_heading(traj, rate))


#: Re-plans of a chunk that exceeds one of PX4's per-axis limits.
AXIS_PASSES = 4

#: Jerk along a straight chunk [m/s^3] (:mod:`companion.trajectory.straight`): a vertical
#: speed change of 1.5 m/s takes 0.75 s, a horizontal one of 5 m/s 1.4 s; on a horizontal
#: line the body rate stays near jerk / g (about 2 rad/s).
STRAIGHT_JERK_M_S3 = 20.0
#: Uniform stretches of a straight chunk over a tilt, thrust or body-rate limit (each 3 %)
#: before it is left to the minimum-snap planner.
STRAIGHT_STRETCHES = 20
#: Share of the tilt limit's horizontal acceleration a straight chunk plans with.
STRAIGHT_TILT_MARGIN = 0.97


def _straight_chunk(
    pts: FloatArray,
    caps: FloatArray,
    lim: Limits,
    params: MultirotorParams | None,
    px4: Px4PlanningParams,
    yaw: object,
    phase: str,
) -> PiecewiseBezier | None:
    """A multirotor chunk whose points lie on one straight line (a climb, a descent, a straight
    leg) planned along the line (:func:`straight_trajectory`: within a few % of the
    time-optimal bound instead of 10-15 % above it), or None when it is not one or its plan
    would exceed a limit even when stretched (the minimum-snap planner then plans it)."""
    u = collinear_direction(pts)
    if u is None or len(u) != 3:
        return None
    spec: float | tuple[float, float]
    if isinstance(yaw, float):
        spec = yaw
    elif isinstance(yaw, str) and yaw == "velocity" and math.hypot(u[0], u[1]) > 0.5:
        spec = math.atan2(float(u[1]), float(u[0]))
    elif isinstance(yaw, list) and len(yaw) >= 2 and (len(yaw) == 2 or all(
            abs(v - yaw[0]) < 1e-9 for v in yaw)):
        spec = (float(yaw[0]), float(yaw[-1]))
    else:
        return None
    # the acceleration along the line that keeps every axis within PX4's limit (and the norm)
    u_h, u_z = math.hypot(float(u[0]), float(u[1])), float(u[2])
    axes = lim.max_acc_axes_m_s2 or (math.inf, math.inf, math.inf)

    def along(pointing_up: bool) -> float:
        a = lim.max_acc_m_s2
        if u_h > 1e-9:
            a = min(a, axes[0] / u_h)
        if abs(u_z) > 1e-9:
            a = min(a, (axes[1] if pointing_up else axes[2]) / abs(u_z))
        return ALLOCATION_MARGIN * a

    climbing = u_z < 0.0  # NED: speeding up along a climb accelerates upwards
    cap, drag = math.inf, 0.0
    if params is not None and lim.max_tilt_rad is not None and u_h > 1e-9:
        # level flight: the thrust's horizontal part pays for the acceleration and the
        # linear drag (D v / m), its vertical part for the weight
        cap = STRAIGHT_TILT_MARGIN * params.g * math.tan(lim.max_tilt_rad) / u_h
        drag = float(params.drag) / float(params.mass)
    line = LineLimits(acc_up_m_s2=along(climbing), acc_down_m_s2=min(along(not climbing), cap),
                      jerk_m_s3=STRAIGHT_JERK_M_S3, speedup_cap_m_s2=cap, drag_per_s=drag)
    caps = np.minimum(np.minimum(caps, lim.max_speed_m_s) * ALLOCATION_MARGIN, line.top_speed())
    try:
        traj = straight_trajectory(pts, caps, line, yaw=spec)
    except ValueError:  # e.g. no acceleration left at a cap: the minimum-snap planner decides
        return None
    if isinstance(spec, tuple) and yaw_peak_rate(spec[0], spec[1], traj.duration) > (
            TURN_RATE_RAD_S):
        return None
    # tilt, thrust and body rate (horizontal lines, drag): stretch the time uniformly (the
    # path stays; speed, acceleration and jerk only drop) until every limit holds
    h = traj.durations
    for k in range(STRAIGHT_STRETCHES + 1):
        scale = 1.03 ** k
        cand = traj if k == 0 else PiecewiseBezier.from_control_points(
            traj.control_points, h * scale,
            None if traj.yaw is None else PiecewiseBezier.from_control_points(
                traj.yaw.control_points, h * scale))
        if any(r.exceeded for r in check(cand, lim, params).values()):
            continue
        r_vel, r_acc = axis_ratios(cand, px4, climb_m_s=(
            px4.MPC_TKO_SPEED if phase == "takeoff" else px4.MPC_Z_VEL_MAX_UP))
        if r_vel <= 1.0 + 1e-3 and r_acc <= 1.0 + 1e-3:
            return cand
    return None


def axis_ratios(
    traj: PiecewiseBezier, px4: Px4PlanningParams, climb_m_s: float | None = None
) -> tuple[float, float]:
    """Worst ratio to PX4's per-axis limits of a planned multirotor trajectory (NED), sampled
    densely: (speed: horizontal / MPC_XY_VEL_MAX, climb / `climb_m_s` (default
    MPC_Z_VEL_MAX_UP), descent / MPC_Z_VEL_MAX_DN; acceleration: horizontal /
    MPC_ACC_HOR_MAX, up / MPC_ACC_UP_MAX, down / MPC_ACC_DOWN_MAX)."""
    t = np.linspace(0.0, traj.duration, max(64, 32 * traj.num_segments))
    v, a = traj.evaluate_orders(t, (1, 2))
    up = px4.MPC_Z_VEL_MAX_UP if climb_m_s is None else climb_m_s
    r_vel = max(
        float(np.max(np.hypot(v[:, 0], v[:, 1]))) / px4.MPC_XY_VEL_MAX,
        float(np.max(-v[:, 2])) / up,
        float(np.max(v[:, 2])) / px4.MPC_Z_VEL_MAX_DN,
    )
    r_acc = max(
        float(np.max(np.hypot(a[:, 0], a[:, 1]))) / px4.MPC_ACC_HOR_MAX,
        float(np.max(-a[:, 2])) / px4.MPC_ACC_UP_MAX,
        float(np.max(a[:, 2])) / px4.MPC_ACC_DOWN_MAX,
    )
    return r_vel, r_acc

