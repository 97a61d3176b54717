"""Parameter read client (MAVLink parameter protocol, PARAM_REQUEST_READ by name only).

Reads a handful of named parameters, never the whole list (PX4 has ~1000: PARAM_REQUEST_LIST
would take seconds). Every name gets a PARAM_REQUEST_READ (``param_index`` -1); the answer is a
PARAM_VALUE with that ``param_id`` from the target. A request without an answer within
``timeout_s`` (default 0.5 s) is sent again, ``retries`` times (default 2: 3 tries in all, as
MAVSDK's parameter client); at most ``max_in_flight`` requests are outstanding at once. The read
ends with one :class:`ParamReadDone`: the values that came back, the names that never did
(PX4 v1.16 does not answer a name it does not have), and the names answered with an unexpected
type.

Values on the wire (PX4, ``MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE``): a REAL32 parameter's
``param_value`` is the float itself; an integer parameter (PX4 sends INT32) carries the integer's
four bytes reinterpreted as a float32 (:func:`decode_param_value`, :func:`encode_param_value`).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from enum import IntEnum

from pymavlink.dialects.v20 import common as mavlink2

from .codec import MavMessage

__all__ = [
    "ParamBusyError",
    "ParamClient",
    "ParamReadDone",
    "ParamType",
    "decode_param_value",
    "encode_param_value",
]


class ParamType(IntEnum):
    """MAV_PARAM_TYPE."""

    UINT8 = 1
    INT8 = 2
    UINT16 = 3
    INT16 = 4
    UINT32 = 5
    INT32 = 6
    UINT64 = 7
    INT64 = 8
    REAL32 = 9
    REAL64 = 10


#: Integer types that fit the 4 bytes of ``param_value`` (bytewise encoding): struct format.
_BYTEWISE: dict[int, str] = {
    ParamType.UINT8: "<B", ParamType.INT8: "<b", ParamType.UINT16: "<H", ParamType.INT16: "<h",
    ParamType.UINT32: "<I", ParamType.INT32: "<i",
}
_REAL = (ParamType.REAL32, ParamType.REAL64)


def _type_name(param_type: int) -> str:
    try:
        return ParamType(param_type).name
    except ValueError:
        return f"type {param_type}"


def decode_param_value(param_value: float | bytes, param_type: int) -> float:
    """The parameter's value from PARAM_VALUE's ``param_value`` (the float, or better its 4 wire
    bytes: an integer whose bytes form a signalling NaN does not survive a float round trip) and
    ``param_type`` (bytewise encoding, as PX4 sends it). ValueError for a type that does not fit
    4 bytes."""
    raw = param_value if isinstance(param_value, bytes) else struct.pack("<f", param_value)
    if param_type in _REAL:
        return float(struct.unpack("<f", raw[:4])[0])
    fmt = _BYTEWISE.get(param_type)
    if fmt is None:
        raise ValueError(f"parameter type {_type_name(param_type)} cannot be decoded")
    return float(struct.unpack(fmt, raw[: struct.calcsize(fmt)])[0])


def _wire_value(msg: MavMessage) -> float | bytes:
    """PARAM_VALUE's ``param_value`` as its 4 wire bytes when the frame is at hand (MAVLink 2:
    the first payload field, zero-extended if the payload was truncated), else the float."""
    buf = getattr(msg, "_msgbuf", None)
    if isinstance(buf, bytes | bytearray) and len(buf) > 10 and buf[0] == 0xFD:
        n = min(4, buf[1])
        return bytes(buf[10:10 + n]).ljust(4, b"\x00")
    return float(msg.param_value)


def encode_param_value(value: float, param_type: int) -> float:
    """``param_value`` for PARAM_SET / PARAM_VALUE (inverse of :func:`decode_param_value`)."""
    if param_type in _REAL:
        return float(value)
    fmt = _BYTEWISE.get(param_type)
    if fmt is None or not float(value).is_integer():
        raise ValueError(f"{value!r} cannot be encoded as {_type_name(param_type)}")
    raw = struct.pack(fmt, int(value)).ljust(4, b"\x00")
    return float(struct.unpack("<f", raw)[0])


@dataclass(frozen=True)
class ParamReadDone:
    """End of a read: ``values`` {name: value} that came back, ``missing`` names never answered
    after every try, ``wrong_type`` {name: why} answered with another type than expected (their
    values are not in ``values``), ``attempts`` PARAM_REQUEST_READ frames sent in all."""

    t_s: float
    values: dict[str, float]
    missing: tuple[str, ...] = ()
    wrong_type: dict[str, str] = field(default_factory=dict)
    attempts: int = 0

    @property
    def ok(self) -> bool:
        """Every requested parameter came back with the expected type."""
        return not self.missing and not self.wrong_type

    def problem(self) -> str:
        """What went wrong, naming the parameters ('' when ``ok``)."""
        parts = []
        if self.missing:
            parts.append(f"no answer for {', '.join(self.missing)}")
        parts += [f"{n}: {why}" for n, why in sorted(self.wrong_type.items())]
        return "; ".join(parts)


class ParamBusyError(RuntimeError):
    """A parameter read is already running."""


@dataclass
class _Request:
    name: str
    tries: int = 0
    deadline: float | None = None  # None: not sent yet (waiting for a slot)


class ParamClient:
    """Sans-IO parameter read client (one read at a time). ``send`` transmits a message."""

    def __init__(
        self,
        send: Callable[[MavMessage], None],
        target_sysid: int = 1,
        target_compid: int = 1,
        *,
        timeout_s: float = 0.5,
        retries: int = 2,
        max_in_flight: int = 8,
    ) -> None:
        if timeout_s <= 0 or retries < 0 or max_in_flight < 1:
            raise ValueError("need timeout_s > 0, retries >= 0 and max_in_flight >= 1")
        self._send = send
        self.target_sysid, self.target_compid = target_sysid, target_compid
        self.timeout_s, self.retries, self.max_in_flight = timeout_s, retries, max_in_flight
        self._reqs: dict[str, _Request] | None = None
        self._order: list[str] = []
        self._expect: dict[str, ParamType] = {}
        self._values: dict[str, float] = {}
        self._missing: list[str] = []
        self._wrong: dict[str, str] = {}
        self._sent = 0

    @property
    def is_idle(self) -> bool:
        """True when no read runs."""
        return self._reqs is None

    def read(self, names: Iterable[str], now: float,
             expect: Mapping[str, ParamType] | None = None) -> list[ParamReadDone]:
        """Start reading ``names`` (PX4 names, at most 16 characters each). ``expect``: the type
        a name must come back with (others: any type). An empty list finishes at once."""
        if self._reqs is not None:
            raise ParamBusyError("a parameter read is already running")
        wanted = list(dict.fromkeys(names))
        for n in wanted:
            if not n or len(n.encode("ascii")) > 16:
                raise ValueError(f"parameter name {n!r} must be 1..16 ASCII characters")
        self._reqs = {n: _Request(n) for n in wanted}
        self._expect = dict(expect or {})
        self._order = wanted
        self._values, self._missing, self._wrong, self._sent = {}, [], {}, 0
        self._fill(now)
        return self._maybe_done(now)

    def cancel(self) -> None:
        """Abandon the running read (no event)."""
        self._reqs = None

    def _transmit(self, req: _Request, now: float) -> None:
        req.tries += 1
        req.deadline = now + self.timeout_s
        self._sent += 1
        self._send(mavlink2.MAVLink_param_request_read_message(
            self.target_sysid, self.target_compid, req.name.encode("ascii"), -1))

    def _fill(self, now: float) -> None:
        """Send waiting requests while fewer than ``max_in_flight`` are outstanding."""
        assert self._reqs is not None
        busy = sum(1 for r in self._reqs.values() if r.deadline is not None)
        for r in self._reqs.values():
            if busy >= self.max_in_flight:
                break
            if r.deadline is None:
                self._transmit(r, now)
                busy += 1

    def _maybe_done(self, now: float) -> list[ParamReadDone]:
        if self._reqs is None or self._reqs:
            return []
        self._reqs = None
        missing = tuple(n for n in self._order if n in self._missing)
        return [ParamReadDone(now, dict(self._values), missing, dict(self._wrong), self._sent)]

    def on_message(self, msg: MavMessage, now: float) -> list[ParamReadDone]:
        """Feed a PARAM_VALUE (others and other senders are ignored)."""
        if (self._reqs is None or msg.get_type() != "PARAM_VALUE"
                or msg.get_srcSystem() != self.target_sysid
                or msg.get_srcComponent() != self.target_compid):
            return []
        raw = msg.param_id
        name = (raw.decode("ascii", "replace") if isinstance(raw, bytes) else str(raw))
        name = name.split("\x00", 1)[0]
        if name not in self._reqs:
            return []  # not asked for, or answered already
        ptype = int(msg.param_type)
        want = self._expect.get(name)
        del self._reqs[name]
        try:
            if want is not None and ptype != want:
                raise ValueError(f"the vehicle sent {_type_name(ptype)}, expected {want.name}")
            value = decode_param_value(_wire_value(msg), ptype)
            if not math.isfinite(value):
                raise ValueError(f"the vehicle sent a non-finite value ({value})")
            self._values[name] = value
        except ValueError as exc:
            self._wrong[name] = str(exc)
        self._fill(now)
        return self._maybe_done(now)

    def handle_timer(self, now: float) -> list[ParamReadDone]:
        """Re-send requests past their deadline; give a name up after ``retries`` re-sends."""
        if self._reqs is None:
            return []
        for r in list(self._reqs.values()):
            if r.deadline is None or now < r.deadline:
                continue
            if r.tries <= self.retries:
                self._transmit(r, now)
            else:
                del self._reqs[r.name]
                self._missing.append(r.name)
        self._fill(now)
        return self._maybe_done(now)

    def next_deadline(self) -> float | None:
        """When ``handle_timer`` must run next."""
        if self._reqs is None:
            return None
        return min((r.deadline for r in self._reqs.values() if r.deadline is not None),
                   default=None)
