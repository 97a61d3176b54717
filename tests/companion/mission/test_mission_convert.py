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


@pytest.mark.parametrize("north_east", [(4.0, -3.0), (0.0, 250.0)])
def test_rehomed_mission_equals_the_file_loaded_about_that_home(
        north_east: tuple[float, float]) -> None:
    """`rehome_mission` against the parser's own home override (`load_mission(home=...)`, which
    projects fence and rally points while reading the file): the same fence, rally points and
    flight plan, every position item at its own coordinates."""
    import numpy as np

    from companion.mission import GeoPoint, mission_to_flight_plan, ned_to_geodetic, rehome_mission

    path = DATA / "geofence.plan"
    m = load_mission(path)
    lat, lon, _ = ned_to_geodetic(np.array([*north_east, 0.0]), m.home)
    moved = rehome_mission(m, float(lat), float(lon))
    ref = load_mission(path, home=GeoPoint(float(lat), float(lon), m.home.alt_amsl_m))
    assert moved.home == ref.home and moved.items == ref.items
    for got, want in zip(moved.geofence.polygons, ref.geofence.polygons, strict=True):
        assert got.vertices_deg == want.vertices_deg
        np.testing.assert_allclose(got.vertices_ne_m, want.vertices_ne_m, atol=1e-9)
    for gc, wc in zip(moved.geofence.circles, ref.geofence.circles, strict=True):
        np.testing.assert_allclose(gc.center_ne_m, wc.center_ne_m, atol=1e-9)
    assert len(moved.rally) == len(ref.rally) == 2
    for gr, wr in zip(moved.rally, ref.rally, strict=True):
        np.testing.assert_allclose(gr.pos_ned_m, wr.pos_ned_m, atol=1e-9)
    got_pts = mission_to_flight_plan(moved).points_ned_m()
    np.testing.assert_allclose(got_pts, mission_to_flight_plan(ref).points_ned_m(), atol=1e-9)
    # the climb starts at the new home, then every point of the file keeps its place (moved by
    # minus the new home's offset), the takeoff item's own coordinates first (the file's home)
    old_pts = mission_to_flight_plan(m).points_ned_m()
    np.testing.assert_allclose(got_pts[:2, :2], 0.0, atol=1e-12)
    # (PX4's projection about another centre: a centimetre over 250 m)
    np.testing.assert_allclose(got_pts[2:, :2], old_pts[1:, :2] - np.array(north_east),
                               atol=0.02)
