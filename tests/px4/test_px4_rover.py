"""PX4 built from main driving SIH's Ackermann rover (fixture `px4_rover`), through the offboard
interface that tracked best in bench/bench_rover_interfaces.py: SET_POSITION_TARGET_LOCAL_NED
with vx, vy only (PX4's rover takes speed = |(vx, vy)| and course = their direction; yaw and
yaw rate are ignored). A ground station on pymavlink only (tests.support.gcs), independent of
the companion; oracles are PX4's own HEARTBEAT, COMMAND_ACKs, LOCAL_POSITION_NED and ATTITUDE.
Every wait is bounded; the streaming task is cancelled and the socket closed on every path.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import time
from collections.abc import AsyncIterator
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import common as mavlink2

from px4_harness import Px4Sitl
from tests.support.gcs import Gcs, ground_station

VEL_MASK = 3559  # vx, vy used; x, y, z, vz, acceleration, yaw, yaw rate ignored
MAV_TYPE_GROUND_ROVER = 10
MAV_STATE_CRITICAL = 5
SETPOINT_HZ = 20.0


@dataclass
class VelocityStream:
    """Streams SET_POSITION_TARGET_LOCAL_NED (vx, vy) at 20 Hz while running."""

    gcs: Gcs
    vel_ne: tuple[float, float] = (0.0, 0.0)
    sent: int = 0
    last_sent: float = 0.0  # monotonic time of the last setpoint
    running: bool = True
    _task: asyncio.Task[None] | None = field(default=None, repr=False)

    async def _run(self) -> None:
        while self.running:
            if self.gcs.peer is not None:
                self.gcs.send(mavlink2.MAVLink_set_position_target_local_ned_message(
                    0, self.gcs.target_system, 1, 1, VEL_MASK, 0.0, 0.0, 0.0,
                    self.vel_ne[0], self.vel_ne[1], 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))
                self.sent += 1
                self.last_sent = time.monotonic()
            await asyncio.sleep(1.0 / SETPOINT_HZ)  # the stream's own period, not a wait

    def stop(self) -> None:
        """Stop sending (the offboard link goes silent); returns at once."""
        self.running = False
        if self._task is not None:
            self._task.cancel()


@contextlib.asynccontextmanager
async def velocity_stream(gcs: Gcs) -> AsyncIterator[VelocityStream]:
    stream = VelocityStream(gcs)
    stream._task = asyncio.create_task(stream._run())
    try:
        yield stream
    finally:
        stream.stop()
        with contextlib.suppress(asyncio.CancelledError):
            await stream._task


async def rover_ready(gcs: Gcs) -> None:
    await gcs.wait_for(lambda: gcs.heartbeat is not None and gcs.position is not None
                       and gcs.attitude is not None, 20.0, "PX4's HEARTBEAT, position, attitude")


async def arm_in_hold(gcs: Gcs, timeout_s: float = 30.0) -> None:
    """ARM, retried: PX4 main's rover refuses until its estimator is ready (~2-6 s after
    start); bounded by `timeout_s`."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if await gcs.command(400, 1.0) == 0:
            await gcs.wait_for(lambda: gcs.armed, 3.0, "the HEARTBEAT to show armed")
            return
        await asyncio.sleep(1.0)  # PX4 is not ready yet: ask again in a second (bounded)
    raise AssertionError(f"the rover did not arm within {timeout_s} s; texts {gcs.texts[-5:]}")


async def enter_offboard(gcs: Gcs, stream: VelocityStream) -> None:
    """Arm in Hold with > 1 s of setpoints behind us, then DO_SET_MODE OFFBOARD."""
    await arm_in_hold(gcs)
    await gcs.wait_for(lambda: stream.sent >= 1.2 * SETPOINT_HZ, 5.0, "1.2 s of setpoints")
    assert await gcs.set_mode("OFFBOARD") == 0, "PX4 refused OFFBOARD on velocity setpoints"
    await gcs.wait_for(lambda: gcs.mode == "OFFBOARD", 3.0, "the HEARTBEAT to show OFFBOARD")


