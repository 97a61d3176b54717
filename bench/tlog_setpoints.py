"""Setpoints the companion sent while PX4 was in OFFBOARD, from a flight's .tlog.

Prints `N` (SET_ATTITUDE_TARGET + SET_POSITION_TARGET_LOCAL_NED frames from anyone but the
autopilot, component 1, sent while the autopilot's last HEARTBEAT said OFFBOARD). An onboard
flight must print 0.

Usage: python bench/tlog_setpoints.py FLIGHT.tlog
"""

from __future__ import annotations

import sys

from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2

SETPOINTS = ("SET_ATTITUDE_TARGET", "SET_POSITION_TARGET_LOCAL_NED")
PX4_OFFBOARD = 6  # PX4's main mode OFFBOARD (custom_mode bits 16-23)


def count(path: str) -> tuple[int, int]:
    """(setpoints sent while OFFBOARD, autopilot HEARTBEATs in OFFBOARD)."""
    conn = mavutil.mavlink_connection(path, dialect="common")
    offboard, n_sp, n_hb = False, 0, 0
    try:
        for _ in range(50_000_000):
            msg = conn.recv_match()
            if msg is None:
                break
            kind = msg.get_type()
            autopilot = msg.get_srcComponent() == 1
            if kind == "HEARTBEAT" and autopilot and msg.type != mavlink2.MAV_TYPE_GCS:
                offboard = ((msg.custom_mode >> 16) & 0xFF) == PX4_OFFBOARD
                n_hb += offboard
            elif kind in SETPOINTS and not autopilot and offboard:
                n_sp += 1
    finally:
        conn.close()
    return n_sp, n_hb


if __name__ == "__main__":
    sp, hb = count(sys.argv[1])
    print(f"{sp} setpoints sent in OFFBOARD ({hb} OFFBOARD heartbeats)")
