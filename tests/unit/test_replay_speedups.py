"""The replay speed-ups (issue 7 bench) equal the general code they stand in for.

- `multirotor_attitude_scalar` (if-branches, only the outputs the controller uses) vs the
  formula module evaluated by `multirotor_setpoint_scalar` and by the batched numpy path,
  including the low-thrust, no-direction, horizontal, heading-singular and inverted branches;
- `reference_of_arrays` / `state_estimate_of_arrays` (no conversions) vs the dataclass
  constructors, and `Schedule.reference`'s fast path vs its general path;
- `TrackingController.attitude_values` vs `attitude` on the same input sequence, and the
  `TrackingSource` output against the controller's command;
- `TlogWriter` with a large buffer writes the same bytes as with the default one, and
  pymavlink reads them back.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2

from companion.aio.tlog import TlogWriter
from companion.control import (
    AttitudeCommand,
    Reference,
    StateEstimate,
    TrackingConfig,
    TrackingController,
    reference_of_arrays,
    state_estimate_of_arrays,
)
from companion.flatness import MultirotorParams, multirotor_setpoint
from companion.flatness.numeric import multirotor_attitude_scalar, multirotor_setpoint_scalar

PARAMS = MultirotorParams(mass=1.3, inertia=(0.021, 0.023, 0.04), hover_thrust=0.45, drag=0.7)
G = PARAMS.g

comp = st.floats(-30.0, 30.0, allow_nan=False)
vec3 = st.tuples(comp, comp, comp)
angle = st.floats(-math.pi, math.pi)


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


# ----------------------------------------------------------------------------- constructors


def _fields_equal(a: object, b: object) -> None:
    assert type(a) is type(b)
    for name in a.__dataclass_fields__:  # type: ignore[attr-defined]
        x, y = getattr(a, name), getattr(b, name)
        if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
            assert isinstance(x, np.ndarray) and isinstance(y, np.ndarray), name
            assert x.dtype == y.dtype == np.float64 and x.shape == y.shape, name
            assert np.array_equal(x, y), name
        else:
            assert x == y, name


@settings(max_examples=40, deadline=None)
@given(st.lists(comp, min_size=18, max_size=18))
def test_reference_of_arrays_equals_constructor(v: list[float]) -> None:
    arrays = [np.array(v[3 * i : 3 * i + 3], dtype=np.float64) for i in range(5)]
    fast = reference_of_arrays(*arrays, v[15], v[16], v[17])
    _fields_equal(fast, Reference(*[a.tolist() for a in arrays], v[15], v[16], v[17]))
    assert fast.is_finite()


def test_state_estimate_of_arrays_equals_constructor() -> None:
    args = (2.5, np.array([1.0, -2.0, -3.0]), np.array([0.1, 0.2, -0.3]),
            np.array([0.9, 0.1, -0.2, 0.3]), np.array([0.01, -0.02, 0.3]))
    for airborne in (True, False):
        fast = state_estimate_of_arrays(*args, airborne=airborne)
        slow = StateEstimate(args[0], *[a.tolist() for a in args[1:]], airborne=airborne)
        _fields_equal(fast, slow)


def test_schedule_reference_fast_path_equals_general_path() -> None:
    from companion.mission import load_mission, mission_to_flight_plan
    from companion.replay import DEFAULT_QUAD
    from companion.schedule import VehicleLimits, build_schedule

    root = Path(__file__).resolve().parents[2]
    m = load_mission(root / "examples" / "missions" / "hold_and_jump.plan")
    sched = build_schedule(mission_to_flight_plan(m, vehicle="quad"), DEFAULT_QUAD,
                           VehicleLimits())
    origin = np.array([0.25, -1.5, -0.125])
    kinds = set()
    for t in np.linspace(-1.0, sched.duration_s + 1.0, 157).tolist():
        kinds.add(sched.piece_at(t).kind)
        fast = sched.reference(t, origin=origin)
        # an origin given as a list takes the general path (numpy broadcasting, constructor)
        _fields_equal(fast, sched.reference(t, origin=origin.tolist()))  # type: ignore[arg-type]
        no_origin = sched.reference(t)
        np.testing.assert_array_equal(no_origin.pos_ned + origin, fast.pos_ned)
    assert "traj" in kinds


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


# ----------------------------------------------------------------------------- tlog


def test_tlog_buffer_writes_the_tlog_writer_bytes(tmp_path: Path) -> None:
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    frames = [
        mavlink2.MAVLink_heartbeat_message(2, 12, 0, 0, 4, 3).pack(mav),
        mavlink2.MAVLink_attitude_message(1000, 0.1, -0.2, 0.3, 0.0, 0.0, 0.0).pack(mav),
        mavlink2.MAVLink_statustext_message(6, b"hello", 0, 0).pack(mav),
    ] * 500
    times = [1_767_225_600.0 + 0.01 * i for i in range(len(frames))]
    # 4 KiB: exercise the block writes too
    with TlogWriter(tmp_path / "fast.tlog", buffer_bytes=4096) as fast, \
            TlogWriter(tmp_path / "ref.tlog") as ref:
        for fr, t in zip(frames, times, strict=True):
            fast.write(fr, t)
            ref.write(fr, t)
    assert fast.frames == ref.frames == len(frames)
    data = (tmp_path / "fast.tlog").read_bytes()
    assert data == (tmp_path / "ref.tlog").read_bytes()
    log = mavutil.mavlink_connection(str(tmp_path / "fast.tlog"))
    n = 0
    try:
        while (m := log.recv_match()) is not None:
            assert m.get_type() in ("HEARTBEAT", "ATTITUDE", "STATUSTEXT")
            n += 1
    finally:
        log.close()
    assert n == len(frames)
