"""Mission legs and per-leg flight figures. Pure (numpy only): no clock, no I/O.

A *leg* is the straight segment between two consecutive points of a :class:`FlightPlan`'s path
(the start on the ground, every waypoint, the touchdown point), zero-length legs dropped. A
trajectory (planned samples or flown positions, time-ordered, in the plan's local NED frame) is
cut into legs at its *passages* of the leg ends, found in order: the first sample inside the
point's acceptance radius, then on to the closest sample while the distance still shrinks (a
point never entered counts as passed at the closest sample before the next point is entered).

Per leg the report gives (:func:`leg_figures`): the planned cruise speed (the mission's speed for
the leg, ``FlightWaypoint.speed_m_s``), the flown mean and max speed, the deviation of the flown
positions from the straight leg (max and RMS distance to the segment, m) and the leg time
against an optional time-optimal bound (``bound_s``; None shows as "-").
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from companion.mission import FlightPlan
from companion.planning.schedule import Schedule

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: Legs shorter than this are dropped (repeated points, e.g. a LAND item above the last
#: waypoint) [m].
MIN_LEG_M = 1e-3
#: Time at rest within this distance of a leg's start point (a hold, a turn on the spot) is not
#: the leg's [m] ...
DEPART_RADIUS_M = 0.5
#: ... at rest: slower than this [m/s].
REST_SPEED_M_S = 0.2
#: Smallest acceptance radius used to find passages [m].
MIN_ACCEPTANCE_M = 0.2


@dataclass(frozen=True)
class Leg:
    """One straight leg of the plan, local NED [m].

    ``start_label``/``end_label`` name the ends for a pilot ("item 5", "the start", "the RTL
    climb", "the landing point"); ``start_item``/``end_item`` are the mission item numbers (None
    for points the plan adds). ``cruise_speed_m_s`` is the mission's cruise speed of the leg
    (the speed of the waypoint it arrives at); ``acceptance_m`` the end point's radius.
    """

    index: int
    start_ned_m: tuple[float, float, float]
    end_ned_m: tuple[float, float, float]
    start_label: str
    end_label: str
    start_item: int | None
    end_item: int | None
    cruise_speed_m_s: float
    acceptance_m: float
    phase: str = "mission"
    """Flight-plan phase of the end point ("takeoff", "mission", "rtl", "land")."""

    @property
    def name(self) -> str:
        """``"item 5 to item 6"``."""
        return f"{self.start_label} to {self.end_label}"

    @property
    def length_m(self) -> float:
        return float(np.linalg.norm(np.subtract(self.end_ned_m, self.start_ned_m)))


def _label(item: int | None, phase: str, command: int) -> str:
    if item is not None:
        return f"item {item}"
    if phase == "rtl":
        return "the RTL climb" if command == 20 else "the RTL point"
    if phase == "takeoff":
        return "the takeoff climb"
    return f"a {phase} point"


def plan_legs(flight: FlightPlan) -> tuple[Leg, ...]:
    """The legs of ``flight``'s path: start -> waypoints -> touchdown (if any)."""
    pts = [_Point(_vec3(flight.start_ned_m), "the start", None, 0.0, MIN_ACCEPTANCE_M,
                  "takeoff")]
    for w in flight.waypoints:
        pts.append(_Point(_vec3(w.pos_ned_m), _label(w.item_index, w.phase, w.command),
                          w.item_index, float(w.speed_m_s), float(w.acceptance_radius_m),
                          w.phase))
    if flight.touchdown_ned_m is not None:
        pts.append(_Point(_vec3(flight.touchdown_ned_m), "the landing point", None,
                          float(flight.land_speed_m_s), MIN_ACCEPTANCE_M, "land"))
    legs: list[Leg] = []
    prev = pts[0]
    for cur in pts[1:]:
        if float(np.linalg.norm(np.subtract(cur.pos, prev.pos))) < MIN_LEG_M:
            # a repeated point: the leg after it starts from the later one (its label)
            prev = _Point(prev.pos, cur.label, cur.item, prev.speed, prev.acceptance, cur.phase)
            continue
        legs.append(Leg(len(legs), prev.pos, cur.pos, prev.label, cur.label, prev.item,
                        cur.item, cur.speed, max(cur.acceptance, MIN_ACCEPTANCE_M), cur.phase))
        prev = cur
    return tuple(legs)


