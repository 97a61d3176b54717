"""Offboard setpoint values and their MAVLink message builders.

World frame NED, body frame FRD, SI units. Builders refuse NaN/inf (a "not given" component is
``None``, never NaN), unnormalised quaternions and thrust outside 0..1, so nothing invalid ever
leaves the companion. type_mask bits follow PX4.md (POSITION_TARGET_TYPEMASK /
ATTITUDE_TARGET_TYPEMASK).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from math import isfinite
from typing import Any

from pymavlink.dialects.v20 import common as mavlink2

from companion._frozen import frozen_new

from .codec import MavMessage

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]

MAV_FRAME_LOCAL_NED = 1

# SET_POSITION_TARGET_LOCAL_NED type_mask ignore bits.
IGNORE_PX, IGNORE_PY, IGNORE_PZ = 1, 2, 4
IGNORE_VX, IGNORE_VY, IGNORE_VZ = 8, 16, 32
IGNORE_AX, IGNORE_AY, IGNORE_AZ = 64, 128, 256
FORCE_SET = 512
IGNORE_YAW = 1024
IGNORE_YAW_RATE = 2048
IGNORE_POS = IGNORE_PX | IGNORE_PY | IGNORE_PZ
IGNORE_VEL = IGNORE_VX | IGNORE_VY | IGNORE_VZ
IGNORE_ACC = IGNORE_AX | IGNORE_AY | IGNORE_AZ

# SET_ATTITUDE_TARGET type_mask ignore bits.
ATT_IGNORE_ROLL_RATE = 1
ATT_IGNORE_PITCH_RATE = 2
ATT_IGNORE_YAW_RATE = 4
ATT_IGNORE_THRUST = 64
ATT_IGNORE_ATTITUDE = 128

#: |q| must be within this of 1 (the flatness map produces unit quaternions to ~1e-12).
QUAT_NORM_TOL = 1e-3


class SetpointError(ValueError):
    """A setpoint that must not be sent (NaN/inf, unnormalised quaternion, thrust out of range)."""


@dataclass(frozen=True)
class PositionSetpoint:
    """SET_POSITION_TARGET_LOCAL_NED content; None = not given (ignore bits set).

    pos_ned [m], vel_ned [m/s], acc_ned [m/s^2] (NED), yaw [rad], yaw_rate [rad/s].
    """

    pos_ned: Vec3 | None = None
    vel_ned: Vec3 | None = None
    acc_ned: Vec3 | None = None
    yaw: float | None = None
    yaw_rate: float | None = None


def make_position_setpoint(pos_ned: Vec3 | None, vel_ned: Vec3 | None, acc_ned: Vec3 | None,
                           yaw: float | None, yaw_rate: float | None) -> PositionSetpoint:
    """``PositionSetpoint(pos_ned, vel_ned, acc_ned, yaw, yaw_rate)`` for per-cycle sources: the
    same object, built ~3x faster than by the frozen dataclass ``__init__`` (which only assigns
    the fields). Validation happens when it is built into a message, as for any setpoint."""
    return frozen_new(PositionSetpoint, pos_ned=pos_ned, vel_ned=vel_ned, acc_ned=acc_ned,
                      yaw=yaw, yaw_rate=yaw_rate)


@dataclass(frozen=True)
class AttitudeSetpoint:
    """SET_ATTITUDE_TARGET with attitude q_wxyz (body FRD -> NED), thrust 0..1 and optional yaw
    rate feed-forward [rad/s] (type_mask 3, or 7 without the yaw rate)."""

    q_wxyz: Quat
    thrust_norm: float
    yaw_rate: float | None = None


@dataclass(frozen=True)
class RatesSetpoint:
    """SET_ATTITUDE_TARGET with body rates omega_frd [rad/s] and thrust 0..1 (type_mask 128)."""

    omega_frd: Vec3
    thrust_norm: float


@dataclass(frozen=True)
class RoverVelocitySetpoint:
    """Ground rover: horizontal velocity vel_ne [m/s] (NED north, east) and yaw rate [rad/s]."""

    vel_ne: tuple[float, float]
    yaw_rate: float


SetpointCommand = PositionSetpoint | AttitudeSetpoint | RatesSetpoint | RoverVelocitySetpoint


def _finite(name: str, values: Sequence[float]) -> list[float]:
    out = [float(v) for v in values]
    if not all(isfinite(v) for v in out):
        raise SetpointError(f"{name} is not finite: {tuple(out)}")
    return out


def _scalar(name: str, value: float) -> float:
    v = float(value)
    if not isfinite(v):
        raise SetpointError(f"{name} is not finite: {v}")
    return v


def _vec3(name: str, v: Sequence[float] | None) -> Vec3 | None:
    """Three finite floats, None for None (per-cycle hot path: no per-element generators)."""
    if v is None:
        return None
    if len(v) != 3:
        raise SetpointError(f"{name} needs 3 components, got {len(v)}")
    x, y, z = float(v[0]), float(v[1]), float(v[2])
    if not (isfinite(x) and isfinite(y) and isfinite(z)):
        raise SetpointError(f"{name} is not finite: {(x, y, z)}")
    return x, y, z


def _thrust(thrust_norm: float) -> float:
    t = _scalar("thrust", thrust_norm)
    if not 0.0 <= t <= 1.0:
        raise SetpointError(f"normalised thrust {t:.3f} outside 0..1")
    return t


def position_type_mask(sp: PositionSetpoint) -> int:
    """type_mask for the components given in ``sp`` (FORCE bit never set)."""
    mask = 0
    if sp.pos_ned is None:
        mask |= IGNORE_POS
    if sp.vel_ned is None:
        mask |= IGNORE_VEL
    if sp.acc_ned is None:
        mask |= IGNORE_ACC
    if sp.yaw is None:
        mask |= IGNORE_YAW
    if sp.yaw_rate is None:
        mask |= IGNORE_YAW_RATE
    return mask


def build_position_target(
    sp: PositionSetpoint, target_system: int, target_component: int, time_boot_ms: int
) -> MavMessage:
    """SET_POSITION_TARGET_LOCAL_NED (frame LOCAL_NED) for ``sp``.

    Raises SetpointError on NaN/inf or when no position, velocity or acceleration is given.
    """
    pos = _vec3("position", sp.pos_ned)
    vel = _vec3("velocity", sp.vel_ned)
    acc = _vec3("acceleration", sp.acc_ned)
    if pos is None and vel is None and acc is None:
        raise SetpointError("a position setpoint needs a position, velocity or acceleration")
    yaw = 0.0 if sp.yaw is None else _scalar("yaw", sp.yaw)
    yaw_rate = 0.0 if sp.yaw_rate is None else _scalar("yaw rate", sp.yaw_rate)
    zero = (0.0, 0.0, 0.0)
    p, v, a = pos or zero, vel or zero, acc or zero
    return mavlink2.MAVLink_set_position_target_local_ned_message(
        time_boot_ms & 0xFFFFFFFF, target_system, target_component, MAV_FRAME_LOCAL_NED,
        position_type_mask(sp), p[0], p[1], p[2], v[0], v[1], v[2], a[0], a[1], a[2],
        yaw, yaw_rate,
    )


def _unit_quat(q: Sequence[float]) -> list[float]:
    if len(q) != 4:
        raise SetpointError(f"quaternion needs 4 components (w, x, y, z), got {len(q)}")
    w, x, y, z = float(q[0]), float(q[1]), float(q[2]), float(q[3])
    qq = [w, x, y, z]
    if not (isfinite(w) and isfinite(x) and isfinite(y) and isfinite(z)):
        raise SetpointError(f"quaternion is not finite: {tuple(qq)}")
    norm = math.sqrt(w * w + x * x + y * y + z * z)
    if abs(norm - 1.0) > QUAT_NORM_TOL:
        raise SetpointError(f"quaternion is not normalised (|q| = {norm:.6f})")
    return qq


def _attitude_fields(sp: AttitudeSetpoint) -> tuple[int, list[float], float, float]:
    """Validated (type_mask, q_wxyz, body_yaw_rate, thrust) of an attitude setpoint."""
    q = _unit_quat(sp.q_wxyz)
    thrust = _thrust(sp.thrust_norm)
    mask = ATT_IGNORE_ROLL_RATE | ATT_IGNORE_PITCH_RATE
    yaw_rate = 0.0
    if sp.yaw_rate is None:
        mask |= ATT_IGNORE_YAW_RATE
    else:
        yaw_rate = _scalar("yaw rate", sp.yaw_rate)
    return mask, q, yaw_rate, thrust


def _rates_fields(sp: RatesSetpoint) -> tuple[Vec3, float]:
    """Validated (body rates, thrust) of a rates setpoint."""
    w = _vec3("body rates", sp.omega_frd)
    assert w is not None
    return w, _thrust(sp.thrust_norm)


def build_attitude_target(
    sp: AttitudeSetpoint, target_system: int, target_component: int, time_boot_ms: int
) -> MavMessage:
    """SET_ATTITUDE_TARGET with q + thrust (+ body_yaw_rate): type_mask 3 (7 without yaw rate).

    Roll/pitch rates stay ignored: with a quaternion they would make PX4 publish a competing
    rate setpoint (PX4.md).
    """
    mask, q, yaw_rate, thrust = _attitude_fields(sp)
    return mavlink2.MAVLink_set_attitude_target_message(
        time_boot_ms & 0xFFFFFFFF, target_system, target_component, mask, q,
        0.0, 0.0, yaw_rate, thrust,
    )


def build_rates_target(
    sp: RatesSetpoint, target_system: int, target_component: int, time_boot_ms: int
) -> MavMessage:
    """SET_ATTITUDE_TARGET with body rates + thrust, attitude ignored: type_mask 128."""
    w, thrust = _rates_fields(sp)
    return mavlink2.MAVLink_set_attitude_target_message(
        time_boot_ms & 0xFFFFFFFF, target_system, target_component, ATT_IGNORE_ATTITUDE,
        [1.0, 0.0, 0.0, 0.0], w[0], w[1], w[2], thrust,
    )


_SET_ATTITUDE_TARGET: Any = mavlink2.MAVLink_set_attitude_target_message
#: SET_ATTITUDE_TARGET's payload in wire order (pymavlink's ``ordered_fieldnames``, arrays
#: flattened), checked at import so that a regenerated dialect cannot silently reorder it.
_SAT_WIRE_ORDER = ["time_boot_ms", "q", "body_roll_rate", "body_pitch_rate", "body_yaw_rate",
                   "thrust", "target_system", "target_component", "type_mask"]
if list(_SET_ATTITUDE_TARGET.ordered_fieldnames) != _SAT_WIRE_ORDER:  # pragma: no cover
    raise ImportError("pymavlink's SET_ATTITUDE_TARGET layout changed: update setpoints.py")
_SAT_ID = int(_SET_ATTITUDE_TARGET.id)
_SAT_EXTRA = bytes((int(_SET_ATTITUDE_TARGET.crc_extra),))
_SAT_PACK = _SET_ATTITUDE_TARGET.unpacker.pack


def pack_setpoint(
    sp: SetpointCommand, target_system: int, target_component: int, time_boot_ms: int
) -> tuple[int, bytes, bytes] | None:
    """(message id, CRC_EXTRA byte, full wire-order payload) of an attitude or rates setpoint,
    validated exactly as ``build_setpoint`` does, for ``Codec.encode_payload`` (the per-cycle
    path: no message object). None for the other setpoint types (use ``build_setpoint``)."""
    tbm = time_boot_ms & 0xFFFFFFFF
    if type(sp) is AttitudeSetpoint:
        mask, q, yaw_rate, thrust = _attitude_fields(sp)
        payload = _SAT_PACK(tbm, q[0], q[1], q[2], q[3], 0.0, 0.0, yaw_rate, thrust,
                            target_system, target_component, mask)
    elif type(sp) is RatesSetpoint:
        w, thrust = _rates_fields(sp)
        payload = _SAT_PACK(tbm, 1.0, 0.0, 0.0, 0.0, w[0], w[1], w[2], thrust,
                            target_system, target_component, ATT_IGNORE_ATTITUDE)
    else:
        return None
    return _SAT_ID, _SAT_EXTRA, payload


def rover_type_mask() -> int:
    """type_mask of the rover setpoint: velocity (vz = 0) + yaw rate; position, acc, yaw ignored."""
    return IGNORE_POS | IGNORE_ACC | IGNORE_YAW


def build_rover_velocity_target(
    sp: RoverVelocitySetpoint, target_system: int, target_component: int, time_boot_ms: int
) -> MavMessage:
    """SET_POSITION_TARGET_LOCAL_NED with NE velocity (vz = 0) and yaw rate for a ground rover."""
    if len(sp.vel_ne) != 2:
        raise SetpointError("rover velocity needs (north, east)")
    vn, ve = _finite("rover velocity", sp.vel_ne)
    yr = _scalar("yaw rate", sp.yaw_rate)
    return mavlink2.MAVLink_set_position_target_local_ned_message(
        time_boot_ms & 0xFFFFFFFF, target_system, target_component, MAV_FRAME_LOCAL_NED,
        rover_type_mask(), 0.0, 0.0, 0.0, vn, ve, 0.0, 0.0, 0.0, 0.0, 0.0, yr,
    )


def build_setpoint(
    sp: SetpointCommand, target_system: int, target_component: int, time_boot_ms: int
) -> MavMessage:
    """Dispatch to the builder for ``sp``'s type."""
    if isinstance(sp, PositionSetpoint):
        return build_position_target(sp, target_system, target_component, time_boot_ms)
    if isinstance(sp, AttitudeSetpoint):
        return build_attitude_target(sp, target_system, target_component, time_boot_ms)
    if isinstance(sp, RatesSetpoint):
        return build_rates_target(sp, target_system, target_component, time_boot_ms)
    if isinstance(sp, RoverVelocitySetpoint):
        return build_rover_velocity_target(sp, target_system, target_component, time_boot_ms)
    raise SetpointError(f"unknown setpoint type {type(sp).__name__}")
