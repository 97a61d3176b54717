"""Geofence check of a planned trajectory and of flown positions. Pure (numpy only).

The plan's geofence (``FlightPlan.geofence``, PX4 semantics: inside at least one inclusion zone
when there are any, outside every exclusion zone, horizontal only) is checked against the
*planned trajectory*, not only its straight legs: the schedule is sampled every ``dt_s`` (0.1 s)
and at most ``max_step_m`` (0.5 m) apart, within a budget of ``max_samples`` points (a longer
flight is sampled more coarsely, uniformly in time). Each breach names the leg it happens on
(``companion.planning.legs``: between two consecutive points of the flight plan, named by their
mission items) and how long it is (path length in breach, m).

:func:`require_plan_inside` raises a :class:`MissionError` with the first breach, for the
commands to refuse a plan before anything is sent; :func:`flown_breaches` checks flown
positions (a flight that breaches the fence has failed, whatever else went right).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from companion.mission import FenceCircle, FencePolygon, FlightPlan, Geofence, MissionError
from companion.planning.legs import Leg, leg_of_samples, plan_legs
from companion.planning.schedule import Schedule

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

#: Time step of the plan's fence check [s].
CHECK_DT_S = 0.1
#: Largest distance between two checked points of the plan [m].
CHECK_STEP_M = 0.5
#: Most points checked per plan (about 1 m apart on a 1,000 km flight).
CHECK_MAX_SAMPLES = 2_000_000


@dataclass(frozen=True)
class FenceBreach:
    """The path breaches ``zone`` ("inclusion": outside every inclusion zone, else e.g.
    "exclusion polygon 2") on ``leg`` over ``length_m`` of path [m], from ``t_s`` (schedule or
    flight time [s]) at ``first_ned_m`` (plan frame); ``samples`` points were in breach."""

    leg: Leg
    zone: str
    length_m: float
    t_s: float
    first_ned_m: tuple[float, float, float]
    samples: int

    @property
    def message(self) -> str:
        """``"the leg from item 5 to item 6 crosses exclusion polygon 2 for 14 m"``."""
        what = ("leaves every inclusion zone" if self.zone == "inclusion"
                else f"crosses {self.zone}")
        length = f"{self.length_m:.0f}" if self.length_m >= 1.0 else f"{self.length_m:.1f}"
        return f"the leg from {self.leg.name} {what} for {length} m"


def zone_masks(fence: Geofence, points_ned_m: FloatArray) -> list[tuple[str, BoolArray]]:
    """Per zone name ("inclusion" for the union of the inclusion zones, then each exclusion
    zone as "exclusion polygon i" / "exclusion circle i"), which points breach it."""
    p = np.asarray(points_ned_m, dtype=np.float64).reshape(-1, 3)
    out: list[tuple[str, BoolArray]] = []
    zones: list[FencePolygon | FenceCircle] = [*fence.polygons, *fence.circles]
    incl = [z for z in zones if z.inclusion]
    if incl:
        inside = np.zeros(len(p), dtype=bool)
        for z in incl:
            inside |= z.contains(p)
        out.append(("inclusion", ~inside))
    for i, poly in enumerate(fence.polygons):
        if not poly.inclusion:
            out.append((f"exclusion polygon {i}", poly.contains(p)))
    for i, circ in enumerate(fence.circles):
        if not circ.inclusion:
            out.append((f"exclusion circle {i}", circ.contains(p)))
    return out


def breaches(
    fence: Geofence, legs: Sequence[Leg], t_s: FloatArray, points_ned_m: FloatArray
) -> list[FenceBreach]:
    """Every (leg, zone) breach of the time-ordered path ``points_ned_m`` (N, 3, plan frame),
    in leg order. The length counts each segment between consecutive points fully when both
    ends breach and half when one does."""
    p = np.asarray(points_ned_m, dtype=np.float64).reshape(-1, 3)
    t = np.asarray(t_s, dtype=np.float64).reshape(-1)
    if fence.empty or len(p) == 0 or not legs:
        return []
    masks = [(z, m) for z, m in zone_masks(fence, p) if m.any()]
    if not masks:
        return []
    leg_idx = leg_of_samples(p, legs)
    step = np.linalg.norm(np.diff(p, axis=0), axis=1) if len(p) > 1 else np.zeros(0)
    found: list[tuple[int, int, FenceBreach]] = []
    for order, (zone, m) in enumerate(masks):
        mf = m.astype(np.float64)
        # per-segment breach length, credited to the leg of the segment's first point
        seg_len = step * 0.5 * (mf[:-1] + mf[1:]) if len(p) > 1 else np.zeros(0)
        for k in np.unique(leg_idx[m]):
            sel = leg_idx == k
            idx = np.flatnonzero(sel & m)
            length = float(np.sum(seg_len[sel[:-1]])) if len(seg_len) else 0.0
            i = int(idx[0])
            first = (float(p[i, 0]), float(p[i, 1]), float(p[i, 2]))
            found.append((int(k), order, FenceBreach(legs[int(k)], zone, length, float(t[i]),
                                                     first, len(idx))))
    found.sort(key=lambda x: (x[0], x[1]))
    return [b for _, _, b in found]


def sample_schedule(
    schedule: Schedule,
    *,
    dt_s: float = CHECK_DT_S,
    max_step_m: float = CHECK_STEP_M,
    max_samples: int = CHECK_MAX_SAMPLES,
) -> tuple[FloatArray, FloatArray]:
    """(t [s], positions (N, 3) NED) of the schedule every ``dt_s`` and at most ``max_step_m``
    apart (intervals that move farther are subdivided), at most about ``max_samples`` points
    (beyond, the time step grows uniformly)."""
    if not (dt_s > 0 and max_step_m > 0 and max_samples >= 2):
        raise ValueError("dt_s and max_step_m must be > 0 and max_samples >= 2")
    dur = float(schedule.duration_s)
    n = max(2, min(math.ceil(dur / dt_s) + 1, max_samples // 2))
    t = np.linspace(0.0, dur, n)
    p = schedule.sample(t)
    gap = np.linalg.norm(np.diff(p, axis=0), axis=1)
    sub = np.ceil(gap / max_step_m).astype(np.int64)
    extra = int(np.sum(np.maximum(sub - 1, 0)))
    budget = max_samples - n
    if extra > budget:  # too long a flight: fewer subdivisions, spread evenly
        scale = budget / extra
        sub = np.maximum(1, np.floor(sub * scale).astype(np.int64))
    if np.all(sub <= 1):
        return t, p
    # sub[i] points in interval i: t[i] + j / sub[i] * (t[i+1] - t[i]), j = 0..sub[i]-1
    idx = np.repeat(np.arange(len(sub)), sub)
    j = np.arange(len(idx)) - np.repeat(np.cumsum(sub) - sub, sub)
    ts = np.append(t[idx] + j / sub[idx] * (t[idx + 1] - t[idx]), t[-1])
    return ts, schedule.sample(ts)


def plan_breaches(
    flight: FlightPlan,
    schedule: Schedule,
    *,
    dt_s: float = CHECK_DT_S,
    max_step_m: float = CHECK_STEP_M,
    max_samples: int = CHECK_MAX_SAMPLES,
) -> list[FenceBreach]:
    """Breaches of ``flight``'s geofence by the planned trajectory ``schedule`` (same frame)."""
    if flight.geofence.empty:
        return []
    t, p = sample_schedule(schedule, dt_s=dt_s, max_step_m=max_step_m, max_samples=max_samples)
    return breaches(flight.geofence, plan_legs(flight), t, p)


