"""Ground rover model: an Ackermann-steered car driven by PX4 main's rover control structure.

Vehicle (after SIH's Ackermann rover in PX4 main, airframe 10045 `sihsim_rover_ackermann`;
written anew): state north, east [m], heading yaw [rad], forward speed v [m/s] (negative when
reversing), yaw rate r [rad/s], and the throttle and steering actuators, each following PX4's
normalised output with a first-order lag SIH_T_TAU [s].
- Drive: a force THROTTLE_FORCE_N x throttle along the heading, mass SIH_MASS; resistance as SIH
  has it: static friction (MU_STATIC m g, below V_STATIC), kinetic (MU_KINETIC m g, below
  V_ROLLING; a rover without throttle stops there), rolling (MU_ROLLING m g) and a quadratic drag
  k(psi) v|v|. SIH applies SIH_KDV per earth-centred (ECEF) axis, which makes the along-track
  drag depend on the heading: k(psi) = SIH_KDV sum_i |u_i|^3 with u the heading's ECEF unit
  vector at home (0.70 SIH_KDV northbound, 0.97 SIH_KDV eastbound at PX4's SITL home). The
  sideways part of that drag is left out.
- Steering: the wheel angle delta = RA_MAX_STR_ANG x steering. No slip: the velocity is along the
  heading. The yaw rate relaxes to the Ackermann rate v tan(delta) / RA_WHEEL_BASE with the
  bicycle model's tyre dynamics (cornering stiffness CORNERING_STIFFNESS, inertia SIH_IZZ) and
  SIH's yaw damping SIH_KDW:  Izz r' = C L^2 / |v| (v tan(delta) / L - r) - SIH_KDW r,
  integrated exactly over each step; in steady state r = v tan(delta) / L / (1 + SIH_KDW |v| /
  (C L^2)): at low speed the turning radius at full steering is L / tan(RA_MAX_STR_ANG), faster
  it widens (understeer). Below V_ROLLING only the damping acts. The rover cannot turn on the
  spot: the yaw rate needs speed.
- Position: exact arcs with the step's mean speed and yaw rate; flat ground (z = 0).
- Estimate (EKF2's error on SIH, estimate_error.py; off by default): north / east position and
  velocity errors (SIM_EST_XY_STD [m], SIM_EST_VXY_STD [m/s], SIM_EST_XY_TAU [s], as the
  quadrotor's) and a heading error (SIM_EST_YAW_STD [deg], SIM_EST_YAW_TAU [s]), advanced every
  physics step; the position estimate also leads the truth by SIM_EST_LEAD_S of travel (EKF2's
  on SIH: ~0.1 s), and the heading carries a bias drawn once per start (std SIM_EST_YAW_BIAS
  [deg]). The control loops and the navigator steer by the estimate (position, heading, forward
  speed = the velocity estimate along the estimated heading; the yaw rate is the true
  one: no gyro model) and `state` / `attitude` (the telemetry) report it; `true_state` is the
  truth (HIL_STATE_QUATERNION on request).

Control (`sitl_mock.rover_control`, PX4's stages; runs every physics step):
- RoverPositionTarget (AUTO modes, from the navigator): pure pursuit along start -> goal, braking
  law towards the arrival speed, stop within the acceptance radius; position NaN: stop (Hold).
- PositionTarget (OFFBOARD): a horizontal position is a goal as above with the line starting at
  the rover (PX4: start NaN), arrival 0, RO_SPEED_LIM, acceptance NAV_ACC_RAD; else a horizontal
  velocity is speed |v| along bearing atan2(v_e, v_n) (PX4's rover ignores yaw, yaw rate,
  acceleration and the vertical); anything else stops the rover.
- AttitudeTarget: not supported by PX4's rovers (docs: SET_ATTITUDE_TARGET "not supported for rover
  offboard control"); the rover stops. IdleTarget or disarmed: outputs zero (PX4's stopVehicle).
"""

from __future__ import annotations

import math
import random

