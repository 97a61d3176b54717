"""Vehicle façade against the mock PX4 (`python -m sitl_mock serve` subprocess, loopback UDP,
ephemeral ports). Oracles: the mock's own telemetry and the .tlog read back by pymavlink."""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import math
import os
import re
import signal
import subprocess
import sys
from collections.abc import AsyncIterator, Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pymavlink import mavutil

from companion.aio import (
    ConnectTimeoutError,
    LinkLostError,
    OffboardExitedError,
    Vehicle,
    VehicleConfig,
    safe_exit,
)
from companion.mavlink import (
    AttitudeSetpoint,
    FlightMode,
    RatesSetpoint,
    TelemetrySnapshot,
    WireMissionItem,
)
from companion.trajectory import PiecewiseBezier, hermite

# flies in wall-clock time (the mock served over a link): README's second test phase
pytestmark = pytest.mark.realtime

MockFactory = Callable[..., int]


@pytest.fixture
def mock_px4() -> Iterator[MockFactory]:
    """Start `sitl_mock serve` on an ephemeral port; returns its offboard port."""
    procs: list[subprocess.Popen[str]] = []

    def start(*extra: str) -> int:
        p = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "sitl_mock",
                "serve",
                "--bind",
                "127.0.0.1:0",
                "--remote",
                "none",
                "--no-gcs",
                "--estimator-ready",
                "0.5",
                *extra,
            ],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        procs.append(p)
        assert p.stdout is not None
        line = p.stdout.readline()  # "sitl_mock ready quad offboard=127.0.0.1:PORT->none"
        m = re.search(r"offboard=127\.0\.0\.1:(\d+)", line)
        assert m, f"mock did not start: {line!r} {p.stderr.read() if p.poll() is not None else ''}"
        return int(m.group(1))

    try:
        yield start
    finally:
        for p in procs:
            p.terminate()
            try:
                p.wait(5)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(5)
            for f in (p.stdout, p.stderr):
                if f is not None:
                    f.close()


@contextlib.asynccontextmanager
async def connected(port: int, tlog: Path, **cfg: Any) -> AsyncIterator[Vehicle]:
    config = VehicleConfig(tlog_path=str(tlog), connect_timeout_s=10.0, **cfg)
    async with Vehicle.connect(f"udpout://127.0.0.1:{port}", config=config) as v:
        yield v


def read_tlog(path: Path) -> list[Any]:
    conn = mavutil.mavlink_connection(str(path))
    out = []
    for _ in range(1_000_000):
        msg = conn.recv_match()
        if msg is None:
            break
        out.append(msg)
    conn.close()
    return out


def ours(msgs: list[Any], kind: str) -> list[Any]:
    return [m for m in msgs if m.get_type() == kind and m.get_srcComponent() == 191]


def offboard_requests(msgs: list[Any]) -> list[Any]:
    return [m for m in ours(msgs, "COMMAND_LONG") if m.command == 176 and m.param2 == 6]


def px4_modes(msgs: list[Any]) -> list[tuple[float, int]]:
    return [
        (m._timestamp, (m.custom_mode >> 16) & 0xFF)
        for m in msgs
        if m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 1
    ]


def line(p0: np.ndarray, delta: tuple[float, float, float], dur: float) -> PiecewiseBezier:
    z = np.zeros(3)
    p1 = p0 + np.asarray(delta)
    return PiecewiseBezier([hermite(np.array([p0, z, z]), np.array([p1, z, z]), dur)])


def _thrust_pd(z_ref: float) -> Callable[[TelemetrySnapshot], float]:
    """Test-side PD altitude loop (hover thrust 0.5 as the mock's MPC_THR_HOVER)."""

    def thrust(tel: TelemetrySnapshot) -> float:
        assert tel.position is not None
        z, vz = tel.position.pos_ned[2], tel.position.vel_ned[2]
        return min(max(0.5 + 0.15 * (z - z_ref) + 0.1 * vz, 0.1), 0.9)

    return thrust


