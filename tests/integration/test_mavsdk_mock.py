"""MAVSDK 4 (native binding, an independent MAVLink client) flies `python -m sitl_mock serve`.

Timing figures are measured on the mock's simulated clock (time_boot_ms in its telemetry, read
through MAVSDK's mavlink_direct plugin), never on the wall clock. PX4 reference figures are
the real PX4 v1.16 SITL (SIH) measurements of shared/PX4.md; the mock must be within 30 %.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
from collections.abc import AsyncIterator, Awaitable, Callable
from pathlib import Path
from typing import Any, TypeVar

import pytest
from mavsdk.asyncio.plugins.offboard import (
    Attitude,
    OffboardError,
    PositionNedYaw,
    VelocityNedYaw,
)
from mavsdk.asyncio.plugins.telemetry import FlightMode
from mavsdk.plugins.mavlink_direct import MavlinkMessage
from mavsdk.plugins.mission_raw.mission_raw import MissionRawError, MissionRawResult

from tests.support.mock_process import Drone, bounded, connect_drone

# flies in wall-clock time (the mock served over a link): README's second test phase
pytestmark = pytest.mark.realtime

T = TypeVar("T")
SPEED = 2.0  # simulated seconds per wall second (MAVSDK's wall-clock timeouts allow it)


async def until(
    get: Callable[[], Awaitable[T]], pred: Callable[[T], bool], timeout_s: float, what: str
) -> T:
    """Poll a MAVSDK getter until pred(value) holds (bounded)."""

    async def loop() -> T:
        while True:
            v = await get()
            if pred(v):
                return v
            await asyncio.sleep(0.02)

    return await bounded(loop(), timeout_s, what)


class Recorder:
    """Records one message type via mavlink_direct: list of field dicts (with time_boot_ms)."""

    def __init__(self, drone: Drone, name: str) -> None:
        self.rows: list[dict[str, Any]] = []
        self._task = asyncio.ensure_future(self._run(drone, name))

    async def _run(self, drone: Drone, name: str) -> None:
        async for m in drone.direct.subscribe_message(name):
            self.rows.append(json.loads(m.fields_json))

    async def close(self) -> None:
        self._task.cancel()
        with contextlib.suppress(asyncio.CancelledError, Exception):
            await self._task


@contextlib.asynccontextmanager
async def recording(drone: Drone, name: str) -> AsyncIterator[Recorder]:
    rec = Recorder(drone, name)
    try:
        yield rec
    finally:
        await rec.close()


async def ready_and_armed(d: Drone) -> None:
    await until(d.telemetry.health, lambda h: h.is_armable, 15.0, "is_armable")
    await d.action.arm()
    await until(d.telemetry.armed, bool, 5.0, "armed")


async def take_off(d: Drone) -> None:
    await ready_and_armed(d)
    await d.action.takeoff()
    await until(d.telemetry.flight_mode, lambda m: m == FlightMode.HOLD, 30.0, "takeoff done")


async def sim_time_s(rec: Recorder) -> float:
    await bounded(_wait_rows(rec), 5.0, "telemetry rows")
    return float(rec.rows[-1]["time_boot_ms"]) / 1000.0


async def _wait_rows(rec: Recorder) -> None:
    while not rec.rows:
        await asyncio.sleep(0.01)


# ---------------------------------------------------------------------------------- tests
async def test_discovery_health_arm_takeoff_land() -> None:
    async def body() -> None:
        async with connect_drone(speed=SPEED) as d:
            from mavsdk.asyncio import Autopilot

            assert await d.system.autopilot_type() == Autopilot.PX4
            health = await until(d.telemetry.health, lambda h: h.is_armable, 15.0, "armable")
            assert health.is_local_position_ok and health.is_global_position_ok
            assert health.is_home_position_ok
            assert await d.telemetry.flight_mode() == FlightMode.HOLD
            assert not await d.telemetry.armed()
            async with recording(d, "GLOBAL_POSITION_INT") as gpi:
                await d.action.arm()
                t_arm = await sim_time_s(gpi)
                await d.action.takeoff()
                await until(
                    d.telemetry.flight_mode, lambda m: m == FlightMode.TAKEOFF, 5.0, "TAKEOFF"
                )
                await until(
                    d.telemetry.position, lambda p: p.relative_altitude_m > 1.5, 20.0, "1.5 m"
                )
                t_up = await sim_time_s(gpi)
                assert await d.telemetry.in_air()
            # PX4 SITL: above 1.5 m ~6.6 s after the arm command; within 30 %
            assert 6.6 * 0.7 <= t_up - t_arm <= 6.6 * 1.3, t_up - t_arm
            pos = await until(d.telemetry.flight_mode, lambda m: m == FlightMode.HOLD, 15.0, "Hold")
            assert pos == FlightMode.HOLD
            p = await d.telemetry.position()
            assert 2.0 <= p.relative_altitude_m <= 3.0  # MIS_TAKEOFF_ALT 2.5 m
            await d.action.land()
            await until(d.telemetry.flight_mode, lambda m: m == FlightMode.LAND, 5.0, "LAND")
            await until(d.telemetry.armed, lambda a: not a, 30.0, "auto disarm after landing")
            assert not await d.telemetry.in_air()

    await asyncio.wait_for(body(), 90.0)


async def test_offboard_position_and_velocity() -> None:
    async def body() -> None:
        async with connect_drone(speed=SPEED) as d:
            await take_off(d)
            await d.offboard.set_position_ned(PositionNedYaw(0.0, 0.0, -3.0, 0.0))
            await d.offboard.start()
            await until(
                d.telemetry.flight_mode, lambda m: m == FlightMode.OFFBOARD, 5.0, "OFFBOARD"
            )
            await d.offboard.set_position_ned(PositionNedYaw(5.0, 0.0, -3.0, 0.0))

            def near(pv: Any) -> bool:
                p = pv.position
                return math.dist((p.north_m, p.east_m, p.down_m), (5.0, 0.0, -3.0)) < 0.5

            await until(d.telemetry.position_velocity_ned, near, 20.0, "position setpoint")
            await d.offboard.set_velocity_ned(VelocityNedYaw(0.0, 1.0, 0.0, 0.0))
            pv = await until(
                d.telemetry.position_velocity_ned,
                lambda pv: pv.velocity.east_m_s > 0.9,
                10.0,
                "velocity setpoint",
            )
            assert abs(pv.velocity.north_m_s) < 0.3 and abs(pv.velocity.down_m_s) < 0.3
            await d.offboard.stop()
            await until(d.telemetry.flight_mode, lambda m: m == FlightMode.HOLD, 5.0, "Hold")

    await asyncio.wait_for(body(), 90.0)


async def test_offboard_attitude_roll_moves_east_and_thrust_climbs() -> None:
    async def body() -> None:
        async with connect_drone(speed=SPEED) as d:
            await take_off(d)
            hover = 0.5  # MPC_THR_HOVER as PX4's figure used it
            await d.offboard.set_attitude(Attitude(0.0, 0.0, 0.0, hover))
            await d.offboard.start()
            await until(
                d.telemetry.flight_mode, lambda m: m == FlightMode.OFFBOARD, 5.0, "OFFBOARD"
            )
            async with recording(d, "LOCAL_POSITION_NED") as lpos:
                v0 = await d.telemetry.velocity_ned()
                t0 = await sim_time_s(lpos)
                await d.offboard.set_attitude(
                    Attitude(10.0, 0.0, 0.0, hover / math.cos(math.radians(10.0)))
                )

                def two_s(_: Any) -> bool:
                    return bool(lpos.rows) and lpos.rows[-1]["time_boot_ms"] / 1000.0 >= t0 + 2.0

                await until(d.telemetry.velocity_ned, two_s, 10.0, "2 s of roll")
                row = lpos.rows[-1]
                # PX4 SIH: 1.3-1.4 m/s to the right after 2 s; within 30 %
                assert 1.3 * 0.7 <= row["vy"] - v0.east_m_s <= 1.4 * 1.3, row
                assert abs(row["vx"]) < 0.4, row
                await d.offboard.set_attitude(Attitude(0.0, 0.0, 0.0, 0.65))
                t1 = await sim_time_s(lpos)

                def climb_s(_: Any) -> bool:
                    return lpos.rows[-1]["time_boot_ms"] / 1000.0 >= t1 + 1.5

                await until(d.telemetry.velocity_ned, climb_s, 10.0, "1.5 s of climb")
                climb = -lpos.rows[-1]["vz"]
                # PX4 SIH: thrust 0.65 -> 2.3-2.7 m/s climb after 1.5 s; within 30 %
                assert 2.3 * 0.7 <= climb <= 2.7 * 1.3, climb
            await d.offboard.stop()

    await asyncio.wait_for(body(), 90.0)


async def test_offboard_refused_without_setpoint_stream() -> None:
    async def body() -> None:
        async with connect_drone(speed=SPEED) as d:
            # MAVSDK itself refuses to start offboard before a setpoint was set
            with pytest.raises(OffboardError):
                await d.offboard.start()
            await ready_and_armed(d)
            # send PX4's DO_SET_MODE(OFFBOARD) raw: the mock must refuse it (no proof of life)
            async with recording(d, "COMMAND_ACK") as acks, recording(d, "STATUSTEXT") as texts:
                fields = {
                    "target_system": 1,
                    "target_component": 1,
                    "command": 176,
                    "confirmation": 0,
                    "param1": 129.0,
                    "param2": 6.0,
                    "param3": 0.0,
                    "param4": 0.0,
                    "param5": 0.0,
                    "param6": 0.0,
                    "param7": 0.0,
                }
                msg = MavlinkMessage("COMMAND_LONG", 0, 0, 1, 1, json.dumps(fields))

                def pairs() -> list[int]:
                    return [a["result"] for a in acks.rows if a["command"] == 176]

                async def two_acks() -> None:
                    # resent every 2 s until acks arrive: MAVSDK's message subscription may
                    # not be live yet when the first pair comes back (a CI run saw none in
                    # 15 s); each request is answered by its own pair
                    for _ in range(8):
                        await d.direct.send_message(msg)
                        for _ in range(200):
                            if len(pairs()) >= 2:
                                return
                            await asyncio.sleep(0.01)

                await bounded(two_acks(), 30.0, "two DO_SET_MODE acks")
                results = pairs()
                # receiver ACCEPTED, then TEMPORARILY_REJECTED, for one request; never accepted
                assert any(results[i:i + 2] == [0, 1] for i in range(len(results) - 1))

                async def refusal_text() -> None:
                    while not any("Offboard" in t.get("text", "") for t in texts.rows):
                        await asyncio.sleep(0.01)

                await bounded(refusal_text(), 15.0, "refusal STATUSTEXT")
            assert await d.telemetry.flight_mode() == FlightMode.HOLD
            await d.action.disarm()

    await asyncio.wait_for(body(), 60.0)


async def test_offboard_loss_failsafe_switches_to_position_mode() -> None:
    async def body() -> None:
        async with connect_drone(speed=SPEED) as d:
            await take_off(d)
            await d.offboard.set_position_ned(PositionNedYaw(0.0, 0.0, -3.0, 0.0))
            await d.offboard.start()
            await until(
                d.telemetry.flight_mode, lambda m: m == FlightMode.OFFBOARD, 5.0, "OFFBOARD"
            )
            async with recording(d, "STATUSTEXT") as texts:
                d.offboard.destroy()  # the setpoint stream stops without a mode change
                await until(
                    d.telemetry.flight_mode, lambda m: m == FlightMode.POSCTL, 10.0, "failsafe"
                )
                assert any("Failsafe activated" in t["text"] for t in texts.rows)
            # no RC: it sinks in Position mode, lands and disarms
            await until(d.telemetry.armed, lambda a: not a, 40.0, "landing after the failsafe")

    await asyncio.wait_for(body(), 90.0)


PLAN = {
    "fileType": "Plan",
    "version": 1,
    "groundStation": "QGroundControl",
    "geoFence": {"circles": [], "polygons": [], "version": 2},
    "rallyPoints": {"points": [], "version": 2},
    "mission": {
        "version": 2,
        "firmwareType": 12,
        "vehicleType": 2,
        "cruiseSpeed": 5,
        "hoverSpeed": 5,
        "plannedHomePosition": [47.397742, 8.545594, 488.0],
        "items": [
            {
                "type": "SimpleItem",
                "command": 22,
                "frame": 3,
                "doJumpId": 1,
                "autoContinue": True,
                "params": [0, 0, 0, None, 47.397742, 8.545594, 5],
                "Altitude": 5,
                "AltitudeMode": 1,
                "AMSLAltAboveTerrain": None,
            },
            {
                "type": "SimpleItem",
                "command": 16,
                "frame": 3,
                "doJumpId": 2,
                "autoContinue": True,
                "params": [0, 0, 0, None, 47.397877, 8.545594, 5],
                "Altitude": 5,
                "AltitudeMode": 1,
                "AMSLAltAboveTerrain": None,
            },
            {
                "type": "SimpleItem",
                "command": 178,
                "frame": 2,
                "doJumpId": 3,
                "autoContinue": True,
                "params": [1, 3, -1, 0, 0, 0, 0],
            },
            {
                "type": "SimpleItem",
                "command": 16,
                "frame": 3,
                "doJumpId": 4,
                "autoContinue": True,
                "params": [0, 0, 0, None, 47.397877, 8.545794, 5],
                "Altitude": 5,
                "AltitudeMode": 1,
                "AMSLAltAboveTerrain": None,
            },
            {
                "type": "SimpleItem",
                "command": 21,
                "frame": 3,
                "doJumpId": 5,
                "autoContinue": True,
                "params": [0, 0, 0, None, 47.397742, 8.545794, 0],
                "Altitude": 0,
                "AltitudeMode": 1,
                "AMSLAltAboveTerrain": None,
            },
        ],
    },
}


async def test_qgc_plan_upload_download_and_mission_flight(tmp_path: Path) -> None:
    plan_path = tmp_path / "square.plan"
    plan_path.write_text(json.dumps(PLAN))

    async def body() -> None:
        async with connect_drone(speed=SPEED) as d:
            imported = await d.mission_raw.import_qgroundcontrol_mission(str(plan_path))
            items = imported.mission_items
            assert [it.command for it in items] == [22, 16, 178, 16, 21]
            await d.mission_raw.upload_mission(items)
            back = await d.mission_raw.download_mission()
            assert [(it.seq, it.command, it.frame) for it in back] == [
                (it.seq, it.command, it.frame) for it in items
            ]
            for a, b in zip(back, items, strict=True):
                assert (a.x, a.y) == (b.x, b.y) and math.isclose(a.z, b.z, abs_tol=1e-4)
            await until(d.telemetry.health, lambda h: h.is_armable, 15.0, "armable")
            async with recording(d, "MISSION_ITEM_REACHED") as reached:
                await d.action.arm()
                await d.mission_raw.start_mission()
                await until(
                    d.telemetry.flight_mode, lambda m: m == FlightMode.MISSION, 5.0, "MISSION"
                )
                # the final LAND item lands and disarms (PX4 stays in MISSION, disarmed)
                await until(d.telemetry.armed, lambda a: not a, 90.0, "mission completion")
                seqs = {r["seq"] for r in reached.rows}
            assert {0, 1, 3, 4} <= seqs, seqs
            p = await d.telemetry.position()
            # landed at the LAND item's position (about 15 m east of home)
            assert abs(p.latitude_deg - 47.397742) < 2e-5
            assert abs(p.longitude_deg - 8.545794) < 3e-5
            progress = await d.mission_raw.mission_progress()
            assert progress.total == 5

    await asyncio.wait_for(body(), 120.0)


async def test_mission_transfer_and_arming_over_a_faulty_link(tmp_path: Path) -> None:
    """5 % loss, duplicates, reordering and latency both ways: retries on both sides cope.

    MAVSDK's own retries cover lost frames, and the mock answers duplicates as PX4 does
    (mavlink_mission.cpp: a second NACK or count does not end the upload). Three things end
    one MAVSDK upload, as they would against PX4: the final ACCEPTED lost (MAVSDK never sends
    the last item again, it times out: TIMEOUT); a duplicated item arriving after the upload
    finished gets MAV_MISSION_ERROR ("no transfer"), which reordering can deliver before the
    ACCEPTED (PROTOCOL_ERROR); duplicated requests counted as MAVSDK's retries (TIMEOUT). A
    ground station retries the upload then, and so does this one, at most three times
    (measured: 8 of 40 first uploads needed one retry, none needed two)."""
    plan_path = tmp_path / "lossy.plan"
    plan_path.write_text(json.dumps(PLAN))
    faults = ("--loss", "5", "--duplicate", "10", "--reorder", "10", "--latency", "0.02")

    async def body() -> None:
        async with connect_drone(*faults, "--seed", "7", speed=SPEED) as d:
            items = (
                await d.mission_raw.import_qgroundcontrol_mission(str(plan_path))
            ).mission_items
            for attempt in range(3):
                try:
                    await d.mission_raw.upload_mission(items)
                    break
                except MissionRawError as exc:
                    if attempt == 2 or exc.result not in (MissionRawResult.PROTOCOL_ERROR,
                                                          MissionRawResult.TIMEOUT):
                        raise
            back = await d.mission_raw.download_mission()
            assert [(it.seq, it.command, it.x, it.y) for it in back] == [
                (it.seq, it.command, it.x, it.y) for it in items
            ]
            await until(d.telemetry.health, lambda h: h.is_armable, 15.0, "armable")
            await d.action.arm()
            await until(d.telemetry.armed, bool, 5.0, "armed")
            await d.action.disarm()
            await until(d.telemetry.armed, lambda a: not a, 5.0, "disarmed")

    await asyncio.wait_for(body(), 60.0)
