"""Bezier segments and piecewise trajectories against independent oracles.

Oracles: central finite differences, a textbook scalar de Casteljau recursion, and the
power-basis polynomial built here from the Bernstein definition with numpy.polynomial.
"""

from __future__ import annotations

import itertools
from math import comb

import numpy as np
import pytest
from numpy.polynomial import Polynomial

from companion.trajectory import Bezier, PiecewiseBezier, hermite

RNG = np.random.default_rng(20261122)


def _bernstein_polys(points: np.ndarray, duration: float) -> list[Polynomial]:
    """Power-basis polynomials in t (s) per dimension, from the Bernstein definition
    B(t) = sum P_i C(n,i) s^i (1-s)^(n-i), s = t/h."""
    n = points.shape[0] - 1
    s = Polynomial([0.0, 1.0 / duration])
    one_minus = Polynomial([1.0, -1.0 / duration])
    out = []
    for dim in range(points.shape[1]):
        poly = Polynomial([0.0])
        for i in range(n + 1):
            poly = poly + points[i, dim] * comb(n, i) * s**i * one_minus ** (n - i)
        out.append(poly)
    return out


def _de_casteljau(points: np.ndarray, u: float) -> np.ndarray:
    """Scalar textbook de Casteljau at parameter u in [0, 1]."""
    work = [p.copy() for p in points]
    while len(work) > 1:
        work = [(1.0 - u) * a + u * b for a, b in itertools.pairwise(work)]
    return work[0]


def _random_bezier(degree: int, dim: int, duration: float) -> Bezier:
    return Bezier(RNG.normal(size=(degree + 1, dim)) * 3.0, duration)


@pytest.mark.parametrize("degree", [1, 3, 5, 7, 9])
def test_derivative_matches_central_differences(degree: int) -> None:
    b = _random_bezier(degree, 3, 1.7)
    t = np.linspace(0.05, 1.65, 17)
    eps = 1e-5
    for order in range(1, min(degree, 4) + 1):
        fd = (b.evaluate(t + eps, order - 1) - b.evaluate(t - eps, order - 1)) / (2.0 * eps)
        np.testing.assert_allclose(b.evaluate(t, order), fd, rtol=1e-6, atol=1e-6)
        # derivative() builds the curve of the derivative: same values
        d = b
        for _ in range(order):
            d = d.derivative()
        assert d.degree == degree - order
        np.testing.assert_allclose(d.evaluate(t), fd, rtol=1e-6, atol=1e-6)


def test_derivative_matches_power_basis_oracle() -> None:
    b = _random_bezier(7, 2, 2.3)
    polys = _bernstein_polys(b.control_points, b.duration)
    t = np.linspace(0.0, 2.3, 11)
    for order in range(0, 9):
        expected = np.stack([p.deriv(order)(t) for p in polys], axis=1)
        np.testing.assert_allclose(b.evaluate(t, order), expected, rtol=1e-9, atol=1e-9)


def test_derivative_of_constant_is_zero() -> None:
    b = Bezier([[1.0, 2.0]], 0.5)
    d = b.derivative()
    assert d.degree == 0
    np.testing.assert_array_equal(d.evaluate(0.3), [0.0, 0.0])


@pytest.mark.parametrize("tau", [0.01, 0.4, 1.0, 1.99])
def test_split_leaves_curve_unchanged(tau: float) -> None:
    b = _random_bezier(7, 3, 2.0)
    left, right = b.split(tau)
    assert left.duration == pytest.approx(tau)
    assert right.duration == pytest.approx(2.0 - tau)
    tl = np.linspace(0.0, tau, 9)
    tr = np.linspace(0.0, 2.0 - tau, 9)
    for order in range(4):
        np.testing.assert_allclose(left.evaluate(tl, order), b.evaluate(tl, order), atol=1e-9)
        # a very short piece amplifies round-off by (1/h)^order in its derivatives
        np.testing.assert_allclose(
            right.evaluate(tr, order), b.evaluate(tr + tau, order), atol=1e-8, rtol=1e-7
        )


