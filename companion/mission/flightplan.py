"""Mission -> flight plan: the expanded sequence of local NED waypoints the companion flies,
and its split into stop-to-stop chunks for ``companion.trajectory.plan``.

Semantics follow PX4's mission mode (multicopter, default parameters) where they matter:
- Takeoff: vertical climb at home to ``max(item altitude, MIS_TAKEOFF_ALT)``
  (``takeoff_alt_default``), then to the takeoff item's latitude/longitude if it is given and
  further from home than NAV_ACC_RAD (``acceptance_default``: within it the climb's top has
  reached the item; a vehicle re-homed where it stands, a GPS fix from the planned home, does
  not turn back to it). A
  mission that starts with another position item gets the same implicit takeoff to that item's
  altitude.
- Waypoint (16): param1 hold [s] (stop there), param2 acceptance radius [m] (0 -> NAV_ACC_RAD,
  ``acceptance_default``), param4 yaw [deg] (NaN -> free). LOITER_TIME (19): param1 hold [s].
  LOITER_UNLIM (17): fly there and loiter (ends the plan). autoContinue = 0: stop there.
- DO_JUMP (177): jump to the target ``repeat`` times, then continue (PX4 counters: an inner loop
  is not re-armed by an outer loop). Expansion is bounded by ``max_items``.
- DO_CHANGE_SPEED (178): param2 [m/s] from the next leg on (-1 no change, -2 back to default).
- DO_SET_ROI_LOCATION (195): yaw toward the ROI at every later waypoint (overrides param4) until
  DO_SET_ROI_NONE (197).
- NAV_DELAY (93): wait param1 [s] where the vehicle is (PX4's navigator holds the last
  position setpoint for the item's time_inside = param1). A delay until a time of day (param1
  < 0, params 2-4) is refused at load time; a delay before the first position item is refused
  (PX4 would sit on the ground armed and may auto-disarm, COM_DISARM_PRFLT).
- LAND (21): fly to above the land point at the current altitude, then descend to the ground
  (assumed at home altitude). RTL (20): climb to ``rtl_return_alt_m`` if lower (PX4
  RTL_RETURN_ALT), fly to above home, descend. Both end the plan. Position items after an RTL
  or a LOITER_UNLIM are ignored with a warning (PX4 never gets to them either); position items
  after a LAND are refused: PX4 v1.16 lands, stays armed (no COM_DISARM_LAND auto-disarm while
  AUTO.MISSION is unfinished) and takes off again for the next position item, which the
  companion cannot fly (in OFFBOARD PX4 disarms after touchdown). A mission that just ends
  hovers at its last waypoint (``final_action="loiter"``).
- VTOL_TAKEOFF (84) / VTOL_LAND (85): flown as TAKEOFF / LAND, as by PX4 on a multicopter.
- The takeoff climb's top counts as the takeoff item where the item is (a TAKEOFF with no
  other latitude/longitude, or one within NAV_ACC_RAD of home); an implicit takeoff, or the
  climb before a TAKEOFF item's own position, is a point the plan adds (``item_index`` None), as
  is the touchdown point.
- Rover: altitudes are ignored (down = 0), no takeoff climb or descent.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal

import numpy as np
import numpy.typing as npt

from companion.mission.errors import MissionError
from companion.mission.geodesy import GeoPoint, geodetic_to_ned
from companion.mission.geofence import Geofence
from companion.mission.model import (
    CMD_DO_CHANGE_SPEED,
    CMD_DO_JUMP,
    CMD_DO_SET_ROI_LOCATION,
    CMD_DO_SET_ROI_NONE,
    CMD_LAND,
    CMD_LOITER_TIME,
    CMD_LOITER_UNLIM,
    CMD_NAV_DELAY,
    CMD_RETURN_TO_LAUNCH,
    CMD_TAKEOFF,
    CMD_VTOL_LAND,
    CMD_VTOL_TAKEOFF,
    CMD_WAYPOINT,
    Mission,
    MissionItem,
    command_name,
)
from companion.mission.px4_params import Px4PlanningParams

__all__ = [
    "FinalAction",
    "FlightChunk",
    "FlightPlan",
    "FlightWaypoint",
    "Phase",
    "expand_jumps",
    "mission_to_flight_plan",
    "split_flight_plan",
]

_log = logging.getLogger("companion.mission")

Phase = Literal["takeoff", "mission", "rtl", "land"]
FinalAction = Literal["land", "rtl", "loiter"]
Vec3 = tuple[float, float, float]
_MERGE_TOL_M = 1e-3
_NAV_COMMANDS = frozenset(
    {CMD_WAYPOINT, CMD_LOITER_UNLIM, CMD_LOITER_TIME, CMD_RETURN_TO_LAUNCH, CMD_LAND, CMD_TAKEOFF,
     CMD_VTOL_TAKEOFF, CMD_VTOL_LAND}
)
#: VTOL takeoff/land flown as a multicopter's (PX4 treats them so on a rotary-wing vehicle).
_AS_MULTICOPTER = {CMD_VTOL_TAKEOFF: CMD_TAKEOFF, CMD_VTOL_LAND: CMD_LAND}
#: Items a multicopter flies through or stops at in the air (their altitude is checked).
_FLY_THROUGH_COMMANDS = frozenset({CMD_WAYPOINT, CMD_LOITER_UNLIM, CMD_LOITER_TIME, CMD_TAKEOFF})


@dataclass(frozen=True)
class FlightWaypoint:
    """One point the vehicle flies to, local NED about home [m].

    ``speed_m_s`` is the cruise speed of the leg that arrives here; ``hold_s`` the time to wait
    here (> 0 implies ``stop``); ``stop`` means come to rest here (hold, takeoff top, phase
    change, autoContinue = 0, end of plan); ``yaw_deg`` is the heading to hold here (deg from
    north, clockwise; None = free). ``item_index`` is the mission item it comes from (None for
    points the plan adds, e.g. the RTL climb).
    """

    pos_ned_m: Vec3
    acceptance_radius_m: float
    hold_s: float
    speed_m_s: float
    yaw_deg: float | None
    item_index: int | None
    command: int
    phase: Phase
    stop: bool


@dataclass(frozen=True)
class FlightPlan:
    """The expanded mission as flown: start on the ground at ``start_ned_m``, then ``waypoints``
    in order, then ``final_action`` (``touchdown_ned_m`` = end of the final descent for land/RTL,
    None for loiter and for rovers)."""

    source: Path
    home: GeoPoint
    vehicle: Literal["quad", "rover"]
    takeoff_alt_m: float
    """Height of the takeoff climb above home [m] (0 for rovers)."""
    waypoints: tuple[FlightWaypoint, ...]
    final_action: FinalAction
    touchdown_ned_m: Vec3 | None
    geofence: Geofence = field(default_factory=Geofence)
    start_ned_m: Vec3 = (0.0, 0.0, 0.0)
    takeoff_speed_m_s: float = 1.5
    land_speed_m_s: float = 0.7
    warnings: tuple[str, ...] = ()
    px4: Px4PlanningParams = field(default_factory=Px4PlanningParams)
    """The vehicle's PX4 parameters the plan was made with (limits, vertical profiles)."""

    def points_ned_m(self) -> npt.NDArray[np.float64]:
        """All path points (start, waypoints, touchdown), shape (N, 3) [m]."""
        pts = [self.start_ned_m, *(w.pos_ned_m for w in self.waypoints)]
        if self.touchdown_ned_m is not None:
            pts.append(self.touchdown_ned_m)
        return np.asarray(pts, dtype=np.float64)

    @property
    def path_length_m(self) -> float:
        """Length of the straight-line path through all points [m]."""
        p = self.points_ned_m()
        return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())

    def nominal_duration_s(self) -> float:
        """Straight legs at their speeds plus holds [s]: a lower-bound-like estimate that ignores
        acceleration (useful to size a replay)."""
        total = 0.0
        for chunk in split_flight_plan(self):
            seg = np.linalg.norm(np.diff(chunk.points_ned_m, axis=0), axis=1)
            total += float(np.sum(seg / np.asarray(chunk.leg_speed_m_s)))
            total += chunk.hold_after_s
        return total


