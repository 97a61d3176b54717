"""Pure summary of a flown trajectory: waypoints reached, tracking error, duration, and the
quality of the setpoints sent (:class:`SetpointQuality`, every flight: replay, fly, serve).

Shared by `fly` and `serve` (replay has its own, richer report from its lockstep log). Inputs are
position samples (NED, m) and the reference each was compared with; nothing here reads a clock.
"""

from __future__ import annotations

import dataclasses
import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field, fields
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from companion.mission.px4_params import Px4PlanningParams

FloatArray = NDArray[np.float64]

#: Commanded normalised thrust may change by at most this much over 10 ms while airborne
#: (the setpoint-smoothness goal; a step above it is counted in the report).
THRUST_STEP_GOAL = 0.05
#: A thrust change over 10 ms above this is chatter (a motor jolt: half of a 0.5 hover thrust)
#: and the flight's result is not "ok". Steps between the goal and this are counted only: a lossy
#: link (10 % loss, 50 ms latency) makes steps of ~0.15 where a late sample arrives.
THRUST_STEP_FAIL = 0.25
#: A commanded tilt above the vehicle's limit by more than this fails the flight [deg].
TILT_MARGIN_DEG = 0.5
#: A commanded body rate above the vehicle's limit by more than this share fails the flight.
RATE_MARGIN = 0.02
#: The commanded tilt's oscillation (`SetpointQuality`): the tilt vector (the thrust axis's lean
#: [rad] toward north and east, less the lean the plan asks for) less its first-order low-pass
#: of this time constant [s] (a high-pass with its corner at 0.64 Hz: a 1.2 Hz oscillation
#: passes at 0.88), RMS over windows of TILT_JITTER_WINDOW_S [s] in the air. It also holds the
#: feedback's answer to the estimate's noise (mock with EKF2-like errors: 4.0 deg at the
#: default gains, 6.1 at kp_xy 20).
TILT_JITTER_TAU_S = 0.25
TILT_JITTER_WINDOW_S = 2.0
#: A window whose tilt oscillation is above this RMS [deg] is counted in the report (the
#: setpoint-smoothness goal). Counted, not a failure: the mock's hard wind case (7.6 m/s^2 of
#: unmodelled force, white position noise 0.05 m) measures 7.5-9.9 deg while the vehicle's own
#: attitude wobbles 1.6 deg by its tlog (the feedback's answer to sensor noise, which the
#: vehicle filters out); real PX4 SIH at the session-30 gains, swinging +-17 deg at 1.2 Hz
#: while hovering, and the mock at kp_xy 27 measure 10-14 and 36 deg.
TILT_JITTER_GOAL_DEG = 5.0


@dataclass(frozen=True)
class SetpointQualityFigures:
    """The setpoint figures of one flight (`SetpointQuality.figures`): setpoints counted,
    the largest thrust step over 10 ms in the air and how many exceeded `thrust_step_goal`,
    the largest commanded tilt [deg] and body rates FRD [rad/s] against the vehicle's limits,
    the time spent over each limit [s], and the commanded tilt's oscillation (RMS over the
    flight and in its worst TILT_JITTER_WINDOW_S window [deg], and how many windows exceeded
    `tilt_jitter_goal_deg`)."""

    setpoints: int
    max_thrust_step_10ms: float
    thrust_steps_over_goal: int
    thrust_step_goal: float
    max_tilt_cmd_deg: float
    tilt_limit_deg: float
    time_over_tilt_limit_s: float
    max_body_rate_cmd_rad_s: tuple[float, float, float]
    body_rate_limit_rad_s: tuple[float, float, float]
    time_over_body_rate_limit_s: float
    tilt_jitter_rms_deg: float
    max_tilt_jitter_window_deg: float
    tilt_jitter_windows_over_goal: int
    tilt_jitter_goal_deg: float

    def to_dict(self) -> dict[str, Any]:
        """The figures as report.json writes them (field names are the keys)."""
        return {f.name: (list(v) if isinstance(v := getattr(self, f.name), tuple) else v)
                for f in fields(self)}