def test_split_rejects_outside_times() -> None:
    b = _random_bezier(3, 2, 1.0)
    for tau in (0.0, 1.0, -0.5, 2.0):
        with pytest.raises(ValueError, match="split"):
            b.split(tau)


def test_elevate_leaves_curve_unchanged() -> None:
    b = _random_bezier(5, 3, 1.3)
    e = b.elevate().elevate()
    assert e.degree == 7
    t = np.linspace(0.0, 1.3, 23)
    for order in range(4):
        np.testing.assert_allclose(e.evaluate(t, order), b.evaluate(t, order), atol=1e-10)


@pytest.mark.parametrize(("k0", "k1"), [(1, 1), (2, 2), (3, 3), (4, 4), (2, 3), (4, 1)])
def test_hermite_reproduces_boundary_derivatives(k0: int, k1: int) -> None:
    h = 1.7
    start = RNG.normal(size=(k0, 3))
    end = RNG.normal(size=(k1, 3))
    b = hermite(start, end, h)
    assert b.degree == k0 + k1 - 1
    polys = _bernstein_polys(b.control_points, h)
    for j in range(k0):
        got = np.array([p.deriv(j)(0.0) for p in polys])
        np.testing.assert_allclose(got, start[j], rtol=1e-12, atol=1e-12)
    for j in range(k1):
        got = np.array([p.deriv(j)(h) for p in polys])
        np.testing.assert_allclose(got, end[j], rtol=1e-11, atol=1e-11)
    assert Bezier.hermite(start, end, h).control_points.tolist() == b.control_points.tolist()


def test_hermite_is_unique_solution_of_the_interpolation_problem() -> None:
    # independent construction: solve the linear conditions on the power basis directly
    h, k = 0.8, 4
    start = RNG.normal(size=(k, 1))
    end = RNG.normal(size=(k, 1))
    n = 2 * k - 1
    A = np.zeros((2 * k, n + 1))
    rhs = np.zeros(2 * k)
    for j in range(k):
        for p in range(j, n + 1):
            fall = np.prod(np.arange(p - j + 1, p + 1)) if j else 1.0
            A[j, p] = fall * (0.0 ** (p - j) if p > j else 1.0)
            A[k + j, p] = fall * h ** (p - j)
        rhs[j] = start[j, 0]
        rhs[k + j] = end[j, 0]
    coef = np.linalg.solve(A, rhs)
    t = np.linspace(0.0, h, 7)
    expected = Polynomial(coef)(t)
    np.testing.assert_allclose(hermite(start, end, h).evaluate(t)[:, 0], expected, atol=1e-10)


def test_to_monomial_agrees_with_de_casteljau() -> None:
    b = _random_bezier(7, 3, 2.5)
    c = b.to_monomial()
    assert c.shape == (8, 3)
    for t in np.linspace(0.0, 2.5, 13):
        mono = sum(c[k] * t**k for k in range(8))
        np.testing.assert_allclose(mono, _de_casteljau(b.control_points, t / 2.5), atol=1e-10)


def test_evaluate_shapes() -> None:
    b = _random_bezier(4, 2, 1.0)
    assert b.evaluate(0.3).shape == (2,)
    assert b.evaluate(np.array([0.1, 0.2, 0.3])).shape == (3, 2)
    assert b.evaluate([0.5], order=2).shape == (1, 2)
    assert b.evaluate(0.3, order=9).tolist() == [0.0, 0.0]


def test_bad_bezier_inputs_are_rejected() -> None:
    with pytest.raises(ValueError, match="finite"):
        Bezier([[0.0, np.nan]], 1.0)
    with pytest.raises(ValueError, match="duration"):
        Bezier([[0.0, 1.0]], 0.0)
    with pytest.raises(ValueError, match="shape"):
        Bezier(np.zeros((2, 2, 2)), 1.0)
    with pytest.raises(ValueError, match="dimensions"):
        hermite(np.zeros((2, 3)), np.zeros((2, 2)), 1.0)


