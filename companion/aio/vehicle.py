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
import threading
import time
from collections.abc import Callable, Generator
from dataclasses import dataclass
from typing import Any

from companion.flight.clock import FlightClock
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
from companion.mavlink import (
    ExtendedState,
    FlightMode,
    LinkConfig,
    OffboardMachine,
    OffboardState,
    PositionSetpoint,
    SetpointCommand,
)
from companion.mavlink.commands import (
    MAV_CMD_COMPONENT_ARM_DISARM,
    MAV_CMD_DO_SET_MODE,
)

from .base import LANDED_STATE_ON_GROUND, MAV_STATE_CRITICAL, VehicleBase, VehicleConfig
from .errors import (
    CommandError,
    LinkLostError,
    OffboardError,
    OffboardExitedError,
    SetpointSourceError,
    TelemetryStaleError,
    VehicleError,
)
from .mission import MissionAPI
from .sources import SetpointSource, TrajectoryLike, TrajectoryPositionSource, hold_setpoint
from .streamer import FixedRateStreamer, StreamStats
from .waits import bounded, wait_event

log = logging.getLogger("companion.aio")

MODES = ("position", "attitude", "rates", "rover")


@dataclass(frozen=True)
class FlightReport:
    """Outcome of a completed ``fly``."""

    mode: str
    duration_s: float
    stream: StreamStats
    held_at_end: bool



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