def _rates3(r: Sequence[float]) -> tuple[float, float, float]:
    return (round(r[0], 3), round(r[1], 3), round(r[2], 3))


@dataclass(frozen=True)
class SetpointLimits:
    """What the vehicle allows a setpoint to command: tilt of the thrust axis from vertical
    [rad] (PX4's MPC_TILTMAX_AIR) and body rates [rad/s], FRD (MC_ROLLRATE_MAX,
    MC_PITCHRATE_MAX, MC_YAWRATE_MAX). The defaults are PX4 v1.16's."""

    tilt_max_rad: float = math.radians(45.0)
    rate_max_frd: tuple[float, float, float] = (
        math.radians(220.0), math.radians(220.0), math.radians(200.0))

    def __post_init__(self) -> None:
        if not 0.0 < self.tilt_max_rad < math.radians(89.0):
            raise ValueError(f"tilt limit must be in (0, 89) deg, got "
                             f"{math.degrees(self.tilt_max_rad):g}")
        if not all(math.isfinite(r) and r > 0.0 for r in self.rate_max_frd):
            raise ValueError(f"body rate limits must be > 0, got {self.rate_max_frd}")

    @classmethod
    def of_px4(cls, px4: Px4PlanningParams) -> SetpointLimits:
        """The limits in the vehicle's PX4 parameters (deg, deg/s)."""
        return cls(math.radians(px4.MPC_TILTMAX_AIR),
                   (math.radians(px4.MC_ROLLRATE_MAX), math.radians(px4.MC_PITCHRATE_MAX),
                    math.radians(px4.MC_YAWRATE_MAX)))