def test_hull_bound_bounds_the_curve() -> None:
    b = _random_bezier(7, 3, 1.4)
    t = np.linspace(0.0, 1.4, 2001)
    for order in range(4):
        sampled = np.max(np.linalg.norm(b.evaluate(t, order), axis=1))
        assert b.hull_bound(order) >= sampled - 1e-12


# ------------------------------------------------------------------------ PiecewiseBezier
def _random_piecewise(m: int = 4, degree: int = 7, dim: int = 3) -> PiecewiseBezier:
    segs = [_random_bezier(degree, dim, float(RNG.uniform(0.3, 2.0))) for _ in range(m)]
    return PiecewiseBezier(segs)


def test_piecewise_evaluate_matches_segments() -> None:
    pw = _random_piecewise()
    assert pw.num_segments == 4 and len(pw) == 4
    assert pw.duration == pytest.approx(float(np.sum(pw.durations)))
    np.testing.assert_allclose(pw.breaks[1:], np.cumsum(pw.durations))
    for k, seg in enumerate(pw.segments):
        tl = np.linspace(0.0, seg.duration, 9)[:-1]  # the joint itself belongs to segment k+1
        for order in range(6):
            np.testing.assert_allclose(
                pw.evaluate(pw.breaks[k] + tl, order),
                seg.evaluate(tl, order),
                rtol=1e-9,
                atol=1e-8,
            )


def test_piecewise_evaluate_scalar_vector_and_clamping() -> None:
    pw = _random_piecewise()
    t = np.array([0.0, 0.1, pw.duration * 0.5, pw.duration])
    vec = pw.evaluate(t, 1)
    assert vec.shape == (4, 3)
    for i, ti in enumerate(t):
        np.testing.assert_allclose(pw.evaluate(float(ti), 1), vec[i])
    last = pw.segments[-1]
    np.testing.assert_allclose(pw.evaluate(pw.duration + 5.0), last.evaluate(last.duration))
    np.testing.assert_allclose(pw.evaluate(-1.0), pw.segments[0].evaluate(0.0))
    with pytest.raises(ValueError, match="NaN"):
        pw.evaluate(np.nan)
    idx = pw.segment_index(np.array([-1.0, 0.0, pw.breaks[1], pw.breaks[2] - 1e-9, 1e9]))
    assert idx.tolist() == [0, 0, 1, 1, pw.num_segments - 1]


def test_piecewise_mixed_degrees_are_elevated_without_change() -> None:
    a = _random_bezier(3, 2, 1.0)
    b = _random_bezier(7, 2, 0.5)
    pw = PiecewiseBezier([a, b])
    assert pw.degree == 7
    t = np.linspace(0.0, 0.99, 7)
    np.testing.assert_allclose(pw.evaluate(t), a.evaluate(t), atol=1e-10)


def test_piecewise_yaw_channel_validation() -> None:
    pw = _random_piecewise(m=2, dim=3)
    good = PiecewiseBezier([Bezier(RNG.normal(size=(8, 1)), float(h)) for h in pw.durations])
    with_yaw = PiecewiseBezier(pw.segments, yaw=good)
    assert with_yaw.yaw is good
    assert pw.with_yaw(good).yaw is good
    wrong_h = PiecewiseBezier([Bezier(np.zeros((8, 1)), 1.0), Bezier(np.zeros((8, 1)), 1.0)])
    with pytest.raises(ValueError, match="durations"):
        PiecewiseBezier(pw.segments, yaw=wrong_h)
    with pytest.raises(ValueError, match="1-D"):
        PiecewiseBezier(pw.segments, yaw=pw)
    with pytest.raises(ValueError, match="at least one"):
        PiecewiseBezier([])
    with pytest.raises(ValueError, match="dimension"):
        PiecewiseBezier([_random_bezier(3, 2, 1.0), _random_bezier(3, 3, 1.0)])


