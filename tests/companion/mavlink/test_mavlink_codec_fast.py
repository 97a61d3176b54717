"""The codec's fast MAVLink 2 decode path against pymavlink's own parser (the oracle).

The oracle is the codec's previous implementation: ``MAVLink.parse_buffer`` with robust parsing,
keeping only messages that are not BAD_DATA and whose frame starts with the MAVLink 2 magic, and
counting everything else as a dropped frame. Messages are compared attribute by attribute
(``vars``), NaN-aware, including header, raw frame, payload and CRC.
"""

from __future__ import annotations

import itertools
import math
import struct
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as m

from companion.mavlink import codec as codec_mod
from companion.mavlink.codec import Codec

SETTINGS = settings(max_examples=60, deadline=None)

NAMED = [
    m.MAVLink_heartbeat_message, m.MAVLink_sys_status_message,
    m.MAVLink_local_position_ned_message, m.MAVLink_attitude_quaternion_message,
    m.MAVLink_attitude_message, m.MAVLink_odometry_message,
    m.MAVLink_global_position_int_message, m.MAVLink_command_ack_message,
    m.MAVLink_command_long_message, m.MAVLink_statustext_message,
    m.MAVLink_mission_count_message, m.MAVLink_mission_request_int_message,
    m.MAVLink_mission_item_int_message, m.MAVLink_mission_ack_message,
    m.MAVLink_mission_current_message, m.MAVLink_mission_item_reached_message,
    m.MAVLink_mission_clear_all_message, m.MAVLink_mission_request_list_message,
    m.MAVLink_timesync_message, m.MAVLink_extended_sys_state_message,
    m.MAVLink_home_position_message, m.MAVLink_set_position_target_local_ned_message,
    m.MAVLink_set_attitude_target_message, m.MAVLink_param_value_message,
    m.MAVLink_battery_status_message, m.MAVLink_autopilot_version_message,
]

_INT_RANGES = {
    "uint8_t": (0, 2**8 - 1), "int8_t": (-(2**7), 2**7 - 1),
    "uint16_t": (0, 2**16 - 1), "int16_t": (-(2**15), 2**15 - 1),
    "uint32_t": (0, 2**32 - 1), "int32_t": (-(2**31), 2**31 - 1),
    "uint64_t": (0, 2**64 - 1), "int64_t": (-(2**63), 2**63 - 1),
}


def _scalar(ftype: str) -> st.SearchStrategy[Any]:
    if ftype == "float":
        return st.floats(width=32)  # NaN and inf included
    if ftype == "double":
        return st.floats()
    lo, hi = _INT_RANGES[ftype]
    return st.integers(lo, hi)


@st.composite
def message(draw: st.DrawFn, classes: list[Any] = NAMED) -> Any:
    """A pymavlink message object of a random type with random field values."""
    cls = draw(st.sampled_from(classes))
    types = dict(zip(cls.fieldnames, cls.fieldtypes, strict=True))
    lengths = dict(zip(cls.ordered_fieldnames, cls.array_lengths, strict=True))
    kwargs: dict[str, Any] = {}
    for name in cls.fieldnames:
        n = lengths[name]
        if types[name] == "char":
            kwargs[name] = draw(st.binary(max_size=n))
        elif n:
            kwargs[name] = draw(st.lists(_scalar(types[name]), min_size=n, max_size=n))
        else:
            kwargs[name] = draw(_scalar(types[name]))
    return cls(**kwargs)


def pack(msg: Any, seq: int = 0, sysid: int = 1, compid: int = 1, v1: bool = False) -> bytes:
    mav = m.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    mav.seq = seq
    return bytes(msg.pack(mav, force_mavlink1=v1))


