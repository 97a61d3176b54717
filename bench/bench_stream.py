"""Setpoint stream benchmark: the deadline sender thread vs a naive asyncio-sleep loop.

Over loopback UDP with a fake PX4 peer that blasts telemetry at PX4 onboard rates
(ATTITUDE 100 Hz, ATTITUDE_QUATERNION 50 Hz, LOCAL_POSITION_NED 30 Hz, HEARTBEAT 1 Hz) into the
companion's asyncio receive loop, while the streamer sends position setpoints computed per cycle
from a figure-8 PiecewiseBezier. Reports achieved rate, period error |dt - T| p50/p99/max
(sender timestamps and receiver arrival timestamps), the companion process's CPU share of one
core (the fake PX4 runs in a child process), and the per-cycle compute time (telemetry in ->
setpoint out), with the codec's fast decode/encode paths and, as the same-run baseline,
pymavlink's byte-wise parser and ``msg.pack`` (the codec's previous implementation), calls
interleaved; plus the trajectory's scalar evaluator against ``PiecewiseBezier.evaluate``.

    python bench/bench_stream.py [--duration 8] [--rates 100 250] [--compute-only]
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import itertools
import json
import math
import os
import socket
import statistics
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import common as m

from companion.aio import FixedRateStreamer, TrajectoryPositionSource, open_transport
from companion.mavlink import Codec, VehicleLink
from companion.trajectory import PiecewiseBezier, hermite


def figure8(period_s: float = 12.0, n: int = 16) -> PiecewiseBezier:
    """Figure-8 x = 5 sin(phi), y = 2.5 sin(2 phi), z = -5 (NED) as n Hermite quintic segments."""
    w = 2 * math.pi / period_s
    segs = []
    for k in range(n):
        t0, t1 = k * period_s / n, (k + 1) * period_s / n

        def derivs(t: float) -> np.ndarray:
            p = w * t
            return np.array([
                [5 * math.sin(p), 2.5 * math.sin(2 * p), -5.0],
                [5 * w * math.cos(p), 5 * w * math.cos(2 * p), 0.0],
                [-5 * w * w * math.sin(p), -10 * w * w * math.sin(2 * p), 0.0],
            ])

        segs.append(hermite(derivs(t0), derivs(t1), t1 - t0))
    return PiecewiseBezier(segs)


def pct(xs: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(xs), q)) if xs else math.nan


class FakePx4:
    """Thread pair: sends telemetry frames to the companion, records setpoint arrival times."""

    def __init__(self, companion_port: int) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.2)
        self.dest = ("127.0.0.1", companion_port)
        self.mav = m.MAVLink(None, srcSystem=1, srcComponent=1)
        self.arrivals: list[float] = []
        self.stop = threading.Event()
        self.threads = [threading.Thread(target=self._rx, daemon=True),
                        threading.Thread(target=self._tx, daemon=True)]

    def start(self) -> None:
        for t in self.threads:
            t.start()

    def close(self) -> None:
        self.stop.set()
        for t in self.threads:
            t.join(2)
        self.sock.close()

    def _rx(self) -> None:
        while not self.stop.is_set():
            try:
                self.sock.recv(512)
            except (TimeoutError, OSError):
                continue
            self.arrivals.append(time.monotonic())

    def _tx(self) -> None:
        t0 = time.monotonic()
        k = 0
        while not self.stop.is_set():
            k += 1
            t = t0 + k / 300.0  # 300 Hz tick: ATTITUDE 100, ATT_Q 50, LPOS 30, HB 1
            dt = t - time.monotonic()
            if dt > 0:
                time.sleep(dt)
            ms = int((time.monotonic() - t0) * 1000)
            frames = []
            if k % 3 == 0:
                frames.append(m.MAVLink_attitude_message(ms, 0.01, 0.02, 0.3, 0, 0, 0))
            if k % 6 == 0:
                frames.append(m.MAVLink_attitude_quaternion_message(ms, 1, 0, 0, 0, 0, 0, 0))
            if k % 10 == 0:
                frames.append(m.MAVLink_local_position_ned_message(ms, 1, 2, -5, 0, 0, 0))
            if k % 300 == 0:
                frames.append(m.MAVLink_heartbeat_message(2, 12, 157, 393216, 4, 3))
            for f in frames:
                with contextlib.suppress(OSError):
                    self.sock.sendto(bytes(f.pack(self.mav)), self.dest)


def fake_px4_main(port: int) -> None:
    """Child process: telemetry to the companion; on stdin EOF print setpoint arrival times."""
    px4 = FakePx4(port)
    px4.start()
    sys.stdin.read()
    px4.close()
    print(json.dumps(px4.arrivals))


async def run_case(rate: float, duration: float, naive: bool,
                   **streamer_kw: Any) -> dict[str, float]:
    link = VehicleLink()
    tr = await open_transport("udpin://127.0.0.1:0")
    child = subprocess.Popen([sys.executable, __file__, "--fake-px4", str(tr.local_address[1])],
                             stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    src = TrajectoryPositionSource(figure8(), yaw=0.0)
    t_start = time.monotonic()

    def producer(now: float) -> bytes:
        snap = link.telemetry.snapshot()
        return link.encode_setpoint(src(now - t_start, snap), now)

    async def rx() -> None:
        while True:
            data = await tr.recv()
            link.receive_bytes(data, time.monotonic())

    rx_task = asyncio.get_running_loop().create_task(rx())
    for _ in range(300):  # the companion learns the peer from the first telemetry
        if getattr(tr, "peer", None) is not None:
            break
        await asyncio.sleep(0.1)
    await asyncio.sleep(0.3)
    cpu0, wall0 = time.process_time(), time.monotonic()
    send_times: list[float] = []
    lateness: list[float] = []
    missed = 0
    if naive:
        period = 1.0 / rate
        t_next = time.monotonic()
        while time.monotonic() - wall0 < duration:
            t_next += period
            await asyncio.sleep(max(t_next - time.monotonic(), 0.0))
            now = time.monotonic()
            tr.send(producer(now))
            send_times.append(now)
            lateness.append(now - t_next)
    else:
        st = FixedRateStreamer(rate, tr.send, producer, target=tr.datagram_target,
                               **streamer_kw)
        st.start()
        await asyncio.sleep(duration)
        st.stop()
        stats = st.stats()
        send_times = list(st.sent_times)
        lateness = list(stats.lateness_s)
        missed = stats.missed
    cpu = (time.process_time() - cpu0) / (time.monotonic() - wall0)
    await asyncio.sleep(0.05)
    rx_task.cancel()
    out, _ = child.communicate("", timeout=10)
    arrivals: list[float] = json.loads(out)
    tr.close()
    period = 1.0 / rate
    err = [abs(b - a - period) * 1e6 for a, b in itertools.pairwise(send_times)]
    arr = [t for t in arrivals if send_times and t >= send_times[0]]
    aerr = [abs(b - a - period) * 1e6 for a, b in itertools.pairwise(arr)]
    achieved = (len(send_times) - 1) / (send_times[-1] - send_times[0])
    return {"rate": rate, "achieved": achieved, "sent": len(send_times), "missed": missed,
            "p50": pct(err, 50), "p99": pct(err, 99), "max": max(err),
            "rx_p50": pct(aerr, 50), "rx_p99": pct(aerr, 99), "rx_max": max(aerr) if aerr else 0,
            "late_p99": pct([x * 1e6 for x in lateness], 99), "cpu": cpu * 100}


def time_it(fn: Callable[[], object], n: int) -> tuple[float, float]:
    xs = []
    for _ in range(n):
        t0 = time.perf_counter_ns()
        fn()
        xs.append((time.perf_counter_ns() - t0) / 1000)
    return statistics.median(xs), pct(xs, 99)


def time_interleaved(fns: dict[str, Callable[[], object]],
                     n: int) -> dict[str, tuple[float, float]]:
    """p50/p99 in us of each function, calls interleaved so that load changes hit all alike."""
    xs: dict[str, list[float]] = {k: [] for k in fns}
    for _ in range(n):
        for k, fn in fns.items():
            t0 = time.perf_counter_ns()
            fn()
            xs[k].append((time.perf_counter_ns() - t0) / 1000)
    return {k: (statistics.median(v), pct(v, 99)) for k, v in xs.items()}


class PymavlinkParserCodec(Codec):
    """Baseline: the codec's previous implementation, pymavlink's byte-wise parser
    (``parse_buffer``) and ``msg.pack``."""

    def encode(self, msg: Any) -> bytes:
        with self._lock:
            frame = bytes(msg.pack(self.mav))
            self.mav.seq = (self.mav.seq + 1) & 0xFF
            return frame

    def decode(self, data: bytes | bytearray) -> list[Any]:
        out = []
        for msg in self.mav.parse_buffer(data) or []:
            if msg.get_type() == "BAD_DATA" or msg.get_msgbuf()[0] != 0xFD:
                self.dropped_frames += 1
            else:
                out.append(msg)
        return out


def compute_bench(n: int = 5000) -> dict[str, tuple[float, float]]:
    link = VehicleLink()
    base = VehicleLink(codec=PymavlinkParserCodec())
    mav = m.MAVLink(None, srcSystem=1, srcComponent=1)
    lpos = bytes(m.MAVLink_local_position_ned_message(1, 1, 2, -5, 0, 0, 0).pack(mav))
    attq = bytes(m.MAVLink_attitude_quaternion_message(1, 1, 0, 0, 0, 0, 0, 0).pack(mav))
    src = TrajectoryPositionSource(figure8(), yaw=0.0)
    t = [0.0]

    def telemetry_in(lk: VehicleLink = link) -> None:
        lk.receive_bytes(lpos, 1.0)
        lk.receive_bytes(attq, 1.0)

    def setpoint_out(lk: VehicleLink = link) -> None:
        t[0] = (t[0] + 0.004) % 12.0
        lk.encode_setpoint(src(t[0], lk.telemetry.snapshot()), 1.0 + t[0])

    def both(lk: VehicleLink = link) -> None:
        telemetry_in(lk)
        setpoint_out(lk)

    return time_interleaved({
        "decode LOCAL_POSITION_NED + ATTITUDE_QUATERNION": lambda: (
            link.codec.decode(lpos), link.codec.decode(attq)),
        "decode, pymavlink parser (baseline)": lambda: (
            base.codec.decode(lpos), base.codec.decode(attq)),
        "telemetry in": telemetry_in,
        "telemetry in, pymavlink parser (baseline)": lambda: telemetry_in(base),
        "setpoint out": setpoint_out,
        "setpoint out, pymavlink pack (baseline)": lambda: setpoint_out(base),
        "total": both,
        "total, pymavlink parser + pack (baseline)": lambda: both(base),
    }, n)


def evaluator_bench(n: int = 3000) -> dict[str, tuple[float, float]]:
    """The trajectory's scalar evaluator vs ``PiecewiseBezier.evaluate`` (separate run, so that
    numpy's cost does not disturb the per-cycle table)."""
    traj = figure8()
    ev2, ev4 = traj.scalar_evaluator(2), traj.scalar_evaluator(4)
    ts = itertools.cycle(np.linspace(0.0, 12.0, 997).tolist())
    t = [0.0]

    def step() -> None:
        t[0] = next(ts)

    return time_interleaved({
        "(next time)": step,
        "orders 0-2 as floats: `ScalarEvaluator.values`": lambda: ev2.values(t[0]),
        "orders 0-4 as (5, 3) array: `ScalarEvaluator.__call__`": lambda: ev4(t[0]),
        "orders 0-2: `PiecewiseBezier.evaluate` x3 (baseline)": lambda: [
            traj.evaluate(t[0], k) for k in range(3)],
        "orders 0-4: `PiecewiseBezier.evaluate` x5 (baseline)": lambda: [
            traj.evaluate(t[0], k) for k in range(5)],
    }, n)


