"""Fuzz targets: each takes raw bytes (what hypothesis, atheris or the campaign runner feed) and
raises only `Finding` for a broken property; the documented errors are part of normal operation.

- `mission_target`: mission text -> loader -> upload frames -> flight plan (quad and rover) ->
  schedule; only `MissionError` (or the schedule's own ValueError naming the file) may come
  out, and whatever is accepted encodes as MISSION_ITEM_INT and gives finite references.
  `MissionTarget` is the same with a `PlanMemo` kept across inputs (long campaigns: a chunk
  whose exact planner input was planned before is served from it, counted, and every
  `verify_every`-th input served from it is re-planned without it and compared bit for bit).
- `LinkTarget`: datagrams into the companion's `VehicleLink` (parsed as UDP datagrams) on a
  fake clock; afterwards the link still recognises a valid HEARTBEAT and answers a TIMESYNC.
- `MockTarget`: datagrams into one long-lived `sitl_mock` Autopilot (as a mock exposed to a
  noisy network is): raw bytes, valid frames of every message type it handles with fuzzed
  payloads, and PARAM_SET of its parameters with any value and type. No handler may raise, the
  state stays finite, and it keeps sending HEARTBEATs and listing every parameter.

The input format (all targets but the mission one): a sequence of chunks ``KIND LEN DATA[LEN]``;
KIND 0 = a raw datagram, 1..0xEF = a valid frame (correct CRC) of the KIND-th handled message
type with DATA as its payload, 0xF0..0xFE = PARAM_SET (DATA: parameter index, float32 value,
type), 0xFF = advance the clock by LEN x 10 ms.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Iterator
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from companion.mavlink.link import LinkConfig, VehicleLink
from companion.mission import MissionError, loads_mission, mission_to_flight_plan
from companion.planning.schedule import PlanMemo, Schedule, VehicleLimits, build_schedule

#: Mission expansion cap in the fuzz (planning costs ~5 ms per waypoint: 200 items stay ~1 s).
FUZZ_MAX_ITEMS = 200


class Finding(AssertionError):
    """A property of the target did not hold for this input."""


# --------------------------------------------------------------------------------- mission
def mission_target(data: bytes, memo: PlanMemo | None = None, verify: bool = False) -> str:
    """Load, plan and schedule; returns "rejected", "not flyable" or "flown". ``memo``: plan
    through it (see `MissionTarget`); ``verify``: also schedule without it and require the
    same schedule bit for bit."""
    from companion.replay.runner import DEFAULT_QUAD, mission_frames

    try:
        mission = loads_mission(data, source="fuzz")
    except MissionError as exc:
        _named(exc, "fuzz")
        return "rejected"
    try:  # what the companion uploads (and writes at the head of a replay tlog) must encode
        mission_frames(mission)
    except MissionError as exc:
        _named(exc, "fuzz")
    outcome = "not flyable"
    for vehicle in ("quad", "rover"):
        try:
            plan = mission_to_flight_plan(mission, vehicle=vehicle,  # type: ignore[arg-type]
                                          max_items=FUZZ_MAX_ITEMS)
            params = None if vehicle == "rover" else DEFAULT_QUAD
            schedule = build_schedule(plan, params, VehicleLimits(), memo=memo)
            if verify and memo is not None:
                try:
                    fresh = build_schedule(plan, params, VehicleLimits())
                except ValueError as exc:
                    raise Finding(f"planned from the memo, but failed without it: {exc}") from exc
                if not same_schedule(schedule, fresh):
                    raise Finding("the memo served a schedule different from planning it")
        except MissionError as exc:
            _named(exc, "fuzz")
            continue
        except ValueError as exc:  # the schedule's own "nothing to fly" names the file
            if not str(exc).startswith("fuzz"):
                raise Finding(f"undocumented ValueError from planning: {exc}") from exc
            continue
        end = schedule.duration_s
        if not (math.isfinite(end) and end >= 0.0):
            raise Finding(f"schedule duration {end}")
        for k in range(5):
            ref = schedule.reference(end * k / 4.0)
            values = [*ref.pos_ned, *ref.vel_ned, *ref.acc_ned, ref.yaw]
            if not all(math.isfinite(float(v)) for v in values):
                raise Finding(f"non-finite reference at t={end * k / 4.0}: {values}")
        outcome = "flown"
    return outcome


def same_schedule(a: Schedule, b: Schedule) -> bool:
    """Two schedules equal bit for bit: every piece's timing, points and yaws, every
    trajectory's (and yaw channel's) control points and durations, the waypoints."""

    def arrays(s: Schedule) -> list[Any]:
        out: list[Any] = [s.duration_s, s.waypoints_ned, s.acceptance_m, s.item_indices,
                          s.final_action, s.vehicle]
        for p in s.pieces:
            out += [p.kind, p.t0_s, p.duration_s, p.phase, p.pos_ned, p.yaw0, p.yaw1,
                    p.speed_caps]
            for tr in (p.traj, p.turn, p.traj.yaw if p.traj is not None else None):
                out += [None] if tr is None else [tr.control_points, tr.durations]
        return out

    from companion.planning.schedule import exact_key

    return exact_key(arrays(a)) == exact_key(arrays(b))


class MissionTarget:
    """`mission_target` through one bounded `PlanMemo` of `memo_entries` planned chunks kept
    across inputs; counts the inputs whose chunks were all served from it ("from memo"), the
    ones that planned at least one ("planned"), and the chunks of each kind."""

    def __init__(self, memo_entries: int = 4096, verify_every: int = 100) -> None:
        self.memo = PlanMemo(memo_entries)
        self.verify_every = verify_every
        self.inputs_planned = 0
        self.inputs_from_memo = 0
        self.verified = 0
        self._with_hits = 0

    def __call__(self, data: bytes) -> str:
        planned, served = self.memo.planned, self.memo.served
        # armed until an input served from the memo (at least one chunk) takes it
        verify = self.verify_every > 0 and (self._with_hits + 1) % self.verify_every == 0
        try:
            return mission_target(data, self.memo, verify=verify)
        finally:
            if self.memo.planned > planned:
                self.inputs_planned += 1
            elif self.memo.served > served:
                self.inputs_from_memo += 1
            if self.memo.served > served:
                self._with_hits += 1
                self.verified += verify

    def stats(self) -> dict[str, int]:
        """Counts for the campaign's summary."""
        return {"inputs_planned": self.inputs_planned, "inputs_from_memo": self.inputs_from_memo,
                "chunks_planned": self.memo.planned, "chunks_from_memo": self.memo.served,
                "verified_against_planning": self.verified, "entries": len(self.memo),
                "max_entries": self.memo.max_entries}


