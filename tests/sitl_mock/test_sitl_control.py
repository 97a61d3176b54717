"""PX4-like control cascade of the mock quadrotor: setpoint semantics and limits.

Attitudes are checked with scipy's Rotation (independent attitude math); targets are tracked to
physically meaningful tolerances; limits (tilt, velocity) are checked on the whole trajectory.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from sitl_mock.flight_control import (
    G,
    McGains,
    attitude_control,
    body_z_to_attitude,
    quat_from_euler,
)
from sitl_mock.params import ParamStore
from sitl_mock.quad import Quadrotor
from sitl_mock.setpoints import AttitudeTarget, IdleTarget, PositionTarget
from sitl_mock.vehicle import make_vehicle

DT = 0.004
NAN = math.nan


def _rot(q: tuple[float, float, float, float]) -> Rotation:
    return Rotation.from_quat([q[1], q[2], q[3], q[0]])


def _hovering(params: ParamStore | None = None, z: float = -10.0) -> Quadrotor:
    v = Quadrotor(params or ParamStore(), seed=0)
    v.set_state(pos_ned=(0.0, 0.0, z), motors=0.49)
    v.mark_airborne(0.49)
    tgt = PositionTarget(pos_ned=(0.0, 0.0, z), yaw=0.0)
    for _ in range(500):
        v.step(DT, tgt, True)
    return v


def _run(v: Quadrotor, tgt: object, seconds: float) -> list[tuple[float, ...]]:
    out: list[tuple[float, ...]] = []
    for _ in range(round(seconds / DT)):
        v.step(DT, tgt, True)  # type: ignore[arg-type]
        s = v.state
        out.append((*s.pos_ned, *s.vel_ned, *s.q_wxyz))
    return out


def _tilt_deg(q: tuple[float, ...]) -> float:
    z_body = _rot((q[0], q[1], q[2], q[3])).apply([0.0, 0.0, 1.0])
    return math.degrees(math.acos(max(-1.0, min(1.0, z_body[2]))))


# ------------------------------------------------------------------------------ attitude math
def test_body_z_to_attitude_matches_scipy() -> None:
    rng = np.random.default_rng(11)
    for _ in range(30):
        bz = rng.normal(size=3)
        bz[2] = abs(bz[2]) + 0.2
        bz /= np.linalg.norm(bz)
        yaw = float(rng.uniform(-3.0, 3.0))
        q = body_z_to_attitude((float(bz[0]), float(bz[1]), float(bz[2])), yaw)
        r = _rot(q)
        np.testing.assert_allclose(r.apply([0.0, 0.0, 1.0]), bz, atol=1e-12)
        # heading: the body x axis projected on the horizontal plane points along yaw,
        # i.e. it is perpendicular to the yaw frame's y axis
        bx = r.apply([1.0, 0.0, 0.0])
        assert abs(bx[0] * -math.sin(yaw) + bx[1] * math.cos(yaw)) < 1e-12
        assert bx[0] * math.cos(yaw) + bx[1] * math.sin(yaw) > 0.0


def test_attitude_controller_rate_points_toward_setpoint() -> None:
    """For small errors the rate setpoint is ~ K * rotation vector of q^-1 q_sp (body frame)."""
    g = McGains.from_params(ParamStore())
    rng = np.random.default_rng(5)
    for _ in range(20):
        q = quat_from_euler(*(float(a) for a in rng.uniform(-0.5, 0.5, 3)))
        err = rng.normal(size=3) * 0.02
        q_sp_r = _rot(q) * Rotation.from_rotvec(err)
        x, y, z, w = q_sp_r.as_quat()
        rate = np.array(attitude_control(g, q, (w, x, y, z), NAN))
        # roll/pitch gains 6.5; yaw gain MC_YAW_P (its weight cancels for small errors)
        gains = np.array([g.att_p[0], g.att_p[1], g.att_p[2] * g.yaw_w])
        tol = 0.02 * float(np.linalg.norm(gains * err))
        np.testing.assert_allclose(rate, gains * err, atol=tol)


# ------------------------------------------------------------------------------ attitude targets
def test_attitude_target_is_tracked() -> None:
    rng = np.random.default_rng(2)
    for _ in range(3):
        v = _hovering()
        roll, pitch, yaw = rng.uniform(-0.4, 0.4), rng.uniform(-0.4, 0.4), rng.uniform(-2, 2)
        q_sp = quat_from_euler(float(roll), float(pitch), float(yaw))
        _run(v, AttitudeTarget(q_wxyz=q_sp, thrust_norm=0.5), 3.0)
        err = (_rot(v.state.q_wxyz).inv() * _rot(q_sp)).magnitude()
        assert math.degrees(err) < 1.0


def test_attitude_target_yaw_rate_feed_forward() -> None:
    """A yaw setpoint turning at 0.5 rad/s is followed with less lag with its rate fed forward."""

    def lag(ff: float) -> float:
        v = _hovering()
        yaw_sp = 0.0
        for _ in range(round(3.0 / DT)):
            yaw_sp += 0.5 * DT
            tgt = AttitudeTarget(
                q_wxyz=quat_from_euler(0.0, 0.0, yaw_sp), thrust_norm=0.49, yaw_rate_ff=ff
            )
            v.step(DT, tgt, True)
        return math.remainder(yaw_sp - v.state.yaw, 2 * math.pi)

    lag_ff, lag_none = lag(0.5), lag(NAN)
    assert lag_none > 0.0
    assert abs(lag_ff) < 0.5 * lag_none


def test_body_rates_target_and_rates_win_over_q() -> None:
    # the controller's law to 0.02 rad/s: without SIH's gyro noise (test_sitl_gyro.py has it)
    v = _hovering(ParamStore({"SIM_GYRO_SIH": 0.0}))
    level = (1.0, 0.0, 0.0, 0.0)
    both = AttitudeTarget(q_wxyz=level, thrust_norm=0.49, body_rates_frd=(0.0, 0.0, 0.8))
    _run(v, both, 3.0)
    assert v.state.omega_frd[2] == pytest.approx(0.8, abs=0.05)
    only_thrust = AttitudeTarget(q_wxyz=None, thrust_norm=0.49)
    _run(v, only_thrust, 2.0)
    w = v.state.omega_frd
    assert abs(w[0]) < 0.02 and abs(w[1]) < 0.02 and abs(w[2]) < 0.06  # yaw decays slowly
    report = v.last_attitude_target
    assert report[1] == (0.0, 0.0, 0.0) and report[2] == pytest.approx(0.49)


def test_attitude_thrust_is_not_hover_scaled() -> None:
    """thrust_norm is the fraction of the total max thrust (20 N): 0.49 holds a 1 kg vehicle."""
    v = _hovering()
    z0 = v.state.pos_ned[2]
    _run(v, AttitudeTarget(q_wxyz=(1.0, 0.0, 0.0, 0.0), thrust_norm=G / 20.0), 3.0)
    assert abs(v.state.pos_ned[2] - z0) < 0.05


# ------------------------------------------------------------------------------ position targets
def test_velocity_only_target() -> None:
    """Tracked; the drag (KDV v) is taken up by the velocity integral, slowly, like PX4 + SIH.
    (The error shrinks monotonically second by second: without SIH's gyro noise.)"""
    v = _hovering(ParamStore({"SIM_GYRO_SIH": 0.0}))
    z0 = v.state.pos_ned[2]
    rows = _run(v, PositionTarget(vel_ned=(2.0, -1.0, 0.0), yaw=0.0), 20.0)
    s = v.state
    np.testing.assert_allclose(s.vel_ned, (2.0, -1.0, 0.0), atol=0.05)
    assert abs(s.pos_ned[2] - z0) < 0.1
    errs = [math.hypot(r[3] - 2.0, r[4] + 1.0) for r in rows[::250]]
    assert all(b <= a + 1e-3 for a, b in itertools.pairwise(errs[2:]))


def test_vertical_velocity_target_with_hold_xy() -> None:
    v = _hovering()
    _run(v, PositionTarget(pos_ned=(0.0, 0.0, NAN), vel_ned=(NAN, NAN, -1.0)), 4.0)
    s = v.state
    assert s.vel_ned[2] == pytest.approx(-1.0, abs=0.05)
    assert math.hypot(s.pos_ned[0], s.pos_ned[1]) < 0.05


def test_acceleration_only_target_reaches_drag_terminal_speed() -> None:
    """An acceleration setpoint of 1 m/s^2 against drag KDV/m = 1/s ends near 1 m/s."""
    v = _hovering()
    _run(v, PositionTarget(acc_ned=(1.0, 0.0, NAN), vel_ned=(NAN, NAN, 0.0), yaw=0.0), 6.0)
    vn = v.state.vel_ned[0]
    assert vn == pytest.approx(1.0 * (1.0 - math.exp(-6.0)), abs=0.1)


def test_position_with_feed_forward_tracks_better_than_position_only() -> None:
    def err(use_ff: bool) -> float:
        v = _hovering()
        w, a = 0.6, 4.0
        total, n = 0.0, 0
        for i in range(round(12.0 / DT)):
            t = (i + 1) * DT
            p = (a * math.sin(w * t), 0.0, -10.0)
            vel = (a * w * math.cos(w * t), 0.0, 0.0) if use_ff else (NAN, NAN, NAN)
            acc = (-a * w * w * math.sin(w * t), 0.0, 0.0) if use_ff else (NAN, NAN, NAN)
            v.step(DT, PositionTarget(pos_ned=p, vel_ned=vel, acc_ned=acc, yaw=0.0), True)
            if t > 6.0:
                total += (v.state.pos_ned[0] - p[0]) ** 2
                n += 1
        return math.sqrt(total / n)

    e_ff, e_pos = err(True), err(False)
    # PX4's feed-forward does not know the SIH drag, so a velocity lag remains
    assert e_ff < 0.5 * e_pos


def test_yaw_and_yaw_rate_targets() -> None:
    v = _hovering()
    _run(v, PositionTarget(pos_ned=(0.0, 0.0, -10.0), yaw=math.radians(90.0)), 4.0)
    assert math.degrees(v.state.yaw) == pytest.approx(90.0, abs=1.0)
    y0 = v.state.yaw
    _run(v, PositionTarget(pos_ned=(0.0, 0.0, -10.0), yaw_rate=0.4), 2.0)
    turned = math.remainder(v.state.yaw - y0, 2 * math.pi)
    assert turned == pytest.approx(0.8, abs=0.15)
    assert v.state.omega_frd[2] == pytest.approx(0.4, abs=0.05)
    # no yaw given: the heading is held
    y1 = v.state.yaw
    _run(v, PositionTarget(pos_ned=(3.0, 0.0, -10.0)), 3.0)
    assert abs(math.remainder(v.state.yaw - y1, 2 * math.pi)) < math.radians(3.0)


def test_tilt_and_velocity_limits_on_a_far_position_step() -> None:
    p = ParamStore()
    v = _hovering(p)
    rows = _run(v, PositionTarget(pos_ned=(200.0, 50.0, -10.0), yaw=0.0), 10.0)
    tilts = [_tilt_deg(r[6:10]) for r in rows]
    speeds = [math.hypot(r[3], r[4]) for r in rows]
    assert max(tilts) <= p["MPC_TILTMAX_AIR"] + 5.0  # attitude overshoot of the limited setpoint
    assert max(tilts) > 0.5 * p["MPC_TILTMAX_AIR"]  # the limit is actually reached/approached
    assert max(speeds) <= p["MPC_XY_VEL_MAX"] * 1.05
    assert max(speeds) > 0.8 * p["MPC_XY_VEL_MAX"]
    # altitude is prioritised over horizontal acceleration
    assert max(abs(r[2] + 10.0) for r in rows) < 1.0


def test_tilt_setpoint_is_limited() -> None:
    p = ParamStore()
    v = _hovering(p)
    worst = 0.0
    for _ in range(round(4.0 / DT)):
        v.step(DT, PositionTarget(pos_ned=(200.0, -300.0, -10.0), yaw=1.0), True)
        worst = max(worst, _tilt_deg(v.last_attitude_target[0]))
    assert worst == pytest.approx(p["MPC_TILTMAX_AIR"], abs=1e-6)


def test_vertical_speed_limits() -> None:
    p = ParamStore()
    v = _hovering(p, z=-40.0)
    up = _run(v, PositionTarget(pos_ned=(0.0, 0.0, -80.0)), 6.0)
    assert min(r[5] for r in up) >= -p["MPC_Z_VEL_MAX_UP"] - 0.1
    down = _run(v, PositionTarget(pos_ned=(0.0, 0.0, -20.0)), 12.0)
    assert max(r[5] for r in down) <= p["MPC_Z_VEL_MAX_DN"] + 0.1


def test_params_take_effect_on_the_fly() -> None:
    p = ParamStore()
    v = _hovering(p)
    p.set("MPC_XY_VEL_MAX", 2.0)
    rows = _run(v, PositionTarget(pos_ned=(50.0, 0.0, -10.0), yaw=0.0), 6.0)
    assert max(math.hypot(r[3], r[4]) for r in rows) < 2.1


# ------------------------------------------------------------------------------ takeoff / landing
def test_armed_on_ground_idles_until_a_climb_is_requested() -> None:
    p = ParamStore()
    v = make_vehicle("quad", p, seed=0)
    assert isinstance(v, Quadrotor)
    for _ in range(round(3.0 / DT)):  # ground-level position target: stays landed, motors idle
        v.step(DT, PositionTarget(pos_ned=(0.0, 0.0, 0.0)), True)
    s = v.state
    assert s.landed and s.on_ground and s.thrust_norm == 0.0
    assert v.takeoff_state == "ready_for_takeoff"
    t_lift = math.nan
    for i in range(round(6.0 / DT)):
        v.step(DT, PositionTarget(pos_ned=(0.0, 0.0, -3.0)), True)
        if math.isnan(t_lift) and not v.state.on_ground:
            t_lift = (i + 1) * DT
    assert 0.5 < t_lift < p["MPC_TKO_RAMP_T"]  # the thrust ramp, not a jump
    assert v.state.pos_ned[2] == pytest.approx(-3.0, abs=0.3)
    assert v.takeoff_state == "flight"


def test_spool_up_after_arming() -> None:
    p = ParamStore()
    v = make_vehicle("quad", p, seed=0)
    tgt = PositionTarget(pos_ned=(0.0, 0.0, -3.0))
    for _ in range(round(0.9 * p["COM_SPOOLUP_TIME"] / DT)):
        v.step(DT, tgt, True)
        assert v.state.thrust_norm == 0.0
    assert v.takeoff_state == "spoolup"  # type: ignore[attr-defined]


def test_descent_lands_and_land_detector_triggers() -> None:
    v = _hovering(z=-2.0)
    tgt = PositionTarget(pos_ned=(0.0, 0.0, NAN), vel_ned=(NAN, NAN, 0.7))
    t_touch = t_landed = math.nan
    for i in range(round(8.0 / DT)):
        v.step(DT, tgt, True)
        s = v.state
        if math.isnan(t_touch) and s.on_ground:
            t_touch = (i + 1) * DT
        if math.isnan(t_landed) and s.landed:
            t_landed = (i + 1) * DT
    assert not math.isnan(t_touch) and not math.isnan(t_landed)
    assert 0.4 <= t_landed - t_touch <= 4.0
    assert v.state.landed and v.state.thrust_norm < 0.05  # back to idle once landed


def test_disarm_cuts_motors_and_idle_target() -> None:
    v = _hovering()
    v.step(DT, IdleTarget(), True)
    for _ in range(50):
        v.step(DT, IdleTarget(), True)
    assert v.state.thrust_norm < 0.1
    assert v.last_position_target is None


def test_last_targets_reported() -> None:
    v = _hovering()
    tgt = PositionTarget(pos_ned=(1.0, 2.0, -10.0), yaw=0.5)
    _run(v, tgt, 0.5)
    assert v.last_position_target == tgt
    q, rates, thrust = v.last_attitude_target
    assert math.isclose(sum(c * c for c in q), 1.0, rel_tol=1e-9)
    assert 0.0 < thrust <= 1.0 and all(math.isfinite(r) for r in rates)


def test_nan_and_garbage_targets_never_produce_nan_state() -> None:
    v = _hovering()
    targets = [
        PositionTarget(),
        PositionTarget(pos_ned=(NAN, 1.0, NAN)),
        AttitudeTarget(q_wxyz=None, thrust_norm=NAN, body_rates_frd=(NAN, 0.1, NAN)),
        AttitudeTarget(q_wxyz=(1.0, 0.0, 0.0, 0.0), thrust_norm=5.0),
        AttitudeTarget(q_wxyz=(NAN, 0.0, 0.0, 1.0), thrust_norm=0.5, yaw_rate_ff=math.inf),
        AttitudeTarget(q_wxyz=(0.0, 0.0, 0.0, 0.0), thrust_norm=0.5),
        AttitudeTarget(q_wxyz=(2.0, 0.0, 0.0, 0.0), thrust_norm=-math.inf),
        PositionTarget(pos_ned=(1e300, -1e300, 1e300), yaw=math.inf),
        PositionTarget(vel_ned=(math.inf, 1e308, -1e308), acc_ned=(1e300, NAN, -1e300)),
        PositionTarget(acc_ned=(1e30, 1e30, 1e30), yaw_rate=1e30),
        PositionTarget(pos_ned=(0.0, 0.0, -10.0)),
    ]
    for tgt in targets:
        _run(v, tgt, 0.2)
        s = v.state
        assert all(math.isfinite(c) for c in (*s.pos_ned, *s.vel_ned, *s.q_wxyz, *s.omega_frd))
        q, rates, thrust = v.last_attitude_target
        assert all(math.isfinite(c) for c in (*q, *rates, thrust))


def test_reset_integrators_keeps_flying() -> None:
    v = _hovering()
    v.reset_integrators()
    _run(v, PositionTarget(pos_ned=(0.0, 0.0, -10.0), yaw=0.0), 5.0)
    assert abs(v.state.pos_ned[2] + 10.0) < 0.05


def test_takeoff_ramp_limits_tilt_and_allows_zero_thrust() -> None:
    """PX4: MPC_TILTMAX_LND (12 deg) and no MPC_THR_MIN floor until the takeoff ramp is done."""
    p = ParamStore()
    v = make_vehicle("quad", p, seed=0)
    assert isinstance(v, Quadrotor)
    tgt = PositionTarget(pos_ned=(20.0, 0.0, -3.0))
    ramp_tilts, ramp_thrusts, flight_tilts = [], [], []
    for _ in range(round(8.0 / DT)):
        v.step(DT, tgt, True)
        q, _, thrust = v.last_attitude_target
        if v.takeoff_state == "rampup":
            ramp_tilts.append(_tilt_deg(q))
            ramp_thrusts.append(thrust)
        elif v.takeoff_state == "flight":
            flight_tilts.append(_tilt_deg(q))
    assert ramp_tilts and flight_tilts
    assert max(ramp_tilts) <= p["MPC_TILTMAX_LND"] + 1e-6
    assert min(ramp_thrusts) < p["MPC_THR_MIN"]
    assert max(flight_tilts) > p["MPC_TILTMAX_LND"] + 5.0
