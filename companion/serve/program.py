"""A mission planned for `serve` (:func:`plan_program`, CPU-bound: the caller runs it off its
event loop) and placed in the vehicle's local frame (:class:`MissionProgram`): where the flown
part begins and ends, when the plan passes each waypoint, and where a join may meet it."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Literal, Protocol

import numpy as np
from numpy.typing import NDArray

from companion.control import Reference
from companion.flatness import MultirotorParams
from companion.mavlink.mission_client import WireMissionItem
from companion.mavlink.telemetry import HomePosition
from companion.mission import (
    GeoPoint,
    geofence_from_wire,
    mission_from_wire,
    mission_to_flight_plan,
)
from companion.mission.px4_params import Px4PlanningParams
from companion.planning.fence_check import require_plan_inside
from companion.planning.schedule import Schedule, VehicleLimits, build_schedule

FloatArray = NDArray[np.float64]


class PlanningConfig(Protocol):
    """What planning reads of the service's configuration (``ServiceConfig``)."""

    @property
    def params(self) -> MultirotorParams: ...
    @property
    def limits(self) -> VehicleLimits: ...
    @property
    def px4(self) -> Px4PlanningParams | None: ...


class MissionProgram:
    """A planned mission placed in the vehicle's local NED frame.

    ``schedule`` is relative to the mission home; ``origin_ned`` [m] is where that home is in
    PX4's local frame (HOME_POSITION x, y, z). The flown part runs from the end of the takeoff
    climb (``t_begin``) to ``t_end``: the start of a trailing land/RTL (PX4 flies those itself,
    as the final action) or the schedule's end.
    """

    def __init__(self, schedule: Schedule, origin_ned: Sequence[float], key: tuple[int, int],
                 sample_dt_s: float = 0.02) -> None:
        self.schedule = schedule
        self.origin = np.asarray(origin_ned, dtype=np.float64).reshape(3)
        self.key = key
        self.final_action = schedule.final_action
        pieces = schedule.pieces
        t_begin = 0.0
        for p in pieces:
            if p.phase != "takeoff":
                break
            t_begin = p.t0_s + p.duration_s
        t_end = schedule.duration_s
        if self.final_action in ("land", "rtl"):
            for p in reversed(pieces):
                if p.phase not in ("land", "rtl"):
                    break
                t_end = p.t0_s
        self.t_begin, self.t_end = t_begin, max(t_end, t_begin)
        n = max(2, math.ceil(schedule.duration_s / sample_dt_s) + 1)
        self.t_samples = np.linspace(0.0, schedule.duration_s, n)
        self.p_samples = schedule.sample(self.t_samples) + self.origin
        # when the plan passes each waypoint, in order; only those before t_end are flown
        times, wps, acc = [], [], []
        t_prev = 0.0
        for w, a in zip(schedule.waypoints_ned, schedule.acceptance_m, strict=True):
            sel = self.t_samples >= t_prev
            d = np.linalg.norm(self.p_samples[sel] - (w + self.origin), axis=1)
            t_w = float(self.t_samples[sel][int(np.argmin(d))])
            if t_w > self.t_end + sample_dt_s:
                break
            times.append(t_w)
            wps.append(w + self.origin)
            acc.append(float(a))
            t_prev = t_w
        self.wp_times = np.asarray(times, dtype=np.float64)
        self.waypoints = np.asarray(wps, dtype=np.float64).reshape(-1, 3)
        self.acceptance = np.asarray(acc, dtype=np.float64)

    @property
    def planned_s(self) -> float:
        """Duration of the flown part [s]."""
        return self.t_end - self.t_begin

    def reference(self, t: float) -> Reference:
        """Reference at schedule time ``t`` in the local frame."""
        return self.schedule.reference(t, self.origin)

    def join_time(self, pos_ned: Sequence[float] | FloatArray, reached: int,
                  t_min: float) -> float:
        """Schedule time of the point nearest to ``pos_ned`` on the part of the plan leading to
        the first waypoint not yet reached (index ``reached``), not before ``t_min``."""
        k = reached
        t_lo = self.t_begin if k == 0 else float(self.wp_times[k - 1])
        t_hi = float(self.wp_times[k]) if k < len(self.wp_times) else self.t_end
        t_lo = min(max(t_lo, t_min, self.t_begin), self.t_end)
        t_hi = min(max(t_hi, t_lo), self.t_end)
        sel = (self.t_samples >= t_lo) & (self.t_samples <= t_hi)
        if not sel.any():
            return t_lo
        d = np.linalg.norm(self.p_samples[sel] - np.asarray(pos_ned, dtype=np.float64), axis=1)
        return float(self.t_samples[sel][int(np.argmin(d))])

    def lead_in(self, pos_ned: Sequence[float] | FloatArray, t_from: float,
                acc_m_s2: float) -> float:
        """The first schedule time >= ``t_from`` whose point is at least ``v^2 / (2 acc)``
        (v the plan's speed there) plus 0.5 m from ``pos_ned``, so a vehicle near rest can
        reach the plan's speed on the way (``t_end`` if none)."""
        here = np.asarray(pos_ned, dtype=np.float64)
        sel = (self.t_samples >= t_from) & (self.t_samples <= self.t_end)
        ts = self.t_samples[sel]
        if len(ts) < 2:
            return min(max(t_from, self.t_begin), self.t_end)
        ps = self.p_samples[sel]
        speed = np.linalg.norm(np.gradient(ps, ts, axis=0), axis=1)
        need = speed**2 / (2.0 * max(acc_m_s2, 0.1)) + 0.5
        ok = np.linalg.norm(ps - here, axis=1) >= need
        if speed[0] < 0.2 and not ok[0]:
            return float(ts[0])  # the plan is (nearly) at rest here: join in place
        idx = np.flatnonzero(ok)
        return float(ts[idx[0]]) if len(idx) else self.t_end


def plan_program(items: Sequence[WireMissionItem], home: HomePosition, key: tuple[int, int],
                 config: PlanningConfig, vehicle: Literal["quad", "rover"] = "quad",
                 fence_items: Sequence[WireMissionItem] = ()) -> MissionProgram:
    """Plan downloaded mission items (CPU-bound; ValueError/MissionError with the reason). A
    plan whose trajectory breaches the vehicle's geofence (``fence_items``) is refused
    (MissionError naming the leg's mission items), and so is a rover's (the service streams a
    multicopter's setpoints: a rover would have been sent attitude setpoints)."""
    if not items:
        raise ValueError("the vehicle has no mission")
    if vehicle == "rover":
        # the service's joins and setpoints are a multicopter's (attitude/rates/position); a
        # rover's mission is driven by `fly`, whose reference waits for it
        raise ValueError("serve flies multicopters; drive a rover's mission with "
                         "`python -m companion fly`")
    home_pt = GeoPoint(home.lat_deg, home.lon_deg, home.alt_amsl_m)
    mission = mission_from_wire(items, home_pt)
    fp = mission_to_flight_plan(mission, vehicle=vehicle, px4=config.px4)
    schedule = build_schedule(fp, config.params, config.limits)  # (a rover was refused above)
    if fence_items:
        fence = geofence_from_wire(fence_items, home_pt)
        require_plan_inside(dataclasses.replace(fp, geofence=fence), schedule)
    return MissionProgram(schedule, home.pos_ned, key)