def _named(exc: MissionError, source: str) -> None:
    if not str(exc).startswith(source + ": "):
        raise Finding(f"MissionError not naming the file: {exc}")


# ---------------------------------------------------------------------------- input format
def _message_classes(names: list[str]) -> list[Any]:
    by_name = {cls.msgname: cls for cls in mavlink.mavlink_map.values()}
    return [by_name[n] for n in sorted(set(names)) if n in by_name]


def frame(cls: Any, payload: bytes, seq: int, sysid: int = 255, compid: int = 190) -> bytes:
    """A MAVLink 2 frame of message class ``cls`` with ``payload`` (cut or zero-padded to the
    class's length, then MAVLink 2 truncated) and a correct CRC."""
    size = int(cls.unpacker.size)
    body = (payload[:size] + bytes(max(0, size - len(payload)))).rstrip(b"\x00") or b"\x00"
    msg_id = int(cls.id)
    header = struct.pack("<BBBBBBBHB", 0xFD, len(body), 0, 0, seq & 0xFF, sysid, compid,
                         msg_id & 0xFFFF, msg_id >> 16)
    crc = mavlink.x25crc(header[1:] + body)
    crc.accumulate(struct.pack("B", cls.crc_extra))
    return header + body + struct.pack("<H", crc.crc)


