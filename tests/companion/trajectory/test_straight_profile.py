"""Rest-to-rest motion along a straight line (`companion.trajectory.straight`): the limits hold
on dense samples, the waypoints are passed in order on the line, the derivatives are continuous,
and the duration sits between the time-optimal trapezoid (no jerk limit: a lower bound) and a
few % above it."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from companion.trajectory.straight import (
    LineLimits,
    collinear_direction,
    straight_profile,
    straight_trajectory,
)


def _trapezoid_s(length: float, cap: float, a_up: float, a_dn: float) -> float:
    """Time-optimal rest-to-rest time over `length` at speed <= cap (infinite jerk)."""
    # peak speed reachable: v^2/(2 a_up) + v^2/(2 a_dn) <= length
    v = min(cap, math.sqrt(2.0 * length / (1.0 / a_up + 1.0 / a_dn)))
    ramps = v * v / (2.0 * a_up) + v * v / (2.0 * a_dn)
    return v / a_up + v / a_dn + (length - ramps) / v


def _samples(traj, n: int = 20001) -> tuple[np.ndarray, ...]:  # type: ignore[no-untyped-def]
    t = np.linspace(0.0, traj.duration, n)
    return (t, *(traj.evaluate(t, k) for k in range(4)))


@pytest.mark.parametrize(
    ("length", "cap", "a_up", "a_dn"),
    [(20.0, 1.5, 4.0, 3.0), (10.0, 3.0, 3.0, 4.0), (80.0, 5.0, 5.0, 5.0), (0.4, 2.0, 4.0, 3.0)],
)
def test_one_band_is_just_above_the_time_optimal_trapezoid(
    length: float, cap: float, a_up: float, a_dn: float
) -> None:
    lim = LineLimits(a_up, a_dn, 20.0)
    traj = straight_trajectory([[0.0, 0.0, 0.0], [0.0, 0.0, -length]], [cap], lim)
    bound = _trapezoid_s(length, cap, a_up, a_dn)
    assert bound <= traj.duration <= bound + 0.6  # the jerk-limited ramps cost < 0.3 s each
    _, p, v, a, j = _samples(traj)
    assert np.allclose(p[0], 0.0) and np.allclose(p[-1], [0.0, 0.0, -length], atol=1e-9)
    assert np.allclose(v[[0, -1]], 0.0, atol=1e-9) and np.allclose(a[[0, -1]], 0.0, atol=1e-9)
    assert np.max(np.linalg.norm(v, axis=1)) <= cap * (1 + 1e-9)
    # climbing (NED -z): speeding up accelerates upwards (-z), slowing down downwards
    assert np.max(-a[:, 2]) <= a_up * (1 + 1e-9) and np.max(a[:, 2]) <= a_dn * (1 + 1e-9)
    assert np.max(np.abs(j)) <= 20.0 * (1 + 1e-6)


@settings(max_examples=60, deadline=None)
@given(
    lengths=st.lists(st.floats(0.2, 40.0), min_size=1, max_size=6),
    caps=st.lists(st.floats(0.3, 8.0), min_size=6, max_size=6),
    a_up=st.floats(0.5, 6.0),
    a_dn=st.floats(0.5, 6.0),
    jerk=st.floats(2.0, 40.0),
    drag=st.sampled_from([0.0, 0.5, 1.0]),
    direction=st.sampled_from([(1.0, 0.0, 0.0), (0.6, 0.8, 0.0), (0.0, 0.0, 1.0),
                               (0.0, 0.6, -0.8)]),
)
# found by the default test run: two speed-up levels both at a_up differed by round-off, and
# their 6e-16 s transition had a snap of 90 m/s^4 at its end
@example(lengths=[27.0], caps=[5.0, 1.0, 1.0, 1.0, 1.0, 1.0], a_up=1.2, a_dn=1.0, jerk=2.0,
         drag=1.0, direction=(1.0, 0.0, 0.0))
# and by a sweep of seeds: the rest at the end of a 129 m profile reads -1.1e-9 m/s (round-off)
@example(lengths=[1.0, 1.8856892152541427, 7.209994162262571, 39.9737688669929,
                  39.652724461001796, 39.29831486791157],
         caps=[1.0, 1.0, 1.0, 1.0, 1.0, 0.30078125], a_up=1.0, a_dn=0.5,
         jerk=29.652724461001796, drag=0.0, direction=(1.0, 0.0, 0.0))
@example(lengths=[1.0, 23.0, 40.0, 10.0], caps=[1.0, 1.0, 1.0, 0.40625, 1.0, 1.0], a_up=1.0,
         a_dn=2.734375, jerk=36.25, drag=0.0, direction=(1.0, 0.0, 0.0))
@example(lengths=[1.0, 32.0, 29.5, 11.0, 1.0], caps=[1.0, 1.0, 2.0, 2.970703125, 1.91796875, 1.0],
         a_up=1.0, a_dn=4.59375, jerk=37.8125, drag=0.0, direction=(1.0, 0.0, 0.0))
def test_bands_caps_accelerations_and_continuity_hold(
    lengths: list[float], caps: list[float], a_up: float, a_dn: float, jerk: float,
    drag: float, direction: tuple[float, float, float],
) -> None:
    cap_tilt = 6.0 if drag > 0.0 else math.inf
    lim = LineLimits(a_up, a_dn, jerk, speedup_cap_m_s2=cap_tilt, drag_per_s=drag)
    caps_b = np.minimum(np.array(caps[: len(lengths)]), lim.top_speed())
    u = np.array(direction)
    s_pts = np.concatenate([[0.0], np.cumsum(lengths)])
    pts = np.array([5.0, -3.0, -10.0]) + s_pts[:, None] * u
    traj = straight_trajectory(pts, caps_b, lim, yaw=(0.2, 1.4))
    t, p, v, a, j = _samples(traj)
    s = (p - pts[0]) @ u
    off = p - pts[0] - s[:, None] * u
    assert np.max(np.linalg.norm(off, axis=1)) < 1e-6  # on the line
    speed = v @ u
    # never backwards (round-off of the Bezier evaluation grows with the length: -1.1e-9 m/s
    # at the end of a 129 m profile)
    assert np.min(speed) >= -1e-9 * max(1.0, s_pts[-1])
    assert abs(s[-1] - s_pts[-1]) < 1e-6 and abs(speed[-1]) < 1e-9 * max(1.0, s_pts[-1])
    assert abs(speed[0]) < 1e-12
    # each band's cap holds inside it (the speed changes happen inside the faster band)
    band = np.clip(np.searchsorted(s_pts, s, side="right") - 1, 0, len(lengths) - 1)
    assert np.all(speed <= caps_b[band] * (1 + 1e-7) + 1e-9)
    acc = a @ u
    up = acc > 0.0
    # speeding up: at most the acceleration and what the tilt leaves beyond the drag
    allowed = np.minimum(a_up, cap_tilt - drag * speed)
    assert np.all(acc[up] <= allowed[up] * 1.02 + 1e-6)
    # (the Bezier form of a millisecond piece carries round-off in its acceleration: 1.4 ms at
    # -4.59375 m/s^2 samples at -4.5937655 at 52 m from the origin; the exact bound is checked
    # on the profile's polynomials below)
    assert np.all(-acc[~up] <= a_dn + 1e-4)
    assert np.max(np.abs(j @ u)) <= jerk * (1 + 1e-6)
    # derivatives up to snap are continuous at every joint (on the profile's polynomials: the
    # Bezier form of a millisecond piece amplifies round-off in its higher derivatives)
    pieces, _ = straight_profile(lengths, caps_b, lim)
    for h0, c0 in pieces:
        acc_p = np.polynomial.polynomial.polyval(
            np.linspace(0.0, h0, 64), np.polynomial.polynomial.polyder(c0, 2))
        assert np.all(-acc_p <= a_dn * (1 + 1e-9) + 1e-12)
        assert np.all(acc_p <= a_up * (1 + 1e-9) + 1e-12)
    for (h0, c0), (_, c1) in itertools.pairwise(pieces):
        for order in range(5):
            d0 = np.polynomial.polynomial.polyder(c0, order)
            d1 = np.polynomial.polynomial.polyder(c1, order)
            end = np.polynomial.polynomial.polyval(h0, d0)
            scale = max(1.0, abs(end), jerk ** (order / 3.0))
            assert abs(end - d1[0]) <= 1e-7 * scale * 10.0 ** order, (order, end, d1[0])
    assert np.allclose(traj.breaks[-1], sum(h for h, _ in pieces))
    # every waypoint is passed (in order)
    passed = np.interp(s_pts, s, t)
    assert np.all(np.diff(passed) > 0.0)
    yaw = traj.yaw
    assert yaw is not None
    assert yaw.evaluate(0.0, 0)[0] == pytest.approx(0.2) and yaw.evaluate(
        traj.duration, 0)[0] == pytest.approx(1.4)
    assert abs(yaw.evaluate(traj.duration, 1)[0]) < 1e-9


def test_a_drag_limited_speed_up_beats_one_level_at_the_top_speed() -> None:
    """Speeding up against drag uses more acceleration at low speed than at the top speed:
    quicker than one ramp at the top speed's acceleration, slower than no drag."""
    drag = LineLimits(5.0, 5.0, 20.0, speedup_cap_m_s2=6.7, drag_per_s=1.0)
    flat = LineLimits(6.7 - 5.0, 5.0, 20.0)  # what is left at 5 m/s, everywhere
    free = LineLimits(5.0, 5.0, 20.0)
    pts = [[0.0, 0.0, -30.0], [80.0, 0.0, -30.0]]
    d = straight_trajectory(pts, [5.0], drag).duration
    assert straight_trajectory(pts, [5.0], free).duration < d
    assert d < straight_trajectory(pts, [5.0], flat).duration - 0.5


