"""Geofence containment against independent oracles (matplotlib's Path, explicit distances)."""

from __future__ import annotations

import numpy as np
import pytest
from matplotlib.path import Path as MplPath

from companion.mission import FenceCircle, FencePolygon, FenceViolation, Geofence

STAR = ((0.0, 0.0), (40.0, 10.0), (10.0, 20.0), (50.0, 40.0), (0.0, 50.0), (-20.0, 25.0))


def _poly(verts: tuple[tuple[float, float], ...], inclusion: bool) -> FencePolygon:
    return FencePolygon(inclusion, verts, verts)  # vertices_deg unused by contains()


def _circle(c: tuple[float, float], r: float, inclusion: bool) -> FenceCircle:
    return FenceCircle(inclusion, 0.0, 0.0, c, r)


def test_polygon_matches_matplotlib_path() -> None:
    rng = np.random.default_rng(3)
    pts = rng.uniform(-30, 60, (4000, 3))
    poly = _poly(STAR, True)
    oracle = MplPath(np.asarray(STAR)).contains_points(pts[:, :2])
    got = poly.contains(pts)
    # ignore points within 1e-6 m of an edge (boundary conventions differ)
    v = np.asarray(STAR)
    near = np.zeros(len(pts), dtype=bool)
    for a, b in zip(v, np.roll(v, -1, axis=0), strict=True):
        t = np.clip(((pts[:, :2] - a) @ (b - a)) / ((b - a) @ (b - a)), 0, 1)
        near |= np.linalg.norm(pts[:, :2] - (a + t[:, None] * (b - a)), axis=1) < 1e-6
    assert np.array_equal(got[~near], oracle[~near])
    assert 500 < oracle.sum() < 3500  # the sample exercises both sides


def test_polygon_winding_does_not_matter() -> None:
    pts = np.random.default_rng(4).uniform(-30, 60, (500, 2))
    a = _poly(STAR, True).contains(pts)
    b = _poly(tuple(reversed(STAR)), True).contains(pts)
    assert np.array_equal(a, b)


def test_circle_is_horizontal_distance() -> None:
    pts = np.array([[3.0, 4.0, -100.0], [3.0, 4.1, 0.0], [0.0, 0.0, 0.0]])
    c = _circle((0.0, 0.0), 5.0, True)
    assert c.contains(pts).tolist() == [True, False, True]


def test_px4_semantics_union_of_inclusions_minus_exclusions() -> None:
    fence = Geofence(
        polygons=(_poly(((0, 0), (10, 0), (10, 10), (0, 10)), True),),
        circles=(_circle((20.0, 5.0), 4.0, True), _circle((5.0, 5.0), 2.0, False)),
    )
    pts = np.array([
        [1.0, 1.0, -5.0],   # inside the square
        [20.0, 6.0, 0.0],   # inside the inclusion circle only
        [5.0, 5.5, 0.0],    # inside the square but in the exclusion circle
        [15.0, 5.0, 0.0],   # between the inclusion zones
    ])  # fmt: skip
    assert fence.contains(pts).tolist() == [True, True, False, False]
    assert fence.violations(pts) == [
        FenceViolation(2, "exclusion circle 1"),
        FenceViolation(3, "inclusion"),
    ]


def test_only_exclusions_allow_everything_else() -> None:
    fence = Geofence(polygons=(_poly(((0, 0), (10, 0), (0, 10)), False),))
    assert fence.contains([[1.0, 1.0, 0.0], [100.0, 100.0, 0.0]]).tolist() == [False, True]


def test_empty_fence_allows_everything() -> None:
    fence = Geofence()
    assert fence.empty
    assert fence.contains(np.zeros((3, 3))).all()
    assert fence.violations(np.zeros((3, 3))) == []


def test_bad_point_shape() -> None:
    with pytest.raises(ValueError, match="shape"):
        Geofence().contains(np.zeros((3, 4)))
