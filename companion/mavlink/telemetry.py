"""Telemetry state from the autopilot's streams (sans-IO, injected receive time).

Every value records the local receive time ``t_s`` [s] so that callers can judge staleness.
NED world, FRD body, SI units; quaternions (w, x, y, z) body FRD -> NED.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

from companion._frozen import frozen_new
from companion.flatness._formulas import FLOAT

from .codec import MavMessage
from .velocity_correction import POSITION_RESET_M as POSITION_RESET_M
from .velocity_correction import VELOCITY_CORRECTION_MAX_M_S as VELOCITY_CORRECTION_MAX_M_S
from .velocity_correction import VELOCITY_CORRECTION_RAD_S as VELOCITY_CORRECTION_RAD_S
from .velocity_correction import velocity_correction_step

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]

MAV_FRAME_BODY_FRD = 12
MAV_FRAME_BODY_NED = 8
MAV_FRAME_BODY_OFFSET_NED = 9


@dataclass(frozen=True)
class LocalPosition:
    """Vehicle position pos_ned [m] and velocity vel_ned [m/s] (LOCAL_POSITION_NED/ODOMETRY), as
    the autopilot sent them, and ``vel_correction_ned`` [m/s]: what to add to ``vel_ned`` for a
    velocity that agrees with how ``pos_ned`` moves (:class:`VelocityCorrection`; horizontal
    only, zero until two samples have arrived)."""

    t_s: float
    time_boot_s: float
    pos_ned: Vec3
    vel_ned: Vec3
    source: str
    vel_correction_ned: Vec3 = (0.0, 0.0, 0.0)

    @property
    def vel_corrected_ned(self) -> Vec3:
        """``vel_ned`` plus ``vel_correction_ned`` [m/s NED]: the velocity to control with."""
        v, c = self.vel_ned, self.vel_correction_ned
        return (v[0] + c[0], v[1] + c[1], v[2] + c[2])


@dataclass(frozen=True)
class Attitude:
    """Attitude q_wxyz (body FRD -> NED) and body rates omega_frd [rad/s]."""

    t_s: float
    q_wxyz: Quat
    omega_frd: Vec3


@dataclass(frozen=True)
class GlobalPosition:
    """GLOBAL_POSITION_INT: lat/lon [deg], alt_amsl_m, relative_alt_m, vel_ned [m/s]."""

    t_s: float
    lat_deg: float
    lon_deg: float
    alt_amsl_m: float
    relative_alt_m: float
    vel_ned: Vec3


@dataclass(frozen=True)
class HomePosition:
    """HOME_POSITION: lat/lon [deg], alt_amsl_m, local pos_ned [m]."""

    t_s: float
    lat_deg: float
    lon_deg: float
    alt_amsl_m: float
    pos_ned: Vec3


@dataclass(frozen=True)
class SystemStatus:
    """SYS_STATUS sensor bitmasks, battery and derived readiness."""

    t_s: float
    present: int
    enabled: int
    health: int
    battery_remaining_pct: int
    voltage_v: float

    @property
    def armable(self) -> bool:
        """PREARM_CHECK health bit (what MAVSDK calls is_armable)."""
        return bool(self.health & 268435456)


@dataclass(frozen=True)
class ExtendedState:
    """EXTENDED_SYS_STATE landed_state: 0 undefined, 1 on ground, 2 in air, 3 takeoff, 4 landing."""

    t_s: float
    landed_state: int
    vtol_state: int

    @property
    def in_air(self) -> bool:
        """MAVSDK's in_air: anything but undefined or on ground."""
        return self.landed_state not in (0, 1)


@dataclass(frozen=True)
class MissionCurrent:
    """MISSION_CURRENT: current item ``seq``, ``total`` items (65535: no mission) and PX4's
    ``mission_id`` (v1.16: a CRC32 of the stored mission that changes with every new upload;
    0 when not sent). The extension is read from the raw payload (pymavlink 2.4 lacks it)."""

    t_s: float
    seq: int
    total: int
    mission_id: int


@dataclass(frozen=True)
class StatusText:
    """A complete STATUSTEXT (chunks reassembled). severity: MAV_SEVERITY (0 emergency..7 debug)."""

    t_s: float
    severity: int
    text: str


TelemetryEvent = (LocalPosition | Attitude | GlobalPosition | HomePosition | SystemStatus
                  | ExtendedState | MissionCurrent | StatusText)


