"""PiecewiseBezier.scalar_evaluator against PiecewiseBezier.evaluate (vectorised numpy Horner),
scipy's BPoly (an independent Bernstein implementation) and Bezier end-point properties
(clamping at the ends, later segment at a joint)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.interpolate import BPoly

from companion.trajectory import PiecewiseBezier
from companion.trajectory.bezier import ScalarEvaluator, horner_fn


@st.composite
def trajectories(draw: st.DrawFn) -> PiecewiseBezier:
    m = draw(st.integers(1, 5))
    n = draw(st.integers(0, 7))
    d = draw(st.integers(1, 3))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    cp = rng.uniform(-50.0, 50.0, size=(m, n + 1, d))  # discontinuous at the joints on purpose
    h = rng.uniform(0.1, 4.0, size=m)
    return PiecewiseBezier.from_control_points(cp, h)


def _close(got: np.ndarray, ref: np.ndarray, scale: float) -> bool:
    """1e-9 relative to the size of the derivative on the trajectory (its convex-hull bound)."""
    return bool(np.all(np.abs(np.asarray(got) - np.asarray(ref)) <= 1e-9 * (1.0 + scale)))


@settings(max_examples=60, deadline=None)
@given(traj=trajectories(), max_order=st.integers(0, 5),
       u=st.lists(st.floats(-0.2, 1.2), min_size=1, max_size=6))
def test_matches_evaluate_everywhere(traj: PiecewiseBezier, max_order: int,
                                     u: list[float]) -> None:
    ev = traj.scalar_evaluator(max_order)
    dur = traj.duration
    ts = [x * dur for x in u] + [float(b) for b in traj.breaks] + [-1.0, dur + 1.0, 0.0, dur]
    for t in ts:
        arr = ev(t)
        flat = ev.values(t)
        assert arr.shape == (max_order + 1, traj.dim) and len(flat) == arr.size
        assert all(isinstance(x, float) for x in flat)
        for k in range(max_order + 1):
            ref = traj.evaluate(t, k)
            scale = float(traj.hull_bounds(k).max())
            assert _close(arr[k], ref, scale), (t, k, arr[k], ref)
            assert _close(flat[k * traj.dim:(k + 1) * traj.dim], ref, scale), (t, k, flat, ref)


@settings(max_examples=40, deadline=None)
@given(traj=trajectories(), u=st.floats(0.0, 1.0))
def test_matches_scipy_bpoly_inside_segments(traj: PiecewiseBezier, u: float) -> None:
    bp = BPoly(np.transpose(traj.control_points, (1, 0, 2)), traj.breaks)
    ev = traj.scalar_evaluator(3)
    # a time strictly inside segment i (BPoly and we may pick different sides at a joint)
    i = min(int(u * traj.num_segments), traj.num_segments - 1)
    t = float(traj.breaks[i] + (0.05 + 0.9 * (u * traj.num_segments - i)) * traj.durations[i])
    got = ev(t)
    for k in range(4):
        scale = float(traj.hull_bounds(k).max())
        ref = bp(t, nu=k) if k <= traj.degree else np.zeros(traj.dim)  # BPoly: nu <= degree
        assert _close(got[k], ref, scale), (t, k)


@settings(max_examples=30, deadline=None)
@given(traj=trajectories())
def test_clamps_ends_and_uses_later_segment_at_joints(traj: PiecewiseBezier) -> None:
    """Bezier end-point interpolation: p = P_0 and p' = n (P_1 - P_0) / h at a segment's start."""
    ev = traj.scalar_evaluator(1)
    cp, h, n, d = traj.control_points, traj.durations, traj.degree, traj.dim

    def start_of(i: int) -> tuple[np.ndarray, np.ndarray]:
        vel = n * (cp[i, 1] - cp[i, 0]) / h[i] if n >= 1 else np.zeros(d)
        return cp[i, 0], vel

    scale0 = float(np.abs(cp).max())
    scale1 = float(traj.hull_bounds(1).max())
    for t in (-5.0, 0.0):
        p, v = start_of(0)
        got = ev(t)
        assert _close(got[0], p, scale0) and _close(got[1], v, scale1)
    for i in range(1, traj.num_segments):  # exactly at the joint: the later segment
        p, v = start_of(i)
        got = ev(float(traj.breaks[i]))
        assert _close(got[0], p, scale0) and _close(got[1], v, scale1)
    end_vel = n * (cp[-1, -1] - cp[-1, -2]) / h[-1] if n >= 1 else np.zeros(d)
    for t in (traj.duration, traj.duration + 3.0):
        got = ev(t)
        assert _close(got[0], cp[-1, -1], scale0) and _close(got[1], end_vel, scale1)


def test_cached_per_trajectory_and_order() -> None:
    traj = PiecewiseBezier.from_control_points(np.arange(12.0).reshape(2, 3, 2), [1.0, 2.0])
    ev = traj.scalar_evaluator(2)
    assert isinstance(ev, ScalarEvaluator) and ev.max_order == 2 and ev.dim == 2
    assert traj.scalar_evaluator(2) is ev
    assert traj.scalar_evaluator(4) is not ev


def test_refuses_nan_time_and_negative_order() -> None:
    traj = PiecewiseBezier.from_control_points(np.ones((1, 4, 3)), [1.0])
    ev = traj.scalar_evaluator(2)
    with pytest.raises(ValueError, match="NaN"):
        ev(math.nan)
    with pytest.raises(ValueError, match="NaN"):
        ev.values(math.nan)
    with pytest.raises(ValueError):
        traj.scalar_evaluator(-1)


@pytest.mark.parametrize("lengths", [(1,), (6, 5, 1), (3, 8, 2, 7), (40, 3)])  # 40: loop path
def test_horner_kernel_matches_numpy_polyval(lengths: tuple[int, ...]) -> None:
    rng = np.random.default_rng(len(lengths))
    rows = [rng.uniform(-3.0, 3.0, n) for n in lengths]  # descending coefficients
    fn = horner_fn(lengths)
    for s in (0.0, 0.3, 1.0, -0.7):
        got = fn(s, tuple(float(x) for r in rows for x in r))
        ref = [np.polyval(r, s) for r in rows]
        assert np.allclose(got, ref, rtol=1e-12, atol=1e-12)
