"""MAVLink 2 signing in the companion's sans-IO core: signatures checked against the spec
(hashlib) and against pymavlink's signing, the replay rules, the forged far-future frame, the
two signing threads, key files and log stripping."""

from __future__ import annotations

import hashlib
import threading
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as m

from companion.aio.tlog import TlogWriter
from companion.app.cli import main as cli_main
from companion.mavlink import (
    AttitudeSetpoint,
    Codec,
    LinkConfig,
    Signer,
    SigningConfig,
    SigningKeyError,
    VehicleLink,
    Verdict,
    load_signing_key,
)
from companion.mavlink.signing import strip_signature

KEY = bytes(range(1, 33))
OTHER_KEY = bytes(32)
UNIX_S = 1_700_000_000.0
TICKS = (1_700_000_000 - 1_420_070_400) * 100_000  # 10 us units since 2015-01-01 (the spec)
MAX_TS = (1 << 48) - 1


def command_long(cmd: int = 400) -> Any:
    return m.MAVLink_command_long_message(1, 1, cmd, 0, 1, 0, 0, 0, 0, 0, 0)


def signer(key: bytes = KEY, unix_s: float | None = UNIX_S, link_id: int = 0) -> Signer:
    return Signer(SigningConfig(key, link_id=link_id), unix_s)


def pymavlink_signer(key: bytes, timestamp: int, sysid: int = 1, compid: int = 191,
                     link_id: int = 0) -> Any:
    mav = m.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    mav.signing.secret_key = key
    mav.signing.sign_outgoing = True
    mav.signing.timestamp = timestamp
    mav.signing.link_id = link_id
    return mav


def pymavlink_receiver(key: bytes, timestamp: int = TICKS) -> Any:
    mav = m.MAVLink(None)
    mav.signing.secret_key = key
    mav.signing.timestamp = timestamp
    mav.robust_parsing = True
    return mav


def test_signed_frame_matches_the_spec_recomputed_with_hashlib() -> None:
    frame = Codec(1, 191, signer(link_id=9)).encode(command_long())
    n = frame[1]
    assert frame[0] == 0xFD and frame[2] == 0x01  # incompat_flags: MAVLINK_IFLAG_SIGNED
    assert len(frame) == 10 + n + 2 + 13
    crc = m.x25crc(frame[1:10 + n])  # the CRC covers the header with the signed flag
    crc.accumulate(bytes((m.MAVLink_command_long_message.crc_extra,)))
    assert frame[10 + n:12 + n] == crc.crc.to_bytes(2, "little")
    assert frame[12 + n] == 9  # link id
    assert int.from_bytes(frame[13 + n:19 + n], "little") == TICKS + 1  # clock, then +1
    assert frame[-6:] == hashlib.sha256(KEY + frame[:-6]).digest()[:6]


def test_pymavlink_holding_the_key_accepts_our_frames_and_refuses_another_key() -> None:
    link = VehicleLink(LinkConfig(signing=SigningConfig(KEY)))
    link.advance_signing_clock(UNIX_S)
    link.arm(0.0)
    link.handle_timer(0.0)  # HEARTBEAT (+ TIMESYNC)
    frames = link.frames_to_send()
    frames.append(link.encode_setpoint(
        AttitudeSetpoint(q_wxyz=(1.0, 0.0, 0.0, 0.0), thrust_norm=0.5), 0.0))
    good = pymavlink_receiver(KEY)
    got = [msg for f in frames for msg in good.parse_buffer(f) or []]
    assert [x.get_type() for x in got][:1] == ["COMMAND_LONG"] and len(got) == len(frames) >= 3
    assert all(x.get_signed() for x in got) and got[0].command == 400
    assert {x.get_link_id() for x in got} == {0, 1}  # event-loop stream, setpoint stream
    bad = pymavlink_receiver(OTHER_KEY)
    assert all(x.get_type() == "BAD_DATA" for f in frames for x in bad.parse_buffer(f) or [])
    assert bad.signing.badsig_count == len(frames)


def test_we_accept_pymavlink_signed_frames_and_refuse_another_key() -> None:
    ours = Codec(1, 191, signer())
    good = bytes(command_long().pack(pymavlink_signer(KEY, TICKS, sysid=1, compid=1)))
    wrong = bytes(command_long().pack(pymavlink_signer(OTHER_KEY, TICKS + 5, 1, 1)))
    assert [x.command for x in ours.decode(good)] == [400]
    assert ours.decode(wrong) == [] and ours.rejected_frames == 1
    assert ours.signer is not None and ours.signer.stats == {"accepted": 1, "bad_signature": 1}


