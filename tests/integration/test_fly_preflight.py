"""`fly` checks everything that can fail before it commands the vehicle.

The test plays a bare PX4 on loopback UDP with pymavlink (HEARTBEAT, positions, SYS_STATUS; it
never answers a command) and records every message `python -m companion fly` sends. A mission
whose planned home is 89 m from the vehicle must end with exit code 2 and without a single
ARM, TAKEOFF, mode change or setpoint on the wire; bad pattern options must fail before the
companion sends anything at all.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
import struct
import sys
import time
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from companion.mission import load_mission
from companion.mission.px4_params import PLANNING_PARAM_NAMES, Px4PlanningParams
from tests.support.mock_process import bounded, free_udp_port

# flies in wall-clock time (the mock served over a link): README's second test phase
pytestmark = pytest.mark.realtime

MISSION = Path(__file__).resolve().parents[1] / "data" / "missions" / "px4_short.plan"
REAL32 = mavlink2.MAV_PARAM_TYPE_REAL32
FORBIDDEN_COMMANDS = {400, 22, 176, 21, 300}  # ARM/DISARM, TAKEOFF, DO_SET_MODE, LAND, START
SETPOINTS = {"SET_POSITION_TARGET_LOCAL_NED", "SET_ATTITUDE_TARGET",
             "SET_POSITION_TARGET_GLOBAL_INT"}


class FakePx4(asyncio.DatagramProtocol):
    """Sends PX4-like telemetry to the companion's port; records what comes back."""

    def __init__(self, lat_deg: float, lon_deg: float,
                 params: dict[str, tuple[float, int]] | None = None,
                 drop: dict[str, int] | None = None) -> None:
        self.lat, self.lon = lat_deg, lon_deg
        self.params = params or {}  # answered by name, as PX4 does; others never
        self.drop = drop or {}  # name -> how many of its first requests are lost
        self.peer: tuple[str, int] | None = None
        self.mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
        self.rx = mavlink2.MAVLink(None)
        self.rx.robust_parsing = True
        self.received: list[object] = []
        self.transport: asyncio.DatagramTransport | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        for msg in self.rx.parse_buffer(data) or []:
            self.received.append(msg)
            if msg.get_type() == "PARAM_REQUEST_READ" and self.drop.get(msg.param_id, 0) > 0:
                self.drop[msg.param_id] -= 1  # this request (or its answer) is lost
            elif msg.get_type() == "PARAM_REQUEST_READ" and msg.param_id in self.params:
                value, ptype = self.params[msg.param_id]
                if ptype == mavlink2.MAV_PARAM_TYPE_INT32:  # PX4's bytewise encoding
                    value = struct.unpack("<f", struct.pack("<i", int(value)))[0]
                reply = self.mav.param_value_encode(msg.param_id.encode(), value, ptype,
                                                    len(self.params), 0)
                assert self.transport is not None
                self.transport.sendto(reply.pack(self.mav), addr)

    def frames(self, t_boot_ms: int) -> list[bytes]:
        m = self.mav
        return [
            m.heartbeat_encode(2, 12, 29, 50593792, 3).pack(m),  # disarmed AUTO.LOITER
            m.sys_status_encode(50348079, 50413615, 320915519, 0, 12000, -1, 90,
                                0, 0, 0, 0, 0, 0).pack(m),
            m.global_position_int_encode(t_boot_ms, int(self.lat * 1e7), int(self.lon * 1e7),
                                         488000, 0, 0, 0, 0, 0).pack(m),
            m.local_position_ned_encode(t_boot_ms, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0).pack(m),
            m.attitude_quaternion_encode(t_boot_ms, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0).pack(m),
        ]


async def _run_fly_against_fake(tmp_path: Path, lat: float, lon: float, *args: str,
                                params: dict[str, tuple[float, int]] | None = None,
                                drop: dict[str, int] | None = None
                                ) -> tuple[int, str, list[object]]:
    port = free_udp_port()
    loop = asyncio.get_running_loop()
    transport, fake = await loop.create_datagram_endpoint(
        lambda: FakePx4(lat, lon, params, drop), local_addr=("127.0.0.1", 0), family=socket.AF_INET)
    comp = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "companion", "fly", *args,
        "--connect", f"udpin://127.0.0.1:{port}", "--log", str(tmp_path / "f.tlog"),
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.STDOUT)

    async def telemetry() -> None:
        t0 = time.monotonic()
        while True:  # 20 Hz until cancelled
            for f in fake.frames(int((time.monotonic() - t0) * 1000)):
                transport.sendto(f, ("127.0.0.1", port))
            await asyncio.sleep(0.05)

    tel = loop.create_task(telemetry())
    try:
        out, _ = await bounded(comp.communicate(), 60.0, "fly to give up")
    finally:
        tel.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await tel
        transport.close()
        if comp.returncode is None:
            comp.kill()
            await comp.wait()
    assert comp.returncode is not None
    return comp.returncode, out.decode(errors="replace"), fake.received


def _commands(received: list[object]) -> set[int]:
    return {int(m.command) for m in received  # type: ignore[attr-defined]
            if m.get_type() in ("COMMAND_LONG", "COMMAND_INT")}  # type: ignore[attr-defined]


