"""companion.mission.convert on the bundled missions: the vehicle's downloaded mission becomes
the same model (and the same flight plan) as the file it was uploaded from, without a detour
through QGC WPL text; QGC WPL written from a model reads back to it; the one error hierarchy."""

from __future__ import annotations

import pickle
from pathlib import Path

import pytest

from companion.aio import MissionTransferError, VehicleError
from companion.mavlink import MissionResult, WireMissionItem
from companion.mission import (
    Mission,
    MissionError,
    geofence_from_wire,
    load_mission,
    loads_mission,
    mission_from_wire,
    mission_to_flight_plan,
    mission_to_wpl,
    mission_upload_items,
)

ROOT = Path(__file__).resolve().parents[3]
EXAMPLES = ROOT / "examples" / "missions"
DATA = ROOT / "tests" / "data" / "missions"


def _waypoints(m: Mission) -> list[tuple[object, ...]]:
    fp = mission_to_flight_plan(m)
    return [(tuple(round(v, 2) for v in w.pos_ned_m), w.phase, w.stop, w.hold_s, w.speed_m_s)
            for w in fp.waypoints]


@pytest.mark.parametrize("name", ["hold_and_jump.plan", "square.plan", "survey.plan"])
def test_downloaded_mission_flies_like_its_file(name: str) -> None:
    m = load_mission(EXAMPLES / name)
    back = mission_from_wire(mission_upload_items(m), m.home)
    assert back.file_format == "wire" and str(back.source) == "vehicle mission"
    assert _waypoints(back) == _waypoints(m)


def test_downloaded_do_jump_targets_the_same_item() -> None:
    # DO_JUMP carries the target's 0-based seq on the wire; the model holds the target's index
    m = load_mission(EXAMPLES / "hold_and_jump.plan")
    wire = mission_upload_items(m)
    (jump,) = [w for w in wire if w.command == 177]
    back = mission_from_wire(wire, m.home)
    (jump_item,) = [it for it in back.items if it.command == 177]
    target = next(it for it in back.items if it.index == int(jump_item.params[0]))
    assert target.index == int(jump.param1) + 1
    assert target.command == wire[int(jump.param1)].command == 16


def test_wire_errors_name_the_item_and_its_seq() -> None:
    m = load_mission(EXAMPLES / "square.plan")
    wire = list(mission_upload_items(m))
    bad = wire[2]
    wire[2] = WireMissionItem(bad.seq, 11, bad.command, bad.current, bad.autocontinue,
                              bad.param1, bad.param2, bad.param3, bad.param4, bad.x, bad.y, bad.z)
    with pytest.raises(MissionError) as exc:
        mission_from_wire(wire, m.home)
    assert exc.value.item == 3
    assert str(exc.value).startswith("vehicle mission: item 3: frame 11 (terrain)")
    assert str(exc.value).endswith("(seq 2)")


def test_malformed_vehicle_fence_is_a_mission_error() -> None:
    m = load_mission(EXAMPLES / "square.plan")
    vertex = WireMissionItem(0, 5, 5001, 0, 1, 4.0, 0.0, 0.0, 0.0, 473977420, 85455940, 0.0, 1)
    with pytest.raises(MissionError, match="polygon of 4 vertices is incomplete"):
        geofence_from_wire([vertex, vertex], m.home)


@pytest.mark.parametrize("path", [EXAMPLES / "hold_and_jump.plan", EXAMPLES / "survey.plan",
                                  EXAMPLES / "square.waypoints", DATA / "all_commands.plan"])
def test_wpl_written_from_a_model_reads_back_to_it(path: Path) -> None:
    m = load_mission(path)
    back = loads_mission(mission_to_wpl(m), source="back.waypoints")
    assert back.home == m.home
    strip = [(it.index, it.command, it.frame, it.autocontinue, repr(it.params)) for it in m.items]
    assert [(it.index, it.command, it.frame, it.autocontinue, repr(it.params))
            for it in back.items] == strip


def test_transfer_error_is_a_vehicle_error_and_a_mission_error() -> None:
    err = MissionTransferError("upload", MissionResult.TIMEOUT, None, "no answer")
    assert isinstance(err, VehicleError) and isinstance(err, MissionError)
    assert str(err) == "mission upload failed: timeout (no answer)"
    back = pickle.loads(pickle.dumps(err))
    assert type(back) is MissionTransferError and str(back) == str(err)
    assert (back.operation, back.result, back.mav_result) == ("upload", MissionResult.TIMEOUT,
                                                              None)
