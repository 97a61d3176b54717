"""Mission protocol server (upload, download, clear) and mission execution, PX4 v1.16 style.

Sans-IO: `MissionServer.handle(msg, now)` consumes mission messages and emits replies through
the `send` callback; `MissionServer.update(now)` drives retries (every 0.25 s) and the 5 s
transfer timeout. `MissionExecutor` sequences stored items for AUTO.MISSION through the
vehicle's navigator. Time `now` is simulated seconds; nothing here reads a clock.
"""

from __future__ import annotations

import dataclasses
import math
import struct
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar

from pymavlink.dialects.v20 import common as mavlink

Msg = Any

MISSION = mavlink.MAV_MISSION_TYPE_MISSION
FENCE = mavlink.MAV_MISSION_TYPE_FENCE
RALLY = mavlink.MAV_MISSION_TYPE_RALLY
ALL_TYPES = mavlink.MAV_MISSION_TYPE_ALL

RETRY_S = 0.25  # MAVLINK_MISSION_RETRY_TIMEOUT_DEFAULT
TIMEOUT_S = 5.0  # MAVLINK_MISSION_PROTOCOL_TIMEOUT_DEFAULT
MAX_ITEMS = 2000

GLOBAL_FRAMES = frozenset({0, 3, 5, 6, 10, 11})
TERRAIN_FRAMES = frozenset({10, 11})
SUPPORTED_FRAMES = frozenset({0, 2, 3, 5, 6})
# Commands the mock accepts in a mission (PX4 accepts these; the mock executes a subset).
SUPPORTED_COMMANDS = frozenset(
    {
        16,
        17,
        18,
        19,
        20,
        21,
        22,
        31,
        84,
        85,
        93,
        112,
        115,
        177,
        178,
        179,
        183,
        184,
        189,
        195,
        197,
        201,
        203,
        205,
        206,
        530,
        2000,
        2001,
        2003,
        2004,
        2500,
        2501,
        3000,
    }
)
POSITION_COMMANDS = frozenset({16, 17, 18, 19, 21, 22, 31, 84, 85})

EARTH_RADIUS_M = 6371000.0  # PX4 CONSTANTS_RADIUS_OF_EARTH


class MissionCountV2(mavlink.MAVLink_mission_count_message):  # type: ignore[misc]
    """MISSION_COUNT with PX4 v1.16's ``opaque_id`` extension (the plan id, on download)."""

    fieldnames: ClassVar[list[str]] = [*mavlink.MAVLink_mission_count_message.fieldnames,
                                       "opaque_id"]
    ordered_fieldnames: ClassVar[list[str]] = [
        *mavlink.MAVLink_mission_count_message.ordered_fieldnames, "opaque_id"]
    fieldtypes: ClassVar[list[str]] = [*mavlink.MAVLink_mission_count_message.fieldtypes,
                                       "uint32_t"]
    array_lengths: ClassVar[list[int]] = [0] * 5
    unpacker = struct.Struct("<HBBBI")

    def __init__(self, target_system: int, target_component: int, count: int,
                 mission_type: int = 0, opaque_id: int = 0) -> None:
        super().__init__(target_system, target_component, count, mission_type)
        self.opaque_id = opaque_id


class MissionAckV2(mavlink.MAVLink_mission_ack_message):  # type: ignore[misc]
    """MISSION_ACK with PX4 v1.16's ``opaque_id`` (the new plan id when an upload is
    accepted, 0 otherwise)."""

    fieldnames: ClassVar[list[str]] = [*mavlink.MAVLink_mission_ack_message.fieldnames,
                                       "opaque_id"]
    ordered_fieldnames: ClassVar[list[str]] = [
        *mavlink.MAVLink_mission_ack_message.ordered_fieldnames, "opaque_id"]
    fieldtypes: ClassVar[list[str]] = [*mavlink.MAVLink_mission_ack_message.fieldtypes,
                                       "uint32_t"]
    array_lengths: ClassVar[list[int]] = [0] * 5
    unpacker = struct.Struct("<BBBBI")

    def __init__(self, target_system: int, target_component: int, type: int,
                 mission_type: int = 0, opaque_id: int = 0) -> None:
        super().__init__(target_system, target_component, type, mission_type)
        self.opaque_id = opaque_id


