"""Sans-IO PX4 v1.16-like autopilot core: MAVLink bytes in, MAVLink bytes out, time injected.

Shape of aioquic's QuicConnection: `receive_datagram(data, addr, now, link)`,
`datagrams_to_send(now, link)`, `get_timer()`, `handle_timer(now)` (= `advance(now)`). The core
never reads a clock and never touches a socket. `now` is simulated time in seconds on any
monotonic origin (boot is the `now` given to the constructor). Physics is stepped at a fixed
rate (default 250 Hz) inside `advance`, and telemetry is emitted at PX4's onboard-link rates on
the simulated clock, so the same inputs give the same outputs in real time or in lockstep.

Two links like PX4 SITL: "offboard" (the API / onboard link, PX4 binds 14580 and talks to
14540) and "gcs" (binds 18570, talks to 14550). MAVLink 2 only, sysid 1, compid 1.

`Autopilot` composes components that own their state: `Links` (connections and traffic),
`Commander` (arming, modes, failsafes), `CommandHandler` (COMMAND_LONG / INT), `OffboardInput`
(setpoints and their timeout), `ParamServer`, `Missions`; telemetry reads the status snapshots
(`VehicleStatus`, `StatusSnapshot`), never the autopilot.
"""

from __future__ import annotations

import heapq
import logging
import math
from collections import Counter
from collections.abc import Callable, Iterable, Mapping
from typing import TYPE_CHECKING

from pymavlink.dialects.v20 import common as mavlink

from sitl_mock._frozen import frozen_new
from sitl_mock.autopilot import telemetry
from sitl_mock.autopilot.commander import IDLE, Commander
from sitl_mock.autopilot.commands import CommandHandler
from sitl_mock.autopilot.links import Link, Links
from sitl_mock.autopilot.missions import Missions
from sitl_mock.autopilot.modes import Mode
from sitl_mock.autopilot.offboard import OffboardInput
from sitl_mock.autopilot.param_server import ParamServer
from sitl_mock.autopilot.shared import Addr, Clock, Msg, StateView
from sitl_mock.autopilot.status import StatusSnapshot, VehicleStatus
from sitl_mock.faults import LinkFaults, ScenarioFaults
from sitl_mock.mission_server import MISSION, MissionExecutor, MissionServer
from sitl_mock.navigator import Navigator
from sitl_mock.params import ParamStore
from sitl_mock.setpoints import Target
from sitl_mock.vehicle import DEFAULT_HOME, Vehicle, VehicleState, make_vehicle

if TYPE_CHECKING:
    from sitl_mock.onboard import OnboardHost

_log = logging.getLogger(__name__)
COMMANDER_PERIOD_S = 0.005
_OFFBOARD = Mode.OFFBOARD
_AUTO_MISSION = Mode.AUTO_MISSION
_PING = telemetry.MSG_ID_PING
_HIL = telemetry.MSG_ID_HIL_STATE_QUATERNION
_VEHICLE_BUILDERS = telemetry.VEHICLE_BUILDERS
_STATUS_BUILDERS = telemetry.STATUS_BUILDERS
_QUIETABLE = telemetry.QUIETABLE
_MAV_TYPE = {"quad": int(mavlink.MAV_TYPE_QUADROTOR), "rover": int(mavlink.MAV_TYPE_GROUND_ROVER)}


