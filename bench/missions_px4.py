"""The real-PX4 part of bench_missions.py (see its doc): each mission flown on a fresh PX4
SITL, under the flight lock, by the companion's `python -m companion fly` and by PX4's own
AUTO.MISSION, and the figures of each flight from its .tlog.

v1.16 (SIH quad): `px4_flight`, the ground truth recorded on PX4's GCS link (`TruthRecorder`),
the armed time from the .tlog (`armed_window`). main (SIH rover): `rover_mission_flight` (PX4's
AUTO.MISSION flown by bench/rover_link.py) and `rover_companion_flight`, both measured the same
way (`rover_tlog_figures`, `mission_window`). `px4_part` flies every `--px4-mission`.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import math
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
from mission_metrics import corner_points, path_metrics

from companion.mission import FlightPlan, GeoPoint, Mission, geodetic_to_ned, mission_to_flight_plan
from companion.planning.schedule import VehicleLimits, build_schedule
from companion.replay.runner import DEFAULT_QUAD
from px4_harness import flight_lock

REPO = Path(__file__).resolve().parents[1]
GCS_PORT = 14550


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
