"""`python -m companion fly` and `status`: connect to PX4 (or an embedded mock), take off, fly a
mission file or a built-in pattern with flatness setpoints, land; rich live status."""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import datetime as dt
import json
import math
import socket
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console
from rich.live import Live
from rich.markup import escape
from rich.table import Table

from companion.control import Reference
from companion.flight.policy import (
    HANDOVER_HEIGHT_M,
    ROVER_SETTLE_S,
    lands_at_end,
    plan_touchdown,
    stall_s,
)
from companion.flight.report import (
    FlightReport,
    FloatArray,
    SetpointLimits,
    TrackRecorder,
    breach_failure,
    missed_result,
)
from companion.flight.tracking import TOUCHDOWN_FROM_M, Touchdown, TrackingSource
from companion.mavlink import FlightMode, LinkConfig
from companion.mission import (
    FlightPlan,
    Mission,
    geodetic_to_ned,
    load_mission,
    mission_to_flight_plan,
    rehome_mission,
)
from companion.mission.px4_params import Px4PlanningParams
from companion.planning.config import VehicleFile, load_vehicle_file
from companion.planning.fence_check import (
    breach_report,
    flown_breaches,
    require_plan_inside,
    sample_schedule,
    zone_masks,
)
from companion.planning.legs import leg_figures, plan_bounds, plan_legs, worst_leg_text
from companion.planning.schedule import Schedule, build_schedule, trajectory_reference
from companion.planning.vehicle_params import ResolvedPlanningParams, read_planning_params
from companion.trajectory import PiecewiseBezier
from companion.trajectory.patterns import PATTERNS, pattern_trajectory, pattern_waypoints

DEFAULT_HOME = (47.397742, 8.545594, 488.0)
#: A mission's planned home must be this close to the vehicle to be flown [m].
MAX_HOME_OFFSET_M = 5.0
#: How long `fly` waits for the vehicle's global position before the home check [s].
HOME_WAIT_S = 5.0
#: A pattern's interpolation points count as reached within this distance [m].
PATTERN_ACCEPTANCE_M = 1.0
#: Test patterns (figure-8, circle, square) accelerate at most this much [m/s^2], whatever the
#: vehicle allows (missions plan with the vehicle's PX4 limits): a pattern is a tracking test.
PATTERN_MAX_ACC_M_S2 = 3.0
MAV_TYPE_GROUND_ROVER = 10


