"""Geofence check of the planned trajectory and of flown positions: breaches named by the leg's
mission items, lengths against the zone's own geometry, and a corner the planner cuts through a
zone that the straight legs clear (only the dense check of the trajectory sees it)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from companion.mavlink.mission_client import WireMissionItem
from companion.mavlink.telemetry import HomePosition
from companion.mission import (
    FlightPlan,
    GeoPoint,
    MissionError,
    geofence_from_wire,
    load_mission,
    mission_to_flight_plan,
)
from companion.planning.fence_check import (
    CHECK_DT_S,
    CHECK_STEP_M,
    flown_breaches,
    plan_breaches,
    require_plan_inside,
    sample_schedule,
)
from companion.planning.schedule import Schedule, build_schedule
from companion.replay.runner import DEFAULT_QUAD
from companion.serve.program import plan_program
from companion.serve.service import ServeService, ServiceConfig
from tests.support.fence_plans import HOME, box, latlon, write_plan

EXAMPLES = Path(__file__).resolve().parents[3] / "examples" / "missions"


def _planned(path: Path) -> tuple[FlightPlan, Schedule]:
    fp = mission_to_flight_plan(load_mission(path))
    return fp, build_schedule(fp, DEFAULT_QUAD)


def test_exclusion_box_across_a_leg_is_named_by_both_items_with_its_width(
        tmp_path: Path) -> None:
    # leg item 2 (60, 0) -> item 3 (60, 60) runs east at north 60; the box spans east 20..34
    plan = write_plan(tmp_path / "cross.plan", [(60, 0), (60, 60)],
                      polygons=[(False, box(50, 70, 20, 34))])
    fp, sched = _planned(plan)
    found = plan_breaches(fp, sched)
    assert [(b.leg.start_item, b.leg.end_item, b.zone) for b in found] == [
        (2, 3, "exclusion polygon 0")]
    # the box is 14 m wide along the leg; the path is sampled at most 0.5 m apart
    assert found[0].length_m == pytest.approx(14.0, abs=2 * CHECK_STEP_M)
    assert 20.0 - CHECK_STEP_M <= found[0].first_ned_m[1] <= 20.0 + CHECK_STEP_M
    with pytest.raises(MissionError) as exc:
        require_plan_inside(fp, sched)
    assert re.search(r"the leg from item 2 to item 3 crosses exclusion polygon 0 for 1[345] m",
                     str(exc.value)), str(exc.value)
    assert str(exc.value).startswith(str(plan))


def test_leaving_the_inclusion_zone_names_the_leg_that_leaves(tmp_path: Path) -> None:
    # inclusion box north -5..45, east -5..65: the leg item 2 (40, 0) -> item 3 (80, 0) leaves it
    plan = write_plan(tmp_path / "out.plan", [(40, 0), (80, 0)],
                      polygons=[(True, box(-5, 45, -5, 65))])
    fp, sched = _planned(plan)
    found = plan_breaches(fp, sched)
    zones = {(b.leg.start_item, b.leg.end_item, b.zone) for b in found}
    assert (2, 3, "inclusion") in zones
    assert all(b.zone == "inclusion" for b in found)
    leg23 = next(b for b in found if (b.leg.start_item, b.leg.end_item) == (2, 3))
    assert leg23.length_m == pytest.approx(35.0, abs=2 * CHECK_STEP_M)  # north 45 -> 80
    assert "leaves every inclusion zone" in leg23.message


def test_plan_inside_its_fence_passes(tmp_path: Path) -> None:
    # legs: north along east 0, east along north 60, back diagonally to home; the exclusion
    # box sits 5 m east of the diagonal
    plan = write_plan(tmp_path / "inside.plan", [(60, 0), (60, 60)],
                      polygons=[(True, box(-10, 70, -10, 70)), (False, box(20, 40, 45, 60))],
                      circles=[(False, (-30.0, -30.0), 10.0)])
    fp, sched = _planned(plan)
    assert plan_breaches(fp, sched) == []
    require_plan_inside(fp, sched)  # no exception
    fp2, sched2 = _planned(EXAMPLES / "survey.plan")  # the bundled fenced example
    assert not fp2.geofence.empty
    assert plan_breaches(fp2, sched2) == []


def test_corner_cut_through_a_zone_the_straight_legs_clear_is_refused(tmp_path: Path) -> None:
    pts = [(40.0, 0.0), (40.0, 40.0)]
    plain = write_plan(tmp_path / "corner.plan", pts)
    _fp, sched = _planned(plain)
    _t, p = sample_schedule(sched)
    corner = np.array([40.0, 0.0])
    near = np.linalg.norm(p[:, :2] - corner, axis=1) < 5.0
    # distance of the planned path to the two straight legs near the corner (independent of
    # companion.planning.legs: the legs are the lines east = 0 and north = 40 there)
    dev = np.minimum(np.abs(p[near, 1]), np.abs(p[near, 0] - 40.0))
    k = int(np.argmax(dev))
    assert dev[k] > 0.3, "precondition: the plan cuts the corner"
    centre = p[near][k, :2]
    r = 0.4 * float(dev[k])  # clears both straight legs by 0.6 dev
    fenced = write_plan(tmp_path / "corner_fenced.plan", pts,
                        circles=[(False, (float(centre[0]), float(centre[1])), r)])
    fp2, sched2 = _planned(fenced)
    assert not any("geofence" in w for w in fp2.warnings)  # the straight-leg check sees nothing
    found = plan_breaches(fp2, sched2)
    assert found and found[0].zone == "exclusion circle 0"
    assert {(b.leg.start_item, b.leg.end_item) for b in found} <= {(1, 2), (2, 3)}
    with pytest.raises(MissionError, match="crosses exclusion circle 0"):
        require_plan_inside(fp2, sched2)


def test_schedule_is_sampled_densely_in_time_and_space_within_the_budget() -> None:
    _fp, sched = _planned(EXAMPLES / "survey.plan")
    t, p = sample_schedule(sched)
    assert t[0] == 0.0 and t[-1] == pytest.approx(sched.duration_s)
    assert np.all(np.diff(t) > 0) and np.max(np.diff(t)) <= CHECK_DT_S + 1e-9
    assert np.max(np.linalg.norm(np.diff(p, axis=0), axis=1)) <= CHECK_STEP_M + 1e-6
    t2, _p2 = sample_schedule(sched, max_samples=1000)
    assert len(t2) <= 1000 and t2[-1] == pytest.approx(sched.duration_s)
    # coarser, but still spread over the whole flight
    assert np.max(np.diff(t2)) <= 2.5 * sched.duration_s / 1000


def test_flown_positions_through_an_exclusion_zone_are_a_breach_on_their_leg(
        tmp_path: Path) -> None:
    # the plan keeps 5 m west of the exclusion box; the synthetic flight drifts 8 m east on
    # the leg item 2 -> item 3 (north 0 -> 60 at east 0.5); no landing (it ends hovering)
    plan = write_plan(tmp_path / "drift.plan", [(0, 0.5), (60, 0.5), (60, 30)],
                      polygons=[(False, box(20, 40, 5.5, 15))], land=False)
    fp, sched = _planned(plan)
    assert plan_breaches(fp, sched) == []
    t, planned = sample_schedule(sched)
    flown = planned.copy()
    on_leg = (planned[:, 0] > 2.0) & (planned[:, 0] < 58.0) & (planned[:, 1] < 3.0)
    flown[on_leg, 1] += 8.0 * np.sin(np.pi * (planned[on_leg, 0] - 2.0) / 56.0)
    found = flown_breaches(fp, t, flown)
    assert [(b.leg.start_item, b.leg.end_item, b.zone) for b in found] == [
        (2, 3, "exclusion polygon 0")]
    # independent length: flown path inside the box, from the samples themselves
    inside = ((flown[:, 0] >= 20) & (flown[:, 0] <= 40) & (flown[:, 1] >= 5.5)
              & (flown[:, 1] <= 15))
    idx = np.flatnonzero(inside)
    seg = np.linalg.norm(np.diff(flown[idx[0]:idx[-1] + 1], axis=0), axis=1).sum()
    assert found[0].length_m == pytest.approx(seg, abs=1.0)
    assert flown_breaches(fp, t, planned) == []


def _fence_items(polygons: list[tuple[bool, list[tuple[float, float]]]],
                 circles: list[tuple[bool, tuple[float, float], float]]) -> list[WireMissionItem]:
    items: list[WireMissionItem] = []
    for inc, verts in polygons:
        for v in verts:
            lat, lon = latlon(v)
            items.append(WireMissionItem(len(items), 0, 5001 if inc else 5002, 0, 1,
                                     float(len(verts)), 0.0, 0.0, 0.0, round(lat * 1e7),
                                     round(lon * 1e7), 0.0, 1))
    for inc, c, r in circles:
        lat, lon = latlon(c)
        items.append(WireMissionItem(len(items), 0, 5003 if inc else 5004, 0, 1, r, 0.0, 0.0, 0.0,
                                 round(lat * 1e7), round(lon * 1e7), 0.0, 1))
    return items


def _home() -> HomePosition:
    return HomePosition(t_s=0.0, lat_deg=HOME[0], lon_deg=HOME[1], alt_amsl_m=HOME[2],
                        pos_ned=(0.0, 0.0, 0.0))


def test_vehicle_fence_items_give_the_same_zones_as_the_plan_file(tmp_path: Path) -> None:
    polys = [(True, box(-10, 70, -10, 70)), (False, box(20, 40, 20, 40))]
    circs = [(False, (-30.0, -30.0), 10.0), (True, (0.0, 0.0), 100.0)]
    plan = write_plan(tmp_path / "zones.plan", [(60, 0)], polygons=polys, circles=circs)
    from_file = load_mission(plan).geofence
    from_items = geofence_from_wire(_fence_items(polys, circs), GeoPoint(*HOME))
    rng = np.random.default_rng(3)
    pts = np.column_stack([rng.uniform(-120, 120, 4000), rng.uniform(-120, 120, 4000),
                           np.zeros(4000)])
    # identical verdicts except within a few cm of a boundary (degE7 rounding)
    same = from_file.contains(pts) == from_items.contains(pts)
    assert np.mean(same) > 0.999


def test_serve_refuses_a_vehicle_mission_that_breaches_the_vehicle_fence() -> None:
    from tests.support.gcs import mission_item

    # what PX4 returns on download: takeoff, two waypoints (items 1..3 after the home row)
    wps = [(0.0, 0.0), (60.0, 0.0), (60.0, 60.0)]
    items = []
    for seq, (ne, cmd) in enumerate(zip(wps, (22, 16, 16), strict=True)):
        lat, lon = latlon(ne)
        m = mission_item(seq, cmd, lat, lon, 10.0)
        items.append(WireMissionItem(m.seq, m.frame, m.command, m.current, m.autocontinue,
                                 m.param1, m.param2, m.param3, m.param4, m.x, m.y, m.z))
    fence = _fence_items([(False, box(50, 70, 20, 34))], [])
    cfg = ServiceConfig()
    plan_program(items, _home(), (1, 3), cfg)  # without the fence it plans
    with pytest.raises(MissionError) as exc:
        plan_program(items, _home(), (1, 3), cfg, fence_items=fence)
    msg = str(exc.value)
    assert re.search(r"the leg from item 2 to item 3 crosses exclusion polygon 0 for 1\d m",
                     msg), msg
    # the service announces the refusal like any other plan failure
    acts = ServeService(cfg).on_planned((1, 3), msg.splitlines()[0], 0.0)
    texts = [a.text for a in acts if hasattr(a, "text")]
    assert any(t.startswith("ecca: cannot fly mission:") and "item 2 to item 3" in t
               for t in texts), texts
