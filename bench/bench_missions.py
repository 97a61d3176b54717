"""Missions: the companion against PX4's own AUTO.MISSION (issue 13's goals), in three parts.

mock (lockstep replay, `companion.replay.runner`): every bundled mission in examples/missions
  (rover_square.plan as a rover) flown by the companion (`prepare_mission` + `run_prepared`,
  attitude mode) and, on a second fresh mock with the same `ReplayConfig` (same PX4
  parameters), in the mock's AUTO.MISSION (`fly_px4_mission`). Per mission:
  - time: from the arm COMMAND_ACK to the first HEARTBEAT showing the vehicle disarmed (both
    flights the same way; a mission ending in loiter: to the first HEARTBEAT in Hold after the
    companion's plan / after "Mission finished"); ratio companion / AUTO.MISSION (goal <= 0.8);
  - closest approach of the flown path (LOCAL_POSITION_NED samples joined by straight lines,
    armed part) to each mission waypoint of the schedule (goal <= 0.5 m for the companion);
  - deviation from the straight legs: distance of each sample to the polyline start, waypoints,
    touchdown of `FlightPlan.points_ned_m()`; inside the corridor when within `--corridor` m
    (default 1) of it or within a waypoint's acceptance radius (corners may be cut there);
  - planned duration vs the time-optimal bound of the same plan and limits, when the planner
    provides one (`time_optimal_bound_s(flight_plan, params, limits)` in
    companion.planning.schedule or companion.trajectory; "n/a" otherwise).
px4 (real PX4 v1.16 SITL, real time, ../shared/px4_sitl through px4_harness.Px4Sitl, each
  flight on a fresh PX4 holding /tmp/ecca-px4-flights.lock): `--px4-mission` (default
  examples/missions/square.plan) flown by `python -m companion fly --connect ... --mode attitude`
  and by PX4's AUTO.MISSION (bench_fidelity's mission flight: upload, arm, mission start),
  `--repeat` times each. Armed time from each flight's .tlog (arm COMMAND_ACK accepted to the
  first disarmed HEARTBEAT, +-1 s: PX4's HEARTBEAT is 1 Hz); closest approach of each waypoint
  (the flight plan's, placed at PX4's HOME_POSITION) from PX4's LOCAL_POSITION_NED and from the
  ground truth HIL_STATE_QUATERNION (requested at 50 Hz on PX4's GCS link, UDP 14550, by a
  recorder in this process; "-" when that port is taken).
px4 with `--build main` (PX4 built from main, ../shared/px4_main_sitl, SIH's Ackermann rover
  `--model sihsim_rover_ackermann` by default): every examples/missions/*rover* file (or
  `--px4-mission`) driven by `python -m companion fly` (rover mode) and by PX4's own
  AUTO.MISSION, flown as an outsider with pymavlink (bench/rover_link.py: upload, arm in Hold
  retried until the estimator is ready, DO_SET_MODE AUTO.MISSION, wait until the rover leaves
  AUTO.MISSION or disarms), each on a fresh PX4. From each .tlog, the same way for both
  (`rover_tlog_figures`): armed time (arm COMMAND_ACK to the first HEARTBEAT out of
  AUTO.MISSION, or out of OFFBOARD for the companion, or disarmed), closest approach of each
  waypoint (horizontal, LOCAL_POSITION_NED, and the ground truth HIL_STATE_QUATERNION at 50 Hz),
  deviation from the straight legs (home, waypoints). `--write` then replaces the section
  "Missions: companion vs PX4 AUTO.MISSION on the rover (PX4 main)" instead.
planning: wall time of `build_schedule` on a 100-waypoint mission with speed changes (the
  vehicle's default limits, which include every limit and the corridor once the planner has
  them) against the plain fixed-duration minimum-snap solve of the same points in the same run
  (`plan(points, durations=leg / speed)`); goal < 300 ms.

Run: `.venv/bin/python bench/bench_missions.py [--parts mock px4 planning] [--repeat 1]
[--write | --write-baseline]`. Do not wrap it in flock: it takes the PX4 flight lock itself,
around each real-PX4 flight only. `--write` replaces the section "Missions: companion vs
AUTO.MISSION" of BENCHMARKS.md, `--write-baseline` the section "Missions: companion vs
AUTO.MISSION (pre-change baseline)"; `--reuse-px4 JSON` takes the real-PX4 figures from an
earlier run's JSON (`OUT/missions.json`) instead of flying again.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import dataclasses
import json
import math
import os
import platform
import shlex
import shutil
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

BENCH = Path(__file__).resolve().parent
REPO = BENCH.parent
if str(BENCH) not in sys.path:
    sys.path.insert(0, str(BENCH))
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from mission_metrics import closest_approach_path, corridor_check  # noqa: E402

from companion.mission import (  # noqa: E402
    FlightPlan,
    GeoPoint,
    Mission,
    geodetic_to_ned,
    loads_mission,
    mission_to_flight_plan,
)
from companion.planning.schedule import VehicleLimits, build_schedule  # noqa: E402
from companion.replay.runner import (  # noqa: E402
    DEFAULT_QUAD,
    FlightLog,
    Phase,
    PreparedMission,
    ReplayConfig,
    fly_px4_mission,
    prepare_mission,
    run_prepared,
)
from px4_harness import flight_lock  # noqa: E402

MISSIONS_DIR = REPO / "examples" / "missions"
ROVER_MISSIONS = tuple(sorted(p.name for p in MISSIONS_DIR.glob("*rover*")))
SECTION = "Missions: companion vs AUTO.MISSION"
SECTION_BASELINE = SECTION + " (pre-change baseline)"
SECTION_ROVER = "Missions: companion vs PX4 AUTO.MISSION on the rover (PX4 main)"
GOAL_RATIO = 0.8
GOAL_WP_M = 0.5
GOAL_BOUND_RATIO = 1.15
GOAL_PLAN_S = 0.300
GCS_PORT = 14550


# ----------------------------------------------------------------------------- shared


BOUND_CALL = "time_optimal_bound_s(flight_plan, params, limits)"


def time_optimal_bound() -> tuple[Callable[..., float] | None, str]:
    """The planner's `time_optimal_bound_s(flight_plan, params, limits) -> s` (same arguments
    as `build_schedule`), or None and why."""
    import importlib

    for mod in ("companion.planning.schedule", "companion.trajectory"):
        fn = getattr(importlib.import_module(mod), "time_optimal_bound_s", None)
        if callable(fn):
            return fn, f"`{mod}.{BOUND_CALL}`"
    return None, (f"n/a: the planner has no `{BOUND_CALL}` (looked in "
                  "companion.planning.schedule and companion.trajectory)")


def flight_plan_of(prep: PreparedMission, vehicle: str) -> FlightPlan:
    """The FlightPlan the schedule was built from (`prep.flight_plan` once replay keeps it;
    else expanded again with the same defaults as `prepare_mission`)."""
    fp = getattr(prep, "flight_plan", None)
    if isinstance(fp, FlightPlan):
        return fp
    return mission_to_flight_plan(prep.mission, vehicle=vehicle)  # type: ignore[arg-type]


def corner_points(fp: FlightPlan) -> tuple[np.ndarray, np.ndarray]:
    """(waypoints (K, 3) NED about home, acceptance radii (K,)) of the flight plan."""
    w = np.array([p.pos_ned_m for p in fp.waypoints], dtype=np.float64).reshape(-1, 3)
    return w, np.array([p.acceptance_radius_m for p in fp.waypoints], dtype=np.float64)


def path_metrics(pos: np.ndarray, wps: np.ndarray, legs: np.ndarray, corners: np.ndarray,
                 acc: np.ndarray, corridor_m: float) -> dict[str, Any]:
    """Closest approach per waypoint and the corridor figures of one flown path (NED [m])."""
    ca = closest_approach_path(pos, wps)
    cr = corridor_check(pos, legs, corners, acc, corridor_m)
    return {"closest_m": [float(c) for c in ca],
            "max_closest_m": float(np.max(ca)) if len(ca) else math.nan,
            "max_dev_m": cr.max_dev_m, "rms_dev_m": cr.rms_dev_m, "samples": cr.samples,
            "outside": cr.outside, "max_excess_m": cr.max_excess_m, "within": cr.within,
            "outside_pct": 100.0 * cr.outside / cr.samples if cr.samples else math.nan}


# ----------------------------------------------------------------------------- mock


def _window(log: FlightLog, t0: float, t1: float) -> np.ndarray:
    t = np.asarray(log.t)
    pos = np.asarray(log.pos, dtype=np.float64).reshape(-1, 3)
    return pos[(t >= t0) & (t <= t1)]


def _disarmed_at(log: FlightLog, t_from: float, heartbeat_t: float | None,
                 ends: tuple[str, ...] = ("Disarmed",)) -> float:
    """When the flight ended: the first mock STATUSTEXT after `t_from` starting with one of
    `ends` ("Disarmed by ...", sent at the moment it disarms), else the first HEARTBEAT
    showing it (`heartbeat_t`, 1 Hz)."""
    for t, _sev, text in log.statustext:
        if t >= t_from and text.startswith(ends):
            return t
    return heartbeat_t if heartbeat_t is not None else math.nan


def mock_mission(path: Path, config: ReplayConfig, corridor_m: float,
                 bound_fn: Callable[..., float] | None) -> dict[str, Any]:
    """Fly `path` with the companion and in AUTO.MISSION on fresh mocks; the figures."""
    prep = prepare_mission(path, config)
    sched = prep.schedule
    wall0 = time.perf_counter()
    run = run_prepared(prep, config, None)
    flight, clog = run.flight, run.log
    # companion: arm ACK (start of FLY) to the disarmed HEARTBEAT, or to Hold at a loiter end
    t0 = clog.fly_t0 if clog.fly_t0 is not None else math.nan
    t1 = _disarmed_at(clog, t0, clog.disarmed_t)
    if math.isnan(t1) and flight.phase == Phase.DONE:  # loiter ending: Hold seen
        t1 = flight.t_phase
    res, plog = fly_px4_mission(config, prep.mission, prep.home, sched.duration_s)
    p0 = plog.armed_t if plog.armed_t is not None else math.nan
    p1 = _disarmed_at(plog, p0, plog.disarmed_t, ("Disarmed", "Mission finished"))
    wall = time.perf_counter() - wall0
    origin = flight.origin
    fp = flight_plan_of(prep, config.vehicle)
    legs = fp.points_ned_m() + origin
    corners, acc = corner_points(fp)
    wps = sched.waypoints_ned + origin
    comp_ok = run.report.result
    out: dict[str, Any] = {
        "file": path.name, "vehicle": config.vehicle,
        "companion": {"result": comp_ok, "time_s": t1 - t0,
                      **path_metrics(_window(clog, t0, t1), wps, legs, corners + origin, acc,
                                     corridor_m)},
        "auto_mission": {"result": res, "time_s": p1 - p0,
                         **path_metrics(_window(plog, p0, p1), wps, legs, corners + origin,
                                        acc, corridor_m)},
        "planned_s": sched.duration_s, "item_indices": list(sched.item_indices),
        "acceptance_m": list(sched.acceptance_m), "warnings": list(prep.warnings),
        "report_closest_m": [w.closest_approach_m for w in run.report.waypoints],
        "wall_s": wall, "limits": dataclasses.asdict(config.limits),
        "mock_params": dict(config.mock_params),
    }
    out["ratio"] = out["companion"]["time_s"] / out["auto_mission"]["time_s"]
    out["bound_s"] = math.nan
    if bound_fn is not None:
        params = None if config.vehicle == "rover" else config.params
        try:
            out["bound_s"] = float(bound_fn(fp, params, config.limits))
        except Exception as exc:  # the bound is optional: say why it is missing
            out["bound_error"] = f"{type(exc).__name__}: {exc}"
    return out


def mock_missions(args: argparse.Namespace, bound_fn: Callable[..., float] | None
                  ) -> list[dict[str, Any]]:
    files = sorted([*MISSIONS_DIR.glob("*.plan"), *MISSIONS_DIR.glob("*.waypoints")])
    if args.missions:
        extra = [Path(m).resolve() for m in args.missions if Path(m).is_file()]
        files = [f for f in files if f.name in args.missions or f.stem in args.missions] + extra
    rows = []
    mock_params = tuple((k, float(v)) for k, v in (p.split("=", 1) for p in args.mock_param))
    for f in files:
        vehicle = "rover" if f.name in ROVER_MISSIONS else "quad"
        config = ReplayConfig(vehicle=vehicle, mode="attitude", mock_params=mock_params)
        try:
            row = mock_mission(f, config, args.corridor, bound_fn)
        except Exception as exc:  # one file must not lose the others
            row = {"file": f.name, "vehicle": vehicle, "error": f"{type(exc).__name__}: {exc}"}
        rows.append(row)
        if "error" in row:
            print(f"mock {f.name}: ERROR {row['error']}", flush=True)
        else:
            c, p = row["companion"], row["auto_mission"]
            print(f"mock {f.name} ({vehicle}): companion {c['time_s']:.1f} s / AUTO.MISSION "
                  f"{p['time_s']:.1f} s = {row['ratio']:.2f}; worst waypoint "
                  f"{c['max_closest_m']:.2f} / {p['max_closest_m']:.2f} m; max dev "
                  f"{c['max_dev_m']:.2f} / {p['max_dev_m']:.2f} m "
                  f"({row['wall_s']:.0f} s wall)", flush=True)
    return rows


# ----------------------------------------------------------------------------- real PX4




class TruthRecorder:
    """Records PX4's ground truth (HIL_STATE_QUATERNION at 50 Hz) and HOME_POSITION on PX4's
    GCS link (PX4 sends to 127.0.0.1:14550) in a thread; `truth_ned()` projects it to PX4's
    local frame. `error` says why there is none (e.g. the port is taken)."""

    def __init__(self, sysid: int, port: int = GCS_PORT) -> None:
        self.sysid = sysid
        self.port = port
        self.rows: list[tuple[float, float, float, float]] = []
        self.home: tuple[float, float, float, float, float, float] | None = None
        self.error = ""
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._conn: Any = None

    def __enter__(self) -> TruthRecorder:
        from pymavlink import mavutil

        try:
            self._conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{self.port}",
                                                    source_system=245, dialect="common")
        except OSError as exc:
            self.error = f"GCS port {self.port}: {exc}"
            return self
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)
        if self._conn is not None:
            self._conn.close()

    def _run(self) -> None:
        c = self._conn
        asked = 0.0
        while not self._stop.is_set():
            m = c.recv_match(blocking=True, timeout=0.2)
            now = time.time()
            if m is not None and m.get_srcSystem() == self.sysid and m.get_srcComponent() == 1:
                k = m.get_type()
                if k == "HIL_STATE_QUATERNION":
                    self.rows.append((now, m.lat * 1e-7, m.lon * 1e-7, m.alt * 1e-3))
                elif k == "HOME_POSITION":
                    self.home = (m.latitude * 1e-7, m.longitude * 1e-7, m.altitude * 1e-3,
                                 m.x, m.y, m.z)
            if now - asked > 2.0 and c.address is not None:  # PX4 is known once it has sent
                asked = now
                with contextlib.suppress(OSError):
                    c.mav.command_long_send(self.sysid, 1, 511, 0, 115, 20000, 0, 0, 0, 0, 0)
                    c.mav.command_long_send(self.sysid, 1, 512, 0, 242, 0, 0, 0, 0, 0, 0)

    def truth_ned(self, t0: float, t1: float) -> np.ndarray:
        """True positions [m NED, PX4's local frame] received in [t0, t1] (Unix s)."""
        if not self.rows or self.home is None:
            return np.zeros((0, 3))
        a = np.array(self.rows)
        a = a[(a[:, 0] >= t0) & (a[:, 0] <= t1)]
        h = self.home
        return np.asarray(geodetic_to_ned(a[:, 1], a[:, 2], a[:, 3], GeoPoint(h[0], h[1], h[2]))
                          + np.array(h[3:]), dtype=np.float64)


def armed_window(tlog: Path, sysid: int) -> tuple[float, float]:
    """(arm COMMAND_ACK accepted, first HEARTBEAT disarmed after it) in Unix s from a .tlog;
    NaN where missing."""
    from pymavlink import mavutil

    conn = mavutil.mavlink_connection(str(tlog))
    t_arm = t_off = math.nan
    try:
        for _ in range(10_000_000):
            m = conn.recv_match(type=["COMMAND_ACK", "HEARTBEAT"])
            if m is None:
                break
            if m.get_srcSystem() != sysid or m.get_srcComponent() != 1:
                continue
            t = float(m._timestamp)
            if m.get_type() == "COMMAND_ACK":
                if math.isnan(t_arm) and m.command == 400 and m.result == 0:
                    t_arm = t
            elif not math.isnan(t_arm) and t > t_arm + 1.0 and not m.base_mode & 128:
                t_off = t
                break
    finally:
        conn.close()
    return t_arm, t_off


def _px4_frame(fp: FlightPlan, mission: Mission, home: tuple[float, ...] | None) -> np.ndarray:
    """Offset [m] from the plan's NED (about the mission's home) to PX4's local frame: the
    horizontal offset of the mission's home from PX4's home, plus PX4's home local position."""
    if home is None:
        return np.zeros(3)
    g = GeoPoint(home[0], home[1], home[2])
    d = geodetic_to_ned(mission.home.lat_deg, mission.home.lon_deg, home[2], g)
    return np.array([float(d[0]) + home[3], float(d[1]) + home[4], home[5]])


def _home_from_tlog(tlog: Path, sysid: int) -> tuple[float, ...] | None:
    import api_harness as H  # noqa: N812

    data = H.read_flight_tlog(tlog, sysid, keep=("HOME_POSITION",))
    hp = data.extra["HOME_POSITION"]
    if not hp:
        return None
    m = hp[-1]
    return (m.latitude * 1e-7, m.longitude * 1e-7, m.altitude * 1e-3, m.x, m.y, m.z)


def px4_flight(kind: str, plan: Path, folder: Path, timeout_s: float, corridor_m: float,
               mode: str, build: str = "v1.16", model: str | None = None) -> dict[str, Any]:
    """One flight of `plan` on a fresh real PX4: `kind` "companion" (fly CLI) or "auto_mission";
    `build` "main" (PX4 main's rover, `model`): AUTO.MISSION only (rover_mission_flight)."""
    if build != "v1.16":
        fn = rover_companion_flight if kind == "companion" else rover_mission_flight
        return fn(plan, folder, timeout_s, corridor_m, build, model or "sihsim_rover_ackermann")
    import api_harness as H  # noqa: N812
    import bench_fidelity as F  # noqa: N812

    from companion.mission import load_mission

    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    mission = load_mission(plan)
    fp = mission_to_flight_plan(mission)
    out: dict[str, Any] = {"kind": kind}
    with flight_lock() as waited:
        out["lock_wait_s"] = waited
        with H.launch("px4", folder) as ep, TruthRecorder(ep.target_system) as truth:
            if kind == "companion":
                tlog = folder / "flight.tlog"
                cmd = [sys.executable, "-m", "companion", "fly", str(plan), "--connect", ep.url,
                       "--target-system", str(ep.target_system), "--mode", mode,
                       "--log", str(tlog)]
                with open(folder / "fly-output.txt", "w") as log:
                    try:
                        rc = subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT,
                                            timeout=timeout_s + 90.0, cwd=REPO).returncode
                    except subprocess.TimeoutExpired:
                        rc = -1
                out["exit_code"] = rc
                rep = Path(f"{tlog}.report.json")
                if rep.exists():
                    r = json.loads(rep.read_text())
                    out["fly_report"] = {k: r.get(k) for k in ("result", "duration_s",
                                                               "planned_duration_s")}
                    out["fly_report_closest_m"] = [w.get("closest_approach_m")
                                                   for w in r.get("waypoints", [])]
            else:
                tlog = folder / "mission.tlog"
                secs = float(asyncio.run(F._bounded(F._mission_flight(ep, folder, plan, timeout_s),
                                                    timeout_s + 60.0)))
                out["exit_code"] = 0 if math.isfinite(secs) else 1
            sysid = ep.target_system
    t0, t1 = armed_window(tlog, sysid)
    out["time_s"] = t1 - t0
    data = H.read_flight_tlog(tlog, sysid)
    home = truth.home or _home_from_tlog(tlog, sysid)
    off = _px4_frame(fp, mission, home)
    sched = build_schedule(fp, DEFAULT_QUAD, VehicleLimits())
    wps = sched.waypoints_ned + off
    legs = fp.points_ned_m() + off
    corners, acc = corner_points(fp)
    end = t1 if math.isfinite(t1) else float(data.lpos_t[-1]) if len(data.lpos_t) else 0.0
    sel = (data.lpos_t >= t0) & (data.lpos_t <= end)
    out["estimate"] = path_metrics(data.lpos[sel, :3], wps, legs, corners + off, acc, corridor_m)
    tr = truth.truth_ned(t0, end)
    out["truth"] = (path_metrics(tr, wps, legs, corners + off, acc, corridor_m) if len(tr)
                    else {"error": truth.error or "no HIL_STATE_QUATERNION / HOME_POSITION"})
    return out


