"""How a replay flies: `ReplayConfig` (vehicle, setpoint mode and rate, the mock's physics,
wind and link perturbations) and the constants of the replay's flight."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

from companion.flatness import MultirotorParams
from companion.flight import policy
from companion.planning.schedule import VehicleLimits

Mode = Literal["position", "attitude", "rates"]

#: Offboard priming: setpoints streamed before OFFBOARD is requested [s].
PRIME_S = 0.5
#: Extra time after the schedule before handing over to PX4's landing [s].
SETTLE_S = 1.0
#: Simulated time a replay spends outside the schedule (waiting for the vehicle, priming,
#: switching to OFFBOARD, the final descent and disarm), for progress reporting only [s].
EXPECTED_OVERHEAD_S = 8.0
#: The companion's view of the default mock quadrotor (PX4 SIH: 1 kg, 4 x 5 N, drag 1 N/(m/s)).
DEFAULT_QUAD = MultirotorParams(
    mass=1.0, inertia=(0.025, 0.025, 0.030), hover_thrust=0.5, drag=1.0
)
#: Simulated t = 0 on the tlog's UNIX clock: 2026-01-01T00:00:00Z, for deterministic timestamps.
TLOG_EPOCH_S = 1_767_225_600.0


@dataclass(frozen=True)
class ReplayConfig:
    """How to replay: vehicle kind, setpoint mode and rate [Hz], mock physics rate [Hz],
    constant wind speed [m/s] blowing from `wind_from_deg` (compass, default 135: from the
    south-east, air moving toward the north-west), RNG seed, and whether to also fly the
    mission in the mock's own AUTO.MISSION for comparison.

    Perturbations (Monte-Carlo campaigns): `params` is the companion's belief about the vehicle
    (e.g. a wrong hover thrust), `mock_params` the mock's truth (SIH_MASS, SIH_KDV, SIM_*...);
    `latency_s`/`jitter_s` delay the telemetry (mock -> companion), `loss_pct` drops datagrams
    in both directions; `start_offset_ne_m` puts the vehicle that far (north, east) [m] from
    the mission's planned home (the companion plans from where it stands, like `fly`).

    `onboard`: the onboard module inside the mock flies the plan (`companion.replay.onboard`,
    as `fly --onboard` on PX4): the companion uploads it and streams no setpoint; a quad in
    attitude mode only, PX4's own landing after the plan (its final descent ends
    HANDOVER_HEIGHT_M up). `onboard_law`: the onboard law's settings over its defaults
    (`[onboard]` of a vehicle file: TrackingGains keys, `disturbance_bandwidth_rad_s`,
    `velocity_correction_rad_s`)."""

    vehicle: Literal["quad", "rover"] = "quad"
    mode: Mode = "attitude"
    rate_hz: float = 100.0
    physics_hz: float = 250.0
    wind_m_s: float = 0.0
    seed: int = 0
    compare_px4_mission: bool = False
    params: MultirotorParams = DEFAULT_QUAD
    limits: VehicleLimits = field(default_factory=VehicleLimits)
    mock_params: tuple[tuple[str, float], ...] = ()
    timeout_margin_s: float = 120.0
    wind_from_deg: float = 135.0
    latency_s: float = 0.0
    jitter_s: float = 0.0
    onboard_law: tuple[tuple[str, float], ...] = ()
    loss_pct: float = 0.0
    start_offset_ne_m: tuple[float, float] = (0.0, 0.0)
    onboard: bool = False

    def __post_init__(self) -> None:
        if self.vehicle not in ("quad", "rover"):
            raise ValueError(f"vehicle must be 'quad' or 'rover', got {self.vehicle!r}")
        if self.mode not in ("position", "attitude", "rates"):
            raise ValueError(f"mode must be position, attitude or rates, got {self.mode!r}")
        if not 20.0 <= self.rate_hz <= 500.0:
            raise ValueError(f"setpoint rate must be 20..500 Hz, got {self.rate_hz}")
        if not (math.isfinite(self.wind_m_s) and self.wind_m_s >= 0.0):
            raise ValueError(f"wind speed must be >= 0 m/s, got {self.wind_m_s}")
        if not math.isfinite(self.wind_from_deg):
            raise ValueError(f"wind direction must be finite, got {self.wind_from_deg}")
        for name in ("latency_s", "jitter_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and 0.0 <= v <= 5.0):
                raise ValueError(f"{name} must be 0..5 s, got {v}")
        if not (math.isfinite(self.loss_pct) and 0.0 <= self.loss_pct <= 100.0):
            raise ValueError(f"packet loss must be 0..100 %, got {self.loss_pct}")
        if not all(math.isfinite(v) and abs(v) <= 1000.0 for v in self.start_offset_ne_m):
            raise ValueError(f"start offset must be within 1 km, got {self.start_offset_ne_m}")
        if self.onboard and (self.vehicle != "quad" or self.mode != "attitude"):
            raise ValueError("the onboard module flies a quad in attitude mode only")
        from sitl_mock.params import PARAMS

        for name, value in self.mock_params:
            if name not in PARAMS:
                raise ValueError(f"unknown mock parameter {name!r}")
            if not math.isfinite(value):
                raise ValueError(f"mock parameter {name} must be finite, got {value}")

    def wind_ned(self) -> tuple[float, float, float]:
        """Steady wind velocity [m/s NED] (air moves toward wind_from_deg + 180)."""
        if self.wind_from_deg == 135.0:  # the replay's historical default, bit for bit
            w = self.wind_m_s / math.sqrt(2.0)
            return (w, -w, 0.0)
        to = math.radians(self.wind_from_deg + 180.0)
        return (self.wind_m_s * math.cos(to), self.wind_m_s * math.sin(to), 0.0)


def planning_limits(config: ReplayConfig) -> VehicleLimits:
    """`config.limits` (a rover's speed, acceleration and steering come from its PX4
    parameters, RO_SPEED_LIM and the others, read from the mock over MAVLink as `fly` reads
    them from PX4)."""
    return config.limits


def self_lands(config: ReplayConfig, final_action: str) -> bool:
    """The companion lands the vehicle itself (`companion.flight.self_lands`; never in an
    onboard flight: the module commands PX4's landing)."""
    return not config.onboard and policy.self_lands(config.vehicle, config.mode, final_action)


def handover_height_m(config: ReplayConfig, final_action: str) -> float:
    """Where the planned final descent ends above the ground [m] (`policy.handover_height_m`;
    an onboard flight: where PX4's landing takes over, as `fly --onboard` plans it)."""
    if config.onboard:
        return policy.HANDOVER_HEIGHT_M
    return policy.handover_height_m(config.vehicle, config.mode, final_action)

