"""`python -m companion fly` driving the mock's Ackermann rover (PX4 main's rover control
structure) over loopback UDP, judged from its own .tlog as an outsider would: the waypoints
from the file's latitude/longitude (independent geodesy), the rover's LOCAL_POSITION_NED, the
messages the companion sent and the HEARTBEAT's mode. A rover that cannot make progress (its
throttle gives almost nothing) is switched to Hold and the flight is reported failed, naming
the waypoints it missed. A rover started 2.5 m from the planned home drives to the file's own
waypoints (as PX4's AUTO.MISSION would), not to ones moved with it. The three flights run at
the same time (~35 s)."""

from __future__ import annotations

import asyncio
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from pymavlink import mavutil

from tests.support.mission_oracle import expected_ne
from tests.support.mock_process import run_companion, run_mock

# flies in wall-clock time (the mock served over a link): README's second test phase
pytestmark = pytest.mark.realtime

ROOT = Path(__file__).resolve().parents[2]
MISSION = ROOT / "tests" / "data" / "missions" / "rover_short.plan"
OFFBOARD, HOLD = 6, (4, 3)  # PX4 main modes: OFFBOARD; AUTO.LOITER (Hold)
NAV_ACC_RAD = 0.5  # the Ackermann airframe's (the mock's rover default)
RO_SPEED_LIM = 3.0


@dataclass
class Drive:
    code: int
    output: str
    pos_offboard: np.ndarray  # (N, 2) north, east while in OFFBOARD
    sent: set[str]  # message types the companion sent while in OFFBOARD
    max_cmd_speed: float  # largest horizontal velocity setpoint [m/s]
    last_mode: tuple[int, int]
    disarmed_at_end: bool
    report: dict[str, object]
    arm_modes: list[tuple[int, int] | None]  # the HEARTBEAT's mode when each ARM went out


def _read(tlog: Path, code: int, output: str) -> Drive:
    m = mavutil.mavlink_connection(str(tlog), dialect="common")
    mode: tuple[int, int] | None = None
    armed = False
    pos: list[tuple[float, float]] = []
    sent: set[str] = set()
    vmax = 0.0
    arm_modes: list[tuple[int, int] | None] = []
    try:
        msgs = []
        while True:
            msg = m.recv_match(blocking=False)
            if msg is None:
                break
            msgs.append(msg)
    finally:
        m.close()
    for msg in msgs:
        kind = msg.get_type()
        if kind == "COMMAND_LONG" and msg.command == 400 and msg.param1 == 1.0:
            arm_modes.append(mode)
        if kind == "HEARTBEAT" and msg.get_srcSystem() == 1 and msg.autopilot == 12:
            mode = ((msg.custom_mode >> 16) & 0xFF, (msg.custom_mode >> 24) & 0xFF)
            armed = bool(msg.base_mode & 128)
        elif mode is not None and mode[0] == OFFBOARD:
            if kind == "LOCAL_POSITION_NED":
                pos.append((msg.x, msg.y))
            elif kind in ("SET_POSITION_TARGET_LOCAL_NED", "SET_ATTITUDE_TARGET"):
                sent.add(kind)
                if kind == "SET_POSITION_TARGET_LOCAL_NED":
                    vmax = max(vmax, float(np.hypot(msg.vx, msg.vy)))
    assert mode is not None
    report = json.loads(Path(f"{tlog}.report.json").read_text())
    return Drive(code, output, np.array(pos).reshape(-1, 2), sent, vmax, mode,
                 not armed, report, arm_modes)


async def _drive(tmp_path: Path, name: str, *params: str, home: str | None = None) -> Drive:
    tlog = tmp_path / f"{name}.tlog"
    extra = [a for p in params for a in ("--param", p)]
    if home is not None:
        extra += ["--home", home]
    async with run_mock("--vehicle", "rover", *extra) as mock:
        code, out = await run_companion(
            "fly", str(MISSION), "--connect", f"udpin://127.0.0.1:{mock.client_port}",
            "--log", str(tlog), "--timeout", "20", timeout_s=120.0, what=f"fly ({name})")
    return _read(tlog, code, out)


def _waypoints_ne() -> np.ndarray:
    """The mission's waypoints north/east of its planned home [m] (independent geodesy)."""
    plan = json.loads(MISSION.read_text())
    lat0, lon0, _ = plan["mission"]["plannedHomePosition"]
    ll = np.array([it["params"][4:6] for it in plan["mission"]["items"]], dtype=float)
    return np.asarray(expected_ne(lat0, lon0, ll[:, 0], ll[:, 1]))


async def test_fly_drives_a_rover_through_its_corners_and_a_stuck_one_is_held(
        tmp_path: Path) -> None:
    plan = json.loads(MISSION.read_text())
    lat0, lon0, alt0 = plan["mission"]["plannedHomePosition"]
    # booted (and so its local origin) 2 m north and 1.5 m west of the planned home
    away_ne = np.array([2.0, -1.5])
    lat1 = lat0 + float(np.degrees(away_ne[0] / 6_371_000.0))
    lon1 = lon0 + float(np.degrees(away_ne[1] / (6_371_000.0 * np.cos(np.radians(lat0)))))
    ok, stuck, away = await asyncio.gather(
        _drive(tmp_path, "ok"),
        # a throttle that gives ~3 % of the speed PX4 expects: the rover barely moves
        _drive(tmp_path, "stuck", "RO_MAX_THR_SPEED=100"),
        _drive(tmp_path, "away", home=f"{lat1!r},{lon1!r},{alt0!r}"))
    wps = _waypoints_ne()
    # the rover drove on velocity setpoints only, within its speed limit, through every
    # waypoint within NAV_ACC_RAD, and ended in Hold, disarmed
    assert ok.code == 0, ok.output[-3000:]
    # armed in OFFBOARD, its stream primed (as the replay; PX4 main's rover drives off at once)
    assert ok.arm_modes and all(md == (OFFBOARD, 0) for md in ok.arm_modes), ok.arm_modes
    assert ok.sent == {"SET_POSITION_TARGET_LOCAL_NED"}
    assert ok.max_cmd_speed <= RO_SPEED_LIM + 1e-6
    closest = [float(np.min(np.linalg.norm(ok.pos_offboard - w, axis=1))) for w in wps]
    print("closest approach to each waypoint [m]:", [round(c, 2) for c in closest])
    assert max(closest) <= NAV_ACC_RAD, closest
    assert ok.last_mode == HOLD and ok.disarmed_at_end
    assert ok.report["result"] == "ok" and ok.report["waypoints_reached"] == len(wps)
    # the stuck rover: switched to Hold once its reference had waited ROVER_SETTLE_S for it,
    # disarmed, and the flight reported failed with the waypoints it missed (exit 1)
    assert stuck.code == 1, stuck.output[-3000:]
    assert "no progress" in stuck.output
    far = [float(np.min(np.linalg.norm(stuck.pos_offboard - w, axis=1))) for w in wps]
    assert min(far) > NAV_ACC_RAD
    assert stuck.last_mode == HOLD and stuck.disarmed_at_end
    assert str(stuck.report["result"]).startswith("missed 2 waypoint(s)")
    # started away from the planned home: the file's waypoints sit at wps - away_ne in its
    # local frame, and it drove through them (moved with it, they would be 2.5 m off)
    assert away.code == 0, away.output[-3000:]
    geo = [float(np.min(np.linalg.norm(away.pos_offboard - (w - away_ne), axis=1)))
           for w in wps]
    print("started away: closest approach to each waypoint [m]:", [round(c, 2) for c in geo])
    assert max(geo) <= NAV_ACC_RAD, geo
