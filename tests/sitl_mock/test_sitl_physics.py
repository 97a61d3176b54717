"""Physics checks of the sitl_mock vehicle models against physical laws (issue 5 acceptance).

Oracles: Newton's laws with closed-form solutions (free fall with and without linear drag,
first-order motor lag, drift into the wind), conservation laws of a torque-free rigid body,
rotor geometry cross products (for the mixer), great-circle distance/bearing (for the geodetic
projection) and scipy's Rotation (for attitude conventions). The rover: test_sitl_rover.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from sitl_mock.flight_control import G, mix_quad_x, quat_from_euler
from sitl_mock.params import ParamStore
from sitl_mock.quad import Quadrotor
from sitl_mock.setpoints import AttitudeTarget, IdleTarget, PositionTarget
from sitl_mock.vehicle import DEFAULT_HOME, make_vehicle, ned_to_geodetic

LEVEL = (1.0, 0.0, 0.0, 0.0)


def _airborne(params: ParamStore, z: float = -50.0, motors: float = 0.0) -> Quadrotor:
    q = Quadrotor(params, seed=0)
    q.set_state(pos_ned=(0.0, 0.0, z), motors=motors)
    return q


def _rot(q_wxyz: tuple[float, float, float, float]) -> Rotation:
    w, x, y, z = q_wxyz
    return Rotation.from_quat([x, y, z, w])  # scipy is scalar-last


# ------------------------------------------------------------------------------ hover
def test_open_loop_true_hover_throttle_holds_altitude() -> None:
    """Collective m g / (4 T_max) (0.49 with the SIH defaults) neither climbs nor sinks."""
    p = ParamStore()
    hover = p["SIH_MASS"] * G / (4.0 * p["SIH_T_MAX"])
    assert hover == pytest.approx(0.49, abs=0.001)
    v = _airborne(p, z=-10.0, motors=hover)
    tgt = AttitudeTarget(q_wxyz=LEVEL, thrust_norm=hover)
    for _ in range(1250):  # 5 s at 250 Hz
        v.step(0.004, tgt, True)
    s = v.state
    assert abs(s.pos_ned[2] + 10.0) < 1e-3
    assert abs(s.vel_ned[2]) < 1e-4
    assert s.thrust_norm == pytest.approx(hover, abs=1e-6)


def test_open_loop_mpc_thr_hover_is_not_the_true_hover() -> None:
    """MPC_THR_HOVER (0.5) applied open loop climbs: the mock does not hide the mismatch."""
    p = ParamStore()
    v = _airborne(p, z=-10.0, motors=0.5)
    for _ in range(750):  # 3 s
        v.step(0.004, AttitudeTarget(q_wxyz=LEVEL, thrust_norm=0.5), True)
    # net upward force 4 * 5 * 0.5 - 9.80665 = 0.193 N against drag 1 N/(m/s)
    expected_vz = -(20.0 * 0.5 - G) / p["SIH_KDV"] * (1.0 - math.exp(-3.0))
    assert v.state.vel_ned[2] == pytest.approx(expected_vz, rel=0.03)


@pytest.mark.parametrize("thr_hover", [0.5, 0.6, 0.42])
def test_position_controller_holds_altitude_despite_hover_mismatch(thr_hover: float) -> None:
    """The vertical velocity integral absorbs MPC_THR_HOVER != true hover throttle (0.49)."""
    p = ParamStore({"MPC_THR_HOVER": thr_hover})
    v = _airborne(p, z=-10.0, motors=0.49)
    v.mark_airborne(0.49)
    tgt = PositionTarget(pos_ned=(0.0, 0.0, -10.0), yaw=0.0)
    zs = []
    for i in range(5000):  # 20 s
        v.step(0.004, tgt, True)
        if i >= 3750:
            zs.append(v.state.pos_ned[2])
    assert max(abs(z + 10.0) for z in zs) < 0.02
    assert v.state.thrust_norm == pytest.approx(0.49, abs=0.005)


# ------------------------------------------------------------------------------ free fall
def test_free_fall_without_drag_matches_g() -> None:
    p = ParamStore({"SIH_KDV": 0.0})
    v = _airborne(p, z=-100.0)
    for _ in range(2000):  # 2 s at 1 kHz, disarmed: no thrust
        v.step(0.001, IdleTarget(), False)
    s = v.state
    assert s.vel_ned[2] == pytest.approx(G * 2.0, rel=1e-9)
    assert s.pos_ned[2] == pytest.approx(-100.0 + 0.5 * G * 4.0, rel=1e-9)
    assert s.acc_ned[2] == pytest.approx(G, rel=1e-9)
    assert s.vel_ned[0] == 0.0 and s.vel_ned[1] == 0.0


def test_free_fall_with_linear_drag_matches_closed_form() -> None:
    """m dv/dt = m g - k v  =>  v = (m g / k)(1 - exp(-k t / m))."""
    p = ParamStore({"SIH_KDV": 0.7, "SIH_MASS": 1.4})
    m, k = 1.4, 0.7
    v = _airborne(p, z=-200.0)
    t = 3.0
    for _ in range(3000):
        v.step(0.001, IdleTarget(), False)
    s = v.state
    vt = m * G / k
    v_exact = vt * (1.0 - math.exp(-k * t / m))
    z_exact = -200.0 + vt * (t - m / k * (1.0 - math.exp(-k * t / m)))
    assert s.vel_ned[2] == pytest.approx(v_exact, rel=1e-3)
    assert s.pos_ned[2] == pytest.approx(z_exact, abs=5e-3)


def test_ground_contact_no_sinking_and_on_ground() -> None:
    p = ParamStore()
    v = _airborne(p, z=-2.0)
    zmax = -math.inf
    for _ in range(3000):
        v.step(0.001, IdleTarget(), False)
        zmax = max(zmax, v.state.pos_ned[2])
    s = v.state
    assert zmax <= 0.0
    assert s.pos_ned[2] == 0.0 and s.vel_ned == (0.0, 0.0, 0.0)
    assert s.on_ground and s.landed


def test_vehicle_starts_on_ground_and_stays_with_idle_motors() -> None:
    v = make_vehicle("quad", ParamStore(), seed=3)
    for _ in range(500):
        v.step(0.004, IdleTarget(), True)
    s = v.state
    assert s.on_ground and s.landed and s.pos_ned == (0.0, 0.0, 0.0)
    assert (s.lat_deg, s.lon_deg, s.alt_amsl_m) == pytest.approx(DEFAULT_HOME)


def test_ground_friction_stops_sliding() -> None:
    p = ParamStore()
    v = _airborne(p, z=-0.01)
    v.set_state(pos_ned=(0.0, 0.0, -0.01), vel_ned=(3.0, 0.0, 0.5))
    for _ in range(100):
        v.step(0.001, IdleTarget(), False)
    s = v.state
    assert s.on_ground and s.vel_ned == (0.0, 0.0, 0.0)
    # it slid only until touchdown: 0.01 m = 0.5 t + g t^2 / 2
    t_fall = (-0.5 + math.sqrt(0.25 + 2 * G * 0.01)) / G
    assert s.pos_ned[0] < 3.0 * (t_fall + 0.002)


# ------------------------------------------------------------------------------ rotation
def test_torque_free_rigid_body_conserves_energy_and_angular_momentum() -> None:
    """Zero thrust, no angular drag, asymmetric inertia: |L| (and L in the world), E constant."""
    p = ParamStore({"SIH_KDW": 0.0, "SIH_IXX": 0.02, "SIH_IYY": 0.035, "SIH_IZZ": 0.05})
    inertia = np.diag([0.02, 0.035, 0.05])
    v = _airborne(p, z=-1000.0)
    q0 = quat_from_euler(0.3, -0.2, 1.0)
    v.set_state(pos_ned=(0.0, 0.0, -1000.0), q_wxyz=q0, omega_frd=(2.0, 0.3, 1.5))

    def invariants() -> tuple[np.ndarray, float]:
        s = v.state
        w = np.array(s.omega_frd)
        l_world = _rot(s.q_wxyz).apply(inertia @ w)
        return l_world, 0.5 * float(w @ inertia @ w)

    l0, e0 = invariants()
    omegas = []
    for _ in range(5000):  # 5 s at 1 kHz
        v.step(0.001, IdleTarget(), False)
        omegas.append(v.state.omega_frd)
    l1, e1 = invariants()
    assert e1 == pytest.approx(e0, rel=1e-5)
    assert np.linalg.norm(l1) == pytest.approx(np.linalg.norm(l0), rel=1e-5)
    np.testing.assert_allclose(l1, l0, atol=2e-4 * float(np.linalg.norm(l0)))
    # the body rates do change (intermediate-axis motion), so this is not a trivial case
    om = np.array(omegas)
    assert np.ptp(om[:, 1]) > 0.5
    q = v.state.q_wxyz
    assert math.isclose(sum(c * c for c in q), 1.0, rel_tol=1e-12)


def test_angular_drag_decays_spin_exponentially() -> None:
    """I dw/dt = -kdw w about a principal axis: w = w0 exp(-kdw t / I)."""
    p = ParamStore()
    v = _airborne(p, z=-1000.0)
    v.set_state(pos_ned=(0.0, 0.0, -1000.0), omega_frd=(0.0, 0.0, 4.0))
    for _ in range(1000):
        v.step(0.001, IdleTarget(), False)
    expected = 4.0 * math.exp(-p["SIH_KDW"] * 1.0 / p["SIH_IZZ"])
    assert v.state.omega_frd[2] == pytest.approx(expected, rel=1e-4)


# ------------------------------------------------------------------------------ actuators
def test_motor_lag_is_first_order_with_sih_t_tau() -> None:
    p = ParamStore()
    tau = p["SIH_T_TAU"]
    v = _airborne(p, z=-50.0, motors=0.49)
    tgt = AttitudeTarget(q_wxyz=None, thrust_norm=0.8, body_rates_frd=(0.0, 0.0, 0.0))
    n = round(tau / 0.0005)
    for _ in range(n):
        v.step(0.0005, tgt, True)
    expected = 0.8 + (0.49 - 0.8) * math.exp(-1.0)
    assert v.state.thrust_norm == pytest.approx(expected, abs=2e-3)


def _rotor_effectiveness(p: ParamStore) -> np.ndarray:
    """Torque [N m] per unit motor command, from rotor positions and spin directions."""
    lr, lp, tmax, qmax = p["SIH_L_ROLL"], p["SIH_L_PITCH"], p["SIH_T_MAX"], p["SIH_Q_MAX"]
    # PX4 quad X: front-right, rear-left, front-left, rear-right; spin +1 = reaction torque +z
    pos = [(lp, lr, 0.0), (-lp, -lr, 0.0), (lp, -lr, 0.0), (-lp, lr, 0.0)]
    spin = [1.0, 1.0, -1.0, -1.0]
    cols = []
    for r, sgn in zip(pos, spin, strict=True):
        force = np.array([0.0, 0.0, -tmax])  # thrust along -z (up) in FRD
        cols.append(np.cross(np.array(r), force) + np.array([0.0, 0.0, sgn * qmax]))
    return np.array(cols).T


def test_mixer_realises_requested_torque_direction_and_thrust() -> None:
    p = ParamStore()
    eff = _rotor_effectiveness(p)
    rng = np.random.default_rng(7)
    for _ in range(50):
        torque = rng.uniform(-0.2, 0.2, 3)
        u = np.array(mix_quad_x((float(torque[0]), float(torque[1]), float(torque[2])), 0.5))
        assert np.all(u >= 0.0) and np.all(u <= 1.0)
        assert u.mean() == pytest.approx(0.5, abs=1e-12)
        realised = eff @ u
        # per-axis positive scaling (PX4-normalised): same signs, proportional per axis
        scale = np.array(
            [
                4 * math.sqrt(0.5) * p["SIH_L_ROLL"] * p["SIH_T_MAX"],
                4 * math.sqrt(0.5) * p["SIH_L_PITCH"] * p["SIH_T_MAX"],
                4 * p["SIH_Q_MAX"],
            ]
        )
        np.testing.assert_allclose(realised, torque * scale, atol=1e-12)


def test_mixer_saturation_keeps_outputs_in_range_and_roll_priority() -> None:
    u = mix_quad_x((1.0, 0.0, 1.0), 0.9)
    assert all(0.0 <= c <= 1.0 for c in u)
    # roll is realised (left motors 1, 2 above right motors 0, 3)
    assert min(u[1], u[2]) > max(u[0], u[3])
    assert mix_quad_x((0.0, 0.0, 0.0), 1.7) == (1.0, 1.0, 1.0, 1.0)
    assert mix_quad_x((0.0, 0.0, 0.0), -1.0) == (0.0, 0.0, 0.0, 0.0)


def test_mixer_without_airmode_never_raises_the_collective() -> None:
    """PX4's sequential desaturation, worked by hand for a full right roll at 0.3 collective:
    the linear mix is 0.3 -/+ 0.707 per motor. Without airmode (PX4's default MC_AIRMODE 0)
    the collective may not rise, so roll is scaled down until the low motors reach 0: 0 and
    0.6, the collective kept. Airmode 1 raises the collective instead: after the two passes
    the mix sits around 0.5 and roll fills [0, 1]."""
    u = mix_quad_x((1.0, 0.0, 0.0), 0.3)
    assert u == pytest.approx((0.0, 0.6, 0.6, 0.0), abs=1e-12)
    u = mix_quad_x((1.0, 0.0, 0.0), 0.3, airmode=1)
    assert u == pytest.approx((0.0, 1.0, 1.0, 0.0), abs=1e-12)
    # near full collective the collective is lowered: a full roll at 0.9 (0.19 / 1.61) is at
    # -0.21 / 1.21 after the two thrust passes, and [0, 1] after the roll pass
    assert mix_quad_x((1.0, 0.0, 0.0), 0.9) == pytest.approx((0.0, 1.0, 1.0, 0.0), abs=1e-12)
    # yaw (PX4's mixYaw): a full yaw at 0.95 (1.95 / -0.05) is scaled to fit [0, 1.15] (1.15 /
    # 0.75), then the collective lowered to fit [0, 1]
    u = mix_quad_x((0.0, 0.0, 1.0), 0.95)
    assert sum(u) / 4 == pytest.approx(0.80, abs=1e-12)
    assert u[0] == u[1] == 1.0 and u[2] == u[3] == pytest.approx(0.6, abs=1e-12)


def test_torque_signs_follow_frd_conventions() -> None:
    """Positive rate commands produce positive body rates (right roll, nose up, clockwise yaw)."""
    p = ParamStore()
    for axis in range(3):
        v = _airborne(p, z=-50.0, motors=0.49)
        rates = [0.0, 0.0, 0.0]
        rates[axis] = 0.5
        tgt = AttitudeTarget(
            q_wxyz=None, thrust_norm=0.49, body_rates_frd=(rates[0], rates[1], rates[2])
        )
        for _ in range(250):
            v.step(0.004, tgt, True)
        w = v.state.omega_frd
        # yaw authority is weak (SIH_Q_MAX) and the yaw rate loop slow, so only ~0.45 after 1 s
        assert w[axis] == pytest.approx(0.5, abs=0.05 if axis < 2 else 0.1)
        assert all(abs(w[i]) < 0.05 for i in range(3) if i != axis)
        ref = _rot(v.state.q_wxyz).as_euler("ZYX")  # yaw, pitch, roll
        assert ref[[2, 1, 0][axis]] > 0.2


# ------------------------------------------------------------------------------ wind
def test_wind_drags_the_vehicle_along() -> None:
    """Level, weight-balancing thrust in a 4 m/s north wind: v_n = 4 (1 - exp(-k t / m))."""
    p = ParamStore()
    v = _airborne(p, z=-50.0, motors=0.49)
    v.set_wind((4.0, 0.0, 0.0))
    hover = G / 20.0
    for _ in range(1000):  # 2 s at 500 Hz
        v.step(0.002, AttitudeTarget(q_wxyz=LEVEL, thrust_norm=hover), True)
    assert v.state.vel_ned[0] == pytest.approx(4.0 * (1.0 - math.exp(-2.0)), rel=5e-3)


def test_position_hold_in_wind() -> None:
    p = ParamStore()
    v = _airborne(p, z=-10.0, motors=0.49)
    v.mark_airborne(0.49)
    v.set_wind((0.0, 3.0, 0.0))
    tgt = PositionTarget(pos_ned=(0.0, 0.0, -10.0), yaw=0.0)
    for _ in range(5000):
        v.step(0.004, tgt, True)
    s = v.state
    assert math.dist(s.pos_ned, (0.0, 0.0, -10.0)) < 0.1
    # it must lean into the wind (toward -east): roll negative
    roll = _rot(s.q_wxyz).as_euler("ZYX")[2]
    assert roll < -math.radians(5.0)


# ------------------------------------------------------------------------------ noise & determinism
def test_seeded_noise_is_deterministic_and_seed_dependent() -> None:
    def run(seed: int) -> tuple[float, ...]:
        p = ParamStore({"SIM_POS_NOISE": 0.05, "SIM_VEL_NOISE": 0.05, "SIM_GYRO_NOISE": 0.01})
        v = Quadrotor(p, seed=seed)
        v.set_state(pos_ned=(0.0, 0.0, -5.0), motors=0.49)
        v.mark_airborne(0.49)
        for _ in range(500):
            v.step(0.004, PositionTarget(pos_ned=(1.0, 0.0, -5.0)), True)
        s = v.state
        return (*s.pos_ned, *s.vel_ned, *s.q_wxyz)

    a, b, c = run(1), run(1), run(2)
    assert a == b
    assert a != c
    assert all(math.isfinite(x) for x in a)


# ------------------------------------------------------------------------------ geodesy
def test_geodetic_projection_is_azimuthal_equidistant() -> None:
    """Great-circle distance from home equals the local range, bearing equals atan2(e, n)."""
    home = (47.397742, 8.545594, 488.0)
    r_earth = 6371000.0
    for n, e, d in [(100.0, 0.0, -10.0), (0.0, -250.0, 0.0), (1234.0, 987.0, -50.0)]:
        lat, lon, alt = ned_to_geodetic((n, e, d), home)
        p1, p2 = math.radians(home[0]), math.radians(lat)
        dl = math.radians(lon - home[1])
        hav = math.sin((p2 - p1) / 2) ** 2 + math.cos(p1) * math.cos(p2) * math.sin(dl / 2) ** 2
        dist = 2 * r_earth * math.asin(math.sqrt(hav))
        bearing = math.atan2(
            math.sin(dl) * math.cos(p2),
            math.cos(p1) * math.sin(p2) - math.sin(p1) * math.cos(p2) * math.cos(dl),
        )
        assert dist == pytest.approx(math.hypot(n, e), rel=1e-9)
        assert math.remainder(bearing - math.atan2(e, n), 2 * math.pi) == pytest.approx(0, abs=1e-9)
        assert alt == pytest.approx(home[2] - d)


def test_attitude_helpers_match_scipy() -> None:
    rng = np.random.default_rng(3)
    for _ in range(20):
        roll, pitch, yaw = rng.uniform(-1.2, 1.2, 3)
        q = quat_from_euler(float(roll), float(pitch), float(yaw))
        ref = Rotation.from_euler("ZYX", [yaw, pitch, roll])
        assert abs(float(np.dot(_rot(q).as_quat(), ref.as_quat()))) == pytest.approx(1.0, abs=1e-12)


# ------------------------------------------------------------------------------ rover
# (the Ackermann rover's physics and control: tests/sitl_mock/test_sitl_rover.py)


def test_bad_step_rejected() -> None:
    v = make_vehicle("quad", ParamStore())
    for bad in (0.0, -0.001, math.nan, 2.0):
        with pytest.raises(ValueError):
            v.step(bad, IdleTarget(), False)
    with pytest.raises(ValueError):
        make_vehicle("plane", ParamStore())


def test_long_steps_are_substepped_and_match_fine_steps() -> None:
    """A 20 ms step is integrated as 5 x 4 ms: same trajectory as stepping at 250 Hz."""

    def fly(dt: float) -> tuple[float, ...]:
        v = Quadrotor(ParamStore(), seed=0)
        v.set_state(pos_ned=(0.0, 0.0, -10.0), motors=0.49)
        v.mark_airborne(0.49)
        tgt = PositionTarget(pos_ned=(3.0, -2.0, -12.0), yaw=1.0)
        for _ in range(round(6.0 / dt)):
            v.step(dt, tgt, True)
        s = v.state
        return (*s.pos_ned, *s.vel_ned, s.t_s)

    coarse, fine = fly(0.02), fly(0.004)
    np.testing.assert_allclose(coarse, fine, atol=1e-9)
    assert math.dist(coarse[:3], (3.0, -2.0, -12.0)) < 0.3


def test_fast_state_constructor_equals_dataclass_init() -> None:
    from sitl_mock.vehicle import VehicleState, make_state

    args = (
        1.5, (1.0, 2.0, -3.0), (0.1, 0.2, 0.3), (0.0, 0.0, 9.8), (1.0, 0.0, 0.0, 0.0),
        (0.01, 0.02, 0.03), False, False, 0.49, 0.9, True, (47.0, 8.0, 400.0),
    )  # fmt: skip
    fast, ref = make_state(*args), VehicleState(*args)
    assert fast == ref and repr(fast) == repr(ref) and hash(fast) == hash(ref)
    with pytest.raises(AttributeError):
        fast.t_s = 2.0  # type: ignore[misc]
    assert fast.alt_amsl_m == pytest.approx(403.0)


def test_estimator_errors_are_slow_of_the_configured_std_and_off_by_default() -> None:
    """SIM_EST_XY_STD / SIM_EST_VXY_STD / SIM_EST_XY_TAU: the reported (and controlled)
    horizontal position and velocity are off the true ones by slowly varying errors of the
    configured std (as EKF2's on PX4 SITL); altitude and the default are exact."""
    def hover(overrides: dict[str, float], seconds: float) -> tuple[np.ndarray, ...]:
        v = Quadrotor(ParamStore(overrides), seed=4)
        v.set_state(pos_ned=(0.0, 0.0, -5.0), motors=0.49)
        v.mark_airborne(0.49)
        tgt = PositionTarget(pos_ned=(0.0, 0.0, -5.0), yaw=0.0)
        est, tru, vest, vtru = [], [], [], []
        for k in range(round(seconds / 0.004)):
            v.step(0.004, tgt, True)
            if k % 5 == 4:  # every 20 ms (after a position-loop tick)
                s = v.state
                est.append(s.pos_ned)
                tru.append(v.true_pos_ned)
                vest.append(s.vel_ned)
                vtru.append(v.true_vel_ned)
        return np.array(est), np.array(tru), np.array(vest), np.array(vtru)

    est, tru, vest, vtru = hover({}, 5.0)
    assert np.array_equal(est, tru) and np.array_equal(vest, vtru)
    std_p, std_v, tau = 0.3, 0.2, 1.0
    est, tru, vest, vtru = hover(
        {"SIM_EST_XY_STD": std_p, "SIM_EST_VXY_STD": std_v, "SIM_EST_XY_TAU": tau}, 300.0)
    err, verr = est - tru, vest - vtru
    assert np.all(err[:, 2] == 0.0) and np.all(verr[:, 2] == 0.0)
    lag = round(0.1 / 0.02)
    for axis in (0, 1):
        for e, std in ((err[:, axis], std_p), (verr[:, axis], std_v)):
            assert float(np.std(e)) == pytest.approx(std, rel=0.3)
            # slowly varying: (1 + t/tau) exp(-t/tau) = 0.995 after 0.1 s
            assert float(np.corrcoef(e[:-lag], e[lag:])[0, 1]) > 0.95
    # independent errors (as measured on PX4): no correlation between position and velocity
    assert abs(float(np.corrcoef(err[:, 0], verr[:, 0])[0, 1])) < 0.3
