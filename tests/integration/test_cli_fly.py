"""`python -m companion fly` end to end against the embedded mock over loopback UDP, judged
from its own .tlog: OFFBOARD entered after priming, attitude setpoints (type_mask 3), the
figure-8 flown at the commanded altitude inside its footprint, then landed and disarmed."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from pymavlink import mavutil

from companion.cli import main as cli_main

OFFBOARD_CUSTOM_MODE = 6 << 16


def test_fly_figure8_attitude_mode_against_embedded_mock(tmp_path: Path) -> None:
    log = tmp_path / "f8.tlog"
    code = cli_main(["fly", "figure8", "--size", "6", "--speed", "2", "--alt", "4",
                     "--log", str(log)])
    assert code == 0
    m = mavutil.mavlink_connection(str(log))
    in_offboard = False
    first_setpoint_t = None
    offboard_t = None
    masks = set()
    pos_offboard = []
    armed_seen = disarmed_after = False
    while True:
        msg = m.recv_match()
        if msg is None:
            break
        kind = msg.get_type()
        if kind == "SET_ATTITUDE_TARGET" or kind == "SET_POSITION_TARGET_LOCAL_NED":
            if first_setpoint_t is None:
                first_setpoint_t = msg._timestamp
            if kind == "SET_ATTITUDE_TARGET":
                masks.add(msg.type_mask)
        elif kind == "HEARTBEAT" and msg.get_srcComponent() == 1:
            in_offboard = msg.custom_mode == OFFBOARD_CUSTOM_MODE
            if in_offboard and offboard_t is None:
                offboard_t = msg._timestamp
            armed = bool(msg.base_mode & 128)
            armed_seen |= armed
            if armed_seen and not armed:
                disarmed_after = True
        elif kind == "LOCAL_POSITION_NED" and in_offboard:
            pos_offboard.append((msg.x, msg.y, msg.z))
    assert offboard_t is not None and first_setpoint_t is not None
    assert offboard_t - first_setpoint_t >= 0.5  # primed before OFFBOARD
    assert masks <= {3, 7} and masks  # attitude + thrust (+ yaw rate), never rates with q
    p = np.asarray(pos_offboard)
    assert len(p) > 100
    assert np.all(np.abs(p[:, 2] + 4.0) < 0.4)  # altitude held
    # figure-8 of size 6 m: north span 6 m, east span 3 m, around the takeoff point
    assert np.ptp(p[:, 0]) > 5.0 and np.ptp(p[:, 0]) < 7.0
    assert np.ptp(p[:, 1]) > 2.4 and np.ptp(p[:, 1]) < 3.6
    assert disarmed_after
