"""Ground rover model: a unicycle with speed, acceleration and yaw-rate limits.

State: position (north, east), heading yaw, forward speed v >= 0 (no reversing), yaw rate r.
Kinematics: x' = v cos(yaw), y' = v sin(yaw), yaw' = r, integrated exactly along circular arcs.
Limits: |v| <= RO_MAX_SPEED, |v'| <= RO_MAX_ACCEL, |r| <= RO_MAX_YAW_RATE. No slip, no dynamics
beyond these limits, flat ground (z = 0).

Control (its own simple controller, not PX4's rover stack):
- PositionTarget with a horizontal position: drive to it (heading to the point, speed limited by
  the braking distance sqrt(2 a d) and by the heading error), then hold; `yaw` turns in place
  once there.
- PositionTarget with a horizontal velocity: speed |v_xy|, heading along it (or `yaw` if given
  and the speed is ~0); `yaw_rate` alone turns in place at that rate.
- AttitudeTarget: heading from q (yaw), speed = thrust_norm * RO_MAX_SPEED; body rates: yaw
  rate from body_rates_frd[2] (rates win over q, as for the quadrotor).
- IdleTarget or disarmed: brake to a stop.
"""

from __future__ import annotations

import math

from sitl_mock.flight_control import quat_from_yaw, quat_yaw, wrap_pi
from sitl_mock.params import ParamStore
from sitl_mock.setpoints import AttitudeTarget, PositionTarget, Quat, Target, Vec3
from sitl_mock.vehicle_state import AttitudeTargetReport, VehicleState

_isfinite = math.isfinite
HEADING_GAIN = 2.5  # yaw-rate command per rad of heading error [1/s]
POS_GAIN = 1.0  # speed command per m of distance [1/s]
ARRIVE_RADIUS_M = 0.2


