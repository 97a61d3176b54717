"""Time allocation with the corridor: containment under dense sampling (distances recomputed
here from the straight legs, not through the planner's corridor code), waypoints held
exactly, limits met (`check`), and the pieces of the faster corridor allocation (segment-wise
breach check, splits with warm-start durations, refinement work cap, coarse feasibility
look) against independent references."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from companion.flatness import MultirotorParams
from companion.trajectory import Limits, check, plan, plan_with_info
from companion.trajectory.allocation import (
    REFINE_MAXITER,
    REFINE_MIN_ITER,
    REFINE_WORK_BUDGET,
    refine_iterations,
)
from companion.trajectory.corridor import (
    CORRIDOR_SAMPLES_PER_SEGMENT,
    corridor_breaches,
    split_breaches,
)
from companion.trajectory.joints import PlanProblem

G = 9.80665
PARAMS = MultirotorParams(mass=1.5, inertia=np.diag([0.03, 0.03, 0.05]), drag=0.4)
LIMITS = Limits(
    max_speed_m_s=8.0,
    max_acc_m_s2=4.0,
    max_tilt_rad=math.radians(35.0),
    max_thrust_n=1.8 * PARAMS.mass * G,
    max_body_rate_rad_s=3.0,
    max_acc_axes_m_s2=(4.0, 3.0, 3.0),
    max_vel_axes_m_s=(8.0, 3.0, 1.5),
)


def zigzag(rng: np.random.Generator, n: int) -> np.ndarray:
    """n waypoints (NED, m): legs 15-60 m with turns up to 115 deg, altitudes 10-40 m up."""
    pts = [np.array([0.0, 0.0, -15.0])]
    heading = 0.0
    for _ in range(n - 1):
        heading += rng.uniform(-2.0, 2.0)
        d = rng.uniform(15.0, 60.0)
        pts.append(np.array([pts[-1][0] + d * math.cos(heading),
                             pts[-1][1] + d * math.sin(heading), -rng.uniform(10.0, 40.0)]))
    return np.array(pts)


def leg_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance (N,) of points p (N, 3) to the segment a-b, by projection."""
    ab = b - a
    t = np.clip((p - a) @ ab / (ab @ ab), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[:, None] * ab), axis=1)


def outside_corridor(path: np.ndarray, wp: np.ndarray, acc: np.ndarray,
                     corridor: float) -> np.ndarray:
    """Excess (N,) of each path sample over the corridor [m] (<= 0 inside): distance to the
    nearest straight leg, unless within a waypoint's acceptance radius."""
    dist = np.min([leg_distance(path, a, b) for a, b in itertools.pairwise(wp)],
                  axis=0)
    near = np.min(np.linalg.norm(path[:, None, :] - wp[None, :, :], axis=2) - acc[None, :],
                  axis=1)
    return np.minimum(dist - corridor, near)


@pytest.mark.parametrize(("seed", "n", "corridor"),
                         [(0, 8, 1.0), (1, 12, 0.5), (2, 10, 2.0), (3, 110, 1.0)])
