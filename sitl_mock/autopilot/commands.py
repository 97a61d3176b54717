"""Command handling: COMMAND_LONG / COMMAND_INT decoded, dispatched by command id, acknowledged.

Each `_cmd_*` handler returns a MAV_RESULT to acknowledge, or -1 / None when it sent its own
acknowledgement (or will: DO_SET_MODE is ACCEPTED on receipt, the commander's verdict follows
~10 ms later, like PX4's receiver and commander).
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable

from pymavlink.dialects.v20 import common as mavlink

from sitl_mock.autopilot import telemetry
from sitl_mock.autopilot.commander import Commander
from sitl_mock.autopilot.links import Link, Links
from sitl_mock.autopilot.modes import Mode
from sitl_mock.autopilot.shared import (
    RESULT_ACCEPTED,
    RESULT_DENIED,
    RESULT_FAILED,
    RESULT_TEMPORARILY_REJECTED,
    RESULT_UNSUPPORTED,
    Clock,
    Msg,
    StateView,
    addressed_to_us,
    finite,
)
from sitl_mock.mission_server import MissionExecutor, project_to_ned
from sitl_mock.navigator import Navigator
from sitl_mock.params import ParamStore

FORCE_MAGIC = 21196
MODE_ACK_DELAY_S = 0.010  # the commander's verdict follows the receiver's ACCEPTED by ~10 ms
Params7 = tuple[float, ...]
CommandFn = Callable[["CommandHandler", Link, Msg, Params7, int], int | None]


class CommandHandler:
    """Runs the commands the mock supports against the commander, navigator and missions.

    schedule(delay_s, fn): run `fn` later on the simulated clock; build(msg_id): the message
    REQUEST_MESSAGE asks for, from the autopilot's status (None if it has none now);
    mission_current(): MISSION_CURRENT now.
    """

    def __init__(
        self,
        clock: Clock,
        stats: Counter[str],
        links: Links,
        commander: Commander,
        view: StateView,
        params: ParamStore,
        nav: Navigator,
        mission: MissionExecutor,
        schedule: Callable[[float, Callable[[], None]], None],
        build: Callable[[int], Msg | None],
        mission_current: Callable[[], Msg],
    ) -> None:
        self.clock = clock
        self.stats = stats
        self.links = links
        self.commander = commander
        self.view = view
        self.params = params
        self.nav = nav
        self.mission = mission
        self.schedule = schedule
        self.build = build
        self.mission_current = mission_current

    def handlers(self) -> dict[str, Callable[[Link, Msg], None]]:
        """Message type -> handler for the command messages."""
        return {"COMMAND_LONG": self._on_command_long, "COMMAND_INT": self._on_command_int}

    def _on_command_long(self, link: Link, msg: Msg) -> None:
        if not addressed_to_us(self.stats, msg.target_system, msg.target_component):
            return
        p = (msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7)
        self._command(link, msg, int(msg.command), p, frame=mavlink.MAV_FRAME_GLOBAL)

    def _on_command_int(self, link: Link, msg: Msg) -> None:
        if not addressed_to_us(self.stats, msg.target_system, msg.target_component):
            return
        x, y = msg.x, msg.y
        if msg.frame in (0, 3, 5, 6, 10, 11):
            px, py = x * 1e-7, y * 1e-7
        else:
            px, py = float(x), float(y)
        if x == 0x7FFFFFFF:
            px = math.nan
        if y == 0x7FFFFFFF:
            py = math.nan
        p = (msg.param1, msg.param2, msg.param3, msg.param4, px, py, msg.z)
        self._command(link, msg, int(msg.command), p, frame=int(msg.frame))

    def _ack(self, link: Link, msg: Msg, command: int, result: int) -> None:
        self.links.send(
            link,
            mavlink.MAVLink_command_ack_message(
                command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()
            ),
        )

    def _command(self, link: Link, msg: Msg, cmd: int, p: Params7, frame: int) -> None:
        self.stats["rx_commands"] += 1
        handler = _COMMANDS.get(cmd)
        if handler is None:
            self._ack(link, msg, cmd, RESULT_UNSUPPORTED)
            return
        result = handler(self, link, msg, p, frame)
        if result is not None and result >= 0:
            self._ack(link, msg, cmd, result)

    # ---------------------------------------------------------------- arming and modes
    def _cmd_arm_disarm(self, link: Link, msg: Msg, p: Params7, frame: int) -> int:
        cmdr = self.commander
        p1 = p[0]
        forced = math.isfinite(p[1]) and round(p[1]) == FORCE_MAGIC
        if not math.isfinite(p1) or round(p1) not in (0, 1):
            self.links.statustext(
                mavlink.MAV_SEVERITY_CRITICAL, f"Unsupported ARM_DISARM param: {p1}"
            )
            return RESULT_DENIED
        if round(p1) == 1:
            if cmdr.armed:
                return RESULT_ACCEPTED
            reason = cmdr.arming_denial(cmdr.mode)
            if reason is not None:
                self.links.statustext(mavlink.MAV_SEVERITY_CRITICAL, reason)
                return RESULT_TEMPORARILY_REJECTED
            cmdr.arm()
            return RESULT_ACCEPTED
        if not cmdr.armed:
            return RESULT_ACCEPTED
        if not forced and cmdr.in_air:
            self.links.statustext(mavlink.MAV_SEVERITY_CRITICAL, "Disarming denied: not landed")
            return RESULT_TEMPORARILY_REJECTED
        cmdr.disarm("external command")
        return RESULT_ACCEPTED

    def _cmd_set_mode(self, link: Link, msg: Msg, p: Params7, frame: int) -> None:
        # MAVLink receiver: ACCEPTED on receipt; the commander's verdict follows ~10 ms later
        self._ack(link, msg, mavlink.MAV_CMD_DO_SET_MODE, RESULT_ACCEPTED)
        base, main, sub = p[0], p[1], p[2]

        def verdict() -> None:
            result = self.mode_request(base, main, sub)
            self._ack(link, msg, mavlink.MAV_CMD_DO_SET_MODE, result)

        self.schedule(MODE_ACK_DELAY_S, verdict)

    def mode_request(self, base: float, main: float, sub: float) -> int:
        """DO_SET_MODE (base mode, PX4 main and sub mode) to the commander: the MAV_RESULT
        (also a vehicle_command from inside the autopilot, e.g. the onboard module)."""
        if not finite(base, main, sub) or not int(base) & 1:
            return RESULT_UNSUPPORTED
        mode = Mode.from_custom(int(main), int(sub))
        if mode is None:
            self.links.statustext(
                mavlink.MAV_SEVERITY_CRITICAL, "Switching to this mode is not supported"
            )
            return RESULT_TEMPORARILY_REJECTED
        reason = self.commander.mode_denial(mode)
        if reason is not None:
            self.links.statustext(mavlink.MAV_SEVERITY_CRITICAL, reason)
            return RESULT_TEMPORARILY_REJECTED
        self.commander.set_mode(mode, user=True)
        return RESULT_ACCEPTED

    def _cmd_takeoff(self, link: Link, msg: Msg, p: Params7, frame: int) -> int:
        cmdr = self.commander
        if cmdr.kind != "quad":
            return RESULT_UNSUPPORTED
        if not cmdr.local_position_valid:
            self.links.statustext(
                mavlink.MAV_SEVERITY_CRITICAL, "Takeoff denied! Please disarm and retry"
            )
            return RESULT_TEMPORARILY_REJECTED
        alt = p[6]
        if math.isfinite(alt):
            rel = alt - cmdr.home[2] if frame in (0, 5) else alt
            if frame not in (0, 3, 5, 6):
                rel = alt - cmdr.home[2]
        else:
            rel = float(self.params["MIS_TAKEOFF_ALT"])
        cmdr.takeoff_alt_rel = max(rel, 0.5)
        cmdr.set_mode(Mode.AUTO_TAKEOFF, user=True)
        return RESULT_ACCEPTED

    def _cmd_land(self, link: Link, msg: Msg, p: Params7, frame: int) -> int:
        self.commander.set_mode(Mode.AUTO_LAND, user=True)
        return RESULT_ACCEPTED

    def _cmd_rtl(self, link: Link, msg: Msg, p: Params7, frame: int) -> int:
        if self.commander.armed and not self.commander.local_position_valid:
            return RESULT_TEMPORARILY_REJECTED
        self.commander.set_mode(Mode.AUTO_RTL, user=True)
        return RESULT_ACCEPTED

    # ---------------------------------------------------------------- messages and streams
    def _cmd_set_message_interval(self, link: Link, msg: Msg, p: Params7, frame: int) -> int:
        if not finite(p[0], p[1]):
            return RESULT_DENIED
        msg_id, interval_us = int(p[0]), float(p[1])
        if msg_id == mavlink.MAVLINK_MSG_ID_HEARTBEAT or msg_id not in telemetry.STREAMABLE:
            return RESULT_FAILED
        self.links.set_interval(link, msg_id, interval_us)
        return RESULT_ACCEPTED

    def _cmd_get_message_interval(self, link: Link, msg: Msg, p: Params7, frame: int) -> int:
        if not math.isfinite(p[0]):
            return RESULT_DENIED
        msg_id = int(p[0])
        interval = link.streams.interval_s.get(msg_id)
        us = int(interval * 1e6) if interval is not None else -1
        self.links.send(link, mavlink.MAVLink_message_interval_message(msg_id, us))
        return RESULT_ACCEPTED

    def _home_message(self) -> Msg:
        return telemetry.home_position_message(self.commander.home, self.clock.time_usec)

    def _cmd_request_message(self, link: Link, msg: Msg, p: Params7, frame: int) -> int:
        if not math.isfinite(p[0]):
            return RESULT_DENIED
        msg_id = int(p[0])
        reply: Msg | None = None
        if msg_id == mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
            reply = telemetry.autopilot_version_message()
        elif msg_id == mavlink.MAVLINK_MSG_ID_HOME_POSITION:
            if not self.commander.estimator_ready:  # home is set once the estimator is ready
                return RESULT_FAILED
            reply = self._home_message()
        elif msg_id in telemetry.STREAMABLE:
            reply = self.build(msg_id)
        if reply is None:
            return RESULT_DENIED
        self._ack(link, msg, mavlink.MAV_CMD_REQUEST_MESSAGE, RESULT_ACCEPTED)
        self.links.send(link, reply)
        return -1  # ack already sent

    def _cmd_capabilities(self, link: Link, msg: Msg, p: Params7, frame: int) -> int:
        self._ack(link, msg, 520, RESULT_ACCEPTED)
        self.links.send(link, telemetry.autopilot_version_message())
        return -1

    def _cmd_get_home(self, link: Link, msg: Msg, p: Params7, frame: int) -> int:
        if not self.commander.estimator_ready:
            return RESULT_FAILED
        self._ack(link, msg, 410, RESULT_ACCEPTED)
        self.links.send(link, self._home_message())
        return -1

    # ---------------------------------------------------------------- missions and navigation
    def _cmd_mission_start(self, link: Link, msg: Msg, p: Params7, frame: int) -> int:
        if not self.mission.valid:
            return RESULT_DENIED
        if math.isfinite(p[0]) and p[0] >= 0:
            self.mission.set_current(int(p[0]))
        reason = self.commander.mode_denial(Mode.AUTO_MISSION)
        if reason is not None:
            self.links.statustext(mavlink.MAV_SEVERITY_CRITICAL, reason)
            return RESULT_TEMPORARILY_REJECTED
        self.commander.set_mode(Mode.AUTO_MISSION, user=True)
        return RESULT_ACCEPTED

    def _cmd_set_mission_current(self, link: Link, msg: Msg, p: Params7, frame: int) -> int:
        if not math.isfinite(p[0]) or not self.mission.set_current(int(p[0])):
            return RESULT_DENIED
        self.links.broadcast(self.mission_current())
        return RESULT_ACCEPTED

    def _cmd_change_speed(self, link: Link, msg: Msg, p: Params7, frame: int) -> int:
        setter = getattr(self.nav, "set_cruise_speed", None)
        if setter is None or not math.isfinite(p[1]):
            return RESULT_DENIED
        setter(p[1] if p[1] > 0 else math.nan)
        return RESULT_ACCEPTED

    def _cmd_reposition(self, link: Link, msg: Msg, p: Params7, frame: int) -> int:
        cmdr = self.commander
        if not cmdr.armed or not cmdr.in_air or not cmdr.local_position_valid:
            return RESULT_TEMPORARILY_REJECTED
        cur = self.view.state.pos_ned
        n, e = cur[0], cur[1]
        if finite(p[4], p[5]):
            n, e = project_to_ned(cmdr.home, p[4], p[5])
        d = cur[2]
        if math.isfinite(p[6]):
            d = -p[6] if frame in (3, 6) else -(p[6] - cmdr.home[2])
        yaw = math.radians(p[3]) if math.isfinite(p[3]) else math.nan
        cmdr.set_mode(Mode.AUTO_LOITER, user=True)
        self.nav.goto((n, e, d), yaw, float(self.params["NAV_ACC_RAD"]), self.view.state)
        cmdr.nav_target = None
        return RESULT_ACCEPTED

    def _cmd_set_home(self, link: Link, msg: Msg, p: Params7, frame: int) -> int:
        cmdr = self.commander
        if math.isfinite(p[0]) and p[0] >= 0.5:
            s = self.view.state
            cmdr.home = (s.lat_deg, s.lon_deg, s.alt_amsl_m)
        elif finite(p[4], p[5], p[6]):
            cmdr.home = (float(p[4]), float(p[5]), float(p[6]))
        else:
            return RESULT_DENIED
        self.links.broadcast(self._home_message())
        return RESULT_ACCEPTED


_COMMANDS: dict[int, CommandFn] = {
    mavlink.MAV_CMD_COMPONENT_ARM_DISARM: CommandHandler._cmd_arm_disarm,
    mavlink.MAV_CMD_DO_SET_MODE: CommandHandler._cmd_set_mode,
    mavlink.MAV_CMD_NAV_TAKEOFF: CommandHandler._cmd_takeoff,
    mavlink.MAV_CMD_NAV_LAND: CommandHandler._cmd_land,
    mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH: CommandHandler._cmd_rtl,
    mavlink.MAV_CMD_SET_MESSAGE_INTERVAL: CommandHandler._cmd_set_message_interval,
    mavlink.MAV_CMD_GET_MESSAGE_INTERVAL: CommandHandler._cmd_get_message_interval,
    mavlink.MAV_CMD_REQUEST_MESSAGE: CommandHandler._cmd_request_message,
    mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: CommandHandler._cmd_capabilities,
    mavlink.MAV_CMD_GET_HOME_POSITION: CommandHandler._cmd_get_home,
    mavlink.MAV_CMD_MISSION_START: CommandHandler._cmd_mission_start,
    mavlink.MAV_CMD_DO_SET_MISSION_CURRENT: CommandHandler._cmd_set_mission_current,
    mavlink.MAV_CMD_DO_CHANGE_SPEED: CommandHandler._cmd_change_speed,
    mavlink.MAV_CMD_DO_REPOSITION: CommandHandler._cmd_reposition,
    mavlink.MAV_CMD_DO_SET_HOME: CommandHandler._cmd_set_home,
}
