"""Sans-IO PX4 v1.16-like autopilot core: MAVLink bytes in, MAVLink bytes out, time injected.

Shape of aioquic's QuicConnection: `receive_datagram(data, addr, now, link)`,
`datagrams_to_send(now, link)`, `get_timer()`, `handle_timer(now)` (= `advance(now)`). The core
never reads a clock and never touches a socket. `now` is simulated time in seconds on any
monotonic origin (boot is the `now` given to the constructor). Physics is stepped at a fixed
rate (default 250 Hz) inside `advance`, and telemetry is emitted at PX4's onboard-link rates on
the simulated clock, so the same inputs give the same outputs in real time or in lockstep.

Two links like PX4 SITL: "offboard" (the API / onboard link, PX4 binds 14580 and talks to
14540) and "gcs" (binds 18570, talks to 14550). MAVLink 2 only, sysid 1, compid 1.
"""

from __future__ import annotations

import heapq
import logging
import math
import struct
from collections import Counter, deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from enum import Enum
from typing import Any, ClassVar

from pymavlink.dialects.v20 import common as mavlink

from sitl_mock import telemetry
from sitl_mock.faults import FaultyChannel, LinkFaults, ScenarioFaults
from sitl_mock.mavwire import MessageCodec, codec, decode_datagram, pack_v2, unpack_single
from sitl_mock.mission_server import MISSION, MissionExecutor, MissionServer, project_to_ned
from sitl_mock.params import PARAMS, ParamStore
from sitl_mock.setpoints import (
    NAN3,
    AttitudeTarget,
    IdleTarget,
    PositionTarget,
    Target,
    Vec3,
    make_attitude_target,
)
from sitl_mock.signing import LinkSigning, boot_ticks_of
from sitl_mock.vehicle import DEFAULT_HOME, Vehicle, VehicleState, make_vehicle

log = logging.getLogger(__name__)

Msg = Any
Addr = Any  # (host, port) for UDP, anything hashable for in-memory links

SYSID = 1
RESULT_ACCEPTED: int = int(mavlink.MAV_RESULT_ACCEPTED)
RESULT_DENIED: int = int(mavlink.MAV_RESULT_DENIED)
RESULT_FAILED: int = int(mavlink.MAV_RESULT_FAILED)
RESULT_TEMPORARILY_REJECTED: int = int(mavlink.MAV_RESULT_TEMPORARILY_REJECTED)
RESULT_UNSUPPORTED: int = int(mavlink.MAV_RESULT_UNSUPPORTED)
COMPID = 1
FORCE_MAGIC = 21196
MODE_ACK_DELAY_S = 0.010  # the commander's verdict follows the receiver's ACCEPTED by ~10 ms
FAILSAFE_ACTION_DELAY_S = 0.5  # loss detected at COM_OF_LOSS_T, mode switch 0.5 s later
COMMANDER_PERIOD_S = 0.005
NAVIGATOR_PERIOD_S = 0.01
DESCEND_SPEED_NO_RC = 0.6  # [m/s] observed sink rate in POSCTL without RC (PX4.md)
AUTOPILOT_CAPABILITIES = (
    mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT
    | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
    | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
    | mavlink.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
    | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
    | mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_FENCE
    | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_RALLY
)
FLIGHT_SW_VERSION = (1 << 24) | (16 << 16) | (0 << 8) | 255  # v1.16.0 release


class Mode(Enum):
    """PX4 flight modes the mock knows: value = (main_mode, sub_mode, base_mode flags)."""

    MANUAL = (1, 0, 64 | 16)
    ALTCTL = (2, 0, 64 | 16)
    POSCTL = (3, 0, 64 | 16)
    AUTO_TAKEOFF = (4, 2, 4 | 8 | 16)
    AUTO_LOITER = (4, 3, 4 | 8 | 16)
    AUTO_MISSION = (4, 4, 4 | 8 | 16)
    AUTO_RTL = (4, 5, 4 | 8 | 16)
    AUTO_LAND = (4, 6, 4 | 8 | 16)
    ACRO = (5, 0, 64)
    OFFBOARD = (6, 0, 16)
    STABILIZED = (7, 0, 64 | 16)

    @property
    def custom_mode(self) -> int:
        main, sub, _ = self.value
        return (main << 16) | (sub << 24)

    @property
    def label(self) -> str:
        return _MODE_LABELS[self]

    @classmethod
    def from_custom(cls, main: int, sub: int) -> Mode | None:
        for m in cls:
            if m.value[0] == main and (m.value[1] == sub or (main != 4 and sub == 0)):
                return m
        if main == 4 and sub == 1:  # AUTO.READY: PX4 treats it as Hold on a multicopter
            return cls.AUTO_LOITER
        return None


_MODE_LABELS = {
    Mode.MANUAL: "Manual",
    Mode.ALTCTL: "Altitude",
    Mode.POSCTL: "Position",
    Mode.AUTO_TAKEOFF: "Takeoff",
    Mode.AUTO_LOITER: "Hold",
    Mode.AUTO_MISSION: "Mission",
    Mode.AUTO_RTL: "Return",
    Mode.AUTO_LAND: "Land",
    Mode.ACRO: "Acro",
    Mode.OFFBOARD: "Offboard",
    Mode.STABILIZED: "Stabilized",
}
# the modes compared on every physics step / commander tick (a module global is ~10x cheaper
# to reach than an Enum class attribute)
_OFFBOARD = Mode.OFFBOARD
_AUTO_MISSION = Mode.AUTO_MISSION
_AUTO_TAKEOFF = Mode.AUTO_TAKEOFF
MANUAL_MODES = frozenset({Mode.MANUAL, Mode.ALTCTL, Mode.POSCTL, Mode.ACRO, Mode.STABILIZED})
AUTO_MODES = frozenset(
    {Mode.AUTO_TAKEOFF, Mode.AUTO_LOITER, Mode.AUTO_MISSION, Mode.AUTO_RTL, Mode.AUTO_LAND}
)
# COM_OBL_RC_ACT -> failsafe mode (None = disarm)
OFFBOARD_LOSS_ACTIONS: dict[int, Mode | None] = {
    0: Mode.POSCTL,
    1: Mode.ALTCTL,
    2: Mode.MANUAL,
    3: Mode.AUTO_RTL,
    4: Mode.AUTO_LAND,
    5: Mode.AUTO_LOITER,
    6: None,
    7: None,
}


@dataclass
class Link:
    """One MAVLink link: codec state, peer address, fault channels, stream schedule."""

    name: str
    remote: Addr | None
    mav: Any
    rx: FaultyChannel[tuple[bytes, Addr]]
    tx: FaultyChannel[bytes]
    streams: telemetry.StreamScheduler
    peer: Addr | None = None
    # outbound without faults: a FIFO of (time since boot [s], frame), exactly the order and due
    # times the pass-through FaultyChannel would give, without its heap entries
    tx_fifo: deque[tuple[float, bytes]] | None = None
    # inbound without faults: datagrams are processed on arrival (rx never queues anything)
    rx_direct: bool = False
    # MAVLink 2 signing (None: off): signs everything sent, refuses unsigned/bad frames
    signing: LinkSigning | None = None

    @property
    def destination(self) -> Addr | None:
        return self.peer if self.peer is not None else self.remote


def _finite(*vals: float) -> bool:
    return all(math.isfinite(v) for v in vals)


def _float_bits_of_int(v: int) -> float:
    """PX4 bytewise encoding: the int32's bytes reinterpreted as a float32."""
    return float(struct.unpack("<f", struct.pack("<i", int(v)))[0])


def _int_of_float_bits(f: float) -> int:
    return int(struct.unpack("<i", struct.pack("<f", f))[0])



