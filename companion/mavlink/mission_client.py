"""Mission upload / download / clear client (MAVLink mission protocol, INT items only).

Modelled on MAVSDK's MavlinkMissionTransferClient. Every step has a ``timeout_s`` (default
0.25 s); a step that times out is re-sent (COUNT, REQUEST_LIST, REQUEST_INT, CLEAR_ALL, or the
last requested item during an upload: PX4 answers a duplicate last item with another ACK, which
recovers a lost final MISSION_ACK) and the transfer gives up after ``retries`` consecutive
timeouts (default 20, i.e. ~5 s without progress).
During upload the vehicle drives: both MISSION_REQUEST (PX4 asks seq 0 that way) and
MISSION_REQUEST_INT are answered with MISSION_ITEM_INT; a repeated request re-sends the item
and counts as a retry.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import Enum

from pymavlink.dialects.v20 import common as mavlink2

from .codec import MavMessage

MAV_MISSION_TYPE_MISSION = 0
MAV_MISSION_ACCEPTED = 0
MAV_MISSION_OPERATION_CANCELLED = 15


class MissionResult(Enum):
    """Outcome of a mission transfer."""

    SUCCESS = "success"
    TIMEOUT = "timeout"
    NO_MISSION_AVAILABLE = "no mission items"
    INVALID_SEQUENCE = "invalid sequence"
    MISSION_TYPE_NOT_CONSISTENT = "mission type not consistent"
    CURRENT_INVALID = "exactly one item must be current"
    PROTOCOL_ERROR = "protocol error"
    UNSUPPORTED_FRAME = "unsupported frame"
    UNSUPPORTED = "unsupported"
    TOO_MANY_MISSION_ITEMS = "too many mission items"
    INVALID_PARAM = "invalid parameter"
    DENIED = "denied"
    CANCELLED = "cancelled"


#: MAV_MISSION_RESULT -> MissionResult (as MAVSDK).
NACK_RESULTS: dict[int, MissionResult] = {
    1: MissionResult.PROTOCOL_ERROR,       # MAV_MISSION_ERROR
    2: MissionResult.UNSUPPORTED_FRAME,
    3: MissionResult.UNSUPPORTED,
    4: MissionResult.TOO_MANY_MISSION_ITEMS,  # NO_SPACE
    5: MissionResult.INVALID_PARAM,        # INVALID
    6: MissionResult.INVALID_PARAM, 7: MissionResult.INVALID_PARAM,
    8: MissionResult.INVALID_PARAM, 9: MissionResult.INVALID_PARAM,
    10: MissionResult.INVALID_PARAM, 11: MissionResult.INVALID_PARAM,
    12: MissionResult.INVALID_PARAM,
    13: MissionResult.INVALID_SEQUENCE,
    14: MissionResult.DENIED,
    15: MissionResult.CANCELLED,
}


@dataclass(frozen=True)
class WireMissionItem:
    """One MISSION_ITEM_INT as it travels: x/y are lat/lon in degE7 (or local x/y in m*1e4 by
    frame), z [m]. The wire record only; the mission model (``companion.mission.MissionItem``)
    and the conversions both ways are in ``companion.mission.convert``."""

    seq: int
    frame: int
    command: int
    current: int
    autocontinue: int
    param1: float
    param2: float
    param3: float
    param4: float
    x: int
    y: int
    z: float
    mission_type: int = MAV_MISSION_TYPE_MISSION


@dataclass(frozen=True)
class MissionTransferDone:
    """End of an upload/download/clear: result, items (download), MAV_MISSION_RESULT if a NACK."""

    t_s: float
    operation: str
    result: MissionResult
    items: tuple[WireMissionItem, ...] = ()
    mav_result: int | None = None
    detail: str = ""


class MissionBusyError(RuntimeError):
    """A mission transfer is already running."""


def item_to_msg(item: WireMissionItem, tsys: int, tcomp: int) -> MavMessage:
    """WireMissionItem -> MISSION_ITEM_INT message to ``tsys``/``tcomp``."""
    return mavlink2.MAVLink_mission_item_int_message(
        tsys, tcomp, item.seq, item.frame, item.command, item.current, item.autocontinue,
        item.param1, item.param2, item.param3, item.param4, item.x, item.y, item.z,
        item.mission_type,
    )


def item_from_msg(msg: MavMessage) -> WireMissionItem:
    """MISSION_ITEM_INT message -> WireMissionItem."""
    return WireMissionItem(
        seq=int(msg.seq), frame=int(msg.frame), command=int(msg.command),
        current=int(msg.current), autocontinue=int(msg.autocontinue),
        param1=float(msg.param1), param2=float(msg.param2), param3=float(msg.param3),
        param4=float(msg.param4), x=int(msg.x), y=int(msg.y), z=float(msg.z),
        mission_type=int(getattr(msg, "mission_type", 0)),
    )


def validate_items(items: Sequence[WireMissionItem], mission_type: int) -> MissionResult | None:
    """Local checks before an upload (None = fine)."""
    if not items:
        return MissionResult.NO_MISSION_AVAILABLE
    if any(it.seq != i for i, it in enumerate(items)):
        return MissionResult.INVALID_SEQUENCE
    if any(it.mission_type != mission_type for it in items):
        return MissionResult.MISSION_TYPE_NOT_CONSISTENT
    if mission_type == MAV_MISSION_TYPE_MISSION and sum(1 for it in items if it.current) != 1:
        return MissionResult.CURRENT_INVALID
    return None


class MissionClient:
    """Sans-IO mission transfer client (one transfer at a time)."""

    def __init__(
        self,
        send: Callable[[MavMessage], None],
        target_sysid: int = 1,
        target_compid: int = 1,
        *,
        timeout_s: float = 0.25,
        retries: int = 20,
    ) -> None:
        self._send = send
        self.target_sysid, self.target_compid = target_sysid, target_compid
        self.timeout_s = timeout_s
        self.retries = retries
        self._op: str | None = None
        self._step = ""
        self._type = MAV_MISSION_TYPE_MISSION
        self._items: list[WireMissionItem] = []
        self._count = 0
        self._next = 0
        self._last_req: int | None = None
        self._tries = 0
        self._deadline: float | None = None

    @property
    def is_idle(self) -> bool:
        """True when no transfer runs."""
        return self._op is None

    def next_deadline(self) -> float | None:
        """When ``handle_timer`` must run next."""
        return self._deadline

    # -- starting -------------------------------------------------------------------------------
    def _begin(self, op: str, mission_type: int, now: float) -> None:
        if self._op is not None:
            raise MissionBusyError(f"mission {self._op} already in progress")
        self._op, self._type, self._tries = op, mission_type, 0
        self._deadline = now + self.timeout_s

    def upload(self, items: Sequence[WireMissionItem], now: float,
               mission_type: int = MAV_MISSION_TYPE_MISSION) -> list[MissionTransferDone]:
        """Start an upload (MISSION_COUNT). Local validation errors finish at once."""
        if self._op is not None:
            raise MissionBusyError(f"mission {self._op} already in progress")
        bad = validate_items(items, mission_type)
        if bad is not None:
            return [MissionTransferDone(now, "upload", bad, detail=bad.value)]
        self._begin("upload", mission_type, now)
        self._items = list(items)
        self._step, self._next, self._last_req = "count", 0, None
        self._send_count()
        return []

    def download(self, now: float,
                 mission_type: int = MAV_MISSION_TYPE_MISSION) -> list[MissionTransferDone]:
        """Start a download (MISSION_REQUEST_LIST)."""
        self._begin("download", mission_type, now)
        self._items, self._step, self._next = [], "list", 0
        self._send_request_list()
        return []

    def clear(self, now: float,
              mission_type: int = MAV_MISSION_TYPE_MISSION) -> list[MissionTransferDone]:
        """Start MISSION_CLEAR_ALL."""
        self._begin("clear", mission_type, now)
        self._step = "clear"
        self._send(mavlink2.MAVLink_mission_clear_all_message(
            self.target_sysid, self.target_compid, self._type))
        return []

    def cancel(self, now: float) -> list[MissionTransferDone]:
        """Abort the running transfer: MISSION_ACK OPERATION_CANCELLED, result CANCELLED."""
        if self._op is None:
            return []
        self._send_ack(MAV_MISSION_OPERATION_CANCELLED)
        return [self._done(now, MissionResult.CANCELLED, detail="cancelled by the companion")]

    # -- sending helpers ----------------------------------------------------------------------
    def _send_count(self) -> None:
        self._send(mavlink2.MAVLink_mission_count_message(
            self.target_sysid, self.target_compid, len(self._items), self._type))

    def _send_request_list(self) -> None:
        self._send(mavlink2.MAVLink_mission_request_list_message(
            self.target_sysid, self.target_compid, self._type))

    def _send_request_int(self, seq: int) -> None:
        self._send(mavlink2.MAVLink_mission_request_int_message(
            self.target_sysid, self.target_compid, seq, self._type))

    def _send_ack(self, result: int) -> None:
        self._send(mavlink2.MAVLink_mission_ack_message(
            self.target_sysid, self.target_compid, result, self._type))

    def _done(self, now: float, result: MissionResult, *, mav_result: int | None = None,
              detail: str = "") -> MissionTransferDone:
        op = self._op or "?"
        items = tuple(self._items) if (op == "download" and result is MissionResult.SUCCESS) else ()
        self._op, self._deadline, self._step = None, None, ""
        self._items = []
        return MissionTransferDone(now, op, result, items, mav_result, detail or result.value)

    # -- inputs -------------------------------------------------------------------------------
    def on_message(self, msg: MavMessage, now: float) -> list[MissionTransferDone]:
        """Feed a mission-protocol message from the vehicle (others are ignored)."""
        if self._op is None or msg.get_srcSystem() != self.target_sysid:
            return []
        kind = msg.get_type()
        if kind == "MISSION_ACK":
            return self._on_ack(msg, now)
        if self._op == "upload" and kind in ("MISSION_REQUEST", "MISSION_REQUEST_INT"):
            return self._on_request(int(msg.seq), now)
        if self._op == "download" and kind == "MISSION_COUNT":
            return self._on_count(int(msg.count), now)
        if self._op == "download" and kind == "MISSION_ITEM_INT":
            return self._on_item(msg, now)
        return []

    def _on_request(self, seq: int, now: float) -> list[MissionTransferDone]:
        n = len(self._items)
        if seq >= n or seq > self._next:
            self._send_ack(MAV_MISSION_OPERATION_CANCELLED)
            return [self._done(now, MissionResult.INVALID_SEQUENCE,
                               detail=f"vehicle requested item {seq} (have {n}, "
                                      f"next {self._next})")]
        if seq == self._last_req:
            self._tries += 1
            if self._tries >= self.retries:
                self._send_ack(MAV_MISSION_OPERATION_CANCELLED)
                return [self._done(now, MissionResult.TIMEOUT,
                                   detail=f"item {seq} requested {self._tries + 1} times")]
        else:
            self._tries = 0
        self._step, self._last_req = "items", seq
        self._next = max(self._next, seq + 1)
        self._send(item_to_msg(self._items[seq], self.target_sysid, self.target_compid))
        self._deadline = now + self.timeout_s
        return []

    def _on_ack(self, msg: MavMessage, now: float) -> list[MissionTransferDone]:
        res = int(msg.type)
        if self._op == "download" and self._step == "list" and res == MAV_MISSION_ACCEPTED:
            return []
        if res != MAV_MISSION_ACCEPTED:
            mapped = NACK_RESULTS.get(res, MissionResult.PROTOCOL_ERROR)
            return [self._done(now, mapped, mav_result=res,
                               detail=f"vehicle answered MISSION_ACK {res} ({mapped.value})")]
        if self._op == "upload":
            if self._next < len(self._items):
                return [self._done(now, MissionResult.PROTOCOL_ERROR, mav_result=res,
                                   detail=f"vehicle accepted after {self._next} of "
                                          f"{len(self._items)} items")]
            return [self._done(now, MissionResult.SUCCESS, mav_result=res)]
        if self._op == "clear":
            return [self._done(now, MissionResult.SUCCESS, mav_result=res)]
        return []

    def _on_count(self, count: int, now: float) -> list[MissionTransferDone]:
        if self._step != "list":
            return []
        self._count, self._tries = count, 0
        if count == 0:
            self._send_ack(MAV_MISSION_ACCEPTED)
            return [self._done(now, MissionResult.SUCCESS)]
        self._step, self._next = "items", 0
        self._send_request_int(0)
        self._deadline = now + self.timeout_s
        return []

    def _on_item(self, msg: MavMessage, now: float) -> list[MissionTransferDone]:
        if self._step != "items" or int(msg.seq) != self._next:
            return []  # duplicate or out of order: the timer re-requests the expected item
        self._items.append(item_from_msg(msg))
        self._next += 1
        self._tries = 0
        if self._next == self._count:
            self._send_ack(MAV_MISSION_ACCEPTED)
            return [self._done(now, MissionResult.SUCCESS)]
        self._send_request_int(self._next)
        self._deadline = now + self.timeout_s
        return []

    def handle_timer(self, now: float) -> list[MissionTransferDone]:
        """Retry the current step or give up after ``retries`` timeouts."""
        if self._op is None or self._deadline is None or now < self._deadline:
            return []
        self._tries += 1
        if self._tries > self.retries:
            return [self._done(now, MissionResult.TIMEOUT,
                               detail=f"no answer from the vehicle ({self._op}, "
                                      f"step {self._step})")]
        self._deadline = now + self.timeout_s
        if self._step == "count":
            self._send_count()
        elif self._step == "list":
            self._send_request_list()
        elif self._step == "items" and self._op == "download":
            self._send_request_int(self._next)
        elif self._step == "items" and self._op == "upload" and self._last_req is not None:
            # The item or the final MISSION_ACK may have been lost: re-send the last requested
            # item (PX4 answers a duplicate last item with another MISSION_ACK).
            self._send(item_to_msg(self._items[self._last_req], self.target_sysid,
                                 self.target_compid))
        elif self._step == "clear":
            self._send(mavlink2.MAVLink_mission_clear_all_message(
                self.target_sysid, self.target_compid, self._type))
        return []
