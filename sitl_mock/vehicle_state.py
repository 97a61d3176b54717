"""Vehicle state and the vehicle-model interface shared by the quadrotor and the rover.

The autopilot core calls `vehicle.step(dt, target, armed)` at a fixed physics rate (>= 250 Hz)
and reads `vehicle.state`. World frame NED about home (local origin at the home position, z = 0
on the ground), body frame FRD, SI units.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

from sitl_mock._frozen import frozen_new
from sitl_mock.setpoints import PositionTarget, Quat, Target, Vec3

EARTH_RADIUS_M = 6371000.0  # PX4 CONSTANTS_RADIUS_OF_EARTH
DEFAULT_HOME: tuple[float, float, float] = (47.397742, 8.545594, 488.0)  # PX4 SITL home


@dataclass(frozen=True)
class VehicleState:
    """Snapshot of the simulated vehicle.

    t_s: simulated time since creation [s]; pos_ned [m], vel_ned [m/s], acc_ned [m/s^2]
    (kinematic acceleration, world NED); q_wxyz: attitude body FRD -> NED; omega_frd: body rates
    [rad/s]; on_ground: touching the ground; landed: PX4-like land detector output;
    thrust_norm: actual collective thrust 0..1 (mean motor thrust / max); battery_remaining 0..1;
    local_position_valid: False while a position-loss fault is injected;
    home_lat_lon_alt: the projection origin. lat_deg, lon_deg, alt_amsl_m (properties): geodetic
    position (azimuthal equidistant projection about home, like PX4's map_projection).
    """

    t_s: float
    pos_ned: Vec3
    vel_ned: Vec3
    acc_ned: Vec3
    q_wxyz: Quat
    omega_frd: Vec3
    on_ground: bool
    landed: bool
    thrust_norm: float
    battery_remaining: float
    local_position_valid: bool
    home_lat_lon_alt: tuple[float, float, float] = DEFAULT_HOME

    @property
    def lat_deg(self) -> float:
        """Latitude [deg]."""
        return ned_to_geodetic(self.pos_ned, self.home_lat_lon_alt)[0]

    @property
    def lon_deg(self) -> float:
        """Longitude [deg]."""
        return ned_to_geodetic(self.pos_ned, self.home_lat_lon_alt)[1]

    @property
    def alt_amsl_m(self) -> float:
        """Altitude above mean sea level [m] (home altitude minus down)."""
        return self.home_lat_lon_alt[2] - self.pos_ned[2]

    @property
    def lat_lon_alt(self) -> tuple[float, float, float]:
        """(lat deg, lon deg, alt AMSL m) in one projection."""
        return ned_to_geodetic(self.pos_ned, self.home_lat_lon_alt)

    @property
    def yaw(self) -> float:
        """Heading [rad] (0 = north, positive clockwise seen from above)."""
        w, x, y, z = self.q_wxyz
        return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def make_state(
    t_s: float,
    pos_ned: Vec3,
    vel_ned: Vec3,
    acc_ned: Vec3,
    q_wxyz: Quat,
    omega_frd: Vec3,
    on_ground: bool,
    landed: bool,
    thrust_norm: float,
    battery_remaining: float,
    local_position_valid: bool,
    home_lat_lon_alt: tuple[float, float, float],
) -> VehicleState:
    """Build a VehicleState ~2x faster than its frozen-dataclass __init__ (used every step)."""
    return frozen_new(
        VehicleState,
        {
            "t_s": t_s,
            "pos_ned": pos_ned,
            "vel_ned": vel_ned,
            "acc_ned": acc_ned,
            "q_wxyz": q_wxyz,
            "omega_frd": omega_frd,
            "on_ground": on_ground,
            "landed": landed,
            "thrust_norm": thrust_norm,
            "battery_remaining": battery_remaining,
            "local_position_valid": local_position_valid,
            "home_lat_lon_alt": home_lat_lon_alt,
        },
    )


AttitudeTargetReport = tuple[Quat, Vec3, float]


class Vehicle(Protocol):
    """What the autopilot core needs from a vehicle model."""

    kind: str

    def step(self, dt: float, target: Target, armed: bool) -> None:
        """Run the controller for `target` and integrate the physics by `dt` seconds."""
        ...

    @property
    def state(self) -> VehicleState:
        """Current state snapshot (with sensor noise if enabled)."""
        ...

    @property
    def true_state(self) -> VehicleState:
        """The true motion as a snapshot (`state` carries the estimator's errors, when modelled;
        the autopilot reports this one as HIL_STATE_QUATERNION, as PX4 SITL its simulator's)."""
        ...

    @property
    def landed(self) -> bool:
        """`state.landed` without building a snapshot (the commander reads it at 200 Hz)."""
        ...

    @property
    def local_position_valid(self) -> bool:
        """`state.local_position_valid` without building a snapshot."""
        ...

    @property
    def battery_remaining(self) -> float:
        """`state.battery_remaining` (0..1) without building a snapshot."""
        ...

    @property
    def attitude(self) -> tuple[Quat, Vec3]:
        """(`state.q_wxyz`, body rates as the autopilot measures them [rad/s FRD]) without
        building a snapshot (100 Hz ATTITUDE): the quadrotor's gyro after PX4's filter while its
        rate loop runs (`state.omega_frd` holds the true rates)."""
        ...

    @property
    def last_attitude_target(self) -> AttitudeTargetReport:
        """(q_wxyz, body_rates_frd, thrust_norm) last commanded by the controller."""
        ...

    @property
    def last_position_target(self) -> PositionTarget | None:
        """Last position target tracked (None if not in a position-controlled mode)."""
        ...

    def reset_integrators(self) -> None:
        """Reset controller integrators and holds (call on mode switches)."""
        ...

    def set_wind(self, vel_ned: Vec3) -> None:
        """Steady wind [m/s NED] (air moves with this velocity)."""
        ...

    def set_local_position_valid(self, valid: bool) -> None:
        """Fault injection: mark the local position estimate (in)valid."""
        ...

    def set_battery_remaining(self, fraction: float) -> None:
        """Fault injection: force the battery state of charge (0..1); it keeps draining."""
        ...


def ned_to_geodetic(
    pos_ned: Vec3, home_lat_lon_alt: tuple[float, float, float]
) -> tuple[float, float, float]:
    """Local NED [m] -> (lat deg, lon deg, alt AMSL m), azimuthal equidistant about home."""
    lat0 = math.radians(home_lat_lon_alt[0])
    lon0 = math.radians(home_lat_lon_alt[1])
    xr = pos_ned[0] / EARTH_RADIUS_M
    yr = pos_ned[1] / EARTH_RADIUS_M
    c = math.sqrt(xr * xr + yr * yr)
    if c > 0.0:
        sc, cc = math.sin(c), math.cos(c)
        s0, c0 = math.sin(lat0), math.cos(lat0)
        lat = math.asin(cc * s0 + xr * sc * c0 / c)
        lon = lon0 + math.atan2(yr * sc, c * c0 * cc - xr * s0 * sc)
    else:
        lat, lon = lat0, lon0
    return math.degrees(lat), math.degrees(lon), home_lat_lon_alt[2] - pos_ned[2]
