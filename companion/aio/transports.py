"""Byte transports for the MAVLink link: UDP (in/out), TCP client, serial.

URLs: ``udpin://host:port`` (listen; reply to the last peer that sent to us: PX4 sends first),
``udpout://host:port`` (send to host:port from an ephemeral port), ``tcp://host:port``,
``serial:///dev/ttyACM0:921600`` or a bare device path ``/dev/ttyAMA0`` (921600 baud) /
``/dev/ttyAMA0:57600``; pymavlink's spellings ``udpin:host:port``,
``udpout:host:port``, ``udp:host:port`` (= udpin), ``tcp:host:port`` are accepted too.

``send`` is thread-safe (the fixed-rate sender thread and the asyncio side both call it) and
never blocks the caller for long. Received data is delivered on the event loop through
``await recv()``.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
import sys
import threading
from dataclasses import dataclass
from typing import Any

#: Baud rate of a serial link given without one (PX4's TELEM2 companion default, SER_TEL2_BAUD).
DEFAULT_BAUD = 921600


class TransportError(ConnectionError):
    """A transport could not be opened or has failed."""


@dataclass(frozen=True)
class Endpoint:
    """Parsed connection URL."""

    kind: str  # "udpin" | "udpout" | "tcp" | "serial"
    host: str
    port: int  # serial: baud rate
    device: str = ""


def parse_url(url: str) -> Endpoint:
    """Parse a connection URL (see module doc); raises ValueError with the accepted forms."""
    u = url.strip()
    forms = ("udpin://host:port, udpout://host:port, tcp://host:port, "
             "serial:///dev/ttyACM0:921600, /dev/ttyACM0, udpin:host:port")
    if u.startswith("serial://") or u.startswith("/dev/") or u.upper().startswith("COM"):
        rest = u.removeprefix("serial://")
        dev, colon, baud = rest.rpartition(":")
        if not colon:  # no baud rate given
            dev, baud = rest, str(DEFAULT_BAUD)
        if not dev or not baud.isdigit() or not 1 <= int(baud) <= 100_000_000:
            raise ValueError(f"bad serial URL {url!r}: expected serial:///dev/ttyACM0:921600, "
                             "/dev/ttyACM0 or /dev/ttyACM0:57600")
        return Endpoint("serial", "", int(baud), dev)
    scheme, sep, rest = u.partition("://")
    if not sep:
        scheme, sep, rest = u.partition(":")
    scheme = {"udp": "udpin"}.get(scheme, scheme)
    if scheme not in ("udpin", "udpout", "tcp") or not sep:
        raise ValueError(f"unsupported connection URL {url!r}; use one of: {forms}")
    host, _, port = rest.rpartition(":")
    if not port.isdigit():
        raise ValueError(f"connection URL {url!r} needs a numeric port")
    lowest = 0 if scheme == "udpin" else 1  # udpin port 0: any free port
    if not lowest <= int(port) <= 65535:
        raise ValueError(f"connection URL {url!r}: port {int(port)} out of range {lowest}..65535")
    host = host.strip("[]") or ("0.0.0.0" if scheme == "udpin" else "127.0.0.1")
    return Endpoint(scheme, host, int(port))


def sockaddr_bytes(family: int, address: tuple[object, ...]) -> bytes:
    """Packed Linux ``struct sockaddr_in`` / ``sockaddr_in6`` of a numeric (host, port[, flow,
    scope]) address, as ``sendto`` takes it."""
    fam = int(family).to_bytes(2, sys.byteorder)
    host, port = str(address[0]), int(str(address[1]))
    if family == socket.AF_INET:
        return fam + port.to_bytes(2, "big") + socket.inet_pton(socket.AF_INET, host) + bytes(8)
    if family == socket.AF_INET6:
        flow = int(str(address[2])) if len(address) > 2 else 0
        scope = int(str(address[3])) if len(address) > 3 else 0
        return (fam + port.to_bytes(2, "big") + flow.to_bytes(4, "big")
                + socket.inet_pton(socket.AF_INET6, host) + scope.to_bytes(4, sys.byteorder))
    raise ValueError(f"unsupported address family {family}")


class Transport:
    """Base class: thread-safe ``send``, asyncio ``recv``, ``close``."""

    #: True where each ``recv()`` chunk is one whole datagram (UDP): parse it on its own, a
    #: partial frame never carries over to the next one. False for byte streams (TCP, serial).
    datagrams: bool = False

    def __init__(self) -> None:
        self._queue: asyncio.Queue[bytes] = asyncio.Queue(maxsize=4096)
        self._send_lock = threading.Lock()
        self._closed = False
        self.send_errors = 0
        self.rx_dropped = 0
        self.failed: BaseException | None = None

    def _deliver(self, data: bytes) -> None:
        try:
            self._queue.put_nowait(data)
        except asyncio.QueueFull:
            self.rx_dropped += 1

    async def recv(self) -> bytes:
        """Next chunk of received bytes; raises TransportError once the transport has failed."""
        if self.failed is not None and self._queue.empty():
            raise TransportError(str(self.failed))
        data = await self._queue.get()
        if not data and self.failed is not None:
            raise TransportError(str(self.failed))
        return data

    def _fail(self, exc: BaseException) -> None:
        self.failed = exc
        self._deliver(b"")

    #: Exceptions of `_write` that count as a failed send (not a crash).
    _write_errors: tuple[type[BaseException], ...] = (OSError,)
    _loop: asyncio.AbstractEventLoop

    def _can_send(self) -> bool:
        return not self._closed

    def _write(self, data: bytes) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _fileno(self) -> int:  # pragma: no cover - abstract
        raise NotImplementedError

    def _release(self) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def send(self, data: bytes) -> bool:
        """Send bytes (thread-safe); returns False if they could not be sent (counted in
        send_errors)."""
        if not self._can_send():
            return False
        try:
            with self._send_lock:
                self._write(data)
            return True
        except self._write_errors:
            self.send_errors += 1
            return False

    def datagram_target(self) -> tuple[int, bytes] | None:
        """(socket fd, packed peer sockaddr) for sending one datagram without the GIL (see
        ``deadline.py``); None where a send is not a single atomic datagram (TCP, serial) or
        there is no peer yet: then use :meth:`send`."""
        return None

    @property
    def local_address(self) -> tuple[str, int]:  # pragma: no cover - abstract
        """Local (host, port) where applicable."""
        raise NotImplementedError

    def _stop_reading(self) -> None:
        with contextlib.suppress(Exception):
            self._loop.remove_reader(self._fileno())

    def close(self) -> None:
        """Release the transport (idempotent)."""
        if self._closed:
            return
        self._closed = True
        self._stop_reading()
        self._release()


class UdpTransport(Transport):
    """UDP, either listening (udpin: the peer is whoever sent last) or sending (udpout)."""

    datagrams = True

    def __init__(self, ep: Endpoint, loop: asyncio.AbstractEventLoop) -> None:
        super().__init__()
        self._loop = loop
        self.listen = ep.kind == "udpin"
        self._target: tuple[Any, tuple[int, bytes]] | None = None
        fam = socket.AF_INET6 if ":" in ep.host else socket.AF_INET
        self.sock = socket.socket(fam, socket.SOCK_DGRAM)
        try:
            self.sock.setblocking(False)
            if self.listen:
                self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                self.sock.bind((ep.host, ep.port))
                self.peer: Any = None
            else:
                self.sock.bind(("0.0.0.0" if fam == socket.AF_INET else "::", 0))
                self.peer = (ep.host, ep.port)
        except OSError as exc:
            self.sock.close()
            raise TransportError(f"cannot open UDP {ep.host}:{ep.port}: {exc}") from exc
        loop.add_reader(self.sock.fileno(), self._readable)

    @property
    def local_address(self) -> tuple[str, int]:
        host, port = self.sock.getsockname()[:2]
        return str(host), int(port)

    def _readable(self) -> None:
        for _ in range(256):
            try:
                data, addr = self.sock.recvfrom(65536)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                # ICMP port unreachable on a connected-style peer: keep listening
                return
            if self.listen:
                self.peer = addr
            self._deliver(data)

    def _can_send(self) -> bool:
        return self.peer is not None and not self._closed

    def _write(self, data: bytes) -> None:
        self.sock.sendto(data, self.peer)

    def datagram_target(self) -> tuple[int, bytes] | None:
        peer = self.peer
        if peer is None or self._closed:
            return None
        cached = self._target
        if cached is not None and cached[0] == peer:
            return cached[1]
        try:
            target = (self.sock.fileno(), sockaddr_bytes(self.sock.family, peer))
        except (OSError, ValueError):  # a host name (udpout://localhost:...): send() resolves it
            return None
        self._target = (peer, target)
        return target

    def _fileno(self) -> int:
        return self.sock.fileno()

    def _release(self) -> None:
        self.sock.close()


class TcpTransport(Transport):
    """TCP client (e.g. to a SITL or a telemetry radio bridge)."""

    def __init__(self, sock: socket.socket, loop: asyncio.AbstractEventLoop) -> None:
        super().__init__()
        self._loop = loop
        self.sock = sock
        sock.settimeout(0.5)  # bounds a blocked send; reads happen only when readable
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        loop.add_reader(sock.fileno(), self._readable)

    @classmethod
    async def open(cls, ep: Endpoint, loop: asyncio.AbstractEventLoop,
                   timeout_s: float = 5.0) -> TcpTransport:
        """Connect to ep.host:ep.port."""
        try:
            infos = await loop.getaddrinfo(ep.host, ep.port, type=socket.SOCK_STREAM)
            fam, typ, proto, _, addr = infos[0]
            sock = socket.socket(fam, typ, proto)
            sock.setblocking(False)
            try:
                await asyncio.wait_for(loop.sock_connect(sock, addr), timeout_s)
            except BaseException:
                sock.close()
                raise
        except (OSError, TimeoutError) as exc:
            raise TransportError(f"cannot connect TCP {ep.host}:{ep.port}: {exc!r}") from exc
        return cls(sock, loop)

    @property
    def local_address(self) -> tuple[str, int]:
        host, port = self.sock.getsockname()[:2]
        return str(host), int(port)

    def _readable(self) -> None:
        try:
            data = self.sock.recv(65536)
        except (BlockingIOError, InterruptedError, TimeoutError):
            return
        except OSError as exc:
            self._stop_reading()
            self._fail(exc)
            return
        if not data:
            self._stop_reading()
            self._fail(ConnectionResetError("TCP peer closed the connection"))
            return
        self._deliver(data)

    def _can_send(self) -> bool:
        return not self._closed and self.failed is None

    def _write(self, data: bytes) -> None:
        self.sock.sendall(data)

    def _fileno(self) -> int:
        return self.sock.fileno()

    def _release(self) -> None:
        self.sock.close()


class SerialTransport(Transport):
    """Serial port through pyserial (raw, non-blocking; a pty works too)."""

    def __init__(self, ep: Endpoint, loop: asyncio.AbstractEventLoop) -> None:
        super().__init__()
        try:
            import serial
        except ImportError as exc:
            raise TransportError(
                f"serial:// needs pyserial, which is not installed (pip install pyserial) "
                f"to open {ep.device}") from exc
        try:
            self.port = serial.Serial(ep.device, ep.port, timeout=0, write_timeout=0.5)
        except Exception as exc:  # serial.SerialException
            raise TransportError(f"cannot open serial port {ep.device}: {exc}") from exc
        self._loop = loop
        loop.add_reader(self.port.fileno(), self._readable)

    @property
    def local_address(self) -> tuple[str, int]:
        return str(self.port.port), int(self.port.baudrate)

    def _readable(self) -> None:
        try:
            data = self.port.read(4096)
        except Exception as exc:
            self._stop_reading()
            self._fail(exc)
            return
        if data:
            self._deliver(bytes(data))

    _write_errors = (Exception,)  # serial.SerialException and write timeouts

    def _write(self, data: bytes) -> None:
        self.port.write(data)

    def _fileno(self) -> int:
        return int(self.port.fileno())

    def _release(self) -> None:
        self.port.close()


async def open_transport(url: str, timeout_s: float = 5.0) -> Transport:
    """Open the transport described by ``url`` on the running event loop."""
    ep = parse_url(url)
    loop = asyncio.get_running_loop()
    if ep.kind in ("udpin", "udpout"):
        return UdpTransport(ep, loop)
    if ep.kind == "tcp":
        return await TcpTransport.open(ep, loop, timeout_s)
    return SerialTransport(ep, loop)