async def test_far_mission_home_refused_before_any_command(tmp_path: Path) -> None:
    home = load_mission(MISSION).home
    # 89 m north of the planned home (1 deg latitude ~ 111.2 km)
    lat = home.lat_deg + 89.0 / 111_200.0
    code, out, received = await _run_fly_against_fake(tmp_path, lat, home.lon_deg, str(MISSION))
    assert code == 2, out
    assert "89 m from the vehicle" in " ".join(out.split()), out
    assert "Connected" in out  # refused on the vehicle's own position, over a live link
    kinds = {m.get_type() for m in received}  # type: ignore[attr-defined]
    assert not _commands(received) & FORBIDDEN_COMMANDS, _commands(received)
    assert not kinds & SETPOINTS, kinds
    assert not (tmp_path / "f.tlog.report.json").exists()


async def test_parameters_read_and_vehicle_file_overrides_are_printed_before_the_checks(
        tmp_path: Path) -> None:
    """The planning parameters are read (and only read) before the home check refuses the
    flight; the printout shows the vehicle's values and marks the vehicle file's override. A
    parameter whose first three requests are lost is asked for again (its value, not the
    default, is used)."""
    home = load_mission(MISSION).home
    params = {n: (v, REAL32) for n, v in Px4PlanningParams().as_dict().items()}
    params.update(MPC_XY_CRUISE=(7.25, REAL32), NAV_ACC_RAD=(3.0, REAL32),
                  MPC_TKO_SPEED=(2.5, REAL32))
    vf = tmp_path / "v.toml"
    vf.write_text("[px4]\nNAV_ACC_RAD = 0.75\n")
    lat = home.lat_deg + 89.0 / 111_200.0
    code, out, received = await _run_fly_against_fake(
        tmp_path, lat, home.lon_deg, str(MISSION), "--vehicle", str(vf), params=params,
        drop={"MPC_TKO_SPEED": 3})
    assert code == 2, out
    flat = " ".join(out.split())
    assert "MPC_XY_CRUISE = 7.25" in flat, out
    assert "NAV_ACC_RAD = 0.75 (vehicle file; vehicle 3)" in flat, out
    assert "MPC_TKO_SPEED = 2.5 " in flat + " " and "(default)" not in flat, out
    assert "89 m from the vehicle" in flat, out
    asked = [m.param_id for m in received  # type: ignore[attr-defined]
             if m.get_type() == "PARAM_REQUEST_READ"]  # type: ignore[attr-defined]
    # each once by name (MPC_TKO_SPEED: three lost, the fourth in the second pass answered)
    assert sorted(asked) == sorted([*PLANNING_PARAM_NAMES, *["MPC_TKO_SPEED"] * 3])
    assert not any(m.get_type() in ("PARAM_REQUEST_LIST", "PARAM_SET")  # type: ignore[attr-defined]
                   for m in received)
    assert not _commands(received) & FORBIDDEN_COMMANDS


async def test_a_parameter_the_planner_cannot_use_stops_fly_before_any_command(
        tmp_path: Path) -> None:
    home = load_mission(MISSION).home
    params = {n: (v, REAL32) for n, v in Px4PlanningParams().as_dict().items()}
    params["NAV_ACC_RAD"] = (2, mavlink2.MAV_PARAM_TYPE_INT32)  # not PX4's type for it
    code, out, received = await _run_fly_against_fake(
        tmp_path, home.lat_deg, home.lon_deg, str(MISSION), params=params)
    assert code == 2, out
    assert "NAV_ACC_RAD from the vehicle" in " ".join(out.split()), out
    assert not _commands(received) & FORBIDDEN_COMMANDS
    assert not {m.get_type() for m in received} & SETPOINTS  # type: ignore[attr-defined]


@pytest.mark.parametrize("bad", [("--speed", "-1"), ("--size", "0"), ("--laps", "0"),
                                 ("--alt", "0.2"), ("--rate", "1")])
async def test_bad_pattern_options_fail_before_anything_is_sent(
        tmp_path: Path, bad: tuple[str, str]) -> None:
    home = load_mission(MISSION).home
    code, out, received = await _run_fly_against_fake(
        tmp_path, home.lat_deg, home.lon_deg, "circle", *bad)
    assert code == 2, out
    assert received == []  # not even a HEARTBEAT: the link was never opened


async def test_missing_vehicle_file_fails_before_anything_is_sent(tmp_path: Path) -> None:
    home = load_mission(MISSION).home
    code, out, received = await _run_fly_against_fake(
        tmp_path, home.lat_deg, home.lon_deg, str(MISSION), "--vehicle",
        str(tmp_path / "missing.toml"))
    assert code == 2 and "not found" in out, out
    assert received == []


async def test_mission_crossing_its_geofence_refused_before_any_command(tmp_path: Path) -> None:
    from tests.support.fence_plans import HOME, box, write_plan

    plan = write_plan(tmp_path / "cross.plan", [(60.0, 0.0), (60.0, 60.0)],
                      polygons=[(False, box(50.0, 70.0, 20.0, 34.0))])
    code, out, received = await _run_fly_against_fake(tmp_path, HOME[0], HOME[1], str(plan))
    assert code == 2, out
    flat = " ".join(out.split())
    assert "the leg from item 2 to item 3 crosses exclusion polygon 0 for 14 m" in flat, out
    kinds = {m.get_type() for m in received}  # type: ignore[attr-defined]
    assert not _commands(received) & FORBIDDEN_COMMANDS, _commands(received)
    assert not kinds & SETPOINTS, kinds
    assert not (tmp_path / "f.tlog.report.json").exists()
