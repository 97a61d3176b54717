"""The mock autopilot with a MAVLink 2 signing key, driven by a pymavlink client (pymavlink's
own signing signs the client's frames and checks the mock's: an independent implementation)."""

from __future__ import annotations

import hashlib
import itertools
from pathlib import Path
from typing import Any

import pytest
from pymavlink.dialects.v20 import common as mavlink

from sitl_mock.__main__ import build_parser
from sitl_mock.signing import read_key_file
from tests.support.autopilot_harness import Harness

KEY = bytes(range(100, 132))
OTHER_KEY = bytes(range(32))
UNIX_BOOT_S = 1_767_225_600.0  # 2026-01-01
BOOT_TICKS = int((UNIX_BOOT_S - 1_420_070_400) * 100_000)  # 10 us units since 2015 (spec)
CMD_UNSUPPORTED = 31999  # the mock answers any unknown command with one ACK (UNSUPPORTED)


def keyed_harness() -> Harness:
    h = Harness(signing_key=KEY, unix_boot_s=UNIX_BOOT_S, estimator_ready_s=0.5)
    sign_with(h.mav, KEY, BOOT_TICKS)
    return h


def sign_with(mav: Any, key: bytes, timestamp: int, link_id: int = 0) -> None:
    """Make a pymavlink MAVLink object sign what it packs."""
    mav.signing.secret_key = key
    mav.signing.sign_outgoing = True
    mav.signing.link_id = link_id
    mav.signing.timestamp = timestamp


def unsigned(msg: Any, seq: int = 0) -> bytes:
    return bytes(msg.pack(mavlink.MAVLink(None, srcSystem=255, srcComponent=190)))


def arm_msg() -> Any:
    return mavlink.MAVLink_command_long_message(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)


def test_keyed_mock_obeys_a_signed_command_and_signs_its_acknowledgement() -> None:
    h = keyed_harness()
    h.wait_ready()
    h.arm()
    h.run(0.1)
    assert h.ap.armed and h.acks(400) == [0]
    rx = mavlink.MAVLink(None)
    rx.signing.secret_key = KEY  # pymavlink holding the key checks the mock's signatures
    rx.signing.timestamp = BOOT_TICKS
    parsed = [m for raw in h.raw for m in rx.parse_buffer(raw) or []]
    assert len(parsed) == len(h.raw) > 50
    assert all(m.get_signed() and m.get_type() != "BAD_DATA" for m in parsed)
    assert rx.signing.badsig_count == 0 and rx.signing.unsigned_count == 0


def test_keyed_mock_refuses_an_unsigned_command_long() -> None:
    h = keyed_harness()
    h.wait_ready()
    h.send_bytes(unsigned(arm_msg()))
    h.command_long(CMD_UNSUPPORTED)  # signed: its ACK proves the unsigned one came first
    h.run(0.1)
    assert h.acks(CMD_UNSUPPORTED) == [3]
    assert h.acks(400) == [] and not h.ap.armed  # no ACK, not armed: dropped like PX4
    assert h.ap.links["offboard"].signing.refused["unsigned"] == 1  # type: ignore[union-attr]


def test_keyed_mock_refuses_a_command_signed_with_another_key() -> None:
    h = keyed_harness()
    h.wait_ready()
    sign_with(h.mav, OTHER_KEY, BOOT_TICKS + 10)
    h.arm()
    sign_with(h.mav, KEY, BOOT_TICKS + 20)
    h.command_long(CMD_UNSUPPORTED)
    h.run(0.1)
    assert h.acks(400) == [] and not h.ap.armed
    assert h.acks(CMD_UNSUPPORTED) == [3]
    assert h.ap.links["offboard"].signing.refused["bad_signature"] == 1  # type: ignore[union-attr]


