"""MAVLink 2 signing over loopback UDP: the companion's Vehicle flies a keyed mock (signed both
ways, the setpoint thread on its own stream); a pymavlink client (pymavlink's own signing) finds
the keyed `sitl_mock serve` refusing its unsigned command; `status` with the right key reports
the vehicle, with the wrong key it names the cause."""

from __future__ import annotations

import asyncio
import contextlib
import socket
import sys
import time
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest
from pymavlink.dialects.v20 import common as m

from companion.aio import Vehicle, VehicleConfig
from companion.app.cli import main as cli_main
from companion.mavlink import LinkConfig, PositionSetpoint, SigningConfig, TelemetrySnapshot
from sitl_mock.autopilot import Autopilot
from sitl_mock.server import LinkConfig as MockLink
from sitl_mock.server import MockServer, ServerConfig
from tests.support.mock_process import bounded, free_udp_port, run_mock

# flies in wall-clock time (the mock served over a link): README's second test phase
pytestmark = pytest.mark.realtime

KEY = bytes(range(7, 39))
OTHER_KEY = bytes(range(32))


@contextlib.asynccontextmanager
async def keyed_mock(key: bytes) -> AsyncIterator[tuple[MockServer, str]]:
    """The mock in this process, keyed, sending to a free port; yields (server, companion URL)."""
    port = free_udp_port()
    server = MockServer(
        lambda remotes, now: Autopilot("quad", None, remotes=remotes, now=now,
                                       estimator_ready_s=0.5, signing_key=key,
                                       unix_boot_s=time.time()),
        ServerConfig(links=[MockLink("offboard", ("127.0.0.1", 0), ("127.0.0.1", port))]))
    await server.start()
    task = asyncio.get_running_loop().create_task(server.run())
    try:
        yield server, f"udpin://127.0.0.1:{port}"
    finally:
        server.stop()
        with contextlib.suppress(asyncio.CancelledError, TimeoutError):
            await asyncio.wait_for(task, 5.0)


async def test_signed_round_trip_companion_flies_a_keyed_mock(tmp_path: Path) -> None:
    async with keyed_mock(KEY) as (server, url):
        link = LinkConfig(signing=SigningConfig(KEY))
        cfg = VehicleConfig(tlog_path=str(tmp_path / "f.tlog"), realtime_priority=None)
        async with Vehicle.connect(url, config=cfg, link_config=link) as v:
            await bounded(v.arm(), 20.0, "arming")
            await bounded(v.takeoff(2.0), 40.0, "takeoff")
            snap = v.telemetry
            assert snap.position is not None
            n, e, d = snap.position.pos_ned

            def hold_1m_north(_t: float, _s: TelemetrySnapshot) -> PositionSetpoint:
                return PositionSetpoint(pos_ned=(n + 1.0, e, d))

            report = await bounded(v.fly(mode="position", setpoint_source=hold_1m_north,
                                         duration_s=3.0), 30.0, "the offboard flight")
            assert report.stream.sent > 100
            pos = v.telemetry.position
            assert pos is not None and abs(pos.pos_ned[0] - (n + 1.0)) < 0.5  # it flew there
            signer = v.link.codec.signer
            assert signer is not None and v.link.codec.rejected_frames == 0
            assert signer.stats["accepted"] > 500 and set(signer.stats) == {"accepted"}
        ap = server.autopilot
        mock_side = ap.links["offboard"].signing
        assert mock_side is not None and ap.stats["rx_signing_refused"] == 0
        # both companion streams reached the mock: event loop (link id 0), setpoints (1)
        assert {k for k in mock_side.streams if k[:2] == (1, 191)} == {(1, 191, 0), (1, 191, 1)}
    # the log holds the flight, unsigned (the signatures stay off disk)
    raw = (tmp_path / "f.tlog").read_bytes()
    parser = m.MAVLink(None)
    parser.robust_parsing = True
    frames, i = [], 0
    while i < len(raw):
        ln = 12 + raw[i + 9]  # 8-byte timestamp, then an unsigned MAVLink 2 frame
        frames.append(raw[i + 8:i + 8 + ln])
        i += 8 + ln
    assert i == len(raw) and len(frames) > 500
    assert all(f[0] == 0xFD and f[2] == 0 for f in frames)
    kinds = {x.get_type() for f in frames for x in parser.parse_buffer(f) or []}
    assert {"SET_POSITION_TARGET_LOCAL_NED", "COMMAND_ACK", "HEARTBEAT"} <= kinds
    assert "BAD_DATA" not in kinds


