"""`python -m companion serve` against the mock, with the test playing QGroundControl on the
mock's GCS link (pymavlink, tests/support/gcs.py).

The pilot uploads a mission, arms and takes off in AUTO, and switches to OFFBOARD: the service
flies the smooth mission; Hold mid-way stops it at once; OFFBOARD again resumes from where the
vehicle is; at the end the service switches PX4 to the mission's LAND. Then: SIGTERM while
flying -> Hold (no failsafe) and exit 0; link loss and a killed service -> PX4's own failsafe.
Oracles are the mock's HEARTBEAT and LOCAL_POSITION_NED seen by the GCS, the service's .tlog
(what it sent and when, relative to the HEARTBEATs it had received) and its events.jsonl.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import signal
import socket
import sys
from collections.abc import AsyncIterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from pymavlink import mavutil

from tests.support.gcs import Gcs, custom_mode, ground_station, mission_item, offset_deg
from tests.support.mock_process import bounded, free_udp_port, run_mock

# flies in wall-clock time (the mock served over a link): README's second test phase
pytestmark = pytest.mark.realtime

HOME = (47.397742, 8.545594)  # the mock's default home (PX4 SITL's)
ALT_M = 5.0
# the mission's waypoints, NED from home [m]
WPS = [(0.0, 0.0), (20.0, 0.0), (20.0, 15.0), (0.0, 15.0)]


def mission() -> list[object]:
    items = []
    for i, (n, e) in enumerate(WPS):
        dlat, dlon = offset_deg(HOME[0], n, e)
        items.append(mission_item(i, 22 if i == 0 else 16, HOME[0] + dlat, HOME[1] + dlon, ALT_M))
    dlat, dlon = offset_deg(HOME[0], *WPS[-1])
    items.append(mission_item(len(WPS), 21, HOME[0] + dlat, HOME[1] + dlon, 0.0))
    return items


def dist_xy(p: tuple[float, float, float], q: tuple[float, float]) -> float:
    return math.hypot(p[0] - q[0], p[1] - q[1])


class UdpRelay(asyncio.DatagramProtocol):
    """Loopback relay between the mock (sends to ``port``) and the service (listens on
    ``service_port``); ``drop = True`` cuts the link both ways."""

    def __init__(self, service_port: int) -> None:
        self.service_port = service_port
        self.mock_addr: tuple[str, int] | None = None
        self.drop = False
        self.transport: asyncio.DatagramTransport | None = None
        self.out: asyncio.DatagramTransport | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        if not self.drop and self.out is not None:
            self.mock_addr = addr
            self.out.sendto(data, ("127.0.0.1", self.service_port))


class _Back(asyncio.DatagramProtocol):
    def __init__(self, relay: UdpRelay) -> None:
        self.relay = relay

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        r = self.relay
        if not r.drop and r.mock_addr is not None and r.transport is not None:
            r.transport.sendto(data, r.mock_addr)


@contextlib.asynccontextmanager
async def relay(port: int, service_port: int) -> AsyncIterator[UdpRelay]:
    loop = asyncio.get_running_loop()
    t1, r = await loop.create_datagram_endpoint(lambda: UdpRelay(service_port),
                                                local_addr=("127.0.0.1", port),
                                                family=socket.AF_INET)
    t2, _ = await loop.create_datagram_endpoint(lambda: _Back(r), local_addr=("127.0.0.1", 0),
                                                family=socket.AF_INET)
    r.out = t2  # type: ignore[assignment]
    try:
        yield r
    finally:
        t1.close()
        t2.close()


@dataclass
class Service:
    proc: asyncio.subprocess.Process
    log_dir: Path

    def events(self) -> list[dict[str, object]]:
        path = self.log_dir / "events.jsonl"
        if not path.exists():
            return []
        return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


@contextlib.asynccontextmanager
async def run_service(port: int, log_dir: Path, *extra: str) -> AsyncIterator[Service]:
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "companion", "serve", "--connect", f"udpin://127.0.0.1:{port}",
        "--log-dir", str(log_dir), *extra,
        stdout=asyncio.subprocess.DEVNULL, stderr=asyncio.subprocess.DEVNULL)
    try:
        yield Service(proc, log_dir)
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()


async def take_off(gcs: Gcs) -> None:
    """What the pilot does: wait until armable, arm in Hold, NAV_TAKEOFF (2.5 m)."""
    await gcs.wait_for(lambda: gcs.heartbeat is not None, 15.0, "the autopilot's HEARTBEAT")
    for _ in range(40):  # the estimator needs a moment after boot (bounded retries)
        if await gcs.command(400, 1.0) == 0:
            break
        await asyncio.sleep(0.25)
    assert gcs.armed or await gcs.command(400, 1.0) == 0
    assert await gcs.command(22, 0, 0, 0, math.nan, math.nan, math.nan, math.nan) == 0
    await gcs.wait_for(lambda: gcs.position is not None and gcs.position[2] < -2.0
                       and gcs.mode == "HOLD", 30.0, "the takeoff to end in Hold")


async def prepared(gcs: Gcs) -> None:
    await gcs.wait_for(lambda: gcs.heartbeat is not None, 15.0, "the autopilot's HEARTBEAT")
    await gcs.upload_mission(mission())
    await gcs.wait_for(lambda: gcs.text_seen("ecca: mission 5 wp"), 20.0,
                       "the service's plan announcement")
    await take_off(gcs)


def sent_after_leaving_offboard(tlog_dir: Path) -> list[int]:
    """For each time the service's link saw the vehicle leave OFFBOARD: how many mission
    setpoints (SET_ATTITUDE_TARGET) it still sent before its first hold setpoint."""
    counts = []
    for path in sorted(tlog_dir.glob("serve-*.tlog")):
        m = mavutil.mavlink_connection(str(path), dialect="common")
        in_offboard, counting, n = False, False, 0
        while (msg := m.recv_match()) is not None:
            kind = msg.get_type()
            if kind == "HEARTBEAT" and msg.get_srcComponent() == 1:
                now_off = msg.custom_mode == custom_mode("OFFBOARD")
                if in_offboard and not now_off:
                    counting, n = True, 0
                in_offboard = now_off
            elif counting and kind == "SET_ATTITUDE_TARGET":
                n += 1
            elif counting and kind == "SET_POSITION_TARGET_LOCAL_NED":
                counts.append(n)
                counting = False
        m.close()
    return counts


async def test_serve_flies_the_pilots_mission_pauses_on_hold_resumes_and_lands(
        tmp_path: Path) -> None:
    gcs_port = free_udp_port()
    async with (ground_station(gcs_port) as gcs,
                run_mock("--estimator-ready", "0.5", gcs_port=gcs_port) as mock,
                run_service(mock.client_port, tmp_path) as svc):
        await prepared(gcs)
        # the pilot selects OFFBOARD: accepted at once, the service has been streaming hold
        assert await gcs.set_mode("OFFBOARD") == 0
        await gcs.wait_for(lambda: gcs.mode == "OFFBOARD", 3.0, "OFFBOARD")
        await gcs.wait_for(lambda: dist_xy(gcs.position, WPS[1]) < 1.5, 40.0,  # type: ignore[arg-type]
                           "the first mission waypoint")
        # ... and takes over mid-way to the next one
        await gcs.wait_for(lambda: gcs.position[1] > 2.0, 20.0, "on the way to wp 2")  # type: ignore[index]
        assert await gcs.set_mode("HOLD") == 0
        await gcs.wait_for(lambda: gcs.mode == "HOLD", 3.0, "Hold")
        i_hold = len(gcs.track)
        t_hold = gcs.track[-1].t
        await gcs.wait_for(lambda: gcs.track[-1].t > t_hold + 6.0, 12.0, "6 s in Hold")
        held = np.array([s.pos_ned for s in gcs.track[i_hold:]])
        late = np.array([s.pos_ned for s in gcs.track[i_hold:] if s.t >= t_hold + 4.0])
        # stopped: braked short of wp 2 (never within its 2 m acceptance radius), at rest from
        # 4 s on (it was flying at up to 5 m/s; Hold brakes, then settles on its position loop)
        assert min(dist_xy(tuple(p), WPS[2]) for p in held) > 2.0  # type: ignore[arg-type]
        assert len(late) >= 2 and np.ptp(late[:, :2], axis=0).max() < 0.5, late
        # back to OFFBOARD: resumes from here to wp 2, wp 3, then LAND
        i_resume = len(gcs.track)
        assert await gcs.set_mode("OFFBOARD") == 0
        await gcs.wait_for(lambda: gcs.mode == "LAND", 60.0, "the service to request LAND")
        await gcs.wait_for(lambda: not gcs.armed, 40.0, "landing and disarm")
        after = [s.pos_ned for s in gcs.track[i_resume:]]
        closest = [min(dist_xy(p, w) for p in after) for w in WPS[2:]]
        print("after resume: closest approach to wp 2, 3 [m]:", np.round(closest, 2))
        assert max(closest) < 1.0
        # never went back towards the first waypoints
        assert min(dist_xy(p, WPS[1]) for p in after) > 3.0
        assert dist_xy(gcs.track[-1].pos_ned, WPS[3]) < 1.5  # landed on the land point
        events = svc.events()
        kinds = [e["event"] for e in events]
        assert "mission_planned" in kinds and "mission_complete" in kinds
        flights = [e for e in events if e["event"] == "state" and e["state"] == "mission"]
        assert len(flights) == 2 and int(flights[1]["reached"]) >= 2  # type: ignore[call-overload]
        assert any(e["event"] == "mode_request" and e["mode"] == "LAND" for e in events)
        # SIGTERM on the ground: a clean stop
        svc.proc.send_signal(signal.SIGTERM)
        assert await bounded(svc.proc.wait(), 10.0, "the service to stop") == 0
    # at most a handful of mission setpoints after the service saw the vehicle leave OFFBOARD
    # (its 20 Hz loop; setpoints go out at 50 Hz): Hold stopped the mission stream at once
    counts = sent_after_leaving_offboard(tmp_path)
    print("mission setpoints sent after leaving OFFBOARD:", counts)
    assert counts and max(counts) <= 4


async def test_serve_sigterm_holds_link_loss_and_kill_leave_it_to_px4(tmp_path: Path) -> None:
    gcs_port, svc_port = free_udp_port(), free_udp_port()
    async with (ground_station(gcs_port) as gcs,
                run_mock("--estimator-ready", "0.5", gcs_port=gcs_port) as mock,
                # the mock sends to its client port, where the relay forwards to the service
                relay(mock.client_port, svc_port) as link):
        if True:  # (one level kept for the two services below)
            async with run_service(svc_port, tmp_path / "a") as svc:
                await prepared(gcs)
                assert await gcs.set_mode("OFFBOARD") == 0
                await gcs.wait_for(lambda: gcs.position[0] > 5.0, 30.0, "mission flight")  # type: ignore[index]
                # SIGTERM while flying the mission: Hold first, then exit 0 (no failsafe)
                svc.proc.send_signal(signal.SIGTERM)
                assert await bounded(svc.proc.wait(), 15.0, "the service to stop") == 0
                assert gcs.mode == "HOLD" and gcs.heartbeat.system_status != 5
            # a new service, OFFBOARD again, then the link is cut: PX4's failsafe
            async with run_service(svc_port, tmp_path / "b") as svc:
                await gcs.wait_for(lambda: any(e["event"] == "connected"
                                               for e in svc.events()), 15.0, "connection")
                await gcs.wait_for(lambda: any(e["event"] == "mission_planned"
                                               for e in svc.events()), 20.0, "the plan")
                assert await gcs.set_mode("OFFBOARD") == 0
                await gcs.wait_for(lambda: gcs.position[1] > 3.0, 30.0, "mission flight")  # type: ignore[index]
                n_events = len(svc.events())
                link.drop = True
                await gcs.wait_for(lambda: gcs.mode != "OFFBOARD", 5.0, "PX4's failsafe")
                print("link loss ->", gcs.mode, "system_status", gcs.heartbeat.system_status)
                assert gcs.mode == "POSCTL" and gcs.heartbeat.system_status == 5
                # the pilot stops the failsafe descent (POSCTL without RC sinks) with Hold
                assert await gcs.set_mode("HOLD") == 0
                # the service notices the silent link (no HEARTBEAT for 3 s) ...
                await gcs.wait_for(lambda: any(e["event"] == "link" and e["ok"] is False
                                               for e in svc.events()[n_events:]), 10.0,
                                   "the service to see the link lost")
                n_events = len(svc.events())
                link.drop = False
                # ... and the link coming back; it streams hold again, so the pilot can
                # re-enter OFFBOARD and the mission resumes
                await gcs.wait_for(lambda: any(e["event"] == "link" and e["ok"] is True
                                               for e in svc.events()[n_events:]), 15.0,
                                   "relink")
                assert gcs.armed and gcs.position[2] < -1.5  # type: ignore[index]
                # (the first hold setpoints may still be on their way: the pilot retries)
                for _ in range(10):
                    if await gcs.set_mode("OFFBOARD") == 0:
                        break
                assert gcs.mode == "OFFBOARD" or await gcs.set_mode("OFFBOARD") == 0
                await gcs.wait_for(lambda: gcs.mode == "OFFBOARD", 3.0, "OFFBOARD again")
                await gcs.wait_for(lambda: sum(e["event"] == "state" and e["state"] == "mission"
                                               for e in svc.events()) >= 2, 5.0,
                                   "the mission to resume")
                # killed while flying: PX4's offboard-loss failsafe as before
                svc.proc.kill()
                await svc.proc.wait()
                await gcs.wait_for(lambda: gcs.mode != "OFFBOARD", 5.0, "failsafe after kill")
                assert gcs.text_seen("ailsafe") or gcs.heartbeat.system_status == 5


async def test_serve_reads_the_mocks_planning_parameters_and_the_vehicle_file_wins(
        tmp_path: Path) -> None:
    """At connect the service reads the PX4 planning parameters over MAVLink (the mock started
    with changed values) and logs what it plans with; the vehicle file's [px4] entry wins."""
    port = free_udp_port()
    vf = tmp_path / "vehicle.toml"
    vf.write_text("[px4]\nNAV_ACC_RAD = 1.25\n")
    async with run_mock("--param", "MPC_XY_CRUISE=7.5", "--param", "MPC_TKO_SPEED=2.25",
                        "--param", "NAV_ACC_RAD=3") as mock, \
            relay(mock.client_port, port), \
            run_service(port, tmp_path / "logs", "--vehicle-file", str(vf)) as svc:

        def read() -> dict[str, object] | None:
            return next((e for e in svc.events() if e["event"] == "px4_params"), None)

        for _ in range(300):  # bounded: the service connects and reads within seconds
            if read() is not None or svc.proc.returncode is not None:
                break
            await asyncio.sleep(0.05)
        ev = read()
        assert ev is not None, svc.events()
        assert ev["MPC_XY_CRUISE"] == 7.5 and ev["MPC_TKO_SPEED"] == 2.25
        assert ev["NAV_ACC_RAD"] == 1.25 and ev["vehicle_file"] == ["NAV_ACC_RAD"]
        assert ev["defaulted"] == []
        svc.proc.send_signal(signal.SIGTERM)
        assert await bounded(svc.proc.wait(), 15.0, "serve to stop") == 0


