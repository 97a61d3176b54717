"""sitl_mock.mavwire's fast decoder and encoder against pymavlink (the oracle).

Decoder: random payloads of every common-dialect message, framed with pymavlink's own X.25
CRC, must decode to the same message objects as `MAVLink.parse_buffer`; anything pymavlink
would report as bad (or MAVLink 1, signed, unknown ids) must be left to pymavlink (None), and
the autopilot's counters must equal what pymavlink's parse says. Encoder: frames from field
values and every datagram the mock actually sends equal pymavlink's `pack`.
"""

from __future__ import annotations

import math
import struct
from typing import Any

from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as mavlink
from pymavlink.generator.mavcrc import x25crc

from sitl_mock.autopilot import Autopilot, telemetry
from sitl_mock.mavwire import codec, decode_datagram, pack_v2

IDS = sorted(mavlink.mavlink_map)
API = ("127.0.0.1", 14540)
GCS = ("127.0.0.1", 14550)


def _frame(
    msg_id: int, payload: bytes, seq: int, sysid: int, compid: int, compat: int, incompat: int = 0
) -> bytes:
    """A MAVLink 2 frame assembled by hand, CRC from pymavlink's x25crc."""
    header = bytes(
        (len(payload), incompat, compat, seq, sysid, compid, msg_id & 0xFF, (msg_id >> 8) & 0xFF)
    ) + bytes((msg_id >> 16,))
    crc = x25crc(header + payload)
    crc.accumulate(bytes((mavlink.mavlink_map[msg_id].crc_extra,)))
    return b"\xfd" + header + payload + struct.pack("<H", crc.crc)


@st.composite
def frames(draw: st.DrawFn, allow_long: bool = False, flags: bool = False) -> bytes:
    """One well-formed frame of a random message; with `flags`, maybe signed or flagged."""
    msg_id = draw(st.sampled_from(IDS))
    size = mavlink.mavlink_map[msg_id].unpacker.size
    hi = min(255, size + 3) if allow_long else size
    payload = draw(st.binary(min_size=0, max_size=hi))
    if draw(st.booleans()):  # senders truncate trailing zeros: exercise zero-extension
        payload = payload.rstrip(b"\x00") or b"\x00"
    incompat = draw(st.sampled_from((0, 0, 0, 0, 1, 2))) if flags else 0
    signature = draw(st.binary(min_size=13, max_size=13)) if incompat & 1 else b""
    return (
        _frame(
            msg_id,
            payload,
            draw(st.integers(0, 255)),
            draw(st.integers(0, 255)),
            draw(st.integers(0, 255)),
            draw(st.sampled_from((0, 0, 0, 1))),
            incompat,
        )
        + signature
    )


def _pymavlink(data: bytes) -> list[Any]:
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    return parser.parse_buffer(data) or []


def _same_value(a: Any, b: Any) -> bool:
    if isinstance(a, float) and isinstance(b, float):
        return (math.isnan(a) and math.isnan(b)) or a == b
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same_value(x, y) for x, y in zip(a, b, strict=True))
    return type(a) is type(b) and a == b


def _assert_same_message(fast: Any, ref: Any) -> None:
    assert type(fast) is type(ref)
    assert fast.get_type() == ref.get_type() and fast.get_msgId() == ref.get_msgId()
    assert fast.get_srcSystem() == ref.get_srcSystem()
    assert fast.get_srcComponent() == ref.get_srcComponent()
    assert fast.get_seq() == ref.get_seq()
    assert vars(fast.get_header()) == vars(ref.get_header())
    assert fast.get_msgbuf() == ref.get_msgbuf() and type(fast.get_msgbuf()) is bytearray
    assert fast.get_payload() == ref.get_payload() and fast.get_crc() == ref.get_crc()
    assert set(vars(fast)) == set(vars(ref))
    for name, value in vars(ref).items():
        if name != "_header":
            assert _same_value(getattr(fast, name), value), name


@settings(max_examples=300, deadline=None)
@given(st.lists(frames(flags=True), min_size=1, max_size=3))
def test_decoder_matches_pymavlink_on_random_frames_of_every_message(parts: list[bytes]) -> None:
    data = b"".join(parts)
    ref = _pymavlink(data)
    fast = decode_datagram(data)
    if any(p[2] for p in parts):  # signed (pymavlink has no key: accepts) or unknown flags
        assert fast is None
        return
    if any(m.get_type() == "BAD_DATA" for m in ref):
        assert fast is None  # e.g. a char field pymavlink cannot decode: left to pymavlink
        return
    assert fast is not None and len(fast) == len(ref) == len(parts)
    for f, r in zip(fast, ref, strict=True):
        _assert_same_message(f, r)


