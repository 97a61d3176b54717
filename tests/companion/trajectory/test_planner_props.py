"""Hypothesis: waypoints hit exactly, boundary conditions met and continuity at every joint, for
random, collinear and U-turn waypoint sets, with fixed durations."""

from __future__ import annotations

import warnings

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.trajectory import PiecewiseBezier, plan

coord = st.floats(min_value=-100.0, max_value=100.0, allow_nan=False, allow_infinity=False)
dur = st.floats(min_value=0.2, max_value=10.0)


@st.composite
def problems(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray]:
    kind = draw(st.sampled_from(["random", "collinear", "uturn"]))
    d = draw(st.sampled_from([2, 3]))
    n = draw(st.integers(min_value=2, max_value=8))
    if kind == "random":
        wp = np.array([[draw(coord) for _ in range(d)] for _ in range(n)])
    elif kind == "collinear":
        direction = np.array([draw(coord) for _ in range(d)])
        if np.linalg.norm(direction) < 1e-3:
            direction = np.ones(d)
        origin = np.array([draw(coord) for _ in range(d)])
        steps = [draw(st.floats(min_value=-3.0, max_value=3.0)) for _ in range(n)]
        wp = origin + np.outer(np.cumsum(steps), direction / np.linalg.norm(direction))
    else:  # back and forth between two points
        a = np.array([draw(coord) for _ in range(d)])
        b = np.array([draw(coord) for _ in range(d)])
        wp = np.array([a if i % 2 == 0 else b for i in range(n)])
    h = np.array([draw(dur) for _ in range(n - 1)])
    return wp, h


def _check(tr: PiecewiseBezier, wp: np.ndarray, times: np.ndarray, s: int) -> None:
    scale = 1.0 + float(np.max(np.abs(wp)))
    np.testing.assert_allclose(tr.evaluate(times), wp, atol=1e-9 * scale)
    for r in range(1, s):
        v0, v1 = tr.evaluate(0.0, r), tr.evaluate(tr.duration, r)
        ref = scale / float(np.min(tr.durations)) ** r
        np.testing.assert_allclose(v0, 0.0, atol=1e-9 * ref)
        np.testing.assert_allclose(v1, 0.0, atol=1e-9 * ref)
    segs = tr.segments
    # the r-th derivatives' largest size at any joint: the joints are solved together in one
    # banded system, whose round-off follows its largest values (a 4 m step in a 0.22 s end
    # segment gave 2e4 at order 5 and put 2e-9 of round-off on a joint where it is ~0, beyond
    # a tolerance scaled by that joint's own 3 s segments; hypothesis in CI, 2026-12-02)
    size = [max((float(np.max(np.abs(seg.evaluate(seg.duration, r)))) for seg in segs[:-1]),
                default=0.0) for r in range(2 * s - 1)]
    for k in range(len(segs) - 1):
        hmin = min(segs[k].duration, segs[k + 1].duration)
        # continuity through snap (s = 4) / jerk (s = 3), and the free-joint optimality
        # conditions through order 2s - 2
        for r in range(0, 2 * s - 1):
            left = segs[k].evaluate(segs[k].duration, r)
            right = segs[k + 1].evaluate(0.0, r)
            ref = max(scale / hmin**r, size[r])
            np.testing.assert_allclose(
                left, right, atol=1e-7 * ref, err_msg=f"joint {k}, order {r}"
            )


@settings(max_examples=40, deadline=None)
@given(problems(), st.sampled_from(["snap", "jerk"]))
def test_waypoints_boundaries_and_continuity(
    problem: tuple[np.ndarray, np.ndarray], order: str
) -> None:
    wp, h = problem
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # collinear steps of 0 are merged duplicates
        keep = np.concatenate(([True], np.max(np.abs(np.diff(wp, axis=0)), axis=1) > 1e-9))
        if keep.sum() < 2:
            return
        wp, h = wp[keep], h[keep[1:]]
        tr = plan(wp, durations=h, order=order)
    s = 4 if order == "snap" else 3
    assert tr.degree == 2 * s - 1
    assert tr.dim == wp.shape[1]
    _check(tr, wp, tr.breaks, s)


