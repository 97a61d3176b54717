"""`fly`'s report of a mission: per-leg figures and geofence breaches from the recorded track
(plan frame = local - origin; the fence in the mission frame = local + the geodetic shift), and
a breach turns the result into a failure. Synthetic tracks, no vehicle."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from companion.app.fly import (
    FlyOptions,
    check_inputs,
    mission_figures,
    plan_flight,
)
from companion.flight.report import FlightReport, TrackRecorder, breach_failure
from companion.planning.fence_check import sample_schedule
from tests.support.fence_plans import box, write_plan


def _planned(tmp_path: Path, **kw: object):  # type: ignore[no-untyped-def]
    plan = write_plan(tmp_path / "m.plan", [(60.0, 0.0), (60.0, 40.0)], land=False,
                      polygons=[(False, box(20.0, 40.0, 3.0, 9.0))])
    opts = FlyOptions(target=str(plan), connect=None, mode="attitude", rate_hz=50.0,
                      vehicle_file=None, log=str(tmp_path / "f.tlog"), size_m=10.0,
                      speed_m_s=3.0, alt_m=5.0, laps=1)
    return plan_flight(opts, check_inputs(opts), rover=False)


def _record(planned, shift_ne: tuple[float, float], origin: np.ndarray) -> TrackRecorder:  # type: ignore[no-untyped-def]
    t, p = sample_schedule(planned.schedule)
    keep = t >= planned.t_off_s
    rec = TrackRecorder()
    for ti, pi in zip(t[keep], p[keep], strict=True):
        local = pi + origin + np.array([shift_ne[0], shift_ne[1], 0.0])
        rec.add(float(ti), local, pi + origin)
    return rec


def _report(rec: TrackRecorder) -> FlightReport:
    return rec.summary(None, (), duration_s=rec.t_s[-1] - rec.t_s[0], planned_duration_s=0.0)


def test_track_on_the_plan_has_no_breach_and_legs_after_the_takeoff(tmp_path: Path) -> None:
    planned = _planned(tmp_path)
    origin = np.array([3.0, -2.0, -0.5])  # PX4's local frame is not the mission's
    rec = _record(planned, (0.0, 0.0), origin)
    fig = mission_figures(_report(rec), planned, rec, origin, None)
    assert fig.geofence_breaches == () and fig.geofence_violations == 0
    assert breach_failure(fig) is None
    legs = fig.legs
    assert legs is not None
    # PX4 flies the takeoff: the legs start at item 1
    assert [(g["from_item"], g["to_item"]) for g in legs] == [(1, 2), (2, 3)]
    for g in legs:
        assert g["time_s"] == pytest.approx(g["planned_time_s"], abs=0.05)


def test_track_shifted_over_the_zone_is_a_failed_result(tmp_path: Path) -> None:
    planned = _planned(tmp_path)
    origin = np.zeros(3)
    rec = _record(planned, (0.0, 6.0), origin)  # flown 6 m east of the plan
    # the fence in the mission frame: local + shift (here the local frame is the mission's)
    fig = mission_figures(_report(rec), planned, rec, origin, np.zeros(3))
    assert fig.geofence_breaches is not None and fig.legs is not None
    (b,) = fig.geofence_breaches
    assert (b["from_item"], b["to_item"], b["zone"]) == (1, 2, "exclusion polygon 0")
    failure = breach_failure(fig)
    assert failure is not None and failure.startswith(
        "geofence breach: the leg from item 1 to item 2 crosses exclusion polygon 0")
    # in the plan frame the same track is 6 m off its leg
    assert max(g["max_deviation_m"] for g in fig.legs) >= 6.0 - 0.1
    # measured against a geodetic shift that puts it back on the plan: no breach
    fig2 = mission_figures(_report(rec), planned, rec, origin, np.array([0.0, -6.0, 0.0]))
    assert fig2.geofence_breaches == ()
