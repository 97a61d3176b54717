"""Vehicle configuration files (TOML) for the CLI.

Example `vehicle.toml` (every key optional; defaults are PX4's SIH quadrotor)::

    [vehicle]
    mass_kg = 1.0
    inertia_kg_m2 = [0.025, 0.025, 0.030]   # diagonal, or a 3x3 matrix
    hover_thrust = 0.5                      # MPC_THR_HOVER (estimated online in attitude mode)
    drag_n_per_m_s = 1.0                    # linear drag, world frame

    [limits]
    max_acc_m_s2 = 3.0
    max_tilt_deg = 35.0
    max_body_rate_rad_s = 3.0
    rover_max_speed_m_s = 2.7               # rover: plan below the vehicle's top speed
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from companion.flatness import MultirotorParams
from companion.schedule import VehicleLimits

_VEHICLE_KEYS = {"mass_kg", "inertia_kg_m2", "hover_thrust", "drag_n_per_m_s"}
_LIMIT_KEYS = {"max_acc_m_s2", "max_tilt_deg", "max_body_rate_rad_s", "rover_max_speed_m_s"}


@dataclass(frozen=True)
class VehicleFile:
    """What a vehicle TOML file configures: flatness parameters and planning limits."""

    params: MultirotorParams = field(
        default_factory=lambda: MultirotorParams(
            mass=1.0, inertia=(0.025, 0.025, 0.030), hover_thrust=0.5, drag=1.0
        )
    )
    limits: VehicleLimits = field(default_factory=VehicleLimits)


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
    unknown = set(data) - {"vehicle", "limits"}
    if unknown:
        raise ValueError(f"{p}: unknown section(s) {sorted(unknown)}; use [vehicle] and [limits]")
    veh = data.get("vehicle", {})
    lim = data.get("limits", {})
    for name, table, keys in (("vehicle", veh, _VEHICLE_KEYS), ("limits", lim, _LIMIT_KEYS)):
        if not isinstance(table, dict):
            raise ValueError(f"{p}: [{name}] must be a table")
        extra = set(table) - keys
        if extra:
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
    limits = VehicleLimits(
        max_acc_m_s2=_number(lim, "max_acc_m_s2", where, 3.0),
        max_tilt_rad=math.radians(_number(lim, "max_tilt_deg", where, 35.0)),
        max_body_rate_rad_s=_number(lim, "max_body_rate_rad_s", where, 3.0),
        rover_max_speed_m_s=(
            None if "rover_max_speed_m_s" not in lim
            else _number(lim, "rover_max_speed_m_s", where, 0.0)
        ),
    )
    if not (limits.max_acc_m_s2 > 0 and 0 < limits.max_tilt_rad < math.radians(80.0)):
        raise ValueError(f"{where}: need max_acc_m_s2 > 0 and 0 < max_tilt_deg < 80")
    if limits.rover_max_speed_m_s is not None and not limits.rover_max_speed_m_s > 0:
        raise ValueError(f"{where}: need rover_max_speed_m_s > 0")
    return VehicleFile(params=params, limits=limits)