class MissionCurrentV2(mavlink.MAVLink_mission_current_message):  # type: ignore[misc]
    """MISSION_CURRENT with the extensions PX4 v1.16 sends (pymavlink 2.4 lacks them):
    ``mission_id`` is the stored mission's opaque id (0 without a mission), so a ground station
    or companion sees a new upload; fence and rally ids stay 0 (trimmed on the wire)."""

    fieldnames: ClassVar[list[str]] = [*mavlink.MAVLink_mission_current_message.fieldnames,
                                       "mission_id", "fence_id", "rally_points_id"]
    ordered_fieldnames: ClassVar[list[str]] = fieldnames
    fieldtypes: ClassVar[list[str]] = [*mavlink.MAVLink_mission_current_message.fieldtypes,
                                       "uint32_t", "uint32_t", "uint32_t"]
    array_lengths: ClassVar[list[int]] = [0] * 7
    unpacker = struct.Struct("<HHBBIII")

    def __init__(self, seq: int, total: int = 0, mission_state: int = 0, mission_mode: int = 0,
                 mission_id: int = 0, fence_id: int = 0, rally_points_id: int = 0) -> None:
        super().__init__(seq, total, mission_state, mission_mode)
        self.mission_id = mission_id
        self.fence_id = fence_id
        self.rally_points_id = rally_points_id


