"""Hypothesis properties of the Ackermann (car-like) rover map over random planar flat outputs.

Random inputs, extremes included: every output finite, the stop rule, the bicycle-model
identities (yaw rate = V kappa, tan(delta) = L kappa) and the CasADi function. Random
polynomial paths: the rates against central differences of the returned curvature and steering.
"""

from __future__ import annotations

import math

import numpy as np
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from companion.flatness import ROVER_SPEED_MIN, rover_setpoint, symbolic

SETTINGS = settings(max_examples=120, deadline=None)
ACK = ("curvature", "curvature_rate", "steer_angle", "steer_rate")

comp = st.one_of(
    st.floats(-20.0, 20.0, allow_nan=False),
    st.sampled_from([0.0, 1e-12, -1e-9, 5e-4, -7e-4, 1.2e-3, 1e3]),
)
vec2 = st.tuples(comp, comp)
wheel_base = st.one_of(st.floats(0.05, 5.0), st.sampled_from([1e-6, 1e3]))


@SETTINGS
@given(vec2, vec2, vec2, wheel_base)
def test_ackermann_finite_and_consistent(
    v: tuple[float, float], a: tuple[float, float], j: tuple[float, float], L: float
) -> None:
    sp = rover_setpoint(v, a, j, wheel_base_m=L)
    vals = [getattr(sp, n) for n in ("yaw", "speed", "speed_dot", "yaw_rate", "yaw_acc", *ACK)]
    assert all(isinstance(x, float) and math.isfinite(x) for x in vals)
    V = math.hypot(*v)
    assert sp.singular == (V < ROVER_SPEED_MIN)
    kappa, delta = float(sp.curvature), float(sp.steer_angle)  # type: ignore[arg-type]
    assert abs(delta) <= math.pi / 2
    if sp.singular:
        assert [getattr(sp, n) for n in ACK] == [0.0, 0.0, 0.0, 0.0]
    else:
        # the unicycle's yaw rate is speed times curvature; steering is atan(L kappa)
        assert abs(V * kappa - float(sp.yaw_rate)) <= 1e-12 * max(1.0, abs(float(sp.yaw_rate)))
        assert math.copysign(1.0, delta) == math.copysign(1.0, kappa) or kappa == 0.0
        if abs(L * kappa) < 1e3:  # tan is ill-conditioned next to pi/2
            assert abs(math.tan(delta) - L * kappa) <= 1e-12 * max(1.0, abs(L * kappa))
        # kappa and its sign: the cross product of velocity and acceleration over V^3
        cross = v[0] * a[1] - v[1] * a[0]
        assert abs(kappa * V**3 - cross) <= 1e-12 * max(1.0, abs(cross), V * math.hypot(*a))
    out = symbolic().rover(vel_xy=v, acc_xy=a, jerk_xy=j, wheel_base=L)
    for key in ACK:
        ref = float(out[key])
        assert abs(float(getattr(sp, key)) - ref) <= 1e-12 * max(1.0, abs(ref)), key


def _poly(c: list[np.ndarray], t: float, n: int) -> np.ndarray:
    """n-th derivative at t of sum_k c_k t^k / k!."""
    out = np.zeros_like(c[0])
    for k in range(n, len(c)):
        out = out + c[k] * t ** (k - n) / math.factorial(k - n)
    return out


@SETTINGS
@given(
    st.lists(st.tuples(st.floats(-6, 6), st.floats(-6, 6)), min_size=6, max_size=6),
    st.floats(0.1, 4.0),
)
def test_ackermann_rates_match_finite_differences(
    coefs: list[tuple[float, float]], L: float
) -> None:
    """A random degree-5 polynomial path around t = 0 (moving at >= 0.5 m/s there): the
    returned kappa' and delta' are the central differences of the returned kappa and delta."""
    c = [np.asarray(x) for x in coefs]
    h = 1e-5

    def at(t: float):  # type: ignore[no-untyped-def]
        return rover_setpoint(_poly(c, t, 1), _poly(c, t, 2), _poly(c, t, 3), wheel_base_m=L)

    s0, sm, spl = at(0.0), at(-h), at(h)
    assume(min(s0.speed, sm.speed, spl.speed) > 0.5)  # type: ignore[type-var]
    dk = (spl.curvature - sm.curvature) / (2 * h)  # type: ignore[operator]
    dd = (spl.steer_angle - sm.steer_angle) / (2 * h)  # type: ignore[operator]
    assert abs(dk - s0.curvature_rate) < 1e-5 * max(1.0, abs(s0.curvature_rate))  # type: ignore[arg-type]
    assert abs(dd - s0.steer_rate) < 1e-5 * max(1.0, abs(s0.steer_rate))  # type: ignore[arg-type]