class Oracle:
    """The previous ``Codec.decode``: pymavlink's parser, MAVLink 2 only."""

    def __init__(self) -> None:
        self.mav = m.MAVLink(None)
        self.mav.robust_parsing = True
        self.dropped_frames = 0

    def decode(self, data: bytes) -> list[Any]:
        out = []
        for msg in self.mav.parse_buffer(data) or []:
            if msg.get_type() == "BAD_DATA" or msg.get_msgbuf()[0] != 0xFD:
                self.dropped_frames += 1
            else:
                out.append(msg)
        return out


def same_value(a: Any, b: Any) -> bool:
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    if isinstance(a, list | tuple):
        return (type(a) is type(b) and len(a) == len(b)
                and all(same_value(x, y) for x, y in zip(a, b, strict=True)))
    if isinstance(a, m.MAVLink_header):
        return isinstance(b, m.MAVLink_header) and vars(a) == vars(b)
    return type(a) is type(b) and a == b


def assert_same(fast: list[Any], ref: list[Any]) -> None:
    assert [x.get_type() for x in fast] == [x.get_type() for x in ref]
    for a, b in zip(fast, ref, strict=True):
        assert type(a) is type(b)
        va, vb = vars(a), vars(b)
        assert va.keys() == vb.keys()
        for key in va:
            assert same_value(va[key], vb[key]), (a.get_type(), key, va[key], vb[key])
        assert (a.get_msgId(), a.get_srcSystem(), a.get_srcComponent(), a.get_seq()) == (
            b.get_msgId(), b.get_srcSystem(), b.get_srcComponent(), b.get_seq())


def both(chunks: list[bytes]) -> tuple[Codec, Oracle, list[Any], list[Any]]:
    c, o = Codec(), Oracle()
    fast: list[Any] = []
    ref: list[Any] = []
    for chunk in chunks:
        fast += c.decode(chunk)
        ref += o.decode(chunk)
    return c, o, fast, ref


@pytest.fixture
def no_slow_path(monkeypatch: pytest.MonkeyPatch) -> None:
    """Make pymavlink's parser unusable inside Codec so a test proves the fast path ran."""
    def boom(self: Any, *args: Any) -> Any:
        raise AssertionError("pymavlink parser used")
    monkeypatch.setattr(m.MAVLink, "decode", boom)
    monkeypatch.setattr(m.MAVLink, "parse_buffer", boom)


# -- CRC ------------------------------------------------------------------------------------------
@SETTINGS
@given(st.binary(max_size=300), st.integers(0, 0xFFFF))
def test_crc_matches_pymavlink_pure_python(data: bytes, init: int) -> None:
    ref = m._x25crc_slow()
    ref.crc = init
    ref.accumulate(data)
    assert codec_mod._crc_mcrf4xx(data, init) == ref.crc
    assert codec_mod._crc_mcrf4xx_stdlib(data, init) == ref.crc


# -- exactness on valid messages ----------------------------------------------------------------
@SETTINGS
@given(message(), st.integers(0, 255), st.integers(1, 255), st.integers(0, 255))
def test_fast_path_equals_pymavlink(msg: Any, seq: int, sysid: int, compid: int) -> None:
    frame = pack(msg, seq, sysid, compid)
    c, o, fast, ref = both([frame])
    assert len(ref) == 1
    assert_same(fast, ref)
    assert c.dropped_frames == o.dropped_frames == 0


def test_named_types_take_the_fast_path(no_slow_path: None) -> None:
    """Every named type decodes without pymavlink's parser, with the encoder's field values."""
    for cls in NAMED:
        frame = pack(_zero_message(cls), 7, 3, 4)
        (msg,) = Codec().decode(frame)
        assert msg.get_type() == cls.msgname
        assert (msg.get_seq(), msg.get_srcSystem(), msg.get_srcComponent()) == (7, 3, 4)