def frame(start: tuple[float, ...], heading: float, p: tuple[float, ...]) -> tuple[float, float]:
    """(along, cross) [m] of NED point `p` from `start` along `heading` (cross + = right)."""
    dn, de = p[0] - start[0], p[1] - start[1]
    return (dn * math.cos(heading) + de * math.sin(heading),
            -dn * math.sin(heading) + de * math.cos(heading))


async def drive_straight(gcs: Gcs, stream: VelocityStream, start: tuple[float, ...],
                         heading: float, speed: float, until_m: float, timeout_s: float) -> bool:
    """Drive along `heading` from `start` at `speed`, steering the velocity's direction back
    onto the line, until `until_m` along; bounded. Course = heading - atan(cross) - 0.3 *
    integral(cross): PX4 steers its heading estimate, which can be ~10 deg off at first (with
    atan(0.5 cross) alone the rover ran up to 0.33 m off the line)."""
    deadline = time.monotonic() + timeout_s
    integral, period = 0.0, 1.0 / SETPOINT_HZ
    while time.monotonic() < deadline:
        pos = gcs.position
        assert pos is not None
        along, cross = frame(start, heading, pos)
        if along >= until_m:
            return True
        integral = min(max(integral + cross * period, -1.0), 1.0)
        course = heading - math.atan(cross) - 0.3 * integral
        stream.vel_ne = (speed * math.cos(course), speed * math.sin(course))
        await asyncio.sleep(period)  # the steering loop's period
    return False


async def test_px4_rover_offboard_velocity_drives_a_straight_leg(px4_rover: Px4Sitl) -> None:
    """Arms, enters OFFBOARD on vx/vy setpoints and drives 12 m along its heading at 1.5 m/s:
    never more than 0.5 m off the line (PX4's estimate; the bench's loop stayed within
    0.23-0.39 m on its 20 m leg and turn at 2 m/s), in 5-12 s, and stops within 2 m past the
    mark once the setpoint is (0, 0) (PX4 overshoots 1.5 m/s by 10-20 % and brakes at
    RO_DECEL_LIM 3 m/s^2 with RO_JERK_LIM 10 m/s^3: measured 1.0-1.1 m past the mark)."""
    leg_m, speed = 12.0, 1.5
    async with ground_station(px4_rover.port, px4_rover.target_system) as gcs, \
            velocity_stream(gcs) as stream:
        await rover_ready(gcs)
        assert gcs.heartbeat.type == MAV_TYPE_GROUND_ROVER
        await enter_offboard(gcs, stream)
        start = gcs.position
        assert start is not None
        heading = float(gcs.attitude.yaw)
        n0 = len(gcs.track)
        t0 = time.monotonic()
        reached = await drive_straight(gcs, stream, start, heading, speed, leg_m, 20.0)
        t_leg = time.monotonic() - t0
        leg = gcs.track[n0:]
        stream.vel_ne = (0.0, 0.0)
        t_zero, n_zero = time.monotonic(), len(gcs.track)
        await gcs.wait_for(lambda: gcs.track[-1].t >= t_zero + 3.0, 5.0,
                           "3 s of positions after the zero setpoint")
        after = gcs.track[n_zero:]
        modes = {s.mode for s in leg}
    crosses = [abs(frame(start, heading, s.pos_ned)[1]) for s in leg]
    alongs = [frame(start, heading, s.pos_ned)[0] for s in after]
    # standing, PX4's estimate wanders (0.2-0.5 m in 3 s on SIH): the stop is the furthest
    # point reached, and "stopped" means less than 0.4 m in the last second
    last = [a for s, a in zip(after, alongs, strict=True) if s.t >= t_zero + 2.0]
    stop_along = max(alongs, default=math.nan)
    print(f"leg {t_leg:.1f} s, cross-track max {max(crosses, default=math.nan):.2f} m, "
          f"stopped {stop_along:.2f} m along, last second {max(last) - min(last):.2f} m")
    assert reached, f"did not cover {leg_m} m in 20 s (reached {stop_along:.1f} m)"
    # 12 m at 1.5 m/s is 8 s; PX4 overshoots the speed by 10-20 % and ramps at 3 m/s^2
    assert 5.0 < t_leg < 12.0, f"{leg_m} m took {t_leg:.1f} s at a {speed} m/s setpoint"
    assert len(crosses) > 100  # ~30 Hz over the leg
    assert max(crosses) <= 0.5, f"cross-track up to {max(crosses):.2f} m"
    assert leg_m <= stop_along <= leg_m + 2.0, f"stopped {stop_along:.2f} m along"
    assert len(last) > 10 and max(last) - min(last) < 0.4, "still driving 2 s after (0, 0)"
    assert modes == {"OFFBOARD"}, f"left OFFBOARD during the leg: {modes}"
    assert all(s.armed for s in leg)


