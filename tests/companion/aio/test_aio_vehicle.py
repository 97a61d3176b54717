"""Vehicle façade against a scripted PX4 stand-in on loopback UDP: failures surface as
exceptions carrying the MAVLink result; the stream never carries an invalid setpoint and stops
when it must."""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import AsyncIterator
from dataclasses import dataclass, field
from typing import Any

import pytest
from pymavlink.dialects.v20 import common as m

from companion.aio import (
    CommandError,
    OffboardError,
    SetpointSourceError,
    TelemetryStaleError,
    Vehicle,
    VehicleConfig,
    VehicleError,
)
from companion.mavlink import FlightMode, PositionSetpoint, TelemetrySnapshot, custom_mode_of


@dataclass
class Script:
    arm_result: int = 0
    disarm_result: int = 0
    reject_offboard: bool = False
    landed_state: int | None = None  # EXTENDED_SYS_STATE sent when set
    touchdown_s: float = 0.3  # after a LAND request: landed_state 1 (on ground) this much later
    auto_disarm_s: float | None = None  # after touchdown: PX4's COM_DISARM_LAND (None: never)
    send_position: bool = True
    # acknowledge a disarm only once a setpoint arrived after it (a stream that stops when the
    # disarm is sent then never sees its ACK)
    disarm_ack_after_setpoint: bool = False
    received: list[Any] = field(default_factory=list)


class FakePx4(asyncio.DatagramProtocol):
    """Minimal PX4 behaviour: HEARTBEAT 20 Hz, LOCAL_POSITION_NED 30 Hz, ARM and DO_SET_MODE
    with PX4's double acknowledgement."""

    def __init__(self, script: Script) -> None:
        self.s = script
        self.mav = m.MAVLink(None, srcSystem=1, srcComponent=1)
        self.parser = m.MAVLink(None)
        self.parser.robust_parsing = True
        self.peer: Any = None
        self.tr: Any = None
        self.armed = False
        self.custom_mode = custom_mode_of(FlightMode.HOLD)
        self.held_disarm: Any = None

    def connection_made(self, transport: Any) -> None:
        self.tr = transport

    def send(self, msg: Any) -> None:
        if self.peer is not None:
            self.tr.sendto(bytes(msg.pack(self.mav)), self.peer)

    def datagram_received(self, data: bytes, addr: Any) -> None:
        self.peer = addr
        for msg in self.parser.parse_buffer(data) or []:
            self.s.received.append(msg)
            if msg.get_type() == "COMMAND_LONG":
                self.on_command(msg)
            elif self.held_disarm is not None and msg.get_type().startswith("SET_"):
                held, self.held_disarm = self.held_disarm, None
                self.on_command(held, hold=False)

    def on_command(self, c: Any, hold: bool = True) -> None:
        loop = asyncio.get_running_loop()
        if c.command == 400 and c.param1 == 0 and hold and self.s.disarm_ack_after_setpoint:
            self.held_disarm = c
        elif c.command == 400:
            result = self.s.arm_result if c.param1 == 1 else self.s.disarm_result
            self.send(m.MAVLink_command_ack_message(400, result, 0, 0, 1, 191))
            if result == 0:
                self.armed = c.param1 == 1
        elif c.command == 21:  # NAV_LAND: touchdown, then (maybe) PX4's own auto-disarm
            self.send(m.MAVLink_command_ack_message(21, 0, 0, 0, 1, 191))
            self.custom_mode = custom_mode_of(FlightMode.LAND)
            loop.call_later(self.s.touchdown_s, self.touchdown)
        elif c.command == 176:
            self.send(m.MAVLink_command_ack_message(176, 0, 0, 0, 1, 191))
            target = (int(c.param2) << 16) | (int(c.param3) << 24)
            if target == custom_mode_of(FlightMode.OFFBOARD) and self.s.reject_offboard:
                loop.call_later(0.01, self.send, m.MAVLink_statustext_message(
                    4, b"Switching to Offboard is currently not available"))
                loop.call_later(0.01, self.send,
                                m.MAVLink_command_ack_message(176, 1, 0, 0, 1, 191))
            else:
                self.custom_mode = target
                loop.call_later(0.01, self.send,
                                m.MAVLink_command_ack_message(176, 0, 0, 0, 1, 191))

    def touchdown(self) -> None:
        self.s.landed_state = 1
        if self.s.auto_disarm_s is not None:
            asyncio.get_running_loop().call_later(self.s.auto_disarm_s, self.auto_disarm)

    def auto_disarm(self) -> None:
        self.armed = False

    async def run(self) -> None:
        k = 0
        t0 = time.monotonic()
        while True:
            k += 1
            if k % 6 == 0 and self.s.landed_state is not None:
                self.send(m.MAVLink_extended_sys_state_message(0, self.s.landed_state))
            if k % 3 == 0:
                self.send(m.MAVLink_heartbeat_message(
                    2, 12, 29 | (128 if self.armed else 0), self.custom_mode, 4, 3))
            if k % 2 == 0 and self.s.send_position:
                boot_ms = int((time.monotonic() - t0) * 1000.0)  # a clock at PX4's pace
                self.send(m.MAVLink_local_position_ned_message(boot_ms, 1.0, 2.0, -3.0, 0, 0, 0))
            await asyncio.sleep(1 / 60)