from sitl_mock.estimate_error import (
    advance_gauss_markov,
    horizontal_config,
    lead_config,
    yaw_bias_config,
    yaw_config,
)
from sitl_mock.flight_control import quat_from_yaw, wrap_pi
from sitl_mock.params import ROVER_AIRFRAME, ParamStore
from sitl_mock.rover_control import AckermannController, RoverParams, position_control
from sitl_mock.setpoints import (
    IdleTarget,
    PositionTarget,
    Quat,
    RoverPositionTarget,
    Target,
    Vec3,
)
from sitl_mock.vehicle_state import AttitudeTargetReport, VehicleState

_isfinite = math.isfinite
_NAN = math.nan
G = 9.81  # SIH's gravity for its friction forces [m/s^2]
THROTTLE_FORCE_N = 400.0  # SIH: drive force at full throttle [N]
CORNERING_STIFFNESS = 500.0  # SIH: tyre cornering stiffness [N/rad]
MU_STATIC = 0.5  # SIH: static friction coefficient
MU_KINETIC = 0.4  # SIH: kinetic friction coefficient
MU_ROLLING = 0.3  # SIH: rolling resistance coefficient
V_STATIC = 0.01  # SIH: below this speed static friction holds the rover [m/s]
V_ROLLING = 0.05  # SIH: below this speed kinetic friction, no tyre forces [m/s]


def ecef_axes(lat_deg: float, lon_deg: float) -> tuple[Vec3, Vec3]:
    """(north, east) unit vectors at (lat, lon) in earth-centred earth-fixed coordinates."""
    la, lo = math.radians(lat_deg), math.radians(lon_deg)
    sla, cla, slo, clo = math.sin(la), math.cos(la), math.sin(lo), math.cos(lo)
    return (-sla * clo, -sla * slo, cla), (-slo, clo, 0.0)


