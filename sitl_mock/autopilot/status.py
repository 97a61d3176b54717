"""The autopilot's status as one frozen value: what the telemetry builders read (PX4's uORB idea).

The core builds a `VehicleStatus` when a stream is due (at most once per telemetry tick), and a
`StatusSnapshot` (which holds one) only when a low-rate status message is due: the builders in
`telemetry.py` turn them into messages and never see the autopilot itself.
"""

from __future__ import annotations

from dataclasses import dataclass

from sitl_mock.setpoints import PositionTarget, Quat, Vec3
from sitl_mock.vehicle_state import AttitudeTargetReport, VehicleState


@dataclass(frozen=True)
class VehicleStatus:
    """The vehicle's side of the status at one instant (what the high-rate streams need).

    time_*: time since boot (ms wrapped to uint32, us, ns); state: the vehicle state snapshot;
    attitude: (q_wxyz body FRD -> NED, measured body rates [rad/s FRD]); last_attitude_target,
    last_position_target: what the vehicle's controller last tracked; home: (lat deg, lon deg,
    alt AMSL m); estimator_ready: home is set and arming possible once True;
    local_position_valid: the estimator has a local position.
    """

    time_boot_ms: int
    time_usec: int
    time_ns: int
    state: VehicleState
    attitude: tuple[Quat, Vec3]
    last_attitude_target: AttitudeTargetReport | None
    last_position_target: PositionTarget | None
    home: tuple[float, float, float]
    estimator_ready: bool
    local_position_valid: bool


@dataclass(frozen=True)
class StatusSnapshot:
    """The whole status at one instant: `vehicle` plus the commander's and the missions' side.

    mav_type, base_mode, custom_mode, system_status: the HEARTBEAT fields; prearm_ok: arming
    would be accepted in the current mode; battery_remaining 0..1, battery_voltage_mv [mV];
    errors_comm: inbound frames dropped; landed_state: MAV_LANDED_STATE; mission_*: the
    MISSION_CURRENT fields.
    """

    vehicle: VehicleStatus
    mav_type: int
    base_mode: int
    custom_mode: int
    system_status: int
    prearm_ok: bool
    battery_remaining: float
    battery_voltage_mv: int
    errors_comm: int
    landed_state: int
    mission_seq: int
    mission_total: int
    mission_state: int
    mission_mode: int
    mission_id: int
