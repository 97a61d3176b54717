"""COMMAND_LONG client: retries, ack matching, IN_PROGRESS, and PX4 mode changes.

A command is sent, re-sent after ``timeout_s`` (default 0.5 s) up to ``retries`` times (default 3)
with ``confirmation`` incremented, and finished by a matching COMMAND_ACK (same command, from the
target, addressed to us or broadcast). IN_PROGRESS (5) stops the re-sending and waits
``in_progress_timeout_s`` (renewed by every further IN_PROGRESS ack) for the final ack.

Mode changes (MAV_CMD_DO_SET_MODE) are special: PX4 acknowledges them twice (ACCEPTED on receipt,
then the commander's verdict ~10 ms later). The verdict is the LAST ack within ``ack_window_s``
(default 1 s) of the first one, and an ACCEPTED verdict is only a success once a HEARTBEAT shows
the requested mode (within ``mode_confirm_s`` of the first ack). A heartbeat with the requested
mode after an ACCEPTED ack ends the wait early.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from enum import IntEnum

from pymavlink.dialects.v20 import common as mavlink2

from .codec import MavMessage

MAV_CMD_DO_SET_MODE = 176
MAV_CMD_COMPONENT_ARM_DISARM = 400
MAV_CMD_NAV_TAKEOFF = 22
MAV_CMD_NAV_LAND = 21
MAV_CMD_NAV_RETURN_TO_LAUNCH = 20
MAV_CMD_REQUEST_MESSAGE = 512
MAV_CMD_SET_MESSAGE_INTERVAL = 511
ARM_FORCE_MAGIC = 21196.0


class MavResult(IntEnum):
    """MAV_RESULT values."""

    ACCEPTED = 0
    TEMPORARILY_REJECTED = 1
    DENIED = 2
    UNSUPPORTED = 3
    FAILED = 4
    IN_PROGRESS = 5
    CANCELLED = 6


def result_name(result: int | None) -> str:
    """Readable name of a MAV_RESULT (or 'NO_ACK' for None)."""
    if result is None:
        return "NO_ACK"
    try:
        return MavResult(result).name
    except ValueError:
        return f"RESULT_{result}"


@dataclass(frozen=True)
class CommandFinished:
    """Final outcome of a command. ``result`` is the MAV_RESULT of the deciding ack (None: none
    arrived). ``ok`` is True only for ACCEPTED (and, for mode changes, heartbeat-confirmed)."""

    t_s: float
    command: int
    ok: bool
    result: int | None
    reason: str
    attempts: int


@dataclass(frozen=True)
class CommandProgress:
    """IN_PROGRESS ack (progress 0..100, 255 = unknown)."""

    t_s: float
    command: int
    progress: int


@dataclass(frozen=True)
class UnsolicitedAck:
    """A COMMAND_ACK from the autopilot that answers no pending command (a module's report,
    e.g. the onboard module's upload acknowledgements): its fields as received."""

    t_s: float
    command: int
    result: int
    progress: int
    result_param2: int


CommandEvent = CommandFinished | CommandProgress | UnsolicitedAck


class CommandBusyError(RuntimeError):
    """The same command is still waiting for its acknowledgement."""


@dataclass
class _Pending:
    command: int
    params: tuple[float, float, float, float, float, float, float]
    mode_custom: int | None
    deadline: float
    attempts: int = 1
    in_progress: bool = False
    acks: list[int] = field(default_factory=list)
    first_ack_t: float | None = None
    confirmed: bool = False


class CommandClient:
    """Sans-IO COMMAND_LONG client. ``send`` is called with each message to transmit."""

    def __init__(
        self,
        send: Callable[[MavMessage], None],
        own_sysid: int,
        own_compid: int,
        target_sysid: int = 1,
        target_compid: int = 1,
        *,
        timeout_s: float = 0.5,
        retries: int = 3,
        in_progress_timeout_s: float = 3.0,
        ack_window_s: float = 1.0,
        mode_confirm_s: float = 2.5,
    ) -> None:
        self._send = send
        self.own_sysid, self.own_compid = own_sysid, own_compid
        self.target_sysid, self.target_compid = target_sysid, target_compid
        self.timeout_s = timeout_s
        self.retries = retries
        self.in_progress_timeout_s = in_progress_timeout_s
        self.ack_window_s = ack_window_s
        self.mode_confirm_s = mode_confirm_s
        self._pending: dict[int, _Pending] = {}
        self._current_custom_mode: int | None = None

    # -- requests -----------------------------------------------------------------------------
    def send_command(
        self, command: int, params: Sequence[float], now: float, *, mode_custom: int | None = None
    ) -> None:
        """Send COMMAND_LONG ``command`` with up to 7 params (missing ones are 0).

        ``mode_custom``: for DO_SET_MODE, the HEARTBEAT custom_mode that confirms success.
        Raises CommandBusyError if the same command is still pending.
        """
        if command in self._pending:
            raise CommandBusyError(f"command {command} is still waiting for its acknowledgement")
        p = [float(x) for x in params] + [0.0] * (7 - len(params))
        if len(p) != 7:
            raise ValueError("COMMAND_LONG takes at most 7 params")
        pend = _Pending(command, (p[0], p[1], p[2], p[3], p[4], p[5], p[6]), mode_custom,
                        deadline=now + self.timeout_s)
        self._pending[command] = pend
        self._transmit(pend, confirmation=0)

    def cancel(self, command: int) -> None:
        """Forget a pending command (no event is produced)."""
        self._pending.pop(command, None)

    def is_pending(self, command: int) -> bool:
        """True while ``command`` awaits its outcome."""
        return command in self._pending

    def _transmit(self, pend: _Pending, confirmation: int) -> None:
        self._send(mavlink2.MAVLink_command_long_message(
            self.target_sysid, self.target_compid, pend.command, confirmation & 0xFF, *pend.params
        ))

    # -- inputs -------------------------------------------------------------------------------
    def on_command_ack(self, msg: MavMessage, now: float) -> list[CommandEvent]:
        """Feed a COMMAND_ACK."""
        if msg.get_srcSystem() != self.target_sysid or msg.get_srcComponent() != self.target_compid:
            return []
        tsys = int(getattr(msg, "target_system", 0))
        tcomp = int(getattr(msg, "target_component", 0))
        if tsys not in (0, self.own_sysid) or tcomp not in (0, self.own_compid):
            return []
        pend = self._pending.get(int(msg.command))
        if pend is None:
            return [UnsolicitedAck(now, int(msg.command), int(msg.result),
                                   int(getattr(msg, "progress", 0)),
                                   int(getattr(msg, "result_param2", 0)))]
        result = int(msg.result)
        if pend.mode_custom is not None:
            return self._mode_ack(pend, result, now)
        if result == MavResult.IN_PROGRESS:
            pend.in_progress = True
            pend.deadline = now + self.in_progress_timeout_s
            return [CommandProgress(now, pend.command, int(getattr(msg, "progress", 255)))]
        return [self._finish(pend, now, result, f"{result_name(result)}")]

    def _mode_ack(self, pend: _Pending, result: int, now: float) -> list[CommandEvent]:
        if result == MavResult.IN_PROGRESS:
            pend.in_progress = True
            pend.deadline = now + self.in_progress_timeout_s
            return []
        pend.acks.append(result)
        if pend.first_ack_t is None:
            pend.first_ack_t = now
            pend.deadline = now + self.ack_window_s
            pend.confirmed = self._current_custom_mode == pend.mode_custom
        return self._mode_maybe_done(pend, now, timer=False)

    def on_heartbeat_mode(self, custom_mode: int, now: float) -> list[CommandEvent]:
        """Feed the autopilot HEARTBEAT custom_mode (confirms pending mode changes)."""
        self._current_custom_mode = custom_mode
        events: list[CommandEvent] = []
        for pend in list(self._pending.values()):
            if pend.mode_custom is None or pend.first_ack_t is None:
                continue
            pend.confirmed = custom_mode == pend.mode_custom
            events += self._mode_maybe_done(pend, now, timer=False)
        return events

    def _mode_maybe_done(self, pend: _Pending, now: float, timer: bool) -> list[CommandEvent]:
        assert pend.first_ack_t is not None
        last = pend.acks[-1]
        if last == MavResult.ACCEPTED and pend.confirmed:
            return [self._finish(pend, now, last, "mode confirmed by HEARTBEAT")]
        if not timer:
            return []
        window_end = pend.first_ack_t + self.ack_window_s
        if now < window_end:
            return []
        if last != MavResult.ACCEPTED:
            return [self._finish(pend, now, last, f"mode change refused: {result_name(last)}")]
        confirm_end = pend.first_ack_t + self.mode_confirm_s
        if now >= confirm_end:
            return [self._finish(pend, now, last, "mode change ACCEPTED but the HEARTBEAT never "
                                 "showed the new mode", ok=False)]
        pend.deadline = confirm_end
        return []

    def handle_timer(self, now: float) -> list[CommandEvent]:
        """Re-send or time out pending commands whose deadline has passed."""
        events: list[CommandEvent] = []
        for pend in list(self._pending.values()):
            if now < pend.deadline:
                continue
            if pend.mode_custom is not None and pend.first_ack_t is not None:
                events += self._mode_maybe_done(pend, now, timer=True)
                continue
            if pend.in_progress:
                events.append(self._finish(pend, now, None, "no final COMMAND_ACK after "
                                           "IN_PROGRESS", ok=False))
                continue
            if pend.attempts <= self.retries:
                self._transmit(pend, confirmation=pend.attempts)
                pend.attempts += 1
                pend.deadline = now + self.timeout_s
                continue
            events.append(self._finish(pend, now, None,
                                       f"no COMMAND_ACK after {pend.attempts} attempts", ok=False))
        return events

    def next_deadline(self) -> float | None:
        """Earliest local time at which ``handle_timer`` has work."""
        return min((p.deadline for p in self._pending.values()), default=None)

    def _finish(
        self, pend: _Pending, now: float, result: int | None, reason: str, ok: bool | None = None
    ) -> CommandFinished:
        self._pending.pop(pend.command, None)
        if ok is None:
            ok = result == MavResult.ACCEPTED
        return CommandFinished(now, pend.command, ok, result, reason, pend.attempts)
