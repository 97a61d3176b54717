"""The figure-8's tracking error split by harmonic, from bench_onboard's output folders.

For each folder (``bench_onboard.py --out DIR``), the onboard flights of one cell (speed,
scale; clean link): the horizontal error against the reference by PX4's estimate over lap 2
(the bench's own RMS window and offset: the error's mean over the lap is removed, as the
bench's figure is planned from where the vehicle hovers), resampled on the figure's phase.

- **common part:** the mean of the flights' error curves, phase by phase. Its RMS is the
  error every flight repeats (with 1/sqrt(n) of the rest); the rest is each flight's own.
- **per harmonic:** the figure is x = 5 sin(phi), y = 2.5 sin(2 phi) (scaled). The common
  error's component at x's first and y's second harmonic, divided by the reference's there,
  is (gain - 1) + j w lead: "gain" > 0 flies the lobes wider than the figure, "lead" > 0
  flies ahead of it [ms]. The odd harmonics x3, y4 are the shape's error (the tilt limit).
- **tilt limit:** the share of PX4's ATTITUDE_TARGET samples (10 Hz) in the air at the
  module's tilt limit (within 0.1 deg of the most tilted one).

    python bench/error_harmonics.py bench_out/s28-six [DIR ...] [--speed 6 --scale 1]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import api_harness as H  # noqa: N812
import bench_tracking as B  # noqa: N812
from bench_onboard import FIGURE8, scaled_figure8

N_PHASE = 400
PX4_SYSID = 2  # the SIH's system id in these tlogs (bench_onboard's target)


def _flight_dir(root: Path, r: dict[str, Any]) -> Path:
    return root / f"{r['mode']}-{r['speed']:g}-x{r['scale']:g}-s{r['start_at']:g}-{r['run']}"


def lap2_error(data: H.TlogData, t0_boot: float, speed: float, scale: float) -> np.ndarray:
    """(N_PHASE, 2) horizontal error [m] north, east over lap 2, on the figure's phase grid,
    its lap mean removed."""
    fig = scaled_figure8(scale)
    tb = data.lpos_boot - t0_boot
    keep = (tb >= 0.0) & (tb <= B.figure8_seconds(speed / scale))
    t, p = tb[keep], data.lpos[keep, :2]
    phase = np.array([FIGURE8(x, speed / scale)[1] for x in t])
    lap = (phase >= 2 * math.pi) & (phase < 4 * math.pi)
    ref = np.array([fig(x, speed).pos_ned[:2] for x in t[lap]])
    e = p[lap] - ref
    e -= e.mean(axis=0)
    grid = np.linspace(0.0, 2 * math.pi, N_PHASE, endpoint=False)
    return np.column_stack([np.interp(grid, phase[lap] - 2 * math.pi, e[:, k])
                            for k in range(2)])


def reference_on_grid(speed: float, scale: float) -> np.ndarray:
    """(N_PHASE, 2) the figure's north, east [m] on lap 2's phase grid."""
    fig = scaled_figure8(scale)
    ts = np.linspace(0.0, B.figure8_seconds(speed / scale), 20000)
    phase = np.array([FIGURE8(x, speed / scale)[1] for x in ts])
    grid = np.linspace(0.0, 2 * math.pi, N_PHASE, endpoint=False) + 2 * math.pi
    return np.array([fig(x, speed).pos_ned[:2] for x in np.interp(grid, phase, ts)])


def at_tilt_limit(data: H.TlogData) -> float:
    """Share of ATTITUDE_TARGET samples tilted more than 5 deg that are within 0.1 deg of the
    flight's largest tilt (the law's limit when it binds)."""
    tilts = []
    for m in data.extra["ATTITUDE_TARGET"]:
        _, x, y, _ = m.q
        tilts.append(math.degrees(math.acos(min(1.0, max(-1.0, 1 - 2 * (x * x + y * y))))))
    a = np.array([v for v in tilts if v > 5.0])
    return float(np.mean(a >= a.max() - 0.1)) if len(a) else math.nan


def analyse(root: Path, speed: float, scale: float) -> dict[str, Any]:
    rows = [r for r in json.loads((root / "onboard.json").read_text())
            if r["mode"] == "onboard" and not r.get("degraded") and r["speed"] == speed
            and r["scale"] == scale]
    curves, flights = [], []
    for r in rows:
        data = H.read_flight_tlog(_flight_dir(root, r) / "flight.tlog", PX4_SYSID,
                                  keep=("ATTITUDE_TARGET",))
        curves.append(lap2_error(data, r["start_boot_s"], speed, scale))
        flights.append({"start_at": r["start_at"], "rms": r["rms"],
                        "at_limit": at_tilt_limit(data), "age_ms": r.get("age_mean_us", math.nan)
                        / 1000.0})
    a = np.array(curves)
    common = a.mean(axis=0)
    ref = reference_on_grid(speed, scale)
    rf = np.fft.fft(ref - ref.mean(axis=0), axis=0)
    ef = np.fft.fft(common, axis=0)
    w = speed / scale / B.FIG8_DPDPHI_MAX
    out: dict[str, Any] = {"folder": str(root), "flights": flights,
                           "common_rms": float(np.sqrt(np.mean(np.sum(common**2, axis=1))))}
    for name, axis, h in (("x1", 0, 1), ("y2", 1, 2)):
        z = ef[h, axis] / rf[h, axis]
        out[name] = {"gain_pct": 100.0 * z.real, "lead_ms": 1000.0 * z.imag / (h * w)}
    for name, axis, h in (("x3", 0, 3), ("y4", 1, 4)):
        out[name] = {"amplitude_m": float(2.0 * abs(ef[h, axis]) / N_PHASE)}
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("folders", nargs="+", type=Path)
    ap.add_argument("--speed", type=float, default=6.0)
    ap.add_argument("--scale", type=float, default=1.0)
    args = ap.parse_args(argv)
    print("| folder | flights: RMS [m] (at tilt limit) | common RMS [m] | x1 gain / lead | "
          "y2 gain / lead | x3, y4 [m] |")
    print("| --- | --- | ---: | --- | --- | --- |")
    for root in args.folders:
        o = analyse(root, args.speed, args.scale)
        fl = ", ".join(f"{f['rms']:.3f} ({100 * f['at_limit']:.0f} %)" for f in o["flights"])
        print(f"| {root.name} | {fl} | {o['common_rms']:.3f} | "
              f"{o['x1']['gain_pct']:+.2f} % / {o['x1']['lead_ms']:+.1f} ms | "
              f"{o['y2']['gain_pct']:+.2f} % / {o['y2']['lead_ms']:+.1f} ms | "
              f"{o['x3']['amplitude_m']:.3f}, {o['y4']['amplitude_m']:.3f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
