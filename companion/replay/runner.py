"""Lockstep replay: the companion's protocol core and controllers fly a mission file against
the `sitl_mock` autopilot core over an in-memory link on a simulated clock.

Nothing here sleeps or reads a clock: both sides are sans-IO and advance together in steps of
one setpoint period, so a replay runs as fast as the CPU allows and is deterministic for a seed.
Every frame in both directions is written to a `.tlog` (8-byte big-endian microsecond
timestamp + raw MAVLink frame), readable by pymavlink, MAVExplorer and QGroundControl.

The companion side follows PX4's offboard protocol exactly as on a real vehicle: wait for a
healthy vehicle, stream setpoints for 0.5 s (priming), switch to OFFBOARD, arm, fly the planned
schedule, then land as `fly` does: in attitude and rates mode touch down itself
(`companion.flight.tracking.Touchdown`), in position mode hand over to PX4's NAV_LAND (a loiter
ending: Hold), and disarm once PX4 reports the vehicle on the ground.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import os
import shutil
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from companion.aio.tlog import TlogWriter
from companion.app.plotting import PlotData, PlotWorker, draw_flight_png
from companion.control import Reference
from companion.flatness import MultirotorParams
from companion.flight import policy
from companion.flight.policy import handover_mode, plan_touchdown
from companion.flight.report import SetpointLimits, closest_approach
from companion.flight.sequence import (
    EndPolicy,
    FlightSequence,
    Phase,
    PhaseChanged,
    SendCommand,
    SequenceAction,
    SequenceConfig,
    Stream,
    VehicleView,
)
from companion.flight.tracking import SetpointMode, Touchdown, TrackingSource
from companion.mavlink.commands import (
    MAV_CMD_COMPONENT_ARM_DISARM,
    MAV_CMD_DO_SET_MODE,
    MAV_CMD_NAV_LAND,
    CommandFinished,
)
from companion.mavlink.link import LinkConfig, VehicleLink
from companion.mavlink.mission_client import MissionTransferDone, item_to_msg
from companion.mavlink.params import ParamReadDone, ParamType
from companion.mavlink.px4_mode import FlightMode
from companion.mavlink.setpoints import (
    AttitudeSetpoint,
    PositionSetpoint,
    RatesSetpoint,
    SetpointCommand,
)
from companion.mission import (
    FlightPlan,
    Mission,
    MissionError,
    load_mission,
    mission_to_flight_plan,
    mission_upload_items,
)
from companion.mission.px4_params import PLANNING_PARAM_NAMES
from companion.planning.fence_check import (
    breach_report,
    flown_breaches,
    require_plan_inside,
    zone_masks,
)
from companion.planning.legs import leg_figures, plan_bounds, plan_legs
from companion.planning.schedule import Schedule, VehicleLimits, build_schedule
from companion.planning.vehicle_params import ResolvedPlanningParams, resolve_planning_params

FloatArray = NDArray[np.float64]
Mode = Literal["position", "attitude", "rates"]

#: Offboard priming: setpoints streamed before OFFBOARD is requested [s].
PRIME_S = 0.5
#: Extra time after the schedule before handing over to PX4's landing [s].
SETTLE_S = 1.0
#: Simulated time a replay spends outside the schedule (waiting for the vehicle, priming,
#: switching to OFFBOARD, the final descent and disarm), for progress reporting only [s].
EXPECTED_OVERHEAD_S = 8.0
#: A rover is planned at most at this fraction of the mock rover's top speed (RO_MAX_SPEED) unless
#: `VehicleLimits.rover_max_speed_m_s` says otherwise: a plan at the top speed leaves the
#: tracking controller nothing to catch up with, and the rover falls behind and cuts corners.
ROVER_SPEED_FRACTION = 0.9
#: The companion's view of the default mock quadrotor (PX4 SIH: 1 kg, 4 x 5 N, drag 1 N/(m/s)).
DEFAULT_QUAD = MultirotorParams(
    mass=1.0, inertia=(0.025, 0.025, 0.030), hover_thrust=0.5, drag=1.0
)
#: Simulated t = 0 on the tlog's UNIX clock: 2026-01-01T00:00:00Z, for deterministic timestamps.
TLOG_EPOCH_S = 1_767_225_600.0


@dataclass(frozen=True)
class ReplayConfig:
    """How to replay: vehicle kind, setpoint mode and rate [Hz], mock physics rate [Hz],
    constant wind speed [m/s] blowing from `wind_from_deg` (compass, default 135: from the
    south-east, air moving toward the north-west), RNG seed, and whether to also fly the
    mission in the mock's own AUTO.MISSION for comparison.

    Perturbations (Monte-Carlo campaigns): `params` is the companion's belief about the vehicle
    (e.g. a wrong hover thrust), `mock_params` the mock's truth (SIH_MASS, SIH_KDV, SIM_*...);
    `latency_s`/`jitter_s` delay the telemetry (mock -> companion), `loss_pct` drops datagrams
    in both directions; `start_offset_ne_m` puts the vehicle that far (north, east) [m] from
    the mission's planned home (the companion plans from where it stands, like `fly`)."""

    vehicle: Literal["quad", "rover"] = "quad"
    mode: Mode = "attitude"
    rate_hz: float = 100.0
    physics_hz: float = 250.0
    wind_m_s: float = 0.0
    seed: int = 0
    compare_px4_mission: bool = False
    params: MultirotorParams = DEFAULT_QUAD
    limits: VehicleLimits = field(default_factory=VehicleLimits)
    mock_params: tuple[tuple[str, float], ...] = ()
    timeout_margin_s: float = 120.0
    wind_from_deg: float = 135.0
    latency_s: float = 0.0
    jitter_s: float = 0.0
    loss_pct: float = 0.0
    start_offset_ne_m: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        if self.vehicle not in ("quad", "rover"):
            raise ValueError(f"vehicle must be 'quad' or 'rover', got {self.vehicle!r}")
        if self.mode not in ("position", "attitude", "rates"):
            raise ValueError(f"mode must be position, attitude or rates, got {self.mode!r}")
        if not 20.0 <= self.rate_hz <= 500.0:
            raise ValueError(f"setpoint rate must be 20..500 Hz, got {self.rate_hz}")
        if not (math.isfinite(self.wind_m_s) and self.wind_m_s >= 0.0):
            raise ValueError(f"wind speed must be >= 0 m/s, got {self.wind_m_s}")
        if not math.isfinite(self.wind_from_deg):
            raise ValueError(f"wind direction must be finite, got {self.wind_from_deg}")
        for name in ("latency_s", "jitter_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and 0.0 <= v <= 5.0):
                raise ValueError(f"{name} must be 0..5 s, got {v}")
        if not (math.isfinite(self.loss_pct) and 0.0 <= self.loss_pct <= 100.0):
            raise ValueError(f"packet loss must be 0..100 %, got {self.loss_pct}")
        if not all(math.isfinite(v) and abs(v) <= 1000.0 for v in self.start_offset_ne_m):
            raise ValueError(f"start offset must be within 1 km, got {self.start_offset_ne_m}")
        from sitl_mock.params import PARAMS

        for name, value in self.mock_params:
            if name not in PARAMS:
                raise ValueError(f"unknown mock parameter {name!r}")
            if not math.isfinite(value):
                raise ValueError(f"mock parameter {name} must be finite, got {value}")

    def wind_ned(self) -> tuple[float, float, float]:
        """Steady wind velocity [m/s NED] (air moves toward wind_from_deg + 180)."""
        if self.wind_from_deg == 135.0:  # the replay's historical default, bit for bit
            w = self.wind_m_s / math.sqrt(2.0)
            return (w, -w, 0.0)
        to = math.radians(self.wind_from_deg + 180.0)
        return (self.wind_m_s * math.cos(to), self.wind_m_s * math.sin(to), 0.0)


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


# ----------------------------------------------------------------------------- the engine


#: Messages the companion acts on during a replay; others (ATTITUDE at 100 Hz, ODOMETRY,
#: GLOBAL_POSITION_INT, targets, battery...) go to the tlog undecoded to save CPU.
COMPANION_MSG_IDS = frozenset(
    {
        0,  # HEARTBEAT
        1,  # SYS_STATUS
        31,  # ATTITUDE_QUATERNION
        32,  # LOCAL_POSITION_NED
        22,  # PARAM_VALUE (the planning parameters, read before planning)
        39, 40, 42, 44, 45, 46, 47, 51, 73, 77,  # MISSION_* and COMMAND_ACK
        111,  # TIMESYNC
        242,  # HOME_POSITION
        245,  # EXTENDED_SYS_STATE
        253,  # STATUSTEXT
    }
)


def _msgid(frame: bytes) -> int | None:
    """Message id of a single MAVLink 2 frame, or None if it is not one."""
    if len(frame) < 12 or frame[0] != 0xFD:
        return None
    return frame[7] | (frame[8] << 8) | (frame[9] << 16)


class LockstepLink:
    """In-memory link between a `VehicleLink` and a `sitl_mock` autopilot, with a tlog tap.

    Each datagram of the mock is one frame; frames whose id is not in `wanted` are logged but
    not decoded (None decodes everything).
    """

    def __init__(
        self,
        autopilot: Any,
        link: VehicleLink,
        tlog: TlogWriter | None,
        wanted: frozenset[int] | None = COMPANION_MSG_IDS,
    ) -> None:
        self.wanted = wanted
        self.ap = autopilot
        self.link = link
        self.tlog = tlog
        self.now = 0.0
        self.on_message: Callable[[Any, float], None] | None = None

    def to_vehicle(self, frames: list[bytes]) -> None:
        now = self.now
        tlog = self.tlog
        receive = self.ap.receive_datagram
        if tlog is not None:
            tlog.write_many(frames, TLOG_EPOCH_S + now)
        for fr in frames:
            receive(fr, "companion", now)

    def advance(self, t: float) -> list[Any]:
        """Advance both sides to `t`; returns the link events produced."""
        self.now = t
        self.ap.advance(t)
        events: list[Any] = []
        tlog = self.tlog
        wanted = self.wanted
        on_message = self.on_message
        link = self.link
        t_log = TLOG_EPOCH_S + t
        out = self.ap.datagrams_to_send(t)
        if tlog is not None and out:
            tlog.write_many([data for data, _addr in out], t_log)
        for data, _addr in out:
            if wanted is not None and _msgid(data) not in wanted:
                continue
            for msg in link.codec.decode(data):
                if on_message is not None:
                    on_message(msg, t)
                events += link.handle_message(msg, t)
        events += link.handle_timer(t)
        frames = link.frames_to_send()
        if frames:
            self.to_vehicle(frames)
        return events


def planning_limits(config: ReplayConfig) -> VehicleLimits:
    """`config.limits`, with a rover's speed capped at ROVER_SPEED_FRACTION of the mock rover's
    RO_MAX_SPEED (with `config.mock_params` applied) unless the limits already set a cap."""
    lim = config.limits
    if config.vehicle != "rover" or lim.rover_max_speed_m_s is not None:
        return lim
    from sitl_mock.params import ParamStore

    top = float(ParamStore(dict(config.mock_params))["RO_MAX_SPEED"])
    return dataclasses.replace(lim, rover_max_speed_m_s=ROVER_SPEED_FRACTION * top)


def _make_autopilot(config: ReplayConfig, home: tuple[float, float, float]) -> Any:
    from sitl_mock.autopilot import Autopilot
    from sitl_mock.faults import LinkFaults
    from sitl_mock.params import ParamStore

    if config.start_offset_ne_m != (0.0, 0.0):
        from sitl_mock.vehicle import ned_to_geodetic

        n, e = config.start_offset_ne_m
        home = ned_to_geodetic((n, e, 0.0), home)  # the vehicle boots (and PX4's home is) here
    faults = None
    if config.latency_s or config.jitter_s or config.loss_pct:
        # Autopilot's view: rx = companion -> vehicle (setpoints, commands), tx = telemetry
        f_in = LinkFaults(loss_pct=config.loss_pct)
        f_out = LinkFaults(loss_pct=config.loss_pct, latency_s=config.latency_s,
                           jitter_s=config.jitter_s)
        faults = {"offboard": (f_in, f_out)}
    ap = Autopilot(
        config.vehicle,
        ParamStore(dict(config.mock_params)),
        home,
        config.seed,
        physics_hz=config.physics_hz,
        now=0.0,
        remotes={"offboard": "companion"},
        link_faults=faults,
    )
    if config.wind_m_s > 0.0:
        ap.vehicle.set_wind(config.wind_ned())
    return ap


class Flight:
    """The replay's side of the one flight sequence (`companion.flight.FlightSequence`): feeds
    it the lockstep link's events and telemetry, performs its actions over the `LockstepLink`
    and records the flight's log (see the module docstring)."""

    def __init__(
        self,
        config: ReplayConfig,
        schedule: Schedule,
        lk: LockstepLink,
        log: FlightLog,
    ) -> None:
        self.config = config
        self.schedule = schedule
        self.lk = lk
        self.link = lk.link
        self.log = log
        self.origin = np.zeros(3)
        mode: SetpointMode = "rover" if config.vehicle == "rover" else config.mode
        # attitude and rates mode land a quad themselves (as `fly` does): the plan's descent
        # ends TOUCHDOWN_FROM_M up (`prepare_mission`); the touchdown takes over where it stops
        # cruising and descends until PX4 detects the landing, then the companion disarms
        self.touchdown: Touchdown | None = None
        if self_lands(config, schedule.final_action):
            self.touchdown = plan_touchdown(schedule, schedule.px4.MPC_LAND_SPEED)
        self.source = TrackingSource(self._reference, mode, config.params,
                                     touchdown=self.touchdown,
                                     limits=SetpointLimits.of_px4(schedule.px4))
        rover = config.vehicle == "rover"
        self.seq = FlightSequence(SequenceConfig(
            rate_hz=config.rate_hz, duration_s=schedule.duration_s, prime_s=PRIME_S,
            end=EndPolicy(
                handover_mode=handover_mode(config.vehicle, schedule.final_action),
                touchdown_from_s=None if self.touchdown is None else self.touchdown.from_s,
                settle_s=SETTLE_S, disarm_at_hold=rover, disarm_on_ground=not rover)))
        self.setpoints_sent = 0
        self._armed_seen = False  # a HEARTBEAT showed armed (disarmed_t is after it)

    @property
    def phase(self) -> Phase:
        """Where the flight sequence is."""
        return self.seq.phase

    @property
    def reason(self) -> str:
        """Why the flight ended (empty: it did not fail)."""
        return self.seq.reason

    @property
    def done(self) -> bool:
        """The sequence finished."""
        return self.seq.finished

    def _reference(self, t_s: float) -> Reference:
        return self.schedule.reference(t_s, origin=self.origin)

    def _stream(self, t_s: float | None, now: float) -> None:
        if t_s is None:  # priming, mode request, arming: hold the start point
            sp: SetpointCommand = (PositionSetpoint(vel_ned=(0.0, 0.0, 0.0), yaw_rate=0.0)
                                   if self.config.vehicle == "rover"
                                   else self.source.position_setpoint(0.0))
        else:
            snap = self.link.telemetry.snapshot()
            # stamp this cycle's clock in place (what dataclasses.replace(snap, now_s=now)
            # gives, without re-running the constructor). The link may hand out the same
            # snapshot again while no value changed; it is this flight's own, and every cycle
            # stamps it first.
            object.__setattr__(snap, "now_s", now)
            sp = self.source(t_s, snap)
        self.lk.to_vehicle([self.link.encode_setpoint(sp, now)])
        self.seq.on_setpoint_sent(now)
        self.setpoints_sent += 1
        if isinstance(sp, (AttitudeSetpoint, RatesSetpoint)):
            self.log.thrust_norm.append(sp.thrust_norm)

    def perform(self, actions: list[SequenceAction], now: float) -> None:
        """Carry out the sequence's actions over the lockstep link."""
        link = self.link
        for a in actions:
            if isinstance(a, Stream):
                self._stream(a.t_s, now)
            elif isinstance(a, SendCommand):
                if a.command == MAV_CMD_DO_SET_MODE and a.mode is not None:
                    link.set_mode(a.mode, now)
                elif a.command == MAV_CMD_COMPONENT_ARM_DISARM:
                    (link.arm if a.arm else link.disarm)(now)
                elif a.command == MAV_CMD_NAV_LAND:
                    link.land(now)
            elif isinstance(a, PhaseChanged):
                if a.new is Phase.PRIME:
                    pos = link.telemetry.position
                    assert pos is not None
                    self.origin = np.array(pos.pos_ned)
                elif a.new is Phase.FLY:
                    self.log.fly_t0 = now
                    # armed from the accepted ARM, as PX4's AUTO.MISSION flight: the
                    # HEARTBEAT (1 Hz) shows it up to 1 s later
                    if self.log.armed_t is None or now < self.log.armed_t:
                        self.log.armed_t = now
                    self.source.reset()
        if self.seq.t_plan_end is not None:
            self.log.fly_t1 = self.seq.t_plan_end

    def on_events(self, events: list[Any], now: float) -> None:
        """Command results from the link."""
        for ev in events:
            if isinstance(ev, CommandFinished):
                self.perform(self.seq.on_command_result(ev.command, ev.ok, ev.reason, now,
                                                        ev.result), now)

    def tick(self, now: float) -> None:
        """One setpoint period."""
        tel = self.link.telemetry
        armed = self.link.armed
        if armed:
            self._armed_seen = True
            if self.log.armed_t is None:
                self.log.armed_t = now
        elif self._armed_seen and self.log.disarmed_t is None:
            self.log.disarmed_t = now
        have_state = tel.position is not None and tel.attitude is not None
        st = tel.sys_status
        ext = tel.extended
        view = VehicleView(
            link_ok=self.link.heartbeat.link_up, armed=armed, mode=self.link.mode,
            ready=have_state and st is not None and st.armable, have_state=have_state,
            on_ground=ext is not None and ext.landed_state == 1)
        self.perform(self.seq.update(now, view), now)

    def abort(self, now: float, reason: str) -> None:
        """End the flight (the replay's time limit)."""
        self.perform(self.seq.fail(now, reason), now)


# ----------------------------------------------------------------------------- public API


@dataclass(frozen=True)
class ReplayResult:
    """Outcome of one replayed file: output folder, report dict, and whether it succeeded."""

    name: str
    out_dir: Path
    report: dict[str, Any]
    ok: bool


def _record_message(log: FlightLog, msg: Any, t: float) -> None:
    kind = msg.get_type()
    if kind == "LOCAL_POSITION_NED":
        log.t.append(msg.time_boot_ms * 1e-3)  # sample time (the mock boots at t = 0)
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


def fly_schedule(
    config: ReplayConfig,
    schedule: Schedule,
    home: tuple[float, float, float],
    tlog: TlogWriter | None,
    progress: Callable[[float, float], None] | None = None,
) -> tuple[Flight, FlightLog]:
    """Fly `schedule` in lockstep against a fresh mock; returns the flight and its log.

    `progress(now_s, expected_s)` is called every 100 setpoint cycles with the simulated time
    and the expected end of the flight (the schedule plus the start-up and landing)."""
    ap = _make_autopilot(config, home)
    link = VehicleLink(LinkConfig())
    log = FlightLog()
    lk = LockstepLink(ap, link, tlog)
    lk.on_message = functools.partial(_record_message, log)
    flight = Flight(config, schedule, lk, log)
    dt = 1.0 / config.rate_hz
    t_max = schedule.duration_s + config.timeout_margin_s
    expected = schedule.duration_s + EXPECTED_OVERHEAD_S
    k = 0
    while not flight.done:
        k += 1
        now = k * dt
        if now > t_max:
            flight.abort(now, f"timed out after {t_max:.0f} s of simulated time")
            break
        flight.on_events(lk.advance(now), now)
        flight.tick(now)
        if progress is not None and k % 100 == 0:
            progress(now, max(expected, now))
    # let the last frames out and record the landing
    end = lk.now + 1.0
    while lk.now < end:
        lk.advance(lk.now + dt)
    return flight, log


def mission_frames(mission: Mission, config: LinkConfig | None = None) -> list[bytes]:
    """The mission as the companion would upload it to PX4 (MISSION_COUNT, then one
    MISSION_ITEM_INT per item, from the companion's ids to the autopilot's), for the head of a
    replay's tlog: QGroundControl and MAVExplorer show the mission of a log from these."""
    from pymavlink.dialects.v20 import common as mavlink2

    from companion.mavlink.codec import Codec

    cfg = config or LinkConfig()
    codec = Codec(cfg.sysid, cfg.compid)
    ts, tc = cfg.target_sysid, cfg.target_compid
    items = mission_upload_items(mission)
    frames = [codec.encode(mavlink2.MAVLink_mission_count_message(ts, tc, len(items), 0))]
    frames += [codec.encode(item_to_msg(u, ts, tc)) for u in items]
    return frames


def fly_px4_mission(
    config: ReplayConfig,
    mission: Mission,
    home: tuple[float, float, float],
    duration_hint_s: float,
) -> tuple[str, FlightLog]:
    """Upload `mission` to a fresh mock and fly it in PX4's own AUTO.MISSION; returns
    ("ok" or the failure reason, log)."""
    ap = _make_autopilot(config, home)
    link = VehicleLink(LinkConfig())
    log = FlightLog()
    lk = LockstepLink(ap, link, None)
    lk.on_message = lambda m, t: _record_message(log, m, t)
    dt = 0.02
    t = 0.0
    state = "wait"
    t_state = 0.0
    result = "ok"
    t_max = duration_hint_s * 3.0 + config.timeout_margin_s
    finished = False
    while True:
        t += dt
        if t > t_max:
            result = f"timed out after {t_max:.0f} s"
            break
        for ev in lk.advance(t):
            if isinstance(ev, MissionTransferDone) and state == "upload":
                if ev.result.name != "SUCCESS":
                    return f"mission upload failed: {ev.result.name} {ev.detail}", log
                state, t_state = "mode", t
                link.set_mode(FlightMode.MISSION, t)
            elif isinstance(ev, CommandFinished) and state == "mode" and ev.command == 176:
                if not ev.ok:
                    return f"AUTO.MISSION refused: {ev.reason}", log
                state = "arm"
                link.arm(t)
            elif isinstance(ev, CommandFinished) and state == "arm" and ev.command == 400:
                if not ev.ok:
                    return f"arming refused: {ev.reason}", log
                state, t_state = "flying", t
                log.armed_t = t
        st = link.telemetry.sys_status
        if state == "wait" and st is not None and st.armable:
            state = "upload"
            link.mission.upload(mission_upload_items(mission), t)
            lk.to_vehicle(link.frames_to_send())
        if any("Mission finished" in s for _, _, s in log.statustext):
            finished = True
        if state == "flying":
            if not link.armed and t - t_state > 2.0:
                log.disarmed_t = t
                break
            if finished and link.mode == FlightMode.HOLD and t - t_state > 2.0:
                log.disarmed_t = t
                break
    return result, log


def tracking_error(
    log: FlightLog, schedule: Schedule, origin: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """(t [s], |flown - planned| [m]) at every position sample taken while flying the plan,
    the plan evaluated at the sample's own time."""
    if log.fly_t0 is None:
        return np.zeros(0), np.zeros(0)
    t = np.asarray(log.t)
    t1 = log.fly_t1 if log.fly_t1 is not None else (t[-1] if len(t) else log.fly_t0)
    sel = (t >= log.fly_t0) & (t <= t1)
    if not sel.any():
        return np.zeros(0), np.zeros(0)
    pos = np.asarray(log.pos, dtype=np.float64)[sel]
    planned = schedule.sample(t[sel] - log.fly_t0) + origin
    return t[sel], np.linalg.norm(pos - planned, axis=1)


def summarize(
    log: FlightLog,
    schedule: Schedule,
    mission: Mission,
    origin: FloatArray,
    *,
    thrust_from_log: bool = True,
    flight_plan: FlightPlan | None = None,
    fence_shift_ned: FloatArray | None = None,
    leg_bounds_s: Sequence[float | None] | None = None,
    bound_s: float | None = None,
) -> dict[str, Any]:
    """Report metrics of one flight (keys carry units).

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
    waypoints = [
        {
            "item_index": schedule.item_indices[i],
            "north_m": float(wps[i, 0]),
            "east_m": float(wps[i, 1]),
            "down_m": float(wps[i, 2]),
            "acceptance_radius_m": schedule.acceptance_m[i],
            "closest_approach_m": float(closest[i]),
            "reached": bool(closest[i] <= schedule.acceptance_m[i]),
        }
        for i in range(len(wps))
    ]
    _, err = tracking_error(log, schedule, origin)
    fence = mission.geofence
    shift = -np.asarray(origin, dtype=np.float64) if fence_shift_ned is None else fence_shift_ned
    pos_fence = pos_f + shift
    masks = zone_masks(fence, pos_fence) if len(pos_f) and not fence.empty else []
    failsafes = [
        {"t_s": round(ts, 3), "text": s}
        for ts, _sev, s in log.statustext
        if "failsafe" in s.lower() or "lost" in s.lower()
    ]
    duration = (
        (log.disarmed_t if log.disarmed_t is not None else (t[-1] if len(t) else 0.0))
        - (log.armed_t or 0.0)
        if log.armed_t is not None
        else 0.0
    )
    out: dict[str, Any] = {
        "duration_s": round(float(duration), 3),
        "planned_duration_s": round(schedule.duration_s, 3),
        "path_length_m": float(np.sum(np.linalg.norm(np.diff(pos_f, axis=0), axis=1)))
        if len(pos_f) > 1
        else 0.0,
        "rms_error_m": float(np.sqrt(np.mean(err**2))) if len(err) else None,
        "max_error_m": float(np.max(err)) if len(err) else None,
        "waypoints": waypoints,
        "waypoints_reached": int(np.count_nonzero(closest <= np.asarray(schedule.acceptance_m))),
        "max_speed_m_s": float(np.max(np.linalg.norm(vel_f, axis=1))) if len(vel_f) else 0.0,
        "max_tilt_deg": float(np.degrees(np.max(log.tilt))) if log.tilt else 0.0,
        "max_thrust_norm": float(np.max(log.thrust_norm)) if log.thrust_norm else None,
        "max_body_rate_rad_s": float(np.max(log.rate_norm)) if log.rate_norm else 0.0,
        "geofence_violations": int(sum(int(np.count_nonzero(m)) for _, m in masks)),
        "geofence_violation_zones": sorted(z for z, m in masks if m.any()),
        "failsafes": failsafes,
        "bound_s": None if bound_s is None else round(float(bound_s), 3),
        "planned_over_bound": (round(schedule.duration_s / bound_s, 3)
                               if bound_s is not None and bound_s > 0 else None),
    }
    if flight_plan is not None:
        legs = plan_legs(flight_plan)
        found = flown_breaches(flight_plan, t_f, pos_fence) if masks else []
        out["geofence_breaches"] = breach_report(found)
        from companion.planning.fence_check import sample_schedule

        pt, pp = sample_schedule(schedule)
        out["legs"] = leg_figures(legs, t_f, pos_f - origin, vel_ned=vel_f, planned_t_s=pt,
                                  planned_ned=pp, bounds_s=leg_bounds_s)
    return out


def plot_data(
    title: str,
    log: FlightLog,
    schedule: Schedule,
    origin: FloatArray,
    px4_log: FlightLog | None = None,
    legs: list[dict[str, Any]] | None = None,
) -> PlotData:
    """What flight.png shows for a flight: the plan sampled at 20 Hz, the flown positions and
    the tracking error (all NED, shifted by the flight's `origin`), and the per-leg figures of
    its report (`legs`), if any."""
    ts = np.linspace(0.0, schedule.duration_s, max(int(schedule.duration_s * 20), 2))
    te, err = tracking_error(log, schedule, origin)
    p4 = None
    if px4_log is not None and px4_log.pos:
        p4 = np.asarray(px4_log.pos, dtype=np.float64).reshape(-1, 3)
    return PlotData(
        title=title,
        plan_t=ts,
        plan_ned=schedule.sample(ts) + origin,
        t=np.asarray(log.t, dtype=np.float64),
        pos_ned=np.asarray(log.pos, dtype=np.float64).reshape(-1, 3),
        px4_pos_ned=p4,
        waypoints_ned=schedule.waypoints_ned + origin,
        acceptance_m=tuple(schedule.acceptance_m),
        t_fly0=log.fly_t0 or 0.0,
        err_t=te,
        err_m=err,
        legs=tuple(legs or ()),
    )


def plot_flight(
    path: Path,
    title: str,
    log: FlightLog,
    schedule: Schedule,
    origin: FloatArray,
    px4_log: FlightLog | None = None,
) -> None:
    """flight.png: top view and altitude / tracking error vs time, planned vs flown."""
    draw_flight_png(path, plot_data(title, log, schedule, origin, px4_log))


def read_mock_params(
    config: ReplayConfig,
    home: tuple[float, float, float],
    names: tuple[str, ...] = PLANNING_PARAM_NAMES,
    *,
    floats: bool = True,
    second_pass: bool = True,
    dt: float = 0.01,
    t_max: float = 10.0,
) -> ParamReadDone:
    """Read parameters from a fresh mock built from `config` (its `mock_params` applied) the
    way `fly` reads them from PX4: PARAM_REQUEST_READ by name over the lockstep link, with the
    client's retries, on simulated time (`floats`: each must come back as REAL32;
    `second_pass`: names not answered are asked for once more, as `Vehicle` does)."""
    ap = _make_autopilot(config, home)
    link = VehicleLink(LinkConfig())
    lk = LockstepLink(ap, link, None, wanted=frozenset({22}))  # PARAM_VALUE only
    expect = {n: ParamType.REAL32 for n in names} if floats else None
    t = 0.0

    def read(wanted: tuple[str, ...]) -> ParamReadDone:
        nonlocal t
        done = [e for e in link.params.read(wanted, t, expect) if isinstance(e, ParamReadDone)]
        lk.to_vehicle(link.frames_to_send())
        while not done:
            t += dt
            if t > t_max:  # the client gives up after its tries long before this
                raise RuntimeError(f"parameter read from the mock did not finish in {t_max:g} s")
            done = [e for e in lk.advance(t) if isinstance(e, ParamReadDone)]
        return done[0]

    first = read(names)
    if not (second_pass and first.missing):
        return first
    again = read(first.missing)  # a second pass, as Vehicle.read_planning_params does
    return ParamReadDone(again.t_s, {**first.values, **again.values}, again.missing,
                         {**first.wrong_type, **again.wrong_type}, first.attempts + again.attempts)


@dataclass(frozen=True)
class PreparedMission:
    """A mission file loaded and planned for one `ReplayConfig`'s vehicle, params and limits;
    `px4`: the PX4 planning parameters read from the mock and used (None: not read)."""

    path: Path
    mission: Mission
    warnings: tuple[str, ...]
    schedule: Schedule
    home: tuple[float, float, float]
    px4: ResolvedPlanningParams | None = None
    flight_plan: FlightPlan | None = None
    leg_bounds_s: tuple[float | None, ...] | None = None
    """Time-optimal bound of each leg of `companion.planning.legs.plan_legs(flight_plan)` [s] (None:
    not known; the report shows "-")."""
    bound_s: float | None = None
    """Time-optimal bound of the whole schedule [s] (None: not known)."""


def self_lands(config: ReplayConfig, final_action: str) -> bool:
    """The companion lands the vehicle itself (`companion.flight.self_lands`)."""
    return policy.self_lands(config.vehicle, config.mode, final_action)


def prepare_mission(path: str | os.PathLike[str], config: ReplayConfig) -> PreparedMission:
    """Load and plan `path` as `config` would fly it: the PX4 planning parameters are read
    from the mock first (`read_mock_params`, so `--mock-param MPC_XY_CRUISE=8` changes the
    plan as the vehicle's parameter would). Raises MissionError on a bad file and on a plan
    whose trajectory breaches the mission's geofence (naming the leg's items)."""
    src = Path(path)
    mission = load_mission(src)
    home = (mission.home.lat_deg, mission.home.lon_deg, mission.home.alt_amsl_m)
    read = read_mock_params(config, home)
    px4 = resolve_planning_params(read.values, wrong_type=read.wrong_type, where="the mock")
    flight_plan = mission_to_flight_plan(mission, vehicle=config.vehicle, px4=px4.params)
    params = None if config.vehicle == "rover" else config.params
    schedule = build_schedule(
        flight_plan, params, planning_limits(config),
        handover_height_m=policy.handover_height_m(config.vehicle, config.mode,
                                                   flight_plan.final_action))
    require_plan_inside(flight_plan, schedule)
    warnings = (*flight_plan.warnings, *px4.warnings, *schedule.warnings)
    leg_bounds, bound = plan_bounds(flight_plan, schedule)
    return PreparedMission(src, mission, warnings, schedule, home, px4, flight_plan, leg_bounds,
                           bound)


def fence_shift(config: ReplayConfig, origin: FloatArray) -> FloatArray:
    """Local mock NED -> mission frame: the mock's local origin is where it booted, the
    mission's home moved by `config.start_offset_ne_m`, so the geofence is checked where the
    vehicle really was (the companion itself flies relative to where it stood: `origin`)."""
    n, e = config.start_offset_ne_m
    if (n, e) == (0.0, 0.0):
        return -np.asarray(origin, dtype=np.float64)
    return np.array([n, e, 0.0])


def breach_result(report: dict[str, Any]) -> str:
    """The report's result, failed by a geofence breach: ``"geofence breach: ..."`` if the
    flight otherwise ended "ok" and breached the fence (a breach is never ok)."""
    result = str(report["result"])
    found = report.get("geofence_breaches") or []
    if result != "ok" or not (found or report.get("geofence_violations")):
        return result
    if not found:
        zones = ", ".join(report.get("geofence_violation_zones") or [])
        return f"geofence breach: {zones}"
    more = f" (+{len(found) - 1} more)" if len(found) > 1 else ""
    return f"geofence breach: {found[0]['message']}{more}"


def missed_result(report: dict[str, Any]) -> str:
    """The report's result, failed by missed waypoints: ``"missed N waypoint(s): item I by D m,
    ..."`` if the flight otherwise ended "ok" and passed a waypoint farther than its
    acceptance radius."""
    result = str(report["result"])
    missed = [w for w in report["waypoints"] if not w["reached"]]
    if result != "ok" or not missed:
        return result
    where = ", ".join(f"item {w['item_index']} by {w['closest_approach_m']:.1f} m"
                      for w in missed[:3])
    more = f" (+{len(missed) - 3} more)" if len(missed) > 3 else ""
    return f"missed {len(missed)} waypoint(s): {where}{more}"


@dataclass(frozen=True)
class ReplayRun:
    """One flight of a prepared mission: the flight, its log and its report (see summarize)."""

    flight: Flight
    log: FlightLog
    report: dict[str, Any]

    @property
    def ok(self) -> bool:
        """Completed inside the geofence and reached every waypoint."""
        return report_ok(self.report)


def report_ok(r: dict[str, Any]) -> bool:
    """A report's verdict: result "ok" (no abort, no geofence breach), every waypoint reached."""
    return bool(r["result"] == "ok" and r["waypoints_reached"] == len(r["waypoints"]))


def run_prepared(
    prep: PreparedMission,
    config: ReplayConfig,
    tlog: TlogWriter | None,
    progress: Callable[[float, float], None] | None = None,
) -> ReplayRun:
    """Fly a prepared mission in lockstep and summarise it (no files except `tlog`)."""
    schedule = prep.schedule
    wall0 = time.perf_counter()
    if tlog is not None:  # the mission first, so QGroundControl/MAVExplorer show it
        tlog.write_many(mission_frames(prep.mission), TLOG_EPOCH_S)
    flight, log = fly_schedule(config, schedule, prep.home, tlog, progress)
    wall = time.perf_counter() - wall0
    report = summarize(log, schedule, prep.mission, flight.origin, flight_plan=prep.flight_plan,
                       fence_shift_ned=fence_shift(config, flight.origin),
                       leg_bounds_s=prep.leg_bounds_s, bound_s=prep.bound_s)
    sim_s = flight.lk.now
    report.update(
        {
            "file": str(prep.path),
            "vehicle": config.vehicle,
            "mode": config.mode,
            "setpoint_rate_hz": config.rate_hz,
            "setpoints_sent": flight.setpoints_sent,
            "tlog_frames": tlog.frames if tlog is not None else None,
            "result": "ok" if flight.phase == Phase.DONE else f"aborted: {flight.reason}",
            "simulated_s": round(sim_s, 3),
            "wall_s": round(wall, 3),
            "real_time_factor": round(sim_s / wall, 1) if wall > 0 else None,
            "warnings": list(prep.warnings),
        }
    )
    if prep.px4 is not None:
        report["px4_params"] = prep.px4.as_report()
    report["setpoint_quality"] = flight.source.quality.report()
    report["result"] = breach_result(report)
    bad = flight.source.quality.failure()
    if bad is not None and report["result"] == "ok":
        report["result"] = f"setpoints: {bad}"

    report["ok"] = report_ok(report)
    if config.start_offset_ne_m != (0.0, 0.0):
        # the companion flew relative to where it stood; the mission's geodetic waypoints sit
        # at -offset in the vehicle's frame, this is how far the flight passed from them
        n, e = config.start_offset_ne_m
        pos = np.asarray(log.pos, dtype=np.float64).reshape(-1, 3)
        wps = schedule.waypoints_ned + flight.origin - np.array([n, e, 0.0])
        report["max_waypoint_miss_geo_m"] = (
            float(np.max(closest_approach(pos, wps))) if len(wps) else 0.0)
    return ReplayRun(flight, log, report)


def replay_file(
    path: str | os.PathLike[str],
    out_root: str | os.PathLike[str],
    config: ReplayConfig,
    progress: Callable[[float, float], None] | None = None,
    plotter: PlotWorker | None = None,
    *,
    plot: bool = True,
) -> ReplayResult:
    """Replay one mission file; writes `out_root/<name>/{flight.tlog, report.json, flight.png}`
    atomically (a temporary folder renamed at the end). Raises MissionError on a bad file.

    `plot` False writes no flight.png (and needs no matplotlib). `plotter` draws flight.png in
    its helper process (started before the flight, it has imported matplotlib by the time the
    figure is needed); None draws it here."""
    prep = prepare_mission(path, config)
    src, mission, schedule, home = prep.path, prep.mission, prep.schedule, prep.home
    name = src.stem
    out_root = Path(out_root)
    out_root.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{name}.", dir=out_root))
    try:
        with TlogWriter(tmp / "flight.tlog", buffer_bytes=1 << 20) as tlog:
            run = run_prepared(prep, config, tlog, progress)
        flight, log, report = run.flight, run.log, run.report
        report["tlog_frames"] = tlog.frames
        px4_log = None
        if config.compare_px4_mission:
            res, px4_log = fly_px4_mission(config, mission, home, schedule.duration_s)
            px4 = summarize(px4_log, schedule, mission, flight.origin,
                            flight_plan=prep.flight_plan,
                            fence_shift_ned=fence_shift(config, flight.origin))
            px4["result"] = res
            px4["result"] = breach_result(px4)
            px4["result"] = missed_result(px4)
            px4["ok"] = report_ok(px4)
            px4.pop("rms_error_m")
            px4.pop("max_error_m")
            report["px4_mission"] = px4
        with open(tmp / "report.json", "w", encoding="utf-8") as f:
            json.dump(report, f, indent=2, allow_nan=False, default=_json_default)
        if plot:
            data = plot_data(
                f"{src.name}: {config.vehicle}, {config.mode} mode",
                log,
                schedule,
                flight.origin,
                px4_log,
                report.get("legs"),
            )
            if plotter is not None:
                plotter.draw(tmp / "flight.png", data)
            else:
                draw_flight_png(tmp / "flight.png", data)
        final = out_root / name
        if final.exists():
            old = out_root / f".{name}.old"
            shutil.rmtree(old, ignore_errors=True)
            final.rename(old)
            tmp.rename(final)
            shutil.rmtree(old, ignore_errors=True)
        else:
            tmp.rename(final)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return ReplayResult(name=name, out_dir=final, report=report, ok=run.ok)


def _json_default(o: object) -> object:
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, float) and not math.isfinite(o):
        return None
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


__all__ = [
    "FlightLog",
    "LockstepLink",
    "MissionError",
    "Phase",
    "PreparedMission",
    "ReplayConfig",
    "ReplayResult",
    "ReplayRun",
    "fly_px4_mission",
    "fly_schedule",
    "missed_result",
    "mission_frames",
    "prepare_mission",
    "read_mock_params",
    "replay_file",
    "run_prepared",
    "summarize",
]
