"""Mission flight plan -> one time-indexed reference: planned trajectory pieces, yaw turns at
stops, and holds. Pure (numpy + the planner); used by the replay and the `fly` command.

The vehicle starts on the ground at the plan's start point. Each stop-to-stop chunk of the
flight plan (`companion.mission.split_flight_plan`) becomes one minimum-snap trajectory that
starts and ends at rest (a chunk on one straight line, e.g. a climb or a descent: the
jerk-limited trapezoid along it, `companion.trajectory.straight`); where the heading changes
at a stop, an in-place yaw turn is inserted; a hold keeps the last point. For multirotors the
final descent is cut `handover_height_m` above the touchdown point, where PX4's own landing
(NAV_LAND) takes over.

One chunk's planning lives in :mod:`companion.planning.chunks` (with :class:`VehicleLimits`),
the memo of planned chunks in :mod:`companion.planning.memo`.
"""

from __future__ import annotations

import bisect
import dataclasses
import functools
import itertools
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from companion.flatness import MultirotorParams
from companion.flatness.reference import Reference, reference_of_arrays
from companion.mission import FlightChunk, FlightPlan, split_flight_plan
from companion.mission.px4_params import Px4PlanningParams
from companion.planning.chunks import (
    AXIS_PASSES,
    LAND_PROFILE_STEPS,
    ROVER_CORRIDOR_SAMPLES,
    ROVER_JOINT_MIN_M,
    ROVER_JOINT_PATTERNS,
    ROVER_RETRY_MAX_LEGS,
    STRAIGHT_JERK_M_S3,
    STRAIGHT_STRETCHES,
    STRAIGHT_TILT_MARGIN,
    TILT_FEEDBACK_MARGIN_DEG,
    TURN_RATE_RAD_S,
    VehicleLimits,
    axis_ratios,
    land_descent_rate,
    land_profile,
    leg_speed_caps,
    level_speed_cap_m_s,
    plan_chunk,
    planning_tilt_rad,
)
from companion.planning.memo import PlanMemo, exact_key
from companion.planning.rover_path import SteeringError
from companion.trajectory import PiecewiseBezier, hermite
from companion.trajectory.bezier import ScalarEvaluator
from companion.trajectory.bound import (
    KinematicLimits,
    time_optimal_duration,
    time_optimal_profile,
)
from companion.trajectory.corridor import segment_distances

# the public names, with those of the chunk planner and the memo (re-exported from their modules)
__all__ = [
    "AXIS_PASSES",
    "CRUISE_ACC_M_S2",
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
    "Piece",
    "PlanMemo",
    "Schedule",
    "VehicleLimits",
    "axis_ratios",
    "build_schedule",
    "exact_key",
    "land_descent_rate",
    "land_profile",
    "leg_speed_caps",
    "level_speed_cap_m_s",
    "planning_tilt_rad",
    "time_optimal_bound_s",
    "trajectory_reference",
]

_log = logging.getLogger("companion.planning.schedule")

FloatArray = NDArray[np.float64]

#: Largest vertical acceleration of a descent still called cruising [m/s^2] (where a vehicle
#: landing itself leaves the plan: 0.05 m/s^2 is 0.0026 of normalised thrust at hover 0.5).
CRUISE_ACC_M_S2 = 0.05


@dataclass(frozen=True, eq=False)
class Piece:
    """One timed piece: a trajectory (kind "traj"), an in-place yaw turn ("turn"), or a hold.

    t0_s: start on the schedule clock [s]; duration_s [s]; pos_ned [m] for turn/hold;
    yaw0/yaw1 [rad] for turns (yaw0 also the held yaw); traj for "traj"; phase as in the plan.
    """

    kind: str
    t0_s: float
    duration_s: float
    phase: str
    pos_ned: FloatArray
    yaw0: float
    yaw1: float
    traj: PiecewiseBezier | None = None
    turn: PiecewiseBezier | None = None
    speed_caps: FloatArray | None = None
    """Planner's speed limit along the path per segment of `traj` [m/s] (for the bound)."""

    @functools.cached_property
    def _eval(self) -> ScalarEvaluator | None:
        return None if self.traj is None else self.traj.scalar_evaluator(4)

    @functools.cached_property
    def _eval_yaw(self) -> ScalarEvaluator | None:
        src = self.turn if self.turn is not None else (self.traj.yaw if self.traj else None)
        return None if src is None else src.scalar_evaluator(2)


