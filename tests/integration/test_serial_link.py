"""The companion over a serial line: the mock's offboard link on a pseudo-terminal (like PX4's
TELEM2 to a companion computer), the companion opening the other end by its bare device path.

Judged by the mock's answers: HEARTBEAT and telemetry arrive, a mission round trip (long frames
in both directions) returns what was uploaded, and arming + takeoff are carried out.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import re
import signal
import sys
from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from companion.aio import Vehicle, VehicleConfig
from companion.mission import load_mission, mission_upload_items
from tests.support.mock_process import bounded, stop_process

# flies in wall-clock time (the mock served over a link): README's second test phase
pytestmark = pytest.mark.realtime

MISSION = Path(__file__).resolve().parents[1] / "data" / "missions" / "px4_short.plan"


@contextlib.asynccontextmanager
async def mock_on_pty() -> AsyncIterator[str]:
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "sitl_mock", "serve", "--serial", "pty", "--no-gcs",
        "--estimator-ready", "0.5", stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE)
    try:
        line = (await bounded(proc.stdout.readline(), 20.0, "mock startup")).decode()  # type: ignore[union-attr]
        m = re.search(r"offboard=serial:(\S+)", line)
        assert m, line
        yield m.group(1)
    finally:
        await stop_process(proc)


async def test_vehicle_over_a_pty_serial_link(tmp_path: Path) -> None:
    async with mock_on_pty() as device:
        assert device.startswith("/dev/")
        cfg = VehicleConfig(tlog_path=str(tmp_path / "serial.tlog"), connect_timeout_s=10.0)
        async with Vehicle.connect(device, config=cfg) as v:  # a bare path: serial, 921600
            assert v.transport is not None and type(v.transport).__name__ == "SerialTransport"
            items = list(mission_upload_items(load_mission(MISSION)))
            await bounded(v.mission.upload(items), 20.0, "mission upload over serial")
            back = await bounded(v.mission.download(), 20.0, "mission download over serial")
            assert [(i.command, i.x, i.y) for i in back] == [(i.command, i.x, i.y)
                                                             for i in items]
            await bounded(v.arm(), 20.0, "arming over serial")
            await bounded(v.takeoff(2.5), 40.0, "takeoff over serial")
            pos = v.telemetry.position
            assert v.is_armed and pos is not None and pos.pos_ned[2] < -2.0
            await bounded(v.land(), 60.0, "landing over serial")
            assert not v.is_armed


async def test_serve_connects_over_the_pty_by_bare_path_and_stops_on_sigterm(
        tmp_path: Path) -> None:
    async with mock_on_pty() as device:
        proc = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "companion", "serve", "--connect", device, "--log-dir",
            str(tmp_path), stdout=asyncio.subprocess.DEVNULL, stderr=asyncio.subprocess.PIPE)
        try:
            events = tmp_path / "events.jsonl"

            def seen(kind: str) -> bool:
                return events.exists() and any(
                    json.loads(line)["event"] == kind for line in events.read_text().splitlines())

            for _ in range(200):  # bounded poll of the service's own log (<= 20 s)
                if seen("mission_none"):
                    break
                await asyncio.sleep(0.1)
            # connected over the pty, and it read MISSION_CURRENT (no mission) from the mock
            assert seen("connected") and seen("mission_none")
            proc.send_signal(signal.SIGTERM)
            assert await bounded(proc.wait(), 10.0, "serve to stop") == 0
            assert seen("stop")
            assert list(tmp_path.glob("serve-*.tlog"))
        finally:
            if proc.returncode is None:
                proc.kill()
                await proc.wait()
