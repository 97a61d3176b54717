"""The flight, sans-IO: the one flight sequence (prime, OFFBOARD, arm, fly, touchdown or
handover, disarm), the end-of-flight policy and the typed flight report."""

from .policy import (
    HANDOVER_HEIGHT_M,
    final_mode,
    handover_height_m,
    handover_mode,
    lands_at_end,
    plan_touchdown,
    self_lands,
)
from .sequence import (
    EndPolicy,
    Failure,
    Finished,
    FlightSequence,
    Phase,
    PhaseChanged,
    SendCommand,
    SequenceAction,
    SequenceConfig,
    Stream,
    VehicleView,
)

__all__ = [
    "HANDOVER_HEIGHT_M", "EndPolicy", "Failure", "Finished", "FlightSequence", "Phase",
    "PhaseChanged", "SendCommand", "SequenceAction", "SequenceConfig", "Stream", "VehicleView",
    "final_mode", "handover_height_m", "handover_mode", "lands_at_end", "plan_touchdown",
    "self_lands",
]