@pytest.fixture
async def px4() -> AsyncIterator[tuple[Script, int, FakePx4]]:
    script = Script()
    loop = asyncio.get_running_loop()
    tr, proto = await loop.create_datagram_endpoint(lambda: FakePx4(script),
                                                    local_addr=("127.0.0.1", 0))
    task = loop.create_task(proto.run())
    try:
        yield script, tr.get_extra_info("sockname")[1], proto
    finally:
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        tr.close()


CFG = VehicleConfig(connect_timeout_s=5.0, armable_timeout_s=2.0, rate_hz=50.0,
                    stale_telemetry_s=0.3, stale_abort_s=0.5, land_timeout_s=5.0)


def setpoints(script: Script) -> list[Any]:
    return [x for x in script.received if x.get_type() == "SET_POSITION_TARGET_LOCAL_NED"]


def mode_requests(script: Script, main: int) -> list[Any]:
    return [x for x in script.received
            if x.get_type() == "COMMAND_LONG" and x.command == 176 and x.param2 == main]


async def test_arm_denied_raises_with_result(px4: tuple[Script, int, FakePx4]) -> None:
    script, port, _ = px4
    script.arm_result = 2
    async with Vehicle.connect(f"udpout://127.0.0.1:{port}", config=CFG) as v:
        with pytest.raises(CommandError) as info:
            await v.arm()
        assert info.value.result == 2 and "DENIED" in str(info.value)


async def test_offboard_refused_after_double_ack(px4: tuple[Script, int, FakePx4]) -> None:
    script, port, _ = px4
    script.reject_offboard = True
    async with Vehicle.connect(f"udpout://127.0.0.1:{port}", config=CFG) as v:
        await v.arm()
        with pytest.raises(OffboardError) as info:
            await v.fly(setpoint_source=lambda t, tel: PositionSetpoint(pos_ned=(1.0, 2.0, -3.0)),
                        duration_s=5.0)
        assert info.value.result == 1
        assert "currently not available" in str(info.value)
        raised_ms = v.link.time_boot_ms(time.monotonic())
        assert len(setpoints(script)) >= 20  # it was primed before asking
        # Observe the link for 0.3 s: frames already in flight at the raise may still arrive,
        # but none may have been stamped after it (the stream stopped).
        await asyncio.sleep(0.3)
        stamps = [x.time_boot_ms for x in setpoints(script)]
        assert max(stamps) <= raised_ms + 1, (max(stamps), raised_ms)
        assert len([r for r in mode_requests(script, 6) if r.confirmation == 0]) == 1


async def test_invalid_setpoint_never_sent_then_hold(px4: tuple[Script, int, FakePx4]) -> None:
    script, port, _ = px4
    t_bad = 0.3

    def source(t: float, tel: TelemetrySnapshot) -> PositionSetpoint:
        x = math.nan if t > t_bad else 1.0
        return PositionSetpoint(pos_ned=(x, 2.0, -3.0), vel_ned=(0.0, 0.0, 0.0))

    async with Vehicle.connect(f"udpout://127.0.0.1:{port}", config=CFG) as v:
        await v.arm()
        with pytest.raises(SetpointSourceError, match="not finite"):
            await v.fly(setpoint_source=source, duration_s=5.0)
        assert v.mode is FlightMode.HOLD
    sps = setpoints(script)
    assert sps and all(math.isfinite(s.x) for s in sps)
    assert mode_requests(script, 4)  # Hold requested
    # after the failure the stand-in got hold setpoints at the vehicle position, at rest
    assert any(s.vx == 0.0 and s.x == 1.0 and s.type_mask & 8 == 0 for s in sps)


