"""The replay's flight: the one flight sequence (`companion.flight.FlightSequence`) driven over
the `LockstepLink` (`Flight`, `fly_schedule`), and the same mission flown in the mock's own
AUTO.MISSION for comparison (`fly_px4_mission`).

The companion side follows PX4's offboard protocol exactly as on a real vehicle: wait for a
healthy vehicle, stream setpoints for 0.5 s (priming), switch to OFFBOARD, arm, fly the planned
schedule, then land as `fly` does: in attitude and rates mode touch down itself
(`companion.flight.tracking.Touchdown`), in position mode hand over to PX4's NAV_LAND (a loiter
ending: Hold), and disarm once PX4 reports the vehicle on the ground.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, Protocol

import numpy as np

from companion._frozen import frozen_new
from companion.aio.tlog import TlogWriter
from companion.control import Reference
from companion.flight.clock import FlightClock
from companion.flight.policy import ROVER_SETTLE_S, handover_mode, plan_touchdown
from companion.flight.policy import stall_s as policy_stall_s
from companion.flight.report import SetpointLimits
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
from companion.flight.summary import FlightLog, record_message
from companion.flight.tracking import SetpointMode, Touchdown, TrackingSource
from companion.mavlink.commands import (
    MAV_CMD_COMPONENT_ARM_DISARM,
    MAV_CMD_DO_SET_MODE,
    MAV_CMD_NAV_LAND,
    CommandFinished,
)
from companion.mavlink.link import LinkConfig, VehicleLink
from companion.mavlink.mission_client import MissionTransferDone, item_to_msg
from companion.mavlink.px4_mode import FlightMode
from companion.mavlink.setpoints import (
    AttitudeSetpoint,
    PositionSetpoint,
    RatesSetpoint,
    SetpointCommand,
)
from companion.mission import Mission, mission_upload_items
from companion.planning.schedule import Schedule
from companion.replay.config import (
    EXPECTED_OVERHEAD_S,
    PRIME_S,
    SETTLE_S,
    ReplayConfig,
    self_lands,
)
from companion.replay.lockstep import UNREAD_STREAMS, LockstepLink, make_sim


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
        # a rover's reference waits for it (ProgressGovernor): it ends within the last
        # waypoint's acceptance radius, or ROVER_SETTLE_S after its reference ended (as `fly`)
        self._rover_end = rover and len(schedule.waypoints_ned) > 0
        end_ned = (tuple(float(x) for x in schedule.waypoints_ned[-1])
                   if self._rover_end else None)
        self.seq = FlightSequence(SequenceConfig(
            rate_hz=config.rate_hz, duration_s=schedule.duration_s, prime_s=PRIME_S,
            end=EndPolicy(
                handover_mode=handover_mode(config.vehicle, schedule.final_action),
                touchdown_from_s=None if self.touchdown is None else self.touchdown.from_s,
                settle_s=ROVER_SETTLE_S if self._rover_end else SETTLE_S,
                settle_m=float(schedule.acceptance_m[-1]) if self._rover_end else None,
                stall_s=policy_stall_s(config.vehicle, config.mode),
                end_ned=end_ned,  # type: ignore[arg-type]
                disarm_at_hold=rover, disarm_on_ground=not rover)))
        # the sequence and the reference run on flight time, which follows the autopilot's
        # clock as `fly`'s does (FlightClock): a mock slowed by SIM_SPEED_FACTOR slows them
        # with it; at full speed flight time is the lockstep clock to the bit
        self.fclock = FlightClock()
        self._times: list[tuple[float, float]] = []  # (flight time, lockstep time) [s]
        self._plan_end: float | None = None  # the sequence's plan end fly_t1 was taken from
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

    def _flight_now(self, now: float) -> float:
        """Flight time [s] at lockstep time `now` [s] (FlightClock on the newest position)."""
        pos = self.link.telemetry.position
        if pos is not None:
            self.fclock.observe(pos.time_boot_s, pos.t_s)
        f = self.fclock.now(now)
        self._times.append((f, now))
        return f

    def _lockstep_time(self, flight_s: float) -> float:
        """The lockstep time [s] at which flight time was `flight_s` [s] (the same while flight
        time never lagged)."""
        if self.fclock.lag_s == 0.0:
            return flight_s
        f, n = zip(*self._times, strict=True)
        return float(np.interp(flight_s, f, n))

    def _reference(self, t_s: float) -> Reference:
        return self.schedule.reference(t_s, origin=self.origin)

    def _stream(self, t_s: float | None, now: float, flight_now: float) -> None:
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
            object.__setattr__(snap, "link_rtt_s", self.link.rtt_s)
            sp = self.source(t_s, snap)
            t_ref = self.source.reference_time_s
            if t_ref is not None:
                self.log.ref_clock.append((now, t_ref))
        self.lk.to_vehicle([self.link.encode_setpoint(sp, now)])
        self.seq.on_setpoint_sent(flight_now)
        self.setpoints_sent += 1
        if isinstance(sp, (AttitudeSetpoint, RatesSetpoint)):
            self.log.thrust_norm.append(sp.thrust_norm)

    def perform(self, actions: list[SequenceAction], now: float, flight_now: float) -> None:
        """Carry out the sequence's actions over the lockstep link at lockstep time `now` [s]
        (`flight_now`: the sequence's flight time then)."""
        link = self.link
        for a in actions:
            if isinstance(a, Stream):
                self._stream(a.t_s, now, flight_now)
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
        end = self.seq.t_plan_end
        if end is not None and end != self._plan_end:
            self._plan_end = end
            self.log.fly_t1 = self._lockstep_time(end)

    def on_events(self, events: list[Any], now: float) -> None:
        """Command results from the link."""
        for ev in events:
            if isinstance(ev, CommandFinished):
                f = self._flight_now(now)
                self.perform(self.seq.on_command_result(ev.command, ev.ok, ev.reason, f,
                                                        ev.result), now, f)

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
        rel: tuple[float, float, float] | None = None
        if self._rover_end and tel.position is not None:  # relative to the plan's origin
            p = tel.position.pos_ned
            o = self.origin
            rel = (p[0] - float(o[0]), p[1] - float(o[1]), p[2] - float(o[2]))
        view = frozen_new(  # VehicleView(...) without its frozen __init__ (every cycle)
            VehicleView,
            link_ok=self.link.heartbeat.link_up, armed=armed, mode=self.link.mode,
            ready=have_state and st is not None and st.armable, have_state=have_state,
            on_ground=ext is not None and ext.landed_state == 1, pos_ned=rel,
            traj_time_s=self.source.reference_time_s, arrived=self.source.arrived,
            stalled_s=self.source.stalled_s, blind_s=self.source.blind_s)
        f = self._flight_now(now)
        self.perform(self.seq.update(f, view), now, f)

    def late_s(self) -> float:
        """How late the reference runs [s]: a multirotor's reference slowed down for the
        vehicle (TimeScaler) moves the deadline with it, and so does flight time's lag behind a
        slow autopilot clock; a reference that stands still ends the flight itself
        (STALL_S)."""
        return float(getattr(self.source.governor, "delay_s", 0.0)) + self.fclock.lag_s

    def abort(self, now: float, reason: str) -> None:
        """End the flight (the replay's time limit)."""
        f = self._flight_now(now)
        self.perform(self.seq.fail(f, reason), now, f)



def recorded_link(config: ReplayConfig, home: tuple[float, float, float],
                  tlog: TlogWriter | None) -> tuple[LockstepLink, FlightLog]:
    """A fresh mock for `config` and the companion's link to it, every message recorded into
    a new flight log (without a tlog the streams nobody reads are not built: `UNREAD_STREAMS`)."""
    sim = make_sim(config, home, unread=UNREAD_STREAMS if tlog is None else frozenset())
    log = FlightLog(boot_clock=sim.autopilot.clock_segments())
    lk = LockstepLink(sim, VehicleLink(LinkConfig()), tlog)
    lk.on_message = functools.partial(record_message, log)
    return lk, log


def fly_schedule(
    config: ReplayConfig,
    schedule: Schedule,
    home: tuple[float, float, float],
    tlog: TlogWriter | None,
    progress: Callable[[float, float], None] | None = None,
) -> tuple[Flight, FlightLog]:
    """Fly `schedule` in lockstep against a fresh mock; returns the flight and its log.

    `progress(now_s, expected_s)` is called every 100 setpoint cycles with the simulated time
    and the expected end of the flight (the schedule plus the start-up and landing). Without
    a tlog the mock leaves the streams the companion does not read unbuilt (the same flight,
    bit for bit: `UNREAD_STREAMS`)."""
    lk, log = recorded_link(config, home, tlog)
    flight = Flight(config, schedule, lk, log)
    drive(flight, lk, config, schedule.duration_s, progress)
    return flight, log


class Driven(Protocol):
    """A companion flight `drive` runs: the link's events in, one cycle per period."""

    @property
    def done(self) -> bool: ...
    def late_s(self) -> float: ...
    def on_events(self, events: list[Any], now: float) -> None: ...
    def tick(self, now: float) -> None: ...
    def abort(self, now: float, reason: str) -> None: ...


def drive(flight: Driven, lk: LockstepLink, config: ReplayConfig, duration_s: float,
          progress: Callable[[float, float], None] | None) -> None:
    """Run `flight` over `lk` in cycles of 1 / `config.rate_hz` until it is done or late
    (`duration_s` + the config's margin + `flight.late_s()`), then 1 s more for the last
    frames and the landing; `progress(now_s, expected_s)` every 100 cycles."""
    dt = 1.0 / config.rate_hz
    t_max = duration_s + config.timeout_margin_s
    expected = duration_s + EXPECTED_OVERHEAD_S
    k = 0
    while not flight.done:
        k += 1
        now = k * dt
        late = flight.late_s()
        if now > t_max + late:
            flight.abort(now, f"timed out after {t_max + late:.0f} s of simulated time")
            break
        flight.on_events(lk.advance(now), now)
        flight.tick(now)
        if progress is not None and k % 100 == 0:
            progress(now, max(expected, now))
    # let the last frames out and record the landing
    end = lk.now + 1.0
    while lk.now < end:
        lk.advance(lk.now + dt)


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
    sim = make_sim(config, home)
    link = VehicleLink(LinkConfig())
    log = FlightLog(boot_clock=sim.autopilot.clock_segments())
    lk = LockstepLink(sim, link, None)
    lk.on_message = functools.partial(record_message, log)
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

