"""The onboard module (gen_c/px4_module) hosted by the mock as ecca_onboard.c hosts it in PX4.

The module's logic is the same C (ecca_onboard_core.c through `gen_c.onboard_native`); this file
is the mock's counterpart of the PX4 glue, ecca_onboard.c's `task_main`, step for step:

- MAVLink DEBUG_FLOAT_ARRAY becomes uORB debug_array, which holds one message: the module takes
  the newest at its next cycle (those in between are lost, as in PX4), named ``ecca`` only;
- every 4 ms (250 Hz, on the autopilot's clock: `hrt_absolute_time`, whole microseconds since
  boot) it steps the core on vehicle_local_position and vehicle_attitude (the mock's estimate,
  `vehicle.state`: position, velocity, attitude; a fresh sample every cycle) and vehicle_status
  (armed in OFFBOARD);
- `publish_mode` is an offboard_control_mode publication: the commander's offboard signal
  (`OffboardInput.control_mode`), so OFFBOARD and arming are accepted as with a setpoint stream;
- the setpoint (while armed in OFFBOARD) is a vehicle_attitude_setpoint: q_d, thrust,
  yaw_sp_move_rate, flown by the mock's attitude controller like an offboard attitude setpoint;
- the final action is a vehicle_command DO_SET_MODE (AUTO: LAND 6, RTL 5, LOITER 3);
- its acknowledgements are vehicle_command_ack, which PX4's mavlink sends on every link as
  COMMAND_ACK (progress = the module's state, result_param2 = its value) to the module's peer;
  a status report (and, once flown, the start report on the autopilot's clock) every 0.5 s
  while it has a peer.

Imports `gen_c.onboard_native` (ctypes, nothing from ``companion``); the C is compiled at first
use into gen_c's cache (`build_onboard_library`) and loaded once per process.
"""

from __future__ import annotations

import functools
import math
from collections import Counter
from collections.abc import Callable
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from gen_c.onboard_native import OnboardAck, OnboardLibrary, OnboardModule, build_onboard_library
from sitl_mock.autopilot.links import Link, Links
from sitl_mock.autopilot.shared import Clock, StateView
from sitl_mock.setpoints import make_attitude_target

PROTO_NAME = "ecca"  # ECCA_PROTO_NAME
PERIOD_US = 4000  # ECCA_PERIOD_US: 250 Hz
STATUS_US = 500000  # ECCA_STATUS_US: a status report every 0.5 s
ACK_CRC = 31011  # ECCA_ACK_CRC
#: ECCA_FINAL_* -> PX4 AUTO sub mode of the DO_SET_MODE the module commands (LAND, RTL, LOITER)
FINAL_SUB_MODE = {1: 6.0, 2: 5.0}
LOITER_SUB_MODE = 3.0
EV_START_REFUSED = 5
EV_TEXT = {1: "flying the trajectory", 2: "trajectory done: holding its end point",
           3: "final action commanded", 4: "OFFBOARD left: trajectory stopped"}


@functools.cache
def onboard_library() -> OnboardLibrary:
    """The compiled onboard core, built (into gen_c's cache, reused across processes) and
    loaded once per process (gen_c.native.NativeBuildError without a C compiler)."""
    return OnboardLibrary(build_onboard_library())


