"""With 10 % packet loss and 50 ms latency a square mission still passes every waypoint.

`python -m companion fly tests/data/missions/square_15m.plan --connect udpin://...` (default
attitude mode) flies against `sitl_mock serve --loss 10 --latency 0.05` (both directions, so
100 ms round trip). Judged from the mock's GLOBAL_POSITION_INT in the companion's .tlog against
the mission file's own coordinates, read here with `json` and compared with a haversine distance
(independent of the companion's mission loader and projection).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
from pymavlink import mavutil

from tests.support.mock_process import run_companion, run_mock

# flies in wall-clock time (the mock served over a link): README's second test phase
pytestmark = pytest.mark.realtime

MISSION = Path(__file__).parents[1] / "data" / "missions" / "square_15m.plan"
EARTH_RADIUS_M = 6_371_008.8  # IUGG mean radius
NAV_MC_ALT_RAD_M = 0.8  # PX4's vertical acceptance for multicopter waypoints
OFFBOARD = 6


def haversine_m(lat1: float, lon1: float, lat2: float, lon2: float) -> float:
    p1, p2 = math.radians(lat1), math.radians(lat2)
    dp, dl = p2 - p1, math.radians(lon2 - lon1)
    a = math.sin(dp / 2) ** 2 + math.cos(p1) * math.cos(p2) * math.sin(dl / 2) ** 2
    return 2 * EARTH_RADIUS_M * math.asin(math.sqrt(a))


def waypoints(plan: Path) -> list[tuple[float, float, float, float]]:
    """(lat, lon, relative alt [m], acceptance radius [m]) of the file's NAV_WAYPOINTs."""
    items = json.loads(plan.read_text())["mission"]["items"]
    out = []
    for it in items:
        if it["command"] == 16:
            p = it["params"]
            assert it["frame"] == 3  # relative altitude
            out.append((p[4], p[5], p[6], p[1] if p[1] else 2.0))
    return out


async def test_square_mission_with_loss_and_latency_passes_every_waypoint(
    tmp_path: Path,
) -> None:
    tlog = tmp_path / "lossy.tlog"
    async with run_mock(
        "--estimator-ready", "0.5", "--loss", "10", "--latency", "0.05", "--seed", "6"
    ) as mock:
        code, text = await run_companion(
            "fly", str(MISSION),
            "--connect", f"udpin://127.0.0.1:{mock.client_port}", "--log", str(tlog),
            timeout_s=90.0, what="the lossy mission flight")
        assert code == 0, text[-3000:]

    wps = waypoints(MISSION)
    assert len(wps) == 4
    conn = mavutil.mavlink_connection(str(tlog))
    in_offboard = False
    track: list[tuple[float, float, float, float]] = []  # t, lat, lon, relative alt
    received = lost = 0
    last_seq: int | None = None
    for _ in range(2_000_000):
        msg = conn.recv_match()
        if msg is None:
            break
        if msg.get_srcComponent() != 1:
            continue
        received += 1
        seq = msg.get_seq()
        if last_seq is not None:
            lost += (seq - last_seq - 1) % 256  # the mock numbers every frame it sends
        last_seq = seq
        kind = msg.get_type()
        if kind == "HEARTBEAT":
            in_offboard = (msg.custom_mode >> 16) & 0xFF == OFFBOARD
        elif kind == "GLOBAL_POSITION_INT" and in_offboard:
            track.append(
                (msg._timestamp, msg.lat * 1e-7, msg.lon * 1e-7, msg.relative_alt * 1e-3)
            )
    conn.close()
    assert len(track) > 500, len(track)
    # the faults were really on: about 10 % of the mock's frames never arrived
    loss = lost / (lost + received)
    assert 0.07 <= loss <= 0.13, f"measured loss {loss:.3f}"
    # passed in order: each waypoint is looked for after the previous one was passed
    start = 0
    report = []
    for i, (lat, lon, alt, radius) in enumerate(wps):
        best = None
        for k in range(start, len(track)):
            _, la, lo, ra = track[k]
            d = haversine_m(lat, lon, la, lo)
            if abs(ra - alt) <= NAV_MC_ALT_RAD_M and (best is None or d < best[0]):
                best = (d, k, ra - alt)
            if best is not None and best[0] <= radius and d > radius:
                break  # left the acceptance circle after having entered it
        assert best is not None, f"waypoint {i + 1}: never at its altitude {alt} m"
        d, k, dz = best
        report.append(f"wp{i + 1} {d:.2f} m (dz {dz:+.2f} m, radius {radius} m)")
        assert d <= radius, f"waypoint {i + 1} missed: closest {d:.2f} m > {radius} m; {report}"
        start = k + 1
    print("; ".join(report), f"({len(track)} GLOBAL_POSITION_INT in OFFBOARD, loss {loss:.3f})")
