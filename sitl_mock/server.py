"""asyncio UDP server around the sans-IO Autopilot (the thin adapter, like aioquic's protocol).

Simulated time = (monotonic wall time since start) x speed. One datagram endpoint per link;
like PX4 SITL each link sends to its configured remote until a peer talks to it, then locks
onto that peer.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from sitl_mock.autopilot import Autopilot

log = logging.getLogger(__name__)

Addr = tuple[str, int]
MAX_BACKLOG_S = 0.25  # simulated seconds the pump may have to catch up in one go


@dataclass
class LinkConfig:
    """One UDP link: local bind address and the remote PX4 sends to first (None = wait)."""

    name: str
    bind: Addr
    remote: Addr | None


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
        remotes = {lk.name: lk.remote for lk in config.links}
        self.autopilot = make_autopilot(remotes, 0.0)
        self._protocols: dict[str, _LinkProtocol] = {}
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
