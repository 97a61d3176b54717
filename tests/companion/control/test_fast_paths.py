"""The controller's fast paths equal the general code they stand in for.

- the float quaternion helpers of the controller vs scipy's Rotation;
- `StateEstimate.is_finite` still catches a non-finite value anywhere, and the constructor keeps
  its shape validation; `state_estimate_of_arrays` (no conversions) vs the constructor;
- `TrackingController.attitude_values` vs `attitude` on the same input sequence;
- the drag estimator's float update vs its former numpy-array update, bit for bit, and the
  controller's body z axes (`law._body_z`) vs `quat_to_dcm`.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from companion.control import (
    AttitudeCommand,
    Reference,
    StateEstimate,
    TrackingConfig,
    TrackingController,
    state_estimate_of_arrays,
)
from companion.control.estimation import DragConfig, DragEstimator, body_z_ned
from companion.control.so3 import body_z_down, quat_integrate_f, quat_normalize_f, quat_to_dcm
from companion.flatness import MultirotorParams
from tests.support.fields import fields_equal

PARAMS = MultirotorParams(mass=1.3, inertia=(0.021, 0.023, 0.04), hover_thrust=0.45, drag=0.7)

comp = st.floats(-30.0, 30.0, allow_nan=False)
vec3 = st.tuples(comp, comp, comp)


quat = st.tuples(*[st.floats(-1.0, 1.0)] * 4).filter(lambda q: math.hypot(*q) > 0.1)


@settings(max_examples=200, deadline=None)
@given(quat, vec3, st.floats(0.0, 0.3))
def test_float_quaternion_integration_matches_scipy(q, omega, dt) -> None:  # type: ignore[no-untyped-def]
    out = np.array(quat_integrate_f(list(q), list(omega), dt))
    w, x, y, z = q
    ref = Rotation.from_quat([x, y, z, w]) * Rotation.from_rotvec(np.array(omega) * dt)
    rx, ry, rz, rw = ref.as_quat()
    expected = np.array([rw, rx, ry, rz]) * (1.0 if rw >= 0.0 else -1.0)
    assert out[0] >= 0.0
    if abs(expected[0]) < 1e-9:  # w = 0: q and -q both have w >= 0
        expected *= np.sign(np.dot(expected, out))
    np.testing.assert_allclose(out, expected, atol=1e-9)


@settings(max_examples=200, deadline=None)
@given(quat)
def test_body_z_down_is_the_dcm_element_c22(q) -> None:  # type: ignore[no-untyped-def]
    w, x, y, z = q
    c22 = Rotation.from_quat([x, y, z, w]).as_matrix()[2, 2]
    assert body_z_down(np.array(q)) == pytest.approx(c22, abs=1e-12)
    n = quat_normalize_f(*q)
    assert math.hypot(*n) == pytest.approx(1.0) and n[0] >= 0.0


def test_degenerate_quaternions_give_identity() -> None:
    assert quat_normalize_f(0.0, 0.0, 0.0, 0.0) == (1.0, 0.0, 0.0, 0.0)
    assert quat_normalize_f(math.nan, 0.0, 0.0, 1.0) == (1.0, 0.0, 0.0, 0.0)
    assert body_z_down(np.array([math.nan, 0.0, 0.0, 0.0])) == 1.0


# ----------------------------------------------------------------------------- StateEstimate


@pytest.mark.parametrize("bad", [math.nan, math.inf])
@pytest.mark.parametrize("field", ["t_s", "pos_ned", "vel_ned", "q_wxyz", "omega_frd", "acc_ned"])
def test_state_estimate_is_finite_catches_every_field(bad: float, field: str) -> None:
    kw: dict[str, object] = {
        "t_s": 1.0,
        "pos_ned": [1.0, 2.0, -3.0],
        "vel_ned": [0.1, 0.2, 0.3],
        "q_wxyz": [1.0, 0.0, 0.0, 0.0],
        "omega_frd": [0.0, 0.1, 0.0],
        "acc_ned": [0.0, 0.0, 0.0],
    }
    assert StateEstimate(**kw).is_finite()  # type: ignore[arg-type]
    if field == "t_s":
        kw[field] = bad
    else:
        val = list(kw[field])  # type: ignore[call-overload]
        val[-1] = bad
        kw[field] = val
    assert not StateEstimate(**kw).is_finite()  # type: ignore[arg-type]


def test_state_estimate_keeps_shape_validation() -> None:
    with pytest.raises(ValueError, match="pos_ned"):
        StateEstimate(0.0, np.zeros(4), np.zeros(3), np.array([1.0, 0, 0, 0]), np.zeros(3))
    with pytest.raises(ValueError, match="q_wxyz"):
        StateEstimate(0.0, np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3))
    # an int array is converted, not passed through
    q = np.array([1.0, 0, 0, 0])
    est = StateEstimate(0.0, np.array([1, 2, 3]), np.zeros(3), q, np.zeros(3))
    assert est.pos_ned.dtype == np.float64


def test_state_estimate_of_arrays_equals_constructor() -> None:
    args = (2.5, np.array([1.0, -2.0, -3.0]), np.array([0.1, 0.2, -0.3]),
            np.array([0.9, 0.1, -0.2, 0.3]), np.array([0.01, -0.02, 0.3]))
    for airborne in (True, False):
        fast = state_estimate_of_arrays(*args, airborne=airborne)
        slow = StateEstimate(args[0], *[a.tolist() for a in args[1:]], airborne=airborne)
        fields_equal(fast, slow)


# ----------------------------------------------------------------------------- controller


def _est(t: float, pos, vel, q=(1.0, 0.0, 0.0, 0.0)) -> StateEstimate:  # type: ignore[no-untyped-def]
    return StateEstimate(t, pos, vel, q, (0.0, 0.0, 0.0))


def test_attitude_values_equals_attitude_on_a_sequence() -> None:
    cfg = TrackingConfig(params=PARAMS)
    a, b = TrackingController(cfg), TrackingController(cfg)
    rng = np.random.default_rng(3)
    for k in range(60):
        now = 0.01 * (k + 1)
        est = _est(now - 0.004, rng.normal(size=3), rng.normal(size=3),
                   tuple(np.r_[1.0, 0.1 * rng.normal(size=3)]))
        ref = Reference(rng.normal(size=3), rng.normal(size=3), rng.normal(size=3),
                        yaw=0.2, yaw_rate=0.1 * k)
        if k == 30:  # one fallback in the middle
            ref = Reference([math.nan, 0.0, 0.0])
        cmd = a.attitude(now, est, ref)
        out = b.attitude_values(now, est, ref)
        if isinstance(out, AttitudeCommand):
            assert cmd.fallback and out.fallback and out.reason == cmd.reason
            np.testing.assert_array_equal(out.q_wxyz, cmd.q_wxyz)
            continue
        q, thrust, rate_ff, sat = out
        assert not cmd.fallback
        assert q == tuple(cmd.q_wxyz.tolist())
        assert (thrust, rate_ff, sat) == (cmd.thrust_norm, cmd.yaw_rate_ff, cmd.saturated)
    assert a.hover_thrust == b.hover_thrust


# ----------------------------------------------------------------------------- drag estimate


@settings(max_examples=200, deadline=None)
@given(st.tuples(*[st.floats(-2.0, 2.0)] * 4))
def test_body_z_is_the_third_dcm_column_bit_for_bit(q) -> None:  # type: ignore[no-untyped-def]
    expected = quat_to_dcm(np.array(q))[:, 2].tolist()
    got = body_z_ned(np.array(q))
    assert all(type(c) is float for c in got)
    assert list(got) == expected


@pytest.mark.parametrize("q", [(0.0, 0.0, 0.0, 0.0), (math.nan, 0.0, 0.0, 1.0),
                               (math.inf, 0.0, 0.0, 0.0)])
def test_body_z_of_degenerate_quaternions_is_the_identity_column(q) -> None:  # type: ignore[no-untyped-def]
    assert list(body_z_ned(np.array(q))) == quat_to_dcm(np.array(q))[:, 2].tolist() == [0, 0, 1]


class _ArrayDragEstimator:
    """`DragEstimator.update` as it was before its float rewrite (numpy arrays and scalars)."""

    def __init__(self, config: DragConfig) -> None:
        self.config = config
        self._k = config.initial_drag_over_mass
        self._var = config.initial_std**2
        self._t_last: float | None = None

    def update(self, now, acc_ned, vel_ned, thrust_norm, z_b_ned, hover_thrust,  # type: ignore[no-untyped-def]
               airborne=True, disturbance_ne=(0.0, 0.0)):
        c = self.config
        dt = 0.0 if self._t_last is None else max(0.0, now - self._t_last)
        self._t_last = now if self._t_last is None else max(now, self._t_last)
        self._var = min(self._var + c.process_noise_std**2 * dt, 4.0)
        a = np.asarray(acc_ned, dtype=float)
        v = np.asarray(vel_ned, dtype=float)
        zb = np.asarray(z_b_ned, dtype=float)
        if not (airborne and np.all(np.isfinite(a)) and np.all(np.isfinite(v))
                and np.all(np.isfinite(zb)) and math.isfinite(thrust_norm)
                and math.isfinite(hover_thrust) and hover_thrust > 0.0):
            return False
        if math.hypot(v[0], v[1]) < c.min_speed:
            return False
        fused_any = False
        R = c.acc_noise_std**2
        for i in (0, 1):
            y = a[i] + c.g * thrust_norm * zb[i] / hover_thrust - disturbance_ne[i]
            H = -v[i]
            innov = y - H * self._k
            S = H * H * self._var + R
            if innov * innov > c.gate_sigma**2 * S:
                continue
            K = self._var * H / S
            self._k = min(max(self._k + K * innov, 0.0), c.max_value)
            self._var = max((1.0 - K * H) * self._var, 1e-12)
            fused_any = True
        return fused_any


@pytest.mark.parametrize("as_lists", [False, True])
def test_drag_estimator_floats_equal_the_array_update(as_lists: bool) -> None:
    """The same fused samples (random flight-like inputs, gated ones, slow ones, non-finite
    ones, on the ground) give the same estimate to the bit, and it is a Python float (it was a
    numpy scalar, which made every setpoint's arithmetic numpy-scalar arithmetic)."""
    rng = np.random.default_rng(5)
    cfg = DragConfig(initial_drag_over_mass=0.3, acc_noise_std=0.5)
    new, old = DragEstimator(cfg), _ArrayDragEstimator(cfg)
    fused = 0
    for k in range(400):
        v = rng.normal(0.0, 4.0, 3)
        a = rng.normal(0.0, 2.0, 3) - 0.6 * v
        zb = rng.normal(0.0, 0.2, 3) + np.array([0.0, 0.0, -1.0])
        u, h = float(rng.uniform(0.3, 0.7)), float(rng.uniform(0.4, 0.6))
        if k % 50 == 7:
            a[1] = math.nan
        if k % 40 == 3:
            v[:2] *= 0.1  # below min_speed
        airborne = k % 30 != 0
        dist = (float(rng.normal(0.0, 0.3)), float(rng.normal(0.0, 0.3)))
        args = ((a.tolist(), v.tolist(), u, zb.tolist()) if as_lists else (a, v, u, zb))
        r_new = new.update(0.03 * k, *args, h, airborne, dist)
        r_old = old.update(0.03 * k, a, v, u, zb, h, airborne, dist)
        assert r_new == r_old
        fused += r_new
        assert new.drag_over_mass == old._k and new.std == math.sqrt(old._var)
        assert type(new.drag_over_mass) is float
    assert fused > 200  # the comparison covers fused updates, not only rejected ones
