"""Autopilot HEARTBEAT tracking and link-loss detection (sans-IO, injected time)."""

from __future__ import annotations

from dataclasses import dataclass

from .codec import MavMessage
from .px4_mode import FlightMode, flight_mode_from_custom_mode, is_armed

MAV_AUTOPILOT_INVALID = 8


@dataclass(frozen=True)
class VehicleHeartbeat:
    """Decoded autopilot HEARTBEAT received at local time t_s [s]."""

    t_s: float
    mode: FlightMode
    custom_mode: int
    base_mode: int
    armed: bool
    system_status: int
    vehicle_type: int
    autopilot: int


@dataclass(frozen=True)
class LinkUp:
    """First autopilot heartbeat, or the first one after a link loss."""

    t_s: float
    regained: bool


@dataclass(frozen=True)
class LinkLost:
    """No autopilot heartbeat for the configured timeout."""

    t_s: float
    silent_for_s: float


@dataclass(frozen=True)
class ModeChanged:
    """HEARTBEAT custom_mode changed (old is None on the first heartbeat)."""

    t_s: float
    old: FlightMode | None
    new: FlightMode


@dataclass(frozen=True)
class ArmedChanged:
    """HEARTBEAT armed flag changed."""

    t_s: float
    armed: bool


HeartbeatEvent = LinkUp | LinkLost | ModeChanged | ArmedChanged


class HeartbeatTracker:
    """Follows the target autopilot's HEARTBEAT; link lost after ``timeout_s`` of silence.

    The link comes up with the first autopilot HEARTBEAT. Any message from the autopilot
    (``on_activity``) keeps it alive: a 1 Hz HEARTBEAT alone would declare a lossy but working
    link dead (3 lost heartbeats in a row happen every few minutes at 10 % loss) while PX4's
    30-100 Hz telemetry still flows. Heartbeats from other systems/components, or with autopilot
    MAV_AUTOPILOT_INVALID (a GCS or companion), are ignored.
    """

    def __init__(self, target_sysid: int = 1, target_compid: int = 1, timeout_s: float = 3.0):
        self.target_sysid = target_sysid
        self.target_compid = target_compid
        self.timeout_s = timeout_s
        self.last: VehicleHeartbeat | None = None
        self.last_rx_s: float | None = None
        self.link_up = False
        self._ever_up = False

    def on_heartbeat(self, msg: MavMessage, now: float) -> list[HeartbeatEvent]:
        """Feed a HEARTBEAT message; returns the events it causes."""
        if msg.get_srcSystem() != self.target_sysid or msg.get_srcComponent() != self.target_compid:
            return []
        if int(msg.autopilot) == MAV_AUTOPILOT_INVALID:
            return []
        custom = int(msg.custom_mode)
        base = int(msg.base_mode)
        hb = VehicleHeartbeat(
            t_s=now, mode=flight_mode_from_custom_mode(custom), custom_mode=custom,
            base_mode=base, armed=is_armed(base), system_status=int(msg.system_status),
            vehicle_type=int(msg.type), autopilot=int(msg.autopilot),
        )
        events: list[HeartbeatEvent] = self._alive(now)
        if not self.link_up:
            self.link_up = True
            events.append(LinkUp(now, regained=self._ever_up))
            self._ever_up = True
        prev = self.last
        if prev is None or prev.custom_mode != hb.custom_mode:
            events.append(ModeChanged(now, None if prev is None else prev.mode, hb.mode))
        if prev is None or prev.armed != hb.armed:
            events.append(ArmedChanged(now, hb.armed))
        self.last = hb
        return events

    def _alive(self, now: float) -> list[HeartbeatEvent]:
        self.last_rx_s = now if self.last_rx_s is None else max(self.last_rx_s, now)
        return []

    def on_activity(self, src_sysid: int, src_compid: int, now: float) -> list[HeartbeatEvent]:
        """Any message from the autopilot keeps the link alive (and regains a lost link)."""
        if src_sysid != self.target_sysid or src_compid != self.target_compid:
            return []
        self._alive(now)
        if not self.link_up and self._ever_up:
            self.link_up = True
            return [LinkUp(now, regained=True)]
        return []

    def check(self, now: float) -> list[HeartbeatEvent]:
        """Declare the link lost if nothing came from the autopilot for the timeout."""
        if self.link_up and self.last_rx_s is not None and now - self.last_rx_s >= self.timeout_s:
            self.link_up = False
            return [LinkLost(now, now - self.last_rx_s)]
        return []

    def mark_lost(self, now: float) -> list[HeartbeatEvent]:
        """The transport itself failed (e.g. TCP closed): declare the link lost now."""
        if not self.link_up:
            return []
        self.link_up = False
        silent = now - self.last_rx_s if self.last_rx_s is not None else 0.0
        return [LinkLost(now, silent)]

    def next_deadline(self) -> float | None:
        """Local time at which ``check`` may declare the link lost."""
        if self.link_up and self.last_rx_s is not None:
            return self.last_rx_s + self.timeout_s
        return None
