"""Time allocation under limits and the `check` report, verified by dense sampling with the
quantities recomputed here (tilt and thrust from the specific force a - g e3 + D v / m, rover
yaw rate from finite differences of the heading), not through the planner's own code."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.flatness import MultirotorParams, multirotor_setpoint
from companion.trajectory import Limits, PiecewiseBezier, RoverLimits, check, plan, plan_with_info

G = 9.80665
PARAMS = MultirotorParams(mass=1.5, inertia=np.diag([0.03, 0.03, 0.05]), drag=0.4)
MG = PARAMS.mass * G
VMAX, AMAX = 5.0, 4.0
LIMITS = Limits(
    max_speed_m_s=VMAX,
    max_acc_m_s2=AMAX,
    max_jerk_m_s3=30.0,
    max_tilt_rad=0.4,
    max_thrust_n=1.5 * MG,
    min_thrust_n=0.6 * MG,
    max_body_rate_rad_s=3.0,
)


def random_waypoints(rng: np.random.Generator, n: int = 10) -> np.ndarray:
    """n waypoints, consecutive ones 1..3 x max_speed^2 / max_acc apart, random 3-D turns."""
    pts = [rng.uniform(-5.0, 5.0, 3)]
    while len(pts) < n:
        step = rng.normal(size=3)
        step[2] *= 0.3
        step *= rng.uniform(1.0, 3.0) * VMAX**2 / AMAX / np.linalg.norm(step)
        pts.append(pts[-1] + step)
    return np.array(pts)


def dense(traj: PiecewiseBezier, order: int, per_segment: int = 200) -> np.ndarray:
    """Derivative samples via each segment's own de Casteljau evaluation."""
    out = []
    for seg in traj.segments:
        out.append(seg.evaluate(np.linspace(0.0, seg.duration, per_segment), order))
    return np.concatenate(out)