def test_corridor_plan_stays_in_corridor_under_dense_sampling(
    seed: int, n: int, corridor: float
) -> None:
    rng = np.random.default_rng(seed)
    wp = zigzag(rng, n)
    acc = rng.uniform(0.5, 3.0, n)
    caps = rng.uniform(3.0, 12.0, n - 1)
    res = plan_with_info(wp, limits=LIMITS, params=PARAMS, speed_caps=np.minimum(caps, 8.0),
                         corridor_m=corridor, acceptance_m=acc)
    traj = res.trajectory
    # 400 samples per segment, ends included: 16x the planner's own corridor sampling
    tau = np.linspace(0.0, 1.0, 400)
    t = (traj.breaks[:-1, None] + tau[None, :] * traj.durations[:, None]).reshape(-1)
    excess = outside_corridor(traj.evaluate(t, 0), wp, acc, corridor)
    assert float(np.max(excess)) <= 0.02 * corridor, float(np.max(excess))
    # every waypoint exactly, in order
    at = traj.evaluate(res.waypoint_times, 0)
    assert np.max(np.abs(at - wp)) < 1e-6
    assert np.all(np.diff(res.waypoint_times) > 0.0)
    # every limit: the library's dense check for the norms, the per-axis ones recomputed
    assert not any(r.exceeded for r in check(traj, LIMITS, PARAMS).values())
    for order, (h_lim, up, down) in ((1, LIMITS.max_vel_axes_m_s),
                                     (2, LIMITS.max_acc_axes_m_s2)):
        v = traj.evaluate(t, order)
        assert float(np.max(np.hypot(v[:, 0], v[:, 1]))) <= h_lim * 1.01
        assert float(np.max(-v[:, 2])) <= up * 1.01
        assert float(np.max(v[:, 2])) <= down * 1.01


def pointwise_breaches(traj, wp, seg_leg, corridor, acc):  # type: ignore[no-untyped-def]
    """Reference: per sample, loop over the leg and its neighbours (projection distance),
    zero inside an acceptance radius of the leg's ends."""
    n = CORRIDOR_SAMPLES_PER_SEGMENT
    out = []
    for k in range(traj.num_segments):
        t = traj.breaks[k] + (np.arange(n) + 0.5) / n * traj.durations[k]
        p = traj.evaluate(t, 0)
        leg = int(seg_leg[k])
        bad = False
        for q in p:
            d = min(float(leg_distance(q[None, :], wp[o], wp[o + 1])[0])
                    for o in (leg - 1, leg, leg + 1) if 0 <= o < len(wp) - 1)
            if any(np.linalg.norm(q - wp[w]) <= acc[w] for w in (leg, leg + 1)):
                d = 0.0
            bad |= d > corridor
        out.append(bad)
    return np.array(out)


@pytest.mark.parametrize("seed", range(6))
def test_segment_wise_breach_check_matches_pointwise_reference(seed: int) -> None:
    rng = np.random.default_rng(10 + seed)
    n = int(rng.integers(3, 7))
    wp = zigzag(rng, n)
    pieces = rng.integers(1, 4, n - 1)
    joints = [wp[0]]
    seg_leg = []
    for leg, k in enumerate(pieces):
        for j in range(1, k + 1):
            joints.append(wp[leg] + j / k * (wp[leg + 1] - wp[leg]))
            seg_leg.append(leg)
    joints_a = np.array(joints)
    # durations off the natural ones: the path swings off the legs
    h = np.linalg.norm(np.diff(joints_a, axis=0), axis=1) / 5.0 * rng.uniform(0.3, 3.0,
                                                                              len(seg_leg))
    traj = plan(joints_a, durations=h)
    acc = rng.uniform(0.0, 4.0, n)
    seg = np.array(seg_leg)
    for corridor in (0.1, 0.5, 1.0, 3.0):
        got = corridor_breaches(traj, wp, seg, corridor, acc)
        np.testing.assert_array_equal(got, pointwise_breaches(traj, wp, seg, corridor, acc))


def test_split_puts_two_joints_on_the_leg_and_shares_the_duration() -> None:
    fracs = [[0.0, 0.5], [0.0], [0.0, 0.2, 0.6]]
    seg_leg = np.array([0, 0, 1, 2, 2, 2])
    bad = np.array([False, True, True, False, True, False])
    h = np.array([1.0, 3.0, 6.0, 2.0, 1.2, 5.0])
    new, h_new = split_breaches(fracs, seg_leg, bad, h)
    assert new == [[0.0, 0.5, 0.5 + 0.5 / 3, 0.5 + 1.0 / 3],
                   [0.0, 1.0 / 3, 2.0 / 3],
                   [0.0, 0.2, 0.2 + 0.4 / 3, 0.2 + 0.8 / 3, 0.6]]
    assert fracs == [[0.0, 0.5], [0.0], [0.0, 0.2, 0.6]]  # the input is left alone
    assert h_new is not None
    assert len(h_new) == sum(len(f) for f in new)
    assert math.isclose(float(h_new.sum()), float(h.sum()))
    np.testing.assert_allclose(h_new, [1.0, 1.0, 1.0, 1.0, 2.0, 2.0, 2.0, 2.0, 0.4, 0.4, 0.4,
                                       5.0])


