"""The pre-flight wind check against independent oracles: a brute-force scan of ground speeds,
the steady-flight force balance written out by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.flatness.reference import Reference
from companion.planning.wind import (
    MIN_PROGRESS_M_S,
    check_wind,
    disturbance_of_wind,
    max_ground_speed,
)

G = 9.80665


@settings(max_examples=120, deadline=None)
@given(st.floats(0.0, 2 * math.pi), st.floats(-12.0, 12.0), st.floats(-12.0, 12.0),
       st.floats(0.2, 2.0), st.floats(math.radians(15.0), math.radians(60.0)))
def test_max_ground_speed_is_the_largest_speed_within_the_tilt_limit(
        heading: float, dn: float, de: float, k: float, tilt: float) -> None:
    """Oracle: scan speeds 0..200 m/s in 2 mm/s steps for |k s u - d| <= g tan(tilt)."""
    u = (math.cos(heading), math.sin(heading))
    got = max_ground_speed(u, (dn, de), k, tilt, G)
    s = np.arange(0.0, 200.0, 0.002)
    ok = np.hypot(k * s * u[0] - dn, k * s * u[1] - de) <= G * math.tan(tilt)
    want = float(s[ok].max()) if ok.any() else 0.0
    assert got == pytest.approx(want, abs=0.003)


def test_a_wind_from_the_north_pushes_south() -> None:
    dn, de = disturbance_of_wind(5.0, 0.0, drag=1.2, mass=0.8)
    assert dn == pytest.approx(-7.5) and de == pytest.approx(0.0, abs=1e-12)
    dn, de = disturbance_of_wind(4.0, 270.0, drag=1.0, mass=1.0)  # from the west: east
    assert dn == pytest.approx(0.0, abs=1e-12) and de == pytest.approx(4.0)


def _north_at(speed: float, duration: float = 20.0):  # type: ignore[no-untyped-def]
    def ref(t: float) -> Reference:
        return Reference(np.array([speed * t, 0.0, -10.0]), np.array([speed, 0.0, 0.0]))
    return ref, duration


@pytest.mark.parametrize(("wind", "flyable", "slowed"), [
    (0.0, True, False),   # 5 m/s north, no wind: atan(5 / g) = 27 deg
    (3.0, True, False),   # headwind 3: atan(8 / g) = 39 deg
    (6.0, True, True),    # headwind 6: atan(11 / g) = 48 deg > 45; best 9.8 - 6 = 3.8 m/s
    (9.0, False, False),  # best 9.8 - 9 = 0.8 m/s < 1: no progress
    (10.5, False, False),  # holding needs atan(10.5 / g) = 47 deg
])
def test_a_leg_into_the_wind(wind: float, flyable: bool, slowed: bool) -> None:
    """D/m = 1: flying north at 5 m/s into a wind from the north of `wind` m/s needs
    atan((5 + wind) / g) of tilt (written out by hand); the tilt limit 45 deg allows
    g - wind m/s of ground speed."""
    ref, duration = _north_at(5.0)
    d = disturbance_of_wind(wind, 0.0, drag=1.0, mass=1.0)
    v = check_wind(ref, duration, d, 1.0, math.radians(45.0), G)
    assert (v.flyable, v.slowed) == (flyable, slowed), v.reason
    assert v.hold_tilt_deg == pytest.approx(math.degrees(math.atan2(wind, G)))
    if wind < 10.0:
        assert v.worst_tilt_deg == pytest.approx(math.degrees(math.atan2(5.0 + wind, G)))
        assert v.slowest_m_s == pytest.approx(max(G - wind, 0.0), abs=1e-9)
    if not flyable:
        assert v.reason
    if wind == 9.0:
        assert "at most 0.8 m/s" in v.reason and f"{MIN_PROGRESS_M_S:g} m/s" in v.reason


def test_a_tailwind_only_helps() -> None:
    ref, duration = _north_at(5.0)
    d = disturbance_of_wind(9.0, 180.0, drag=1.0, mass=1.0)  # from the south
    v = check_wind(ref, duration, d, 1.0, math.radians(45.0), G)
    assert v.flyable and not v.slowed
    assert v.worst_tilt_deg == pytest.approx(math.degrees(math.atan2(4.0, G)))
