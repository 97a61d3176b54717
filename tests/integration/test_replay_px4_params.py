"""`replay` plans with the PX4 parameters it reads from the mock over MAVLink, as `fly` reads
them from PX4: `--mock-param` on a planning parameter changes the plan in the right direction,
and the report says which values were used."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from companion.app.cli import main as cli_main
from companion.mission.px4_params import PLANNING_PARAM_NAMES
from companion.replay.runner import ReplayConfig, prepare_mission, read_mock_params
from sitl_mock.params import PARAMS

ROOT = Path(__file__).resolve().parents[2]
SQUARE = ROOT / "examples" / "missions" / "square.plan"
HOME = (47.397742, 8.545594, 488.0)


def _takeoff_s(prep: object) -> float:
    pieces = prep.schedule.pieces  # type: ignore[attr-defined]
    return sum(p.duration_s for p in pieces if p.phase == "takeoff")


def test_the_companion_reads_the_mocks_values_over_mavlink() -> None:
    """Oracle: the mock's own parameter table (sitl_mock/params.py) and the changed value."""
    done = read_mock_params(ReplayConfig(mock_params=(("MPC_Z_VEL_MAX_DN", 2.5),)), HOME)
    assert done.ok and set(done.values) == set(PLANNING_PARAM_NAMES)
    assert done.values["MPC_Z_VEL_MAX_DN"] == 2.5
    for name in PLANNING_PARAM_NAMES:
        if name != "MPC_Z_VEL_MAX_DN":
            assert done.values[name] == pytest.approx(PARAMS[name].default, rel=1e-6), name
    assert done.attempts == len(PLANNING_PARAM_NAMES)  # one request each, no retries needed


def test_a_name_the_mock_does_not_have_is_reported_missing_after_two_passes() -> None:
    done = read_mock_params(ReplayConfig(), HOME, ("MPC_XY_CRUISE", "MPC_NO_SUCH_P"))
    assert done.missing == ("MPC_NO_SUCH_P",) and set(done.values) == {"MPC_XY_CRUISE"}
    assert done.attempts == 1 + 3 + 3  # three tries in each pass


def test_faster_takeoff_on_the_mock_shortens_the_planned_takeoff() -> None:
    base = prepare_mission(SQUARE, ReplayConfig())
    quick = prepare_mission(SQUARE, ReplayConfig(mock_params=(("MPC_TKO_SPEED", 3.0),)))
    assert base.px4 is not None and quick.px4 is not None
    assert base.px4.params.MPC_TKO_SPEED == 1.5 and quick.px4.params.MPC_TKO_SPEED == 3.0
    assert quick.px4.source["MPC_TKO_SPEED"] == "vehicle"
    assert _takeoff_s(quick) < _takeoff_s(base)
    assert quick.schedule.duration_s < base.schedule.duration_s


def test_replay_mock_param_on_cruise_speed_changes_the_plan_and_the_report(
        tmp_path: Path) -> None:
    """The CLI path: a faster MPC_XY_CRUISE (the square's first legs fly at the default cruise
    speed) gives a shorter planned duration than the same mission planned at PX4's default."""
    base = prepare_mission(SQUARE, ReplayConfig())
    code = cli_main(["replay", str(SQUARE), "--out", str(tmp_path),
                     "--mock-param", "MPC_XY_CRUISE=10"])
    assert code == 0
    report = json.loads((tmp_path / "square" / "report.json").read_text())
    assert report["px4_params"]["MPC_XY_CRUISE"] == {"value": 10.0, "source": "vehicle"}
    assert report["px4_params"]["NAV_ACC_RAD"]["value"] == PARAMS["NAV_ACC_RAD"].default
    assert report["planned_duration_s"] < base.schedule.duration_s - 1.0