@dataclass(frozen=True)
class Schedule:
    """A planned flight: pieces back to back from t = 0 to `duration_s`.

    `waypoints_ned` (K, 3) with `acceptance_m` and `item_indices` are the points the flight must
    pass (for reach checks): one per mission item with a position flown (each pass of a DO_JUMP
    loop), none for points the plan adds; `final_action` is "land", "rtl" or "loiter".
    """

    pieces: tuple[Piece, ...]
    duration_s: float
    waypoints_ned: FloatArray
    acceptance_m: tuple[float, ...]
    item_indices: tuple[int | None, ...]
    final_action: str
    vehicle: str
    px4: Px4PlanningParams = dataclasses.field(default_factory=Px4PlanningParams)
    level_speed_cap_m_s: float = math.inf
    """The fastest level flight the plan allows [m/s] (:func:`level_speed_cap_m_s`); the
    time-optimal bound respects it too."""
    warnings: tuple[str, ...] = ()
    """What the plan could not give the mission as asked (e.g. a speed item above the level
    speed cap), each said once."""

    def bound_profile(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """The time-optimal traversal behind :meth:`piece_bounds_s`, piece after piece: times
        (N,) [s], points (N, 3) NED [m] (with the schedule's turns and holds as rests) and
        speeds (N,) [m/s]. Multirotor only."""
        lim = self._bound_limits()
        ts: list[FloatArray] = []
        ps: list[FloatArray] = []
        vs: list[FloatArray] = []
        t0 = 0.0
        for p in self.pieces:
            if p.kind == "traj" and p.traj is not None and p.traj.dim == 3:
                t, pts, v = time_optimal_profile(p.traj, lim, p.speed_caps)
                ts.append(t0 + t)
                ps.append(pts)
                vs.append(v)
                t0 += float(t[-1])
            else:
                ts.append(np.array([t0, t0 + p.duration_s]))
                ps.append(np.repeat(_pad3(np.asarray(p.pos_ned, dtype=np.float64))[None, :], 2,
                                    axis=0))
                vs.append(np.zeros(2))
                t0 += p.duration_s
        return np.concatenate(ts), np.concatenate(ps), np.concatenate(vs)

    def _bound_limits(self) -> KinematicLimits:
        px4 = self.px4
        return KinematicLimits(
            max_speed_xy_m_s=min(px4.MPC_XY_VEL_MAX, self.level_speed_cap_m_s),
            max_climb_m_s=px4.MPC_Z_VEL_MAX_UP,
            max_descent_m_s=px4.MPC_Z_VEL_MAX_DN,
            max_acc_xy_m_s2=px4.MPC_ACC_HOR_MAX,
            max_acc_up_m_s2=px4.MPC_ACC_UP_MAX,
            max_acc_down_m_s2=px4.MPC_ACC_DOWN_MAX,
        )

    def piece_bounds_s(self) -> list[float]:
        """Per piece, the time-optimal bound [s]: for a multirotor trajectory piece the
        shortest time along the same path under the same speed caps and PX4's speed and
        acceleration limits (``companion.trajectory.bound``); turns, holds and rover pieces
        count at their planned duration."""
        lim = self._bound_limits()
        out: list[float] = []
        for p in self.pieces:
            if p.kind == "traj" and p.traj is not None and p.traj.dim == 3:
                out.append(time_optimal_duration(p.traj, lim, p.speed_caps))
            else:
                out.append(p.duration_s)
        return out

    def time_optimal_bound_s(self) -> float:
        """Lower bound on the schedule's duration [s] (sum of :meth:`piece_bounds_s`)."""
        return float(sum(self.piece_bounds_s()))

    def reference(self, t: float, origin: FloatArray | None = None) -> Reference:
        """Flat-output reference at schedule time `t` [s] (clamped to the schedule), with the
        positions shifted by `origin` (NED, m) if given."""
        piece = self.piece_at(t)
        tl = min(max(t - piece.t0_s, 0.0), piece.duration_s)
        if piece.kind == "traj":
            ev = piece._eval
            assert ev is not None
            ey = piece._eval_yaw
            # values are order-major: every dim-th is yaw, its rate, its acceleration (floats)
            y = ey.values(tl)[:: ey.dim] if ey is not None else (piece.yaw0, 0.0, 0.0)
            if ev.dim == 3 and (
                origin is None or (type(origin) is np.ndarray and origin.shape == (3,))
            ):
                # fast path: [pos, vel, acc, jerk, snap] as 15 floats, the origin added in
                # floats (the same IEEE sums as `d[0] + origin`), then one float64 (5, 3)
                # array whose rows are already what Reference's conversions would give
                v = ev.values(tl)
                if origin is not None:
                    o0, o1, o2 = origin.tolist()
                    v[0] += o0
                    v[1] += o1
                    v[2] += o2
                d = np.array(v, dtype=np.float64).reshape(5, 3)
                return reference_of_arrays(
                    d[0], d[1], d[2], d[3], d[4], float(y[0]), float(y[1]), float(y[2])
                )
            d = ev(tl)
            if d.shape[1] == 2:
                d = np.column_stack([d, np.zeros(5)])
            p = d[0] if origin is None else d[0] + origin
            return Reference(p, d[1], d[2], d[3], d[4], float(y[0]), float(y[1]), float(y[2]))
        if piece.kind == "turn":
            ey = piece._eval_yaw
            assert ey is not None
            y = ey.values(tl)[:: ey.dim]
            p = piece.pos_ned if origin is None else piece.pos_ned + origin
            return Reference(p, yaw=float(y[0]), yaw_rate=float(y[1]), yaw_acc=float(y[2]))
        p = piece.pos_ned if origin is None else piece.pos_ned + origin
        return Reference(p, yaw=piece.yaw0)

    def phase(self, t: float) -> str:
        """Flight-plan phase at schedule time `t`."""
        return self.piece_at(t).phase

    def final_descent_cruise(self, speed_m_s: float, step_s: float = 0.02) -> tuple[float, float]:
        """Where the final landing descent stops cruising: (schedule time [s], descent speed
        [m/s] there), the last time the plan still descends at >= 95 % of `speed_m_s`
        (MPC_LAND_SPEED) at a steady speed (vertical acceleration at most
        CRUISE_ACC_M_S2) before it slows to its stop; (duration_s, 0.0) when the plan does
        not end in such a descent. A vehicle landing itself continues straight down from
        there instead of stopping above the ground first; cut inside the plan's slow-down
        ramp, the reference's acceleration would step back to zero (a thrust step)."""
        last = self.pieces[-1]
        if last.kind != "traj" or last.phase != "land" or last.traj is None:
            return self.duration_s, 0.0
        t = np.arange(last.duration_s, -1e-9, -step_s)
        v = last.traj.evaluate(t, 1)
        if v.shape[1] < 3:
            return self.duration_s, 0.0
        a = last.traj.evaluate(t, 2)
        cruising = (v[:, 2] >= 0.95 * speed_m_s) & (np.abs(a[:, 2]) <= CRUISE_ACC_M_S2)
        level = np.hypot(v[:, 0], v[:, 1]) <= 0.1
        if not cruising.any():
            return self.duration_s, 0.0
        k = int(np.argmax(cruising))  # the first from the end
        if not level[: k + 1].all():
            return self.duration_s, 0.0
        return last.t0_s + float(t[k]), float(v[k, 2])

    def sample(self, t: FloatArray) -> FloatArray:
        """Planned positions (N, 3) NED at times `t` [s] (vectorised over trajectory pieces)."""
        t = np.asarray(t, dtype=np.float64)
        out = np.empty((len(t), 3))
        for p in self.pieces:
            sel = (t >= p.t0_s) & (t <= p.t0_s + p.duration_s)
            if not sel.any():
                continue
            if p.kind == "traj":
                assert p.traj is not None
                v = p.traj.evaluate(t[sel] - p.t0_s, 0)
                out[sel] = v if v.shape[1] == 3 else np.column_stack([v, np.zeros(len(v))])
            else:
                out[sel] = p.pos_ned
        out[t > self.duration_s] = self.reference(self.duration_s).pos_ned
        return out

    def piece_at(self, t: float) -> Piece:
        """The piece flown at schedule time `t` [s]: the first ending after it (the last piece
        beyond the end)."""
        ends = self._ends
        if ends is not None:  # back to back: ends ascending, so bisect finds the first
            i = bisect.bisect_right(ends, t)
            return self.pieces[i] if i < len(ends) else self.pieces[-1]
        for p in self.pieces:
            if t < p.t0_s + p.duration_s:
                return p
        return self.pieces[-1]

    @functools.cached_property
    def _ends(self) -> list[float] | None:
        ends = [p.t0_s + p.duration_s for p in self.pieces]
        return ends if all(a <= b for a, b in itertools.pairwise(ends)) else None


def _pad3(v: FloatArray) -> FloatArray:
    v = np.asarray(v, dtype=np.float64).reshape(-1)
    return v if v.shape[0] == 3 else np.array([v[0], v[1], 0.0])


def _heading(a: FloatArray, b: FloatArray, fallback: float) -> float:
    d = np.asarray(b, dtype=np.float64) - np.asarray(a, dtype=np.float64)
    if math.hypot(d[0], d[1]) < 0.5:
        return fallback
    return math.atan2(d[1], d[0])


def _unwrap_to(target: float, reference: float) -> float:
    """`target` shifted by multiples of 2 pi to be within pi of `reference`."""
    return reference + (target - reference + math.pi) % (2.0 * math.pi) - math.pi


def _turn(yaw0: float, yaw1: float) -> tuple[PiecewiseBezier, float]:
    """Rest-to-rest quintic yaw turn from yaw0 to yaw1 (peak rate <= TURN_RATE_RAD_S)."""
    dy = abs(yaw1 - yaw0)
    duration = max(1.875 * dy / TURN_RATE_RAD_S, 0.5)  # quintic peak rate = 1.875 dy / T
    seg = hermite(
        np.array([[yaw0], [0.0], [0.0]]), np.array([[yaw1], [0.0], [0.0]]), duration
    )
    return PiecewiseBezier([seg]), duration


def _chunk_yaw(chunk: FlightChunk, yaw_in: float, vehicle: str) -> tuple[object, float, float]:
    """Yaw spec for `plan` and the (start, end) yaw of the chunk [rad]."""
    pts = chunk.points_ned_m
    given = [None if y is None else math.radians(y) for y in chunk.yaw_deg]
    horizontal = float(np.max(np.ptp(np.asarray(pts)[:, :2], axis=0))) if len(pts) else 0.0
    if chunk.phase in ("takeoff", "land") or len(pts) < 2 or horizontal < 0.5:
        # a vertical climb or descent: no heading to follow, hold (or turn to) the given yaw
        yaw = yaw_in if given[-1] is None else _unwrap_to(given[-1], yaw_in)
        return yaw, yaw, yaw
    if vehicle == "rover" or all(g is None for g in given[1:]):
        start = _unwrap_to(_heading(pts[0], pts[1], yaw_in), yaw_in)
        end = _heading(pts[-2], pts[-1], start)
        return "velocity", start, end
    # per-waypoint yaw: fill the free ones with the leg heading, unwrap along the way
    seq: list[float] = []
    prev = yaw_in
    for i, g in enumerate(given):
        if g is None:
            g = _heading(pts[max(i - 1, 0)], pts[min(i + 1, len(pts) - 1)], prev) if i else prev
        prev = _unwrap_to(g, prev)
        seq.append(prev)
    return seq, seq[0], seq[-1]


def build_schedule(
    flight: FlightPlan,
    params: MultirotorParams | None,
    limits: VehicleLimits | None = None,
    *,
    initial_yaw: float = 0.0,
    handover_height_m: float = 1.0,
    memo: PlanMemo | None = None,
) -> Schedule:
    """Plan every chunk of `flight` and lay them on one clock (see the module docstring).
    `memo`: serve a chunk whose planner input was planned before from there (:class:`PlanMemo`;
    the schedule is the same as without it)."""
    limits = limits or VehicleLimits()
    rover = flight.vehicle == "rover"
    chunks = list(split_flight_plan(flight))
    if not chunks:
        raise ValueError(f"{flight.source}: the mission has no positional item to fly")
    pieces: list[Piece] = []
    t = 0.0
    yaw = initial_yaw
    v_level = math.inf if rover else level_speed_cap_m_s(params, limits, flight.px4)
    too_fast: dict[float, list[int]] = {}  # asked speed -> items of the legs that asked it
    wps: list[FloatArray] = []
    acc: list[float] = []
    items: list[int | None] = []
    ci = -1
    while ci + 1 < len(chunks):
        ci += 1
        chunk = chunks[ci]
        pts = np.array(chunk.points_ned_m, dtype=np.float64)
        if not rover and ci == len(chunks) - 1 and chunk.phase == "land" and (
            flight.final_action in ("land", "rtl")
        ):
            # stop above the touchdown point; PX4's NAV_LAND does the last metre
            pts[-1, 2] = min(pts[-1, 2], float(flight.start_ned_m[2]) - handover_height_m)
            if np.linalg.norm(pts[-1] - pts[-2]) < 0.05:
                pts = pts[:-1]
        if len(pts) < 2:
            continue
        yaw_spec, y_start, y_end = _chunk_yaw(chunk, yaw, flight.vehicle)
        if not rover and isinstance(yaw_spec, float) and ci + 1 < len(chunks):
            # a vertical climb turns to the next leg's heading on the way (as PX4 does) instead
            # of turning in place before or after it
            nxt = chunks[ci + 1]
            nxt_spec, nxt_start, _ = _chunk_yaw(nxt, yaw, flight.vehicle)
            if not isinstance(nxt_spec, float) and chunk.phase != "land":
                target = _unwrap_to(nxt_start, yaw)
                if abs(target - yaw) > math.radians(1.0):
                    yaw_spec = [float(v) for v in np.linspace(yaw, target, len(pts))]
                    y_start, y_end = yaw, target
        caps = leg_speed_caps(chunk, pts, flight.px4, rover)
        if math.isfinite(v_level):
            _note_fast_legs(chunk, min(v_level, flight.px4.MPC_XY_VEL_MAX), too_fast)
        if chunk.phase == "land" and not rover:
            pts, caps = land_profile(pts, caps, flight.px4, float(flight.start_ned_m[2]))
        try:
            run = functools.partial(plan_chunk, chunk, pts, params, limits, rover, yaw_spec,
                                    caps, flight.px4)
            # the memo's key: everything `plan_chunk` reads (of the chunk its acceptance
            # radii, point count and phase)
            traj = run() if memo is None else memo.get_or_plan(exact_key((
                chunk.acceptance_radius_m, len(chunk.points_ned_m), chunk.phase, pts, params,
                limits, rover, yaw_spec, caps, flight.px4)), run)
        except ValueError as exc:
            if isinstance(exc, SteeringError):  # stops would not help a car-like rover
                raise SteeringError(f"{flight.source}: {exc}") from exc
            if len(chunk.points_ned_m) <= 2:
                leg = f"{np.round(pts[0], 1)} to {np.round(pts[-1], 1)} m"
                raise ValueError(f"{flight.source}: cannot plan the leg {leg}: {exc}") from exc
            # numerically out of reach as a whole (e.g. a 40 km leg next to a 50 m one: the
            # snap cost spans beyond double precision): fly it as rest-to-rest legs instead
            _log.warning("%s: %s; flying that part leg by leg, stopping at each point",
                         flight.source, exc)
            chunks[ci:ci + 1] = _legs(chunk)
            ci -= 1
            continue
        yaw_ch = traj.yaw
        if yaw_ch is not None:
            # the planner unwraps on its own: shift its channel to start within pi of `yaw`
            y0 = float(yaw_ch.evaluate(0.0, 0)[0])
            y_start = _unwrap_to(y0, yaw)
            if abs(y_start - yaw) <= math.radians(1.0):
                y_start = yaw  # too small for a turn: shift the channel to join continuously
            if y_start != y0:
                yaw_ch = PiecewiseBezier.from_control_points(
                    yaw_ch.control_points + (y_start - y0), yaw_ch.durations
                )
                traj = traj.with_yaw(yaw_ch)
            y_end = float(yaw_ch.evaluate(traj.duration, 0)[0])
        if abs(y_start - yaw) > math.radians(1.0):
            turn, dur = _turn(yaw, y_start)
            pieces.append(Piece("turn", t, dur, chunk.phase, pts[0], yaw, y_start, turn=turn))
            t += dur
        yaw = y_start
        pieces.append(
            Piece("traj", t, traj.duration, chunk.phase, pts[0], yaw, y_end, traj=traj,
                  speed_caps=_segment_caps(traj, pts, caps))
        )
        t += traj.duration
        yaw = y_end
        if chunk.hold_after_s > 0.0:
            pieces.append(Piece("hold", t, chunk.hold_after_s, chunk.phase, pts[-1], yaw, yaw))
            t += chunk.hold_after_s
    if not pieces:
        raise ValueError(f"{flight.source}: nothing to fly (all points coincide)")
    # the points to reach are the mission items' (one per item flown, a DO_JUMP pass each),
    # never the points the plan adds (a takeoff climb before an item, the touchdown point)
    for w in flight.waypoints:
        if w.item_index is not None:
            wps.append(np.array(w.pos_ned_m, dtype=np.float64))
            acc.append(float(w.acceptance_radius_m))
            items.append(w.item_index)
    warnings: tuple[str, ...] = ()
    if too_fast:
        asked = ", ".join(f"{v:g}" for v in sorted(too_fast))
        items_ = sorted({i for v in too_fast.values() for i in v})
        fly_at = min(v_level, flight.px4.MPC_XY_VEL_MAX)
        why = (f"the level speed its {math.degrees(planning_tilt_rad(limits, flight.px4)):.0f}"
               f" deg planning tilt holds against its drag" if fly_at == v_level
               else "PX4's MPC_XY_VEL_MAX")
        text = (f"{flight.source}: mission speed {asked} m/s (legs to item "
                f"{', '.join(map(str, items_))}) is above {why}: those legs fly at "
                f"{fly_at:.1f} m/s")
        _log.warning(text)
        warnings = (text,)
    return Schedule(
        pieces=tuple(pieces),
        duration_s=t,
        waypoints_ned=np.array(wps, dtype=np.float64).reshape(-1, 3),
        acceptance_m=tuple(acc),
        item_indices=tuple(items),
        final_action=flight.final_action,
        vehicle=flight.vehicle,
        px4=flight.px4,
        level_speed_cap_m_s=v_level,
        warnings=warnings,
    )


def _note_fast_legs(chunk: FlightChunk, fly_at: float, out: dict[float, list[int]]) -> None:
    """Add to `out` the horizontal legs of `chunk` whose mission speed is above `fly_at`
    [m/s] (asked speed -> mission items the legs lead to)."""
    pts = chunk.points_ned_m
    for k, v in enumerate(chunk.leg_speed_m_s):
        if k + 1 >= len(pts) or v <= fly_at * (1.0 + 1e-6):
            continue
        a, b = pts[k], pts[k + 1]
        if math.hypot(b[0] - a[0], b[1] - a[1]) < 1.0:
            continue
        item = chunk.item_indices[k + 1]
        out.setdefault(float(v), [])
        if item is not None:
            out[float(v)].append(item)


def _segment_caps(traj: PiecewiseBezier, pts: FloatArray, caps: FloatArray) -> FloatArray:
    """The leg speed cap of each segment of `traj` (the leg nearest its midpoint) [m/s]."""
    mid = traj.evaluate(traj.breaks[:-1] + 0.5 * traj.durations, 0)
    d = pts.shape[1] if mid.shape[1] >= pts.shape[1] else mid.shape[1]
    mid, legs = mid[:, :d], pts[:, :d]
    out = np.full(mid.shape[0], float(np.max(caps)))
    # all midpoints against all legs, in blocks of about 2^18 pairs; the first nearest leg
    step = max(1, (1 << 18) // max(len(legs) - 1, 1))
    for i in range(0, mid.shape[0], step):
        dist = segment_distances(mid[i:i + step, None, :], legs[None, :-1], legs[None, 1:])
        if dist.shape[1]:
            out[i:i + step] = caps[np.argmin(dist, axis=1)]
    return out


def _legs(chunk: FlightChunk) -> list[FlightChunk]:
    """`chunk` split into rest-to-rest legs (one per pair of consecutive points); the hold
    stays at the end."""
    n = len(chunk.points_ned_m)
    return [
        dataclasses.replace(
            chunk,
            points_ned_m=chunk.points_ned_m[k:k + 2],
            yaw_deg=chunk.yaw_deg[k:k + 2],
            acceptance_radius_m=chunk.acceptance_radius_m[k:k + 2],
            item_indices=chunk.item_indices[k:k + 2],
            leg_speed_m_s=chunk.leg_speed_m_s[k:k + 1],
            hold_after_s=chunk.hold_after_s if k == n - 2 else 0.0,
        )
        for k in range(n - 1)
    ]


def time_optimal_bound_s(
    flight: FlightPlan, params: MultirotorParams | None, limits: VehicleLimits | None = None
) -> float:
    """Time-optimal lower bound [s] of the schedule `build_schedule(flight, params, limits)`
    flies (:meth:`Schedule.time_optimal_bound_s`). Multirotors only (ValueError for a rover:
    the bound's limits are a multirotor's)."""
    if flight.vehicle == "rover":
        raise ValueError("the time-optimal bound is computed for multirotor plans only")
    return build_schedule(flight, params, limits).time_optimal_bound_s()


def trajectory_reference(traj: PiecewiseBezier, yaw: float = 0.0) -> Callable[[float], Reference]:
    """Fast reference function t [s] -> Reference for one trajectory (clamped to its ends;
    without a yaw channel the yaw is held at `yaw` [rad])."""
    pos = traj.scalar_evaluator(4)
    yaw_ev = None if traj.yaw is None else traj.yaw.scalar_evaluator(2)
    duration = traj.duration

    def ref(t: float) -> Reference:
        inside = 0.0 <= t <= duration
        d = pos(t)
        if d.shape[1] == 2:
            d = np.column_stack([d, np.zeros(5)])
        if not inside:
            d[1:] = 0.0
        if yaw_ev is None:
            y = (yaw, 0.0, 0.0)
        else:
            yv = yaw_ev(t)[:, 0]
            y = (float(yv[0]), float(yv[1]) if inside else 0.0, float(yv[2]) if inside else 0.0)
        return Reference(d[0], d[1], d[2], d[3], d[4], y[0], y[1], y[2])

    return ref

