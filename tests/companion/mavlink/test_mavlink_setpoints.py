"""Setpoint builders: type_mask against PX4.md's observed masks, field round trip through a
real MAVLink frame, and refusal of NaN/inf, unnormalised quaternions, thrust out of range."""

from __future__ import annotations

import math
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.mavlink import (
    AttitudeSetpoint,
    PositionSetpoint,
    RatesSetpoint,
    RoverVelocitySetpoint,
    SetpointError,
    build_setpoint,
)
from tests.support.mavlink_fakes import Px4Side

P = (1.0, -2.0, -5.0)


def wire(sp: Any) -> Any:
    return Px4Side(1, 191).msg(build_setpoint(sp, 1, 1, 1234))


@pytest.mark.parametrize(
    ("sp", "mask"),
    [
        # PX4.md: MAVSDK position-only (with yaw) = 2552; accepted masks 2552, 3576, 2048.
        (PositionSetpoint(pos_ned=P, yaw=0.3), 2552),
        (PositionSetpoint(pos_ned=P), 3576),
        (PositionSetpoint(pos_ned=P, vel_ned=P, acc_ned=P, yaw=0.3), 2048),
        (PositionSetpoint(pos_ned=P, vel_ned=P, acc_ned=P, yaw=0.3, yaw_rate=0.1), 0),
    ],
)
def test_position_masks_match_px4_observations(sp: PositionSetpoint, mask: int) -> None:
    msg = wire(sp)
    assert msg.type_mask == mask and msg.coordinate_frame == 1
    assert (msg.target_system, msg.target_component) == (1, 1)
    assert not msg.type_mask & 512  # never FORCE


def test_position_fields_round_trip() -> None:
    sp = PositionSetpoint(pos_ned=(1.5, -2.25, -5.0), vel_ned=(0.5, 0.25, -0.125),
                          acc_ned=(0.0625, -1.0, 2.0), yaw=1.25, yaw_rate=-0.5)
    msg = wire(sp)
    got = (msg.x, msg.y, msg.z, msg.vx, msg.vy, msg.vz, msg.afx, msg.afy, msg.afz,
           msg.yaw, msg.yaw_rate)
    assert got == (*sp.pos_ned, *sp.vel_ned, *sp.acc_ned, 1.25, -0.5)


def test_attitude_and_rates_masks() -> None:
    h = math.sqrt(0.5)
    att = wire(AttitudeSetpoint(q_wxyz=(h, 0.0, 0.0, h), thrust_norm=0.55, yaw_rate=0.2))
    assert att.type_mask == 3 and att.body_yaw_rate == pytest.approx(0.2)
    assert list(att.q) == pytest.approx([h, 0, 0, h]) and att.thrust == pytest.approx(0.55)
    att7 = wire(AttitudeSetpoint(q_wxyz=(1.0, 0.0, 0.0, 0.0), thrust_norm=0.5))
    assert att7.type_mask == 7  # PX4.md: accepted SET_ATTITUDE_TARGET mask 7
    rates = wire(RatesSetpoint(omega_frd=(0.1, -0.2, 0.3), thrust_norm=0.6))
    assert rates.type_mask == 128
    assert (rates.body_roll_rate, rates.body_pitch_rate, rates.body_yaw_rate) == pytest.approx(
        (0.1, -0.2, 0.3))


def test_rover_velocity() -> None:
    msg = wire(RoverVelocitySetpoint(vel_ne=(1.0, 2.0), yaw_rate=0.25))
    mask = msg.type_mask
    # velocity and yaw rate used; position, acceleration and yaw ignored
    assert mask & (8 | 16 | 32 | 2048) == 0 and mask & (1 | 2 | 4) == 7
    assert mask & (64 | 128 | 256) == 448 and mask & 1024
    assert (msg.vx, msg.vy, msg.vz, msg.yaw_rate) == (1.0, 2.0, 0.0, 0.25)


BAD = st.sampled_from([math.nan, math.inf, -math.inf])
FIN = st.floats(-100, 100)


@given(bad=BAD, idx=st.integers(0, 10), vals=st.lists(FIN, min_size=11, max_size=11))
@settings(max_examples=60, deadline=None)
def test_position_refuses_non_finite(bad: float, idx: int, vals: list[float]) -> None:
    v = list(vals)
    v[idx] = bad
    sp = PositionSetpoint(pos_ned=(v[0], v[1], v[2]), vel_ned=(v[3], v[4], v[5]),
                          acc_ned=(v[6], v[7], v[8]), yaw=v[9], yaw_rate=v[10])
    with pytest.raises(SetpointError):
        build_setpoint(sp, 1, 1, 0)


@given(bad=BAD, idx=st.integers(0, 5))
@settings(max_examples=40, deadline=None)
def test_attitude_and_rates_refuse_non_finite(bad: float, idx: int) -> None:
    q = [1.0, 0.0, 0.0, 0.0]
    if idx < 4:
        q[idx] = bad
        sp: Any = AttitudeSetpoint(q_wxyz=(q[0], q[1], q[2], q[3]), thrust_norm=0.5)
    elif idx == 4:
        sp = AttitudeSetpoint(q_wxyz=(1.0, 0.0, 0.0, 0.0), thrust_norm=bad)
    else:
        sp = RatesSetpoint(omega_frd=(0.0, bad, 0.0), thrust_norm=0.5)
    with pytest.raises(SetpointError):
        build_setpoint(sp, 1, 1, 0)


@pytest.mark.parametrize("scale", [0.5, 0.99, 1.01, 2.0])
def test_attitude_refuses_unnormalised_quaternion(scale: float) -> None:
    with pytest.raises(SetpointError, match="normalised"):
        build_setpoint(AttitudeSetpoint(q_wxyz=(scale, 0.0, 0.0, 0.0), thrust_norm=0.5), 1, 1, 0)


