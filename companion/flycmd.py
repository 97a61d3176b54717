"""`python -m companion fly` and `status`: connect to PX4 (or an embedded mock), take off, fly a
mission file or a built-in pattern with flatness setpoints, land; rich live status."""

from __future__ import annotations

import asyncio
import contextlib
import datetime as dt
import math
import socket
from collections.abc import AsyncIterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console
from rich.live import Live
from rich.markup import escape
from rich.table import Table

from companion.config import VehicleFile, load_vehicle_file
from companion.control import Reference
from companion.mavlink import LinkConfig
from companion.mission import geodetic_to_ned, load_mission, mission_to_flight_plan
from companion.patterns import PATTERNS, pattern_trajectory
from companion.schedule import Schedule, build_schedule, trajectory_reference
from companion.tracking import TrackingSource

DEFAULT_HOME = (47.397742, 8.545594, 488.0)
#: A mission's planned home must be this close to the vehicle to be flown [m].
MAX_HOME_OFFSET_M = 5.0
MAV_TYPE_GROUND_ROVER = 10


@dataclass
class FlyOptions:
    """Options of `fly` (see `build_fly_parser` in companion.cli)."""

    target: str
    connect: str | None
    mode: str
    rate_hz: float
    vehicle_file: str | None
    log: str | None
    size_m: float
    speed_m_s: float
    alt_m: float
    laps: int
    mock_params: tuple[tuple[str, float], ...] = ()
    busy_wait: bool = False
    sender_cpu: int | None = None
    target_system: int = 1  # the autopilot's MAVLink system id (PX4 MAV_SYS_ID)


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@contextlib.asynccontextmanager
async def embedded_mock(
    home: tuple[float, float, float], mock_params: tuple[tuple[str, float], ...] = ()
) -> AsyncIterator[str]:
    """Run `sitl_mock` in this process on loopback; yields the URL the companion connects to."""
    from sitl_mock.autopilot import Autopilot
    from sitl_mock.params import ParamStore
    from sitl_mock.server import LinkConfig, MockServer, ServerConfig

    port = _free_udp_port()
    config = ServerConfig(links=[LinkConfig("offboard", ("127.0.0.1", 0), ("127.0.0.1", port))])
    server = MockServer(
        lambda remotes, now: Autopilot(
            "quad", ParamStore(dict(mock_params)), home, 0, remotes=remotes, now=now
        ),
        config,
    )
    await server.start()
    task = asyncio.get_running_loop().create_task(server.run())
    try:
        yield f"udpin://127.0.0.1:{port}"
    finally:
        server.stop()
        with contextlib.suppress(asyncio.CancelledError, TimeoutError):
            await asyncio.wait_for(task, 5.0)


def _status_table(
    v: Any, source: TrackingSource | None, started: float | None, ended: float | None = None
) -> Table:
    t = Table(title="ecca-offboard", show_header=False, min_width=60)
    snap = v.telemetry
    mode = v.mode.name if v.mode is not None else "-"
    t.add_row("link", "[green]ok[/green]" if v.link_ok else "[red]lost[/red]")
    t.add_row("mode / armed", f"{mode} / {'ARMED' if v.is_armed else 'disarmed'}")
    if snap.position is not None:
        p = snap.position.pos_ned
        t.add_row("position NED [m]", f"{p[0]:8.2f} {p[1]:8.2f} {p[2]:8.2f}")
        if source is not None and source.last_reference is not None and ended is None:
            err = np.linalg.norm(np.asarray(p) - source.last_reference.pos_ned)
            t.add_row("position error [m]", f"{err:.2f}")
    if source is not None and started is not None:
        elapsed = (ended or asyncio.get_running_loop().time()) - started
        if elapsed > 0:
            t.add_row("mean setpoint rate [Hz]", f"{source.calls / elapsed:.0f}")
    if v.last_status_text is not None:
        t.add_row("vehicle says", escape(v.last_status_text.text))
    return t


def _takeoff_end(schedule: Schedule) -> float:
    """Schedule time [s] at which its leading takeoff climb ends (PX4's takeoff replaces it)."""
    t_off = 0.0
    for p in schedule.pieces:
        if p.phase != "takeoff":
            break
        t_off = p.t0_s + p.duration_s
    return t_off


def check_fly_options(opts: FlyOptions) -> None:
    """ValueError for options that cannot be flown, before anything starts (mock, link): the
    target is neither a pattern nor an existing file, or a pattern's size/speed/altitude/laps
    is out of range."""
    if opts.target not in PATTERNS:
        if not Path(opts.target).is_file():
            raise ValueError(
                f"{opts.target}: no such mission file, and not a pattern "
                f"(patterns: {', '.join(PATTERNS)})"
            )
        return
    for name, value in (("--size", opts.size_m), ("--speed", opts.speed_m_s)):
        if not (0.0 < value < math.inf):
            raise ValueError(f"{name} must be a number > 0, got {value}")
    if not (0.5 < opts.alt_m < math.inf):
        raise ValueError(f"--alt must be above 0.5 m, got {opts.alt_m}")
    if opts.laps < 1:
        raise ValueError(f"--laps must be >= 1, got {opts.laps}")


