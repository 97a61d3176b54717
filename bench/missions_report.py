"""The Markdown of bench_missions.py (see its doc): the mock table, the real-PX4 tables (quad
and rover), the planning time and the whole BENCHMARKS.md section, from the figures its parts
return (or an earlier run's JSON); the goals they are checked against."""

from __future__ import annotations

import math
import os
import platform
import subprocess
import time
from pathlib import Path
from typing import Any

import numpy as np

from companion.mission import mission_to_flight_plan
from companion.planning.schedule import VehicleLimits, build_schedule
from companion.replay.runner import DEFAULT_QUAD

REPO = Path(__file__).resolve().parents[1]
GOAL_RATIO = 0.8
GOAL_WP_M = 0.5
GOAL_BOUND_RATIO = 1.15
GOAL_PLAN_S = 0.300


def _f(v: Any, fmt: str = ".1f") -> str:
    return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else format(v, fmt)


def _yes(ok: bool) -> str:
    return "yes" if ok else "**no**"


def _cell(runs: list[dict[str, Any]], key: str, sub: str | None = None,
          fmt: str = ".1f") -> str:
    """`r[key]` (or `r[key][sub]`) over `runs`: the one value, or median (min-max); "-" if
    none is a finite number."""
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
        return _cell(runs[kind], key, sub, fmt)

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


def rover_px4_table(entries: list[dict[str, Any]]) -> str:
    """One row per mission (median (min-max) over the repeats)."""
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
                f"| {name} | {label} | {_cell(runs, 'time_s')} | {ratio} | {ended} | {per} | "
                f"{_cell(runs, 'estimate', 'max_closest_m', '.2f')} / "
                f"{_cell(runs, 'truth', 'max_closest_m', '.2f')} | "
                f"{_cell(runs, 'estimate', 'rms_dev_m', '.2f')} / "
                f"{_cell(runs, 'estimate', 'max_dev_m', '.2f')} | "
                f"{_cell(runs, 'truth', 'rms_dev_m', '.2f')} / "
                f"{_cell(runs, 'truth', 'max_dev_m', '.2f')} |")
    return "\n".join(lines) + "\n"


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