def chunks(data: bytes) -> Iterator[tuple[int, bytes, int]]:
    """(kind, data, length byte) chunks of a fuzz input (see the module doc)."""
    i = 0
    while i + 1 < len(data):
        kind, n = data[i], data[i + 1]
        i += 2
        yield kind, data[i:i + n], n
        i += n


# ------------------------------------------------------------------------- companion link
_LINK_KINDS = sorted(VehicleLink().telemetry.kinds | {
    "HEARTBEAT", "COMMAND_ACK", "TIMESYNC", "MISSION_REQUEST", "MISSION_REQUEST_INT",
    "MISSION_ACK", "MISSION_COUNT", "MISSION_ITEM_INT", "MISSION_ITEM", "STATUSTEXT",
    "PARAM_VALUE"})
LINK_CLASSES = _message_classes(_LINK_KINDS)


class LinkTarget:
    """Datagrams into a fresh companion `VehicleLink` per input, on a fake clock."""

    def __call__(self, data: bytes) -> None:
        link = VehicleLink(LinkConfig())
        now = 100.0
        seq = 0
        link.handle_timer(now)
        link.frames_to_send()
        for kind, body, n in chunks(data):
            if kind == 0xFF:
                now += n * 0.01
                link.handle_timer(now)
                link.frames_to_send()
                continue
            if kind == 0:
                datagram = body
            else:
                cls = LINK_CLASSES[(kind - 1) % len(LINK_CLASSES)]
                sysid = 1 if n & 1 == 0 else body[:1][0] if body else 0
                datagram = frame(cls, body, seq, sysid=sysid, compid=1)
                seq += 1
            link.receive_bytes(datagram, now, datagram=True)
        self.check_usable(link, now + 0.01, seq)

    @staticmethod
    def check_usable(link: VehicleLink, now: float, seq: int) -> None:
        """A valid HEARTBEAT from PX4 is seen; a TIMESYNC request is answered."""
        hb = mavlink.MAVLink_heartbeat_message(2, 12, 157, 50593792, 4, 3)
        mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        mav.seq = seq & 0xFF
        link.receive_bytes(bytes(hb.pack(mav)), now, datagram=True)
        last = link.heartbeat.last
        if last is None or last.t_s != now or last.custom_mode != 50593792:
            raise Finding(f"a valid HEARTBEAT after the input was not taken: {last}")
        link.frames_to_send()
        mav.seq = (seq + 1) & 0xFF
        ts = mavlink.MAVLink_timesync_message(0, 123456789)
        link.receive_bytes(bytes(ts.pack(mav)), now, datagram=True)
        replies = [m for f in link.frames_to_send()
                   for m in (mavlink.MAVLink(None).parse_buffer(f) or [])
                   if m.get_type() == "TIMESYNC" and m.ts1 == 123456789]
        if not replies:
            raise Finding("a TIMESYNC request after the input was not answered")


