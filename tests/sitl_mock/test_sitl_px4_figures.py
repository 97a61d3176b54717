"""The mock quadrotor reproduces dynamic figures measured on real PX4 v1.16 SITL (SIH).

Reference values: /work/shared/PX4.md, "Observed on real PX4 v1.16.0 SITL" (midpoint of each
measured range). Each manoeuvre is flown on the vehicle model + controller directly (no MAVLink),
with PX4's default parameters, the same durations, and must land within 30 % of PX4's value.
"""

from __future__ import annotations

import math

import pytest
from scipy.spatial.transform import Rotation

from sitl_mock.flight_control import quat_from_euler
from sitl_mock.navigator import Navigator
from sitl_mock.params import ParamStore
from sitl_mock.quad import Quadrotor
from sitl_mock.setpoints import AttitudeTarget, PositionTarget
from sitl_mock.vehicle import make_vehicle

TOLERANCE = 0.30
PX4_ROLL_10DEG_2S_EAST_M_S = (1.3 + 1.4) / 2
PX4_PITCH_M10DEG_2S_NORTH_M_S = (1.3 + 1.6) / 2
PX4_THRUST_065_1S5_CLIMB_M_S = (2.3 + 2.7) / 2
PX4_POS_STEP_5M_SETTLE_1M_S = (2.2 + 3.4) / 2
PX4_TAKEOFF_1M5_FROM_ARM_S = 6.6
PX4_FIGURE8_POSITION_ONLY_RMS_M = 4.6


def _within(measured: float, reference: float) -> None:
    assert abs(measured - reference) <= TOLERANCE * reference, (
        f"measured {measured:.3f} vs PX4 {reference:.3f} (more than 30 % off)"
    )


def _hovering(dt: float, z: float = -10.0) -> Quadrotor:
    """Quadrotor hovering under position control (steady, integrators settled)."""
    v = Quadrotor(ParamStore(), seed=0)
    v.set_state(pos_ned=(0.0, 0.0, z), motors=0.49)
    v.mark_airborne(0.49)
    tgt = PositionTarget(pos_ned=(0.0, 0.0, z), yaw=0.0)
    for _ in range(round(5.0 / dt)):
        v.step(dt, tgt, True)
    return v


def _fly_attitude(
    dt: float, q: tuple[float, float, float, float], thrust: float, t: float
) -> Quadrotor:
    v = _hovering(dt)
    tgt = AttitudeTarget(q_wxyz=q, thrust_norm=thrust)
    for _ in range(round(t / dt)):
        v.step(dt, tgt, True)
    return v


def _fly_attitude_mean(
    dt: float, q: tuple[float, float, float, float], thrust: float, t: float
) -> tuple[Quadrotor, float, float]:
    """`_fly_attitude`, plus the mean roll and pitch [deg] over its last 0.2 s (SIH's gyro
    noise makes the attitude jitter by ~0.2 deg, as on PX4)."""
    v = _hovering(dt)
    tgt = AttitudeTarget(q_wxyz=q, thrust_norm=thrust)
    n = round(t / dt)
    rp: list[tuple[float, float]] = []
    for k in range(n):
        v.step(dt, tgt, True)
        if k >= n - round(0.2 / dt):
            roll, pitch, _ = _euler_deg(v)
            rp.append((roll, pitch))
    return v, sum(r for r, _ in rp) / len(rp), sum(p for _, p in rp) / len(rp)


def _euler_deg(v: Quadrotor) -> tuple[float, float, float]:
    w, x, y, z = v.state.q_wxyz
    yaw, pitch, roll = Rotation.from_quat([x, y, z, w]).as_euler("ZYX", degrees=True)
    return float(roll), float(pitch), float(yaw)


@pytest.mark.parametrize("dt", [0.004, 0.001])
def test_roll_plus_10deg_moves_east(dt: float) -> None:
    thrust = 0.5 / math.cos(math.radians(10.0))  # MPC_THR_HOVER / cos(10 deg), as a client would
    v, roll, pitch = _fly_attitude_mean(
        dt, quat_from_euler(math.radians(10.0), 0.0, 0.0), thrust, 2.0
    )
    vn, ve, _ = v.state.vel_ned
    assert roll == pytest.approx(10.0, abs=0.5) and abs(pitch) < 0.5
    assert abs(vn) < 0.05
    _within(ve, PX4_ROLL_10DEG_2S_EAST_M_S)


