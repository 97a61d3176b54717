"""`python -m companion serve`: the asyncio runner around :mod:`companion.serve.service`.

One :class:`~companion.aio.Vehicle` carries the link (UDP or serial; it reopens a failed
transport and notices a silent link), a fixed-rate sender thread sends whatever
``ServeService.stream`` says, and a 20 Hz loop feeds observations to the service and performs
its actions (mission download + planning off the event loop, mode requests, STATUSTEXT).
Logs go to one folder: rotating ``.tlog`` files (a new one at every arming and when one grows
past ``tlog_max_bytes``; the newest ``tlog_keep`` are kept) and ``events.jsonl`` (one JSON object
per line: ``t`` UNIX seconds, ``event``, fields). SIGTERM/SIGINT: Hold first if the vehicle flies
on our stream in OFFBOARD (while still streaming), then stop.

With ``--onboard`` (:mod:`companion.serve.onboard`) the onboard PX4 module is checked before
anything else is sent (`check_module`: exit 2), there is no sender thread at all, the module's
reports feed the observations, and the service's uploads are planned off the event loop and
sent part by part with their CRC verified (`_upload_onboard`).
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import datetime as dt
import json
import logging
import math
import signal
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO, Literal

from rich.console import Console

from companion.flight.clock import FlightClock
from companion.mavlink import FlightMode, LinkConfig, VehicleLink
from companion.mavlink.codec import MavMessage
from companion.mission.px4_params import Px4PlanningParams
from companion.onboard.protocol import OP_ABORT, OP_STATUS, PROTO_NAME, Ack, request
from companion.planning.config import VehicleFile, load_vehicle_file
from companion.planning.vehicle_params import ResolvedPlanningParams, read_planning_params
from companion.serve.onboard import OnboardServeService
from companion.serve.program import MissionProgram, plan_program
from companion.serve.service import (
    AbortOnboard,
    Action,
    Announce,
    DownloadMission,
    HoldStream,
    LogEvent,
    MissionStream,
    Observation,
    PlanJoin,
    RequestMode,
    ServeService,
    ServiceConfig,
    UploadOnboard,
)

log = logging.getLogger("companion.serve")
MSG_HOME_POSITION = 242
MAV_MISSION_TYPE_FENCE = 1
_TS_BYTES = 8
#: serve --onboard: ask the onboard module for its state when it has not reported for this
#: long [s] (it reports every 0.5 s to whoever asked last)
MODULE_POLL_S = 2.0


@dataclass(frozen=True)
class ServeOptions:
    """Options of `serve` (see `build_parser` in companion.app.cli)."""

    connect: str
    mode: str = "attitude"
    rate_hz: float = 50.0
    vehicle_file: str | None = None
    log_dir: str = "ecca-logs"
    target_system: int = 1
    tlog_max_bytes: int = 64 * 1024 * 1024
    tlog_keep: int = 20
    connect_timeout_s: float = 10.0
    signing_key: bytes | None = None  # MAVLink 2 signing (32-byte key) when set
    onboard: bool = False  # the onboard PX4 module flies (companion.serve.onboard)


class RotatingTlog:
    """``.tlog`` files in ``folder``: ``serve-<UTC time>.tlog``, a new one on ``rotate()`` and
    when the current one passes ``max_bytes``; only the newest ``keep`` are kept. Thread-safe;
    ``close()`` ends the current file (the next write starts a new one)."""

    def __init__(self, folder: Path, max_bytes: int, keep: int) -> None:
        if max_bytes < 1024 or keep < 1:
            raise ValueError("tlog rotation needs max_bytes >= 1024 and keep >= 1")
        self.folder, self.max_bytes, self.keep = folder, max_bytes, keep
        self._lock = threading.Lock()
        self._f: BinaryIO | None = None
        self._size = 0
        self.path: Path | None = None
        self._n = 0

    def _open(self) -> BinaryIO:
        self._n += 1
        stamp = dt.datetime.now(dt.UTC).strftime("%Y%m%dT%H%M%S")
        self.path = self.folder / f"serve-{stamp}-{self._n:03d}.tlog"
        f = open(self.path, "ab")  # noqa: SIM115 - closed in rotate()/close()
        self._size = 0
        old = sorted(self.folder.glob("serve-*.tlog"), key=lambda p: p.stat().st_mtime)
        for p in old[:-self.keep]:
            if p != self.path:
                with contextlib.suppress(OSError):
                    p.unlink()
        return f

    def write(self, frame: bytes, unix_time_s: float | None = None) -> None:
        """Record one frame (8-byte big-endian UNIX us + frame, the .tlog format)."""
        t = time.time() if unix_time_s is None else unix_time_s
        rec = int(t * 1e6).to_bytes(_TS_BYTES, "big") + frame
        with self._lock:
            if self._f is None or self._size + len(rec) > self.max_bytes:
                if self._f is not None:
                    self._f.close()
                self._f = self._open()
            self._f.write(rec)
            self._size += len(rec)

    def rotate(self) -> None:
        """Start a new file with the next frame."""
        with self._lock:
            if self._f is not None:
                self._f.close()
                self._f = None

    def flush(self) -> None:
        with self._lock:
            if self._f is not None:
                self._f.flush()

    close = rotate


class EventLog:
    """``events.jsonl``: one JSON object per line, flushed at once."""

    def __init__(self, path: Path, console: Console | None = None) -> None:
        self.path = path
        self._f = open(path, "a", encoding="utf-8")  # noqa: SIM115 - closed in close()
        self.console = console

    def write(self, event: str, **fields: Any) -> None:
        rec = {"t": round(time.time(), 3), "event": event, **fields}
        self._f.write(json.dumps(rec, default=str) + "\n")
        self._f.flush()
        if self.console is not None:
            extra = " ".join(f"{k}={v}" for k, v in fields.items())
            self.console.print(f"[dim]{dt.datetime.now():%H:%M:%S}[/dim] {event} {extra}")

    def close(self) -> None:
        self._f.close()


def statustext_messages(text: str, severity: int, text_id: int) -> list[MavMessage]:
    """STATUSTEXT message(s) for ``text`` (chunked with ``id``/``chunk_seq`` beyond 50 chars)."""
    from pymavlink.dialects.v20 import common as mavlink2

    raw = text.encode("ascii", "replace")
    if len(raw) <= 50:
        return [mavlink2.MAVLink_statustext_message(severity, raw, 0, 0)]
    chunks = [raw[i:i + 50] for i in range(0, len(raw), 50)]
    if len(chunks[-1]) == 50:
        chunks.append(b"")
    return [mavlink2.MAVLink_statustext_message(severity, c, text_id, i)
            for i, c in enumerate(chunks)]


def _yaw(q: tuple[float, float, float, float]) -> float:
    import math

    w, x, y, z = q
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


class _Session:
    """One connected Vehicle driven by the service until ``stop`` is set."""

    def __init__(self, v: Any, service: ServeService, events: EventLog, tlog: RotatingTlog,
                 opts: ServeOptions, vehicle_file: VehicleFile | None = None) -> None:
        self.v, self.service, self.events, self.tlog, self.opts = v, service, events, tlog, opts
        self.vehicle_file = vehicle_file or VehicleFile()
        self.px4_overrides = self.vehicle_file.px4_overrides  # the vehicle file's [px4] table
        self.module: tuple[Ack, float] | None = None  # the onboard module's latest report
        self._tasks: set[asyncio.Task[None]] = set()
        self._mode_task: asyncio.Task[None] | None = None
        self._text_id = 0
        self._armed = False
        self._px4: asyncio.Task[Px4PlanningParams | str] | None = None
        # each mission stream's reference runs on flight time, which follows the autopilot's
        # clock as `fly`'s does (a PX4 SITL slowed by its host slows the reference with it);
        # the onboard module flies on the autopilot's clock itself
        if not isinstance(service, OnboardServeService):
            service.clock = self.flight_clock

    def flight_clock(self) -> Callable[[float], float]:
        """A new flight clock (one per mission stream, as `fly` has one per flight: a
        `FlightClock` fed only while it is read would take a pause for a stall): flight time
        [s] at local time [s], on the newest position sample."""
        fclock = FlightClock()
        lock = threading.Lock()  # (the setpoint thread and the service loop)

        def flight_time(local_s: float) -> float:
            pos = self.v.telemetry.position
            with lock:
                if pos is not None:
                    fclock.observe(pos.time_boot_s, pos.t_s)
                return fclock.now(local_s)

        return flight_time

    async def read_px4_params(self) -> Px4PlanningParams | str:
        """The vehicle's planning parameters with the vehicle file's [px4] overrides, logged
        (``px4_params``); a reason string (``px4_params_refused``) if the planner cannot use
        them: missions are then refused with it."""
        from companion.aio import VehicleError

        try:
            hb = self.v.link.heartbeat.last
            kind = "rover" if hb is not None and hb.vehicle_type == 10 else "quad"
            r: ResolvedPlanningParams = await read_planning_params(self.v.fetch_params,
                                                                   self.px4_overrides,
                                                                   vehicle=kind)
        except ValueError as exc:
            self.events.write("px4_params_refused", why=str(exc))
            return f"PX4 parameters: {exc}"
        except (TimeoutError, VehicleError) as exc:  # e.g. the link went down meanwhile
            self.events.write("px4_params_refused", why=f"read failed: {exc}")
            return f"PX4 parameters could not be read: {exc}"
        self.events.write(
            "px4_params", **{n: round(v, 4) for n, v in r.params.as_dict(r.names).items()},
            vehicle_file=sorted(n for n, s in r.source.items() if s == "file"),
            defaulted=list(r.defaulted))
        for w in r.warnings:
            self.events.write("px4_params_warning", why=w)
        if self.opts.mode == "attitude":
            refused = await self.v.stream_position_fast()
            if refused is not None:
                self.events.write("position_stream_refused", why=refused)
        return r.params

    def observe(self) -> Observation:
        v = self.v
        snap = v.telemetry
        ext = snap.extended
        return Observation(
            now_s=time.monotonic(), link_ok=v.link_ok, armed=v.is_armed, mode=v.mode,
            landed_state=None if ext is None else ext.landed_state, position=snap.position,
            yaw=None if snap.attitude is None else _yaw(snap.attitude.q_wxyz), home=snap.home,
            mission=v.link.telemetry.mission_current,
            attitude_q=None if snap.attitude is None else snap.attitude.q_wxyz,
            module=None if self.module is None else self.module[0],
            module_t_s=None if self.module is None else self.module[1])

    def producer(self, now: float) -> bytes | None:
        s = self.service.stream
        link: VehicleLink = self.v.link
        if s is None:
            return None
        if isinstance(s, HoldStream):
            return link.encode_setpoint(s.setpoint, now)
        snap = dataclasses.replace(self.v.telemetry, now_s=now, link_rtt_s=link.rtt_s)
        try:
            return link.encode_setpoint(s.setpoint(now, snap), now)
        except Exception as exc:  # an invalid setpoint is never sent: hold where we are
            log.error("mission setpoint failed (%s): holding", exc)
            r = s.source.last_reference
            if r is None:
                return None
            from companion.mavlink import PositionSetpoint

            hold = PositionSetpoint(pos_ned=tuple(float(c) for c in r.pos_ned),  # type: ignore[arg-type]
                                    vel_ned=(0.0, 0.0, 0.0), yaw=float(r.yaw))
            self.service.stream = HoldStream(hold)
            return link.encode_setpoint(hold, now)

    def _spawn(self, coro: Any) -> asyncio.Task[None]:
        t: asyncio.Task[None] = asyncio.get_running_loop().create_task(coro)
        self._tasks.add(t)
        t.add_done_callback(self._tasks.discard)
        return t

    def perform(self, actions: list[Action]) -> None:
        for a in actions:
            if isinstance(a, LogEvent):
                self.events.write(a.event, **a.fields)
            elif isinstance(a, Announce):
                self.announce(a.text, a.severity)
            elif isinstance(a, RequestMode):
                if self._mode_task is None or self._mode_task.done():
                    self._mode_task = self._spawn(self._request_mode(a.mode, a.why))
            elif isinstance(a, DownloadMission):
                self._spawn(self._download_and_plan(a.key))
            elif isinstance(a, PlanJoin):
                self._spawn(self._plan_join(a))
            elif isinstance(a, UploadOnboard):
                self._spawn(self._upload_onboard(a))
            elif isinstance(a, AbortOnboard):
                self.events.write("onboard_abort", why=a.why)
                self._module_request(OP_ABORT)

    def announce(self, text: str, severity: int) -> None:
        self._text_id = self._text_id % 65535 + 1
        for m in statustext_messages(text, severity, self._text_id):
            self.v.link.send_message(m)
        self.v._flush()
        self.events.write("announce", text=text)

    async def _request_mode(self, mode: FlightMode, why: str) -> None:
        from companion.aio import VehicleError

        pos = self.v.telemetry.position  # where the vehicle is handed over (local NED, m)
        self.events.write("mode_request", mode=mode.name, why=why,
                          pos_ned=None if pos is None else [round(c, 3) for c in pos.pos_ned])
        try:
            await self.v.set_mode(mode)
        except (VehicleError, TimeoutError) as exc:
            self.events.write("mode_refused", mode=mode.name, why=str(exc))

    async def _plan_join(self, req: PlanJoin) -> None:
        """The join planned in a worker thread: telemetry, the ground station and the service
        loop go on meanwhile (planned on the loop it held them up 0.15-0.3 s; the hold stream's
        own thread never waited)."""
        result: MissionStream | str
        try:
            result = await asyncio.to_thread(self.service.plan_join, req)
        except Exception as exc:  # a planner failure holds, with its reason
            result = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        self.perform(self.service.on_joined(req.token, result, time.monotonic()))

    def _module_request(self, op: int) -> None:
        """One message to the onboard module (STATUS: also makes us the peer it reports to)."""
        cfg = self.v.link.config
        self.v.send_float_array(PROTO_NAME, op, request(cfg.sysid, cfg.compid))

    async def _follow_module(self) -> None:
        """The onboard module's reports (its status every 0.5 s, its answers), the latest kept
        for the observations."""
        from companion.aio.onboard import module_states

        async for t_s, ack in module_states(self.v):
            self.module = (ack, t_s)

    async def _upload_onboard(self, req: UploadOnboard) -> None:
        """Plan the onboard trajectory off the event loop, upload it and verify its CRC."""
        from companion.aio import VehicleError
        from companion.aio.onboard import upload
        from companion.flight.report import SetpointLimits
        from companion.onboard.protocol import encode_upload
        from companion.planning.onboard_segments import (
            HOLD_S,
            START_TOLERANCE_M,
            bend_for_tilt,
            law_params,
        )
        from companion.serve.onboard import OnboardTrajectory

        svc = self.service
        assert isinstance(svc, OnboardServeService)
        result: OnboardTrajectory | str
        crc = 0
        try:
            result = await asyncio.to_thread(svc.plan_onboard, req)
            if isinstance(result, OnboardTrajectory):
                px4 = await self._px4 if self._px4 is not None else None
                if isinstance(px4, str):
                    raise ValueError(px4)
                hover = (await self.v.read_params(["MPC_THR_HOVER"]))["MPC_THR_HOVER"]
                tilt = SetpointLimits.of_px4(px4 or Px4PlanningParams()).tilt_max_rad
                cfg = self.v.link.config
                law = law_params(self.vehicle_file, hover, tilt)
                segs = await asyncio.to_thread(bend_for_tilt, result.segments, law)  # ~0.3 s
                up = encode_upload(*segs, law,
                                   sysid=cfg.sysid, compid=cfg.compid,
                                   final_action=result.final_action, hold_s=HOLD_S,
                                   start_tolerance_m=START_TOLERANCE_M)
                u = await upload(self.v, up)
                crc = up.crc
                if not u.verified:
                    result = f"not verified ({u.failed})"
        except (ValueError, VehicleError, TimeoutError) as exc:
            result = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        self.perform(svc.on_uploaded(req.token, result, time.monotonic(), crc))

    async def _download_and_plan(self, key: tuple[int, int]) -> None:
        from companion.aio import VehicleError

        v, svc = self.v, self.service
        try:
            items = await v.mission.download()
            # the geofence too: a plan that breaches it is refused (MAV_MISSION_TYPE_FENCE)
            fence_items = await v.mission.download(MAV_MISSION_TYPE_FENCE)
            if v.telemetry.home is None:
                v.link.request_message(MSG_HOME_POSITION, time.monotonic())
                v._flush()
                deadline = time.monotonic() + 5.0
                while v.telemetry.home is None and time.monotonic() < deadline:
                    await asyncio.sleep(0.05)  # poll for HOME_POSITION (bounded)
            home = v.telemetry.home
            if home is None:
                raise VehicleError("no HOME_POSITION from the vehicle")
        except (VehicleError, TimeoutError) as exc:
            self.perform(svc.on_download_failed(key, str(exc)))
            return
        self.perform(svc.on_downloaded(key, len(items)))
        hb = v.link.heartbeat.last
        vehicle: Literal["quad", "rover"] = (
            "rover" if hb is not None and hb.vehicle_type == 10 else "quad")
        result: MissionProgram | str
        px4 = await self._px4 if self._px4 is not None else None
        try:
            if isinstance(px4, str):
                raise ValueError(px4)
            config = dataclasses.replace(svc.config, px4=px4)
            result = await asyncio.to_thread(plan_program, items, home, key, config, vehicle,
                                             fence_items)
        except Exception as exc:  # MissionError, ValueError, planner failures: say why
            result = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        self.perform(svc.on_planned(key, result, time.monotonic()))

    async def run(self, stop: asyncio.Event) -> None:
        from companion.aio.streamer import FixedRateStreamer

        v = self.v

        def send(frame: bytes) -> bool:
            tr = v.transport
            return tr is not None and tr.send(frame)

        def on_sent(frame: bytes, _t: float) -> None:
            self.tlog.write(frame)

        streamer = None
        if self.opts.onboard:  # the module flies: no setpoint stream at all
            self._spawn(self._follow_module())
        else:
            streamer = FixedRateStreamer(self.opts.rate_hz, send, self.producer,
                                         on_sent=on_sent, name="serve-streamer")
            streamer.start()
        # read the planning parameters beside the hold stream (never delay it); a mission
        # download waits for them before it is planned
        self._px4 = asyncio.get_running_loop().create_task(self.read_px4_params())
        polled = time.monotonic()  # (check_module asked the module at connect)
        try:
            while not stop.is_set():
                obs = self.observe()
                if obs.armed and not self._armed:
                    self.tlog.rotate()  # one .tlog per flight
                self._armed = obs.armed
                if self.opts.onboard and (obs.module_t_s is None or obs.now_s - obs.module_t_s
                                          > MODULE_POLL_S) and obs.now_s - polled > MODULE_POLL_S:
                    polled = obs.now_s  # a module restarted since reports to no one: ask it
                    self._module_request(OP_STATUS)
                self.perform(self.service.update(obs))
                with contextlib.suppress(TimeoutError):
                    async with asyncio.timeout(0.05):  # 20 Hz service loop
                        await stop.wait()
            # stopping: Hold first while the stream still runs
            obs = self.observe()
            acts = self.service.shutdown(obs)
            for a in acts:
                if isinstance(a, RequestMode):
                    self.events.write("mode_request", mode=a.mode.name, why=a.why)
                    with contextlib.suppress(Exception):
                        async with asyncio.timeout(5.0):
                            await v.set_mode(a.mode)
                    self.events.write("stopped_in", mode=v.mode.name if v.mode else None)
                elif isinstance(a, LogEvent):
                    self.events.write(a.event, **a.fields)
        finally:
            if streamer is not None:
                streamer.stop()
            self.service.stream = None
            for t in [*self._tasks, *([self._px4] if self._px4 is not None else [])]:
                t.cancel()
            for t in [*self._tasks, *([self._px4] if self._px4 is not None else [])]:
                with contextlib.suppress(asyncio.CancelledError, Exception):
                    await t


async def check_module(v: Any, events: EventLog) -> None:
    """`serve --onboard`: the onboard module answers and is ready for a trajectory (not
    receiving or flying one); else OnboardError (exit 2), with nothing else sent."""
    from companion.aio.onboard import module_status
    from companion.onboard.protocol import (
        STATE_FLYING,
        STATE_HOLDING,
        STATE_NAMES,
        STATE_RECEIVING,
    )
    from companion.planning.onboard_segments import OnboardError

    st = await module_status(v)
    if st is None:
        events.write("onboard_module", state=None)
        raise OnboardError("no onboard module answers (load it: `dyn FILE.px4mod start`, see "
                           "docs/guides/onboard.md); nothing was sent to fly")
    name = STATE_NAMES.get(st.state, str(st.state))
    events.write("onboard_module", state=name)
    if st.state in (STATE_RECEIVING, STATE_FLYING, STATE_HOLDING):
        raise OnboardError(f"the onboard module is {name}: not ready")


async def serve(opts: ServeOptions, console: Console) -> int:
    """Run the service until SIGTERM/SIGINT; returns the exit code (0 after a clean stop)."""
    from companion.aio import ConnectTimeoutError, Vehicle, VehicleConfig
    from companion.aio.transports import TransportError, parse_url

    parse_url(opts.connect)  # a bad URL is bad input (ValueError), before anything starts
    vf = load_vehicle_file(opts.vehicle_file) if opts.vehicle_file else VehicleFile()
    if opts.mode not in ("position", "attitude", "rates"):
        raise ValueError(f"--mode must be position, attitude or rates, got {opts.mode!r}")
    if not 2.0 < opts.rate_hz <= 500.0:
        raise ValueError(f"--rate must be above 2 Hz and at most 500, got {opts.rate_hz:g}")
    if opts.onboard and opts.mode != "attitude":
        raise ValueError("--onboard: the onboard module flies attitude setpoints "
                         "(--mode attitude)")
    folder = Path(opts.log_dir)
    folder.mkdir(parents=True, exist_ok=True)
    config = ServiceConfig(setpoint_mode=opts.mode, params=vf.params,  # type: ignore[arg-type]
                           limits=vf.limits, tracking=vf.tracking_config(math.radians(50.0)),
                           rate_hz=opts.rate_hz)
    service = OnboardServeService(config) if opts.onboard else ServeService(config,
                                                                            defer_join=True)
    module_checked = not opts.onboard
    events = EventLog(folder / "events.jsonl", console)
    tlog = RotatingTlog(folder, opts.tlog_max_bytes, opts.tlog_keep)
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    installed = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(NotImplementedError, RuntimeError, ValueError):
            loop.add_signal_handler(sig, stop.set)
            installed.append(sig)
    events.write("start", connect=opts.connect, mode=opts.mode, rate_hz=opts.rate_hz,
                 log_dir=str(folder.resolve()))
    try:
        while not stop.is_set():
            vconfig = VehicleConfig(rate_hz=opts.rate_hz, connect_timeout_s=opts.connect_timeout_s)
            try:
                v = await Vehicle.connect(opts.connect, config=vconfig,
                                          link_config=LinkConfig(target_sysid=opts.target_system
                                                                 ).with_signing_key(opts.signing_key))
            except (ConnectTimeoutError, TransportError, OSError) as exc:
                events.write("connect_failed", why=str(exc))
                with contextlib.suppress(TimeoutError):
                    async with asyncio.timeout(2.0):  # retry period
                        await stop.wait()
                continue
            v.tlog = tlog  # type: ignore[assignment]  # same write/close interface
            events.write("connected", url=opts.connect)
            try:
                if not module_checked:  # before anything else is sent: the module is there
                    await check_module(v, events)
                    module_checked = True
                await _Session(v, service, events, tlog, opts, vf).run(stop)
            finally:
                await v.close()
    finally:
        for sig in installed:
            loop.remove_signal_handler(sig)
        events.write("stop")
        events.close()
        tlog.close()
    return 0