class SetpointQuality:
    """Running figures of the attitude/rates setpoints a flight sent (pure; O(1) memory).

    `add` each setpoint with its local time [s]: normalised thrust, the commanded tilt (the
    thrust axis from vertical [rad]: from the quaternion sent, or in rates mode the attitude the
    controller steers to), the commanded body rates FRD [rad/s] (rates mode; attitude mode: only
    the yaw-rate feed-forward), and whether the vehicle is in the air. The thrust step is the
    change from the command in force 10 ms earlier, counted only while airborne and not across
    a gap (the first setpoint after arming, or after position setpoints, has none). Time over a
    limit adds each setpoint's period (at most 0.1 s) while over it.

    `tilt_ne` (the commanded thrust axis's lean [rad] toward north and east, less the lean the
    plan itself asks for: the feedback's share) measures how the commanded tilt oscillates: its
    part above ~0.6 Hz (TILT_JITTER_TAU_S) in the air, RMS per TILT_JITTER_WINDOW_S window; the
    filter restarts after a gap or on the ground."""

    def __init__(self, limits: SetpointLimits | None = None) -> None:
        self.limits = limits or SetpointLimits()
        self.setpoints = 0
        self.max_thrust_step = 0.0
        self.thrust_steps_over_goal = 0
        self.max_tilt_rad = 0.0
        self.over_tilt_s = 0.0
        self.max_rate_frd = [0.0, 0.0, 0.0]
        self.over_rate_s = 0.0
        self._hist: deque[tuple[float, float]] = deque(maxlen=32)
        self._t_last: float | None = None
        self._lp: tuple[float, float] | None = None  # the tilt vector's low-pass [rad]
        self._jit_sum = 0.0  # sum of squared high-passed tilt [rad^2], whole flight
        self._jit_n = 0
        self._win: tuple[float, float, int] | None = None  # (start [s], sum [rad^2], count)
        self.max_jitter_rad = 0.0  # worst window's RMS
        self.jitter_windows_over_goal = 0

    def gap(self) -> None:
        """A setpoint of another kind went out (e.g. a position setpoint while priming): the
        next thrust has no predecessor to step from."""
        self._hist.clear()
        self._t_last = None
        self._lp = None

    def _jitter(self, t_s: float, dt: float, tilt_ne: tuple[float, float]) -> None:
        """Feed the tilt oscillation measure one airborne setpoint (see the class docstring)."""
        n, e = tilt_ne
        if not (math.isfinite(n) and math.isfinite(e)):
            return
        lp = self._lp
        if lp is None:
            self._lp = (n, e)
            return
        a = min(dt / TILT_JITTER_TAU_S, 1.0)
        lp = (lp[0] + a * (n - lp[0]), lp[1] + a * (e - lp[1]))
        self._lp = lp
        sq = (n - lp[0]) ** 2 + (e - lp[1]) ** 2
        self._jit_sum += sq
        self._jit_n += 1
        win = self._win
        if win is None:
            win = (t_s, 0.0, 0)
        start, total, count = win[0], win[1] + sq, win[2] + 1
        if t_s - start >= TILT_JITTER_WINDOW_S:
            rms = math.sqrt(total / count)
            self.max_jitter_rad = max(self.max_jitter_rad, rms)
            if rms > math.radians(TILT_JITTER_GOAL_DEG):
                self.jitter_windows_over_goal += 1
            self._win = None
        else:
            self._win = (start, total, count)

    def add(self, t_s: float, thrust: float, tilt_rad: float,
            rates_frd: tuple[float, float, float], airborne: bool,
            tilt_ne: tuple[float, float] | None = None) -> None:
        """Record one setpoint (see the class docstring)."""
        if not (math.isfinite(t_s) and math.isfinite(thrust)):
            return
        self.setpoints += 1
        dt = 0.0 if self._t_last is None else min(max(t_s - self._t_last, 0.0), 0.1)
        self._t_last = t_s
        lim = self.limits
        if airborne:
            hist = self._hist
            before = None
            for t_i, u_i in reversed(hist):
                if t_i <= t_s - 0.01 + 1e-6:
                    before = (t_i, u_i)
                    break
            if before is None and hist:
                before = hist[0]  # setpoints slower than 100 Hz: the one before
            if before is not None and t_s - before[0] <= 0.03:
                step = abs(thrust - before[1])
                self.max_thrust_step = max(self.max_thrust_step, step)
                if step > THRUST_STEP_GOAL:
                    self.thrust_steps_over_goal += 1
            hist.append((t_s, thrust))
            if tilt_ne is not None:
                self._jitter(t_s, dt, tilt_ne)
        else:
            self._hist.clear()
            self._lp = None
        if math.isfinite(tilt_rad):
            self.max_tilt_rad = max(self.max_tilt_rad, tilt_rad)
            if tilt_rad > lim.tilt_max_rad + 1e-6:  # (a command clamped at it: round-off)
                self.over_tilt_s += dt
        over = False
        for i in range(3):
            r = abs(rates_frd[i])
            if math.isfinite(r):
                self.max_rate_frd[i] = max(self.max_rate_frd[i], r)
                over = over or r > lim.rate_max_frd[i] + 1e-6
        if over:
            self.over_rate_s += dt

    def figures(self) -> SetpointQualityFigures:
        """The figures for a flight report (rounded as reported)."""
        lim = self.limits
        return SetpointQualityFigures(
            setpoints=self.setpoints,
            max_thrust_step_10ms=round(self.max_thrust_step, 4),
            thrust_steps_over_goal=self.thrust_steps_over_goal,
            thrust_step_goal=THRUST_STEP_GOAL,
            max_tilt_cmd_deg=round(math.degrees(self.max_tilt_rad), 2),
            tilt_limit_deg=round(math.degrees(lim.tilt_max_rad), 2),
            time_over_tilt_limit_s=round(self.over_tilt_s, 3),
            max_body_rate_cmd_rad_s=_rates3(self.max_rate_frd),
            body_rate_limit_rad_s=_rates3(lim.rate_max_frd),
            time_over_body_rate_limit_s=round(self.over_rate_s, 3),
            tilt_jitter_rms_deg=round(self.jitter_rms_deg, 2),
            max_tilt_jitter_window_deg=round(math.degrees(self.max_jitter_rad), 2),
            tilt_jitter_windows_over_goal=self.jitter_windows_over_goal,
            tilt_jitter_goal_deg=TILT_JITTER_GOAL_DEG,
        )

    @property
    def jitter_rms_deg(self) -> float:
        """RMS of the commanded tilt's oscillation over the whole flight in the air [deg]."""
        return math.degrees(math.sqrt(self._jit_sum / self._jit_n)) if self._jit_n else 0.0

    def report(self) -> dict[str, Any]:
        """The figures for a flight report as JSON (keys carry units)."""
        return self.figures().to_dict()

    def failure(self) -> str | None:
        """Why the setpoints make the flight not "ok" (None: they do not): a commanded tilt or
        body rate over the vehicle's limit by more than its margin, or thrust chatter."""
        lim = self.limits
        if math.degrees(self.max_tilt_rad - lim.tilt_max_rad) > TILT_MARGIN_DEG:
            return (f"commanded tilt {math.degrees(self.max_tilt_rad):.1f} deg over the "
                    f"vehicle's limit {math.degrees(lim.tilt_max_rad):.1f} deg "
                    f"for {self.over_tilt_s:.2f} s")
        for i, axis in enumerate(("roll", "pitch", "yaw")):
            if self.max_rate_frd[i] > lim.rate_max_frd[i] * (1.0 + RATE_MARGIN):
                return (f"commanded {axis} rate {self.max_rate_frd[i]:.2f} rad/s over the "
                        f"vehicle's limit {lim.rate_max_frd[i]:.2f} rad/s")
        if self.max_thrust_step > THRUST_STEP_FAIL:
            return (f"thrust chatter: the commanded thrust changed by {self.max_thrust_step:.2f} "
                    f"within 10 ms in the air")
        return None


