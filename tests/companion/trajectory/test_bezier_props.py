"""Hypothesis properties of Bezier segments: split / elevate / to_monomial / hermite."""

from __future__ import annotations

import itertools

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from companion.trajectory import Bezier, hermite

finite = st.floats(min_value=-50.0, max_value=50.0, allow_nan=False, allow_infinity=False)
durations = st.floats(min_value=0.05, max_value=20.0)


@st.composite
def beziers(draw: st.DrawFn) -> Bezier:
    degree = draw(st.integers(min_value=0, max_value=9))
    dim = draw(st.integers(min_value=1, max_value=3))
    pts = draw(arrays(np.float64, (degree + 1, dim), elements=finite))
    return Bezier(pts, draw(durations))


def _de_casteljau(points: np.ndarray, u: float) -> np.ndarray:
    work = [p.copy() for p in points]
    while len(work) > 1:
        work = [(1.0 - u) * a + u * b for a, b in itertools.pairwise(work)]
    return work[0]


def _scale(b: Bezier) -> float:
    return 1.0 + float(np.max(np.abs(b.control_points)))


@settings(max_examples=60, deadline=None)
@given(beziers(), st.floats(min_value=0.02, max_value=0.98))
def test_split_is_the_same_curve(b: Bezier, frac: float) -> None:
    tau = frac * b.duration
    left, right = b.split(tau)
    for u in np.linspace(0.0, 1.0, 7):
        np.testing.assert_allclose(
            left.evaluate(u * tau), _de_casteljau(b.control_points, u * frac), atol=1e-9 * _scale(b)
        )
        t_right = u * (b.duration - tau)
        np.testing.assert_allclose(
            right.evaluate(t_right),
            _de_casteljau(b.control_points, (tau + t_right) / b.duration),
            atol=1e-9 * _scale(b),
        )


@settings(max_examples=60, deadline=None)
@given(beziers())
def test_elevate_is_the_same_curve(b: Bezier) -> None:
    e = b.elevate()
    assert e.degree == b.degree + 1
    t = np.linspace(0.0, b.duration, 9)
    np.testing.assert_allclose(e.evaluate(t), b.evaluate(t), atol=1e-10 * _scale(b))


@settings(max_examples=60, deadline=None)
@given(beziers(), st.floats(min_value=0.0, max_value=1.0))
def test_to_monomial_matches_de_casteljau(b: Bezier, u: float) -> None:
    c = b.to_monomial()
    # evaluate the monomial form in normalised time to keep the check well conditioned
    t = u * b.duration
    mono = sum(c[k] * t**k for k in range(c.shape[0]))
    np.testing.assert_allclose(mono, _de_casteljau(b.control_points, u), atol=1e-8 * _scale(b))


@settings(max_examples=60, deadline=None)
@given(
    st.integers(min_value=1, max_value=4),
    st.integers(min_value=1, max_value=4),
    st.integers(min_value=1, max_value=3),
    st.floats(min_value=0.1, max_value=5.0),
    st.integers(min_value=0, max_value=2**31 - 1),
)
def test_hermite_boundary_derivatives_by_finite_differences(
    k0: int, k1: int, dim: int, h: float, seed: int
) -> None:
    rng = np.random.default_rng(seed)
    start = rng.normal(size=(k0, dim))
    end = rng.normal(size=(k1, dim))
    b = hermite(start, end, h)
    # exact: evaluated derivative equals the requested one
    for j in range(k0):
        np.testing.assert_allclose(b.evaluate(0.0, j), start[j], rtol=1e-9, atol=1e-9)
    for j in range(k1):
        np.testing.assert_allclose(b.evaluate(h, j), end[j], rtol=1e-9, atol=1e-8)
    # and the evaluated velocity is the slope of the evaluated position (independent check)
    if k0 >= 2:
        eps = 1e-6 * h
        fd = (b.evaluate(eps) - b.evaluate(-eps)) / (2 * eps)
        np.testing.assert_allclose(fd, start[1], rtol=1e-5, atol=1e-5)
