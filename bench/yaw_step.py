"""A 70 deg yaw step in attitude mode: how the autopilot's yaw settles (mock against real PX4).

The vehicle takes off and hovers; the companion then sends a level attitude at the current
yaw for 2 s and a level attitude 70 deg of yaw away for 5 s, both at the hover thrust
(bench_fidelity's HOVER_THRUST), in OFFBOARD attitude mode. The yaw error |yaw - target| [deg]
is read from the autopilot's ATTITUDE in the .tlog every 0.25 s from the step on (the sample
received nearest each instant). A large yaw step saturates the yaw torque, so the response
shows the mixer's desaturation and the rate loop's integrator at work:

    .venv/bin/python bench/yaw_step.py --target mock px4 --out bench_out/yaw_step

prints one line per flight and, for the mock, the mean absolute difference from the PX4
flight of the same run [deg].
"""

from __future__ import annotations

import argparse
import asyncio
import math
import shutil
import sys
import time
from pathlib import Path
from typing import Any

from pymavlink import mavutil

BENCH = Path(__file__).resolve().parent
if str(BENCH) not in sys.path:
    sys.path.insert(0, str(BENCH))

import api_harness as H  # noqa: E402, N812
from bench_fidelity import HOVER_THRUST, _q_euler  # noqa: E402

from companion.mavlink import TelemetrySnapshot  # noqa: E402
from companion.mavlink.setpoints import AttitudeSetpoint  # noqa: E402

STEP_RAD = math.radians(70.0)
HOLD_S = 2.0  # level at the start yaw before the step [s]
AFTER_S = 5.0  # after the step [s]
SAMPLE_S = 0.25


class YawStep:
    """Setpoint source: level at `yaw` [rad] for HOLD_S, then level at `yaw` + STEP_RAD;
    remembers the Unix time of the first stepped setpoint."""

    def __init__(self, yaw: float) -> None:
        self.yaw = yaw
        self.t_step: float | None = None
        self.duration_s = HOLD_S + AFTER_S

    def __call__(self, t_s: float, telemetry: TelemetrySnapshot) -> AttitudeSetpoint:
        if t_s < HOLD_S:
            return AttitudeSetpoint(_q_euler(0.0, 0.0, self.yaw), HOVER_THRUST)
        if self.t_step is None:
            self.t_step = time.time()
        return AttitudeSetpoint(_q_euler(0.0, 0.0, self.yaw + STEP_RAD), HOVER_THRUST)


async def _fly(ep: H.Endpoint, tlog: Path) -> YawStep:
    async with H.airborne(ep, tlog=tlog) as v:
        await H.fresh_position(v)
        att: Any = v.telemetry.attitude
        assert att is not None
        w, x, y, z = att.q_wxyz
        seq = YawStep(math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)))
        await v.fly(mode="attitude", setpoint_source=seq, duration_s=seq.duration_s)
    return seq


def yaw_errors(tlog: Path, sysid: int, t_step: float, target: float) -> list[float]:
    """|yaw - target| [deg] every SAMPLE_S from `t_step` [Unix s] to AFTER_S after it."""
    m = mavutil.mavlink_connection(str(tlog))
    rows: list[tuple[float, float]] = []
    while (msg := m.recv_match(type="ATTITUDE")) is not None:
        if msg.get_srcSystem() == sysid:
            rows.append((float(msg._timestamp), float(msg.yaw)))
    out = []
    for k in range(round(AFTER_S / SAMPLE_S) + 1):
        tt = t_step + SAMPLE_S * k
        _, yaw = min(rows, key=lambda r: abs(r[0] - tt))
        out.append(abs(math.degrees(math.remainder(yaw - target, 2 * math.pi))))
    return out


def run(target: str, out: Path) -> list[float]:
    """One yaw-step flight on a fresh autopilot of kind `target`: its yaw errors [deg]."""
    folder = out / target
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    with H.launch(target, folder) as ep:
        seq = asyncio.run(_fly(ep, folder / "flight.tlog"))
        sysid = ep.target_system
    assert seq.t_step is not None
    return yaw_errors(folder / "flight.tlog", sysid, seq.t_step, seq.yaw + STEP_RAD)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--target", nargs="+", choices=("mock", "px4"), default=["mock", "px4"])
    ap.add_argument("--out", type=Path, default=Path("bench_out/yaw_step"))
    args = ap.parse_args(argv)
    res = {t: run(t, args.out) for t in args.target}
    for t, errs in res.items():
        print(f"{t:5s} |yaw error| every {SAMPLE_S} s [deg]: " + " ".join(f"{e:.1f}" for e in errs))
    if "mock" in res and "px4" in res:
        d = [abs(a - b) for a, b in zip(res["mock"], res["px4"], strict=True)]
        print(f"mock vs px4: mean |difference| {sum(d) / len(d):.2f} deg")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
