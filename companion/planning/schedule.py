"""Mission flight plan -> one time-indexed reference: planned trajectory pieces, yaw turns at
stops, and holds. Pure (numpy + the planner); used by the replay and the `fly` command.

The vehicle starts on the ground at the plan's start point. Each stop-to-stop chunk of the
flight plan (`companion.mission.split_flight_plan`) becomes one minimum-snap trajectory that
starts and ends at rest (a chunk on one straight line, e.g. a climb or a descent: the
jerk-limited trapezoid along it, `companion.trajectory.straight`); where the heading changes
at a stop, an in-place yaw turn is inserted; a hold keeps the last point. For multirotors the
final descent is cut `handover_height_m` above the touchdown point, where PX4's own landing
(NAV_LAND) takes over.
"""

from __future__ import annotations

import bisect
import collections
import dataclasses
import functools
import itertools
import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from companion.flatness import MultirotorParams
from companion.flatness.reference import Reference, reference_of_arrays
from companion.mission import FlightChunk, FlightPlan, split_flight_plan
from companion.mission.px4_params import Px4PlanningParams
from companion.trajectory import Limits, PiecewiseBezier, RoverLimits, check, hermite, plan
from companion.trajectory.bezier import ScalarEvaluator
from companion.trajectory.bound import (
    KinematicLimits,
    time_optimal_duration,
    time_optimal_profile,
)
from companion.trajectory.planner import (
    ALLOCATION_MARGIN,
    corridor_deviation,
    segment_distances,
    velocity_heading,
)
from companion.trajectory.straight import (
    LineLimits,
    collinear_direction,
    straight_trajectory,
    yaw_peak_rate,
)

_log = logging.getLogger("companion.planning.schedule")

FloatArray = NDArray[np.float64]

#: Tilt the planner leaves below PX4's MPC_TILTMAX_AIR for the tracking feedback [deg] (the
#: companion's commands are clamped at MPC_TILTMAX_AIR itself; at most half of it is kept).
TILT_FEEDBACK_MARGIN_DEG = 10.0


#: Largest vertical acceleration of a descent still called cruising [m/s^2] (where a vehicle
#: landing itself leaves the plan: 0.05 m/s^2 is 0.0026 of normalised thrust at hover 0.5).
CRUISE_ACC_M_S2 = 0.05

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
    rover_max_yaw_rate_rad_s: float = math.radians(60.0)
    rover_max_lat_acc_m_s2: float = 1.5
    rover_max_speed_m_s: float | None = None
    """Cap on the rover's planned speed [m/s] (leave the controller headroom below the
    vehicle's top speed); None plans at the mission's leg speeds."""


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
        piece = self._piece_at(t)
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
        return self._piece_at(t).phase

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

    def _piece_at(self, t: float) -> Piece:
        """The first piece ending after `t` (the last piece beyond the end)."""
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
        caps = _leg_speed_caps(chunk, pts, flight.px4, rover)
        if math.isfinite(v_level):
            _note_fast_legs(chunk, min(v_level, flight.px4.MPC_XY_VEL_MAX), too_fast)
        if chunk.phase == "land" and not rover:
            pts, caps = _land_profile(pts, caps, flight.px4, float(flight.start_ned_m[2]))
        try:
            run = functools.partial(_plan_chunk, chunk, pts, params, limits, rover, yaw_spec,
                                    caps, flight.px4)
            # the memo's key: everything `_plan_chunk` reads (of the chunk its acceptance
            # radii, point count and phase)
            traj = run() if memo is None else memo.get_or_plan(exact_key((
                chunk.acceptance_radius_m, len(chunk.points_ned_m), chunk.phase, pts, params,
                limits, rover, yaw_spec, caps, flight.px4)), run)
        except ValueError as exc:
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


#: Climb/descent speed steps between MPC_LAND_ALT1 and MPC_LAND_ALT2 (PX4 interpolates the
#: descent rate linearly in height there; each step flies the lower end's rate).
LAND_PROFILE_STEPS = 8


def time_optimal_bound_s(
    flight: FlightPlan, params: MultirotorParams | None, limits: VehicleLimits | None = None
) -> float:
    """Time-optimal lower bound [s] of the schedule `build_schedule(flight, params, limits)`
    flies (:meth:`Schedule.time_optimal_bound_s`). Multirotors only (ValueError for a rover:
    the bound's limits are a multirotor's)."""
    if flight.vehicle == "rover":
        raise ValueError("the time-optimal bound is computed for multirotor plans only")
    return build_schedule(flight, params, limits).time_optimal_bound_s()


def _leg_speed_caps(
    chunk: FlightChunk, pts: FloatArray, px4: Px4PlanningParams, rover: bool
) -> FloatArray:
    """Speed cap along each leg of `pts` [m/s]: the leg's horizontal speed (its mission speed,
    at most MPC_XY_VEL_MAX) on the horizontal part and the climb (MPC_Z_VEL_MAX_UP, or
    MPC_TKO_SPEED in the takeoff) or descent rate (MPC_Z_VEL_MAX_DN) on the vertical part."""
    legs = np.diff(pts, axis=0)
    lengths = np.linalg.norm(legs, axis=1)
    speeds = list(chunk.leg_speed_m_s)
    caps = np.empty(len(legs))
    for i, (d, n) in enumerate(zip(legs, lengths, strict=True)):
        v_h = min(speeds[min(i, len(speeds) - 1)], px4.MPC_XY_VEL_MAX)
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


