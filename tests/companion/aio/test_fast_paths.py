"""The tlog writer's fast path equals its general path: `TlogWriter` with a large buffer writes
the same bytes as with the default one, and pymavlink reads them back."""

from __future__ import annotations

from pathlib import Path

from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2

from companion.aio.tlog import TlogWriter


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
