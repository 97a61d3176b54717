"""Values a mission may carry are bounded where they enter (the loader), from PX4's own limits;
whatever the loader accepts, the planner finishes in bounded work."""

from __future__ import annotations

import copy
import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from companion.mission import MissionError, checks, mission_to_flight_plan, parse_plan, parse_wpl
from companion.mission.geofence import Geofence

EXAMPLES = Path(__file__).resolve().parents[3] / "examples" / "missions"
SQUARE: dict[str, Any] = json.loads((EXAMPLES / "square.plan").read_text())
FENCE = json.loads((EXAMPLES / "survey.plan").read_text())["geoFence"]


def _plan(mutate: Callable[[dict[str, Any]], None], fence: bool = True) -> str:
    doc = copy.deepcopy(SQUARE)
    if fence:
        doc["geoFence"] = copy.deepcopy(FENCE)
    mutate(doc)
    return json.dumps(doc)


def _item(doc: dict[str, Any], k: int) -> dict[str, Any]:
    item: dict[str, Any] = doc["mission"]["items"][k]
    return item


def _set(k: int, p: int, v: float) -> Callable[[dict[str, Any]], None]:
    return lambda d: _item(d, k)["params"].__setitem__(p, v)


def _speed_item(v: float) -> Callable[[dict[str, Any]], None]:
    item = {"type": "SimpleItem", "command": 178, "frame": 2, "autoContinue": True,
            "params": [1, v, -1, 0, 0, 0, 0]}
    return lambda d: d["mission"]["items"].insert(2, item)


@pytest.mark.parametrize(
    ("mutate", "part"),
    [
        (_set(1, 6, 1e300), "PX4 allows at most 10000 m"),
        (_set(1, 6, 1e15), "PX4 allows at most 10000 m"),
        (_set(1, 6, -1e8), "PX4 allows at most 10000 m"),
        (_set(1, 0, 1e300), "hold time 1e+300 s exceeds 3600 s"),
        (_set(0, 0, 1e300), "param1 1e+300 does not fit MAVLink's float32"),  # takeoff pitch
        (_set(1, 1, 1e6), "exceeds PX4's largest NAV_ACC_RAD"),
        (_speed_item(1e300), "DO_CHANGE_SPEED: 1e+300 m/s exceeds"),
        (_speed_item(40.5), "DO_CHANGE_SPEED: 40.5 m/s exceeds"),
        (lambda d: d["mission"].update(plannedHomePosition=[47.4, 8.5, 1e300]), "m AMSL out of"),
        (lambda d: d.update(rallyPoints={"points": [[47.3978, 8.5456, 1e12]]}), "within 10000 m"),
        (lambda d: d["geoFence"]["circles"][0]["circle"].update(radius=1e300), "up to 200000"),
    ],
)
def test_out_of_range_values_are_mission_errors(
    mutate: Callable[[dict[str, Any]], None], part: str
) -> None:
    with pytest.raises(MissionError) as info:
        parse_plan(_plan(mutate), source="edited.plan")
    assert part in str(info.value)


def test_wpl_altitude_is_bounded_too() -> None:
    text = (EXAMPLES / "square.waypoints").read_text()
    lines = text.splitlines()
    fields = lines[2].split("\t")
    fields[10] = "1e300"
    lines[2] = "\t".join(fields)
    with pytest.raises(MissionError, match="PX4 allows at most 10000 m"):
        parse_wpl("\n".join(lines), source="edited.waypoints")


@pytest.mark.parametrize(
    "mutate",
    [
        _set(1, 6, checks.MAX_HEIGHT_M),
        _set(1, 0, checks.MAX_HOLD_S),
        _set(1, 1, checks.MAX_ACCEPT_RADIUS_M),
        _speed_item(checks.MAX_SPEED_M_S),
    ],
)
def test_values_at_the_limits_load_and_plan(mutate: Callable[[dict[str, Any]], None]) -> None:
    plan = mission_to_flight_plan(parse_plan(_plan(mutate), source="edge.plan"))
    assert all(np.isfinite(w.pos_ned_m).all() for w in plan.waypoints)


def test_geofence_check_of_long_legs_has_a_sample_budget(monkeypatch: pytest.MonkeyPatch) -> None:
    """A 70 km square at 10 km up (~300 km of legs, 300 000 samples at one per metre): the
    budget caps the whole flight's samples."""
    far = 70_000.0 / 6_371_000.0 * 180.0 / math.pi  # degrees of latitude for 99 km

    def corners(d: dict[str, Any]) -> None:
        lat0, lon0 = 47.397742, 8.545594
        dlon = far / math.cos(math.radians(lat0))
        for k, (dn, de) in zip(range(1, 5), [(1, 0), (1, 1), (0, 1), (0, 0)], strict=True):
            p = _item(d, k)["params"]
            p[4], p[5], p[6] = lat0 + dn * far, lon0 + de * dlon, 10_000.0

    seen: list[int] = []
    real = Geofence.violations

    def counting(self: Geofence, pts: Any) -> Any:
        seen.append(len(np.atleast_2d(np.asarray(pts))))
        return real(self, pts)

    monkeypatch.setattr(Geofence, "violations", counting)
    plan = mission_to_flight_plan(parse_plan(_plan(corners), source="far.plan"))
    assert plan.warnings  # the far corners leave the survey fence: the check did run
    assert sum(seen) <= 200_000 + 2 * len(seen)
