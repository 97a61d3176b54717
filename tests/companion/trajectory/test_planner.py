"""Minimum-snap / minimum-jerk planner: optimality against an independent dense KKT built here
from the monomial basis, optimality conditions, constraints, yaw, input errors."""

from __future__ import annotations

import math
import warnings
from math import comb, factorial

import numpy as np
import pytest
from numpy.polynomial import Polynomial

from companion.trajectory import (
    Limits,
    PiecewiseBezier,
    RoverLimits,
    plan,
    plan_with_info,
)


# ----------------------------------------------------------------------------- oracles
def _falling(p: int, r: int) -> float:
    return factorial(p) / factorial(p - r) if p >= r else 0.0


def _row(n: int, r: int, u: float, h: float) -> np.ndarray:
    """Row of d^r/dt^r of sum_p c_p (t/h)^p at t = u h (monomials in normalised time)."""
    return np.array([_falling(p, r) * u ** (p - r) / h**r if p >= r else 0.0 for p in range(n + 1)])


def dense_reference(
    wp: np.ndarray,
    h: np.ndarray,
    s: int,
    start: dict[int, np.ndarray] | None = None,
    end: dict[int, np.ndarray] | None = None,
    interior: dict[int, dict[int, np.ndarray]] | None = None,
) -> tuple[float, np.ndarray]:
    """min sum_k int |p_k^(s)|^2 over monomial coefficients subject to waypoints, boundary
    derivatives (rest unless given), continuity through order s at interior joints and fixed
    interior derivatives; solved as one dense KKT system in the monomial basis of normalised
    local time u = t / h. Returns (cost, coeffs (M, n+1, d))."""
    m, d = h.shape[0], wp.shape[1]
    n = 2 * s - 1
    nc = n + 1
    Q = np.zeros((m * nc, m * nc))
    for k in range(m):
        for i in range(s, nc):
            for j in range(s, nc):
                e = i + j - 2 * s + 1
                Q[k * nc + i, k * nc + j] = (
                    _falling(i, s) * _falling(j, s) / e * h[k] ** (1 - 2 * s)
                )
    rows: list[np.ndarray] = []
    rhs: list[np.ndarray] = []

    def add(coeffs: dict[int, np.ndarray], value: np.ndarray) -> None:
        row = np.zeros(m * nc)
        for k, v in coeffs.items():
            row[k * nc : (k + 1) * nc] += v
        rows.append(row)
        rhs.append(value)

    start = start or {}
    end = end or {}
    interior = interior or {}
    for k in range(m):
        add({k: _row(n, 0, 0.0, h[k])}, wp[k])
        add({k: _row(n, 0, 1.0, h[k])}, wp[k + 1])
    for r in range(1, s):
        add({0: _row(n, r, 0.0, h[0])}, start.get(r, np.zeros(d)))
        add({m - 1: _row(n, r, 1.0, h[-1])}, end.get(r, np.zeros(d)))
    for k in range(m - 1):
        for r in range(1, s + 1):
            add({k: _row(n, r, 1.0, h[k]), k + 1: -_row(n, r, 0.0, h[k + 1])}, np.zeros(d))
        for r, v in interior.get(k + 1, {}).items():
            add({k: _row(n, r, 1.0, h[k])}, v)
    A = np.array(rows)
    b = np.array(rhs)
    kkt = np.block([[2.0 * Q, A.T], [A, np.zeros((A.shape[0], A.shape[0]))]])
    sol = np.linalg.solve(kkt, np.vstack([np.zeros((m * nc, d)), b]))
    c = sol[: m * nc]
    cost = float(np.sum(c * (Q @ c)))
    return cost, c.reshape(m, nc, d)


def bezier_polys(traj: PiecewiseBezier) -> list[list[Polynomial]]:
    """Power-basis polynomials (local time) of every segment, from the Bernstein definition."""
    out = []
    for seg in traj.segments:
        P, h = seg.control_points, seg.duration
        n = P.shape[0] - 1
        s = Polynomial([0.0, 1.0 / h])
        om = Polynomial([1.0, -1.0 / h])
        polys = []
        for dim in range(P.shape[1]):
            poly = Polynomial([0.0])
            for i in range(n + 1):
                poly = poly + P[i, dim] * comb(n, i) * s**i * om ** (n - i)
            polys.append(poly)
        out.append(polys)
    return out