async def fly(opts: FlyOptions, console: Console) -> int:
    """Run `fly`; returns the exit code (0 ok, 1 flight failure, 2 bad input)."""
    from companion.aio import Vehicle, VehicleConfig, VehicleError, safe_exit

    check_fly_options(opts)
    vf = load_vehicle_file(opts.vehicle_file) if opts.vehicle_file else VehicleFile()
    mission = None
    home = DEFAULT_HOME
    if opts.target not in PATTERNS:
        mission = load_mission(opts.target)
        home = (mission.home.lat_deg, mission.home.lon_deg, mission.home.alt_amsl_m)
    log_path = opts.log or f"flight-{dt.datetime.now(dt.UTC):%Y%m%dT%H%M%SZ}.tlog"
    vconfig = VehicleConfig(rate_hz=opts.rate_hz, tlog_path=log_path,
                            stream_wait="busy" if opts.busy_wait else "sleep",
                            stream_cpu=opts.sender_cpu)
    async with contextlib.AsyncExitStack() as stack:
        url = opts.connect
        if url is None:
            url = await stack.enter_async_context(embedded_mock(home, opts.mock_params))
            console.print(f"No --connect: flying the embedded mock PX4 ({escape(url)})")
        link = LinkConfig(target_sysid=opts.target_system if opts.connect else 1)
        v = await stack.enter_async_context(Vehicle.connect(url, config=vconfig,
                                                            link_config=link))
        await stack.enter_async_context(safe_exit(v))
        hb = v.link.heartbeat.last
        rover = hb is not None and hb.vehicle_type == MAV_TYPE_GROUND_ROVER
        mode = "rover" if rover else opts.mode
        console.print(
            f"Connected: {'rover' if rover else 'multicopter'}, logging to {escape(log_path)}")
        source: TrackingSource | None = None
        started: float | None = None
        ended: float | None = None

        async def show(live: Live) -> None:
            while True:
                live.update(_status_table(v, source, started, ended))
                await asyncio.sleep(0.2)  # display refresh period

        with Live(_status_table(v, None, None), console=console, refresh_per_second=5) as live:
            ui = asyncio.get_running_loop().create_task(show(live))
            try:
                # plan before arming (off the event loop: planning takes up to a second)
                if mission is not None:
                    fp = mission_to_flight_plan(mission, vehicle="rover" if rover else "quad")
                    schedule = await asyncio.to_thread(
                        build_schedule, fp, None if rover else vf.params, vf.limits
                    )
                    alt = fp.takeoff_alt_m
                    t_off = _takeoff_end(schedule)
                    duration = schedule.duration_s - t_off
                    start_rel = schedule.reference(t_off).pos_ned

                    def rel_ref(t: float, origin: np.ndarray | None = None) -> Reference:
                        return schedule.reference(t + t_off, origin)
                else:
                    alt = opts.alt_m
                    traj = await asyncio.to_thread(
                        lambda: pattern_trajectory(
                            opts.target, np.zeros(3), size_m=opts.size_m,
                            speed_m_s=opts.speed_m_s, laps=opts.laps, yaw=0.0,
                            params=vf.params, max_acc_m_s2=vf.limits.max_acc_m_s2,
                            max_tilt_rad=vf.limits.max_tilt_rad,
                        )
                    )
                    pattern_ref = trajectory_reference(traj, 0.0)
                    duration = traj.duration

                    def rel_ref(t: float, origin: np.ndarray | None = None) -> Reference:
                        r = pattern_ref(t)
                        if origin is None:
                            return r
                        return Reference(
                            r.pos_ned + origin, r.vel_ned, r.acc_ned, r.jerk_ned, r.snap_ned,
                            r.yaw, r.yaw_rate, r.yaw_acc,
                        )
                    start_rel = np.zeros(3)
                await v.arm()
                if not rover:
                    await v.takeoff(alt)
                snap = v.telemetry
                if snap.position is None:
                    raise VehicleError("no position telemetry after takeoff")
                here = np.asarray(snap.position.pos_ned, dtype=float)
                if mission is not None and snap.global_position is not None:
                    g = snap.global_position
                    off = geodetic_to_ned(g.lat_deg, g.lon_deg, g.alt_amsl_m, mission.home)
                    horiz = math.hypot(off[0], off[1])
                    if horiz > MAX_HOME_OFFSET_M:
                        raise ValueError(
                            f"{opts.target}: planned home is {horiz:.0f} m from the vehicle "
                            f"(limit {MAX_HOME_OFFSET_M:g} m); move the vehicle there or "
                            "edit plannedHomePosition"
                        )
                origin = here - start_rel

                def ref(t: float) -> Reference:
                    return rel_ref(t, origin)

                source = TrackingSource(ref, mode, vf.params)  # type: ignore[arg-type]
                started = asyncio.get_running_loop().time()
                report = await v.fly(mode=mode, setpoint_source=source, duration_s=duration)
                ended = asyncio.get_running_loop().time()
                console.print(
                    f"Trajectory flown in {mode} mode: {report.duration_s:.1f} s"
                )
                final = schedule.final_action if mission is not None else "land"
                if rover:
                    await v.disarm()
                elif final in ("land", "rtl"):
                    await v.land()
                else:
                    await v.hold()
            finally:
                ui.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await ui
                live.update(_status_table(v, source, started, ended or 0.0))
    console.print(f"Done. Log: {escape(str(Path(log_path).resolve()))}")
    return 0


async def status(url: str, console: Console, timeout_s: float = 10.0,
                 target_system: int = 1) -> int:
    """Connect, wait for telemetry, print the vehicle state once."""
    from companion.aio import Vehicle, VehicleConfig

    async with Vehicle.connect(url, config=VehicleConfig(connect_timeout_s=timeout_s),
                               link_config=LinkConfig(target_sysid=target_system)) as v:
        deadline = asyncio.get_running_loop().time() + 3.0
        while v.telemetry.position is None and asyncio.get_running_loop().time() < deadline:
            await asyncio.sleep(0.05)  # poll until the first position arrives (bounded)
        console.print(_status_table(v, None, None))
        st = v.link.telemetry.sys_status
        if st is not None:
            console.print(
                f"ready to arm: {'yes' if st.armable else 'no'}, "
                f"battery {st.battery_remaining_pct} %"
            )
    return 0
