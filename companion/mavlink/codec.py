"""MAVLink 2 codec: a thin, thread-safe wrapper on pymavlink's ``dialects.v20.common``.

The companion defaults to sysid 1 / compid 191 (MAV_COMP_ID_ONBOARD_COMPUTER): a companion computer
is a component of the vehicle and shares the autopilot's system id (MAVLink convention); PX4 is
1/1. Only MAVLink 2 frames are emitted and accepted (MAVLink 1 frames and frames with a bad CRC
are dropped and counted).
"""

from __future__ import annotations

import threading
from typing import Any

from pymavlink.dialects.v20 import common as mavlink2

MAVLINK2_MAGIC = 0xFD

#: Default ids of the companion (MAV_COMP_ID_ONBOARD_COMPUTER) and of PX4.
DEFAULT_SYSID = 1
DEFAULT_COMPID = 191
PX4_SYSID = 1
PX4_COMPID = 1

MavMessage = Any  # pymavlink.dialects.v20.common.MAVLink_message (pymavlink ships no stubs)


class Codec:
    """Encode/decode MAVLink 2 frames with our system/component id.

    ``encode`` is guarded by a lock so that the fixed-rate sender thread and the asyncio side can
    share one sequence counter. ``decode`` must be called from one thread only.
    """

    def __init__(self, sysid: int = DEFAULT_SYSID, compid: int = DEFAULT_COMPID) -> None:
        if not (1 <= sysid <= 255 and 0 <= compid <= 255):
            raise ValueError(f"invalid MAVLink ids sysid={sysid} compid={compid}")
        self.sysid = sysid
        self.compid = compid
        self.mav: Any = mavlink2.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        self.mav.robust_parsing = True
        self._lock = threading.Lock()
        self.dropped_frames = 0

    def encode(self, msg: MavMessage) -> bytes:
        """Serialise ``msg`` as one MAVLink 2 frame (assigns the next sequence number)."""
        with self._lock:
            return bytes(msg.pack(self.mav))

    def decode(self, data: bytes) -> list[MavMessage]:
        """Parse bytes (any fragmentation) into complete, CRC-valid MAVLink 2 messages."""
        msgs = self.mav.parse_buffer(data) or []
        out: list[MavMessage] = []
        for msg in msgs:
            if msg.get_type() == "BAD_DATA" or msg.get_msgbuf()[0] != MAVLINK2_MAGIC:
                self.dropped_frames += 1
                continue
            out.append(msg)
        return out


def raw_frame(msg: MavMessage) -> bytes:
    """The exact bytes of a received message's frame (for .tlog)."""
    return bytes(msg.get_msgbuf())