async def test_px4_rover_offboard_loss_returns_to_launch_and_disarms(px4_rover: Px4Sitl
                                                                    ) -> None:
    """What PX4 main does on the rover when the offboard stream stops (default parameters:
    COM_OF_LOSS_T 1 s, COM_OBL_RC_ACT 0 "position mode", which without RC falls back): after
    the 1 s timeout the HEARTBEAT shows AUTO.RTL with system_status CRITICAL, the rover drives
    back to where it was armed (home) and disarms there (measured: RTL 1.7 s after the last
    setpoint, disarmed at home ~8 s later from 14 m out)."""
    async with ground_station(px4_rover.port, px4_rover.target_system) as gcs, \
            velocity_stream(gcs) as stream:
        await rover_ready(gcs)
        home = gcs.position
        assert home is not None
        heading = float(gcs.attitude.yaw)
        await enter_offboard(gcs, stream)
        reached = await drive_straight(gcs, stream, home, heading, 2.0, 6.0, 15.0)
        assert reached, "did not drive 6 m out before the loss"
        stream.stop()
        t_last = stream.last_sent
        out = gcs.position
        assert out is not None
        far = math.hypot(out[0] - home[0], out[1] - home[1])
        await gcs.wait_for(lambda: gcs.mode != "OFFBOARD", 4.0, "PX4 to leave OFFBOARD")
        t_leave = gcs.heartbeat_t - t_last
        mode, status = gcs.mode, gcs.heartbeat.system_status
        n_loss = len(gcs.track)
        await gcs.wait_for(lambda: not gcs.armed, 30.0, "the rover to disarm")
        after = gcs.track[n_loss:]
        end = gcs.position
        assert end is not None
    dist = [math.hypot(s.pos_ned[0] - home[0], s.pos_ned[1] - home[1]) for s in after]
    print(f"left OFFBOARD for {mode} (status {status}) {t_leave:.2f} s after the last "
          f"setpoint, {far:.1f} m out; closest to home afterwards {min(dist, default=math.nan):.2f}"
          f" m; disarmed {len(after) and after[-1].t - t_last:.1f} s after the last setpoint")
    # PX4 waits out COM_OF_LOSS_T (1 s) before the failsafe; HEARTBEATs come at 1 Hz
    assert 0.95 <= t_leave <= 3.0, f"left OFFBOARD {t_leave:.2f} s after the last setpoint"
    assert mode == "RTL", f"offboard-loss failsafe went to {mode}"
    assert status == MAV_STATE_CRITICAL
    assert far > 5.0
    assert min(dist) < 1.5 and math.hypot(end[0] - home[0], end[1] - home[1]) < 1.5, (
        f"did not return home: {far:.1f} m out, ended {dist[-1]:.1f} m from home")
    assert {s.mode for s in after if s.armed} <= {"RTL"}, "changed mode before disarming"
