"""The PX4 parameters the mission planner plans with (pure: no I/O).

At connect the companion reads these from the vehicle (``fly``, ``serve``) or from the mock
(``replay``); a vehicle TOML overrides them. Names and units are PX4's (v1.16 parameter
metadata); the defaults are PX4 v1.16's for a multicopter: its generic defaults, except where
its multicopter defaults (``rc.mc_defaults``, as on the SITL airframes) change them: NAV_ACC_RAD
2 m (generic 10 m) and RTL_RETURN_ALT 30 m (generic 60 m). A rover reads NAV_ACC_RAD and its own
RO_* / RA_* parameters instead (``ROVER_PARAM_NAMES``; defaults: PX4 main's SIH Ackermann rover).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

__all__ = [
    "ALL_PARAM_NAMES", "PLANNING_PARAM_NAMES", "ROVER_PARAM_NAMES", "Px4PlanningParams",
    "planning_param_names",
]


@dataclass(frozen=True)
class Px4PlanningParams:
    """PX4 parameters the planner uses, under their PX4 names and units (m, m/s, m/s^2, deg)."""

    MPC_XY_CRUISE: float = 5.0
    """Horizontal speed of mission legs without DO_CHANGE_SPEED [m/s]."""
    MPC_XY_VEL_MAX: float = 12.0
    """Cap on any planned horizontal speed [m/s]."""
    MPC_Z_VEL_MAX_UP: float = 3.0
    """Cap on the planned climb rate [m/s]."""
    MPC_Z_VEL_MAX_DN: float = 1.5
    """Cap on the planned descent rate [m/s]."""
    MPC_ACC_HOR_MAX: float = 5.0
    """Horizontal acceleration limit [m/s^2]."""
    MPC_ACC_UP_MAX: float = 4.0
    """Upward acceleration limit [m/s^2]."""
    MPC_ACC_DOWN_MAX: float = 3.0
    """Downward acceleration limit [m/s^2]."""
    MPC_TILTMAX_AIR: float = 45.0
    """Tilt limit in flight [deg]."""
    MPC_TKO_SPEED: float = 1.5
    """Takeoff climb rate [m/s]."""
    MPC_LAND_SPEED: float = 0.7
    """Descent rate below MPC_LAND_ALT2 when landing [m/s]."""
    MPC_LAND_ALT1: float = 10.0
    """Height above home below which a landing descent starts slowing down [m]."""
    MPC_LAND_ALT2: float = 5.0
    """Height above home below which a landing descends at MPC_LAND_SPEED [m]."""
    NAV_ACC_RAD: float = 2.0
    """Default waypoint acceptance radius [m]."""
    RTL_RETURN_ALT: float = 30.0
    """Return altitude above home of RTL [m]."""
    MIS_TAKEOFF_ALT: float = 2.5
    """Default (and minimum) takeoff height above home [m]."""
    MPC_THR_HOVER: float = 0.5
    """Hover thrust, normalised 0..1."""
    MC_ROLLRATE_MAX: float = 220.0
    """Roll rate limit [deg/s] (commanded body rates are held within it)."""
    MC_PITCHRATE_MAX: float = 220.0
    """Pitch rate limit [deg/s]."""
    MC_YAWRATE_MAX: float = 200.0
    """Yaw rate limit [deg/s]."""
    # -- a rover's (PX4's rover modules; defaults: PX4 main's SIH Ackermann rover, airframe 10045)
    RO_SPEED_LIM: float = 3.0
    """Rover speed limit [m/s]; also its mission speed without DO_CHANGE_SPEED."""
    RO_ACCEL_LIM: float = 3.0
    """Rover acceleration limit [m/s^2]."""
    RO_DECEL_LIM: float = 3.0
    """Rover deceleration limit [m/s^2]."""
    RO_JERK_LIM: float = 10.0
    """Rover jerk limit [m/s^3]."""
    RO_YAW_RATE_LIM: float = 180.0
    """Rover yaw rate limit [deg/s]."""
    RA_WHEEL_BASE: float = 0.321
    """Ackermann rover: distance from the front to the rear axle [m]."""
    RA_MAX_STR_ANG: float = 0.5236
    """Ackermann rover: largest steering angle [rad] (with RA_WHEEL_BASE: the smallest turning
    radius RA_WHEEL_BASE / tan(RA_MAX_STR_ANG))."""

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if not isinstance(v, int | float) or isinstance(v, bool) or not math.isfinite(v):
                raise ValueError(f"{f.name} must be a finite number, got {v!r}")
            if f.name in ("RTL_RETURN_ALT", "MIS_TAKEOFF_ALT", "MPC_LAND_ALT1", "MPC_LAND_ALT2"):
                if v < 0.0:
                    raise ValueError(f"{f.name} must be >= 0, got {v}")
            elif v <= 0.0:
                raise ValueError(f"{f.name} must be > 0, got {v}")
        if not 0.0 < self.MPC_TILTMAX_AIR < 90.0:
            raise ValueError(f"MPC_TILTMAX_AIR must be in (0, 90) deg, got {self.MPC_TILTMAX_AIR}")
        if not 0.0 < self.MPC_THR_HOVER < 1.0:
            raise ValueError(f"MPC_THR_HOVER must be in (0, 1), got {self.MPC_THR_HOVER}")
        if not 0.0 < self.RA_MAX_STR_ANG < math.pi / 2:
            raise ValueError(f"RA_MAX_STR_ANG must be in (0, pi/2) rad, got {self.RA_MAX_STR_ANG}")

    @property
    def rover_max_curvature_1_m(self) -> float:
        """The tightest turn an Ackermann rover can drive: tan(RA_MAX_STR_ANG) / RA_WHEEL_BASE
        [1/m] (the inverse of its smallest turning radius)."""
        return math.tan(self.RA_MAX_STR_ANG) / self.RA_WHEEL_BASE

    @classmethod
    def from_values(cls, values: Mapping[str, float]) -> Px4PlanningParams:
        """The defaults with every known name in `values` applied (other names are ignored)."""
        known = {k: float(v) for k, v in values.items() if k in ALL_PARAM_NAMES}
        return cls(**known)

    def replace(self, **changes: float) -> Px4PlanningParams:
        """A copy with `changes` applied (PX4 names)."""
        unknown = sorted(set(changes) - set(ALL_PARAM_NAMES))
        if unknown:
            raise ValueError(
                f"unknown planning parameter(s) {', '.join(unknown)}; known: "
                f"{', '.join(ALL_PARAM_NAMES)}"
            )
        return dataclasses.replace(self, **changes)

    def as_dict(self, names: Sequence[str] | None = None) -> dict[str, float]:
        """``{PX4 name: value}`` of ``names`` (default: a multicopter's,
        ``PLANNING_PARAM_NAMES``) in declaration order."""
        return {n: float(getattr(self, n)) for n in (PLANNING_PARAM_NAMES if names is None
                                                      else names)}


ALL_PARAM_NAMES: tuple[str, ...] = tuple(f.name for f in dataclasses.fields(Px4PlanningParams))
"""Every PX4 parameter name the planner knows (a vehicle file's ``[px4]`` may set any)."""
ROVER_PARAM_NAMES: tuple[str, ...] = (
    "NAV_ACC_RAD", "RO_SPEED_LIM", "RO_ACCEL_LIM", "RO_DECEL_LIM", "RO_JERK_LIM",
    "RO_YAW_RATE_LIM", "RA_WHEEL_BASE", "RA_MAX_STR_ANG",
)
"""The PX4 parameters a rover's plan reads from the vehicle."""
PLANNING_PARAM_NAMES: tuple[str, ...] = tuple(
    n for n in ALL_PARAM_NAMES if n not in ROVER_PARAM_NAMES or n == "NAV_ACC_RAD")
"""The PX4 parameter names a multicopter's plan reads from the vehicle, in a stable order."""


def planning_param_names(vehicle: str) -> tuple[str, ...]:
    """The PX4 parameters the plan of ``vehicle`` ("quad" or "rover") reads from it."""
    return ROVER_PARAM_NAMES if vehicle == "rover" else PLANNING_PARAM_NAMES
