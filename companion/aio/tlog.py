"""MAVLink ``.tlog`` writer: every frame received and sent, each prefixed by its 8-byte
big-endian UNIX timestamp in microseconds (the format pymavlink, MAVExplorer and QGroundControl
read). Thread-safe: the sender thread and the asyncio side both write. Signed frames are logged
unsigned (signature block removed, flag cleared, CRC recomputed), as the MAVLink signing spec
asks of log files: a log then gives no material for attacks on the key."""

from __future__ import annotations

import struct
import threading
import time
from pathlib import Path
from typing import BinaryIO

from companion.mavlink.signing import strip_signature

_TS = struct.Struct(">Q")


class TlogWriter:
    """Append-only .tlog file; ``buffer_bytes`` sets the file buffer (a bulk writer such as the
    replay, ~400 frames per simulated second, uses 1 MiB; -1: Python's default)."""

    def __init__(self, path: str | Path, buffer_bytes: int = -1) -> None:
        self.path = Path(path)
        self._f: BinaryIO | None = open(  # noqa: SIM115 - closed in close()
            self.path, "ab", buffering=buffer_bytes)
        self._lock = threading.Lock()
        self.frames = 0

    def write(self, frame: bytes, unix_time_s: float | None = None) -> None:
        """Record one complete MAVLink frame (timestamp defaults to now; signed frames are
        logged unsigned)."""
        t = time.time() if unix_time_s is None else unix_time_s
        if len(frame) > 2 and frame[2] & 0x01 and frame[0] == 0xFD:
            frame = strip_signature(frame)
        rec = _TS.pack(int(t * 1e6)) + frame
        with self._lock:
            if self._f is None:
                return
            self._f.write(rec)
            self.frames += 1

    def write_many(self, frames: list[bytes], unix_time_s: float) -> None:
        """Record several complete frames that share one timestamp (a bulk writer's batch),
        as given (the lockstep replay, which does not sign)."""
        if not frames:
            return
        ts = _TS.pack(int(unix_time_s * 1e6))
        rec = ts + ts.join(frames)
        with self._lock:
            if self._f is None:
                return
            self._f.write(rec)
            self.frames += len(frames)

    def flush(self) -> None:
        """Push buffered records to the OS."""
        with self._lock:
            if self._f is not None:
                self._f.flush()

    def close(self) -> None:
        """Flush and close (idempotent)."""
        with self._lock:
            if self._f is not None:
                self._f.close()
                self._f = None

    def __enter__(self) -> TlogWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


#: The offboard setpoint messages a companion streams.
SETPOINT_MESSAGES = ("SET_ATTITUDE_TARGET", "SET_POSITION_TARGET_LOCAL_NED")
_PX4_OFFBOARD = 6  # PX4's main mode OFFBOARD (custom_mode bits 16-23)


def offboard_setpoints(path: str | Path) -> tuple[int, int]:
    """Setpoints sent while PX4 was in OFFBOARD, from a flight's .tlog: (SET_ATTITUDE_TARGET +
    SET_POSITION_TARGET_LOCAL_NED frames from anyone but the autopilot, component 1, sent
    while the autopilot's last HEARTBEAT said OFFBOARD; the autopilot's HEARTBEATs in
    OFFBOARD). An onboard flight (the module flies) has 0 setpoints."""
    from pymavlink import mavutil
    from pymavlink.dialects.v20 import common as mavlink2

    conn = mavutil.mavlink_connection(str(path), dialect="common")
    offboard, n_sp, n_hb = False, 0, 0
    try:
        for _ in range(50_000_000):
            msg = conn.recv_match()
            if msg is None:
                break
            kind = msg.get_type()
            autopilot = msg.get_srcComponent() == 1
            if kind == "HEARTBEAT" and autopilot and msg.type != mavlink2.MAV_TYPE_GCS:
                offboard = ((msg.custom_mode >> 16) & 0xFF) == _PX4_OFFBOARD
                n_hb += offboard
            elif kind in SETPOINT_MESSAGES and not autopilot and offboard:
                n_sp += 1
    finally:
        conn.close()
    return n_sp, n_hb