def mission_window(tlog: Path, sysid: int, flown: int | None = None
                   ) -> tuple[float, float, str]:
    """(arm COMMAND_ACK accepted, the first HEARTBEAT after it, once the mode `flown` (PX4
    custom_mode; default AUTO.MISSION, OFFBOARD for the companion's drive) was seen, that is
    out of it or disarmed, that HEARTBEAT's mode) from a .tlog (Unix s; NaN where missing). A
    rover's mission ends in Hold, armed (no landing to disarm it)."""
    from pymavlink import mavutil
    from rover_link import MISSION, mode_name

    mode_flown = MISSION if flown is None else flown

    conn = mavutil.mavlink_connection(str(tlog))
    t_arm = t_end = math.nan
    seen = False
    how = ""
    try:
        for _ in range(10_000_000):
            m = conn.recv_match(type=["COMMAND_ACK", "HEARTBEAT"])
            if m is None:
                break
            if m.get_srcSystem() != sysid or m.get_srcComponent() != 1:
                continue
            t = float(m._timestamp)
            if m.get_type() == "COMMAND_ACK":
                if math.isnan(t_arm) and m.command == 400 and m.result == 0:
                    t_arm = t
                continue
            if math.isnan(t_arm) or t < t_arm + 1.0:
                continue
            armed = bool(m.base_mode & 128)
            seen = seen or (m.custom_mode == mode_flown and armed)
            if seen and (m.custom_mode != mode_flown or not armed):
                t_end = t
                how = f"{mode_name(m.custom_mode)}, {'armed' if armed else 'disarmed'}"
                break
    finally:
        conn.close()
    return t_arm, t_end, how


