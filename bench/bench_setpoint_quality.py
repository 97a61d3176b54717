"""Setpoint quality before and after a change, in one run (issue 24): thrust steps between
consecutive attitude/rates setpoints, commanded tilt and time over PX4's MPC_TILTMAX_AIR, and
how the vehicle rocks (its own attitude, high-passed), judged from each flight's .tlog alone.

Two versions of the code fly the same missions: `--before REF` (a git revision, checked out in a
temporary worktree and run from there: `python -m companion` from the worktree's folder imports
that version) and the working tree. Parts:
  mock: `python -m companion replay FILE --mode M` of every quad mission in examples/missions
    plus tests/data/missions/square_8ms.plan (takeoff to 10 m, 8 m/s square, land: a 10 m
    final descent), attitude and rates mode;
  px4: `python -m companion fly square_8ms.plan --connect ...` on a fresh real PX4 v1.16 SITL
    (px4_harness.Px4Sitl, under /tmp/ecca-px4-flights.lock), attitude and rates mode.
From each tlog: the companion's SET_ATTITUDE_TARGET frames, and at each the vehicle's landed
state (EXTENDED_SYS_STATE) and height above its first LOCAL_POSITION_NED. A thrust step is the
change between consecutive setpoints at most 20 ms apart, both in the air (landed state 2) and
more than 0.5 m up. Tilt: the commanded quaternion's z axis from vertical (attitude mode).

Run: `.venv/bin/python bench/bench_setpoint_quality.py [--parts mock px4] [--before 910ef12]
[--write]`; `--write` replaces the section "Setpoint quality" of BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import contextlib
import fcntl
import json
import math
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
from pymavlink import mavutil

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.benchmarks_md import write_section  # noqa: E402

SQUARE = ROOT / "tests" / "data" / "missions" / "square_8ms.plan"
TILT_LIMIT_DEG = 45.0  # PX4's MPC_TILTMAX_AIR default, the mock's and SIH's
STEP_GOAL = 0.05
LOCK = "/tmp/ecca-px4-flights.lock"


def quality_of_tlog(path: Path) -> dict[str, Any]:
    """The figures of one flight's tlog (see the module docstring)."""
    conn = mavutil.mavlink_connection(str(path), dialect="common")
    z0: float | None = None
    height, in_air = 0.0, False
    prev: tuple[float, float, bool] | None = None
    steps: list[float] = []
    tilt_max, over_s, t_last = 0.0, 0.0, None
    att: list[tuple[float, float, float]] = []  # (vehicle time [s], roll, pitch [deg]) > 3 m up
    try:
        while (m := conn.recv_match(blocking=False)) is not None:
            kind = m.get_type()
            if kind == "LOCAL_POSITION_NED":
                z0 = float(m.z) if z0 is None else z0
                height = z0 - float(m.z)
            elif kind == "ATTITUDE" and height > 3.0:
                att.append((m.time_boot_ms * 1e-3, math.degrees(m.roll), math.degrees(m.pitch)))
            elif kind == "EXTENDED_SYS_STATE":
                in_air = int(m.landed_state) == 2
            elif kind == "SET_ATTITUDE_TARGET":
                t = float(m._timestamp)
                up = in_air and height > 0.5
                if prev is not None and up and prev[2] and t - prev[0] <= 0.02:
                    steps.append(abs(float(m.thrust) - prev[1]))
                prev = (t, float(m.thrust), up)
                if not int(m.type_mask) & 128:
                    x, y = float(m.q[1]), float(m.q[2])
                    tilt = math.degrees(math.acos(max(-1.0, min(1.0, 1.0 - 2.0 * (x * x + y * y)))))
                    tilt_max = max(tilt_max, tilt)
                    if tilt > TILT_LIMIT_DEG + 1e-3 and t_last is not None:
                        over_s += min(t - t_last, 0.1)
                t_last = t
    finally:
        conn.close()
    return {"pairs": len(steps), "max_step": max(steps, default=0.0),
            "over_0_05": sum(s > STEP_GOAL for s in steps),
            "over_0_1": sum(s > 0.1 for s in steps), "max_tilt_deg": tilt_max,
            "over_tilt_s": over_s, "wobble_deg": _wobble(att)}