async def test_takeoff_fly_position_attitude_rates_land(
    mock_px4: MockFactory, tmp_path: Path
) -> None:
    """One flight: position-mode trajectory, then attitude (type_mask 3) and rates (type_mask
    128) setpoints from a test-side PD altitude loop, then land."""
    port = mock_px4()
    tlog = tmp_path / "flight.tlog"
    async with connected(port, tlog) as v:
        await v.arm()
        assert v.is_armed
        await v.takeoff(2.5)
        assert v.telemetry.position is not None
        # the climb has finished: AUTO.TAKEOFF left for Hold, or no longer climbing
        assert v.mode is FlightMode.HOLD or abs(v.telemetry.position.vel_ned[2]) < 0.3
        p0 = np.array(v.telemetry.position.pos_ned)
        assert -2.5 - 0.3 < p0[2] < -2.5 + 0.3
        traj = line(p0, (3.0, 1.0, 0.0), 4.0)
        report = await v.fly(traj, mode="position")
        assert report.held_at_end and v.mode is FlightMode.HOLD
        end = np.array(traj.evaluate(traj.duration, 0))
        assert np.linalg.norm(np.array(v.telemetry.position.pos_ned) - end) < 0.3
        assert report.stream.sent > 350 and report.stream.producer_errors == 0
        z_ref = v.telemetry.position.pos_ned[2]
        thrust = _thrust_pd(z_ref)

        def attitude(t: float, tel: TelemetrySnapshot) -> AttitudeSetpoint:
            return AttitudeSetpoint(
                q_wxyz=(1.0, 0.0, 0.0, 0.0), thrust_norm=thrust(tel), yaw_rate=0.0
            )

        def rates(t: float, tel: TelemetrySnapshot) -> RatesSetpoint:
            return RatesSetpoint(omega_frd=(0.0, 0.0, 0.0), thrust_norm=thrust(tel))

        for mode, src in (("attitude", attitude), ("rates", rates)):
            rep = await v.fly(mode=mode, setpoint_source=src, duration_s=2.0)
            assert rep.held_at_end and rep.stream.producer_errors == 0
            assert abs(v.telemetry.position.pos_ned[2] - z_ref) < 0.5
        await v.land()
        assert not v.is_armed
        assert v.telemetry.extended is not None and v.telemetry.extended.landed_state == 1
    msgs = read_tlog(tlog)
    masks = [s.type_mask for s in ours(msgs, "SET_ATTITUDE_TARGET")]
    assert set(masks) == {3, 128} and 3 not in masks[masks.index(128) :]  # attitude, then rates
    sps = ours(msgs, "SET_POSITION_TARGET_LOCAL_NED")
    reqs = [r for r in offboard_requests(msgs) if r.confirmation == 0]
    assert len(reqs) == 3  # one per fly(), never repeated
    req = reqs[0]
    # priming: >= 0.5 s of setpoints at ~100 Hz before the OFFBOARD request
    before = [s._timestamp for s in sps if s._timestamp <= req._timestamp]
    assert before and req._timestamp - before[0] >= 0.5
    recent = [t for t in before if t >= req._timestamp - 0.5]
    assert len(recent) >= 45
    # the vehicle entered OFFBOARD only after the request
    offb = [t for t, main in px4_modes(msgs) if main == 6]
    assert offb and min(offb) >= req._timestamp
    # every setpoint: pos+vel+acc+yaw (yaw rate ignored without a yaw trajectory), finite
    assert {s.type_mask for s in sps} == {2048}
    assert all(math.isfinite(f) for s in sps for f in (s.x, s.y, s.z, s.vx, s.afx, s.yaw))
    # the stream stopped once Hold was confirmed: no setpoints after the first HOLD heartbeat
    hold_after = [t for t, main in px4_modes(msgs) if main == 4 and t > req._timestamp]
    assert hold_after and max(s._timestamp for s in sps) <= min(hold_after) + 0.05
    # attitude setpoints only between the 2nd OFFBOARD request and the end of that flight
    att_t = [s._timestamp for s in ours(msgs, "SET_ATTITUDE_TARGET")]
    assert min(att_t) > min(hold_after)