def _zero_message(cls: Any) -> Any:
    lengths = dict(zip(cls.ordered_fieldnames, cls.array_lengths, strict=True))
    types = dict(zip(cls.fieldnames, cls.fieldtypes, strict=True))
    kwargs: dict[str, Any] = {}
    for i, name in enumerate(cls.fieldnames):
        if types[name] == "char":
            kwargs[name] = b"abc"[: lengths[name]]
        elif lengths[name]:
            kwargs[name] = [i + k for k in range(lengths[name])]
        else:
            kwargs[name] = i + 1
    return cls(**kwargs)


def test_known_values_round_trip(no_slow_path: None) -> None:
    """Field values come back as the sender set them (independent of pymavlink's decoder)."""
    q = [0.5, -0.5, 0.5, -0.5]
    msgs = [
        m.MAVLink_local_position_ned_message(1234, 1.5, -2.25, -5.0, 0.125, 0.0, -1.0),
        m.MAVLink_attitude_quaternion_message(99, *q, 0.1, 0.2, 0.3, [1.0, 0.0, 0.0, 0.0]),
        m.MAVLink_statustext_message(4, b"Takeoff detected", 0, 0),
        m.MAVLink_heartbeat_message(2, 12, 157, 393216, 4, 3),
    ]
    out = Codec().decode(b"".join(pack(x, k) for k, x in enumerate(msgs)))
    assert [x.get_type() for x in out] == [
        "LOCAL_POSITION_NED", "ATTITUDE_QUATERNION", "STATUSTEXT", "HEARTBEAT"]
    lp, aq, txt, hb = out
    assert (lp.time_boot_ms, lp.x, lp.y, lp.z) == (1234, 1.5, -2.25, -5.0)
    assert (lp.vx, lp.vy, lp.vz) == (0.125, 0.0, -1.0)
    assert [aq.q1, aq.q2, aq.q3, aq.q4] == q and aq.repr_offset_q == [1.0, 0.0, 0.0, 0.0]
    assert math.isclose(aq.yawspeed, 0.3, rel_tol=1e-6)
    assert txt.text == "Takeoff detected" and txt.severity == 4
    assert (hb.custom_mode, hb.base_mode, hb.system_status) == (393216, 157, 4)
    assert [x.get_seq() for x in out] == [0, 1, 2, 3]


# -- every message type, truncated and over-long payloads ------------------------------------------
def frame_v2(msg_id: int, payload: bytes, crc_extra: int, seq: int = 0, sysid: int = 1,
             compid: int = 1, incompat: int = 0, compat: int = 0, signature: bytes = b"") -> bytes:
    """MAVLink 2 frame written from the spec (CRC by pymavlink's pure-Python X.25)."""
    header = struct.pack("<BBBBBBBHB", 0xFD, len(payload), incompat, compat, seq, sysid, compid,
                         msg_id & 0xFFFF, msg_id >> 16)
    crc = m._x25crc_slow(header[1:] + payload + bytes([crc_extra])).crc
    return header + payload + struct.pack("<H", crc) + signature


@SETTINGS
@given(st.sampled_from(sorted(m.mavlink_map)), st.data())
def test_every_type_random_payload(msg_id: int, data: st.DataObject) -> None:
    cls = m.mavlink_map[msg_id]
    size = cls.unpacker.size
    payload = data.draw(st.binary(max_size=min(255, size + 8)))
    frame = frame_v2(msg_id, payload, cls.crc_extra, data.draw(st.integers(0, 255)),
                     compat=data.draw(st.integers(0, 255)))
    c, o, fast, ref = both([frame])
    assert_same(fast, ref)
    assert c.dropped_frames == o.dropped_frames


def test_all_types_zero_length_payload(no_slow_path: None) -> None:
    """A MAVLink 2 payload truncated to nothing decodes as all zeros for every known type."""
    for msg_id, cls in m.mavlink_map.items():
        (msg,) = Codec().decode(frame_v2(msg_id, b"", cls.crc_extra))
        assert msg.get_type() == cls.msgname
        for name in cls.fieldnames:
            v = getattr(msg, name)
            assert v in (0, "", b"") or (isinstance(v, list) and not any(v)), (cls.msgname, name)


