"""The autopilot's attitude response to small sinusoids, mock against real PX4 in one run: the
part of the position loop that decides its stability margin (session 31: the streamed law at
kp_xy 20 rocked real PX4 at 1.2 Hz while the mock only did from kp_xy 27).

Each flight, on a fresh autopilot (`api_harness.launch`; the mock `sitl_mock serve`, with
`--mock-estimator`), takes off to 5 m and hovers in OFFBOARD; then per frequency in FREQS_HZ
and per axis (roll, then pitch) it holds its position for HOLD_S, then sends level attitude
setpoints with a sinusoid of AMP_DEG on that axis for CYCLES periods (thrust
MPC_THR_HOVER / cos of the tilt), at the companion's setpoint rate.

Measured from the tlog: the autopilot's ATTITUDE on the local clock (`api_harness.clock_map`
of time_boot_ms), against the commanded angle at the moment each setpoint was produced (just
before it was sent): a least-squares fit of a sinusoid of the known frequency (plus a line:
drift) to each over the whole periods after the first (its start transient). Gain = the
ratio of amplitudes; lag [ms] = the phase difference over 2 pi f: the link, the autopilot's
attitude and rate loops, the motors and the telemetry stream together, what the companion's
loop sees.

Run (PX4 flights must not overlap with other real-PX4 runs):
`.venv/bin/python bench/attitude_sweep.py [--target mock px4] [--repeat 2] [--out DIR]`
"""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import shutil
import sys
import time
from pathlib import Path

import numpy as np
from pymavlink import mavutil

BENCH = Path(__file__).resolve().parent
if str(BENCH) not in sys.path:
    sys.path.insert(0, str(BENCH))

import api_harness as H  # noqa: E402, N812
from bench_fidelity import HOVER_THRUST, _q_euler  # noqa: E402

from companion.mavlink import TelemetrySnapshot  # noqa: E402
from companion.mavlink.setpoints import (  # noqa: E402
    AttitudeSetpoint,
    PositionSetpoint,
    SetpointCommand,
)

FREQS_HZ = (0.8, 1.2, 1.6, 2.4)
AMP_DEG = 5.0
CYCLES = 6
HOLD_S = 2.5


def segments() -> list[tuple[str, float, float, float]]:
    """(axis, frequency [Hz], start [s], end [s]) of every sinusoid, in flight time."""
    out, t = [], 0.0
    for f in FREQS_HZ:
        for axis in ("roll", "pitch"):
            t += HOLD_S
            out.append((axis, f, t, t + CYCLES / f))
            t += CYCLES / f
    return out


class Sweep:
    """Setpoint source of `segments()` around the hold point `p0` [m NED] with yaw `yaw`;
    logs (Unix time, commanded roll, commanded pitch [rad]) of every attitude setpoint."""

    def __init__(self, p0: tuple[float, float, float], yaw: float) -> None:
        self.p0, self.yaw = p0, yaw
        self.segs = segments()
        self.duration_s = self.segs[-1][3] + HOLD_S
        self.log: list[tuple[float, float, float]] = []
        self.t0_unix: float | None = None

    def __call__(self, t_s: float, telemetry: TelemetrySnapshot) -> SetpointCommand:
        if t_s > 0.0 and self.t0_unix is None:
            self.t0_unix = time.time() - t_s
        for axis, f, a, b in self.segs:
            if a <= t_s < b:
                ang = math.radians(AMP_DEG) * math.sin(2.0 * math.pi * f * (t_s - a))
                roll, pitch = (ang, 0.0) if axis == "roll" else (0.0, ang)
                self.log.append((time.time(), roll, pitch))
                tilt = math.acos(math.cos(roll) * math.cos(pitch))
                return AttitudeSetpoint(_q_euler(roll, pitch, self.yaw),
                                        HOVER_THRUST / math.cos(tilt))
        return PositionSetpoint(self.p0, yaw=self.yaw)


def _fit(t: np.ndarray, y: np.ndarray, f: float) -> complex:
    """Complex amplitude (phasor of sin) of frequency `f` in y(t), fitted with a line."""
    w = 2.0 * math.pi * f
    A = np.column_stack([np.sin(w * t), np.cos(w * t), np.ones_like(t), t - t.mean()])
    c, *_ = np.linalg.lstsq(A, y, rcond=None)
    return complex(c[0], c[1])  # a sin + b cos = Im((a + i b) e^{iwt}) up to convention