def require_plan_inside(flight: FlightPlan, schedule: Schedule) -> None:
    """Raise :class:`MissionError` naming the offending leg(s) if the planned trajectory
    breaches the geofence (the command then refuses the mission: exit 2 / STATUSTEXT)."""
    found = plan_breaches(flight, schedule)
    if not found:
        return
    more = f" (and {len(found) - 1} more breach(es))" if len(found) > 1 else ""
    raise MissionError(flight.source,
                       f"geofence: {found[0].message}{more}; refusing to fly this plan")


def flown_breaches(flight: FlightPlan, t_s: FloatArray,
                   pos_ned_m: FloatArray) -> list[FenceBreach]:
    """Breaches of ``flight``'s geofence by flown positions (N, 3) at ``t_s`` [s], given in the
    plan's frame (mission home at the origin)."""
    return breaches(flight.geofence, plan_legs(flight), t_s, pos_ned_m)


def breach_report(found: Sequence[FenceBreach]) -> list[dict[str, object]]:
    """JSON-ready rows of breaches (leg, items, zone, length, first time and point)."""
    return [
        {"leg": b.leg.name, "from_item": b.leg.start_item, "to_item": b.leg.end_item,
         "zone": b.zone, "length_m": round(b.length_m, 2), "t_s": round(b.t_s, 3),
         "first_north_m": round(b.first_ned_m[0], 2), "first_east_m": round(b.first_ned_m[1], 2),
         "samples": b.samples, "message": b.message}
        for b in found
    ]


__all__ = [
    "FenceBreach",
    "breach_report",
    "breaches",
    "flown_breaches",
    "plan_breaches",
    "require_plan_inside",
    "sample_schedule",
    "zone_masks",
]
