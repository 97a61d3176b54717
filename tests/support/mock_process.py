"""Subprocess helpers for the integration and real-PX4 tests: `python -m sitl_mock serve` or
`python -m companion` in a subprocess, MAVSDK 4 against the mock, free ports, bounded waits.

Every test gets its own mock on ephemeral loopback ports; the subprocess is terminated (then
killed) when its context manager exits, and MAVSDK is destroyed.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
import sys
from collections.abc import AsyncIterator, Awaitable
from dataclasses import dataclass
from typing import Any, TypeVar

import pytest

T = TypeVar("T")


def free_udp_port() -> int:
    """A currently free loopback UDP port (bind port 0, read it back, release it)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


async def bounded(aw: Awaitable[T], timeout_s: float, what: str) -> T:
    """Await with a time bound and a readable failure."""
    try:
        return await asyncio.wait_for(aw, timeout_s)
    except TimeoutError:
        pytest.fail(f"timed out after {timeout_s} s waiting for {what}")


@dataclass
class MockProcess:
    proc: asyncio.subprocess.Process
    client_port: int
    ready_line: str


@contextlib.asynccontextmanager
async def run_mock(*extra: str, speed: float = 1.0,
                   gcs_port: int | None = None) -> AsyncIterator[MockProcess]:
    """Start the mock sending to a free client port (and its GCS link to `gcs_port` if given);
    stop it (SIGTERM, then kill) on exit."""
    port = free_udp_port()
    gcs = (["--gcs-bind", "127.0.0.1:0", "--gcs-remote", f"127.0.0.1:{gcs_port}"]
           if gcs_port is not None else ["--no-gcs"])
    proc = await asyncio.create_subprocess_exec(
        sys.executable,
        "-m",
        "sitl_mock",
        "serve",
        "--bind",
        "127.0.0.1:0",
        "--remote",
        f"127.0.0.1:{port}",
        *gcs,
        "--speed",
        str(speed),
        *extra,
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE,
    )
    try:
        line = (await bounded(proc.stdout.readline(), 20.0, "mock startup")).decode()  # type: ignore[union-attr]
        assert line.startswith("sitl_mock ready"), line
        yield MockProcess(proc, port, line)
    finally:
        await stop_process(proc)


async def run_companion(*args: str, timeout_s: float, what: str) -> tuple[int, str]:
    """Run `python -m companion ARGS` to completion (killed after `timeout_s`); returns its
    exit code and its combined output."""
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "companion", *args,
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.STDOUT,
    )
    try:
        output, _ = await bounded(proc.communicate(), timeout_s, what)
    finally:
        if proc.returncode is None:
            proc.kill()
            with contextlib.suppress(Exception):
                await proc.wait()
    assert proc.returncode is not None
    return proc.returncode, output.decode(errors="replace")


async def stop_process(proc: asyncio.subprocess.Process) -> None:
    """SIGTERM, then SIGKILL after 5 s; waits until the process is gone."""
    if proc.returncode is None:
        proc.terminate()
        try:
            await asyncio.wait_for(proc.wait(), 5.0)
        except TimeoutError:
            proc.kill()
            await proc.wait()


@dataclass
class Drone:
    """A MAVSDK connection to the mock, with the plugins the tests use."""

    mavsdk: Any
    system: Any
    action: Any
    telemetry: Any
    offboard: Any
    mission_raw: Any
    direct: Any
    mock: MockProcess


@contextlib.asynccontextmanager
async def connect_drone(*extra: str, speed: float = 1.0) -> AsyncIterator[Drone]:
    from mavsdk import log_subscribe
    from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
    from mavsdk.asyncio.plugins.action import ActionAsync
    from mavsdk.asyncio.plugins.mavlink_direct import MavlinkDirectAsync
    from mavsdk.asyncio.plugins.mission_raw import MissionRawAsync
    from mavsdk.asyncio.plugins.offboard import OffboardAsync
    from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

    log_subscribe(lambda *_a: True)  # silence MAVSDK's console logging
    async with run_mock(*extra, speed=speed) as mock:
        m = Mavsdk(Configuration.create_with_component_type(ComponentType.COMPANION_COMPUTER))
        plugins: list[Any] = []
        try:
            await m.add_any_connection(f"udpin://127.0.0.1:{mock.client_port}")
            system = await bounded(m.first_autopilot(timeout_s=10.0), 15.0, "discovery")
            assert system is not None, "MAVSDK discovered no autopilot"
            plugins = [
                ActionAsync(system),
                TelemetryAsync(system),
                OffboardAsync(system),
                MissionRawAsync(system),
                MavlinkDirectAsync(system),
            ]
            yield Drone(m, system, *plugins, mock=mock)
        finally:
            for p in plugins:
                with contextlib.suppress(Exception):
                    p.destroy()
            m.destroy()
