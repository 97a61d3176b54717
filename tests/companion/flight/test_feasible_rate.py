"""The reference clock's feasible rate against a dense scan of rates (the oracle) on references
with random velocity and acceleration, in a random disturbance."""

from __future__ import annotations

import math

import numpy as np
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
