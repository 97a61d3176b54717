"""The setpoints the tracking law produces: attitude + thrust, rates + thrust, position/velocity."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from companion.control.so3 import quat_to_dcm, yaw_of_dcm
from companion.control.state import StateEstimate
from companion.flatness.reference import Reference

FloatArray = npt.NDArray[np.float64]

_NAN3 = np.full(3, math.nan)


@dataclass(frozen=True)
class AttitudeCommand:
    """SET_ATTITUDE_TARGET with attitude (type_mask 3): q + normalised thrust + yaw-rate ff.

    q_wxyz: unit quaternion body FRD -> NED, w >= 0. thrust_norm: 0..1, no hover scaling.
    yaw_rate_ff: yaw rate feed-forward [rad/s]. fallback/reason: a hover fallback was produced.
    saturated: the tilt/thrust limits were active.
    """

    q_wxyz: FloatArray
    thrust_norm: float
    yaw_rate_ff: float
    fallback: bool = False
    reason: str = ""
    saturated: bool = False


@dataclass(frozen=True)
class RateCommand:
    """SET_ATTITUDE_TARGET with attitude ignored (type_mask 128): body rates + thrust.

    omega_frd: body rates [rad/s]. thrust_norm: 0..1, no hover scaling.
    """

    omega_frd: FloatArray
    thrust_norm: float
    fallback: bool = False
    reason: str = ""
    saturated: bool = False


@dataclass(frozen=True)
class PositionCommand:
    """SET_POSITION_TARGET_LOCAL_NED: NaN components mean "not given" (ignore bit set).

    pos_ned [m], vel_ned [m/s], acc_ned [m/s^2] world NED (3,); yaw [rad]; yaw_rate [rad/s].
    """

    pos_ned: FloatArray = field(default_factory=lambda: _NAN3.copy())
    vel_ned: FloatArray = field(default_factory=lambda: _NAN3.copy())
    acc_ned: FloatArray = field(default_factory=lambda: _NAN3.copy())
    yaw: float = math.nan
    yaw_rate: float = math.nan
    fallback: bool = False
    reason: str = ""


def position_command(
    ref: Reference, feedforward: bool = True, hold: StateEstimate | None = None,
    drag_per_kg: float = 0.0,
) -> PositionCommand:
    """`position` mode: the reference as a PX4 position setpoint (PX4 closes the loop).

    feedforward False sends position + yaw only (the naive baseline); True adds velocity,
    acceleration and the yaw rate. `drag_per_kg` = D / m [1/s] (linear world-frame drag,
    docs/theory/multirotor.md)
    adds the acceleration that cancels the drag at the reference velocity, D v / m, to the
    acceleration feed-forward: PX4 turns that feed-forward into thrust without a drag model, so
    without it its velocity integral has to carry the drag (6 m/s^2 at 6 m/s on SIH) and the
    vehicle lags. A non-finite reference gives a flagged hold at `hold`'s position and heading,
    or raises ValueError when no `hold` estimate is given.
    """
    if not ref.is_finite():
        if hold is not None and hold.is_finite():
            return PositionCommand(
                pos_ned=hold.pos_ned.copy(),
                yaw=yaw_of_dcm(quat_to_dcm(hold.q_wxyz)),
                fallback=True,
                reason="reference not finite",
            )
        raise ValueError("reference is not finite; refusing to build a position setpoint")
    if feedforward:
        acc = ref.acc_ned + drag_per_kg * ref.vel_ned if drag_per_kg else ref.acc_ned.copy()
        return PositionCommand(ref.pos_ned.copy(), ref.vel_ned.copy(), acc, ref.yaw, ref.yaw_rate)
    return PositionCommand(pos_ned=ref.pos_ned.copy(), yaw=ref.yaw)