class Rover:
    """Ackermann ground vehicle under PX4-like rover control; see the module docstring.

    Applies airframe 10045's defaults (`ROVER_AIRFRAME`: NAV_ACC_RAD 0.5, SIH_MASS 20, ...) to
    `params` where the user has not set them, as PX4's airframe script does at boot.
    """

    kind = "rover"

    def __init__(
        self,
        params: ParamStore,
        home_lat_lon_alt: tuple[float, float, float] = (47.397742, 8.545594, 488.0),
        seed: int = 0,
    ) -> None:
        params.apply_airframe(ROVER_AIRFRAME)
        self._params = params
        self._home = home_lat_lon_alt
        self._seed = seed
        self._north_ecef, self._east_ecef = ecef_axes(home_lat_lon_alt[0], home_lat_lon_alt[1])
        self._t = 0.0
        self._x = self._y = 0.0
        self._yaw = 0.0
        self._v = 0.0
        self._r = 0.0
        self._throttle = 0.0  # actuator states after SIH's lag, -1..1
        self._steering = 0.0
        self._acc: Vec3 = (0.0, 0.0, 0.0)
        self._armed = False
        self._battery = 1.0
        self._local_pos_valid = True
        self._wind: Vec3 = (0.0, 0.0, 0.0)
        self._ctl = AckermannController()
        self._last_pos_target: PositionTarget | None = None
        self._p_version = -1
        self._p = RoverParams.read(params)
        # estimate errors (SIM_EST_*): (driving state, error) for north, east position and
        # velocity, and for the heading; each group from its own random stream
        self._est: list[float] = [0.0] * 8
        self._est_yaw: list[float] = [0.0] * 2
        self._est_rng = random.Random(seed)
        self._est_yaw_rng = random.Random(seed * 7919 + 104729)
        # this start's heading bias, in units of SIM_EST_YAW_BIAS (one draw per vehicle)
        self._est_yaw_z = random.Random(seed * 104729 + 7919).gauss(0.0, 1.0)
        self._est_injected = False
        self._read_estimator()

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
        """Restart the control loops from the measured state (PX4 resets its rover controllers
        on every mode change)."""
        _x, _y, yaw, v = self._measured()
        self._ctl.reset(v, yaw, self._r)

    def set_estimate_error(self, pos_ne: tuple[float, float] = (0.0, 0.0),
                           vel_ne: tuple[float, float] = (0.0, 0.0), yaw: float = 0.0) -> None:
        """Tests: the estimate error now (estimate = truth + error): north, east position [m],
        velocity [m/s], heading [rad]. It evolves as SIM_EST_* say from here; while they are 0
        it stays as set."""
        e, h = self._est, self._est_yaw
        e[0], e[1], e[2], e[3] = pos_ne[0], pos_ne[0], pos_ne[1], pos_ne[1]
        e[4], e[5], e[6], e[7] = vel_ne[0], vel_ne[0], vel_ne[1], vel_ne[1]
        h[0] = h[1] = yaw
        self._est_injected = True
        self._read_estimator()

    def set_state(self, north_m: float, east_m: float, yaw: float, speed: float = 0.0) -> None:
        """Place the rover (tests, replays): position [m], heading [rad], forward speed [m/s]."""
        self._x, self._y, self._yaw, self._v = float(north_m), float(east_m), float(yaw), speed
        self._r = 0.0
        self._ctl.reset(speed, self._yaw, 0.0)

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
        """= (`state.q_wxyz`, `state.omega_frd`): level, the estimated heading; yaw rate only."""
        return quat_from_yaw(self._yaw_estimate()), (0.0, 0.0, self._r)

    @property
    def steering(self) -> float:
        """Steering actuator -1..1 (after SIH's lag): the wheel angle / RA_MAX_STR_ANG."""
        return self._steering

    @property
    def throttle(self) -> float:
        """Throttle actuator -1..1 (after SIH's lag)."""
        return self._throttle

    @property
    def last_attitude_target(self) -> AttitudeTargetReport:
        """(q_wxyz, body_rates_frd, thrust_norm): the yaw and yaw-rate setpoints of the control
        loops and the throttle magnitude."""
        c = self._ctl
        return quat_from_yaw(c.attitude.adjusted), (0.0, 0.0, c.rate_sp), abs(self._throttle)

    @property
    def last_position_target(self) -> PositionTarget | None:
        """What the rover drives to, as a PositionTarget (POSITION_TARGET_LOCAL_NED): the goal
        (NaN without one), the speed setpoint after the acceleration slew (RO_ACCEL_LIM /
        RO_DECEL_LIM) along the bearing, the bearing as yaw; None while idle or disarmed."""
        return self._last_pos_target

    @property
    def state(self) -> VehicleState:
        """Snapshot as the estimator sees the rover (z = 0, level attitude, on the ground;
        landed while disarmed): the truth plus the estimate errors (module docstring)."""
        return self._snapshot(*self._estimate())

    @property
    def true_state(self) -> VehicleState:
        """Snapshot of the true motion (= `state` while the estimate is ideal)."""
        c, s = math.cos(self._yaw), math.sin(self._yaw)
        return self._snapshot(self._x, self._y, self._yaw, self._v * c, self._v * s)

    @property
    def true_pos_ned(self) -> Vec3:
        """True position [m NED], without the estimate error that `state` carries."""
        return (self._x, self._y, 0.0)

    @property
    def true_vel_ned(self) -> Vec3:
        """True velocity [m/s NED]."""
        return (self._v * math.cos(self._yaw), self._v * math.sin(self._yaw), 0.0)

    def _estimate(self) -> tuple[float, float, float, float, float]:
        """(north, east [m], heading [rad], velocity north, east [m/s]): the estimate."""
        c, s = math.cos(self._yaw), math.sin(self._yaw)
        if not self._est_on:
            return self._x, self._y, self._yaw, self._v * c, self._v * s
        e, lead = self._est, self._est_lead * self._v
        return (self._x + e[1] + lead * c, self._y + e[3] + lead * s, self._yaw_estimate(),
                self._v * c + e[5], self._v * s + e[7])

    def _yaw_estimate(self) -> float:
        """The heading estimate [rad]: the truth plus its error and this start's bias."""
        if not self._est_on:
            return self._yaw
        return wrap_pi(self._yaw + self._est_yaw[1] + self._est_yaw_bias)

    def _measured(self) -> tuple[float, float, float, float]:
        """(north, east [m], heading [rad], forward speed [m/s]) as the control loops read them:
        the estimate, its velocity along its heading (PX4: the body-x velocity)."""
        if not self._est_on:
            return self._x, self._y, self._yaw, self._v
        x, y, yaw, vn, ve = self._estimate()
        return x, y, yaw, vn * math.cos(yaw) + ve * math.sin(yaw)

    def _snapshot(self, x: float, y: float, yaw: float, vn: float, ve: float) -> VehicleState:
        return VehicleState(
            t_s=self._t,
            pos_ned=(x, y, 0.0),
            vel_ned=(vn, ve, 0.0),
            acc_ned=self._acc,
            q_wxyz=quat_from_yaw(yaw),
            omega_frd=(0.0, 0.0, self._r),
            on_ground=True,
            landed=not self._armed,
            thrust_norm=abs(self._throttle),
            battery_remaining=self._battery,
            local_position_valid=self._local_pos_valid,
            home_lat_lon_alt=self._home,
        )

    # ------------------------------------------------------------------ physics
    def drag_coefficient(self, yaw: float) -> float:
        """Along-track quadratic drag [N/(m/s)^2] heading `yaw` (SIH_KDV per ECEF axis)."""
        c, s = math.cos(yaw), math.sin(yaw)
        n, e = self._north_ecef, self._east_ecef
        return self._params["SIH_KDV"] * sum(abs(c * n[i] + s * e[i]) ** 3 for i in range(3))

    def _speed_step(self, v: float, force: float, dt: float) -> float:
        """Forward speed after `dt` with drive `force` [N] (SIH's friction regimes)."""
        p = self._params
        m = p["SIH_MASS"]
        if abs(v) < V_STATIC:
            stiction = MU_STATIC * m * G
            if abs(force) <= stiction:
                return 0.0
            return v + (force - math.copysign(stiction, force)) / m * dt
        if abs(v) < V_ROLLING:
            if force == 0.0:
                return 0.0  # SIH stops a rover without throttle at once
            resist = MU_KINETIC * m * G
        else:
            resist = MU_ROLLING * m * G + self.drag_coefficient(self._yaw) * v * v
        new = v + (force - math.copysign(resist, v)) / m * dt
        if new * v < 0.0 and abs(force) <= resist:
            return 0.0  # resistance stops the rover, it does not push it back
        return new

    def _rate_step(self, r: float, v_mean: float, delta: float, dt: float) -> float:
        """Yaw rate after `dt` (module docstring), exact for a constant speed and wheel angle."""
        p = self._params
        izz, kdw, wb = p["SIH_IZZ"], p["SIH_KDW"], p["RA_WHEEL_BASE"]
        damping = kdw / izz
        if abs(v_mean) < V_ROLLING:
            return r * math.exp(-damping * dt)
        tyre = CORNERING_STIFFNESS * wb * wb / (izz * abs(v_mean))
        r_kin = v_mean * math.tan(delta) / wb
        rate = tyre + damping
        r_ss = tyre * r_kin / rate
        return r_ss + (r - r_ss) * math.exp(-rate * dt)

    # ------------------------------------------------------------------ control
    def _goal(self, target: Target) -> RoverPositionTarget | tuple[float, float] | None:
        """What `target` asks of the rover: a position goal, a (speed, bearing) or None (stop)."""
        if isinstance(target, RoverPositionTarget):
            return target
        if isinstance(target, PositionTarget):
            (px, py, _), (vx, vy, _) = target.pos_ned, target.vel_ned
            if _isfinite(px) and _isfinite(py):
                return RoverPositionTarget(
                    (px, py), arrival_speed=0.0, acceptance_radius_m=self._p.nav_acc_rad_m)
            if _isfinite(vx) and _isfinite(vy):
                return math.hypot(vx, vy), math.atan2(vy, vx)
        return None

    def _control(self, dt: float, target: Target, armed: bool) -> tuple[float, float]:
        """(throttle, steering) actuator commands -1..1 for this step."""
        ctl = self._ctl
        x, y, yaw, v = self._measured()
        if not armed or isinstance(target, IdleTarget):
            ctl.actuators.stop()
            ctl.reset(v, yaw, self._r)
            self._last_pos_target = None
            return 0.0, 0.0
        goal = self._goal(target)
        if isinstance(goal, RoverPositionTarget):
            speed, bearing = position_control(goal, (x, y), yaw, self._p)
            gx, gy = goal.position_ne
        elif goal is None:  # stop, heading as it is
            speed, bearing, gx, gy = 0.0, yaw, _NAN, _NAN
        else:
            speed, bearing = goal
            gx = gy = _NAN
        out = ctl.drive(speed, bearing, v, yaw, self._r, dt, self._p)
        adj = ctl.speed.adjusted.value  # the speed setpoint after PX4's acceleration slew
        self._last_pos_target = PositionTarget(
            (gx, gy, _NAN), (adj * math.cos(bearing), adj * math.sin(bearing), _NAN),
            yaw=bearing)
        return out

    def step(self, dt: float, target: Target, armed: bool) -> None:
        """Run the control loops, then integrate actuators, speed, yaw rate and pose over dt."""
        self._begin_step(dt, armed)
        self._integrate(dt, *self._control(dt, target, armed))

    def step_actuators(self, dt: float, throttle: float, steering: float) -> None:
        """The vehicle alone, armed, without the control loops: PX4's actuator outputs
        (normalised throttle and steering, -1..1) held for `dt` [s] (tests of the physics)."""
        self._begin_step(dt, True)
        self._integrate(dt, min(max(throttle, -1.0), 1.0), min(max(steering, -1.0), 1.0))

    def _begin_step(self, dt: float, armed: bool) -> None:
        if not (dt > 0.0 and dt < 1.0):
            raise ValueError(f"physics step must be in (0, 1) s, got {dt!r}")
        p = self._params
        if p.version != self._p_version:
            self._p = RoverParams.read(p)
            self._p_version = p.version
            self._read_estimator()
        if self._est_xy_on:
            std_p, std_v, tau = self._est_xy
            advance_gauss_markov(self._est, (std_p, std_p, std_v, std_v), tau, dt,
                                 self._est_rng.gauss)
        if self._est_yaw_on:
            std_yaw, tau_yaw = self._est_yaw_cfg
            advance_gauss_markov(self._est_yaw, (std_yaw,), tau_yaw, dt, self._est_yaw_rng.gauss)
        self._t += dt
        self._armed = armed
        if armed:
            drain = max(p["SIM_BAT_DRAIN"], 1.0)
            self._battery = max(p["SIM_BAT_MIN_PCT"] / 100.0, self._battery - dt / drain)

    def _read_estimator(self) -> None:
        """The SIM_EST_* parameters; the estimate is the truth unless one is on or an error was
        set (`set_estimate_error`)."""
        self._est_xy = horizontal_config(self._params)
        self._est_yaw_cfg = yaw_config(self._params)
        self._est_xy_on = self._est_xy[0] > 0.0 or self._est_xy[1] > 0.0
        self._est_yaw_on = self._est_yaw_cfg[0] > 0.0
        self._est_lead = lead_config(self._params)
        self._est_yaw_bias = yaw_bias_config(self._params) * self._est_yaw_z
        self._est_on = (self._est_xy_on or self._est_yaw_on or self._est_lead > 0.0
                        or self._est_yaw_bias != 0.0 or self._est_injected)

    def _integrate(self, dt: float, thr_cmd: float, steer_cmd: float) -> None:
        p = self._params
        lag = 1.0 - math.exp(-dt / max(p["SIH_T_TAU"], 1e-6))
        self._throttle += lag * (thr_cmd - self._throttle)
        self._steering += lag * (steer_cmd - self._steering)
        v0, yaw0, r0 = self._v, self._yaw, self._r
        v1 = self._speed_step(v0, THROTTLE_FORCE_N * self._throttle, dt)
        vm = 0.5 * (v0 + v1)
        r1 = self._rate_step(r0, vm, p["RA_MAX_STR_ANG"] * self._steering, dt)
        rm = 0.5 * (r0 + r1)
        if abs(rm) > 1e-9:
            yaw1 = yaw0 + rm * dt
            self._x += vm / rm * (math.sin(yaw1) - math.sin(yaw0))
            self._y -= vm / rm * (math.cos(yaw1) - math.cos(yaw0))
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
        self._v, self._r = v1, r1
