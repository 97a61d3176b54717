"""The commander: arming, flight modes, failsafes, home, and what the vehicle is asked to track.

A state machine on the injected clock: `update(t)` runs at <= 200 Hz (auto-disarm, takeoff
completion, offboard-loss and position-loss failsafes), `housekeeping(t)` at 50 Hz (scenario
faults, battery warnings); `target()` picks the setpoint the vehicle tracks on each physics step
(offboard input, the navigator at <= 100 Hz, a no-RC descent, or idle).
"""

from __future__ import annotations

import math
from collections.abc import Callable

from pymavlink.dialects.v20 import common as mavlink

from sitl_mock.autopilot import telemetry
from sitl_mock.autopilot.links import Links
from sitl_mock.autopilot.modes import AUTO_MODES, MANUAL_MODES, OFFBOARD_LOSS_ACTIONS, Mode
from sitl_mock.autopilot.offboard import OffboardInput
from sitl_mock.autopilot.shared import Clock, Msg, StateView
from sitl_mock.faults import ScenarioFaults
from sitl_mock.mission_server import MissionExecutor
from sitl_mock.navigator import Navigator
from sitl_mock.params import ParamStore
from sitl_mock.setpoints import IdleTarget, PositionTarget, RoverPositionTarget, Target

FAILSAFE_ACTION_DELAY_S = 0.5  # loss detected at COM_OF_LOSS_T, mode switch 0.5 s later
#: PX4 v1.16's commander publishes vehicle_status and vehicle_control_mode "at 2 Hz or
#: immediately when changed" (Commander::run: 500 ms after the last publication, or on a
#: status, nav-state or arming change); a change of the offboard setpoint kind (position <->
#: attitude) is none of these, so its controllers follow the new kind only at the next
#: publication. Meanwhile they fly the last setpoint of the old kind (real PX4 SITL: attitude
#: setpoints after position setpoints in OFFBOARD applied 0.3-0.5 s late, PX4's own position
#: control in between; `offboard_target`).
STATUS_PERIOD_S = 0.5
NAVIGATOR_PERIOD_S = 0.01
DESCEND_SPEED_NO_RC = 0.6  # [m/s] observed sink rate in POSCTL without RC (PX4.md)
_DENIED = "Arming denied: Resolve system health failures first"
# the modes compared on every physics step / commander tick (a module global is ~10x cheaper
# to reach than an Enum class attribute)
_OFFBOARD = Mode.OFFBOARD
_AUTO_MISSION = Mode.AUTO_MISSION
_AUTO_TAKEOFF = Mode.AUTO_TAKEOFF
IDLE = IdleTarget()


