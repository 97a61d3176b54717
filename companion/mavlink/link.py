"""VehicleLink: the whole sans-IO vehicle protocol in one object (aioquic-style).

Feed bytes with ``receive_bytes(data, now)`` (or decoded messages with ``handle_message``),
drain ``frames_to_send()``, run ``handle_timer(now)`` at ``get_timer()``. Requests (arm,
set_mode, takeoff, land, mission transfers, parameter reads) queue messages and return nothing;
their outcomes come back as events. Never reads a clock, never touches a socket.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

from pymavlink.dialects.v20 import common as mavlink2

from .codec import DEFAULT_COMPID, DEFAULT_SYSID, PX4_COMPID, PX4_SYSID, Codec, MavMessage
from .commands import (
    ARM_FORCE_MAGIC,
    MAV_CMD_COMPONENT_ARM_DISARM,
    MAV_CMD_DO_SET_MODE,
    MAV_CMD_NAV_LAND,
    MAV_CMD_NAV_TAKEOFF,
    MAV_CMD_REQUEST_MESSAGE,
    MAV_CMD_SET_MESSAGE_INTERVAL,
    CommandClient,
    CommandEvent,
)
from .heartbeat import HeartbeatEvent, HeartbeatTracker
from .mission_client import MissionClient, MissionTransferDone
from .params import ParamClient, ParamReadDone
from .px4_mode import FlightMode, custom_mode_of, set_mode_params
from .setpoints import SetpointCommand, build_setpoint, pack_setpoint
from .signing import Signer, SigningConfig
from .telemetry import VELOCITY_CORRECTION_RAD_S, TelemetryEvent, TelemetryState
from .timesync import TimeSync, TimesyncUpdate

MAV_TYPE_ONBOARD_CONTROLLER = 18
MAV_AUTOPILOT_INVALID = 8
MAV_STATE_ACTIVE = 4

LinkEvent = (HeartbeatEvent | CommandEvent | MissionTransferDone | TelemetryEvent
             | TimesyncUpdate | ParamReadDone)


@dataclass(frozen=True)
class LinkConfig:
    """Ids, timing (seconds) and MAVLink 2 signing (None: off) of the companion link."""

    sysid: int = DEFAULT_SYSID
    compid: int = DEFAULT_COMPID
    target_sysid: int = PX4_SYSID
    target_compid: int = PX4_COMPID
    heartbeat_timeout_s: float = 3.0
    heartbeat_interval_s: float = 1.0
    command_timeout_s: float = 0.5
    command_retries: int = 3
    ack_window_s: float = 1.0
    mode_confirm_s: float = 2.5
    mission_timeout_s: float = 0.25
    mission_retries: int = 20
    param_timeout_s: float = 0.5
    param_retries: int = 2
    timesync_interval_s: float = 1.0
    signing: SigningConfig | None = None
    #: telemetry's horizontal velocity correction (`VelocityCorrection`) [rad/s]; 0: none
    velocity_correction_rad_s: float = VELOCITY_CORRECTION_RAD_S

    def with_signing_key(self, key: bytes | None) -> LinkConfig:
        """This configuration signing with ``key`` (32 bytes, default link ids; None: as is)."""
        return self if key is None else replace(self, signing=SigningConfig(key))


class VehicleLink:
    """Companion side of one MAVLink link to a PX4 autopilot."""

    def __init__(self, config: LinkConfig | None = None, codec: Codec | None = None) -> None:
        self.config = cfg = config or LinkConfig()
        signer = None if cfg.signing is None else Signer(cfg.signing)
        self.codec = codec or Codec(cfg.sysid, cfg.compid, signer)
        self._out: list[bytes] = []
        self.heartbeat = HeartbeatTracker(cfg.target_sysid, cfg.target_compid,
                                          cfg.heartbeat_timeout_s)
        self.commands = CommandClient(
            self._queue, cfg.sysid, cfg.compid, cfg.target_sysid, cfg.target_compid,
            timeout_s=cfg.command_timeout_s, retries=cfg.command_retries,
            ack_window_s=cfg.ack_window_s, mode_confirm_s=cfg.mode_confirm_s)
        self.mission = MissionClient(self._queue, cfg.target_sysid, cfg.target_compid,
                                     timeout_s=cfg.mission_timeout_s,
                                     retries=cfg.mission_retries)
        self.params = ParamClient(self._queue, cfg.target_sysid, cfg.target_compid,
                                  timeout_s=cfg.param_timeout_s, retries=cfg.param_retries)
        self.telemetry = TelemetryState(cfg.target_sysid, cfg.target_compid,
                                        velocity_correction_rad_s=cfg.velocity_correction_rad_s)
        self.timesync = TimeSync(self._queue, interval_s=cfg.timesync_interval_s)
        self._next_heartbeat: float | None = None
        self._t0: float | None = None
        # message type -> handler for everything but HEARTBEAT and MISSION_* (telemetry: any type
        # TelemetryState handles; other types are ignored)
        self._handlers: dict[str, Callable[[MavMessage, float], Sequence[LinkEvent]]] = {
            kind: self.telemetry.update for kind in self.telemetry.kinds}
        self._handlers["COMMAND_ACK"] = self.commands.on_command_ack
        self._handlers["TIMESYNC"] = self.timesync.on_timesync
        self._handlers["PARAM_VALUE"] = self.params.on_message

    # -- output -----------------------------------------------------------------------------
    def _queue(self, msg: MavMessage) -> None:
        self._out.append(self.codec.encode(msg))

    def send_message(self, msg: MavMessage) -> None:
        """Queue an arbitrary message (encoded with our ids)."""
        self._queue(msg)

    def send_float_array(self, name: str, array_id: int, data: Sequence[float],
                         now: float) -> None:
        """Queue a DEBUG_FLOAT_ARRAY (58 values; PX4 publishes it as uORB debug_array)."""
        if len(data) != 58:
            raise ValueError(f"DEBUG_FLOAT_ARRAY carries 58 values, got {len(data)}")
        self._queue(mavlink2.MAVLink_debug_float_array_message(
            int(now * 1e6), name.encode(), array_id, [float(x) for x in data]))

    def advance_signing_clock(self, unix_time_s: float) -> None:
        """Give the signer the wall clock (UNIX seconds): outgoing signing timestamps never fall
        behind it. Call before the first send and periodically; a no-op without signing."""
        if self.codec.signer is not None:
            self.codec.signer.advance_clock(unix_time_s)

    def frames_to_send(self) -> list[bytes]:
        """Encoded frames queued since the last call (one MAVLink frame each)."""
        out, self._out = self._out, []
        return out

    def time_boot_ms(self, now: float) -> int:
        """Milliseconds since the first call with ``now`` (for message time fields)."""
        if self._t0 is None:
            self._t0 = now
        return int((now - self._t0) * 1000.0)

    def encode_setpoint(self, sp: SetpointCommand, now: float) -> bytes:
        """Validate and encode one setpoint frame (thread-safe; raises SetpointError). Signed
        on the setpoint stream (``SigningConfig.setpoint_link_id``) when signing is on."""
        ts, tc, tbm = self.config.target_sysid, self.config.target_compid, self.time_boot_ms(now)
        sc = self.config.signing
        lid = None if sc is None else sc.setpoint_link_id
        packed = pack_setpoint(sp, ts, tc, tbm)
        if packed is not None:
            return self.codec.encode_payload(*packed, link_id=lid)
        return self.codec.encode(build_setpoint(sp, ts, tc, tbm), lid)

    # -- input ------------------------------------------------------------------------------
    def receive_bytes(self, data: bytes, now: float, *, datagram: bool = False) -> list[LinkEvent]:
        """Decode bytes from the transport and handle every complete message; ``datagram``:
        ``data`` is one whole datagram (UDP), parsed on its own (see ``Codec.decode``)."""
        events: list[LinkEvent] = []
        for msg in self.codec.decode(data, datagram=datagram):
            events += self.handle_message(msg, now)
        return events

    def handle_message(self, msg: MavMessage, now: float) -> list[LinkEvent]:
        """Dispatch one decoded message."""
        kind = msg.get_type()
        events: list[LinkEvent] = []
        if kind == "HEARTBEAT":
            events += self.heartbeat.on_heartbeat(msg, now)
            last = self.heartbeat.last
            if last is not None and last.t_s == now:
                events += self.commands.on_heartbeat_mode(last.custom_mode, now)
            return events
        events += self.heartbeat.on_activity(msg.get_srcSystem(), msg.get_srcComponent(), now)
        handler = self._handlers.get(kind)
        if handler is not None:
            events += handler(msg, now)
        elif kind.startswith("MISSION_"):
            events += self.mission.on_message(msg, now)
        return events

    def transport_lost(self, now: float) -> list[LinkEvent]:
        """Tell the core the byte transport failed; returns LinkLost if the link was up."""
        return list(self.heartbeat.mark_lost(now))

    # -- timers -----------------------------------------------------------------------------
    def get_timer(self) -> float | None:
        """Earliest local time at which ``handle_timer`` has work."""
        ds = [self._next_heartbeat, self.heartbeat.next_deadline(), self.commands.next_deadline(),
              self.mission.next_deadline(), self.params.next_deadline(),
              self.timesync.next_deadline(),
              self.telemetry.next_deadline()]
        return min((d for d in ds if d is not None), default=None)

    def handle_timer(self, now: float) -> list[LinkEvent]:
        """Run retries/timeouts, send our HEARTBEAT and TIMESYNC when due."""
        if self._next_heartbeat is None or now >= self._next_heartbeat:
            self._queue(mavlink2.MAVLink_heartbeat_message(
                MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID, 0, 0, MAV_STATE_ACTIVE, 3))
            self._next_heartbeat = now + self.config.heartbeat_interval_s
        events: list[LinkEvent] = []
        events += self.heartbeat.check(now)
        events += self.commands.handle_timer(now)
        events += self.mission.handle_timer(now)
        events += self.params.handle_timer(now)
        events += self.telemetry.handle_timer(now)
        self.timesync.handle_timer(now)
        return events

    @property
    def rtt_s(self) -> float:
        """The link's round-trip time [s]: the smallest of TIMESYNC's recent exchanges (NaN
        before the first reply)."""
        est = self.timesync.estimate
        return math.nan if est is None else est.rtt_s

    # -- vehicle state shortcuts ----------------------------------------------------------------
    @property
    def mode(self) -> FlightMode | None:
        """Flight mode from the last HEARTBEAT (None before the first)."""
        return None if self.heartbeat.last is None else self.heartbeat.last.mode

    @property
    def armed(self) -> bool:
        """Armed flag from the last HEARTBEAT."""
        return self.heartbeat.last is not None and self.heartbeat.last.armed

    # -- requests ---------------------------------------------------------------------------
    def command_long(self, command: int, params: list[float] | tuple[float, ...],
                     now: float) -> None:
        """Send a COMMAND_LONG with retries (outcome: CommandFinished event)."""
        self.commands.send_command(command, params, now)

    def arm(self, now: float, force: bool = False) -> None:
        """MAV_CMD_COMPONENT_ARM_DISARM(1)."""
        self.commands.send_command(MAV_CMD_COMPONENT_ARM_DISARM,
                                   [1.0, ARM_FORCE_MAGIC if force else 0.0], now)

    def disarm(self, now: float, force: bool = False) -> None:
        """MAV_CMD_COMPONENT_ARM_DISARM(0)."""
        self.commands.send_command(MAV_CMD_COMPONENT_ARM_DISARM,
                                   [0.0, ARM_FORCE_MAGIC if force else 0.0], now)

    def set_mode(self, mode: FlightMode, now: float) -> None:
        """DO_SET_MODE to ``mode``; success needs the last ack ACCEPTED and a HEARTBEAT in it."""
        p1, p2, p3 = set_mode_params(mode, self.armed)
        self.commands.send_command(MAV_CMD_DO_SET_MODE, [p1, p2, p3], now,
                                   mode_custom=custom_mode_of(mode))

    def takeoff(self, now: float, alt_amsl_m: float = math.nan) -> None:
        """NAV_TAKEOFF to alt_amsl_m (NaN: PX4's MIS_TAKEOFF_ALT above the current altitude)."""
        nan = math.nan
        self.commands.send_command(MAV_CMD_NAV_TAKEOFF,
                                   [nan, 0.0, 0.0, nan, nan, nan, alt_amsl_m], now)

    def land(self, now: float) -> None:
        """NAV_LAND at the current position."""
        nan = math.nan
        self.commands.send_command(MAV_CMD_NAV_LAND, [0.0, 0.0, 0.0, nan, nan, nan, nan], now)

    def set_message_interval(self, message_id: int, interval_us: float, now: float) -> None:
        """MAV_CMD_SET_MESSAGE_INTERVAL: stream ``message_id`` every ``interval_us`` [us]
        (-1 stops it, 0 restores the autopilot's default rate)."""
        self.commands.send_command(MAV_CMD_SET_MESSAGE_INTERVAL,
                                   [float(message_id), float(interval_us)], now)

    def request_message(self, message_id: int, now: float) -> None:
        """MAV_CMD_REQUEST_MESSAGE (e.g. 242 HOME_POSITION)."""
        self.commands.send_command(MAV_CMD_REQUEST_MESSAGE, [float(message_id)], now)