async def test_stale_position_holds_then_reports(px4: tuple[Script, int, FakePx4]) -> None:
    script, port, _ = px4
    async with Vehicle.connect(f"udpout://127.0.0.1:{port}", config=CFG) as v:
        await v.arm()

        async def stop_position_later() -> None:
            async for mode in v.flight_mode():
                if mode is FlightMode.OFFBOARD:
                    await asyncio.sleep(0.3)
                    script.send_position = False
                    return

        task = asyncio.get_running_loop().create_task(stop_position_later())
        try:
            with pytest.raises(TelemetryStaleError):
                await v.fly(setpoint_source=lambda t, tel: PositionSetpoint(
                    pos_ned=(1.0 + t, 2.0, -3.0)), duration_s=10.0)
        finally:
            task.cancel()
        assert v.mode is FlightMode.HOLD
    sps = setpoints(script)
    # the last setpoints are the hold setpoint: last known position, zero velocity
    assert sps[-1].x == 1.0 and sps[-1].vx == 0.0


async def test_telemetry_streams(px4: tuple[Script, int, FakePx4]) -> None:
    _, port, fake = px4
    async with Vehicle.connect(f"udpout://127.0.0.1:{port}", config=CFG) as v:
        positions = []
        async for p in v.position():
            positions.append(p)
            if len(positions) == 3:
                break
        assert [p.pos_ned for p in positions] == [(1.0, 2.0, -3.0)] * 3
        assert positions[0].t_s < positions[2].t_s
        modes = v.flight_mode()
        assert await anext(modes) is FlightMode.HOLD  # current mode first
        fake.custom_mode = custom_mode_of(FlightMode.MISSION)
        assert await asyncio.wait_for(anext(modes), 2.0) is FlightMode.MISSION
        await modes.aclose()  # type: ignore[attr-defined]
        armed = v.armed()
        assert await anext(armed) is False
        await v.arm()
        assert await asyncio.wait_for(anext(armed), 2.0) is True
        await armed.aclose()  # type: ignore[attr-defined]


async def test_tcp_link_is_reopened_after_the_peer_closes() -> None:
    mav = m.MAVLink(None, srcSystem=1, srcComponent=1)
    conns: list[asyncio.StreamWriter] = []

    async def handle(r: asyncio.StreamReader, w: asyncio.StreamWriter) -> None:
        conns.append(w)
        try:
            for _ in range(400):
                w.write(bytes(m.MAVLink_heartbeat_message(2, 12, 29, 50593792, 3, 3).pack(mav)))
                await w.drain()
                await asyncio.sleep(0.05)
        except (ConnectionError, OSError):
            pass

    srv = await asyncio.start_server(handle, "127.0.0.1", 0)
    port = srv.sockets[0].getsockname()[1]
    try:
        async with Vehicle.connect(f"tcp://127.0.0.1:{port}", config=CFG) as v:
            assert v.mode is FlightMode.HOLD
            conns[0].close()  # the autopilot side drops the TCP connection
            for _ in range(100):
                if not v.link_ok:
                    break
                await asyncio.sleep(0.01)
            assert not v.link_ok  # the dropped transport counts as a lost link at once
            for _ in range(100):
                if len(conns) >= 2 and v.link_ok:
                    break
                await asyncio.sleep(0.05)
            assert len(conns) == 2  # the companion reconnected
            assert v.link_ok  # ... and saw the autopilot again (LinkLost then LinkUp)
            assert v.link.heartbeat.last is not None
            t_before = v.link.heartbeat.last.t_s
            await asyncio.sleep(0.3)
            assert v.link.heartbeat.last.t_s > t_before  # heartbeats flow on the new socket
    finally:
        for w in conns:
            w.close()
        srv.close()
        await srv.wait_closed()


def commands(script: Script, command: int) -> list[Any]:
    return [x for x in script.received
            if x.get_type() == "COMMAND_LONG" and x.command == command and x.confirmation == 0]


async def test_fly_arm_in_offboard_refused_stops_stream_disarmed(
        px4: tuple[Script, int, FakePx4]) -> None:
    script, port, fake = px4
    script.arm_result = 2
    script.landed_state = 1
    async with Vehicle.connect(f"udpout://127.0.0.1:{port}", config=CFG) as v:
        with pytest.raises(CommandError) as info:
            await v.fly(setpoint_source=lambda t, tel: PositionSetpoint(pos_ned=(1.0, 2.0, -3.0)),
                        duration_s=5.0, arm=True)
        assert info.value.result == 2
        raised_ms = v.link.time_boot_ms(time.monotonic())
        assert not fake.armed and v.mode is FlightMode.HOLD  # back to a mode that can arm
    # OFFBOARD requested before the ARM, which followed the primed stream
    sent = [x for x in script.received if x.get_type() in ("COMMAND_LONG",
                                                           "SET_POSITION_TARGET_LOCAL_NED")]
    kinds = [("sp" if x.get_type() != "COMMAND_LONG" else (x.command, x.param2)) for x in sent]
    i_off = kinds.index((176, 6.0))
    i_arm = kinds.index((400, 0.0))
    assert kinds[:i_off].count("sp") >= 20 and i_off < i_arm
    assert max(x.time_boot_ms for x in setpoints(script)) <= raised_ms + 1


