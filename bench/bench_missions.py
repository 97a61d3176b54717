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

This script holds the mock and planning parts and the command line; the real-PX4 flights are
in missions_px4.py, the tables and the BENCHMARKS.md section in missions_report.py, the path
metrics in mission_metrics.py.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import math
import os
import shlex
import sys
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

from mission_metrics import corner_points, path_metrics  # noqa: E402
from missions_px4 import px4_part  # noqa: E402
from missions_report import planning_text, section  # noqa: E402

from companion.mission import (  # noqa: E402
    FlightPlan,
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

MISSIONS_DIR = REPO / "examples" / "missions"
ROVER_MISSIONS = tuple(sorted(p.name for p in MISSIONS_DIR.glob("*rover*")))
SECTION = "Missions: companion vs AUTO.MISSION"
SECTION_BASELINE = SECTION + " (pre-change baseline)"
SECTION_ROVER = "Missions: companion vs PX4 AUTO.MISSION on the rover (PX4 main)"


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
