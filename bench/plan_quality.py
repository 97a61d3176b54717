"""Plan quality of every bundled mission (issue 13, planning speed work): planned duration,
time-optimal bound, planned/bound, corridor containment under dense sampling, waypoints held,
PX4 per-axis ratios, planning time. Prints a markdown table; `--json` writes the rows.

    .venv/bin/python bench/plan_quality.py [--json out.json] [--synthetic]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from mission_metrics import corridor_check  # noqa: E402

from companion.mission import load_mission, loads_mission, mission_to_flight_plan  # noqa: E402
from companion.planning.schedule import VehicleLimits, axis_ratios, build_schedule  # noqa: E402
from companion.replay.runner import DEFAULT_QUAD  # noqa: E402

MISSIONS = sorted([*ROOT.glob("examples/missions/*.plan"),
                   *ROOT.glob("examples/missions/*.waypoints"),
                   *ROOT.glob("tests/data/missions/*.plan")])


def rows(synthetic: bool) -> list[dict[str, object]]:
    out: list[dict[str, object]] = []
    limits = VehicleLimits()
    corridor = limits.corridor_m or 1.0
    srcs: list[tuple[str, object]] = [(str(p.relative_to(ROOT)), p) for p in MISSIONS]
    if synthetic:
        from bench_missions import synthetic_mission
        srcs.append(("synthetic-100", synthetic_mission()))
    for name, src in srcs:
        try:
            mission = (load_mission(src) if isinstance(src, Path)
                       else loads_mission(str(src), source="synthetic-100.waypoints"))
            fp = mission_to_flight_plan(mission, vehicle="rover" if "rover" in name else "quad")
            t0 = time.perf_counter()
            sched = build_schedule(fp, DEFAULT_QUAD, limits)
            dt = time.perf_counter() - t0
        except Exception as exc:
            out.append({"mission": name, "error": f"{type(exc).__name__}: {exc}"})
            continue
        row: dict[str, object] = {"mission": name, "vehicle": fp.vehicle,
                                  "planned_s": sched.duration_s, "plan_ms": 1e3 * dt}
        if fp.vehicle != "rover":
            bound = sched.time_optimal_bound_s()
            row.update(bound_s=bound, ratio=sched.duration_s / bound)
            # dense samples of the trajectory pieces (200 per segment)
            pts, brk = [], []
            r_vel = r_acc = 0.0
            for p in sched.pieces:
                if p.kind != "traj" or p.traj is None:
                    continue
                tr = p.traj
                tau = np.linspace(0.0, 1.0, 201)
                t = (tr.breaks[:-1, None] + tau[None, :] * tr.durations[:, None]).reshape(-1)
                pts.append(tr.evaluate(t, 0))
                brk.append(tr.evaluate(tr.breaks, 0))
                climb = (sched.px4.MPC_TKO_SPEED if p.phase == "takeoff"
                         else sched.px4.MPC_Z_VEL_MAX_UP)
                rv, ra = axis_ratios(tr, sched.px4, climb_m_s=climb)
                r_vel, r_acc = max(r_vel, rv), max(r_acc, ra)
            path = np.concatenate(pts)
            legs = fp.points_ned_m()
            cc = corridor_check(path, legs, sched.waypoints_ned, sched.acceptance_m, corridor)
            joints = np.concatenate(brk)
            wp_err = max((float(np.min(np.linalg.norm(joints - w, axis=1)))
                          for w in sched.waypoints_ned), default=0.0)
            row.update(max_dev_m=cc.max_dev_m, outside=cc.outside, wp_err_m=wp_err,
                       r_vel=r_vel, r_acc=r_acc)
        out.append(row)
    return out


def table(rs: list[dict[str, object]]) -> str:
    def f(v: object, fmt: str) -> str:
        bad = not isinstance(v, float | int) or (isinstance(v, float) and not math.isfinite(v))
        return "-" if bad else format(v, fmt)
    lines = ["| mission | planned [s] | bound [s] | planned/bound | max dev [m] | samples out "
             "| waypoint err [m] | axis vel/acc ratio | plan [ms] |",
             "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for r in rs:
        if "error" in r:
            lines.append(f"| {r['mission']} | error: {r['error']} | | | | | | | |")
            continue
        lines.append(
            f"| {r['mission']} | {f(r['planned_s'], '.2f')} | {f(r.get('bound_s'), '.2f')} | "
            f"{f(r.get('ratio'), '.4f')} | {f(r.get('max_dev_m'), '.3f')} | "
            f"{f(r.get('outside'), 'd')} | {f(r.get('wp_err_m'), '.1e')} | "
            f"{f(r.get('r_vel'), '.4f')}/{f(r.get('r_acc'), '.4f')} | {f(r['plan_ms'], '.0f')} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--json", type=Path)
    ap.add_argument("--synthetic", action="store_true",
                    help="add bench_missions.synthetic_mission() (100 waypoints)")
    a = ap.parse_args()
    rs = rows(a.synthetic)
    print(table(rs))
    if a.json:
        a.json.write_text(json.dumps(rs, indent=1))


if __name__ == "__main__":
    main()
