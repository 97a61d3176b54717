"""Property tests of the mock's own attitude math and mixer (hypothesis, scipy as the oracle)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from sitl_mock.flight_control import (
    McGains,
    attitude_control,
    attitude_control_reference,
    constrain_xy,
    dcm_to_quat,
    mix_quad_x,
    quat_body_z,
    quat_from_two_vectors,
    quat_mul,
    quat_rotate,
    quat_yaw,
)
from sitl_mock.params import ParamStore

unit = st.floats(-1.0, 1.0, allow_nan=False)
vec = st.tuples(
    st.floats(-10, 10, allow_nan=False),
    st.floats(-10, 10, allow_nan=False),
    st.floats(-10, 10, allow_nan=False),
)
quat = st.tuples(unit, unit, unit, unit).filter(lambda q: sum(c * c for c in q) > 0.01)


def _unit(q: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
    n = math.sqrt(sum(c * c for c in q))
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)


def _scipy(q: tuple[float, float, float, float]) -> Rotation:
    return Rotation.from_quat([q[1], q[2], q[3], q[0]])


@settings(max_examples=60, deadline=None)
@given(quat, vec)
def test_quat_rotate_matches_scipy(
    q: tuple[float, float, float, float], v: tuple[float, ...]
) -> None:
    qu = _unit(q)
    np.testing.assert_allclose(quat_rotate(qu, (v[0], v[1], v[2])), _scipy(qu).apply(v), atol=1e-9)
    np.testing.assert_allclose(quat_body_z(qu), _scipy(qu).apply([0, 0, 1]), atol=1e-12)


@settings(max_examples=60, deadline=None)
@given(quat, quat)
def test_quat_mul_composes_like_scipy(a: tuple[float, ...], b: tuple[float, ...]) -> None:
    qa, qb = _unit((a[0], a[1], a[2], a[3])), _unit((b[0], b[1], b[2], b[3]))
    prod = quat_mul(qa, qb)
    ref = (_scipy(qa) * _scipy(qb)).as_quat()
    assert abs(float(np.dot([prod[1], prod[2], prod[3], prod[0]], ref))) > 1.0 - 1e-12


@settings(max_examples=60, deadline=None)
@given(quat)
def test_dcm_to_quat_and_yaw(q: tuple[float, ...]) -> None:
    qu = _unit((q[0], q[1], q[2], q[3]))
    m = _scipy(qu).as_matrix()
    rows = tuple(tuple(float(c) for c in r) for r in m)
    back = dcm_to_quat(rows)  # type: ignore[arg-type]
    assert abs(float(np.dot(back, qu))) > 1.0 - 1e-9
    if abs(m[2, 0]) < 0.999:  # yaw is defined away from gimbal lock
        yaw = _scipy(qu).as_euler("ZYX")[0]
        assert abs(math.remainder(quat_yaw(qu) - yaw, 2 * math.pi)) < 1e-9


@settings(max_examples=60, deadline=None)
@given(vec, vec)
@example((1.0, 0.0, 0.0), (-1.0, 0.0, 1e-5))  # nearly opposite: found by Hypothesis
@example((0.0, 0.0, 1.0), (0.0, 0.0, -1.0))  # exactly opposite
def test_quat_from_two_vectors_rotates_a_onto_b(a: tuple[float, ...], b: tuple[float, ...]) -> None:
    na, nb = np.linalg.norm(a), np.linalg.norm(b)
    if na < 1e-3 or nb < 1e-3:
        return
    q = quat_from_two_vectors((a[0], a[1], a[2]), (b[0], b[1], b[2]))
    ua, ub = np.array(a) / na, np.array(b) / nb
    rotated = _scipy(q).apply(ua)
    # as PX4's matrix::Quaternion(src, dst): a pair within ~5e-5 rad of opposite is taken as
    # opposite (a half turn about an axis normal to a), so b is met to that angle
    sin_off = float(np.linalg.norm(np.cross(ua, ub))) if float(ua @ ub) < 0.0 else 0.0
    np.testing.assert_allclose(rotated, ub, atol=1e-6 + (2.0 * sin_off if sin_off < 1e-4 else 0.0))


@settings(max_examples=80, deadline=None)
@given(
    st.tuples(st.floats(-3, 3), st.floats(-3, 3), st.floats(-3, 3)),
    st.floats(-1.0, 2.0, allow_nan=False),
)
def test_mixer_outputs_always_in_range(torque: tuple[float, float, float], thrust: float) -> None:
    u = mix_quad_x(torque, thrust)
    assert all(0.0 <= c <= 1.0 for c in u)
    # the realised roll/pitch torque never has the wrong sign
    roll = -u[0] + u[1] + u[2] - u[3]
    pitch = u[0] - u[1] + u[2] - u[3]
    assert roll * torque[0] >= -1e-12
    assert pitch * torque[1] >= -1e-12


@settings(max_examples=150, deadline=None)
@given(st.floats(-2, 2), st.floats(-2, 2), st.floats(0.0, 1.0))
def test_mixer_without_airmode_scales_roll_pitch_instead_of_raising_thrust(
    roll: float, pitch: float, thrust: float
) -> None:
    """MC_AIRMODE 0: the collective never rises above the command, the realised roll/pitch
    keep their signs and never exceed the request."""
    u = mix_quad_x((roll, pitch, 0.0), thrust)
    assert all(0.0 <= c <= 1.0 for c in u)
    assert sum(u) / 4 <= thrust + 1e-12
    r_req, p_req = 4 * roll * math.sqrt(0.5), 4 * pitch * math.sqrt(0.5)
    r_got = -u[0] + u[1] + u[2] - u[3]
    p_got = u[0] - u[1] + u[2] - u[3]
    assert r_got * roll >= -1e-12 and abs(r_got) <= abs(r_req) + 1e-9
    assert p_got * pitch >= -1e-12 and abs(p_got) <= abs(p_req) + 1e-9


@settings(max_examples=150, deadline=None)
@given(quat, quat, st.one_of(st.just(math.nan), st.floats(-3.0, 3.0)))
def test_fast_attitude_control_equals_readable_version(
    a: tuple[float, ...], b: tuple[float, ...], ff: float
) -> None:
    g = McGains.from_params(ParamStore())
    qa, qb = _unit((a[0], a[1], a[2], a[3])), _unit((b[0], b[1], b[2], b[3]))
    fast = attitude_control(g, qa, qb, ff)
    slow = attitude_control_reference(g, qa, qb, ff)
    # near a 180-degree yaw error q_mix's w is ~0 and its z ~1, where asin/acos turn rounding
    # into ~sqrt(machine epsilon) ~ 1e-8 rad (times the P gain): equal to 1e-6 rad/s
    np.testing.assert_allclose(fast, slow, rtol=0.0, atol=1e-6)


@settings(max_examples=100, deadline=None)
@given(vec, vec, st.floats(0.5, 12.0))
def test_constrain_xy_keeps_position_part_first(
    v0: tuple[float, ...], v1: tuple[float, ...], vmax: float
) -> None:
    x, y = constrain_xy(v0[0], v0[1], v1[0], v1[1], vmax)
    n = math.hypot(x, y)
    assert n <= vmax + 1e-9
    total = (v0[0] + v1[0], v0[1] + v1[1])
    if math.hypot(*total) <= vmax:
        assert (x, y) == total
    elif math.hypot(v0[0], v0[1]) >= vmax:
        # the position part alone, scaled: same direction as v0
        assert x * v0[1] - y * v0[0] == pytest.approx(0.0, abs=1e-6 * vmax * math.hypot(*v0[:2]))
    else:
        # full v0 plus a non-negative multiple of v1, exactly at the limit
        assert n == pytest.approx(vmax, rel=1e-9)
        rx, ry = x - v0[0], y - v0[1]
        assert rx * v1[0] + ry * v1[1] >= -1e-9
        assert rx * v1[1] - ry * v1[0] == pytest.approx(0.0, abs=1e-6 * (1 + math.hypot(rx, ry)))