@dataclass(frozen=True)
class TelemetrySnapshot:
    """Immutable view of the latest telemetry handed to setpoint sources."""

    position: LocalPosition | None = None
    attitude: Attitude | None = None
    global_position: GlobalPosition | None = None
    home: HomePosition | None = None
    extended: ExtendedState | None = None
    now_s: float = math.nan  # local time of the consumer's cycle (set by the streamer)
    #: the link's round-trip time [s] (TIMESYNC, `VehicleLink.rtt_s`; set by the streamer with
    #: now_s; NaN: not measured): how much older a sample is than its arrival shows, plus how
    #: late a setpoint sent now takes effect (`estimate_from_telemetry`)
    link_rtt_s: float = math.nan


# Per-cycle constructors of the hot values: the same objects as the dataclass constructors (whose
# generated frozen __init__ only assigns the fields, one object.__setattr__ each, ~3x slower),
# checked field by field against them in tests/companion/mavlink/test_fast_paths.py.
def _local_position(t_s: float, time_boot_s: float, pos_ned: Vec3, vel_ned: Vec3,
                    source: str, vel_correction_ned: Vec3) -> LocalPosition:
    return frozen_new(LocalPosition, t_s=t_s, time_boot_s=time_boot_s, pos_ned=pos_ned,
                      vel_ned=vel_ned, source=source, vel_correction_ned=vel_correction_ned)


def _attitude(t_s: float, q_wxyz: Quat, omega_frd: Vec3) -> Attitude:
    return frozen_new(Attitude, t_s=t_s, q_wxyz=q_wxyz, omega_frd=omega_frd)


def _snapshot(position: LocalPosition | None, attitude: Attitude | None,
              global_position: GlobalPosition | None, home: HomePosition | None,
              extended: ExtendedState | None) -> TelemetrySnapshot:
    return frozen_new(TelemetrySnapshot, position=position, attitude=attitude,
                      global_position=global_position, home=home, extended=extended,
                      now_s=math.nan, link_rtt_s=math.nan)


def _rotate(q: Quat, v: Vec3) -> Vec3:
    """Rotate v by unit quaternion q (w, x, y, z): R(q) v."""
    w, x, y, z = q
    vx, vy, vz = v
    # t = 2 * cross(q_vec, v); v' = v + w t + cross(q_vec, t)
    tx, ty, tz = 2 * (y * vz - z * vy), 2 * (z * vx - x * vz), 2 * (x * vy - y * vx)
    return (vx + w * tx + (y * tz - z * ty), vy + w * ty + (z * tx - x * tz),
            vz + w * tz + (x * ty - y * tx))


class VelocityCorrection:
    """The horizontal velocity error of the autopilot's estimate, seen from its own position: a
    second-order complementary filter. Between samples a filtered position moves with the
    reported velocity plus the correction (trapezoid over the sample times); the position's
    innovation r then pulls it by k1 dt r and the correction by k2 dt r (k1 = 2 w, k2 = w^2,
    w = ``omega_rad_s``). Reported velocity plus correction is the reported velocity above ~w
    and the position's rate of change below it, so a velocity that agrees with its position
    gets no correction, and a slowly varying velocity error (a bias) is removed within a few
    1 / w. White noise on the position (a GPS) is filtered twice.

    Why: EKF2 on PX4 v1.16 SIH reports velocities 0.13-0.35 m/s off per axis, slowly varying
    (bench_fidelity), while its GPS-corrected position moves with the true vehicle. On a loaded
    host the error grew to 0.4-0.75 m/s after a Hold's braking (HIL_STATE_QUATERNION as truth,
    serve's pause and resume, 2026-11-29): the law, braking a forward velocity that was not
    there, flew the vehicle back at 0.8-1.0 m/s. On 17 such flights the correction (w = 4)
    cut EKF2's error against the truth from 0.45 to 0.18 m/s RMS in OFFBOARD and from 0.67 to
    0.22 m/s around the resume; a higher w does a little better on PX4's smooth position but
    lets white position noise through as w^1.5 (docs/theory/estimation.md). The vertical axis
    is left alone (baro height; the touchdown reads EKF2's vertical speed).

    The update is `companion.mavlink.velocity_correction`'s step, which gen_c also emits as C
    (``ecca_velocity_correction_step``) for the onboard PX4 module; this class keeps the
    bookkeeping (the sample clock, the same sample again, non-finite samples)."""

    def __init__(self, omega_rad_s: float = VELOCITY_CORRECTION_RAD_S) -> None:
        self.omega_rad_s = omega_rad_s
        self.k1, self.k2 = 2.0 * omega_rad_s, omega_rad_s * omega_rad_s
        self._t: float | None = None  # sample time [s] of the last sample
        self._p = (0.0, 0.0)  # filtered horizontal position [m]
        self._v = (0.0, 0.0)  # the last sample's reported horizontal velocity [m/s]
        self.c = (0.0, 0.0)  # the correction [m/s]

    def update(self, t_s: float, pos: Vec3, vel: Vec3) -> Vec3:
        """Feed one sample (its time on the autopilot's clock [s], position [m], velocity [m/s]
        NED); returns the correction (north, east, 0) [m/s]."""
        cx, cy = self.c
        t0 = self._t
        px, py = pos[0], pos[1]
        if not (math.isfinite(t_s) and math.isfinite(px) and math.isfinite(py)
                and math.isfinite(vel[0]) and math.isfinite(vel[1])):
            return (cx, cy, 0.0)
        dt = t_s - t0 if t0 is not None else 0.0
        if t0 is not None and dt == 0.0:  # the same sample again
            return (cx, cy, 0.0)
        # the step written once with the generated C's (companion.mavlink.velocity_correction);
        # the first sample (no t0), a gap or an estimator reset restart it
        v = (vel[0], vel[1])
        self._p, self.c = velocity_correction_step(
            FLOAT, self._p, self._v, self.c, (px, py), v, dt, self.omega_rad_s,
            VELOCITY_CORRECTION_MAX_M_S, POSITION_RESET_M, t0 is not None)
        self._t = t_s
        self._v = v
        cx, cy = self.c
        return (cx, cy, 0.0)