def rover_mission_flight(plan: Path, folder: Path, timeout_s: float, corridor_m: float,
                         build: str, model: str) -> dict[str, Any]:
    """PX4's AUTO.MISSION of `plan` on a fresh PX4 `build` running SIH `model` (a rover), flown
    and recorded by bench/rover_link.py; the figures from its .tlog (see the module doc)."""
    from rover_link import HOLD, MISSION, RoverLink

    from companion.mission import load_mission, mission_upload_items
    from px4_harness import STARTED_MARK, Px4Sitl, find_px4_sitl

    loc, why = find_px4_sitl(build)
    if loc is None:
        raise RuntimeError(f"no PX4 {build} SITL: {why}")
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    mission = load_mission(plan)
    fp = mission_to_flight_plan(mission, vehicle="rover")
    items = list(mission_upload_items(mission))
    tlog = folder / "mission.tlog"
    out: dict[str, Any] = {"kind": "auto_mission", "build": build, "model": model}
    with flight_lock() as waited:
        out["lock_wait_s"] = waited
        with Px4Sitl(location=loc, model=model, ready_mark=STARTED_MARK,
                     log=folder / "px4-console.log") as px4, \
                RoverLink(px4.port, px4.target_system, tlog=tlog) as link:
            sysid = px4.target_system
            if not link.wait_heartbeat(20.0):
                raise RuntimeError("no HEARTBEAT from PX4")
            link.set_message_interval(115, 50.0)  # ground truth
            link.set_message_interval(32, 50.0)
            out["upload_result"] = link.upload_mission(items)
            if out["upload_result"] != 0:
                raise RuntimeError(f"mission upload: MAV_MISSION_RESULT {out['upload_result']}")
            armed, out["arm_wait_s"] = link.arm(40.0)
            if not armed:
                raise RuntimeError("the rover did not arm")
            out["mission_ack"] = link.set_mode(MISSION)
            link.wait(lambda: link.mode == MISSION, 5.0)
            link.wait(lambda: link.mode != MISSION or not link.armed, timeout_s)
            link.wait(lambda: False, 1.5)  # the HEARTBEAT after the end, into the tlog
            out["texts"] = [t for _, t in link.texts]
            out["reached"] = [(t, seq) for t, seq in link.reached]
            link.set_mode(HOLD)
    out.update(rover_tlog_figures(tlog, sysid, mission, fp, timeout_s, corridor_m, MISSION))
    return out