@dataclass(frozen=True)
class _Point:
    pos: tuple[float, float, float]
    label: str
    item: int | None
    speed: float
    acceptance: float
    phase: str


def _vec3(v: Sequence[float]) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))


def segment_distance(points: FloatArray, a: Sequence[float] | FloatArray,
                     b: Sequence[float] | FloatArray) -> FloatArray:
    """Distance [m] of each point (N, 3) to the segment from ``a`` to ``b`` (3D)."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    a_ = np.asarray(a, dtype=np.float64)
    ab = np.asarray(b, dtype=np.float64) - a_
    den = float(ab @ ab)
    s = np.zeros(len(p)) if den == 0.0 else np.clip((p - a_) @ ab / den, 0.0, 1.0)
    return np.asarray(np.linalg.norm(p - (a_ + s[:, None] * ab), axis=1), dtype=np.float64)


def _first_within(p: FloatArray, i0: int, point: FloatArray, r: float) -> int | None:
    """First index >= i0 of ``p`` within ``r`` of ``point`` (searched in growing windows, so
    a long flight costs about the samples up to the hit)."""
    n, i, w = len(p), i0, 1024
    while i < n:
        hit = np.flatnonzero(np.linalg.norm(p[i:i + w] - point, axis=1) <= r)
        if len(hit):
            return i + int(hit[0])
        i += w
        w *= 2
    return None


def _downhill(p: FloatArray, j: int, point: FloatArray) -> int:
    """From ``j`` on, the first sample after which the distance to ``point`` stops shrinking."""
    n = len(p)
    while True:
        d = np.linalg.norm(p[j:j + 256] - point, axis=1)
        up = np.flatnonzero(np.diff(d) >= 0.0)
        if len(up):
            return j + int(up[0])
        if j + len(d) >= n:
            return n - 1
        j += len(d) - 1


def passages(points: FloatArray, legs: Sequence[Leg]) -> list[int | None]:
    """Sample index at which ``points`` (N, 3, in time order) passes each leg's end point, in
    order (see the module doc); None once the samples run out. Element 0 is the start (index 0
    when there are samples)."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    n = len(p)
    out: list[int | None] = [0 if n else None]
    i0 = 0
    ends = [np.asarray(leg.end_ned_m, dtype=np.float64) for leg in legs]
    for k, leg in enumerate(legs):
        if n == 0 or out[-1] is None:
            out.append(None)
            continue
        first = _first_within(p, i0, ends[k], leg.acceptance_m)
        if first is not None:
            j = _downhill(p, first, ends[k])
        else:
            # never entered: the closest sample before the next point is entered
            stop = n
            if k + 1 < len(legs):
                nxt = _first_within(p, i0, ends[k + 1], legs[k + 1].acceptance_m)
                if nxt is not None and nxt > i0:
                    stop = nxt
            j = i0 + int(np.argmin(np.linalg.norm(p[i0:stop] - ends[k], axis=1)))
        out.append(j)
        i0 = j
    return out


