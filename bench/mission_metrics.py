"""Pure metrics of a flown mission (numpy only; used by bench_missions.py and missions_px4.py,
tested in bench/tests/test_mission_metrics.py): closest approach of the flown path to each
waypoint, deviation of the flown path from the mission's straight legs, and the corridor check;
`path_metrics` puts them together for one flight, `corner_points` reads a flight plan's
waypoints and acceptance radii.

Positions are NED [m] in one frame; a flown path is the polyline through its samples in time
order (between two samples the vehicle is taken to move straight, so a waypoint passed
between samples is not over-estimated by half a sample spacing).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:
    from companion.mission import FlightPlan

FloatArray = npt.NDArray[np.float64]

__all__ = ["CorridorResult", "closest_approach_path", "corner_points", "corridor_check",
           "path_metrics", "polyline_distance"]


def _segment_distance(points: FloatArray, a: FloatArray, b: FloatArray) -> FloatArray:
    """Distance [m] of each of `points` (N, 3) to the segments a[j]-b[j] (M, 3): (N, M)."""
    ab = b - a  # (M, 3)
    ab2 = np.einsum("ij,ij->i", ab, ab)  # (M,)
    ap = points[:, None, :] - a[None, :, :]  # (N, M, 3)
    with np.errstate(invalid="ignore", divide="ignore"):
        u = np.einsum("nmk,mk->nm", ap, ab) / ab2[None, :]
    u = np.where(ab2[None, :] > 0.0, np.clip(u, 0.0, 1.0), 0.0)
    d = ap - u[:, :, None] * ab[None, :, :]
    return np.asarray(np.sqrt(np.einsum("nmk,nmk->nm", d, d)), dtype=np.float64)


def polyline_distance(points: FloatArray, poly: FloatArray, chunk: int = 4096) -> FloatArray:
    """Distance [m] of each of `points` (N, 3) to the polyline through `poly` (M >= 1, 3)."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    pl = np.asarray(poly, dtype=np.float64).reshape(-1, 3)
    if len(pl) == 0:
        raise ValueError("empty polyline")
    if len(pl) == 1:
        return np.asarray(np.linalg.norm(pts - pl[0], axis=1), dtype=np.float64)
    out = np.empty(len(pts))
    for i in range(0, len(pts), chunk):
        out[i:i + chunk] = _segment_distance(pts[i:i + chunk], pl[:-1], pl[1:]).min(axis=1)
    return out


def closest_approach_path(path: FloatArray, waypoints: FloatArray) -> FloatArray:
    """Smallest distance [m] from each waypoint (K, 3) to the flown polyline `path` (N, 3);
    inf for every waypoint when there is no sample."""
    p = np.asarray(path, dtype=np.float64).reshape(-1, 3)
    w = np.asarray(waypoints, dtype=np.float64).reshape(-1, 3)
    if len(p) == 0:
        return np.full(len(w), math.inf)
    return polyline_distance(w, p, chunk=64)


@dataclass(frozen=True)
class CorridorResult:
    """Deviation of a flown path from the straight legs [m] and the corridor verdict.

    A sample is inside when it is within `corridor_m` of the legs' polyline or within the
    acceptance radius of a waypoint (a corner may be cut there, PX4 semantics)."""

    max_dev_m: float
    rms_dev_m: float
    samples: int
    outside: int
    max_excess_m: float
    """Largest distance beyond what the sample was allowed (0 if none outside) [m]."""

    @property
    def within(self) -> bool:
        return self.samples > 0 and self.outside == 0


def corridor_check(path: FloatArray, legs: FloatArray, waypoints: FloatArray,
                   acceptance_m: npt.ArrayLike, corridor_m: float) -> CorridorResult:
    """Deviation of the samples `path` (N, 3) from the polyline `legs` (M, 3) and whether each
    stays in the corridor: within `corridor_m` of the legs, or within `acceptance_m[k]` of
    `waypoints[k]` (K, 3)."""
    p = np.asarray(path, dtype=np.float64).reshape(-1, 3)
    if len(p) == 0:
        return CorridorResult(math.nan, math.nan, 0, 0, math.nan)
    dev = polyline_distance(p, legs)
    w = np.asarray(waypoints, dtype=np.float64).reshape(-1, 3)
    acc = np.asarray(acceptance_m, dtype=np.float64).reshape(-1)
    if len(w) != len(acc):
        raise ValueError(f"{len(w)} waypoints but {len(acc)} acceptance radii")
    excess = dev - corridor_m
    if len(w):
        dw = np.linalg.norm(p[:, None, :] - w[None, :, :], axis=2) - acc[None, :]
        excess = np.minimum(excess, dw.min(axis=1))
    out = excess > 0.0
    return CorridorResult(float(dev.max()), float(np.sqrt(np.mean(dev**2))), len(p),
                          int(np.count_nonzero(out)),
                          float(excess[out].max()) if np.any(out) else 0.0)


def corner_points(fp: FlightPlan) -> tuple[np.ndarray, np.ndarray]:
    """(waypoints (K, 3) NED about home, acceptance radii (K,)) of the flight plan."""
    w = np.array([p.pos_ned_m for p in fp.waypoints], dtype=np.float64).reshape(-1, 3)
    return w, np.array([p.acceptance_radius_m for p in fp.waypoints], dtype=np.float64)


def path_metrics(pos: np.ndarray, wps: np.ndarray, legs: np.ndarray, corners: np.ndarray,
                 acc: np.ndarray, corridor_m: float) -> dict[str, Any]:
    """Closest approach per waypoint and the corridor figures of one flown path (NED [m])."""
    ca = closest_approach_path(pos, wps)
    cr = corridor_check(pos, legs, corners, acc, corridor_m)
    return {"closest_m": [float(c) for c in ca],
            "max_closest_m": float(np.max(ca)) if len(ca) else math.nan,
            "max_dev_m": cr.max_dev_m, "rms_dev_m": cr.rms_dev_m, "samples": cr.samples,
            "outside": cr.outside, "max_excess_m": cr.max_excess_m, "within": cr.within,
            "outside_pct": 100.0 * cr.outside / cr.samples if cr.samples else math.nan}
