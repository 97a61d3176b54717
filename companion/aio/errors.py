"""Exceptions of the asyncio façade; each carries what a pilot needs to understand it.

``MissionError`` here is ``companion.mission.MissionError`` (re-exported): the base of
:class:`MissionTransferError`, so ``except MissionError`` also catches a failed transfer."""

from __future__ import annotations

from companion.mavlink import MissionResult, result_name
from companion.mission import MissionError


class VehicleError(Exception):
    """Base class of vehicle failures."""


class ConnectTimeoutError(VehicleError):
    """No autopilot HEARTBEAT within the connect timeout."""


class CommandError(VehicleError):
    """A COMMAND_LONG failed. ``result`` is the MAV_RESULT (None: no acknowledgement)."""

    def __init__(self, command: int, result: int | None, reason: str, what: str = "") -> None:
        self.command = command
        self.result = result
        self.reason = reason
        name = what or f"command {command}"
        super().__init__(f"{name} failed: {result_name(result)} ({reason})")


class ModeChangeError(CommandError):
    """A flight mode change was refused or not confirmed by the HEARTBEAT."""


class OffboardError(VehicleError):
    """OFFBOARD could not be entered (result: MAV_RESULT of the refusal, if any)."""

    def __init__(self, message: str, result: int | None = None) -> None:
        self.result = result
        super().__init__(message)


class OffboardExitedError(OffboardError):
    """The vehicle left OFFBOARD (pilot takeover, failsafe): streaming stopped, not re-entered.

    mode: the new flight mode's name; failsafe: PX4 reported a failsafe (HEARTBEAT
    system_status MAV_STATE_CRITICAL) when it left OFFBOARD.
    """

    def __init__(self, message: str, mode: str, failsafe: bool = False) -> None:
        self.mode = mode
        self.failsafe = failsafe
        super().__init__(message)


class LinkLostError(VehicleError):
    """The link to the autopilot was lost during a flight (streaming stopped)."""

    def __init__(self, message: str, regained: bool) -> None:
        self.regained = regained
        super().__init__(message)


class TelemetryStaleError(VehicleError):
    """Position telemetry stopped arriving; the vehicle was told to hold."""


class SetpointSourceError(VehicleError):
    """The setpoint source produced an invalid setpoint; the vehicle was told to hold."""


class MissionTransferError(VehicleError, MissionError):
    """A mission upload / download / clear failed: both a :class:`VehicleError` and a
    ``companion.mission.MissionError`` (the one mission error hierarchy). ``operation``
    (``"upload"``, ``"download"``, ``"clear"``), ``result`` (:class:`MissionResult`) and
    ``mav_result`` (the MAV_MISSION_RESULT of a refusal, None otherwise) carry the parts."""

    def __init__(self, operation: str, result: MissionResult, mav_result: int | None,
                 detail: str) -> None:
        self.operation = operation
        self.result = result
        self.mav_result = mav_result
        self.transfer_detail = detail
        MissionError.__init__(self, "", f"mission {operation} failed: {result.value} ({detail})")

    def __reduce__(self) -> tuple[type[MissionTransferError],  # type: ignore[override]
                                  tuple[str, MissionResult, int | None, str]]:
        return (MissionTransferError,
                (self.operation, self.result, self.mav_result, self.transfer_detail))


class ParamReadError(VehicleError):
    """Parameters did not come back (or came back with an unexpected type). ``values``: those
    that did; ``missing`` / ``wrong_type``: the others, by name."""

    def __init__(self, values: dict[str, float], missing: tuple[str, ...],
                 wrong_type: dict[str, str], detail: str) -> None:
        self.values = values
        self.missing = missing
        self.wrong_type = wrong_type
        super().__init__(f"parameter read failed: {detail}")