def test_forged_far_future_frame_does_not_lock_the_mock_out_of_genuine_commands() -> None:
    h = keyed_harness()
    forger = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)  # same stream, wrong key
    sign_with(forger, OTHER_KEY, (1 << 48) - 10)
    h.send_bytes(bytes(mavlink.MAVLink_command_long_message(
        1, 1, CMD_UNSUPPORTED, 0, 0, 0, 0, 0, 0, 0, 0).pack(forger)))
    for k in range(100):
        h.command_long(CMD_UNSUPPORTED, confirmation=k % 256)
    h.run(0.05)
    assert h.acks(CMD_UNSUPPORTED) == [3] * 100  # every genuine command answered
    lk = h.ap.links["offboard"].signing
    assert lk is not None and lk.refused == {"unsigned": 0, "bad_signature": 1,
                                             "old_timestamp": 0}
    assert lk.streams[(255, 190, 0)] == BOOT_TICKS + 99  # pymavlink stamped 0..99 after boot


def test_keyed_mock_refuses_a_replayed_signed_frame() -> None:
    h = keyed_harness()
    frame = bytes(mavlink.MAVLink_command_long_message(
        1, 1, CMD_UNSUPPORTED, 0, 0, 0, 0, 0, 0, 0, 0).pack(h.mav))
    h.send_bytes(frame)
    h.send_bytes(frame)  # captured and sent again
    h.run(0.05)
    assert h.acks(CMD_UNSUPPORTED) == [3]
    assert h.ap.links["offboard"].signing.refused["old_timestamp"] == 1  # type: ignore[union-attr]


def test_mock_signature_recomputed_from_the_spec() -> None:
    """sha256(key + frame without the last 6 bytes)[:6]; link id and 48-bit timestamp in the
    13-byte block; the signed flag set and covered by a CRC pymavlink (no key) accepts."""
    h = keyed_harness()
    h.run(1.0)
    stamps = []
    for raw in h.raw:
        assert raw[2] & 0x01 and len(raw) == 12 + raw[1] + 13
        assert hashlib.sha256(KEY + raw[:-6]).digest()[:6] == raw[-6:]
        assert raw[-13] == 0  # the offboard link is the mock's link 0
        stamps.append(int.from_bytes(raw[-12:-6], "little"))
        assert mavlink.MAVLink(None).parse_buffer(raw)[0].get_type() != "BAD_DATA"
    assert all(b > a for a, b in itertools.pairwise(stamps))
    # the timestamps follow simulated time from the wall clock given at boot (+1 per frame)
    assert stamps[0] > BOOT_TICKS and stamps[-1] <= BOOT_TICKS + 100_000 + len(stamps)


def test_unkeyed_mock_still_accepts_unsigned_commands() -> None:
    h = Harness(estimator_ready_s=0.5)
    h.wait_ready()
    h.arm()
    h.run(0.1)
    assert h.ap.armed and not any(raw[2] & 0x01 for raw in h.raw)


def test_unkeyed_mock_obeys_signed_commands_unchecked_like_px4_v1_16() -> None:
    """PX4 v1.16 has no signing and ignores signatures (tests/px4/test_px4_signing.py); so does
    the mock without a key."""
    h = Harness(estimator_ready_s=0.5)
    sign_with(h.mav, OTHER_KEY, BOOT_TICKS)
    h.wait_ready()
    h.arm()
    h.run(0.1)
    assert h.ap.armed and h.acks(400) == [0]


@pytest.mark.parametrize(("content", "ok"), [
    (KEY.hex().encode() + b"\n", True),
    (b"  " + KEY.hex().upper().encode() + b"\r\n", True),
    (KEY, True),
    (KEY.hex().encode()[:-1], False),
    (KEY[:31], False),
    (KEY + b"\x00", False),
    (b"", False),
])
def test_mock_key_file_parsing(tmp_path: Path, content: bytes, ok: bool) -> None:
    path = tmp_path / "key"
    path.write_bytes(content)
    if ok:
        assert read_key_file(str(path)) == KEY
    else:
        with pytest.raises(ValueError, match="64 hex digits or 32 raw bytes"):
            read_key_file(str(path))
        with pytest.raises(SystemExit) as exc:  # the CLI refuses it before starting
            build_parser().parse_args(["serve", "--signing-key", str(path)])
        assert exc.value.code == 2


def test_mock_refuses_a_missing_key_file(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"signing key file .*nope"):
        read_key_file(str(tmp_path / "nope"))
