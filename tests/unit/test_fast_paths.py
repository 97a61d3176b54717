"""The replay's single-sample fast paths equal the general code they stand in for.

- `multirotor_setpoint_scalar` (plain floats) vs the batched numpy path of `multirotor_setpoint`
  (a batch of one: different backend, different code), and the same refusals of bad input;
- the float quaternion helpers of the controller vs scipy's Rotation;
- `StateEstimate.is_finite` / `Reference.is_finite` still catch a non-finite value anywhere.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from companion.control import Reference, StateEstimate
from companion.control.so3 import body_z_down, quat_integrate_f, quat_normalize_f
from companion.flatness import MultirotorParams, multirotor_setpoint
from companion.flatness.numeric import multirotor_setpoint_scalar

PARAMS = MultirotorParams(mass=1.3, inertia=(0.021, 0.023, 0.04), hover_thrust=0.45, drag=0.7)

comp = st.floats(-30.0, 30.0, allow_nan=False)
vec3 = st.tuples(comp, comp, comp)
angle = st.floats(-math.pi, math.pi)


@settings(max_examples=200, deadline=None)
@given(vec3, vec3, vec3, vec3, angle, st.floats(-3, 3), st.floats(-5, 5))
def test_scalar_flatness_equals_batched_numpy_path(v, a, j, s, yaw, yaw_rate, yaw_acc) -> None:  # type: ignore[no-untyped-def]
    fast = multirotor_setpoint_scalar(v, a, j, s, yaw, yaw_rate, yaw_acc, PARAMS)
    batch = multirotor_setpoint(
        np.array([v]), np.array([a]), np.array([j]), np.array([s]),
        np.array([yaw]), np.array([yaw_rate]), np.array([yaw_acc]), PARAMS,
    )
    tol = {"rtol": 1e-12, "atol": 1e-12}
    for key in ("thrust", "thrust_dot", "thrust_ddot", "thrust_norm"):
        np.testing.assert_allclose(fast[key], np.asarray(getattr(batch, key))[0], **tol)
    for key in ("q_wxyz", "omega_frd", "omega_dot_frd", "moment_frd", "C_eb"):
        np.testing.assert_allclose(
            np.array(fast[key]), np.asarray(getattr(batch, key))[0], err_msg=key, **tol
        )
    assert int(fast["flags"]) == int(batch.flags[0])
    assert bool(fast["singular"]) == bool(batch.singular[0])


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf, 2e12])
@pytest.mark.parametrize("slot", range(15))
def test_scalar_flatness_refuses_bad_input_like_the_array_path(bad: float, slot: int) -> None:
    flat = [0.1] * 15
    flat[slot] = bad
    args = (flat[0:3], flat[3:6], flat[6:9], flat[9:12], flat[12], flat[13], flat[14])
    with pytest.raises(ValueError, match="refusing") as fast_err:
        multirotor_setpoint_scalar(*args, PARAMS)
    with pytest.raises(ValueError, match="refusing") as arr_err:
        multirotor_setpoint(*(np.asarray(x) for x in args), PARAMS)
    assert str(fast_err.value) == str(arr_err.value)


def test_scalar_flatness_rejects_wrong_length() -> None:
    with pytest.raises(ValueError, match="jerk"):
        multirotor_setpoint_scalar((0, 0, 0), (0, 0, 0), (0, 0), (0, 0, 0), 0, 0, 0, PARAMS)


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


@pytest.mark.parametrize("bad", [math.nan, -math.inf])
@pytest.mark.parametrize("slot", range(18))
def test_reference_is_finite_catches_every_component(bad: float, slot: int) -> None:
    vals = [0.5] * 18
    assert Reference(*_ref_args(vals)).is_finite()
    vals[slot] = bad
    assert not Reference(*_ref_args(vals)).is_finite()


def _ref_args(v: list[float]) -> tuple[object, ...]:
    return (
        np.array(v[0:3]), np.array(v[3:6]), np.array(v[6:9]), np.array(v[9:12]),
        np.array(v[12:15]), v[15], v[16], v[17],
    )


def test_state_estimate_keeps_shape_validation() -> None:
    with pytest.raises(ValueError, match="pos_ned"):
        StateEstimate(0.0, np.zeros(4), np.zeros(3), np.array([1.0, 0, 0, 0]), np.zeros(3))
    with pytest.raises(ValueError, match="q_wxyz"):
        StateEstimate(0.0, np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3))
    # an int array is converted, not passed through
    q = np.array([1.0, 0, 0, 0])
    est = StateEstimate(0.0, np.array([1, 2, 3]), np.zeros(3), q, np.zeros(3))
    assert est.pos_ned.dtype == np.float64


@pytest.mark.parametrize("mode", ["attitude", "rates"])
def test_tracking_source_reuses_estimates_without_changing_setpoints(mode: str) -> None:
    """Telemetry arrives slower than setpoints: the source's estimate cache must give exactly
    the setpoints of building a fresh estimate every call (oracle: a source whose cache is
    bypassed)."""
    from companion.control import Reference as Ref
    from companion.flight.tracking import TrackingSource, estimate_from_telemetry
    from companion.mavlink.telemetry import (
        Attitude,
        ExtendedState,
        LocalPosition,
        TelemetrySnapshot,
    )

    def reference(t: float) -> Ref:
        return Ref(
            np.array([math.sin(t), 0.5 * t, -2.0]), np.array([math.cos(t), 0.5, 0.0]),
            np.array([-math.sin(t), 0.0, 0.0]), np.array([-math.cos(t), 0.0, 0.0]),
            np.array([math.sin(t), 0.0, 0.0]), 0.1 * t, 0.1, 0.0,
        )

    cached = TrackingSource(reference, mode, PARAMS)  # type: ignore[arg-type]
    fresh = TrackingSource(reference, mode, PARAMS)  # type: ignore[arg-type]
    fresh._estimate = lambda tel: estimate_from_telemetry(tel, fresh.clock)  # type: ignore[method-assign]
    rng = np.random.default_rng(3)
    pos = att = None
    in_air = ExtendedState(0.0, 2, 0)
    for k in range(300):
        now = 0.01 * k
        if k % 3 == 0:  # 33 Hz position, with jittered latency
            t_boot = now - 0.004
            pos = LocalPosition(
                now + float(rng.uniform(0.0, 0.01)), t_boot,
                (float(np.sin(now)), 0.5 * now, -2.0 + 0.01 * float(rng.normal())),
                (float(np.cos(now)), 0.5, 0.0), "lpos",
            )
        if k % 2 == 0:  # 50 Hz attitude
            q = Rotation.from_euler("ZYX", [0.1 * now, 0.02, -0.01]).as_quat()
            att = Attitude(now, (float(q[3]), float(q[0]), float(q[1]), float(q[2])),
                           (0.01, -0.02, 0.1))
        ext = in_air if k > 20 else ExtendedState(0.0, 1, 0)
        snap = TelemetrySnapshot(pos, att, None, None, ext, now)
        a, b = cached(now, snap), fresh(now, snap)
        assert a == b, k
    assert cached.calls == fresh.calls == 300
