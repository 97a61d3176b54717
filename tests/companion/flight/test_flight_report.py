"""The typed flight report: each kind writes the keys report.json always had, in their order,
and the verdict helpers read the typed fields. Synthetic values, no flight."""

from __future__ import annotations

import dataclasses
import json

from companion.flight.report import (
    FlightReport,
    SetpointQuality,
    TrackRecorder,
    WaypointResult,
    breach_failure,
    breach_result,
    missed_result,
    report_ok,
)

_WPS = (WaypointResult(1.0, 2.0, -5.0, 1.0, 0.4, True, 1),
        WaypointResult(9.0, 2.0, -5.0, 1.0, 2.5, False, 2))


def _replay(**kw: object) -> FlightReport:
    base = FlightReport(kind="replay", result="ok", duration_s=10.0, planned_duration_s=9.0,
                        waypoints=_WPS, waypoints_reached=1, rms_error_m=0.1, max_error_m=0.3,
                        geofence_violations=0, file="m.plan", vehicle="quad", mode="attitude",
                        setpoint_rate_hz=100.0, setpoint_quality=SetpointQuality().figures())
    return dataclasses.replace(base, **kw)  # type: ignore[arg-type]


def test_replay_report_keys_in_order() -> None:
    d = _replay().to_dict()
    assert list(d) == [
        "duration_s", "planned_duration_s", "path_length_m", "rms_error_m", "max_error_m",
        "waypoints", "waypoints_reached", "max_speed_m_s", "max_tilt_deg", "max_thrust_norm",
        "max_body_rate_rad_s", "geofence_violations", "geofence_violation_zones", "failsafes",
        "bound_s", "planned_over_bound", "file", "vehicle", "mode", "setpoint_rate_hz",
        "setpoints_sent", "tlog_frames", "result", "simulated_s", "wall_s", "real_time_factor",
        "warnings", "setpoint_quality", "ok"]
    assert list(d["waypoints"][0]) == ["item_index", "north_m", "east_m", "down_m",
                                       "acceptance_radius_m", "closest_approach_m", "reached"]
    json.dumps(d, allow_nan=False)


def test_px4_mission_part_has_no_tracking_error() -> None:
    px4 = _replay(kind="px4_mission", legs=(), geofence_breaches=())
    d = px4.to_dict()
    assert "rms_error_m" not in d and "max_error_m" not in d and "file" not in d
    assert list(d)[-4:] == ["geofence_breaches", "legs", "result", "ok"]
    assert "px4_mission" in _replay(px4_mission=px4).to_dict()


def test_fly_report_shapes() -> None:
    rec = TrackRecorder()
    rec.add(0.0, (0.0, 0.0, -5.0), (0.0, 0.0, -5.0))
    rec.add(1.0, (1.0, 0.0, -5.0), (1.2, 0.0, -5.0))
    failed = dataclasses.replace(rec.summary(None, (), duration_s=1.0, planned_duration_s=5.0),
                                 result="failed: link lost", mode="attitude", target="square")
    assert list(failed.to_dict()) == ["duration_s", "planned_duration_s", "samples",
                                      "rms_error_m", "max_error_m", "waypoints",
                                      "waypoints_reached", "result", "mode", "target"]
    done = dataclasses.replace(failed, result="ok", final_action="land", ok=True,
                               setpoint_quality=SetpointQuality().figures())
    assert list(done.to_dict())[-3:] == ["final_action", "setpoint_quality", "ok"]


def test_verdicts() -> None:
    r = _replay()
    assert not report_ok(r) and missed_result(r) == "missed 1 waypoint(s): item 2 by 2.50 m"
    assert report_ok(_replay(waypoints=_WPS[:1]))
    breach = {"message": "the leg from item 1 to item 2 crosses zone 0"}
    b = _replay(geofence_breaches=(breach,), geofence_violations=3)
    assert breach_result(b) == breach_failure(b) == f"geofence breach: {breach['message']}"
    assert breach_result(_replay(result="aborted: x", geofence_violations=1)) == "aborted: x"
    zones = _replay(geofence_violations=2, geofence_violation_zones=("polygon 0",))
    assert breach_failure(zones) == "geofence breach: polygon 0"


def test_quality_report_is_its_figures() -> None:
    q = SetpointQuality()
    q.add(0.0, 0.5, 0.1, (0.1, 0.2, 0.3), True)
    q.add(0.01, 0.52, 0.1, (0.1, 0.2, 0.3), True)
    assert q.report() == q.figures().to_dict()
    assert q.report()["max_body_rate_cmd_rad_s"] == [0.1, 0.2, 0.3]
