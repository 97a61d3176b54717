"""The autopilot's MAVLink links: codec state, fault channels, signing, stream schedules.

`Links` owns every link and all traffic: inbound datagrams are parsed and dispatched to the
handler registered for the message type (`handlers`); outbound messages are packed, signed and
queued (`send`, `broadcast`, `statustext`), and the periodic streams are emitted (`emit_streams`).
Link-level messages (HEARTBEAT, TIMESYNC, PING, a foreign STATUSTEXT) are handled here.
"""

from __future__ import annotations

import logging
import struct
from collections import Counter, deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from sitl_mock.autopilot import telemetry
from sitl_mock.autopilot.shared import COMPID, SYSID, Addr, Clock, Msg
from sitl_mock.faults import FaultyChannel, LinkFaults
from sitl_mock.mavwire import MessageCodec, codec, decode_datagram, pack_v2, unpack_single
from sitl_mock.signing import LinkSigning, boot_ticks_of

log = logging.getLogger("sitl_mock.autopilot")

Handler = Callable[["Link", Msg], None]
# SET_ATTITUDE_TARGET's fields in handler order: target system / component, type_mask, q (w, x,
# y, z), body roll / pitch / yaw rate [rad/s], thrust 0..1
AttitudeFieldsHandler = Callable[[int, int, int, Any, float, float, float, float], None]
_C_SET_ATTITUDE_TARGET = codec(mavlink.MAVLink_set_attitude_target_message)


@dataclass
class Link:
    """One MAVLink link: codec state, peer address, fault channels, stream schedule."""

    name: str
    remote: Addr | None
    mav: Any
    rx: FaultyChannel[tuple[bytes, Addr]]
    tx: FaultyChannel[bytes | None]  # None: a quiet stream's message (takes its place, not sent)
    streams: telemetry.StreamScheduler
    peer: Addr | None = None
    # outbound without faults: a FIFO of (time since boot [s], frame), exactly the order and due
    # times the pass-through FaultyChannel would give, without its heap entries
    tx_fifo: deque[tuple[float, bytes]] | None = None
    # inbound without faults: datagrams are processed on arrival (rx never queues anything)
    rx_direct: bool = False
    # MAVLink 2 signing (None: off): signs everything sent, refuses unsigned/bad frames
    signing: LinkSigning | None = None
    # streams nobody reads on this link (`Links.quiet_streams`): scheduled and counted as sent,
    # not built
    quiet: frozenset[int] = frozenset()

    @property
    def destination(self) -> Addr | None:
        return self.peer if self.peer is not None else self.remote