@dataclass(frozen=True, eq=False)
class FlightChunk:
    """A stop-to-stop piece of the plan: starts and ends at rest, passes through the points in
    between without stopping. ``points_ned_m`` (M >= 2, read-only, no consecutive duplicates)
    is what ``companion.trajectory.plan`` takes (use ``[:, :2]`` for a rover); per point:
    ``yaw_deg``, ``acceptance_radius_m``, ``item_indices``; per leg: ``leg_speed_m_s``.
    ``hold_after_s`` is the wait at the last point. ``phase`` is "takeoff" (vertical climb),
    "mission", "rtl" or "land" (final descent)."""

    points_ned_m: npt.NDArray[np.float64]
    yaw_deg: tuple[float | None, ...]
    acceptance_radius_m: tuple[float, ...]
    item_indices: tuple[int | None, ...]
    leg_speed_m_s: tuple[float, ...]
    hold_after_s: float
    phase: Phase

    @property
    def max_speed_m_s(self) -> float:
        """The slowest leg speed: a single speed limit valid for the whole chunk [m/s]."""
        return min(self.leg_speed_m_s)


# --------------------------------------------------------------------------------- expansion
def expand_jumps(mission: Mission, *, max_items: int = 10_000) -> list[MissionItem]:
    """The items in the order PX4 would execute them, DO_JUMPs resolved (and removed).

    Raises :class:`MissionError` naming the jump if more than ``max_items`` items would result.
    """
    items = mission.items
    pos_of = {it.index: k for k, it in enumerate(items)}
    counters: dict[int, int] = {}
    out: list[MissionItem] = []
    steps = 0
    step_limit = 4 * max_items + 4 * len(items) + 16
    last_jump: MissionItem | None = None
    k = 0
    while k < len(items):
        it = items[k]
        steps += 1
        if len(out) > max_items or steps > step_limit:
            if last_jump is None:
                raise MissionError(
                    mission.source, f"the mission has more than {max_items} items", item=it.index
                )
            raise MissionError(
                mission.source,
                f"DO_JUMP expansion exceeds {max_items} items (repeat count "
                f"{int(last_jump.params[1])}); lower the repeat counts",
                item=last_jump.index,
            )
        if it.command == CMD_DO_JUMP:
            repeat = int(it.params[1])
            done = counters.get(k, 0)
            target = int(it.params[0])
            if done < repeat and target in pos_of:
                counters[k] = done + 1
                last_jump = it
                k = pos_of[target]
            else:
                k += 1
            continue
        out.append(it)
        k += 1
    return out


