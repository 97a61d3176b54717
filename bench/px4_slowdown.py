"""A real PX4 SITL that slows down mid-flight, and what the companion's sample clock made of it.

PX4 SITL slowed from 0.98x to 0.65x real time mid-flight when its host got busy (2026-12-01).
`throttle` reproduces that on purpose: it SIGSTOPs the newest `px4` process for (1 - SHARE) of
every 20 ms, from START s on for DUR s (PX4's lockstep clock stalls while it is stopped).
`ages` reads a flight's tlog: PX4's clock rate per 2 s window (time_boot against the tlog's
receive times) and the sample age the companion's `SampleClock` maps each LOCAL_POSITION_NED
to, replayed through the `SampleClock` of TREE (default: this one), so that two trees' clocks
can be compared on the same flight.

    python bench/px4_slowdown.py throttle 18 15 0.65 &
    python bench/bench_tracking.py --target px4 --speeds 6 --modes attitude --repeat 1 --out D
    python bench/px4_slowdown.py ages D/px4-attitude-6-0/flight.tlog [--tree OTHER_TREE]
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def throttle(start_s: float, dur_s: float, share: float, period_s: float = 0.02) -> None:
    """Let the newest `px4` run only `share` of every `period_s` [s] for `dur_s` [s], after
    `start_s` [s]."""
    time.sleep(start_s)
    pids = subprocess.run(["pgrep", "-n", "-x", "px4"], capture_output=True, text=True,
                          check=False).stdout.split()
    if not pids:
        sys.exit("no px4 process")
    pid = int(pids[0])
    t_end = time.monotonic() + dur_s
    try:
        while time.monotonic() < t_end:
            os.kill(pid, signal.SIGSTOP)
            time.sleep(period_s * (1.0 - share))
            os.kill(pid, signal.SIGCONT)
            time.sleep(period_s * share)
    except ProcessLookupError:
        return
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGCONT)


def ages(tlog: Path, tree: Path) -> None:
    """Print PX4's clock rate and the mapped sample age per 2 s window around OFFBOARD."""
    sys.path.insert(0, str(tree))
    os.environ["MAVLINK20"] = "1"
    from pymavlink import mavutil

    from companion.flight.clock import SampleClock

    m = mavutil.mavlink_connection(str(tlog), dialect="common")
    pos: list[tuple[float, float]] = []  # (receive time, time_boot) [s]
    offboard: list[float] = []
    t0: float | None = None
    while (msg := m.recv_match(blocking=False)) is not None:
        t = float(msg._timestamp)
        t0 = t if t0 is None else t0
        kind = msg.get_type()
        if kind == "LOCAL_POSITION_NED":
            pos.append((t - t0, msg.time_boot_ms * 1e-3))
        elif kind == "HEARTBEAT" and msg.autopilot == 12 and (msg.custom_mode >> 16) & 0xFF == 6:
            offboard.append(t - t0)
    if not offboard or not pos:
        sys.exit("no OFFBOARD or no positions in the tlog")
    clock = SampleClock()
    rows = [(rx, boot, rx - clock.local_time(boot, rx)) for rx, boot in pos]
    t_on, t_off = min(offboard), max(offboard)
    print(f"{tlog}: OFFBOARD {t_on:.1f}-{t_off:.1f} s of the tlog, SampleClock of {tree}")
    t = t_on - 4.0
    while t < t_off + 2.0:
        sel = [r for r in rows if t <= r[0] < t + 2.0]
        if len(sel) > 2:
            rate = (sel[-1][1] - sel[0][1]) / (sel[-1][0] - sel[0][0])
            print(f"  {t:6.1f}-{t + 2:5.1f} s  PX4 {rate:.2f}x real time, "
                  f"mapped age max {max(r[2] for r in sel):.3f} s")
        t += 2.0
    flown = [r[2] for r in rows if t_on <= r[0] <= t_off]
    print(f"in OFFBOARD: mapped age max {max(flown):.3f} s, "
          f"{sum(a > 0.5 for a in flown)} samples older than the law's 0.5 s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    th = sub.add_parser("throttle")
    th.add_argument("start", type=float)
    th.add_argument("dur", type=float)
    th.add_argument("share", type=float)
    ag = sub.add_parser("ages")
    ag.add_argument("tlog", type=Path)
    ag.add_argument("--tree", type=Path, default=ROOT)
    a = ap.parse_args()
    if a.cmd == "throttle":
        throttle(a.start, a.dur, a.share)
    else:
        ages(a.tlog, a.tree)


if __name__ == "__main__":
    main()