def plan_id(items: list[MissionItem]) -> int:
    """PX4 v1.16's opaque plan id: a CRC32 over the stored items (0 for none), so it changes
    with every different upload and stays the same for an identical one. The mock hashes the
    items' fields; PX4 its own storage layout, so the values differ, the behaviour does not."""
    if not items:
        return 0
    crc = 0
    for it in items:
        crc = zlib.crc32(repr(dataclasses.astuple(it)).encode(), crc)
    return crc or 1


@dataclass(frozen=True)
class MissionItem:
    """One stored item. x/y are degrees for global frames, raw params 5/6 otherwise."""

    seq: int
    frame: int
    command: int
    current: int
    autocontinue: int
    param1: float
    param2: float
    param3: float
    param4: float
    x: float
    y: float
    z: float
    mission_type: int = MISSION

    @property
    def is_global(self) -> bool:
        return self.frame in GLOBAL_FRAMES

    def to_int_message(self, target_system: int, target_component: int) -> Msg:
        """MISSION_ITEM_INT for this item (x/y scaled by 1e7 for global frames)."""
        if self.is_global:
            xi, yi = round(self.x * 1e7), round(self.y * 1e7)
        else:
            xi, yi = _int_or_zero(self.x), _int_or_zero(self.y)
        return mavlink.MAVLink_mission_item_int_message(
            target_system,
            target_component,
            self.seq,
            self.frame,
            self.command,
            self.current,
            self.autocontinue,
            self.param1,
            self.param2,
            self.param3,
            self.param4,
            xi,
            yi,
            self.z,
            self.mission_type,
        )

    def to_float_message(self, target_system: int, target_component: int) -> Msg:
        """MISSION_ITEM (float) for this item."""
        return mavlink.MAVLink_mission_item_message(
            target_system,
            target_component,
            self.seq,
            self.frame,
            self.command,
            self.current,
            self.autocontinue,
            self.param1,
            self.param2,
            self.param3,
            self.param4,
            self.x,
            self.y,
            self.z,
            self.mission_type,
        )


def _int_or_zero(v: float) -> int:
    return round(v) if math.isfinite(v) else 0


def item_from_message(msg: Msg) -> MissionItem:
    """MissionItem from a MISSION_ITEM or MISSION_ITEM_INT message."""
    is_int = msg.get_type() == "MISSION_ITEM_INT"
    x, y = float(msg.x), float(msg.y)
    if is_int and msg.frame in GLOBAL_FRAMES:
        x, y = x * 1e-7, y * 1e-7
    return MissionItem(
        int(msg.seq),
        int(msg.frame),
        int(msg.command),
        int(msg.current),
        int(msg.autocontinue),
        float(msg.param1),
        float(msg.param2),
        float(msg.param3),
        float(msg.param4),
        x,
        y,
        float(msg.z),
        int(getattr(msg, "mission_type", 0)),
    )


def validate_item(item: MissionItem) -> int:
    """MAV_MISSION_RESULT for one item (ACCEPTED if the mock can store it)."""
    if item.mission_type != MISSION:
        return int(mavlink.MAV_MISSION_ACCEPTED)
    if item.frame in TERRAIN_FRAMES:
        return int(mavlink.MAV_MISSION_UNSUPPORTED_FRAME)  # no terrain data in the mock
    if item.command not in SUPPORTED_COMMANDS:
        return int(mavlink.MAV_MISSION_UNSUPPORTED)
    if item.command in POSITION_COMMANDS:
        if item.frame not in SUPPORTED_FRAMES:
            return int(mavlink.MAV_MISSION_UNSUPPORTED_FRAME)
        if item.frame != 2:
            if not (math.isfinite(item.x) and -90.0 <= item.x <= 90.0):
                return int(mavlink.MAV_MISSION_INVALID_PARAM5_X)
            if not (math.isfinite(item.y) and -180.0 <= item.y <= 180.0):
                return int(mavlink.MAV_MISSION_INVALID_PARAM6_Y)
            if not math.isfinite(item.z):
                return int(mavlink.MAV_MISSION_INVALID_PARAM7)
    return int(mavlink.MAV_MISSION_ACCEPTED)