def leg_spans(points: FloatArray, legs: Sequence[Leg],
              speed_m_s: FloatArray | None = None) -> list[tuple[int, int] | None]:
    """Per leg, the sample range ``(first, last)`` (inclusive) flown on it: from the passage
    of its start point, or, if the trajectory rests there (``speed_m_s`` per sample below
    REST_SPEED_M_S within DEPART_RADIUS_M: a hold, a turn), from the end of that rest, to the
    passage of its end point; None if the trajectory never got there."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    pas = passages(p, legs)
    spans: list[tuple[int, int] | None] = []
    for k, leg in enumerate(legs):
        i, j = pas[k], pas[k + 1]
        if i is None or j is None or j < i:
            spans.append(None)
            continue
        if speed_m_s is not None:
            d0 = np.linalg.norm(p[i:j + 1] - np.asarray(leg.start_ned_m), axis=1)
            resting = (speed_m_s[i:j + 1] < REST_SPEED_M_S) & (d0 <= DEPART_RADIUS_M)
            moving = np.flatnonzero(~resting)
            if len(moving) and moving[0] > 0:
                i = min(i + int(moving[0]) - 1, j)  # the last sample at rest
        spans.append((i, j))
    return spans


def leg_of_samples(points: FloatArray, legs: Sequence[Leg]) -> IntArray:
    """Leg index of every sample (by passages: samples up to the first passage belong to leg 0,
    samples after the last passage found to the last leg reached)."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    out = np.zeros(len(p), dtype=np.int64)
    pas = passages(p, legs)
    for k in range(1, len(legs)):
        j = pas[k]
        if j is None:
            break
        out[j + 1:] = k
    return out


def _r(x: float | None, nd: int = 3) -> float | None:
    return None if x is None or not math.isfinite(x) else round(float(x), nd)


def leg_figures(
    legs: Sequence[Leg],
    t_s: FloatArray,
    pos_ned: FloatArray,
    *,
    vel_ned: FloatArray | None = None,
    planned_t_s: FloatArray | None = None,
    planned_ned: FloatArray | None = None,
    bounds_s: Sequence[float | None] | None = None,
) -> list[dict[str, Any]]:
    """Per-leg figures of a flight (keys carry units; None where not measurable).

    ``t_s``/``pos_ned`` the flown samples (plan frame), ``vel_ned`` their velocities (else
    finite differences); ``planned_t_s``/``planned_ned`` the plan sampled densely (for the
    planned time and max speed of each leg); ``bounds_s`` the time-optimal bound of each leg
    (None: unknown). Keys: leg, from_item, to_item, length_m, cruise_speed_m_s,
    planned_time_s, planned_max_speed_m_s, time_s, bound_s, time_over_bound, mean_speed_m_s,
    max_speed_m_s, max_deviation_m, rms_deviation_m, samples.
    """
    t = np.asarray(t_s, dtype=np.float64).reshape(-1)
    p = np.asarray(pos_ned, dtype=np.float64).reshape(-1, 3)
    if len(t) != len(p):
        raise ValueError(f"{len(t)} times but {len(p)} positions")
    if bounds_s is not None and len(bounds_s) != len(legs):
        raise ValueError(f"{len(legs)} legs but {len(bounds_s)} bounds")
    speed = _speeds(t, p, vel_ned)
    spans = leg_spans(p, legs, speed)
    pspans: list[tuple[int, int] | None] = [None] * len(legs)
    pspeed = np.zeros(0)
    pt = np.zeros(0)
    if planned_t_s is not None and planned_ned is not None:
        pt = np.asarray(planned_t_s, dtype=np.float64).reshape(-1)
        pp = np.asarray(planned_ned, dtype=np.float64).reshape(-1, 3)
        pspeed = _speeds(pt, pp, None)
        pspans = leg_spans(pp, legs, pspeed)
    out: list[dict[str, Any]] = []
    for k, leg in enumerate(legs):
        bound = None if bounds_s is None else bounds_s[k]
        row: dict[str, Any] = {
            "leg": leg.name, "from_item": leg.start_item, "to_item": leg.end_item,
            "length_m": _r(leg.length_m), "cruise_speed_m_s": _r(leg.cruise_speed_m_s),
            "planned_time_s": None, "planned_max_speed_m_s": None,
            "time_s": None, "bound_s": _r(bound), "time_over_bound": None,
            "mean_speed_m_s": None, "max_speed_m_s": None,
            "max_deviation_m": None, "rms_deviation_m": None, "samples": 0,
        }
        ps = pspans[k]
        if ps is not None:
            row["planned_time_s"] = _r(float(pt[ps[1]] - pt[ps[0]]))
            row["planned_max_speed_m_s"] = _r(float(np.max(pspeed[min(ps[0] + 1, ps[1]):
                                                                  ps[1] + 1])))
        sp = spans[k]
        if sp is not None:
            i, j = sp
            seg = p[i:j + 1]
            dev = segment_distance(seg, leg.start_ned_m, leg.end_ned_m)
            dt = float(t[j] - t[i])
            flown = float(np.sum(np.linalg.norm(np.diff(seg, axis=0), axis=1)))
            row.update(
                time_s=_r(dt),
                mean_speed_m_s=_r(flown / dt) if dt > 0 else None,
                # the first sample is the previous leg's arrival
                max_speed_m_s=_r(float(np.max(speed[min(i + 1, j):j + 1]))),
                max_deviation_m=_r(float(np.max(dev))),
                rms_deviation_m=_r(float(np.sqrt(np.mean(dev**2)))),
                samples=int(j - i + 1),
            )
            if bound is not None and bound > 0 and dt > 0:
                row["time_over_bound"] = _r(dt / bound)
        out.append(row)
    return out


