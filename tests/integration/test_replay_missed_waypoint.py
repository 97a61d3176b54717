"""A replay that passes a waypoint outside its acceptance radius is a failed flight in every
place it is reported: report.json's `result` names the miss (it said "ok" beside `ok: false`,
and a campaign's row copied that "ok"), and the exit code is 1. The miss is confirmed from the
tlog's own GLOBAL_POSITION_INT, independent of the companion's judge."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from pymavlink import mavutil

from companion.app.cli import main as cli_main

ROOT = Path(__file__).resolve().parents[2]
R_EARTH = 6_371_000.0
#: the acceptance radius [m] given to item 2 (a corner flown through, not stopped at): tighter
#: than any tracking error of the mock, so the flight must miss it
TIGHT_M = 0.002


def _closest_approach(tlog: Path, lat: float, lon: float, home_lat: float) -> float:
    """Closest horizontal approach [m] of the tlog's GLOBAL_POSITION_INT to (lat, lon) [deg]."""
    mlog = mavutil.mavlink_connection(str(tlog))
    best = math.inf
    try:
        for _ in range(1_000_000):
            m = mlog.recv_match(type="GLOBAL_POSITION_INT")
            if m is None:
                break
            dn = math.radians(m.lat * 1e-7 - lat) * R_EARTH
            de = math.radians(m.lon * 1e-7 - lon) * R_EARTH * math.cos(math.radians(home_lat))
            best = min(best, math.hypot(dn, de))
    finally:
        mlog.close()
    return best


def test_a_waypoint_passed_outside_its_radius_fails_the_result_and_the_exit_code(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    plan = json.loads((ROOT / "examples" / "missions" / "square.plan").read_text())
    items = plan["mission"]["items"]
    items[2]["params"][1] = TIGHT_M
    src = tmp_path / "tight.plan"
    src.write_text(json.dumps(plan))
    out = tmp_path / "out"
    code = cli_main(["replay", str(src), "--out", str(out)])
    report = json.loads((out / "tight" / "report.json").read_text())
    home_lat = float(plan["mission"]["plannedHomePosition"][0])
    lat, lon = float(items[2]["params"][4]), float(items[2]["params"][5])
    miss = _closest_approach(out / "tight" / "flight.tlog", lat, lon, home_lat)
    assert TIGHT_M < miss < 1.0, miss  # missed, by the tlog; the rest of the flight was fine
    assert report["ok"] is False
    # items are numbered as QGroundControl shows them (the .plan's first item is item 1)
    head = "missed 1 waypoint(s): item 3 by "
    assert report["result"].startswith(head) and report["result"].endswith(" m"), report["result"]
    # the companion's closest approach, against the tlog's (GLOBAL_POSITION_INT: 1e-7 deg, ~1 cm,
    # sampled less often than the companion's own log)
    assert float(report["result"][len(head):-2]) == pytest.approx(miss, abs=0.02)
    reached = [w["reached"] for w in report["waypoints"]]
    assert reached.count(False) == 1
    assert code == 1
    row = next(ln for ln in capsys.readouterr().out.splitlines() if "│ tight.plan" in ln)
    assert "│ missed 1" in row and "│ ok" not in row, row  # the summary table's result cell
    assert np.isfinite(report["rms_error_m"])
