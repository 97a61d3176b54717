"""Fast MAVLink 2 framing for the mock: encoder and decoder, byte-identical to pymavlink.

pymavlink computes the CRC-16/MCRF4XX byte by byte in Python (unless the optional `fastcrc`
package is installed) and parses incoming bytes one frame at a time through a generic path,
which dominated the mock's MAVLink cost. Here:

- the reflected CRC comes from `binascii.crc_hqx` (stdlib C, the non-reflected CRC-CCITT) on
  bit-reversed bytes, then bit-reversing the result;
- each message class gets a `MessageCodec` once: its `struct.Struct`, CRC_EXTRA, and small
  generated functions that flatten fields into wire order (encoding) and reorder the unpacked
  tuple into constructor order (decoding), exactly as pymavlink's `pack` / `decode` do;
  `pack_frame` packs constructor-order values straight into a frame, with the header and the
  CRC state after it cached per (payload length, seq, sysid, compid);
- `unpack_single` reads the fields of a datagram that is exactly one clean frame of a given
  message (the autopilot's SET_ATTITUDE_TARGET hot path), without a pymavlink object;
- `decode_datagram` splits a datagram into unsigned MAVLink 2 frames, checks each CRC and
  builds the same pymavlink message objects as `MAVLink.parse_buffer` (fields, header,
  srcSystem/srcComponent, `_msgbuf`). Anything unusual (MAVLink 1, signed or flagged frames,
  unknown ids, bad CRC, garbage, truncated or over-long frames) returns None so the caller can
  hand the whole datagram to pymavlink's robust parser and count it exactly as before.

Tests compare every path with pymavlink (tests/sitl_mock/test_sitl_autopilot_mavwire.py,
tests/sitl_mock/test_sitl_mavwire_codec.py, tests/sitl_mock/test_fast_paths.py).
"""

from __future__ import annotations

import binascii
import inspect
import struct
from collections.abc import Callable
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

_REV8 = bytes(int(f"{i:08b}"[::-1], 2) for i in range(256))
_HDR6 = struct.Struct("<BBBBBB").pack  # len, incompat, compat, seq, sysid, compid
_B2 = struct.Struct("<BB").pack
_crc_hqx = binascii.crc_hqx
_Header = mavlink.MAVLink_header


def crc_mcrf4xx(data: bytes, crc: int = 0xFFFF) -> int:
    """CRC-16/MCRF4XX (MAVLink's X.25 checksum) of `data` starting from `crc`."""
    rev_init = (_REV8[crc & 0xFF] << 8) | _REV8[crc >> 8]
    r = _crc_hqx(data.translate(_REV8), rev_init)
    return (_REV8[r & 0xFF] << 8) | _REV8[r >> 8]


# One MAVLink 2 frame around a full-size payload: trailing zeros truncated, the header (and the
# CRC state after it) cached per (length, seq, sysid, compid), then the CRC continued over the
# payload and CRC_EXTRA. Generated per message as `pack_frame(seq, sysid, compid, a)` (payload
# packed from constructor-order values `a`) and `frame_payload(payload, seq, sysid, compid)`.
_FRAME_SRC = """
def {name}({params}):
{prelude}    payload = {payload}.rstrip(b"\\x00") or b"\\x00"
    key = (len(payload), seq & 0xFF, sysid, compid)
    head = _headers.get(key)
    if head is None:
        head = _header(key)
    r = _crc_hqx((payload + _crc_extra).translate(_REV8), head[1])
    return head[0] + payload + _B2(_REV8[r >> 8], _REV8[r & 0xFF])
"""


def _as_bytes(v: Any) -> Any:
    """A char[] field value for struct: str -> UTF-8 bytes, anything else unchanged."""
    return v.encode("utf-8") if isinstance(v, str) else v


