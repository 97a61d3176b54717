"""`SetpointQuality`: the setpoint figures of a flight report and their verdict, on synthetic
setpoint series whose answers are known by construction."""

from __future__ import annotations

import math

import pytest

from companion.flight.report import (
    THRUST_STEP_GOAL,
    SetpointLimits,
    SetpointQuality,
)
from companion.mission.px4_params import Px4PlanningParams


def _feed(q: SetpointQuality, thrust: list[float], dt: float = 0.01, tilt: float = 0.1,
          airborne: bool = True, t0: float = 0.0) -> None:
    for k, u in enumerate(thrust):
        q.add(t0 + k * dt, u, tilt, (0.0, 0.0, 0.0), airborne)


def test_smooth_thrust_is_ok_and_a_step_is_measured_against_10ms_earlier() -> None:
    q = SetpointQuality()
    _feed(q, [0.5 + 0.001 * k for k in range(100)])
    assert q.max_thrust_step == pytest.approx(0.001) and q.failure() is None
    # at 250 Hz a ramp of 0.01 per 4 ms: measured against the command in force 10 ms earlier
    # (sent 12 ms earlier, three frames back), not frame to frame
    q = SetpointQuality()
    _feed(q, [0.5 + 0.01 * k for k in range(40)], dt=0.004)
    assert q.max_thrust_step == pytest.approx(0.03, abs=1e-9)
    q = SetpointQuality()
    _feed(q, [0.5] * 10 + [0.62] + [0.5] * 10)
    assert q.max_thrust_step == pytest.approx(0.12) and q.thrust_steps_over_goal == 2
    assert q.failure() is None  # counted, not a failure
    _feed(q, [0.5, 0.8, 0.5], t0=1.0)
    assert q.max_thrust_step == pytest.approx(0.3) and q.thrust_steps_over_goal == 4
    assert q.failure() is not None and "chatter" in q.failure()  # type: ignore[operator]


def test_steps_on_the_ground_across_gaps_and_after_position_setpoints_do_not_count() -> None:
    q = SetpointQuality()
    _feed(q, [0.0, 0.6, 0.0, 0.6], airborne=False)  # spool-up on the ground
    _feed(q, [0.3, 0.6], dt=0.05, t0=1.0)  # 50 ms apart: no command 10 ms before
    q.gap()
    _feed(q, [0.9], t0=2.0)  # the first after position setpoints
    assert q.max_thrust_step == 0.0 and q.thrust_steps_over_goal == 0
    assert q.failure() is None
    assert THRUST_STEP_GOAL == 0.05


def test_tilt_and_body_rate_over_the_limit_fail_with_time_over() -> None:
    lim = SetpointLimits.of_px4(Px4PlanningParams(MPC_TILTMAX_AIR=30.0, MC_YAWRATE_MAX=90.0))
    assert lim.tilt_max_rad == pytest.approx(math.radians(30.0))
    assert lim.rate_max_frd[2] == pytest.approx(math.radians(90.0))
    q = SetpointQuality(lim)
    _feed(q, [0.5] * 50, tilt=math.radians(30.0))  # at the limit (a clamped command)
    assert q.over_tilt_s == 0.0 and q.failure() is None
    _feed(q, [0.5] * 20, tilt=math.radians(31.0), t0=0.5)
    assert q.over_tilt_s == pytest.approx(0.2, abs=0.011)
    assert "tilt 31.0 deg" in (q.failure() or "")
    r = SetpointQuality(lim)
    for k in range(10):
        r.add(0.01 * k, 0.5, 0.0, (0.0, 0.0, math.radians(100.0)), True)
    assert "yaw rate" in (r.failure() or "")
    assert r.report()["max_body_rate_cmd_rad_s"][2] == pytest.approx(math.radians(100.0),
                                                                      abs=1e-3)