CASES: list[tuple[str, bool, dict[str, Any]]] = [
    ("asyncio.sleep loop (baseline)", True, {}),
    ("Python deadline thread: sleep + spin (previous design)", False, {"native": False}),
    ("deadline thread, C wait + send: sleep + spin", False, {"native": True}),
    ("deadline thread, C wait + send: sleep + spin, SCHED_FIFO", False,
     {"native": True, "realtime_priority": 10}),
    ("deadline thread, C wait + send: busy wait", False, {"native": True, "wait": "busy"}),
]


async def main_async(args: argparse.Namespace) -> None:
    print("| rate Hz | sender | achieved Hz | sent | missed | period err p50/p99/max us "
          "(send) | (arrival) | lateness p99 us | CPU % of one core |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for rate in [] if args.compute_only else args.rates:
        for name, naive, kw in CASES:
            if args.cases and not any(c in name for c in args.cases):
                continue
            r = await run_case(rate, args.duration, naive, **kw)
            print(f"| {rate:g} | {name} | {r['achieved']:.2f} | {r['sent']:.0f} | "
                  f"{r['missed']:.0f} | {r['p50']:.0f} / {r['p99']:.0f} / {r['max']:.0f} | "
                  f"{r['rx_p50']:.0f} / {r['rx_p99']:.0f} / {r['rx_max']:.0f} | "
                  f"{r['late_p99']:.0f} | {r['cpu']:.1f} |")
    c = compute_bench()
    print()
    print(f"| per-cycle compute (load average {os.getloadavg()[0]:.1f}) | p50 us | p99 us |")
    print("| --- | --- | --- |")
    for k, (p50, p99) in c.items():
        print(f"| {k} | {p50:.1f} | {p99:.1f} |")
    e = evaluator_bench()
    print()
    print("| figure-8 trajectory at one time | p50 us | p99 us |")
    print("| --- | --- | --- |")
    for k, (p50, p99) in e.items():
        if not k.startswith("("):
            print(f"| {k} | {p50:.1f} | {p99:.1f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--duration", type=float, default=8.0)
    ap.add_argument("--rates", type=float, nargs="+", default=[100.0, 250.0])
    ap.add_argument("--cases", nargs="*", default=[],
                    help="only the sender rows whose name contains one of these strings")
    ap.add_argument("--compute-only", action="store_true", help="only the per-cycle compute table")
    ap.add_argument("--fake-px4", type=int, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.fake_px4 is not None:
        fake_px4_main(args.fake_px4)
        return
    asyncio.run(main_async(args))


if __name__ == "__main__":
    main()