class MessageCodec:
    """Wire layout of one pymavlink message class (encoding and decoding, MAVLink 2).

    `frame(seq, sysid, compid, args)` packs constructor-order field values `args` (the
    positional arguments of the pymavlink class, extensions optional) into a complete frame;
    `frame_of(msg, seq, sysid, compid)` does the same from a message object. `pack_frame` is
    `frame` as one generated function (the autopilot's telemetry hot path).
    """

    def __init__(self, cls: type) -> None:
        c: Any = cls
        self.cls = cls
        self.msg_id = int(c.id)
        self.crc_extra = int(c.crc_extra)
        self.crc_extra_b = bytes((self.crc_extra,))
        self.id3 = bytes((self.msg_id & 0xFF, (self.msg_id >> 8) & 0xFF, self.msg_id >> 16))
        self.struct: struct.Struct = c.unpacker
        self.size = int(c.unpacker.size)
        names: list[str] = list(c.fieldnames)
        types = dict(zip(c.fieldnames, c.fieldtypes, strict=True))
        # constructor defaults for the extension fields a caller may leave out
        params = list(inspect.signature(c.__init__).parameters.values())[1:]
        self.n_fields = len(names)
        self.defaults: tuple[Any, ...] = tuple(p.default for p in params)
        self.n_required = sum(p.default is inspect.Parameter.empty for p in params)
        if len(params) != self.n_fields:
            raise TypeError(f"{cls.__name__}: constructor does not take one argument per field")
        index = {n: i for i, n in enumerate(names)}
        from_args: list[str] = []
        from_msg: list[str] = []
        for name, n in zip(c.ordered_fieldnames, c.array_lengths, strict=True):
            i = index[name]
            if types[name] == "char":
                from_args.append(f"_b(a[{i}])")
                from_msg.append(f"_b(m.{name})")
            elif n:
                from_args.append(f"*a[{i}][:{int(n)}]")
                from_msg.append(f"*m.{name}[:{int(n)}]")
            else:
                from_args.append(f"a[{i}]")
                from_msg.append(f"m.{name}")
        env: dict[str, Any] = {"_b": _as_bytes}
        self.flat_args: Callable[[tuple[Any, ...]], tuple[Any, ...]] = eval(
            "lambda a: (" + ", ".join(from_args) + ",)", env
        )
        self.flat_msg: Callable[[Any], tuple[Any, ...]] = eval(
            "lambda m: (" + ", ".join(from_msg) + ",)", env
        )
        # (payload length, seq, sysid, compid) -> (frame start b"\xfd" + header, CRC state after
        # the header); at most 256 x (payload size) entries per message
        self._headers: dict[tuple[int, int, int, int], tuple[bytes, int]] = {}
        env.update(
            _pack=self.struct.pack,
            _complete=self._complete,
            _headers=self._headers,
            _header=self._header,
            _crc_extra=self.crc_extra_b,
            _crc_hqx=_crc_hqx,
            _REV8=_REV8,
            _B2=_B2,
        )
        exec(
            _FRAME_SRC.format(
                name="frame_payload",
                params="payload, seq, sysid, compid",
                prelude="",
                payload="payload",
            ),
            env,
        )
        exec(
            _FRAME_SRC.format(
                name="pack_frame",
                params="seq, sysid, compid, a",
                prelude=f"    if len(a) < {self.n_fields}:\n        a = _complete(a)\n",
                payload=f"_pack({', '.join(from_args)})",
            ),
            env,
        )
        self._frame_payload: Callable[[bytes, int, int, int], bytes] = env["frame_payload"]
        self.pack_frame: Callable[[int, int, int, tuple[Any, ...]], bytes] = env["pack_frame"]
        # decoding: pymavlink's MAVLink.decode reordering, resolved once per class
        zero = self.struct.unpack(bytes(self.size))
        lengths: list[int] = list(c.lengths)
        parts = []
        for order in c.orders:
            n = lengths[order]
            tip = sum(lengths[:order])
            if isinstance(zero[tip], bytes):
                parts.append(f"t[{tip}].rstrip(b'\\x00')")
            elif n == 1:
                parts.append(f"t[{tip}]")
            else:
                parts.append(f"list(t[{tip}:{tip + n}])")
        self.ctor_args: Callable[[tuple[Any, ...]], tuple[Any, ...]] = eval(
            "lambda t: (" + ", ".join(parts) + ",)", {}
        )

    def _header(self, key: tuple[int, int, int, int]) -> tuple[bytes, int]:
        """(b"\\xfd" + header, CRC state after it) for (payload length, seq, sysid, compid)."""
        n, seq, sysid, compid = key
        hdr = _HDR6(n, 0, 0, seq, sysid, compid) + self.id3  # struct.error if not 0..255
        head = self._headers[key] = (b"\xfd" + hdr, _crc_hqx(hdr.translate(_REV8), 0xFFFF))
        return head

    def _frame(self, flat: tuple[Any, ...], seq: int, sysid: int, compid: int) -> bytes:
        return self._frame_payload(self.struct.pack(*flat), seq, sysid, compid)

    def _complete(self, args: tuple[Any, ...]) -> tuple[Any, ...]:
        """`args` with the omitted extension fields at their constructor defaults."""
        if len(args) < self.n_required:
            raise TypeError(f"{self.cls.__name__} needs {self.n_required} fields")
        return args + self.defaults[len(args) :]

    def frame(self, seq: int, sysid: int, compid: int, args: tuple[Any, ...]) -> bytes:
        """MAVLink 2 frame (unsigned) of constructor-order values `args`."""
        return self.pack_frame(seq, sysid, compid, args)

    def frame_of(self, msg: Any, seq: int, sysid: int, compid: int) -> bytes:
        """MAVLink 2 frame (unsigned) of pymavlink message object `msg`."""
        return self._frame(self.flat_msg(msg), seq, sysid, compid)


