"""A/B of the replay speed across source trees (e.g. `git worktree`s of two commits).

Each run is a fresh process with the tree under test first on `sys.path`, timing
`replay_file(examples/missions/five_minute.plan, ReplayConfig(mode=...))` (flight, report, tlog,
PNG drawn in-process); the trees take turns, `--rounds` times, so drift of the machine hits
all of them alike. Compare the ratios between trees, not the absolute figures.

Usage: python bench/bench_replay_ab.py TREE [TREE ...] [--rounds 3] [--mode attitude]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

_CHILD = """
import os, sys, tempfile, time
root, mode = sys.argv[1], sys.argv[2]
sys.path.insert(0, root)
import companion, sitl_mock
assert companion.__file__.startswith(root) and sitl_mock.__file__.startswith(root)
from companion.replay.runner import ReplayConfig, replay_file
try:  # flight.png drawn by the caller since issue 25; before, replay_file drew it
    from companion.app.plotting import replay_drawer
    kw = {"draw": replay_drawer()}
except ImportError:
    kw = {}
with tempfile.TemporaryDirectory() as out:
    load = os.getloadavg()[0]
    c0, t0 = time.process_time(), time.perf_counter()
    r = replay_file(os.path.join(root, "examples/missions/five_minute.plan"), out,
                    ReplayConfig(mode=mode), **kw)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
rep = r.report
sim = rep["simulated_s"] if isinstance(rep, dict) else rep.simulated_s
print(f"{sim:.1f} {wall:.3f} {cpu:.3f} {load:.2f} {int(r.ok)}")
"""


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("trees", nargs="+", type=Path)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--mode", default="attitude", choices=("attitude", "position", "rates"))
    args = ap.parse_args()
    rows: dict[Path, list[tuple[float, float, float, float]]] = {t: [] for t in args.trees}
    for _ in range(args.rounds):
        for tree in args.trees:
            out = subprocess.run(
                [sys.executable, "-c", _CHILD, str(tree.resolve()), args.mode],
                check=True, capture_output=True, text=True, env=dict(os.environ),
            ).stdout.split()
            sim, wall, cpu, load = (float(v) for v in out[:4])
            rows[tree].append((sim, wall, cpu, load))
            print(f"{tree}: sim {sim:.0f} s wall {wall:.2f} s cpu {cpu:.2f} s "
                  f"x {sim / wall:.1f} load {load:.2f} ok {out[4]}", flush=True)
    print(f"\n| tree | wall s ({args.rounds} runs) | x real time |\n| --- | --- | --- |")
    for tree, rs in rows.items():
        walls = ", ".join(f"{w:.2f}" for _, w, _, _ in rs)
        xs = [s / w for s, w, _, _ in rs]
        print(f"| {tree} | {walls} | {min(xs):.1f}-{max(xs):.1f} |")


if __name__ == "__main__":
    main()