def rover_tlog_figures(tlog: Path, sysid: int, mission: Any, fp: FlightPlan, timeout_s: float,
                       corridor_m: float, flown: int, truth: Any = None) -> dict[str, Any]:
    """A rover flight's figures from its .tlog, as an outsider would take them (the same for
    PX4's AUTO.MISSION and the companion's OFFBOARD drive): the armed time until the vehicle
    leaves the mode `flown`, and horizontal distances of PX4's estimate (LOCAL_POSITION_NED)
    and of the truth (HIL_STATE_QUATERNION in the .tlog, or `truth`'s recording) to the
    waypoints placed at PX4's HOME_POSITION and to the straight legs."""
    import api_harness as H  # noqa: N812

    out: dict[str, Any] = {}
    t0, t1, how = mission_window(tlog, sysid, flown)
    out["time_s"] = t1 - t0
    out["ended"] = how or f"not within {timeout_s:g} s"
    data = H.read_flight_tlog(tlog, sysid)
    home = _home_from_tlog(tlog, sysid)
    off = _px4_frame(fp, mission, home)
    flat = np.array([1.0, 1.0, 0.0])  # a rover: horizontal distances only
    legs = (fp.points_ned_m() + off) * flat
    corners, acc = corner_points(fp)
    wps = (corners + off) * flat
    end = t1 if math.isfinite(t1) else float(data.lpos_t[-1]) if len(data.lpos_t) else 0.0
    sel = (data.lpos_t >= t0) & (data.lpos_t <= end)
    out["estimate"] = path_metrics(data.lpos[sel, :3] * flat, wps, legs, wps, acc, corridor_m)
    tsel = (data.truth_t >= t0) & (data.truth_t <= end)
    tr = (data.truth[tsel] if np.any(tsel) else
          truth.truth_ned(t0, end) if truth is not None else np.zeros((0, 3)))
    out["truth"] = (path_metrics(tr * flat, wps, legs, wps, acc, corridor_m) if len(tr)
                    else {"error": "no HIL_STATE_QUATERNION / HOME_POSITION"})
    out["acceptance_m"] = [float(a) for a in acc]
    return out


