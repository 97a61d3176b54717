"""MAVLink 2 codec: a thin, thread-safe wrapper on pymavlink's ``dialects.v20.common``.

The companion defaults to sysid 1 / compid 191 (MAV_COMP_ID_ONBOARD_COMPUTER): a companion computer
is a component of the vehicle and shares the autopilot's system id (MAVLink convention); PX4 is
1/1. Only MAVLink 2 frames are emitted and accepted (MAVLink 1 frames and frames with a bad CRC
are dropped and counted).

Decoding has a fast path that returns the same pymavlink message objects as pymavlink's parser
(``MAVLink.parse_buffer``) but skips its per-byte state machine: frames are split by length exactly
as pymavlink does it (a run of bytes that are neither 0xFD nor 0xFE is one bad-data drop; at a magic
byte the frame length is taken from the header whatever the frame holds), the CRC-16/MCRF4XX with
CRC_EXTRA is checked in C (``fastcrc``, pymavlink's own dependency; stdlib ``binascii`` otherwise),
and the payload is zero-extended and unpacked with the message class's ``struct`` in wire order.
Signed frames and unknown message ids go through pymavlink's ``MAVLink.decode`` (pymavlink's
own signing, ``mav.signing``, is not used). Encoding likewise packs the payload with the class's
``struct`` in the generated ``pack``'s order and gives the same bytes as ``msg.pack(mav)``; every
frame gets the next sequence number. ``tests/companion/mavlink/test_mavlink_codec_fast.py``
checks both against pymavlink.

Signing (``signer``, see :mod:`companion.mavlink.signing`): every encoded frame is signed, every
decoded frame is verified after its CRC (signature first, then the replay rules) and dropped
unless the signer accepts it (counted in ``rejected_frames``, reasons in ``signer.stats``).
"""

from __future__ import annotations

import binascii
import operator
import struct
import threading
from collections.abc import Callable
from typing import Any

from pymavlink.dialects.v20 import common as mavlink2

from .signing import IFLAG_SIGNED, Signer

MAVLINK2_MAGIC = 0xFD
MAVLINK1_MAGIC = 0xFE

#: Default ids of the companion (MAV_COMP_ID_ONBOARD_COMPUTER) and of PX4.
DEFAULT_SYSID = 1
DEFAULT_COMPID = 191
PX4_SYSID = 1
PX4_COMPID = 1

MavMessage = Any  # pymavlink.dialects.v20.common.MAVLink_message (pymavlink ships no stubs)

_V2_HEADER_LEN = 10
_V1_HEADER_LEN = 6
_SIGNATURE_LEN = 13
_IFLAG_SIGNED = IFLAG_SIGNED
_REV8 = bytes(int(f"{i:08b}"[::-1], 2) for i in range(256))


def _crc_mcrf4xx_stdlib(data: bytes | bytearray, crc: int = 0xFFFF) -> int:
    """CRC-16/MCRF4XX (MAVLink's X.25 checksum) of ``data`` from ``crc``, via ``binascii``.

    ``binascii.crc_hqx`` is the non-reflected CRC-CCITT; MCRF4XX is its reflected form, so the
    input bytes, the initial value and the result are bit-reversed around it.
    """
    rev_init = (_REV8[crc & 0xFF] << 8) | _REV8[crc >> 8]
    r = binascii.crc_hqx(bytes(data).translate(_REV8), rev_init)
    return (_REV8[r & 0xFF] << 8) | _REV8[r >> 8]


_crc_mcrf4xx: Callable[[bytes | bytearray, int], int] = (
    mavlink2.mcrf4xx if getattr(mavlink2, "mcrf4xx", None) is not None else _crc_mcrf4xx_stdlib
)

# Per message id: (class, CRC_EXTRA byte, struct, payload size, argument builder), built lazily.
_Layout = tuple[type, bytes, struct.Struct, int, Callable[[tuple[Any, ...]], Any]]
_MISSING: Any = object()
# Per message class: (message id, CRC_EXTRA byte, msg -> full-length payload bytes).
_Packer = tuple[int, bytes, Callable[[Any], bytes]]
_V2_HEADER = struct.Struct("<BBBBBBBHB")  # magic, len, incompat, compat, seq, sys, comp, id lo/hi
_CRC = struct.Struct("<H")