def test_refinement_work_cap_keeps_small_plans_and_bounds_large_ones() -> None:
    full = REFINE_WORK_BUDGET // REFINE_MAXITER
    assert all(refine_iterations(m) == REFINE_MAXITER for m in (1, 7, 150, full))
    prev = REFINE_MAXITER
    for m in range(full, 5000, 37):
        it = refine_iterations(m)
        assert REFINE_MIN_ITER <= it <= prev
        assert it == REFINE_MIN_ITER or it * m <= REFINE_WORK_BUDGET
        prev = it


@pytest.mark.parametrize("seed", range(3))
def test_coarse_feasibility_look_gives_the_dense_verdict(seed: int) -> None:
    rng = np.random.default_rng(20 + seed)
    wp = zigzag(rng, 6)
    fracs = [[0.0, 1.0 / 3.0, 2.0 / 3.0] for _ in range(len(wp) - 1)]
    planner, _, _ = PlanProblem(wp, 4, {}, {}, {}, None, None, None, LIMITS).planner(fracs)
    h = planner.refined(LIMITS, PARAMS)
    seen = set()
    for k in np.linspace(0.8, 1.6, 17):
        coarse = planner.max_ratio(h * k, LIMITS, PARAMS, coarse=True)
        dense = planner.max_ratio(h * k, LIMITS, PARAMS)
        seen.add(dense[0] <= 1.0)
        if coarse[0] <= 1.0:  # a feasible verdict is the dense check's own
            assert coarse[0] == dense[0]
            np.testing.assert_array_equal(coarse[1], dense[1])
        if dense[0] > 1.0 and coarse[0] <= 1.0:
            pytest.fail("coarse look called an infeasible plan feasible")
    assert seen == {True, False}  # both verdicts exercised


def _scalar_distance(p: list[float], a: list[float], b: list[float]) -> float:
    """Point-segment distance with Python floats: nearest point a + t (b - a), t in [0, 1]."""
    ab = [y - x for x, y in zip(a, b, strict=True)]
    den = sum(v * v for v in ab)
    t = 0.0 if den == 0.0 else sum((pi - ai) * v for pi, ai, v in zip(p, a, ab, strict=True)) / den
    t = min(max(t, 0.0), 1.0)
    return math.dist(p, [ai + t * v for ai, v in zip(a, ab, strict=True)])


@pytest.mark.parametrize("dim", [2, 3])
def test_segment_distances_broadcast_match_scalar_projection(dim: int) -> None:
    # points (5, 1, d) against segments (1, 4, d), one of zero length: every pair equals the
    # textbook projection (clamped to the segment; a zero-length segment is its point)
    from companion.trajectory.corridor import segment_distances

    rng = np.random.default_rng(7 + dim)
    p = rng.normal(size=(5, 1, dim)) * 20.0
    a = rng.normal(size=(1, 4, dim)) * 20.0
    b = rng.normal(size=(1, 4, dim)) * 20.0
    b[0, 2] = a[0, 2]
    got = segment_distances(p, a, b)
    assert got.shape == (5, 4)
    for i, j in itertools.product(range(5), range(4)):
        want = _scalar_distance(p[i, 0].tolist(), a[0, j].tolist(), b[0, j].tolist())
        assert got[i, j] == pytest.approx(want, rel=1e-12, abs=1e-9)