# ---------------------------------------------------------------------------- flight plan
def _wrap_deg(a: float) -> float:
    return (a + 180.0) % 360.0 - 180.0


MAV_TYPE_GROUND_ROVER = 10
_MULTICOPTER_TYPES = frozenset({2, 3, 4, 13, 14, 15})
"""MAV_TYPE quadrotor, coaxial, helicopter, hexarotor, octorotor, tricopter."""
_VTOL_TYPES = frozenset({19, 20, 21, 22, 23, 24})
_MAV_TYPE_NAMES = {
    1: "fixed-wing aircraft", 2: "quadrotor", 3: "coaxial helicopter", 4: "helicopter",
    10: "ground rover", 11: "surface boat", 12: "submarine", 13: "hexarotor", 14: "octorotor",
    15: "tricopter", 19: "VTOL", 20: "VTOL", 21: "VTOL", 22: "VTOL", 23: "VTOL", 24: "VTOL",
}


def mission_to_flight_plan(
    mission: Mission,
    *,
    takeoff_alt_default: float = 2.5,
    acceptance_default: float = 2.0,
    cruise_speed_default: float = 5.0,
    vehicle: Literal["quad", "rover"] = "quad",
    rtl_return_alt_m: float = 30.0,
    takeoff_speed_m_s: float = 1.5,
    land_speed_m_s: float = 0.7,
    max_items: int = 10_000,
    strict_geofence: bool = False,
    min_height_m: float = 1.0,
    px4: Px4PlanningParams | None = None,
) -> FlightPlan:
    """Expand ``mission`` into the :class:`FlightPlan` the companion flies (see module doc).

    Defaults are PX4's (multicopter): MIS_TAKEOFF_ALT 2.5 m, NAV_ACC_RAD 2 m, MPC_XY_CRUISE
    5 m/s, RTL_RETURN_ALT 30 m, MPC_TKO_SPEED 1.5 m/s, MPC_LAND_SPEED 0.7 m/s. Waypoints or legs
    outside the geofence give warnings (``strict_geofence=True``: a :class:`MissionError`, like
    PX4's mission feasibility check). A multicopter waypoint (WAYPOINT, LOITER, TAKEOFF as a
    waypoint) less than ``min_height_m`` above home is a :class:`MissionError`: the vehicle would
    fly at ground level (typically a ground-vehicle mission flown with ``vehicle="quad"``).

    ``px4``: the vehicle's parameters (read at connect); when given they replace the defaults
    above (MIS_TAKEOFF_ALT, NAV_ACC_RAD, MPC_XY_CRUISE (a rover: RO_SPEED_LIM, PX4's rover
    mission speed), RTL_RETURN_ALT, MPC_TKO_SPEED, MPC_LAND_SPEED) and travel with the plan to
    the planner (``FlightPlan.px4``).
    """
    src = mission.source
    if px4 is not None:
        takeoff_alt_default = max(px4.MIS_TAKEOFF_ALT, 0.1)
        acceptance_default = px4.NAV_ACC_RAD
        cruise_speed_default = (px4.RO_SPEED_LIM if vehicle == "rover"
                                else min(px4.MPC_XY_CRUISE, px4.MPC_XY_VEL_MAX))
        rtl_return_alt_m = px4.RTL_RETURN_ALT
        takeoff_speed_m_s = px4.MPC_TKO_SPEED
        land_speed_m_s = px4.MPC_LAND_SPEED
    for name, v in (
        ("takeoff_alt_default", takeoff_alt_default),
        ("acceptance_default", acceptance_default),
        ("cruise_speed_default", cruise_speed_default),
        ("takeoff_speed_m_s", takeoff_speed_m_s),
        ("land_speed_m_s", land_speed_m_s),
    ):
        if not (math.isfinite(v) and v > 0.0):
            raise ValueError(f"{name} must be a positive number, got {v}")
    if not math.isfinite(rtl_return_alt_m):
        raise ValueError(f"rtl_return_alt_m must be finite, got {rtl_return_alt_m}")
    if px4 is None:
        px4 = Px4PlanningParams(
            MIS_TAKEOFF_ALT=takeoff_alt_default,
            NAV_ACC_RAD=acceptance_default,
            MPC_XY_CRUISE=cruise_speed_default,
            MPC_XY_VEL_MAX=max(cruise_speed_default, Px4PlanningParams.MPC_XY_VEL_MAX),
            RTL_RETURN_ALT=max(rtl_return_alt_m, 0.0),
            MPC_TKO_SPEED=takeoff_speed_m_s,
            MPC_LAND_SPEED=land_speed_m_s,
        )
    home = mission.home
    rover = vehicle == "rover"
    warnings: list[str] = list(mission.warnings)

    def warn(msg: str, item: MissionItem | None = None) -> None:
        text = f"{src}: item {item.index}: {msg}" if item is not None else f"{src}: {msg}"
        warnings.append(text)
        _log.warning(text)

    vtype = mission.vehicle_type
    if vtype is not None and vtype != 0:
        written_for = _MAV_TYPE_NAMES.get(vtype, f"MAV_TYPE {vtype}")
        if rover and vtype != MAV_TYPE_GROUND_ROVER:
            warn(f"the file was written for a {written_for} (vehicleType {vtype}); "
                 "flying it as a ground rover")
        elif not rover and vtype not in _MULTICOPTER_TYPES:
            hint = ("; fly it as a rover (replay --vehicle rover)"
                    if vtype == MAV_TYPE_GROUND_ROVER else "")
            if vtype in _VTOL_TYPES:
                hint = ("; VTOL takeoff/land are flown as multicopter takeoff/land, "
                        "without transitions")
            warn(f"the file was written for a {written_for} (vehicleType {vtype}); "
                 f"flying it as a multicopter{hint}")

    executed = expand_jumps(mission, max_items=max_items)
    wps: list[FlightWaypoint] = []
    cur: Vec3 = (0.0, 0.0, 0.0)
    airborne = rover
    takeoff_alt = 0.0
    speed = cruise_speed_default
    roi: tuple[float, float] | None = None
    final: FinalAction = "loiter"
    touchdown: Vec3 | None = None
    ended_by: MissionItem | None = None

    def ne_of(it: MissionItem) -> tuple[float, float] | None:
        if not it.has_latlon:
            return None
        p = geodetic_to_ned(it.lat_deg, it.lon_deg, home.alt_amsl_m, home)
        return float(p[0]), float(p[1])

    def yaw_at(n: float, e: float, explicit: float) -> float | None:
        if roi is not None:
            dn, de = roi[0] - n, roi[1] - e
            if math.hypot(dn, de) > 0.5:
                return _wrap_deg(math.degrees(math.atan2(de, dn)))
            return None
        return _wrap_deg(explicit) if math.isfinite(explicit) else None

    def add(
        pos: Vec3,
        *,
        it: MissionItem | None,
        command: int,
        phase: Phase,
        stop: bool,
        hold: float = 0.0,
        acc: float = acceptance_default,
        yaw: float | None = None,
        spd: float | None = None,
    ) -> None:
        nonlocal cur
        z = 0.0 if rover else pos[2]
        p = (pos[0], pos[1], z)
        wps.append(
            FlightWaypoint(
                pos_ned_m=p,
                acceptance_radius_m=acc,
                hold_s=hold,
                speed_m_s=speed if spd is None else spd,
                yaw_deg=yaw,
                item_index=None if it is None else it.index,
                command=command,
                phase=phase,
                stop=stop or hold > 0.0,
            )
        )
        cur = p

    def takeoff(alt_rel: float, it: MissionItem, at_item: bool) -> None:
        """The vertical climb; its top is mission item ``it`` when ``at_item`` (a TAKEOFF
        there), else a point the plan adds (PX4 does not report it reached either)."""
        nonlocal airborne, takeoff_alt
        h = alt_rel if math.isfinite(alt_rel) else takeoff_alt_default
        h = max(h, takeoff_alt_default)
        takeoff_alt = h
        yaw = it.params[3] if it.command in (CMD_TAKEOFF, CMD_VTOL_TAKEOFF) else math.nan
        add(
            (cur[0], cur[1], -h),
            it=it if at_item else None,
            command=CMD_TAKEOFF,
            phase="takeoff",
            stop=True,
            yaw=yaw_at(cur[0], cur[1], yaw),
            spd=takeoff_speed_m_s,
        )
        airborne = True

    for it in executed:
        cmd = _AS_MULTICOPTER.get(it.command, it.command)
        if ended_by is not None:
            if cmd in _NAV_COMMANDS and ended_by.command in (CMD_LAND, CMD_VTOL_LAND):
                raise MissionError(
                    src,
                    f"{command_name(it.command)} after the landing at item {ended_by.index}: "
                    "PX4 would land there, stay armed and take off again to fly on; the "
                    "companion cannot fly a landing in the middle of a mission (in OFFBOARD "
                    "PX4 disarms after touchdown): split the mission at the landing",
                    item=it.index,
                )
            if cmd in _NAV_COMMANDS:
                warn(f"ignored: the mission already ended at item {ended_by.index} "
                     f"({command_name(ended_by.command)}); PX4 does not fly it either", it)
            continue
        if cmd == CMD_NAV_DELAY:
            delay = it.params[0] if math.isfinite(it.params[0]) and it.params[0] > 0 else 0.0
            if not wps:
                raise MissionError(
                    src,
                    "NAV_DELAY before the first position item is not supported: PX4 would "
                    "wait on the ground, armed, and its preflight auto-disarm (COM_DISARM_PRFLT) "
                    "may disarm it first; put the delay after the takeoff",
                    item=it.index,
                )
            if delay <= 0.0:
                warn("NAV_DELAY of 0 s: no wait (PX4 goes on at once)", it)
                continue
            # PX4 holds the last position setpoint for the delay: rest at the point flown to
            wps[-1] = replace(wps[-1], hold_s=wps[-1].hold_s + delay, stop=True)
            continue
        if cmd == CMD_DO_CHANGE_SPEED:
            s = it.params[1]
            if s == -2.0:
                speed = cruise_speed_default
            elif math.isfinite(s) and s > 0.0:
                speed = s
            elif not (math.isnan(s) or s == -1.0):
                warn(f"DO_CHANGE_SPEED: speed {s} m/s ignored", it)
            continue
        if cmd == CMD_DO_SET_ROI_LOCATION:
            roi = ne_of(it)
            continue
        if cmd == CMD_DO_SET_ROI_NONE:
            roi = None
            continue
        if cmd not in _NAV_COMMANDS:
            continue  # unknown non-position command: warned about at load time
        ne = ne_of(it)
        alt_rel = it.alt_rel_home_m(home)
        if cmd in (CMD_LAND, CMD_RETURN_TO_LAUNCH) and not airborne:
            raise MissionError(
                src, "the mission lands/returns before taking off: nothing to fly", item=it.index
            )
        if not airborne:
            # PX4: the first position item starts with a takeoff at the current position
            if cmd == CMD_TAKEOFF:
                moves = ne is not None and math.hypot(ne[0] - cur[0], ne[1] - cur[1]) > max(
                    _MERGE_TOL_M, acceptance_default)
                takeoff(alt_rel, it, at_item=not moves)
                if moves:
                    assert ne is not None
                    add(
                        (ne[0], ne[1], cur[2]),
                        it=it,
                        command=CMD_WAYPOINT,
                        phase="mission",
                        stop=not it.autocontinue,
                        yaw=yaw_at(ne[0], ne[1], math.nan),
                    )
                continue
            takeoff(alt_rel, it, at_item=False)
        n, e = ne if ne is not None else (cur[0], cur[1])
        d = -alt_rel if math.isfinite(alt_rel) else cur[2]
        if not rover and cmd in _FLY_THROUGH_COMMANDS and -d < min_height_m:
            hint = (
                "the file was written for a ground rover (vehicleType 10): fly it as a rover "
                "(replay --vehicle rover)"
                if mission.vehicle_type == MAV_TYPE_GROUND_ROVER
                else "is this a ground-vehicle mission? (replay --vehicle rover)"
            )
            raise MissionError(
                src,
                f"{command_name(cmd)} at {-d:.1f} m above home: a multicopter would fly at ground "
                f"level (less than {min_height_m:g} m up); {hint}",
                item=it.index,
            )
        if cmd == CMD_TAKEOFF:
            if rover and ne is None:
                continue
            add(
                (n, e, d),
                it=it,
                command=CMD_WAYPOINT,
                phase="mission",
                stop=not it.autocontinue,
                yaw=yaw_at(n, e, it.params[3]),
            )
        elif cmd == CMD_WAYPOINT:
            hold = it.params[0] if math.isfinite(it.params[0]) else 0.0
            acc = it.params[1] if math.isfinite(it.params[1]) and it.params[1] > 0 else None
            add(
                (n, e, d),
                it=it,
                command=cmd,
                phase="mission",
                stop=not it.autocontinue,
                hold=hold,
                acc=acceptance_default if acc is None else acc,
                yaw=yaw_at(n, e, it.params[3]),
            )
        elif cmd == CMD_LOITER_TIME:
            hold = it.params[0] if math.isfinite(it.params[0]) else 0.0
            add(
                (n, e, d),
                it=it,
                command=cmd,
                phase="mission",
                stop=not it.autocontinue,
                hold=hold,
                yaw=yaw_at(n, e, math.nan),
            )
        elif cmd == CMD_LOITER_UNLIM:
            add(
                (n, e, d),
                it=it,
                command=cmd,
                phase="mission",
                stop=True,
                yaw=yaw_at(n, e, it.params[3]),
            )
            final, ended_by = "loiter", it
        elif cmd == CMD_LAND:
            add(
                (n, e, cur[2]),
                it=it,
                command=cmd,
                phase="mission",
                stop=True,
                yaw=yaw_at(n, e, it.params[3]),
            )
            final, ended_by = "land", it
            touchdown = None if rover else (n, e, 0.0)
        elif cmd == CMD_RETURN_TO_LAUNCH:
            # PX4 starts RTL from where the mission is: come to rest first
            if wps:
                wps[-1] = replace(wps[-1], stop=True)
            if not rover and -cur[2] < rtl_return_alt_m:
                add(
                    (cur[0], cur[1], -rtl_return_alt_m),
                    it=None,
                    command=cmd,
                    phase="rtl",
                    stop=True,
                    yaw=wps[-1].yaw_deg if wps else None,
                    spd=takeoff_speed_m_s,
                )
            add(
                (0.0, 0.0, cur[2]),
                it=it,
                command=cmd,
                phase="rtl",
                stop=True,
                yaw=None,
            )
            final, ended_by = "rtl", it
            touchdown = None if rover else (0.0, 0.0, 0.0)

    if not wps:
        raise MissionError(src, "the mission has no position items to fly")
    # the end of the plan is a stop
    last = wps[-1]
    if not last.stop:
        wps[-1] = replace(last, stop=True)

    plan = FlightPlan(
        source=src,
        home=home,
        vehicle=vehicle,
        takeoff_alt_m=0.0 if rover else takeoff_alt,
        waypoints=tuple(wps),
        final_action=final,
        touchdown_ned_m=touchdown,
        geofence=mission.geofence,
        takeoff_speed_m_s=takeoff_speed_m_s,
        land_speed_m_s=land_speed_m_s,
        warnings=(),
        px4=px4,
    )
    fence_msgs = _fence_messages(plan)
    if fence_msgs and strict_geofence:
        raise MissionError(src, fence_msgs[0])
    for msg in fence_msgs:
        warn(msg)
    return replace(plan, warnings=tuple(warnings))


