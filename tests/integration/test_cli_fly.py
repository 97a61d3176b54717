"""`python -m companion fly figure8` end to end over loopback UDP, judged from its own .tlog:
OFFBOARD entered after priming, the right setpoint message and type_mask for the mode, the
figure-8 flown at the commanded altitude inside its footprint (distance to the analytic curve
x = a sin th, y = a/2 sin 2th the pattern is planned through), then landed and disarmed.

Attitude mode runs against the embedded mock (the default without --connect); position and
rates mode run as `python -m companion fly ... --connect udpin://...` subprocesses against
`sitl_mock serve` subprocesses, both flights at the same time to keep the test short.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from pymavlink import mavutil

from companion.app.cli import main as cli_main
from tests.support.mock_process import bounded, run_mock

# flies in wall-clock time (the mock served over a link): README's second test phase
pytestmark = pytest.mark.realtime

OFFBOARD_CUSTOM_MODE = 6 << 16
SIZE_M, SPEED_M_S = 6.0, 2.0
# SET_POSITION_TARGET_LOCAL_NED ignore bits: position 1|2|4, velocity 8|16|32,
# acceleration 64|128|256, FORCE 512 (PX4.md)
POS_VEL_ACC_BITS = 0x1FF | 512


@dataclass
class Flight:
    first_setpoint_t: float
    offboard_request_t: float
    offboard_t: float
    att_masks: set[int]
    pos_masks_offboard: list[tuple[float, int]]  # (t, SET_POSITION_TARGET mask) in OFFBOARD
    pos_count: int
    pos_offboard: np.ndarray  # (N, 3) LOCAL_POSITION_NED while in OFFBOARD
    start_ned: np.ndarray  # vehicle position when OFFBOARD was requested
    disarmed_after: bool
    setpoint_times: np.ndarray  # every setpoint the companion sent [s, unix]
    last_landed_state: int | None  # EXTENDED_SYS_STATE.landed_state at the end of the log


def read_flight(log: Path) -> Flight:
    m = mavutil.mavlink_connection(str(log))
    in_offboard = False
    first_setpoint_t = offboard_t = request_t = None
    att_masks: set[int] = set()
    pos_masks: list[tuple[float, int]] = []
    pos_count = 0
    pos_offboard = []
    last_pos = start = None
    armed_seen = disarmed_after = False
    sp_times: list[float] = []
    landed_state = None
    for _ in range(2_000_000):
        msg = m.recv_match()
        if msg is None:
            break
        kind = msg.get_type()
        if kind == "SET_ATTITUDE_TARGET" or kind == "SET_POSITION_TARGET_LOCAL_NED":
            if first_setpoint_t is None:
                first_setpoint_t = msg._timestamp
            sp_times.append(msg._timestamp)
            if kind == "SET_ATTITUDE_TARGET":
                att_masks.add(msg.type_mask)
            else:
                pos_count += 1
                if in_offboard:
                    pos_masks.append((msg._timestamp, msg.type_mask))
        elif kind == "COMMAND_LONG" and msg.command == 176 and msg.param2 == 6:
            if request_t is None:
                request_t, start = msg._timestamp, last_pos
        elif kind == "COMMAND_LONG" and msg.command in (176, 21) and in_offboard:
            # the companion hands over (LAND, Hold): the 1 Hz HEARTBEAT shows it up to 1 s
            # later, and those positions are PX4's flight, not the pattern
            in_offboard = False
        elif kind == "HEARTBEAT" and msg.get_srcComponent() == 1:
            in_offboard = msg.custom_mode == OFFBOARD_CUSTOM_MODE
            if in_offboard and offboard_t is None:
                offboard_t = msg._timestamp
            armed = bool(msg.base_mode & 128)
            armed_seen |= armed
            if armed_seen and not armed:
                disarmed_after = True
        elif kind == "EXTENDED_SYS_STATE":
            landed_state = msg.landed_state
        elif kind == "LOCAL_POSITION_NED":
            last_pos = (msg.x, msg.y, msg.z)
            if in_offboard:
                pos_offboard.append(last_pos)
    m.close()
    assert offboard_t is not None and first_setpoint_t is not None and request_t is not None
    assert start is not None
    return Flight(first_setpoint_t, request_t, offboard_t, att_masks, pos_masks, pos_count,
                  np.asarray(pos_offboard), np.asarray(start), disarmed_after,
                  np.asarray(sp_times), landed_state)


def figure8_distance(p_ned: np.ndarray, start_ned: np.ndarray) -> np.ndarray:
    """Horizontal distance [m] of each point to the analytic figure-8 through `start_ned`."""
    a = 0.5 * SIZE_M
    th = np.linspace(0.0, 2.0 * np.pi, 4001)
    curve = np.column_stack([a * np.sin(th), 0.5 * a * np.sin(2.0 * th)])
    rel = p_ned[:, :2] - start_ned[:2]
    d = np.linalg.norm(rel[:, None, :] - curve[None, :, :], axis=2)
    return np.min(d, axis=1)


def check_figure8(f: Flight, alt_m: float, max_curve_dist_m: float) -> str:
    """Mode-independent checks; returns the measured numbers."""
    assert f.offboard_request_t - f.first_setpoint_t >= 0.5  # primed before the request
    primed = f.setpoint_times[
        (f.setpoint_times >= f.offboard_request_t - 0.5) & (f.setpoint_times < f.offboard_request_t)
    ]
    assert len(primed) >= 45  # at the configured 100 Hz
    assert f.offboard_t >= f.offboard_request_t  # OFFBOARD only after the request
    p = f.pos_offboard
    assert len(p) > 100
    # the takeoff reached the commanded altitude (within the takeoff's own tolerance) ...
    assert abs(f.start_ned[2] + alt_m) <= max(0.3, 0.1 * alt_m) + 0.05, f.start_ned
    # ... and the pattern was flown at the altitude where it started
    dz = float(np.abs(p[:, 2] - f.start_ned[2]).max())
    assert dz < 0.3, f"altitude deviation {dz:.2f} m"
    # footprint: north span = size, east span = size / 2, close to the analytic figure-8
    ptp_n, ptp_e = np.ptp(p[:, 0]), np.ptp(p[:, 1])
    assert 0.85 * SIZE_M < ptp_n < 1.15 * SIZE_M, ptp_n
    assert 0.4 * SIZE_M < ptp_e < 0.6 * SIZE_M, ptp_e
    dist = figure8_distance(p, f.start_ned)
    numbers = (f"span N {ptp_n:.2f} m E {ptp_e:.2f} m, max |dz| {dz:.2f} m, distance to the "
               f"figure-8 max {dist.max():.2f} m RMS {np.sqrt(np.mean(dist**2)):.2f} m")
    assert dist.max() < max_curve_dist_m, numbers
    assert f.disarmed_after and f.last_landed_state == 1  # landed and disarmed at the end
    return numbers


def test_fly_figure8_attitude_mode_against_embedded_mock(tmp_path: Path) -> None:
    log = tmp_path / "f8.tlog"
    code = cli_main(["fly", "figure8", "--size", "6", "--speed", "2", "--alt", "4",
                     "--log", str(log)])
    assert code == 0
    f = read_flight(log)
    assert f.att_masks <= {3, 7} and f.att_masks  # attitude + thrust (+ yaw rate), never rates
    # position setpoints only while priming (the start point, no feed-forward)
    assert {m for _, m in f.pos_masks_offboard} <= {2552}
    assert np.all(np.abs(f.pos_offboard[:, 2] + 4.0) < 0.4)  # altitude held
    print("attitude:", check_figure8(f, 4.0, 0.35))
    # the summary written next to the tlog: every interpolation point of the pattern reached,
    # its tracking error no larger than the tlog's distance to the analytic curve allows
    report = json.loads((tmp_path / "f8.tlog.report.json").read_text())
    assert report["result"] == "ok"
    assert report["waypoints_reached"] == len(report["waypoints"]) == 17
    assert report["samples"] > 100
    assert 0.0 < report["rms_error_m"] <= report["max_error_m"] < 0.5
    assert abs(report["duration_s"] - report["planned_duration_s"]) < 3.0


async def _fly_cli(mode: str, log: Path, alt_m: float, *extra: str) -> None:
    """`python -m companion fly figure8 --connect ...` against its own `sitl_mock serve`."""
    async with run_mock("--estimator-ready", "0.5") as mock:
        comp = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "companion", "fly", "figure8", "--mode", mode,
            "--connect", f"udpin://127.0.0.1:{mock.client_port}", "--size", str(SIZE_M),
            "--speed", str(SPEED_M_S), "--alt", str(alt_m), "--log", str(log), *extra,
            stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.STDOUT,
        )
        try:
            out, _ = await bounded(comp.communicate(), 80.0, f"the {mode}-mode flight")
        finally:
            if comp.returncode is None:
                comp.kill()
                with contextlib.suppress(Exception):
                    await comp.wait()
        assert comp.returncode == 0, f"{mode}: " + out.decode(errors="replace")[-3000:]


async def test_fly_figure8_position_and_rates_mode_over_udp(tmp_path: Path) -> None:
    alt = 2.5
    logs = {mode: tmp_path / f"{mode}.tlog" for mode in ("position", "rates")}
    # the rates flight also exercises the busy-wait sender (C wait + send off the GIL)
    await asyncio.gather(_fly_cli("position", logs["position"], alt),
                         _fly_cli("rates", logs["rates"], alt, "--busy-wait"))

    pos = read_flight(logs["position"])
    # position mode: only SET_POSITION_TARGET_LOCAL_NED, never attitude targets; in flight
    # every mask carries position, velocity and acceleration (no FORCE bit), as PX4 expects
    assert not pos.att_masks and pos.pos_count > 1000
    # (from 0.1 s after the OFFBOARD heartbeat: the source starts flying the trajectory then)
    flying = {m for t, m in pos.pos_masks_offboard if t > pos.offboard_t + 0.1}
    assert flying and all(m & POS_VEL_ACC_BITS == 0 for m in flying), flying
    print("position:", check_figure8(pos, alt, 0.6))

    rates = read_flight(logs["rates"])
    assert rates.att_masks == {128}  # body rates + thrust, attitude ignored
    print("rates:", check_figure8(rates, alt, 0.35))