def integral_cost(traj: PiecewiseBezier, s: int) -> float:
    """int |p^(s)|^2 dt, integrated exactly with numpy.polynomial."""
    total = 0.0
    for seg, polys in zip(traj.segments, bezier_polys(traj), strict=True):
        for p in polys:
            q = p.deriv(s) ** 2
            total += float(q.integ()(seg.duration) - q.integ()(0.0))
    return total


def _random_problem(m: int, d: int = 3, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(1000 * m + seed)
    wp = np.cumsum(rng.normal(size=(m + 1, d)) * 3.0, axis=0)
    h = rng.uniform(0.6, 2.5, size=m)
    return wp, h


# ----------------------------------------------------------------------------- optimality
@pytest.mark.parametrize(("order", "s"), [("snap", 4), ("jerk", 3)])
@pytest.mark.parametrize("m", [1, 2, 5])
def test_cost_equals_dense_kkt_reference(order: str, s: int, m: int) -> None:
    wp, h = _random_problem(m)
    res = plan_with_info(wp, durations=h, order=order)
    ref_cost, _ = dense_reference(wp, h, s)
    assert res.trajectory.degree == 2 * s - 1
    assert res.cost == pytest.approx(ref_cost, rel=1e-9)
    assert integral_cost(res.trajectory, s) == pytest.approx(ref_cost, rel=1e-9)


def test_cost_equals_dense_reference_with_boundary_and_interior_constraints() -> None:
    wp, h = _random_problem(4)
    start = {1: np.array([1.0, -0.5, 0.2]), 2: np.array([0.3, 0.0, -0.1])}
    end = {1: np.array([0.0, 2.0, 0.0])}
    interior = {2: {1: np.array([0.5, 0.5, 0.0])}, 3: {2: np.array([0.0, 0.0, 1.0])}}
    res = plan_with_info(wp, durations=h, start=start, end=end, constraints=interior)
    ref_cost, _ = dense_reference(wp, h, 4, start, end, interior)
    assert res.cost == pytest.approx(ref_cost, rel=1e-9)
    tr = res.trajectory
    np.testing.assert_allclose(tr.evaluate(0.0, 1), start[1], atol=1e-9)
    np.testing.assert_allclose(tr.evaluate(0.0, 2), start[2], atol=1e-9)
    np.testing.assert_allclose(tr.evaluate(0.0, 3), 0.0, atol=1e-9)
    np.testing.assert_allclose(tr.evaluate(tr.duration, 1), end[1], atol=1e-9)
    np.testing.assert_allclose(tr.evaluate(tr.breaks[2], 1), interior[2][1], atol=1e-9)
    np.testing.assert_allclose(tr.evaluate(tr.breaks[3], 2), interior[3][2], atol=1e-9)


def test_perturbing_a_free_interior_derivative_increases_the_cost() -> None:
    wp, h = _random_problem(5)
    res = plan_with_info(wp, durations=h)
    tr = res.trajectory
    joint = 2
    for r in (1, 2, 3):
        opt = tr.evaluate(tr.breaks[joint], r)
        same = plan_with_info(wp, durations=h, constraints={joint: {r: opt}})
        assert same.cost == pytest.approx(res.cost, rel=1e-9)
        for axis in range(3):
            for sign in (-1.0, 1.0):
                bumped = opt.copy()
                bumped[axis] += sign * 0.05 * (1.0 + abs(opt[axis]))
                worse = plan_with_info(wp, durations=h, constraints={joint: {r: bumped}})
                assert worse.cost > res.cost * (1.0 + 1e-9)


@pytest.mark.parametrize(("order", "s"), [("snap", 4), ("jerk", 3)])
def test_optimality_conditions_at_free_joints(order: str, s: int) -> None:
    """Continuity through order 2s-2 (5th and 6th derivatives for snap) at free joints."""
    wp, h = _random_problem(6)
    tr = plan(wp, durations=h, order=order)
    segs = tr.segments
    for k in range(len(segs) - 1):
        for r in range(0, 2 * s - 1):
            left = segs[k].evaluate(segs[k].duration, r)
            right = segs[k + 1].evaluate(0.0, r)
            scale = 1.0 + float(np.max(np.abs(left)))
            np.testing.assert_allclose(left, right, atol=1e-7 * scale, err_msg=f"order {r}")
        # the (2s-1)-th derivative generally jumps: the optimum is not a single polynomial
    jumps = [
        np.max(
            np.abs(
                segs[k].evaluate(segs[k].duration, 2 * s - 1) - segs[k + 1].evaluate(0.0, 2 * s - 1)
            )
        )
        for k in range(len(segs) - 1)
    ]
    assert max(jumps) > 1e-6


def test_waypoints_and_rest_boundaries() -> None:
    wp, h = _random_problem(4)
    tr = plan(wp, durations=h)
    np.testing.assert_allclose(tr.evaluate(tr.breaks), wp, atol=1e-10)
    for r in (1, 2, 3):
        np.testing.assert_allclose(tr.evaluate(0.0, r), 0.0, atol=1e-9)
        np.testing.assert_allclose(tr.evaluate(tr.duration, r), 0.0, atol=1e-9)
    np.testing.assert_allclose(tr.durations, h)


def test_free_end_derivative() -> None:
    wp, h = _random_problem(3)
    res = plan_with_info(wp, durations=h, end={1: None, 2: None, 3: None})
    # natural boundary: cheaper than stopping
    stop = plan_with_info(wp, durations=h)
    assert res.cost < stop.cost
    assert np.linalg.norm(res.trajectory.evaluate(res.trajectory.duration, 1)) > 1e-3


def test_linear_scaling_in_many_segments_is_exact() -> None:
    wp, h = _random_problem(400)
    res = plan_with_info(wp, durations=h)
    tr = res.trajectory
    np.testing.assert_allclose(tr.evaluate(tr.breaks), wp, atol=1e-8)
    segs = tr.segments
    for k in (0, 100, 398):
        for r in range(1, 7):
            left = segs[k].evaluate(segs[k].duration, r)
            right = segs[k + 1].evaluate(0.0, r)
            np.testing.assert_allclose(left, right, atol=1e-6 * (1.0 + np.max(np.abs(left))))


# ----------------------------------------------------------------------------- input handling
def test_bad_waypoints_are_named() -> None:
    wp = np.zeros((4, 3))
    wp[:, 0] = [0.0, 1.0, 2.0, 3.0]
    wp[2, 1] = np.nan
    with pytest.raises(ValueError, match="waypoint 2"):
        plan(wp, durations=[1.0, 1.0, 1.0])
    wp[2, 1] = np.inf
    with pytest.raises(ValueError, match="waypoint 2"):
        plan(wp, durations=[1.0, 1.0, 1.0])
    with pytest.raises(ValueError, match="at least one"):
        plan(np.zeros((0, 3)), durations=[])
    with pytest.raises(ValueError, match="shape"):
        plan(np.zeros((3, 4)), durations=[1.0, 1.0])
    with pytest.raises(ValueError, match="shape"):
        plan([1.0, 2.0, 3.0], durations=[])
    with pytest.raises(ValueError, match="durations"):
        plan(np.eye(3), durations=[1.0])
    with pytest.raises(ValueError, match="waypoint 1 to 2"):
        plan(np.eye(3), durations=[1.0, -1.0])
    with pytest.raises(ValueError, match="order"):
        plan(np.eye(3), durations=[1.0, 1.0], order="crackle")
    with pytest.raises(ValueError, match="interior"):
        plan(np.eye(3), durations=[1.0, 1.0], constraints={0: {1: [0, 0, 0]}})
    with pytest.raises(ValueError, match="order"):
        plan(np.eye(3), durations=[1.0, 1.0], start={4: [0, 0, 0]})
    with pytest.raises(ValueError, match="3 components"):
        plan(np.eye(3), durations=[1.0, 1.0], start={1: [0, 0]})
    with pytest.raises(ValueError, match="durations or limits"):
        plan(np.eye(3))


def test_impossible_limits_are_rejected() -> None:
    with pytest.raises(ValueError, match="max_speed"):
        Limits(max_speed_m_s=0.0, max_acc_m_s2=1.0)
    with pytest.raises(ValueError, match="max_acc"):
        Limits(max_speed_m_s=1.0, max_acc_m_s2=-1.0)
    with pytest.raises(ValueError, match="max_tilt"):
        Limits(max_speed_m_s=1.0, max_acc_m_s2=1.0, max_tilt_rad=2.0)
    with pytest.raises(ValueError, match="min_thrust"):
        Limits(max_speed_m_s=1.0, max_acc_m_s2=1.0, max_thrust_n=5.0, min_thrust_n=6.0)
    with pytest.raises(ValueError, match="max_yaw_rate"):
        RoverLimits(max_speed_m_s=1.0, max_yaw_rate_rad_s=math.nan, max_lat_acc_m_s2=1.0)
    with pytest.raises(ValueError, match="params"):
        plan(np.eye(3), limits=Limits(1.0, 1.0, max_tilt_rad=0.3))
    with pytest.raises(ValueError, match="2-D"):
        plan(np.eye(3), limits=RoverLimits(1.0, 1.0, 1.0))
    with pytest.raises(ValueError, match="start: velocity 6 exceeds max_speed"):
        plan(np.eye(3), limits=Limits(5.0, 4.0), start={1: [6.0, 0.0, 0.0]})
    with pytest.raises(ValueError, match="waypoint 1: acceleration"):
        plan(np.eye(3), limits=Limits(5.0, 4.0), constraints={1: {2: [0.0, 5.0, 0.0]}})


def test_duplicate_waypoints_are_merged_with_warning() -> None:
    wp = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 1.0, 0.0]])
    with pytest.warns(UserWarning, match="waypoint 2 duplicates waypoint 1"):
        res = plan_with_info(wp, durations=[1.0, 0.5, 1.0])
    tr = res.trajectory
    assert tr.num_segments == 2
    assert tr.duration == pytest.approx(2.5)
    np.testing.assert_allclose(tr.evaluate(res.waypoint_times), wp, atol=1e-10)
    assert res.waypoint_times[1] == res.waypoint_times[2]