class Links:
    """Every link of the autopilot (by name) and the traffic on them; time from `clock`.

    remotes: link name -> default destination (PX4 sends there until a peer talks);
    link_faults: link name -> (inbound, outbound) LinkFaults; seed: for the fault channels;
    signing_key / unix_boot_s: MAVLink 2 signing on every link (None: off).
    """

    def __init__(
        self,
        clock: Clock,
        stats: Counter[str],
        remotes: Mapping[str, Addr | None],
        link_faults: Mapping[str, tuple[LinkFaults | None, LinkFaults | None]],
        seed: int,
        signing_key: bytes | None,
        unix_boot_s: float | None,
    ) -> None:
        self.clock = clock
        self.stats = stats
        self.by_name: dict[str, Link] = {}
        for i, (name, remote) in enumerate(remotes.items()):
            f_in, f_out = link_faults.get(name, (None, None))
            rates = telemetry.ONBOARD_RATES_HZ if name == "offboard" else telemetry.GCS_RATES_HZ
            self.by_name[name] = Link(
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
        # channel delivers at once in `receive` and never queues anything
        self.delayed_rx = [lk.rx for lk in self.by_name.values() if not lk.rx_direct]
        self.tele_next_t = 0.0  # earliest due time of any stream on any link [s since boot]
        self._statustext_id = 0
        # message type -> handler; the SET_ATTITUDE_TARGET hot path goes to `attitude_fields`
        self.handlers: dict[str, Handler] = {
            "HEARTBEAT": self._on_heartbeat,
            "TIMESYNC": self._on_timesync,
            "PING": self._on_ping,
            "STATUSTEXT": self._on_statustext,
        }
        self.attitude_fields: AttitudeFieldsHandler | None = None

    # ================================================================== inbound
    def receive(self, lk: Link, data: bytes, addr: Addr) -> None:
        """One datagram arrived on `lk` from `addr` now (after faults, if any, let it pass)."""
        t = self.clock.t
        if lk.peer is None:
            lk.peer = addr  # like PX4: lock onto the first peer that talks to us
        if lk.rx_direct:  # pass-through: deliver now
            lk.rx.stats.passed += 1
            self.process_datagram(lk, bytes(data), addr)
            return
        lk.rx.push((bytes(data), addr), t, t)
        for d, a in lk.rx.pop_due(t):
            self.process_datagram(lk, d, a)

    def deliver_delayed(self) -> None:
        """Process the inbound datagrams the fault channels release by now."""
        t = self.clock.t
        for lk in self.by_name.values():
            for d, a in lk.rx.pop_due(t):
                self.process_datagram(lk, d, a)

    def process_datagram(self, link: Link, data: bytes, addr: Addr) -> None:
        stats = self.stats
        stats["rx_datagrams"] += 1
        if link.signing is not None:
            self._parse_robust(link, data)
            return
        # hot path: a datagram that is exactly one clean SET_ATTITUDE_TARGET frame (what the
        # companion streams at 50-250 Hz), handled from its unpacked fields: the same counters
        # and effects as the general path below, without a pymavlink object
        f = unpack_single(data, _C_SET_ATTITUDE_TARGET)
        if f is not None and self.attitude_fields is not None:
            stats["rx_messages"] += 1
            try:  # wire order: time, q[4], roll/pitch/yaw rate, thrust, target sys/comp, mask
                self.attitude_fields(f[9], f[10], f[11], f[1:5], f[5], f[6], f[7], f[8])
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
        stats = self.stats
        for msg in msgs:
            kind = msg.get_type()
            if kind == "BAD_DATA":
                stats["rx_bad_data"] += 1
                continue
            if msg.get_msgbuf()[:1] != b"\xfd":
                stats["rx_mavlink1"] += 1  # PX4 in MAVLink 2 mode ignores v1 frames
                continue
            if link.signing is not None and not link.signing.accept(bytes(msg.get_msgbuf())):
                stats["rx_signing_refused"] += 1  # reasons: link.signing.refused
                continue
            stats["rx_messages"] += 1
            handler = self.handlers.get(kind)
            if handler is None:
                stats["rx_unhandled"] += 1
                continue
            try:
                handler(link, msg)
            except Exception:  # never let one bad message stop the vehicle
                stats["handler_errors"] += 1
                log.exception("error handling %s", kind)

    def _on_heartbeat(self, link: Link, msg: Msg) -> None:
        self.stats["rx_heartbeat"] += 1

    def _on_timesync(self, link: Link, msg: Msg) -> None:
        if msg.tc1 == 0:  # a request: answer at once (replies are not filtered by target)
            self.send(link, mavlink.MAVLink_timesync_message(self.clock.time_ns, msg.ts1))

    def _on_ping(self, link: Link, msg: Msg) -> None:
        if msg.target_system == 0:
            self.send(
                link,
                mavlink.MAVLink_ping_message(
                    msg.time_usec, msg.seq, msg.get_srcSystem(), msg.get_srcComponent()
                ),
            )

    def _on_statustext(self, link: Link, msg: Msg) -> None:
        if (msg.get_srcSystem(), msg.get_srcComponent()) != (SYSID, COMPID):
            self._forward(link, bytes(msg.get_msgbuf()))

    # ================================================================== outbound
    def send(self, link: Link, msg: Msg) -> None:
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
        t = self.clock.t
        if link.signing is not None:
            data = link.signing.sign(data, t)
        mav = link.mav
        mav.seq = (mav.seq + 1) & 0xFF
        fifo = link.tx_fifo
        if fifo is not None:
            fifo.append((t, data))
            link.tx.stats.passed += 1
        else:
            link.tx.push(data, t, t)
        self.stats["tx_messages"] += 1

    def broadcast(self, msg: Msg) -> None:
        """Queue `msg` on every link."""
        for lk in self.by_name.values():
            self.send(lk, msg)

    def _forward(self, src: Link, frame: bytes) -> None:
        """Pass another component's frame unchanged to the other links (PX4 `mavlink start
        -f`, on in SITL: e.g. a companion's STATUSTEXT reaches the ground station)."""
        t = self.clock.t
        for lk in self.by_name.values():
            if lk is src:
                continue
            if lk.tx_fifo is not None:
                lk.tx_fifo.append((t, frame))
                lk.tx.stats.passed += 1
            else:
                lk.tx.push(frame, t, t)

    def statustext(self, severity: int, text: str) -> None:
        """STATUSTEXT on every link, chunked (id / chunk_seq) when longer than 50 chars."""
        raw = text.encode("ascii", "replace")
        if len(raw) <= 50:
            self.broadcast(mavlink.MAVLink_statustext_message(severity, raw, 0, 0))
            return
        self._statustext_id = self._statustext_id % 65535 + 1
        chunks = [raw[i : i + 50] for i in range(0, len(raw), 50)]
        if len(chunks[-1]) == 50:
            chunks.append(b"")  # the text must end with a NUL-terminated chunk
        for seq, chunk in enumerate(chunks):
            self.broadcast(
                mavlink.MAVLink_statustext_message(severity, chunk, self._statustext_id, seq)
            )

    def datagrams_to_send(self, t: float, link: str | None = None) -> list[tuple[bytes, Addr]]:
        """Datagrams due by `t` [s since boot] on one link (or all), with their destinations."""
        out: list[tuple[bytes, Addr]] = []
        for lk in self.by_name.values() if link is None else (self.by_name[link],):
            dest = lk.peer if lk.peer is not None else lk.remote  # lk.destination
            fifo = lk.tx_fifo
            if fifo is not None:
                while fifo and fifo[0][0] <= t:
                    data = fifo.popleft()[1]
                    if dest is not None:
                        out.append((data, dest))
                continue
            for item in lk.tx.pop_due(t):
                if dest is not None and item is not None:
                    out.append((item, dest))
        return out

    def frames_due(self, t: float, link: str) -> list[bytes]:
        """`datagrams_to_send(t, link)` without the destinations (an in-process caller that
        reads one link: the lockstep pipe); the same datagrams, in the same order."""
        lk = self.by_name[link]
        if (lk.peer if lk.peer is not None else lk.remote) is None:
            return [d for d, _a in self.datagrams_to_send(t, link)]  # (discards them)
        fifo = lk.tx_fifo
        if fifo is None:
            return [item for item in lk.tx.pop_due(t) if item is not None]
        out: list[bytes] = []
        while fifo and fifo[0][0] <= t:
            out.append(fifo.popleft()[1])
        return out

    def next_due(self, t: float) -> float:
        """The earlier of `t` and the next time [s since boot] a channel has work."""
        for lk in self.by_name.values():
            t = min(t, lk.rx.next_due(), lk.tx.next_due())
            if lk.tx_fifo:
                t = min(t, lk.tx_fifo[0][0])
        return t

    # ================================================================== streams
    def quiet_streams(self, link: Link, msg_ids: frozenset[int]) -> None:
        """Streams on `link` that nobody reads (a lockstep run that keeps no log): their
        messages are not built nor sent, but everything else happens as if they were: the
        schedule, the link's sequence numbers, the outbound fault channel's draws (loss,
        latency, ...) and the counters, so every other message goes out exactly as before.
        Only `telemetry.QUIETABLE` streams (whether one would be sent is known from the
        vehicle status; when not, it is built as usual), and not on a signed link."""
        bad = set(msg_ids) - set(telemetry.QUIETABLE)
        if bad:
            raise ValueError(f"streams {sorted(bad)} cannot be left unbuilt")
        if msg_ids and link.signing is not None:
            raise ValueError("a signed link sends every message (signing timestamps)")
        link.quiet = frozenset(msg_ids)

    def _count_unsent(self, link: Link) -> None:
        """`send`'s effects for a quiet stream's message, without the message."""
        t = self.clock.t
        mav = link.mav
        mav.seq = (mav.seq + 1) & 0xFF
        if link.tx_fifo is not None:
            link.tx.stats.passed += 1
        else:
            link.tx.push(None, t, t)
        self.stats["tx_messages"] += 1

    def emit_streams(self, t: float, build: Callable[[int], Msg | None],
                     would_send: Callable[[int], bool | None] | None = None) -> None:
        """Build (with `build(msg_id)`) and queue the periodic messages due at `t` on every
        link; a builder's ValueError / OverflowError (non-finite state) skips that message.
        A link's quiet streams are counted instead when `would_send(msg_id)` knows whether
        the message would go out (see `quiet_streams`)."""
        nxt = float("inf")
        for lk in self.by_name.values():
            streams = lk.streams
            if t >= streams.earliest:
                quiet = lk.quiet if would_send is not None else ()
                for msg_id in streams.due(t):
                    if msg_id in quiet:
                        sent = would_send(msg_id)  # type: ignore[misc]
                        if sent is not None:
                            if sent:
                                self._count_unsent(lk)
                            continue
                    try:
                        m = build(msg_id)
                    except (ValueError, OverflowError):  # non-finite state: skip, count
                        self.stats["tx_encode_errors"] += 1
                        continue
                    if m is not None:
                        self.send(lk, m)
            if streams.earliest < nxt:
                nxt = streams.earliest
        self.tele_next_t = nxt

    def heartbeat_now(self) -> None:
        """Make the HEARTBEAT due now on every link that streams it (phase reset)."""
        t = self.clock.t
        hb = mavlink.MAVLINK_MSG_ID_HEARTBEAT
        for lk in self.by_name.values():
            if hb in lk.streams.next_due:
                lk.streams.next_due[hb] = t
                lk.streams.earliest = t
        self.tele_next_t = t

    def set_interval(self, link: Link, msg_id: int, interval_us: float) -> None:
        """SET_MESSAGE_INTERVAL on `link` (see StreamScheduler.set_interval)."""
        link.streams.set_interval(msg_id, interval_us, self.clock.t)
        self.tele_next_t = min(self.tele_next_t, link.streams.earliest)