@settings(max_examples=60, deadline=None)
@given(frames(allow_long=True))
def test_payload_longer_than_the_message_is_left_to_pymavlink(frame: bytes) -> None:
    size = mavlink.mavlink_map[frame[7] | frame[8] << 8 | frame[9] << 16].unpacker.size
    fast = decode_datagram(frame)
    if frame[1] > size:
        assert fast is None
    elif fast is not None:
        _assert_same_message(fast[0], _pymavlink(frame)[0])


def _msg_frame(msg: Any, seq: int = 0) -> bytes:
    mav = mavlink.MAVLink(None, 255, 190)
    mav.seq = seq
    return bytes(msg.pack(mav))


HB = mavlink.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3)


def test_unusual_frames_are_left_to_pymavlink() -> None:
    good = _msg_frame(HB)
    assert decode_datagram(b"") == []
    assert decode_datagram(good) is not None
    bad_crc = good[:-1] + bytes((good[-1] ^ 1,))
    flipped = good[:12] + bytes((good[12] ^ 0x40,)) + good[13:]
    mav1 = mavlink.MAVLink(None, 255, 190)
    v1 = bytes(HB.pack(mav1, force_mavlink1=True))
    signed = bytearray(good)
    signed[2] = mavlink.MAVLINK_IFLAG_SIGNED
    raw = bytearray(good)
    raw[7:10] = bytes((0xDE, 0xBC, 0x0A))  # id 0x0ABCDE: not in the dialect
    for data in (
        bad_crc,
        flipped,
        v1,
        bytes(signed) + bytes(13),
        bytes(raw),
        good[:-3],  # truncated
        b"junk" + good,
        good + b"junk",
        good + good[:5],
        b"\xfd",
    ):
        assert decode_datagram(data) is None, data


@st.composite
def messy_datagrams(draw: st.DrawFn) -> bytes:
    """Valid, corrupted, truncated and MAVLink 1 frames plus garbage, concatenated."""
    parts = []
    for _ in range(draw(st.integers(1, 4))):
        kind = draw(st.sampled_from(("good", "good", "crc", "v1", "garbage", "cut")))
        if kind == "garbage":
            parts.append(draw(st.binary(min_size=1, max_size=12)))
            continue
        f = bytearray(draw(frames(flags=True)))
        if kind == "crc":
            f[-1] ^= 1 + draw(st.integers(0, 254))
        elif kind == "v1":
            msg = mavlink.MAVLink_heartbeat_message(*draw(st.tuples(*[st.integers(0, 9)] * 6)))
            f = bytearray(msg.pack(mavlink.MAVLink(None, 255, 190), force_mavlink1=True))
        elif kind == "cut":
            f = f[: draw(st.integers(1, len(f) - 1))]
        parts.append(bytes(f))
    return b"".join(parts)


def _expected_counts(data: bytes) -> dict[str, int]:
    """What the autopilot counted before the fast path: pymavlink's robust parse."""
    try:
        msgs = _pymavlink(data)
    except Exception:
        return {"rx_bad_data": 1, "rx_mavlink1": 0, "rx_messages": 0}
    bad = sum(m.get_type() == "BAD_DATA" for m in msgs)
    v1 = sum(m.get_type() != "BAD_DATA" and m.get_msgbuf()[:1] != b"\xfd" for m in msgs)
    return {"rx_bad_data": bad, "rx_mavlink1": v1, "rx_messages": len(msgs) - bad - v1}


@settings(max_examples=60, deadline=None)
@given(st.lists(messy_datagrams(), min_size=1, max_size=3))
def test_autopilot_counts_garbage_and_frames_exactly_like_pymavlink(
    datagrams: list[bytes],
) -> None:
    ap = Autopilot(remotes={"offboard": API}, now=0.0)
    expected = {"rx_bad_data": 0, "rx_mavlink1": 0, "rx_messages": 0}
    for i, data in enumerate(datagrams):
        for k, v in _expected_counts(data).items():
            expected[k] += v
        ap.receive_datagram(data, API, 0.01 * (i + 1))
    assert {k: ap.stats[k] for k in expected} == expected
    assert ap.stats["rx_datagrams"] == len(datagrams)


def test_several_frames_in_one_datagram_are_all_handled() -> None:
    ap = Autopilot(remotes={"offboard": API}, now=0.0)
    ping = mavlink.MAVLink_ping_message(123, 7, 0, 0)
    data = _msg_frame(HB, 1) + _msg_frame(ping, 2) + _msg_frame(HB, 3)
    ap.receive_datagram(data, API, 0.001)
    assert ap.stats["rx_heartbeat"] == 2 and ap.stats["rx_messages"] == 3
    replies = [m for d, _a in ap.datagrams_to_send(0.001) for m in _pymavlink(d)]
    pongs = [m for m in replies if m.get_type() == "PING"]
    assert len(pongs) == 1 and pongs[0].seq == 7 and pongs[0].target_system == 255
    assert pongs[0].target_component == 190