def test_single_waypoint_is_a_hover() -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        tr = plan([[1.0, 2.0, -3.0]], yaw=0.5)
    t = np.linspace(0.0, tr.duration, 11)
    np.testing.assert_allclose(tr.evaluate(t), np.tile([1.0, 2.0, -3.0], (11, 1)))
    for r in range(1, 5):
        np.testing.assert_allclose(tr.evaluate(t, r), 0.0)
    assert tr.yaw is not None
    np.testing.assert_allclose(tr.yaw.evaluate(t)[:, 0], 0.5)
    with pytest.warns(UserWarning):
        tr2 = plan([[1.0, 2.0, -3.0], [1.0, 2.0, -3.0]], limits=Limits(1.0, 1.0))
    np.testing.assert_allclose(tr2.evaluate(0.3), [1.0, 2.0, -3.0])


# ----------------------------------------------------------------------------- yaw
def test_per_waypoint_yaw_is_unwrapped_the_short_way() -> None:
    wp = np.array([[0.0, 0.0, 0.0], [5.0, 0.0, 0.0], [10.0, 5.0, 0.0], [10.0, 10.0, 0.0]])
    yaws = [3.0, -3.0, 3.0, -2.9]
    res = plan_with_info(wp, durations=[2.0, 2.0, 2.0], yaw=yaws)
    assert res.trajectory.yaw is not None
    yaw = res.trajectory.yaw
    at_wp = yaw.evaluate(res.waypoint_times)[:, 0]
    # same heading as requested (mod 2 pi), reached the short way (steps below pi)
    np.testing.assert_allclose(np.cos(at_wp), np.cos(yaws), atol=1e-9)
    np.testing.assert_allclose(np.sin(at_wp), np.sin(yaws), atol=1e-9)
    assert np.all(np.abs(np.diff(at_wp)) < math.pi)
    assert abs(at_wp[-1] - at_wp[0]) < 1.0  # never a full turn
    np.testing.assert_allclose(yaw.evaluate(0.0, 1), 0.0, atol=1e-12)
    np.testing.assert_allclose(yaw.durations, res.trajectory.durations)


