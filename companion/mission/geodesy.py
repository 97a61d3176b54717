"""Geodetic <-> local NED conversion about a home point (PX4's azimuthal equidistant projection).

PX4 (``src/lib/geo/geo.cpp``, ``MapProjection::project/reproject``) maps latitude/longitude to a
local north/east plane with the spherical azimuthal equidistant projection about the reference
point on a sphere of radius 6 371 000 m: the distance from the reference to a point in the plane
equals the great-circle distance, and its direction equals the initial bearing. Down is
``-(alt_amsl - home_alt_amsl)``. This is an independent implementation of the same formulas, in
float64 throughout (PX4 stores the projected x/y as float32).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

__all__ = [
    "EARTH_RADIUS_M",
    "GeoPoint",
    "geodetic_to_ned",
    "ned_to_geodetic",
]

EARTH_RADIUS_M = 6_371_000.0
"""Sphere radius used by PX4's map projection (CONSTANTS_RADIUS_OF_EARTH) [m]."""

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class GeoPoint:
    """A WGS-84 position: latitude/longitude in degrees, altitude above mean sea level in metres."""

    lat_deg: float
    lon_deg: float
    alt_amsl_m: float


def geodetic_to_ned(
    lat_deg: npt.ArrayLike,
    lon_deg: npt.ArrayLike,
    alt_amsl_m: npt.ArrayLike,
    home: GeoPoint,
) -> FloatArray:
    """Project geodetic positions to local NED about ``home`` [m].

    Inputs broadcast against each other; the result has shape ``broadcast_shape + (3,)``
    (north, east, down). Uses PX4's azimuthal equidistant projection on a sphere.
    """
    lat = np.radians(np.asarray(lat_deg, dtype=np.float64))
    lon = np.radians(np.asarray(lon_deg, dtype=np.float64))
    alt = np.asarray(alt_amsl_m, dtype=np.float64)
    lat, lon, alt = np.broadcast_arrays(lat, lon, alt)
    lat0 = np.radians(home.lat_deg)
    lon0 = np.radians(home.lon_deg)
    sin_lat0, cos_lat0 = np.sin(lat0), np.cos(lat0)
    cos_lat = np.cos(lat)
    dlon = lon - lon0
    # central angle c between home and the point (the projection keeps c * R as the radius);
    # PX4 takes acos(cos c), the haversine form below is the same angle without the round-off
    # of acos near 0
    hav = np.sin((lat - lat0) / 2.0) ** 2 + cos_lat0 * cos_lat * np.sin(dlon / 2.0) ** 2
    c = 2.0 * np.arcsin(np.sqrt(np.clip(hav, 0.0, 1.0)))
    sin_c = np.sin(c)
    # k = c / sin(c), -> 1 as c -> 0 (series avoids 0/0 and cancellation near the origin)
    small = c < 1e-6
    k = np.where(small, 1.0 + c * c / 6.0, c / np.where(small, 1.0, sin_c))
    # cos(lat0) sin(lat) - sin(lat0) cos(lat) cos(dlon), rewritten without the cancellation
    north = (
        k * (np.sin(lat - lat0) + 2.0 * sin_lat0 * cos_lat * np.sin(dlon / 2.0) ** 2)
    ) * EARTH_RADIUS_M
    east = k * cos_lat * np.sin(dlon) * EARTH_RADIUS_M
    down = -(alt - home.alt_amsl_m)
    return np.stack([north, east, down], axis=-1)


def ned_to_geodetic(
    pos_ned_m: npt.ArrayLike, home: GeoPoint
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Inverse of :func:`geodetic_to_ned`: local NED [m] (shape ``(..., 3)``) -> (lat_deg,
    lon_deg, alt_amsl_m), longitude wrapped to [-180, 180)."""
    p = np.asarray(pos_ned_m, dtype=np.float64)
    if p.shape[-1:] != (3,):
        raise ValueError(f"pos_ned_m must have shape (..., 3), got {p.shape}")
    x = p[..., 0] / EARTH_RADIUS_M
    y = p[..., 1] / EARTH_RADIUS_M
    lat0 = np.radians(home.lat_deg)
    lon0 = np.radians(home.lon_deg)
    sin_lat0, cos_lat0 = np.sin(lat0), np.cos(lat0)
    c = np.hypot(x, y)
    sin_c, cos_c = np.sin(c), np.cos(c)
    small = c < 1e-12
    c_safe = np.where(small, 1.0, c)
    # sin(c)/c -> 1 at the origin
    sinc = np.where(small, 1.0, sin_c / c_safe)
    lat = np.arcsin(np.clip(cos_c * sin_lat0 + x * sinc * cos_lat0, -1.0, 1.0))
    lon = lon0 + np.arctan2(y * sinc, cos_lat0 * cos_c - x * sin_lat0 * sinc)
    lon_deg = (np.degrees(lon) + 180.0) % 360.0 - 180.0
    alt = home.alt_amsl_m - p[..., 2]
    return np.degrees(lat), lon_deg, np.asarray(alt, dtype=np.float64)