def project_to_ned(
    home: tuple[float, float, float], lat_deg: float, lon_deg: float
) -> tuple[float, float]:
    """North/East [m] of (lat, lon) about home: azimuthal equidistant (PX4 map_projection)."""
    lat0, lon0 = math.radians(home[0]), math.radians(home[1])
    lat, lon = math.radians(lat_deg), math.radians(lon_deg)
    sin_lat0, cos_lat0 = math.sin(lat0), math.cos(lat0)
    sin_lat, cos_lat = math.sin(lat), math.cos(lat)
    cos_dlon = math.cos(lon - lon0)
    arg = max(-1.0, min(1.0, sin_lat0 * sin_lat + cos_lat0 * cos_lat * cos_dlon))
    c = math.acos(arg)
    k = 1.0 if abs(c) < 1e-12 else c / math.sin(c)
    north = k * (cos_lat0 * sin_lat - sin_lat0 * cos_lat * cos_dlon) * EARTH_RADIUS_M
    east = k * cos_lat * math.sin(lon - lon0) * EARTH_RADIUS_M
    return north, east


class MissionServer:
    """PX4-like mission transfer state machine for one link partner at a time.

    `send(msg)` emits a reply on the link the request came from; `statustext(severity, text)`
    reports errors like PX4 does; `on_changed(mission_type)` is called after an upload or
    clear has replaced the stored items.
    """

    def __init__(
        self,
        send: Callable[[Msg], None],
        statustext: Callable[[int, str], None],
        on_changed: Callable[[int], None],
        own_sysid: int = 1,
        own_compid: int = 1,
    ) -> None:
        self._send = send
        self._statustext = statustext
        self._on_changed = on_changed
        self.sysid = own_sysid
        self.compid = own_compid
        self.items: dict[int, list[MissionItem]] = {MISSION: [], FENCE: [], RALLY: []}
        self.opaque_id: dict[int, int] = {MISSION: 0, FENCE: 0, RALLY: 0}
        self.state = "idle"  # idle | upload | download
        self._type = MISSION
        self._partner = (0, 0)
        self._count = 0
        self._expected = 0
        self._use_int = False
        self._pending: list[MissionItem] = []
        self._uploaded = False  # idle after an upload of _count items from _partner
        self._last_recv = 0.0
        self._last_sent = 0.0
        self.retries = 0
        self.errors = 0

    # ---------------------------------------------------------------- helpers
    def _ack(self, sys_comp: tuple[int, int], result: int, mission_type: int,
             opaque_id: int = 0) -> None:
        self._send(MissionAckV2(sys_comp[0], sys_comp[1], result, mission_type, opaque_id))

    def _request(self, now: float) -> None:
        cls = (
            mavlink.MAVLink_mission_request_int_message
            if self._use_int
            else mavlink.MAVLink_mission_request_message
        )
        self._send(cls(self._partner[0], self._partner[1], self._expected, self._type))
        self._last_sent = now

    def _idle(self) -> None:
        self.state = "idle"
        self._pending = []
        self._uploaded = False  # set again by a finished upload

    def next_timer(self) -> float:
        """Next time `update` has work to do (inf if idle)."""
        if self.state == "idle":
            return math.inf
        t = self._last_recv + TIMEOUT_S
        if self.state == "upload":
            t = min(t, self._last_sent + RETRY_S)
        return t

    # ---------------------------------------------------------------- driver
    def update(self, now: float) -> None:
        """Retry the outstanding request every 0.25 s; give up after 5 s of silence."""
        if self.state == "idle":
            return
        if now - self._last_recv > TIMEOUT_S:
            self._statustext(mavlink.MAV_SEVERITY_CRITICAL, "Operation timeout")
            self.errors += 1
            self._idle()
            return
        if self.state == "upload" and now - self._last_sent >= RETRY_S:
            self.retries += 1
            self._request(now)

    def handle(self, msg: Msg, now: float) -> None:
        """Consume one mission-protocol message already filtered by target id."""
        kind = msg.get_type()
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        handler = getattr(self, "_on_" + kind.lower(), None)
        if handler is not None:
            handler(msg, src, now)

    # ---------------------------------------------------------------- upload
    def _on_mission_count(self, msg: Msg, src: tuple[int, int], now: float) -> None:
        mtype = int(getattr(msg, "mission_type", 0))
        if mtype not in self.items:
            self._ack(src, mavlink.MAV_MISSION_UNSUPPORTED, mtype)
            return
        if self.state == "download":
            self._idle()
        if self.state == "upload":
            # as PX4 (mavlink_mission.cpp, GETLIST): the count again before any item arrived
            # means our first request was lost: ask again; later it is refused as busy and
            # the transfer in progress goes on
            self._last_recv = now
            if self._expected == 0:
                self._request(now)
            else:
                self._statustext(mavlink.MAV_SEVERITY_CRITICAL, "WPM: REJ. CMD: Busy")
                self._ack(src, mavlink.MAV_MISSION_ERROR, mtype)
            return
        count = int(msg.count)
        if count > MAX_ITEMS:
            self._ack(src, mavlink.MAV_MISSION_NO_SPACE, mtype)
            self._idle()
            return
        if count == 0:
            self._store(mtype, [])
            self._ack(src, mavlink.MAV_MISSION_ACCEPTED, mtype)
            self._idle()
            return
        self.state = "upload"
        self._type = mtype
        self._partner = src
        self._count = count
        self._expected = 0
        self._use_int = False  # PX4 asks seq 0 with MISSION_REQUEST, then switches to _INT
        self._pending = []
        self._last_recv = now
        self._request(now)

    def _on_item(self, msg: Msg, src: tuple[int, int], now: float, is_int: bool) -> None:
        mtype = int(getattr(msg, "mission_type", 0))
        if (self.state == "idle" and self._uploaded and src == self._partner
                and mtype == self._type and int(msg.seq) == self._count - 1):
            # as PX4 (mavlink_mission.cpp): the last item again after a finished upload is the
            # client's retry after a lost ACK: accept it again, with the mission's id
            self._ack(src, mavlink.MAV_MISSION_ACCEPTED, mtype, self.opaque_id[mtype])
            return
        if self.state != "upload" or src != self._partner:
            self.errors += 1
            self._ack(src, mavlink.MAV_MISSION_ERROR, int(getattr(msg, "mission_type", 0)))
            return
        self._last_recv = now
        if mtype != self._type:
            self.errors += 1
            self._ack(src, mavlink.MAV_MISSION_INVALID, mtype)
            self._idle()
            return
        if is_int:
            self._use_int = True
        seq = int(msg.seq)
        if seq != self._expected:
            # duplicate or out of order: ignored, as PX4 does (the retry timer asks again)
            self.errors += 1
            return
        item = item_from_message(msg)
        result = validate_item(item)
        if result != mavlink.MAV_MISSION_ACCEPTED:
            self.errors += 1
            self._statustext(
                mavlink.MAV_SEVERITY_CRITICAL,
                f"Mission item {seq}: {_result_text(result)} (command {item.command},"
                f" frame {item.frame})",
            )
            self._ack(src, result, mtype)
            self._idle()
            return
        self._pending.append(item)
        self._expected += 1
        if self._expected >= self._count:
            self._store(mtype, self._pending)
            self._ack(src, mavlink.MAV_MISSION_ACCEPTED, mtype, self.opaque_id[mtype])
            self._idle()
            self._uploaded = True
        else:
            self._request(now)

    def _on_mission_item_int(self, msg: Msg, src: tuple[int, int], now: float) -> None:
        self._on_item(msg, src, now, True)

    def _on_mission_item(self, msg: Msg, src: tuple[int, int], now: float) -> None:
        self._on_item(msg, src, now, False)

    def _store(self, mtype: int, items: list[MissionItem]) -> None:
        self.items[mtype] = list(items)
        self.opaque_id[mtype] = plan_id(items)
        self._on_changed(mtype)

    # ---------------------------------------------------------------- download
    def _on_mission_request_list(self, msg: Msg, src: tuple[int, int], now: float) -> None:
        mtype = int(getattr(msg, "mission_type", 0))
        if mtype not in self.items:
            self._ack(src, mavlink.MAV_MISSION_UNSUPPORTED, mtype)
            return
        if self.state == "upload":
            self._statustext(mavlink.MAV_SEVERITY_CRITICAL, "Mission upload in progress")
            self._ack(src, mavlink.MAV_MISSION_DENIED, mtype)
            return
        items = self.items[mtype]
        self._send(MissionCountV2(src[0], src[1], len(items), mtype, self.opaque_id[mtype]))
        if items:
            self.state = "download"
            self._type = mtype
            self._partner = src
            self._last_recv = now

    def _answer_request(self, msg: Msg, src: tuple[int, int], now: float, is_int: bool) -> None:
        mtype = int(getattr(msg, "mission_type", 0))
        if self.state == "upload":
            return
        items = self.items.get(mtype)
        seq = int(msg.seq)
        if items is None or not 0 <= seq < len(items):
            self.errors += 1
            self._ack(src, mavlink.MAV_MISSION_INVALID_SEQUENCE, mtype)
            self._idle()
            return
        self.state = "download"
        self._type = mtype
        self._partner = src
        self._last_recv = now
        item = items[seq]
        self._send(item.to_int_message(*src) if is_int else item.to_float_message(*src))

    def _on_mission_request_int(self, msg: Msg, src: tuple[int, int], now: float) -> None:
        self._answer_request(msg, src, now, True)

    def _on_mission_request(self, msg: Msg, src: tuple[int, int], now: float) -> None:
        self._answer_request(msg, src, now, False)

    def _on_mission_ack(self, msg: Msg, src: tuple[int, int], now: float) -> None:
        if self.state == "idle" or src != self._partner:
            return
        if self.state == "upload":
            # as PX4 (mavlink_mission.cpp, GETLIST): UNSUPPORTED toggles between float and
            # _INT requests (MAVSDK NACKs the float one; a duplicated NACK toggles back and the
            # client NACKs again), CANCELLED ends the upload, any other result is ignored
            if int(msg.type) == mavlink.MAV_MISSION_UNSUPPORTED:
                self._use_int = not self._use_int
                self._request(now)
            elif int(msg.type) == mavlink.MAV_MISSION_OPERATION_CANCELLED:
                self._idle()
            return
        self._idle()  # the partner ended or cancelled the download

    # ---------------------------------------------------------------- clear
    def _on_mission_clear_all(self, msg: Msg, src: tuple[int, int], now: float) -> None:
        mtype = int(getattr(msg, "mission_type", 0))
        if self.state == "upload":
            self._ack(src, mavlink.MAV_MISSION_DENIED, mtype)
            return
        types = list(self.items) if mtype == ALL_TYPES else [mtype]
        if any(t not in self.items for t in types):
            self._ack(src, mavlink.MAV_MISSION_UNSUPPORTED, mtype)
            return
        for t in types:
            self._store(t, [])
        self._ack(src, mavlink.MAV_MISSION_ACCEPTED, mtype)


