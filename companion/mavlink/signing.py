"""MAVLink 2 message signing (mavlink.io "Message Signing"), sans-IO.

A signed frame has bit 0x01 of ``incompat_flags`` set (covered by the CRC) and 13 bytes after
the CRC: ``link_id`` (1 byte), ``timestamp`` (48 bits little-endian, 10 us units since
2015-01-01T00:00:00Z) and the signature: the first 6 bytes of
``SHA-256(secret_key + header + payload + CRC + link_id + timestamp)``.

:class:`Signer` signs outgoing frames and verifies incoming ones with one 32-byte key:

- Outgoing: every frame gets a timestamp at least 1 above the previous one; the caller moves it
  up to the wall clock with :meth:`Signer.advance_clock` (this module never reads a clock).
- Incoming: the signature is checked FIRST; only a correctly signed frame may touch the replay
  state. Then its timestamp must be above the last one of its ``(sysid, compid, link_id)``
  stream, or, for a stream not seen yet, at most one minute behind our own timestamp. An accepted
  frame advances its stream and, if later, our timestamp. A forged frame with a far-future
  timestamp therefore changes nothing (pymavlink stores the stream timestamp before it compares
  the signature, so one such frame locks a genuine stream out).
- Unsigned frames are refused except for the message ids in ``SigningConfig.accept_unsigned``
  (PX4's list: RADIO_STATUS, ADSB_VEHICLE, COLLISION).

Thread-safe: the setpoint sender thread and the event loop both sign.
"""

from __future__ import annotations

import enum
import hashlib
import hmac
import logging
import stat
import string
import threading
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from pymavlink.dialects.v20 import common as mavlink2

#: 2015-01-01T00:00:00Z on the UNIX clock [s]: the signing timestamp's epoch.
MAVLINK_EPOCH_UNIX_S = 1_420_070_400
#: Signing timestamp units per second (10 us units).
TIMESTAMP_PER_S = 100_000
#: A new stream's first timestamp may lag ours by at most this (one minute) [10 us].
NEW_STREAM_MAX_LAG = 6_000_000
TIMESTAMP_MAX = (1 << 48) - 1
KEY_LEN = 32
SIGNATURE_BLOCK_LEN = 13  # link id, timestamp, signature
IFLAG_SIGNED = 0x01
_HEADER_LEN = 10  # magic .. msgid, MAVLink 2
#: Accepted unsigned even when signing is required (PX4's list).
PX4_UNSIGNED_IDS = frozenset({109, 246, 247})  # RADIO_STATUS, ADSB_VEHICLE, COLLISION

log = logging.getLogger(__name__)


class SigningKeyError(ValueError):
    """A signing key (file) that is not 32 bytes of raw data or 64 hex digits."""


def parse_signing_key(data: bytes, source: str = "signing key") -> bytes:
    """The 32-byte key in ``data``: 64 hex digits (surrounding whitespace and a ``0x`` prefix
    allowed) or exactly 32 raw bytes. ``source`` names the origin in error messages."""
    text = data.strip()
    if text[:2].lower() == b"0x":
        text = text[2:]
    if text and all(chr(b) in string.hexdigits for b in text):
        if len(text) == 2 * KEY_LEN:
            return bytes.fromhex(text.decode("ascii"))
        raise SigningKeyError(
            f"{source}: {len(text)} hex digits; a MAVLink signing key is 32 bytes "
            f"(64 hex digits or 32 raw bytes)")
    if len(data) == KEY_LEN:
        return bytes(data)
    raise SigningKeyError(
        f"{source}: {len(data)} bytes that are neither 64 hex digits nor 32 raw bytes; a "
        "MAVLink signing key is 32 bytes (e.g. `openssl rand -hex 32 > key.hex`)")