def test_fixed_yaw() -> None:
    tr = plan(np.eye(3) * 4.0, durations=[1.0, 1.0], yaw=1.2)
    assert tr.yaw is not None
    t = np.linspace(0.0, tr.duration, 9)
    np.testing.assert_allclose(tr.yaw.evaluate(t)[:, 0], 1.2)
    np.testing.assert_allclose(tr.yaw.evaluate(t, 1)[:, 0], 0.0, atol=1e-9)


def test_velocity_yaw_follows_the_heading() -> None:
    # a smooth left-hand curve: the heading is well defined away from the rest ends
    ang = np.linspace(0.0, math.pi, 7)
    wp = np.stack([20.0 * np.sin(ang), 20.0 * (1 - np.cos(ang)), np.zeros(7)], axis=1)
    tr = plan(wp, durations=np.full(6, 3.0), yaw="velocity")
    assert tr.yaw is not None
    np.testing.assert_allclose(tr.yaw.durations, tr.durations)
    t = np.linspace(0.0, tr.duration, 2000)
    v = tr.evaluate(t, 1)
    speed = np.linalg.norm(v[:, :2], axis=1)
    heading = np.arctan2(v[:, 1], v[:, 0])  # independent: atan2 of the sampled velocity
    yaw = tr.yaw.evaluate(t)[:, 0]
    err = np.angle(np.exp(1j * (yaw - heading)))
    assert np.max(np.abs(err[speed > 0.1 * speed.max()])) < 0.06
    # the yaw rate follows the heading rate (finite differences) where the vehicle is fast
    rate_fd = np.gradient(np.unwrap(heading), t)
    fast = speed > 0.5 * speed.max()
    assert np.max(np.abs(tr.yaw.evaluate(t, 1)[fast, 0] - rate_fd[fast])) < 0.1
    # at rest at both ends, and it never spins: a net left turn of under pi
    np.testing.assert_allclose(tr.yaw.evaluate(0.0, 1), 0.0, atol=1e-9)
    np.testing.assert_allclose(tr.yaw.evaluate(tr.duration, 1), 0.0, atol=1e-9)
    assert 0.0 < yaw[-1] - yaw[0] < math.pi
    assert np.max(yaw) - np.min(yaw) < math.pi
    with pytest.raises(ValueError, match="yaw"):
        plan(wp, durations=np.full(6, 3.0), yaw="north")
    with pytest.raises(ValueError, match="waypoint 1"):
        plan(wp, durations=np.full(6, 3.0), yaw=[0.0, np.nan, 0, 0, 0, 0, 0])