def _speeds(t: FloatArray, p: FloatArray, vel: FloatArray | None) -> FloatArray:
    """|velocity| per sample [m/s]: from ``vel`` if given, else backward differences."""
    if vel is not None:
        v = np.asarray(vel, dtype=np.float64).reshape(-1, 3)
        if len(v) != len(p):
            raise ValueError(f"{len(p)} positions but {len(v)} velocities")
        return np.asarray(np.linalg.norm(v, axis=1), dtype=np.float64)
    if len(p) < 2:
        return np.zeros(len(p))
    dt = np.diff(t)
    step = np.linalg.norm(np.diff(p, axis=0), axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        seg = np.where(dt > 0, step / np.where(dt > 0, dt, 1.0), 0.0)
    # backward differences: a sample's speed is that of the step arriving at it
    return np.concatenate([seg[:1], seg])


def worst_leg(figures: Sequence[dict[str, Any]]) -> dict[str, Any] | None:
    """The leg with the largest max deviation (None if no leg was flown)."""
    flown = [f for f in figures if f.get("max_deviation_m") is not None]
    return max(flown, key=lambda f: f["max_deviation_m"]) if flown else None


def _fmt(x: object, spec: str) -> str:
    return "-" if x is None else format(x, spec)


def worst_leg_text(figures: Sequence[dict[str, Any]]) -> str:
    """One line for the console: the worst leg's deviation, speeds and time vs bound."""
    w = worst_leg(figures)
    if w is None:
        return "no leg flown"
    return (f"worst leg {w['leg']}: deviation max {_fmt(w['max_deviation_m'], '.2f')} m, "
            f"RMS {_fmt(w['rms_deviation_m'], '.2f')} m; speed mean "
            f"{_fmt(w['mean_speed_m_s'], '.1f')} / max {_fmt(w['max_speed_m_s'], '.1f')} "
            f"(mission {_fmt(w['cruise_speed_m_s'], '.1f')}, planned "
            f"{_fmt(w.get('planned_max_speed_m_s'), '.1f')}) m/s; time "
            f"{_fmt(w['time_s'], '.1f')} s (bound {_fmt(w['bound_s'], '.1f')} s)")


__all__ = [
    "Leg",
    "leg_figures",
    "leg_of_samples",
    "leg_spans",
    "passages",
    "plan_legs",
    "segment_distance",
    "worst_leg",
    "worst_leg_text",
]


def plan_bounds(flight: FlightPlan, schedule: Schedule) -> tuple[tuple[float | None, ...], float]:
    """Time-optimal bound per leg of :func:`plan_legs` and of the whole schedule [s]
    (``Schedule.bound_profile``, cut into legs by the same passages as the flown and planned
    times: :func:`leg_spans`). A leg the bound never reaches gets None; rovers get Nones and
    the planned duration."""
    legs = plan_legs(flight)
    if schedule.vehicle == "rover":
        return tuple(None for _ in legs), schedule.duration_s
    t, p, v = schedule.bound_profile()
    spans = leg_spans(p, legs, v)
    out = tuple(None if sp is None else float(t[sp[1]] - t[sp[0]]) for sp in spans)
    return out, float(t[-1])
