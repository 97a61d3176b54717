"""`SetpointQuality`: the setpoint figures of a flight report and their verdict, on synthetic
setpoint series whose answers are known by construction."""

from __future__ import annotations

import math

import pytest

from companion.flight.report import (
    THRUST_STEP_GOAL,
    TILT_JITTER_GOAL_DEG,
    TILT_JITTER_TAU_S,
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


def _feed_lean(q: SetpointQuality, lean: list[tuple[float, float]], dt: float = 0.01,
               airborne: bool = True) -> None:
    for k, v in enumerate(lean):
        q.add(k * dt, 0.5, math.hypot(*v), (0.0, 0.0, 0.0), airborne, v)


def _sine(amp_deg: float, f_hz: float, n: int, dt: float = 0.01) -> list[tuple[float, float]]:
    a = math.radians(amp_deg)
    return [(a * math.sin(2.0 * math.pi * f_hz * k * dt), 0.0) for k in range(n)]


def test_a_rocking_command_is_measured_and_counted() -> None:
    """A +-17 deg roll at 1.2 Hz (real PX4 SIH at kp_xy 20, hovering): its measured RMS is the
    sinusoid's (amp / sqrt 2) through the first-order high-pass at TILT_JITTER_TAU_S (gain
    w tau / sqrt(1 + (w tau)^2)), within 5 %, and every window counts against the goal (a
    count, not a failure of the flight)."""
    q = SetpointQuality()
    _feed_lean(q, _sine(17.0, 1.2, 2000))
    wt = 2.0 * math.pi * 1.2 * TILT_JITTER_TAU_S
    expected = 17.0 / math.sqrt(2.0) * wt / math.sqrt(1.0 + wt * wt)
    f = q.figures()
    assert f.tilt_jitter_rms_deg == pytest.approx(expected, rel=0.05)
    assert f.max_tilt_jitter_window_deg == pytest.approx(expected, rel=0.05)
    assert f.tilt_jitter_windows_over_goal >= 9  # 20 s in 2 s windows
    assert q.failure() is None
    # half of it: counted against the goal; a quarter: not
    for amp, over in ((8.5, True), (4.0, False)):
        q = SetpointQuality()
        _feed_lean(q, _sine(amp, 1.2, 2000))
        assert (q.figures().tilt_jitter_windows_over_goal > 0) is over
        assert q.failure() is None


def test_a_slow_lean_and_the_ground_are_not_rocking() -> None:
    """A 30 deg lean swung round at 0.1 Hz (a lean the caller did not subtract as the plan's)
    passes the high-pass at its gain (30 deg x w tau / sqrt(1 + (w tau)^2), within 6 %) and
    stays under the goal; a rocking on the ground is not counted."""
    q = SetpointQuality()
    a, w = math.radians(30.0), 0.2 * math.pi
    _feed_lean(q, [(a * math.cos(w * k * 0.01), a * math.sin(w * k * 0.01)) for k in range(3000)])
    wt = w * TILT_JITTER_TAU_S
    window = q.figures().max_tilt_jitter_window_deg
    assert window == pytest.approx(30.0 * wt / math.sqrt(1.0 + wt * wt), rel=0.06)
    assert window < TILT_JITTER_GOAL_DEG
    q = SetpointQuality()
    _feed_lean(q, _sine(17.0, 1.2, 2000), airborne=False)
    assert q.figures().max_tilt_jitter_window_deg == 0.0 and q.failure() is None
