"""MAVLink 2 signing for the mock autopilot (written from the mavlink.io spec; independent of the
companion's implementation, which this package must not import).

With a key, the mock behaves like PX4 with MAV_SIGN_CFG = 2 (signing always required):
- every frame it sends is signed (per link: link id = the link's index, its own timestamp,
  starting at the wall clock given at boot and advancing with simulated time, +1 per frame);
- a received frame is used only if it is correctly signed and fresh for its
  (sysid, compid, link id) stream, or unsigned with one of PX4's always-accepted ids
  (RADIO_STATUS, ADSB_VEHICLE, COLLISION). The signature is compared before any replay state
  is read or written, so a forged frame with a far-future timestamp cannot lock a stream out.
Refused frames are dropped silently (PX4 sends no ACK) and counted by reason.
"""

from __future__ import annotations

import hashlib
import hmac
import struct
from pathlib import Path

from sitl_mock.mavwire import codec_by_id, crc_mcrf4xx

EPOCH_2015_UNIX_S = 1_420_070_400.0
TICKS_PER_S = 100_000  # the signing timestamp counts 10 us ticks
ONE_MINUTE_TICKS = 60 * TICKS_PER_S
ALWAYS_ACCEPTED_UNSIGNED = (109, 246, 247)  # RADIO_STATUS, ADSB_VEHICLE, COLLISION (PX4)
_TRAILER = 13
_TS48 = struct.Struct("<IH")  # a 48-bit little-endian integer as (low 32, high 16)


def read_key_file(path: str) -> bytes:
    """The 32-byte key in a file of 64 hex digits (whitespace around it allowed) or 32 raw
    bytes; ValueError with the path and the reason otherwise."""
    try:
        raw = Path(path).read_bytes()
    except OSError as exc:
        raise ValueError(f"signing key file {path}: {exc.strerror or exc}") from None
    stripped = raw.strip()
    try:
        if len(stripped) == 64:
            return bytes.fromhex(stripped.decode("ascii"))
    except (UnicodeDecodeError, ValueError):
        pass
    if len(raw) == 32:
        return raw
    raise ValueError(
        f"signing key file {path}: expected 64 hex digits or 32 raw bytes, found {len(raw)} bytes"
    )


def _ts48(b: bytes) -> int:
    lo, hi = _TS48.unpack(b)
    return int(lo) | (int(hi) << 32)


class LinkSigning:
    """Signing state of one mock link: its link id, the local timestamp and the incoming
    streams' last timestamps; counts refused frames in `refused` by reason."""

    def __init__(self, key: bytes, link_id: int, boot_ticks: int) -> None:
        if len(key) != 32:
            raise ValueError("a MAVLink signing key is 32 bytes")
        self.key = key
        self.link_id = link_id
        self.boot_ticks = boot_ticks
        self.local_ticks = boot_ticks
        self.streams: dict[tuple[int, int, int], int] = {}
        self.refused = {"unsigned": 0, "bad_signature": 0, "old_timestamp": 0}

    def sign(self, frame: bytes, t_boot_s: float) -> bytes:
        """The signed form of an unsigned MAVLink 2 frame sent `t_boot_s` after boot."""
        c = codec_by_id(frame[7] | (frame[8] << 8) | (frame[9] << 16))
        if c is None:
            raise ValueError("cannot sign a frame of an unknown message")
        self.local_ticks = max(self.local_ticks + 1, self.boot_ticks + int(t_boot_s * TICKS_PER_S))
        hdr = bytearray(frame[:-2])
        hdr[2] |= 0x01  # MAVLINK_IFLAG_SIGNED, covered by the CRC
        crc = crc_mcrf4xx(bytes(hdr[1:]) + c.crc_extra_b)
        tick = self.local_ticks
        out = bytes(hdr) + struct.pack("<HB", crc, self.link_id)
        out += _TS48.pack(tick & 0xFFFFFFFF, tick >> 32)
        return out + hashlib.sha256(self.key + out).digest()[:6]

    def accept(self, frame: bytes) -> bool:
        """Whether a received (CRC-valid) frame may be used; advances its stream if so."""
        if not frame[2] & 0x01:
            msg_id = frame[7] | (frame[8] << 8) | (frame[9] << 16)
            if msg_id in ALWAYS_ACCEPTED_UNSIGNED:
                return True
            self.refused["unsigned"] += 1
            return False
        if len(frame) != 12 + frame[1] + _TRAILER:
            self.refused["bad_signature"] += 1
            return False
        mac = hashlib.sha256(self.key + frame[:-6]).digest()[:6]
        if not hmac.compare_digest(mac, frame[-6:]):
            self.refused["bad_signature"] += 1  # no state is touched for a forged frame
            return False
        tick = _ts48(frame[-12:-6])
        key = (frame[5], frame[6], frame[-13])
        prev = self.streams.get(key)
        if (prev is not None and tick <= prev) or (
            prev is None and tick < self.local_ticks - ONE_MINUTE_TICKS
        ):
            self.refused["old_timestamp"] += 1
            return False
        self.streams[key] = tick
        self.local_ticks = max(self.local_ticks, tick)
        return True


def boot_ticks_of(unix_time_s: float) -> int:
    """The signing timestamp of a UNIX time [s]."""
    return max(int((unix_time_s - EPOCH_2015_UNIX_S) * TICKS_PER_S), 0)
