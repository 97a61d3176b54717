"""Telemetry: stream tables (PX4 onboard / normal link rates) and message builders.

The builders turn a `VehicleStatus` or a `StatusSnapshot` (the vehicle's / the whole status at
one instant, status.py) into messages the autopilot packs on a link: either a pymavlink message
object or, on the hot path, a `(MessageCodec, fields)` pair with the pymavlink constructor's
positional arguments, packed without building the message object (same bytes:
tests/sitl_mock/test_sitl_mavwire_codec.py). Attitude math here is the mock's own (explicit Euler
3-2-1 from the Hamilton quaternion body FRD -> NED), independent of `companion`.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from typing import Any, ClassVar

from pymavlink.dialects.v20 import common as mavlink

from sitl_mock.autopilot.status import StatusSnapshot, VehicleStatus
from sitl_mock.mavwire import codec
from sitl_mock.vehicle_state import VehicleState

Msg = Any  # a pymavlink MAVLink_message, or a (MessageCodec, fields) pair

# PX4 onboard-link stream rates [Hz] (mavlink_main.cpp, MAVLINK_MODE_ONBOARD) plus the extras
# the mock needs (BATTERY_STATUS, MISSION_CURRENT, PING).
ONBOARD_RATES_HZ: dict[int, float] = {
    mavlink.MAVLINK_MSG_ID_HEARTBEAT: 1.0,
    mavlink.MAVLINK_MSG_ID_ATTITUDE: 100.0,
    mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: 50.0,
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 50.0,
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 30.0,
    mavlink.MAVLINK_MSG_ID_ODOMETRY: 30.0,
    mavlink.MAVLINK_MSG_ID_ATTITUDE_TARGET: 10.0,
    mavlink.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED: 10.0,
    mavlink.MAVLINK_MSG_ID_SYS_STATUS: 5.0,
    mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 5.0,
    mavlink.MAVLINK_MSG_ID_HOME_POSITION: 0.5,
    mavlink.MAVLINK_MSG_ID_TIMESYNC: 10.0,
    mavlink.MAVLINK_MSG_ID_BATTERY_STATUS: 1.0,
    mavlink.MAVLINK_MSG_ID_MISSION_CURRENT: 1.0,
    mavlink.MAVLINK_MSG_ID_PING: 1.0,
}

# A lighter GCS-link set (PX4 "normal" mode, approximately).
GCS_RATES_HZ: dict[int, float] = {
    mavlink.MAVLINK_MSG_ID_HEARTBEAT: 1.0,
    mavlink.MAVLINK_MSG_ID_ATTITUDE: 15.0,
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 5.0,
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 1.0,
    mavlink.MAVLINK_MSG_ID_SYS_STATUS: 1.0,
    mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 1.0,
    mavlink.MAVLINK_MSG_ID_HOME_POSITION: 0.5,
    mavlink.MAVLINK_MSG_ID_BATTERY_STATUS: 0.5,
    mavlink.MAVLINK_MSG_ID_MISSION_CURRENT: 1.0,
    mavlink.MAVLINK_MSG_ID_VFR_HUD: 4.0,
    mavlink.MAVLINK_MSG_ID_GPS_RAW_INT: 1.0,
}

# SYS_STATUS sensor bits as seen on PX4 v1.16 SITL when ready to arm (PX4.md).
SENSORS_PRESENT = 50348079
SENSORS_ENABLED = 50413615
SENSORS_HEALTH_READY = 320915519
BIT_GPS = mavlink.MAV_SYS_STATUS_SENSOR_GPS
BIT_PREARM = mavlink.MAV_SYS_STATUS_PREARM_CHECK
BIT_XY_POS = mavlink.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL

_C_ATTITUDE = codec(mavlink.MAVLink_attitude_message)
_C_ATTITUDE_QUATERNION = codec(mavlink.MAVLink_attitude_quaternion_message)
_C_ATTITUDE_TARGET = codec(mavlink.MAVLink_attitude_target_message)
_C_BATTERY_STATUS = codec(mavlink.MAVLink_battery_status_message)
_C_EXTENDED_SYS_STATE = codec(mavlink.MAVLink_extended_sys_state_message)
_C_GLOBAL_POSITION_INT = codec(mavlink.MAVLink_global_position_int_message)
_C_GPS_RAW_INT = codec(mavlink.MAVLink_gps_raw_int_message)
_C_HIL_STATE_QUATERNION = codec(mavlink.MAVLink_hil_state_quaternion_message)
_C_LOCAL_POSITION_NED = codec(mavlink.MAVLink_local_position_ned_message)
_C_ODOMETRY = codec(mavlink.MAVLink_odometry_message)
_C_PING = codec(mavlink.MAVLink_ping_message)
_C_POSITION_TARGET_LOCAL_NED = codec(mavlink.MAVLink_position_target_local_ned_message)
_C_SYS_STATUS = codec(mavlink.MAVLink_sys_status_message)
_C_TIMESYNC = codec(mavlink.MAVLink_timesync_message)
_C_VFR_HUD = codec(mavlink.MAVLink_vfr_hud_message)
UINT16_MAX = 65535
_NAN21 = (math.nan,) + (0.0,) * 20  # covariance "unknown" (first element NaN)
INT16_MAX = 32767


def euler_321(q_wxyz: tuple[float, float, float, float]) -> tuple[float, float, float]:
    """Roll, pitch, yaw [rad] (body 3-2-1) of the body FRD -> NED quaternion."""
    w, x, y, z = q_wxyz
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    s = max(-1.0, min(1.0, 2.0 * (w * y - z * x)))
    pitch = math.asin(s)
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return roll, pitch, yaw


def rotate_ned_to_body(
    q_wxyz: tuple[float, float, float, float], v: tuple[float, float, float]
) -> tuple[float, float, float]:
    """Express an NED vector in body FRD: v_b = R(q)^T v (R rotates body -> NED)."""
    w, x, y, z = q_wxyz
    # rotation by the conjugate quaternion
    x, y, z = -x, -y, -z
    vx, vy, vz = v
    # t = 2 q_vec x v
    tx = 2.0 * (y * vz - z * vy)
    ty = 2.0 * (z * vx - x * vz)
    tz = 2.0 * (x * vy - y * vx)
    return (
        vx + w * tx + (y * tz - z * ty),
        vy + w * ty + (z * tx - x * tz),
        vz + w * tz + (x * ty - y * tx),
    )


def _f(v: float) -> float:
    """Float field for the wire (NaN passes through as NaN, as PX4 sends it)."""
    return float(v)


def type_mask_of(target: Any) -> int:
    """POSITION_TARGET_LOCAL_NED type_mask for a PositionTarget (ignore bits where NaN)."""
    mask = 0
    for i, c in enumerate(target.pos_ned):
        if not math.isfinite(c):
            mask |= 1 << i
    for i, c in enumerate(target.vel_ned):
        if not math.isfinite(c):
            mask |= 8 << i
    for i, c in enumerate(target.acc_ned):
        if not math.isfinite(c):
            mask |= 64 << i
    if not math.isfinite(target.yaw):
        mask |= 1024
    if not math.isfinite(target.yaw_rate):
        mask |= 2048
    return mask


AUTOPILOT_CAPABILITIES = (
    mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT
    | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
    | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
    | mavlink.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
    | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
    | mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_FENCE
    | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_RALLY
)
FLIGHT_SW_VERSION = (1 << 24) | (16 << 16) | (0 << 8) | 255  # v1.16.0 release


class MissionCurrentV2(mavlink.MAVLink_mission_current_message):  # type: ignore[misc]
    """MISSION_CURRENT with the extensions PX4 v1.16 sends (pymavlink 2.4 lacks them):
    ``mission_id`` is the stored mission's opaque id (0 without a mission), so a ground station
    or companion sees a new upload; fence and rally ids stay 0 (trimmed on the wire)."""

    fieldnames: ClassVar[list[str]] = [*mavlink.MAVLink_mission_current_message.fieldnames,
                                       "mission_id", "fence_id", "rally_points_id"]
    ordered_fieldnames: ClassVar[list[str]] = fieldnames
    fieldtypes: ClassVar[list[str]] = [*mavlink.MAVLink_mission_current_message.fieldtypes,
                                       "uint32_t", "uint32_t", "uint32_t"]
    array_lengths: ClassVar[list[int]] = [0] * 7
    unpacker = struct.Struct("<HHBBIII")

    def __init__(self, seq: int, total: int = 0, mission_state: int = 0, mission_mode: int = 0,
                 mission_id: int = 0, fence_id: int = 0, rally_points_id: int = 0) -> None:
        super().__init__(seq, total, mission_state, mission_mode)
        self.mission_id = mission_id
        self.fence_id = fence_id
        self.rally_points_id = rally_points_id


def home_position_message(home: tuple[float, float, float], time_usec: int) -> Msg:
    """HOME_POSITION of `home` (lat deg, lon deg, alt AMSL m), local position and q zero."""
    lat, lon, alt = home
    return mavlink.MAVLink_home_position_message(
        round(lat * 1e7),
        round(lon * 1e7),
        round(alt * 1000.0),
        0.0,
        0.0,
        0.0,
        [1.0, 0.0, 0.0, 0.0],
        0.0,
        0.0,
        0.0,
        time_usec,
    )


def autopilot_version_message() -> Msg:
    """AUTOPILOT_VERSION: PX4 v1.16.0's capabilities and version, uid "SITLMOCK"."""
    return mavlink.MAVLink_autopilot_version_message(
        AUTOPILOT_CAPABILITIES,
        FLIGHT_SW_VERSION,
        FLIGHT_SW_VERSION,
        0,
        0,
        [0] * 8,
        [0] * 8,
        [0] * 8,
        0,
        0,
        0x5349544C4D4F434B,  # "SITLMOCK"
    )


