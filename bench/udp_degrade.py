"""A UDP relay between a companion and an autopilot that delays and drops datagrams (both ways),
for benches of a degraded link on loopback.

The autopilot keeps sending to `autopilot_side_port` (its usual destination, which the relay
binds); the companion connects to `udpin://127.0.0.1:<companion_port>` instead. Each datagram
is dropped with probability `loss` and delivered `latency_s` later, in order (a fixed delay:
what a slow radio link adds), from a seeded generator.
"""

from __future__ import annotations

import heapq
import random
import socket
import threading
import time
from types import TracebackType


class DegradedLink:
    """Context manager: the relay's threads run between enter and exit."""

    def __init__(self, autopilot_side_port: int, *, latency_s: float = 0.02, loss: float = 0.05,
                 seed: int = 1) -> None:
        self.latency_s = latency_s
        self.loss = loss
        self._rng = random.Random(seed)
        self._ap = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._ap.bind(("127.0.0.1", autopilot_side_port))
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:  # a free port
            probe.bind(("127.0.0.1", 0))
            self.companion_port = int(probe.getsockname()[1])
        # the relay's companion-facing socket: the companion (listening on companion_port)
        # answers it
        self._co = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._co.bind(("127.0.0.1", 0))
        self._ap_addr: tuple[str, int] | None = None
        self._queue: list[tuple[float, int, socket.socket, bytes, str]] = []
        self._seq = 0
        self._lock = threading.Condition()
        self._stop = False
        self.dropped = 0
        self.passed = 0
        self._threads = [threading.Thread(target=self._rx, args=(self._ap, "to_companion"),
                                          daemon=True),
                         threading.Thread(target=self._rx, args=(self._co, "to_autopilot"),
                                          daemon=True),
                         threading.Thread(target=self._tx, daemon=True)]

    @property
    def url(self) -> str:
        """The companion's connect URL."""
        return f"udpin://127.0.0.1:{self.companion_port}"

    def _rx(self, sock: socket.socket, way: str) -> None:
        sock.settimeout(0.2)
        while not self._stop:
            try:
                data, addr = sock.recvfrom(65536)
            except TimeoutError:
                continue
            except OSError:
                return
            with self._lock:
                if way == "to_companion":
                    self._ap_addr = addr
                if self._rng.random() < self.loss:
                    self.dropped += 1
                    continue
                self.passed += 1
                self._seq += 1
                heapq.heappush(self._queue, (time.monotonic() + self.latency_s, self._seq,
                                             sock, data, way))
                self._lock.notify()

    def _tx(self) -> None:
        while True:
            with self._lock:
                while not self._stop and (not self._queue
                                          or self._queue[0][0] > time.monotonic()):
                    wait = (self._queue[0][0] - time.monotonic()) if self._queue else 0.2
                    self._lock.wait(max(wait, 0.0005))
                if self._stop:
                    return
                _, _, _, data, way = heapq.heappop(self._queue)
                ap_addr = self._ap_addr
            try:
                if way == "to_companion":
                    self._co.sendto(data, ("127.0.0.1", self.companion_port))
                elif ap_addr is not None:
                    self._ap.sendto(data, ap_addr)
            except OSError:
                pass

    def __enter__(self) -> DegradedLink:
        for t in self._threads:
            t.start()
        return self

    def __exit__(self, et: type[BaseException] | None, ev: BaseException | None,
                 tb: TracebackType | None) -> None:
        with self._lock:
            self._stop = True
            self._lock.notify_all()
        for t in self._threads:
            t.join(timeout=2.0)
        self._ap.close()
        self._co.close()
