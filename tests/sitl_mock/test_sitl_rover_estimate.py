"""The mock rover's estimate errors (SIM_EST_*, like EKF2's on SIH; issue 29).

Oracles independent of the model's code: the errors are read from the mock's MAVLink output
alone (LOCAL_POSITION_NED and ATTITUDE, the estimate, minus HIL_STATE_QUATERNION, the truth)
and compared with the parameters through the second-order Gauss-Markov process's textbook
statistics (stationary std, autocorrelation (1 + t / tau) exp(-t / tau)); the control loops'
translation invariance (a rover whose estimate is off by a constant drives the same path off by
that constant); byte equality of the telemetry for determinism.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from sitl_mock.params import ParamStore
from sitl_mock.rover import Rover
from sitl_mock.setpoints import IdleTarget, PositionTarget, RoverPositionTarget
from tests.support.autopilot_harness import Harness

EARTH_RADIUS_M = 6371000.0
HIL = mavlink.MAVLINK_MSG_ID_HIL_STATE_QUATERNION
DT = 0.004
VEL_ONLY = 0b110111000111  # SET_POSITION_TARGET_LOCAL_NED: vx, vy, vz


def _errors(h: Harness) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t, (N, 4) estimate - truth for north, east [m], v north, v east [m/s] at the
    LOCAL_POSITION_NED samples, (M, 2) t and heading error [rad] at the ATTITUDE samples), the
    truth (HIL_STATE_QUATERNION) interpolated on the autopilot's time stamps."""
    home = h.ap.commander.home
    hil = h.msgs("HIL_STATE_QUATERNION")
    th = np.array([m.time_usec * 1e-6 for m in hil])
    lat0, lon0 = math.radians(home[0]), math.radians(home[1])
    n = np.array([(math.radians(m.lat * 1e-7) - lat0) * EARTH_RADIUS_M for m in hil])
    e = np.array([(math.radians(m.lon * 1e-7) - lon0) * EARTH_RADIUS_M * math.cos(lat0)
                  for m in hil])
    vn = np.array([m.vx * 0.01 for m in hil])
    ve = np.array([m.vy * 0.01 for m in hil])
    yaw = np.unwrap([math.atan2(2.0 * (m.attitude_quaternion[0] * m.attitude_quaternion[3]),
                                1.0 - 2.0 * m.attitude_quaternion[3] ** 2) for m in hil])
    lp = h.msgs("LOCAL_POSITION_NED")
    t = np.array([m.time_boot_ms * 1e-3 for m in lp])
    est = np.array([(m.x, m.y, m.vx, m.vy) for m in lp])
    tru = np.column_stack([np.interp(t, th, c) for c in (n, e, vn, ve)])
    att = h.msgs("ATTITUDE")
    ta = np.array([m.time_boot_ms * 1e-3 for m in att])
    dyaw = np.angle(np.exp(1j * (np.array([m.yaw for m in att]) - np.interp(ta, th, yaw))))
    return t, est - tru, np.column_stack([ta, dyaw])


def _standing(params: dict[str, float], seconds: float, seed: int = 0) -> Harness:
    """A standing rover (disarmed) streaming its truth at 50 Hz for `seconds`."""
    h = Harness(step_s=0.02, vehicle_kind="rover", params=params, seed=seed)
    h.command_long(511, float(HIL), 20000.0)
    h.run(seconds)
    return h


def _acf(x: np.ndarray, lags: list[int]) -> list[float]:
    y = x - x.mean()
    v = float(np.dot(y, y)) / len(y)
    return [float(np.dot(y[: len(y) - k], y[k:])) / (len(y) - k) / v for k in lags]


