"""The ``Vehicle`` façade: connect, arm, takeoff, fly a trajectory in OFFBOARD, land.

    async with Vehicle.connect("udpin://0.0.0.0:14540") as v:
        await v.arm()
        await v.takeoff(2.5)
        await v.fly(trajectory, mode="position")
        await v.land()

Thin asyncio adapter over the sans-IO :class:`companion.mavlink.VehicleLink`: a receive task
feeds bytes in, a timer task runs retries/heartbeats, a sender thread streams setpoints at a
fixed rate during ``fly``. Safety: OFFBOARD is requested once, only after the stream is primed;
if the vehicle leaves OFFBOARD the stream stops and ``OffboardExitedError`` is raised (never
re-requested); stale position telemetry -> hold setpoint, then Hold mode; link loss -> stop
streaming, wait for the link, raise ``LinkLostError``; cancellation (SIGINT/SIGTERM via
:func:`safe_exit`) -> Hold or Land before returning.
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import dataclasses
import logging
import math
import signal
import time
from collections.abc import AsyncIterator, Awaitable, Callable, Generator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Generic, Literal, TypeVar

from companion.flight.sequence import (
    EndPolicy,
    Failure,
    Finished,
    FlightSequence,
    Phase,
    PhaseChanged,
    SendCommand,
    SequenceAction,
    SequenceConfig,
    VehicleView,
)
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
    MissionResult,
    MissionTransferDone,
    ModeChanged,
    OffboardMachine,
    OffboardState,
    ParamReadDone,
    ParamType,
    PositionSetpoint,
    SetpointCommand,
    StatusText,
    SystemStatus,
    TelemetrySnapshot,
    VehicleLink,
    WireMissionItem,
    raw_frame,
)
from companion.mavlink.commands import (
    MAV_CMD_COMPONENT_ARM_DISARM,
    MAV_CMD_DO_SET_MODE,
    MAV_CMD_NAV_LAND,
    MAV_CMD_NAV_TAKEOFF,
    MAV_CMD_SET_MESSAGE_INTERVAL,
)
from companion.mission.px4_params import PLANNING_PARAM_NAMES
from companion.planning.vehicle_params import ResolvedPlanningParams, resolve_planning_params

from .errors import (
    CommandError,
    ConnectTimeoutError,
    LinkLostError,
    MissionTransferError,
    ModeChangeError,
    OffboardError,
    OffboardExitedError,
    ParamReadError,
    SetpointSourceError,
    TelemetryStaleError,
    VehicleError,
)
from .sources import SetpointSource, TrajectoryLike, TrajectoryPositionSource, hold_setpoint
from .streamer import FixedRateStreamer, StreamStats
from .tlog import TlogWriter
from .transports import Transport, TransportError, open_transport

log = logging.getLogger("companion.aio")

T = TypeVar("T")
MODES = ("position", "attitude", "rates", "rover")
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


@dataclass(frozen=True)
class FlightReport:
    """Outcome of a completed ``fly``."""

    mode: str
    duration_s: float
    stream: StreamStats
    held_at_end: bool


class _Broadcast(Generic[T]):
    """Fan-out of values to ``async for`` subscribers (each keeps the latest ``maxsize``)."""

    def __init__(self, maxsize: int = 1) -> None:
        self._subs: set[asyncio.Queue[T]] = set()
        self._maxsize = maxsize

    def publish(self, value: T) -> None:
        for q in self._subs:
            if q.full():
                with contextlib.suppress(asyncio.QueueEmpty):
                    q.get_nowait()
            q.put_nowait(value)

    async def stream(self, initial: T | None = None) -> AsyncIterator[T]:
        q: asyncio.Queue[T] = asyncio.Queue(self._maxsize)
        if initial is not None:
            q.put_nowait(initial)
        self._subs.add(q)
        try:
            while True:
                yield await q.get()
        finally:
            self._subs.discard(q)


async def _bounded(aw: Awaitable[T], timeout_s: float) -> T:
    """``await aw`` with a timeout (TimeoutError). Unlike ``asyncio.wait_for`` on Python 3.11,
    ``asyncio.timeout`` never swallows an outside cancellation that races with completion (a
    lost cancellation would make SIGINT handling miss)."""
    async with asyncio.timeout(timeout_s):
        return await aw


async def _wait_event(ev: asyncio.Event, timeout_s: float) -> None:
    """Wait for ``ev`` at most ``timeout_s`` (no error on timeout)."""
    with contextlib.suppress(TimeoutError):
        async with asyncio.timeout(timeout_s):
            await ev.wait()


def _as_item(obj: Any) -> WireMissionItem:
    if isinstance(obj, WireMissionItem):
        return obj
    fields = [f.name for f in dataclasses.fields(WireMissionItem)]
    return WireMissionItem(**{f: getattr(obj, f) for f in fields if hasattr(obj, f)})


class MissionAPI:
    """``vehicle.mission``: upload / download / clear / start."""

    def __init__(self, vehicle: Vehicle) -> None:
        self._v = vehicle

    async def _run(self, start: Callable[[float], list[MissionTransferDone]],
                   timeout_s: float = 30.0) -> MissionTransferDone:
        v = self._v
        if v._mission_waiter is not None:
            raise VehicleError("a mission transfer is already running")
        fut: asyncio.Future[MissionTransferDone] = asyncio.get_running_loop().create_future()
        v._mission_waiter = fut
        try:
            immediate = start(time.monotonic())
            v._flush()
            v._wake.set()
            done = immediate[0] if immediate else await _bounded(fut, timeout_s)
        except (asyncio.CancelledError, TimeoutError):
            v._dispatch(v.link.mission.cancel(time.monotonic()))
            v._flush()
            raise
        finally:
            v._mission_waiter = None
        if done.result is not MissionResult.SUCCESS:
            raise MissionTransferError(done.operation, done.result, done.mav_result, done.detail)
        return done

    async def upload(self, items: Sequence[Any], mission_type: int = 0) -> None:
        """Upload MISSION_ITEM_INT items (``WireMissionItem``, e.g.
        ``companion.mission.mission_upload_items(mission)``, or objects with the same fields).
        :class:`MissionTransferError` if the vehicle refuses or stops answering."""
        its = [_as_item(i) for i in items]
        await self._run(lambda now: self._v.link.mission.upload(its, now, mission_type))

    async def download(self, mission_type: int = 0) -> list[WireMissionItem]:
        """Download the vehicle's mission (``companion.mission.mission_from_wire`` makes it a
        ``Mission``)."""
        done = await self._run(lambda now: self._v.link.mission.download(now, mission_type))
        return list(done.items)

    async def clear(self, mission_type: int = 0) -> None:
        """Clear the vehicle's mission."""
        await self._run(lambda now: self._v.link.mission.clear(now, mission_type))

    async def start(self) -> None:
        """Switch to AUTO.MISSION."""
        await self._v.set_mode(FlightMode.MISSION)


