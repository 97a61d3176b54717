"""The mission benchmark's path metrics (bench/mission_metrics.py) against independent checks:
hand-built geometry with known distances, and brute force over densely sampled polylines."""

from __future__ import annotations

import itertools
import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))

from mission_metrics import (
    closest_approach_path,
    corridor_check,
    polyline_distance,
)

SQUARE = np.array([[0.0, 0.0, -10.0], [40.0, 0.0, -10.0], [40.0, 40.0, -10.0],
                   [0.0, 40.0, -10.0], [0.0, 0.0, -10.0]])


def densify(poly: np.ndarray, step: float) -> np.ndarray:
    """Points along the polyline no more than `step` apart (vertices included)."""
    out = [poly[:1]]
    for a, b in itertools.pairwise(poly):
        n = max(math.ceil(np.linalg.norm(b - a) / step), 1)
        u = np.linspace(0.0, 1.0, n + 1)[1:, None]
        out.append(a + u * (b - a))
    return np.vstack(out)


@pytest.mark.parametrize("seed", range(5))
def test_polyline_distance_matches_brute_force_over_a_dense_polyline(seed: int) -> None:
    rng = np.random.default_rng(seed)
    poly = np.cumsum(rng.normal(scale=10.0, size=(6, 3)), axis=0)
    pts = rng.uniform(-30.0, 30.0, size=(200, 3)) + poly.mean(axis=0)
    step = 0.002
    dense = densify(poly, step)
    brute = np.array([np.min(np.linalg.norm(dense - p, axis=1)) for p in pts])
    d = polyline_distance(pts, poly, chunk=37)  # a chunk size that splits the points unevenly
    # the exact distance is below the brute-force one by at most half a sample spacing
    assert np.all(d <= brute + 1e-9)
    assert np.all(brute - d <= step / 2 + 1e-9)


def test_polyline_distance_of_known_points() -> None:
    pts = np.array([[20.0, 3.0, -10.0],     # 3 m beside the first leg
                    [43.0, -4.0, -10.0],    # outside the first corner: 5 m (3-4-5)
                    [20.0, 20.0, -10.0],    # the centre: 20 m from every leg
                    [10.0, 0.0, -12.5]])    # 2.5 m below the first leg
    assert polyline_distance(pts, SQUARE) == pytest.approx([3.0, 5.0, 20.0, 2.5])
    # a single point is a degenerate polyline; repeated vertices are zero-length legs
    assert polyline_distance(pts[:1], SQUARE[:1]) == pytest.approx([math.hypot(20.0, 3.0)])
    doubled = np.repeat(SQUARE, 2, axis=0)
    assert polyline_distance(pts, doubled) == pytest.approx([3.0, 5.0, 20.0, 2.5])


def test_closest_approach_sees_a_waypoint_passed_between_two_samples() -> None:
    # two samples 2 m apart pass 0.3 m beside the waypoint, which lies between them: the
    # nearest sample is sqrt(1 + 0.09) m away, the path itself 0.3 m
    path = np.array([[-1.0, 0.3, 0.0], [1.0, 0.3, 0.0]])
    wps = np.array([[0.0, 0.0, 0.0], [5.0, 0.3, 0.0], [-1.0, 0.3, 0.0]])
    assert closest_approach_path(path, wps) == pytest.approx([0.3, 4.0, 0.0])
    assert np.all(np.isinf(closest_approach_path(np.zeros((0, 3)), wps)))


def test_corridor_along_legs_and_around_corners() -> None:
    acc = np.full(len(SQUARE), 2.0)
    inside = np.array([[20.0, 0.9, -10.0],     # 0.9 m beside a leg
                       [40.0, 20.0, -10.6],    # 0.6 m below a leg
                       [38.8, 1.2, -10.0]])    # corner cut: 1.2 m from both legs, 1.7 m from
    # the corner (within its 2 m acceptance radius)
    r = corridor_check(inside, SQUARE, SQUARE, acc, 1.0)
    assert r.within and r.outside == 0 and r.samples == 3
    assert r.max_dev_m == pytest.approx(1.2)
    assert r.max_excess_m == 0.0
    outside = np.vstack([inside, [[20.0, -1.25, -10.0],   # 1.25 m off mid-leg: 0.25 m beyond
                                  [37.5, 2.5, -10.0]]])   # 2.5 m from both legs, 3.54 m
    # from the corner: 1.5 m beyond the corridor, 1.54 m beyond the acceptance radius
    r = corridor_check(outside, SQUARE, SQUARE, acc, 1.0)
    assert not r.within
    assert r.outside == 2 and r.samples == 5
    assert r.max_dev_m == pytest.approx(2.5)
    corner_gap = math.hypot(2.5, 2.5) - 2.0
    assert r.max_excess_m == pytest.approx(min(1.5, corner_gap))
    expected_rms = math.sqrt(np.mean(np.array([0.9, 0.6, 1.2, 1.25, 2.5]) ** 2))
    assert r.rms_dev_m == pytest.approx(expected_rms)


def test_corridor_without_samples_is_not_within() -> None:
    r = corridor_check(np.zeros((0, 3)), SQUARE, SQUARE, np.full(5, 2.0), 1.0)
    assert not r.within and r.samples == 0
    with pytest.raises(ValueError, match="acceptance"):
        corridor_check(SQUARE, SQUARE, SQUARE, [2.0], 1.0)


def test_mission_bench_on_a_short_mission_agrees_with_the_replay_report() -> None:
    """bench_missions' mock row of a 3-waypoint mission: times cover the flights, its closest
    approach (between samples) is never worse than the replay report's (at samples), and the
    mock's AUTO.MISSION passes every waypoint within its acceptance radius."""
    import bench_missions

    from companion.replay.runner import ReplayConfig

    root = Path(__file__).resolve().parents[2]
    row = bench_missions.mock_mission(root / "tests" / "data" / "missions" / "px4_short.plan",
                                      ReplayConfig(), 1.0, None)
    comp, auto = row["companion"], row["auto_mission"]
    assert comp["result"] == "ok" and auto["result"] == "ok"
    assert comp["time_s"] > row["planned_s"]  # armed for the whole plan, then the landing
    assert 0.0 < auto["time_s"] < 3.0 * row["planned_s"]
    assert row["ratio"] == pytest.approx(comp["time_s"] / auto["time_s"])
    assert np.all(np.array(comp["closest_m"]) <= np.array(row["report_closest_m"]) + 1e-9)
    assert np.all(np.array(auto["closest_m"]) <= np.array(row["acceptance_m"]))
    assert comp["samples"] > 0 and auto["samples"] > 0
    assert math.isnan(row["bound_s"])  # no bound function given
