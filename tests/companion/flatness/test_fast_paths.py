"""The flatness fast paths equal the general code they stand in for.

- `multirotor_setpoint_scalar` (plain floats) vs the batched numpy path of `multirotor_setpoint`
  (a batch of one: different backend, different code), and the same refusals of bad input;
- `multirotor_attitude_scalar` (if-branches, only the outputs the controller uses) vs the
  formula module evaluated by `multirotor_setpoint_scalar` and by the batched numpy path,
  including the low-thrust, no-direction, horizontal, heading-singular and inverted branches;
- `rover_setpoint` of one sample (float backend) vs a batch of one (numpy backend), with and
  without a wheel base;
- `reference_of_arrays` (no conversions) vs the `Reference` constructor, and
  `Reference.is_finite` still catches a non-finite value anywhere.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.flatness import MultirotorParams, multirotor_setpoint, rover_setpoint
from companion.flatness.numeric import multirotor_attitude_scalar, multirotor_setpoint_scalar
from companion.flatness.reference import Reference, reference_of_arrays
from tests.support.fields import fields_equal

PARAMS = MultirotorParams(mass=1.3, inertia=(0.021, 0.023, 0.04), hover_thrust=0.45, drag=0.7)
G = PARAMS.g

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


@settings(max_examples=200, deadline=None)
@given(st.tuples(comp, comp), st.tuples(comp, comp), st.tuples(comp, comp),
       st.one_of(st.none(), st.floats(0.05, 5.0)))
def test_scalar_rover_equals_batched_numpy_path(v, a, j, wheel_base) -> None:  # type: ignore[no-untyped-def]
    fast = rover_setpoint(v, a, j, wheel_base_m=wheel_base)
    batch = rover_setpoint(np.array([v]), np.array([a]), np.array([j]), wheel_base_m=wheel_base)
    for key in ("yaw", "speed", "speed_dot", "yaw_rate", "yaw_acc", "curvature",
                "curvature_rate", "steer_angle", "steer_rate"):
        f, b = getattr(fast, key), getattr(batch, key)
        if wheel_base is None and key in ("curvature", "curvature_rate", "steer_angle",
                                          "steer_rate"):
            assert f is None and b is None, key
            continue
        assert isinstance(f, float), key
        np.testing.assert_allclose(f, np.asarray(b)[0], rtol=1e-12, atol=1e-12, err_msg=key)
    assert fast.singular == bool(np.asarray(batch.singular)[0])


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


def _check_attitude_path(v, a, j, s, yaw, yaw_rate, yaw_acc) -> None:  # type: ignore[no-untyped-def]
    fast = multirotor_attitude_scalar(v, a, j, s, yaw, yaw_rate, yaw_acc, PARAMS)
    ref = multirotor_setpoint_scalar(v, a, j, s, yaw, yaw_rate, yaw_acc, PARAMS)
    qw, qx, qy, qz, thrust, p, q, r, singular = fast
    # same operations in the same order as the formula module on floats: bit-identical
    assert (qw, qx, qy, qz) == tuple(ref["q_wxyz"])
    assert thrust == ref["thrust"]
    assert (p, q, r) == tuple(ref["omega_frd"])
    assert singular == bool(ref["singular"])
    # and the batched numpy evaluation (a different backend) agrees to round-off
    batch = multirotor_setpoint(
        np.array([v]), np.array([a]), np.array([j]), np.array([s]),
        np.array([yaw]), np.array([yaw_rate]), np.array([yaw_acc]), PARAMS,
    )
    np.testing.assert_allclose([qw, qx, qy, qz], batch.q_wxyz[0], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose([p, q, r], batch.omega_frd[0], rtol=1e-12, atol=1e-12)
    assert thrust == pytest.approx(float(batch.thrust[0]), rel=1e-12, abs=1e-12)


@settings(max_examples=150, deadline=None)
@given(vec3, vec3, vec3, vec3, angle, st.floats(-3, 3), st.floats(-5, 5))
def test_attitude_fast_path_equals_formula_module(v, a, j, s, yaw, yaw_rate, yaw_acc) -> None:  # type: ignore[no-untyped-def]
    _check_attitude_path(v, a, j, s, yaw, yaw_rate, yaw_acc)


def _acc_for_thrust(t: tuple[float, float, float], vel: tuple[float, float, float]):  # type: ignore[no-untyped-def]
    """Acceleration giving thrust vector `t` [N] at velocity `vel` (t = m (g e3 - a) - D v)."""
    m, D = PARAMS.mass, PARAMS.drag
    return ((-t[0] - D * vel[0]) / m, (-t[1] - D * vel[1]) / m, G - (t[2] + D * vel[2]) / m)


@pytest.mark.parametrize(
    "thrust_vec, yaw",
    [
        ((0.0, 0.0, 0.0), 0.3),  # no thrust direction
        ((1e-4, -2e-4, 1e-4), 0.3),  # low thrust
        ((5.0, 2.0, 0.0), 0.3),  # horizontal thrust
        ((5.0, 2.0, 3e-7), 1.1),  # horizontal within HORIZONTAL_EPS
        ((0.0, 9.0, 0.0), 0.0),  # z_b parallel to y_c: heading singular
        ((-3.0, 0.0, 0.0), math.pi / 2),  # heading singular, other side
        ((1.0, 2.0, -8.0), -0.7),  # inverted
        ((0.5, -0.4, 12.0), 2.9),  # regular
    ],
)
@pytest.mark.parametrize("jerk", [(0.0, 0.0, 0.0), (1.5, -2.0, 0.7)])
def test_attitude_fast_path_branches(thrust_vec, yaw, jerk) -> None:  # type: ignore[no-untyped-def]
    vel = (1.0, -0.5, 0.2)
    _check_attitude_path(vel, _acc_for_thrust(thrust_vec, vel), jerk, (0.3, 0.1, -0.2),
                         yaw, 0.4, -0.1)


@pytest.mark.parametrize("bad", [math.nan, math.inf, 2e12])
@pytest.mark.parametrize("slot", range(15))
def test_attitude_fast_path_refuses_like_the_general_one(bad: float, slot: int) -> None:
    flat = [0.1] * 15
    flat[slot] = bad
    args = (flat[0:3], flat[3:6], flat[6:9], flat[9:12], flat[12], flat[13], flat[14])
    with pytest.raises(ValueError) as general:
        multirotor_setpoint_scalar(*args, PARAMS)
    with pytest.raises(ValueError) as fast:
        multirotor_attitude_scalar(*args, PARAMS)
    assert str(fast.value) == str(general.value)


# ----------------------------------------------------------------------------- Reference


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


@settings(max_examples=40, deadline=None)
@given(st.lists(comp, min_size=18, max_size=18))
def test_reference_of_arrays_equals_constructor(v: list[float]) -> None:
    arrays = [np.array(v[3 * i : 3 * i + 3], dtype=np.float64) for i in range(5)]
    fast = reference_of_arrays(*arrays, v[15], v[16], v[17])
    fields_equal(fast, Reference(*[a.tolist() for a in arrays], v[15], v[16], v[17]))
    assert fast.is_finite()