class Vehicle(VehicleBase):
    """Asyncio façade over one PX4 link (see module doc)."""

    def __init__(self, url: str, config: VehicleConfig | None = None,
                 link_config: LinkConfig | None = None) -> None:
        super().__init__(url, config, link_config)
        self.mission = MissionAPI(self)

    @classmethod
    def connect(cls, url: str, *, config: VehicleConfig | None = None,
                link_config: LinkConfig | None = None) -> _Connect:
        """Open ``url`` and wait for the autopilot HEARTBEAT (``await`` or ``async with``)."""
        return _Connect(cls(url, config, link_config))

    # -- offboard flight ------------------------------------------------------------------------
    async def fly(self, trajectory: TrajectoryLike | None = None, *, mode: str = "position",
                  setpoint_source: SetpointSource | None = None, rate_hz: float | None = None,
                  duration_s: float | None = None, feedforward: str = "acc",
                  arm: bool = False, end_action: str = "hold",
                  disarm: bool = False, end_ned: tuple[float, float, float] | None = None,
                  settle_m: float | None = None, settle_s: float | None = None,
                  stall_s: float | None = None) -> FlightReport:
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
        disarm: end on the ground disarmed: after "land" or "touchdown" wait (at most
        ``land_timeout_s`` in LAND) for the landing, disarm once PX4 reports the vehicle on the
        ground (a refusal leaves it to PX4's auto-disarm) and return when disarmed; after "hold"
        (a rover) disarm once in Hold (CommandError if refused). The report's ``duration_s``
        still ends where the stream stopped.
        end_ned, settle_m, settle_s: the end ("hold", "land") comes once the trajectory is
        complete and the vehicle within ``settle_m`` [m] of ``end_ned`` (default: the
        trajectory's end, ``VehicleConfig.settle_m``), or ``settle_s`` [s] after it is
        complete (default ``VehicleConfig.settle_s``; 0 without an end position). A source
        that governs its reference time (``reference_time_s``, e.g. a rover's
        ``TrackingSource``) says when the trajectory is complete. stall_s: such a source's
        reference standing still this long [s] (the vehicle makes no progress) ends the flight
        too (None: never).
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
            end_pos: tuple[float, float, float] | None = end_ned
            if end_pos is None and trajectory is not None and math.isfinite(total):
                pe = trajectory.evaluate(total, 0)
                end_pos = (float(pe[0]), float(pe[1]), float(pe[2]))
            return await self._fly(source, mode, rate_hz or self.config.rate_hz, total, end_pos,
                                   arm, FlightMode.HOLD if end_action == "hold" else
                                   FlightMode.LAND, end_action == "touchdown", disarm,
                                   settle_m, settle_s, stall_s)
        finally:
            self._flying = False

    async def _fly(self, source: SetpointSource, mode: str, rate: float, total_s: float,
                   end_pos: tuple[float, float, float] | None, arm: bool = False,
                   end_mode: FlightMode = FlightMode.HOLD,
                   touchdown: bool = False, disarm: bool = False,
                   settle_m: float | None = None, settle_s: float | None = None,
                   stall_s: float | None = None) -> FlightReport:
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
                          settle_s=(0.0 if end_pos is None else cfg.settle_s if settle_s is None
                                    else settle_s),
                                    settle_m=cfg.settle_m if settle_m is None else settle_m,
                          end_ned=end_pos, land_command=False, stall_s=stall_s,
                          stream_handover=True, land_and_disarm=disarm,
                          disarm_at_hold=disarm and end_mode is FlightMode.HOLD,
                          disarm_on_ground=end_mode is not FlightMode.HOLD,
                          land_timeout_s=cfg.land_timeout_s)))
        sm = seq.machine
        state: dict[str, Any] = {"hold": None, "error": ""}
        link = self.link
        # the sequence and the reference run on flight time, which follows the autopilot's
        # clock (FlightClock: a PX4 SITL slowed by its host slows the reference with it)
        fclock = FlightClock()
        fclock_lock = threading.Lock()

        def flight_now(local: float) -> float:
            pos = self._snapshot.position
            with fclock_lock:
                if pos is not None:
                    fclock.observe(pos.time_boot_s, pos.t_s)
                return fclock.now(local)

        def producer(now: float) -> bytes | None:
            snap = dataclasses.replace(self._snapshot, now_s=now, link_rtt_s=link.rtt_s)
            hold: PositionSetpoint | None = state["hold"]
            if hold is None:
                t0 = seq.t_fly0
                t = 0.0 if t0 is None else max(flight_now(now) - t0, 0.0)
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
            if not streamer.sent_times:
                return
            mono = time.monotonic()
            f = flight_now(mono)
            while streamer.sent_times:  # send times on the flight clock (it runs <= local)
                seq.on_setpoint_sent(f - max(mono - streamer.sent_times.popleft(), 0.0))

        t_start = time.monotonic()
        t_stop: float | None = None  # the stream stopped: the flown part ended
        stale_since: float | None = None
        done: Finished | None = None
        try:
            # the sequence's priming starts with the first setpoint sent
            mono = await self._first_setpoint(streamer, state, rate)
            now = flight_now(mono)
            while done is None:
                actions: list[SequenceAction] = []
                while results:
                    command, ok, reason, result = results.popleft()
                    actions += seq.on_command_result(command, ok, reason, now, result)
                actions += seq.update(now, self._flight_view(source))
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
                            t_start = mono
                        elif act.new is Phase.HANDOVER:
                            log.info("%s: switching to %s", act.reason,
                                     (FlightMode.LAND if seq.disarm_sent or touchdown
                                      else end_mode).name)
                if not seq.streaming:
                    streamer.stop()
                    if t_stop is None and seq.t_fly0 is not None:
                        t_stop = time.monotonic()
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
                                                          mono)
                self._changed.clear()
                await wait_event(self._changed, 0.02)
                pump()
                mono = time.monotonic()
                now = flight_now(mono)
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
        return FlightReport(mode, (t_stop or time.monotonic()) - t_start, streamer.stats(), True)

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

    def _flight_view(self, source: object = None) -> VehicleView:
        """The vehicle as the flight sequence sees it now, with what ``source`` says of its
        reference if it governs it (``reference_time_s``, ``arrived``, ``stalled_s``, e.g. a
        rover's `TrackingSource`)."""
        tel = self.link.telemetry
        ext: ExtendedState | None = tel.extended
        pos = tel.position
        return VehicleView(
            link_ok=self._link_lost_at is None and self.link_ok, armed=self.is_armed,
            mode=self.mode,
            on_ground=ext is not None and ext.landed_state == LANDED_STATE_ON_GROUND,
            pos_ned=None if pos is None else pos.pos_ned,
            traj_time_s=getattr(source, "reference_time_s", None),
            arrived=bool(getattr(source, "arrived", False)),
            stalled_s=float(getattr(source, "stalled_s", 0.0)),
            blind_s=float(getattr(source, "blind_s", 0.0)))

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
                await bounded(self.disarm() if self.is_armed else self.hold(), 5.0)
            if done.result is not None:
                raise CommandError(MAV_CMD_COMPONENT_ARM_DISARM, done.result,
                                   done.reason.removeprefix("arming refused: "),
                                   "arming in OFFBOARD")
            raise VehicleError(done.reason)
        if why is Failure.DISARM_REFUSED:
            raise CommandError(MAV_CMD_COMPONENT_ARM_DISARM, done.result,
                               done.reason.removeprefix("disarm refused: "), "disarming")
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
            await bounded(self._link_up.wait(), self.config.reconnect_timeout_s)
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
