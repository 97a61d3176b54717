"""The link half of the ``Vehicle`` façade: connect, receive and timer tasks, telemetry
streams, commands (mode, arm, takeoff, land) and parameter reads over the sans-IO
:class:`companion.mavlink.VehicleLink`. :class:`companion.aio.Vehicle` adds the offboard flight.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import time
from collections.abc import AsyncIterator, Callable, Sequence
from dataclasses import dataclass
from typing import Any, Literal

from companion.flight.tracking import TOUCHDOWN_TIMEOUT_S
from companion.mavlink import (
    ArmedChanged,
    Attitude,
    CommandFinished,
    ExtendedState,
    FlightMode,
    GlobalPosition,
    LinkConfig,
    LinkLost,
    LinkUp,
    LocalPosition,
    MissionTransferDone,
    ModeChanged,
    ParamReadDone,
    ParamType,
    StatusText,
    SystemStatus,
    TelemetrySnapshot,
    VehicleLink,
    raw_frame,
)
from companion.mavlink.commands import (
    MAV_CMD_COMPONENT_ARM_DISARM,
    MAV_CMD_DO_SET_MODE,
    MAV_CMD_NAV_LAND,
    MAV_CMD_NAV_TAKEOFF,
    MAV_CMD_SET_MESSAGE_INTERVAL,
    UnsolicitedAck,
)

from .broadcast import Broadcast
from .errors import (
    CommandError,
    ConnectTimeoutError,
    ModeChangeError,
    ParamReadError,
    VehicleError,
)
from .tlog import TlogWriter
from .transports import Transport, TransportError, open_transport
from .waits import bounded, wait_event

log = logging.getLogger("companion.aio")

MAV_STATE_CRITICAL = 5  # HEARTBEAT system_status while PX4 is in a failsafe
LANDED_STATE_ON_GROUND = 1  # EXTENDED_SYS_STATE landed_state (MAV_LANDED_STATE_ON_GROUND)
LOCAL_POSITION_NED_ID = 32  # MAVLink message id
#: Rate [Hz] `Vehicle.stream_position_fast` asks of LOCAL_POSITION_NED (PX4's default: 30).
POSITION_STREAM_HZ = 100.0
_CAN_NOT_ARM = {FlightMode.OFFBOARD, FlightMode.POSCTL, FlightMode.ALTCTL,
                FlightMode.STABILIZED, FlightMode.MANUAL, FlightMode.ACRO}


@dataclass(frozen=True)
class VehicleConfig:
    """Façade behaviour (seconds, metres, Hz)."""

    rate_hz: float = 100.0
    realtime_priority: int | None = 10  # SCHED_FIFO for the sender thread (Linux; None: off)
    stream_wait: Literal["sleep", "busy"] = "sleep"  # "busy": spin off the GIL (a whole core)
    stream_cpu: int | None = None  # pin the sender thread to this core
    prime_s: float = 0.5
    prime_timeout_s: float = 3.0
    stale_telemetry_s: float = 0.5
    stale_abort_s: float = 2.0
    connect_timeout_s: float = 10.0
    reconnect_timeout_s: float = 30.0
    max_start_error_m: float = 2.0
    settle_s: float = 2.0  # after the trajectory: keep streaming its end until within settle_m
    settle_m: float = 0.2
    armable_timeout_s: float = 15.0
    takeoff_timeout_s: float = 40.0
    land_timeout_s: float = 90.0
    touchdown_timeout_s: float = TOUCHDOWN_TIMEOUT_S  # end_action "touchdown": then LAND
    command_timeout_s: float = 15.0
    exit_action: str = "hold"  # "hold" or "land" on cancellation / signals
    tlog_path: str | None = None


class VehicleBase:
    """One PX4 link in asyncio: connection, telemetry, commands, parameters (the offboard
    flight is :class:`companion.aio.Vehicle`)."""

    def __init__(self, url: str, config: VehicleConfig | None = None,
                 link_config: LinkConfig | None = None) -> None:
        self.url = url
        self.config = config or VehicleConfig()
        self.link = VehicleLink(link_config)
        self.transport: Transport | None = None
        self.tlog: TlogWriter | None = None
        self._tasks: list[asyncio.Task[None]] = []
        self._cmd_waiters: dict[int, asyncio.Future[CommandFinished]] = {}
        self._mission_waiter: asyncio.Future[MissionTransferDone] | None = None
        self._param_waiter: asyncio.Future[ParamReadDone] | None = None
        self._wake = asyncio.Event()
        self._changed = asyncio.Event()
        self._link_up = asyncio.Event()
        self._snapshot = TelemetrySnapshot()
        self._closed = False
        self._flying = False
        self._link_lost_at: float | None = None
        self._pos_bc: Broadcast[LocalPosition] = Broadcast()
        self._att_bc: Broadcast[Attitude] = Broadcast()
        self._gpos_bc: Broadcast[GlobalPosition] = Broadcast()
        self._mode_bc: Broadcast[FlightMode] = Broadcast(8)
        self._armed_bc: Broadcast[bool] = Broadcast(8)
        self._text_bc: Broadcast[StatusText] = Broadcast(64)
        self._ack_bc: Broadcast[UnsolicitedAck] = Broadcast(64)
        self.last_status_text: StatusText | None = None

    # -- connection ---------------------------------------------------------------------------
    async def _open(self) -> None:
        self.link.advance_signing_clock(time.time())
        self.transport = await open_transport(self.url)
        if self.config.tlog_path:
            self.tlog = TlogWriter(self.config.tlog_path)
        loop = asyncio.get_running_loop()
        self._tasks = [loop.create_task(self._rx_loop(), name="mavlink-rx"),
                       loop.create_task(self._timer_loop(), name="mavlink-timer")]
        try:
            await bounded(self._link_up.wait(), self.config.connect_timeout_s)
        except TimeoutError:
            await self.close()
            raise ConnectTimeoutError(
                f"no vehicle heard on {self.url} within {self.config.connect_timeout_s:g} s: "
                f"no PX4 HEARTBEAT ({self._silence_hint()})") from None

    def _silence_hint(self) -> str:
        """Why no HEARTBEAT got through, as far as the signer saw (for the connect error)."""
        signer = self.link.codec.signer
        refused = {} if signer is None else {
            k: n for k, n in signer.stats.items() if k not in ("accepted", "unsigned_allowed")}
        if refused.get("unsigned"):
            return (f"{refused['unsigned']} unsigned frames dropped: the autopilot does not sign; "
                    "enable signing there with the same key, or connect without --signing-key")
        if refused.get("bad_signature"):
            return (f"{refused['bad_signature']} frames with a wrong signature dropped: "
                    "the signing keys differ")
        if refused:
            return "frames dropped by signing: " + ", ".join(f"{k} {n}" for k, n in refused.items())
        return "is the autopilot running and sending to this address?"

    async def close(self) -> None:
        """Stop tasks, close the transport and the .tlog (idempotent)."""
        if self._closed:
            return
        self._closed = True
        for t in self._tasks:
            t.cancel()
        for t in self._tasks:
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await t
        if self.transport is not None:
            self.transport.close()
        if self.tlog is not None:
            self.tlog.close()

    # -- plumbing -----------------------------------------------------------------------------
    def _flush(self) -> None:
        tr = self.transport
        for frame in self.link.frames_to_send():
            if tr is not None:
                tr.send(frame)
            if self.tlog is not None:
                self.tlog.write(frame)

    def send_float_array(self, name: str, array_id: int, data: Sequence[float]) -> None:
        """Send a DEBUG_FLOAT_ARRAY to the autopilot now (`VehicleLink.send_float_array`)."""
        self.link.send_float_array(name, array_id, data, time.monotonic())
        self._flush()

    def _dispatch(self, events: Sequence[Any]) -> None:
        for e in events:
            if isinstance(e, CommandFinished):
                fut = self._cmd_waiters.pop(e.command, None)
                if fut is not None and not fut.done():
                    fut.set_result(e)
            elif isinstance(e, MissionTransferDone):
                mw = self._mission_waiter
                if mw is not None and not mw.done():
                    mw.set_result(e)
            elif isinstance(e, ParamReadDone):
                pw = self._param_waiter
                if pw is not None and not pw.done():
                    pw.set_result(e)
            elif isinstance(e, LocalPosition):
                self._pos_bc.publish(e)
            elif isinstance(e, Attitude):
                self._att_bc.publish(e)
            elif isinstance(e, GlobalPosition):
                self._gpos_bc.publish(e)
            elif isinstance(e, ModeChanged):
                self._mode_bc.publish(e.new)
                log.info("flight mode %s", e.new.name)
            elif isinstance(e, ArmedChanged):
                self._armed_bc.publish(e.armed)
            elif isinstance(e, UnsolicitedAck):
                self._ack_bc.publish(e)
            elif isinstance(e, StatusText):
                self.last_status_text = e
                self._text_bc.publish(e)
                log.info("vehicle says [%d]: %s", e.severity, e.text)
            elif isinstance(e, LinkUp):
                self._link_up.set()
                self._link_lost_at = None
                if e.regained:
                    log.warning("link to the autopilot regained")
            elif isinstance(e, LinkLost):
                self._link_up.clear()
                self._link_lost_at = e.t_s
                log.warning("link to the autopilot lost (%.1f s silent)", e.silent_for_s)
        if events:
            self._snapshot = self.link.telemetry.snapshot()
            self._changed.set()

    async def _rx_loop(self) -> None:
        assert self.transport is not None
        codec = self.link.codec
        while True:
            try:
                data = await self.transport.recv()
            except TransportError as exc:
                log.warning("transport failed: %s; reconnecting", exc)
                self._dispatch(self.link.transport_lost(time.monotonic()))
                await self._reopen()
                continue
            now = time.monotonic()
            events: list[Any] = []
            for msg in codec.decode(data, datagram=self.transport.datagrams):
                if self.tlog is not None:
                    self.tlog.write(raw_frame(msg))
                events += self.link.handle_message(msg, now)
            self._dispatch(events)
            self._flush()

    async def _reopen(self) -> None:
        old = self.transport
        while not self._closed:
            await asyncio.sleep(1.0)
            try:
                new = await open_transport(self.url)
            except (TransportError, ValueError) as exc:
                log.info("reconnect failed: %s", exc)
                continue
            if old is not None:
                old.close()
            self.transport = new
            return

    async def _timer_loop(self) -> None:
        while True:
            now = time.monotonic()
            self.link.advance_signing_clock(time.time())
            self._dispatch(self.link.handle_timer(now))
            self._flush()
            deadline = self.link.get_timer()
            delay = 0.05 if deadline is None else min(max(deadline - time.monotonic(), 0.001), 0.05)
            self._wake.clear()
            await wait_event(self._wake, delay)

    async def _wait_for(self, cond: Callable[[], bool], timeout_s: float, what: str) -> None:
        """Wait until ``cond()`` holds (re-checked on every telemetry batch and every 50 ms)."""
        deadline = time.monotonic() + timeout_s
        while not cond():
            left = deadline - time.monotonic()
            if left <= 0:
                raise VehicleError(f"timed out after {timeout_s:g} s waiting for {what}")
            self._changed.clear()
            await wait_event(self._changed, min(left, 0.05))

    async def _command(self, start: Callable[[float], None], command: int, what: str,
                       *, check: bool = True, error: type[CommandError] = CommandError
                       ) -> CommandFinished:
        if command in self._cmd_waiters:
            raise VehicleError(f"{what}: the previous request is still pending")
        fut: asyncio.Future[CommandFinished] = asyncio.get_running_loop().create_future()
        self._cmd_waiters[command] = fut
        try:
            start(time.monotonic())
            self._flush()
            self._wake.set()
            fin = await bounded(fut, self.config.command_timeout_s)
        except (asyncio.CancelledError, TimeoutError):
            self.link.commands.cancel(command)
            raise
        finally:
            self._cmd_waiters.pop(command, None)
        if check and not fin.ok:
            raise error(command, fin.result, fin.reason, what)
        return fin

    # -- parameters -------------------------------------------------------------------------
    async def _read_params(self, names: Sequence[str], timeout_s: float,
                           expect: dict[str, ParamType] | None = None) -> ParamReadDone:
        if self._param_waiter is not None:
            raise VehicleError("a parameter read is already running")
        fut: asyncio.Future[ParamReadDone] = asyncio.get_running_loop().create_future()
        self._param_waiter = fut
        try:
            immediate = self.link.params.read(names, time.monotonic(), expect)
            self._flush()
            self._wake.set()
            return immediate[0] if immediate else await bounded(fut, timeout_s)
        except (asyncio.CancelledError, TimeoutError):
            self.link.params.cancel()
            raise
        finally:
            self._param_waiter = None

    async def fetch_params(self, names: Sequence[str], timeout_s: float = 10.0, *,
                           floats_only: bool = False) -> ParamReadDone:
        """Read PX4 parameters by name (PARAM_REQUEST_READ, 3 tries 0.5 s apart each) without
        raising for missing or (``floats_only``: not REAL32) wrong-typed ones: the
        :class:`ParamReadDone` says which (a ``ParamReader`` of
        :func:`companion.planning.vehicle_params.read_planning_params`). TimeoutError after
        ``timeout_s`` [s]."""
        expect = {n: ParamType.REAL32 for n in names} if floats_only else None
        return await self._read_params(names, timeout_s, expect)

    async def read_params(self, names: Sequence[str], timeout_s: float = 10.0,
                          *, floats_only: bool = False) -> dict[str, float]:
        """Read PX4 parameters by name (PARAM_REQUEST_READ, 3 tries 0.5 s apart each); returns
        {name: value}. Raises ParamReadError naming every parameter that never came back (or,
        with ``floats_only``, came back as another type than REAL32), TimeoutError after
        ``timeout_s`` [s]."""
        expect = {n: ParamType.REAL32 for n in names} if floats_only else None
        done = await self._read_params(names, timeout_s, expect)
        if not done.ok:
            raise ParamReadError(done.values, done.missing, done.wrong_type, done.problem())
        return done.values

    # -- state --------------------------------------------------------------------------------
    @property
    def telemetry(self) -> TelemetrySnapshot:
        """Latest telemetry snapshot."""
        return self._snapshot

    @property
    def mode(self) -> FlightMode | None:
        """Current flight mode from the HEARTBEAT."""
        return self.link.mode

    @property
    def is_armed(self) -> bool:
        """Armed flag from the HEARTBEAT."""
        return self.link.armed

    @property
    def link_ok(self) -> bool:
        """True while autopilot heartbeats arrive."""
        return self._link_up.is_set()

    # -- telemetry streams ------------------------------------------------------------------
    def position(self) -> AsyncIterator[LocalPosition]:
        """Local NED position/velocity updates."""
        return self._pos_bc.stream()

    def attitude(self) -> AsyncIterator[Attitude]:
        """Attitude quaternion / body-rate updates."""
        return self._att_bc.stream()

    def command_acks(self) -> AsyncIterator[UnsolicitedAck]:
        """COMMAND_ACKs from the autopilot that answer none of our commands (a module's)."""
        return self._ack_bc.stream()

    def global_position(self) -> AsyncIterator[GlobalPosition]:
        """GLOBAL_POSITION_INT updates."""
        return self._gpos_bc.stream()

    def flight_mode(self) -> AsyncIterator[FlightMode]:
        """Current mode, then every change."""
        return self._mode_bc.stream(self.mode)

    def armed(self) -> AsyncIterator[bool]:
        """Current armed state, then every change."""
        return self._armed_bc.stream(self.is_armed if self.mode is not None else None)

    def status_text(self) -> AsyncIterator[StatusText]:
        """STATUSTEXT messages (chunks reassembled)."""
        return self._text_bc.stream()

    # -- commands -----------------------------------------------------------------------------
    async def set_mode(self, mode: FlightMode) -> None:
        """Change flight mode; raises ModeChangeError with the deciding MAV_RESULT."""
        await self._command(lambda now: self.link.set_mode(mode, now), MAV_CMD_DO_SET_MODE,
                            f"switch to {mode.name}", error=ModeChangeError)

    async def set_message_interval(self, message_id: int, rate_hz: float) -> None:
        """Ask the autopilot to stream MAVLink message ``message_id`` at ``rate_hz`` (0 stops
        it); raises CommandError when refused (PX4 refuses it for HEARTBEAT)."""
        if not (math.isfinite(rate_hz) and rate_hz >= 0.0):
            raise ValueError(f"rate must be a finite number of Hz >= 0, got {rate_hz}")
        interval = -1.0 if rate_hz == 0.0 else 1e6 / rate_hz
        await self._command(lambda now: self.link.set_message_interval(message_id, interval, now),
                            MAV_CMD_SET_MESSAGE_INTERVAL, f"stream message {message_id}")

    async def stream_position_fast(self, rate_hz: float = POSITION_STREAM_HZ) -> str | None:
        """Ask for LOCAL_POSITION_NED at `rate_hz` (`fly` and `serve` do in attitude mode,
        whose loop closes on it): between PX4's default 30 Hz samples the controller's
        extrapolation drifts from the vehicle's true motion, and each new sample stepped the
        velocity feedback (thrust steps of up to 0.055 between setpoints 10 ms apart at the
        corners of an 8 m/s square on real PX4 SITL; 0.031 at 100 Hz). Rates mode stays at the
        default: on the mock at 100 Hz its figure-8 error doubled (0.04 -> 0.08 m RMS), cause
        not found. Returns None, or what was refused (the flight goes on at the default
        rate)."""
        try:
            await self.set_message_interval(LOCAL_POSITION_NED_ID, rate_hz)
        except (VehicleError, TimeoutError) as exc:
            return (f"LOCAL_POSITION_NED at {rate_hz:g} Hz refused ({exc}): flying on the "
                    "default rate")
        return None

    async def hold(self) -> None:
        """Switch to Hold (AUTO.LOITER)."""
        await self.set_mode(FlightMode.HOLD)

    def _armable(self) -> bool:
        st: SystemStatus | None = self.link.telemetry.sys_status
        return (st is None or st.armable) and self.link.telemetry.position is not None

    async def wait_armable(self) -> None:
        """Wait (up to ``armable_timeout_s``) until the vehicle reports it is ready to arm and
        sends its local position."""
        await self._wait_for(self._armable, self.config.armable_timeout_s,
                             "the vehicle to be ready to arm (estimator / preflight checks)")

    async def arm(self, force: bool = False, keep_mode: bool = False) -> None:
        """Arm (after the vehicle reports it is armable); switches to Hold first if the current
        mode cannot arm without RC (PX4 returns to OFFBOARD/POSCTL after a landing), unless
        `keep_mode` (arming in OFFBOARD with an onboard module's offboard stream)."""
        if self.is_armed:
            return
        await self.wait_armable()
        if self.mode in _CAN_NOT_ARM and not keep_mode:
            await self.set_mode(FlightMode.HOLD)
        await self._command(lambda now: self.link.arm(now, force), MAV_CMD_COMPONENT_ARM_DISARM,
                            "arming")
        await self._wait_for(lambda: self.is_armed, 3.0, "the HEARTBEAT to show armed")

    async def disarm(self, force: bool = False) -> None:
        """Disarm."""
        await self._command(lambda now: self.link.disarm(now, force),
                            MAV_CMD_COMPONENT_ARM_DISARM, "disarming")

    async def takeoff(self, alt_m: float = 2.5, wait: bool = True) -> None:
        """NAV_TAKEOFF to ``alt_m`` above the current position; waits until the vehicle is within
        max(0.3 m, 10 %) of it and the climb has ended (AUTO.TAKEOFF left, or |vz| < 0.2 m/s), or
        until PX4 itself ended the takeoff (AUTO.TAKEOFF left, |vz| < 0.2 m/s) within its own
        acceptance, NAV_MC_ALT_RAD (0.8 m by default): its target is AMSL from the global
        altitude, which EKF2 may put 0.3 m or more off the local frame, and SIH's takeoff then
        ended 2.6-2.8 m above the start of a 3 m one (this waited until its timeout)."""
        tel = self.link.telemetry
        pos0 = tel.position
        alt_amsl = math.nan
        if tel.global_position is not None:
            alt_amsl = tel.global_position.alt_amsl_m + alt_m
        await self._command(lambda now: self.link.takeoff(now, alt_amsl), MAV_CMD_NAV_TAKEOFF,
                            "takeoff")
        if not wait or pos0 is None:
            return
        z_goal = pos0.pos_ned[2] - alt_m + max(0.3, 0.1 * alt_m)
        z_px4 = pos0.pos_ned[2] - alt_m + max(0.8, 0.1 * alt_m)  # NAV_MC_ALT_RAD's default

        def done() -> bool:
            # near the altitude, and the climb finished (PX4 leaves AUTO.TAKEOFF for Hold)
            p = self.link.telemetry.position
            if p is None:
                return False
            still = abs(p.vel_ned[2]) < 0.2
            left = self.mode is not None and self.mode is not FlightMode.TAKEOFF
            return ((p.pos_ned[2] <= z_goal and (left or still))
                    or (p.pos_ned[2] <= z_px4 and left and still))

        await self._wait_for(done, self.config.takeoff_timeout_s, f"the takeoff to {alt_m:g} m")

    async def land(self, wait: bool = True, disarm_when_landed: bool = True) -> None:
        """NAV_LAND here (unless already in LAND); waits until landed and disarmed.

        disarm_when_landed: disarm as soon as PX4's land detector reports the vehicle on the
        ground (EXTENDED_SYS_STATE), instead of waiting COM_DISARM_LAND for PX4's own
        auto-disarm; PX4 refuses a disarm that is not forced unless it has detected the
        landing, and a refusal leaves the wait for the auto-disarm."""
        if self.mode is not FlightMode.LAND:
            await self._command(self.link.land, MAV_CMD_NAV_LAND, "landing")
        if not wait:
            return

        def on_ground() -> bool:
            ext: ExtendedState | None = self.link.telemetry.extended
            return ext is not None and ext.landed_state == LANDED_STATE_ON_GROUND

        def landed() -> bool:
            ext: ExtendedState | None = self.link.telemetry.extended
            return not self.is_armed and (ext is None or ext.landed_state == LANDED_STATE_ON_GROUND)

        deadline = time.monotonic() + self.config.land_timeout_s
        if disarm_when_landed:
            await self._wait_for(lambda: not self.is_armed or on_ground(),
                                 self.config.land_timeout_s, "the landing")
            if self.is_armed:
                try:
                    await self.disarm()
                except CommandError as exc:  # not landed after all: PX4 disarms on its own
                    log.warning("disarm after landing refused (%s): waiting for PX4's "
                                "auto-disarm", exc)
        await self._wait_for(landed, max(0.1, deadline - time.monotonic()), "landing and disarm")

    async def exit_action(self, action: str | None = None) -> None:
        """The configured safe action (Hold or Land), best effort, bounded in time."""
        act = action or self.config.exit_action
        mode = FlightMode.LAND if act == "land" else FlightMode.HOLD
        if self.mode is mode:
            return
        try:
            await bounded(self.set_mode(mode), 5.0)
        except (VehicleError, TimeoutError) as exc:
            log.error("could not switch to %s on exit: %s", mode.name, exc)
