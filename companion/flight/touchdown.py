"""How a source lands the vehicle itself at the end of a plan (`Touchdown`), with its constants.
Pure; `companion.flight.tracking` flies it."""

from __future__ import annotations

import math
from dataclasses import dataclass

#: Height above the ground [m] where a mission's planned descent ends when the companion lands
#: the vehicle itself (attitude and rates modes, :class:`Touchdown`).
TOUCHDOWN_FROM_M = 0.5
#: After this long past the plan without a landing detected, PX4's LAND is requested [s].
TOUCHDOWN_TIMEOUT_S = 15.0


@dataclass(frozen=True)
class Touchdown:
    """How a source lands the vehicle itself once its reference has ended (a plan that ends at rest
    just above the ground), instead of handing over to PX4's LAND.

    From reference time `from_s` [s] the reference descends straight down from where it was,
    starting at `v0_m_s` (the plan's own descent speed there: the touchdown may take over a
    descent that is still cruising) and changing smoothly, at most at `accel_m_s2` and
    `jerk_m_s3` (PX4's MPC_JERK_AUTO), to `descent_m_s` (PX4's MPC_LAND_SPEED) [m/s]. Ground
    contact is what PX4's land detector calls "hit ground": after the ramp-in, the vehicle is
    not descending (|vz| < `still_m_s`) while the reference is more than `gap_m` [m] below it,
    for `contact_s` [s]; `still_m_s` is PX4's own LNDMC_Z_VEL_MAX (EKF2's vertical speed jitters
    by +-0.2 m/s on the ground). Then (attitude and rates modes) the attitude goes level at the
    current yaw and the thrust ramps from its last value to zero over `ramp_s` [s], so PX4's
    land detector sees low thrust and no motion (its three stages take LNDMC_TRIG_TIME or more)
    and accepts a disarm. Throughout the touchdown the commanded tilt stays within
    `max_tilt_rad` (PX4's MPC_TILTMAX_LND, 12 deg by default): near the ground the thrust is
    low, and the air limit (45 deg) then lets a small horizontal correction tip the vehicle
    over as its feet touch (seen on real PX4 SITL: 44 deg commanded at contact, the vehicle on
    its back). Position mode only descends: PX4's own controller and land detector finish
    it."""

    from_s: float
    descent_m_s: float = 0.7
    v0_m_s: float = 0.0
    accel_m_s2: float = 1.0
    jerk_m_s3: float = 4.0
    still_m_s: float = 0.25
    gap_m: float = 0.2
    contact_s: float = 0.3
    ramp_s: float = 0.5
    max_tilt_rad: float = math.radians(12.0)

    def __post_init__(self) -> None:
        for name in ("descent_m_s", "accel_m_s2", "jerk_m_s3", "still_m_s", "gap_m", "contact_s",
                     "ramp_s", "max_tilt_rad"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0.0):
                raise ValueError(f"Touchdown.{name} must be a positive number, got {v}")
        if not math.isfinite(self.from_s):
            raise ValueError(f"Touchdown.from_s must be finite, got {self.from_s}")
        if not (math.isfinite(self.v0_m_s) and self.v0_m_s >= 0.0):
            raise ValueError(f"Touchdown.v0_m_s must be >= 0, got {self.v0_m_s}")

    def offset(self, tau: float) -> tuple[float, float, float]:
        """Distance below the start point [m], descent speed [m/s] and acceleration [m/s^2]
        `tau` [s] after `from_s`. The speed changes from `v0_m_s` to `descent_m_s` along a
        cubic smoothstep (acceleration continuous, zero at both ends, peak `accel_m_s2`), so
        the thrust command has no step where the touchdown takes over or reaches its speed."""
        v0, dv = self.v0_m_s, self.descent_m_s - self.v0_m_s
        if tau <= 0.0:
            return 0.0, v0, 0.0
        t_ramp = self.ramp_in_s
        if tau < t_ramp:
            x = tau / t_ramp
            return (v0 * tau + dv * t_ramp * (x ** 3 - 0.5 * x ** 4),
                    v0 + dv * x * x * (3.0 - 2.0 * x), dv / t_ramp * 6.0 * x * (1.0 - x))
        return v0 * t_ramp + 0.5 * dv * t_ramp + self.descent_m_s * (tau - t_ramp), \
            self.descent_m_s, 0.0

    @property
    def ramp_in_s(self) -> float:
        """Time from `from_s` until the descent reaches its speed [s]: long enough that the
        smoothstep's peak acceleration 1.5 |dv| / ramp stays within `accel_m_s2` and its jerk
        6 |dv| / ramp^2 within `jerk_m_s3`."""
        dv = abs(self.descent_m_s - self.v0_m_s)
        return max(1.5 * dv / self.accel_m_s2, math.sqrt(6.0 * dv / self.jerk_m_s3))
