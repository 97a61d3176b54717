"""Benchmark: per-sample cost of the multirotor flatness map.

Compares, in one run, the batched numpy path (N = 1e5), the numeric path one sample at a time,
the CasADi ``Function`` called one sample at a time, and ``Function.map`` over the batch. Prints
a table and writes the "## Flatness" section of BENCHMARKS.md (``--no-write`` to skip).

    python bench/bench_flatness.py [--n 100000] [--no-write]

Both the best wall-clock time and the best process CPU time of several repetitions are
reported: the machine is shared, and CPU time is what the code costs when other processes
compete for the two cores (for the 2-thread map it sums both threads).
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from collections.abc import Callable
from pathlib import Path

import casadi as ca
import numpy as np
from benchmarks_md import write_section

from companion.flatness import MultirotorParams, multirotor_setpoint, symbolic

ROOT = Path(__file__).resolve().parents[1]
GOAL_US = 1.0

Row = tuple[str, float, float]  # name, wall us/sample, CPU us/sample


def _best(fn: Callable[[], object], repeat: int, per: int) -> tuple[float, float]:
    """Best (wall, CPU) microseconds per sample over ``repeat`` runs of ``per`` samples."""
    wall = cpu = float("inf")
    for _ in range(repeat):
        w0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall = min(wall, time.perf_counter() - w0)
        cpu = min(cpu, time.process_time() - c0)
    return wall / per * 1e6, cpu / per * 1e6


def run(n: int) -> tuple[list[Row], str]:
    rng = np.random.default_rng(0)
    P = MultirotorParams(1.0, np.diag([0.01, 0.012, 0.02]), drag=1.0, hover_thrust=0.5)
    vel, acc, jerk, snap = (rng.normal(size=(n, 3)) * s for s in (3.0, 4.0, 5.0, 10.0))
    yaw, yaw_rate, yaw_acc = rng.normal(size=(3, n))
    rows: list[Row] = []

    def batched() -> None:
        multirotor_setpoint(vel, acc, jerk, snap, yaw, yaw_rate, yaw_acc, P)

    batched()  # warm-up
    rows.append((f"numeric batched (N={n})", *_best(batched, 15, n)))

    m = 2000

    def single() -> None:
        for i in range(m):
            multirotor_setpoint(
                vel[i], acc[i], jerk[i], snap[i], yaw[i], yaw_rate[i], yaw_acc[i], P
            )

    rows.append(("numeric, one sample per call", *_best(single, 3, m)))

    f = symbolic().multirotor
    J = P.inertia_matrix
    p_args = (P.mass, J, P.g, P.hover_thrust, P.drag)

    def cas_single() -> None:
        for i in range(m):
            f(vel[i], acc[i], jerk[i], snap[i], yaw[i], yaw_rate[i], yaw_acc[i], *p_args)

    rows.append(("CasADi Function, one sample per call", *_best(cas_single, 3, m)))

    args = (vel.T, acc.T, jerk.T, snap.T, yaw[None], yaw_rate[None], yaw_acc[None], *p_args)
    for label, fmap in (("serial", f.map(n)), ("thread x2", f.map(n, "thread", 2))):

        def mapped(g: ca.Function = fmap) -> None:
            g(*args)

        mapped()
        rows.append((f"CasADi Function.map({n}, {label})", *_best(mapped, 3, n)))

    env = (
        f"{platform.machine()}, {os.cpu_count()} cores, load average "
        f"{os.getloadavg()[0]:.1f} at the end of the run, Python {platform.python_version()}, "
        f"numpy {np.__version__}, casadi {getattr(ca, '__version__', '?')}, "
        f"{f.n_instructions()} SX instructions"
    )
    return rows, env


def render(rows: list[Row], env: str, cmd: str) -> str:
    base_wall, base_cpu = rows[0][1], rows[0][2]
    lines = [
        "## Flatness",
        "",
        f"Command: `{cmd}` (from the repository root, in the project's virtual environment).",
        f"Machine: {env}.",
        "Per-sample cost of `multirotor_setpoint` (drag on), best of several repetitions; ratio ="
        " time / batched numeric time measured in the same run.",
        "",
        "| path | wall us/sample | CPU us/sample | ratio (wall) |",
        "| --- | ---: | ---: | ---: |",
    ]
    for name, wall, cpu in rows:
        lines.append(f"| {name} | {wall:.3f} | {cpu:.3f} | {wall / base_wall:.1f} |")
    verdict = "met" if base_wall <= GOAL_US else "NOT met (wall clock)"
    lines += [
        "",
        f"Goal (batched numeric <= {GOAL_US:g} us per sample): {verdict}: {base_wall:.3f} us "
        f"wall, {base_cpu:.3f} us CPU.",
        "",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="Per-sample cost of the flatness map.")
    ap.add_argument("--n", type=int, default=100_000, help="batch size (default 100000)")
    ap.add_argument("--no-write", action="store_true", help="do not update BENCHMARKS.md")
    ns = ap.parse_args(argv)
    rows, env = run(ns.n)
    cmd = "python bench/bench_flatness.py" + ("" if ns.n == 100_000 else f" --n {ns.n}")
    text = render(rows, env, cmd)
    print(text)
    if not ns.no_write:
        write_section("Flatness", text)
        print(f"updated {ROOT / 'BENCHMARKS.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
