"""Test harness: a pymavlink client driving the sans-IO sitl_mock Autopilot on a fake clock.

Imported by the mock's tests (tests/sitl_mock/); test_sitl_autopilot_harness.py there checks the
harness itself.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from sitl_mock.autopilot import Autopilot

CLIENT_ADDR = ("127.0.0.1", 14540)
Msg = Any


class Harness:
    """Client (sysid 255, compid 190) + Autopilot on a fake clock; records every message."""

    def __init__(self, *, step_s: float = 0.01, boot_s: float = 0.0, **kw: Any) -> None:
        kw.setdefault("remotes", {"offboard": CLIENT_ADDR})
        self.ap = Autopilot(now=boot_s, **kw)
        self.t = boot_s
        self.boot = boot_s
        self.step_s = step_s
        self.mav = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
        self._log: list[list[Any]] = []  # [t, msgid, bytes, parsed or None]
        self.raw: list[bytes] = []

    # ------------------------------------------------------------------ I/O
    def send(self, msg: Msg, link: str = "offboard") -> None:
        self.send_bytes(msg.pack(self.mav), link)
        self.mav.seq = (self.mav.seq + 1) & 0xFF

    def send_bytes(self, data: bytes, link: str = "offboard") -> None:
        self.ap.receive_datagram(data, CLIENT_ADDR, self.t, link)
        self._collect()

    def _collect(self) -> None:
        t = self.t - self.boot
        for data, _addr in self.ap.datagrams_to_send(self.t):
            self.raw.append(data)
            # MAVLink 2 header: msgid is bytes 7..9 (little endian); parse lazily on query
            msgid = data[7] | (data[8] << 8) | (data[9] << 16) if len(data) >= 10 else -1
            self._log.append([t, msgid, data, None])

    @property
    def log(self) -> list[tuple[float, Msg]]:
        """Every received message as (time since boot, message), parsed."""
        return [(e[0], self._parsed(e)) for e in self._log]

    @staticmethod
    def _parsed(entry: list[Any]) -> Msg:
        if entry[3] is None:
            msgs = mavlink.MAVLink(None).parse_buffer(entry[2]) or []
            assert len(msgs) == 1, "one MAVLink message per datagram expected"
            entry[3] = msgs[0]
        return entry[3]

    def run(self, duration_s: float, every: Callable[[], None] | None = None) -> None:
        """Advance the fake clock by duration_s in steps, calling `every` before each step."""
        n = max(1, round(duration_s / self.step_s))
        for _ in range(n):
            if every is not None:
                every()
            self.t += self.step_s
            self.ap.advance(self.t)
            self._collect()

    def run_until(
        self, pred: Callable[[], bool], timeout_s: float, every: Callable[[], None] | None = None
    ) -> float:
        """Run until pred() holds; return the elapsed fake time; fail after timeout_s."""
        t0 = self.t
        while not pred():
            assert self.t - t0 < timeout_s, f"condition not met within {timeout_s} s"
            self.run(self.step_s, every)
        return self.t - t0

    # ------------------------------------------------------------------ queries
    def msgs(self, kind: str, since: float = -math.inf) -> list[Msg]:
        return [m for _t, m in self.timed(kind, since)]

    def timed(self, kind: str, since: float = -math.inf) -> list[tuple[float, Msg]]:
        mid = getattr(mavlink, "MAVLINK_MSG_ID_" + kind)
        return [(e[0], self._parsed(e)) for e in self._log if e[1] == mid and e[0] >= since]

    def last(self, kind: str) -> Msg | None:
        mid = getattr(mavlink, "MAVLINK_MSG_ID_" + kind)
        for e in reversed(self._log):
            if e[1] == mid:
                return self._parsed(e)
        return None

    @property
    def now_boot(self) -> float:
        return self.t - self.boot

    def acks(self, command: int, since: float = -math.inf) -> list[int]:
        return [m.result for m in self.msgs("COMMAND_ACK", since) if m.command == command]

    def texts(self, since: float = -math.inf) -> list[str]:
        """STATUSTEXTs since `since`, chunked ones (MAVLink 2 id/chunk_seq) reassembled."""
        out: list[str] = []
        pending: dict[int, list[str]] = {}
        for m in self.msgs("STATUSTEXT", since):
            if m.id == 0:
                out.append(m.text)
                continue
            parts = pending.setdefault(m.id, [])
            parts.append(m.text)
            if len(m.text.encode()) < 50:  # the NUL-terminated last chunk
                out.append("".join(pending.pop(m.id)))
        return out

    # ------------------------------------------------------------------ commands
    def command_long(
        self, command: int, *params: float, target: tuple[int, int] = (1, 1), confirmation: int = 0
    ) -> None:
        p = list(params) + [0.0] * (7 - len(params))
        self.send(
            mavlink.MAVLink_command_long_message(target[0], target[1], command, confirmation, *p)
        )

    def arm(self, force: bool = False) -> None:
        self.command_long(400, 1.0, 21196.0 if force else 0.0)

    def set_mode(self, main: int, sub: int = 0, base: float | None = None) -> None:
        if base is None:
            base = 1.0 + (128.0 if self.ap.armed else 0.0)
        self.command_long(176, base, float(main), float(sub))

    def takeoff(self, alt_amsl: float = math.nan) -> None:
        self.command_long(22, math.nan, 0.0, 0.0, math.nan, math.nan, math.nan, alt_amsl)

    def pos_setpoint(
        self, n: float, e: float, d: float, yaw: float = 0.0, mask: int = 2552, frame: int = 1
    ) -> None:
        self.send(
            mavlink.MAVLink_set_position_target_local_ned_message(
                0, 1, 1, frame, mask, n, e, d, 0, 0, 0, 0, 0, 0, yaw, 0
            )
        )

    def wait_ready(self) -> None:
        self.run_until(lambda: self.ap.prearm_ok(), 6.0)

    def heartbeat(self) -> Msg:
        hb = self.last("HEARTBEAT")
        assert hb is not None
        return hb

