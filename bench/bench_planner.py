"""Planner benchmark: fixed-duration solve vs M (and a dense KKT reference in the same run),
time-allocated plans for 10 and 100 waypoints, and the duration ratio of the time-allocation
test set.

Usage: ``python bench/bench_planner.py [--write]`` (``--write`` replaces the "## Planner"
section of BENCHMARKS.md). The planner makes no multi-threaded BLAS calls in its hot loops
(its L-BFGS is numpy on 1-D vectors, the banded Cholesky is LAPACK dpbtrf/dpbtrs, and its wide
matrix products are chunked below OpenBLAS's threading threshold), so the BLAS thread setting
is left as the environment has it. Other jobs share the machine: the load average is recorded
and CPU (process) time is reported next to wall time.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from collections.abc import Callable
from math import factorial
from pathlib import Path

import numpy as np
import scipy
from benchmarks_md import BENCHMARKS_MD, write_section

from companion.flatness import MultirotorParams
from companion.trajectory import Limits, plan, plan_with_info

ROOT = Path(__file__).resolve().parents[1]
G = 9.80665
VMAX, AMAX = 5.0, 4.0
PARAMS = MultirotorParams(mass=1.5, inertia=np.diag([0.03, 0.03, 0.05]), drag=0.4)
MG = PARAMS.mass * G
FULL_LIMITS = Limits(
    max_speed_m_s=VMAX,
    max_acc_m_s2=AMAX,
    max_jerk_m_s3=30.0,
    max_tilt_rad=0.4,
    max_thrust_n=1.5 * MG,
    min_thrust_n=0.6 * MG,
    max_body_rate_rad_s=3.0,
)
KIN_LIMITS = Limits(max_speed_m_s=VMAX, max_acc_m_s2=AMAX)
#: Timed runs per time-allocated case (after one warm-up run).
ALLOC_RUNS = 11
#: Recorded comparison with the earlier implementation (not re-measured by this script).
HISTORY = [
    "Before / after the time-allocation speed-up (2026-11-22; the previous planner and limits "
    "modules run side by side with the new ones in one process, 11 interleaved runs, load "
    "average 2.8; 100 waypoints of this benchmark): all multirotor limits 222 ms wall best / "
    "221 ms CPU best before, 86 / 85 ms after; speed and acceleration only 163 / 148 ms "
    "before, 81 / 66 ms after. Trajectory durations: this set +0.04 %; the 30 ten-waypoint "
    "sets below mean ratio 0.898 before, 0.899 after; five other 100-waypoint sets +0.4 % on "
    "average; 60 varied sets (3..14 waypoints, yaw none / fixed / velocity) -0.2 % on "
    "average (-17 % .. +3.3 %); every limit still met under dense sampling. Main changes: "
    "penalty evaluated for all segments at once with "
    "one matrix product each way and its gradient only at accepted line-search points; "
    "softer penalty weight (1e3, 45 L-BFGS iterations) for multirotors; body rate through "
    "the flatness map only where an attitude-free bound comes near the limit; closed-form "
    "time scaling of speed, acceleration and jerk in the common-scale search; no "
    "multi-threaded BLAS; banded Cholesky of bandwidth 2s - 3 instead of 2s - 1.",
]


def random_waypoints(rng: np.random.Generator, n: int) -> np.ndarray:
    """Same generator as tests/companion/trajectory/test_planner_allocation.py."""
    pts = [rng.uniform(-5.0, 5.0, 3)]
    while len(pts) < n:
        step = rng.normal(size=3)
        step[2] *= 0.3
        step *= rng.uniform(1.0, 3.0) * VMAX**2 / AMAX / np.linalg.norm(step)
        pts.append(pts[-1] + step)
    return np.array(pts)


def best_of(fn: Callable[[], object], reps: int) -> float:
    """Best wall time (s) of ``reps`` runs."""
    best = float("inf")
    for _ in range(reps):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def dense_kkt_solve(wp: np.ndarray, h: np.ndarray, s: int = 4) -> float:
    """Dense KKT reference (monomial basis, normalised time, continuity through order s)."""
    m, d = h.shape[0], wp.shape[1]
    nc = 2 * s

    def fall(p: int, r: int) -> float:
        return factorial(p) / factorial(p - r) if p >= r else 0.0

    def row(r: int, u: float, hk: float) -> np.ndarray:
        return np.array(
            [fall(p, r) * u ** max(p - r, 0) / hk**r if p >= r else 0.0 for p in range(nc)]
        )

    Q = np.zeros((m * nc, m * nc))
    for k in range(m):
        for i in range(s, nc):
            for j in range(s, nc):
                e = i + j - 2 * s + 1
                Q[k * nc + i, k * nc + j] = fall(i, s) * fall(j, s) / e * h[k] ** (1 - 2 * s)
    rows, rhs = [], []

    def add(parts: dict[int, np.ndarray], value: np.ndarray) -> None:
        r_ = np.zeros(m * nc)
        for k, v in parts.items():
            r_[k * nc : (k + 1) * nc] += v
        rows.append(r_)
        rhs.append(value)

    for k in range(m):
        add({k: row(0, 0.0, h[k])}, wp[k])
        add({k: row(0, 1.0, h[k])}, wp[k + 1])
    for r in range(1, s):
        add({0: row(r, 0.0, h[0])}, np.zeros(d))
        add({m - 1: row(r, 1.0, h[-1])}, np.zeros(d))
    for k in range(m - 1):
        for r in range(1, s + 1):
            add({k: row(r, 1.0, h[k]), k + 1: -row(r, 0.0, h[k + 1])}, np.zeros(d))
    A = np.array(rows)
    kkt = np.block([[2 * Q, A.T], [A, np.zeros((A.shape[0], A.shape[0]))]])
    sol = np.linalg.solve(kkt, np.vstack([np.zeros((m * nc, d)), np.array(rhs)]))
    c = sol[: m * nc]
    return float(np.sum(c * (Q @ c)))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--write", action="store_true", help="update BENCHMARKS.md")
    args = ap.parse_args()
    load_start = os.getloadavg()
    rng = np.random.default_rng(0)
    lines: list[str] = []

    # ---------------------------------------------------------------- fixed durations
    sizes = [10, 100, 1000, 10000]
    times: list[float] = []
    dense: dict[int, tuple[float, float]] = {}
    for m in sizes:
        wp = random_waypoints(rng, m + 1)
        h = rng.uniform(1.0, 5.0, size=m)
        reps = 30 if m <= 100 else 10 if m <= 1000 else 7
        plan(wp, durations=h)  # warm-up
        times.append(best_of(lambda wp=wp, h=h: plan(wp, durations=h), reps))
        if m <= 100:
            t_dense = best_of(lambda wp=wp, h=h: dense_kkt_solve(wp, h), 3 if m == 10 else 1)
            rel = abs(plan_with_info(wp, durations=h).cost - dense_kkt_solve(wp, h))
            rel /= dense_kkt_solve(wp, h)
            dense[m] = (t_dense, rel)
    slope_all = float(np.polyfit(np.log(sizes), np.log(times), 1)[0])
    slope_big = float(np.polyfit(np.log(sizes[1:]), np.log(times[1:]), 1)[0])

    lines.append(
        "Fixed-duration minimum-snap solve (`plan(waypoints, durations=h)`, 3-D, degree 7, "
        "best of several runs; includes input checks and building the PiecewiseBezier):"
    )
    lines.append("")
    lines.append(
        "| segments M | banded solve [ms] | us per segment | dense KKT [ms] | dense / banded "
        "| cost rel. diff |"
    )
    lines.append("| ---: | ---: | ---: | ---: | ---: | ---: |")
    for m, t in zip(sizes, times, strict=True):
        if m in dense:
            td, rel = dense[m]
            extra = f"{td * 1e3:.2f} | {td / t:.1f} | {rel:.1e}"
        else:
            extra = "- | - | -"
        lines.append(f"| {m} | {t * 1e3:.3f} | {t / m * 1e6:.2f} | {extra} |")
    lines.append("")
    verdict_exp = "met" if slope_big <= 1.1 else "NOT met"
    verdict_1000 = "met" if times[2] < 0.020 else "NOT met"
    lines.append(
        f"Fitted exponent of time vs M ({verdict_exp}): {slope_big:.3f} over M = 100..10000 "
        f"({slope_all:.3f} over 10..10000; goal <= 1.1). "
        f"1000 segments: {times[2] * 1e3:.2f} ms (goal < 20 ms: {verdict_1000})."
    )
    lines.append("")

    # ---------------------------------------------------------------- time allocation
    lines.append(
        "Time-allocated plans (`plan(waypoints, limits=..., params=...)`, 3 segments per leg; "
        f"wall and CPU (process) time: best and median of {ALLOC_RUNS} runs):"
    )
    lines.append("")
    lines.append(
        "| waypoints | limits | wall best [ms] | wall median [ms] | CPU best [ms] "
        "| CPU median [ms] | fixed solves | duration / bound |"
    )
    lines.append("| ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    alloc: dict[tuple[int, str], tuple[float, float]] = {}
    for n in (10, 100):
        wp = random_waypoints(np.random.default_rng(42 + n), n)
        polyline = float(np.sum(np.linalg.norm(np.diff(wp, axis=0), axis=1)))
        bound = 1.5 * polyline / VMAX + 2.0 * VMAX / AMAX
        for name, lim, yaw in (
            ("speed, acc", KIN_LIMITS, None),
            ("all multirotor (yaw 0)", FULL_LIMITS, 0.0),
        ):
            runs, cpus = [], []
            res = plan_with_info(wp, limits=lim, params=PARAMS, yaw=yaw)
            for _ in range(ALLOC_RUNS):
                t0, c0 = time.perf_counter(), time.process_time()
                plan_with_info(wp, limits=lim, params=PARAMS, yaw=yaw)
                runs.append(time.perf_counter() - t0)
                cpus.append(time.process_time() - c0)
            alloc[(n, name)] = (min(runs), min(cpus), float(np.median(runs)))
            lines.append(
                f"| {n} | {name} | {min(runs) * 1e3:.1f} | {float(np.median(runs)) * 1e3:.1f} | "
                f"{min(cpus) * 1e3:.1f} | {float(np.median(cpus)) * 1e3:.1f} | {res.solves} | "
                f"{res.trajectory.duration / bound:.3f} |"
            )
    lines.append("")
    kin = alloc[(100, "speed, acc")]
    full = alloc[(100, "all multirotor (yaw 0)")]

    def verdict(t: float) -> str:
        return "met" if t < 0.2 else "NOT met"

    lines.append(
        "Goal 100 waypoints with time allocation < 200 ms (wall best): speed/acc limits "
        f"{kin[0] * 1e3:.0f} ms, {verdict(kin[0])} ({kin[1] * 1e3:.0f} ms CPU, wall median "
        f"{kin[2] * 1e3:.0f} ms); all multirotor limits incl. body rate {full[0] * 1e3:.0f} ms, "
        f"{verdict(full[0])} ({full[1] * 1e3:.0f} ms CPU, wall median {full[2] * 1e3:.0f} ms)."
    )
    lines.append("")

    lines.extend(HISTORY)
    lines.append("")

    # ---------------------------------------------------------------- duration ratio
    ratios = []
    for seed in range(30):
        r = np.random.default_rng(100 + seed)
        wp = random_waypoints(r, 10)
        tr = plan(wp, limits=FULL_LIMITS, params=PARAMS, yaw=float(r.uniform(-3, 3)))
        polyline = float(np.sum(np.linalg.norm(np.diff(wp, axis=0), axis=1)))
        ratios.append(tr.duration / (1.5 * polyline / VMAX + 2.0 * VMAX / AMAX))
    lines.append(
        "Duration ratio T / (1.5 polyline / v_max + 2 v_max / a_max) on the time-allocation test "
        "set (10 random waypoints, legs 1..3 x v_max^2/a_max, v_max 5 m/s, a_max 4 m/s^2, "
        "jerk 30 m/s^3, tilt 0.4 rad, thrust 0.6..1.5 m g, body rate 3 rad/s, 1.5 kg, drag "
        f"0.4 N/(m/s); seeds 100..129, the test uses 100..104): mean {np.mean(ratios):.3f}, "
        f"max {np.max(ratios):.3f} (acceptance: <= 1)."
    )

    load_end = os.getloadavg()
    header = (
        f"Command: `python bench/bench_planner.py --write` ({platform.machine()}, "
        f"{os.cpu_count()} cores shared with other jobs, Python {platform.python_version()}, "
        f"numpy {np.__version__}, scipy {scipy.__version__}, OPENBLAS_NUM_THREADS="
        f"{os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}). Other jobs load the machine "
        f"(1-min load average {load_start[0]:.2f} at the start, {load_end[0]:.2f} at the end): "
        "timings are best-of / median, CPU = process time."
    )
    section = "## Planner\n\n" + header + "\n\n" + "\n".join(lines) + "\n"
    print(section)
    if args.write:
        write_section("Planner", section)
        path = BENCHMARKS_MD
        print(f"updated {path}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