def test_estimate_error_std_and_decorrelation_are_the_parameters() -> None:
    """Standing 200 s with position 0.2 m, velocity 0.15 m/s (tau 0.5 s) and heading 3 deg
    (tau 1 s) errors: each position / velocity channel's std within 20 % of its parameter
    (~100 independent stretches: over seeds the ratio spreads 0.88-1.16), the heading's within
    25 % (half as many: 0.82-1.17); each autocorrelation at its tau within 0.15 of the
    process's 2/e = 0.74 (seeds: 0.61-0.78; the heading at the position's tau would give 0.41)
    and at 4 tau below 0.3 (the process: 0.09); the position and velocity errors uncorrelated
    (|r| < 0.2)."""
    tau, tau_yaw = 0.5, 1.0
    p = {"SIM_EST_XY_STD": 0.2, "SIM_EST_VXY_STD": 0.15, "SIM_EST_XY_TAU": tau,
         "SIM_EST_YAW_STD": 3.0, "SIM_EST_YAW_TAU": tau_yaw}
    h = _standing(p, 200.0, seed=5)
    t, err, yaw = _errors(h)
    dt_lp = float(np.median(np.diff(t)))
    for j, std in ((0, 0.2), (1, 0.2), (2, 0.15), (3, 0.15)):
        assert err[:, j].std() == pytest.approx(std, rel=0.2), j
        at_tau, at_4tau = _acf(err[:, j], [round(tau / dt_lp), round(4 * tau / dt_lp)])
        assert at_tau == pytest.approx(2.0 / math.e, abs=0.15), j
        assert at_4tau < 0.3, j
    assert abs(np.corrcoef(err[:, 0], err[:, 2])[0, 1]) < 0.2
    dt_att = float(np.median(np.diff(yaw[:, 0])))
    assert math.degrees(yaw[:, 1].std()) == pytest.approx(3.0, rel=0.25)
    at_tau, at_4tau = _acf(yaw[:, 1], [round(tau_yaw / dt_att), round(4 * tau_yaw / dt_att)])
    assert at_tau == pytest.approx(2.0 / math.e, abs=0.15)
    assert at_4tau < 0.3


def test_ideal_estimate_is_the_truth_exactly_and_hil_reports_it() -> None:
    """SIM_EST_* at 0 (the default): while the rover drives a loop under its controller, its
    estimate (`state`, what the telemetry reports) equals its truth bit for bit; on the wire
    HIL_STATE_QUATERNION agrees with LOCAL_POSITION_NED / ATTITUDE within its integer
    resolution (1e-7 deg ~ 1.1 cm, 1 cm/s)."""
    rv = Rover(ParamStore())
    goal = RoverPositionTarget((8.0, -6.0), arrival_speed=0.0, acceptance_radius_m=0.5)
    for _ in range(round(12.0 / DT)):
        rv.step(DT, goal, True)
        assert rv.state == rv.true_state
    assert math.dist(rv.true_pos_ned[:2], (8.0, -6.0)) <= 0.5
    h = Harness(step_s=0.02, vehicle_kind="rover")
    h.command_long(511, float(HIL), 20000.0)
    h.wait_ready()
    h.send(mavlink.MAVLink_set_position_target_local_ned_message(
        0, 1, 1, 1, VEL_ONLY, 0, 0, 0, 1.5, 1.0, 0, 0, 0, 0, 0, 0))
    h.set_mode(6)
    h.arm()
    h.run(8.0, lambda: h.send(mavlink.MAVLink_set_position_target_local_ned_message(
        0, 1, 1, 1, VEL_ONLY, 0, 0, 0, 1.5, 1.0, 0, 0, 0, 0, 0, 0)))
    _t, err, yaw = _errors(h)
    assert np.abs(err[:, :2]).max() < 0.02  # the truth interpolated between 50 Hz samples
    assert np.abs(err[:, 2:]).max() < 0.06
    assert np.abs(yaw[:, 1]).max() < 0.05
    assert math.hypot(*h.ap.state.pos_ned[:2]) > 5.0  # it drove