def ping_message(time_usec: int, seq: int) -> Msg:
    """PING request number `seq` (the autopilot counts its pings)."""
    return (_C_PING, (time_usec, seq, 0, 0))


def build_heartbeat(st: StatusSnapshot) -> Msg:
    return mavlink.MAVLink_heartbeat_message(
        st.mav_type,
        mavlink.MAV_AUTOPILOT_PX4,
        st.base_mode,
        st.custom_mode,
        st.system_status,
        3,
    )


def build_attitude(st: VehicleStatus) -> Msg:
    q_wxyz, omega_frd = st.attitude  # = state.q_wxyz, the measured body rates
    roll, pitch, yaw = euler_321(q_wxyz)
    p, q, r = omega_frd
    return (_C_ATTITUDE, (st.time_boot_ms, roll, pitch, yaw, p, q, r))


def build_attitude_quaternion(st: VehicleStatus) -> Msg:
    (w, x, y, z), (p, q, r) = st.attitude  # = state.q_wxyz, the measured body rates
    return (_C_ATTITUDE_QUATERNION, (st.time_boot_ms, w, x, y, z, p, q, r, (0.0, 0.0, 0.0, 0.0)))


def build_local_position_ned(st: VehicleStatus) -> Msg | None:
    s = st.state
    if not st.local_position_valid:
        return None
    x, y, z = s.pos_ned
    vx, vy, vz = s.vel_ned
    return (_C_LOCAL_POSITION_NED, (st.time_boot_ms, x, y, z, vx, vy, vz))


