"""What a flight against a schedule recorded, and its summary (pure).

`FlightLog` holds the telemetry of one flight (simulated or vehicle time [s], NED [m], rad),
filled from decoded MAVLink messages by `record_message`; `summarize` turns it into the
flown figures of a `FlightReport`: waypoints reached, tracking error against the schedule,
speed, tilt, thrust, body rates, failsafes, the geofence and the per-leg figures.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from companion.flight.report import (
    Failsafe,
    FlightReport,
    ReportKind,
    WaypointResult,
    closest_approach,
)
from companion.mission import FlightPlan, Mission
from companion.planning.fence_check import (
    breach_report,
    flown_breaches,
    sample_schedule,
    zone_masks,
)
from companion.planning.legs import leg_figures, plan_legs
from companion.planning.schedule import Schedule

FloatArray = NDArray[np.float64]


@dataclass
class FlightLog:
    """Time series recorded during a flight (simulated time, s; NED m; rad)."""

    t: list[float] = field(default_factory=list)
    pos: list[tuple[float, float, float]] = field(default_factory=list)
    vel: list[tuple[float, float, float]] = field(default_factory=list)
    fly_t0: float | None = None
    fly_t1: float | None = None
    att_t: list[float] = field(default_factory=list)
    tilt: list[float] = field(default_factory=list)
    rate_norm: list[float] = field(default_factory=list)
    thrust_norm: list[float] = field(default_factory=list)
    statustext: list[tuple[float, int, str]] = field(default_factory=list)
    modes: list[tuple[float, str]] = field(default_factory=list)
    armed_t: float | None = None
    disarmed_t: float | None = None
    boot_clock: tuple[tuple[float, float, float], ...] = ()
    """Flight time of the autopilot's time since boot, as segments (from boot time [s], flight
    time then [s], boot seconds per flight second) of which the last one begun applies: a
    mock at SIM_SPEED_FACTOR runs that fast against the replay's lockstep clock (and changes
    at SIM_SPEED_CHG_T); `t` is kept on flight time. Empty: the same."""
    ref_clock: list[tuple[float, float]] = field(default_factory=list)
    """(time [s], the reference's own time [s]) of each setpoint of a source that governs its
    reference time (a rover's `ProgressGovernor`); empty: the reference ran on flight time."""


def record_message(log: FlightLog, msg: Any, t: float) -> None:
    """Record one decoded MAVLink message received at `t` [s]: LOCAL_POSITION_NED (at its own
    sample time, the vehicle booting at t = 0, on the clock `log.boot_clock`),
    ATTITUDE_QUATERNION (tilt, body-rate norm) and STATUSTEXT; others are ignored."""
    kind = msg.get_type()
    if kind == "LOCAL_POSITION_NED":
        # sample time (the mock boots at t = 0), on flight time
        boot = msg.time_boot_ms * 1e-3
        segs = log.boot_clock
        if segs:
            seg = segs[0]
            for later in segs[1:]:
                if boot >= later[0]:
                    seg = later
            boot = seg[1] + (boot - seg[0]) / seg[2]
        log.t.append(boot)
        log.pos.append((msg.x, msg.y, msg.z))
        log.vel.append((msg.vx, msg.vy, msg.vz))
    elif kind == "ATTITUDE_QUATERNION":
        x, y = msg.q2, msg.q3
        c33 = 1.0 - 2.0 * (x * x + y * y)  # z_b . e3 (C_eb[2, 2])
        log.att_t.append(t)
        log.tilt.append(math.acos(max(-1.0, min(1.0, c33))))
        log.rate_norm.append(math.sqrt(msg.rollspeed**2 + msg.pitchspeed**2 + msg.yawspeed**2))
    elif kind == "STATUSTEXT":
        log.statustext.append((t, int(msg.severity), str(msg.text)))


def tracking_error(
    log: FlightLog, schedule: Schedule, origin: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """(t [s], |flown - planned| [m]) at every position sample taken while flying the plan,
    the plan evaluated at the sample's own time (mapped to the reference's own time through
    ``log.ref_clock`` when the source governed it)."""
    if log.fly_t0 is None:
        return np.zeros(0), np.zeros(0)
    t = np.asarray(log.t)
    t1 = log.fly_t1 if log.fly_t1 is not None else (t[-1] if len(t) else log.fly_t0)
    sel = (t >= log.fly_t0) & (t <= t1)
    if not sel.any():
        return np.zeros(0), np.zeros(0)
    pos = np.asarray(log.pos, dtype=np.float64)[sel]
    t_ref = t[sel] - log.fly_t0
    if log.ref_clock:
        clock = np.asarray(log.ref_clock, dtype=np.float64)
        t_ref = np.interp(t[sel], clock[:, 0], clock[:, 1])
    planned = schedule.sample(t_ref) + origin
    return t[sel], np.linalg.norm(pos - planned, axis=1)


def summarize(
    log: FlightLog,
    schedule: Schedule,
    mission: Mission,
    origin: FloatArray,
    *,
    flight_plan: FlightPlan | None = None,
    fence_shift_ned: FloatArray | None = None,
    leg_bounds_s: Sequence[float | None] | None = None,
    bound_s: float | None = None,
    kind: ReportKind = "replay",
) -> FlightReport:
    """The flown figures of one flight as a report of `kind` (result still empty).

    With ``flight_plan`` the report also has ``legs`` (per-leg figures, see
    :func:`companion.planning.legs.leg_figures`; ``leg_bounds_s`` the time-optimal bound per
    leg, None unknown) and ``geofence_breaches`` (per leg and zone, see
    :mod:`companion.planning.fence_check`). ``bound_s``: the time-optimal bound of the whole
    schedule [s] (None: unknown), reported with the planned duration over it. The fence is
    checked in the mission's frame: flown local positions plus ``fence_shift_ned`` (default
    ``-origin``: the companion's plan frame)."""
    pos = np.asarray(log.pos, dtype=np.float64).reshape(-1, 3)
    vel = np.asarray(log.vel, dtype=np.float64).reshape(-1, 3)
    t = np.asarray(log.t)
    if log.armed_t is not None:
        sel = (t >= log.armed_t) & (t <= (log.disarmed_t if log.disarmed_t is not None else t[-1]))
        pos_f, vel_f, t_f = pos[sel], vel[sel], t[sel]
    else:
        pos_f, vel_f, t_f = pos[:0], vel[:0], t[:0]
    wps = schedule.waypoints_ned + origin
    closest = closest_approach(pos_f, wps)
    waypoints = tuple(
        WaypointResult(
            item_index=schedule.item_indices[i],
            north_m=float(wps[i, 0]),
            east_m=float(wps[i, 1]),
            down_m=float(wps[i, 2]),
            acceptance_radius_m=schedule.acceptance_m[i],
            closest_approach_m=float(closest[i]),
            reached=bool(closest[i] <= schedule.acceptance_m[i]),
        )
        for i in range(len(wps))
    )
    _, err = tracking_error(log, schedule, origin)
    fence = mission.geofence
    shift = -np.asarray(origin, dtype=np.float64) if fence_shift_ned is None else fence_shift_ned
    pos_fence = pos_f + shift
    masks = zone_masks(fence, pos_fence) if len(pos_f) and not fence.empty else []
    failsafes = tuple(
        Failsafe(round(ts, 3), s)
        for ts, _sev, s in log.statustext
        if "failsafe" in s.lower() or "lost" in s.lower()
    )
    duration = (
        (log.disarmed_t if log.disarmed_t is not None else (t[-1] if len(t) else 0.0))
        - (log.armed_t or 0.0)
        if log.armed_t is not None
        else 0.0
    )
    breaches: tuple[dict[str, Any], ...] | None = None
    legs: tuple[dict[str, Any], ...] | None = None
    if flight_plan is not None:
        found = flown_breaches(flight_plan, t_f, pos_fence) if masks else []
        breaches = tuple(breach_report(found))
        pt, pp = sample_schedule(schedule)
        legs = tuple(leg_figures(plan_legs(flight_plan), t_f, pos_f - origin, vel_ned=vel_f,
                                 planned_t_s=pt, planned_ned=pp, bounds_s=leg_bounds_s))
    return FlightReport(
        kind=kind,
        result="",
        duration_s=round(float(duration), 3),
        planned_duration_s=round(schedule.duration_s, 3),
        path_length_m=float(np.sum(np.linalg.norm(np.diff(pos_f, axis=0), axis=1)))
        if len(pos_f) > 1
        else 0.0,
        rms_error_m=float(np.sqrt(np.mean(err**2))) if len(err) else None,
        max_error_m=float(np.max(err)) if len(err) else None,
        waypoints=waypoints,
        waypoints_reached=int(np.count_nonzero(closest <= np.asarray(schedule.acceptance_m))),
        max_speed_m_s=float(np.max(np.linalg.norm(vel_f, axis=1))) if len(vel_f) else 0.0,
        max_tilt_deg=float(np.degrees(np.max(log.tilt))) if log.tilt else 0.0,
        max_thrust_norm=float(np.max(log.thrust_norm)) if log.thrust_norm else None,
        max_body_rate_rad_s=float(np.max(log.rate_norm)) if log.rate_norm else 0.0,
        geofence_violations=int(sum(int(np.count_nonzero(m)) for _, m in masks)),
        geofence_violation_zones=tuple(sorted(z for z, m in masks if m.any())),
        failsafes=failsafes,
        bound_s=None if bound_s is None else round(float(bound_s), 3),
        planned_over_bound=(round(schedule.duration_s / bound_s, 3)
                            if bound_s is not None and bound_s > 0 else None),
        geofence_breaches=breaches,
        legs=legs,
    )