class Autopilot:
    """The mock PX4: modes, arming, commands, offboard, failsafes, missions, params, telemetry.

    vehicle_kind: "quad" or "rover"; params: a ParamStore or NAME -> value overrides;
    home: (lat deg, lon deg, alt AMSL m); seed: for the vehicle noise and the fault channels;
    physics_hz: fixed physics/control rate (>= 250 Hz); now: the boot time on the caller's
    clock; remotes: link name -> default destination (PX4 sends there until a peer talks);
    link_faults: link name -> (inbound, outbound) LinkFaults; scenario: vehicle-level faults;
    estimator_ready_s: time after boot before the estimator is ready and arming is possible;
    signing_key: 32-byte MAVLink 2 signing key (None: no signing; see sitl_mock/signing.py),
    then unix_boot_s, the wall clock at boot [UNIX s], starts the signing timestamps;
    onboard: host the onboard module (gen_c/px4_module, `sitl_mock.onboard`) as PX4 hosts
    ecca_onboard (its C compiled at first use; a quad only).
    """

    def __init__(
        self,
        vehicle_kind: str = "quad",
        params: ParamStore | Mapping[str, float] | None = None,
        home: tuple[float, float, float] = DEFAULT_HOME,
        seed: int = 0,
        *,
        physics_hz: float = 250.0,
        now: float = 0.0,
        remotes: Mapping[str, Addr | None] | None = None,
        link_faults: Mapping[str, tuple[LinkFaults | None, LinkFaults | None]] | None = None,
        scenario: ScenarioFaults | None = None,
        estimator_ready_s: float = 3.0,
        vehicle: Vehicle | None = None,
        signing_key: bytes | None = None,
        unix_boot_s: float | None = None,
        onboard: bool = False,
    ) -> None:
        if not (math.isfinite(physics_hz) and physics_hz >= 250.0):
            raise ValueError(f"physics rate must be >= 250 Hz, got {physics_hz!r}")
        if vehicle_kind not in ("quad", "rover"):
            raise ValueError(f"unknown vehicle kind {vehicle_kind!r}: use 'quad' or 'rover'")
        if signing_key is not None and unix_boot_s is None:
            raise ValueError("signing needs unix_boot_s (the wall clock at boot) for timestamps")
        self.params = params if isinstance(params, ParamStore) else ParamStore(params or {})
        self.kind = vehicle_kind
        home = (float(home[0]), float(home[1]), float(home[2]))
        self.seed = seed
        self.vehicle: Vehicle = vehicle or make_vehicle(vehicle_kind, self.params, home, seed)
        self.dt = 1.0 / physics_hz
        self._boot = float(now)
        self.clock = Clock()
        # simulated seconds per second of the caller's clock (SIM_SPEED_FACTOR)
        self._speed = float(self.params["SIM_SPEED_FACTOR"])
        # from simulated time _chg_t on, the rate is _chg_speed (SIM_SPEED_CHG_T, 0 = never)
        chg_t = float(self.params["SIM_SPEED_CHG_T"])
        self._chg_t = chg_t if chg_t > 0.0 else math.inf
        self._chg_speed = float(self.params["SIM_SPEED_CHG"])
        self._chg_now = self._boot + self._chg_t / self._speed  # the caller's time of it
        self._n_steps = 0
        self.scenario = scenario or ScenarioFaults()
        self.stats: Counter[str] = Counter()
        self.ping_seq = 0
        self._events: list[tuple[float, int, Callable[[], None]]] = []
        self._event_order = 0
        self._cmd_next_t = 0.0
        self._last_target: Target = IDLE
        self.view = StateView(self.vehicle)
        # components
        self.comms = Links(
            self.clock,
            self.stats,
            dict(remotes) if remotes is not None else {"offboard": None},
            dict(link_faults or {}),
            seed,
            signing_key,
            unix_boot_s,
        )
        self.offboard = OffboardInput(
            self.clock, self.params, self.stats, self.view, self.comms.statustext
        )
        self.nav = Navigator(self.params, ground_vehicle=self.kind == "rover")
        self.missions = Missions(
            self.clock, self.stats, self.comms, self.view, self.nav, self.params, home,
            self.mission_current_message,
        )
        self.commander = Commander(
            self.clock, self.view, self.params, self.kind, self.dt, self.nav,
            self.missions.executor, self.offboard, self.comms, self.scenario, home,
            estimator_ready_s, self.mission_current_message,
        )
        self.param_server = ParamServer(self.params, self.comms, self.stats)
        self.commands = CommandHandler(
            self.clock, self.stats, self.comms, self.commander, self.view, self.params,
            self.nav, self.missions.executor, self._schedule, self._request_build,
            self.mission_current_message,
        )
        # wiring: who hears what
        self.offboard.on_setpoint = self.commander.on_offboard_setpoint
        self.missions.on_loaded = self.commander.on_mission_loaded
        self.missions.on_item_current = self.commander.on_item_current
        self.missions.on_finished = self.commander.on_mission_finished
        handlers = self.comms.handlers
        handlers.update(self.param_server.handlers())
        handlers.update(self.missions.handlers())
        handlers["SET_POSITION_TARGET_LOCAL_NED"] = self.offboard.on_set_position_target_local_ned
        handlers["SET_ATTITUDE_TARGET"] = self.offboard.on_set_attitude_target
        handlers.update(self.commands.handlers())
        self.comms.attitude_fields = self.offboard.attitude_setpoint
        self.onboard: OnboardHost | None = None
        if onboard:
            if vehicle_kind != "quad":
                raise ValueError("the onboard module flies a quad only")
            from sitl_mock.onboard import OnboardHost

            self.onboard = OnboardHost(
                self.clock, self.view, self.comms, self.stats, self._onboard_inputs,
                self.offboard.control_mode, self.offboard.module_attitude,
                self.commands.mode_request, self._module_log,
            )
            handlers.update(self.onboard.handlers())

    # ================================================================== public sans-IO API
    @property
    def speed(self) -> float:
        """Simulated seconds per second of the caller's clock (SIM_SPEED_FACTOR at boot)."""
        return self._speed

    @property
    def now(self) -> float:
        """Current simulated time on the caller's clock."""
        return self.caller_time(self.clock.t)

    def _sim_time(self, now: float) -> float:
        """Simulated time since boot [s] at the caller's time `now` [s]."""
        if now < self._chg_now:
            return (now - self._boot) * self._speed
        return self._chg_t + (now - self._chg_now) * self._chg_speed

    def clock_segments(self) -> tuple[tuple[float, float, float], ...]:
        """The simulated clock against the caller's, as segments (from simulated time [s], the
        caller's time then [s], simulated seconds per second of the caller's) of which the
        last one begun applies (SIM_SPEED_FACTOR, SIM_SPEED_CHG_T)."""
        first = (0.0, self._boot, self._speed)
        if math.isinf(self._chg_t):
            return (first,)
        return (first, (self._chg_t, self._chg_now, self._chg_speed))

    def caller_time(self, t_sim: float) -> float:
        """The caller's time [s] at simulated time since boot `t_sim` [s] (the clock that
        drives the mock: SIM_SPEED_FACTOR, SIM_SPEED_CHG_T)."""
        if t_sim < self._chg_t:
            return self._boot + t_sim / self._speed
        return self._chg_now + (t_sim - self._chg_t) / self._chg_speed

    @property
    def handled_messages(self) -> frozenset[str]:
        """The inbound MAVLink message types this autopilot handles (upper-case names)."""
        return frozenset(self.comms.handlers)

    @property
    def t_boot(self) -> float:
        """Simulated seconds since boot."""
        return self.clock.t

    def receive_datagram(self, data: bytes, addr: Addr, now: float, link: str = "offboard") -> None:
        """Feed one datagram received on `link` from `addr` at time `now`."""
        if self._sim_time(now) > self.clock.t:  # (advance's own early return)
            self.advance(now)
        lk = self.comms.by_name.get(link)
        if lk is None:
            raise KeyError(f"unknown link {link!r}; links are {sorted(self.comms.by_name)}")
        self.comms.receive(lk, data, addr)

    def datagrams_to_send(self, now: float, link: str | None = None) -> list[tuple[bytes, Addr]]:
        """Datagrams due by `now` on one link (or all links), with their destinations."""
        # physics steps may land a hair past `now`
        return self.comms.datagrams_to_send(self._sim_time(now) + 1e-9, link)

    def frames_to_send(self, now: float, link: str) -> list[bytes]:
        """`datagrams_to_send(now, link)`'s datagrams without their destinations."""
        return self.comms.frames_due(self._sim_time(now) + 1e-9, link)

    def get_timer(self) -> float:
        """Next time (caller's clock) at which `handle_timer` has work to do."""
        t = (self._n_steps + 1) * self.dt
        if self._events:
            t = min(t, self._events[0][0])
        return self.caller_time(self.comms.next_due(t))

    def handle_timer(self, now: float) -> None:
        """Run everything due by `now` (physics steps, telemetry, retries, failsafes)."""
        self.advance(now)

    def advance(self, now: float) -> None:
        """Advance simulated time to `now` (the caller's clock), stepping physics at the fixed
        rate."""
        clock = self.clock
        t_end = self._sim_time(now)
        if not t_end > clock.t:  # also rejects NaN
            return
        dt = self.dt
        t_lim = t_end + 1e-12
        delayed_rx = self.comms.delayed_rx
        comms = self.comms
        while True:
            t_phys = (self._n_steps + 1) * dt
            if self._events or delayed_rx:
                t_next_ev = self._next_input_time()
                if t_next_ev <= t_end and t_next_ev <= t_phys:
                    clock.t = max(clock.t, t_next_ev)
                    self._run_events()
                    continue
            if t_phys <= t_lim:
                self._physics_step(t_phys)
                # physics-only steps follow only if neither the end, the commander nor the
                # telemetry is due at the next step (rare while streaming: skip the call)
                t_next = (self._n_steps + 1) * dt
                if (
                    t_next < t_lim
                    and t_next < self._cmd_next_t - 1e-9
                    and t_next < comms.tele_next_t
                ):
                    self._quiet_steps(t_end)
                continue
            break
        clock.t = max(clock.t, t_end)

    def _onboard_inputs(self) -> tuple[bool, bool]:
        """What the onboard module reads of vehicle_status / vehicle_local_position: armed in
        OFFBOARD, and the position and velocity estimate valid."""
        cmdr = self.commander
        return cmdr.armed and cmdr.mode is _OFFBOARD, cmdr.local_position_valid

    def _module_log(self, severity: int, text: str) -> None:
        """The onboard module's console: warnings and errors reach the links as STATUSTEXT
        (PX4's log_message), information stays in the log."""
        if severity <= mavlink.MAV_SEVERITY_WARNING:
            self.comms.statustext(severity, f"ecca_onboard: {text}")
        else:
            _log.debug("ecca_onboard: %s", text)

    # ================================================================== time and events
    def _next_input_time(self) -> float:
        """Time of the next scheduled event or delayed inbound datagram (inf if none)."""
        t = self._events[0][0] if self._events else math.inf
        for rx in self.comms.delayed_rx:
            if len(rx):
                t = min(t, rx.next_due())
        return t

    def _schedule(self, delay_s: float, fn: Callable[[], None]) -> None:
        self._event_order += 1
        heapq.heappush(self._events, (self.clock.t + delay_s, self._event_order, fn))

    def _run_events(self) -> None:
        t = self.clock.t
        while self._events and self._events[0][0] <= t:
            _, _, fn = heapq.heappop(self._events)
            fn()
        self.comms.deliver_delayed()

    def _physics_step(self, t_phys: float) -> None:
        self._n_steps += 1
        self.clock.t = t_phys
        onboard = self.onboard
        if onboard is not None and onboard.due(t_phys):
            onboard.cycle()  # before the controllers: its setpoint is flown from this step on
        cmdr = self.commander
        if self.offboard.pending:
            self.offboard.release()
        ob_target = self.offboard.target
        if (cmdr.armed and cmdr.mode is _OFFBOARD and ob_target is not None
                and type(ob_target) is cmdr.control_kind):
            target: Target = ob_target  # the streaming case of `target()`, without the call
        else:
            target = cmdr.target()
        self._last_target = target
        self.vehicle.step(self.dt, target, cmdr.armed)
        self.view.stale = True
        if t_phys >= self._cmd_next_t - 1e-9:  # commander at <= 200 Hz
            self._cmd_next_t = t_phys + COMMANDER_PERIOD_S
            self._commander_tick(t_phys)
        if self._events and self._events[0][0] <= t_phys:
            self._run_events()
        if t_phys >= self.comms.tele_next_t:
            self._telemetry(t_phys)

    def _quiet_steps(self, t_end: float) -> None:
        """Physics-only steps up to the next step where anything else is due.

        Exactly what `_physics_step` would do on those steps (same target, no commander,
        telemetry, navigator or event work), without its per-step bookkeeping.
        """
        cmdr = self.commander
        if self.onboard is not None or cmdr.descend or (cmdr.nav_active
                                                        and cmdr.nav_target is None):
            return  # (the onboard module runs at every 4 ms step)
        dt = self.dt
        n = self._n_steps
        t_next = (n + 1) * dt
        horizon = min(
            t_end + 1e-12,
            self._next_input_time(),
            self._cmd_next_t - 1e-9,
            self.comms.tele_next_t,
        )
        if cmdr.nav_active and cmdr.armed and cmdr.mode is not _OFFBOARD:
            horizon = min(horizon, cmdr.nav_next_t - 1e-9)
        if t_next >= horizon:
            return
        step = self.vehicle.step
        target, armed = self._last_target, cmdr.armed
        while (n + 1) * dt < horizon:
            step(dt, target, armed)
            n += 1
        self._n_steps = n
        self.clock.t = n * dt
        self.view.stale = True

    def _commander_tick(self, t: float) -> None:
        cmdr = self.commander
        veh = self.vehicle  # its flags at this tick (read without building a snapshot)
        landed, pos_valid = veh.landed, veh.local_position_valid
        cmdr.housekeeping(t)
        self.missions.update(t, cmdr.mode is _AUTO_MISSION)
        cmdr.update(t, landed, pos_valid)

    # ================================================================== telemetry
    def _telemetry(self, t: float) -> None:
        """Build and queue the periodic messages due at `t` on every link, from one status
        (each part built at most once, when a message needs it)."""
        vehicle: VehicleStatus | None = None
        full: StatusSnapshot | None = None

        def build(msg_id: int) -> Msg | None:
            nonlocal vehicle, full
            if vehicle is None:
                vehicle = self.vehicle_status()
            fn = _VEHICLE_BUILDERS.get(msg_id)
            if fn is not None:
                return fn(vehicle)
            if msg_id == _PING:
                return self._ping(vehicle)
            if msg_id == _HIL:
                return telemetry.build_hil_state_quaternion(vehicle, self.vehicle.true_state)
            if full is None:
                full = self.status(vehicle)
            return _STATUS_BUILDERS[msg_id](full)

        def would_send(msg_id: int) -> bool | None:
            nonlocal vehicle
            if vehicle is None:
                vehicle = self.vehicle_status()
            return _QUIETABLE[msg_id](vehicle)

        self.comms.emit_streams(t, build, would_send)

    def quiet_streams(self, link: str, msg_ids: Iterable[int]) -> None:
        """Telemetry streams on `link` that nobody reads: not built nor sent, while the link's
        sequence numbers, fault channel and counters go on as if they were, so every other
        message is the same, byte for byte (see `Links.quiet_streams`; ValueError for a
        stream whose message cannot be known unbuilt)."""
        self.comms.quiet_streams(self.comms.by_name[link], frozenset(msg_ids))

    def _ping(self, vehicle: VehicleStatus) -> Msg:
        self.ping_seq = (self.ping_seq + 1) & 0xFFFFFFFF
        return telemetry.ping_message(vehicle.time_usec, self.ping_seq)

    def _request_build(self, msg_id: int) -> Msg | None:
        """A streamable message now (REQUEST_MESSAGE)."""
        fn = _VEHICLE_BUILDERS.get(msg_id)
        if fn is not None:
            return fn(self.vehicle_status())
        if msg_id == _PING:
            return self._ping(self.vehicle_status())
        if msg_id == _HIL:
            return telemetry.build_hil_state_quaternion(self.vehicle_status(),
                                                        self.vehicle.true_state)
        return _STATUS_BUILDERS[msg_id](self.status())

    def vehicle_status(self) -> VehicleStatus:
        """The vehicle's side of the status now (what the high-rate streams report)."""
        clock = self.clock
        veh = self.vehicle
        estimator_ready = self.commander.estimator_ready
        return frozen_new(
            VehicleStatus,
            {
                "time_boot_ms": clock.time_boot_ms,
                "time_usec": clock.time_usec,
                "time_ns": clock.time_ns,
                "state": self.view.state,
                "attitude": veh.attitude,
                "last_attitude_target": veh.last_attitude_target,
                "last_position_target": veh.last_position_target,
                "home": self.commander.home,
                "estimator_ready": estimator_ready,
                "local_position_valid": estimator_ready and veh.local_position_valid,
            },
        )

    def status(self, vehicle: VehicleStatus | None = None) -> StatusSnapshot:
        """The whole status now, as the telemetry reports it (`vehicle`: its vehicle side, if
        already built at this instant)."""
        cmdr = self.commander
        mode = cmdr.mode
        server = self.missions.server
        ex = self.missions.executor
        items = server.items[MISSION]
        if not items:
            m_state = mavlink.MISSION_STATE_NO_MISSION
        elif ex.finished:
            m_state = mavlink.MISSION_STATE_COMPLETE
        elif mode == Mode.AUTO_MISSION and ex.active:
            m_state = mavlink.MISSION_STATE_ACTIVE
        elif cmdr.mission_started:
            m_state = mavlink.MISSION_STATE_PAUSED
        else:
            m_state = mavlink.MISSION_STATE_NOT_STARTED
        battery = cmdr.battery_remaining
        return frozen_new(
            StatusSnapshot,
            {
                "vehicle": vehicle if vehicle is not None else self.vehicle_status(),
                "mav_type": _MAV_TYPE[self.kind],
                "base_mode": cmdr.base_mode,
                "custom_mode": mode.custom_mode,
                "system_status": cmdr.system_status,
                "prearm_ok": cmdr.arming_denial(mode) is None,
                "battery_remaining": battery,
                "battery_voltage_mv": round(4 * (3.5 + 0.7 * battery) * 1000.0),
                "errors_comm": self.errors_comm,
                "landed_state": cmdr.landed_state,
                "mission_seq": ex.current,
                "mission_total": len(items) if items else 65535,
                "mission_state": m_state,
                "mission_mode": 1 if mode == Mode.AUTO_MISSION else 2,
                "mission_id": server.opaque_id[MISSION],
            },
        )

    # ================================================================== derived state
    @property
    def links(self) -> dict[str, Link]:
        """The links by name."""
        return self.comms.by_name

    @property
    def mission_server(self) -> MissionServer:
        return self.missions.server

    @property
    def mission(self) -> MissionExecutor:
        return self.missions.executor

    @property
    def home(self) -> tuple[float, float, float]:
        """Home (lat deg, lon deg, alt AMSL m)."""
        return self.commander.home

    @property
    def estimator_ready_s(self) -> float:
        return self.commander.estimator_ready_s

    @property
    def mode(self) -> Mode:
        return self.commander.mode

    @property
    def user_mode(self) -> Mode:
        return self.commander.user_mode

    @property
    def armed(self) -> bool:
        return self.commander.armed

    @property
    def failsafe(self) -> bool:
        return self.commander.failsafe

    @property
    def rc_present(self) -> bool:
        return self.commander.rc_present

    @property
    def state(self) -> VehicleState:
        """Vehicle state snapshot (the same object until the next physics step)."""
        return self.view.state

    @property
    def time_boot_ms(self) -> int:
        return self.clock.time_boot_ms

    @property
    def time_usec(self) -> int:
        return self.clock.time_usec

    @property
    def time_ns(self) -> int:
        return self.clock.time_ns

    @property
    def estimator_ready(self) -> bool:
        return self.commander.estimator_ready

    @property
    def home_set(self) -> bool:
        """Home is set once the estimator is ready (PX4 SITL: at boot, before arming)."""
        return self.commander.estimator_ready

    @property
    def local_position_valid(self) -> bool:
        return self.commander.local_position_valid

    @property
    def offboard_fresh(self) -> bool:
        """Offboard proof of life: a valid setpoint within COM_OF_LOSS_T."""
        return self.offboard.fresh

    @property
    def battery_remaining(self) -> float:
        return self.commander.battery_remaining

    @property
    def battery_voltage_mv(self) -> int:
        return round(4 * (3.5 + 0.7 * self.battery_remaining) * 1000.0)

    @property
    def errors_comm(self) -> int:
        return self.stats["rx_bad_data"] + self.stats["rx_mavlink1"]

    @property
    def in_air(self) -> bool:
        return self.commander.in_air

    @property
    def landed_state(self) -> int:
        return self.commander.landed_state

    def prearm_ok(self, mode: Mode | None = None) -> bool:
        """True if arming would be accepted now in `mode` (default: the current mode)."""
        return self.commander.arming_denial(mode or self.commander.mode) is None

    @property
    def system_status(self) -> int:
        return self.commander.system_status

    @property
    def base_mode(self) -> int:
        return self.commander.base_mode

    # ================================================================== messages
    def heartbeat_message(self) -> Msg:
        return telemetry.build_heartbeat(self.status())

    def home_position_message(self) -> Msg:
        return telemetry.home_position_message(self.commander.home, self.clock.time_usec)

    def autopilot_version_message(self) -> Msg:
        return telemetry.autopilot_version_message()

    def mission_current_message(self) -> Msg:
        return telemetry.build_mission_current(self.status())

    def statustext(self, severity: int, text: str) -> None:
        """STATUSTEXT on every link, chunked (id / chunk_seq) when longer than 50 chars."""
        self.comms.statustext(severity, text)

    # ================================================================== convenience
    def set_rc_present(self, present: bool) -> None:
        """Pretend an RC transmitter / joystick is (not) connected (enables manual modes)."""
        self.commander.rc_present = present
