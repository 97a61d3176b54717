"""Trajectory upload time to the onboard module over a degraded link, A/B across source trees.

Each tree's own `companion.onboard.protocol.Uploader` uploads a figure-8-sized trajectory
(`--segments`, random degree-7 segments) to that tree's own module C (`gen_c.onboard_native`,
compiled for the run) through a simulated link, sans I/O, in simulated time:
- each way a latency of `--latency` s plus a uniform jitter of `--jitter` s, each message lost
  with probability `--loss`;
- the module reads one message per 4 ms cycle, the newest (PX4's uORB `debug_array` holds a
  single message: an older one not yet read is overwritten);
- the companion polls every millisecond (what its event loop does when it waits on the next
  acknowledgement or the next resend).

Figures per tree over `--runs` seeded links (the same seeds in every tree): median and p90 of
the upload's simulated time (first send to verified), resent parts, failures, and the median's
ratio to the first tree. Simulated time: the figures do not depend on the machine's load.

Usage:
  python bench/bench_upload.py git:HEAD~1 . [--segments 210] [--latency 0.02] [--loss 0.05]
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys

from bench_replay_speed import _check_tree, _env, resolve_tree

_SIM = """
import json, sys, tempfile, pathlib
import numpy as np
from companion.onboard import protocol as P
from gen_c import onboard_native as N
segments, runs = int(sys.argv[1]), int(sys.argv[5])
latency, jitter, loss = map(float, sys.argv[2:5])
lib = N.OnboardLibrary(N.build_onboard_library(cache=pathlib.Path(tempfile.mkdtemp())))
rng0 = np.random.default_rng(0)
breaks = np.concatenate([[0.0], np.cumsum(rng0.uniform(0.2, 0.5, segments))])
cps = [np.array([0.0, 0.0, -5.0]) + np.cumsum(rng0.normal(0, 0.5, (8, 3)), axis=0)
       for _ in range(segments)]
law = P.LawParams(kp=(6.0, 6.0, 8.0), kd=(4.0, 4.0, 5.0), ki=(1.0, 1.0, 1.0),
                  i_max=(2.0, 2.0, 2.0), hover=0.5, drag=1.0, mass=1.0, g=9.80665,
                  thrust_min=0.08, thrust_max=1.0, max_tilt_rad=0.78, drag_estimate=True,
                  lead_s=0.15)
up = P.encode_upload(breaks, cps, None, law, sysid=255, compid=190)
out = []
for seed in range(runs):
    rng = np.random.default_rng(1000 + seed)
    m = N.OnboardModule(lib)
    u = P.Uploader(up)
    to_mod, to_comp, pending, t = [], [], None, 0.0
    next_cycle = 0.0
    while not u.done and t < 120.0:
        msg = u.poll(t)
        if msg is not None and rng.random() >= loss:
            to_mod.append((t + latency + rng.random() * jitter, msg))
        for item in sorted((i for i in to_mod if i[0] <= t), key=lambda i: i[0]):
            to_mod.remove(item)
            pending = item[1]  # debug_array: the newest message overwrites an unread one
        if t >= next_cycle:
            next_cycle += 0.004
            if pending is not None:
                a = m.message(pending[0], pending[1])
                pending = None
                if a is not None and rng.random() >= loss:
                    ack = P.decode_ack(a.command, a.result, a.state, a.value)
                    to_comp.append((t + latency + rng.random() * jitter, ack))
        for item in sorted((i for i in to_comp if i[0] <= t), key=lambda i: i[0]):
            to_comp.remove(item)
            u.on_ack(item[1], t)
        t = round(t + 0.001, 6)
    out.append({"t": t, "verified": u.verified, "resent": u.resent})
print(json.dumps(out))
"""


def run_tree(tree_arg: str, args: argparse.Namespace) -> list[dict[str, float]]:
    tree = resolve_tree(tree_arg)
    _check_tree(tree)
    proc = subprocess.run(
        [sys.executable, "-c", _SIM, str(args.segments), str(args.latency), str(args.jitter),
         str(args.loss), str(args.runs)],
        cwd=tree, env=_env(tree, "cached"), capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise SystemExit(f"the simulation in {tree} failed:\n{proc.stderr[-3000:]}")
    return list(json.loads(proc.stdout.strip().splitlines()[-1]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("trees", nargs="+")
    ap.add_argument("--segments", type=int, default=210)
    ap.add_argument("--latency", type=float, default=0.02, help="one way [s]")
    ap.add_argument("--jitter", type=float, default=0.005, help="uniform, one way [s]")
    ap.add_argument("--loss", type=float, default=0.05, help="each way (0..1)")
    ap.add_argument("--runs", type=int, default=30)
    args = ap.parse_args()
    rows = []
    base = None
    for tree in args.trees:
        res = run_tree(tree, args)
        ok = [r for r in res if r["verified"]]
        times = sorted(r["t"] for r in ok)
        med = statistics.median(times) if times else float("nan")
        p90 = times[int(0.9 * (len(times) - 1))] if times else float("nan")
        base = med if base is None else base
        rows.append(f"| {tree} | {med:.2f} | {p90:.2f} | "
                    f"{statistics.median(r['resent'] for r in res):.0f} | "
                    f"{len(res) - len(ok)} | {med / base:.2f} |")
    print(f"Upload of {args.segments} segments, {args.latency * 1e3:.0f} ms (+0-"
          f"{args.jitter * 1e3:.0f} ms) each way, {args.loss:.0%} loss each way, "
          f"{args.runs} seeded links per tree (simulated time):\n")
    print("| tree | median [s] | p90 [s] | resent (median) | failed | median / first |")
    print("| --- | ---: | ---: | ---: | ---: | ---: |")
    print("\n".join(rows))


if __name__ == "__main__":
    main()
