"""Sans-IO core of `python -m companion serve`: the companion-computer service.

The service never arms, takes off or switches the vehicle into OFFBOARD: the pilot does, from
the RC or the ground station. It:

- streams a hold setpoint whenever the vehicle is armed and flying (the vehicle's own position
  while in another mode, the position where OFFBOARD began while holding in OFFBOARD), so PX4
  always has a fresh offboard "proof of life" and the pilot can switch to OFFBOARD at any time;
- downloads the mission the pilot uploaded (again whenever PX4's MISSION_CURRENT reports another
  mission: ``mission_id``, PX4 v1.16's CRC32 of the plan, or the item count), plans it and
  announces the result by STATUSTEXT;
- in OFFBOARD flies the planned smooth mission from where the vehicle is: a joining trajectory
  to the nearest point of the leg towards the first waypoint not yet reached, then the plan;
  leaving OFFBOARD stops the mission stream at once (back to hold); re-entering resumes from the
  current position. At the end of the plan it requests the mission's final action (Land, RTL or
  Hold) while still streaming. Each OFFBOARD entry that flies the mission is one
  :class:`companion.flight.FlightSequence` started by the pilot: it decides when the plan has
  settled and requests (and re-requests) the final mode; the hold stream stays here.

``ServeService.update(obs)`` takes one :class:`Observation` (all times are the caller's
monotonic seconds; nothing here reads a clock or does I/O) and returns actions
(:class:`DownloadMission`, :class:`RequestMode`, :class:`Announce`, :class:`LogEvent`,
:class:`PlanJoin`);
``ServeService.stream`` is what the fixed-rate sender should send right now (a
:class:`HoldStream`, a :class:`MissionStream` or None), swapped atomically so a sender thread can
read it. Mission planning is slow (up to a second) and done by the caller: :func:`plan_program`
(companion.serve.program) turns downloaded items into a :class:`MissionProgram`,
``on_planned`` hands it back. So is the
join at each OFFBOARD entry (0.1-0.3 s) with ``defer_join``: ``plan_join`` then ``on_joined``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from companion.control import Reference, TrackingConfig
from companion.control.estimation import HoverWindEstimator
from companion.flatness import MultirotorParams
from companion.flight.policy import final_mode
from companion.flight.policy import stall_s as policy_stall_s
from companion.flight.report import SetpointLimits
from companion.flight.sequence import (
    EndPolicy,
    FlightSequence,
    PhaseChanged,
    SendCommand,
    SequenceAction,
    SequenceConfig,
    VehicleView,
)
from companion.flight.tracking import SetpointMode, TrackingSource
from companion.mavlink.px4_mode import FlightMode
from companion.mavlink.setpoints import PositionSetpoint, SetpointCommand
from companion.mavlink.telemetry import HomePosition, LocalPosition, MissionCurrent
from companion.mission.px4_params import Px4PlanningParams
from companion.onboard.protocol import Ack
from companion.planning.schedule import (
    VehicleLimits,
    trajectory_reference,
)
from companion.planning.wind import WindCheck, check_wind
from companion.serve.program import MissionProgram
from companion.trajectory import Limits, PiecewiseBezier, check, plan

FloatArray = NDArray[np.float64]

#: MISSION_CURRENT.total when the vehicle holds no mission (PX4 v1.16, measured).
NO_MISSION_TOTAL = 65535
#: EXTENDED_SYS_STATE landed states counted as flying: in air, takeoff, landing.
FLYING_STATES = (2, 3, 4)
#: The wind is judged from this long [s] of holding still under PX4 (`HoverWindEstimator`), and
#: a mission re-checked against it (and a changed verdict announced) at most this often [s].
WIND_MIN_HELD_S = 3.0
WIND_CHECK_EVERY_S = 5.0
#: ... and only once the estimate has moved this much [m/s^2] (or the mission changed).
WIND_RECHECK_M_S2 = 0.3
MAV_SEVERITY_WARNING = 4
MAV_SEVERITY_INFO = 6
#: The joining trajectory (ServeService._join_trajectory): its shortest duration [s], the factor
#: between the durations tried and how many are tried (0.5 s to ~100 s), the samples of its
#: velocity, and how fast [m/s] it may move back along the line to the plan beyond what its
#: ends do (a vehicle moving away from the plan must first stop).
JOIN_MIN_S = 0.5
JOIN_STRETCH = 1.15
JOIN_TRIES = 40
JOIN_SAMPLES = 64
JOIN_BACKUP_M_S = 0.05
#: The join may use this much more acceleration and tilt than the plan (which may sit at its
#: limits where the join ends on it); 1.1 x the default 35 deg is 38.5 deg, under PX4's 45 deg.
JOIN_LIMIT_MARGIN = 1.1
#: A join ending on the plan's velocity but not its acceleration counts this much later [s].
JOIN_ACC_STEP_S = 1.0


@dataclass(frozen=True)
class ServiceConfig:
    """Behaviour of the service (SI units)."""

    setpoint_mode: SetpointMode = "attitude"
    params: MultirotorParams = field(default_factory=lambda: MultirotorParams(
        mass=1.0, inertia=(0.025, 0.025, 0.030), hover_thrust=0.5, drag=1.0))
    limits: VehicleLimits = field(default_factory=VehicleLimits)
    tracking: TrackingConfig | None = None  # attitude/rates controller (None: from params)
    join_speed_m_s: float = 3.0  # cruise speed of the joining trajectory
    stale_s: float = 0.5  # position older than this is not used
    settle_m: float = 0.5  # at the plan's end: request the final action within this distance
    settle_s: float = 3.0  # ... or this long after the plan ended
    mode_retry_s: float = 3.0  # re-request the final action if PX4 is still in OFFBOARD
    px4: Px4PlanningParams | None = None  # the vehicle's planning parameters (None: defaults)
    rate_hz: float = 50.0  # the sender's setpoint rate [Hz]


# -- observations and actions ------------------------------------------------------------------
@dataclass(frozen=True)
class Observation:
    """What the service sees of the vehicle at ``now_s`` [s, caller's monotonic clock]."""

    now_s: float
    link_ok: bool
    armed: bool
    mode: FlightMode | None
    landed_state: int | None = None  # EXTENDED_SYS_STATE (None: not reported)
    position: LocalPosition | None = None
    yaw: float | None = None  # [rad]
    home: HomePosition | None = None
    mission: MissionCurrent | None = None
    attitude_q: tuple[float, float, float, float] | None = None  # ATTITUDE_QUATERNION (w, x, y, z)
    module: Ack | None = None  # the onboard module's latest report (serve --onboard)
    module_t_s: float | None = None  # when it came [s, the caller's monotonic clock]


@dataclass(frozen=True)
class DownloadMission:
    """Download the vehicle's mission, then call ``on_downloaded`` / ``on_download_failed``."""

    key: tuple[int, int]  # (mission_id, total) the download is for


@dataclass(frozen=True)
class RequestMode:
    """Ask PX4 for ``mode`` (keep streaming meanwhile)."""

    mode: FlightMode
    why: str


@dataclass(frozen=True)
class Announce:
    """STATUSTEXT to the ground station (``text`` starts with "ecca: ")."""

    text: str
    severity: int = MAV_SEVERITY_INFO


@dataclass(frozen=True)
class LogEvent:
    """One line of the JSON event log."""

    event: str
    fields: dict[str, Any]


@dataclass(frozen=True)
class PlanJoin:
    """Plan the joining trajectory (``ServeService.plan_join``: 0.1-0.3 s, so off the caller's
    event loop), then call ``on_joined`` with ``token`` and its result. The hold stream goes on
    meanwhile; a result that arrives after the vehicle left OFFBOARD or the mission changed is
    discarded."""

    token: int
    program: MissionProgram
    obs: Observation  # where the vehicle was when OFFBOARD began
    reached: int  # waypoints reached so far
    t_progress: float  # schedule time flown so far [s]


@dataclass(frozen=True)
class UploadOnboard:
    """serve --onboard: plan the trajectory from ``obs`` (``OnboardServeService.plan_onboard``,
    off the caller's event loop), upload it to the onboard module with its CRC verified, then
    call ``on_uploaded`` with ``token`` and the result."""

    token: int
    program: MissionProgram
    obs: Observation  # where the vehicle holds
    reached: int  # waypoints reached so far
    t_progress: float  # schedule time flown so far [s]


@dataclass(frozen=True)
class AbortOnboard:
    """serve --onboard: have the onboard module drop the trajectory it holds, not flown (it
    keeps OFFBOARD available while it holds one)."""

    why: str


Action = (DownloadMission | RequestMode | Announce | LogEvent | PlanJoin | UploadOnboard
          | AbortOnboard)


@dataclass(frozen=True)
class HoldStream:
    """Send this fixed position setpoint."""

    setpoint: PositionSetpoint


@dataclass(frozen=True)
class MissionStream:
    """Fly ``source`` with time ``now - t0_s``."""

    source: TrackingSource
    t0_s: float
    join_s: float  # duration of the joining trajectory [s]
    t_join: float  # schedule time where the join ends [s]
    #: flight time [s] at the caller's time [s], a clock that follows the autopilot's
    #: (`FlightClock`; None: the caller's own), and its value at ``t0_s``
    clock: Callable[[float], float] | None = None
    t0_flight_s: float = 0.0

    def elapsed_s(self, now_s: float) -> float:
        """Flight time [s] since ``t0_s`` at ``now_s`` (on ``clock`` when there is one)."""
        if self.clock is None:
            return now_s - self.t0_s
        return self.clock(now_s) - self.t0_flight_s

    def flight_time(self, now_s: float) -> float:
        """Time [s] on this stream's own clock at ``now_s``: the reference's own time when the
        source slows it down for the vehicle (`TrackingSource.reference_time_s`), else the
        flight time since ``t0_s``."""
        governed = self.source.reference_time_s
        return self.elapsed_s(now_s) if governed is None else governed

    def schedule_time(self, now_s: float) -> float:
        """Schedule time [s] being flown at ``now_s``."""
        return self.t_join + max(0.0, self.flight_time(now_s) - self.join_s)

    def setpoint(self, now_s: float, telemetry: Any) -> SetpointCommand:
        """The setpoint for ``now_s`` (calls the tracking source)."""
        return self.source(self.elapsed_s(now_s), telemetry)


Stream = HoldStream | MissionStream


def is_flying(obs: Observation) -> bool:
    """Armed and, when PX4 reports it, in the air (taking off, flying or landing)."""
    return obs.armed and (obs.landed_state is None or obs.landed_state in FLYING_STATES)


def _yaw_of(ref: Reference) -> float:
    return float(ref.yaw)


class ServeService:
    """The service's state machine (see the module doc)."""

    def __init__(self, config: ServiceConfig | None = None, defer_join: bool = False,
                 clock: Callable[[], Callable[[float], float]] | None = None) -> None:
        """``defer_join``: return a :class:`PlanJoin` action for the caller to plan off its
        event loop (the runner); otherwise the join is planned inside ``update``. ``clock``:
        makes a new flight clock for each mission stream, flight time [s] at the caller's time
        [s] following the autopilot's clock (the runner's `FlightClock`: a PX4 SITL slowed by
        its host slows the mission's reference with it); None: the caller's time."""
        self.config = config or ServiceConfig()
        self.defer_join = defer_join
        self.clock = clock
        self.state = "idle"  # idle | hold | offboard_hold | joining | mission | finishing
        self._joining: int | None = None  # the token of the join being planned
        self._join_token = 0
        self._obs: Observation | None = None  # the latest observation
        self.stream: Stream | None = None
        self.program: MissionProgram | None = None
        self.plan_error: str | None = None
        self._key: tuple[int, int] | None = None  # mission on the vehicle (id, total)
        self._downloading: tuple[int, int] | None = None
        self.reached = 0  # waypoints reached on this flight, in order
        self.t_progress = 0.0  # schedule time flown so far on this flight [s]
        self.done = False  # the final action was requested on this flight
        self._seq: FlightSequence | None = None  # this OFFBOARD entry's flight (mission, finishing)
        self._last_mode: FlightMode | None = None
        self._link_ok = False
        self.hover_wind = HoverWindEstimator(g=self.config.params.g)
        self.wind_check: WindCheck | None = None  # the mission against the estimated wind
        self._wind_checked_s = -math.inf
        self._wind_said: tuple[bool, bool] | None = None  # (flyable, slowed) last announced
        self._wind_key: tuple[object, float] | None = None  # (program, progress) last checked
        self._wind_d: tuple[float, float] = (math.inf, math.inf)  # the estimate last checked

    # -- inputs ------------------------------------------------------------------------------
    def update(self, obs: Observation) -> list[Action]:
        """Advance on a new observation; returns the actions to perform."""
        out: list[Action] = []
        fresh = self._observe(obs, out)
        return out if fresh is None else out + self._decide(obs, fresh)

    def _observe(self, obs: Observation, out: list[Action]) -> bool | None:
        """What every mode of the service follows (the link, the mode, the mission on the
        vehicle, the waypoints reached, a disarm's reset), into ``out``; None when the link is
        down, else whether the position is fresh."""
        self._obs = obs
        if obs.link_ok != self._link_ok:
            self._link_ok = obs.link_ok
            out.append(LogEvent("link", {"ok": obs.link_ok}))
        if not obs.link_ok:
            self.stream = None  # nothing reaches the vehicle; PX4 runs its own failsafe
            return None
        if obs.mode is not self._last_mode:
            out.append(LogEvent("mode", {"mode": obs.mode.name if obs.mode else None,
                                         "armed": obs.armed}))
            self._last_mode = obs.mode
        out += self._watch_mission(obs)
        pos = obs.position
        fresh = pos is not None and obs.now_s - pos.t_s <= self.config.stale_s
        prog = self.program
        if fresh and prog is not None and pos is not None:
            p = np.asarray(pos.pos_ned)
            while (self.reached < len(prog.waypoints) and float(
                    np.linalg.norm(p - prog.waypoints[self.reached]))
                    <= prog.acceptance[self.reached]):
                out.append(LogEvent("waypoint", {"index": self.reached}))
                self.reached += 1
        if not obs.armed and (self.reached or self.done or self.t_progress):
            out.append(LogEvent("flight_reset", {"reached": self.reached}))
            self._reset_progress()
        return fresh

    def _decide(self, obs: Observation, fresh: bool) -> list[Action]:
        """The streaming service's decisions on a new observation (link up)."""
        out: list[Action] = []
        flying = is_flying(obs)
        if not flying:
            if self.state != "idle":
                out.append(LogEvent("state", {"state": "idle", "why": "not flying"}))
            self.state, self.stream, self._seq = "idle", None, None
            return out
        offboard = obs.mode is FlightMode.OFFBOARD
        if not offboard:
            out += self._watch_wind(obs, fresh)
            if self._seq is not None:  # the entry ends (a pause, or the final mode took over)
                self._seq.update(obs.now_s, self._view(obs, fresh))
                self._seq = None
            if self.state == "mission":
                out.append(Announce(f"ecca: paused at {self._progress_text()}, holding stream"))
                out.append(LogEvent("state", {"state": "hold", "why": "left OFFBOARD",
                                              "mode": obs.mode.name if obs.mode else None}))
            elif self.state == "finishing":
                out.append(LogEvent("final_action", {"mode": obs.mode.name if obs.mode
                                                     else None}))
            self.state = "hold"
            sp = self._hold_here(obs)
            self.stream = HoldStream(sp) if sp is not None else self.stream
            return out
        # in OFFBOARD
        if self.state in ("idle", "hold"):
            out += self._enter_offboard(obs, fresh)
        elif self.state == "mission":
            out += self._fly(obs, fresh)
        elif self.state == "finishing" and self._seq is not None:
            out += self._final_requests(self._seq.update(obs.now_s, self._view(obs, fresh)))
        return out

    def on_downloaded(self, key: tuple[int, int], n_items: int) -> list[Action]:
        """The download for ``key`` finished (the caller now plans it)."""
        return [LogEvent("mission_downloaded", {"mission_id": key[0], "items": n_items})]

    def on_download_failed(self, key: tuple[int, int], why: str) -> list[Action]:
        """The download for ``key`` failed: retried on the next update."""
        self._downloading = None
        self._key = None
        return [LogEvent("mission_download_failed", {"mission_id": key[0], "why": why}),
                Announce(f"ecca: mission download failed: {why}", MAV_SEVERITY_WARNING)]

    def on_planned(self, key: tuple[int, int], result: MissionProgram | str,
                   now_s: float) -> list[Action]:
        """Planning of the mission ``key`` ended: a program, or why it cannot be flown."""
        if self._downloading == key:
            self._downloading = None
        out: list[Action] = []
        if self.state in ("mission", "joining"):  # never fly on with a replaced plan
            ms = self.stream
            hold = None
            if isinstance(ms, MissionStream):  # hold where the reference is now
                r = ms.source.reference(max(0.0, ms.elapsed_s(now_s)))
                if r is not None:
                    hold = PositionSetpoint(pos_ned=tuple(float(c) for c in r.pos_ned),  # type: ignore[arg-type]
                                            vel_ned=(0.0, 0.0, 0.0), yaw=_yaw_of(r))
            if hold is not None:
                self.stream = HoldStream(hold)
            self.state, self._seq = "offboard_hold", None
            out.append(Announce("ecca: mission changed in flight: holding, re-enter OFFBOARD "
                                "to fly the new one", MAV_SEVERITY_WARNING))
        self._reset_progress()
        if isinstance(result, str):
            self.program, self.plan_error = None, result
            out += [LogEvent("mission_rejected", {"mission_id": key[0], "why": result}),
                    Announce(f"ecca: cannot fly mission: {result}", MAV_SEVERITY_WARNING)]
            return out
        self.program, self.plan_error = result, None
        n = len(result.waypoints)
        out += [LogEvent("mission_planned", {"mission_id": key[0], "waypoints": n,
                                             "planned_s": round(result.planned_s, 2),
                                             "final_action": result.final_action}),
                Announce(f"ecca: mission {n} wp, {result.planned_s:.0f} s planned")]
        for w in result.schedule.warnings:  # e.g. a speed item above the level speed cap
            out += [LogEvent("plan_warning", {"mission_id": key[0], "why": w}),
                    Announce(f"ecca: {w.split(': ', 1)[-1]}", MAV_SEVERITY_WARNING)]
        return out

    def shutdown(self, obs: Observation) -> list[Action]:
        """Stopping (SIGTERM/SIGINT): Hold first if the vehicle flies on our stream."""
        if obs.link_ok and obs.armed and obs.mode is FlightMode.OFFBOARD:
            return [RequestMode(FlightMode.HOLD, "service stopping"),
                    LogEvent("shutdown", {"hold_requested": True})]
        return [LogEvent("shutdown", {"hold_requested": False})]

    # -- internals ---------------------------------------------------------------------------
    def _reset_progress(self) -> None:
        self.reached = 0
        self.t_progress = 0.0
        self.done = False

    def _progress_text(self) -> str:
        prog = self.program
        n = 0 if prog is None else len(prog.waypoints)
        return f"wp {self.reached}/{n}"

    def _watch_mission(self, obs: Observation) -> list[Action]:
        mc = obs.mission
        if mc is None:
            return []
        key = (mc.mission_id, mc.total)
        if key == self._key or self._downloading is not None:
            return []
        self._key = key
        if mc.total in (0, NO_MISSION_TOTAL):
            out: list[Action] = [LogEvent("mission_none", {})]
            if self.plan_error != "no mission":  # once per change
                out.append(Announce("ecca: no mission on the vehicle"))
            if self.state == "mission":
                out += self.on_planned(key, "the mission was cleared", obs.now_s)[:1]
            self.program, self.plan_error = None, "no mission"
            return out
        self._downloading = key
        return [DownloadMission(key), LogEvent("mission_changed", {"mission_id": mc.mission_id,
                                                                   "total": mc.total})]

    # -- the wind ------------------------------------------------------------------------------
    def _watch_wind(self, obs: Observation, fresh: bool) -> list[Action]:
        """While PX4 flies (not OFFBOARD): learn the wind from the attitude held still, check
        the mission against it, announce a changed verdict (a mission that cannot be flown in
        this wind is said before the pilot switches to OFFBOARD)."""
        pos, q = obs.position, obs.attitude_q
        if fresh and pos is not None and q is not None:
            self.hover_wind.update(obs.now_s, pos.vel_ned, q, True)
        if not self._check_wind(obs.now_s):
            return []
        wc = self.wind_check
        assert wc is not None
        key = (wc.flyable, wc.slowed)
        if key == self._wind_said:
            return []
        self._wind_said = key
        wind = self._wind_text()
        if not wc.flyable:
            return [Announce(f"ecca: mission not flyable in {wind}: {wc.reason}",
                             MAV_SEVERITY_WARNING),
                    LogEvent("wind", {"flyable": False, "reason": wc.reason, "wind": wind})]
        if wc.slowed:
            return [Announce(f"ecca: {wind}: {wc.reason}", MAV_SEVERITY_WARNING),
                    LogEvent("wind", {"flyable": True, "slowed": True, "wind": wind})]
        return [LogEvent("wind", {"flyable": True, "slowed": False, "wind": wind})]

    def _check_wind(self, now_s: float, force: bool = False) -> bool:
        """Re-check the mission (from the progress so far) against the estimated wind when due
        (or `force`d); False when there is nothing to check (no mission, no wind yet)."""
        prog, d = self.program, self.hover_wind.acc_ne
        if prog is None or d is None or self.hover_wind.held_s < WIND_MIN_HELD_S:
            return False
        key = (prog, round(self.t_progress, 1))
        if not force and (now_s - self._wind_checked_s < WIND_CHECK_EVERY_S or (
                key == self._wind_key and math.dist(d, self._wind_d) < WIND_RECHECK_M_S2)):
            return False  # (the check samples the whole plan: not every cycle)
        self._wind_checked_s, self._wind_key, self._wind_d = now_s, key, d
        cfg = self.config
        p = cfg.params
        t0 = min(max(self.t_progress, prog.t_begin), prog.t_end)
        tilt = SetpointLimits.of_px4(cfg.px4 or Px4PlanningParams()).tilt_max_rad
        self.wind_check = check_wind(lambda t: prog.reference(t0 + t), prog.t_end - t0, d,
                                     p.drag / p.mass, tilt, p.g)
        return True

    def _wind_text(self) -> str:
        """The estimated wind, as the configured drag and mass imply it."""
        d = self.hover_wind.acc_ne
        p = self.config.params
        if d is None or not p.drag > 0.0:
            return "this wind"
        wn, we = d[0] * p.mass / p.drag, d[1] * p.mass / p.drag
        frm = math.degrees(math.atan2(-we, -wn)) % 360.0
        return f"wind {math.hypot(wn, we):.1f} m/s from {frm:03.0f} deg"

    def _hold_here(self, obs: Observation) -> PositionSetpoint | None:
        """Hold where the vehicle is, stopped: its velocity setpoint is the estimate's velocity
        error reversed (``LocalPosition.vel_correction_ned``), the velocity PX4's estimate reads
        when the vehicle stands still. With zero there, PX4 (its own position control flies
        this setpoint from the switch to OFFBOARD until the service sees the switch, up to a
        1 Hz HEARTBEAT later) braked a velocity that was not there: real PX4 SITL on a loaded
        host, EKF2's velocity 0.4-0.5 m/s off after a Hold, accelerated the vehicle back at up to
        0.5 m/s in that second."""
        pos = obs.position
        if pos is None:
            return None
        c = pos.vel_correction_ned
        return PositionSetpoint(pos_ned=pos.pos_ned, vel_ned=(-c[0], -c[1], 0.0), yaw=obs.yaw)

    def _enter_offboard(self, obs: Observation, fresh: bool) -> list[Action]:
        prog = self.program
        if isinstance(self.stream, HoldStream):
            pass  # keep holding where OFFBOARD began while we decide
        elif (sp := self._hold_here(obs)) is not None:
            self.stream = HoldStream(sp)
        why = None
        if prog is None:
            why = self.plan_error or "no mission planned yet"
        elif self.done:
            why = "mission already flown on this flight"
        elif not fresh or obs.position is None:
            why = "no fresh position"
        else:
            self._check_wind(obs.now_s, force=True)
            wc = self.wind_check
            if wc is not None and not wc.flyable:
                why = f"not flyable in the wind here: {wc.reason}"
        if why is not None:
            self.state = "offboard_hold"
            return [Announce(f"ecca: holding in OFFBOARD ({why})"),
                    LogEvent("state", {"state": "offboard_hold", "why": why})]
        assert prog is not None and obs.position is not None
        self._join_token += 1
        req = PlanJoin(self._join_token, prog, obs, self.reached, self.t_progress)
        self._joining, self.state = req.token, "joining"
        if self.defer_join:
            return [req]
        return self.on_joined(req.token, self.plan_join(req), obs.now_s)

    def plan_join(self, req: PlanJoin) -> MissionStream | str:
        """The mission stream joining ``req.program`` from ``req.obs``, or why there is none.
        Reads only the configuration and ``req``: safe to call from a worker thread."""
        try:
            return self._join(req.program, req.obs, req.reached, req.t_progress)
        except ValueError as exc:
            return str(exc)

    def on_joined(self, token: int, result: MissionStream | str, now_s: float) -> list[Action]:
        """The join ``token`` was planned (``plan_join``'s result): fly it from ``now_s`` [s],
        unless the vehicle left OFFBOARD or the mission changed meanwhile."""
        prog, obs = self.program, self._obs
        if token != self._joining or self.state != "joining" or prog is None or obs is None:
            return [LogEvent("join_discarded", {"why": "left OFFBOARD or the mission changed "
                                                       "while the join was planned"})]
        self._joining = None
        if isinstance(result, str):
            self.state = "offboard_hold"
            return [Announce(f"ecca: holding, cannot join the mission: {result}",
                             MAV_SEVERITY_WARNING),
                    LogEvent("join_failed", {"why": result})]
        clock = None if self.clock is None else self.clock()
        stream = dataclasses.replace(result, t0_s=now_s, clock=clock,
                                     t0_flight_s=now_s if clock is None else clock(now_s))
        self.stream = stream
        self.state = "mission"
        self._seq = self._sequence(prog, stream, dataclasses.replace(obs, now_s=now_s))
        return [Announce(f"ecca: flying mission from {self._progress_text()}"),
                LogEvent("state", {"state": "mission", "t_join": round(stream.t_join, 3),
                                   "join_s": round(stream.join_s, 3),
                                   "reached": self.reached})]

    def _join(self, prog: MissionProgram, obs: Observation, reached: int, t_progress: float
              ) -> MissionStream:
        cfg = self.config
        t_join, join = self.join_choice(prog, obs, reached, t_progress)
        if join is None:
            join_s = 0.0

            def ref(t: float) -> Reference:
                return prog.reference(t_join + t)
        else:
            join_s = join.duration
            join_ref = trajectory_reference(join)

            def ref(t: float) -> Reference:
                if t < join_s:
                    return join_ref(t)
                return prog.reference(t_join + t - join_s)
        source = TrackingSource(ref, cfg.setpoint_mode, cfg.params,
                                tracking=cfg.tracking if cfg.setpoint_mode in ("attitude", "rates")
                                else None,
                                limits=SetpointLimits.of_px4(cfg.px4 or Px4PlanningParams()))
        return MissionStream(source, obs.now_s, join_s, t_join)

    def join_choice(self, prog: MissionProgram, obs: Observation, reached: int,
                    t_progress: float) -> tuple[float, PiecewiseBezier | None]:
        """Where to join ``prog`` from ``obs`` (its fresh position) with ``reached`` waypoints
        and ``t_progress`` [s] flown: (the schedule time where the join ends [s], the joining
        trajectory in local NED with its yaw, or None when already there). ValueError if no
        join keeps the limits."""
        assert obs.position is not None
        cfg = self.config
        here = np.asarray(obs.position.pos_ned, dtype=np.float64)
        vel = np.array(obs.position.vel_corrected_ned, dtype=np.float64)
        if cfg.setpoint_mode in ("attitude", "rates"):
            # the tracking source stops the vehicle first (its handover, HANDOVER_S: PX4 may fly
            # its own control meanwhile) and starts the join from where it stopped: from rest
            # (planned from a Hold's pull-back at -0.15 m/s, the join led a stopped vehicle
            # back toward wp 1 at up to 0.5 m/s on real PX4)
            vel = np.zeros(3)
        t_near = prog.join_time(here, reached, max(t_progress, prog.t_begin))
        yaw_here = obs.yaw
        # join ahead of the nearest point, far enough to reach the plan's speed there without
        # backing up (distance >= v^2 / (2 a)); farther ahead if the join cannot be planned
        # within the limits. Candidates: three lead-in distances and the next waypoint, each
        # ending on the plan's velocity and acceleration or on its velocity only (an
        # acceleration step the controller absorbs, counted as JOIN_ACC_STEP_S later); the
        # earliest end of the mission wins (each candidate takes ~5-50 ms)
        best: tuple[float, PiecewiseBezier | None] | None = None
        best_end = math.inf
        last: Exception | None = None
        t_cands = [prog.lead_in(here, t_near, frac * cfg.limits.max_acc_m_s2)
                   for frac in (0.5, 0.25, 0.125)]
        if reached < len(prog.wp_times):  # and the next waypoint itself
            t_cands.append(max(float(prog.wp_times[reached]), t_near))
        for t_cand in sorted(set(t_cands)):
            for with_acc in (True, False):
                try:
                    cand = self._join_trajectory(here, vel, yaw_here, prog.reference(t_cand),
                                                 with_acc)
                except ValueError as exc:
                    last = exc
                    continue
                t_mission_end = ((cand.duration if cand else 0.0) + prog.t_end - t_cand
                                 + (0.0 if with_acc else JOIN_ACC_STEP_S))
                if t_mission_end < best_end:
                    best, best_end = (t_cand, cand), t_mission_end
        if best is None:
            assert last is not None
            raise last
        return best

    def _join_trajectory(self, here: FloatArray, vel: FloatArray, yaw_here: float | None,
                         target: Reference, with_acc: bool) -> PiecewiseBezier | None:
        """The trajectory (with its yaw) from ``here`` moving at ``vel`` to ``target``
        (its position, velocity and, with ``with_acc``, acceleration), or None when already
        there. One degree-7 segment (its ends fixed through jerk), the shortest of a geometric
        series of durations that keeps the speed, acceleration and tilt limits and never backs
        up along the way: its velocity along the line to the target stays above the lower of
        the start's and the end's (ValueError if none does)."""
        cfg = self.config
        chord = target.pos_ned - here
        dist = float(np.linalg.norm(chord))
        if dist < 0.05:
            return None
        along = chord / dist
        yaw0 = yaw_here if yaw_here is not None else target.yaw
        yaw1 = target.yaw + 2.0 * math.pi * round((yaw0 - target.yaw) / (2.0 * math.pi))
        # the join may end (or start) faster than its cruise speed: allow that speed
        v_max = max(cfg.join_speed_m_s, 1.5 * float(np.linalg.norm(target.vel_ned)),
                    1.1 * float(np.linalg.norm(vel)))
        # the plan itself may run at its acceleration and tilt limits where the join ends
        tilt = cfg.limits.max_tilt_rad
        lim = Limits(max_speed_m_s=v_max, max_acc_m_s2=JOIN_LIMIT_MARGIN * cfg.limits.max_acc_m_s2,
                     max_tilt_rad=None if tilt is None else JOIN_LIMIT_MARGIN * tilt)
        floor = min(0.0, float(vel @ along), float(target.vel_ned @ along)) - JOIN_BACKUP_M_S
        end = {1: target.vel_ned, 2: target.acc_ned} if with_acc else {1: target.vel_ned}
        waypoints = np.vstack([here, target.pos_ned])
        duration = max(JOIN_MIN_S, dist / v_max)
        for _ in range(JOIN_TRIES):
            traj = plan(waypoints, durations=[duration], start={1: vel}, end=end,
                        yaw=[yaw0, yaw1])
            v_along = traj.evaluate(np.linspace(0.0, duration, JOIN_SAMPLES), 1) @ along
            if float(np.min(v_along)) >= floor and not any(
                    r.exceeded for r in check(traj, lim, cfg.params).values()):
                return traj
            duration *= JOIN_STRETCH
        raise ValueError(f"no joining trajectory to the plan {dist:.1f} m away within the "
                         f"limits without backing up")

    def _fly(self, obs: Observation, fresh: bool) -> list[Action]:
        ms = self.stream
        prog = self.program
        if not isinstance(ms, MissionStream) or prog is None:
            return []
        t = ms.schedule_time(obs.now_s)
        self.t_progress = max(self.t_progress, min(t, prog.t_end))
        # the plan passing a waypoint counts, whatever the tracking error
        while self.reached < len(prog.wp_times) and prog.wp_times[self.reached] <= t \
                and obs.now_s - ms.t0_s >= ms.join_s:
            self.reached += 1
        seq = self._seq
        requests = [] if seq is None else self._final_requests(
            seq.update(obs.now_s, self._view(obs, fresh)))
        if not requests:  # the plan has not ended and settled yet
            return []
        end = prog.reference(prog.t_end).pos_ned
        self.done = True
        self.state = "finishing"
        self.stream = HoldStream(PositionSetpoint(
            pos_ned=(float(end[0]), float(end[1]), float(end[2])), vel_ned=(0.0, 0.0, 0.0),
            yaw=_yaw_of(prog.reference(prog.t_end))))
        quality = ms.source.quality
        bad = quality.failure()
        return [Announce(f"ecca: mission complete, {prog.final_action}"),
                *([Announce(f"ecca: setpoints: {bad}", MAV_SEVERITY_WARNING)] if bad else []),
                LogEvent("mission_complete", {"reached": self.reached,
                                              "final_action": prog.final_action,
                                              "setpoint_quality": quality.figures().to_dict(),
                                              "setpoints_ok": bad is None}),
                *requests]

    def _sequence(self, prog: MissionProgram, ms: MissionStream, obs: Observation
                  ) -> FlightSequence:
        """The flight sequence of this OFFBOARD entry, started now (with the mission stream):
        its trajectory runs until the stream's schedule time reaches the plan's end (at once if
        the join ends there), then it hands over to the final mode once within settle_m of the
        plan's end or settle_s later, re-requesting it every mode_retry_s while in OFFBOARD."""
        cfg = self.config
        to_end = 0.0 if ms.t_join >= prog.t_end else ms.join_s + (prog.t_end - ms.t_join)
        end = prog.reference(prog.t_end).pos_ned
        seq = FlightSequence(SequenceConfig(
            rate_hz=cfg.rate_hz, duration_s=to_end, pilot_start=True,
            end=EndPolicy(handover_mode=final_mode(prog.final_action), settle_s=cfg.settle_s,
                          settle_m=cfg.settle_m,
                          end_ned=(float(end[0]), float(end[1]), float(end[2])),
                          land_command=False, land_and_disarm=False,
                          stall_s=policy_stall_s("quad", cfg.setpoint_mode),
                          handover_retry_s=cfg.mode_retry_s)))
        seq.update(obs.now_s, self._view(obs, True))
        assert seq.t_fly0 == ms.t0_s
        return seq

    def _view(self, obs: Observation, fresh: bool) -> VehicleView:
        """What the flight sequence sees: a position only when fresh; the stream's reference
        time when its source governs it (slowed down for the vehicle)."""
        pos = obs.position
        ms = self.stream
        src = ms.source if isinstance(ms, MissionStream) else None
        return VehicleView(armed=obs.armed, mode=obs.mode,
                           pos_ned=pos.pos_ned if fresh and pos is not None else None,
                           traj_time_s=None if src is None else src.reference_time_s,
                           stalled_s=0.0 if src is None else src.stalled_s,
                           blind_s=0.0 if src is None else src.blind_s)

    def _final_requests(self, acts: list[SequenceAction]) -> list[Action]:
        """The sequence's handover commands as mode requests (results are not awaited)."""
        prog = self.program
        action = prog.final_action if prog is not None else "loiter"
        # the sequence's reason (e.g. how far from the plan's end it settled) goes with it
        why = next((a.reason for a in acts if isinstance(a, PhaseChanged) and a.reason), "")
        suffix = f" ({why})" if why else ""
        return [RequestMode(a.mode, f"mission end: {action}{suffix}") for a in acts
                if isinstance(a, SendCommand) and a.mode is not None]
