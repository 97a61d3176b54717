"""Tables and BENCHMARKS.md sections of bench_tracking.py's API targets (`--target mock px4`).

A row is (target, mode, peak speed, agg): agg holds the cell's figures (median `rms`, `max`,
`truth_rms`, the runs' `rms_lo`/`rms_hi`/`rms_i`) and, since `--param`, `params`: the autopilot
parameters the cell was flown with ({} or absent = the autopilot's defaults). Rows of different
parameters are different rows, labelled in a column, so runs with and without a changed
parameter sit side by side.
"""

from __future__ import annotations

import argparse
import math
import sys
from typing import Any

Row = tuple[str, str, float, dict[str, Any]]

API_SECTION = "Tracking on real PX4 SITL (public API, side by side with the mock)"
#: where --write puts a table with changed autopilot parameters (the defaults' section stays)
PARAM_SECTION = "Tracking with changed autopilot parameters (the companion not told)"


def params_label(params: dict[str, float] | None) -> str:
    """`SIH_MASS=0.8, MPC_THR_HOVER=0.55` (sorted by name), or `default`."""
    if not params:
        return "default"
    return ", ".join(f"{k}={v:g}" for k, v in sorted(params.items()))


def row_label(row: Row) -> str:
    return params_label(row[3].get("params"))


def write_api_section(table: str, args: argparse.Namespace, wall_s: float, reused: list[str],
                      with_params: bool) -> None:
    """Replace the API-target section of BENCHMARKS.md (with changed parameters: PARAM_SECTION)
    with this run's table."""
    from benchmarks_md import write_section

    title = PARAM_SECTION if with_params else API_SECTION
    argv = " ".join(sys.argv[1:])
    params_text = (
        "Autopilot parameters: each row's (`--param NAME=VALUE`), set before the autopilot "
        "starts: `sitl_mock serve --param`, PX4's `PX4_PARAM_<NAME>` at boot (PX4's rcS sets "
        "it before SIH and the controllers start), each read back over MAVLink "
        "(PARAM_REQUEST_READ) before the pattern. The companion is not told: its "
        "`TrackingConfig` keeps the defaults below. "
        if with_params else "")
    text = (
        f"## {title}\n\n"
        f"Command: `flock /tmp/ecca-px4-flights.lock .venv/bin/python bench/bench_tracking.py "
        f"{argv}` ({wall_s / 60:.0f} min wall; real PX4 runs in real time)"
        + "".join(f"; rows from {r}" for r in reused) + ".\n\n"
        "Each cell starts a fresh autopilot (real PX4 v1.16.0 SITL, SIH quadrotor, "
        + ("" if with_params else "default parameters, ")
        + "from `../shared/px4_sitl`; or `sitl_mock serve`) and flies it through the "
        "companion's public API: `Vehicle.connect`, arm, takeoff to 5 m, then `Vehicle.fly` with "
        "a `TrackingSource` (default `TrackingConfig`: nominal mass 1 kg, drag 1 N/(m/s), "
        "hover 0.5, estimated online) on the figure-8 of the Tracking section, shifted to start "
        "where the takeoff ended. " + params_text
        + "Error: horizontal distance to the reference over lap 2, from "
        "the autopilot's own estimate (LOCAL_POSITION_NED, the figure the issue states) and "
        "from the simulator's truth (HIL_STATE_QUATERNION; SIH's GPS noise through EKF2 puts "
        "the estimate ~0.15 m RMS off the truth, the mock has no estimator so both are equal). "
        "Hover rows: 30 s holding a point, the companion in attitude mode and PX4's own "
        "position controller (OFFBOARD position setpoint): the floor PX4 itself reaches."
        + (" Hover estimate: the companion's hover-thrust estimate at the end of the flight "
           "(median; the true hover throttle is SIH_MASS x 9.80665 / (4 x SIH_T_MAX), 0.49 "
           "at 1 kg)." if with_params else "")
        + f"\n\n{table}\n"
    )
    write_section(title, text)


def _fmt(agg: dict[str, Any] | None, key: str, lo: str = "", hi: str = "") -> str:
    if agg is None or key not in agg or not math.isfinite(agg[key]):
        return "-"
    if lo and agg[lo] != agg[hi]:
        return f"{agg[key]:.3f} ({agg[lo]:.3f}-{agg[hi]:.3f})"
    return f"{agg[key]:.3f}"


def api_table(rows: list[Row], targets: list[str], repeats: dict[str, set[int]],
              stagger_s: float) -> str:
    """Markdown: one row per (mode, speed, autopilot parameters), estimate and truth errors per
    target; the parameters' column (and the hover estimate) only when some row changed them."""
    label = {"position": "position + vel + acc", "attitude": "attitude (q + thrust)",
             "rates": "rates (body rates + thrust)", "hover": "hover, companion attitude mode",
             "px4_hold": "hover, PX4 position hold"}
    by = {(r[0], r[1], r[2], row_label(r)): r[3] for r in rows}
    keys = list(dict.fromkeys((r[1], r[2], row_label(r)) for r in rows))
    first = {mv: i for i, mv in reversed(list(enumerate(k[:2] for k in keys)))}
    keys.sort(key=lambda k: (first[k[:2]], k[2] != "default"))  # variants beside the default
    with_params = any(k[2] != "default" for k in keys)
    head = ["peak speed", "mode"] + (["autopilot parameters"] if with_params else [])
    for t in targets:
        name = "real PX4" if t == "px4" else "mock"
        head += [f"{name} RMS (estimate) [m]", f"{name} max [m]", f"{name} RMS (truth) [m]"]
        head += [f"{name} hover estimate"] if with_params else []
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for m, v, lab in keys:
        cells = ["-" if m in ("hover", "px4_hold") else f"{v:g} m/s", label.get(m, m)]
        cells += [lab] if with_params else []
        for t in targets:
            a = by.get((t, m, v, lab))
            cells += [_fmt(a, "rms", "rms_lo", "rms_hi"), _fmt(a, "max"), _fmt(a, "truth_rms")]
            cells += [_fmt(a, "hover_est")] if with_params else []
        lines.append("| " + " | ".join(cells) + " |")

    def runs(n: set[int]) -> str:
        k = max(n)
        spread = (f" (range in brackets; run i held i x {stagger_s:g} s after the takeoff)"
                  if k > 1 else "")
        if len(n) > 1:
            return f"median of {min(n)}-{k} runs per cell" + spread
        return f"median of {k} runs{spread}" if k > 1 else "one run per cell"

    note = "; ".join(f"{'real PX4' if t == 'px4' else 'mock'}: {runs(repeats[t])}"
                     for t in targets)
    return "\n".join(lines) + f"\n\n({note}; lap 2 of the figure-8, hover: 30 s)"