def build_odometry(st: VehicleStatus) -> Msg | None:
    s = st.state
    if not st.local_position_valid:
        return None
    x, y, z = s.pos_ned
    vb = rotate_ned_to_body(s.q_wxyz, s.vel_ned)
    p, q, r = st.attitude[1]  # the measured body rates, as ATTITUDE
    nan21 = _NAN21
    return (
        _C_ODOMETRY,
        (
            st.time_usec,
            mavlink.MAV_FRAME_LOCAL_NED,
            mavlink.MAV_FRAME_BODY_FRD,
            x,
            y,
            z,
            list(s.q_wxyz),
            vb[0],
            vb[1],
            vb[2],
            p,
            q,
            r,
            nan21,
            nan21,
            0,
            mavlink.MAV_ESTIMATOR_TYPE_AUTOPILOT,
            100,
        ),
    )


def build_global_position_int(st: VehicleStatus) -> Msg:
    s = st.state
    yaw = s.yaw  # the yaw of euler_321 (same expression), without roll and pitch
    hdg = round(math.degrees(yaw) % 360.0 * 100.0) % 36000
    vx, vy, vz = s.vel_ned
    lat, lon, alt = s.lat_lon_alt  # one projection (the same values as lat_deg, lon_deg, ...)
    return (
        _C_GLOBAL_POSITION_INT,
        (
            st.time_boot_ms,
            round(lat * 1e7),
            round(lon * 1e7),
            round(alt * 1000.0),
            round((alt - st.home[2]) * 1000.0),
            _clamp_i16(vx * 100.0),
            _clamp_i16(vy * 100.0),
            _clamp_i16(vz * 100.0),
            hdg,
        ),
    )


def _clamp_i16(v: float) -> int:
    """Nearest int16 (saturated); 0 for NaN / inf."""
    if not math.isfinite(v):
        return 0
    r = round(v)
    return -32768 if r < -32768 else 32767 if r > 32767 else r


