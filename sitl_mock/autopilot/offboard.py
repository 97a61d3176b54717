"""Offboard input: SET_POSITION_TARGET_LOCAL_NED / SET_ATTITUDE_TARGET intake and its freshness.

PX4 v1.16 mavlink_receiver semantics. A valid setpoint becomes `target` and proves the offboard
link alive for COM_OF_LOSS_T seconds (`fresh`); the commander decides what a stale link means.
"""

from __future__ import annotations

import math
from collections import Counter, deque
from collections.abc import Callable
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from sitl_mock.autopilot.links import Link
from sitl_mock.autopilot.shared import Clock, Msg, StateView, addressed_to_us, finite
from sitl_mock.autopilot.telemetry import rotate_ned_to_body
from sitl_mock.params import ParamStore
from sitl_mock.setpoints import NAN3, AttitudeTarget, PositionTarget, Vec3, make_attitude_target


class OffboardInput:
    """The last offboard setpoint (`target`) and when it arrived (`last_t`, s since boot).

    `on_setpoint` runs after each accepted setpoint (the commander: the signal is back).
    """

    def __init__(
        self,
        clock: Clock,
        params: ParamStore,
        stats: Counter[str],
        view: StateView,
        statustext: Callable[[int, str], None],
    ) -> None:
        self.clock = clock
        self.params = params
        self.stats = stats
        self.view = view
        self.statustext = statustext
        self.last_t = -math.inf
        self.target: PositionTarget | AttitudeTarget | None = None
        # the newest of each kind (what PX4's controllers still fly while the commander's
        # control mode has not caught up with a change of kind: `Commander.offboard_target`)
        self.last_position: PositionTarget | None = None
        self.last_attitude: AttitudeTarget | None = None
        self.on_setpoint: Callable[[], None] = lambda: None
        # attitude/rates setpoints received, flown from SIM_SP_DELAY later: (due [s], target)
        self.pending: deque[tuple[float, AttitudeTarget]] = deque()

    @property
    def fresh(self) -> bool:
        """Offboard proof of life: a valid setpoint within COM_OF_LOSS_T."""
        return (self.clock.t - self.last_t) < float(self.params["COM_OF_LOSS_T"])

    def on_set_position_target_local_ned(self, link: Link, msg: Msg) -> None:
        """PX4 v1.16 mavlink_receiver semantics (frames LOCAL_NED 1 and BODY_NED 8 only)."""
        if not addressed_to_us(self.stats, msg.target_system, msg.target_component):
            return
        frame = msg.coordinate_frame
        if frame not in (mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_BODY_NED):
            self.stats["rx_invalid_setpoint"] += 1
            self.statustext(
                mavlink.MAV_SEVERITY_CRITICAL,
                f"SET_POSITION_TARGET_LOCAL_NED coordinate frame {frame} unsupported",
            )
            return
        mask = int(msg.type_mask)

        def pick(bits: tuple[int, int, int], vals: tuple[float, float, float]) -> Vec3:
            a, b, c = (
                math.nan if (mask & bit) or not math.isfinite(v) else float(v)
                for bit, v in zip(bits, vals, strict=True)
            )
            return (a, b, c)

        if frame == mavlink.MAV_FRAME_LOCAL_NED:
            pos = pick((1, 2, 4), (msg.x, msg.y, msg.z))
            vel = pick((8, 16, 32), (msg.vx, msg.vy, msg.vz))
            acc = pick((64, 128, 256), (msg.afx, msg.afy, msg.afz))
        else:
            # BODY_NED: positions ignored; velocity (all three or none) rotated by the heading,
            # acceleration (all three or none) rotated by the full attitude
            pos = NAN3
            vel = acc = NAN3
            if not mask & (8 | 16 | 32) and finite(msg.vx, msg.vy, msg.vz):
                yaw = self.view.state.yaw
                c, s = math.cos(yaw), math.sin(yaw)
                vel = (c * msg.vx - s * msg.vy, s * msg.vx + c * msg.vy, float(msg.vz))
            if not mask & (64 | 128 | 256) and finite(msg.afx, msg.afy, msg.afz):
                w, x, y, z = self.view.state.q_wxyz
                acc = rotate_ned_to_body((w, -x, -y, -z), (msg.afx, msg.afy, msg.afz))
        yaw = math.nan if mask & 1024 or not math.isfinite(msg.yaw) else float(msg.yaw)
        yaw_rate = (
            math.nan if mask & 2048 or not math.isfinite(msg.yaw_rate) else float(msg.yaw_rate)
        )
        target = PositionTarget(pos, vel, acc, yaw, yaw_rate)
        if any(math.isfinite(a) for a in acc) and mask & 512:
            self.stats["rx_invalid_setpoint"] += 1
            self.statustext(
                mavlink.MAV_SEVERITY_CRITICAL, "SET_POSITION_TARGET_LOCAL_NED force not supported"
            )
            return
        if not target.has_motion():
            self.stats["rx_invalid_setpoint"] += 1
            self.statustext(mavlink.MAV_SEVERITY_CRITICAL, "SET_POSITION_TARGET_LOCAL_NED invalid")
            return
        self._accept(target)

    def on_set_attitude_target(self, link: Link, msg: Msg) -> None:
        self.attitude_setpoint(
            msg.target_system,
            msg.target_component,
            msg.type_mask,
            msg.q,
            msg.body_roll_rate,
            msg.body_pitch_rate,
            msg.body_yaw_rate,
            msg.thrust,
        )

    def attitude_setpoint(
        self,
        target_system: int,
        target_component: int,
        type_mask: int,
        q: Any,
        body_roll_rate: float,
        body_pitch_rate: float,
        body_yaw_rate: float,
        thrust_norm: float,
    ) -> None:
        """SET_ATTITUDE_TARGET fields (PX4 v1.16 mavlink_receiver semantics): q (w, x, y, z)
        body FRD -> NED, body rates [rad/s FRD], thrust 0..1; ignore bits in `type_mask`."""
        if not addressed_to_us(self.stats, target_system, target_component):
            return
        mask = int(type_mask)
        q_wxyz = None
        if not mask & 128:
            q0, q1, q2, q3 = q
            q0, q1, q2, q3 = float(q0), float(q1), float(q2), float(q3)
            isfinite = math.isfinite
            n = (
                math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
                if isfinite(q0) and isfinite(q1) and isfinite(q2) and isfinite(q3)
                else 0.0
            )
            if not n > 1e-6:
                self.stats["rx_invalid_setpoint"] += 1
                return
            q_wxyz = (q0 / n, q1 / n, q2 / n, q3 / n)
        rates = None
        if not (mask & 1) and not (mask & 2):
            r = (body_roll_rate, body_pitch_rate, 0.0 if mask & 4 else body_yaw_rate)
            if not finite(*r):
                self.stats["rx_invalid_setpoint"] += 1
                return
            rates = (float(r[0]), float(r[1]), float(r[2]))
        thrust = float(thrust_norm)
        if (q_wxyz is None and rates is None) or mask & 64 or not math.isfinite(thrust):
            self.stats["rx_invalid_setpoint"] += 1
            return
        yaw_ff = math.nan
        if q_wxyz is not None and not mask & 4 and math.isfinite(body_yaw_rate):
            yaw_ff = float(body_yaw_rate)
        target = make_attitude_target(q_wxyz, min(max(thrust, 0.0), 1.0), rates, yaw_ff)
        self._accept(target)

    def control_mode(self) -> None:
        """An offboard_control_mode publication inside the autopilot (the onboard module,
        `sitl_mock.onboard`): the offboard signal, as a streamed setpoint proves it."""
        self.last_t = self.clock.t
        self.on_setpoint()

    def module_attitude(self, target: AttitudeTarget) -> None:
        """A vehicle_attitude_setpoint published inside the autopilot (the onboard module):
        flown in OFFBOARD as an offboard attitude setpoint (not a received message)."""
        self.target = target
        self.last_attitude = target

    def _accept(self, target: PositionTarget | AttitudeTarget) -> None:
        self.stats["rx_setpoints"] += 1
        self.last_t = self.clock.t
        delay = float(self.params["SIM_SP_DELAY"])
        if delay > 0.0 and isinstance(target, AttitudeTarget):
            self.pending.append((self.clock.t + delay, target))
            self.release()
        else:
            self.pending.clear()
            self._fly(target)
        self.on_setpoint()

    def _fly(self, target: PositionTarget | AttitudeTarget) -> None:
        self.target = target
        if isinstance(target, PositionTarget):
            self.last_position = target
        else:
            self.last_attitude = target

    def release(self) -> None:
        """The attitude/rates setpoints due by now become `target` (SIM_SP_DELAY; each physics
        step calls this before the controllers run)."""
        pending, t = self.pending, self.clock.t
        while pending and pending[0][0] <= t + 1e-9:
            self._fly(pending.popleft()[1])