def test_not_a_straight_line_or_a_reversal_is_refused() -> None:
    assert collinear_direction([[0, 0, 0], [1, 0, 0], [1, 1, 0]]) is None
    assert collinear_direction([[0, 0, 0], [2, 0, 0], [1, 0, 0]]) is None
    assert collinear_direction([[0, 0, 0], [0, 0, 0]]) is None
    u = collinear_direction([[0, 0, 0], [0, 0, -3], [0, 0, -10]])
    assert u is not None and np.allclose(u, [0, 0, -1])
    with pytest.raises(ValueError):
        straight_trajectory([[0, 0, 0], [1, 0, 0], [1, 1, 0]], [1.0, 1.0], LineLimits(1, 1, 1))
    with pytest.raises(ValueError):
        straight_profile([1.0], [0.0], LineLimits(1, 1, 1))
    with pytest.raises(ValueError):
        LineLimits(0.0, 1.0, 1.0)


@pytest.mark.parametrize("name", ["square.plan", "survey.plan"])
def test_climbs_and_descents_of_a_mission_fly_near_their_bound_within_px4_limits(
    name: str,
) -> None:
    """The straight chunks of a mission (takeoff, RTL climb and return, final descent) take at
    most 3 % + 0.5 s over the time-optimal bound of the same path (`trajectory.bound`, a
    separate TOPP) and keep PX4's per-axis accelerations (finite differences of the
    positions)."""
    from pathlib import Path

    from companion.mission import load_mission, mission_to_flight_plan
    from companion.planning.config import VehicleFile
    from companion.planning.schedule import build_schedule

    root = Path(__file__).resolve().parents[3]
    vf = VehicleFile()
    fp = mission_to_flight_plan(load_mission(root / "examples" / "missions" / name))
    sched = build_schedule(fp, vf.params, vf.limits)
    px4 = fp.px4
    straight = 0
    for piece, bound in zip(sched.pieces, sched.piece_bounds_s(), strict=True):
        if piece.kind != "traj" or piece.traj is None:
            continue
        ends = piece.traj.evaluate(np.array([0.0, piece.duration_s]), 0)
        if collinear_direction(ends) is None or piece.traj.num_segments > 40:
            continue
        mid = np.asarray(piece.traj.evaluate(0.5 * piece.duration_s, 0)).reshape(-1)
        if np.linalg.norm(np.cross(mid - ends[0], ends[1] - ends[0])) > 1e-6 * np.linalg.norm(
                ends[1] - ends[0]) ** 2:
            continue  # not on the straight line between its ends
        straight += 1
        # the jerk-limited ramps cost a few tenths of a second in all (the bound: infinite jerk)
        assert bound <= piece.duration_s <= 1.03 * bound + 0.5, (piece.phase, piece.duration_s,
                                                                bound)
        dt = 0.005
        t = np.arange(0.0, piece.duration_s, dt)
        p = piece.traj.evaluate(t, 0)
        acc = np.diff(p, 2, axis=0) / dt**2
        assert np.max(np.hypot(acc[:, 0], acc[:, 1])) <= px4.MPC_ACC_HOR_MAX * 1.01
        assert np.max(-acc[:, 2]) <= px4.MPC_ACC_UP_MAX * 1.01  # NED: up is -z
        assert np.max(acc[:, 2]) <= px4.MPC_ACC_DOWN_MAX * 1.01
    assert straight >= (2 if name == "square.plan" else 4)