def rover_companion_flight(plan: Path, folder: Path, timeout_s: float, corridor_m: float,
                           build: str, model: str) -> dict[str, Any]:
    """`python -m companion fly PLAN` (rover mode) on a fresh PX4 `build` running SIH `model`,
    the ground truth recorded on PX4's GCS link; the figures from its .tlog as for PX4's
    AUTO.MISSION (`rover_tlog_figures`, OFFBOARD being the mode flown)."""
    from rover_link import OFFBOARD

    from companion.mission import load_mission
    from px4_harness import STARTED_MARK, Px4Sitl, find_px4_sitl

    loc, why = find_px4_sitl(build)
    if loc is None:
        raise RuntimeError(f"no PX4 {build} SITL: {why}")
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    mission = load_mission(plan)
    fp = mission_to_flight_plan(mission, vehicle="rover")
    tlog = folder / "flight.tlog"
    out: dict[str, Any] = {"kind": "companion", "build": build, "model": model}
    with flight_lock() as waited:
        out["lock_wait_s"] = waited
        with Px4Sitl(location=loc, model=model, ready_mark=STARTED_MARK,
                     log=folder / "px4-console.log") as px4, \
                TruthRecorder(px4.target_system) as truth:
            cmd = [sys.executable, "-m", "companion", "fly", str(plan), "--connect", px4.url,
                   "--target-system", str(px4.target_system), "--log", str(tlog),
                   "--timeout", "30"]
            with open(folder / "fly-output.txt", "w") as log:
                try:
                    rc = subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT,
                                        timeout=timeout_s + 90.0, cwd=REPO).returncode
                except subprocess.TimeoutExpired:
                    rc = -1
            out["exit_code"] = rc
            sysid = px4.target_system
            rep = Path(f"{tlog}.report.json")
            if rep.exists():
                r = json.loads(rep.read_text())
                out["fly_report"] = {k: r.get(k) for k in ("result", "duration_s",
                                                           "planned_duration_s")}
            out.update(rover_tlog_figures(tlog, sysid, mission, fp, timeout_s, corridor_m,
                                          OFFBOARD, truth))
    return out


def rover_px4_table(entries: list[dict[str, Any]]) -> str:
    """One row per mission (median (min-max) over the repeats)."""
    def cell(runs: list[dict[str, Any]], key: str, sub: str | None = None,
             fmt: str = ".1f") -> str:
        vals = []
        for r in runs:
            v = r.get(key) if sub is None else r.get(key, {}).get(sub)
            if isinstance(v, (int, float)) and math.isfinite(v):
                vals.append(float(v))
        if not vals:
            return "-"
        if len(vals) == 1:
            return format(vals[0], fmt)
        return f"{np.median(vals):{fmt}} ({min(vals):{fmt}}-{max(vals):{fmt}})"

    lines = ["| mission | flown by | armed time [s] | time / AUTO.MISSION | how it ended | "
             "closest approach per waypoint, estimate [m] | worst waypoint, estimate / truth "
             "[m] | deviation from the legs RMS / max, estimate [m] | RMS / max, truth [m] |",
             "| --- | --- | ---: | ---: | --- | --- | ---: | ---: | ---: |"]
    for e in entries:
        name = Path(e["mission"]).name
        auto = [r for r in e["runs"].get("auto_mission", []) if "error" not in r]
        auto_t = float(np.median([r["time_s"] for r in auto])) if auto else math.nan
        for kind, label in (("companion", "companion (fly)"), ("auto_mission", "AUTO.MISSION")):
            all_runs = e["runs"].get(kind, [])
            runs = [r for r in all_runs if "error" not in r]
            if not runs:
                errs = "; ".join(r.get("error", "?") for r in all_runs) or "not flown"
                lines.append(f"| {name} | {label} | failed: {errs} | | | | | | |")
                continue
            per = " / ".join(", ".join(f"{c:.2f}" for c in r["estimate"]["closest_m"])
                             for r in runs)
            ended = "; ".join(sorted({r.get("ended", "?") for r in runs}))
            ratio = (f"{np.median([r['time_s'] for r in runs]) / auto_t:.2f}"
                     if math.isfinite(auto_t) else "-")
            lines.append(
                f"| {name} | {label} | {cell(runs, 'time_s')} | {ratio} | {ended} | {per} | "
                f"{cell(runs, 'estimate', 'max_closest_m', '.2f')} / "
                f"{cell(runs, 'truth', 'max_closest_m', '.2f')} | "
                f"{cell(runs, 'estimate', 'rms_dev_m', '.2f')} / "
                f"{cell(runs, 'estimate', 'max_dev_m', '.2f')} | "
                f"{cell(runs, 'truth', 'rms_dev_m', '.2f')} / "
                f"{cell(runs, 'truth', 'max_dev_m', '.2f')} |")
    return "\n".join(lines) + "\n"