async def test_serve_refuses_a_mission_that_crosses_the_vehicles_geofence(
        tmp_path: Path) -> None:
    """The pilot uploads a fence (an exclusion box across the leg wp 1 -> wp 2) and then the
    mission: the service downloads both and refuses the plan by STATUSTEXT, naming the leg."""
    from pymavlink.dialects.v20 import common as mavlink2

    box_ne = [(15.0, 5.0), (25.0, 5.0), (25.0, 10.0), (15.0, 10.0)]  # across north 20, east 5..10
    fence = []
    for i, (n, e) in enumerate(box_ne):
        dlat, dlon = offset_deg(HOME[0], n, e)
        fence.append(mavlink2.MAVLink_mission_item_int_message(
            1, 1, i, 0, 5002, 0, 1, float(len(box_ne)), 0.0, 0.0, 0.0,
            round((HOME[0] + dlat) * 1e7), round((HOME[1] + dlon) * 1e7), 0.0, 1))
    gcs_port = free_udp_port()
    async with (ground_station(gcs_port) as gcs,
                run_mock("--estimator-ready", "0.5", gcs_port=gcs_port) as mock,
                run_service(mock.client_port, tmp_path) as svc):
        await gcs.wait_for(lambda: gcs.heartbeat is not None, 15.0, "the autopilot's HEARTBEAT")
        await gcs.upload_mission(fence, mission_type=1)
        await gcs.upload_mission(mission())

        def joined() -> str:  # the refusal comes in 50-character STATUSTEXT chunks
            return "".join(t for _, t in gcs.texts)

        await gcs.wait_for(lambda: "refusing to fly" in joined(), 20.0,
                           "the service's refusal")
        assert gcs.text_seen("ecca: cannot fly mission")
        # items as the service numbers the downloaded mission: takeoff 1, wp 2, 3, 4, land 5
        assert "the leg from item 2 to item 3 crosses exclusion polygon 0" in joined(), joined()
        assert not gcs.text_seen("ecca: mission 5 wp")
        rejected = [e for e in svc.events() if e["event"] == "mission_rejected"]
        assert rejected and "geofence" in str(rejected[0]["why"])


async def test_serve_onboard_exits_2_when_no_onboard_module_answers(tmp_path: Path) -> None:
    """The mock runs no onboard module: `serve --onboard` asks for its state, hears nothing,
    and exits 2 before it reads a parameter or sends anything that could move the vehicle."""
    port = free_udp_port()
    async with run_mock() as mock, relay(mock.client_port, port), \
            run_service(port, tmp_path / "logs", "--onboard") as svc:
        assert await bounded(svc.proc.wait(), 20.0, "serve --onboard to give up") == 2
        ev = [e["event"] for e in svc.events()]
        assert "onboard_module" in ev and "px4_params" not in ev, ev
