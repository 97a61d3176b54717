"""sitl_mock.mavwire.pack_v2 must produce exactly pymavlink's MAVLink 2 frames."""

from __future__ import annotations

import math

from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as mavlink

from sitl_mock.mavwire import crc_mcrf4xx, pack_v2

floats = st.floats(width=32, allow_nan=True, allow_infinity=True)


def _crc_reference(data: bytes) -> int:
    """CRC-16/MCRF4XX bit by bit (poly 0x8408 reflected, init 0xFFFF): the textbook definition."""
    crc = 0xFFFF
    for b in data:
        crc ^= b
        for _ in range(8):
            crc = (crc >> 1) ^ 0x8408 if crc & 1 else crc >> 1
    return crc


@settings(max_examples=60, deadline=None)
@given(st.binary(max_size=300))
def test_crc_matches_the_bitwise_definition(data: bytes) -> None:
    assert crc_mcrf4xx(data) == _crc_reference(data)


def _same(msg: object, seq: int) -> None:
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    mav.seq = seq
    ref = msg.pack(mav)  # type: ignore[attr-defined]
    assert pack_v2(msg, seq, 1, 1) == ref
    parsed = mavlink.MAVLink(None).parse_buffer(ref)
    assert parsed and parsed[0].get_type() == msg.get_type()  # type: ignore[attr-defined]


@settings(max_examples=60, deadline=None)
@given(
    st.integers(0, 2**32 - 1),
    st.lists(floats, min_size=7, max_size=7),
    st.integers(0, 255),
)
def test_attitude_and_quaternion_frames_match_pymavlink(t: int, f: list[float], seq: int) -> None:
    _same(mavlink.MAVLink_attitude_message(t, *f[:6]), seq)
    _same(mavlink.MAVLink_attitude_quaternion_message(t, *f, [0.0, f[0], 0.0, 0.0]), seq)


@settings(max_examples=40, deadline=None)
@given(st.text(alphabet=st.characters(min_codepoint=32, max_codepoint=126), max_size=50))
def test_char_fields_and_truncation_match_pymavlink(text: str) -> None:
    _same(mavlink.MAVLink_statustext_message(6, text.encode(), 0, 0), 9)
    _same(mavlink.MAVLink_param_value_message(text[:16].encode(), 0.5, 9, 80, 3), 200)


def test_all_zero_payload_keeps_one_byte_and_odometry_arrays() -> None:
    _same(mavlink.MAVLink_mission_item_reached_message(0), 0)
    cov = [math.nan] + [0.0] * 20
    _same(
        mavlink.MAVLink_odometry_message(
            1, 1, 12, 1, 2, 3, [1, 0, 0, 0], 4, 5, 6, 7, 8, 9, cov, cov, 0, 8, 100
        ),
        77,
    )