def closest_approach(points: FloatArray, wps: FloatArray, horizontal: bool = False
                     ) -> FloatArray:
    """Smallest distance [m] of `points` (N, 3) to each waypoint of `wps` (K, 3); inf if no
    points. ``horizontal``: north and east only (a rover: its height estimate drifts with the
    GPS's vertical error, 0.2-0.7 m over a 60 s drive of PX4's SIH rover)."""
    if len(points) == 0 or len(wps) == 0:
        return np.full(len(wps), math.inf)
    k = 2 if horizontal else 3
    out = np.empty(len(wps))
    for i, w in enumerate(wps):
        out[i] = float(np.min(np.linalg.norm(points[:, :k] - w[:k], axis=1)))
    return out


@dataclass
class TrackRecorder:
    """Collects (time [s], flown position NED [m], reference position NED [m]) samples."""

    t_s: list[float] = field(default_factory=list)
    pos_ned: list[tuple[float, float, float]] = field(default_factory=list)
    ref_ned: list[tuple[float, float, float]] = field(default_factory=list)

    def add(self, t_s: float, pos_ned: Sequence[float] | FloatArray,
            ref_ned: Sequence[float] | FloatArray) -> None:
        """Record one sample."""
        self.t_s.append(float(t_s))
        self.pos_ned.append((float(pos_ned[0]), float(pos_ned[1]), float(pos_ned[2])))
        self.ref_ned.append((float(ref_ned[0]), float(ref_ned[1]), float(ref_ned[2])))

    def summary(
        self,
        waypoints_ned: FloatArray | None,
        acceptance_m: Sequence[float],
        *,
        duration_s: float,
        planned_duration_s: float,
        horizontal: bool = False,
    ) -> FlightReport:
        """A `fly` report of the samples (result still empty): duration, RMS/max error of
        flown vs reference, closest approach to and reached flag of every waypoint (within
        its acceptance radius); ``horizontal``: errors and distances in north and east only (a
        rover)."""
        pos = np.asarray(self.pos_ned, dtype=np.float64).reshape(-1, 3)
        ref = np.asarray(self.ref_ned, dtype=np.float64).reshape(-1, 3)
        k = 2 if horizontal else 3
        err = np.linalg.norm(pos[:, :k] - ref[:, :k], axis=1)
        wps = (np.zeros((0, 3)) if waypoints_ned is None
               else np.asarray(waypoints_ned, dtype=np.float64).reshape(-1, 3))
        acc = np.asarray(list(acceptance_m), dtype=np.float64)
        if len(acc) != len(wps):
            raise ValueError(f"{len(wps)} waypoints but {len(acc)} acceptance radii")
        closest = closest_approach(pos, wps, horizontal)
        return FlightReport(
            kind="fly",
            result="",
            duration_s=round(float(duration_s), 3),
            planned_duration_s=round(float(planned_duration_s), 3),
            samples=len(err),
            rms_error_m=float(np.sqrt(np.mean(err**2))) if len(err) else None,
            max_error_m=float(np.max(err)) if len(err) else None,
            waypoints=tuple(
                WaypointResult(float(w[0]), float(w[1]), float(w[2]), float(a),
                               float(c) if math.isfinite(c) else None, bool(c <= a))
                for w, a, c in zip(wps, acc, closest, strict=True)
            ),
            waypoints_reached=int(np.count_nonzero(closest <= acc)),
        )


