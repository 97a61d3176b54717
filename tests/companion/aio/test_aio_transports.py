"""Transports over loopback with ephemeral ports; URL parsing; clear pyserial error."""

from __future__ import annotations

import asyncio
import os
import socket
import tty
from collections.abc import AsyncIterator

import pytest

from companion.aio import Endpoint, TransportError, open_transport, parse_url


@pytest.mark.parametrize(
    ("url", "ep"),
    [
        ("udpin://0.0.0.0:14540", Endpoint("udpin", "0.0.0.0", 14540)),
        ("udpin:0.0.0.0:14540", Endpoint("udpin", "0.0.0.0", 14540)),
        ("udp:127.0.0.1:14550", Endpoint("udpin", "127.0.0.1", 14550)),
        ("udpin://:14540", Endpoint("udpin", "0.0.0.0", 14540)),
        ("udpout://10.0.0.2:14580", Endpoint("udpout", "10.0.0.2", 14580)),
        ("udpout:10.0.0.2:14580", Endpoint("udpout", "10.0.0.2", 14580)),
        ("tcp://localhost:5760", Endpoint("tcp", "localhost", 5760)),
        ("tcp:localhost:5760", Endpoint("tcp", "localhost", 5760)),
        ("serial:///dev/ttyACM0:921600", Endpoint("serial", "", 921600, "/dev/ttyACM0")),
        ("serial:///dev/ttyACM0", Endpoint("serial", "", 921600, "/dev/ttyACM0")),
        ("/dev/ttyAMA0", Endpoint("serial", "", 921600, "/dev/ttyAMA0")),
        ("/dev/ttyUSB0:57600", Endpoint("serial", "", 57600, "/dev/ttyUSB0")),
        ("/dev/serial/by-id/usb-Pixhawk", Endpoint("serial", "", 921600,
                                                   "/dev/serial/by-id/usb-Pixhawk")),
    ],
)
def test_parse_url(url: str, ep: Endpoint) -> None:
    assert parse_url(url) == ep


@pytest.mark.parametrize("url", ["http://x:1", "udpin://host", "serial://", "/dev/ttyS0:fast",
                                 "14540"])
def test_parse_url_rejects(url: str) -> None:
    with pytest.raises(ValueError):
        parse_url(url)


async def _recv(tr: object, timeout: float = 5.0) -> bytes:
    return await asyncio.wait_for(tr.recv(), timeout)  # type: ignore[attr-defined]


async def test_udpin_udpout_round_trip() -> None:
    server = await open_transport("udpin://127.0.0.1:0")
    try:
        _host, port = server.local_address
        assert port != 0
        assert not server.send(b"nobody yet")  # udpin: no peer until someone talks
        client = await open_transport(f"udpout://127.0.0.1:{port}")
        try:
            assert client.send(b"hello")
            assert await _recv(server) == b"hello"
            assert server.send(b"world")  # replies to the last peer
            assert await _recv(client) == b"world"
        finally:
            client.close()
    finally:
        server.close()


@pytest.fixture
async def tcp_echo() -> AsyncIterator[tuple[int, list[asyncio.StreamWriter]]]:
    writers: list[asyncio.StreamWriter] = []

    async def handle(r: asyncio.StreamReader, w: asyncio.StreamWriter) -> None:
        writers.append(w)
        while data := await r.read(1024):
            w.write(data.upper())
            await w.drain()
        w.close()

    srv = await asyncio.start_server(handle, "127.0.0.1", 0)
    port = srv.sockets[0].getsockname()[1]
    try:
        yield port, writers
    finally:
        for w in writers:
            w.close()
        srv.close()
        await srv.wait_closed()


async def test_tcp_round_trip_and_peer_close(tcp_echo: tuple[int, list[asyncio.StreamWriter]]
                                             ) -> None:
    port, writers = tcp_echo
    tr = await open_transport(f"tcp://127.0.0.1:{port}")
    try:
        assert tr.send(b"abc")
        got = b""
        for _ in range(10):
            got += await _recv(tr)
            if len(got) >= 3:
                break
        assert got == b"ABC"
        writers[0].close()
        with pytest.raises(TransportError):
            for _ in range(10):
                await _recv(tr)
    finally:
        tr.close()


async def test_tcp_connect_refused_is_transport_error() -> None:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()  # nothing listens there now
    with pytest.raises(TransportError, match="cannot connect"):
        await open_transport(f"tcp://127.0.0.1:{port}", timeout_s=2.0)


async def test_serial_missing_device_is_a_transport_error_naming_it() -> None:
    with pytest.raises(TransportError, match="ttyNONE-ecca"):
        await open_transport("/dev/ttyNONE-ecca")


async def test_serial_transport_over_a_pty_pair_both_ways() -> None:
    """A bare device path opens the pty's slave end; bytes cross in both directions intact."""
    master, slave = os.openpty()
    tty.setraw(slave)  # no line discipline: binary MAVLink must pass unchanged
    tr = await open_transport(os.ttyname(slave))
    try:
        data = bytes(range(256)) * 4  # every byte value, incl. CR/LF/XON/XOFF
        os.write(master, data)
        got = b""
        while len(got) < len(data):
            got += await _recv(tr)
        assert got == data
        assert tr.send(data[::-1])
        back = b""
        loop = asyncio.get_running_loop()
        while len(back) < len(data):
            back += await asyncio.wait_for(loop.run_in_executor(None, os.read, master, 4096),
                                           5.0)
        assert back == data[::-1]
    finally:
        tr.close()
        os.close(master)
        os.close(slave)
