"""`replay` and the geofence: a plan whose trajectory crosses an exclusion zone is refused with
exit 2 naming the leg's mission items (nothing flown, no output folder); a fenced plan that stays
inside flies "ok" with per-leg figures; a flight that breaches the fence (blown east of its leg by
a 9 m/s crosswind, more than the tilt limit holds, over a zone the plan clears by 1 m) is a
failed result with exit 1, the breach confirmed from the tlog's own GLOBAL_POSITION_INT; a
vehicle started 6 m east of the planned home still flies the file's own legs (planned from where
it stands), clear of a zone 3 m east of them."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from pymavlink import mavutil

from companion.app.cli import main as cli_main
from tests.support.fence_plans import HOME, box, write_plan

R_EARTH = 6_371_000.0
# the leg item 2 (60, 0) -> item 3 (60, 40) at 10 m; no landing (the flight ends hovering)
POINTS = [(60.0, 0.0), (60.0, 40.0)]
# 3..9 m east of the north-bound leg item 1 -> item 2, between north 20 and 40
SIDE_BOX = box(20.0, 40.0, 3.0, 9.0)
# the same, from 1 m east of the leg
NEAR_BOX = box(20.0, 40.0, 1.0, 9.0)


def _flown_ne(tlog: Path) -> np.ndarray:
    """(north, east) [m] about the planned home from the tlog's GLOBAL_POSITION_INT
    (equirectangular projection, independent of the companion's)."""
    mlog = mavutil.mavlink_connection(str(tlog))
    out = []
    try:
        for _ in range(1_000_000):
            m = mlog.recv_match(type="GLOBAL_POSITION_INT")
            if m is None:
                break
            out.append((math.radians(m.lat * 1e-7 - HOME[0]) * R_EARTH,
                        math.radians(m.lon * 1e-7 - HOME[1]) * R_EARTH
                        * math.cos(math.radians(HOME[0]))))
    finally:
        mlog.close()
    return np.asarray(out)


def test_plan_crossing_an_exclusion_zone_is_refused_with_exit_2(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    plan = write_plan(tmp_path / "cross.plan", POINTS, land=False,
                      polygons=[(False, box(50.0, 70.0, 20.0, 34.0))])
    out = tmp_path / "out"
    code = cli_main(["replay", str(plan), "--out", str(out)])
    err = " ".join(capsys.readouterr().err.split())
    assert code == 2
    assert "the leg from item 2 to item 3 crosses exclusion polygon 0 for 14 m" in err, err
    assert "refusing to fly" in err
    assert not (out / "cross").exists()


def test_fenced_plan_inside_flies_ok_with_per_leg_figures(tmp_path: Path) -> None:
    plan = write_plan(tmp_path / "inside.plan", POINTS, land=False,
                      polygons=[(True, box(-10.0, 70.0, -10.0, 50.0)), (False, SIDE_BOX)])
    out = tmp_path / "out"
    assert cli_main(["replay", str(plan), "--out", str(out)]) == 0
    report = json.loads((out / "inside" / "report.json").read_text())
    assert report["result"] == "ok" and report["ok"] is True
    assert report["geofence_breaches"] == [] and report["geofence_violations"] == 0
    legs = report["legs"]
    assert [(g["from_item"], g["to_item"]) for g in legs] == [(None, 1), (1, 2), (2, 3)]
    for g in legs:
        assert g["time_s"] > 0 and g["max_deviation_m"] >= g["rms_deviation_m"] >= 0
        # the time-optimal bound is a lower bound: the flown leg is not quicker (up to the
        # passage detection's sample spacing)
        assert g["bound_s"] > 0 and g["time_over_bound"] >= 0.98, g
    # the 60 m leg north: the flown mean speed is below its 5 m/s cruise speed, and reaches it
    north = legs[1]
    assert north["cruise_speed_m_s"] == pytest.approx(5.0)
    assert 2.0 < north["mean_speed_m_s"] < 5.0 <= north["max_speed_m_s"] + 0.2
    # independent deviation: flown positions (tlog) on that leg are within max_deviation_m of
    # the line east = 0 (north 5..55, away from the corners)
    ne = _flown_ne(out / "inside" / "flight.tlog")
    mid = ne[(ne[:, 0] > 5.0) & (ne[:, 0] < 55.0) & (np.abs(ne[:, 1]) < 5.0)]
    assert len(mid) > 50
    assert float(np.max(np.abs(mid[:, 1]))) <= north["max_deviation_m"] + 0.05


def test_flight_breaching_the_fence_fails_with_exit_1(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    plan = write_plan(tmp_path / "blown.plan", POINTS, land=False,
                      polygons=[(False, NEAR_BOX)])
    out = tmp_path / "out"
    # 9 m/s from the west: holding against it takes 42.5 deg of the 45 deg limit, so the
    # north-bound leg is flown 1.3-1.7 m east of its line (the plan itself clears the box)
    code = cli_main(["replay", str(plan), "--out", str(out), "--wind", "9", "--wind-from", "270"])
    text = " ".join(capsys.readouterr().out.split())
    assert code == 1
    report = json.loads((out / "blown" / "report.json").read_text())
    assert report["ok"] is False
    assert report["result"].startswith(
        "geofence breach: the leg from item 1 to item 2 crosses exclusion polygon 0"), report
    assert report["waypoints_reached"] == len(report["waypoints"])  # otherwise a clean flight
    (b,) = report["geofence_breaches"]
    assert (b["from_item"], b["to_item"], b["zone"]) == (1, 2, "exclusion polygon 0")
    assert b["length_m"] == pytest.approx(20.0, abs=2.0)  # box north 20..40
    assert "geofence breach" in text
    # the tlog says the vehicle really was inside the box
    ne = _flown_ne(out / "blown" / "flight.tlog")
    inside = ((ne[:, 0] > 20.0) & (ne[:, 0] < 40.0) & (ne[:, 1] > 1.0) & (ne[:, 1] < 9.0))
    assert inside.sum() > 10


def test_a_vehicle_started_away_from_the_planned_home_flies_the_files_own_legs(
        tmp_path: Path) -> None:
    plan = write_plan(tmp_path / "shifted.plan", POINTS, land=False,
                      polygons=[(False, SIDE_BOX)])
    out = tmp_path / "out"
    assert cli_main(["replay", str(plan), "--out", str(out), "--start-offset", "0,6"]) == 0
    report = json.loads((out / "shifted" / "report.json").read_text())
    assert report["result"] == "ok" and report["geofence_breaches"] == []
    # the file's own waypoints (geodetic), not ones moved 6 m east with the vehicle
    assert report["max_waypoint_miss_geo_m"] < 0.5
    ne = _flown_ne(out / "shifted" / "flight.tlog")
    assert np.hypot(ne[0, 0], ne[0, 1] - 6.0) < 0.5  # it started 6 m east of the planned home
    leg = ne[(ne[:, 0] > 5.0) & (ne[:, 0] < 55.0) & (np.abs(ne[:, 1]) < 3.0)]
    assert len(leg) > 50  # the north-bound leg, on the file's line east = 0
    assert float(np.max(np.abs(leg[:, 1]))) < 0.5


def test_campaign_refuses_a_fence_crossing_plan_before_any_run(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    plan = write_plan(tmp_path / "cross.plan", POINTS, land=False,
                      polygons=[(False, box(50.0, 70.0, 20.0, 34.0))])
    out = tmp_path / "camp"
    code = cli_main(["campaign", str(plan), "--runs", "2", "--workers", "1", "--out", str(out)])
    text = " ".join(capsys.readouterr().out.split())
    assert code == 2
    assert "the leg from item 2 to item 3 crosses exclusion polygon 0" in text, text
    assert not (out / "runs.jsonl").exists()


def test_time_optimal_bounds_given_to_the_replay_appear_per_leg_and_per_flight(
        tmp_path: Path) -> None:
    import dataclasses

    from companion.planning.legs import plan_legs
    from companion.replay.runner import ReplayConfig, prepare_mission, run_prepared

    plan = write_plan(tmp_path / "b.plan", POINTS, land=False)
    config = ReplayConfig()
    prep = prepare_mission(plan, config)
    assert prep.flight_plan is not None
    n = len(plan_legs(prep.flight_plan))
    bounds = tuple([None] + [4.0] * (n - 1))
    prep = dataclasses.replace(prep, leg_bounds_s=bounds, bound_s=20.0)
    rep = run_prepared(prep, config, None).report
    assert rep.bound_s == 20.0
    assert rep.planned_over_bound == pytest.approx(rep.planned_duration_s / 20.0, rel=1e-3)
    legs = rep.legs
    assert legs is not None
    assert legs[0]["bound_s"] is None and legs[0]["time_over_bound"] is None
    for g in legs[1:]:
        assert g["bound_s"] == 4.0
        assert g["time_over_bound"] == pytest.approx(g["time_s"] / 4.0, abs=1e-3)
