"""`python -m companion fly FILE --connect` on real PX4 SITL, judged from the flight's tlog:
- every mission position passed within 0.5 m, then landed and disarmed, by PX4's own
  GLOBAL_POSITION_INT and HEARTBEAT (read back with pymavlink; the mission's own coordinates);
- no thrust chatter on the final 10 m descent, commanded tilt within PX4's MPC_TILTMAX_AIR
  (tests/support/setpoint_checks.py) against PX4's own LOCAL_POSITION_NED and landed state;
- the vehicle does not rock: PX4's own ATTITUDE, high-passed, at most 3 deg RMS.
  Before the fix, the same square in attitude mode made 95 thrust jumps over 0.1 (up to 0.5)
  between setpoints 10-20 ms apart."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pymavlink import mavutil

from companion.mission import geodetic_to_ned, load_mission
from px4_harness import Px4Sitl
from tests.support.setpoint_checks import attitude_wobble_deg, read_setpoints

REPO = Path(__file__).resolve().parents[2]
#: takeoff to 10 m, a 30 x 20 m square at 8 m/s, land at home: a 10 m final descent
MISSION = REPO / "tests" / "data" / "missions" / "square_8ms.plan"


# attitude mode only: the mode that chattered (rates mode on the same square: largest step 0.047
# before, 0.044 after; BENCHMARKS.md "Setpoint quality"), to keep the real-time px4 set short
@pytest.mark.parametrize("mode", ["attitude"])
def test_px4_fly_passes_every_waypoint_without_thrust_chatter_within_the_tilt_limit(
        px4: Px4Sitl, tmp_path: Path, mode: str) -> None:
    tlog = tmp_path / "flight.tlog"
    cmd = [sys.executable, "-m", "companion", "fly", str(MISSION), "--connect", px4.url,
           "--target-system", str(px4.target_system), "--mode", mode, "--log", str(tlog)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=240, cwd=tmp_path)
    print(proc.stdout[-3000:], proc.stderr[-3000:])
    assert proc.returncode == 0
    check_mission_positions(tlog, px4.target_system)
    s = read_setpoints(str(tlog))
    steps = s.thrust_steps()
    top = max(range(len(s.height_m)), key=s.height_m.__getitem__)
    descent = [d for t, d in steps if t > s.t_s[top]]
    assert len(descent) > 300  # the final descent is in the measurement
    worst = max(d for _, d in steps)
    wobble = attitude_wobble_deg(str(tlog))
    print(f"{mode}: {len(steps)} setpoint pairs in the air, largest thrust step {worst:.3f}, "
          f"largest commanded tilt {s.max_tilt_deg():.1f} deg, attitude wobble {wobble:.2f} deg")
    assert worst <= 0.05
    assert s.max_tilt_deg() <= 45.0 + 1e-3  # MPC_TILTMAX_AIR (PX4's default)
    # the vehicle does not rock: its own roll and pitch above ~2 Hz (session 30's gains, kp_xy
    # 20: 4.6-5.8 deg, a 1.2 Hz oscillation all flight; 15 / 7.4: 2.1-2.2, 12 / 6.5: 1.6)
    assert wobble <= 3.0
    report = json.loads(Path(f"{tlog}.report.json").read_text())
    print(report.get("setpoint_quality"))
    assert report["result"] == "ok"


def check_mission_positions(tlog: Path, sysid: int) -> None:
    """Every position item of MISSION passed within 0.5 m (LAND: horizontally) by PX4's own
    GLOBAL_POSITION_INT in the tlog; the vehicle armed, then landed (PX4's land detector,
    EXTENDED_SYS_STATE, said on the ground before the last disarm) and disarmed."""
    mission = load_mission(MISSION)
    home = mission.home
    targets = [it for it in mission.items if it.command in (16, 21)]
    assert targets
    conn = mavutil.mavlink_connection(str(tlog))
    pos: list[tuple[float, float, float]] = []
    armed: list[bool] = []
    landed_state = 0  # MAV_LANDED_STATE, the newest
    landed_at_disarm: list[int] = []
    try:
        for _ in range(2_000_000):
            m = conn.recv_match(type=["GLOBAL_POSITION_INT", "HEARTBEAT", "EXTENDED_SYS_STATE"])
            if m is None:
                break
            if m.get_srcSystem() != sysid or m.get_srcComponent() != 1:
                continue
            if m.get_type() == "HEARTBEAT":
                if armed and armed[-1] and not m.base_mode & 128:
                    landed_at_disarm.append(landed_state)
                armed.append(bool(m.base_mode & 128))
            elif m.get_type() == "EXTENDED_SYS_STATE":
                landed_state = int(m.landed_state)
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
    assert any(armed) and not armed[-1]  # flown, then disarmed
    # ... on the ground: PX4's land detector said so before the disarm (not the estimate's
    # height: EKF2 drifts in SIH, in CI 2026-12-02 relative_alt read -0.61 m at the disarm,
    # the rangefinder out of range on the ground)
    assert landed_at_disarm and landed_at_disarm[-1] == 1, landed_at_disarm  # ON_GROUND
    assert abs(pos[-1][2]) < 1.5  # and not far from home's height by the estimate either
    assert math.isfinite(pos[-1][0])
