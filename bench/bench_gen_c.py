"""Benchmark: the generated C setpoint library vs the Python numeric path, in one run.

Builds ``bench/bench_gen_c.c`` against ``gen_c/ecca_setpoint`` with the system compiler
(``cc -std=c99 -O2``), runs its 1e6-call loops (ns per call, best of 5, thread CPU time) for
Bezier evaluation, multirotor flatness and the full setpoint (evaluate + flatness), in double
and float; measures the Python path one sample at a time (``PiecewiseBezier.evaluate`` orders
0..4 + yaw 0..2, ``multirotor_setpoint``) and the ctypes path (``gen_c.native``) in the same
run; counts instructions per call with valgrind's callgrind (if installed: load-independent);
cross-compiles both variants for a Cortex-M7 (code size, worst stack). Prints the
"## gen_c" section of BENCHMARKS.md and writes it there (``--no-write`` to skip).

    python bench/bench_gen_c.py [--calls 1000000] [--no-write]
"""

from __future__ import annotations

import argparse
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from benchmarks_md import write_section

from companion.flatness import MultirotorParams, multirotor_setpoint
from companion.trajectory import Bezier, PiecewiseBezier
from gen_c import crossbuild, native

ROOT = Path(__file__).resolve().parents[1]
LIB = ROOT / "gen_c" / "ecca_setpoint"
GOAL_FULL_NS = 250.0
GOAL_SPEEDUP = 100.0
CFLAGS = ["-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", "-pedantic"]

# The segment and vehicle of bench_gen_c.c (kept identical).
CTRL_PTS = np.array([[0, 0, -2], [1, 0.5, -2.2], [2.5, 1.5, -2.5], [4, 1, -3], [5, -0.5, -3.2],
                     [6.5, -1, -3], [8, 0, -2.8], [9, 0.5, -2.5]], dtype=np.float64)
YAW_PTS = 0.1 * np.arange(8.0)
H = 4.0
PARAMS = MultirotorParams(mass=1.5, inertia=[[0.03, 0.001, 0], [0.001, 0.03, 0], [0, 0, 0.05]],
                          g=9.80665, hover_thrust=0.5, drag=1.0)


def _best(fn: Callable[[], object], repeat: int) -> float:
    """Best CPU time (s) of ``repeat`` runs (process CPU time, like the C side: shared box)."""
    best = float("inf")
    for _ in range(repeat):
        t0 = time.process_time()
        fn()
        best = min(best, time.process_time() - t0)
    return best


# Callgrind: instructions per call (inclusive, libm included) of these API functions.
CALLGRIND_FUNCS = ("ecca_full_setpoint", "ecca_full_setpoint_f", "ecca_bezier_eval",
                   "ecca_multirotor_setpoint")
CALLGRIND_CALLS = 10_000
# The same measurement on the library before the 2026-11-22 speed-up (commit e7a0c52: separate
# kernels, element-by-element validation before and after each kernel, libm fmax/fmin calls,
# CasADi's NULL guards on every argument): valgrind 3.19 callgrind, same compiler and flags.
CALLGRIND_BEFORE = {"ecca_full_setpoint": 2753, "ecca_full_setpoint_f": 2697,
                    "ecca_bezier_eval": 1206, "ecca_multirotor_setpoint": 1545}
# One-off wall-clock comparison of the same two versions (bench_gen_c.c built against each,
# run alternately, 1e6 calls x 15 repetitions, best; load average 3.4-3.9), 2026-11-22.
BEFORE_AFTER_NS = ("full double setpoint, before / after, run alternately in one session "
                   "(load average 3.4-3.9): 382 / 211 ns and 321 / 204 ns")


def _build(exe: Path) -> None:
    cmd = ["cc", *CFLAGS, f"-I{LIB}", str(ROOT / "bench" / "bench_gen_c.c"),
           *(str(LIB / s) for s in native.SOURCES), "-lm", "-o", str(exe)]
    subprocess.run(cmd, check=True, timeout=300)


def run_c(calls: int, reps: int) -> tuple[dict[str, float], str]:
    with tempfile.TemporaryDirectory(prefix="bench_gen_c_") as tmp:
        exe = Path(tmp) / "bench_gen_c"
        _build(exe)
        out = subprocess.run([str(exe), str(calls), str(reps)], check=True, capture_output=True,
                             text=True, timeout=600).stdout
    version = subprocess.run(["cc", "--version"], capture_output=True, text=True,
                             check=True).stdout.splitlines()[0]
    return {k: float(v) for k, v in (line.split() for line in out.splitlines())}, version


