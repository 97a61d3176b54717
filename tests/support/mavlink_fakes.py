"""Test helpers for the MAVLink core: an independent PX4-side encoder/decoder (pymavlink)."""

from __future__ import annotations

from typing import Any

from pymavlink.dialects.v20 import common as m


class Px4Side:
    """Encodes messages as PX4 (sysid 1, compid 1) would, and decodes what the companion sent."""

    def __init__(self, sysid: int = 1, compid: int = 1) -> None:
        self.mav = m.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        self.parser = m.MAVLink(None)
        self.parser.robust_parsing = True

    def frame(self, msg: Any) -> bytes:
        return bytes(msg.pack(self.mav))

    def msg(self, msg: Any) -> Any:
        """Pack and re-parse, so the message carries a real header (srcSystem etc.)."""
        (out,) = self.parser.parse_buffer(self.frame(msg))
        return out

    def decode(self, frames: list[bytes]) -> list[Any]:
        out: list[Any] = []
        for f in frames:
            out += self.parser.parse_buffer(f) or []
        return out


def heartbeat(base_mode: int, custom_mode: int, status: int = 4, autopilot: int = 12) -> Any:
    return m.MAVLink_heartbeat_message(2, autopilot, base_mode, custom_mode, status, 3)


def command_ack(command: int, result: int, target_system: int = 1, target_component: int = 191,
                progress: int = 0) -> Any:
    return m.MAVLink_command_ack_message(command, result, progress, 0, target_system,
                                         target_component)


class Outbox:
    """Collects messages a sans-IO component sends; decodes them via a real frame round trip."""

    def __init__(self) -> None:
        self.sent: list[Any] = []
        self._enc = m.MAVLink(None, srcSystem=1, srcComponent=191)
        self._dec = m.MAVLink(None)

    def __call__(self, msg: Any) -> None:
        (out,) = self._dec.parse_buffer(bytes(msg.pack(self._enc)))
        self.sent.append(out)

    def take(self) -> list[Any]:
        out, self.sent = self.sent, []
        return out

    def types(self) -> list[str]:
        return [x.get_type() for x in self.sent]
