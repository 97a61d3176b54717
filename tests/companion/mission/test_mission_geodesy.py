"""Projection tests: PX4's azimuthal equidistant map projection against an independent oracle."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.mission import EARTH_RADIUS_M, GeoPoint, geodetic_to_ned, ned_to_geodetic
from tests.support.mission_oracle import R_EARTH_M, distance_bearing, expected_ne

HOME = GeoPoint(47.397742, 8.545594, 488.0)


def test_radius_is_px4_constant() -> None:
    assert EARTH_RADIUS_M == R_EARTH_M == 6_371_000.0


def test_home_maps_to_origin() -> None:
    p = geodetic_to_ned(HOME.lat_deg, HOME.lon_deg, HOME.alt_amsl_m, HOME)
    np.testing.assert_allclose(p, [0.0, 0.0, 0.0], atol=1e-9)


def test_pure_north_is_the_meridian_arc() -> None:
    # along a meridian the projection radius is the arc length R * dlat, east stays zero
    for dlat in (1e-5, 1e-3, 0.1, -0.2):
        p = geodetic_to_ned(HOME.lat_deg + dlat, HOME.lon_deg, HOME.alt_amsl_m, HOME)
        # (abs: the degree inputs themselves carry ~1e-14 deg of rounding, i.e. ~1 nm)
        assert p[0] == pytest.approx(R_EARTH_M * math.radians(dlat), rel=1e-12, abs=1e-8)
        assert abs(p[1]) < 1e-9


def test_altitude_maps_to_down() -> None:
    p = geodetic_to_ned(HOME.lat_deg, HOME.lon_deg, [478.0, 488.0, 520.5], HOME)
    np.testing.assert_allclose(p[:, 2], [10.0, 0.0, -32.5], atol=1e-12)


def test_matches_great_circle_oracle() -> None:
    rng = np.random.default_rng(7)
    # points up to ~150 km away in every direction, plus a far one
    lat = HOME.lat_deg + rng.uniform(-1.3, 1.3, 500)
    lon = HOME.lon_deg + rng.uniform(-2.0, 2.0, 500)
    lat = np.append(lat, [10.0, -33.0])
    lon = np.append(lon, [100.0, -70.0])
    p = geodetic_to_ned(lat, lon, 0.0, HOME)
    ne = expected_ne(HOME.lat_deg, HOME.lon_deg, lat, lon)
    dist, _ = distance_bearing(HOME.lat_deg, HOME.lon_deg, lat, lon)
    err = np.linalg.norm(p[:, :2] - ne, axis=1)
    assert np.all(err <= 1e-6 + 1e-9 * dist)
    # equidistance: |NE| is the great-circle distance
    np.testing.assert_allclose(np.hypot(p[:, 0], p[:, 1]), dist, rtol=1e-9, atol=1e-6)


def test_sitl_scale_numbers() -> None:
    # 100 m east at PX4 SITL home: dlon = 100 / (R cos(lat)) in radians (first order)
    dlon = math.degrees(100.0 / (R_EARTH_M * math.cos(math.radians(HOME.lat_deg))))
    p = geodetic_to_ned(HOME.lat_deg, HOME.lon_deg + dlon, HOME.alt_amsl_m, HOME)
    assert p[1] == pytest.approx(100.0, abs=1e-4)
    # the parallel lies north of the great circle that starts due east: north offset is
    # d^2 tan(lat) / (2 R) to leading order
    expected_north = 100.0**2 * math.tan(math.radians(HOME.lat_deg)) / (2 * R_EARTH_M)
    assert p[0] == pytest.approx(expected_north, rel=1e-3)


def test_round_trip_geodetic_ned_geodetic() -> None:
    rng = np.random.default_rng(11)
    lat = HOME.lat_deg + rng.uniform(-0.9, 0.9, 300)
    lon = HOME.lon_deg + rng.uniform(-0.9, 0.9, 300)
    alt = rng.uniform(300, 900, 300)
    la, lo, al = ned_to_geodetic(geodetic_to_ned(lat, lon, alt, HOME), HOME)
    np.testing.assert_allclose(la, lat, atol=1e-10)
    np.testing.assert_allclose(lo, lon, atol=1e-10)
    np.testing.assert_allclose(al, alt, atol=1e-9)


def test_round_trip_ned_geodetic_ned() -> None:
    rng = np.random.default_rng(12)
    ned = rng.uniform(-50_000, 50_000, (300, 3))
    back = geodetic_to_ned(*ned_to_geodetic(ned, HOME), HOME)
    np.testing.assert_allclose(back, ned, atol=1e-5)
    np.testing.assert_allclose(ned_to_geodetic([0.0, 0.0, 0.0], HOME)[0], HOME.lat_deg, atol=0)


def test_reproject_wraps_longitude_across_the_antimeridian() -> None:
    home = GeoPoint(-16.5, 179.999, 0.0)
    lat, lon, _ = ned_to_geodetic([0.0, 500.0, 0.0], home)
    assert -180.0 <= float(lon) < -179.99
    back = geodetic_to_ned(lat, lon, 0.0, home)
    np.testing.assert_allclose(back, [0.0, 500.0, 0.0], atol=1e-6)


def test_shapes_broadcast() -> None:
    p = geodetic_to_ned(np.full((2, 3), HOME.lat_deg), HOME.lon_deg, 500.0, HOME)
    assert p.shape == (2, 3, 3)
    lat, lon, alt = ned_to_geodetic(np.zeros((4, 3)), HOME)
    assert lat.shape == lon.shape == alt.shape == (4,)
    with pytest.raises(ValueError, match="shape"):
        ned_to_geodetic(np.zeros((4, 2)), HOME)