@st.composite
def allocation_problems(draw: st.DrawFn) -> np.ndarray:
    kind = draw(st.sampled_from(["random", "collinear", "uturn"]))
    n = draw(st.integers(min_value=2, max_value=5))
    unit = np.array([draw(st.floats(-1.0, 1.0)) for _ in range(3)])
    if np.linalg.norm(unit) < 0.1:
        unit = np.array([1.0, 0.0, 0.0])
    unit /= np.linalg.norm(unit)
    if kind == "random":
        steps = [np.array([draw(st.floats(-1.0, 1.0)) for _ in range(3)]) for _ in range(n - 1)]
        steps = [st_ / max(np.linalg.norm(st_), 1e-3) * draw(st.floats(2.0, 20.0)) for st_ in steps]
    elif kind == "collinear":
        steps = [unit * draw(st.floats(2.0, 20.0)) for _ in range(n - 1)]
    else:
        length = draw(st.floats(2.0, 20.0))
        steps = [unit * length * (1 if i % 2 == 0 else -1) for i in range(n - 1)]
    return np.cumsum(np.vstack([np.zeros((1, 3)), *steps]), axis=0)


@settings(max_examples=8, deadline=None)
@given(allocation_problems())
def test_time_allocated_plans_hit_waypoints_within_limits(wp: np.ndarray) -> None:
    from companion.trajectory import Limits, check, plan_with_info

    lim = Limits(max_speed_m_s=4.0, max_acc_m_s2=3.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a zero random step is a merged duplicate
        res = plan_with_info(wp, limits=lim)
    tr = res.trajectory
    np.testing.assert_allclose(tr.evaluate(res.waypoint_times), wp, atol=1e-8)
    assert not any(r.exceeded for r in check(tr, lim).values())
    _check(tr, tr.evaluate(tr.breaks), tr.breaks, 4)


@st.composite
def rover_problems(draw: st.DrawFn) -> np.ndarray:
    """3..8 waypoints with legs >= max_speed^2 / max_lat_acc and turns up to a near-U-turn."""
    n = draw(st.integers(min_value=3, max_value=8))
    heading = draw(st.floats(-np.pi, np.pi))
    pts = [np.zeros(2)]
    for i in range(n - 1):
        if i > 0:
            heading += draw(st.floats(-np.pi + 1e-3, np.pi - 1e-3))
        step = draw(st.floats(4.0, 16.0))
        pts.append(pts[-1] + step * np.array([np.cos(heading), np.sin(heading)]))
    return np.array(pts)


@settings(max_examples=10, deadline=None)
@given(rover_problems())
def test_rover_time_allocation_always_succeeds_within_limits(wp: np.ndarray) -> None:
    from companion.trajectory import RoverLimits, plan_with_info

    lim = RoverLimits(max_speed_m_s=2.0, max_yaw_rate_rad_s=0.8, max_lat_acc_m_s2=1.0)
    res = plan_with_info(wp, limits=lim)
    tr = res.trajectory
    np.testing.assert_allclose(tr.evaluate(res.waypoint_times), wp, atol=1e-8)
    tol = 1.0 + 1e-6
    for seg in tr.segments:
        t = np.linspace(0.0, seg.duration, 1000)
        v, a = seg.evaluate(t, 1), seg.evaluate(t, 2)
        speed = np.hypot(v[:, 0], v[:, 1])
        assert speed.max() <= 2.0 * tol
        cross = v[:, 0] * a[:, 1] - v[:, 1] * a[:, 0]
        ok = speed > 1e-3  # heading undefined at rest (RoverLimits convention)
        assert np.all(np.abs(cross[ok]) / speed[ok] ** 2 <= 0.8 * tol)
        assert np.all(np.abs(cross[ok]) / speed[ok] <= 1.0 * tol)