def _result_text(result: int) -> str:
    entry = mavlink.enums["MAV_MISSION_RESULT"].get(result)
    return entry.name if entry is not None else str(result)


# ====================================================================== execution
class MissionExecutor:
    """Runs the stored mission items through the navigator (AUTO.MISSION).

    As PX4 v1.16: NAV_DELAY (93) holds the last setpoint for param1 s from the moment it
    becomes current; VTOL takeoff/land (84/85) fly as takeoff/land; after a NAV_LAND that is
    not the last item the mission goes on (a later position item takes off again first) and the
    autopilot does not auto-disarm while landed amid it.

    Events go to the callbacks: `on_reached(seq)` (MISSION_ITEM_REACHED), `on_current(seq)`
    (current item changed), `on_finished(landed)` (past the last item).
    """

    def __init__(
        self,
        navigator: Any,
        params: Any,
        home: tuple[float, float, float],
        on_reached: Callable[[int], None],
        on_current: Callable[[int], None],
        on_finished: Callable[[bool], None],
    ) -> None:
        self.nav = navigator
        self.params = params
        self.home = home
        self.items: list[MissionItem] = []
        self.current = 0
        self.finished = False
        self._on_reached = on_reached
        self._on_current = on_current
        self._on_finished = on_finished
        self._phase = "idle"
        self._hold_until = 0.0
        self._jump_counts: dict[int, int] = {}
        self.active = False
        self.last_goal_ned: tuple[float, float, float] | None = None
        self._prev_goal: tuple[float, float, float] | None = None  # start of a rover's leg
        self._takeoff_goal: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def load(self, items: list[MissionItem]) -> None:
        self.items = list(items)
        self.current = 0
        self.finished = False
        self._jump_counts = {}
        self.active = False
        self.last_goal_ned = None

    def set_current(self, seq: int) -> bool:
        if not 0 <= seq < len(self.items):
            return False
        self.current = seq
        self.finished = False
        if self.active:
            self._phase = "enter"
        return True

    @property
    def valid(self) -> bool:
        return bool(self.items)

    def start(self, t: float) -> None:
        """Enter AUTO.MISSION: resume at the current item (restart if it had finished)."""
        if self.finished:
            self.current = 0
            self.finished = False
            self._jump_counts = {}
        self.active = True
        self._phase = "enter"
        self._prev_goal = None  # the first leg starts at the vehicle (PX4: no previous item)

    def stop(self) -> None:
        self.active = False

    def _pos_of(self, item: MissionItem, state: Any) -> tuple[float, float, float]:
        north, east, down = state.pos_ned
        if item.frame != 2 and item.is_global and not (item.x == 0.0 and item.y == 0.0):
            north, east = project_to_ned(self.home, item.x, item.y)
        if item.frame in (3, 6):
            down = -item.z
        elif item.frame in (0, 5):
            down = -(item.z - self.home[2])
        return (north, east, down)

    def _next_position(self, state: Any) -> tuple[float, float, float] | None:
        """Where the item after the current one goes (PX4's triplet `next`): the next waypoint,
        loiter or land position past any DO_* items; None at the end, at an RTL or a DO_JUMP."""
        for item in self.items[self.current + 1:]:
            cmd = {85: 21}.get(item.command, item.command)
            if cmd in (16, 17, 19, 31, 21):
                return self._pos_of(item, state)
            if cmd in (20, 177, 22, 84, 93):
                return None
        return None

    def _acceptance(self, item: MissionItem) -> float:
        r = item.param2
        return r if math.isfinite(r) and r > 0 else float(self.params["NAV_ACC_RAD"])

    def update(self, t: float, state: Any) -> None:
        """Advance the item sequence; the navigator produces the target itself."""
        if not self.active or self.finished:
            return
        for _ in range(len(self.items) + 2):  # bounded: non-position items chain instantly
            if not self._step(t, state):
                return

    def _next(self, t: float, landed: bool = False) -> bool:
        self.current += 1
        self._phase = "enter"
        if self.current >= len(self.items):
            self.finished = True
            self.active = False
            self.current = max(len(self.items) - 1, 0)
            self._on_finished(landed)
            return False
        self._on_current(self.current)
        return True

    def _step(self, t: float, state: Any) -> bool:
        if not self.items:
            self.finished = True
            self.active = False
            self._on_finished(state.landed)
            return False
        item = self.items[self.current]
        # PX4 on a multicopter (or rover) flies VTOL takeoff / land as takeoff / land
        cmd = {84: 22, 85: 21}.get(item.command, item.command)
        nav = self.nav
        if self._phase == "enter":
            self._on_current(self.current)
            if cmd == 22:  # TAKEOFF: climb where the vehicle stands, then to the item
                pos = self._pos_of(item, state)
                alt_rel = -pos[2]
                if item.frame == 2 or not math.isfinite(alt_rel):
                    alt_rel = float(self.params["MIS_TAKEOFF_ALT"])
                self._takeoff_goal = (pos[0], pos[1], -alt_rel)
                if state.landed or nav.ground_vehicle:
                    nav.takeoff(alt_rel, state)
                    self._phase = "takeoff_climb"
                    return False
                # in the air: PX4 flies a TAKEOFF item as a waypoint
                nav.goto(self._takeoff_goal, math.nan, self._acceptance(item), state)
                self.last_goal_ned = self._takeoff_goal
                self._phase = "fly"
            elif cmd in (16, 17, 19, 31):
                pos = self._pos_of(item, state)
                if state.landed:
                    nav.takeoff(max(-pos[2], float(self.params["MIS_TAKEOFF_ALT"])), state)
                    self._phase = "takeoff_first"
                    return False
                yaw = (
                    math.radians(item.param4)
                    if cmd == 16 and math.isfinite(item.param4)
                    else math.nan
                )
                hold = item.param1 if cmd in (16, 19) and math.isfinite(item.param1) else 0.0
                stop = cmd != 16 or hold > 0.0 or not item.autocontinue
                nav.goto(pos, yaw, self._acceptance(item), state, start_ned=self._prev_goal,
                         next_ned=self._next_position(state), stop=stop)
                self.last_goal_ned = pos
                self._phase = "fly"
            elif cmd == 21:  # LAND: fly over the land point, report reached, then descend
                pos = self._pos_of(item, state)
                # tight acceptance: the descent starts over the land point
                nav.goto((pos[0], pos[1], state.pos_ned[2]), math.nan, 0.5, state,
                         start_ned=self._prev_goal)
                self._phase = "fly"
            elif cmd == 20:  # RTL
                nav.rtl(state)
                self._phase = "rtl"
            elif cmd == 177:  # DO_JUMP p1 target seq, p2 repeat count
                target = int(item.param1) if math.isfinite(item.param1) else -1
                repeat = int(item.param2) if math.isfinite(item.param2) else 0
                done = self._jump_counts.get(item.seq, 0)
                if 0 <= target < len(self.items) and (repeat < 0 or done < repeat):
                    self._jump_counts[item.seq] = done + 1
                    self.current = target
                    self._phase = "enter"
                    self._on_current(self.current)
                    return True
                return self._next(t, bool(state.landed))
            elif cmd == 93:  # NAV_DELAY: hold the last setpoint for param1 s (PX4 time_inside)
                delay = item.param1 if math.isfinite(item.param1) else 0.0
                self._hold_until = t + max(delay, 0.0)
                self._phase = "delay"
                return False
            elif cmd == 178:  # DO_CHANGE_SPEED p2 m/s
                speed = item.param2
                setter = getattr(nav, "set_cruise_speed", None)
                if setter is not None:
                    setter(speed if math.isfinite(speed) and speed > 0 else math.nan)
                return self._next(t, bool(state.landed))
            else:  # DO_* items without an effect in the mock
                return self._next(t, bool(state.landed))
            return False
        if self._phase == "takeoff_climb":
            # PX4 (mission.cpp handleTakeoff): after the vertical climb the TAKEOFF item becomes
            # a waypoint at its own position and is reported reached only there (a point
            # already within the acceptance radius: at once)
            if not nav.reached:
                return False
            gx, gy, _ = self._takeoff_goal
            px, py, _ = state.pos_ned
            away = math.hypot(gx - px, gy - py) > self._acceptance(item)
            if away and not nav.ground_vehicle:
                nav.goto(self._takeoff_goal, math.nan, self._acceptance(item), state)
                self.last_goal_ned = self._takeoff_goal
            self._phase = "fly"
            return True
        if self._phase == "takeoff_first":
            if nav.reached:
                self._phase = "enter"
                return True
            return False
        if self._phase == "fly":
            if not nav.reached:
                return False
            self._on_reached(item.seq)
            if cmd in (16, 17, 19, 31, 21):
                self._prev_goal = self._pos_of(item, state)
            if cmd == 21:
                nav.land(state)
                self._phase = "landing"
                return False
            if cmd == 17:
                self._phase = "loiter_forever"
                return False
            hold = item.param1 if cmd in (16, 19) and math.isfinite(item.param1) else 0.0
            self._hold_until = t + max(hold, 0.0)
            self._phase = "hold"
        if self._phase == "hold":
            if t < self._hold_until:
                return False
            return self._next(t, bool(state.landed))
        if self._phase == "delay":
            if t < self._hold_until:
                return False
            self._on_reached(item.seq)
            return self._next(t, bool(state.landed))
        if self._phase in ("landing", "rtl"):
            # a rover has no landing: it is "landed" once stopped at the point (navigator)
            if state.landed or (nav.ground_vehicle and nav.phase == "landed" and nav.reached):
                if self._phase == "rtl":
                    self._on_reached(item.seq)
                    self.finished = True
                    self.active = False
                    self._on_finished(True)
                    return False
                # PX4 v1.16: LAND is done once landed; the mission goes on (still armed: no
                # auto-disarm amid a mission), taking off again for a later position item
                return self._next(t, landed=True)
            return False
        return False