@dataclass
class FlyOptions:
    """Options of `fly` (see `build_fly_parser` in companion.app.cli)."""

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
    signing_key: bytes | None = dataclasses.field(default=None, repr=False)  # MAVLink 2 signing
    connect_timeout_s: float = 10.0  # no vehicle HEARTBEAT within this: ConnectTimeoutError
    wind: tuple[float, float] | None = None  # expected wind (m/s, compass deg it blows from)


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@contextlib.asynccontextmanager
async def embedded_mock(
    home: tuple[float, float, float], mock_params: tuple[tuple[str, float], ...] = (),
    signing_key: bytes | None = None,
) -> AsyncIterator[str]:
    """Run `sitl_mock` in this process on loopback; yields the URL the companion connects to.
    With a signing key the mock signs everything and refuses unsigned frames."""
    import time

    from sitl_mock.autopilot import Autopilot
    from sitl_mock.params import ParamStore
    from sitl_mock.server import LinkConfig, MockServer, ServerConfig

    port = _free_udp_port()
    config = ServerConfig(links=[LinkConfig("offboard", ("127.0.0.1", 0), ("127.0.0.1", port))])
    server = MockServer(
        lambda remotes, now: Autopilot(
            "quad", ParamStore(dict(mock_params)), home, 0, remotes=remotes, now=now,
            signing_key=signing_key, unix_boot_s=time.time(),
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
        est = source.estimates()
        if est is not None:
            wind = ("-" if est.wind_m_s is None
                    else f"{est.wind_m_s:.1f} m/s from {est.wind_from_deg:03.0f} deg")
            t.add_row("wind (estimate)", wind)
            t.add_row("mass / thrust (estimate)", f"{est.mass_ratio:.2f} x assumed")
            if est.slowed_s > 0.05:
                t.add_row("slowed for the vehicle", f"{est.slowed_s:.1f} s behind the plan")
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


@dataclass(frozen=True)
class FlyInputs:
    """Everything `fly` reads from files and options, checked before connecting."""

    vehicle: VehicleFile
    mission: Mission | None
    home: tuple[float, float, float]
    log_path: str


def check_inputs(opts: FlyOptions) -> FlyInputs:
    """Load and check files and options; ValueError/FileNotFoundError before any link opens."""
    vf = load_vehicle_file(opts.vehicle_file) if opts.vehicle_file else VehicleFile()
    if opts.mode not in ("position", "attitude", "rates"):
        raise ValueError(f"--mode must be position, attitude or rates, got {opts.mode!r}")
    if not (math.isfinite(opts.rate_hz) and 2.0 < opts.rate_hz <= 1000.0):
        raise ValueError(f"--rate must be above 2 Hz (PX4's minimum) and at most 1000, "
                         f"got {opts.rate_hz:g}")
    mission = None
    home = DEFAULT_HOME
    if opts.target not in PATTERNS:
        if not Path(opts.target).is_file():
            raise ValueError(
                f"{opts.target}: no such mission file, and not a pattern "
                f"(patterns: {', '.join(PATTERNS)})"
            )
        mission = load_mission(opts.target)
        home = (mission.home.lat_deg, mission.home.lon_deg, mission.home.alt_amsl_m)
    else:
        if not (math.isfinite(opts.alt_m) and opts.alt_m > 0.5):
            raise ValueError(f"--alt must be above 0.5 m, got {opts.alt_m}")
        # the pattern's own argument checks (size, speed, laps) without planning it
        pattern_waypoints(opts.target, np.zeros(3), opts.size_m, opts.laps)
        if not (math.isfinite(opts.speed_m_s) and opts.speed_m_s > 0.0):
            raise ValueError(f"--speed must be a positive number of m/s, got {opts.speed_m_s}")
    log_path = opts.log or f"flight-{dt.datetime.now(dt.UTC):%Y%m%dT%H%M%SZ}.tlog"
    parent = Path(log_path).resolve().parent
    if not parent.is_dir():
        raise FileNotFoundError(f"log folder {parent} does not exist")
    return FlyInputs(vf, mission, home, log_path)


@dataclass(frozen=True)
class PlannedFlight:
    """A flight ready to go: reference relative to its start, and what to report against."""

    alt_m: float  # takeoff altitude above the ground [m]
    duration_s: float  # offboard part [s]
    start_rel: FloatArray  # reference position at t = 0, in the plan's own frame (NED, m)
    rel_ref: Callable[[float, FloatArray | None], Reference]  # t [s], origin -> reference
    waypoints_rel: FloatArray  # (K, 3) in the plan's frame
    acceptance_m: tuple[float, ...]
    final_action: str  # "land", "rtl" or "loiter"
    flight_plan: FlightPlan | None = None  # a mission's plan (legs, geofence); None: pattern
    schedule: Schedule | None = None  # a mission's schedule (the plan's frame)
    t_off_s: float = 0.0  # schedule time at which the offboard part starts [s]
    trajectory: PiecewiseBezier | None = None  # a pattern's trajectory (the plan's frame)


def plan_flight(opts: FlyOptions, inputs: FlyInputs, rover: bool,
                px4: Px4PlanningParams | None = None,
                fly_takeoff: bool = False, handover_height_m: float = 1.0) -> PlannedFlight:
    """Plan the mission or pattern (CPU-bound: run it off the event loop). ``px4``: the
    vehicle's planning parameters (None: PX4's defaults); patterns use their own options. A
    mission whose planned trajectory breaches its geofence raises MissionError naming the
    leg's items. fly_takeoff: the offboard part starts on the ground and flies the
    mission's takeoff climb (else it starts where PX4's NAV_TAKEOFF ended).
    handover_height_m: a multicopter's final descent ends this high above the ground [m]."""
    vf = inputs.vehicle
    if inputs.mission is not None:
        fp = mission_to_flight_plan(inputs.mission, vehicle="rover" if rover else "quad",
                                    px4=px4)
        schedule = build_schedule(fp, None if rover else vf.params, vf.limits,
                                  handover_height_m=handover_height_m)
        require_plan_inside(fp, schedule)
        t_off = 0.0 if fly_takeoff else _takeoff_end(schedule)

        def sched_ref(t: float, origin: FloatArray | None = None) -> Reference:
            return schedule.reference(t + t_off, origin)

        return PlannedFlight(fp.takeoff_alt_m, schedule.duration_s - t_off,
                             schedule.reference(t_off).pos_ned, sched_ref,
                             np.asarray(schedule.waypoints_ned, dtype=np.float64),
                             tuple(schedule.acceptance_m), schedule.final_action,
                             fp, schedule, t_off)
    traj = pattern_trajectory(
        opts.target, np.zeros(3), size_m=opts.size_m, speed_m_s=opts.speed_m_s,
        laps=opts.laps, yaw=0.0, params=vf.params,
        max_acc_m_s2=min(vf.limits.max_acc_m_s2, PATTERN_MAX_ACC_M_S2),
        max_tilt_rad=vf.limits.max_tilt_rad,
    )
    pattern_ref = trajectory_reference(traj, 0.0)

    def pat_ref(t: float, origin: FloatArray | None = None) -> Reference:
        r = pattern_ref(t)
        if origin is None:
            return r
        return Reference(r.pos_ned + origin, r.vel_ned, r.acc_ned, r.jerk_ned, r.snap_ned,
                         r.yaw, r.yaw_rate, r.yaw_acc)

    wps = pattern_waypoints(opts.target, np.zeros(3), opts.size_m, opts.laps)
    return PlannedFlight(opts.alt_m, traj.duration, np.zeros(3), pat_ref, wps,
                         (PATTERN_ACCEPTANCE_M,) * len(wps), "land", trajectory=traj)


async def rehome_at_vehicle(v: Any, mission: Mission, timeout_s: float
                            ) -> tuple[float, Mission, FloatArray | None]:
    """Where the vehicle stands against the mission's planned home (waits for a
    GLOBAL_POSITION_INT; ValueError without one): the horizontal distance [m] between them, the
    mission re-homed at the vehicle's latitude/longitude (`rehome_mission`: planned from there,
    its waypoints stay at their own coordinates, as PX4's AUTO.MISSION flies them), and the shift
    local NED -> that mission's frame (add it to a local position) [m], None without a local
    position."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout_s
    while v.telemetry.global_position is None and loop.time() < deadline:
        await asyncio.sleep(0.05)  # poll until the first global position (bounded)
    g = v.telemetry.global_position
    if g is None:
        raise ValueError(f"no global position from the vehicle within {timeout_s:g} s: cannot "
                         "check the mission's planned home (GPS?)")
    off = geodetic_to_ned(g.lat_deg, g.lon_deg, g.alt_amsl_m, mission.home)
    here = rehome_mission(mission, g.lat_deg, g.lon_deg)
    local = v.telemetry.position
    # the vehicle stands at the re-homed mission's home, off[2] below it (the altitude kept)
    shift = None if local is None else (np.array([0.0, 0.0, float(off[2])])
                                        - np.asarray(local.pos_ned, float))
    return math.hypot(off[0], off[1]), here, shift


def mission_figures(report: FlightReport, planned: PlannedFlight, recorder: TrackRecorder,
                    origin: FloatArray, fence_shift_ned: FloatArray | None) -> FlightReport:
    """`report` with the per-leg figures and geofence breaches of a flown mission (unchanged
    for a pattern).

    ``origin``: the plan's frame in local NED (local = plan + origin); ``fence_shift_ned``:
    local -> mission frame for the geofence (None: ``-origin``, the plan's frame)."""
    fp, schedule = planned.flight_plan, planned.schedule
    if fp is None or schedule is None:
        return report
    t = np.asarray(recorder.t_s, dtype=np.float64)
    pos = np.asarray(recorder.pos_ned, dtype=np.float64).reshape(-1, 3)
    if fp.vehicle == "rover":  # on the ground: its height estimate's drift is no deviation
        pos = pos.copy()
        pos[:, 2] = float(origin[2])
    shift = -np.asarray(origin, float) if fence_shift_ned is None else fence_shift_ned
    fence_pos = pos + shift
    masks = zone_masks(fp.geofence, fence_pos) if len(pos) and not fp.geofence.empty else []
    found = flown_breaches(fp, t, fence_pos) if masks else []
    # when PX4 flew the takeoff: the legs from the end of the companion's takeoff climb on
    all_legs = plan_legs(fp)
    leg_bounds, bound = plan_bounds(fp, schedule)
    flown = [k for k, leg in enumerate(all_legs)
             if planned.t_off_s <= 0.0 or leg.phase != "takeoff"]
    legs = [all_legs[k] for k in flown]
    pt, pp = sample_schedule(schedule)
    keep = pt >= planned.t_off_s
    return dataclasses.replace(
        report,
        geofence_violations=int(sum(int(np.count_nonzero(m)) for _, m in masks)),
        geofence_violation_zones=tuple(sorted(z for z, m in masks if m.any())),
        geofence_breaches=tuple(breach_report(found)),
        planned_s=round(schedule.duration_s, 3),
        bound_s=round(bound, 3),
        legs=tuple(leg_figures(legs, t, pos - origin, planned_t_s=pt[keep],
                               planned_ned=pp[keep], bounds_s=[leg_bounds[k] for k in flown])),
    )


def print_planning_params(console: Console, resolved: ResolvedPlanningParams,
                          where: str = "the vehicle") -> None:
    """The PX4 parameters a plan uses, one compact block (overrides and defaults marked; the
    warnings naming parameters the vehicle lacked are logged by ``read_planning_params``)."""
    console.print(f"PX4 parameters (read from {where}):")
    for line in resolved.lines():
        console.print(f"  {escape(line)}", soft_wrap=True)


def write_report(log_path: str, report: FlightReport) -> Path:
    """Write `report` as `<tlog>.report.json` next to the flight log; returns its path."""
    path = Path(f"{log_path}.report.json")
    path.write_text(json.dumps(report.to_dict(), indent=2) + "\n", encoding="utf-8")
    return path


def summary_table(report: FlightReport) -> Table:
    """A replay-like summary of one flight."""
    t = Table(title="flight summary", show_header=False)
    n = len(report.waypoints)
    t.add_row("result", report.result)
    t.add_row("waypoints reached", f"{report.waypoints_reached}/{n}")
    for val, label in ((report.rms_error_m, "RMS error \\[m]"),
                       (report.max_error_m, "max error \\[m]")):
        t.add_row(label, "-" if val is None else f"{val:.2f}")
    t.add_row("duration \\[s]", f"{report.duration_s:.1f} (planned "
              f"{report.planned_duration_s:.1f})")
    legs = report.legs
    if legs:
        t.add_row("worst leg", escape(worst_leg_text(legs).removeprefix("worst leg ")))
    return t


def wind_check(console: Console, wind: tuple[float, float], planned: PlannedFlight,
               vf: VehicleFile, px4: Px4PlanningParams | None) -> None:
    """`--wind`: the plan against the expected wind (`companion.planning.wind.check_wind`, the
    vehicle file's drag and mass, the tilt limit PX4's MPC_TILTMAX_AIR sets). ValueError (exit
    2, before anything is sent) when the vehicle cannot fly it; a warning when it will be
    flown slower."""
    from companion.planning.wind import check_wind, disturbance_of_wind

    p = vf.params
    tilt = SetpointLimits.of_px4(px4 if px4 is not None else Px4PlanningParams()).tilt_max_rad
    d = disturbance_of_wind(wind[0], wind[1], p.drag, p.mass)
    verdict = check_wind(lambda t: planned.rel_ref(t, None), planned.duration_s, d,
                         p.drag / p.mass, tilt, p.g)
    where = f"wind {wind[0]:g} m/s from {wind[1]:03.0f} deg"
    if not verdict.flyable:
        raise ValueError(f"not flyable in {where}: {verdict.reason}")
    if verdict.slowed:
        console.print(f"[yellow]{escape(where)}: {escape(verdict.reason)}[/yellow]")
    else:
        console.print(f"{escape(where)}: flyable as planned (up to "
                      f"{verdict.worst_tilt_deg:.0f} deg of tilt)")


async def fly(opts: FlyOptions, console: Console) -> int:
    """Run `fly`; returns the exit code (0 ok, 1 flight failure, 2 bad input).

    Safety order: files and options are checked before the link opens; the PX4 parameters the
    mission plans with are read (PARAM_REQUEST_READ only), the flight is planned and the
    mission's planned home compared with the vehicle's position before anything but link
    upkeep (HEARTBEAT, TIMESYNC, stream-rate requests) and those reads is sent, so a failed
    check never arms the vehicle.
    """
    from companion.aio import Vehicle, VehicleConfig, VehicleError, safe_exit

    inputs = check_inputs(opts)
    mission = inputs.mission
    log_path = inputs.log_path
    vconfig = VehicleConfig(rate_hz=opts.rate_hz, tlog_path=log_path,
                            stream_wait="busy" if opts.busy_wait else "sleep",
                            stream_cpu=opts.sender_cpu,
                            connect_timeout_s=opts.connect_timeout_s)
    recorder = TrackRecorder()
    report: FlightReport | None = None
    fence_shift: FloatArray | None = None
    async with contextlib.AsyncExitStack() as stack:
        url = opts.connect
        if url is None:
            url = await stack.enter_async_context(
                embedded_mock(inputs.home, opts.mock_params, opts.signing_key))
            console.print(f"No --connect: flying the embedded mock PX4 ({escape(url)})")
        link = LinkConfig(target_sysid=opts.target_system if opts.connect else 1
                          ).with_signing_key(opts.signing_key)
        if link.signing is not None:
            console.print("MAVLink 2 signing on: frames not signed with the key are dropped")
        v = await stack.enter_async_context(Vehicle.connect(url, config=vconfig,
                                                            link_config=link))
        await stack.enter_async_context(safe_exit(v))
        hb = v.link.heartbeat.last
        rover = hb is not None and hb.vehicle_type == MAV_TYPE_GROUND_ROVER
        mode = "rover" if rover else opts.mode
        console.print(
            f"Connected: {'rover' if rover else 'multicopter'}, logging to {escape(log_path)}")
        # every check that can fail, before the first command: read the PX4 parameters the
        # mission is planned with (only reads go out), plan (off the event loop, up to a
        # second) and compare the mission's home with where the vehicle is
        px4: ResolvedPlanningParams | None = None
        if mission is not None:
            px4 = await read_planning_params(v.fetch_params, inputs.vehicle.px4_overrides,
                                             vehicle="rover" if rover else "quad")
            print_planning_params(console, px4)
        # a multicopter mission from the ground: the plan flies the takeoff too, armed in
        # OFFBOARD (PX4's NAV_TAKEOFF spool-up and the switch after it cost ~5 s)
        fly_takeoff = mission is not None and not rover and not v.is_armed
        # a rover on the ground is armed in OFFBOARD too (as the replay does): the stream is
        # primed and OFFBOARD confirmed before the ARM, so it drives off as soon as it is armed
        # (armed first, the priming and the OFFBOARD HEARTBEAT cost 1.3 s more than
        # AUTO.MISSION's start on PX4 main's SIH rover: first motion 2.1 s vs 0.8 s after ARM)
        arm_in_offboard = fly_takeoff or (rover and not v.is_armed)
        # attitude and rates mode land the vehicle themselves: the plan's descent ends
        # TOUCHDOWN_FROM_M up, a Touchdown takes over where it stops cruising and descends at
        # MPC_LAND_SPEED until PX4 sees the landing (PX4's LAND crawls the last metre at
        # MPC_LAND_CRWL and took ~4 s to detect it)
        touchdown = mission is not None and not rover and mode in ("attitude", "rates")
        if mode == "attitude":
            refused = await v.stream_position_fast()
            if refused is not None:
                console.print(f"[yellow]{escape(refused)}[/yellow]")
        if mission is not None:
            # planned from where the vehicle stands to the file's own coordinates
            horiz, here, fence_shift = await rehome_at_vehicle(v, mission, HOME_WAIT_S)
            if horiz > MAX_HOME_OFFSET_M:
                raise ValueError(
                    f"{opts.target}: planned home is {horiz:.0f} m from the vehicle "
                    f"(limit {MAX_HOME_OFFSET_M:g} m); move the vehicle there or "
                    "edit plannedHomePosition")
            inputs = dataclasses.replace(inputs, mission=here)
        planned = await asyncio.to_thread(
            plan_flight, opts, inputs, rover, None if px4 is None else px4.params, fly_takeoff,
            TOUCHDOWN_FROM_M if touchdown else HANDOVER_HEIGHT_M)
        if opts.wind is not None and not rover:
            wind_check(console, opts.wind, planned, inputs.vehicle,
                       None if px4 is None else px4.params)
        source: TrackingSource | None = None
        started: float | None = None
        ended: float | None = None

        async def show(live: Live) -> None:
            while True:
                live.update(_status_table(v, source, started, ended))
                await asyncio.sleep(0.2)  # display refresh period

        async def record() -> None:
            async for p in v.position():
                if source is None or source.touching_down:  # the plan, not the touchdown
                    continue
                ref = source.last_reference
                if ref is not None and v.mode is FlightMode.OFFBOARD:
                    # stamped with the vehicle's own sample time: a PX4 SITL that stalls
                    # delivers a burst of samples whose receive times made leg speeds of
                    # 12-18 m/s out of a 5-8 m/s flight
                    recorder.add(p.time_boot_s, p.pos_ned, ref.pos_ned)

        with Live(_status_table(v, None, None), console=console, refresh_per_second=5) as live:
            loop = asyncio.get_running_loop()
            ui = loop.create_task(show(live))
            rec: asyncio.Task[None] | None = None
            try:
                if arm_in_offboard:
                    await v.wait_armable()
                else:
                    await v.arm()
                    if not rover:
                        await v.takeoff(planned.alt_m)
                snap = v.telemetry
                if snap.position is None:
                    raise VehicleError("no position telemetry")
                here = np.asarray(snap.position.pos_ned, dtype=float)
                origin = here - planned.start_rel
                rel_ref = planned.rel_ref

                def ref(t: float) -> Reference:
                    return rel_ref(t, origin)

                vf = inputs.vehicle
                landing = lands_at_end("rover" if rover else "quad", planned.final_action)
                land_speed = (px4.params.MPC_LAND_SPEED if px4 is not None
                              else Px4PlanningParams().MPC_LAND_SPEED)
                td: Touchdown | None = None
                if touchdown and landing and planned.schedule is not None:
                    td = plan_touchdown(planned.schedule, land_speed, planned.t_off_s)
                limits = SetpointLimits.of_px4(px4.params if px4 is not None
                                               else Px4PlanningParams())
                source = TrackingSource(
                    ref, mode, vf.params,  # type: ignore[arg-type]
                    tracking=(vf.tracking_config(limits.tilt_max_rad)
                              if mode in ("attitude", "rates") else None),
                    touchdown=td, limits=limits)
                rec = loop.create_task(record())
                started = loop.time()
                # a rover's reference waits for it (TrackingSource's ProgressGovernor): it ends
                # once within the last waypoint's acceptance radius, or ROVER_SETTLE_S after
                # its reference ended (then the report names the waypoints it missed)
                wps = planned.waypoints_rel + origin
                rover_end = rover and len(wps) > 0
                flown = await v.fly(mode=mode, setpoint_source=source,
                                    duration_s=planned.duration_s if td is None else td.from_s,
                                    arm=arm_in_offboard,
                                    end_action=("touchdown" if source.touchdown is not None
                                                else "land" if landing else "hold"),
                                    # landed and disarmed (a rover: disarmed in Hold)
                                    disarm=rover or landing,
                                    end_ned=(tuple(float(x) for x in wps[-1])  # type: ignore[arg-type]
                                             if rover_end else None),
                                    settle_m=(float(planned.acceptance_m[-1]) if rover_end
                                              else None),
                                    settle_s=ROVER_SETTLE_S if rover_end else None,
                                    stall_s=stall_s("rover" if rover else "quad", mode))
                ended = loop.time()
                console.print(f"Trajectory flown in {mode} mode: {flown.duration_s:.1f} s")
                report = dataclasses.replace(
                    recorder.summary(planned.waypoints_rel + origin, planned.acceptance_m,
                                     duration_s=flown.duration_s,
                                     planned_duration_s=planned.duration_s, horizontal=rover),
                    result="ok", mode=mode, target=opts.target,
                    final_action=planned.final_action,
                    px4_params=None if px4 is None else px4.as_report())
                report = mission_figures(report, planned, recorder, origin, fence_shift)
                bad = source.quality.failure()
                report = dataclasses.replace(
                    report, setpoint_quality=source.quality.figures(),
                    estimates=source.estimates(),
                    result=breach_failure(report) or (
                        f"setpoints: {bad}" if bad is not None else "ok"))
                # a flight that missed a waypoint is not "ok"
                report = dataclasses.replace(report, result=missed_result(report))
            except Exception as exc:
                if recorder.t_s:  # what was flown before the failure, for the post-mortem
                    report = dataclasses.replace(
                        recorder.summary(None, (), duration_s=recorder.t_s[-1]
                                         - recorder.t_s[0],
                                         planned_duration_s=planned.duration_s),
                        result=f"failed: {exc}", mode=mode, target=opts.target)
                    write_report(log_path, report)
                raise
            finally:
                for task in (ui, rec):
                    if task is not None:
                        task.cancel()
                        with contextlib.suppress(asyncio.CancelledError):
                            await task
                live.update(_status_table(v, source, started, ended or 0.0))
    if report is not None:
        report = dataclasses.replace(report, ok=report.result == "ok")
        console.print(summary_table(report))
        for b in report.geofence_breaches or ():
            console.print(f"[red]geofence breach in flight:[/red] {escape(str(b['message']))}")
        console.print(f"Report: {escape(str(write_report(log_path, report)))}")
    console.print(f"Done. Log: {escape(str(Path(log_path).resolve()))}")
    return 0 if report is None or report.result == "ok" else 1


async def status(url: str, console: Console, timeout_s: float = 10.0,
                 target_system: int = 1, signing_key: bytes | None = None) -> int:
    """Connect, wait for telemetry, print the vehicle state once (signed with ``signing_key``);
    ConnectTimeoutError without a vehicle HEARTBEAT within ``timeout_s``."""
    from companion.aio import Vehicle, VehicleConfig

    link = LinkConfig(target_sysid=target_system).with_signing_key(signing_key)
    async with Vehicle.connect(url, config=VehicleConfig(connect_timeout_s=timeout_s),
                               link_config=link) as v:
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