def _wobble(att: list[tuple[float, float, float]]) -> float:
    """How the vehicle rocks [deg]: its roll and pitch on a 100 Hz grid of its own clock, less
    their centred 0.51 s mean, RMS of both together (NaN without 100 samples)."""
    if len(att) < 100:
        return math.nan
    a = np.array(sorted(att))
    grid = np.arange(a[0, 0], a[-1, 0], 0.01)
    box = np.ones(51) / 51.0
    hp = [np.interp(grid, a[:, 0], a[:, k]) for k in (1, 2)]
    hp = [(y - np.convolve(y, box, mode="same"))[25:-25] for y in hp]
    return float(np.sqrt(np.mean(hp[0] ** 2 + hp[1] ** 2)))


@contextlib.contextmanager
def worktree(ref: str) -> Iterator[Path]:
    """A temporary git worktree of `ref` (removed after)."""
    folder = Path(tempfile.mkdtemp(prefix="ecca-before-"))
    subprocess.run(["git", "worktree", "add", "--detach", str(folder), ref], cwd=ROOT,
                   check=True, capture_output=True)
    try:
        yield folder
    finally:
        subprocess.run(["git", "worktree", "remove", "--force", str(folder)], cwd=ROOT,
                       check=False, capture_output=True)


def _replay(code: Path, mission: Path, mode: str, out: Path) -> dict[str, Any]:
    cmd = [sys.executable, "-m", "companion", "replay", str(mission), "--mode", mode,
           "--out", str(out)]
    subprocess.run(cmd, cwd=code, capture_output=True, text=True, timeout=900)
    tlog = out / mission.stem / "flight.tlog"
    if not tlog.exists():
        return {"error": "no tlog"}
    return quality_of_tlog(tlog)