async def test_fly_arm_refuses_an_armed_vehicle(px4: tuple[Script, int, FakePx4]) -> None:
    script, port, _ = px4
    async with Vehicle.connect(f"udpout://127.0.0.1:{port}", config=CFG) as v:
        await v.arm()
        with pytest.raises(VehicleError, match="already armed"):
            await v.fly(setpoint_source=lambda t, tel: PositionSetpoint(pos_ned=(1.0, 2.0, -3.0)),
                        duration_s=5.0, arm=True)
    assert not setpoints(script) and not mode_requests(script, 6)


async def test_land_disarms_once_on_ground(px4: tuple[Script, int, FakePx4]) -> None:
    script, port, fake = px4
    script.landed_state = 2  # in air
    async with Vehicle.connect(f"udpout://127.0.0.1:{port}", config=CFG) as v:
        await v.arm()
        t0 = time.monotonic()
        await v.land()
        assert time.monotonic() - t0 >= script.touchdown_s
        assert not fake.armed and not v.is_armed
    disarms = [x for x in commands(script, 400) if x.param1 == 0.0]
    assert len(disarms) == 1 and disarms[0].param2 == 0.0  # never forced


async def test_land_waits_for_px4_disarm_when_the_disarm_is_refused(
        px4: tuple[Script, int, FakePx4]) -> None:
    script, port, fake = px4
    script.landed_state = 2
    script.disarm_result = 1  # TEMPORARILY_REJECTED: PX4 not sure yet
    script.auto_disarm_s = 0.4
    async with Vehicle.connect(f"udpout://127.0.0.1:{port}", config=CFG) as v:
        await v.arm()
        t0 = time.monotonic()
        await v.land()
        assert time.monotonic() - t0 >= script.touchdown_s + script.auto_disarm_s
        assert not v.is_armed
    assert len([x for x in commands(script, 400) if x.param1 == 0.0]) == 1
    assert fake.custom_mode == custom_mode_of(FlightMode.LAND)


async def test_touchdown_without_a_detected_landing_hands_over_to_land(
        px4: tuple[Script, int, FakePx4]) -> None:
    script, port, fake = px4
    script.landed_state = 2  # PX4 never reports the landing
    cfg = VehicleConfig(connect_timeout_s=5.0, armable_timeout_s=2.0, rate_hz=50.0,
                        touchdown_timeout_s=0.5)
    async with Vehicle.connect(f"udpout://127.0.0.1:{port}", config=cfg) as v:
        await v.arm()
        t0 = time.monotonic()
        await v.fly(setpoint_source=lambda t, tel: PositionSetpoint(pos_ned=(1.0, 2.0, -3.0)),
                    duration_s=0.3, end_action="touchdown")
        assert time.monotonic() - t0 >= 0.3 + 0.5
        assert fake.custom_mode == custom_mode_of(FlightMode.LAND) and fake.armed
    assert not [x for x in commands(script, 400) if x.param1 == 0.0]  # never disarmed in air


async def test_touchdown_disarms_once_on_ground_while_still_streaming(
        px4: tuple[Script, int, FakePx4]) -> None:
    script, port, fake = px4
    script.landed_state = 1  # on ground by the end of the trajectory
    script.disarm_ack_after_setpoint = True
    async with Vehicle.connect(f"udpout://127.0.0.1:{port}", config=CFG) as v:
        await v.arm()
        await v.fly(setpoint_source=lambda t, tel: PositionSetpoint(pos_ned=(1.0, 2.0, -3.0)),
                    duration_s=0.3, end_action="touchdown")
        assert not fake.armed and not v.is_armed
    disarm = [x for x in commands(script, 400) if x.param1 == 0.0]
    assert len(disarm) == 1
    sps = [x for x in script.received if x.get_type() == "SET_POSITION_TARGET_LOCAL_NED"]
    i_disarm = script.received.index(disarm[0])
    assert any(script.received.index(sp) > i_disarm for sp in sps)  # streamed through it
    assert not mode_requests(script, 4)  # no LAND or Hold request
