"""asyncio UDP (and serial) server around the sans-IO Autopilot (the thin adapter, like
aioquic's protocol).

Simulated time = (monotonic wall time since start) x speed. One datagram endpoint per link;
like PX4 SITL each link sends to its configured remote until a peer talks to it, then locks
onto that peer.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import os
import termios
import time
import tty
from collections.abc import Callable
from dataclasses import dataclass, field

from sitl_mock.autopilot import Autopilot

log = logging.getLogger(__name__)

Addr = tuple[str, int]
MAX_BACKLOG_S = 0.25  # simulated seconds the pump may have to catch up in one go


@dataclass
class LinkConfig:
    """One UDP link: local bind address and the remote PX4 sends to first (None = wait).

    With ``serial`` set the link is a serial line instead (like PX4's TELEM2): a device path
    opened raw at ``baud``, or "pty" for a new pseudo-terminal pair whose other end
    (``MockServer.bound[name]`` = (path, 0)) a client opens as its serial port.
    """

    name: str
    bind: Addr
    remote: Addr | None
    serial: str | None = None
    baud: int = 921600


SERIAL_ADDR: Addr = ("serial", 0)  # the peer address the autopilot sees on a serial link


class _SerialLink:
    """A raw serial device or pty master: bytes are split into whole MAVLink frames before the
    autopilot sees them (it parses each chunk on its own, like a datagram)."""

    def __init__(self, server: MockServer, cfg: LinkConfig) -> None:
        self.server, self.name = server, cfg.name
        self._keep: int | None = None
        device = cfg.serial or ""
        if device == "pty":
            self.fd, self._keep = os.openpty()
            tty.setraw(self._keep)  # binary-safe; kept open so the master never reads EIO
            self.path = os.ttyname(self._keep)
        else:
            self.fd = os.open(device, os.O_RDWR | os.O_NOCTTY)
            tty.setraw(self.fd)
            speed = getattr(termios, f"B{cfg.baud}", None)
            if speed is None:
                raise ValueError(f"unsupported baud rate {cfg.baud}")
            attrs = termios.tcgetattr(self.fd)
            attrs[4] = attrs[5] = speed
            termios.tcsetattr(self.fd, termios.TCSANOW, attrs)
            self.path = device
        os.set_blocking(self.fd, False)
        self._buf = bytearray()

    def readable(self) -> None:
        try:
            data = os.read(self.fd, 4096)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            return  # EIO on a pty whose other side closed: wait for the next client
        self._buf += data
        for frame in self._frames():
            self.server.on_datagram(self.name, frame, SERIAL_ADDR)

    def _frames(self) -> list[bytes]:
        out: list[bytes] = []
        buf = self._buf
        while True:
            start = buf.find(b"\xfd")
            if start < 0:
                buf.clear()
                return out
            del buf[:start]
            if len(buf) < 10:
                return out
            n = 12 + buf[1] + (13 if buf[2] & 1 else 0)
            if len(buf) < n:
                return out
            out.append(bytes(buf[:n]))
            del buf[:n]

    def write(self, data: bytes) -> None:
        try:
            os.write(self.fd, data)
        except (BlockingIOError, InterruptedError):
            self.server.stats_errors += 1  # output buffer full (nobody reading): drop
        except OSError:
            self.server.stats_errors += 1

    def close(self) -> None:
        for fd in (self.fd, self._keep):
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.close(fd)


@dataclass
class ServerConfig:
    links: list[LinkConfig] = field(default_factory=list)
    speed: float = 1.0
    tick_s: float = 0.002  # wall-clock period of the physics/telemetry pump


class _LinkProtocol(asyncio.DatagramProtocol):
    def __init__(self, server: MockServer, name: str) -> None:
        self.server = server
        self.name = name
        self.transport: asyncio.DatagramTransport | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]

    def datagram_received(self, data: bytes, addr: Addr) -> None:
        self.server.on_datagram(self.name, data, addr)

    def error_received(self, exc: Exception) -> None:
        # ICMP port unreachable when nobody listens on the remote yet: keep going like PX4
        self.server.stats_errors += 1


def _identity(proto: _LinkProtocol) -> _LinkProtocol:
    return proto


class MockServer:
    """Runs an Autopilot against UDP sockets in real time (scaled by `speed`)."""

    def __init__(
        self,
        make_autopilot: Callable[[dict[str, Addr | None], float], Autopilot],
        config: ServerConfig,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if not config.speed > 0:
            raise ValueError(f"speed must be > 0, got {config.speed!r}")
        self.config = config
        self._clock = clock
        self._t0 = clock()
        remotes = {lk.name: SERIAL_ADDR if lk.serial is not None else lk.remote
                   for lk in config.links}
        self.autopilot = make_autopilot(remotes, 0.0)
        self._protocols: dict[str, _LinkProtocol] = {}
        self._serial: dict[str, _SerialLink] = {}
        self.bound: dict[str, Addr] = {}
        self.stats_errors = 0
        self.stats_internal_errors = 0
        self.stats_dropped_sim_s = 0.0
        self._stop = asyncio.Event()

    def sim_now(self) -> float:
        return (self._clock() - self._t0) * self.config.speed

    async def start(self) -> None:
        loop = asyncio.get_running_loop()
        for lk in self.config.links:
            if lk.serial is not None:
                ser = _SerialLink(self, lk)
                self._serial[lk.name] = ser
                loop.add_reader(ser.fd, ser.readable)
                self.bound[lk.name] = (ser.path, 0)
                continue
            proto = _LinkProtocol(self, lk.name)
            transport, _ = await loop.create_datagram_endpoint(
                functools.partial(_identity, proto), local_addr=lk.bind
            )
            self._protocols[lk.name] = proto
            sock = transport.get_extra_info("sockname")
            self.bound[lk.name] = (sock[0], sock[1])
        self._t0 = self._clock()

    def on_datagram(self, link: str, data: bytes, addr: Addr) -> None:
        try:
            self.autopilot.receive_datagram(data, addr, self.sim_now(), link)
        except Exception:  # a bug must not take the vehicle down: log (rate-limited), go on
            self._internal_error()
        self._flush()

    def _internal_error(self) -> None:
        self.stats_internal_errors += 1
        if self.stats_internal_errors <= 10:
            log.exception("sitl_mock internal error (%d)", self.stats_internal_errors)

    def _flush(self) -> None:
        now = self.sim_now()
        for name, proto in self._protocols.items():
            if proto.transport is None:
                continue
            for data, dest in self.autopilot.datagrams_to_send(now, name):
                try:
                    proto.transport.sendto(data, dest)
                except OSError:
                    self.stats_errors += 1
        for name, ser in self._serial.items():
            for data, _dest in self.autopilot.datagrams_to_send(now, name):
                ser.write(data)

    def stop(self) -> None:
        self._stop.set()

    async def run(self) -> None:
        """Pump physics and telemetry until `stop()`."""
        tick = self.config.tick_s
        try:
            while not self._stop.is_set():
                behind = self.sim_now() - self.autopilot.now
                if behind > MAX_BACKLOG_S:
                    # the CPU cannot keep up with --speed: let simulated time fall behind wall
                    # time instead of blocking the event loop with an ever-growing backlog
                    self._t0 += (behind - MAX_BACKLOG_S) / self.config.speed
                    self.stats_dropped_sim_s += behind - MAX_BACKLOG_S
                try:
                    self.autopilot.advance(self.sim_now())
                except Exception:
                    self._internal_error()
                self._flush()
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(self._stop.wait(), timeout=tick)
        finally:
            for proto in self._protocols.values():
                if proto.transport is not None:
                    proto.transport.close()
            loop = asyncio.get_running_loop()
            for ser in self._serial.values():
                loop.remove_reader(ser.fd)
                ser.close()