class _Connect:
    """Result of ``Vehicle.connect``: ``await`` it or use it as ``async with``."""

    def __init__(self, vehicle: Vehicle) -> None:
        self._vehicle = vehicle

    def __await__(self) -> Generator[Any, None, Vehicle]:
        return self._open().__await__()

    async def _open(self) -> Vehicle:
        await self._vehicle._open()
        return self._vehicle

    async def __aenter__(self) -> Vehicle:
        return await self._open()

    async def __aexit__(self, *exc: object) -> None:
        await self._vehicle.close()


class Vehicle:
    """Asyncio façade over one PX4 link (see module doc)."""

    def __init__(self, url: str, config: VehicleConfig | None = None,
                 link_config: LinkConfig | None = None) -> None:
        self.url = url
        self.config = config or VehicleConfig()
        self.link = VehicleLink(link_config)
        self.mission = MissionAPI(self)
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
        self._pos_bc: _Broadcast[LocalPosition] = _Broadcast()
        self._att_bc: _Broadcast[Attitude] = _Broadcast()
        self._gpos_bc: _Broadcast[GlobalPosition] = _Broadcast()
        self._mode_bc: _Broadcast[FlightMode] = _Broadcast(8)
        self._armed_bc: _Broadcast[bool] = _Broadcast(8)
        self._text_bc: _Broadcast[StatusText] = _Broadcast(64)
        self.last_status_text: StatusText | None = None

    # -- connection ---------------------------------------------------------------------------
    @classmethod
    def connect(cls, url: str, *, config: VehicleConfig | None = None,
                link_config: LinkConfig | None = None) -> _Connect:
        """Open ``url`` and wait for the autopilot HEARTBEAT (``await`` or ``async with``)."""
        return _Connect(cls(url, config, link_config))

    async def _open(self) -> None:
        self.link.advance_signing_clock(time.time())
        self.transport = await open_transport(self.url)
        if self.config.tlog_path:
            self.tlog = TlogWriter(self.config.tlog_path)
        loop = asyncio.get_running_loop()
        self._tasks = [loop.create_task(self._rx_loop(), name="mavlink-rx"),
                       loop.create_task(self._timer_loop(), name="mavlink-timer")]
        try:
            await _bounded(self._link_up.wait(), self.config.connect_timeout_s)
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
            await _wait_event(self._wake, delay)

    async def _wait_for(self, cond: Callable[[], bool], timeout_s: float, what: str) -> None:
        """Wait until ``cond()`` holds (re-checked on every telemetry batch and every 50 ms)."""
        deadline = time.monotonic() + timeout_s
        while not cond():
            left = deadline - time.monotonic()
            if left <= 0:
                raise VehicleError(f"timed out after {timeout_s:g} s waiting for {what}")
            self._changed.clear()
            await _wait_event(self._changed, min(left, 0.05))

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
            fin = await _bounded(fut, self.config.command_timeout_s)
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
            return immediate[0] if immediate else await _bounded(fut, timeout_s)
        except (asyncio.CancelledError, TimeoutError):
            self.link.params.cancel()
            raise
        finally:
            self._param_waiter = None

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

    async def read_planning_params(self, overrides: Mapping[str, float] | None = None,
                                   timeout_s: float = 10.0) -> ResolvedPlanningParams:
        """The PX4 parameters the mission planner uses (``PLANNING_PARAM_NAMES``, all REAL32 in
        PX4), read from the vehicle (names not answered are asked for once more) and combined
        with the vehicle file's ``[px4]`` overrides:
        ``.params`` is the :class:`Px4PlanningParams` to plan with, ``.warnings`` names the
        parameters the vehicle did not have (PX4's default used; see
        :mod:`companion.planning.vehicle_params` for the policy). ValueError for a value the planner
        cannot use (wrong type, out of range) unless overridden."""
        names = list(PLANNING_PARAM_NAMES)
        expect = {n: ParamType.REAL32 for n in names}
        done = await self._read_params(names, timeout_s, expect)
        values, wrong = dict(done.values), dict(done.wrong_type)
        if done.missing:  # a second pass: tells a lossy link from a parameter PX4 lacks
            again = await self._read_params(done.missing, timeout_s, expect)
            values.update(again.values)
            wrong.update(again.wrong_type)
        resolved = resolve_planning_params(values, overrides, wrong_type=wrong)
        for w in resolved.warnings:
            log.warning("%s", w)
        return resolved

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

    async def arm(self, force: bool = False) -> None:
        """Arm (after the vehicle reports it is armable); switches to Hold first if the current
        mode cannot arm without RC (PX4 returns to OFFBOARD/POSCTL after a landing)."""
        if self.is_armed:
            return
        await self.wait_armable()
        if self.mode in _CAN_NOT_ARM:
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
        max(0.3 m, 10 %) of it and the climb has ended (AUTO.TAKEOFF left, or |vz| < 0.2 m/s)."""
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

        def done() -> bool:
            # near the altitude, and the climb finished (PX4 leaves AUTO.TAKEOFF for Hold)
            p = self.link.telemetry.position
            return (p is not None and p.pos_ned[2] <= z_goal
                    and (self.mode is not FlightMode.TAKEOFF or abs(p.vel_ned[2]) < 0.2))

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
            await _bounded(self.set_mode(mode), 5.0)
        except (VehicleError, TimeoutError) as exc:
            log.error("could not switch to %s on exit: %s", mode.name, exc)

    # -- offboard flight ------------------------------------------------------------------------
    async def fly(self, trajectory: TrajectoryLike | None = None, *, mode: str = "position",
                  setpoint_source: SetpointSource | None = None, rate_hz: float | None = None,
                  duration_s: float | None = None, feedforward: str = "acc",
                  arm: bool = False, end_action: str = "hold") -> FlightReport:
        """Fly ``trajectory`` (or ``setpoint_source`` for ``duration_s``) in OFFBOARD, then Hold
        (or Land).

        mode: "position" (built-in: trajectory -> SET_POSITION_TARGET_LOCAL_NED), or
        "attitude" / "rates" / "rover" with a ``setpoint_source`` (see ``sources``). The
        stream is primed for ``prime_s`` before OFFBOARD is requested once.
        arm: the vehicle is disarmed on the ground; it is switched to OFFBOARD disarmed (PX4
        accepts that with a live stream) and armed there, and the trajectory's time starts
        when the HEARTBEAT shows armed: the setpoints fly the takeoff.
        end_action: "hold" or "land": the mode requested, still streaming, when the trajectory
        is complete. "touchdown": the source lands the vehicle itself after ``duration_s``
        (e.g. a ``TrackingSource`` with a ``Touchdown``): the stream goes on until PX4 reports
        the vehicle on the ground (EXTENDED_SYS_STATE), then it is disarmed while still
        streaming; without a detected landing within ``touchdown_timeout_s``, or if the disarm
        is refused, PX4's LAND is requested (and finishes the landing).
        """
        if mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
        if end_action not in ("hold", "land", "touchdown"):
            raise ValueError(f"end_action must be 'hold', 'land' or 'touchdown', "
                             f"got {end_action!r}")
        if end_action == "touchdown" and not math.isfinite(duration_s or math.inf):
            raise ValueError("end_action 'touchdown' needs a finite duration_s")
        if arm:
            ext = self.link.telemetry.extended
            if self.is_armed:
                raise VehicleError("fly(arm=True) takes off from the ground, but the vehicle "
                                   "is already armed")
            if ext is not None and ext.landed_state not in (0, LANDED_STATE_ON_GROUND):
                raise VehicleError("fly(arm=True): the vehicle is not reported on the ground")
        if self._flying:
            raise VehicleError("already flying a trajectory")
        if not self.link_ok:
            raise LinkLostError("no link to the autopilot", regained=False)
        snap = self.link.telemetry.snapshot()
        now = time.monotonic()
        if snap.position is None or now - snap.position.t_s > self.config.stale_telemetry_s:
            raise TelemetryStaleError("no fresh local position from the vehicle: cannot fly")
        source: SetpointSource
        if setpoint_source is not None:
            source = setpoint_source
        elif trajectory is not None and mode in ("position",):
            yaw0 = hold_setpoint(snap)
            source = TrajectoryPositionSource(
                trajectory, yaw=None if yaw0 is None else yaw0.yaw, feedforward=feedforward)
        else:
            raise ValueError(f"mode {mode!r} needs a setpoint_source (e.g. from companion.control)")
        total = duration_s if duration_s is not None else (
            float(trajectory.duration) if trajectory is not None else math.inf)
        if trajectory is not None:
            p0 = trajectory.evaluate(0.0, 0)
            d = math.dist((float(p0[0]), float(p0[1]), float(p0[2])), snap.position.pos_ned)
            if d > self.config.max_start_error_m:
                raise VehicleError(
                    f"trajectory starts {d:.1f} m from the vehicle (limit "
                    f"{self.config.max_start_error_m:g} m): fly there first")
        self._flying = True
        try:
            end_pos: tuple[float, float, float] | None = None
            if trajectory is not None and math.isfinite(total):
                pe = trajectory.evaluate(total, 0)
                end_pos = (float(pe[0]), float(pe[1]), float(pe[2]))
            return await self._fly(source, mode, rate_hz or self.config.rate_hz, total, end_pos,
                                   arm, FlightMode.HOLD if end_action == "hold" else
                                   FlightMode.LAND, end_action == "touchdown")
        finally:
            self._flying = False

    async def _fly(self, source: SetpointSource, mode: str, rate: float, total_s: float,
                   end_pos: tuple[float, float, float] | None, arm: bool = False,
                   end_mode: FlightMode = FlightMode.HOLD,
                   touchdown: bool = False) -> FlightReport:
        """Drive the one flight sequence (`companion.flight.FlightSequence`) in real time: a
        sender thread streams while it says so, its commands are sent and their results fed
        back; stale telemetry and a failing source are handled here (hold, then Hold)."""
        cfg = self.config
        seq = FlightSequence(SequenceConfig(
            rate_hz=rate, duration_s=total_s, prime_s=cfg.prime_s,
            prime_timeout_s=cfg.prime_timeout_s, arm=arm, confirm_arm_s=3.0,
            end=EndPolicy(handover_mode=end_mode,
                          touchdown_from_s=total_s if touchdown else None,
                          touchdown_timeout_s=cfg.touchdown_timeout_s,
                          settle_s=cfg.settle_s if end_pos is not None else 0.0,
                          settle_m=cfg.settle_m, end_ned=end_pos, land_command=False,
                          stream_handover=True, land_and_disarm=False)))
        sm = seq.machine
        state: dict[str, Any] = {"hold": None, "error": ""}
        link = self.link

        def producer(now: float) -> bytes | None:
            snap = dataclasses.replace(self._snapshot, now_s=now)
            hold: PositionSetpoint | None = state["hold"]
            if hold is None:
                t0 = seq.t_fly0
                t = 0.0 if t0 is None else now - t0
                try:
                    sp: SetpointCommand = source(t, snap)
                    return link.encode_setpoint(sp, now)
                except Exception as exc:  # invalid setpoint: hold instead, never send it
                    state["error"] = f"{type(exc).__name__}: {exc}"
                    hold = hold_setpoint(snap)
                    state["hold"] = hold
                    if hold is None:
                        raise
            return link.encode_setpoint(hold, now)

        wall_minus_mono = time.time() - time.monotonic()

        def on_sent(frame: bytes, t_send: float) -> None:
            if self.tlog is not None:  # stamped with the send time, not the (later) log time
                self.tlog.write(frame, t_send + wall_minus_mono)

        assert self.transport is not None

        def send(frame: bytes) -> bool:
            tr = self.transport
            return tr is not None and tr.send(frame)

        def target() -> tuple[int, bytes] | None:
            tr = self.transport
            return None if tr is None else tr.datagram_target()

        streamer = FixedRateStreamer(rate, send, producer, target=target, on_sent=on_sent,
                                     realtime_priority=cfg.realtime_priority,
                                     wait=cfg.stream_wait, cpu=cfg.stream_cpu)
        results: collections.deque[tuple[int, bool, str, int | None]] = collections.deque()
        tasks: list[asyncio.Task[None]] = []

        async def run_command(a: SendCommand) -> None:
            fin = await self._send_command(a)
            results.append(fin)
            self._changed.set()

        def pump() -> None:
            while streamer.sent_times:
                seq.on_setpoint_sent(streamer.sent_times.popleft())

        t_start = time.monotonic()
        stale_since: float | None = None
        done: Finished | None = None
        try:
            # the sequence's priming starts with the first setpoint sent
            now = await self._first_setpoint(streamer, state, rate)
            while done is None:
                actions: list[SequenceAction] = []
                while results:
                    command, ok, reason, result = results.popleft()
                    actions += seq.on_command_result(command, ok, reason, now, result)
                actions += seq.update(now, self._flight_view())
                for act in actions:
                    if isinstance(act, SendCommand):
                        tasks.append(asyncio.get_running_loop().create_task(run_command(act)))
                    elif isinstance(act, Finished):
                        done = act
                    elif isinstance(act, PhaseChanged):
                        if act.new is Phase.REQUEST_OFFBOARD:
                            log.info("stream primed (%d setpoints); requesting OFFBOARD",
                                     streamer.sent)
                        elif act.new is Phase.ARM:
                            log.info("OFFBOARD active (%s mode, %g Hz)", mode, rate)
                        elif act.new is Phase.FLY:
                            if not arm:
                                log.info("OFFBOARD active (%s mode, %g Hz)", mode, rate)
                            t_start = now
                        elif act.new is Phase.HANDOVER:
                            log.info("%s: switching to %s", act.reason,
                                     (FlightMode.LAND if seq.disarm_sent or touchdown
                                      else end_mode).name)
                if not seq.streaming:
                    streamer.stop()
                if done is not None:
                    break
                if state["error"]:
                    if seq.phase is not Phase.FLY:
                        raise SetpointSourceError(f"setpoint source failed: {state['error']}")
                    await self._hold_and_stop(streamer, sm, "invalid setpoint")
                    raise SetpointSourceError(
                        f"setpoint source failed ({state['error']}); vehicle told to hold")
                if seq.phase is Phase.FLY:
                    stale_since = await self._check_stale(streamer, sm, state, stale_since,
                                                          now)
                self._changed.clear()
                await _wait_event(self._changed, 0.02)
                pump()
                now = time.monotonic()
            await self._fly_failed(done, streamer, rate)
        except asyncio.CancelledError:
            if sm.state in (OffboardState.ACTIVE, OffboardState.REQUESTED):
                state["hold"] = hold_setpoint(self._snapshot) or state["hold"]
                await asyncio.shield(self.exit_action())
            raise
        finally:
            streamer.stop()
            pump()
            sm.stop(time.monotonic(), "fly() ended")
            for task in tasks:
                task.cancel()
        if seq.reason.startswith("handover failed"):
            log.error("%s", seq.reason)
        elif seq.disarm_sent and not self.is_armed:
            log.info("landed and disarmed")
        return FlightReport(mode, time.monotonic() - t_start, streamer.stats(), True)

    async def _first_setpoint(self, streamer: FixedRateStreamer, state: dict[str, Any],
                              rate: float) -> float:
        """Start the stream; the send time of its first setpoint [s, monotonic]."""
        streamer.start()
        t_wait = time.monotonic()
        while not streamer.sent_times:
            if state["error"]:
                raise SetpointSourceError(f"setpoint source failed: {state['error']}")
            if time.monotonic() - t_wait > self.config.prime_timeout_s:
                raise OffboardError(f"could not prime the setpoint stream at {rate:g} Hz "
                                    f"(sent {streamer.sent}, last error "
                                    f"{streamer.last_error or 'none'})")
            await asyncio.sleep(0.005)
        return streamer.sent_times[0]

    def _flight_view(self) -> VehicleView:
        """The vehicle as the flight sequence sees it now."""
        tel = self.link.telemetry
        ext: ExtendedState | None = tel.extended
        pos = tel.position
        return VehicleView(
            link_ok=self._link_lost_at is None and self.link_ok, armed=self.is_armed,
            mode=self.mode,
            on_ground=ext is not None and ext.landed_state == LANDED_STATE_ON_GROUND,
            pos_ned=None if pos is None else pos.pos_ned)

    async def _send_command(self, a: SendCommand) -> tuple[int, bool, str, int | None]:
        """Send one command of the flight sequence; (command, ok, reason, MAV_RESULT)."""
        link = self.link
        start: Callable[[float], None]
        if a.command == MAV_CMD_DO_SET_MODE and a.mode is not None:
            mode = a.mode
            start, what = (lambda now: link.set_mode(mode, now)), f"switch to {mode.name}"
        elif a.command == MAV_CMD_COMPONENT_ARM_DISARM:
            start = (lambda now: link.arm(now, False)) if a.arm else (
                lambda now: link.disarm(now, False))
            what = "arming in OFFBOARD" if a.arm else "disarming"
        else:
            start, what = link.land, "landing"
        try:
            fin = await self._command(start, a.command, what, check=False)
        except (VehicleError, TimeoutError) as exc:
            return a.command, False, f"{what}: {exc or 'no answer'}", None
        return a.command, fin.ok, fin.reason, fin.result

    async def _check_stale(self, streamer: FixedRateStreamer, sm: OffboardMachine,
                           state: dict[str, Any], stale_since: float | None,
                           now: float) -> float | None:
        """Stale position telemetry: hold the last position, then Hold and raise."""
        cfg = self.config
        pos = self.link.telemetry.position
        age = math.inf if pos is None else now - pos.t_s
        if age > cfg.stale_telemetry_s:
            if stale_since is None:
                stale_since = now
                state["hold"] = hold_setpoint(self._snapshot)
                log.warning("position telemetry stale (%.2f s): holding", age)
            rx = self.link.heartbeat.last_rx_s
            link_talking = rx is not None and now - rx <= cfg.stale_telemetry_s
            # a silent link is left to the link-loss path (declared after 3 s)
            if now - stale_since > cfg.stale_abort_s and link_talking:
                await self._hold_and_stop(streamer, sm, "stale telemetry")
                raise TelemetryStaleError(
                    f"no position telemetry for {age:.1f} s; vehicle told to hold")
        elif stale_since is not None:
            await self._hold_and_stop(streamer, sm, "telemetry was stale")
            raise TelemetryStaleError("position telemetry was interrupted; vehicle told "
                                      "to hold")
        return stale_since

    async def _fly_failed(self, done: Finished | None, streamer: FixedRateStreamer,
                          rate: float) -> None:
        """Raise the error of a failed flight (after its clean-up); nothing if it went well."""
        if done is None or done.ok:
            return
        streamer.stop()
        why = done.failure
        if why is Failure.LINK_LOST:
            await self._after_link_loss()
        if why is Failure.PRIME_TIMEOUT:
            raise OffboardError(f"could not prime the setpoint stream at {rate:g} Hz "
                                f"(sent {streamer.sent}, last error "
                                f"{streamer.last_error or 'none'})")
        if why is Failure.OFFBOARD_REFUSED:
            text = self.last_status_text.text if self.last_status_text else ""
            raise OffboardError(done.reason + (f" (vehicle: {text})" if text else ""),
                                done.result)
        if why is Failure.ARM_REFUSED:
            # still disarmed: back to Hold, so a later ``arm`` works; armed late (the
            # HEARTBEAT came after the wait): never leave it so
            with contextlib.suppress(VehicleError, TimeoutError):
                await _bounded(self.disarm() if self.is_armed else self.hold(), 5.0)
            if done.result is not None:
                raise CommandError(MAV_CMD_COMPONENT_ARM_DISARM, done.result,
                                   done.reason.removeprefix("arming refused: "),
                                   "arming in OFFBOARD")
            raise VehicleError(done.reason)
        if why is Failure.LEFT_OFFBOARD:
            hb = self.link.heartbeat.last
            name = hb.mode.name if hb is not None else "unknown"
            failsafe = hb is not None and hb.system_status == MAV_STATE_CRITICAL
            how = "PX4 failsafe" if failsafe else "pilot takeover or failsafe"
            raise OffboardExitedError(
                f"vehicle left OFFBOARD for {name} ({how}); setpoint stream stopped, OFFBOARD "
                "not re-requested", name, failsafe)
        raise VehicleError(f"flight failed: {done.reason}")

    async def _hold_and_stop(self, streamer: FixedRateStreamer, sm: OffboardMachine,
                             why: str, end_mode: FlightMode = FlightMode.HOLD) -> None:
        """Switch to Hold (or ``end_mode``) while still streaming, then stop the stream."""
        log.info("%s: switching to %s", why, end_mode.name)
        try:
            await self.set_mode(end_mode)
        except (VehicleError, TimeoutError) as exc:
            log.error("%s after %s failed: %s", end_mode.name, why, exc)
        finally:
            streamer.stop()
            sm.stop(time.monotonic(), why)

    async def _after_link_loss(self) -> None:
        """Streaming is stopped; wait for the link (bounded), then report."""
        log.error("link lost during OFFBOARD: stream stopped, waiting for the link")
        try:
            await _bounded(self._link_up.wait(), self.config.reconnect_timeout_s)
        except TimeoutError:
            raise LinkLostError(f"link lost and not regained within "
                                f"{self.config.reconnect_timeout_s:g} s", regained=False) from None
        t_back = time.monotonic()
        with contextlib.suppress(VehicleError):  # report the mode from a fresh HEARTBEAT
            await self._wait_for(lambda: (self.link.heartbeat.last is not None
                                          and self.link.heartbeat.last.t_s >= t_back), 2.5,
                                 "a HEARTBEAT after the link came back")
        mode = self.mode.name if self.mode else "unknown"
        raise LinkLostError(f"link lost during OFFBOARD and regained (vehicle now in {mode}); "
                            "OFFBOARD not re-requested", regained=True)


@contextlib.asynccontextmanager
async def safe_exit(vehicle: Vehicle, action: str | None = None,
                    signals: Sequence[int] = (signal.SIGINT, signal.SIGTERM)
                    ) -> AsyncIterator[list[int]]:
    """On SIGINT/SIGTERM: cancel the enclosed block, switch the vehicle to Hold (or Land), and
    re-raise as KeyboardInterrupt. Yields the list of signals received (for the CLI's exit code).
    """
    loop = asyncio.get_running_loop()
    task = asyncio.current_task()
    hit: list[int] = []

    def handler(sig: int) -> None:
        if not hit and task is not None:
            task.cancel()
        hit.append(sig)

    installed = []
    for s in signals:
        with contextlib.suppress(NotImplementedError, RuntimeError, ValueError):
            loop.add_signal_handler(s, handler, s)
            installed.append(s)
    try:
        yield hit
    except asyncio.CancelledError:
        if not hit:
            raise
        log.warning("signal %s: %s before exit", hit[0], (action or vehicle.config.exit_action))
        await vehicle.exit_action(action)
        raise KeyboardInterrupt from None
    else:
        if hit:  # the block ended on its own while the signal was being delivered
            with contextlib.suppress(asyncio.CancelledError):
                await asyncio.sleep(0)  # absorb the cancellation if it is still pending
            if task is not None and task.cancelling():
                task.uncancel()
            log.warning("signal %s: %s before exit", hit[0], (action or vehicle.config.exit_action))
            await vehicle.exit_action(action)
            raise KeyboardInterrupt
    finally:
        for s in installed:
            loop.remove_signal_handler(s)
