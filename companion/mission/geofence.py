"""Geofence zones (polygons and circles, inclusion and exclusion) tested in local NED."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

__all__ = ["FenceCircle", "FencePolygon", "FenceViolation", "Geofence"]

BoolArray = npt.NDArray[np.bool_]


def _as_points_ne(points_ned_m: npt.ArrayLike) -> npt.NDArray[np.float64]:
    p = np.asarray(points_ned_m, dtype=np.float64)
    if p.ndim == 1:
        p = p[None, :]
    if p.ndim != 2 or p.shape[1] not in (2, 3):
        raise ValueError(f"points must have shape (N, 2) or (N, 3), got {p.shape}")
    return p[:, :2]


@dataclass(frozen=True)
class FencePolygon:
    """A polygon zone. ``vertices_deg`` are (lat, lon) [deg]; ``vertices_ne_m`` the same vertices
    projected to local north/east about home [m]. Horizontal only (no altitude limits)."""

    inclusion: bool
    vertices_deg: tuple[tuple[float, float], ...]
    vertices_ne_m: tuple[tuple[float, float], ...]

    def contains(self, points_ned_m: npt.ArrayLike) -> BoolArray:
        """Whether each point (N, 2|3) lies inside the polygon (even-odd rule)."""
        p = _as_points_ne(points_ned_m)
        v = np.asarray(self.vertices_ne_m, dtype=np.float64)
        x, y = p[:, 0], p[:, 1]
        inside = np.zeros(len(p), dtype=bool)
        for i in range(len(v)):
            x1, y1 = v[i - 1]
            x2, y2 = v[i]
            straddles = (y1 > y) != (y2 > y)
            if not straddles.any():
                continue
            with np.errstate(divide="ignore", invalid="ignore"):
                x_cross = x1 + (y - y1) * (x2 - x1) / (y2 - y1)
            inside ^= straddles & (x < x_cross)
        return inside


@dataclass(frozen=True)
class FenceCircle:
    """A circular zone: centre (lat, lon) [deg] and local NE [m], radius [m]."""

    inclusion: bool
    center_lat_deg: float
    center_lon_deg: float
    center_ne_m: tuple[float, float]
    radius_m: float

    def contains(self, points_ned_m: npt.ArrayLike) -> BoolArray:
        """Whether each point (N, 2|3) lies within the radius (horizontal distance)."""
        p = _as_points_ne(points_ned_m)
        d = np.hypot(p[:, 0] - self.center_ne_m[0], p[:, 1] - self.center_ne_m[1])
        return np.asarray(d <= self.radius_m, dtype=bool)


@dataclass(frozen=True)
class FenceViolation:
    """Point ``point_index`` is outside every inclusion zone (``zone`` = "inclusion") or inside
    the exclusion zone named by ``zone`` (e.g. ``"exclusion circle 0"``)."""

    point_index: int
    zone: str


@dataclass(frozen=True)
class Geofence:
    """The plan's geofence, PX4 semantics: a point is allowed if it lies inside at least one
    inclusion zone (when there are any) and outside every exclusion zone. Horizontal only."""

    polygons: tuple[FencePolygon, ...] = ()
    circles: tuple[FenceCircle, ...] = ()

    @property
    def empty(self) -> bool:
        return not self.polygons and not self.circles

    def _zones(self) -> list[tuple[str, FencePolygon | FenceCircle]]:
        zones: list[tuple[str, FencePolygon | FenceCircle]] = []
        for i, poly in enumerate(self.polygons):
            zones.append((f"{'inclusion' if poly.inclusion else 'exclusion'} polygon {i}", poly))
        for i, circ in enumerate(self.circles):
            zones.append((f"{'inclusion' if circ.inclusion else 'exclusion'} circle {i}", circ))
        return zones

    def contains(self, points_ned_m: npt.ArrayLike) -> BoolArray:
        """Whether each local NED point (N, 3) or NE point (N, 2) [m] is allowed by the fence."""
        p = _as_points_ne(points_ned_m)
        any_inclusion = False
        in_inclusion = np.zeros(len(p), dtype=bool)
        in_exclusion = np.zeros(len(p), dtype=bool)
        for _, zone in self._zones():
            inside = zone.contains(p)
            if zone.inclusion:
                any_inclusion = True
                in_inclusion |= inside
            else:
                in_exclusion |= inside
        ok = ~in_exclusion
        if any_inclusion:
            ok &= in_inclusion
        return np.asarray(ok, dtype=bool)

    def violations(self, points_ned_m: npt.ArrayLike) -> list[FenceViolation]:
        """Every (point, zone) breach, in point order: one ``"inclusion"`` entry per point outside
        all inclusion zones, one entry per exclusion zone a point is inside."""
        p = _as_points_ne(points_ned_m)
        zones = self._zones()
        inclusions = [z for _, z in zones if z.inclusion]
        out_incl = np.zeros(len(p), dtype=bool)
        if inclusions:
            in_any = np.zeros(len(p), dtype=bool)
            for z in inclusions:
                in_any |= z.contains(p)
            out_incl = ~in_any
        excl_hits = [(name, z.contains(p)) for name, z in zones if not z.inclusion]
        result: list[FenceViolation] = []
        for i in range(len(p)):
            if out_incl[i]:
                result.append(FenceViolation(i, "inclusion"))
            for name, hit in excl_hits:
                if hit[i]:
                    result.append(FenceViolation(i, name))
        return result