# ----------------------------------------------------------------------------- the flight report

#: Which report: a lockstep replay of the companion's flight, the mock's own AUTO.MISSION flight
#: of the same file (replay --compare-px4-mission), or a `fly` flight.
ReportKind = Literal["replay", "px4_mission", "fly"]


@dataclass(frozen=True)
class WaypointResult:
    """One planned waypoint against the flown track: its position (NED [m], the flight's
    frame), acceptance radius [m], the track's closest approach [m] (None or inf: no track)
    and whether it came within the radius. `item_index`: the mission item (None: a pattern's
    waypoint, or a `fly` report, which does not name items)."""

    north_m: float
    east_m: float
    down_m: float
    acceptance_radius_m: float
    closest_approach_m: float | None
    reached: bool
    item_index: int | None = None

    def to_dict(self) -> dict[str, Any]:
        """The waypoint as report.json writes it."""
        d: dict[str, Any] = {} if self.item_index is None else {"item_index": self.item_index}
        d.update(north_m=self.north_m, east_m=self.east_m, down_m=self.down_m,
                 acceptance_radius_m=self.acceptance_radius_m,
                 closest_approach_m=self.closest_approach_m, reached=self.reached)
        return d


@dataclass(frozen=True)
class Failsafe:
    """A STATUSTEXT naming a failsafe or a loss, at simulated time `t_s` [s]."""

    t_s: float
    text: str


@dataclass(frozen=True)
class FlightEstimates:
    """What the companion's tracking law learnt in flight (attitude and rates modes).

    wind_m_s / wind_from_deg: the wind its disturbance estimate implies with the drag per mass
    in use (learnt in flight by default, else the configured D / m), w = d / (D / m) (None: no
    drag feed-forward), speed [m/s] and compass direction it blows
    from [deg]; disturbance_m_s2: the estimated horizontal force per mass [m/s^2] (wind, drag
    error); mass_ratio: hover thrust estimated / hover thrust assumed (1.1: the vehicle is 10 %
    heavier for its thrust than the companion was told); slowed_s: how far [s] the reference
    was slowed down behind flight time for a vehicle that could not follow it (0: the plan's
    own timing); min_rate: the slowest reference rate (1: never slowed).
    """

    wind_m_s: float | None
    wind_from_deg: float | None
    disturbance_m_s2: float
    mass_ratio: float
    slowed_s: float
    min_rate: float

    def to_dict(self) -> dict[str, Any]:
        """report.json's "estimates"."""
        return dataclasses.asdict(self)