class Autopilot:
    """The mock PX4: modes, arming, commands, offboard, failsafes, missions, params, telemetry.

    vehicle_kind: "quad" or "rover"; params: a ParamStore or NAME -> value overrides;
    home: (lat deg, lon deg, alt AMSL m); seed: for the vehicle noise and the fault channels;
    physics_hz: fixed physics/control rate (>= 250 Hz); now: the boot time on the caller's
    clock; remotes: link name -> default destination (PX4 sends there until a peer talks);
    link_faults: link name -> (inbound, outbound) LinkFaults; scenario: vehicle-level faults;
    estimator_ready_s: time after boot before the estimator is ready and arming is possible;
    signing_key: 32-byte MAVLink 2 signing key (None: no signing; see sitl_mock/signing.py),
    then unix_boot_s, the wall clock at boot [UNIX s], starts the signing timestamps.
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
    ) -> None:
        if not (math.isfinite(physics_hz) and physics_hz >= 250.0):
            raise ValueError(f"physics rate must be >= 250 Hz, got {physics_hz!r}")
        if vehicle_kind not in ("quad", "rover"):
            raise ValueError(f"unknown vehicle kind {vehicle_kind!r}: use 'quad' or 'rover'")
        if signing_key is not None and unix_boot_s is None:
            raise ValueError("signing needs unix_boot_s (the wall clock at boot) for timestamps")
        self.params = params if isinstance(params, ParamStore) else ParamStore(params or {})
        self.kind = vehicle_kind
        self.home = (float(home[0]), float(home[1]), float(home[2]))
        self.seed = seed
        self.vehicle: Vehicle = vehicle or make_vehicle(vehicle_kind, self.params, self.home, seed)
        self.dt = 1.0 / physics_hz
        self._boot = float(now)
        self._t = 0.0  # time since boot of the last processed event [s]
        self._n_steps = 0
        self.estimator_ready_s = estimator_ready_s
        self.scenario = scenario or ScenarioFaults()
        self.stats: Counter[str] = Counter()
        self.ping_seq = 0
        self._events: list[tuple[float, int, Callable[[], None]]] = []
        self._event_order = 0
        self._statustext_id = 0
        # links
        remotes = dict(remotes) if remotes is not None else {"offboard": None}
        faults = dict(link_faults or {})
        self.links: dict[str, Link] = {}
        for i, (name, remote) in enumerate(remotes.items()):
            f_in, f_out = faults.get(name, (None, None))
            rates = telemetry.ONBOARD_RATES_HZ if name == "offboard" else telemetry.GCS_RATES_HZ
            self.links[name] = Link(
                name=name,
                remote=remote,
                mav=mavlink.MAVLink(None, srcSystem=SYSID, srcComponent=COMPID),
                rx=FaultyChannel(f_in, seed * 1000 + 2 * i + 1),
                tx=FaultyChannel(f_out, seed * 1000 + 2 * i + 2),
                streams=telemetry.StreamScheduler(rates, 0.0),
                tx_fifo=None if f_out is not None and f_out.active else deque(),
                rx_direct=not (f_in is not None and f_in.active),
                signing=None
                if signing_key is None
                else LinkSigning(signing_key, i, boot_ticks_of(float(unix_boot_s or 0.0))),
            )
        # inbound channels that can hold datagrams back (faults configured); a pass-through
        # channel delivers at once in receive_datagram and never queues anything
        self._delayed_rx = [lk.rx for lk in self.links.values() if not lk.rx_direct]
        # commander state
        self.mode = Mode.AUTO_LOITER
        self.user_mode = Mode.AUTO_LOITER
        self.armed = False
        self.failsafe = False
        self.rc_present = False
        self._home_announced = False
        self._armed_t = 0.0
        self._taken_off = False
        self._landed_since: float | None = None
        self._takeoff_alt_rel = float(self.params["MIS_TAKEOFF_ALT"])
        self._takeoff_done = False
        self._hold_ned: tuple[float, float, float] | None = None
        self._descend = False
        self._nav_active = False
        # offboard
        self._ob_last_t = -math.inf
        self._ob_target: PositionTarget | AttitudeTarget | None = None
        self._ob_loss_t: float | None = None
        # battery
        self._bat_warned = 0  # 0 none, 1 low, 2 critical, 3 emergency
        self._slow_next_t = 0.0
        self._cmd_next_t = 0.0
        self._last_target: Target = _IDLE
        self._tele_next_t = 0.0
        self._nav_target: PositionTarget | None = None
        self._nav_last_t = 0.0
        self._nav_next_t = 0.0
        self._battery_cap = 1.0  # low-battery fault: the level never rises above this again
        # scenario faults bookkeeping
        self._scn_takeover_done = False
        self._scn_pos_state = 0  # 0 before, 1 lost, 2 restored
        self._scn_battery_done = False
        # navigator and missions
        from sitl_mock.navigator import Navigator

        self.nav = Navigator(self.params, ground_vehicle=self.kind == "rover")
        self._mission_link = "offboard"
        self.mission_server = MissionServer(
            self._send_mission_reply, self.statustext, self._on_mission_changed, SYSID, COMPID
        )
        self.mission = MissionExecutor(
            self.nav,
            self.params,
            self.home,
            self._on_item_reached,
            self._on_item_current,
            self._on_mission_finished,
        )
        self._mission_started = False
        self._reached_seq: int | None = None
        self._reached_next_t = math.inf
        self._state_cache: VehicleState = self.vehicle.state
        self._state_stale = False

    # ================================================================== public sans-IO API
    @property
    def now(self) -> float:
        """Current simulated time on the caller's clock."""
        return self._boot + self._t

    @property
    def t_boot(self) -> float:
        """Simulated seconds since boot."""
        return self._t

    def receive_datagram(self, data: bytes, addr: Addr, now: float, link: str = "offboard") -> None:
        """Feed one datagram received on `link` from `addr` at time `now`."""
        if now - self._boot > self._t:  # (advance's own early return, without the call)
            self.advance(now)
        lk = self.links.get(link)
        if lk is None:
            raise KeyError(f"unknown link {link!r}; links are {sorted(self.links)}")
        if lk.peer is None:
            lk.peer = addr  # like PX4: lock onto the first peer that talks to us
        if lk.rx_direct:  # pass-through: deliver now
            lk.rx.stats.passed += 1
            self._process_datagram(lk, bytes(data), addr)
            return
        lk.rx.push((bytes(data), addr), self._t, self._t)
        for d, a in lk.rx.pop_due(self._t):
            self._process_datagram(lk, d, a)

    def datagrams_to_send(self, now: float, link: str | None = None) -> list[tuple[bytes, Addr]]:
        """Datagrams due by `now` on one link (or all links), with their destinations."""
        t = now - self._boot + 1e-9  # physics steps may land a hair past `now`
        out: list[tuple[bytes, Addr]] = []
        for lk in self.links.values() if link is None else (self.links[link],):
            dest = lk.peer if lk.peer is not None else lk.remote  # lk.destination
            fifo = lk.tx_fifo
            if fifo is not None:
                while fifo and fifo[0][0] <= t:
                    data = fifo.popleft()[1]
                    if dest is not None:
                        out.append((data, dest))
                continue
            for data in lk.tx.pop_due(t):
                if dest is not None:
                    out.append((data, dest))
        return out

    def get_timer(self) -> float:
        """Next time (caller's clock) at which `handle_timer` has work to do."""
        t = (self._n_steps + 1) * self.dt
        if self._events:
            t = min(t, self._events[0][0])
        for lk in self.links.values():
            t = min(t, lk.rx.next_due(), lk.tx.next_due())
            if lk.tx_fifo:
                t = min(t, lk.tx_fifo[0][0])
        return self._boot + t

    def handle_timer(self, now: float) -> None:
        """Run everything due by `now` (physics steps, telemetry, retries, failsafes)."""
        self.advance(now)

    def advance(self, now: float) -> None:
        """Advance simulated time to `now`, stepping physics at the fixed rate."""
        t_end = now - self._boot
        if not t_end > self._t:  # also rejects NaN
            return
        dt = self.dt
        t_lim = t_end + 1e-12
        delayed_rx = self._delayed_rx
        while True:
            t_phys = (self._n_steps + 1) * dt
            if self._events or delayed_rx:
                t_next_ev = self._next_input_time()
                if t_next_ev <= t_end and t_next_ev <= t_phys:
                    self._t = max(self._t, t_next_ev)
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
                    and t_next < self._tele_next_t
                ):
                    self._quiet_steps(t_end)
                continue
            break
        self._t = max(self._t, t_end)

    def _next_input_time(self) -> float:
        """Time of the next scheduled event or delayed inbound datagram (inf if none)."""
        t = self._events[0][0] if self._events else math.inf
        for rx in self._delayed_rx:
            if len(rx):
                t = min(t, rx.next_due())
        return t

    def _quiet_steps(self, t_end: float) -> None:
        """Physics-only steps up to the next step where anything else is due.

        Exactly what `_physics_step` would do on those steps (same target, no commander,
        telemetry, navigator or event work), without its per-step bookkeeping.
        """
        if self._descend or (self._nav_active and self._nav_target is None):
            return
        dt = self.dt
        n = self._n_steps
        t_next = (n + 1) * dt
        horizon = min(
            t_end + 1e-12,
            self._next_input_time(),
            self._cmd_next_t - 1e-9,
            self._tele_next_t,
        )
        if self._nav_active and self.armed and self.mode is not _OFFBOARD:
            horizon = min(horizon, self._nav_next_t - 1e-9)
        if t_next >= horizon:
            return
        step = self.vehicle.step
        target, armed = self._last_target, self.armed
        while (n + 1) * dt < horizon:
            step(dt, target, armed)
            n += 1
        self._n_steps = n
        self._t = n * dt
        self._state_stale = True

    # ================================================================== derived state
    @property
    def _state(self) -> VehicleState:
        """Vehicle state snapshot, fetched lazily once per physics step."""
        if self._state_stale:
            self._state_cache = self.vehicle.state
            self._state_stale = False
        return self._state_cache

    @property
    def state(self) -> VehicleState:
        """Vehicle state snapshot (the same object until the next physics step)."""
        return self._state

    @property
    def time_boot_ms(self) -> int:
        return int(self._t * 1000.0) & 0xFFFFFFFF

    @property
    def time_usec(self) -> int:
        return int(self._t * 1e6)

    @property
    def time_ns(self) -> int:
        return int(self._t * 1e9)

    @property
    def estimator_ready(self) -> bool:
        return self._t >= self.estimator_ready_s

    @property
    def home_set(self) -> bool:
        """Home is set once the estimator is ready (PX4 SITL: at boot, before arming)."""
        return self.estimator_ready

    @property
    def local_position_valid(self) -> bool:
        return self.estimator_ready and self.vehicle.local_position_valid

    @property
    def offboard_fresh(self) -> bool:
        """Offboard proof of life: a valid setpoint within COM_OF_LOSS_T."""
        return (self._t - self._ob_last_t) < float(self.params["COM_OF_LOSS_T"])

    @property
    def battery_remaining(self) -> float:
        return max(0.0, min(1.0, self._battery_cap, float(self.vehicle.battery_remaining)))

    @property
    def battery_voltage_mv(self) -> int:
        return round(4 * (3.5 + 0.7 * self.battery_remaining) * 1000.0)

    @property
    def errors_comm(self) -> int:
        return self.stats["rx_bad_data"] + self.stats["rx_mavlink1"]

    @property
    def in_air(self) -> bool:
        return self.kind == "quad" and not self.vehicle.landed

    @property
    def landed_state(self) -> int:
        if self.kind != "quad":
            return int(mavlink.MAV_LANDED_STATE_ON_GROUND)
        if self.armed and self.mode == Mode.AUTO_TAKEOFF and not self._takeoff_done:
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

    def prearm_ok(self, mode: Mode | None = None) -> bool:
        """True if arming would be accepted now in `mode` (default: the current mode)."""
        return self._arming_denial(mode or self.mode) is None

    def _arming_denial(self, mode: Mode) -> str | None:
        if not self.estimator_ready or not self.vehicle.local_position_valid:
            return "Arming denied: Resolve system health failures first"
        if self.battery_remaining < float(self.params["BAT_CRIT_THR"]):
            return "Arming denied: Resolve system health failures first"
        if mode in MANUAL_MODES and not self.rc_present:
            return "Arming denied: Resolve system health failures first"
        if mode == Mode.OFFBOARD and not self.offboard_fresh:
            return "Arming denied: Resolve system health failures first"
        if mode == Mode.AUTO_MISSION and not self.mission.valid:
            return "Arming denied: Resolve system health failures first"
        return None

    @property
    def system_status(self) -> int:
        if self.armed:
            return int(mavlink.MAV_STATE_CRITICAL if self.failsafe else mavlink.MAV_STATE_ACTIVE)
        return int(mavlink.MAV_STATE_STANDBY if self.prearm_ok() else mavlink.MAV_STATE_UNINIT)

    @property
    def base_mode(self) -> int:
        flags = self.mode.value[2]
        if self.mode == Mode.OFFBOARD and not self.offboard_fresh:
            flags = 0
        return int(mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED) | flags | (128 if self.armed else 0)

    # ================================================================== messages
    def heartbeat_message(self) -> Msg:
        mav_type = (
            mavlink.MAV_TYPE_QUADROTOR if self.kind == "quad" else mavlink.MAV_TYPE_GROUND_ROVER
        )
        return mavlink.MAVLink_heartbeat_message(
            mav_type,
            mavlink.MAV_AUTOPILOT_PX4,
            self.base_mode,
            self.mode.custom_mode,
            self.system_status,
            3,
        )

    def home_position_message(self) -> Msg:
        lat, lon, alt = self.home
        return mavlink.MAVLink_home_position_message(
            round(lat * 1e7),
            round(lon * 1e7),
            round(alt * 1000.0),
            0.0,
            0.0,
            0.0,
            [1.0, 0.0, 0.0, 0.0],
            0.0,
            0.0,
            0.0,
            self.time_usec,
        )

    def autopilot_version_message(self) -> Msg:
        return mavlink.MAVLink_autopilot_version_message(
            AUTOPILOT_CAPABILITIES,
            FLIGHT_SW_VERSION,
            FLIGHT_SW_VERSION,
            0,
            0,
            [0] * 8,
            [0] * 8,
            [0] * 8,
            0,
            0,
            0x5349544C4D4F434B,  # "SITLMOCK"
        )

    def mission_current_message(self) -> Msg:
        items = self.mission_server.items[MISSION]
        if not items:
            state = mavlink.MISSION_STATE_NO_MISSION
        elif self.mission.finished:
            state = mavlink.MISSION_STATE_COMPLETE
        elif self.mode == Mode.AUTO_MISSION and self.mission.active:
            state = mavlink.MISSION_STATE_ACTIVE
        elif self._mission_started:
            state = mavlink.MISSION_STATE_PAUSED
        else:
            state = mavlink.MISSION_STATE_NOT_STARTED
        mission_mode = 1 if self.mode == Mode.AUTO_MISSION else 2
        return MissionCurrentV2(
            self.mission.current, len(items) if items else 65535, state, mission_mode,
            self.mission_server.opaque_id[MISSION],
        )

    def _send(self, link: Link, msg: Msg) -> None:
        """Queue `msg` on `link`: a pymavlink message or a telemetry (codec, fields) pair."""
        try:
            if type(msg) is tuple:
                c: MessageCodec = msg[0]
                data = c.pack_frame(link.mav.seq, SYSID, COMPID, msg[1])
            else:
                data = pack_v2(msg, link.mav.seq, SYSID, COMPID)
        except (OverflowError, struct.error):
            # a value outside float32 range (e.g. echoing an absurd setpoint): drop, count
            self.stats["tx_encode_errors"] += 1
            return
        if link.signing is not None:
            data = link.signing.sign(data, self._t)
        mav = link.mav
        mav.seq = (mav.seq + 1) & 0xFF
        fifo = link.tx_fifo
        if fifo is not None:
            fifo.append((self._t, data))
            link.tx.stats.passed += 1
        else:
            link.tx.push(data, self._t, self._t)
        self.stats["tx_messages"] += 1

    def _broadcast(self, msg: Msg) -> None:
        for lk in self.links.values():
            self._send(lk, msg)

    def _forward(self, src: Link, frame: bytes) -> None:
        """Pass another component's frame unchanged to the other links (PX4 `mavlink start
        -f`, on in SITL: e.g. a companion's STATUSTEXT reaches the ground station)."""
        for lk in self.links.values():
            if lk is src:
                continue
            if lk.tx_fifo is not None:
                lk.tx_fifo.append((self._t, frame))
                lk.tx.stats.passed += 1
            else:
                lk.tx.push(frame, self._t, self._t)

    def _on_statustext(self, link: Link, msg: Msg) -> None:
        if (msg.get_srcSystem(), msg.get_srcComponent()) != (SYSID, COMPID):
            self._forward(link, bytes(msg.get_msgbuf()))

    def statustext(self, severity: int, text: str) -> None:
        """STATUSTEXT on every link, chunked (id / chunk_seq) when longer than 50 chars."""
        raw = text.encode("ascii", "replace")
        if len(raw) <= 50:
            self._broadcast(mavlink.MAVLink_statustext_message(severity, raw, 0, 0))
            return
        self._statustext_id = self._statustext_id % 65535 + 1
        chunks = [raw[i : i + 50] for i in range(0, len(raw), 50)]
        if len(chunks[-1]) == 50:
            chunks.append(b"")  # the text must end with a NUL-terminated chunk
        for seq, chunk in enumerate(chunks):
            self._broadcast(
                mavlink.MAVLink_statustext_message(severity, chunk, self._statustext_id, seq)
            )

    def _schedule(self, delay_s: float, fn: Callable[[], None]) -> None:
        self._event_order += 1
        heapq.heappush(self._events, (self._t + delay_s, self._event_order, fn))

    def _run_events(self) -> None:
        while self._events and self._events[0][0] <= self._t:
            _, _, fn = heapq.heappop(self._events)
            fn()
        for lk in self.links.values():
            for d, a in lk.rx.pop_due(self._t):
                self._process_datagram(lk, d, a)

    # ================================================================== inbound
    def _process_datagram(self, link: Link, data: bytes, addr: Addr) -> None:
        stats = self.stats
        stats["rx_datagrams"] += 1
        if link.signing is not None:
            self._parse_robust(link, data)
            return
        # hot path: a datagram that is exactly one clean SET_ATTITUDE_TARGET frame (what the
        # companion streams at 50-250 Hz), handled from its unpacked fields: the same counters
        # and effects as the general path below, without a pymavlink object
        f = unpack_single(data, _C_SET_ATTITUDE_TARGET)
        if f is not None:
            stats["rx_messages"] += 1
            try:  # wire order: time, q[4], roll/pitch/yaw rate, thrust, target sys/comp, mask
                self._attitude_setpoint(f[9], f[10], f[11], f[1:5], f[5], f[6], f[7], f[8])
            except Exception:  # never let one bad message stop the vehicle
                stats["handler_errors"] += 1
                log.exception("error handling SET_ATTITUDE_TARGET")
            return
        msgs = decode_datagram(data)  # fast path: clean unsigned MAVLink 2 frames
        if msgs is None:  # anything unusual: pymavlink's robust parser, counted as always
            self._parse_robust(link, data)
            return
        self._handle_messages(link, msgs)

    def _parse_robust(self, link: Link, data: bytes) -> None:
        """A datagram through pymavlink's robust parser (no key given to pymavlink: the link's
        own signing check judges each frame in `_handle_messages`)."""
        parser = mavlink.MAVLink(None)
        parser.robust_parsing = True
        try:
            msgs = parser.parse_buffer(data) or []
        except Exception:  # pymavlink raises on some malformed input even when robust
            self.stats["rx_bad_data"] += 1
            return
        self._handle_messages(link, msgs)

    def _handle_messages(self, link: Link, msgs: list[Any]) -> None:
        for msg in msgs:
            kind = msg.get_type()
            if kind == "BAD_DATA":
                self.stats["rx_bad_data"] += 1
                continue
            if msg.get_msgbuf()[:1] != b"\xfd":
                self.stats["rx_mavlink1"] += 1  # PX4 in MAVLink 2 mode ignores v1 frames
                continue
            if link.signing is not None and not link.signing.accept(bytes(msg.get_msgbuf())):
                self.stats["rx_signing_refused"] += 1  # reasons: link.signing.refused
                continue
            self.stats["rx_messages"] += 1
            name = _HANDLER_NAMES.get(kind)
            if name is None:
                name = _HANDLER_NAMES[kind] = "_on_" + kind.lower()
            handler = getattr(self, name, None)
            if handler is None:
                self.stats["rx_unhandled"] += 1
                continue
            try:
                handler(link, msg)
            except Exception:  # never let one bad message stop the vehicle
                self.stats["handler_errors"] += 1
                log.exception("error handling %s", kind)

    def _targets_us(self, msg: Msg) -> bool:
        return self._targets(msg.target_system, msg.target_component)

    def _targets(self, target_system: int, target_component: int) -> bool:
        """Addressed to us (or broadcast, 0); anything else is counted and ignored, like PX4."""
        ok = target_system in (0, SYSID) and target_component in (0, COMPID)
        if not ok:
            self.stats["rx_wrong_target"] += 1
        return bool(ok)

    def _on_heartbeat(self, link: Link, msg: Msg) -> None:
        self.stats["rx_heartbeat"] += 1

    def _on_timesync(self, link: Link, msg: Msg) -> None:
        if msg.tc1 == 0:  # a request: answer at once (replies are not filtered by target)
            self._send(link, mavlink.MAVLink_timesync_message(self.time_ns, msg.ts1))

    def _on_ping(self, link: Link, msg: Msg) -> None:
        if msg.target_system == 0:
            self._send(
                link,
                mavlink.MAVLink_ping_message(
                    msg.time_usec, msg.seq, msg.get_srcSystem(), msg.get_srcComponent()
                ),
            )

    # ---------------------------------------------------------------- params
    def _param_value(self, name: str) -> Msg:
        spec = PARAMS[name]
        v = self.params[name]
        if spec.is_int:
            value, ptype = _float_bits_of_int(int(v)), mavlink.MAV_PARAM_TYPE_INT32
        else:
            value, ptype = float(v), mavlink.MAV_PARAM_TYPE_REAL32
        return mavlink.MAVLink_param_value_message(
            name.encode("ascii"), value, ptype, len(self.params), self.params.index(name)
        )

    def _on_param_request_list(self, link: Link, msg: Msg) -> None:
        if self._targets_us(msg):
            for name in self.params:
                self._send(link, self._param_value(name))

    def _on_param_request_read(self, link: Link, msg: Msg) -> None:
        if not self._targets_us(msg):
            return
        if msg.param_index >= 0:
            names = list(self.params)
            if msg.param_index < len(names):
                self._send(link, self._param_value(names[msg.param_index]))
            return
        name = _param_name(msg.param_id)
        if name in PARAMS:
            self._send(link, self._param_value(name))

    def _on_param_set(self, link: Link, msg: Msg) -> None:
        if not self._targets_us(msg):
            return
        name = _param_name(msg.param_id)
        spec = PARAMS.get(name)
        if spec is None:
            self.stats["param_unknown"] += 1
            return
        value = float(msg.param_value)
        real = (mavlink.MAV_PARAM_TYPE_REAL32, mavlink.MAV_PARAM_TYPE_REAL64)
        problem: str | None = None
        new = value
        if spec.is_int and msg.param_type == mavlink.MAV_PARAM_TYPE_INT32:
            new = float(_int_of_float_bits(value))
        elif spec.is_int and msg.param_type in real:
            pass  # lenient (PX4 refuses): an integral float value is taken, checked below
        elif spec.is_int or msg.param_type not in real:
            problem = "param types mismatch"  # PX4's words ("[pm] param types mismatch ...")
        if problem is None:
            try:
                self.params.set(name, new)
            except ValueError as exc:
                problem = str(exc)
        if problem is not None:
            # PX4 takes any in-type value; the mock refuses what would break its simulation or
            # lies outside PX4's metadata range, says why, and echoes the unchanged value
            self.stats["param_rejected"] += 1
            self.statustext(mavlink.MAV_SEVERITY_ERROR, f"[pm] {name}: {problem}")
        self._broadcast(self._param_value(name))

    # ---------------------------------------------------------------- mission protocol
    def _send_mission_reply(self, msg: Msg) -> None:
        self._send(self.links[self._mission_link], msg)

    def _mission_message(self, link: Link, msg: Msg) -> None:
        if not self._targets_us(msg):
            return
        self._mission_link = link.name
        self.mission_server.handle(msg, self._t)

    _on_mission_count = _mission_message
    _on_mission_item = _mission_message
    _on_mission_item_int = _mission_message
    _on_mission_request = _mission_message
    _on_mission_request_int = _mission_message
    _on_mission_request_list = _mission_message
    _on_mission_ack = _mission_message
    _on_mission_clear_all = _mission_message

    def _on_mission_set_current(self, link: Link, msg: Msg) -> None:
        if self._targets_us(msg) and self.mission.set_current(int(msg.seq)):
            self._broadcast(self.mission_current_message())

    def _on_mission_changed(self, mission_type: int) -> None:
        if mission_type != MISSION:
            return
        self.mission.load(self.mission_server.items[MISSION])
        self._mission_started = False
        self._reached_seq = None
        self._reached_next_t = math.inf
        if self.mode == Mode.AUTO_MISSION:
            if self.mission.valid:
                self.mission.start(self._t)
                self._mission_started = True
            else:
                self._set_mode(Mode.AUTO_LOITER, user=False)

    def _on_item_reached(self, seq: int) -> None:
        self._reached_seq = seq
        self._reached_next_t = self._t + 1.0
        self._broadcast(mavlink.MAVLink_mission_item_reached_message(seq))

    def _on_item_current(self, seq: int) -> None:
        self._nav_target = None  # the executor gave the navigator a new goal
        self._broadcast(self.mission_current_message())

    def _on_mission_finished(self, landed: bool) -> None:
        self._broadcast(self.mission_current_message())
        if self.mode != Mode.AUTO_MISSION:
            return
        if landed and self.kind == "rover" and self.armed:
            # a quad's land detector disarms it after touchdown; a rover that ends its
            # mission with LAND or RTL is disarmed where it stopped
            self._disarm("mission end (rover stopped at its land point)")
            return
        if landed or not self.armed:
            return
        self.statustext(mavlink.MAV_SEVERITY_INFO, "Mission finished, loitering")
        self._set_mode(Mode.AUTO_LOITER, user=False)
        goal = self.mission.last_goal_ned
        if goal is not None:  # hold at the last waypoint, not where it was reported reached
            self.nav.goto(goal, self._state.yaw, float(self.params["NAV_ACC_RAD"]), self._state)
            self._nav_target = None

    # ---------------------------------------------------------------- setpoints
    def _on_set_position_target_local_ned(self, link: Link, msg: Msg) -> None:
        """PX4 v1.16 mavlink_receiver semantics (frames LOCAL_NED 1 and BODY_NED 8 only)."""
        if not self._targets_us(msg):
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
            if not mask & (8 | 16 | 32) and _finite(msg.vx, msg.vy, msg.vz):
                c, s = math.cos(self._state.yaw), math.sin(self._state.yaw)
                vel = (c * msg.vx - s * msg.vy, s * msg.vx + c * msg.vy, float(msg.vz))
            if not mask & (64 | 128 | 256) and _finite(msg.afx, msg.afy, msg.afz):
                w, x, y, z = self._state.q_wxyz
                acc = telemetry.rotate_ned_to_body((w, -x, -y, -z), (msg.afx, msg.afy, msg.afz))
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
        self._offboard_setpoint(target)

    def _on_set_attitude_target(self, link: Link, msg: Msg) -> None:
        self._attitude_setpoint(
            msg.target_system,
            msg.target_component,
            msg.type_mask,
            msg.q,
            msg.body_roll_rate,
            msg.body_pitch_rate,
            msg.body_yaw_rate,
            msg.thrust,
        )

    def _attitude_setpoint(
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
        if not self._targets(target_system, target_component):
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
            if not _finite(*r):
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
        self._offboard_setpoint(target)

    def _offboard_setpoint(self, target: PositionTarget | AttitudeTarget) -> None:
        self.stats["rx_setpoints"] += 1
        self._ob_last_t = self._t
        self._ob_target = target
        if self._ob_loss_t is not None and self.mode == Mode.OFFBOARD:
            self._ob_loss_t = None  # signal back before the failsafe action

    # ---------------------------------------------------------------- commands
    def _on_command_long(self, link: Link, msg: Msg) -> None:
        if not self._targets_us(msg):
            return
        p = (msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7)
        self._command(link, msg, int(msg.command), p, frame=mavlink.MAV_FRAME_GLOBAL)

    def _on_command_int(self, link: Link, msg: Msg) -> None:
        if not self._targets_us(msg):
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
        self._send(
            link,
            mavlink.MAVLink_command_ack_message(
                command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()
            ),
        )

    def _command(self, link: Link, msg: Msg, cmd: int, p: tuple[float, ...], frame: int) -> None:
        self.stats["rx_commands"] += 1
        handler = _COMMANDS.get(cmd)
        if handler is None:
            self._ack(link, msg, cmd, RESULT_UNSUPPORTED)
            return
        result = handler(self, link, msg, p, frame)
        if result is not None and result >= 0:
            self._ack(link, msg, cmd, result)

    def _cmd_arm_disarm(self, link: Link, msg: Msg, p: tuple[float, ...], frame: int) -> int:
        p1 = p[0]
        forced = math.isfinite(p[1]) and round(p[1]) == FORCE_MAGIC
        if not math.isfinite(p1) or round(p1) not in (0, 1):
            self.statustext(mavlink.MAV_SEVERITY_CRITICAL, f"Unsupported ARM_DISARM param: {p1}")
            return RESULT_DENIED
        if round(p1) == 1:
            if self.armed:
                return RESULT_ACCEPTED
            reason = self._arming_denial(self.mode)
            if reason is not None:
                self.statustext(mavlink.MAV_SEVERITY_CRITICAL, reason)
                return RESULT_TEMPORARILY_REJECTED
            self._arm()
            return RESULT_ACCEPTED
        if not self.armed:
            return RESULT_ACCEPTED
        if not forced and self.in_air:
            self.statustext(mavlink.MAV_SEVERITY_CRITICAL, "Disarming denied: not landed")
            return RESULT_TEMPORARILY_REJECTED
        self._disarm("external command")
        return RESULT_ACCEPTED

    def _cmd_set_mode(self, link: Link, msg: Msg, p: tuple[float, ...], frame: int) -> None:
        # MAVLink receiver: ACCEPTED on receipt; the commander's verdict follows ~10 ms later
        self._ack(link, msg, mavlink.MAV_CMD_DO_SET_MODE, RESULT_ACCEPTED)
        base, main, sub = p[0], p[1], p[2]

        def verdict() -> None:
            result = self._mode_request(base, main, sub)
            self._ack(link, msg, mavlink.MAV_CMD_DO_SET_MODE, result)

        self._schedule(MODE_ACK_DELAY_S, verdict)

    def _mode_request(self, base: float, main: float, sub: float) -> int:
        if not _finite(base, main, sub) or not int(base) & 1:
            return RESULT_UNSUPPORTED
        mode = Mode.from_custom(int(main), int(sub))
        if mode is None:
            self.statustext(
                mavlink.MAV_SEVERITY_CRITICAL, "Switching to this mode is not supported"
            )
            return RESULT_TEMPORARILY_REJECTED
        reason = self._mode_denial(mode)
        if reason is not None:
            self.statustext(mavlink.MAV_SEVERITY_CRITICAL, reason)
            return RESULT_TEMPORARILY_REJECTED
        self._set_mode(mode, user=True)
        return RESULT_ACCEPTED

    def _mode_denial(self, mode: Mode) -> str | None:
        msg = f"Switching to {mode.label} is currently not available"
        if not self.armed:
            return None  # while disarmed any mode can be selected
        if mode == Mode.OFFBOARD:
            if not self.offboard_fresh:
                return msg
            if isinstance(self._ob_target, PositionTarget) and not self.local_position_valid:
                return msg
        if mode in AUTO_MODES and not self.local_position_valid:
            return msg
        if mode == Mode.AUTO_MISSION and not self.mission.valid:
            return msg
        if mode in MANUAL_MODES and not self.rc_present:
            return msg
        return None

    def _cmd_takeoff(self, link: Link, msg: Msg, p: tuple[float, ...], frame: int) -> int:
        if self.kind != "quad":
            return RESULT_UNSUPPORTED
        if not self.local_position_valid:
            self.statustext(
                mavlink.MAV_SEVERITY_CRITICAL, "Takeoff denied! Please disarm and retry"
            )
            return RESULT_TEMPORARILY_REJECTED
        alt = p[6]
        if math.isfinite(alt):
            rel = alt - self.home[2] if frame in (0, 5) else alt
            if frame not in (0, 3, 5, 6):
                rel = alt - self.home[2]
        else:
            rel = float(self.params["MIS_TAKEOFF_ALT"])
        self._takeoff_alt_rel = max(rel, 0.5)
        self._set_mode(Mode.AUTO_TAKEOFF, user=True)
        return RESULT_ACCEPTED

    def _cmd_land(self, link: Link, msg: Msg, p: tuple[float, ...], frame: int) -> int:
        self._set_mode(Mode.AUTO_LAND, user=True)
        return RESULT_ACCEPTED

    def _cmd_rtl(self, link: Link, msg: Msg, p: tuple[float, ...], frame: int) -> int:
        if self.armed and not self.local_position_valid:
            return RESULT_TEMPORARILY_REJECTED
        self._set_mode(Mode.AUTO_RTL, user=True)
        return RESULT_ACCEPTED

    def _cmd_set_message_interval(
        self, link: Link, msg: Msg, p: tuple[float, ...], frame: int
    ) -> int:
        if not _finite(p[0], p[1]):
            return RESULT_DENIED
        msg_id, interval_us = int(p[0]), float(p[1])
        if msg_id == mavlink.MAVLINK_MSG_ID_HEARTBEAT or msg_id not in telemetry.BUILDERS:
            return RESULT_FAILED
        link.streams.set_interval(msg_id, interval_us, self._t)
        self._tele_next_t = min(self._tele_next_t, link.streams.earliest)
        return RESULT_ACCEPTED

    def _cmd_get_message_interval(
        self, link: Link, msg: Msg, p: tuple[float, ...], frame: int
    ) -> int:
        if not math.isfinite(p[0]):
            return RESULT_DENIED
        msg_id = int(p[0])
        interval = link.streams.interval_s.get(msg_id)
        us = int(interval * 1e6) if interval is not None else -1
        self._send(link, mavlink.MAVLink_message_interval_message(msg_id, us))
        return RESULT_ACCEPTED

    def _cmd_request_message(self, link: Link, msg: Msg, p: tuple[float, ...], frame: int) -> int:
        if not math.isfinite(p[0]):
            return RESULT_DENIED
        msg_id = int(p[0])
        reply: Msg | None = None
        if msg_id == mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
            reply = self.autopilot_version_message()
        elif msg_id == mavlink.MAVLINK_MSG_ID_HOME_POSITION:
            if not self.home_set:
                return RESULT_FAILED
            reply = self.home_position_message()
        elif msg_id in telemetry.BUILDERS:
            reply = telemetry.BUILDERS[msg_id](self)
        if reply is None:
            return RESULT_DENIED
        self._ack(link, msg, mavlink.MAV_CMD_REQUEST_MESSAGE, RESULT_ACCEPTED)
        self._send(link, reply)
        return -1  # ack already sent

    def _cmd_capabilities(self, link: Link, msg: Msg, p: tuple[float, ...], frame: int) -> int:
        self._ack(link, msg, 520, RESULT_ACCEPTED)
        self._send(link, self.autopilot_version_message())
        return -1

    def _cmd_get_home(self, link: Link, msg: Msg, p: tuple[float, ...], frame: int) -> int:
        if not self.home_set:
            return RESULT_FAILED
        self._ack(link, msg, 410, RESULT_ACCEPTED)
        self._send(link, self.home_position_message())
        return -1

    def _cmd_mission_start(self, link: Link, msg: Msg, p: tuple[float, ...], frame: int) -> int:
        if not self.mission.valid:
            return RESULT_DENIED
        if math.isfinite(p[0]) and p[0] >= 0:
            self.mission.set_current(int(p[0]))
        reason = self._mode_denial(Mode.AUTO_MISSION)
        if reason is not None:
            self.statustext(mavlink.MAV_SEVERITY_CRITICAL, reason)
            return RESULT_TEMPORARILY_REJECTED
        self._set_mode(Mode.AUTO_MISSION, user=True)
        return RESULT_ACCEPTED

    def _cmd_set_mission_current(
        self, link: Link, msg: Msg, p: tuple[float, ...], frame: int
    ) -> int:
        if not math.isfinite(p[0]) or not self.mission.set_current(int(p[0])):
            return RESULT_DENIED
        self._broadcast(self.mission_current_message())
        return RESULT_ACCEPTED

    def _cmd_change_speed(self, link: Link, msg: Msg, p: tuple[float, ...], frame: int) -> int:
        setter = getattr(self.nav, "set_cruise_speed", None)
        if setter is None or not math.isfinite(p[1]):
            return RESULT_DENIED
        setter(p[1] if p[1] > 0 else math.nan)
        return RESULT_ACCEPTED

    def _cmd_reposition(self, link: Link, msg: Msg, p: tuple[float, ...], frame: int) -> int:
        if not self.armed or not self.in_air or not self.local_position_valid:
            return RESULT_TEMPORARILY_REJECTED
        cur = self._state.pos_ned
        n, e = cur[0], cur[1]
        if _finite(p[4], p[5]):
            n, e = project_to_ned(self.home, p[4], p[5])
        d = cur[2]
        if math.isfinite(p[6]):
            d = -p[6] if frame in (3, 6) else -(p[6] - self.home[2])
        yaw = math.radians(p[3]) if math.isfinite(p[3]) else math.nan
        self._set_mode(Mode.AUTO_LOITER, user=True)
        self.nav.goto((n, e, d), yaw, float(self.params["NAV_ACC_RAD"]), self._state)
        self._nav_target = None
        return RESULT_ACCEPTED

    def _cmd_set_home(self, link: Link, msg: Msg, p: tuple[float, ...], frame: int) -> int:
        if math.isfinite(p[0]) and p[0] >= 0.5:
            s = self._state
            self.home = (s.lat_deg, s.lon_deg, s.alt_amsl_m)
        elif _finite(p[4], p[5], p[6]):
            self.home = (float(p[4]), float(p[5]), float(p[6]))
        else:
            return RESULT_DENIED
        self._broadcast(self.home_position_message())
        return RESULT_ACCEPTED

    # ================================================================== commander
    def _arm(self) -> None:
        self.armed = True
        self._armed_t = self._t
        self._taken_off = False
        self._landed_since = None
        self._takeoff_done = False
        self.statustext(mavlink.MAV_SEVERITY_INFO, "Armed by external command")
        self.vehicle.reset_integrators()
        self._enter_mode(self.mode)

    def _disarm(self, why: str) -> None:
        self.armed = False
        self._ob_loss_t = None
        self.statustext(mavlink.MAV_SEVERITY_INFO, f"Disarmed by {why}")
        if self.failsafe:
            # PX4 returns to the last user-selected mode once the failsafe clears on disarm
            self.failsafe = False
            self.mode = self.user_mode

    def _set_mode(self, mode: Mode, user: bool, failsafe: bool = False) -> None:
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
            self._ob_loss_t = None
        if mode == Mode.AUTO_TAKEOFF:
            self._takeoff_done = False
        if prev not in AUTO_MODES or mode not in AUTO_MODES:
            # PX4 activates another flight task: an AUTO trajectory restarts at the vehicle
            self.nav.forget_reference()
        self._enter_mode(mode)

    def _enter_mode(self, mode: Mode) -> None:
        """Mode entry actions (also run on arming in the current mode)."""
        s = self._state
        self._descend = False
        self._nav_active = False
        self._nav_target = None
        self.vehicle.reset_integrators()
        if not self.armed:
            return
        if mode == Mode.AUTO_TAKEOFF:
            self.nav.takeoff(self._takeoff_alt_rel, s)
            self._nav_active = True
        elif mode == Mode.AUTO_LOITER:
            if self.in_air:
                self.nav.loiter(s)
                self._nav_active = True
        elif mode == Mode.AUTO_LAND:
            self.nav.land(s)
            self._nav_active = True
        elif mode == Mode.AUTO_RTL:
            self.nav.rtl(s)
            self._nav_active = True
        elif mode == Mode.AUTO_MISSION:
            if self.mission.valid:
                self.mission.start(self._t)
                self._mission_started = True
                self._nav_active = True
        elif mode in MANUAL_MODES:
            self.nav.loiter(s)
            self._nav_active = True
            self._descend = not self.rc_present and self.in_air
            self._hold_ned = s.pos_ned

    def _physics_step(self, t_phys: float) -> None:
        self._n_steps += 1
        self._t = t_phys
        ob_target = self._ob_target
        if self.armed and self.mode is _OFFBOARD and ob_target is not None:
            target: Target = ob_target  # the streaming case of `_target`, without the call
        else:
            target = self._target()
        self._last_target = target
        self.vehicle.step(self.dt, target, self.armed)
        self._state_stale = True
        if t_phys >= self._cmd_next_t - 1e-9:  # commander at <= 200 Hz
            self._cmd_next_t = t_phys + COMMANDER_PERIOD_S
            self._commander(t_phys)
        if self._events and self._events[0][0] <= t_phys:
            self._run_events()
        if t_phys >= self._tele_next_t:
            self._telemetry(t_phys)

    def _telemetry(self, t: float) -> None:
        """Build and queue the periodic messages due at `t` on every link."""
        builders = telemetry.BUILDERS
        nxt = math.inf
        for lk in self.links.values():
            streams = lk.streams
            if t >= streams.earliest:
                for msg_id in streams.due(t):
                    try:
                        m = builders[msg_id](self)
                    except (ValueError, OverflowError):  # non-finite state: skip, count
                        self.stats["tx_encode_errors"] += 1
                        continue
                    if m is not None:
                        self._send(lk, m)
            if streams.earliest < nxt:
                nxt = streams.earliest
        self._tele_next_t = nxt

    def _target(self) -> Target:
        if not self.armed:
            return _IDLE
        if self.mode is _OFFBOARD:
            return self._ob_target if self._ob_target is not None else _IDLE
        if self._descend:
            s = self._state
            if self.kind == "quad" and s.landed and not self._nav_active:
                return _IDLE
            hold = self._hold_ned or s.pos_ned
            return PositionTarget(
                (hold[0], hold[1], math.nan), (math.nan, math.nan, DESCEND_SPEED_NO_RC)
            )
        if self._nav_active:
            # navigator at <= 100 Hz like PX4's position control loop; target held in between
            t = self._t
            if self._nav_target is None or t >= self._nav_next_t - 1e-9:
                dt_nav = t - self._nav_last_t if self._nav_target is not None else self.dt
                self._nav_target = self.nav.update(max(dt_nav, self.dt), self._state)
                self._nav_last_t = t
                self._nav_next_t = t + NAVIGATOR_PERIOD_S
            return self._nav_target
        return _IDLE

    def _commander(self, t: float) -> None:
        # the flags of the vehicle state at this tick (read without building a snapshot)
        veh = self.vehicle
        landed = veh.landed
        pos_valid = veh.local_position_valid
        p = self.params
        if not self._home_announced and self.estimator_ready:
            self._home_announced = True
            self._broadcast(self.home_position_message())
        if t >= self._slow_next_t:  # 50 Hz housekeeping
            self._slow_next_t = t + 0.02
            self._scenario(t)
            self._battery_check()
        if self.mission_server.state != "idle":
            self.mission_server.update(t)
        if self.mode is _AUTO_MISSION and self.mission.active:
            self.mission.update(t, self._state)
        if self._reached_seq is not None and t >= self._reached_next_t:
            self._reached_next_t += 1.0
            self._broadcast(mavlink.MAVLink_mission_item_reached_message(self._reached_seq))
        if not self.armed:
            return
        # takeoff / landing bookkeeping (quad)
        if self.kind == "quad":
            if not landed:
                self._taken_off = True
            if self.mode is _AUTO_TAKEOFF and not self._takeoff_done and self.nav.reached:
                self._takeoff_done = True
                self._set_mode(Mode.AUTO_LOITER, user=False)
                self.user_mode = Mode.AUTO_LOITER
            # PX4 (Commander::handleAutoDisarm): no COM_DISARM_LAND auto-disarm while landed
            # amid an unfinished AUTO.MISSION (a landing in the middle of a mission)
            amid_mission = self.mode is _AUTO_MISSION and not self.mission.finished
            if landed and self._taken_off and not amid_mission:
                if self._landed_since is None:
                    self._landed_since = t
                elif 0.0 <= float(p["COM_DISARM_LAND"]) <= t - self._landed_since:
                    self._disarm("auto disarm on land")
                    return
            else:
                self._landed_since = None
            if not self._taken_off:
                prflt = float(p["COM_DISARM_PRFLT"])
                if prflt > 0 and t - self._armed_t >= prflt:
                    self._disarm("auto preflight disarming")
                    return
        # offboard loss
        if self.mode is _OFFBOARD:
            if self._ob_loss_t is None:
                if not self.offboard_fresh:
                    self._ob_loss_t = t
                    action = OFFBOARD_LOSS_ACTIONS.get(int(p["COM_OBL_RC_ACT"]), Mode.POSCTL)
                    what = action.label if action is not None else "Disarm"
                    self.statustext(
                        mavlink.MAV_SEVERITY_CRITICAL,
                        f"Failsafe activated: no offboard signal, switching to {what}",
                    )
            elif t - self._ob_loss_t >= FAILSAFE_ACTION_DELAY_S:
                self._ob_loss_t = None
                action = OFFBOARD_LOSS_ACTIONS.get(int(p["COM_OBL_RC_ACT"]), Mode.POSCTL)
                self._failsafe_to(action)
        # local position loss while a position is needed
        if not pos_valid and not self.failsafe and self.in_air:
            needs_pos = (
                self.mode in AUTO_MODES
                or self.mode == Mode.POSCTL
                or (self.mode == Mode.OFFBOARD and isinstance(self._ob_target, PositionTarget))
            )
            if needs_pos:
                self.statustext(
                    mavlink.MAV_SEVERITY_CRITICAL,
                    "Failsafe activated: no local position, descending",
                )
                self._set_mode(Mode.AUTO_LAND, user=False, failsafe=True)
                self._nav_active = False
                self._descend = True
                self._hold_ned = None

    def _failsafe_to(self, action: Mode | None) -> None:
        if action is None:
            self.failsafe = True
            self._disarm("failsafe")
            return
        self._set_mode(action, user=False, failsafe=True)
        # PX4.md: the HEARTBEAT leaves OFFBOARD 1.3-1.7 s after the last setpoint. With a plain
        # 1 Hz heartbeat that would be 1.5-2.5 s here, so the heartbeat phase is reset to now.
        self._heartbeat_now()

    def _heartbeat_now(self) -> None:
        hb = mavlink.MAVLINK_MSG_ID_HEARTBEAT
        for lk in self.links.values():
            if hb in lk.streams.next_due:
                lk.streams.next_due[hb] = self._t
                lk.streams.earliest = self._t
        self._tele_next_t = self._t

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
        if level <= self._bat_warned:
            return
        self._bat_warned = level
        text = {
            1: "Low battery level! Return advised",
            2: "Critical battery level! Land advised",
            3: "Emergency battery level! Landing immediately",
        }[level]
        self.statustext(
            mavlink.MAV_SEVERITY_WARNING if level == 1 else mavlink.MAV_SEVERITY_CRITICAL, text
        )
        act = int(p["COM_LOW_BAT_ACT"])
        if not (self.armed and self.in_air) or act == 0 or level < 2:
            return
        if act == 3 and level == 2:
            self._set_mode(Mode.AUTO_RTL, user=False, failsafe=True)
        elif act in (2, 3):
            self._set_mode(Mode.AUTO_LAND, user=False, failsafe=True)

    def _scenario(self, t: float) -> None:
        sc = self.scenario
        if (
            sc.pilot_takeover_s is not None
            and not self._scn_takeover_done
            and t >= sc.pilot_takeover_s
        ):
            self._scn_takeover_done = True
            self.rc_present = True
            self.statustext(
                mavlink.MAV_SEVERITY_WARNING, "Pilot took over position control using sticks"
            )
            self._set_mode(Mode.POSCTL, user=True)
        if sc.local_position_loss is not None:
            start, end = sc.local_position_loss
            if self._scn_pos_state == 0 and t >= start:
                self._scn_pos_state = 1
                self.vehicle.set_local_position_valid(False)
                self._state_stale = True
            elif self._scn_pos_state == 1 and t >= end:
                self._scn_pos_state = 2
                self.vehicle.set_local_position_valid(True)
                self._state_stale = True
        if sc.low_battery_s is not None and not self._scn_battery_done and t >= sc.low_battery_s:
            self._scn_battery_done = True
            self.vehicle.set_battery_remaining(sc.low_battery_remaining)
            self._battery_cap = sc.low_battery_remaining
            self._state_stale = True

    # ================================================================== convenience
    def set_rc_present(self, present: bool) -> None:
        """Pretend an RC transmitter / joystick is (not) connected (enables manual modes)."""
        self.rc_present = present


def _param_name(raw: Any) -> str:
    if isinstance(raw, bytes):
        raw = raw.decode("ascii", "replace")
    return str(raw).split("\x00", 1)[0]


_IDLE = IdleTarget()
_C_SET_ATTITUDE_TARGET = codec(mavlink.MAVLink_set_attitude_target_message)
_HANDLER_NAMES: dict[str, str] = {}  # message type -> handler method name

_COMMANDS: dict[int, Callable[[Autopilot, Link, Msg, tuple[float, ...], int], int | None]] = {
    mavlink.MAV_CMD_COMPONENT_ARM_DISARM: Autopilot._cmd_arm_disarm,
    mavlink.MAV_CMD_DO_SET_MODE: Autopilot._cmd_set_mode,
    mavlink.MAV_CMD_NAV_TAKEOFF: Autopilot._cmd_takeoff,
    mavlink.MAV_CMD_NAV_LAND: Autopilot._cmd_land,
    mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH: Autopilot._cmd_rtl,
    mavlink.MAV_CMD_SET_MESSAGE_INTERVAL: Autopilot._cmd_set_message_interval,
    mavlink.MAV_CMD_GET_MESSAGE_INTERVAL: Autopilot._cmd_get_message_interval,
    mavlink.MAV_CMD_REQUEST_MESSAGE: Autopilot._cmd_request_message,
    mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: Autopilot._cmd_capabilities,
    mavlink.MAV_CMD_GET_HOME_POSITION: Autopilot._cmd_get_home,
    mavlink.MAV_CMD_MISSION_START: Autopilot._cmd_mission_start,
    mavlink.MAV_CMD_DO_SET_MISSION_CURRENT: Autopilot._cmd_set_mission_current,
    mavlink.MAV_CMD_DO_CHANGE_SPEED: Autopilot._cmd_change_speed,
    mavlink.MAV_CMD_DO_REPOSITION: Autopilot._cmd_reposition,
    mavlink.MAV_CMD_DO_SET_HOME: Autopilot._cmd_set_home,
}