def build_attitude_target(st: VehicleStatus) -> Msg | None:
    last = st.last_attitude_target
    if last is None:
        return None
    q, rates, thrust = last
    mask = 0
    if q is None:
        q = (1.0, 0.0, 0.0, 0.0)
        mask |= 128
    if rates is None:
        rates = (0.0, 0.0, 0.0)
        mask |= 7
    return (
        _C_ATTITUDE_TARGET,
        (st.time_boot_ms, mask, list(q), rates[0], rates[1], rates[2], float(thrust)),
    )


def build_position_target_local_ned(st: VehicleStatus) -> Msg | None:
    t = st.last_position_target
    if t is None:
        return None
    return (
        _C_POSITION_TARGET_LOCAL_NED,
        (
            st.time_boot_ms,
            mavlink.MAV_FRAME_LOCAL_NED,
            type_mask_of(t),
            *(_f(c) for c in t.pos_ned),
            *(_f(c) for c in t.vel_ned),
            *(_f(c) for c in t.acc_ned),
            _f(t.yaw),
            _f(t.yaw_rate),
        ),
    )


def build_sys_status(st: StatusSnapshot) -> Msg:
    health = SENSORS_HEALTH_READY
    if not st.vehicle.estimator_ready:
        health &= ~(BIT_GPS | BIT_PREARM | BIT_XY_POS)
    elif not st.prearm_ok:
        health &= ~BIT_PREARM
    if not st.vehicle.local_position_valid:
        health &= ~(BIT_GPS | BIT_XY_POS)
    rem = st.battery_remaining
    return (
        _C_SYS_STATUS,
        (
            SENSORS_PRESENT,
            SENSORS_ENABLED,
            health,
            250,
            st.battery_voltage_mv,
            -1,
            round(rem * 100.0),
            0,
            min(st.errors_comm, UINT16_MAX),
            0,
            0,
            0,
            0,
        ),
    )


def build_extended_sys_state(st: StatusSnapshot) -> Msg:
    return (_C_EXTENDED_SYS_STATE, (mavlink.MAV_VTOL_STATE_UNDEFINED, st.landed_state))


def build_home_position(st: VehicleStatus) -> Msg | None:
    if not st.estimator_ready:  # home is set once the estimator is ready
        return None
    return home_position_message(st.home, st.time_usec)


def build_timesync(st: VehicleStatus) -> Msg:
    return (_C_TIMESYNC, (0, st.time_ns))


def build_battery_status(st: StatusSnapshot) -> Msg:
    rem = st.battery_remaining
    voltages = [st.battery_voltage_mv] + [UINT16_MAX] * 9
    charge = mavlink.MAV_BATTERY_CHARGE_STATE_OK
    if rem < 0.07:
        charge = mavlink.MAV_BATTERY_CHARGE_STATE_CRITICAL
    elif rem < 0.15:
        charge = mavlink.MAV_BATTERY_CHARGE_STATE_LOW
    return (
        _C_BATTERY_STATUS,
        (
            0,
            mavlink.MAV_BATTERY_FUNCTION_ALL,
            mavlink.MAV_BATTERY_TYPE_LIPO,
            INT16_MAX,
            voltages,
            -1,
            -1,
            -1,
            round(rem * 100.0),
            0,
            charge,
        ),
    )


def build_mission_current(st: StatusSnapshot) -> Msg:
    return MissionCurrentV2(
        st.mission_seq, st.mission_total, st.mission_state, st.mission_mode, st.mission_id
    )


def build_vfr_hud(st: VehicleStatus) -> Msg:
    s = st.state
    vn, ve, vd = s.vel_ned
    _, _, yaw = euler_321(s.q_wxyz)
    speed = math.hypot(vn, ve)
    return (
        _C_VFR_HUD,
        (
            speed,
            speed,
            round(math.degrees(yaw)) % 360,
            round(100.0 * max(0.0, min(1.0, s.thrust_norm))),
            s.alt_amsl_m,
            -vd,
        ),
    )


def build_gps_raw_int(st: VehicleStatus) -> Msg:
    s = st.state
    vn, ve, _ = s.vel_ned
    fix = 3 if st.local_position_valid else 0
    cog = round(math.degrees(math.atan2(ve, vn)) % 360.0 * 100.0) % 36000
    return (
        _C_GPS_RAW_INT,
        (
            st.time_usec,
            fix,
            round(s.lat_deg * 1e7),
            round(s.lon_deg * 1e7),
            round(s.alt_amsl_m * 1000.0),
            100,
            150,
            min(round(math.hypot(vn, ve) * 100.0), UINT16_MAX - 1),
            cog,
            10,
        ),
    )


