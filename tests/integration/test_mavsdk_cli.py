"""`python -m sitl_mock serve` over raw UDP: sends first, locks onto the first peer, stops."""

from __future__ import annotations

import asyncio
import re
import signal
import socket
import sys

import pytest
from pymavlink.dialects.v20 import common as mavlink

from tests.support.mock_process import bounded

# flies in wall-clock time (the mock served over a link): README's second test phase
pytestmark = pytest.mark.realtime


def _udp() -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    s.setblocking(False)
    return s


async def _recv_heartbeat(sock: socket.socket, timeout_s: float) -> tuple[object, object]:
    loop = asyncio.get_running_loop()

    async def go() -> tuple[object, object]:
        while True:
            data, addr = await loop.sock_recvfrom(sock, 4096)
            for m in mavlink.MAVLink(None).parse_buffer(data) or []:
                if m.get_type() == "HEARTBEAT":
                    return m, addr

    return await bounded(go(), timeout_s, "a HEARTBEAT")


async def _recv_param(sock: socket.socket) -> float:
    loop = asyncio.get_running_loop()
    while True:
        data, _addr = await loop.sock_recvfrom(sock, 4096)
        for m in mavlink.MAVLink(None).parse_buffer(data) or []:
            if m.get_type() == "PARAM_VALUE":
                return float(m.param_value)


def _drain(sock: socket.socket) -> int:
    n = 0
    while True:
        try:
            sock.recvfrom(4096)
            n += 1
        except BlockingIOError:
            return n


async def test_sends_first_to_remotes_then_locks_onto_first_peer_and_stops_on_sigterm() -> None:
    first, gcs, peer = _udp(), _udp(), _udp()
    try:
        gcs_port = gcs.getsockname()[1]
        proc = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "sitl_mock", "serve",
            "--bind", "127.0.0.1:0", "--remote", f"127.0.0.1:{first.getsockname()[1]}",
            "--gcs-bind", "127.0.0.1:0", "--gcs-remote", f"127.0.0.1:{gcs_port}",
            "--param", "MIS_TAKEOFF_ALT=4.5",
            stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
        )  # fmt: skip
        try:
            line = (await bounded(proc.stdout.readline(), 20.0, "ready line")).decode()  # type: ignore[union-attr]
            m = re.search(r"offboard=127\.0\.0\.1:(\d+)", line)
            assert m, line
            mock_port = int(m.group(1))
            hb, addr = await _recv_heartbeat(first, 10.0)
            assert addr[1] == mock_port  # type: ignore[index]
            assert (hb.get_srcSystem(), hb.autopilot) == (1, 12)  # type: ignore[attr-defined]
            await _recv_heartbeat(gcs, 10.0)
            # a different client talks first: the link locks onto it
            client = mavlink.MAVLink(None, 255, 190)
            peer.sendto(
                mavlink.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3).pack(client),
                ("127.0.0.1", mock_port),
            )
            await _recv_heartbeat(peer, 10.0)
            await asyncio.sleep(0.2)  # let datagrams already in flight to `first` arrive
            _drain(first)
            await _recv_heartbeat(peer, 5.0)
            assert _drain(first) == 0
            # --param reached the parameter store
            peer.sendto(
                mavlink.MAVLink_param_request_read_message(1, 1, b"MIS_TAKEOFF_ALT", -1).pack(
                    client
                ),
                ("127.0.0.1", mock_port),
            )
            value = await bounded(_recv_param(peer), 5.0, "PARAM_VALUE")
            assert value == 4.5
            proc.send_signal(signal.SIGTERM)
            rc = await bounded(proc.wait(), 10.0, "clean stop")
            assert rc == 0
            out = await proc.stdout.read()  # type: ignore[union-attr]
            assert b"sitl_mock stopped" in out
        finally:
            if proc.returncode is None:
                proc.kill()
                await proc.wait()
    finally:
        for s in (first, gcs, peer):
            s.close()


async def test_bad_arguments_exit_with_code_2() -> None:
    for args in (["--param", "NOPE=1"], ["--home", "1,2"], ["--speed", "0"], ["--loss", "200"]):
        proc = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "sitl_mock", "serve", "--bind", "127.0.0.1:0", *args,
            stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
        )  # fmt: skip
        try:
            rc = await bounded(proc.wait(), 20.0, f"exit on {args}")
            assert rc == 2, (args, rc)
        finally:
            if proc.returncode is None:
                proc.kill()
                await proc.wait()
