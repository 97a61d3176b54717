"""Vehicle models: `make_vehicle` builds the quadrotor or the rover at rest at home.

The state and interface types live in `sitl_mock.vehicle_state` (the models import them from
there) and are re-exported here.
"""

from __future__ import annotations

from typing import Literal

from sitl_mock.params import ParamStore
from sitl_mock.quad import Quadrotor
from sitl_mock.rover import Rover
from sitl_mock.vehicle_state import (
    DEFAULT_HOME,
    EARTH_RADIUS_M,
    AttitudeTargetReport,
    Vehicle,
    VehicleState,
    make_state,
    ned_to_geodetic,
)

__all__ = [
    "DEFAULT_HOME",
    "EARTH_RADIUS_M",
    "AttitudeTargetReport",
    "Vehicle",
    "VehicleState",
    "make_state",
    "make_vehicle",
    "ned_to_geodetic",
]


def make_vehicle(
    kind: Literal["quad", "rover"] | str,
    params: ParamStore,
    home_lat_lon_alt: tuple[float, float, float] = DEFAULT_HOME,
    seed: int = 0,
) -> Vehicle:
    """Create the vehicle model `kind` ("quad" or "rover") at rest on the ground at home."""
    if kind == "quad":
        return Quadrotor(params, home_lat_lon_alt, seed)
    if kind == "rover":
        return Rover(params, home_lat_lon_alt, seed)
    raise ValueError(f"unknown vehicle kind {kind!r}: use 'quad' or 'rover'")
