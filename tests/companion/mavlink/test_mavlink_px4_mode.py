"""PX4 custom_mode decoding against HEARTBEATs observed on real PX4 v1.16 SITL (PX4.md)."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.mavlink import FlightMode, custom_mode_of, decode_custom_mode, encode_custom_mode
from companion.mavlink.px4_mode import flight_mode_from_custom_mode, is_armed, set_mode_params

# (base_mode, custom_mode, expected mode, expected armed) as seen on the wire (PX4.md).
OBSERVED = [
    (29, 50593792, FlightMode.HOLD, False),
    (145, 393216, FlightMode.OFFBOARD, True),
    (157, 50593792, FlightMode.HOLD, True),
    (157, 67371008, FlightMode.MISSION, True),
    (157, 100925440, FlightMode.LAND, True),
    (157, 33816576, FlightMode.TAKEOFF, True),
    (209, 196608, FlightMode.POSCTL, True),
    (17, 393216, FlightMode.OFFBOARD, False),
    (1, 393216, FlightMode.OFFBOARD, False),
]


@pytest.mark.parametrize(("base", "custom", "mode", "armed"), OBSERVED)
def test_observed_heartbeats_decode(base: int, custom: int, mode: FlightMode, armed: bool) -> None:
    assert flight_mode_from_custom_mode(custom) is mode
    assert is_armed(base) is armed
    # and the encoder reproduces the observed number exactly
    assert custom_mode_of(mode) == custom


@given(main=st.integers(0, 255), sub=st.integers(0, 255))
@settings(max_examples=100, deadline=None)
def test_encode_decode_round_trip(main: int, sub: int) -> None:
    assert decode_custom_mode(encode_custom_mode(main, sub)) == (main, sub)


def test_unknown_and_posctl_submodes() -> None:
    assert flight_mode_from_custom_mode(encode_custom_mode(9, 0)) is FlightMode.UNKNOWN
    assert flight_mode_from_custom_mode(encode_custom_mode(4, 42)) is FlightMode.UNKNOWN
    assert flight_mode_from_custom_mode(encode_custom_mode(3, 1)) is FlightMode.POSCTL  # orbit
    with pytest.raises(ValueError):
        encode_custom_mode(256, 0)


def test_set_mode_params_match_mavsdk() -> None:
    # MAVSDK sends DO_SET_MODE(129, 6, 0) to enter OFFBOARD while armed (PX4.md).
    assert set_mode_params(FlightMode.OFFBOARD, armed=True) == (129.0, 6.0, 0.0)
    assert set_mode_params(FlightMode.HOLD, armed=False) == (1.0, 4.0, 3.0)