@pytest.mark.parametrize("dt", [0.004, 0.001])
def test_pitch_minus_10deg_moves_north(dt: float) -> None:
    thrust = 0.5 / math.cos(math.radians(10.0))
    v, _roll, pitch = _fly_attitude_mean(
        dt, quat_from_euler(0.0, math.radians(-10.0), 0.0), thrust, 2.0
    )
    vn, ve, _ = v.state.vel_ned
    assert pitch == pytest.approx(-10.0, abs=0.5)
    assert abs(ve) < 0.05
    _within(vn, PX4_PITCH_M10DEG_2S_NORTH_M_S)


@pytest.mark.parametrize("dt", [0.004, 0.001])
def test_thrust_065_climbs(dt: float) -> None:
    v = _fly_attitude(dt, (1.0, 0.0, 0.0, 0.0), 0.65, 1.5)
    climb = -v.state.vel_ned[2]
    _within(climb, PX4_THRUST_065_1S5_CLIMB_M_S)


def test_position_step_5m_settles_within_1m() -> None:
    dt = 0.002
    v = _hovering(dt)
    goal = (5.0, 0.0, -10.0)
    tgt = PositionTarget(pos_ned=goal, yaw=0.0)
    last_outside = 0.0
    overshoot = 0.0
    for i in range(round(8.0 / dt)):
        v.step(dt, tgt, True)
        s = v.state
        if math.dist(s.pos_ned, goal) >= 1.0:
            last_outside = (i + 1) * dt
        overshoot = max(overshoot, s.pos_ned[0] - goal[0])
    _within(last_outside, PX4_POS_STEP_5M_SETTLE_1M_S)
    # the velocity integral (which carried the drag during the move) bleeds off slowly
    assert overshoot < 1.0
    assert math.dist(v.state.pos_ned, goal) < 0.3


def test_takeoff_to_1m5_time_from_arming() -> None:
    """Arm and command AUTO.TAKEOFF (MIS_TAKEOFF_ALT) at t = 0: spool-up, ramp, climb."""
    p = ParamStore()
    v = make_vehicle("quad", p, seed=0)
    nav = Navigator(p)
    nav.takeoff(p["MIS_TAKEOFF_ALT"], v.state)
    dt, t = 0.004, 0.0
    t_15 = math.nan
    while t < 15.0 and not nav.reached:
        v.step(dt, nav.update(dt, v.state), True)
        t += dt
        if math.isnan(t_15) and -v.state.pos_ned[2] > 1.5:
            t_15 = t
    _within(t_15, PX4_TAKEOFF_1M5_FROM_ARM_S)
    assert nav.reached and -v.state.pos_ned[2] == pytest.approx(p["MIS_TAKEOFF_ALT"], abs=0.5)


def figure8_rms_error(dt: float = 0.002) -> float:
    """Position-only figure-8 (x = 5 sin phi, y = 2.5 sin 2 phi, z = -5, peak 6 m/s, phi' ramped
    with a smoothstep over 3 s); RMS horizontal error over the second lap [m]."""
    v = _hovering(dt, z=-5.0)
    w_max = 6.0 / math.hypot(5.0, 5.0)  # |d(x, y)/dphi| peaks at phi = 0: sqrt(25 + 25)
    phi, t = 0.0, 0.0
    sq, n = 0.0, 0
    while phi < 4.0 * math.pi:
        r = min(t / 3.0, 1.0)
        phi += w_max * r * r * (3.0 - 2.0 * r) * dt
        t += dt
        goal = (5.0 * math.sin(phi), 2.5 * math.sin(2.0 * phi), -5.0)
        v.step(dt, PositionTarget(pos_ned=goal), True)
        if phi >= 2.0 * math.pi:
            s = v.state
            sq += (s.pos_ned[0] - goal[0]) ** 2 + (s.pos_ned[1] - goal[1]) ** 2
            n += 1
    assert n > 1000
    return math.sqrt(sq / n)


def test_figure8_position_only_tracking_error() -> None:
    _within(figure8_rms_error(), PX4_FIGURE8_POSITION_ONLY_RMS_M)