def _arg_builder(cls: Any) -> Callable[[tuple[Any, ...]], Any]:
    """Map the unpacked wire-order tuple to the constructor's arguments (pymavlink's rules)."""
    orders: list[int] = list(cls.orders)
    lengths: list[int] = list(cls.lengths)
    has_bytes = any(ch in cls.unpacker.format for ch in "sc")
    if sum(lengths) == len(lengths):  # no numeric arrays: a pure reordering
        if len(orders) == 1:
            only = orders[0]

            def reorder(t: tuple[Any, ...]) -> Any:
                return (t[only],)
        else:
            reorder = operator.itemgetter(*orders)  # type: ignore[assignment]
    else:
        spec: list[tuple[int, int]] = []
        for order in orders:
            n = lengths[order]
            tip = sum(lengths[:order])
            spec.append((tip, tip + n if n > 1 else -1))

        def reorder(t: tuple[Any, ...]) -> Any:
            return [t[a] if b < 0 else list(t[a:b]) for a, b in spec]

    if not has_bytes:
        return reorder

    def with_strings(t: tuple[Any, ...]) -> Any:  # pymavlink strips trailing NULs of char fields
        return [v.rstrip(b"\x00") if isinstance(v, bytes) else v for v in reorder(t)]

    return with_strings


def _payload_packer(cls: Any) -> _Packer | None:
    """Payload serialiser mirroring the generated ``cls.pack``: wire order, arrays element by
    element, char fields from ``_<name>_raw``. None for classes pymavlink does not map."""
    if mavlink2.mavlink_map.get(getattr(cls, "id", None)) is not cls:
        return None
    types = dict(zip(cls.fieldnames, cls.fieldtypes, strict=True))
    spec: list[tuple[str, int]] = []  # (attribute, element index or -1 for a scalar)
    for name, n in zip(cls.ordered_fieldnames, cls.array_lengths, strict=True):
        if types[name] == "char":
            spec.append((f"_{name}_raw", -1))
        elif n:
            spec += [(name, k) for k in range(n)]
        else:
            spec.append((name, -1))
    struct_pack = cls.unpacker.pack
    if all(k < 0 for _, k in spec):
        get = operator.attrgetter(*(a for a, _ in spec))
        if len(spec) == 1:
            def pack(msg: Any) -> bytes:
                return bytes(struct_pack(get(msg)))
        else:
            def pack(msg: Any) -> bytes:
                return bytes(struct_pack(*get(msg)))
    else:
        def pack(msg: Any) -> bytes:
            return bytes(struct_pack(*[getattr(msg, a) if k < 0 else getattr(msg, a)[k]
                                       for a, k in spec]))
    return int(cls.id), bytes((int(cls.crc_extra),)), pack


