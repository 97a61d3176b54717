"""The end of a flight, decided once: when the companion lands the vehicle itself (a touchdown
after the plan) and when it hands over to a PX4 mode (Hold, Land, RTL) per the mission's final
action. Used by replay, `fly`, `Vehicle.fly` (through :mod:`companion.flight.sequence`) and
`serve`. Pure: no I/O, no clock.
"""

from __future__ import annotations

from typing import Literal

from companion.flight.tracking import TOUCHDOWN_FROM_M, TOUCHDOWN_TIMEOUT_S, Touchdown
from companion.mavlink.px4_mode import FlightMode
from companion.planning.schedule import Schedule

__all__ = [
    "BLIND_S", "HANDOVER_HEIGHT_M", "ROVER_SETTLE_S", "STALL_S", "TOUCHDOWN_FROM_M",
    "TOUCHDOWN_TIMEOUT_S",
    "final_mode", "handover_height_m", "handover_mode", "lands_at_end", "plan_touchdown",
    "self_lands", "stall_s",
]

#: Height above the ground [m] where a mission's planned descent ends when PX4 lands it.
HANDOVER_HEIGHT_M = 1.0
#: A rover whose (governed) reference has ended gets this long [s] to come within the last
#: waypoint's acceptance radius before it is switched to Hold anyway (its report then names the
#: waypoint it missed); a rover whose reference has waited this long for it to make progress
#: (stuck, blocked) is switched to Hold too.
ROVER_SETTLE_S = 20.0
#: A governed reference (a rover's; a multirotor's in attitude or rates mode, slowed down for a
#: vehicle that cannot follow it) that has stood still this long [s] ends the flight with a
#: handover to the final mode: the vehicle makes no progress (stuck; wind it cannot fly into).
STALL_S = 20.0
#: A tracking law that has flown its level hover fallback (telemetry stale, missing or
#: implausible) this long [s] without a break ends the flight with a handover to the final
#: mode: PX4 flies on its own fresh estimate. The fallback is meant for a glitch of a few
#: setpoints; on real PX4 SITL at 0.7x real time a sample clock that fell behind kept it
#: there for 20 s in OFFBOARD while the vehicle sank to the ground (2026-12-01).
BLIND_S = 2.0


def stall_s(vehicle: str, mode: str) -> float | None:
    """`EndPolicy.stall_s` for a vehicle flown in `mode`: STALL_S where the companion governs
    its reference's time (a rover; a quad in attitude or rates mode), else None."""
    return STALL_S if vehicle == "rover" or mode in ("attitude", "rates") else None

Vehicle = Literal["quad", "rover"]

_FINAL_MODE = {"land": FlightMode.LAND, "rtl": FlightMode.RTL, "loiter": FlightMode.HOLD}


def lands_at_end(vehicle: str, final_action: str) -> bool:
    """A multicopter whose mission ends in a landing (``land`` or ``rtl``)."""
    return vehicle == "quad" and final_action in ("land", "rtl")


def self_lands(vehicle: str, mode: str, final_action: str) -> bool:
    """The companion lands the vehicle itself (a quad in attitude or rates mode whose mission
    ends in a landing); else PX4's LAND does the last metre."""
    return lands_at_end(vehicle, final_action) and mode in ("attitude", "rates")


def handover_height_m(vehicle: str, mode: str, final_action: str) -> float:
    """Where the planned final descent ends above the ground [m]: TOUCHDOWN_FROM_M when the
    companion touches down itself, HANDOVER_HEIGHT_M when PX4's LAND takes over."""
    return TOUCHDOWN_FROM_M if self_lands(vehicle, mode, final_action) else HANDOVER_HEIGHT_M


def plan_touchdown(schedule: Schedule, land_speed_m_s: float, t_off_s: float = 0.0) -> Touchdown:
    """The touchdown of a self-landing flight of ``schedule``: it takes over where the plan's
    last descent stops cruising (no stop just above the ground) and descends at
    ``land_speed_m_s`` (PX4's MPC_LAND_SPEED) [m/s]. ``t_off_s``: schedule time at which the
    flown reference's time 0 is [s] (the reference starts after a takeoff PX4 flew)."""
    t_td, v_td = schedule.final_descent_cruise(land_speed_m_s)
    return Touchdown(t_td - t_off_s, descent_m_s=land_speed_m_s,
                     v0_m_s=v_td)


def handover_mode(vehicle: str, final_action: str) -> FlightMode:
    """The PX4 mode a flight that does not touch down itself ends in after its plan: LAND for a
    multicopter mission ending in a landing (also ``rtl``: the plan flew back home already),
    else HOLD (a rover, a loiter ending, a test pattern flown as ``loiter``)."""
    return FlightMode.LAND if lands_at_end(vehicle, final_action) else FlightMode.HOLD


def final_mode(final_action: str) -> FlightMode:
    """The PX4 mode of a mission's final action when PX4 flies it (``serve``: the plan stops
    before a trailing land/RTL): LAND, RTL or HOLD."""
    return _FINAL_MODE.get(final_action, FlightMode.HOLD)