def test_forged_far_future_frame_does_not_lock_out_100_genuine_frames() -> None:
    """One frame on the genuine stream (same sysid, compid, link id) with a timestamp at the
    48-bit limit and a signature made with another key, then 100 frames pymavlink signs with
    the right key: all 100 are accepted (pymavlink itself accepts 0 of them after the forgery,
    because it stores the stream timestamp before it compares the signature)."""
    receiver = Codec(1, 191, signer())
    forged = bytes(command_long().pack(pymavlink_signer(OTHER_KEY, MAX_TS, 1, 1)))
    assert receiver.decode(forged) == []
    genuine_tx = pymavlink_signer(KEY, TICKS + 1, 1, 1)
    got = [x for k in range(100) for x in receiver.decode(bytes(command_long(k).pack(genuine_tx)))]
    assert [x.command for x in got] == list(range(100))
    s = receiver.signer
    assert s is not None and s.stats == {"bad_signature": 1, "accepted": 100}
    assert s.stream_timestamp(1, 1, 0) == TICKS + 100  # the genuine stream, never MAX_TS
    assert s.timestamp == TICKS + 100  # our own clock was not dragged to the forged value


def test_replayed_old_and_unsigned_frames_are_refused() -> None:
    s = signer()
    tx = pymavlink_signer(KEY, TICKS, 7, 1)
    first = bytes(command_long().pack(tx))
    second = bytes(command_long().pack(tx))
    assert s.verify(second) is Verdict.ACCEPTED
    assert s.verify(second) is Verdict.REPLAYED  # the same frame captured and sent again
    assert s.verify(first) is Verdict.REPLAYED  # an older one of the same stream
    # a stream not seen yet: up to one minute behind our timestamp is fine, more is not
    late = bytes(command_long().pack(pymavlink_signer(KEY, TICKS - 6_000_000 + 10, 8, 1)))
    stale = bytes(command_long().pack(pymavlink_signer(KEY, TICKS - 6_000_010, 9, 1)))
    assert s.verify(late) is Verdict.ACCEPTED
    assert s.verify(stale) is Verdict.STALE
    unsigned = bytes(command_long().pack(m.MAVLink(None, srcSystem=1, srcComponent=1)))
    radio = bytes(m.MAVLink_radio_status_message(1, 2, 3, 4, 5, 6, 7).pack(m.MAVLink(None)))
    assert s.verify(unsigned) is Verdict.UNSIGNED
    assert s.verify(radio) is Verdict.UNSIGNED_ALLOWED  # PX4 accepts it unsigned too
    assert s.stream_timestamp(7, 1, 0) == TICKS + 1


@settings(max_examples=60, deadline=None)
@given(st.data())
def test_any_altered_byte_of_a_signed_frame_is_refused(data: st.DataObject) -> None:
    frame = bytearray(Codec(1, 191, signer()).encode(command_long()))
    k = data.draw(st.integers(1, len(frame) - 1), label="byte")
    frame[k] ^= data.draw(st.integers(1, 255), label="xor")
    rx = Codec(1, 1, signer())
    assert rx.decode(bytes(frame)) == []


def test_two_sending_threads_keep_each_stream_monotonic() -> None:
    """The event loop (commands) and the sender thread (setpoints) sign concurrently; whatever
    the interleaving on the wire between the two, every frame is accepted, because each
    thread signs its own stream (link id, link id + 1) in its own send order."""
    link = VehicleLink(LinkConfig(signing=SigningConfig(KEY, link_id=3)))
    link.advance_signing_clock(UNIX_S)
    sp = AttitudeSetpoint(q_wxyz=(1.0, 0.0, 0.0, 0.0), thrust_norm=0.5)
    commands: list[bytes] = []
    setpoints: list[bytes] = []

    def sender() -> None:
        for _ in range(400):
            setpoints.append(link.encode_setpoint(sp, 0.0))

    t = threading.Thread(target=sender)
    t.start()
    for _ in range(400):
        link.send_message(command_long())
        commands += link.frames_to_send()
    t.join(10)
    assert {f[-13] for f in commands} == {3} and {f[-13] for f in setpoints} == {4}
    rx = Codec(1, 1, signer())
    # worst case for a single stream: all setpoints delivered first, then all commands
    got = [x for f in setpoints + commands for x in rx.decode(f)]
    assert len(got) == 800 and rx.rejected_frames == 0


