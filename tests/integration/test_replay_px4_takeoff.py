"""`replay --compare-px4-mission` with a TAKEOFF item away from home: the mock's AUTO.MISSION
flies to the takeoff point like PX4, and a waypoint AUTO.MISSION misses fails the replay (the
PX4 row and `px4_mission.result` say which, exit code 1) instead of passing as "ok"."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import pytest

import companion.replay.runner
from companion.app.cli import main as cli_main
from companion.mission import load_mission

ROOT = Path(__file__).resolve().parents[2]
SQUARE = ROOT / "examples" / "missions" / "square.plan"
R_EARTH = 6_371_000.0
TKO_N, TKO_E = 6.0, -4.0  # the takeoff point, 7.2 m from home [m]


def _offset_takeoff_plan(folder: Path) -> Path:
    """square.plan with its TAKEOFF item moved TKO_N north, TKO_E east of home."""
    doc = json.loads(SQUARE.read_text())
    lat0, lon0, _ = doc["mission"]["plannedHomePosition"]
    takeoff = next(it for it in doc["mission"]["items"] if it.get("command") == 22)
    takeoff["params"][4] = lat0 + math.degrees(TKO_N / R_EARTH)
    takeoff["params"][5] = lon0 + math.degrees(TKO_E / (R_EARTH * math.cos(math.radians(lat0))))
    path = folder / "offset_takeoff.plan"
    path.write_text(json.dumps(doc))
    return path


def _takeoff_point(report: dict[str, Any]) -> dict[str, Any]:
    """The report's waypoint at the takeoff point (the one nearest to it)."""
    return min(report["waypoints"],
               key=lambda w: math.hypot(w["north_m"] - TKO_N, w["east_m"] - TKO_E))


def test_auto_mission_flies_to_a_takeoff_point_away_from_home(tmp_path: Path) -> None:
    plan = _offset_takeoff_plan(tmp_path)
    code = cli_main(["replay", str(plan), "--compare-px4-mission", "--out", str(tmp_path)])
    report = json.loads((tmp_path / plan.stem / "report.json").read_text())
    px4 = report["px4_mission"]
    wp = _takeoff_point(px4)
    assert math.hypot(wp["north_m"] - TKO_N, wp["east_m"] - TKO_E) < 0.1
    assert wp["closest_approach_m"] <= wp["acceptance_radius_m"]
    assert px4["result"] == "ok"
    assert px4["waypoints_reached"] == len(px4["waypoints"])
    assert code == 0


def test_a_waypoint_auto_mission_misses_fails_the_replay(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """AUTO.MISSION is given the square with its takeoff at home, so it never goes to the
    offset takeoff point the companion flies: the comparison must say so and fail."""
    plan = _offset_takeoff_plan(tmp_path)
    real = companion.replay.runner.fly_px4_mission
    at_home = load_mission(SQUARE)

    def fly_takeoff_at_home(config: Any, _mission: Any, home: Any, hint: float) -> Any:
        return real(config, at_home, home, hint)

    monkeypatch.setattr(companion.replay.runner, "fly_px4_mission", fly_takeoff_at_home)
    code = cli_main(["replay", str(plan), "--compare-px4-mission", "--out", str(tmp_path)])
    out = capsys.readouterr().out
    report = json.loads((tmp_path / plan.stem / "report.json").read_text())
    px4 = report["px4_mission"]
    wp = _takeoff_point(px4)
    assert wp["closest_approach_m"] > wp["acceptance_radius_m"]
    assert px4["result"].startswith("missed 1 waypoint(s): item ")
    assert f"item {wp['item_index']} by" in px4["result"]
    assert px4["ok"] is False
    assert report["result"] == "ok"  # the companion's own flight did reach it
    row = " ".join(ln for ln in out.splitlines() if "PX4 AUTO.MISSION" in ln)
    assert "missed" in row and " ok " not in row
    assert code == 1
