"""How rough a position estimate is from sample to sample: for each LOCAL_POSITION_NED in a
tlog, the step from the previous one less the mean velocity times the step,
p[k+1] - p[k] - (v[k] + v[k+1]) dt / 2 [m], over samples less than 0.1 s apart (by the
autopilot's time_boot_ms). Its std per axis and the 99th percentile of its horizontal norm.

    python bench/estimate_jitter.py TLOG [TLOG ...]

Real PX4 sends the EKF2 output predictor's state, which IMU propagation smooths; the mock's
SIM_POS_NOISE adds white noise to every sample (BENCHMARKS.md, issue 28, session 20).
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
from pymavlink import mavutil


def jitter(path: str) -> tuple[int, float, np.ndarray, float]:
    """(samples, median step [s], jitter std per axis [m NED], p99 horizontal jitter [m])."""
    m = mavutil.mavlink_connection(path)
    rows = []
    try:
        for _ in range(10_000_000):
            x = m.recv_match(type="LOCAL_POSITION_NED")
            if x is None:
                break
            rows.append((x.time_boot_ms / 1000.0, x.x, x.y, x.z, x.vx, x.vy, x.vz))
    finally:
        m.close()
    a = np.asarray(rows, dtype=float)
    if len(a) < 3:
        raise ValueError(f"{path}: fewer than 3 LOCAL_POSITION_NED")
    _, first = np.unique(a[:, 0], return_index=True)  # one per autopilot time
    a = a[np.sort(first)]
    dt = np.diff(a[:, 0])
    r = np.diff(a[:, 1:4], axis=0) - 0.5 * (a[1:, 4:7] + a[:-1, 4:7]) * dt[:, None]
    r = r[(dt > 0.0) & (dt < 0.1)]
    return len(r), float(np.median(dt)), r.std(axis=0), float(
        np.percentile(np.hypot(r[:, 0], r[:, 1]), 99))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("tlogs", nargs="+")
    args = ap.parse_args(argv)
    for f in args.tlogs:
        n, dt, std, p99 = jitter(f)
        print(f"{f}: {n} steps of {dt:.3f} s | jitter std x/y/z "
              f"{std[0] * 1e3:.1f} / {std[1] * 1e3:.1f} / {std[2] * 1e3:.1f} mm, "
              f"p99 horizontal {p99 * 1e3:.1f} mm")
    return 0


if __name__ == "__main__":
    sys.exit(main())