def load_signing_key(path: str | Path) -> bytes:
    """Read a key file (see :func:`parse_signing_key`); raises SigningKeyError with the path.
    Logs a warning when the file is readable by other users (it should be mode 600)."""
    try:
        data = Path(path).read_bytes()
        mode = Path(path).stat().st_mode
    except OSError as exc:
        raise SigningKeyError(f"signing key file {path}: {exc.strerror or exc}") from None
    key = parse_signing_key(data, f"signing key file {path}")
    if mode & (stat.S_IRWXG | stat.S_IRWXO):
        log.warning("signing key file %s is accessible to other users (mode %03o); "
                    "`chmod 600 %s` keeps the key secret", path, mode & 0o777, path)
    return key


def signing_timestamp(unix_s: float) -> int:
    """The signing timestamp [10 us since 2015-01-01] of a UNIX time [s] (0 before 2015)."""
    return min(max(int((unix_s - MAVLINK_EPOCH_UNIX_S) * TIMESTAMP_PER_S), 0), TIMESTAMP_MAX)


def signature_of(key: bytes, signed_part: bytes | bytearray | memoryview) -> bytes:
    """The 6-byte signature of a frame: ``signed_part`` is the frame up to and including the
    timestamp (flag set, CRC computed over it), i.e. everything but the last 6 bytes."""
    return hashlib.sha256(key + bytes(signed_part)).digest()[:6]


def strip_signature(frame: bytes) -> bytes:
    """The unsigned copy of a signed MAVLink 2 frame (flag cleared, CRC recomputed, signature
    block removed), as the spec asks for log files; other frames are returned unchanged.
    Unknown message ids (no CRC_EXTRA) are returned unchanged too."""
    if len(frame) < _HEADER_LEN + 2 + SIGNATURE_BLOCK_LEN or frame[0] != 0xFD or not (
            frame[2] & IFLAG_SIGNED):
        return frame
    msg_id = frame[7] | (frame[8] << 8) | (frame[9] << 16)
    cls = mavlink2.mavlink_map.get(msg_id)
    if cls is None:
        return frame
    body = bytearray(frame[:-SIGNATURE_BLOCK_LEN - 2])
    body[2] &= ~IFLAG_SIGNED & 0xFF
    crc = mavlink2.x25crc(bytes(body[1:]))
    crc.accumulate(bytes((cls.crc_extra,)))
    return bytes(body) + int(crc.crc).to_bytes(2, "little")


class Verdict(enum.Enum):
    """Outcome of :meth:`Signer.verify` for one frame."""

    ACCEPTED = "accepted"  # correctly signed, fresh timestamp
    UNSIGNED_ALLOWED = "unsigned_allowed"  # unsigned, id in accept_unsigned
    UNSIGNED = "unsigned"  # refused: unsigned
    BAD_SIGNATURE = "bad_signature"  # refused: wrong key or altered frame
    REPLAYED = "replayed"  # refused: timestamp not above its stream's last
    STALE = "stale"  # refused: new stream more than a minute behind our timestamp
    MALFORMED = "malformed"  # refused: not a MAVLink 2 frame of consistent length

    @property
    def ok(self) -> bool:
        """True if the frame may be used."""
        return self in (Verdict.ACCEPTED, Verdict.UNSIGNED_ALLOWED)


@dataclass(frozen=True)
class SigningConfig:
    """MAVLink 2 signing on a link: the 32-byte ``key`` (never shown in repr), the ``link_id``
    of frames sent from the event loop (commands, heartbeats, mission, ...) and the message ids
    accepted unsigned. Setpoints from the fixed-rate sender thread are signed as their own stream,
    ``setpoint_link_id`` = link_id + 1 (mod 256): two threads sending on one stream could put a
    lower timestamp on the wire after a higher one and have it refused as a replay."""

    key: bytes = field(repr=False)
    link_id: int = 0
    accept_unsigned: frozenset[int] = PX4_UNSIGNED_IDS

    def __post_init__(self) -> None:
        if not isinstance(self.key, bytes | bytearray) or len(self.key) != KEY_LEN:
            raise SigningKeyError(f"a MAVLink signing key is {KEY_LEN} bytes")
        if not 0 <= self.link_id <= 255:
            raise ValueError(f"signing link id must be 0-255, got {self.link_id}")

    @property
    def setpoint_link_id(self) -> int:
        """Link id of the setpoint stream (see class doc)."""
        return (self.link_id + 1) & 0xFF