def build_hil_state_quaternion(st: VehicleStatus, truth: VehicleState) -> Msg:
    """HIL_STATE_QUATERNION from the vehicle's true motion (`Vehicle.true_state`), as PX4 SITL
    streams its simulator's state on request: attitude q_wxyz, true body rates [rad/s FRD],
    geodetic position (lat, lon degE7, alt AMSL mm), velocity NED [cm/s], specific force NED
    (acceleration less gravity) [mG]."""
    lat, lon, alt = truth.lat_lon_alt
    vx, vy, vz = truth.vel_ned
    ax, ay, az = truth.acc_ned
    speed = min(round(math.sqrt(vx * vx + vy * vy + vz * vz) * 100.0), UINT16_MAX)
    mg = 1000.0 / 9.80665
    return (
        _C_HIL_STATE_QUATERNION,
        (
            st.time_usec,
            list(truth.q_wxyz),
            *truth.omega_frd,
            round(lat * 1e7),
            round(lon * 1e7),
            round(alt * 1000.0),
            _clamp_i16(vx * 100.0),
            _clamp_i16(vy * 100.0),
            _clamp_i16(vz * 100.0),
            speed,
            speed,
            _clamp_i16(ax * mg),
            _clamp_i16(ay * mg),
            _clamp_i16((az - 9.80665) * mg),
        ),
    )


# Builders of the high-rate streams read only the vehicle's side of the status; PING is
# streamed too, but its sequence number is the autopilot's (`ping_message`).
VEHICLE_BUILDERS: dict[int, Callable[[VehicleStatus], Msg | None]] = {
    mavlink.MAVLINK_MSG_ID_ATTITUDE: build_attitude,
    mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: build_attitude_quaternion,
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: build_global_position_int,
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: build_local_position_ned,
    mavlink.MAVLINK_MSG_ID_ODOMETRY: build_odometry,
    mavlink.MAVLINK_MSG_ID_ATTITUDE_TARGET: build_attitude_target,
    mavlink.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED: build_position_target_local_ned,
    mavlink.MAVLINK_MSG_ID_HOME_POSITION: build_home_position,
    mavlink.MAVLINK_MSG_ID_TIMESYNC: build_timesync,
    mavlink.MAVLINK_MSG_ID_VFR_HUD: build_vfr_hud,
    mavlink.MAVLINK_MSG_ID_GPS_RAW_INT: build_gps_raw_int,
}
# Builders of the low-rate status messages read the whole status snapshot.
STATUS_BUILDERS: dict[int, Callable[[StatusSnapshot], Msg | None]] = {
    mavlink.MAVLINK_MSG_ID_HEARTBEAT: build_heartbeat,
    mavlink.MAVLINK_MSG_ID_SYS_STATUS: build_sys_status,
    mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: build_extended_sys_state,
    mavlink.MAVLINK_MSG_ID_BATTERY_STATUS: build_battery_status,
    mavlink.MAVLINK_MSG_ID_MISSION_CURRENT: build_mission_current,
}

_FLT_MAX = 3.4028234663852886e38  # largest float32: the wire's float fields


def _float32_ok(*vals: float) -> bool:
    """Every value packs as a float32 field: NaN and infinities do; finite values beyond the
    float32 range raise OverflowError (here also the few just above it that would round down
    to it: a conservative answer only means "build it")."""
    return not any(_FLT_MAX < abs(v) < math.inf for v in vals)


def _attitude_builds(st: VehicleStatus) -> bool | None:
    return True if _float32_ok(*st.attitude[1]) else None


def _odometry_builds(st: VehicleStatus) -> bool | None:
    if not st.local_position_valid:
        return False
    s = st.state
    # the body-frame velocity is rotated: a margin below float32's range for its components
    slow = not any(1e30 <= abs(v) < math.inf for v in s.vel_ned)
    return True if slow and _float32_ok(*s.pos_ned, *s.q_wxyz, *st.attitude[1]) else None