# -- rejection, fragmentation, concatenation ----------------------------------------------------
def test_rejections() -> None:
    good = pack(m.MAVLink_timesync_message(5, 6), 1)
    bad_crc = good[:-1] + bytes([good[-1] ^ 0x01])
    v1 = pack(m.MAVLink_heartbeat_message(2, 12, 0, 0, 4, 3), v1=True)
    bad_flags = bytearray(good)
    bad_flags[2] = 0x02
    for data in (bad_crc, v1, bytes(bad_flags), b"\x01\x02\x03garbage"):
        c = Codec()
        assert c.decode(data) == []
        assert c.dropped_frames == 1
    c = Codec()
    assert c.decode(good[:-3]) == [] and c.dropped_frames == 0  # incomplete: kept
    (msg,) = c.decode(good[-3:])
    assert (msg.tc1, msg.ts1) == (5, 6)


def test_signed_and_unknown_frames_like_pymavlink() -> None:
    mav = m.MAVLink(None, srcSystem=1, srcComponent=1)
    mav.signing.secret_key = bytes(range(32))
    mav.signing.sign_outgoing = True
    signed = bytes(m.MAVLink_attitude_message(1, 0.1, 0.2, 0.3, 0, 0, 0).pack(mav))
    unknown = frame_v2(60001, b"\x01\x02\x03", 0)
    c, o, fast, ref = both([signed + unknown])
    assert [x.get_type() for x in fast] == ["ATTITUDE", "UNKNOWN_60001"]
    assert fast[0].get_signed() is False  # no key configured: accepted unverified, as pymavlink
    assert_same(fast, ref)
    assert c.dropped_frames == o.dropped_frames == 0


def _fragments() -> st.SearchStrategy[bytes]:
    valid = message().map(pack)
    v1 = st.sampled_from([m.MAVLink_heartbeat_message(2, 12, 0, 0, 4, 3),
                          m.MAVLink_attitude_message(1, 0.1, 0.2, 0.3, 0, 0, 0)]).map(
        lambda x: pack(x, v1=True))
    corrupt = st.tuples(message().map(pack), st.data()).map(
        lambda fd: _flip(fd[0], fd[1].draw(st.integers(1, len(fd[0]) - 1))))
    truncated = st.tuples(message().map(pack), st.data()).map(
        lambda fd: fd[0][: fd[1].draw(st.integers(0, len(fd[0]) - 1))])
    garbage = st.binary(min_size=1, max_size=40)
    return st.one_of(valid, valid, valid, v1, corrupt, truncated, garbage)


def _flip(frame: bytes, k: int) -> bytes:
    b = bytearray(frame)
    b[k] ^= 0x5A
    return bytes(b)


@settings(max_examples=80, deadline=None)
@given(st.lists(_fragments(), max_size=12), st.lists(st.integers(0, 4000), max_size=8))
def test_streams_match_pymavlink(parts: list[bytes], cuts: list[int]) -> None:
    """Valid, MAVLink 1, corrupted, truncated frames and garbage, concatenated and re-split at
    random points: same messages, same order, same drop count, same leftover handling."""
    stream = b"".join(parts)
    bounds = sorted({min(x, len(stream)) for x in cuts} | {0, len(stream)})
    chunks = [stream[a:b] for a, b in itertools.pairwise(bounds)]
    c, o, fast, ref = both(chunks)
    assert_same(fast, ref)
    assert c.dropped_frames == o.dropped_frames
    whole_c, whole_o, whole_fast, whole_ref = both([stream])  # one datagram
    assert_same(whole_fast, whole_ref)
    assert whole_c.dropped_frames == whole_o.dropped_frames
    assert_same(whole_fast, fast)


