"""`python -m companion fly --connect` flies a short QGroundControl mission on real PX4 SITL.

Oracle: PX4's own GLOBAL_POSITION_INT and HEARTBEAT in the flight's .tlog (read back with
pymavlink): every mission position passed within 0.5 m, the vehicle landed and disarmed.
"""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
from pymavlink import mavutil

from companion.mission import geodetic_to_ned, load_mission
from px4_harness import Px4Sitl

REPO = Path(__file__).resolve().parents[2]
MISSION = REPO / "tests" / "data" / "missions" / "px4_short.plan"


def test_fly_cli_flies_a_short_mission_on_px4(px4: Px4Sitl, tmp_path: Path) -> None:
    tlog = tmp_path / "flight.tlog"
    cmd = [sys.executable, "-m", "companion", "fly", str(MISSION), "--connect", px4.url,
           "--target-system", str(px4.target_system), "--mode", "attitude", "--log", str(tlog)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=180, cwd=tmp_path)
    print(proc.stdout[-3000:], proc.stderr[-3000:])
    assert proc.returncode == 0

    mission = load_mission(MISSION)
    home = mission.home
    targets = [it for it in mission.items if it.command in (16, 21)]
    conn = mavutil.mavlink_connection(str(tlog))
    pos: list[tuple[float, float, float]] = []
    armed: list[bool] = []
    try:
        for _ in range(2_000_000):
            m = conn.recv_match(type=["GLOBAL_POSITION_INT", "HEARTBEAT"])
            if m is None:
                break
            if m.get_srcSystem() != px4.target_system or m.get_srcComponent() != 1:
                continue
            if m.get_type() == "HEARTBEAT":
                armed.append(bool(m.base_mode & 128))
            else:
                pos.append((m.lat * 1e-7, m.lon * 1e-7, m.relative_alt * 1e-3))
    finally:
        conn.close()
    assert len(pos) > 100 and armed
    flown = np.array([geodetic_to_ned(la, lo, home.alt_amsl_m + alt, home) for la, lo, alt in pos])
    for it in targets:
        goal = geodetic_to_ned(it.lat_deg, it.lon_deg, home.alt_amsl_m + it.alt_rel_home_m(home),
                               home)
        if it.command == 21:  # LAND: judged horizontally; it ends on the ground
            d = float(np.min(np.hypot(*(flown[:, :2] - goal[:2]).T)))
        else:
            d = float(np.min(np.linalg.norm(flown - goal, axis=1)))
        print(f"item {it.index}: closest {d:.2f} m")
        assert d < 0.5, (it.index, d)
    assert any(armed) and not armed[-1]  # flown, then landed and disarmed
    assert abs(pos[-1][2]) < 0.5
    assert math.isfinite(pos[-1][0])
