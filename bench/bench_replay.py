"""Replay speed: simulated seconds per wall second for a ~5-minute mission in attitude mode, and
throughput of `--jobs 2` against `--jobs 1` on 8 missions, measured in the same run.

Usage: python bench/bench_replay.py [--write] [--repeat N]   (--write updates BENCHMARKS.md)
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks_md import write_section  # noqa: E402

from companion.app.cli import main as cli_main  # noqa: E402
from companion.app.plotting import PlotWorker, replay_drawer  # noqa: E402
from companion.replay.runner import ReplayConfig, replay_file  # noqa: E402

FIVE_MIN = ROOT / "examples" / "missions" / "five_minute.plan"
EIGHT = [ROOT / "examples" / "missions" / n for n in (
    "square.plan", "ten_waypoints.plan", "hold_and_jump.plan", "square.waypoints",
    "square.plan", "ten_waypoints.plan", "hold_and_jump.plan", "square.waypoints",
)]


def run_single(mode: str) -> dict[str, float]:
    """One `python -m companion replay five_minute.plan` worth of work, timed as the CLI runs
    it for one file: the plot helper process is started inside the timed region."""
    with tempfile.TemporaryDirectory() as out:
        load = os.getloadavg()[0]
        ch0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        c0 = time.process_time()
        t0 = time.perf_counter()
        with PlotWorker() as plotter:
            r = replay_file(FIVE_MIN, out, ReplayConfig(mode=mode),  # type: ignore[arg-type]
                            draw=replay_drawer(plotter))
        wall = time.perf_counter() - t0
        cpu = time.process_time() - c0
        ch1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        if plotter.failures:
            raise SystemExit(f"plot helper not used: {plotter.failures}")
    helper = (ch1.ru_utime + ch1.ru_stime) - (ch0.ru_utime + ch0.ru_stime)
    sim = float(r.report.simulated_s)
    return {"sim_s": sim, "wall_s": wall, "factor": sim / wall, "cpu_s": cpu,
            "helper_cpu_s": helper, "cpu_factor": sim / (cpu + helper), "load1": load,
            "ok": float(r.ok)}


def median_run(mode: str, repeat: int) -> dict[str, float]:
    """`run_single` `repeat` times; the run with the median wall time, plus the wall range."""
    runs = sorted((run_single(mode) for _ in range(repeat)), key=lambda r: r["wall_s"])
    med = dict(runs[len(runs) // 2])
    med["wall_min_s"], med["wall_max_s"] = runs[0]["wall_s"], runs[-1]["wall_s"]
    med["repeat"] = float(repeat)
    return med


#: Text after this line in the existing "## Replay" section is kept by --write (notes and
#: A/B measurements that this script does not produce itself).
NOTES_MARK = "<!-- notes below are kept by bench_replay.py --write -->"


def _kept_notes() -> str:
    md = ROOT / "BENCHMARKS.md"
    text = md.read_text(encoding="utf-8") if md.exists() else ""
    start = text.find("\n## Replay\n")
    if start < 0:
        return ""
    end = text.find("\n## ", start + 1)
    section = text[start : end if end >= 0 else len(text)]
    i = section.find(NOTES_MARK)
    return section[i:].strip("\n") if i >= 0 else ""


def run_jobs(jobs: int) -> float:
    with tempfile.TemporaryDirectory() as out:
        files = []
        for i, f in enumerate(EIGHT):  # distinct names so outputs do not collide
            dst = Path(out) / f"m{i}{f.suffix}"
            dst.write_bytes(f.read_bytes())
            files.append(str(dst))
        t0 = time.perf_counter()
        code = cli_main(["replay", *files, "--jobs", str(jobs), "--out", str(Path(out) / "o")])
        wall = time.perf_counter() - t0
        if code not in (0, 1):
            raise SystemExit(f"replay failed with exit code {code}")
    return wall


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--write", action="store_true", help="update BENCHMARKS.md")
    ap.add_argument("--repeat", type=int, default=3, help="runs per mode (median reported)")
    args = ap.parse_args()
    single = {m: median_run(m, args.repeat) for m in ("attitude", "position")}
    w1 = run_jobs(1)
    w2 = run_jobs(2)
    lines = [
        "## Replay",
        "",
        f"Command: `python bench/bench_replay.py --write` (--repeat {args.repeat}; "
        f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores).",
        "",
        "| case | simulated s | wall s (median) | x real time | wall s range | CPU s main "
        "+ plot helper | x real time (CPU) | load avg (1 min) before |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for m, r in single.items():
        lines.append(
            f"| five_minute.plan, {m} mode | {r['sim_s']:.0f} | {r['wall_s']:.1f} | "
            f"{r['factor']:.1f} | {r['wall_min_s']:.1f}-{r['wall_max_s']:.1f} | "
            f"{r['cpu_s']:.1f} + {r['helper_cpu_s']:.1f} | {r['cpu_factor']:.1f} | "
            f"{r['load1']:.2f} |"
        )
    lines += [
        "",
        "Wall and CPU time of one file as `python -m companion replay` runs it: `replay_file` "
        "(flight, report, tlog, PNG) with its plot helper process started in the timed region. "
        "The helper imports matplotlib (~0.6 s of CPU) on the other core while the flight "
        "runs; its CPU time is the second CPU figure.",
        "",
        f"8 missions: `--jobs 1` {w1:.1f} s, `--jobs 2` {w2:.1f} s wall: "
        f"throughput ratio {w1 / w2:.2f}x (goal: close to 2 on 2 cores).",
        "",
    ]
    notes = _kept_notes()
    if notes:
        lines += [notes, ""]
    text = "\n".join(lines)
    print(text)
    print(json.dumps({"single": single, "jobs1_s": w1, "jobs2_s": w2}, indent=1))
    if args.write:
        write_section("Replay", text)


if __name__ == "__main__":
    main()