def test_from_control_points_round_trip() -> None:
    pw = _random_piecewise()
    again = PiecewiseBezier.from_control_points(pw.control_points, pw.durations)
    t = np.linspace(0.0, pw.duration, 31)
    np.testing.assert_array_equal(again.evaluate(t, 2), pw.evaluate(t, 2))
    assert not pw.control_points.flags.writeable
    with pytest.raises(ValueError, match="durations"):
        PiecewiseBezier.from_control_points(pw.control_points, pw.durations[:-1])


def test_hull_bounds_per_segment() -> None:
    pw = _random_piecewise()
    bounds = pw.hull_bounds(1)
    for k, seg in enumerate(pw.segments):
        t = np.linspace(0.0, seg.duration, 500)
        assert bounds[k] >= np.max(np.linalg.norm(seg.evaluate(t, 1), axis=1)) - 1e-12


def test_evaluate_orders_matches_power_basis_oracle_and_evaluate() -> None:
    # several orders at once (shared segment lookup): each equals evaluate(t, order) and the
    # numpy.polynomial derivative of the segment's Bernstein polynomial, ends and joints included
    cps = RNG.normal(size=(5, 8, 3))
    h = RNG.uniform(0.3, 2.5, size=5)
    traj = PiecewiseBezier.from_control_points(cps, h)
    t = np.concatenate([np.linspace(-0.5, traj.duration + 0.5, 211), traj.breaks])
    orders = (0, 1, 2, 4, 9)
    got = traj.evaluate_orders(t, orders)
    tc = np.clip(t, 0.0, traj.duration)
    seg = np.clip(np.searchsorted(traj.breaks, tc, side="right") - 1, 0, 4)
    for r, vals in zip(orders, got, strict=True):
        assert vals.shape == (t.shape[0], 3)
        np.testing.assert_array_equal(vals, traj.evaluate(t, r))
        polys = [_bernstein_polys(cps[k], float(h[k])) for k in range(5)]
        want = np.array([[polys[k][dim].deriv(r)(tc[i] - traj.breaks[k]) if r else
                          polys[k][dim](tc[i] - traj.breaks[k]) for dim in range(3)]
                         for i, k in enumerate(seg)])
        np.testing.assert_allclose(vals, want, rtol=1e-9, atol=1e-9 * max(1.0, np.abs(want).max()))


@pytest.mark.parametrize(("k0", "k1", "d"), [(1, 1, 1), (2, 2, 3), (4, 4, 2), (4, 4, 1),
                                             (3, 5, 2), (5, 2, 3)])
def test_hermite_batch_is_hermite_bit_for_bit_and_meets_the_boundary_derivatives(
        k0: int, k1: int, d: int) -> None:
    """Each segment of `hermite_batch` has exactly `hermite`'s control points (the rover's
    path planner switched to the batch: its plans must not move), and meets the boundary
    derivatives it was given (by the Bezier's own evaluation)."""
    from companion.trajectory.bezier import hermite_batch

    rng = np.random.default_rng(k0 * 100 + k1 * 10 + d)
    m = 40
    s0 = rng.normal(scale=10.0, size=(m, k0, d))
    s1 = rng.normal(scale=10.0, size=(m, k1, d))
    h = np.exp(rng.uniform(np.log(1e-3), np.log(50.0), m))
    batch = hermite_batch(s0, s1, h)
    assert batch.num_segments == m and batch.degree == k0 + k1 - 1
    for i in range(m):
        one = hermite(s0[i], s1[i], float(h[i]))
        assert np.array_equal(batch.control_points[i], one.control_points), i
        assert batch.durations[i] == one.duration
    seg = batch.segments[7]
    for j in range(k0):
        np.testing.assert_allclose(seg.evaluate(0.0, j), s0[7, j], rtol=1e-6, atol=1e-6)
    for j in range(k1):
        np.testing.assert_allclose(seg.evaluate(seg.duration, j), s1[7, j], rtol=1e-6,
                                   atol=1e-6)
    with pytest.raises(ValueError, match="positive"):
        hermite_batch(s0[:2], s1[:2], [1.0, 0.0])
    with pytest.raises(ValueError, match="finite"):
        hermite_batch(np.full((1, k0, d), np.nan), s1[:1], [1.0])