def test_link_without_a_clock_signs_from_zero_and_is_refused_as_stale() -> None:
    """advance_signing_clock is what makes the timestamps current: without it a receiver whose
    clock is set refuses the first frame of the new stream as more than a minute old."""
    stale = Codec(1, 191, signer(unix_s=None)).encode(command_long())
    assert signer().verify(stale) is Verdict.STALE


def test_tlog_records_signed_frames_unsigned(tmp_path: Path) -> None:
    frame = Codec(1, 191, signer()).encode(command_long())
    plain = strip_signature(frame)
    assert len(plain) == len(frame) - 13 and plain[2] == 0
    (msg,) = m.MAVLink(None).parse_buffer(plain)  # CRC recomputed: pymavlink accepts it
    assert msg.command == 400 and not msg.get_signed()
    w = TlogWriter(tmp_path / "x.tlog")
    w.write(frame, 1.0)
    w.close()
    assert (tmp_path / "x.tlog").read_bytes() == (1_000_000).to_bytes(8, "big") + plain


# -- key files ------------------------------------------------------------------------------
@pytest.mark.parametrize("content", [
    KEY.hex().encode(),
    KEY.hex().encode() + b"\n",
    b"  0x" + KEY.hex().upper().encode() + b"\r\n",
    KEY,
    b"\n" + KEY[1:31] + b" ",  # raw bytes that begin and end with whitespace
])
def test_key_file_accepts_hex_text_and_raw_bytes(tmp_path: Path, content: bytes) -> None:
    path = tmp_path / "key"
    path.write_bytes(content)
    expected = content if len(content) == 32 else KEY
    assert load_signing_key(path) == expected


@pytest.mark.parametrize(("content", "why"), [
    (KEY.hex().encode()[:-1], "63 hex digits"),
    (KEY.hex().encode() + b"ab", "66 hex digits"),
    (KEY.hex()[:32].encode(), "32 hex digits"),  # a 16-byte key written in hex
    (KEY[:31], "31 bytes"),
    (KEY + b"\x00", "33 bytes"),
    (b"", "0 bytes"),
    (b"not a key at all\n", "17 bytes"),
])
def test_key_file_errors_say_what_is_wrong(tmp_path: Path, content: bytes, why: str) -> None:
    path = tmp_path / "key"
    path.write_bytes(content)
    with pytest.raises(SigningKeyError, match=why) as exc:
        load_signing_key(path)
    assert str(path) in str(exc.value) and "32 bytes" in str(exc.value)


def test_missing_key_file_is_named(tmp_path: Path) -> None:
    with pytest.raises(SigningKeyError, match="nope"):
        load_signing_key(tmp_path / "nope")


def test_signing_config_checks_the_key_and_hides_it() -> None:
    with pytest.raises(SigningKeyError):
        SigningConfig(KEY[:16])
    assert KEY.hex() not in repr(SigningConfig(KEY)) and str(KEY) not in repr(SigningConfig(KEY))


@pytest.mark.parametrize("command", ["status", "fly"])
def test_cli_refuses_a_bad_key_file_before_connecting(tmp_path: Path, command: str,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "short.key"
    path.write_bytes(b"abcd\n")
    target = ["figure8"] if command == "fly" else []
    code = cli_main([command, *target, "--connect", "udpin://127.0.0.1:9",
                     "--signing-key", str(path)])
    err = capsys.readouterr().err
    assert code == 2 and "--signing-key" in err and "4 hex digits" in err


def test_shared_link_options_give_the_link_config(tmp_path: Path) -> None:
    """What a command (fly, status, serve) does with `add_signing_option` + `link_config`."""
    import argparse

    from companion.app.link_options import add_signing_option, link_config

    path = tmp_path / "k"
    path.write_text(KEY.hex())
    p = argparse.ArgumentParser()
    p.add_argument("--target-system", type=int, default=1)
    add_signing_option(p)
    cfg = link_config(p.parse_args(["--target-system", "3", "--signing-key", str(path)]),
                      compid=190)
    assert cfg.target_sysid == 3 and cfg.compid == 190
    assert cfg.signing is not None and cfg.signing.key == KEY
    assert link_config(p.parse_args([])).signing is None


def test_key_file_readable_by_others_is_warned_about(tmp_path: Path,
                                                     caplog: pytest.LogCaptureFixture) -> None:
    path = tmp_path / "key"
    path.write_text(KEY.hex())
    path.chmod(0o600)
    with caplog.at_level("WARNING", logger="companion.mavlink.signing"):
        load_signing_key(path)
        assert not caplog.records
        path.chmod(0o644)
        assert load_signing_key(path) == KEY  # still used, with a warning
    assert "chmod 600" in caplog.text and "644" in caplog.text