def test_velocity_yaw_on_time_allocated_plans() -> None:
    for seed in range(3):
        rng = np.random.default_rng(seed)
        wp = np.cumsum(rng.normal(size=(8, 3)) * [8.0, 8.0, 1.0], axis=0)
        tr = plan(wp, limits=Limits(max_speed_m_s=5.0, max_acc_m_s2=4.0), yaw="velocity")
        assert tr.yaw is not None
        t = np.linspace(0.0, tr.duration, 4000)
        v = tr.evaluate(t, 1)
        speed = np.linalg.norm(v[:, :2], axis=1)
        err = np.angle(np.exp(1j * (tr.yaw.evaluate(t)[:, 0] - np.arctan2(v[:, 1], v[:, 0]))))
        assert np.max(np.abs(err[speed > 0.5 * speed.max()])) < 0.1


# ----------------------------------------------------------------------------- gradients
def test_analytic_duration_gradients_match_finite_differences() -> None:
    """dJ*/dh (envelope theorem) and the limit-penalty gradient (adjoint) used by the time
    allocation, against central differences of re-solved problems."""
    from companion.flatness import MultirotorParams
    from companion.trajectory.allocation import Planner
    from companion.trajectory.penalty import LimitPenalty

    wp, h = _random_problem(5, seed=3)
    joints_mask = np.ones(6, dtype=bool)
    pl = Planner(wp, joints_mask, 4, {}, {}, {}, None, None)
    params = MultirotorParams(mass=1.5, inertia=np.diag([0.02, 0.02, 0.04]), drag=0.3)
    lim = Limits(
        max_speed_m_s=2.0,
        max_acc_m_s2=1.0,
        max_jerk_m_s3=1.0,
        max_tilt_rad=0.05,
        max_thrust_n=15.5,
        min_thrust_n=14.0,
    )
    pen = LimitPenalty(pl.system, lim, params)

    def cost(hh: np.ndarray) -> float:
        return pl.system.solve(hh)[1]

    def penalty(hh: np.ndarray) -> float:
        x, _ = pl.system.solve(hh)
        return pen.value_grad(x, hh)[0]

    x, _ = pl.system.solve(h)
    g_cost = pl.system.cost_grad(x, h)
    g_pen = pen.value_grad(x, h)[1]
    eps = 1e-6
    for k in range(h.shape[0]):
        e = np.zeros_like(h)
        e[k] = eps
        fd_cost = (cost(h + e) - cost(h - e)) / (2 * eps)
        fd_pen = (penalty(h + e) - penalty(h - e)) / (2 * eps)
        assert g_cost[k] == pytest.approx(fd_cost, rel=1e-5)
        assert g_pen[k] == pytest.approx(fd_pen, rel=1e-5)