@pytest.mark.parametrize("thrust", [-0.01, 1.01])
def test_thrust_range(thrust: float) -> None:
    with pytest.raises(SetpointError, match="thrust"):
        build_setpoint(RatesSetpoint(omega_frd=(0.0, 0.0, 0.0), thrust_norm=thrust), 1, 1, 0)


def test_position_needs_motion_and_rover_refuses_nan() -> None:
    with pytest.raises(SetpointError):
        build_setpoint(PositionSetpoint(yaw=0.0), 1, 1, 0)
    with pytest.raises(SetpointError):
        build_setpoint(RoverVelocitySetpoint(vel_ne=(math.nan, 0.0), yaw_rate=0.0), 1, 1, 0)


# -- the per-cycle path: pack_setpoint + Codec.encode_payload against pymavlink -----------------
UNIT = st.floats(-1.0, 1.0, allow_nan=False)


def _pymavlink_frame(msg: Any, seq: int) -> bytes:
    from pymavlink.dialects.v20 import common as m

    mav = m.MAVLink(None, srcSystem=1, srcComponent=191)
    mav.seq = seq
    return bytes(msg.pack(mav))


@given(q=st.tuples(UNIT, UNIT, UNIT, UNIT), thrust=st.floats(0.0, 1.0),
       yaw_rate=st.none() | st.floats(-10, 10) | st.just(0.0) | st.just(-0.0),
       rates=st.tuples(FIN, FIN, FIN), tbm=st.integers(0, 2**40), seq=st.integers(0, 255),
       target=st.tuples(st.integers(0, 255), st.integers(0, 255)))
@settings(max_examples=120, deadline=None)
def test_pack_setpoint_frames_equal_pymavlink(
    q: tuple[float, float, float, float], thrust: float, yaw_rate: float | None,
    rates: tuple[float, float, float], tbm: int, seq: int, target: tuple[int, int],
) -> None:
    """The frame the link sends per cycle is byte-for-byte pymavlink's pack of the message that
    build_setpoint gives (zero truncation, wire order, CRC, sequence)."""
    from companion.mavlink import Codec
    from companion.mavlink.setpoints import pack_setpoint

    n = math.sqrt(sum(x * x for x in q))
    qn = (1.0, 0.0, 0.0, 0.0) if n < 1e-3 else tuple(x / n for x in q)
    for sp in (AttitudeSetpoint(q_wxyz=qn, thrust_norm=thrust, yaw_rate=yaw_rate),  # type: ignore[arg-type]
               RatesSetpoint(omega_frd=rates, thrust_norm=thrust)):
        packed = pack_setpoint(sp, *target, tbm)
        assert packed is not None
        c = Codec(1, 191)
        c.mav.seq = seq
        ours = c.encode_payload(*packed)
        assert ours == _pymavlink_frame(build_setpoint(sp, *target, tbm), seq)
        assert c.mav.seq == (seq + 1) % 256


@given(bad=BAD, idx=st.integers(0, 6))
@settings(max_examples=40, deadline=None)
def test_pack_setpoint_refuses_what_build_refuses(bad: float, idx: int) -> None:
    from companion.mavlink.setpoints import pack_setpoint

    q = [1.0, 0.0, 0.0, 0.0]
    if idx < 4:
        q[idx] = bad
        sp: Any = AttitudeSetpoint(q_wxyz=(q[0], q[1], q[2], q[3]), thrust_norm=0.5)
    elif idx == 4:
        sp = AttitudeSetpoint(q_wxyz=(1.0, 0.0, 0.0, 0.0), thrust_norm=0.5, yaw_rate=bad)
    elif idx == 5:
        sp = RatesSetpoint(omega_frd=(0.0, 0.0, bad), thrust_norm=0.5)
    else:
        sp = AttitudeSetpoint(q_wxyz=(0.9, 0.0, 0.0, 0.0), thrust_norm=0.5)  # not unit
    for fn in (build_setpoint, pack_setpoint):
        with pytest.raises(SetpointError):
            fn(sp, 1, 1, 0)


def test_pack_setpoint_leaves_position_types_to_build() -> None:
    from companion.mavlink.setpoints import pack_setpoint

    assert pack_setpoint(PositionSetpoint(pos_ned=P), 1, 1, 0) is None
    assert pack_setpoint(RoverVelocitySetpoint(vel_ne=(1.0, 0.0), yaw_rate=0.0), 1, 1, 0) is None


def test_link_signs_setpoints_when_signing_is_on() -> None:
    """With outgoing signing configured, the link's per-cycle setpoint is a signed frame that a
    receiver holding the key accepts (the unsigned struct path must not be taken)."""
    from pymavlink.dialects.v20 import common as m

    from companion.mavlink import LinkConfig, SigningConfig, VehicleLink

    key = bytes(range(32))
    link = VehicleLink(LinkConfig(signing=SigningConfig(key, link_id=4)))
    frame = link.encode_setpoint(AttitudeSetpoint(q_wxyz=(1.0, 0.0, 0.0, 0.0), thrust_norm=0.5),
                                 1.0)
    assert frame[2] & 0x01  # MAVLINK_IFLAG_SIGNED
    assert frame[-13] == 5  # the setpoint stream: link id + 1
    rx = m.MAVLink(None)
    rx.signing.secret_key = key
    (msg,) = rx.parse_buffer(frame)
    assert msg.get_type() == "SET_ATTITUDE_TARGET" and msg.get_signed() and msg.thrust == 0.5