def _gpi_builds(st: VehicleStatus) -> bool | None:
    """GLOBAL_POSITION_INT builds and packs: True when the position and attitude are finite,
    within 100 km of a home below 80 deg of latitude (so lat/lon/alt fit their int32 fields);
    None: not known without building it."""
    s = st.state
    x, y, z = s.pos_ned
    lat, lon, alt = st.home
    if (abs(x) < 1e5 and abs(y) < 1e5 and abs(z) < 1e5 and abs(lat) <= 80.0
            and abs(lon) <= 180.0 and abs(alt) < 1e5 and all(map(math.isfinite, s.q_wxyz))):
        return True
    return None


def _attitude_target_builds(st: VehicleStatus) -> bool | None:
    last = st.last_attitude_target
    if last is None:
        return False
    q, rates, thrust = last
    return True if _float32_ok(*(q or ()), *(rates or ()), thrust) else None


def _position_target_builds(st: VehicleStatus) -> bool | None:
    t = st.last_position_target
    if t is None:
        return False
    return True if _float32_ok(*t.pos_ned, *t.vel_ned, *t.acc_ned, t.yaw, t.yaw_rate) else None


#: Streams a link may leave unbuilt when nobody reads them (`Links.emit_streams`' `quiet`):
#: message id -> whether its builder would give a message that packs, from the vehicle status
#: alone (True: sent, False: the builder gives None, None: not known, build it). The others
#: are never left out: their builders need the whole status or have side effects (PING).
QUIETABLE: dict[int, Callable[[VehicleStatus], bool | None]] = {
    mavlink.MAVLINK_MSG_ID_ATTITUDE: _attitude_builds,
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: _gpi_builds,
    mavlink.MAVLINK_MSG_ID_ODOMETRY: _odometry_builds,
    mavlink.MAVLINK_MSG_ID_ATTITUDE_TARGET: _attitude_target_builds,
    mavlink.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED: _position_target_builds,
}

MSG_ID_PING = mavlink.MAVLINK_MSG_ID_PING
#: the vehicle's truth (`build_hil_state_quaternion`), streamed only on request, as PX4 SITL does
MSG_ID_HIL_STATE_QUATERNION = mavlink.MAVLINK_MSG_ID_HIL_STATE_QUATERNION
# Messages that SET_MESSAGE_INTERVAL can stream and REQUEST_MESSAGE (512) can produce once.
STREAMABLE = (frozenset(VEHICLE_BUILDERS) | frozenset(STATUS_BUILDERS)
              | {MSG_ID_PING, MSG_ID_HIL_STATE_QUATERNION})


class StreamScheduler:
    """Per-link periodic schedule: message id -> interval [s] and next due time (sim s)."""

    def __init__(self, rates_hz: dict[int, float], now: float) -> None:
        self.defaults = dict(rates_hz)
        self.interval_s: dict[int, float] = {k: 1.0 / v for k, v in rates_hz.items() if v > 0}
        # all streams start together: they then fire on common ticks (fewer wake-ups)
        self.next_due: dict[int, float] = dict.fromkeys(self.interval_s, now)
        self.earliest = min(self.next_due.values(), default=math.inf)

    def set_interval(self, msg_id: int, interval_us: float, now: float) -> None:
        """SET_MESSAGE_INTERVAL semantics: -1 disable, 0 default rate, > 0 interval [us]."""
        if interval_us < 0:
            self.interval_s.pop(msg_id, None)
            self.next_due.pop(msg_id, None)
        else:
            if interval_us == 0:
                hz = self.defaults.get(msg_id, 0.0)
                if hz <= 0:
                    self.interval_s.pop(msg_id, None)
                    self.next_due.pop(msg_id, None)
                    self._refresh()
                    return
                interval_s = 1.0 / hz
            else:
                interval_s = max(interval_us * 1e-6, 1e-3)
            self.interval_s[msg_id] = interval_s
            self.next_due[msg_id] = now
        self._refresh()

    def _refresh(self) -> None:
        self.earliest = min(self.next_due.values(), default=math.inf)

    def due(self, now: float) -> list[int]:
        """Message ids due at `now`; advances their schedule (no burst catch-up)."""
        if now < self.earliest:
            return []
        out = []
        next_due, interval_s = self.next_due, self.interval_s
        earliest = math.inf
        for k, t in next_due.items():
            if t <= now:
                out.append(k)
                dt = interval_s[k]
                t = t + dt
                if t <= now:  # fell behind: skip missed slots rather than bursting
                    t = now + dt
                next_due[k] = t
            if t < earliest:
                earliest = t
        self.earliest = earliest  # = min(next_due.values()), computed in the same pass
        return out