def _drive(offset_ne: tuple[float, float], yaw_err: float = 0.0) -> np.ndarray:
    """True (north, east, yaw) every step: 10 s to a position goal (OFFBOARD-like: the line
    starts at the rover), with the estimate off by a constant; placed so that its estimate
    starts at the origin."""
    rv = Rover(ParamStore())
    rv.set_state(-offset_ne[0], -offset_ne[1], -yaw_err)
    rv.set_estimate_error(pos_ne=offset_ne, yaw=yaw_err)
    tgt = PositionTarget((12.0, 7.0, 0.0), (math.nan,) * 3, (math.nan,) * 3)
    rows = []
    for _ in range(round(10.0 / DT)):
        rv.step(DT, tgt, True)
        rows.append((*rv.true_pos_ned[:2], rv.true_state.yaw))
    return np.array(rows)


def test_the_rover_steers_by_its_estimate() -> None:
    """A constant position error (1.2 m north, -0.7 m east), the rover placed where its
    estimate reads the origin: the whole true path is the error-free one moved by minus that
    error (the controller is translation invariant: the same path in estimate coordinates).
    A constant heading error of 0.2 rad leaves the rover heading 0.2 rad off its course (told
    to drive north, it drives at -0.2 rad)."""
    base = _drive((0.0, 0.0))
    off = _drive((1.2, -0.7))
    assert np.abs(off[:, 0] - (base[:, 0] - 1.2)).max() < 1e-6
    assert np.abs(off[:, 1] - (base[:, 1] + 0.7)).max() < 1e-6
    assert np.abs(off[:, 2] - base[:, 2]).max() < 1e-9
    rv = Rover(ParamStore())
    rv.set_estimate_error(yaw=0.2)
    north = PositionTarget((math.nan,) * 3, (2.0, 0.0, math.nan), (math.nan,) * 3)
    for _ in range(round(6.0 / DT)):
        rv.step(DT, north, True)
    assert rv.true_state.yaw == pytest.approx(-0.2, abs=0.01)
    assert rv.state.yaw == pytest.approx(0.0, abs=0.01)
    vn, ve, _ = rv.true_vel_ned
    assert math.atan2(ve, vn) == pytest.approx(-0.2, abs=0.01)


def test_estimate_errors_are_deterministic_per_seed() -> None:
    """The same seed: the same bytes on the wire; another seed: other errors."""
    p = {"SIM_EST_XY_STD": 0.2, "SIM_EST_VXY_STD": 0.1, "SIM_EST_YAW_STD": 2.0}
    a, b, c = (_standing(p, 6.0, seed=s) for s in (3, 3, 4))
    assert a.raw == b.raw
    assert a.raw != c.raw
    rv = Rover(ParamStore(p), seed=3)
    for _ in range(100):
        rv.step(DT, IdleTarget(), False)
    assert rv.state != rv.true_state  # the errors are on


def test_the_position_estimate_leads_the_truth_by_sim_est_lead_s() -> None:
    """SIM_EST_LEAD_S 0.11 alone (EKF2 on SIH, measured: bench/rover_estimate_error.py): read
    off the wire while the rover drives under a velocity setpoint, the position estimate is
    ahead of the truth along the true velocity by 0.11 s x the true speed (within the 1 cm and
    1 cm/s resolution of HIL_STATE_QUATERNION), with nothing across it; standing, it is the
    truth."""
    h = _standing({"SIM_EST_LEAD_S": 0.11}, 0.0)
    h.wait_ready()
    h.run(1.0)
    _t, err0, _yaw0 = _errors(h)
    assert np.abs(err0[:, :2]).max() < 0.02  # standing: no lead

    def send() -> None:
        h.send(mavlink.MAVLink_set_position_target_local_ned_message(
            0, 1, 1, 1, VEL_ONLY, 0, 0, 0, 1.5, 2.0, 0, 0, 0, 0, 0, 0))

    send()
    h.set_mode(6)
    h.arm()
    h.run(8.0, send)
    t, err, _yaw = _errors(h)
    hil = h.msgs("HIL_STATE_QUATERNION")
    th = np.array([m.time_usec * 1e-6 for m in hil])
    vel = np.column_stack([np.interp(t, th, [m.vx * 0.01 for m in hil]),
                           np.interp(t, th, [m.vy * 0.01 for m in hil])])
    speed = np.hypot(vel[:, 0], vel[:, 1])
    moving = speed > 1.0
    assert moving.sum() > 100
    u = vel[moving] / speed[moving, None]
    along = np.sum(err[moving, :2] * u, axis=1)
    across = err[moving, 0] * -u[:, 1] + err[moving, 1] * u[:, 0]
    assert np.abs(along - 0.11 * speed[moving]).max() < 0.03
    assert np.abs(across).max() < 0.03