_FENCE_SAMPLES = 200_000
"""Sample budget of the geofence check of the legs (1 m apart up to a 200 km flight)."""


def _fence_messages(plan: FlightPlan) -> list[str]:
    """Waypoints and straight legs (sampled every max(1 m, flight length / 200 000)) that
    breach the geofence."""
    fence = plan.geofence
    if fence.empty:
        return []
    msgs: list[str] = []
    wps = plan.waypoints
    pts = np.asarray([w.pos_ned_m for w in wps], dtype=np.float64)
    for v in fence.violations(pts):
        w = wps[v.point_index]
        label = f"item {w.item_index}" if w.item_index is not None else f"{w.phase} point"
        what = "outside every inclusion zone" if v.zone == "inclusion" else f"inside {v.zone}"
        msgs.append(f"geofence: waypoint {v.point_index} ({label}) is {what}")
    allp = plan.points_ned_m()
    lengths = np.linalg.norm(np.diff(allp, axis=0), axis=1) if len(allp) > 1 else np.zeros(0)
    # every metre, coarser on very long flights: at most ~_FENCE_SAMPLES samples in all
    spacing = max(1.0, float(np.sum(lengths)) / _FENCE_SAMPLES)
    for i in range(len(allp) - 1):
        a, b = allp[i], allp[i + 1]
        n = max(2, math.ceil(float(lengths[i]) / spacing) + 1)
        s = a + np.linspace(0.0, 1.0, n)[:, None] * (b - a)
        zones = sorted({v.zone for v in fence.violations(s[1:-1])}) if n > 2 else []
        for z in zones:
            what = "leaves every inclusion zone" if z == "inclusion" else f"crosses {z}"
            msgs.append(f"geofence: the leg from path point {i} to {i + 1} {what}")
    return msgs