def run_callgrind() -> dict[str, float]:
    """Instructions per call of :data:`CALLGRIND_FUNCS` (valgrind's callgrind: counts
    instructions, so the result does not depend on the machine's load); {} without valgrind."""
    if shutil.which("valgrind") is None:
        return {}
    out: dict[str, float] = {}
    with tempfile.TemporaryDirectory(prefix="bench_gen_c_cg_") as tmp:
        exe = Path(tmp) / "bench_gen_c"
        _build(exe)
        for fn in CALLGRIND_FUNCS:
            prof = Path(tmp) / f"{fn}.out"
            subprocess.run(["valgrind", "--tool=callgrind", f"--toggle-collect={fn}",
                            f"--callgrind-out-file={prof}", str(exe), str(CALLGRIND_CALLS), "1"],
                           check=True, capture_output=True, timeout=600)
            m = re.search(r"^(?:summary|totals): (\d+)", prof.read_text(), re.M)
            assert m is not None, f"no totals in {prof}"
            # Each loop calls fn CALLGRIND_CALLS times; ecca_bezier_eval also fills the 1024
            # precomputed states of bench_gen_c.c.
            calls = CALLGRIND_CALLS + (1024 if fn == "ecca_bezier_eval" else 0)
            out[fn] = int(m.group(1)) / calls
    return out


def run_python(m: int) -> dict[str, float]:
    """Seconds -> ns per sample of the Python path, one sample at a time."""
    traj = PiecewiseBezier([Bezier(CTRL_PTS, H)], yaw=PiecewiseBezier([Bezier(YAW_PTS, H)]))
    ts = H * (np.arange(m) % 1024) / 1024.0
    yaw = traj.yaw
    assert yaw is not None

    def bezier() -> None:
        for t in ts:
            for k in range(5):
                traj.evaluate(t, k)
            for k in range(3):
                yaw.evaluate(t, k)

    states = [[traj.evaluate(t, k) for k in range(5)] + [float(yaw.evaluate(t, k)[0])
                                                          for k in range(3)] for t in ts]

    def flat() -> None:
        for s in states:
            multirotor_setpoint(s[1], s[2], s[3], s[4], s[5], s[6], s[7], PARAMS)

    def full() -> None:
        for t in ts:
            d = [traj.evaluate(t, k) for k in range(5)]
            y = [float(yaw.evaluate(t, k)[0]) for k in range(3)]
            multirotor_setpoint(d[1], d[2], d[3], d[4], y[0], y[1], y[2], PARAMS)

    lib = native.NativeSetpoint(native.build_library())

    def ct_flat() -> None:
        for s in states:
            lib.multirotor(s[1], s[2], s[3], s[4], float(s[5]), float(s[6]), float(s[7]), PARAMS)

    def ct_full() -> None:
        for t in ts:
            lib.full(CTRL_PTS, YAW_PTS, H, float(t), PARAMS)

    out = {}
    for name, fn in (("py_bezier", bezier), ("py_flat", flat), ("py_full", full),
                     ("ctypes_flat", ct_flat), ("ctypes_full", ct_full)):
        fn()
        out[name] = _best(fn, 3) / m * 1e9
    return out