def test_the_heading_bias_is_one_draw_per_start() -> None:
    """SIM_EST_YAW_BIAS 3 deg alone: each vehicle's heading error is constant while it drives
    and the same for the same seed; over 400 seeds (starts) the errors have a mean within
    3 standard errors of 0 and a std within 15 % of 3 deg (its standard error ~3.5 %); at 0 deg
    there is none."""
    p = {"SIM_EST_YAW_BIAS": 3.0}
    goal = RoverPositionTarget((20.0, 5.0), arrival_speed=0.0, acceptance_radius_m=0.5)

    def heading_errors(seed: int, params: dict[str, float], steps: int) -> list[float]:
        rv = Rover(ParamStore(params), seed=seed)
        out = []
        for _ in range(steps):
            rv.step(DT, goal, True)
            out.append(math.remainder(rv.state.yaw - rv.true_state.yaw, math.tau))
        return out

    one = heading_errors(7, p, 500)
    assert max(one) - min(one) < 1e-9
    assert heading_errors(7, p, 1)[0] == one[0]
    biases = np.degrees([heading_errors(s, p, 1)[0] for s in range(400)])
    assert abs(biases.mean()) < 3.0 * 3.0 / math.sqrt(400)
    assert biases.std() == pytest.approx(3.0, rel=0.15)
    assert heading_errors(7, {}, 50) == [0.0] * 50


@pytest.mark.parametrize("bias_deg", [-4.0, 3.0])
def test_a_heading_error_holds_the_estimate_beside_the_leg(bias_deg: float) -> None:
    """PX4's rover was measured holding its estimate 3.4 m x tan(heading error) beside a leg
    (bench/rover_estimate_error.py, "legs"); pure pursuit's geometry says why: driving straight
    along the leg, the estimated heading (true + error) points at the look-ahead point
    (PP_LOOKAHD_GAIN x speed ahead on the leg) only from an offset of -lookahead x sin(error).
    The mock rover on a 60 m leg at RO_SPEED_LIM (3 m/s: a 3 m look-ahead) holds that offset
    within 2 cm over its middle."""
    b = math.radians(bias_deg)
    rv = Rover(ParamStore(), seed=0)
    rv.set_estimate_error(yaw=b)
    leg = RoverPositionTarget((60.0, 0.0), start_ne=(0.0, 0.0), arrival_speed=0.0,
                              acceptance_radius_m=0.5)
    rows = []
    for _ in range(round(22.0 / DT)):
        rv.step(DT, leg, True)
        s = rv.state
        rows.append((s.pos_ned[0], s.pos_ned[1], math.hypot(*rv.true_vel_ned[:2])))
    a = np.array(rows)
    mid = (a[:, 0] > 25.0) & (a[:, 0] < 45.0)
    assert mid.sum() > 500
    lookahead = a[mid, 2] * 1.0  # PP_LOOKAHD_GAIN 1 s, within PP_LOOKAHD_MIN/MAX (1-10 m)
    assert np.abs(a[mid, 1] - (-lookahead * math.sin(b))).max() < 0.02