class Rover:
    """Unicycle ground vehicle; see the module docstring."""

    kind = "rover"

    def __init__(
        self,
        params: ParamStore,
        home_lat_lon_alt: tuple[float, float, float] = (47.397742, 8.545594, 488.0),
        seed: int = 0,
    ) -> None:
        self._params = params
        self._home = home_lat_lon_alt
        self._seed = seed
        self._t = 0.0
        self._x = self._y = 0.0
        self._yaw = 0.0
        self._v = 0.0
        self._r = 0.0
        self._acc: Vec3 = (0.0, 0.0, 0.0)
        self._armed = False
        self._battery = 1.0
        self._local_pos_valid = True
        self._wind: Vec3 = (0.0, 0.0, 0.0)
        self._yaw_hold: float | None = None
        self._cmd_v = 0.0
        self._cmd_r = 0.0
        self._q_sp: Quat = (1.0, 0.0, 0.0, 0.0)
        self._last_pos_target: PositionTarget | None = None

    # ------------------------------------------------------------------ interface
    def set_wind(self, vel_ned: Vec3) -> None:
        """Wind has no effect on the rover (stored for completeness)."""
        self._wind = (float(vel_ned[0]), float(vel_ned[1]), float(vel_ned[2]))

    def set_local_position_valid(self, valid: bool) -> None:
        """Fault injection flag only."""
        self._local_pos_valid = bool(valid)

    def set_battery_remaining(self, fraction: float) -> None:
        """Force the battery state of charge (0..1)."""
        self._battery = min(max(float(fraction), 0.0), 1.0)

    def reset_integrators(self) -> None:
        """No integrators; releases the heading hold."""
        self._yaw_hold = None

    def set_state(self, north_m: float, east_m: float, yaw: float, speed: float = 0.0) -> None:
        """Place the rover (tests, replays)."""
        self._x, self._y, self._yaw, self._v = float(north_m), float(east_m), float(yaw), speed

    @property
    def landed(self) -> bool:
        """= `state.landed`: landed while disarmed."""
        return not self._armed

    @property
    def local_position_valid(self) -> bool:
        """= `state.local_position_valid` (False while a position-loss fault is injected)."""
        return self._local_pos_valid

    @property
    def battery_remaining(self) -> float:
        """= `state.battery_remaining`: state of charge 0..1."""
        return self._battery

    @property
    def attitude(self) -> tuple[Quat, Vec3]:
        """= (`state.q_wxyz`, `state.omega_frd`): level, heading yaw; yaw rate only."""
        return quat_from_yaw(self._yaw), (0.0, 0.0, self._r)

    @property
    def last_attitude_target(self) -> AttitudeTargetReport:
        """(q_wxyz, body_rates_frd, thrust_norm): heading and speed fraction commanded."""
        vmax = max(self._params["RO_MAX_SPEED"], 1e-6)
        return self._q_sp, (0.0, 0.0, self._cmd_r), min(abs(self._cmd_v) / vmax, 1.0)

    @property
    def last_position_target(self) -> PositionTarget | None:
        """Last PositionTarget tracked."""
        return self._last_pos_target

    @property
    def state(self) -> VehicleState:
        """Snapshot (z = 0, level attitude, on the ground; landed while disarmed)."""
        pos = (self._x, self._y, 0.0)
        c, s = math.cos(self._yaw), math.sin(self._yaw)
        vmax = max(self._params["RO_MAX_SPEED"], 1e-6)
        return VehicleState(
            t_s=self._t,
            pos_ned=pos,
            vel_ned=(self._v * c, self._v * s, 0.0),
            acc_ned=self._acc,
            q_wxyz=quat_from_yaw(self._yaw),
            omega_frd=(0.0, 0.0, self._r),
            on_ground=True,
            landed=not self._armed,
            thrust_norm=min(abs(self._v) / vmax, 1.0),
            battery_remaining=self._battery,
            local_position_valid=self._local_pos_valid,
            home_lat_lon_alt=self._home,
        )

    # ------------------------------------------------------------------ control
    def _heading_rate(self, heading: float) -> float:
        return HEADING_GAIN * wrap_pi(heading - self._yaw)

    def _control(self, target: Target, armed: bool) -> tuple[float, float]:
        """(speed command [m/s], yaw-rate command [rad/s]) before limits."""
        if not armed or not isinstance(target, (PositionTarget, AttitudeTarget)):
            self._last_pos_target = None
            self._yaw_hold = None
            return 0.0, 0.0
        if isinstance(target, AttitudeTarget):
            self._last_pos_target = None
            th = target.thrust_norm if _isfinite(target.thrust_norm) else 0.0
            v = max(0.0, min(th, 1.0)) * self._params["RO_MAX_SPEED"]
            if target.body_rates_frd is not None and _isfinite(target.body_rates_frd[2]):
                return v, target.body_rates_frd[2]
            if target.q_wxyz is not None:
                return v, self._heading_rate(quat_yaw(target.q_wxyz))
            return v, 0.0
        self._last_pos_target = target
        amax = max(self._params["RO_MAX_ACCEL"], 1e-3)
        (px, py, _), (vx, vy, _) = target.pos_ned, target.vel_ned
        if self._yaw_hold is None:
            self._yaw_hold = self._yaw
        if _isfinite(target.yaw):
            self._yaw_hold = target.yaw
        if _isfinite(px) and _isfinite(py):
            dx, dy = px - self._x, py - self._y
            dist = math.hypot(dx, dy)
            if dist > ARRIVE_RADIUS_M:
                heading = math.atan2(dy, dx)
                err = wrap_pi(heading - self._yaw)
                v = min(POS_GAIN * dist, math.sqrt(2.0 * amax * dist))
                if _isfinite(vx) and _isfinite(vy):
                    v = max(v, math.hypot(vx, vy))
                v *= max(0.0, math.cos(err))
                return v, HEADING_GAIN * err
            return 0.0, self._heading_rate(self._yaw_hold)
        if _isfinite(vx) and _isfinite(vy):
            sp = math.hypot(vx, vy)
            if sp > 0.05:
                heading = math.atan2(vy, vx)
                err = wrap_pi(heading - self._yaw)
                return sp * max(0.0, math.cos(err)), HEADING_GAIN * err
        if _isfinite(target.yaw_rate) and not _isfinite(target.yaw):
            self._yaw_hold = self._yaw
            return 0.0, target.yaw_rate
        return 0.0, self._heading_rate(self._yaw_hold)

    def step(self, dt: float, target: Target, armed: bool) -> None:
        """Apply the controller and the limits, then integrate the unicycle exactly over dt."""
        if not (dt > 0.0 and dt < 1.0):
            raise ValueError(f"physics step must be in (0, 1) s, got {dt!r}")
        p = self._params
        self._t += dt
        self._armed = armed
        if armed:
            drain = max(p["SIM_BAT_DRAIN"], 1.0)
            self._battery = max(p["SIM_BAT_MIN_PCT"] / 100.0, self._battery - dt / drain)
        v_cmd, r_cmd = self._control(target, armed)
        vmax = max(p["RO_MAX_SPEED"], 0.0)
        amax = max(p["RO_MAX_ACCEL"], 1e-3)
        rmax = math.radians(max(p["RO_MAX_YAW_RATE"], 0.0))
        v_cmd = min(max(v_cmd if _isfinite(v_cmd) else 0.0, 0.0), vmax)
        r_cmd = min(max(r_cmd if _isfinite(r_cmd) else 0.0, -rmax), rmax)
        self._cmd_v, self._cmd_r = v_cmd, r_cmd
        self._q_sp = quat_from_yaw(self._yaw_hold if self._yaw_hold is not None else self._yaw)
        dv = min(max(v_cmd - self._v, -amax * dt), amax * dt)
        v0, yaw0 = self._v, self._yaw
        v1 = v0 + dv
        vm = 0.5 * (v0 + v1)
        r = r_cmd
        if abs(r) > 1e-9:
            yaw1 = yaw0 + r * dt
            self._x += vm / r * (math.sin(yaw1) - math.sin(yaw0))
            self._y -= vm / r * (math.cos(yaw1) - math.cos(yaw0))
        else:
            yaw1 = yaw0
            self._x += vm * dt * math.cos(yaw0)
            self._y += vm * dt * math.sin(yaw0)
        self._yaw = wrap_pi(yaw1)
        self._acc = (
            (v1 * math.cos(yaw1) - v0 * math.cos(yaw0)) / dt,
            (v1 * math.sin(yaw1) - v0 * math.sin(yaw0)) / dt,
            0.0,
        )
        self._v, self._r = v1, r