@pytest.mark.parametrize("seed", range(5))
def test_time_allocation_meets_every_limit_and_the_duration_bound(seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    wp = random_waypoints(rng)
    res = plan_with_info(wp, limits=LIMITS, params=PARAMS, yaw=float(rng.uniform(-3, 3)))
    tr = res.trajectory
    # waypoints are hit, in order
    np.testing.assert_allclose(tr.evaluate(res.waypoint_times), wp, atol=1e-9)
    assert np.all(np.diff(res.waypoint_times) > 0)
    v, a, j = dense(tr, 1), dense(tr, 2), dense(tr, 3)
    tol = 1.0 + 1e-9
    assert np.max(np.linalg.norm(v, axis=1)) <= VMAX * tol
    assert np.max(np.linalg.norm(a, axis=1)) <= AMAX * tol
    assert np.max(np.linalg.norm(j, axis=1)) <= 30.0 * tol
    # specific force f = a - g e3 + D v / m; thrust is -m f, tilt is the angle of -f from down
    f = a + PARAMS.drag * v / PARAMS.mass
    f[:, 2] -= G
    thrust = PARAMS.mass * np.linalg.norm(f, axis=1)
    tilt = np.arccos(np.clip(-f[:, 2] / np.linalg.norm(f, axis=1), -1.0, 1.0))
    assert np.max(tilt) <= 0.4 * tol
    assert np.max(thrust) <= 1.5 * MG * tol
    assert np.min(thrust) >= 0.6 * MG / tol
    # body rates through the flatness module (yaw channel included)
    assert tr.yaw is not None
    yaw = np.concatenate(
        [s.evaluate(np.linspace(0, s.duration, 200))[:, 0] for s in tr.yaw.segments]
    )
    sp = multirotor_setpoint(v, a, j, dense(tr, 4), yaw, 0.0 * yaw, 0.0 * yaw, PARAMS)
    assert np.max(np.linalg.norm(sp.omega_frd, axis=1)) <= 3.0 * tol
    polyline = float(np.sum(np.linalg.norm(np.diff(wp, axis=0), axis=1)))
    assert tr.duration <= 1.5 * polyline / VMAX + 2.0 * VMAX / AMAX
    # and check() agrees: nothing exceeded
    assert not any(r.exceeded for r in check(tr, LIMITS, PARAMS).values())


def test_time_allocation_with_nonzero_start_velocity_and_velocity_yaw() -> None:
    rng = np.random.default_rng(3)
    wp = random_waypoints(rng, n=6)
    v0 = (wp[1] - wp[0]) / np.linalg.norm(wp[1] - wp[0]) * 2.0
    lim = Limits(max_speed_m_s=VMAX, max_acc_m_s2=AMAX)
    tr = plan(wp, limits=lim, start={1: v0}, yaw="velocity")
    np.testing.assert_allclose(tr.evaluate(0.0, 1), v0, atol=1e-9)
    assert np.max(np.linalg.norm(dense(tr, 1), axis=1)) <= VMAX * (1 + 1e-9)
    assert np.max(np.linalg.norm(dense(tr, 2), axis=1)) <= AMAX * (1 + 1e-9)


def test_rover_time_allocation() -> None:
    rng = np.random.default_rng(11)
    lim = RoverLimits(max_speed_m_s=2.0, max_yaw_rate_rad_s=0.8, max_lat_acc_m_s2=1.0)
    pts = [np.zeros(2)]
    for _ in range(5):
        ang = rng.uniform(-2.0, 2.0)
        pts.append(pts[-1] + rng.uniform(4.0, 10.0) * np.array([math.cos(ang), math.sin(ang)]))
    wp = np.array(pts)
    tr = plan(wp, limits=lim, yaw="velocity")
    assert tr.dim == 2
    dt = 1e-3
    t = np.arange(0.0, tr.duration, dt)
    v = tr.evaluate(t, 1)
    speed = np.linalg.norm(v, axis=1)
    assert np.max(speed) <= 2.0 * (1 + 1e-9)
    heading = np.unwrap(np.arctan2(v[:, 1], v[:, 0]))
    rate = np.gradient(heading, dt)
    moving = speed > 0.05
    # finite differences: allow their truncation error
    assert np.max(np.abs(rate[moving])) <= 0.8 * 1.01
    assert np.max((speed * np.abs(rate))[moving]) <= 1.0 * 1.01


def test_short_collinear_legs_where_local_stretching_balloons() -> None:
    """Regression (found by hypothesis): stretching only the offending segment of this plan made
    the minimum-snap path overshoot more at every pass until the allocation gave up. Limits and
    waypoints are checked here by dense sampling, the duration against the polyline bound."""
    wp = np.array([[0.0, 0.0, 0.0], [2.0625, 0.0, 0.0], [4.453125, 0.0, 0.0]])
    res = plan_with_info(wp, limits=Limits(max_speed_m_s=4.0, max_acc_m_s2=3.0))
    tr = res.trajectory
    np.testing.assert_allclose(tr.evaluate(res.waypoint_times), wp, atol=1e-9)
    assert np.max(np.linalg.norm(dense(tr, 1), axis=1)) <= 4.0 * (1 + 1e-9)
    assert np.max(np.linalg.norm(dense(tr, 2), axis=1)) <= 3.0 * (1 + 1e-9)
    assert tr.duration <= 1.5 * 4.453125 / 4.0 + 2.0 * 4.0 / 3.0


def test_duration_bound_holds_on_average_well_below_one() -> None:
    """Mean duration / bound over a handful of sets (the benchmark reports the same figure)."""
    ratios = []
    lim = Limits(max_speed_m_s=VMAX, max_acc_m_s2=AMAX)
    for seed in range(4):
        wp = random_waypoints(np.random.default_rng(200 + seed))
        tr = plan(wp, limits=lim)
        polyline = float(np.sum(np.linalg.norm(np.diff(wp, axis=0), axis=1)))
        ratios.append(tr.duration / (1.5 * polyline / VMAX + 2.0 * VMAX / AMAX))
    assert max(ratios) <= 1.0


# ----------------------------------------------------------------------------- check()
def test_check_reports_the_worst_values() -> None:
    wp = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, -2.0], [10.0, 10.0, -2.0], [0.0, 12.0, 0.0]])
    tr = plan(wp, durations=[3.0, 2.5, 3.5])
    speed = np.linalg.norm(dense(tr, 1, 4000), axis=1)
    acc = np.linalg.norm(dense(tr, 2, 4000), axis=1)
    lim = Limits(max_speed_m_s=0.9 * speed.max(), max_acc_m_s2=2.0 * acc.max())
    rep = check(tr, lim)
    assert set(rep) == {"speed", "acc"}
    assert rep["speed"].worst == pytest.approx(speed.max(), rel=1e-6)
    assert rep["speed"].exceeded
    assert not rep["acc"].exceeded
    assert rep["acc"].worst == pytest.approx(acc.max(), rel=1e-6)
    for r in rep.values():
        assert r.bound is not None and r.bound >= r.worst - 1e-12
        assert tr.breaks[r.segment] - 1e-12 <= r.time_s <= tr.breaks[r.segment + 1] + 1e-12
    order = {"speed": 1, "acc": 2}
    for name, r in rep.items():
        at = float(np.linalg.norm(tr.evaluate(r.time_s, order[name])))
        assert at == pytest.approx(r.worst, rel=1e-12)


