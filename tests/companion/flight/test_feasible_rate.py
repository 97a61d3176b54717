"""The reference clock's feasible rate against a dense scan of rates (the oracle) on references
with random velocity and acceleration, in a random disturbance."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.flatness.reference import Reference
from companion.flight.governor import FEASIBLE_SHARE, feasible_rate

G = 9.80665
comp = st.floats(-8.0, 8.0)


@settings(max_examples=150, deadline=None)
@given(st.lists(st.tuples(comp, comp, comp, comp), min_size=1, max_size=4), comp, comp,
       st.floats(0.0, 2.0), st.floats(math.radians(20.0), math.radians(60.0)))
def test_the_rate_is_the_largest_within_the_limit(refs: list[tuple[float, float, float, float]],
                                                 dn: float, de: float, k: float,
                                                 tilt: float) -> None:
    """Oracle: scan s in [0, 1] by 1e-4 against the limit (FEASIBLE_SHARE of g tan(tilt), or
    70 % of what holding leaves). The rate returned is itself within the limit for every
    reference, and no slower than the first rate at which one leaves it (0 when holding alone
    needs the whole limit)."""
    rs = [Reference(np.array([0.0, 0.0, -5.0]), np.array([vx, vy, 0.0]), np.array([ax, ay, 0.0]))
          for vx, vy, ax, ay in refs]
    got = feasible_rate(rs, (dn, de), k, tilt, G)
    full = G * math.tan(tilt)
    hold = math.hypot(dn, de)
    if hold >= full:
        assert got == 0.0
        return
    lim = max(FEASIBLE_SHARE * full, hold + 0.7 * (full - hold))
    s = np.arange(0.0, 1.0 + 1e-9, 1e-4)
    ok = np.ones_like(s, dtype=bool)
    for vx, vy, ax, ay in refs:
        ok &= np.hypot(s * s * ax + s * k * vx - dn, s * s * ay + s * k * vy - de) <= lim
        # the rate returned is within the limit (to the bisection's 2^-12)
        n = math.hypot(got * got * ax + got * k * vx - dn, got * got * ay + got * k * vy - de)
        assert n <= lim * (1.0 + 1e-3) + 1e-3
    bad = np.nonzero(~ok)[0]
    first_bad = 1.0 if len(bad) == 0 else float(s[bad[0]])
    assert got >= min(first_bad, 1.0) - 5e-4


@pytest.mark.parametrize("shape", [False, True])
def test_drag_estimated_above_the_configured_one_slows_a_reference_beyond_the_tilt_limit(
        shape: bool) -> None:
    """A lighter vehicle than told: its drag per mass is estimated 40 % above the configured
    one, and the disturbance reads ~0 (the drag estimator took the error). A turn at 6 m/s with
    5 m/s^2 of centripetal acceleration then needs |a + k v| = 9.8 m/s^2, beyond 45 deg's
    g tan(45 deg) = 9.81 less any margin: the source caps the rate below 1. Without the bend
    the cap keeps FEASIBLE_SHARE (8.8 m/s^2) for the feedback; with the bend in charge it is
    the bend's own limit less half its margin (44.5 deg, 9.64 m/s^2), so the two never
    disagree.
    Oracle: the rate s at which |s^2 a + s k v| equals that limit, by SciPy's brentq. With the
    configured drag (7.8 m/s^2 needed, the gate's control) it keeps rate 1."""
    from scipy.optimize import brentq

    from companion.control import Reference, ShapingConfig, TrackingConfig
    from companion.flatness import MultirotorParams
    from companion.flight.tracking import TrackingSource

    params = MultirotorParams(1.0, np.diag([0.025, 0.025, 0.03]), hover_thrust=0.5, drag=1.0)
    a, v = np.array([-5.0, 0.0, 0.0]), np.array([0.0, 6.0, 0.0])

    def ref(t: float) -> Reference:
        return Reference(np.array([0.0, 6.0 * t, -5.0]), v, a)

    caps = []
    for k in (1.4, 1.0):
        src = TrackingSource(ref, "attitude", tracking=TrackingConfig(
            params, max_tilt_rad=math.radians(45.0), shape_reference=shape))
        ctl = src.controller
        assert ctl is not None
        assert (src.shaper is not None) == shape
        ctl.drag_estimator._k = k  # what the estimator learnt in flight [1/s]
        assert ctl.drag == pytest.approx(k)
        caps.append(src._feasible_rate(1.0))
    lighter, told = caps
    margin = ShapingConfig().margin_rad
    limit = G * (math.tan(math.radians(45.0) - 0.5 * margin) if shape
                 else FEASIBLE_SHARE * math.tan(math.radians(45.0)))
    want = brentq(lambda r: math.hypot(r * r * a[0], r * 1.4 * v[1]) - limit, 0.1, 1.0)
    assert lighter == pytest.approx(want, abs=1e-3)
    assert lighter < 0.99
    assert told == 1.0
