"""Lockstep real-time factor of the sitl_mock quadrotor (simulated seconds per CPU second).

Flies arm -> takeoff -> hold through the full MAVLink path (LockstepSim: the autopilot core
with every onboard telemetry stream encoded, drained by the caller every 20 ms of simulated
time) at 250 Hz and 1 kHz physics. Baseline in the same run: the bare vehicle model stepped at
the same rate with a fixed hover target (no autopilot, no MAVLink), so the ratio shows what the
autopilot and telemetry cost on top of the physics ("autopilot ms / sim s" is lockstep minus
vehicle-only CPU time per simulated second). A second table times the MAVLink codec per message
against pymavlink in the same run: decoding a SET_ATTITUDE_TARGET datagram (the companion's
100 Hz setpoint) with `mavwire.decode_datagram` vs `MAVLink.parse_buffer`, and encoding an
ATTITUDE frame from field values (`MessageCodec.frame`, the telemetry hot path) vs building the
pymavlink message and calling its `pack`. Times are process CPU time (`time.process_time`), so
other jobs on a shared machine do not distort the factor much.

    python bench/bench_sitl.py [--sim-seconds 30] [--repeat 3]
"""

from __future__ import annotations

import argparse
import math
import platform
import time

from pymavlink.dialects.v20 import common as mavlink

from sitl_mock.lockstep import LockstepSim
from sitl_mock.mavwire import codec, decode_datagram, pack_v2
from sitl_mock.params import ParamStore
from sitl_mock.setpoints import PositionTarget
from sitl_mock.vehicle import make_vehicle


def run_lockstep(physics_hz: float, sim_s: float) -> tuple[float, int]:
    """Wall seconds for `sim_s` simulated seconds, and the number of datagrams produced."""
    sim = LockstepSim("quad", physics_hz=physics_hz, seed=1)
    mav = mavlink.MAVLink(None, 255, 190)
    n_out = 0
    t0 = time.process_time()
    t = 0.0
    sent = False
    while t < sim_s:
        t += 0.02
        sim.step_until(t)
        n_out += len(sim.recv())
        if not sent and t >= 3.5:
            sent = True
            for m in (
                mavlink.MAVLink_command_long_message(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0),
                mavlink.MAVLink_command_long_message(
                    1, 1, 22, 0, math.nan, 0, 0, math.nan, math.nan, math.nan, math.nan
                ),
            ):
                sim.send(m.pack(mav))
                mav.seq += 1
    wall = time.process_time() - t0
    assert sim.autopilot.armed and -sim.autopilot.state.pos_ned[2] > 2.0, "did not fly"
    return wall, n_out


def run_vehicle_only(physics_hz: float, sim_s: float) -> float:
    v = make_vehicle("quad", ParamStore(), seed=1)
    dt = 1.0 / physics_hz
    target = PositionTarget(pos_ned=(0.0, 0.0, -2.5))
    n = round(sim_s * physics_hz)
    t0 = time.process_time()
    for _ in range(n):
        v.step(dt, target, True)
    return time.process_time() - t0


def _per_call_us(fn: object, n: int, repeat: int) -> float:
    best = math.inf
    for _ in range(repeat):
        t0 = time.process_time()
        for _ in range(n):
            fn()  # type: ignore[operator]
        best = min(best, time.process_time() - t0)
    return best / n * 1e6


def codec_rows(repeat: int) -> list[tuple[str, float, float]]:
    """(case, mock us, pymavlink us) per message."""
    mav = mavlink.MAVLink(None, 255, 190)
    sp = mavlink.MAVLink_set_attitude_target_message(
        1234, 1, 1, 7, [0.99, 0.01, 0.02, 0.1], 0.0, 0.0, 0.0, 0.55
    )
    frame = bytes(sp.pack(mav))

    def ref_decode() -> object:
        parser = mavlink.MAVLink(None)
        parser.robust_parsing = True
        return parser.parse_buffer(frame)

    assert decode_datagram(frame) is not None
    att = (123456, 0.01, -0.02, 1.5, 0.001, 0.002, -0.003)
    c = codec(mavlink.MAVLink_attitude_message)
    tx = mavlink.MAVLink(None, 1, 1)

    def ref_encode() -> bytes:
        return bytes(mavlink.MAVLink_attitude_message(*att).pack(tx))

    def obj_encode() -> bytes:
        return pack_v2(mavlink.MAVLink_attitude_message(*att), 0, 1, 1)

    assert c.frame(0, 1, 1, att) == pack_v2(mavlink.MAVLink_attitude_message(*att), 0, 1, 1)
    n = 3000
    return [
        (
            "decode SET_ATTITUDE_TARGET datagram",
            _per_call_us(lambda: decode_datagram(frame), n, repeat),
            _per_call_us(ref_decode, n, repeat),
        ),
        (
            "encode ATTITUDE from field values",
            _per_call_us(lambda: c.frame(0, 1, 1, att), n, repeat),
            _per_call_us(ref_encode, n, repeat),
        ),
        (
            "encode ATTITUDE from a message object (pack_v2)",
            _per_call_us(obj_encode, n, repeat),
            _per_call_us(ref_encode, n, repeat),
        ),
    ]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--sim-seconds", type=float, default=30.0)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    impl = f"{platform.python_implementation()} {platform.python_version()}"
    sim_s = args.sim_seconds
    print(f"# {impl}, {platform.machine()}, {sim_s:.0f} simulated s, best of {args.repeat}")
    print()
    print("| physics | lockstep RTF (MAVLink + telemetry) | datagrams/sim s "
          "| vehicle-only RTF (baseline) | lockstep / baseline CPU time "
          "| autopilot ms / sim s |")  # fmt: skip
    print("| --- | --- | --- | --- | --- | --- |")
    for hz in (250.0, 1000.0):
        walls, outs = zip(
            *(run_lockstep(hz, args.sim_seconds) for _ in range(args.repeat)), strict=True
        )
        base = min(run_vehicle_only(hz, args.sim_seconds) for _ in range(args.repeat))
        wall = min(walls)
        print(
            f"| {hz:.0f} Hz | {args.sim_seconds / wall:.1f}x | {outs[0] / args.sim_seconds:.0f} "
            f"| {args.sim_seconds / base:.1f}x | {wall / base:.2f} "
            f"| {(wall - base) / args.sim_seconds * 1e3:.1f} |"
        )
    print()
    print("| MAVLink codec, per message | sitl_mock.mavwire | pymavlink | speed-up |")
    print("| --- | ---: | ---: | ---: |")
    for case, mine, ref in codec_rows(args.repeat):
        print(f"| {case} | {mine:.1f} us | {ref:.1f} us | {ref / mine:.1f}x |")


if __name__ == "__main__":
    main()