class OnboardHost:
    """The module's task inside the mock (see the module docstring).

    offboard_state(): (armed in OFFBOARD, position and velocity valid); control_mode(): an
    offboard_control_mode publication; attitude(target): a vehicle_attitude_setpoint;
    set_mode(base, main, sub): a vehicle_command DO_SET_MODE; log(severity, text): the
    module's console line (PX4_INFO / PX4_ERR).
    """

    def __init__(
        self,
        clock: Clock,
        view: StateView,
        links: Links,
        stats: Counter[str],
        offboard_state: Callable[[], tuple[bool, bool]],
        control_mode: Callable[[], None],
        attitude: Callable[[Any], None],
        set_mode: Callable[[float, float, float], int],
        log: Callable[[int, str], None],
        module: OnboardModule | None = None,
    ) -> None:
        self.clock = clock
        self.view = view
        self.links = links
        self.stats = stats
        self.offboard_state = offboard_state
        self.control_mode = control_mode
        self.attitude = attitude
        self.set_mode = set_mode
        self.log = log
        self.module = module if module is not None else OnboardModule(onboard_library())
        self._debug_array: tuple[int, list[float]] | None = None  # uORB debug_array
        self._next_us = PERIOD_US  # the first cycle 4 ms after start (px4_usleep first)
        self._t_status_us = 0

    def handlers(self) -> dict[str, Callable[[Link, Any], None]]:
        """MAVLink receiver: DEBUG_FLOAT_ARRAY -> debug_array."""
        return {"DEBUG_FLOAT_ARRAY": self._on_debug_float_array}

    def _on_debug_float_array(self, link: Link, msg: Any) -> None:
        name = msg.name
        if isinstance(name, bytes):
            name = name.decode("ascii", "replace")
        if name.rstrip("\x00") != PROTO_NAME:  # strncmp(m.name, ECCA_PROTO_NAME, 10)
            return
        self._debug_array = (int(msg.array_id), [float(x) for x in msg.data])  # the newest only

    def due(self, t_s: float) -> bool:
        """A module cycle is due at `t_s` [s since boot]."""
        return t_s * 1e6 >= self._next_us - 0.5

    def cycle(self) -> None:
        """One pass of task_main's loop at the autopilot's clock now."""
        self._next_us += PERIOD_US
        now_us = self.clock.time_usec
        m = self.module
        if self._debug_array is not None:
            op, data = self._debug_array
            self._debug_array = None
            ack = m.message(op, data)
            if ack is not None:
                self._publish_ack(ack)
                if ack.command == ACK_CRC:
                    self.stats["onboard_uploads" if ack.result == 0 else "onboard_refused"] += 1
                    if ack.result != 0:
                        self.log(mavlink.MAV_SEVERITY_WARNING,
                                 f"upload refused: crc 0x{ack.value & 0xFFFFFFFF:08x}")
        offboard, pos_ok = self.offboard_state()
        s = self.view.state
        out = m.step(now_us * 1e-6, offboard, pos_ok, s.pos_ned, s.vel_ned, s.q_wxyz)
        if out.event == EV_START_REFUSED:
            self.log(mavlink.MAV_SEVERITY_ERROR, f"not flying: the vehicle is "
                     f"{out.start_error_m:.1f} m from the trajectory's start")
        elif out.event in EV_TEXT:
            self.log(mavlink.MAV_SEVERITY_INFO, EV_TEXT[out.event])
        if out.publish_mode:
            self.control_mode()
        if out.publish_setpoint and offboard:
            q = out.q_d
            n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
            if n > 1e-6:
                self.stats["onboard_setpoints"] += 1
                self.attitude(make_attitude_target(
                    (q[0] / n, q[1] / n, q[2] / n, q[3] / n), min(max(out.thrust, 0.0), 1.0),
                    None, out.yaw_rate))
        if out.final_action >= 0:
            self.stats["onboard_final_action"] += 1
            self.set_mode(1.0, 4.0, FINAL_SUB_MODE.get(out.final_action, LOITER_SUB_MODE))
        if m.peer[0] != 0 and now_us - self._t_status_us >= STATUS_US:
            self._t_status_us = now_us
            self._publish_ack(m.status())
            start = m.start_report()
            if start is not None:
                self._publish_ack(start)

    @property
    def peer(self) -> tuple[int, int]:
        """The core's peer (system, component id; 0 before any STATUS or BEGIN)."""
        return self.module.peer

    def _publish_ack(self, ack: OnboardAck) -> None:
        peer_sys, peer_comp = self.module.peer
        self.links.broadcast(mavlink.MAVLink_command_ack_message(
            ack.command, ack.result, ack.state, ack.value, peer_sys, peer_comp))
