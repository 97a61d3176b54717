"""Datagram links are parsed one datagram at a time: a stray or corrupt datagram costs nothing
but itself. Byte streams (TCP, serial) keep pymavlink's carry-over of a partial frame."""

from __future__ import annotations

import asyncio
import socket

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as m

from companion.aio.transports import UdpTransport, parse_url
from companion.mavlink.codec import Codec


def _heartbeats(n: int) -> list[bytes]:
    mav = m.MAVLink(None, srcSystem=1, srcComponent=1)
    out = []
    for seq in range(n):
        mav.seq = seq
        out.append(bytes(m.MAVLink_heartbeat_message(2, 12, 29, 50593792, 3, 3).pack(mav)))
    return out


def test_stray_two_byte_datagram_loses_no_following_frame() -> None:
    frames = _heartbeats(30)
    codec = Codec()
    got = codec.decode(b"\xfd\x05", datagram=True)
    for f in frames:
        got += codec.decode(f, datagram=True)
    assert [msg.get_seq() for msg in got] == list(range(30))
    assert codec.dropped_frames == 1


def test_stream_parsing_still_joins_a_frame_split_over_two_reads() -> None:
    frame = _heartbeats(1)[0]
    codec = Codec()
    assert codec.decode(frame[:5]) == []
    assert [msg.get_type() for msg in codec.decode(frame[5:])] == ["HEARTBEAT"]


def test_header_running_past_the_datagram_does_not_hide_the_frame_after_it() -> None:
    frame = _heartbeats(1)[0]
    codec = Codec()
    got = codec.decode(b"\xfd\xff\x00" + frame, datagram=True)
    assert [msg.get_type() for msg in got] == ["HEARTBEAT"]


@settings(max_examples=200, deadline=None)
@given(junk=st.lists(st.binary(max_size=40), max_size=5))
def test_any_junk_datagrams_between_frames_leave_every_frame_decodable(junk: list[bytes]) -> None:
    frames = _heartbeats(len(junk) + 1)
    codec = Codec()
    got = []
    for j, f in zip([*junk, b""], frames, strict=True):
        if j:
            codec.decode(j, datagram=True)
        got += codec.decode(f, datagram=True)
    assert len(got) == len(frames)


async def test_udp_transport_delivers_whole_datagrams_marked_as_such() -> None:
    loop = asyncio.get_running_loop()
    tr = UdpTransport(parse_url("udpin://127.0.0.1:0"), loop)
    sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        assert tr.datagrams
        frames = _heartbeats(30)
        sender.sendto(b"\xfd\x05", tr.local_address)
        for f in frames:
            sender.sendto(f, tr.local_address)
        codec = Codec()
        got = []
        for _ in range(31):
            data = await asyncio.wait_for(tr.recv(), 5.0)
            got += codec.decode(data, datagram=tr.datagrams)
        assert len(got) == 30
    finally:
        sender.close()
        tr.close()


@pytest.mark.parametrize(
    "url", ["udpin://0.0.0.0:99999", "udpout://127.0.0.1:65536", "tcp://127.0.0.1:0"]
)
def test_port_out_of_range_is_a_value_error(url: str) -> None:
    with pytest.raises(ValueError, match="out of range"):
        parse_url(url)