async def _wait_for_frame(sock: socket.socket, rx: Any, pred: Any, what: str,
                          timeout_s: float = 10.0) -> list[Any]:
    """Messages received (parsed by `rx`) up to and including the first one matching pred."""
    loop = asyncio.get_running_loop()
    seen: list[Any] = []

    async def read() -> list[Any]:
        while True:
            data = await loop.sock_recv(sock, 65536)
            for msg in rx.parse_buffer(data) or []:
                seen.append(msg)
                if pred(msg):
                    return seen

    return await bounded(read(), timeout_s, what)


async def test_keyed_mock_process_refuses_unsigned_command_from_pymavlink(
        tmp_path: Path) -> None:
    key_file = tmp_path / "key.hex"
    key_file.write_text(KEY.hex() + "\n")
    async with run_mock("--signing-key", str(key_file)) as mock:
        assert "signing=required" in mock.ready_line
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.bind(("127.0.0.1", mock.client_port))
            sock.setblocking(False)
            rx = m.MAVLink(None)
            rx.signing.secret_key = KEY  # pymavlink verifies what the mock signs
            rx.signing.timestamp = int((time.time() - 1_420_070_400) * 100_000)
            first = await _wait_for_frame(sock, rx, lambda x: x.get_type() == "HEARTBEAT",
                                          "the mock's first HEARTBEAT")
            assert all(x.get_signed() for x in first) and rx.signing.badsig_count == 0
            _, addr = await asyncio.get_running_loop().sock_recvfrom(sock, 65536)
            plain = m.MAVLink(None, srcSystem=255, srcComponent=190)
            signed = m.MAVLink(None, srcSystem=255, srcComponent=190)
            signed.signing.secret_key = KEY
            signed.signing.sign_outgoing = True
            signed.signing.timestamp = rx.signing.timestamp
            # unsigned first, then a signed command: UDP on loopback keeps the order, so an
            # ACK for the unsigned one would arrive before the signed one's
            cmd = m.MAVLink_command_long_message
            sock.sendto(cmd(1, 1, 31998, 0, 0, 0, 0, 0, 0, 0, 0).pack(plain), addr)
            sock.sendto(cmd(1, 1, 31999, 0, 0, 0, 0, 0, 0, 0, 0).pack(signed), addr)
            got = await _wait_for_frame(
                sock, rx, lambda x: x.get_type() == "COMMAND_ACK" and x.command == 31999,
                "the ACK of the signed command")
            acks = [x.command for x in got if x.get_type() == "COMMAND_ACK"]
            assert acks == [31999] and got[-1].get_signed()
        finally:
            sock.close()


async def _status(url: str, key_file: Path) -> tuple[int, str]:
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "companion", "status", "--connect", url,
        "--signing-key", str(key_file), "--timeout", "4",
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.STDOUT)
    try:
        out, _ = await bounded(proc.communicate(), 40.0, "companion status")
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
    assert proc.returncode is not None
    return proc.returncode, out.decode(errors="replace")


async def test_status_with_the_right_key_reports_and_with_a_wrong_key_names_it(
        tmp_path: Path) -> None:
    good, bad = tmp_path / "good.key", tmp_path / "bad.key"
    good.write_bytes(KEY)  # raw 32 bytes
    bad.write_text(OTHER_KEY.hex())
    async with run_mock("--signing-key", str(good)) as m1, \
            run_mock("--signing-key", str(good)) as m2:
        (ok_code, ok_out), (bad_code, bad_out) = await asyncio.gather(
            _status(f"udpin://127.0.0.1:{m1.client_port}", good),
            _status(f"udpin://127.0.0.1:{m2.client_port}", bad))
    assert ok_code == 0 and "ready to arm" in ok_out, ok_out
    assert bad_code == 3 and "signing keys differ" in bad_out.replace("\n", " "), bad_out


def test_fly_with_a_signing_key_flies_the_keyed_embedded_mock(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`fly --signing-key` keys both ends: the companion drops unsigned frames and the embedded
    mock refuses unsigned commands, so a flight that ends in exit code 0 was signed both ways."""
    key_file = tmp_path / "key.hex"
    key_file.write_text(KEY.hex())
    log = tmp_path / "c.tlog"
    code = cli_main(["fly", "circle", "--size", "2", "--speed", "1", "--alt", "2",
                     "--signing-key", str(key_file), "--log", str(log)])
    out = capsys.readouterr().out
    assert code == 0, out[-2000:]
    assert "MAVLink 2 signing on" in out
    assert log.stat().st_size > 10_000