class Signer:
    """Signs and verifies MAVLink 2 frames with one key (see module doc).

    ``unix_time_s``: the wall clock at creation (None: timestamps start at 0 until
    :meth:`advance_clock`; receivers then refuse them as more than a minute old).
    """

    def __init__(self, config: SigningConfig, unix_time_s: float | None = None) -> None:
        self.config = config
        self._key = bytes(config.key)
        self._lock = threading.Lock()
        self._timestamp = 0 if unix_time_s is None else signing_timestamp(unix_time_s)
        self._streams: dict[tuple[int, int, int], int] = {}
        self.stats: Counter[str] = Counter()

    @property
    def timestamp(self) -> int:
        """Our current timestamp [10 us since 2015] (the last one used or accepted)."""
        return self._timestamp

    def stream_timestamp(self, sysid: int, compid: int, link_id: int) -> int | None:
        """Last accepted timestamp of an incoming stream (None if never seen)."""
        return self._streams.get((sysid, compid, link_id))

    def advance_clock(self, unix_time_s: float) -> None:
        """Move our timestamp up to the wall clock (never down)."""
        ts = signing_timestamp(unix_time_s)
        with self._lock:
            if ts > self._timestamp:
                self._timestamp = ts

    def sign(self, frame: bytes | bytearray, link_id: int | None = None) -> bytes:
        """``frame`` (a MAVLink 2 frame whose header already has the signed flag and whose CRC
        was computed over it) followed by its signature block, with the next timestamp."""
        if len(frame) < _HEADER_LEN + 2 or frame[0] != 0xFD or not frame[2] & IFLAG_SIGNED:
            raise ValueError("sign() needs a MAVLink 2 frame with the signed flag set")
        lid = self.config.link_id if link_id is None else link_id
        with self._lock:
            ts = self._timestamp = min(self._timestamp + 1, TIMESTAMP_MAX)
        head = bytes(frame) + bytes((lid,)) + ts.to_bytes(6, "little")
        return head + signature_of(self._key, head)

    def verify(self, frame: bytes | bytearray) -> Verdict:
        """Judge one complete MAVLink 2 frame (CRC already checked by the caller) and, if it is
        correctly signed and fresh, advance its stream; counts the verdict in ``stats``."""
        v = self._verify(frame)
        self.stats[v.value] += 1
        return v

    def _verify(self, frame: bytes | bytearray) -> Verdict:
        n = len(frame)
        if n < _HEADER_LEN + 2 or frame[0] != 0xFD:
            return Verdict.MALFORMED
        if not frame[2] & IFLAG_SIGNED:
            msg_id = frame[7] | (frame[8] << 8) | (frame[9] << 16)
            return (Verdict.UNSIGNED_ALLOWED if msg_id in self.config.accept_unsigned
                    else Verdict.UNSIGNED)
        if n != _HEADER_LEN + frame[1] + 2 + SIGNATURE_BLOCK_LEN:
            return Verdict.MALFORMED
        if not hmac.compare_digest(signature_of(self._key, frame[:-6]), bytes(frame[-6:])):
            return Verdict.BAD_SIGNATURE  # nothing below runs for a forged frame
        link_id = frame[-SIGNATURE_BLOCK_LEN]
        ts = int.from_bytes(frame[-12:-6], "little")
        stream = (frame[5], frame[6], link_id)
        with self._lock:
            last = self._streams.get(stream)
            if last is None:
                if ts + NEW_STREAM_MAX_LAG < self._timestamp:
                    return Verdict.STALE
            elif ts <= last:
                return Verdict.REPLAYED
            self._streams[stream] = ts
            if ts > self._timestamp:
                self._timestamp = ts
        return Verdict.ACCEPTED
