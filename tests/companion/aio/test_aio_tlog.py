"""The .tlog written by TlogWriter is read back by pymavlink's own reader (independent oracle)."""

from __future__ import annotations

from pathlib import Path

from pymavlink import mavutil
from pymavlink.dialects.v20 import common as m

from companion.aio import TlogWriter
from companion.mavlink import Codec


def test_tlog_round_trip_with_pymavlink(tmp_path: Path) -> None:
    path = tmp_path / "flight.tlog"
    ours = Codec(1, 191)
    px4 = m.MAVLink(None, srcSystem=1, srcComponent=1)
    frames = []
    t0 = 1_700_000_000.0
    with TlogWriter(path) as tlog:
        for k in range(20):
            if k % 2:
                f = bytes(m.MAVLink_heartbeat_message(2, 12, 157, 50593792, 4, 3).pack(px4))
            else:
                f = ours.encode(m.MAVLink_set_position_target_local_ned_message(
                    k, 1, 1, 1, 2552, float(k), 0.0, -5.0, 0, 0, 0, 0, 0, 0, 0.0, 0.0))
            frames.append(f)
            tlog.write(f, unix_time_s=t0 + 0.01 * k)
        assert tlog.frames == 20
    conn = mavutil.mavlink_connection(str(path))
    got = []
    for _ in range(40):
        msg = conn.recv_match()
        if msg is None:
            break
        got.append(msg)
    conn.close()
    assert [g.get_type() for g in got] == [
        "HEARTBEAT" if k % 2 else "SET_POSITION_TARGET_LOCAL_NED" for k in range(20)]
    assert [round(g._timestamp, 3) for g in got] == [round(t0 + 0.01 * k, 3) for k in range(20)]
    assert [bytes(g.get_msgbuf()) for g in got] == frames
    assert got[0].get_srcComponent() == 191 and got[1].get_srcComponent() == 1
    assert [g.x for g in got if g.get_type() != "HEARTBEAT"] == [float(k) for k in range(0, 20, 2)]


def test_tlog_close_is_idempotent_and_write_after_close_ignored(tmp_path: Path) -> None:
    tlog = TlogWriter(tmp_path / "x.tlog")
    tlog.close()
    tlog.write(b"\xfd")
    tlog.close()
    assert (tmp_path / "x.tlog").read_bytes() == b""


def test_write_many_reads_back_like_single_writes(tmp_path: Path) -> None:
    """A batch sharing one timestamp reads back with pymavlink as the same frames, each with that
    timestamp, and the file equals the one written frame by frame."""
    px4 = m.MAVLink(None, srcSystem=1, srcComponent=1)
    frames = [bytes(m.MAVLink_heartbeat_message(2, 12, 157, k, 4, 3).pack(px4)) for k in range(5)]
    t = 1_700_000_123.25
    with TlogWriter(tmp_path / "a.tlog") as a, TlogWriter(tmp_path / "b.tlog") as b:
        a.write_many(frames[:3], t)
        a.write_many([], t + 1.0)  # nothing recorded
        a.write_many(frames[3:], t + 0.5)
        for k, f in enumerate(frames):
            b.write(f, t if k < 3 else t + 0.5)
        assert a.frames == b.frames == 5
    assert (tmp_path / "a.tlog").read_bytes() == (tmp_path / "b.tlog").read_bytes()
    conn = mavutil.mavlink_connection(str(tmp_path / "a.tlog"))
    got = [conn.recv_match() for _ in range(6)]
    conn.close()
    assert got[5] is None
    assert [g.custom_mode for g in got[:5]] == list(range(5))
    assert [g._timestamp for g in got[:5]] == [t, t, t, t + 0.5, t + 0.5]
