"""bench/estimate_lead.py against tlogs written here with a known lead: a vehicle circling at
4 m/s (and a straight run at 2 m/s) whose GLOBAL_POSITION_INT is its true position moved along
its velocity by `lead` seconds of travel, both streams at 50 Hz with their own receive times;
the estimate's own lat/lon resolution (1e-7 deg, 1.1 cm) is the only error."""

from __future__ import annotations

import math
import struct
import sys
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as mavlink

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))

from estimate_lead import lead

LAT0, LON0 = 47.397742, 8.545594
R = 6371000.0


def _geo(n: float, e: float) -> tuple[int, int]:
    lat = LAT0 + math.degrees(n / R)
    lon = LON0 + math.degrees(e / (R * math.cos(math.radians(LAT0))))
    return round(lat * 1e7), round(lon * 1e7)


def _tlog(path: Path, lead_s: float, seconds: float = 30.0) -> None:
    """A tlog (8-byte big-endian microsecond stamp before each frame, as MAVProxy and the
    companion write them): 16 m circle at 4 m/s, then 10 s straight north at 2 m/s."""
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    frames = []
    for k in range(round(seconds / 0.02)):
        t = k * 0.02
        if t < 20.0:
            w = 4.0 / 16.0
            n, e = 16.0 * math.sin(w * t), 16.0 * (1.0 - math.cos(w * t))
            vn, ve = 4.0 * math.cos(w * t), 4.0 * math.sin(w * t)
        else:
            n, e, vn, ve = 2.0 * (t - 20.0), 32.0, 2.0, 0.0
        lat, lon = _geo(n, e)
        hil = mavlink.MAVLink_hil_state_quaternion_message(
            0, (1.0, 0.0, 0.0, 0.0), 0, 0, 0, lat, lon, 0, round(vn * 100), round(ve * 100), 0,
            0, 0, 0, 0, 0)
        elat, elon = _geo(n + lead_s * vn, e + lead_s * ve)
        gpi = mavlink.MAVLink_global_position_int_message(
            round(t * 1000), elat, elon, 0, 0, round(vn * 100), round(ve * 100), 0, 0)
        frames.append((1e6 * (100.0 + t + 0.003), gpi.pack(mav)))
        frames.append((1e6 * (100.0 + t + 0.011), hil.pack(mav)))
    frames.sort(key=lambda f: f[0])
    path.write_bytes(b"".join(struct.pack(">Q", int(us)) + data for us, data in frames))


@pytest.mark.parametrize("lead_s", [0.0, 0.11, -0.05])
def test_the_lead_written_is_the_lead_read(tmp_path: Path, lead_s: float) -> None:
    path = tmp_path / "flight.tlog"
    _tlog(path, lead_s)
    r = lead(path)
    # each truth sample arrives 8 ms after the estimate of its instant: on the receive clock the
    # estimate it is compared with is 8 ms newer, 8 ms more of lead
    assert r["lead_s"] == pytest.approx(lead_s + 0.008, abs=0.004)
    assert r["lead_s 1-3 m/s"] == pytest.approx(lead_s + 0.008, abs=0.006)
    assert r["lead_s 3-5 m/s"] == pytest.approx(lead_s + 0.008, abs=0.004)
    assert r["samples"] > 1000