_CODECS: dict[type, MessageCodec] = {}
_CODECS_BY_ID: dict[int, MessageCodec] = {}


def codec(cls: type) -> MessageCodec:
    """The (cached) codec of pymavlink message class `cls`."""
    c = _CODECS.get(cls)
    if c is None:
        c = _CODECS[cls] = MessageCodec(cls)
    return c


def codec_by_id(msg_id: int) -> MessageCodec | None:
    """The codec of a common-dialect message id, or None if pymavlink does not know it."""
    c = _CODECS_BY_ID.get(msg_id)
    if c is None:
        cls = mavlink.mavlink_map.get(msg_id)
        if cls is None:
            return None
        c = _CODECS_BY_ID[msg_id] = codec(cls)
    return c


def pack_v2(msg: Any, seq: int, sysid: int, compid: int) -> bytes:
    """MAVLink 2 frame of pymavlink message `msg` (same bytes as `msg.pack(mav)`, unsigned)."""
    c = _CODECS.get(type(msg))
    if c is None:
        c = codec(type(msg))
    return c._frame(c.flat_msg(msg), seq, sysid, compid)


def unpack_single(data: bytes, c: MessageCodec) -> tuple[Any, ...] | None:
    """Wire-order field values of `data` if it is exactly one clean frame of `c`'s message.

    The hot inbound path (one SET_ATTITUDE_TARGET per datagram) without building a pymavlink
    object: returns `c.struct.unpack` of the zero-extended payload, or None whenever
    `decode_datagram` would not accept `data` as that single frame (another id, several
    frames, MAVLink 1, signed or flagged, over-long, truncated, bad CRC), so the caller falls
    back to the general path with unchanged results.
    """
    n = len(data)
    if n < 12 or data[0] != 0xFD or data[2] or n != 12 + data[1] or data[1] > c.size:
        return None
    if data[7:10] != c.id3:
        return None
    r = _crc_hqx((data[1:-2] + c.crc_extra_b).translate(_REV8), 0xFFFF)
    if data[-2] != _REV8[r >> 8] or data[-1] != _REV8[r & 0xFF]:
        return None
    payload = data[10:-2]
    if n - 12 < c.size:
        payload += bytes(c.size - (n - 12))  # MAVLink 2 trailing-zero truncation
    return c.struct.unpack(payload)


def decode_datagram(data: bytes) -> list[Any] | None:
    """Messages of a datagram made only of valid unsigned MAVLink 2 frames of known ids.

    Returns the same message objects as pymavlink's `MAVLink(None).parse_buffer(data)` (robust
    parsing) would, or None if anything is unusual (MAVLink 1, signed or flagged frames,
    unknown ids, payloads longer than the message, bad CRC, garbage, a truncated tail): then
    the caller parses the whole datagram with pymavlink. An empty datagram gives [].
    """
    out: list[Any] = []
    n = len(data)
    i = 0
    get = _CODECS_BY_ID.get
    while i < n:
        if data[i] != 0xFD or i + 12 > n or data[i + 2]:
            return None
        mlen = data[i + 1]
        end = i + 12 + mlen
        if end > n:
            return None
        msg_id = data[i + 7] | (data[i + 8] << 8) | (data[i + 9] << 16)
        c = get(msg_id) or codec_by_id(msg_id)
        if c is None or mlen > c.size:
            return None
        r = _crc_hqx((data[i + 1 : end - 2] + c.crc_extra_b).translate(_REV8), 0xFFFF)
        if data[end - 2] != _REV8[r >> 8] or data[end - 1] != _REV8[r & 0xFF]:
            return None
        payload = data[i + 10 : end - 2]
        if mlen < c.size:
            payload += bytes(c.size - mlen)  # MAVLink 2 trailing-zero truncation
        try:
            m = c.cls(*c.ctor_args(c.struct.unpack(payload)))
        except Exception:  # pymavlink would report BAD_DATA: let it
            return None
        msgbuf = bytearray(data[i:end])
        m._signed = False
        m._msgbuf = msgbuf
        m._payload = msgbuf[6:-2]
        m._crc = data[end - 2] | (data[end - 1] << 8)
        m._header = _Header(msg_id, 0, data[i + 3], mlen, data[i + 4], data[i + 5], data[i + 6])
        out.append(m)
        i = end
    return out