def test_check_multirotor_quantities_and_min_thrust() -> None:
    wp = np.array([[0.0, 0.0, 0.0], [8.0, 0.0, 0.0], [8.0, 0.0, 6.0]])  # ends with a descent
    tr = plan(wp, durations=[2.5, 2.0])
    lim = Limits(
        max_speed_m_s=100.0,
        max_acc_m_s2=100.0,
        max_tilt_rad=0.1,
        min_thrust_n=0.9 * MG,
        max_thrust_n=1.1 * MG,
    )
    rep = check(tr, lim, PARAMS)
    a = dense(tr, 2, 3000)
    v = dense(tr, 1, 3000)
    f = a + PARAMS.drag * v / PARAMS.mass
    f[:, 2] -= G
    thrust = PARAMS.mass * np.linalg.norm(f, axis=1)
    tilt = np.arccos(-f[:, 2] / np.linalg.norm(f, axis=1))
    assert rep["tilt"].worst == pytest.approx(tilt.max(), rel=1e-5)
    assert rep["min_thrust"].kind == "min"
    assert rep["min_thrust"].worst == pytest.approx(thrust.min(), rel=1e-5)
    assert rep["max_thrust"].worst == pytest.approx(thrust.max(), rel=1e-5)
    assert rep["tilt"].exceeded == (tilt.max() > 0.1)
    assert rep["min_thrust"].exceeded == (thrust.min() < 0.9 * MG)
    with pytest.raises(ValueError, match="params"):
        check(tr, lim)


def test_check_rover_yaw_rate_against_heading_differences() -> None:
    ang = np.linspace(0.0, math.pi / 2, 4)
    wp = np.stack([8.0 * np.sin(ang), 8.0 * (1 - np.cos(ang))], axis=1)
    tr = plan(wp, durations=[2.0, 2.0, 2.0])
    rep = check(tr, RoverLimits(max_speed_m_s=10.0, max_yaw_rate_rad_s=0.1, max_lat_acc_m_s2=50.0))
    dt = 1e-4
    t = np.arange(0.05, tr.duration - 0.05, dt)
    v = tr.evaluate(t, 1)
    heading = np.unwrap(np.arctan2(v[:, 1], v[:, 0]))
    rate = np.abs(np.gradient(heading, dt))
    assert rep["yaw_rate"].worst >= rate.max() * (1 - 1e-4)
    assert rep["yaw_rate"].exceeded
    speed = np.linalg.norm(v, axis=1)
    assert rep["lat_acc"].worst == pytest.approx(np.max(speed * rate), rel=1e-3)
