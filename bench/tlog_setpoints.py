"""Setpoints the companion sent while PX4 was in OFFBOARD, from a flight's .tlog.

Prints `N` (SET_ATTITUDE_TARGET + SET_POSITION_TARGET_LOCAL_NED frames from anyone but the
autopilot, component 1, sent while the autopilot's last HEARTBEAT said OFFBOARD). An onboard
flight must print 0.

Usage: python bench/tlog_setpoints.py FLIGHT.tlog
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from companion.aio.tlog import offboard_setpoints

if __name__ == "__main__":
    sp, hb = offboard_setpoints(sys.argv[1])
    print(f"{sp} setpoints sent in OFFBOARD ({hb} OFFBOARD heartbeats)")