def _fly_px4(code: Path, mode: str, out: Path, mission: Path = SQUARE) -> dict[str, Any]:
    from px4_harness import Px4Sitl, find_px4_sitl

    loc, why = find_px4_sitl()
    if loc is None:
        return {"error": f"no PX4 SITL: {why}"}
    out.mkdir(parents=True, exist_ok=True)
    tlog = out / "flight.tlog"
    with open(LOCK, "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        sitl = Px4Sitl(location=loc, log=out / "px4-console.log")
        sitl.start()
        try:
            cmd = [sys.executable, "-m", "companion", "fly", str(mission), "--connect", sitl.url,
                   "--target-system", str(sitl.target_system), "--mode", mode,
                   "--log", str(tlog)]
            proc = subprocess.run(cmd, cwd=code, capture_output=True, text=True, timeout=300)
        finally:
            sitl.stop()
    res = quality_of_tlog(tlog) if tlog.exists() else {"error": "no tlog"}
    res["exit"] = proc.returncode
    rep = Path(f"{tlog}.report.json")
    if rep.exists():  # `fly`'s own figures: armed time flown, tracking error, waypoints
        r = json.loads(rep.read_text())
        res.update(duration_s=r.get("duration_s"), rms_m=r.get("rms_error_m"),
                   reached=f"{r.get('waypoints_reached')}/{len(r.get('waypoints') or [])}")
    return res


def _row(label: str, b: dict[str, Any], a: dict[str, Any]) -> str:
    def cell(r: dict[str, Any]) -> str:
        if "error" in r:
            return r["error"]
        text = (f"{r['max_step']:.3f} / {r['over_0_05']} / {r['over_0_1']} / "
                f"{r['max_tilt_deg']:.1f} / {r['over_tilt_s']:.2f} / "
                f"{r.get('wobble_deg', math.nan):.2f}")
        if r.get("duration_s") is not None:
            text += (f" (fly: {r['duration_s']:.1f} s, RMS {r['rms_m']:.3f} m, "
                     f"{r['reached']} waypoints)")
        return text
    return f"| {label} | {cell(b)} | {cell(a)} |"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--parts", nargs="+", choices=("mock", "px4"), default=["mock", "px4"])
    ap.add_argument("--before", default="910ef12", help="git revision of the 'before' code")
    ap.add_argument("--px4-missions", nargs="+", type=Path, default=[SQUARE],
                    help="missions flown on real PX4 (default: the 10 m-descent square)")
    ap.add_argument("--after-only", action="store_true",
                    help="fly the working tree only (the 'before' column says 'not flown')")
    ap.add_argument("--title", default="Setpoint quality", help="BENCHMARKS.md section")
    ap.add_argument("--out", default="bench_out/setpoint-quality")
    ap.add_argument("--write", action="store_true")
    args = ap.parse_args(argv)
    out = ROOT / args.out
    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                          text=True).stdout.strip()
    t0 = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    rows: list[str] = []
    results: dict[str, Any] = {}
    missions = [p for p in sorted((ROOT / "examples" / "missions").glob("*.plan"))
                if "rover" not in p.name] + [SQUARE]
    with worktree(args.before) as before:
        for part in args.parts:
            for mode in ("attitude", "rates"):
                cases = ([(m.name, m) for m in missions] if part == "mock"
                         else [(f"{m.name} on real PX4", m.resolve()) for m in args.px4_missions])
                for label, mission in cases:
                    pair: list[dict[str, Any]] = []
                    for name, code in (("before", before), ("after", ROOT)):
                        if name == "before" and args.after_only:
                            pair.append({"error": "not flown"})
                            continue
                        where = out / part / mode / name / mission.stem
                        r = (_replay(code, mission, mode, where) if part == "mock"
                             else _fly_px4(code, mode, where, mission))
                        pair.append(r)
                        results[f"{part}/{mode}/{label}/{name}"] = r
                    rows.append(_row(f"{label}, {mode}", *pair))
                    print(rows[-1], flush=True)
    out.mkdir(parents=True, exist_ok=True)
    (out / "quality.json").write_text(json.dumps(results, indent=1))
    cmd = "`.venv/bin/python bench/bench_setpoint_quality.py " + " ".join(
        (["--parts", *args.parts] if args.parts != ["mock", "px4"] else [])
        + (["--px4-missions", *map(str, args.px4_missions)] if args.px4_missions != [SQUARE]
           else [])
        + (["--after-only"] if args.after_only else [])
        + (["--title", repr(args.title)] if args.title != "Setpoint quality" else [])
        + ["--before", args.before, "--write"]) + "`"
    text = "\n".join([
        f"## {args.title}", "",
        f"Command: {cmd} ({t0}, before = git {args.before}, after = git {head} and the working "
        "tree). Mock: lockstep replay; real PX4: v1.16 SITL (SIH quad, default parameters), "
        "`companion fly`, one flight per cell. Judged from each flight's tlog alone: thrust steps "
        "between consecutive SET_ATTITUDE_TARGET frames at most 20 ms apart while PX4 reports "
        "the vehicle in the air and it is more than 0.5 m up; tilt of the commanded quaternion "
        "(attitude mode) against MPC_TILTMAX_AIR 45 deg.", "",
        "Cells: largest thrust step / steps over 0.05 / steps over 0.1 / largest commanded tilt "
        "[deg] / time over 45 deg [s] / wobble [deg] (the vehicle's own roll and pitch in "
        "ATTITUDE more than 3 m up, less their centred 0.51 s mean, RMS); real PX4 rows add "
        "`fly`'s own report: armed time flown "
        "(ARM to disarm), RMS distance to the reference, waypoints reached.", "",
        "| mission, mode | before | after |", "| --- | --- | --- |", *rows, ""])
    print(text)
    if args.write:
        write_section(args.title, text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