class Commander:
    """Arming state, flight mode and failsafe state of the autopilot; see the module docstring.

    kind: "quad" or "rover"; dt: the physics step [s]; home: (lat deg, lon deg, alt AMSL m);
    estimator_ready_s: time after boot [s] before the estimator is ready; mission_current:
    builds MISSION_CURRENT from the autopilot's status.
    """

    def __init__(
        self,
        clock: Clock,
        view: StateView,
        params: ParamStore,
        kind: str,
        dt: float,
        nav: Navigator,
        mission: MissionExecutor,
        offboard: OffboardInput,
        links: Links,
        scenario: ScenarioFaults,
        home: tuple[float, float, float],
        estimator_ready_s: float,
        mission_current: Callable[[], Msg],
    ) -> None:
        self.clock = clock
        self.view = view
        self.vehicle = view.vehicle
        self.params = params
        self.kind = kind
        self.dt = dt
        self.nav = nav
        self.mission = mission
        self.offboard = offboard
        self.links = links
        self.scenario = scenario
        self.home = home
        self.estimator_ready_s = estimator_ready_s
        self.mission_current = mission_current
        self.mode = Mode.AUTO_LOITER
        self.user_mode = Mode.AUTO_LOITER
        self.armed = False
        self.failsafe = False
        self.rc_present = False
        self.home_announced = False
        self.armed_t = 0.0
        self.taken_off = False
        self.landed_since: float | None = None
        self.takeoff_alt_rel = float(params["MIS_TAKEOFF_ALT"])
        self.takeoff_done = False
        self.mission_started = False  # AUTO_MISSION started since the mission was loaded
        # offboard loss: when the signal was found lost (the failsafe acts 0.5 s later)
        self.ob_loss_t: float | None = None
        # what the vehicle tracks outside offboard
        self.hold_ned: tuple[float, float, float] | None = None
        self.descend = False
        self.nav_active = False
        self.nav_target: PositionTarget | RoverPositionTarget | None = None
        self.nav_last_t = 0.0
        self.nav_next_t = 0.0
        # housekeeping
        self.slow_next_t = 0.0
        self.bat_warned = 0  # 0 none, 1 low, 2 critical, 3 emergency
        self.battery_cap = 1.0  # low-battery fault: the level never rises above this again
        self.scn_takeover_done = False
        self.scn_pos_state = 0  # 0 before, 1 lost, 2 restored
        self.scn_battery_done = False
        # the offboard setpoint kind the controllers follow, as of the last status publication
        self.status_t = -math.inf
        self.control_kind: type | None = None

    # ================================================================== derived state
    @property
    def estimator_ready(self) -> bool:
        return self.clock.t >= self.estimator_ready_s

    @property
    def local_position_valid(self) -> bool:
        return self.estimator_ready and self.vehicle.local_position_valid

    @property
    def battery_remaining(self) -> float:
        return max(0.0, min(1.0, self.battery_cap, float(self.vehicle.battery_remaining)))

    @property
    def in_air(self) -> bool:
        return self.kind == "quad" and not self.vehicle.landed

    @property
    def landed_state(self) -> int:
        if self.kind != "quad":
            return int(mavlink.MAV_LANDED_STATE_ON_GROUND)
        if self.armed and self.mode == Mode.AUTO_TAKEOFF and not self.takeoff_done:
            return int(mavlink.MAV_LANDED_STATE_TAKEOFF)
        if self.vehicle.landed:
            return int(mavlink.MAV_LANDED_STATE_ON_GROUND)
        if self.armed and self._is_landing():
            return int(mavlink.MAV_LANDED_STATE_LANDING)
        return int(mavlink.MAV_LANDED_STATE_IN_AIR)

    def _is_landing(self) -> bool:
        if self.mode == Mode.AUTO_LAND:
            return True
        phase = str(getattr(self.nav, "phase", ""))
        return self.mode in (Mode.AUTO_RTL, Mode.AUTO_MISSION) and "land" in phase.lower()

    def arming_denial(self, mode: Mode) -> str | None:
        """Why arming in `mode` would be refused now (None: it would be accepted)."""
        if not self.estimator_ready or not self.vehicle.local_position_valid:
            return _DENIED
        if self.battery_remaining < float(self.params["BAT_CRIT_THR"]):
            return _DENIED
        if mode in MANUAL_MODES and not self.rc_present:
            return _DENIED
        if mode == Mode.OFFBOARD and not self.offboard.fresh:
            return _DENIED
        if mode == Mode.AUTO_MISSION and not self.mission.valid:
            return _DENIED
        return None

    def mode_denial(self, mode: Mode) -> str | None:
        """Why switching to `mode` would be refused now (None: it would be accepted)."""
        msg = f"Switching to {mode.label} is currently not available"
        if not self.armed:
            return None  # while disarmed any mode can be selected
        if mode == Mode.OFFBOARD:
            if not self.offboard.fresh:
                return msg
            if isinstance(self.offboard.target, PositionTarget) and not self.local_position_valid:
                return msg
        if mode in AUTO_MODES and not self.local_position_valid:
            return msg
        if mode == Mode.AUTO_MISSION and not self.mission.valid:
            return msg
        if mode in MANUAL_MODES and not self.rc_present:
            return msg
        return None

    @property
    def system_status(self) -> int:
        if self.armed:
            return int(mavlink.MAV_STATE_CRITICAL if self.failsafe else mavlink.MAV_STATE_ACTIVE)
        ready = self.arming_denial(self.mode) is None
        return int(mavlink.MAV_STATE_STANDBY if ready else mavlink.MAV_STATE_UNINIT)

    @property
    def base_mode(self) -> int:
        flags = self.mode.value[2]
        if self.mode == Mode.OFFBOARD and not self.offboard.fresh:
            flags = 0
        return int(mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED) | flags | (128 if self.armed else 0)

    # ================================================================== status publication
    def publish_status(self, t: float) -> None:
        """A vehicle_status / vehicle_control_mode publication (STATUS_PERIOD_S): the offboard
        setpoint kind the controllers follow becomes the newest setpoint's."""
        self.status_t = t
        tgt = self.offboard.target
        self.control_kind = None if tgt is None else type(tgt)

    def offboard_target(self) -> Target:
        """The offboard setpoint the controllers fly: the newest, or while the control mode has
        not caught up with a change of its kind (a quad), the newest of the kind it has."""
        ob = self.offboard
        tgt = ob.target
        if tgt is None:
            return IDLE
        kind = self.control_kind
        if kind is None or type(tgt) is kind or self.kind != "quad":
            return tgt
        last = ob.last_position if kind is PositionTarget else ob.last_attitude
        return tgt if last is None else last

    # ================================================================== transitions
    def arm(self) -> None:
        self.armed = True
        self.armed_t = self.clock.t
        self.taken_off = False
        self.landed_since = None
        self.takeoff_done = False
        self.links.statustext(mavlink.MAV_SEVERITY_INFO, "Armed by external command")
        self.vehicle.reset_integrators()
        self.publish_status(self.clock.t)
        self._enter_mode(self.mode)

    def disarm(self, why: str) -> None:
        self.armed = False
        self.ob_loss_t = None
        self.publish_status(self.clock.t)
        self.links.statustext(mavlink.MAV_SEVERITY_INFO, f"Disarmed by {why}")
        if self.failsafe:
            # PX4 returns to the last user-selected mode once the failsafe clears on disarm
            self.failsafe = False
            self.mode = self.user_mode

    def set_mode(self, mode: Mode, user: bool, failsafe: bool = False) -> None:
        prev = self.mode
        self.mode = mode
        if user:
            self.user_mode = mode
            self.failsafe = False
        if failsafe:
            self.failsafe = True
        if prev == Mode.AUTO_MISSION and mode != Mode.AUTO_MISSION:
            self.mission.stop()
        if mode != Mode.OFFBOARD:
            self.ob_loss_t = None
        if mode == Mode.AUTO_TAKEOFF:
            self.takeoff_done = False
        if prev not in AUTO_MODES or mode not in AUTO_MODES:
            # PX4 activates another flight task: an AUTO trajectory restarts at the vehicle
            self.nav.forget_reference()
        self.publish_status(self.clock.t)
        self._enter_mode(mode)

    def _enter_mode(self, mode: Mode) -> None:
        """Mode entry actions (also run on arming in the current mode)."""
        s = self.view.state
        self.descend = False
        self.nav_active = False
        self.nav_target = None
        self.vehicle.reset_integrators()
        if not self.armed:
            return
        if mode == Mode.AUTO_TAKEOFF:
            self.nav.takeoff(self.takeoff_alt_rel, s)
            self.nav_active = True
        elif mode == Mode.AUTO_LOITER:
            if self.in_air:
                self.nav.loiter(s)
                self.nav_active = True
        elif mode == Mode.AUTO_LAND:
            self.nav.land(s)
            self.nav_active = True
        elif mode == Mode.AUTO_RTL:
            self.nav.rtl(s)
            self.nav_active = True
        elif mode == Mode.AUTO_MISSION:
            if self.mission.valid:
                self.mission.start(self.clock.t)
                self.mission_started = True
                self.nav_active = True
        elif mode in MANUAL_MODES:
            self.nav.loiter(s)
            self.nav_active = True
            self.descend = not self.rc_present and self.in_air
            self.hold_ned = s.pos_ned

    def on_offboard_setpoint(self) -> None:
        """A valid offboard setpoint arrived: the signal is back before the failsafe acts."""
        if self.ob_loss_t is not None and self.mode == Mode.OFFBOARD:
            self.ob_loss_t = None

    # ================================================================== setpoint selection
    def target(self) -> Target:
        """What the vehicle tracks on this physics step."""
        if not self.armed:
            return IDLE
        if self.mode is _OFFBOARD:
            return self.offboard_target()
        if self.descend:
            s = self.view.state
            if self.kind == "quad" and s.landed and not self.nav_active:
                return IDLE
            hold = self.hold_ned or s.pos_ned
            return PositionTarget(
                (hold[0], hold[1], math.nan), (math.nan, math.nan, DESCEND_SPEED_NO_RC)
            )
        if self.nav_active:
            # navigator at <= 100 Hz like PX4's position control loop; target held in between
            t = self.clock.t
            if self.nav_target is None or t >= self.nav_next_t - 1e-9:
                dt_nav = t - self.nav_last_t if self.nav_target is not None else self.dt
                self.nav_target = self.nav.update(max(dt_nav, self.dt), self.view.state)
                self.nav_last_t = t
                self.nav_next_t = t + NAVIGATOR_PERIOD_S
            return self.nav_target
        return IDLE

    # ================================================================== periodic work
    def housekeeping(self, t: float) -> None:
        """Home announcement once the estimator is ready; scenario faults and battery (50 Hz)."""
        if not self.home_announced and self.estimator_ready:
            self.home_announced = True
            self.links.broadcast(telemetry.home_position_message(self.home, self.clock.time_usec))
        if t >= self.slow_next_t:  # 50 Hz housekeeping
            self.slow_next_t = t + 0.02
            self._scenario(t)
            self._battery_check()

    def update(self, t: float, landed: bool, pos_valid: bool) -> None:
        """The commander's state machine at time `t` [s since boot]; `landed` and `pos_valid`
        are the vehicle's flags as read at the start of this tick (before housekeeping)."""
        if t >= self.status_t + STATUS_PERIOD_S - 1e-9:
            self.publish_status(t)
        if not self.armed:
            return
        p = self.params
        # takeoff / landing bookkeeping (quad)
        if self.kind == "quad":
            if not landed:
                self.taken_off = True
            if self.mode is _AUTO_TAKEOFF and not self.takeoff_done and self.nav.reached:
                self.takeoff_done = True
                self.set_mode(Mode.AUTO_LOITER, user=False)
                self.user_mode = Mode.AUTO_LOITER
            # PX4 (Commander::handleAutoDisarm): no COM_DISARM_LAND auto-disarm while landed
            # amid an unfinished AUTO.MISSION (a landing in the middle of a mission)
            amid_mission = self.mode is _AUTO_MISSION and not self.mission.finished
            if landed and self.taken_off and not amid_mission:
                if self.landed_since is None:
                    self.landed_since = t
                elif 0.0 <= float(p["COM_DISARM_LAND"]) <= t - self.landed_since:
                    self.disarm("auto disarm on land")
                    return
            else:
                self.landed_since = None
            if not self.taken_off:
                prflt = float(p["COM_DISARM_PRFLT"])
                if prflt > 0 and t - self.armed_t >= prflt:
                    self.disarm("auto preflight disarming")
                    return
        # offboard loss
        if self.mode is _OFFBOARD:
            if self.ob_loss_t is None:
                if not self.offboard.fresh:
                    self.ob_loss_t = t
                    action = OFFBOARD_LOSS_ACTIONS.get(int(p["COM_OBL_RC_ACT"]), Mode.POSCTL)
                    what = action.label if action is not None else "Disarm"
                    self.links.statustext(
                        mavlink.MAV_SEVERITY_CRITICAL,
                        f"Failsafe activated: no offboard signal, switching to {what}",
                    )
            elif t - self.ob_loss_t >= FAILSAFE_ACTION_DELAY_S:
                self.ob_loss_t = None
                action = OFFBOARD_LOSS_ACTIONS.get(int(p["COM_OBL_RC_ACT"]), Mode.POSCTL)
                self._failsafe_to(action)
        # local position loss while a position is needed
        if not pos_valid and not self.failsafe and self.in_air:
            needs_pos = (
                self.mode in AUTO_MODES
                or self.mode == Mode.POSCTL
                or (
                    self.mode == Mode.OFFBOARD
                    and isinstance(self.offboard.target, PositionTarget)
                )
            )
            if needs_pos:
                self.links.statustext(
                    mavlink.MAV_SEVERITY_CRITICAL,
                    "Failsafe activated: no local position, descending",
                )
                self.set_mode(Mode.AUTO_LAND, user=False, failsafe=True)
                self.nav_active = False
                self.descend = True
                self.hold_ned = None

    def _failsafe_to(self, action: Mode | None) -> None:
        if action is None:
            self.failsafe = True
            self.disarm("failsafe")
            return
        self.set_mode(action, user=False, failsafe=True)
        # PX4.md: the HEARTBEAT leaves OFFBOARD 1.3-1.7 s after the last setpoint. With a plain
        # 1 Hz heartbeat that would be 1.5-2.5 s here, so the heartbeat phase is reset to now.
        self.links.heartbeat_now()

    def _battery_check(self) -> None:
        rem = self.battery_remaining
        p = self.params
        level = 0
        if rem < float(p["BAT_EMERGEN_THR"]):
            level = 3
        elif rem < float(p["BAT_CRIT_THR"]):
            level = 2
        elif rem < float(p["BAT_LOW_THR"]):
            level = 1
        if level <= self.bat_warned:
            return
        self.bat_warned = level
        text = {
            1: "Low battery level! Return advised",
            2: "Critical battery level! Land advised",
            3: "Emergency battery level! Landing immediately",
        }[level]
        self.links.statustext(
            mavlink.MAV_SEVERITY_WARNING if level == 1 else mavlink.MAV_SEVERITY_CRITICAL, text
        )
        act = int(p["COM_LOW_BAT_ACT"])
        if not (self.armed and self.in_air) or act == 0 or level < 2:
            return
        if act == 3 and level == 2:
            self.set_mode(Mode.AUTO_RTL, user=False, failsafe=True)
        elif act in (2, 3):
            self.set_mode(Mode.AUTO_LAND, user=False, failsafe=True)

    def _scenario(self, t: float) -> None:
        sc = self.scenario
        if (
            sc.pilot_takeover_s is not None
            and not self.scn_takeover_done
            and t >= sc.pilot_takeover_s
        ):
            self.scn_takeover_done = True
            self.rc_present = True
            self.links.statustext(
                mavlink.MAV_SEVERITY_WARNING, "Pilot took over position control using sticks"
            )
            self.set_mode(Mode.POSCTL, user=True)
        if sc.local_position_loss is not None:
            start, end = sc.local_position_loss
            if self.scn_pos_state == 0 and t >= start:
                self.scn_pos_state = 1
                self.vehicle.set_local_position_valid(False)
                self.view.stale = True
            elif self.scn_pos_state == 1 and t >= end:
                self.scn_pos_state = 2
                self.vehicle.set_local_position_valid(True)
                self.view.stale = True
        if sc.low_battery_s is not None and not self.scn_battery_done and t >= sc.low_battery_s:
            self.scn_battery_done = True
            self.vehicle.set_battery_remaining(sc.low_battery_remaining)
            self.battery_cap = sc.low_battery_remaining
            self.view.stale = True

    # ================================================================== mission events
    def on_mission_loaded(self) -> None:
        """A new mission was stored: restart it if flying one, else leave AUTO_MISSION."""
        self.mission_started = False
        if self.mode == Mode.AUTO_MISSION:
            if self.mission.valid:
                self.mission.start(self.clock.t)
                self.mission_started = True
            else:
                self.set_mode(Mode.AUTO_LOITER, user=False)

    def on_item_current(self, seq: int) -> None:
        """The executor gave the navigator a new goal (mission item `seq`)."""
        self.nav_target = None
        self.links.broadcast(self.mission_current())

    def on_mission_finished(self, landed: bool) -> None:
        """The mission's last item is done (`landed`: it ended with a landing)."""
        self.links.broadcast(self.mission_current())
        if self.mode != Mode.AUTO_MISSION:
            return
        if landed and self.kind == "rover" and self.armed:
            # a quad's land detector disarms it after touchdown; a rover that ends its
            # mission with LAND or RTL is disarmed where it stopped
            self.disarm("mission end (rover stopped at its land point)")
            return
        if landed or not self.armed:
            return
        self.links.statustext(mavlink.MAV_SEVERITY_INFO, "Mission finished, loitering")
        self.set_mode(Mode.AUTO_LOITER, user=False)
        goal = self.mission.last_goal_ned
        if goal is not None:  # hold at the last waypoint, not where it was reported reached
            s = self.view.state
            self.nav.goto(goal, s.yaw, float(self.params["NAV_ACC_RAD"]), s)
            self.nav_target = None
