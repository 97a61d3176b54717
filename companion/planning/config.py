"""Vehicle configuration files (TOML) for the CLI.

Example `vehicle.toml` (every key optional; defaults are PX4's SIH quadrotor)::

    [vehicle]
    mass_kg = 1.0
    inertia_kg_m2 = [0.025, 0.025, 0.030]   # diagonal, or a 3x3 matrix
    hover_thrust = 0.5                      # MPC_THR_HOVER (estimated online in attitude mode)
    drag_n_per_m_s = 1.0                    # linear drag, world frame

    [limits]
    max_acc_m_s2 = 5.0
    max_tilt_deg = 35.0
    max_body_rate_rad_s = 3.0
    rover_max_speed_m_s = 2.7               # rover: plan below the vehicle's top speed
    corridor_m = 1.0                        # path within 1 m of the legs (0: no corridor)

    [tracking]                              # attitude/rates-mode controller (TrackingGains)
    kp_xy = 14.0                            # defaults suit a wired or UDP link (< 50 ms);
    kd_xy = 7.1                             # over a link with ~100 ms latency use
    ki_xy = 3.0                             # kp_xy 6, kd_xy 4.5, ki_xy 1, k_roll 6.5
    k_roll = 10.0                           # attitude gains of rates mode [1/s]

    [onboard]                               # the onboard module's law (fly/serve --onboard):
    ki_xy = 18.0                            # [tracking]'s gains with these over them
    disturbance_bandwidth_rad_s = 0.0       # its wind observer (0: none; 1.5 for wind)
    velocity_correction_rad_s = 4.0         # its velocity correction (0: none)

    [px4]                                   # PX4 parameters the mission planner uses: these
    MPC_XY_CRUISE = 8.0                     # win over the values read from the vehicle at
    NAV_ACC_RAD = 1.0                       # connect (names: companion.mission.px4_params)
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from companion.control import AttitudeGains, TrackingConfig, TrackingGains
from companion.control.estimation import DisturbanceConfig
from companion.flatness import MultirotorParams
from companion.mavlink.velocity_correction import VELOCITY_CORRECTION_RAD_S
from companion.planning.schedule import VehicleLimits
from companion.planning.vehicle_params import check_overrides

_VEHICLE_KEYS = {"mass_kg", "inertia_kg_m2", "hover_thrust", "drag_n_per_m_s"}
_LIMIT_KEYS = {
    "max_acc_m_s2", "max_tilt_deg", "max_body_rate_rad_s", "rover_max_speed_m_s", "corridor_m",
}
_GAIN_KEYS = {f.name for f in fields(TrackingGains)}
_ATT_KEYS = {"k_roll", "k_pitch", "k_yaw"}
_SECTIONS = {"vehicle": _VEHICLE_KEYS, "limits": _LIMIT_KEYS, "tracking": _GAIN_KEYS | _ATT_KEYS,
             "onboard": _GAIN_KEYS | {"disturbance_bandwidth_rad_s", "velocity_correction_rad_s"},
             "px4": set()}  # [px4]: checked by check_overrides (PX4 parameter names)

#: The onboard law's settings that differ from the streamed law's (`[onboard]` overrides them;
#: its other keys are TrackingGains'). Measured on real PX4 (SIH), figure-8 at 6 m/s and at
#: 8 m/s (scale 2), at several start times (BENCHMARKS.md, "Onboard module", session 25):
#: - (it was measured with the streamed law's kp_xy 20 / kd_xy 8.5 of then; since session 31
#:   both fly 14 / 7.1, the module not re-measured: the link's delay had made 20 / 8.5 the
#:   streamed loop's stability limit, and the module has no link in its loop)
#: - `ki_xy` 18, not 3. The module reads PX4's estimate with no link in its loop, and its
#:   horizontal integrator can be faster. PX4's velocity estimate disagrees with the rate of its
#:   position estimate by 0.1-0.4 m/s for seconds in the SIH; the position and velocity terms
#:   then settle on a position offset that only the integrator removes. 0.081-0.092 m against
#:   0.086-0.126 m at 6 m/s, 0.095-0.189 m against 0.108-0.44 m at 8 m/s.
#: - `disturbance_bandwidth_rad_s` 0: no disturbance observer. The module's observer models the
#:   thrust with the uploaded hover thrust and drag (the streamed law learns both online), and
#:   at speed it chases the model's error: 0.127-0.129 m with it against 0.081 m without at
#:   6 m/s, 0.19-0.235 m against 0.095-0.11 m at 8 m/s. In the mock's steady wind it helps
#:   (median error 0.024 m against 0.069 m): set it to 1.5 (the streamed law's) for wind.
#: - `velocity_correction_rad_s` 4, the streamed law's (`VelocityCorrection`; the module runs
#:   the same step, generated as C): what the law gets is PX4's horizontal velocity corrected to
#:   agree with how PX4's position moves (0: PX4's velocity as reported).
ONBOARD_DEFAULTS: dict[str, float] = {"ki_xy": 18.0,
                                      "disturbance_bandwidth_rad_s": 0.0,
                                      "velocity_correction_rad_s": VELOCITY_CORRECTION_RAD_S}
_ONBOARD_KEYS = _GAIN_KEYS | {"disturbance_bandwidth_rad_s", "velocity_correction_rad_s"}


def onboard_config(cfg: TrackingConfig, overrides: dict[str, float] | None = None
                   ) -> TrackingConfig:
    """The onboard law's configuration: `cfg` with ONBOARD_DEFAULTS, then `overrides` (keys of
    TrackingGains, and `disturbance_bandwidth_rad_s` [rad/s], 0: no observer), over it (the
    velocity correction is not the controller's: `onboard_velocity_correction`)."""
    o = {**ONBOARD_DEFAULTS, **(overrides or {})}
    unknown = set(o) - _ONBOARD_KEYS
    if unknown:
        raise ValueError(f"onboard settings: unknown {sorted(unknown)}")
    bw = o.pop("disturbance_bandwidth_rad_s")
    o.pop("velocity_correction_rad_s")
    dist = (replace(cfg.disturbance_config or DisturbanceConfig(), bandwidth_rad_s=bw)
            if bw > 0.0 else cfg.disturbance_config)
    return replace(cfg, gains=replace(cfg.gains, **o), estimate_disturbance=bw > 0.0,
                   disturbance_config=dist)


def onboard_velocity_correction(overrides: dict[str, float] | None = None) -> float:
    """The onboard module's velocity correction frequency [rad/s] (0: none): ONBOARD_DEFAULTS',
    or `overrides`' `velocity_correction_rad_s`."""
    return float({**ONBOARD_DEFAULTS, **(overrides or {})}["velocity_correction_rad_s"])


@dataclass(frozen=True)
class VehicleFile:
    """What a vehicle TOML file configures: flatness parameters, planning limits and the
    attitude/rates-mode controller gains."""

    params: MultirotorParams = field(
        default_factory=lambda: MultirotorParams(
            mass=1.0, inertia=(0.025, 0.025, 0.030), hover_thrust=0.5, drag=1.0
        )
    )
    limits: VehicleLimits = field(default_factory=VehicleLimits)
    gains: TrackingGains = field(default_factory=TrackingGains)
    attitude_gains: AttitudeGains = field(default_factory=AttitudeGains)
    px4_overrides: dict[str, float] = field(default_factory=dict)
    """``[px4]``: PX4 parameter values that win over those read from the vehicle."""
    onboard_overrides: dict[str, float] = field(default_factory=dict)
    """``[onboard]``: the onboard law's settings over ONBOARD_DEFAULTS (`onboard_config`)."""

    def tracking_config(self, max_tilt_rad: float) -> TrackingConfig:
        """The controller configuration for attitude/rates mode (tilt limit [rad])."""
        return TrackingConfig(params=self.params, gains=self.gains,
                              attitude_gains=self.attitude_gains, max_tilt_rad=max_tilt_rad)

    def onboard_tracking_config(self, max_tilt_rad: float) -> TrackingConfig:
        """`tracking_config` as the onboard law has it (`onboard_config`)."""
        return onboard_config(self.tracking_config(max_tilt_rad), self.onboard_overrides)


def _number(table: dict[str, Any], key: str, where: str, default: float) -> float:
    v = table.get(key, default)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ValueError(f"{where}: {key} must be a finite number, got {v!r}")
    return float(v)


def load_vehicle_file(path: str | Path) -> VehicleFile:
    """Read a vehicle TOML file; ValueError naming the file and key on any problem."""
    p = Path(path)
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ValueError(f"{p}: vehicle file not found") from None
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{p}: not valid TOML: {exc}") from None
    unknown = set(data) - set(_SECTIONS)
    if unknown:
        names = " and ".join(f"[{n}]" for n in _SECTIONS)
        raise ValueError(f"{p}: unknown section(s) {sorted(unknown)}; use {names}")
    veh = data.get("vehicle", {})
    lim = data.get("limits", {})
    trk = data.get("tracking", {})
    for name, keys in _SECTIONS.items():
        table = data.get(name, {})
        if not isinstance(table, dict):
            raise ValueError(f"{p}: [{name}] must be a table")
        extra = set(table) - keys
        if extra and name != "px4":
            raise ValueError(f"{p}: [{name}] unknown key(s) {sorted(extra)}; known: {sorted(keys)}")
    where = f"{p} [vehicle]"
    inertia = veh.get("inertia_kg_m2", [0.025, 0.025, 0.030])
    mass = _number(veh, "mass_kg", where, 1.0)  # these name the file themselves
    hover = _number(veh, "hover_thrust", where, 0.5)
    drag = _number(veh, "drag_n_per_m_s", where, 1.0)
    try:
        params = MultirotorParams(mass=mass, inertia=inertia, hover_thrust=hover, drag=drag)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{where}: {exc}") from None
    where = f"{p} [limits]"
    dflt = VehicleLimits()
    limits = VehicleLimits(
        max_acc_m_s2=_number(lim, "max_acc_m_s2", where, dflt.max_acc_m_s2),
        max_tilt_rad=math.radians(
            _number(lim, "max_tilt_deg", where, math.degrees(dflt.max_tilt_rad))
        ),
        max_body_rate_rad_s=_number(lim, "max_body_rate_rad_s", where, dflt.max_body_rate_rad_s),
        corridor_m=_number(lim, "corridor_m", where, dflt.corridor_m or 0.0) or None,
        rover_max_speed_m_s=(
            None if "rover_max_speed_m_s" not in lim
            else _number(lim, "rover_max_speed_m_s", where, 0.0)
        ),
    )
    if not (limits.max_acc_m_s2 > 0 and 0 < limits.max_tilt_rad < math.radians(80.0)):
        raise ValueError(f"{where}: need max_acc_m_s2 > 0 and 0 < max_tilt_deg < 80")
    if limits.rover_max_speed_m_s is not None and not limits.rover_max_speed_m_s > 0:
        raise ValueError(f"{where}: need rover_max_speed_m_s > 0")
    where = f"{p} [tracking]"
    base_g, base_a = TrackingGains(), AttitudeGains()
    gains = replace(base_g, **{k: _number(trk, k, where, getattr(base_g, k))
                               for k in _GAIN_KEYS if k in trk})
    att = replace(base_a, k_roll=_number(trk, "k_roll", where, base_a.k_roll),
                  k_pitch=_number(trk, "k_pitch", where, base_a.k_pitch),
                  k_yaw=_number(trk, "k_yaw", where, base_a.k_yaw))
    if (any(getattr(gains, k) < 0 for k in _GAIN_KEYS)
            or any(getattr(att, k) <= 0 for k in _ATT_KEYS)):
        raise ValueError(f"{where}: gains must be >= 0 (attitude gains > 0)")
    where = f"{p} [onboard]"
    onb = data.get("onboard", {})
    onboard = {k: _number(onb, k, where, 0.0) for k in _ONBOARD_KEYS if k in onb}
    if any(v < 0 for v in onboard.values()):
        raise ValueError(f"{where}: gains must be >= 0")
    px4 = check_overrides(data.get("px4", {}), f"{p} [px4]")
    return VehicleFile(params=params, limits=limits, gains=gains, attitude_gains=att,
                       px4_overrides=px4, onboard_overrides=onboard)