# ------------------------------------------------------------------------------ encoder
_INT_RANGES = {
    "uint8_t": (0, 2**8 - 1),
    "int8_t": (-(2**7), 2**7 - 1),
    "uint16_t": (0, 2**16 - 1),
    "int16_t": (-(2**15), 2**15 - 1),
    "uint32_t": (0, 2**32 - 1),
    "int32_t": (-(2**31), 2**31 - 1),
    "uint64_t": (0, 2**64 - 1),
    "int64_t": (-(2**63), 2**63 - 1),
}


def _value(ftype: str, n: int) -> st.SearchStrategy[Any]:
    if ftype == "char":
        return st.binary(max_size=max(n, 1)).map(lambda b: b.replace(b"\x00", b"a"))
    if ftype in ("float", "double"):
        one: st.SearchStrategy[Any] = st.floats(width=32 if ftype == "float" else 64)
    else:
        lo, hi = _INT_RANGES[ftype.replace("_mavlink_version", "")]
        one = st.integers(lo, hi)
    return st.lists(one, min_size=n, max_size=n) if n else one


@st.composite
def messages(draw: st.DrawFn, classes: list[type]) -> tuple[type, tuple[Any, ...]]:
    cls: Any = draw(st.sampled_from(classes))
    lengths = dict(zip(cls.ordered_fieldnames, cls.array_lengths, strict=True))
    vals = tuple(
        draw(_value(t, lengths[name]))
        for name, t in zip(cls.fieldnames, cls.fieldtypes, strict=True)
    )
    return cls, vals


ALL_CLASSES = [mavlink.mavlink_map[i] for i in IDS]


@settings(max_examples=200, deadline=None)
@given(messages(ALL_CLASSES), st.integers(0, 255), st.integers(0, 255), st.integers(0, 255))
def test_encoder_matches_pymavlink_pack_for_random_messages(
    cm: tuple[Any, tuple[Any, ...]], seq: int, sysid: int, compid: int
) -> None:
    cls, vals = cm
    msg = cls(*vals)
    mav = mavlink.MAVLink(None, sysid, compid)
    mav.seq = seq
    ref = bytes(msg.pack(mav))
    if not any(t == "char" for t in cls.fieldtypes):  # (codec, fields) pairs: no text fields
        assert codec(cls).frame(seq, sysid, compid, vals) == ref
    if all(not isinstance(v, bytes) or v.isascii() for v in vals):  # str round trip is lossy
        assert pack_v2(msg, seq, sysid, compid) == ref


def test_every_datagram_the_mock_sends_is_what_pymavlink_would_pack() -> None:
    """A flight on two links through every telemetry builder; each frame re-packed by pymavlink."""
    ap = Autopilot(remotes={"offboard": API, "gcs": GCS}, now=0.0, seed=2)
    client = mavlink.MAVLink(None, 255, 190)
    script = {
        1.0: [mavlink.MAVLink_param_request_read_message(1, 1, b"MPC_XY_CRUISE", -1)],
        3.5: [mavlink.MAVLink_command_long_message(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)],
        3.6: [
            mavlink.MAVLink_command_long_message(
                1, 1, 22, 0, math.nan, 0, 0, math.nan, math.nan, math.nan, 495.0
            )
        ],
        4.0: [
            mavlink.MAVLink_command_long_message(1, 1, 512, 0, i, 0, 0, 0, 0, 0, 0)
            for i in (148, 242, 245, 24, 74, 115)
        ],
        4.1: [mavlink.MAVLink_timesync_message(0, 77), mavlink.MAVLink_ping_message(9, 3, 0, 0)],
    }
    seen: set[int] = set()
    n = 0
    t = 0.0
    while t < 14.0:
        t = round(t + 0.02, 6)
        ap.advance(t)
        for m in script.pop(min(script), []) if script and min(script) <= t else []:
            ap.receive_datagram(m.pack(client), API, t)
        if t >= 9.0:  # offboard attitude setpoints: ATTITUDE_TARGET echoes them
            sp = mavlink.MAVLink_set_attitude_target_message(
                0, 1, 1, 7, [1.0, 0.01, 0.0, 0.0], 0, 0, 0, 0.5
            )
            ap.receive_datagram(sp.pack(client), API, t)
        for data, _addr in ap.datagrams_to_send(t):
            (msg,) = _pymavlink(data)
            assert msg.get_type() != "BAD_DATA"
            mav = mavlink.MAVLink(None, msg.get_srcSystem(), msg.get_srcComponent())
            mav.seq = msg.get_seq()
            assert bytes(msg.pack(mav)) == data, msg.get_type()
            seen.add(msg.get_msgId())
            n += 1
    assert set(telemetry.STREAMABLE) <= seen, set(telemetry.STREAMABLE) - seen
    assert n > 1000
