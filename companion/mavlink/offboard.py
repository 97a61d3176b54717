"""Offboard state machine: IDLE -> PRIMING -> REQUESTED -> ACTIVE -> EXITED / LOST, or
IDLE -> ACTIVE when the pilot switched the vehicle into OFFBOARD (serve streams on its own).

Transitions are data (``TRANSITIONS``). PRIMING streams setpoints; the OFFBOARD request is only
allowed once the stream has run continuously for ``prime_s`` (default 0.5 s) at the configured
rate (PX4 refuses OFFBOARD without a fresh "proof of life"). Once the vehicle leaves OFFBOARD
(pilot takeover, failsafe) the machine goes to EXITED and never re-requests OFFBOARD by itself.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum


class OffboardState(Enum):
    """Offboard session state."""

    IDLE = "idle"            # not streaming
    PRIMING = "priming"      # streaming, OFFBOARD not requested yet
    REQUESTED = "requested"  # streaming, DO_SET_MODE(OFFBOARD) pending
    ACTIVE = "active"        # vehicle confirmed in OFFBOARD, setpoints are flown
    EXITED = "exited"        # OFFBOARD refused or left (takeover/failsafe): stop streaming
    LOST = "lost"            # link lost: stop streaming


class OffboardTrigger(Enum):
    """Inputs of the offboard state machine."""

    START = "start"
    REQUEST = "request"
    CONFIRMED = "confirmed"
    REJECTED = "rejected"
    MODE_LEFT = "mode_left"
    LINK_LOST = "link_lost"
    STOP = "stop"
    PILOT_ENTERED_OFFBOARD = "pilot_entered_offboard"  # the pilot switched to OFFBOARD


S, T = OffboardState, OffboardTrigger

#: (state, trigger) -> next state. Pairs not listed are ignored (no transition).
TRANSITIONS: dict[tuple[OffboardState, OffboardTrigger], OffboardState] = {
    (S.IDLE, T.START): S.PRIMING,
    (S.IDLE, T.PILOT_ENTERED_OFFBOARD): S.ACTIVE,
    (S.EXITED, T.START): S.PRIMING,
    (S.LOST, T.START): S.PRIMING,
    (S.PRIMING, T.REQUEST): S.REQUESTED,
    (S.PRIMING, T.LINK_LOST): S.LOST,
    (S.PRIMING, T.STOP): S.IDLE,
    (S.REQUESTED, T.CONFIRMED): S.ACTIVE,
    (S.REQUESTED, T.REJECTED): S.EXITED,
    (S.REQUESTED, T.LINK_LOST): S.LOST,
    (S.REQUESTED, T.STOP): S.IDLE,
    (S.ACTIVE, T.MODE_LEFT): S.EXITED,
    (S.ACTIVE, T.LINK_LOST): S.LOST,
    (S.ACTIVE, T.STOP): S.IDLE,
    (S.EXITED, T.STOP): S.IDLE,
    (S.LOST, T.STOP): S.IDLE,
}

#: States in which setpoints must be streamed.
STREAMING_STATES = frozenset({S.PRIMING, S.REQUESTED, S.ACTIVE})


@dataclass(frozen=True)
class OffboardStateChanged:
    """A transition of the offboard state machine."""

    t_s: float
    old: OffboardState
    new: OffboardState
    trigger: OffboardTrigger
    reason: str


class OffboardNotPrimedError(RuntimeError):
    """OFFBOARD requested before the setpoint stream ran long enough."""


class OffboardMachine:
    """Pure offboard state machine with stream-priming bookkeeping (injected time).

    rate_hz: configured setpoint rate; prime_s: continuous streaming required before the request.
    A gap longer than ``max(3 / rate_hz, 0.1)`` s between setpoints restarts the priming run.
    """

    def __init__(self, rate_hz: float, prime_s: float = 0.5) -> None:
        if not (math.isfinite(rate_hz) and rate_hz > 2.0):
            raise ValueError(f"setpoint rate must be > 2 Hz (PX4 needs it), got {rate_hz}")
        self.rate_hz = rate_hz
        self.prime_s = prime_s
        self.max_gap_s = max(3.0 / rate_hz, 0.1)
        self.min_count = math.ceil(0.9 * prime_s * rate_hz)
        self.state = OffboardState.IDLE
        self.history: list[OffboardStateChanged] = []
        self._run_start: float | None = None
        self._run_count = 0
        self._last_sent: float | None = None

    @property
    def streaming(self) -> bool:
        """True while setpoints must be sent."""
        return self.state in STREAMING_STATES

    def fire(
        self, trigger: OffboardTrigger, now: float, reason: str = ""
    ) -> OffboardStateChanged | None:
        """Apply ``trigger``; returns the transition, or None if the table has no entry."""
        new = TRANSITIONS.get((self.state, trigger))
        if new is None:
            return None
        ev = OffboardStateChanged(now, self.state, new, trigger, reason)
        self.state = new
        self.history.append(ev)
        if new is OffboardState.PRIMING:
            self._run_start, self._run_count, self._last_sent = None, 0, None
        return ev

    # -- stream bookkeeping ---------------------------------------------------------------------
    def on_setpoint_sent(self, t: float) -> None:
        """Record that a setpoint left at local time ``t``."""
        if self._last_sent is None or t - self._last_sent > self.max_gap_s:
            self._run_start, self._run_count = t, 0
        self._run_count += 1
        self._last_sent = t

    @property
    def run_count(self) -> int:
        """Setpoints sent since the stream's last gap."""
        return self._run_count

    @property
    def last_sent_s(self) -> float | None:
        """When the last setpoint left [s] (None: none since the stream started)."""
        return self._last_sent

    def is_primed(self, now: float) -> bool:
        """Stream continuous for >= prime_s with >= 90 % of the expected setpoints."""
        if self._run_start is None or self._last_sent is None:
            return False
        if now - self._last_sent > self.max_gap_s:
            return False
        return now - self._run_start >= self.prime_s and self._run_count >= self.min_count

    # -- convenience wrappers ----------------------------------------------------------------
    def start(self, now: float) -> OffboardStateChanged | None:
        """Begin streaming (IDLE/EXITED/LOST -> PRIMING)."""
        return self.fire(T.START, now, "stream started")

    def request(self, now: float) -> OffboardStateChanged:
        """PRIMING -> REQUESTED; raises OffboardNotPrimedError if the stream is not primed yet."""
        if self.state is not OffboardState.PRIMING:
            raise RuntimeError(f"cannot request OFFBOARD in state {self.state.value}")
        if not self.is_primed(now):
            raise OffboardNotPrimedError(
                f"setpoint stream not primed: need {self.prime_s:.2f} s at {self.rate_hz:g} Hz")
        ev = self.fire(T.REQUEST, now, "OFFBOARD requested")
        assert ev is not None
        return ev

    def on_mode_result(self, ok: bool, now: float, reason: str = "") -> OffboardStateChanged | None:
        """Outcome of the OFFBOARD DO_SET_MODE (heartbeat-confirmed or refused)."""
        return self.fire(T.CONFIRMED if ok else T.REJECTED, now, reason)

    def on_heartbeat_offboard(self, in_offboard: bool, now: float, mode_name: str = "") -> (
            OffboardStateChanged | None):
        """Heartbeat mode: leaving OFFBOARD while ACTIVE -> EXITED."""
        if in_offboard:
            return None
        return self.fire(T.MODE_LEFT, now, f"vehicle left OFFBOARD (now {mode_name or 'other'})")

    def on_link_lost(self, now: float) -> OffboardStateChanged | None:
        """Link to the autopilot lost."""
        return self.fire(T.LINK_LOST, now, "link lost")

    def stop(self, now: float, reason: str = "stopped") -> OffboardStateChanged | None:
        """Companion ends the session."""
        return self.fire(T.STOP, now, reason)
