"""Lockstep replay: the companion's protocol core and controllers fly a mission file against
the `sitl_mock` autopilot core over an in-memory link on a simulated clock.

Nothing here sleeps or reads a clock: both sides are sans-IO and advance together in steps of
one setpoint period, so a replay runs as fast as the CPU allows and is deterministic for a seed.
Every frame in both directions is written to a `.tlog` (8-byte big-endian microsecond
timestamp + raw MAVLink frame), readable by pymavlink, MAVExplorer and QGroundControl.

The parts: `companion.replay.config` (how to replay), `companion.replay.lockstep` (the link
and the mock), `companion.replay.flight` (the flight sequence over it, PX4's own mission) and
`companion.flight.summary` (the flight's log and figures). This module prepares a mission,
flies it and writes the outputs; flight.png is drawn by the caller's `draw` (the plotting is
an application concern: `companion.app.plotting`).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import shutil
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from companion.aio.tlog import TlogWriter
from companion.flight.report import (
    FlightReport,
    breach_result,
    closest_approach,
    missed_result,
    report_ok,
)
from companion.flight.sequence import Phase
from companion.flight.summary import FlightLog, summarize, tracking_error
from companion.mission import (
    FlightPlan,
    Mission,
    MissionError,
    load_mission,
    mission_to_flight_plan,
    ned_to_geodetic,
    rehome_mission,
)
from companion.mission.px4_params import planning_param_names
from companion.planning.fence_check import require_plan_inside
from companion.planning.legs import plan_bounds
from companion.planning.schedule import Schedule, build_schedule
from companion.planning.vehicle_params import ResolvedPlanningParams, resolve_planning_params
from companion.replay.config import (
    DEFAULT_QUAD,
    EXPECTED_OVERHEAD_S,
    PRIME_S,
    SETTLE_S,
    TLOG_EPOCH_S,
    Mode,
    ReplayConfig,
    handover_height_m,
    planning_limits,
    self_lands,
)
from companion.replay.flight import Flight, fly_px4_mission, fly_schedule, mission_frames
from companion.replay.lockstep import COMPANION_MSG_IDS, LockstepLink, read_mock_params
from companion.replay.onboard import OnboardFlight, fly_onboard_schedule

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class ReplayResult:
    """Outcome of one replayed file: output folder, report, and whether it succeeded."""

    name: str
    out_dir: Path
    report: FlightReport
    ok: bool


@dataclass(frozen=True)
class FlightPicture:
    """What flight.png shows of one replay: its title, the companion's log, the schedule it
    flew, the flight's origin (plan frame -> local NED [m]), PX4's own mission flight (None:
    not flown) and the per-leg figures of the report (None: none)."""

    title: str
    log: FlightLog
    schedule: Schedule
    origin: FloatArray
    px4_log: FlightLog | None = None
    legs: tuple[dict[str, object], ...] | None = None

    def tracking_error(self) -> tuple[FloatArray, FloatArray]:
        """(t [s], |flown - planned| [m]) while flying the plan (`tracking_error`)."""
        return tracking_error(self.log, self.schedule, self.origin)


#: Draws flight.png at a path (e.g. `companion.app.plotting.draw_replay`).
Draw = Callable[[Path, FlightPicture], None]


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



def prepare_mission(
    path: str | os.PathLike[str], config: ReplayConfig, *, bounds: bool = True
) -> PreparedMission:
    """Load and plan `path` as `config` would fly it: the PX4 planning parameters are read
    from the mock first (`read_mock_params`, so `--mock-param MPC_XY_CRUISE=8` changes the
    plan as the vehicle's parameter would). Raises MissionError on a bad file and on a plan
    whose trajectory breaches the mission's geofence (naming the leg's items).

    `bounds`: also compute the time-optimal bounds of the legs and of the plan (the report's
    "bound" figures; False leaves them unknown, for callers that do not report them: a
    campaign's runs)."""
    src = Path(path)
    mission = load_mission(src)
    home = (mission.home.lat_deg, mission.home.lon_deg, mission.home.alt_amsl_m)
    if config.start_offset_ne_m != (0.0, 0.0):
        # the vehicle boots that far from the planned home: planned from there to the file's
        # own coordinates, as `fly` plans from where the vehicle stands
        n, e = config.start_offset_ne_m
        lat, lon, _ = ned_to_geodetic(np.array([n, e, 0.0]), mission.home)
        mission = rehome_mission(mission, float(lat), float(lon))
    read = read_mock_params(config, home, planning_param_names(config.vehicle))
    px4 = resolve_planning_params(read.values, wrong_type=read.wrong_type, where="the mock",
                                  vehicle=config.vehicle)
    flight_plan = mission_to_flight_plan(mission, vehicle=config.vehicle, px4=px4.params)
    params = None if config.vehicle == "rover" else config.params
    schedule = build_schedule(
        flight_plan, params, planning_limits(config),
        handover_height_m=handover_height_m(config, flight_plan.final_action))
    require_plan_inside(flight_plan, schedule)
    warnings = (*flight_plan.warnings, *px4.warnings, *schedule.warnings)
    if not bounds:
        return PreparedMission(src, mission, warnings, schedule, home, px4, flight_plan)
    leg_bounds, bound = plan_bounds(flight_plan, schedule)
    return PreparedMission(src, mission, warnings, schedule, home, px4, flight_plan, leg_bounds,
                           bound)


@dataclass(frozen=True)
class ReplayRun:
    """One flight of a prepared mission: the flight (streamed, or onboard: the module flies),
    its log and its report (see summarize)."""

    flight: Flight | OnboardFlight
    log: FlightLog
    report: FlightReport

    @property
    def schedule(self) -> Schedule:
        return self.flight.schedule

    @property
    def ok(self) -> bool:
        """Completed inside the geofence and reached every waypoint."""
        return report_ok(self.report)


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
    if config.onboard:
        return _run_onboard(prep, config, tlog, progress, wall0)
    flight, log = fly_schedule(config, schedule, prep.home, tlog, progress)
    quality = flight.source.quality
    report = _flown_report(
        prep, config, flight, log, tlog, wall0,
        mode=config.mode,
        setpoint_rate_hz=config.rate_hz,
        setpoints_sent=flight.setpoints_sent,
        result="ok" if flight.phase == Phase.DONE else f"aborted: {flight.reason}",
        setpoint_quality=quality.figures(),
        estimates=flight.source.estimates(),
    )
    bad = quality.failure()
    return _finish(ReplayRun(flight, log, report), config,
                   None if bad is None else f"setpoints: {bad}")


def _run_onboard(prep: PreparedMission, config: ReplayConfig, tlog: TlogWriter | None,
                 progress: Callable[[float, float], None] | None, wall0: float) -> ReplayRun:
    """`run_prepared` of an onboard flight (`companion.replay.onboard`): the module's law
    is given PX4's MPC_THR_HOVER, read from the mock as `fly --onboard` reads it."""
    hover = read_mock_params(config, prep.home, ("MPC_THR_HOVER",)).values["MPC_THR_HOVER"]
    flight, log = fly_onboard_schedule(config, prep.schedule, prep.home, tlog, hover, progress)
    report = _flown_report(
        prep, config, flight, log, tlog, wall0, mode="onboard", setpoint_rate_hz=None,
        setpoints_sent=flight.setpoints_sent,
        result="ok" if flight.ok else f"aborted: {flight.reason}")
    return _finish(ReplayRun(flight, log, report), config, None)


def _flown_report(prep: PreparedMission, config: ReplayConfig, flight: Flight | OnboardFlight,
                  log: FlightLog, tlog: TlogWriter | None, wall0: float,
                  **fields: Any) -> FlightReport:
    """The flight's summary (`summarize`) with the run's figures and `fields` (the flight
    kind's own: mode, result, setpoint figures)."""
    wall = time.perf_counter() - wall0
    flown = summarize(log, prep.schedule, prep.mission, flight.origin,
                      flight_plan=prep.flight_plan,
                      leg_bounds_s=prep.leg_bounds_s, bound_s=prep.bound_s)
    sim_s = flight.lk.now
    return dataclasses.replace(
        flown,
        file=str(prep.path),
        vehicle=config.vehicle,
        tlog_frames=tlog.frames if tlog is not None else None,
        simulated_s=round(sim_s, 3),
        wall_s=round(wall, 3),
        real_time_factor=round(sim_s / wall, 1) if wall > 0 else None,
        warnings=tuple(prep.warnings),
        px4_params=None if prep.px4 is None else prep.px4.as_report(),
        **fields,
    )


def _finish(run: ReplayRun, config: ReplayConfig, setpoint_failure: str | None) -> ReplayRun:
    """The run's result and verdict: the geofence, the setpoints' quality, the waypoints
    (and, started away from the planned home, how far it passed from the mission's)."""
    flight, log, report = run.flight, run.log, run.report
    schedule = run.schedule
    result = breach_result(report)
    if setpoint_failure is not None and result == "ok":
        result = setpoint_failure
    # a waypoint passed outside its acceptance radius fails the flight in its result too,
    # not only in `ok` (a campaign's row and report.json said "ok" for such a flight)
    report = dataclasses.replace(report, result=result)
    report = dataclasses.replace(report, result=missed_result(report))
    report = dataclasses.replace(report, ok=report_ok(report))
    if config.start_offset_ne_m != (0.0, 0.0):
        # started away from the planned home: how far the flight passed from the file's own
        # (geodetic) waypoints, which the plan, made about where the vehicle booted, keeps
        pos = np.asarray(log.pos, dtype=np.float64).reshape(-1, 3)
        wps = schedule.waypoints_ned + flight.origin
        report = dataclasses.replace(report, max_waypoint_miss_geo_m=(
            float(np.max(closest_approach(pos, wps))) if len(wps) else 0.0))
    return ReplayRun(flight, log, report)


def replay_file(
    path: str | os.PathLike[str],
    out_root: str | os.PathLike[str],
    config: ReplayConfig,
    progress: Callable[[float, float], None] | None = None,
    draw: Draw | None = None,
) -> ReplayResult:
    """Replay one mission file; writes `out_root/<name>/{flight.tlog, report.json, flight.png}`
    atomically (a temporary folder renamed at the end). Raises MissionError on a bad file.

    `draw(path, picture)` draws flight.png (e.g. `companion.app.plotting.draw_replay`, or a
    `PlotWorker`'s); None writes no flight.png."""
    prep = prepare_mission(path, config)
    src, mission, schedule, home = prep.path, prep.mission, prep.schedule, prep.home
    name = src.stem
    out_root = Path(out_root)
    out_root.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{name}.", dir=out_root))
    try:
        with TlogWriter(tmp / "flight.tlog", buffer_bytes=1 << 20) as tlog:
            run = run_prepared(prep, config, tlog, progress)
        flight, log = run.flight, run.log
        report = dataclasses.replace(run.report, tlog_frames=tlog.frames)
        px4_log = None
        if config.compare_px4_mission:
            res, px4_log = fly_px4_mission(config, mission, home, schedule.duration_s)
            px4 = summarize(px4_log, schedule, mission, flight.origin,
                            flight_plan=prep.flight_plan, kind="px4_mission")
            px4 = dataclasses.replace(px4, result=res)
            px4 = dataclasses.replace(px4, result=breach_result(px4))
            px4 = dataclasses.replace(px4, result=missed_result(px4))
            px4 = dataclasses.replace(px4, ok=report_ok(px4))
            report = dataclasses.replace(report, px4_mission=px4)
        with open(tmp / "report.json", "w", encoding="utf-8") as f:
            json.dump(report.to_dict(), f, indent=2, allow_nan=False, default=_json_default)
        if draw is not None:
            draw(tmp / "flight.png", FlightPicture(
                f"{src.name}: {config.vehicle}, "
                f"{'the onboard module' if config.onboard else config.mode + ' mode'}", log,
                schedule,
                flight.origin, px4_log, report.legs))
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
    "COMPANION_MSG_IDS",
    "DEFAULT_QUAD",
    "EXPECTED_OVERHEAD_S",
    "PRIME_S",
    "SETTLE_S",
    "TLOG_EPOCH_S",
    "Draw",
    "Flight",
    "FlightLog",
    "FlightPicture",
    "FlightReport",
    "LockstepLink",
    "MissionError",
    "Mode",
    "Phase",
    "PreparedMission",
    "ReplayConfig",
    "ReplayResult",
    "ReplayRun",
    "breach_result",
    "fly_px4_mission",
    "fly_schedule",
    "missed_result",
    "mission_frames",
    "planning_limits",
    "prepare_mission",
    "read_mock_params",
    "replay_file",
    "report_ok",
    "run_prepared",
    "self_lands",
    "summarize",
    "tracking_error",
]