# ------------------------------------------------------------------------------------ chunks
@dataclass
class _Pt:
    pos: npt.NDArray[np.float64]
    yaw: float | None
    acc: float
    item: int | None
    speed: float
    hold: float
    stop: bool
    phase: Phase


def split_flight_plan(plan: FlightPlan) -> tuple[FlightChunk, ...]:
    """Split the plan into stop-to-stop :class:`FlightChunk` s: the takeoff climb, the mission
    pieces between stops (hold > 0, autoContinue = 0, phase changes), and the final descent."""
    first_yaw = plan.waypoints[0].yaw_deg if plan.waypoints else None
    pts: list[_Pt] = [
        _Pt(
            np.asarray(plan.start_ned_m, float),
            first_yaw,
            plan.waypoints[0].acceptance_radius_m if plan.waypoints else 2.0,
            None,
            plan.takeoff_speed_m_s,
            0.0,
            True,
            "takeoff",
        )
    ]
    for w in plan.waypoints:
        pts.append(
            _Pt(
                np.asarray(w.pos_ned_m, float),
                w.yaw_deg,
                w.acceptance_radius_m,
                w.item_index,
                w.speed_m_s,
                w.hold_s,
                w.stop,
                w.phase,
            )
        )
    if plan.touchdown_ned_m is not None:
        pts.append(
            _Pt(
                np.asarray(plan.touchdown_ned_m, float),
                pts[-1].yaw,
                pts[-1].acc,
                None,  # a point the plan adds: the LAND / RTL item is reached above it
                plan.land_speed_m_s,
                0.0,
                True,
                "land",
            )
        )
    # merge consecutive coincident points (keep the later one's data, sum the holds)
    merged: list[_Pt] = []
    for p in pts:
        if merged and float(np.linalg.norm(p.pos - merged[-1].pos)) <= _MERGE_TOL_M:
            prev = merged[-1]
            p.hold += prev.hold
            p.stop = p.stop or prev.stop
            if p.yaw is None:
                p.yaw = prev.yaw
            merged[-1] = p
            continue
        merged.append(p)
    chunks: list[FlightChunk] = []
    cur: list[_Pt] = [merged[0]]
    for p in merged[1:]:
        cur.append(p)
        if p.stop:
            chunks.append(_make_chunk(cur))
            cur = [p]
    if len(cur) > 1:  # pragma: no cover - the last waypoint is always a stop
        chunks.append(_make_chunk(cur))
    if not chunks:
        return ()
    # a hold at the very start point (before any chunk) cannot happen: start has hold 0
    return tuple(chunks)


def _make_chunk(pts: list[_Pt]) -> FlightChunk:
    arr = np.stack([p.pos for p in pts]).astype(np.float64)
    arr.setflags(write=False)
    last = pts[-1]
    phase: Phase = last.phase
    return FlightChunk(
        points_ned_m=arr,
        yaw_deg=tuple(p.yaw for p in pts),
        acceptance_radius_m=tuple(p.acc for p in pts),
        item_indices=tuple(p.item for p in pts),
        leg_speed_m_s=tuple(p.speed for p in pts[1:]),
        hold_after_s=last.hold,
        phase=phase,
    )
