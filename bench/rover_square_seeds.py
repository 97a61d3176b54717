"""The spread of the mock rover's rover_square path figures over estimate-error seeds (issue 29).

With `serve --estimator ekf2` each seed is another realisation of the estimate error the rover
steers by, and the per-waypoint closest approaches of one flight are single samples of it. This
flies examples/missions/rover_square.plan in AUTO.MISSION on the mock in lockstep (simulated
time, in process: sitl_mock.lockstep) once per seed and reports, on the TRUE motion (the
vehicle's true_state every 0.02 s), the measures of bench_rover_fidelity.py (`mission_metrics`):
closest approach to each waypoint and the cross-track RMS while driving; per row the median and
the range over the seeds.
Usage: `python bench/rover_square_seeds.py [--seeds 10] [--estimator ekf2]`
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

BENCH = Path(__file__).resolve().parent
REPO = BENCH.parent
for p in (str(REPO), str(BENCH)):
    if p not in sys.path:
        sys.path.insert(0, p)

import bench_rover_fidelity as fid  # noqa: E402

from sitl_mock.__main__ import estimator_preset  # noqa: E402
from sitl_mock.lockstep import LockstepSim  # noqa: E402

STEP_S = 0.02
KEYS = ("closest_wp1_m", "closest_wp2_m", "closest_wp3_m", "closest_wp4_m", "xtrack_rms_m")


def fly_seed(seed: int, estimator: str, timeout_s: float = 120.0) -> dict[str, Any]:
    """rover_square on a fresh mock rover with `seed`; `mission_metrics` of its true motion."""
    items, _home, _wps = fid.plan_items(fid.PLAN)
    sim = LockstepSim("rover", estimator_preset(estimator, "rover"), seed=seed)
    mav = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    parse = mavlink.MAVLink(None)
    seen: list[Any] = []

    def pump(dt: float) -> None:
        sim.step(dt)
        for data in sim.recv():
            seen.extend(parse.parse_buffer(data) or [])

    def send(msg: Any) -> None:
        sim.send(msg.pack(mav))

    send(mavlink.MAVLink_mission_count_message(1, 1, len(items), 0))
    for _ in range(500):  # the upload: answer each request until the ACK
        pump(STEP_S)
        for m in seen:
            if m.get_type() in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
                it = items[m.seq]
                it.target_system = 1
                send(it)
        if any(m.get_type() == "MISSION_ACK" for m in seen):
            break
        seen.clear()
    seen.clear()
    pump(3.5)  # the estimator is ready after 3 s
    send(mavlink.MAVLink_command_long_message(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0))
    pump(STEP_S)
    send(mavlink.MAVLink_command_long_message(1, 1, 176, 0, 129, 4, 4, 0, 0, 0, 0))
    rec = fid.Record()
    rec.marks["arm"] = sim.now
    veh = sim.autopilot.vehicle
    end = sim.now + timeout_s
    done_at = None
    while sim.now < end:
        pump(STEP_S)
        s = veh.true_state
        rec.truth.append((sim.now, s.pos_ned[0], s.pos_ned[1], s.vel_ned[0], s.vel_ned[1],
                          s.yaw, 0.0))
        if done_at is None and any(m.get_type() == "STATUSTEXT" and "Mission finished" in m.text
                                   for m in seen):
            done_at = sim.now
        seen.clear()
        if done_at is not None and sim.now > done_at + 2.0:
            break
    rec.marks["end"] = sim.now
    return fid.mission_metrics(rec, fid.PLAN)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--estimator", choices=("ideal", "ekf2"), default="ekf2")
    args = ap.parse_args(argv)
    rows = []
    for seed in range(args.seeds):
        m = fly_seed(seed, args.estimator)
        rows.append([float(m[k]) for k in KEYS])
        print(f"  seed {seed}: " + ", ".join(f"{k} {v:.3f}" for k, v in zip(KEYS, rows[-1],
                                                                          strict=True)))
    a = np.array(rows)
    print(f"| row | median over {args.seeds} seeds | min-max |\n|---|---|---|")
    for j, k in enumerate(KEYS):
        print(f"| {k} | {np.median(a[:, j]):.3f} | {a[:, j].min():.3f}-{a[:, j].max():.3f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