# ------------------------------------------------------------------------------------ mock
class MockTarget:
    """Datagrams into one long-lived mock Autopilot (renewed every `renew_every` inputs,
    alternately on the ground and flying in AUTO.LOITER)."""

    CLIENT = ("127.0.0.1", 14540)

    def __init__(self, renew_every: int = 300, check_every: int = 25) -> None:
        from sitl_mock.autopilot import Autopilot
        from sitl_mock.params import PARAMS

        self._autopilot_cls = Autopilot
        self.param_names = list(PARAMS)
        handled = sorted(Autopilot(now=0.0, remotes={"offboard": self.CLIENT}).handled_messages)
        self.classes = _message_classes(handled)
        if not self.classes:
            raise RuntimeError("the mock handles no message type pymavlink knows")
        self.renew_every = renew_every
        self.check_every = check_every
        self.inputs = 0
        self.renewals = 0
        self.ap: Any = None
        self.t = 0.0
        self.seq = 0
        self.mav = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)

    # -- driving ---------------------------------------------------------------------------
    def _send(self, data: bytes) -> None:
        self.ap.receive_datagram(data, self.CLIENT, self.t)

    def _msg(self, msg: Any) -> None:
        self.mav.seq = self.seq & 0xFF
        self.seq += 1
        self._send(bytes(msg.pack(self.mav)))

    def _run(self, seconds: float) -> list[bytes]:
        out: list[bytes] = []
        end = self.t + seconds
        while self.t < end - 1e-9:
            self.t = min(end, self.t + 0.05)
            self.ap.advance(self.t)
            out += [d for d, _a in self.ap.datagrams_to_send(self.t)]
        return out

    def renew(self) -> None:
        """A fresh autopilot; every other one is armed and hovering (AUTO.LOITER)."""
        self.t = 0.0
        self.ap = self._autopilot_cls(now=0.0, remotes={"offboard": self.CLIENT})
        self._run(4.0)
        self.renewals += 1
        if self.renewals % 2 == 0:
            nan = math.nan
            self._msg(mavlink.MAVLink_command_long_message(1, 1, 22, 0, 0, 0, 0, nan, nan, nan,
                                                           nan))
            self._msg(mavlink.MAVLink_command_long_message(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0))
            self._run(8.0)
        self._errors = self.ap.stats["handler_errors"]

    # -- one input ---------------------------------------------------------------------------
    def __call__(self, data: bytes) -> None:
        if self.ap is None or self.inputs % self.renew_every == 0:
            self.renew()
        self.inputs += 1
        for kind, body, n in chunks(data):
            if kind == 0xFF:
                self._run(n * 0.01)
            elif kind >= 0xF0:
                self._param_set(body)
            elif kind == 0:
                self._send(body)
            else:
                cls = self.classes[(kind - 1) % len(self.classes)]
                self._send(frame(cls, body, self.seq))
                self.seq += 1
        self._run(0.02)
        errors = self.ap.stats["handler_errors"]
        if errors != self._errors:
            self._errors = errors
            raise Finding("a message handler raised (see the sitl_mock log)")
        s = self.ap.state
        if not all(math.isfinite(v) for v in (*s.pos_ned, *s.vel_ned, *s.q_wxyz)):
            raise Finding(f"non-finite vehicle state {s}")
        if self.inputs % self.check_every == 0:
            self.check_usable()

    def _param_set(self, body: bytes) -> None:
        body = body + bytes(max(0, 6 - len(body)))
        name = self.param_names[body[0] % len(self.param_names)]
        value = struct.unpack("<f", body[1:5])[0]
        ptype = (mavlink.MAV_PARAM_TYPE_INT32, mavlink.MAV_PARAM_TYPE_REAL32)[body[5] & 1] \
            if body[5] < 0x80 else body[5] % 11
        self._msg(mavlink.MAVLink_param_set_message(0, 0, name.encode(), value, ptype))

    def check_usable(self) -> None:
        """HEARTBEATs keep coming and PARAM_REQUEST_LIST lists every parameter."""
        self._msg(mavlink.MAVLink_param_request_list_message(0, 0))
        out = self._run(1.2)
        parser = mavlink.MAVLink(None)
        msgs = [m for d in out for m in (parser.parse_buffer(d) or [])]
        kinds = [m.get_type() for m in msgs]
        if "HEARTBEAT" not in kinds:
            raise Finding("no HEARTBEAT for 1.2 s")
        listed = {m.param_id for m in msgs if m.get_type() == "PARAM_VALUE"}
        if listed != set(self.param_names):
            raise Finding(f"PARAM_REQUEST_LIST listed {len(listed)} of {len(self.param_names)}")