def test_several_frames_in_one_datagram(no_slow_path: None) -> None:
    msgs = [_zero_message(cls) for cls in NAMED]
    data = b"".join(pack(x, k) for k, x in enumerate(msgs))
    out = Codec().decode(data)
    assert [x.get_type() for x in out] == [cls.msgname for cls in NAMED]
    assert [x.get_seq() for x in out] == list(range(len(NAMED)))


def test_codec_with_a_signer_refuses_unsigned_and_accepts_pymavlink_signed_frames() -> None:
    """With a signer on the codec, a frame pymavlink signed with the key is decoded as pymavlink
    (holding the key) decodes it; the unsigned frame after it is refused."""
    from companion.mavlink import Signer, SigningConfig

    key = bytes(range(32))
    tx = m.MAVLink(None, srcSystem=1, srcComponent=1)
    tx.signing.secret_key = key
    tx.signing.sign_outgoing = True
    tx.signing.timestamp = 10**12
    signed = bytes(m.MAVLink_timesync_message(1, 2).pack(tx))
    unsigned = pack(m.MAVLink_timesync_message(3, 4))
    c, o = Codec(signer=Signer(SigningConfig(key))), Oracle()
    o.mav.signing.secret_key = key
    fast = c.decode(signed + unsigned)
    ref = o.decode(signed + unsigned)
    assert [x.tc1 for x in fast] == [1] and fast[0].get_signed() is True
    assert_same(fast, ref)
    assert c.rejected_frames == o.dropped_frames == 1 and c.dropped_frames == 0


# -- encode ---------------------------------------------------------------------------------------
ALL_CLASSES = [m.mavlink_map[k] for k in sorted(m.mavlink_map)]


@settings(max_examples=150, deadline=None)
@given(message(ALL_CLASSES), st.integers(0, 255), st.integers(1, 255), st.integers(0, 255))
def test_encode_is_byte_identical_to_pymavlink(msg: Any, seq: int, sysid: int,
                                               compid: int) -> None:
    c = Codec(sysid, compid)
    c.mav.seq = seq
    ours = c.encode(msg)
    assert ours == pack(msg, seq, sysid, compid)
    assert c.mav.seq == (seq + 1) % 256
    (back,) = Codec().decode(ours)
    assert back.get_type() == msg.get_type() and back.get_seq() == seq


def test_encode_sequence_increments_wraps_and_is_thread_safe() -> None:
    import threading

    c = Codec()
    hb = m.MAVLink_heartbeat_message(18, 8, 0, 0, 4, 3)
    seqs: list[int] = []
    lock = threading.Lock()

    def worker() -> None:
        for _ in range(300):
            f = c.encode(hb)
            with lock:
                seqs.append(f[4])

    threads = [threading.Thread(target=worker) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(10)
    assert sorted(seqs) == sorted(k % 256 for k in range(600))  # each value handed out once
    assert [c.encode(hb)[4] for _ in range(3)] == [600 % 256, 601 % 256, 602 % 256]


def test_signed_encode_matches_pymavlink_signing_byte_for_byte() -> None:
    """Same key, ids, sequence number and timestamp: our signed frame is pymavlink's."""
    from companion.mavlink import Signer, SigningConfig

    key = bytes(range(32))
    signer = Signer(SigningConfig(key, link_id=7))
    signer.advance_clock(1_420_070_400 + 1.23456)  # 123456 ticks: ours signs with the next one
    c = Codec(1, 191, signer)
    ref = m.MAVLink(None, srcSystem=1, srcComponent=191)
    ref.signing.secret_key = key
    ref.signing.sign_outgoing = True
    ref.signing.link_id = 7
    ref.signing.timestamp = 123457
    msg = m.MAVLink_set_attitude_target_message(5, 1, 1, 3, [1, 0, 0, 0], 0, 0, 0.2, 0.5)
    assert c.encode(msg) == bytes(msg.pack(ref))
    rx = Oracle()
    rx.mav.signing.secret_key = key
    (back,) = rx.decode(c.encode(msg))
    assert back.get_signed() and back.get_seq() == 1