def analyse(tlog: Path, sysid: int, cmd: list[tuple[float, float, float]],
            t0_unix: float) -> dict[str, dict[str, float]]:
    """Gain and lag [ms] per (axis, frequency) (see the module docstring)."""
    conn = mavutil.mavlink_connection(str(tlog))
    rows: list[tuple[float, float, float, float]] = []
    try:
        while (m := conn.recv_match(type="ATTITUDE")) is not None:
            if m.get_srcSystem() == sysid and m.get_srcComponent() == 1:
                rows.append((float(m._timestamp), m.time_boot_ms * 1e-3, m.roll, m.pitch))
    finally:
        conn.close()
    a = np.array(rows)
    t_att = H.clock_map(a[:, 1], a[:, 0])
    c = np.array(cmd)
    out: dict[str, dict[str, float]] = {}
    for axis, f, s, e in segments():
        lo, hi = t0_unix + s + 1.0 / f, t0_unix + e  # whole periods after the first
        k = 1 if axis == "roll" else 2
        mc = (c[:, 0] >= lo) & (c[:, 0] < hi)
        ma = (t_att >= lo) & (t_att < hi)
        if mc.sum() < 20 or ma.sum() < 20:
            continue
        pc = _fit(c[mc, 0] - lo, c[mc, k], f)
        pa = _fit(t_att[ma] - lo, a[ma, k + 1], f)
        ratio = pa / pc
        lag = -math.atan2(ratio.imag, ratio.real) / (2.0 * math.pi * f)
        out[f"{axis} {f:g} Hz"] = {"gain": abs(ratio), "lag_ms": 1e3 * lag}
    return out


async def _flight(ep: H.Endpoint, folder: Path) -> dict[str, dict[str, float]]:
    tlog = folder / "flight.tlog"
    async with H.airborne(ep, tlog=tlog) as v:
        await H.fresh_position(v)
        pos, att = v.telemetry.position, v.telemetry.attitude
        assert pos is not None and att is not None
        w, x, y, z = att.q_wxyz
        yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
        sweep = Sweep(tuple(float(p) for p in pos.pos_ned), yaw)  # type: ignore[arg-type]
        await v.fly(mode="attitude", setpoint_source=sweep, duration_s=sweep.duration_s)
    assert sweep.t0_unix is not None
    return analyse(tlog, ep.target_system, sweep.log, sweep.t0_unix)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--target", nargs="+", choices=("mock", "px4"), default=["mock", "px4"])
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--mock-estimator", default="ekf2")
    ap.add_argument("--out", type=Path, default=Path("bench_out/attitude_sweep"))
    args = ap.parse_args(argv)
    results: dict[str, list[dict[str, dict[str, float]]]] = {}
    for target in args.target:
        for i in range(args.repeat):
            folder = args.out / f"{target}-{i}"
            shutil.rmtree(folder, ignore_errors=True)
            mock_args = ("--estimator", args.mock_estimator, "--seed", str(i))
            with H.launch(target, folder, mock_args=mock_args) as ep:
                budget = segments()[-1][3] + HOLD_S + 90.0
                res = asyncio.run(asyncio.wait_for(_flight(ep, folder), budget))
            results.setdefault(target, []).append(res)
            print(target, i, json.dumps({k: {q: round(x, 3) for q, x in v.items()}
                                         for k, v in res.items()}), flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "sweep.json").write_text(json.dumps(results, indent=1))
    keys = [f"{ax} {f:g} Hz" for f in FREQS_HZ for ax in ("roll", "pitch")]
    print("| axis, frequency | " + " | ".join(f"{t}: gain / lag [ms]" for t in results) + " |")
    print("| --- |" + " --- |" * len(results))
    for k in keys:
        cells = []
        for t in results:
            g = [r[k]["gain"] for r in results[t] if k in r]
            lag = [r[k]["lag_ms"] for r in results[t] if k in r]
            cells.append(f"{np.median(g):.2f} / {np.median(lag):.0f}" if g else "-")
        print(f"| {k} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