async def test_pilot_takeover_stops_stream(mock_px4: MockFactory, tmp_path: Path) -> None:
    port = mock_px4("--pilot-takeover", "5.0")
    tlog = tmp_path / "takeover.tlog"
    async with connected(port, tlog) as v:
        await v.arm()
        assert v.telemetry.position is not None
        p0 = np.array(v.telemetry.position.pos_ned)
        with pytest.raises(OffboardExitedError) as info:
            await v.fly(line(p0, (0.0, 0.0, -4.0), 12.0))
        assert info.value.mode == "POSCTL"
        await asyncio.sleep(0.5)  # let the vehicle report a while longer
        assert v.mode is FlightMode.POSCTL
    msgs = read_tlog(tlog)
    sps = ours(msgs, "SET_POSITION_TARGET_LOCAL_NED")
    t_posctl = min(t for t, main in px4_modes(msgs) if main == 3)
    # stream stopped right after the takeover was seen, and OFFBOARD was never re-requested
    assert max(s._timestamp for s in sps) <= t_posctl + 0.1
    reqs = offboard_requests(msgs)
    assert reqs and max(r._timestamp for r in reqs) < t_posctl


async def test_link_loss_stops_stream_and_reports(mock_px4: MockFactory, tmp_path: Path) -> None:
    port = mock_px4("--blackout", "4.0-8.0")
    tlog = tmp_path / "linkloss.tlog"
    async with connected(port, tlog, reconnect_timeout_s=15.0) as v:
        await v.arm()
        assert v.telemetry.position is not None
        p0 = np.array(v.telemetry.position.pos_ned)
        with pytest.raises(LinkLostError) as info:
            await v.fly(line(p0, (0.0, 0.0, -4.0), 20.0))
        assert info.value.regained
        assert v.mode is not FlightMode.OFFBOARD  # the vehicle failsafed; we did not fight back
    msgs = read_tlog(tlog)
    assert len({r._timestamp for r in offboard_requests(msgs) if r.confirmation == 0}) == 1
    # the stream stopped once the link was declared lost (3 s without any autopilot message)
    rx = [x._timestamp for x in msgs if x.get_srcComponent() == 1]
    gap_len, gap_start = max((b - a, a) for a, b in itertools.pairwise(rx))
    assert gap_len > 3.0
    sps = [s._timestamp for s in ours(msgs, "SET_POSITION_TARGET_LOCAL_NED")]
    assert sps and max(sps) <= gap_start + 3.0 + 0.2


async def test_sigint_switches_to_hold(mock_px4: MockFactory, tmp_path: Path) -> None:
    port = mock_px4()
    tlog = tmp_path / "sigint.tlog"
    async with connected(port, tlog) as v:
        await v.arm()
        assert v.telemetry.position is not None
        p0 = np.array(v.telemetry.position.pos_ned)

        async def interrupt_when_offboard() -> None:
            async for mode in v.flight_mode():
                if mode is FlightMode.OFFBOARD:
                    await asyncio.sleep(1.0)
                    os.kill(os.getpid(), signal.SIGINT)
                    return

        killer = asyncio.get_running_loop().create_task(interrupt_when_offboard())
        try:
            with pytest.raises(KeyboardInterrupt):
                async with safe_exit(v, action="hold"):
                    await v.fly(line(p0, (0.0, 0.0, -3.0), 10.0))
        finally:
            killer.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await killer
        assert v.mode is FlightMode.HOLD


async def test_mission_upload_download_clear(mock_px4: MockFactory, tmp_path: Path) -> None:
    port = mock_px4()
    items = [
        WireMissionItem(
            seq=i,
            frame=6,
            command=16,
            current=int(i == 0),
            autocontinue=1,
            param1=0.0,
            param2=2.0,
            param3=0.0,
            param4=math.nan,
            x=473977420 + 100 * i,
            y=85455940 + 50 * i,
            z=10.0 + i,
        )
        for i in range(4)
    ]
    async with connected(port, tmp_path / "mission.tlog") as v:
        await v.mission.upload(items)
        got = await v.mission.download()
        assert len(got) == 4
        for a, b in zip(got, items, strict=True):
            assert (a.seq, a.frame, a.command, a.x, a.y, a.z) == (
                b.seq,
                b.frame,
                b.command,
                b.x,
                b.y,
                b.z,
            )
        await v.mission.clear()
        assert await v.mission.download() == []


async def test_connect_timeout_names_the_url() -> None:
    import socket

    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    try:  # a silent peer: bound but never answers
        with pytest.raises(ConnectTimeoutError, match=str(port)):
            await Vehicle.connect(
                f"udpout://127.0.0.1:{port}", config=VehicleConfig(connect_timeout_s=0.5)
            )
    finally:
        s.close()