@dataclass
class _Chunks:
    severity: int
    parts: dict[int, str] = field(default_factory=dict)
    t_first: float = 0.0


class TelemetryState:
    """Latest value of each telemetry stream, updated by ``update(msg, now)``."""

    def __init__(self, target_sysid: int = 1, target_compid: int = 1,
                 statustext_timeout_s: float = 1.0,
                 velocity_correction_rad_s: float = VELOCITY_CORRECTION_RAD_S) -> None:
        """``velocity_correction_rad_s``: :class:`VelocityCorrection`'s frequency (0: none,
        ``LocalPosition.vel_correction_ned`` stays zero)."""
        self.target_sysid, self.target_compid = target_sysid, target_compid
        self._vel_correction = (VelocityCorrection(velocity_correction_rad_s)
                                if velocity_correction_rad_s > 0.0 else None)
        self.position: LocalPosition | None = None
        self.attitude: Attitude | None = None
        self.global_position: GlobalPosition | None = None
        self.home: HomePosition | None = None
        self.sys_status: SystemStatus | None = None
        self.extended: ExtendedState | None = None
        self.mission_current: MissionCurrent | None = None
        self.statustext_timeout_s = statustext_timeout_s
        self._chunks: dict[int, _Chunks] = {}
        # message type -> handler, e.g. "LOCAL_POSITION_NED" -> self._on_local_position_ned
        self._handlers: dict[str, Callable[[MavMessage, float], list[TelemetryEvent]]] = {
            name[4:].upper(): getattr(self, name) for name in dir(self) if name.startswith("_on_")
        }
        self._snapshot = TelemetrySnapshot()

    @property
    def kinds(self) -> frozenset[str]:
        """Message types that ``update`` handles."""
        return frozenset(self._handlers)

    def snapshot(self) -> TelemetrySnapshot:
        """Immutable copy of the kinematic state (cheap; values are already frozen). The same
        object is returned again while none of its values changed."""
        s = self._snapshot
        if (s.position is self.position and s.attitude is self.attitude
                and s.global_position is self.global_position and s.home is self.home
                and s.extended is self.extended):
            return s
        s = self._snapshot = _snapshot(self.position, self.attitude, self.global_position,
                                       self.home, self.extended)
        return s

    def update(self, msg: MavMessage, now: float) -> list[TelemetryEvent]:
        """Feed any message from the vehicle; returns the telemetry values it produced."""
        handler = self._handlers.get(msg.get_type())
        if (handler is None or msg.get_srcSystem() != self.target_sysid
                or msg.get_srcComponent() != self.target_compid):
            return []
        return handler(msg, now)

    def _correction(self, t_s: float, pos: Vec3, vel: Vec3) -> Vec3:
        vc = self._vel_correction
        return vc.update(t_s, pos, vel) if vc is not None else (0.0, 0.0, 0.0)

    def _on_local_position_ned(self, m: MavMessage, now: float) -> list[TelemetryEvent]:
        t = m.time_boot_ms * 1e-3
        pos: Vec3 = (float(m.x), float(m.y), float(m.z))
        vel: Vec3 = (float(m.vx), float(m.vy), float(m.vz))
        v = _local_position(now, t, pos, vel, "LOCAL_POSITION_NED", self._correction(t, pos, vel))
        self.position = v
        return [v]

    def _on_odometry(self, m: MavMessage, now: float) -> list[TelemetryEvent]:
        if int(m.frame_id) not in (1, 18, 20):  # LOCAL_NED, ESTIM_NED, LOCAL_FRD
            return []
        q: Quat = (float(m.q[0]), float(m.q[1]), float(m.q[2]), float(m.q[3]))
        vel: Vec3 = (float(m.vx), float(m.vy), float(m.vz))
        if int(m.child_frame_id) in (MAV_FRAME_BODY_FRD, MAV_FRAME_BODY_NED) and all(
                math.isfinite(c) for c in q):
            vel = _rotate(q, vel)
        out: list[TelemetryEvent] = []
        pos: Vec3 = (float(m.x), float(m.y), float(m.z))
        if all(math.isfinite(c) for c in pos + vel):
            t = m.time_usec * 1e-6
            self.position = LocalPosition(now, t, pos, vel, "ODOMETRY",
                                          self._correction(t, pos, vel))
            out.append(self.position)
        if all(math.isfinite(c) for c in q):
            self.attitude = Attitude(now, q, (float(m.rollspeed), float(m.pitchspeed),
                                              float(m.yawspeed)))
            out.append(self.attitude)
        return out

    def _on_attitude_quaternion(self, m: MavMessage, now: float) -> list[TelemetryEvent]:
        v = _attitude(now, (float(m.q1), float(m.q2), float(m.q3), float(m.q4)),
                      (float(m.rollspeed), float(m.pitchspeed), float(m.yawspeed)))
        self.attitude = v
        return [v]

    def _on_global_position_int(self, m: MavMessage, now: float) -> list[TelemetryEvent]:
        v = GlobalPosition(now, m.lat * 1e-7, m.lon * 1e-7, m.alt * 1e-3, m.relative_alt * 1e-3,
                           (m.vx * 1e-2, m.vy * 1e-2, m.vz * 1e-2))
        self.global_position = v
        return [v]

    def _on_home_position(self, m: MavMessage, now: float) -> list[TelemetryEvent]:
        v = HomePosition(now, m.latitude * 1e-7, m.longitude * 1e-7, m.altitude * 1e-3,
                         (float(m.x), float(m.y), float(m.z)))
        self.home = v
        return [v]

    def _on_sys_status(self, m: MavMessage, now: float) -> list[TelemetryEvent]:
        v = SystemStatus(now, int(m.onboard_control_sensors_present),
                         int(m.onboard_control_sensors_enabled),
                         int(m.onboard_control_sensors_health), int(m.battery_remaining),
                         m.voltage_battery * 1e-3)
        self.sys_status = v
        return [v]

    def _on_extended_sys_state(self, m: MavMessage, now: float) -> list[TelemetryEvent]:
        v = ExtendedState(now, int(m.landed_state), int(m.vtol_state))
        self.extended = v
        return [v]

    def _on_mission_current(self, m: MavMessage, now: float) -> list[TelemetryEvent]:
        v = MissionCurrent(now, int(m.seq), int(getattr(m, "total", 0)), mission_id_of(m))
        self.mission_current = v
        return [v]

    def _on_statustext(self, m: MavMessage, now: float) -> list[TelemetryEvent]:
        text = m.text if isinstance(m.text, str) else bytes(m.text).decode("utf-8", "replace")
        text = text.split("\x00", 1)[0]
        sid = int(getattr(m, "id", 0))
        sev = int(m.severity)
        if sid == 0:
            return [StatusText(now, sev, text)]
        ch = self._chunks.setdefault(sid, _Chunks(sev, t_first=now))
        ch.parts[int(getattr(m, "chunk_seq", 0))] = text
        if len(text) < 50:  # the last chunk is shorter than the 50-char field
            return [self._flush(sid, now)]
        return []

    def _flush(self, sid: int, now: float) -> StatusText:
        ch = self._chunks.pop(sid)
        return StatusText(now, ch.severity, "".join(ch.parts[k] for k in sorted(ch.parts)))

    def handle_timer(self, now: float) -> list[TelemetryEvent]:
        """Emit chunked STATUSTEXTs whose final chunk never came."""
        old = [sid for sid, ch in self._chunks.items()
               if now - ch.t_first >= self.statustext_timeout_s]
        return [self._flush(sid, now) for sid in old]

    def next_deadline(self) -> float | None:
        """When pending STATUSTEXT chunks time out."""
        return min((c.t_first + self.statustext_timeout_s for c in self._chunks.values()),
                   default=None)


def mission_id_of(msg: MavMessage) -> int:
    """MISSION_CURRENT's ``mission_id`` extension (uint32 at payload offset 6; MAVLink 2 trims
    trailing zero bytes, so a short payload is zero-extended); 0 if absent."""
    buf = bytes(msg.get_msgbuf())
    if len(buf) < 10 or buf[0] != 0xFD:
        return 0
    payload = buf[10:10 + buf[1]].ljust(10, b"\x00")
    return int.from_bytes(payload[6:10], "little")
