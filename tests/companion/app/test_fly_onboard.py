"""`fly --onboard`'s conversion of a planned flight into the module's segments: the segments,
evaluated as a piecewise Bezier, are the schedule's reference (position, velocity, yaw) at every
time, with the origin applied; bundled missions fit the module; the refusals come before any
link is opened."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from companion.app.fly import FlyOptions
from companion.app.fly_onboard import OnboardError, fly_onboard, planned_segments
from companion.mission import load_mission, mission_to_flight_plan
from companion.onboard.protocol import MAX_SEGMENTS
from companion.planning.config import VehicleFile
from companion.planning.schedule import build_schedule
from companion.trajectory import Bezier, PiecewiseBezier

ROOT = Path(__file__).resolve().parents[3]
MISSIONS = ["examples/missions/square.plan", "examples/missions/hold_and_jump.plan",
            "examples/missions/one_minute.plan", "tests/data/missions/px4_short.plan",
            "examples/missions/survey.plan"]


class _Planned:
    def __init__(self, schedule: object) -> None:
        self.schedule = schedule
        self.t_off_s = 0.0
        self.trajectory = None


@pytest.mark.parametrize("rel", MISSIONS)
def test_the_segments_are_the_schedule(rel: str) -> None:
    vf = VehicleFile()
    fp = mission_to_flight_plan(load_mission(ROOT / rel), vehicle="quad")
    schedule = build_schedule(fp, vf.params, vf.limits, handover_height_m=1.0)
    origin = np.array([3.0, -2.0, -0.5])
    breaks, cps, ycps = planned_segments(_Planned(schedule), origin)  # type: ignore[arg-type]
    assert len(cps) <= MAX_SEGMENTS and len(breaks) == len(cps) + 1
    assert breaks[-1] == pytest.approx(schedule.duration_s, abs=1e-9)
    durations = np.diff(breaks)
    pos = PiecewiseBezier([Bezier(c, d) for c, d in zip(cps, durations, strict=True)])
    yaw = PiecewiseBezier([Bezier(np.asarray(y)[:, None], d)
                           for y, d in zip(ycps, durations, strict=True)])
    for t in np.linspace(0.0, schedule.duration_s, 997):
        ref = schedule.reference(float(t), origin)
        np.testing.assert_allclose(pos.evaluate(t), ref.pos_ned, atol=1e-8)
        np.testing.assert_allclose(pos.evaluate(t, 1), ref.vel_ned, atol=1e-7)
        assert math.isclose(float(yaw.evaluate(t)[0]), ref.yaw, abs_tol=1e-8)


def _opts(**kw: object) -> FlyOptions:
    base = {"target": str(ROOT / "tests/data/missions/px4_short.plan"), "connect": None,
            "mode": "attitude", "rate_hz": 100.0, "vehicle_file": None, "log": None,
            "size_m": 10.0, "speed_m_s": 3.0, "alt_m": 5.0, "laps": 1}
    base.update(kw)
    return FlyOptions(**base)  # type: ignore[arg-type]


@pytest.mark.parametrize(("kw", "why"), [({}, "--connect"),
                                         ({"connect": "udpin://127.0.0.1:1", "mode": "rates"},
                                          "attitude")])
async def test_onboard_refuses_what_it_cannot_fly_before_connecting(
        kw: dict[str, object], why: str, tmp_path: Path) -> None:
    from rich.console import Console

    with pytest.raises(OnboardError, match=why):
        await fly_onboard(_opts(log=str(tmp_path / "f.tlog"), **kw), Console())
