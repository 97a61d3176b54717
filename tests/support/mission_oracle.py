"""Independent reference geodesy for the mission tests (n-vector form, not PX4's formulas).

The azimuthal equidistant projection about home keeps, for every point, the great-circle
distance from home as the radius and the initial great-circle bearing as the direction. Here
both come from 3-D unit vectors: distance = R * atan2(|a x b|, a . b); bearing = direction of b
in the local east/north tangent basis at a.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

R_EARTH_M = 6_371_000.0


def unit_vector(lat_deg: npt.ArrayLike, lon_deg: npt.ArrayLike) -> npt.NDArray[np.float64]:
    lat = np.deg2rad(np.asarray(lat_deg, dtype=float))
    lon = np.deg2rad(np.asarray(lon_deg, dtype=float))
    return np.stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)], axis=-1)


def distance_bearing(
    lat0: float, lon0: float, lat: npt.ArrayLike, lon: npt.ArrayLike
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Great-circle distance [m] and initial bearing [rad, from north, clockwise] from 0 to 1."""
    a = unit_vector(lat0, lon0)
    b = unit_vector(lat, lon)
    dist = R_EARTH_M * np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), b @ a)
    phi, lam = np.deg2rad(lat0), np.deg2rad(lon0)
    north = np.array([-np.sin(phi) * np.cos(lam), -np.sin(phi) * np.sin(lam), np.cos(phi)])
    east = np.array([-np.sin(lam), np.cos(lam), 0.0])
    return dist, np.arctan2(b @ east, b @ north)


def expected_ne(
    lat0: float, lon0: float, lat: npt.ArrayLike, lon: npt.ArrayLike
) -> npt.NDArray[np.float64]:
    """North/east [m] of the points in an azimuthal equidistant projection about (lat0, lon0)."""
    d, brg = distance_bearing(lat0, lon0, lat, lon)
    return np.stack([d * np.cos(brg), d * np.sin(brg)], axis=-1)
