"""A minimal ground station for tests, on pymavlink only (independent of the companion's MAVLink
code): it listens where the autopilot's GCS link sends (PX4 sends first), tracks the autopilot's
HEARTBEAT, position and STATUSTEXTs, and sends what QGroundControl would: mission upload,
ARM, TAKEOFF, mode changes. Every wait is bounded.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import socket
import time
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass, field
from typing import Any

from pymavlink.dialects.v20 import common as mavlink2

GCS_SYSID, GCS_COMPID = 255, 190  # QGroundControl's ids
# PX4 custom_mode = main << 16 | sub << 24 (PX4.md)
MODES = {"OFFBOARD": (6, 0), "HOLD": (4, 3), "POSCTL": (3, 0), "MISSION": (4, 4),
         "LAND": (4, 6), "RTL": (4, 5), "TAKEOFF": (4, 2)}


def custom_mode(name: str) -> int:
    main, sub = MODES[name]
    return main << 16 | sub << 24


def mode_name(custom: int) -> str:
    for name in MODES:
        if custom_mode(name) == custom:
            return name
    return f"custom {custom}"


@dataclass
class Sample:
    t: float  # receive time, monotonic [s]
    pos_ned: tuple[float, float, float]
    mode: str
    armed: bool
    vel_ned: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class Truth:
    """One HIL_STATE_QUATERNION (PX4 SITL's ground truth, sent when requested)."""

    t: float  # receive time, monotonic [s] (PX4 leaves time_usec 0)
    vel_ned: tuple[float, float, float]  # [m/s]


@dataclass
class Gcs(asyncio.DatagramProtocol):
    """See the module doc. ``track`` holds one Sample per LOCAL_POSITION_NED."""

    target_system: int = 1
    transport: asyncio.DatagramTransport | None = None
    peer: tuple[str, int] | None = None
    mav: Any = None
    parser: Any = None
    heartbeat: Any = None
    heartbeat_t: float = 0.0
    attitude: Any = None  # the latest ATTITUDE (roll, pitch, yaw [rad])
    home: Any = None  # the latest HOME_POSITION (lat/lon [degE7] and local x/y/z [m])
    texts: list[tuple[float, str]] = field(default_factory=list)
    track: list[Sample] = field(default_factory=list)
    truth: list[Truth] = field(default_factory=list)  # HIL_STATE_QUATERNION, once requested
    acks: list[Any] = field(default_factory=list)
    mission_msgs: list[Any] = field(default_factory=list)
    changed: asyncio.Event = field(default_factory=asyncio.Event)

    def __post_init__(self) -> None:
        self.mav = mavlink2.MAVLink(None, srcSystem=GCS_SYSID, srcComponent=GCS_COMPID)
        self.parser = mavlink2.MAVLink(None)
        self.parser.robust_parsing = True

    # -- protocol ----------------------------------------------------------------------------
    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        self.peer = addr
        now = time.monotonic()
        for m in self.parser.parse_buffer(data) or []:
            kind = m.get_type()
            if kind == "STATUSTEXT":
                self.texts.append((now, m.text))
            if m.get_srcSystem() != self.target_system:
                continue
            if kind == "HEARTBEAT" and m.get_srcComponent() == 1:
                self.heartbeat, self.heartbeat_t = m, now
            elif kind == "LOCAL_POSITION_NED" and self.heartbeat is not None:
                self.track.append(Sample(now, (m.x, m.y, m.z), self.mode, self.armed,
                                         (m.vx, m.vy, m.vz)))
            elif kind == "ATTITUDE":
                self.attitude = m
            elif kind == "HOME_POSITION":
                self.home = m
            elif kind == "HIL_STATE_QUATERNION":  # velocities in cm/s
                self.truth.append(Truth(now, (m.vx / 100.0, m.vy / 100.0, m.vz / 100.0)))
            elif kind == "COMMAND_ACK":
                self.acks.append(m)
            elif kind.startswith("MISSION_") and kind not in ("MISSION_CURRENT",
                                                               "MISSION_ITEM_REACHED"):
                self.mission_msgs.append(m)
        self.changed.set()

    # -- state -------------------------------------------------------------------------------
    @property
    def mode(self) -> str:
        return "-" if self.heartbeat is None else mode_name(self.heartbeat.custom_mode)

    @property
    def armed(self) -> bool:
        return self.heartbeat is not None and bool(self.heartbeat.base_mode & 128)

    @property
    def position(self) -> tuple[float, float, float] | None:
        return self.track[-1].pos_ned if self.track else None

    def send(self, msg: Any) -> None:
        assert self.transport is not None and self.peer is not None
        self.transport.sendto(msg.pack(self.mav), self.peer)

    async def wait_for(self, cond: Callable[[], bool], timeout_s: float, what: str) -> None:
        deadline = time.monotonic() + timeout_s
        while not cond():
            left = deadline - time.monotonic()
            if left <= 0:
                raise AssertionError(f"timed out after {timeout_s} s waiting for {what} "
                                     f"(mode {self.mode}, armed {self.armed}, "
                                     f"position {self.position}, texts {self.texts[-5:]})")
            self.changed.clear()
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(min(left, 0.1)):
                    await self.changed.wait()

    def text_seen(self, fragment: str) -> bool:
        return any(fragment in t for _, t in self.texts)

    # -- commands ----------------------------------------------------------------------------
    async def command(self, command: int, *params: float, timeout_s: float = 3.0) -> int:
        """COMMAND_LONG with MAVSDK's retries; returns the last ACK's result within ~0.3 s of
        the first (PX4 acks DO_SET_MODE twice: receipt, then the commander's verdict)."""
        p = [*params, *([0.0] * (7 - len(params)))]
        n0 = len(self.acks)
        for attempt in range(4):
            self.send(mavlink2.MAVLink_command_long_message(
                self.target_system, 1, command, attempt, *p))
            with contextlib.suppress(AssertionError):
                await self.wait_for(lambda: any(a.command == command for a in self.acks[n0:]),
                                    0.5, "ack")
                break
        else:
            raise AssertionError(f"no COMMAND_ACK for command {command}")
        await asyncio.sleep(0.3)  # collect a second (final) ack if one comes
        results = [a.result for a in self.acks[n0:] if a.command == command]
        return int(results[-1])

    async def set_mode(self, name: str) -> int:
        main, sub = MODES[name]
        base = 1 | (128 if self.armed else 0)
        return await self.command(176, base, main, sub)

    async def upload_mission(self, items: list[Any], timeout_s: float = 10.0,
                             mission_type: int = 0) -> None:
        """MISSION_COUNT, answer each MISSION_REQUEST(_INT) with MISSION_ITEM_INT, until ACK
        (``mission_type`` 1: the geofence; the items must carry the same type)."""
        self.mission_msgs.clear()
        self.send(mavlink2.MAVLink_mission_count_message(self.target_system, 1, len(items),
                                                         mission_type))
        deadline = time.monotonic() + timeout_s
        handled = 0
        while time.monotonic() < deadline:
            n = handled
            await self.wait_for(lambda n=n: len(self.mission_msgs) > n,  # type: ignore[misc]
                                deadline - time.monotonic(), "mission transfer")
            m = self.mission_msgs[handled]
            handled += 1
            kind = m.get_type()
            if kind in ("MISSION_REQUEST", "MISSION_REQUEST_INT"):
                it = items[m.seq]
                it.seq = m.seq
                self.send(it)
            elif kind == "MISSION_ACK":
                assert m.type == 0, f"mission upload refused: MAV_MISSION_RESULT {m.type}"
                return
        raise AssertionError("mission upload timed out")


def mission_item(seq: int, command: int, lat: float, lon: float, alt_rel_m: float,
                 *params: float) -> Any:
    """A MISSION_ITEM_INT in MAV_FRAME_GLOBAL_RELATIVE_ALT_INT (6)."""
    p = [*params, *([0.0] * (4 - len(params)))]
    return mavlink2.MAVLink_mission_item_int_message(
        1, 1, seq, 6, command, 1 if seq == 0 else 0, 1, p[0], p[1], p[2], p[3],
        round(lat * 1e7), round(lon * 1e7), alt_rel_m, 0)


def plan_file_items(path: Any, target_system: int) -> list[Any]:
    """A mission file's items as the MISSION_ITEM_INTs a ground station uploads to PX4."""
    from companion.mission import load_mission, mission_upload_items

    return [mavlink2.MAVLink_mission_item_int_message(
        target_system, 1, i, u.frame, u.command, int(i == 0), u.autocontinue, u.param1,
        u.param2, u.param3, u.param4, u.x, u.y, u.z, 0)
        for i, u in enumerate(mission_upload_items(load_mission(path)))]


def local_of(home: Any, lat_deg: float, lon_deg: float) -> tuple[float, float]:
    """(north, east) [m] in the autopilot's local frame of a point near HOME_POSITION `home`:
    its local x/y plus the offset from its lat/lon (spherical Earth, R 6371 km; < 1 cm at
    50 m), independent of the companion's projection."""
    r = 6371000.0
    lat0, lon0 = home.latitude * 1e-7, home.longitude * 1e-7
    return (home.x + math.radians(lat_deg - lat0) * r,
            home.y + math.radians(lon_deg - lon0) * r * math.cos(math.radians(lat0)))


def offset_deg(lat0: float, north_m: float, east_m: float) -> tuple[float, float]:
    """(dlat, dlon) [deg] of a small offset (spherical Earth, R 6371 km; < 1 cm at 50 m)."""
    r = 6371000.0
    return (math.degrees(north_m / r), math.degrees(east_m / (r * math.cos(math.radians(lat0)))))


@contextlib.asynccontextmanager
async def ground_station(port: int, target_system: int = 1) -> AsyncIterator[Gcs]:
    """Listen on loopback ``port`` (where the autopilot's GCS link sends); closed on exit."""
    loop = asyncio.get_running_loop()
    transport, gcs = await loop.create_datagram_endpoint(
        lambda: Gcs(target_system=target_system), local_addr=("127.0.0.1", port),
        family=socket.AF_INET)
    try:
        yield gcs
    finally:
        transport.close()