def px4_part(args: argparse.Namespace) -> list[dict[str, Any]]:
    """Every `--px4-mission`, `--repeat` times by the companion and by AUTO.MISSION."""
    out = []
    for m, mission in enumerate(args.px4_mission):
        plan = Path(mission).resolve()
        kinds = ("companion", "auto_mission")
        runs: dict[str, list[dict[str, Any]]] = {k: [] for k in kinds}
        for i in range(args.repeat):
            for kind in runs:
                t0 = time.perf_counter()
                try:
                    r = px4_flight(kind, plan, Path(args.out) / f"px4-{m}-{kind}-{i}",
                                   args.px4_timeout, args.corridor, args.mode, args.build,
                                   args.model)
                except Exception as exc:  # one failed flight must not lose the run
                    r = {"kind": kind, "error": f"{type(exc).__name__}: {exc}",
                         "time_s": math.nan}
                r["wall_s"] = time.perf_counter() - t0
                runs[kind].append(r)
                est = r.get("estimate", {})
                print(f"px4 {plan.name} {kind} #{i}: armed {r['time_s']:.1f} s, worst waypoint "
                      f"{est.get('max_closest_m', math.nan):.2f} m (estimate) "
                      f"{r.get('error', '')} ({r['wall_s']:.0f} s wall, lock wait "
                      f"{r.get('lock_wait_s', 0.0):.0f} s)", flush=True)
        out.append({"mission": str(plan.relative_to(REPO) if plan.is_relative_to(REPO)
                                   else plan),
                    "mode": args.mode, "runs": runs, "build": args.build,
                    "model": args.model,
                    "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())})
    return out


# ----------------------------------------------------------------------------- planning


def synthetic_mission(n: int = 100, seed: int = 7) -> str:
    """QGC WPL text: takeoff to 15 m, `n` waypoints (legs 15-60 m, 10-40 m up, a
    DO_CHANGE_SPEED of 3-12 m/s every 10 waypoints), land."""
    rng = np.random.default_rng(seed)
    lat0, lon0 = 47.397742, 8.545594
    m_per_deg = 111_195.0
    lines = ["QGC WPL 110", f"0\t1\t0\t16\t0\t0\t0\t0\t{lat0}\t{lon0}\t488.0\t1",
             f"1\t0\t3\t22\t0\t0\t0\t0\t{lat0}\t{lon0}\t15.0\t1"]
    n_, e_ = 0.0, 0.0
    seq = 2
    heading = 0.0
    for k in range(n):
        if k % 10 == 0:
            lines.append(f"{seq}\t0\t3\t178\t1\t{rng.uniform(3.0, 12.0):.1f}\t-1\t0\t0\t0\t0\t1")
            seq += 1
        heading += rng.uniform(-2.0, 2.0)
        d = rng.uniform(15.0, 60.0)
        n_ += d * math.cos(heading)
        e_ += d * math.sin(heading)
        lat = lat0 + n_ / m_per_deg
        lon = lon0 + e_ / (m_per_deg * math.cos(math.radians(lat0)))
        lines.append(f"{seq}\t0\t3\t16\t0\t0\t0\t0\t{lat:.7f}\t{lon:.7f}\t"
                     f"{rng.uniform(10.0, 40.0):.1f}\t1")
        seq += 1
    lines.append(f"{seq}\t0\t3\t21\t0\t0\t0\t0\t{lat:.7f}\t{lon:.7f}\t0.0\t1")
    return "\n".join(lines) + "\n"


def planning_part(runs: int = 7) -> dict[str, Any]:
    from companion.trajectory import plan

    mission = loads_mission(synthetic_mission(), source="synthetic-100.waypoints")
    fp = mission_to_flight_plan(mission)
    limits = VehicleLimits()
    n_wp = sum(1 for it in mission.items if it.command == 16)
    build_schedule(fp, DEFAULT_QUAD, limits)  # warm-up
    wall, cpu = [], []
    for _ in range(runs):
        t0, c0 = time.perf_counter(), time.process_time()
        sched = build_schedule(fp, DEFAULT_QUAD, limits)
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    pts = fp.points_ned_m()
    keep = np.concatenate([[True], np.linalg.norm(np.diff(pts, axis=0), axis=1) > 1e-6])
    pts = pts[keep]
    speeds = [w.speed_m_s for w in fp.waypoints]
    v = float(np.median(speeds)) if speeds else 5.0
    h = np.maximum(np.linalg.norm(np.diff(pts, axis=0), axis=1) / v, 0.5)
    plan(pts, durations=h)  # warm-up
    base = []
    for _ in range(runs):
        t0 = time.perf_counter()
        plan(pts, durations=h)
        base.append(time.perf_counter() - t0)
    bound_fn, _ = time_optimal_bound()
    bound = math.nan
    if bound_fn is not None:
        with contextlib.suppress(Exception):
            bound = float(bound_fn(fp, DEFAULT_QUAD, limits))
    return {"waypoints": n_wp, "points": len(pts), "runs": runs,
            "wall_best_s": min(wall), "wall_median_s": float(np.median(wall)),
            "cpu_best_s": min(cpu), "baseline_best_s": min(base),
            "baseline_median_s": float(np.median(base)),
            "planned_s": sched.duration_s, "bound_s": bound,
            "limits": {k: (round(v, 4) if isinstance(v, float) else v)
                       for k, v in dataclasses.asdict(limits).items()}}


# ----------------------------------------------------------------------------- table


def _f(v: Any, fmt: str = ".1f") -> str:
    return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else format(v, fmt)


def _yes(ok: bool) -> str:
    return "yes" if ok else "**no**"


def mock_table(rows: list[dict[str, Any]], corridor_m: float, bound_name: str) -> str:
    lines = [
        "| mission | companion [s] | AUTO.MISSION [s] | ratio (<= 0.8) | worst waypoint: "
        "companion / AUTO [m] (<= 0.5) | max deviation from legs: companion / AUTO [m] | "
        f"companion in corridor ({corridor_m:g} m / acc. radius) | planned [s] | bound [s] | "
        "planned / bound (<= 1.15) |",
        "| --- | ---: | ---: | ---: | ---: | ---: | --- | ---: | ---: | ---: |"]
    errors = []
    for r in rows:
        name = r["file"] + (" (rover)" if r["vehicle"] == "rover" else "")
        if "error" in r:
            lines.append(f"| {name} | error | | | | | | | | |")
            errors.append(f"{name}: {r['error']}")
            continue
        c, p = r["companion"], r["auto_mission"]
        bad = [f"{k}: {v}" for k, v in (("companion", c["result"]), ("AUTO.MISSION",
                                                                     p["result"])) if v != "ok"]
        if bad:
            errors.append(f"{name}: " + "; ".join(bad))
        within = (f"{_yes(c['within'])}" + ("" if c["within"] else
                  f" ({c['outside']}/{c['samples']} samples out, up to "
                  f"{c['max_excess_m']:.1f} m beyond)"))
        br = r["planned_s"] / r["bound_s"] if math.isfinite(r["bound_s"]) else math.nan
        lines.append(
            f"| {name} | {_f(c['time_s'])} | {_f(p['time_s'])} | {_f(r['ratio'], '.2f')} "
            f"{'' if r['ratio'] <= GOAL_RATIO else '(no)'} | {_f(c['max_closest_m'], '.2f')} / "
            f"{_f(p['max_closest_m'], '.2f')} | {_f(c['max_dev_m'], '.2f')} / "
            f"{_f(p['max_dev_m'], '.2f')} | {within} | {_f(r['planned_s'])} | "
            f"{_f(r['bound_s']) if math.isfinite(r['bound_s']) else 'n/a'} | "
            f"{_f(br, '.2f') if math.isfinite(br) else 'n/a'} |")
    ok = [r for r in rows if "error" not in r]
    met_t = sum(r["ratio"] <= GOAL_RATIO for r in ok)
    met_w = sum(r["companion"]["max_closest_m"] <= GOAL_WP_M for r in ok)
    met_c = sum(bool(r["companion"]["within"]) for r in ok)
    text = "\n".join(lines) + "\n\n"
    text += (f"Goals met (mock): time ratio <= {GOAL_RATIO} in {met_t} of {len(rows)} missions; "
             f"every waypoint within {GOAL_WP_M} m in {met_w} of {len(rows)}; path within the "
             f"corridor in {met_c} of {len(rows)}. Time-optimal bound: {bound_name}.\n")
    if errors:
        text += "\nNot ok: " + "; ".join(errors) + "\n"
    return text


def fly_report_worst(closest: list[float | None], plan: Path) -> float:
    """Worst closest approach [m] in `fly`'s own report.json (in its plan's frame), the landing
    point left out: that report stops where the plan's descent ends above it."""
    from companion.mission import load_mission

    fp = mission_to_flight_plan(load_mission(plan))
    land = {w.item_index for w in fp.waypoints if w.command == 21}
    items = build_schedule(fp, DEFAULT_QUAD, VehicleLimits()).item_indices
    vals = [c for c, i in zip(closest, items, strict=False) if c is not None and i not in land]
    return max(vals) if vals else math.nan


def px4_table(px4: dict[str, Any]) -> str:
    runs = px4["runs"]
    plan = REPO / px4["mission"]
    for r in runs["companion"]:
        if r.get("fly_report_closest_m"):
            r["fly_report_worst_m"] = fly_report_worst(r["fly_report_closest_m"], plan)

    def cell(kind: str, key: str, sub: str | None = None, fmt: str = ".1f") -> str:
        vals = []
        for r in runs[kind]:
            v = r.get(key) if sub is None else r.get(key, {}).get(sub)
            if isinstance(v, (int, float)) and math.isfinite(v):
                vals.append(float(v))
        if not vals:
            return "-"
        if len(vals) == 1:
            return format(vals[0], fmt)
        return f"{np.median(vals):{fmt}} ({min(vals):{fmt}}-{max(vals):{fmt}})"

    def med(kind: str) -> float:
        v = [r["time_s"] for r in runs[kind] if math.isfinite(r.get("time_s", math.nan))]
        return float(np.median(v)) if v else math.nan

    ratio = med("companion") / med("auto_mission")
    lines = ["| quantity | companion `fly --mode " + px4["mode"] + "` | PX4 AUTO.MISSION |",
             "| --- | ---: | ---: |",
             f"| armed time [s] | {cell('companion', 'time_s')} | "
             f"{cell('auto_mission', 'time_s')} |",
             "| worst waypoint closest approach, estimate (LOCAL_POSITION_NED) [m] | "
             f"{cell('companion', 'estimate', 'max_closest_m', '.2f')} | "
             f"{cell('auto_mission', 'estimate', 'max_closest_m', '.2f')} |",
             "| worst waypoint closest approach, truth (HIL_STATE_QUATERNION) [m] | "
             f"{cell('companion', 'truth', 'max_closest_m', '.2f')} | "
             f"{cell('auto_mission', 'truth', 'max_closest_m', '.2f')} |",
             "| worst waypoint but the landing point, `fly`'s own report (in its plan's frame) "
             "[m] | "
             f"{cell('companion', 'fly_report_worst_m', None, '.2f')} | - |",
             "| max deviation from the legs, estimate [m] | "
             f"{cell('companion', 'estimate', 'max_dev_m', '.2f')} | "
             f"{cell('auto_mission', 'estimate', 'max_dev_m', '.2f')} |",
             "| armed samples outside the corridor, estimate [%] | "
             f"{cell('companion', 'estimate', 'outside_pct', '.1f')} | "
             f"{cell('auto_mission', 'estimate', 'outside_pct', '.1f')} |"]
    per = []
    for kind in runs:
        for i, r in enumerate(runs[kind]):
            if "estimate" in r:
                per.append(f"{kind} #{i}: " + ", ".join(
                    f"{c:.2f}" for c in r["estimate"]["closest_m"]))
            if "error" in r:
                per.append(f"{kind} #{i}: failed ({r['error']})")
    n = len(runs["companion"])
    text = "\n".join(lines) + "\n\n"
    text += (f"Ratio companion / AUTO.MISSION (medians of {n} flight(s) each): "
             f"{_f(ratio, '.2f')} (goal <= {GOAL_RATIO}: "
             f"{'met' if ratio <= GOAL_RATIO else 'NOT met'}). Closest approach per waypoint "
             f"(estimate, m): " + "; ".join(per) + ".\n")
    return text


def planning_text(p: dict[str, Any]) -> str:
    ratio = p["wall_best_s"] / p["baseline_best_s"]
    bound = (f"planned {p['planned_s']:.1f} s vs bound {p['bound_s']:.1f} s "
             f"({p['planned_s'] / p['bound_s']:.2f})" if math.isfinite(p["bound_s"])
             else f"planned {p['planned_s']:.1f} s, bound n/a")
    met = "met" if p["wall_best_s"] < GOAL_PLAN_S else "NOT met"
    return (f"`build_schedule` of a synthetic mission ({p['waypoints']} waypoints, a "
            "DO_CHANGE_SPEED of 3-12 m/s every 10, legs 15-60 m, 10-40 m up, takeoff and land; "
            f"`bench_missions.synthetic_mission`), `VehicleLimits()` defaults ({p['limits']}), "
            f"best of {p['runs']}: {p['wall_best_s'] * 1e3:.0f} ms wall (median "
            f"{p['wall_median_s'] * 1e3:.0f} ms, CPU best {p['cpu_best_s'] * 1e3:.0f} ms); "
            f"goal < {GOAL_PLAN_S * 1e3:.0f} ms: {met}. Same run, fixed-duration minimum-snap "
            f"solve of the same {p['points']} points (`plan(points, durations=leg / median "
            f"speed)`): {p['baseline_best_s'] * 1e3:.1f} ms best; ratio {ratio:.0f}x. {bound}.\n")


def section(title: str, argv: str, mock: list[dict[str, Any]] | None,
            px4: list[dict[str, Any]] | None, planning: dict[str, Any] | None, corridor_m: float,
            bound_name: str, load: tuple[float, float], label: str, reused: str) -> str:
    head = (f"## {title}\n\nCommand: `.venv/bin/python bench/bench_missions.py {argv}` "
            f"({time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, git "
            f"{_git_rev()}, {platform.machine()}, {os.cpu_count()} cores shared with other "
            f"jobs, 1-min load {load[0]:.1f} at the start, {load[1]:.1f} at the end).")
    if label:
        head += f" **{label}**"
    parts = [head + "\n"]
    if mock is not None:
        parts.append(
            "### Mock (lockstep replay, attitude mode, default PX4 parameters on both sides)\n\n"
            "Time: arm COMMAND_ACK to the mock's \"Disarmed by ...\" STATUSTEXT, the same for "
            "both flights (a loiter ending: AUTO.MISSION's \"Mission finished\", the companion's "
            "Hold HEARTBEAT after its plan, or its own disarm of a rover). Waypoints: "
            "closest approach of the flown path (LOCAL_POSITION_NED joined by straight lines) "
            "to each mission waypoint of the schedule. Deviation: distance of each armed "
            "sample from the straight legs (start, waypoints, touchdown); in the corridor when "
            f"within {corridor_m:g} m of them or within the acceptance radius of a waypoint. "
            "The companion plans as "
            f"`prepare_mission` does (`ReplayConfig.limits`: {_limits_text(mock)}).\n\n"
            + mock_table(mock, corridor_m, bound_name))
    rover = [e for e in px4 or [] if e.get("build", "v1.16") != "v1.16"]
    if rover:
        parts.append(
            "### Real PX4 main SITL (SIH Ackermann rover, default parameters, real time): the "
            f"companion and PX4's AUTO.MISSION\n\n{reused}Each flight on a fresh PX4 "
            f"({rover[0]['date']}): `python -m companion fly` (rover mode), and AUTO.MISSION "
            "flown and recorded by a pymavlink client (bench/rover_link.py); armed time from "
            "the .tlog (arm COMMAND_ACK to the first HEARTBEAT out of OFFBOARD (the companion) "
            "or AUTO.MISSION, or disarmed, +-1 s); waypoints placed at PX4's HOME_POSITION; "
            "horizontal distances; deviation from the straight legs home -> waypoints "
            "(cross-track, corners included). Closest approach per waypoint: one group per "
            "flight. Cells: median (min-max) over the flights.\n\n"
            + rover_px4_table(rover))
    for entry in px4 or []:
        if entry.get("build", "v1.16") != "v1.16":
            continue
        parts.append(
            "### Real PX4 v1.16 SITL (SIH quad, default parameters, real time): "
            f"{entry['mission']}\n\n{reused}Each flight on a fresh PX4 ({entry['date']}); armed "
            "time from the flight's .tlog (arm COMMAND_ACK to the first disarmed HEARTBEAT, "
            "+-1 s); waypoints placed at PX4's HOME_POSITION. The companion's `fly` flies "
            "the takeoff itself and plans from where the vehicle stood (before 2026-11-26: from "
            "where PX4's NAV_TAKEOFF ended, carrying its drift), lands itself in attitude mode "
            "and disarms once PX4 reports it on the ground.\n\n" + px4_table(entry))
    if planning is not None:
        parts.append("### Planning time\n\n" + planning_text(planning))
    return "\n".join(parts)


def _limits_text(rows: list[dict[str, Any]]) -> str:
    lim = next((r["limits"] for r in rows if "limits" in r and r["vehicle"] == "quad"), {})
    mp = next((r["mock_params"] for r in rows if r.get("mock_params")), {})
    text = ", ".join(f"{k} {v:.3g}" if isinstance(v, float) else f"{k} {v}"
                     for k, v in lim.items() if not k.startswith("rover"))
    return text + (f"; mock parameters {mp}" if mp else "")


def _git_rev() -> str:
    try:
        r = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True,
                           text=True, timeout=10, check=True)
        dirty = subprocess.run(["git", "status", "--porcelain", "companion"], cwd=REPO,
                               capture_output=True, text=True, timeout=10).stdout.strip()
        return r.stdout.strip() + (" + uncommitted changes in companion/" if dirty else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="companion vs AUTO.MISSION (issue 13's goals)")
    ap.add_argument("--parts", nargs="+", choices=("mock", "px4", "planning"), default=None,
                    help="default: mock px4 planning (--build v1.16), px4 (--build main)")
    ap.add_argument("--build", choices=("v1.16", "main"), default="v1.16",
                    help="real PX4 build: v1.16 (SIH quad: companion and AUTO.MISSION) or main "
                         "(SIH rover: AUTO.MISSION only; --write updates "
                         f"\"{SECTION_ROVER}\")")
    ap.add_argument("--model", default=None,
                    help="SIH model of --build main (default sihsim_rover_ackermann)")
    ap.add_argument("--missions", nargs="*", default=[],
                    help="mock: only these files of examples/missions (name or stem) and any "
                         "other mission file given by its path")
    ap.add_argument("--mock-param", action="append", default=[], metavar="NAME=VALUE",
                    help="mock parameter for both mock flights (repeatable)")
    ap.add_argument("--corridor", type=float, default=None,
                    help="corridor half-width along the legs [m] (default: VehicleLimits()."
                         "corridor_m if the planner has it, else 1)")
    ap.add_argument("--px4-mission", nargs="+", default=None,
                    help="mission(s) flown on real PX4 (default examples/missions/square.plan; "
                         "--build main: examples/missions/*rover*)")
    ap.add_argument("--repeat", type=int, default=1,
                    help="real-PX4 flights per kind (each ~2-3 min real time)")
    ap.add_argument("--mode", default="attitude", choices=("position", "attitude", "rates"),
                    help="setpoint mode of the companion's real-PX4 flight")
    ap.add_argument("--px4-timeout", type=float, default=240.0,
                    help="bound of one real-PX4 mission flight [s]")
    ap.add_argument("--reuse-px4", default=None, metavar="JSON",
                    help="take the real-PX4 figures from an earlier run's JSON")
    ap.add_argument("--out", default="bench_out/missions", help="folder for logs and JSON")
    ap.add_argument("--label", default="", help="a note put in the section's header")
    g = ap.add_mutually_exclusive_group()
    g.add_argument("--write", action="store_true", help=f'update "## {SECTION}"')
    g.add_argument("--write-baseline", action="store_true",
                   help=f'update "## {SECTION_BASELINE}"')
    args = ap.parse_args(argv)
    if args.repeat < 1:
        ap.error("--repeat must be >= 1")
    if args.parts is None:
        args.parts = ["mock", "px4", "planning"] if args.build == "v1.16" else ["px4"]
    if args.px4_mission is None:
        args.px4_mission = ([str(MISSIONS_DIR / "square.plan")] if args.build == "v1.16" else
                            [str(MISSIONS_DIR / n) for n in ROVER_MISSIONS])
    if args.build != "v1.16" and args.model is None:
        args.model = "sihsim_rover_ackermann"
    if args.corridor is None:
        args.corridor = float(getattr(VehicleLimits(), "corridor_m", 1.0))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    load0 = os.getloadavg()
    bound_fn, bound_name = time_optimal_bound()
    mock = mock_missions(args, bound_fn) if "mock" in args.parts else None
    reused = ""
    px4 = None
    if args.reuse_px4:
        old = json.loads(Path(args.reuse_px4).read_text())
        px4 = old["px4"]
        reused = (f"Figures of an earlier run, `.venv/bin/python bench/bench_missions.py "
                  f"{old['command']}` ({old['date']}), read from its JSON. ")
    elif "px4" in args.parts:
        px4 = px4_part(args)
    planning = planning_part() if "planning" in args.parts else None
    if planning is not None:
        print(planning_text(planning), flush=True)
    argv_s = shlex.join(sys.argv[1:] if argv is None else argv)
    (out / "missions.json").write_text(json.dumps(
        {"date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "command": argv_s,
         "mock": mock, "px4": px4, "planning": planning, "bound": bound_name},
        indent=1, default=float))
    title = SECTION_BASELINE if args.write_baseline else SECTION
    if args.build != "v1.16":
        if args.write_baseline:
            ap.error("--write-baseline is for the quad's section (--build v1.16)")
        title = SECTION_ROVER
    text = section(title, argv_s, mock, px4, planning, args.corridor, bound_name,
                   (load0[0], os.getloadavg()[0]), args.label, reused)
    print(text)
    if args.write or args.write_baseline:
        from benchmarks_md import write_section

        write_section(title, text)
        print(f"updated BENCHMARKS.md ## {title}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
