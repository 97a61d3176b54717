"""The autopilot's status as one frozen value: what the telemetry builders read (PX4's uORB idea).

The core builds a `StatusSnapshot` when a message is due (`Autopilot.status()`); the builders in
`telemetry.py` turn it into messages and never see the autopilot itself.
"""

from __future__ import annotations

from dataclasses import dataclass

from sitl_mock.setpoints import PositionTarget, Quat, Vec3
from sitl_mock.vehicle_state import AttitudeTargetReport, VehicleState


@dataclass(frozen=True)
class StatusSnapshot:
    """Everything the periodic messages say, at one instant.

    time_*: time since boot (ms wrapped to uint32, us, ns); mav_type, base_mode, custom_mode,
    system_status: the HEARTBEAT fields; state: the vehicle state snapshot; attitude:
    (q_wxyz body FRD -> NED, measured body rates [rad/s FRD]); last_attitude_target,
    last_position_target: what the vehicle's controller last tracked; home: (lat deg, lon deg,
    alt AMSL m); battery_remaining 0..1, battery_voltage_mv [mV]; errors_comm: inbound frames
    dropped; landed_state: MAV_LANDED_STATE; mission_*: the MISSION_CURRENT fields.
    """

    time_boot_ms: int
    time_usec: int
    time_ns: int
    mav_type: int
    base_mode: int
    custom_mode: int
    system_status: int
    state: VehicleState
    attitude: tuple[Quat, Vec3]
    last_attitude_target: AttitudeTargetReport | None
    last_position_target: PositionTarget | None
    home: tuple[float, float, float]
    home_set: bool
    estimator_ready: bool
    local_position_valid: bool
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
