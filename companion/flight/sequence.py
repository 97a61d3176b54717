"""The one flight sequence, sans-IO: wait for a ready vehicle, prime the setpoint stream,
OFFBOARD, arm, fly the trajectory, then touch down (disarm once PX4 reports the vehicle on the
ground) or hand over to a PX4 mode (Hold or Land), and disarm.

Built on :class:`companion.mavlink.OffboardMachine` (its state says whether setpoints stream).
Nothing here reads a clock or does I/O: the caller feeds

- :meth:`FlightSequence.update` once per cycle with the time [s] and a :class:`VehicleView`;
- :meth:`FlightSequence.on_command_result` with each finished command (ack / HEARTBEAT);
- :meth:`FlightSequence.on_setpoint_sent` with the send time of every setpoint;

and performs the actions returned, in order: :class:`Stream` (send one setpoint now: replay
sends it, a fixed-rate sender thread streams on its own while :attr:`FlightSequence.streaming`),
:class:`SendCommand`, :class:`PhaseChanged`, :class:`Finished`. Used by the lockstep replay
(`companion.replay.runner`), by `Vehicle.fly` (`companion.aio`), which `fly` drives, and by
`serve` (`companion.serve.service`), one sequence per OFFBOARD entry of the pilot
(:attr:`SequenceConfig.pilot_start`; serve streams its own setpoints and ignores :class:`Stream`).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

from companion.mavlink.commands import (
    MAV_CMD_COMPONENT_ARM_DISARM,
    MAV_CMD_DO_SET_MODE,
    MAV_CMD_NAV_LAND,
)
from companion.mavlink.offboard import OffboardMachine, OffboardTrigger
from companion.mavlink.px4_mode import FlightMode

from .policy import BLIND_S, TOUCHDOWN_TIMEOUT_S

__all__ = [
    "EndPolicy", "Failure", "Finished", "FlightSequence", "Phase", "PhaseChanged",
    "SendCommand", "SequenceAction", "SequenceConfig", "Stream", "VehicleView",
]


class Phase(enum.Enum):
    """Where the flight is."""

    WAIT_READY = "wait_ready"  # vehicle not ready (estimator, preflight checks, telemetry)
    PRIME = "prime"  # streaming, OFFBOARD not requested yet
    REQUEST_OFFBOARD = "request_offboard"  # DO_SET_MODE(OFFBOARD) pending
    ARM = "arm"  # ARM pending (in OFFBOARD, streaming)
    CONFIRM_ARM = "confirm_arm"  # ARM accepted, waiting for the HEARTBEAT to show it
    FLY = "fly"  # the trajectory (then the touchdown) is flown
    HANDOVER = "handover"  # the end mode requested
    WAIT_DISARM = "wait_disarm"  # landing / disarming under PX4
    DONE = "done"
    FAILED = "failed"


class Failure(enum.Enum):
    """Why a flight failed."""

    PRIME_TIMEOUT = "prime_timeout"
    OFFBOARD_REFUSED = "offboard_refused"
    ARM_REFUSED = "arm_refused"
    LEFT_OFFBOARD = "left_offboard"
    LINK_LOST = "link_lost"
    NO_LAND = "no_land"
    DISARM_REFUSED = "disarm_refused"  # disarming in Hold (a rover) refused
    ABORTED = "aborted"  # by the caller (timeout, cancellation)
    BLIND = "blind"  # the tracking law flew its hover fallback too long: handed over to PX4


@dataclass(frozen=True)
class VehicleView:
    """What the sequence sees of the vehicle in one cycle."""

    link_ok: bool = True
    armed: bool = False  # HEARTBEAT
    mode: FlightMode | None = None  # HEARTBEAT
    ready: bool = True  # armable, with position and attitude telemetry (leaves WAIT_READY)
    have_state: bool = True  # position and attitude known: no setpoint is streamed without
    on_ground: bool = False  # EXTENDED_SYS_STATE landed_state ON_GROUND
    pos_ned: tuple[float, float, float] | None = None  # local position [m NED]
    # the trajectory's own time [s] when the setpoint source governs it (it waits for a vehicle
    # that falls behind, e.g. `TrackingSource` in rover mode); None: flight time since it began
    traj_time_s: float | None = None
    # the source says the vehicle has reached (or passed: a car cannot back up) the stop its
    # reference is at: with the trajectory's time at its end, the flight is complete
    arrived: bool = False
    # how long [s] the source's governed reference has stood still waiting for the vehicle
    stalled_s: float = 0.0
    # how long [s] the source's tracking law has flown its hover fallback without a break
    blind_s: float = 0.0


@dataclass(frozen=True)
class Stream:
    """Send one setpoint now: the trajectory at time ``t_s`` [s] (None: the start point, the
    trajectory's time is not running yet)."""

    t_s: float | None


@dataclass(frozen=True)
class SendCommand:
    """Send a MAVLink command: ``command`` is a ``MAV_CMD_*`` of companion.mavlink.commands;
    ``mode`` for DO_SET_MODE, ``arm`` for COMPONENT_ARM_DISARM."""

    command: int
    mode: FlightMode | None = None
    arm: bool | None = None

    @classmethod
    def set_mode(cls, mode: FlightMode) -> SendCommand:
        """DO_SET_MODE(mode)."""
        return cls(MAV_CMD_DO_SET_MODE, mode=mode)

    @classmethod
    def arm_disarm(cls, arm: bool) -> SendCommand:
        """COMPONENT_ARM_DISARM (never forced)."""
        return cls(MAV_CMD_COMPONENT_ARM_DISARM, arm=arm)

    @classmethod
    def land(cls) -> SendCommand:
        """NAV_LAND where the vehicle is."""
        return cls(MAV_CMD_NAV_LAND)


@dataclass(frozen=True)
class PhaseChanged:
    """The sequence moved from ``old`` to ``new`` at ``t_s`` [s]."""

    t_s: float
    old: Phase
    new: Phase
    reason: str = ""


@dataclass(frozen=True)
class Finished:
    """The flight ended: ``ok``, or ``failure`` with a pilot-readable ``reason`` and, for a
    refused command, its MAV_RESULT (``result``)."""

    t_s: float
    ok: bool
    reason: str = ""
    failure: Failure | None = None
    result: int | None = None


SequenceAction = Stream | SendCommand | PhaseChanged | Finished


@dataclass(frozen=True)
class EndPolicy:
    """How a flight ends after its trajectory (build it with :mod:`companion.flight.policy`).

    touchdown_from_s: the companion touches down itself from this trajectory time [s] on: it
    keeps streaming, disarms once PX4 reports the vehicle on the ground and finishes when the
    HEARTBEAT shows disarmed; PX4's LAND after ``touchdown_timeout_s`` without (or after a
    refused disarm, or a disarm not shown within ``disarm_confirm_s``). None: after the
    trajectory (plus ``settle_s``, or earlier once within ``settle_m`` of ``end_ned``) the
    flight hands over to ``handover_mode``.
    land_command: LAND is requested by NAV_LAND (else DO_SET_MODE AUTO.LAND).
    stream_handover: keep streaming until the handover command finished (PX4 sees no offboard
    loss while it switches); else the stream stops when it is sent.
    land_and_disarm: after the handover wait for the mode (``mode_wait_s``), then for the
    landing and disarm (a quad is disarmed once on the ground; ``disarm_at_hold``: a rover is
    disarmed once in Hold); else the flight is done when the handover command finished.
    land_timeout_s: after the handover the landing and disarm must end within this long [s]
    from the vehicle being in LAND (or the disarm in Hold being sent), else the flight fails
    (NO_LAND); None: no limit (the caller bounds the flight).
    handover_retry_s: with ``land_and_disarm`` False and ``stream_handover`` False: send the
    handover command again this often [s] while the HEARTBEAT still shows OFFBOARD (its results
    are not needed); the flight is done once the HEARTBEAT shows another mode. None: sent once.
    stall_s: hand over when the source's governed reference has stood still this long [s]
    (``VehicleView.stalled_s``: a vehicle that makes no progress, e.g. a stuck rover); None:
    never. blind_s: hand over when the source's tracking law has flown its hover fallback this
    long [s] (``VehicleView.blind_s``: telemetry stale or missing); None: never."""

    handover_mode: FlightMode = FlightMode.HOLD
    touchdown_from_s: float | None = None
    touchdown_timeout_s: float = TOUCHDOWN_TIMEOUT_S
    disarm_confirm_s: float = 3.0
    settle_s: float = 0.0
    settle_m: float | None = None
    end_ned: tuple[float, float, float] | None = None
    land_command: bool = True
    stream_handover: bool = False
    land_and_disarm: bool = True
    disarm_at_hold: bool = False
    disarm_on_ground: bool = True
    mode_wait_s: float = 3.0
    land_timeout_s: float | None = None
    handover_retry_s: float | None = None
    stall_s: float | None = None
    blind_s: float | None = BLIND_S


@dataclass(frozen=True)
class SequenceConfig:
    """rate_hz: setpoint rate [Hz]; prime_s: streaming before OFFBOARD is requested [s] (at
    least 90 % of the expected setpoints, no gap); arm: arm in OFFBOARD (else the vehicle is
    already armed); confirm_arm_s: after an accepted ARM wait at most this long for the
    HEARTBEAT to show armed before the trajectory's time starts (None: the ack starts it);
    duration_s: the trajectory [s]; pilot_start: the pilot switches to OFFBOARD (serve): the
    trajectory's time starts when the HEARTBEAT first shows OFFBOARD, nothing is primed,
    requested or armed (the caller streams)."""

    rate_hz: float
    duration_s: float
    end: EndPolicy = EndPolicy()
    prime_s: float = 0.5
    prime_timeout_s: float = 3.0
    arm: bool = True
    confirm_arm_s: float | None = None
    pilot_start: bool = False


_STREAM_PHASES = frozenset({Phase.PRIME, Phase.REQUEST_OFFBOARD, Phase.ARM, Phase.CONFIRM_ARM,
                            Phase.FLY, Phase.HANDOVER})


class FlightSequence:
    """The flight sequence (see the module docstring). ``t_fly0`` is when the trajectory's
    time started, ``t_plan_end`` when tracking the plan ended (left OFFBOARD, the touchdown
    began, the handover), ``reason`` why it ended."""

    def __init__(self, config: SequenceConfig) -> None:
        self.config = config
        self.end = config.end
        self.machine = OffboardMachine(config.rate_hz, config.prime_s)
        self.phase = Phase.WAIT_READY
        self.t_phase = 0.0
        self.t_fly0: float | None = None
        self.t_plan_end: float | None = None
        self.reason = ""
        self.failure: Failure | None = None
        self._fault: tuple[Failure, str] | None = None  # a handover for a fault (BLIND)
        self.offboard_seen = False
        self.disarm_sent = False
        self._t_disarm_ack: float | None = None
        self._handover_cmd: int | None = None
        self._handover_mode = FlightMode.HOLD
        self._t_handover_sent = 0.0
        self._t_traj_end: float | None = None  # when the trajectory's time reached its end

    # -- state --------------------------------------------------------------------------------
    @property
    def streaming(self) -> bool:
        """Setpoints must be sent now."""
        return self.machine.streaming

    @property
    def finished(self) -> bool:
        """DONE or FAILED."""
        return self.phase in (Phase.DONE, Phase.FAILED)

    def trajectory_time(self, now: float) -> float | None:
        """Trajectory time [s] at ``now`` (None before it started)."""
        return None if self.t_fly0 is None else now - self.t_fly0

    # -- transitions --------------------------------------------------------------------------
    def _go(self, phase: Phase, now: float, reason: str = "") -> list[SequenceAction]:
        old = self.phase
        self.phase = phase
        self.t_phase = now
        if reason:
            self.reason = reason
        return [PhaseChanged(now, old, phase, reason)]

    def _finish(self, now: float, reason: str = "", failure: Failure | None = None,
                result: int | None = None) -> list[SequenceAction]:
        if failure is None and self._fault is not None:  # a handover for a fault ends failed
            failure = self._fault[0]
            reason = self._fault[1] + (f"; {reason}" if reason else "")
        out = self._go(Phase.FAILED if failure is not None else Phase.DONE, now, reason)
        self.failure = failure
        self.machine.stop(now, reason or "done")
        return [*out, Finished(now, failure is None, reason, failure, result)]

    def fail(self, now: float, reason: str, failure: Failure = Failure.ABORTED
             ) -> list[SequenceAction]:
        """End the flight from outside (a timeout, a cancellation); no-op once finished."""
        if self.finished:
            return []
        return self._finish(now, reason, failure)

    # -- inputs -------------------------------------------------------------------------------
    def on_setpoint_sent(self, t: float) -> None:
        """A setpoint left at ``t`` [s]."""
        self.machine.on_setpoint_sent(t)

    def on_command_result(self, command: int, ok: bool, reason: str, now: float,
                          result: int | None = None) -> list[SequenceAction]:
        """A command finished (``ok``: accepted, and for a mode change HEARTBEAT-confirmed)."""
        ph = self.phase
        if ph is Phase.REQUEST_OFFBOARD and command == MAV_CMD_DO_SET_MODE:
            self.machine.on_mode_result(ok, now, reason)
            if not ok:
                return self._finish(now, f"OFFBOARD refused: {reason}",
                                    Failure.OFFBOARD_REFUSED, result)
            if not self.config.arm:
                return self._start_fly(now)
            out = self._go(Phase.ARM, now)
            return [*out, SendCommand.arm_disarm(True)]
        if ph is Phase.ARM and command == MAV_CMD_COMPONENT_ARM_DISARM:
            if not ok:
                return self._finish(now, f"arming refused: {reason}", Failure.ARM_REFUSED, result)
            if self.config.confirm_arm_s is not None:
                return self._go(Phase.CONFIRM_ARM, now)
            return self._start_fly(now)
        if ph is Phase.FLY and command == MAV_CMD_COMPONENT_ARM_DISARM and self.disarm_sent:
            if ok:
                self._t_disarm_ack = now
                return []
            return self._handover(now, FlightMode.LAND, f"disarm refused: {reason}")
        if (ph is Phase.WAIT_DISARM and command == MAV_CMD_COMPONENT_ARM_DISARM and not ok
                and self.end.disarm_at_hold):
            return self._finish(now, f"disarm refused: {reason}", Failure.DISARM_REFUSED, result)
        if ph is Phase.HANDOVER and command == self._handover_cmd and self.machine.streaming:
            self.machine.stop(now, "handed over")  # the stream ran on while PX4 switched
            if not self.end.land_and_disarm:
                return self._finish(now, "" if ok else f"handover failed: {reason}")
        return []

    def _start_fly(self, now: float) -> list[SequenceAction]:
        self.t_fly0 = now
        return self._go(Phase.FLY, now)

    def update(self, now: float, view: VehicleView) -> list[SequenceAction]:
        """One cycle at ``now`` [s]."""
        if view.mode is FlightMode.OFFBOARD:
            self.offboard_seen = True
        ph = self.phase
        if ph is Phase.WAIT_READY:
            if self.config.pilot_start:
                if view.mode is not FlightMode.OFFBOARD:
                    return []
                self.machine.fire(OffboardTrigger.PILOT_ENTERED_OFFBOARD, now,
                                  "pilot entered OFFBOARD")
                return self._start_fly(now)
            if view.ready and view.mode is not None:
                self.machine.start(now)
                return self._go(Phase.PRIME, now)
            return []
        if self.finished:
            return []
        if not view.link_ok and self.machine.streaming:
            self.machine.on_link_lost(now)
            return self._finish(now, "link lost", Failure.LINK_LOST)
        if ph in (Phase.HANDOVER, Phase.WAIT_DISARM) and not self.machine.streaming:
            return self._after_handover(now, view)
        if not view.have_state:
            return []
        out: list[SequenceAction] = []
        if ph is Phase.FLY:
            if self.disarm_sent and not view.armed:
                return self._finish(now)  # landed and disarmed by the companion
            if self.offboard_seen and view.mode is not FlightMode.OFFBOARD:
                # pilot takeover or failsafe: stop streaming, never fight back
                self.t_plan_end = now
                self.machine.on_heartbeat_offboard(False, now)
                name = view.mode.name if view.mode is not None else "unknown"
                return self._finish(now, f"vehicle left OFFBOARD (now {name})",
                                    Failure.LEFT_OFFBOARD)
        assert self.t_fly0 is not None or ph is not Phase.FLY
        out.append(Stream(None if ph is not Phase.FLY or self.t_fly0 is None
                          else now - self.t_fly0))
        if ph is Phase.PRIME:
            if self._primed(now):
                self.machine.fire(OffboardTrigger.REQUEST, now, "OFFBOARD requested")
                out += self._go(Phase.REQUEST_OFFBOARD, now)
                out.append(SendCommand.set_mode(FlightMode.OFFBOARD))
            elif now - self.t_phase > self.config.prime_timeout_s:
                out += self._finish(now, f"could not prime the setpoint stream at "
                                    f"{self.config.rate_hz:g} Hz", Failure.PRIME_TIMEOUT)
        elif ph is Phase.CONFIRM_ARM:
            assert self.config.confirm_arm_s is not None
            if view.armed:
                out += self._start_fly(now)
            elif now - self.t_phase > self.config.confirm_arm_s:
                out += self._finish(now, f"arming not shown by the HEARTBEAT within "
                                    f"{self.config.confirm_arm_s:g} s", Failure.ARM_REFUSED)
        elif ph is Phase.FLY:
            out += self._fly_end(now, view)
        return out

    def _primed(self, now: float) -> bool:
        """Streamed for prime_s since PRIME began, without a gap, >= 90 % of the setpoints."""
        m = self.machine
        last = m.last_sent_s
        return (now - self.t_phase >= self.config.prime_s and last is not None
                and now - last <= m.max_gap_s and m.run_count >= m.min_count)

    def _fly_end(self, now: float, view: VehicleView) -> list[SequenceAction]:
        assert self.t_fly0 is not None
        end = self.end
        t = now - self.t_fly0
        if end.blind_s is not None and view.blind_s >= end.blind_s:
            why = (f"tracking blind for {view.blind_s:.1f} s (telemetry stale or missing): "
                   f"handed over to PX4's {end.handover_mode.name}")
            self._fault = (Failure.BLIND, why)
            return self._handover(now, end.handover_mode, why)
        if end.touchdown_from_s is not None:
            # a governed reference (slowed down for the vehicle) reaches the touchdown later
            late = (t if view.traj_time_s is None else view.traj_time_s) - end.touchdown_from_s
            if late < 0.0:
                return []
            if not self.disarm_sent and view.on_ground:
                self.disarm_sent = True
                # tracking ends where the touchdown began (it is not plan tracking)
                self.t_plan_end = self.t_fly0 + end.touchdown_from_s + (
                    0.0 if view.traj_time_s is None else t - view.traj_time_s)
                return [SendCommand.arm_disarm(False)]
            if late >= end.touchdown_timeout_s:  # no landing seen, or no disarm
                return self._handover(now, FlightMode.LAND,
                                      f"no landing detected after {late:.0f} s")
            ack = self._t_disarm_ack
            if ack is not None and now - ack > end.disarm_confirm_s:
                return self._handover(now, FlightMode.LAND, "disarm not shown by the HEARTBEAT")
            return []
        if end.stall_s is not None and view.stalled_s >= end.stall_s:
            return self._handover(now, end.handover_mode,
                                  f"no progress for {view.stalled_s:.0f} s: the vehicle does not "
                                  "follow its reference")
        if view.traj_time_s is not None:  # governed: settle_s counts from its end
            t = view.traj_time_s
            if self._t_traj_end is None and t >= self.config.duration_s:
                self._t_traj_end = now
            settled = self._t_traj_end is not None and now - self._t_traj_end >= end.settle_s
        else:
            settled = now - self.t_fly0 >= self.config.duration_s + end.settle_s
        if t < self.config.duration_s and not settled:
            return []
        if view.arrived:
            return self._handover(now, end.handover_mode, "trajectory complete")
        if end.settle_m is not None and end.end_ned is not None and view.pos_ned is not None:
            d = math.dist(view.pos_ned, end.end_ned)
            if d <= end.settle_m:
                return self._handover(now, end.handover_mode,
                                      f"trajectory complete, {d:.2f} m from its end")
        if settled:
            why = "trajectory complete"
            if end.settle_m is not None and end.end_ned is not None and view.pos_ned is not None:
                why = (f"trajectory complete, {math.dist(view.pos_ned, end.end_ned):.1f} m from "
                       f"its end after {end.settle_s:g} s")
            return self._handover(now, end.handover_mode, why)
        return []

    def _handover(self, now: float, mode: FlightMode, why: str) -> list[SequenceAction]:
        out = self._go(Phase.HANDOVER, now, why)
        self.t_plan_end = now
        if not self.end.stream_handover:
            self.machine.stop(now, why)
        cmd = self._handover_command(mode)
        self._handover_mode = mode
        self._handover_cmd = cmd.command
        self._t_handover_sent = now
        return [*out, cmd]

    def _handover_command(self, mode: FlightMode) -> SendCommand:
        if mode is FlightMode.LAND and self.end.land_command:
            return SendCommand.land()
        return SendCommand.set_mode(mode)

    def _retry_handover(self, now: float, view: VehicleView) -> list[SequenceAction]:
        """EndPolicy.handover_retry_s: again while still in OFFBOARD, done once out of it."""
        retry = self.end.handover_retry_s
        if retry is None or view.mode is None:
            return []
        if view.mode is not FlightMode.OFFBOARD:
            return self._finish(now, f"handed over (now {view.mode.name})")
        if now - self._t_handover_sent >= retry:
            self._t_handover_sent = now
            return [self._handover_command(self._handover_mode)]
        return []

    def _after_handover(self, now: float, view: VehicleView) -> list[SequenceAction]:
        if not self.end.land_and_disarm:
            return self._retry_handover(now, view)
        if self.phase is Phase.HANDOVER:
            if self._handover_mode is not FlightMode.LAND:
                if view.mode is self._handover_mode or now - self.t_phase > self.end.mode_wait_s:
                    if self.end.disarm_at_hold:
                        return [SendCommand.arm_disarm(False), *self._go(Phase.WAIT_DISARM, now)]
                    return self._finish(now)
            elif view.mode is FlightMode.LAND:
                return self._go(Phase.WAIT_DISARM, now)
            elif (now - self.t_phase > self.end.mode_wait_s
                  and self._handover_cmd != MAV_CMD_NAV_LAND):
                # AUTO.LAND by DO_SET_MODE did not take: NAV_LAND once more (as `land()` would)
                self._handover_cmd = MAV_CMD_NAV_LAND
                self.t_phase = now
                return [SendCommand.land()]
            elif now - self.t_phase > self.end.mode_wait_s:
                return self._finish(now, "PX4 did not switch to LAND", Failure.NO_LAND)
            return []
        if not view.armed:
            return self._finish(now)
        limit = self.end.land_timeout_s
        if limit is not None and now - self.t_phase > limit:
            return self._finish(now, f"timed out after {limit:g} s waiting for the landing and "
                                "disarm", Failure.NO_LAND)
        if self.end.disarm_on_ground and not self.disarm_sent and view.on_ground:
            self.disarm_sent = True
            return [SendCommand.arm_disarm(False)]
        return []