@dataclass(frozen=True, kw_only=True)
class FlightReport:
    """The report of one flight (replay, `fly`), typed; `to_dict` is its report.json.

    Common to every kind: `result` ("ok" or what went wrong), the flight's duration and the
    plan's [s], the RMS and largest tracking error [m] (None: no sample), the waypoints and how
    many were reached, the setpoint figures, the PX4 planning parameters used (None: not read).
    Geofence and per-leg figures are None where not checked (a `fly` pattern). Fields of other
    kinds keep their defaults and are not written; see `to_dict` for each kind's keys.

    `ok`: the flight's verdict as written (None: not judged, a `fly` report written after a
    failure). A replay's is `result == "ok"` with every waypoint reached (`report_ok`)."""

    kind: ReportKind
    result: str
    duration_s: float
    planned_duration_s: float
    waypoints: tuple[WaypointResult, ...]
    waypoints_reached: int
    rms_error_m: float | None = None
    max_error_m: float | None = None
    ok: bool | None = None
    setpoint_quality: SetpointQualityFigures | None = None
    px4_params: dict[str, Any] | None = None
    # flown figures (replay, px4_mission)
    path_length_m: float = 0.0
    max_speed_m_s: float = 0.0
    max_tilt_deg: float = 0.0
    max_thrust_norm: float | None = None
    max_body_rate_rad_s: float = 0.0
    failsafes: tuple[Failsafe, ...] = ()
    # the geofence (violations None: not checked) and the legs of a mission
    geofence_violations: int | None = None
    geofence_violation_zones: tuple[str, ...] = ()
    geofence_breaches: tuple[dict[str, Any], ...] | None = None
    legs: tuple[dict[str, Any], ...] | None = None
    bound_s: float | None = None
    """Time-optimal bound of the whole plan [s] (None: unknown)."""
    planned_over_bound: float | None = None
    planned_s: float | None = None
    """`fly`: the whole schedule's duration [s], takeoff included."""
    # the replay run
    file: str | None = None
    vehicle: str | None = None
    mode: str | None = None
    setpoint_rate_hz: float | None = None
    setpoints_sent: int = 0
    tlog_frames: int | None = None
    simulated_s: float = 0.0
    wall_s: float = 0.0
    real_time_factor: float | None = None
    warnings: tuple[str, ...] = ()
    max_waypoint_miss_geo_m: float | None = None
    """Farthest miss of the mission's geodetic waypoints [m] (replay with a start offset)."""
    px4_mission: FlightReport | None = None
    # fly
    samples: int | None = None
    target: str | None = None
    final_action: str | None = None
    estimates: FlightEstimates | None = None
    """The tracking law's estimates (attitude and rates modes; None: not flown by it)."""

    @property
    def reached_all(self) -> bool:
        """Every waypoint reached."""
        return self.waypoints_reached == len(self.waypoints)

    def to_dict(self) -> dict[str, Any]:
        """report.json: the keys (with units) and values, in the order each kind writes them."""
        if self.kind == "fly":
            return self._fly_dict()
        d: dict[str, Any] = {
            "duration_s": self.duration_s,
            "planned_duration_s": self.planned_duration_s,
            "path_length_m": self.path_length_m,
        }
        if self.kind == "replay":  # PX4's own mission follows no plan of the companion's
            d["rms_error_m"] = self.rms_error_m
            d["max_error_m"] = self.max_error_m
        d.update({
            "waypoints": [w.to_dict() for w in self.waypoints],
            "waypoints_reached": self.waypoints_reached,
            "max_speed_m_s": self.max_speed_m_s,
            "max_tilt_deg": self.max_tilt_deg,
            "max_thrust_norm": self.max_thrust_norm,
            "max_body_rate_rad_s": self.max_body_rate_rad_s,
            "geofence_violations": self.geofence_violations,
            "geofence_violation_zones": list(self.geofence_violation_zones),
            "failsafes": [{"t_s": f.t_s, "text": f.text} for f in self.failsafes],
            "bound_s": self.bound_s,
            "planned_over_bound": self.planned_over_bound,
        })
        if self.geofence_breaches is not None:
            d["geofence_breaches"] = list(self.geofence_breaches)
        if self.legs is not None:
            d["legs"] = list(self.legs)
        if self.kind == "px4_mission":
            d["result"] = self.result
            d["ok"] = self.ok
            return d
        d.update({
            "file": self.file,
            "vehicle": self.vehicle,
            "mode": self.mode,
            "setpoint_rate_hz": self.setpoint_rate_hz,
            "setpoints_sent": self.setpoints_sent,
            "tlog_frames": self.tlog_frames,
            "result": self.result,
            "simulated_s": self.simulated_s,
            "wall_s": self.wall_s,
            "real_time_factor": self.real_time_factor,
            "warnings": list(self.warnings),
        })
        if self.px4_params is not None:
            d["px4_params"] = self.px4_params
        d["setpoint_quality"] = (None if self.setpoint_quality is None
                                 else self.setpoint_quality.to_dict())
        d["ok"] = self.ok
        if self.max_waypoint_miss_geo_m is not None:
            d["max_waypoint_miss_geo_m"] = self.max_waypoint_miss_geo_m
        if self.estimates is not None:
            d["estimates"] = self.estimates.to_dict()
        if self.px4_mission is not None:
            d["px4_mission"] = self.px4_mission.to_dict()
        return d

    def _fly_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {
            "duration_s": self.duration_s,
            "planned_duration_s": self.planned_duration_s,
            "samples": self.samples,
            "rms_error_m": self.rms_error_m,
            "max_error_m": self.max_error_m,
            "waypoints": [w.to_dict() for w in self.waypoints],
            "waypoints_reached": self.waypoints_reached,
            "result": self.result,
            "mode": self.mode,
            "target": self.target,
        }
        if self.final_action is not None:
            d["final_action"] = self.final_action
        if self.px4_params is not None:
            d["px4_params"] = self.px4_params
        if self.geofence_violations is not None:  # a mission's figures
            d.update({
                "geofence_violations": self.geofence_violations,
                "geofence_violation_zones": list(self.geofence_violation_zones),
                "geofence_breaches": list(self.geofence_breaches or ()),
                "planned_s": self.planned_s,
                "bound_s": self.bound_s,
                "legs": list(self.legs or ()),
            })
        if self.setpoint_quality is not None:
            d["setpoint_quality"] = self.setpoint_quality.to_dict()
        if self.estimates is not None:
            d["estimates"] = self.estimates.to_dict()
        if self.ok is not None:
            d["ok"] = self.ok
        return d