def _land_profile(
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
#: order and the first whose path keeps within the corridor is flown (see `_plan_chunk`).
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


class PlanMemo:
    """Bounded memo of planned chunks for callers that schedule many near-identical flight
    plans (the fuzz campaign: a mutation that leaves a stop-to-stop piece as it was).

    The key is the chunk planner's exact complete input (every float by its bits, so 0.0 and
    -0.0 differ and NaN matches only NaN; arrays by dtype, shape and bytes); the planner is
    deterministic, so a served trajectory is the one planning would give (read-only arrays,
    shared). Only successful plans are kept; the least recently used entry goes beyond
    `max_entries`. ``planned`` / ``served`` count the chunks planned and served."""

    def __init__(self, max_entries: int = 4096) -> None:
        if max_entries < 1:
            raise ValueError(f"max_entries must be >= 1, got {max_entries}")
        self.max_entries = max_entries
        self.planned = 0
        self.served = 0
        self._entries: collections.OrderedDict[object, PiecewiseBezier] = (
            collections.OrderedDict()
        )

    def __len__(self) -> int:
        return len(self._entries)

    def get_or_plan(self, key: object, plan_fn: Callable[[], PiecewiseBezier]) -> PiecewiseBezier:
        """The trajectory stored under `key` (see :func:`exact_key`), else ``plan_fn()``
        stored."""
        hit = self._entries.get(key)
        if hit is not None:
            self._entries.move_to_end(key)
            self.served += 1
            return hit
        traj = plan_fn()
        self.planned += 1
        self._entries[key] = traj
        if len(self._entries) > self.max_entries:
            self._entries.popitem(last=False)
        return traj


def exact_key(value: object) -> object:
    """A hashable key equal for two values only when they are the same bit for bit: floats by
    their hex form (0.0 and -0.0 differ, NaN equals NaN), arrays by dtype, shape and bytes,
    dataclasses by type and fields, sequences element-wise; str, int, bool and None as they
    are. TypeError for anything else."""
    if isinstance(value, float):
        return ("f", value.hex())
    if value is None or isinstance(value, (str, int, bool)):
        return value
    if isinstance(value, np.ndarray):
        return ("a", value.dtype.str, value.shape, value.tobytes())
    if isinstance(value, np.floating):
        return ("f", float(value).hex())
    if isinstance(value, (tuple, list)):
        return (type(value).__name__, *(exact_key(v) for v in value))
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return (type(value).__qualname__,
                *(exact_key(getattr(value, f.name)) for f in dataclasses.fields(value)))
    raise TypeError(f"no exact key for {type(value).__name__}")


def _plan_chunk(
    chunk: FlightChunk,
    pts: FloatArray,
    params: MultirotorParams | None,
    limits: VehicleLimits,
    rover: bool,
    yaw_spec: object,
    caps: FloatArray,
    px4: Px4PlanningParams,
) -> PiecewiseBezier:
    speed = max(float(np.max(caps)), 0.1)
    lim: Limits | RoverLimits
    if rover:
        if limits.rover_max_speed_m_s is not None:
            caps = np.minimum(caps, limits.rover_max_speed_m_s)
            speed = min(speed, limits.rover_max_speed_m_s)
        lim = RoverLimits(
            max_speed_m_s=speed,
            max_yaw_rate_rad_s=limits.rover_max_yaw_rate_rad_s,
            max_lat_acc_m_s2=limits.rover_max_lat_acc_m_s2,
        )
        whole = len(pts) == len(chunk.points_ned_m)
        corridor = limits.rover_corridor_m if whole else None
        if corridor is None:
            # joints on the straight legs: one polynomial per leg has a bell-shaped speed
            # profile (a 30 m leg at 2.7 m/s took 24 s) and bulges off the leg (7.6 m on the
            # rover square); joints let it cruise between the turns and pin it to the legs.
            # The first pattern whose path keeps within the corridor is flown; if none does,
            # the closer one, with a warning (the planner's corridor refinement below is
            # rover_corridor_m's: seconds per chunk).
            check = limits.corridor_m if whole else None
            best: tuple[float, PiecewiseBezier] | None = None
            tries = (ROVER_JOINT_PATTERNS if len(pts) - 1 <= ROVER_RETRY_MAX_LEGS
                     else ROVER_JOINT_PATTERNS[:1])
            for fractions in tries:
                jp, jc, seg_leg = _rover_joints(pts, caps, fractions)
                traj = plan(jp[:, :2], limits=lim, yaw="velocity", speed_caps=jc)
                if check is None:
                    return traj
                dev = _rover_corridor_deviation(traj, pts, seg_leg, chunk.acceptance_radius_m)
                if dev <= check:
                    return traj
                if best is None or dev < best[0]:
                    best = (dev, traj)
            assert best is not None
            _log.warning("the rover's path leaves the %g m corridor around the legs by up to "
                         "%.1f m (legs of %.0f m at most; set VehicleLimits.rover_corridor_m "
                         "to plan it inside, slower)", check, best[0],
                         float(np.max(np.linalg.norm(np.diff(pts[:, :2], axis=0), axis=1))))
            return best[1]
        return plan(
            pts[:, :2], limits=lim, yaw="velocity", speed_caps=caps, corridor_m=corridor,
            acceptance_m=chunk.acceptance_radius_m,
        )
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
