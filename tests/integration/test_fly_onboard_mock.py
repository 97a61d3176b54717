"""`python -m companion fly MISSION --onboard --connect udpin://...` against `sitl_mock serve
--onboard` (the mock hosting the onboard module's C behind the PX4 module's MAVLink protocol),
real UDP on loopback, judged from the companion's .tlog and report:

- the flight exits 0 with every waypoint reached, and the companion sent no
  SET_ATTITUDE_TARGET / SET_POSITION_TARGET_LOCAL_NED while the vehicle was in OFFBOARD
  (`companion.aio.tlog.offboard_setpoints`, what bench/tlog_setpoints.py prints);
- against a mock without the module, `fly --onboard` exits 2 having sent nothing but its
  status queries (no upload, no mode change, no arming, no setpoint).

The module runs on the mock's clock, so the mock runs at 4x real time (the companion follows
the module's reports; its judgement uses the autopilot's time stamps)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from pymavlink import mavutil

from companion.aio.tlog import offboard_setpoints
from companion.onboard.protocol import OP_STATUS, PROTO_NAME
from tests.support.mock_process import run_companion, run_mock

# flies in wall-clock time (the mock served over a link): README's second test phase
pytestmark = pytest.mark.realtime

MISSION = Path(__file__).parents[1] / "data" / "missions" / "px4_short.plan"
SPEED = 4.0


def _sent_by_companion(tlog: Path) -> list[object]:
    """Every message in the tlog that the vehicle (component 1) did not send."""
    conn = mavutil.mavlink_connection(str(tlog))
    out = []
    try:
        for _ in range(2_000_000):
            msg = conn.recv_match()
            if msg is None:
                break
            if msg.get_srcComponent() != 1:
                out.append(msg)
    finally:
        conn.close()
    return out


async def test_fly_onboard_flies_the_mission_with_no_setpoint_sent(tmp_path: Path) -> None:
    tlog = tmp_path / "onboard.tlog"
    async with run_mock("--estimator-ready", "0.5", "--onboard", speed=SPEED) as mock:
        assert mock.ready_line.rstrip().endswith("onboard")
        code, text = await run_companion(
            "fly", str(MISSION), "--onboard",
            "--connect", f"udpin://127.0.0.1:{mock.client_port}", "--log", str(tlog),
            timeout_s=90.0, what="the onboard flight")
    assert code == 0, text[-3000:]
    report = json.loads(Path(f"{tlog}.report.json").read_text())
    assert report["result"] == "ok" and report["mode"] == "onboard"
    assert report["waypoints_reached"] == len(report["waypoints"]) > 0
    setpoints, offboard_heartbeats = offboard_setpoints(tlog)
    assert offboard_heartbeats > 0, "the vehicle was never in OFFBOARD"
    assert setpoints == 0
    parts = [m for m in _sent_by_companion(tlog) if m.get_type() == "DEBUG_FLOAT_ARRAY"]
    assert {m.array_id for m in parts} >= {1, 2, 3}  # BEGIN, SEGMENT(s), COMMIT were sent


async def test_fly_onboard_without_the_module_exits_2_having_sent_only_queries(
        tmp_path: Path) -> None:
    tlog = tmp_path / "nomodule.tlog"
    async with run_mock("--estimator-ready", "0.5", speed=SPEED) as mock:
        code, text = await run_companion(
            "fly", str(MISSION), "--onboard",
            "--connect", f"udpin://127.0.0.1:{mock.client_port}", "--log", str(tlog),
            timeout_s=60.0, what="fly --onboard without a module")
    assert code == 2, text[-3000:]
    assert "no onboard module answers" in text
    sent = _sent_by_companion(tlog)
    queries = [m for m in sent if m.get_type() == "DEBUG_FLOAT_ARRAY"]
    assert queries and all(m.array_id == OP_STATUS and m.name == PROTO_NAME for m in queries)
    kinds = {m.get_type() for m in sent}
    assert not kinds & {"SET_ATTITUDE_TARGET", "SET_POSITION_TARGET_LOCAL_NED", "COMMAND_LONG",
                        "COMMAND_INT", "MISSION_COUNT", "PARAM_SET"}, kinds