def report_ok(report: FlightReport) -> bool:
    """A replay's verdict: result "ok" (no abort, no geofence breach), every waypoint reached."""
    return report.result == "ok" and report.reached_all


def breach_result(report: FlightReport) -> str:
    """The report's result, failed by a geofence breach: ``"geofence breach: ..."`` if the
    flight otherwise ended "ok" and breached the fence (a breach is never ok)."""
    if report.result != "ok":
        return report.result
    return breach_failure(report) or report.result


def breach_failure(report: FlightReport) -> str | None:
    """``"geofence breach: ..."`` if the flight breached the fence (the first breach, or the
    zones entered when the breaches were not found per leg), else None."""
    found = report.geofence_breaches or ()
    if found:
        more = f" (+{len(found) - 1} more)" if len(found) > 1 else ""
        return f"geofence breach: {found[0]['message']}{more}"
    if report.geofence_violations:
        return "geofence breach: " + ", ".join(report.geofence_violation_zones)
    return None


def missed_result(report: FlightReport) -> str:
    """The report's result, failed by missed waypoints: ``"missed N waypoint(s): item I by D m,
    ..."`` if the flight otherwise ended "ok" and passed a waypoint farther than its
    acceptance radius."""
    missed = [(i, w) for i, w in enumerate(report.waypoints) if not w.reached]
    if report.result != "ok" or not missed:
        return report.result
    where = ", ".join(
        f"{'waypoint ' + str(i + 1) if w.item_index is None else 'item ' + str(w.item_index)} "
        f"by {w.closest_approach_m if w.closest_approach_m is not None else math.inf:.2f} m"
        for i, w in missed[:3])
    more = f" (+{len(missed) - 3} more)" if len(missed) > 3 else ""
    return f"missed {len(missed)} waypoint(s): {where}{more}"