class Codec:
    """Encode/decode MAVLink 2 frames with our system/component id.

    ``encode`` is guarded by a lock so that the fixed-rate sender thread and the asyncio side can
    share one sequence counter. ``decode`` must be called from one thread only. With a
    ``signer`` every frame out is signed and every frame in must pass ``signer.verify``.
    """

    def __init__(self, sysid: int = DEFAULT_SYSID, compid: int = DEFAULT_COMPID,
                 signer: Signer | None = None) -> None:
        if not (1 <= sysid <= 255 and 0 <= compid <= 255):
            raise ValueError(f"invalid MAVLink ids sysid={sysid} compid={compid}")
        self.sysid = sysid
        self.compid = compid
        self.signer = signer
        self.rejected_frames = 0
        self.mav: Any = mavlink2.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        self.mav.robust_parsing = True
        self._lock = threading.Lock()
        self.dropped_frames = 0
        self._pending = b""
        self._layouts: dict[int, _Layout | None] = {}
        self._packers: dict[type, _Packer | None] = {}

    def encode(self, msg: MavMessage, link_id: int | None = None) -> bytes:
        """Serialise ``msg`` as one MAVLink 2 frame and advance the sequence number (0..255).

        Unsigned: the same bytes as pymavlink's ``msg.pack(mav)``, built with the class's
        ``struct`` and a C CRC; unlike ``msg.pack`` it does not store the frame on ``msg``.
        With a signer the frame is signed on stream ``link_id`` (default: the signer's).
        """
        cls = type(msg)
        packer = self._packers.get(cls, _MISSING)
        if packer is _MISSING:
            packer = self._packers[cls] = _payload_packer(cls)
        if packer is None:  # a class outside pymavlink's map: its own pack gives the payload
            with self._lock:
                unsigned = bytes(msg.pack(self.mav))
            return self.encode_payload(int(msg.get_msgId()), bytes((int(msg.crc_extra),)),
                                       unsigned[_V2_HEADER_LEN:-2], link_id)
        msg_id, extra, pack = packer
        return self.encode_payload(msg_id, extra, pack(msg), link_id)

    def encode_payload(self, msg_id: int, crc_extra: bytes, payload: bytes,
                       link_id: int | None = None) -> bytes:
        """One MAVLink 2 frame around a full-length ``payload`` already packed in wire order
        (the message class's ``struct``), trailing zeros truncated as MAVLink 2 does; advances
        the sequence number. ``crc_extra`` is the class's CRC_EXTRA as one byte. With a signer
        the frame is signed on stream ``link_id`` (default: the signer's)."""
        payload = payload.rstrip(b"\x00") or b"\x00"
        signer = self.signer
        flags = 0 if signer is None else _IFLAG_SIGNED
        with self._lock:
            mav = self.mav
            seq = mav.seq
            header = _V2_HEADER.pack(MAVLINK2_MAGIC, len(payload), flags, 0, seq, mav.srcSystem,
                                     mav.srcComponent, msg_id & 0xFFFF, msg_id >> 16)
            mav.seq = (seq + 1) & 0xFF
            crc = _crc_mcrf4xx(crc_extra, _crc_mcrf4xx(header[1:] + payload, 0xFFFF))
            frame = header + payload + _CRC.pack(crc)
            if signer is not None:  # in the lock: sequence and timestamp orders agree
                frame = signer.sign(frame, link_id)
        return frame

    def decode(self, data: bytes | bytearray, *, datagram: bool = False) -> list[MavMessage]:
        """Parse bytes (any fragmentation) into complete, CRC-valid MAVLink 2 messages.

        Byte streams (TCP, serial; ``datagram=False``): same messages, order and drop count as
        pymavlink's ``parse_buffer`` filtered to valid MAVLink 2 frames; an incomplete trailing
        frame is kept for the next call. Datagram links (UDP; ``datagram=True``): ``data`` is one
        datagram, parsed on its own: nothing carries over to the next datagram (a frame never
        spans two), and a header whose length runs past the datagram's end is dropped and the
        parser resynchronises at the next magic byte of the same datagram.
        """
        if datagram:
            saved, self._pending = self._pending, b""
            try:
                return self._decode(bytes(data), datagram=True)
            finally:
                self._pending = saved
        return self._decode(self._pending + bytes(data) if self._pending else bytes(data),
                            datagram=False)

    def _decode(self, buf: bytes, *, datagram: bool) -> list[MavMessage]:
        n = len(buf)
        out: list[MavMessage] = []
        layouts = self._layouts
        crc16 = _crc_mcrf4xx
        header = mavlink2.MAVLink_header
        signer = self.signer
        i = 0
        while i < n:
            magic = buf[i]
            if magic != MAVLINK2_MAGIC and magic != MAVLINK1_MAGIC:
                # pymavlink: one bad-data drop per run of non-magic bytes
                j2 = buf.find(b"\xfd", i)
                j1 = buf.find(b"\xfe", i)
                i = n if j1 < 0 and j2 < 0 else (j1 if j2 < 0 else j2 if j1 < 0 else min(j1, j2))
                self.dropped_frames += 1
                continue
            if n - i < 3:
                if datagram:  # a truncated header at the end of a datagram
                    self.dropped_frames += 1
                    i = n
                break
            start = i
            mlen = buf[i + 1]
            if magic != MAVLINK2_MAGIC:  # MAVLink 1: pymavlink frames it by length; we drop it
                i += _V1_HEADER_LEN + 2 + mlen
                if i > n:
                    if datagram:  # runs past the datagram: not a frame, look further on
                        self.dropped_frames += 1
                        i = start + 1
                        continue
                    i = start
                    break
                self.dropped_frames += 1
                continue
            flags = buf[i + 2]
            pend = i + _V2_HEADER_LEN + mlen
            i = pend + 2 + (_SIGNATURE_LEN if flags & _IFLAG_SIGNED else 0)
            if i > n:
                if datagram:
                    self.dropped_frames += 1
                    i = start + 1
                    continue
                i = start
                break
            if flags & ~_IFLAG_SIGNED:
                self.dropped_frames += 1  # incompat flags pymavlink rejects
                if datagram:  # a rejected frame may hide a real one: resynchronise
                    i = start + 1
                continue
            msg_id = buf[start + 7] | (buf[start + 8] << 8) | (buf[start + 9] << 16)
            layout = layouts.get(msg_id, _MISSING)
            if layout is _MISSING:
                layout = self._layout(msg_id)
            if layout is None or flags:  # unknown id or signed: pymavlink's decode
                msg = self._slow_decode(buf[start:i])
                if msg is None:
                    self.dropped_frames += 1
                    if datagram:
                        i = start + 1
                elif signer is None:
                    out.append(msg)
                elif signer.verify(buf[start:i]).ok:
                    if flags:  # verified here, not by pymavlink: mark it as pymavlink would
                        msg._signed = True
                        msg._link_id = buf[i - _SIGNATURE_LEN]
                    out.append(msg)
                else:
                    self.rejected_frames += 1
                continue
            cls, extra, unpacker, size, build = layout
            crc = buf[pend] | (buf[pend + 1] << 8)
            if crc != crc16(extra, crc16(buf[start + 1:pend], 0xFFFF)) and not (
                    mavlink2.MAVLINK_IGNORE_CRC):
                self.dropped_frames += 1
                if datagram:
                    i = start + 1
                continue
            if signer is not None and not signer.verify(buf[start:i]).ok:
                self.rejected_frames += 1  # unsigned (and not on the allowed list)
                continue
            if mlen >= size:
                values = unpacker.unpack_from(buf, start + _V2_HEADER_LEN)
            else:  # MAVLink 2 truncates trailing zero bytes: zero-extend
                values = unpacker.unpack(buf[start + _V2_HEADER_LEN:pend] + bytes(size - mlen))
            try:
                msg = cls(*build(values))
            except Exception:  # pymavlink turns any constructor error into bad data
                self.dropped_frames += 1
                continue
            msgbuf = bytearray(buf[start:i])
            msg._msgbuf = msgbuf
            msg._payload = msgbuf[_V1_HEADER_LEN:-2]  # sic: pymavlink's decode slices from 6
            msg._crc = crc
            msg._header = header(msg_id, 0, buf[start + 3], mlen, buf[start + 4], buf[start + 5],
                                 buf[start + 6])
            out.append(msg)
        self._pending = buf[i:] if i < n else b""
        return out

    def _layout(self, msg_id: int) -> _Layout | None:
        cls: Any = mavlink2.mavlink_map.get(msg_id)
        layout: _Layout | None = None
        if cls is not None:
            layout = (cls, bytes((int(cls.crc_extra),)), cls.unpacker, int(cls.unpacker.size),
                      _arg_builder(cls))
        self._layouts[msg_id] = layout
        return layout

    def _slow_decode(self, frame: bytes) -> MavMessage | None:
        """pymavlink's own decode of one frame (signed or unknown id); pymavlink checks no
        signature here (no key on ``mav.signing``): the signer does."""
        try:
            msg = self.mav.decode(bytearray(frame))
        except mavlink2.MAVError:
            return None
        return msg if msg.get_type() != "BAD_DATA" else None


def raw_frame(msg: MavMessage) -> bytes:
    """The exact bytes of a received message's frame (for .tlog)."""
    return bytes(msg.get_msgbuf())