def render(c: dict[str, float], py: dict[str, float], arm: list[crossbuild.ArmReport],
           env: str, cmd: str, calls: int, reps: int, cg: dict[str, float] | None = None) -> str:
    lines = [
        "## gen_c",
        "",
        f"Command: `{cmd}` ({env}).",
        "C: `bench/bench_gen_c.c` built with `cc " + " ".join(CFLAGS) + f"`, {calls:.0e} calls "
        f"per loop on a degree-7 segment swept over [0, h] (drag on), best of {reps} "
        "repetitions, thread CPU time. Python (process CPU time, best of 3): the companion's "
        "numeric path, one sample at a time "
        "(`PiecewiseBezier.evaluate` orders 0..4 + yaw 0..2, `multirotor_setpoint`), and the "
        "compiled library through `gen_c.native` (ctypes), measured in the same run.",
        "",
        "| operation | C double [ns] | C float [ns] | Python [ns] | Python / C double | "
        "ctypes [ns] |",
        "| --- | ---: | ---: | ---: | ---: | ---: |",
    ]
    rows = (("Bezier evaluation (pos..snap, yaw..yaw_acc)", "bezier_eval", "py_bezier", None),
            ("multirotor flatness", "multirotor_setpoint", "py_flat", "ctypes_flat"),
            ("full setpoint (evaluate + flatness)", "full_setpoint", "py_full", "ctypes_full"))
    for label, ck, pk, tk in rows:
        d, f, p = c[f"{ck}_double"], c[f"{ck}_float"], py[pk]
        ct = f"{py[tk]:.0f}" if tk else "-"
        lines.append(f"| {label} | {d:.1f} | {f:.1f} | {p:.0f} | {p / d:.0f}x | {ct} |")
    lines.append(f"| rover flatness | {c['rover_setpoint_double']:.1f} | - | - | - | - |")
    full_d = c["full_setpoint_double"]
    speed = py["py_full"] / full_d
    lines += [
        "",
        f"Goals: full multirotor setpoint <= {GOAL_FULL_NS:g} ns in double: "
        f"{'met' if full_d <= GOAL_FULL_NS else 'NOT met'} ({full_d:.0f} ns); >= "
        f"{GOAL_SPEEDUP:g}x the single-sample Python path: "
        f"{'met' if speed >= GOAL_SPEEDUP else 'NOT met'} ({speed:.0f}x). The machine is "
        "shared with other jobs (load average above): repeated runs vary by about +-30 %.",
        "",
    ]
    if cg:
        lines += [
            f"Instructions per call (callgrind, inclusive of libm; {CALLGRIND_CALLS} calls of "
            "the same loops; independent of the load), now and before the 2026-11-22 speed-up "
            "(commit e7a0c52, measured the same way):",
            "",
            "| function | instructions / call | before |",
            "| --- | ---: | ---: |",
        ]
        for fn, n in cg.items():
            before = CALLGRIND_BEFORE.get(fn)
            lines.append(f"| `{fn}` | {n:.0f} | {before if before else '-'} |")
        lines += ["", f"Wall clock, {BEFORE_AFTER_NS}. Changes: one fused CasADi kernel for "
                  "evaluate + flatness; validation by sums of outputs (a finite sum proves "
                  "every term finite) with the element-by-element checks as fallback that "
                  "decides every error code; no CasADi NULL guards; inline fmax/fmin.", ""]
    lines += [
        "Cortex-M7 cross-build (`arm-none-eabi-gcc -mcpu=cortex-m7 -mfpu=fpv5-d16 "
        "-mfloat-abi=hard -mthumb -O2 -fstack-usage`, one variant per build, linked against "
        "newlib's libm; `gen_c.crossbuild`, checked by `tests/gen_c/test_gen_c_arm.py`). Code "
        "size is `arm-none-eabi-size` text of the library objects before `--gc-sections` "
        "(includes CasADi's unused metadata functions); worst stack = own frame + deepest callee "
        "chain in the library (from `-fstack-usage`/`-fcallgraph-info`, libm excluded). No "
        ".data/.bss.",
        "",
        "| variant | text [B] | worst stack, full setpoint [B] | bezier | multirotor | rover |",
        "| --- | ---: | ---: | ---: | ---: | ---: |",
    ]
    for r in arm:
        s = "" if r.variant == "double" else "_f"
        ws = r.worst_stack
        lines.append(
            f"| {r.variant} | {r.text} | {ws['ecca_full_setpoint' + s]} | "
            f"{ws['ecca_bezier_eval' + s]} | {ws['ecca_multirotor_setpoint' + s]} | "
            f"{ws['ecca_rover_setpoint' + s]} |")
    if arm:
        lines += ["", f"Cross compiler: {arm[0].compiler}."]
    lines.append("")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--calls", type=int, default=1_000_000, help="C calls per loop (1e6)")
    ap.add_argument("--samples", type=int, default=2000, help="Python samples (2000)")
    ap.add_argument("--reps", type=int, default=15, help="C repetitions, best kept (15)")
    ap.add_argument("--no-write", action="store_true", help="do not update BENCHMARKS.md")
    ns = ap.parse_args(argv)
    c, cc_version = run_c(ns.calls, ns.reps)
    cg = run_callgrind()
    py = run_python(ns.samples)
    arm = []
    if crossbuild.have_arm_toolchain():
        with tempfile.TemporaryDirectory(prefix="bench_gen_c_arm_") as tmp:
            arm = [crossbuild.build_arm(v, Path(tmp) / v) for v in ("double", "float")]
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    env = (f"{platform.machine()}, {os.cpu_count()} cores, load average {load:.1f} during the "
           f"run, {cc_version}, Python {platform.python_version()}")
    cmd = "python bench/bench_gen_c.py" + ("" if ns.calls == 1_000_000 else
                                           f" --calls {ns.calls}") + (
        "" if ns.reps == 15 else f" --reps {ns.reps}")
    text = render(c, py, arm, env, cmd, ns.calls, ns.reps, cg)
    print(text)
    if not ns.no_write:
        write_section("gen_c", text)
        print(f"updated {ROOT / 'BENCHMARKS.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
