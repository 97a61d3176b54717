"""Quadrotor model: PX4 SIH-like 6-DOF rigid body plus the PX4-like control cascade.

Physics (world NED, body FRD, SI units), defaults from PX4 SIH (SIH_* parameters):
- four rotors in X configuration, rotor i thrust = SIH_T_MAX * u_i with a first-order lag
  SIH_T_TAU on u_i; roll/pitch torque from the arm lengths SIH_L_ROLL/SIH_L_PITCH, yaw torque
  SIH_Q_MAX * u_i with the rotor's spin sign (PX4 quad X: 0 FR ccw, 1 RL ccw, 2 FL cw, 3 RR cw);
- linear drag -SIH_KDV * (v - wind) in the world frame, angular drag -SIH_KDW * omega;
- rigid-body rotation with the full Euler equations (gyroscopic term), quaternion attitude
  integrated with the exponential map and renormalised each step;
- flat ground at z = 0 (home altitude): no sinking; on contact the vehicle stops (friction) and
  sits level, like SIH; it lifts off as soon as the thrust exceeds the weight.

Control: flight_control.py (position loop <= 100 Hz, attitude loop <= 250 Hz, rate loop
<= 500 Hz; motor commands are held between rate-loop ticks), PX4's takeoff handling (spool-up,
ready, thrust ramp, flight) and a PX4-like land detector. Sensor noise (SIM_*_NOISE) is added to
what the controller and `state` see.
"""

from __future__ import annotations

import math
import random

from sitl_mock.flight_control import (
    AngularVelocityFilter,
    G,
    McGains,
    PositionVelocityController,
    RateController,
    attitude_control,
    body_z_to_attitude,
    mix_quad_x,
    quat_from_yaw,
    quat_normalize,
    quat_yaw,
    wrap_pi,
)
from sitl_mock.params import ParamStore
from sitl_mock.setpoints import AttitudeTarget, PositionTarget, Quat, Target, Vec3
from sitl_mock.vehicle import AttitudeTargetReport, VehicleState, make_state

_isfinite = math.isfinite

# takeoff states (PX4 TakeoffHandling)
DISARMED, SPOOLUP, READY, RAMPUP, FLIGHT = range(5)
_TAKEOFF_STATE_NAMES = ("disarmed", "spoolup", "ready_for_takeoff", "rampup", "flight")

POS_LOOP_PERIOD_S = 0.01
PARAM_REFRESH_S = 0.1
GUST_PERIOD_S = 0.02  # the gust process is updated at 50 Hz (held in between)
MAX_STEP_S = 1.0 / 250.0  # longer steps are split (integration always at >= 250 Hz)
ATT_LOOP_PERIOD_S = 0.004
RATE_LOOP_PERIOD_S = 0.002  # rate loop at <= 500 Hz (every physics step below 500 Hz)
#: Rate [Hz] at which a change of the offboard attitude-target kind (attitude <-> body rates)
#: reaches the controllers. PX4 v1.16: the commander republishes vehicle_control_mode "at 2 Hz or
#: immediately when changed" (Commander::run: 500 ms since the last vehicle_status publish, a
#: status change or a nav-state change), and a changed offboard_control_mode is not a status
#: change (Commander::offboardControlCheck). Measured on PX4 v1.16 SITL: a 60 deg/s rates step
#: right after attitude setpoints reached 50 % after 0.20-0.84 s (three flights), beyond what a
#: 10 Hz cycle allows (<= ~0.15 s). The cycle restarts when attitude control is entered (PX4: the
#: immediate publish of a nav-state change)
CONTROL_MODE_RATE_HZ = 2.0
#: SIH's sensor period in PX4 SITL (IMU_INTEG_RATE 250 Hz): its gyro noise is per sample of this
#: period; the mock scales it to its rate-loop period so the noise density (and what the
#: IMU_GYRO_CUTOFF filter lets through) does not depend on the physics rate
SIH_IMU_PERIOD_S = 0.004
#: SIH's gyro noise std per sample while the rotors push, roll/pitch/yaw [rad/s]
#: (SIH reconstruct_sensors_signals; times SIM_GYRO_SIH)
SIH_GYRO_NOISE = (0.14, 0.07, 0.03)
#: Touching the ground while the position controller asks for more than this descent rate
#: [m/s] is "ground contact" (PX4's land detector stage): the thrust is cut (see
#: `_control_position`); the land detector uses the same threshold. Half of PX4's landing crawl
#: (MPC_LAND_CRWL 0.3 m/s), so an AUTO landing that crawls onto the ground is detected.
GROUND_CONTACT_DESCENT_M_S = 0.15
_SPLIT_ABOVE_S = MAX_STEP_S + 1e-12
_RATE_TICK_S = RATE_LOOP_PERIOD_S - 1e-9



# Guards of the explicit integrator: parameter combinations at the ends of their ranges (a
# 0.05 kg vehicle with 100 N/(m/s) drag, 1e-4 kg m^2 inertia against 10 kg m^2) make it
# unstable; the state is held to these bounds (NaN -> 0) so the simulation goes on instead of
# overflowing. Never reached with physical parameters.
_W_LIMIT = 200.0  # body rate [rad/s]
_V_LIMIT = 1_000.0  # velocity [m/s]
_P_LIMIT = 1.0e7  # position [m]


def _bounded(xs: tuple[float, ...], limit: float) -> tuple[float, ...]:
    """Each value clamped to [-limit, limit]; NaN becomes 0."""
    return tuple(0.0 if x != x else max(-limit, min(limit, x)) for x in xs)


class Quadrotor:
    """PX4 SIH-like quadrotor with a PX4-like controller; see the module docstring."""

    kind = "quad"
    __slots__ = (
        "_alpha",
        "_alpha_dt",
        "_arm_t",
        "_armed_prev",
        "_att_acc",
        "_att_q",
        "_att_rates",
        "_att_tgt",
        "_att_thrust",
        "_ax",
        "_ay",
        "_az",
        "_bat_drain",
        "_bat_min",
        "_battery",
        "_cm_att",
        "_cm_q",
        "_cm_rates",
        "_cm_t0",
        "_cm_thrust",
        "_cm_tick",
        "_est",
        "_est_acc",
        "_est_cfg",
        "_gains",
        "_gust",
        "_gust_acc",
        "_gust_rng",
        "_gust_std",
        "_gust_tau",
        "_gyro",
        "_gyro_rate",
        "_gyro_rng",
        "_gyro_std",
        "_hdt",
        "_hdt2",
        "_home",
        "_idle",
        "_imu_cut",
        "_invdt",
        "_ixx",
        "_ixx_m_izz",
        "_iyy",
        "_iyy_m_ixx",
        "_izz",
        "_izz_m_iyy",
        "_kdv",
        "_kdw",
        "_land_detect_s",
        "_land_timer",
        "_landed",
        "_last_mode",
        "_last_pos_target",
        "_local_pos_valid",
        "_lpitch",
        "_lpitch_t",
        "_lroll",
        "_lroll_t",
        "_mass",
        "_motor_cmd",
        "_noise",
        "_npos",
        "_nvel",
        "_on_ground",
        "_param_acc",
        "_param_version",
        "_params",
        "_pos_acc",
        "_pvc",
        "_px",
        "_py",
        "_pz",
        "_q_sp",
        "_qmax",
        "_qw",
        "_qx",
        "_qy",
        "_qz",
        "_ramp_up_limit",
        "_rate_acc",
        "_rate_sp",
        "_rc",
        "_rng",
        "_state_cache",
        "_t",
        "_tau",
        "_thrust_sp",
        "_tko_state",
        "_tmax",
        "_touched",
        "_u",
        "_vx",
        "_vy",
        "_vz",
        "_wind",
        "_wind_base",
        "_wx",
        "_wy",
        "_wz",
        "_yaw_ff",
        "_yaw_hold",
    )

    def __init__(
        self,
        params: ParamStore,
        home_lat_lon_alt: tuple[float, float, float] = (47.397742, 8.545594, 488.0),
        seed: int = 0,
    ) -> None:
        self._params = params
        self._home = home_lat_lon_alt
        self._rng = random.Random(seed)
        self._state_cache: VehicleState | None = None
        self._att_tgt: AttitudeTarget | None = None
        self._att_thrust = 0.0
        self._att_q: Quat | None = None
        self._att_rates: Vec3 | None = None
        # control mode of attitude targets in effect: attitude control (True) or rates only,
        # the tick of its cycle (CONTROL_MODE_RATE_HZ, from `_cm_t0`), and the last setpoints of
        # each kind (held across a pending switch)
        self._cm_att = False
        self._cm_tick = -1
        self._cm_t0 = 0.0
        self._cm_q: Quat | None = None
        self._cm_rates: Vec3 = (0.0, 0.0, 0.0)
        self._cm_thrust = 0.0
        # rigid-body state
        self._t = 0.0
        self._px = self._py = self._pz = 0.0
        self._vx = self._vy = self._vz = 0.0
        self._ax = self._ay = 0.0
        self._az = 0.0
        self._qw, self._qx, self._qy, self._qz = 1.0, 0.0, 0.0, 0.0
        self._wx = self._wy = self._wz = 0.0
        self._u: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)  # rotor thrust 0..1
        self._on_ground = True
        self._touched = False
        self._wind: Vec3 = (0.0, 0.0, 0.0)  # steady wind + gust, what the physics sees
        self._wind_base: Vec3 = (0.0, 0.0, 0.0)
        self._gust: Vec3 = (0.0, 0.0, 0.0)
        self._gust_acc = 0.0
        # gusts draw from their own stream, so turning them on leaves the noise sequence alone
        self._gust_rng = random.Random(seed * 7919 + 104729)
        # SIH's gyro noise too: turning it on leaves the estimator and sensor noise alone
        self._gyro_rng = random.Random(seed * 6271 + 130363)
        # derived
        self._battery = 1.0
        self._local_pos_valid = True
        self._landed = True
        self._land_timer = 0.0
        # controllers
        self._gains = McGains.from_params(params)
        self._param_version: int | None = getattr(params, "version", None)
        self._pvc = PositionVelocityController()
        self._rc = RateController()
        self._gyro = AngularVelocityFilter()
        self._gyro_rate: Vec3 | None = None  # filtered gyro; None while idle (= true rates)
        self._pos_acc = math.inf
        self._att_acc = math.inf
        self._rate_acc = math.inf
        self._param_acc = 0.0
        self._alpha_dt = -1.0
        self._alpha = 0.0
        self._armed_prev = False
        self._arm_t = 0.0
        self._tko_state = DISARMED
        self._ramp_up_limit = 0.0
        self._yaw_hold: float | None = None
        self._q_sp: Quat = (1.0, 0.0, 0.0, 0.0)
        self._thrust_sp = 0.0
        self._yaw_ff = math.nan
        self._rate_sp: Vec3 = (0.0, 0.0, 0.0)
        self._idle = True
        self._last_mode = ""
        self._last_pos_target: PositionTarget | None = None
        self._motor_cmd: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
        self._read_physical_params()
        # measurement noise (sampled at the position-loop rate)
        self._npos: Vec3 = (0.0, 0.0, 0.0)
        self._nvel: Vec3 = (0.0, 0.0, 0.0)
        # estimator errors (SIM_EST_*): (driving state, error) for position x, y, velocity x, y,
        # advanced at the position-loop rate
        self._est: list[float] = [0.0] * 8
        self._est_acc = 0.0

    # ------------------------------------------------------------------ interface
    def set_wind(self, vel_ned: Vec3) -> None:
        """Steady wind [m/s NED]."""
        if not all(_isfinite(c) for c in vel_ned):
            raise ValueError("wind velocity must be finite")
        self._wind_base = (float(vel_ned[0]), float(vel_ned[1]), float(vel_ned[2]))
        self._apply_gust()

    def _apply_gust(self) -> None:
        b, g = self._wind_base, self._gust
        self._wind = (b[0] + g[0], b[1] + g[1], b[2] + g[2])

    @property
    def wind(self) -> Vec3:
        """Wind the airframe sees now, steady part plus gust [m/s NED]."""
        return self._wind

    def _step_gust(self, dt: float) -> None:
        """Advance the gust process by `dt` [s] (exact Gauss-Markov discretisation)."""
        e = math.exp(-dt / max(self._gust_tau, 1e-3))
        s = self._gust_std * math.sqrt(1.0 - e * e)
        gauss = self._gust_rng.gauss
        gx, gy, gz = self._gust
        self._gust = (gx * e + s * gauss(), gy * e + s * gauss(), gz * e + 0.5 * s * gauss())
        self._apply_gust()

    def set_local_position_valid(self, valid: bool) -> None:
        """Fault injection flag only: the controller keeps using the true state."""
        self._local_pos_valid = bool(valid)
        self._state_cache = None

    def set_battery_remaining(self, fraction: float) -> None:
        """Force the battery state of charge (0..1)."""
        self._battery = min(max(float(fraction), 0.0), 1.0)
        self._state_cache = None

    def reset_integrators(self) -> None:
        """Reset velocity/rate integrators and the heading hold."""
        self._pvc.reset()
        self._rc.reset()
        self._yaw_hold = None

    @property
    def takeoff_state(self) -> str:
        """PX4 takeoff state: disarmed, spoolup, ready_for_takeoff, rampup or flight."""
        return _TAKEOFF_STATE_NAMES[self._tko_state]

    @property
    def motor_outputs(self) -> tuple[float, float, float, float]:
        """Actual rotor thrust fractions 0..1 (after the motor lag)."""
        return self._u

    @property
    def landed(self) -> bool:
        """Land detector output (= `state.landed`, without building a snapshot)."""
        return self._landed

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
        """(`state.q_wxyz`, measured body rates [rad/s FRD]): the rates are the gyro as PX4
        reports it (SIH noise, IMU_GYRO_CUTOFF low-pass) while the rate loop runs, else the true
        rates `state.omega_frd`."""
        w = self._gyro_rate
        return (self._qw, self._qx, self._qy, self._qz), (
            (self._wx, self._wy, self._wz) if w is None else w
        )

    @property
    def last_attitude_target(self) -> AttitudeTargetReport:
        """(q_wxyz, body_rates_frd, thrust_norm) last commanded."""
        return self._q_sp, self._rate_sp, self._thrust_sp

    @property
    def last_position_target(self) -> PositionTarget | None:
        """Last PositionTarget tracked (None outside position control)."""
        return self._last_pos_target

    @property
    def state(self) -> VehicleState:
        """Snapshot of the vehicle state (built once per step; geodetic fields on demand)."""
        if self._state_cache is not None:
            return self._state_cache
        pos = (self._px + self._npos[0], self._py + self._npos[1], self._pz + self._npos[2])
        u = self._u
        self._state_cache = st = make_state(  # positional: the VehicleState field order
            self._t,
            pos,
            (self._vx + self._nvel[0], self._vy + self._nvel[1], self._vz + self._nvel[2]),
            (self._ax, self._ay, self._az),
            (self._qw, self._qx, self._qy, self._qz),
            (self._wx, self._wy, self._wz),
            self._on_ground,
            self._landed,
            0.25 * (u[0] + u[1] + u[2] + u[3]),
            self._battery,
            self._local_pos_valid,
            self._home,
        )
        return st

    @property
    def true_pos_ned(self) -> Vec3:
        """True position [m NED], without the estimator error and noise that `state` carries."""
        return (self._px, self._py, self._pz)

    @property
    def true_vel_ned(self) -> Vec3:
        """True velocity [m/s NED]."""
        return (self._vx, self._vy, self._vz)

    # ------------------------------------------------------------------ test helpers
    def set_state(
        self,
        pos_ned: Vec3 = (0.0, 0.0, 0.0),
        vel_ned: Vec3 = (0.0, 0.0, 0.0),
        q_wxyz: Quat = (1.0, 0.0, 0.0, 0.0),
        omega_frd: Vec3 = (0.0, 0.0, 0.0),
        motors: float | None = None,
    ) -> None:
        """Place the vehicle (tests, replays); `motors` presets all rotor outputs 0..1."""
        self._state_cache = None
        self._px, self._py, self._pz = (float(c) for c in pos_ned)
        self._vx, self._vy, self._vz = (float(c) for c in vel_ned)
        n = math.sqrt(sum(c * c for c in q_wxyz))
        self._qw, self._qx, self._qy, self._qz = (float(c) / n for c in q_wxyz)
        self._wx, self._wy, self._wz = (float(c) for c in omega_frd)
        self._on_ground = self._pz >= 0.0 and self._vz >= 0.0
        self._touched = False
        if motors is not None:
            m = float(motors)
            self._u = (m, m, m, m)
        if not self._on_ground:
            self._landed = False
            self._land_timer = 0.0

    def mark_airborne(self, thrust: float) -> None:
        """Tests: treat the vehicle as flying (takeoff handling in flight, motors at `thrust`)."""
        self._state_cache = None
        self._tko_state = FLIGHT
        self._armed_prev = True
        self._landed = False
        f = float(thrust)
        self._u = (f, f, f, f)

    # ------------------------------------------------------------------ stepping
    def _read_physical_params(self) -> None:
        p = self._params
        self._mass = max(p["SIH_MASS"], 1e-3)
        self._ixx = max(p["SIH_IXX"], 1e-6)
        self._iyy = max(p["SIH_IYY"], 1e-6)
        self._izz = max(p["SIH_IZZ"], 1e-6)
        self._tmax = p["SIH_T_MAX"]
        self._qmax = p["SIH_Q_MAX"]
        self._lroll = p["SIH_L_ROLL"]
        self._lpitch = p["SIH_L_PITCH"]
        self._kdv = p["SIH_KDV"]
        self._kdw = p["SIH_KDW"]
        # PX4's land detector: ground contact, maybe landed and landed each hold for a third
        self._land_detect_s = p["LNDMC_TRIG_TIME"]
        # products/differences used every physics step (same evaluation order as written out)
        self._lroll_t = self._lroll * self._tmax
        self._lpitch_t = self._lpitch * self._tmax
        self._izz_m_iyy = self._izz - self._iyy
        self._ixx_m_izz = self._ixx - self._izz
        self._iyy_m_ixx = self._iyy - self._ixx
        tau = p["SIH_T_TAU"]
        if tau != getattr(self, "_tau", None):
            self._tau = tau
            self._alpha_dt = -1.0
        self._noise = (p["SIM_POS_NOISE"], p["SIM_VEL_NOISE"], p["SIM_GYRO_NOISE"])
        sih, white = max(p["SIM_GYRO_SIH"], 0.0), max(p["SIM_GYRO_NOISE"], 0.0)
        self._gyro_std: tuple[float, float, float] = (
            math.hypot(sih * SIH_GYRO_NOISE[0], white),
            math.hypot(sih * SIH_GYRO_NOISE[1], white),
            math.hypot(sih * SIH_GYRO_NOISE[2], white),
        )
        self._imu_cut = (p["IMU_GYRO_CUTOFF"], p["IMU_DGYRO_CUTOFF"])
        self._gust_std = max(p["SIM_WIND_GUST"], 0.0)
        self._gust_tau = p["SIM_WIND_GUST_T"]
        self._est_cfg = (max(p["SIM_EST_XY_STD"], 0.0), max(p["SIM_EST_VXY_STD"], 0.0),
                         max(p["SIM_EST_XY_TAU"], 0.05))
        self._bat_drain = max(p["SIM_BAT_DRAIN"], 1.0)
        self._bat_min = min(max(p["SIM_BAT_MIN_PCT"] / 100.0, 0.0), 1.0)

    def step(self, dt: float, target: Target, armed: bool) -> None:
        """Run the controller for `target` and integrate the physics by `dt` [s].

        Steps longer than 1/250 s are split into equal sub-steps of at most 1/250 s.
        """
        if not (dt > 0.0 and dt < 1.0):
            raise ValueError(f"physics step must be in (0, 1) s, got {dt!r}")
        if dt > _SPLIT_ABOVE_S:
            n = math.ceil(dt / MAX_STEP_S - 1e-9)
            for _ in range(n):
                self._step(dt / n, target, armed)
        else:
            self._step(dt, target, armed)

    def _step(self, dt: float, target: Target, armed: bool) -> None:
        t = self._t + dt
        self._t = t
        self._state_cache = None
        param_acc = self._param_acc + dt
        if param_acc >= PARAM_REFRESH_S:
            param_acc = 0.0
            version = getattr(self._params, "version", None)
            if version is None or version != self._param_version:
                self._param_version = version
                self._gains = McGains.from_params(self._params)
                self._read_physical_params()
        self._param_acc = param_acc
        if self._gust_std > 0.0:
            gust_acc = self._gust_acc + dt
            if gust_acc >= GUST_PERIOD_S:
                self._step_gust(gust_acc)
                gust_acc = 0.0
            self._gust_acc = gust_acc
        # arming transitions
        if armed and not self._armed_prev:
            self._arm_t = t
            self._tko_state = SPOOLUP if self._on_ground else FLIGHT
            self.reset_integrators()
        elif not armed:
            self._tko_state = DISARMED
        self._armed_prev = armed
        if armed:
            bat = self._battery - dt / self._bat_drain
            self._battery = bat if bat > self._bat_min else self._bat_min

        if self._est_cfg[0] > 0.0 or self._est_cfg[1] > 0.0:
            est_acc = self._est_acc + dt
            if est_acc >= POS_LOOP_PERIOD_S - 1e-9:
                self._advance_estimator_error(est_acc)
                est_acc = 0.0
            self._est_acc = est_acc

        # ---------------------------------------------------------------- control
        if armed and isinstance(target, PositionTarget):
            self._control_position(dt, target)
        elif armed and isinstance(target, AttitudeTarget):
            self._control_attitude(dt, target)
        else:
            self._control_idle()

        self._integrate(dt)

        # land detector (PX4-like)
        if not armed:
            self._landed = self._on_ground
            self._land_timer = 0.0
            return
        if not self._on_ground:  # in the air: not landed (the hot path)
            self._land_timer = 0.0
            self._landed = False
            return
        g = self._gains
        # "landed": on the ground with low thrust, or on the ground while the position
        # controller still commands a descent into it (PX4: hit ground while descending)
        if (
            self._idle
            or self._thrust_sp <= g.thr_min + (g.hover - g.thr_min) * 0.3
            or (self._last_mode == "pos" and self._pvc.vel_sp[2] > GROUND_CONTACT_DESCENT_M_S)
        ):
            self._land_timer += dt
            if self._land_timer >= self._land_detect_s or self._idle:
                self._landed = True
        else:
            self._land_timer = 0.0
            self._landed = False

    def _control_idle(self) -> None:
        if self._last_mode != "idle":
            self._last_mode = "idle"
            self.reset_integrators()
        self._pos_acc = math.inf
        self._att_acc = math.inf
        self._rate_acc = math.inf
        self._last_pos_target = None
        self._q_sp = quat_from_yaw(quat_yaw((self._qw, self._qx, self._qy, self._qz)))
        self._rate_sp = (0.0, 0.0, 0.0)
        self._thrust_sp = 0.0
        self._motor_cmd = (0.0, 0.0, 0.0, 0.0)
        self._idle = True
        self._gyro_rate = None

    def _advance_estimator_error(self, dt: float) -> None:
        """Horizontal estimator errors like EKF2's on SIH (measured on PX4 v1.16 SITL: position
        ~0.16 m, velocity ~0.2 m/s per axis, both slowly varying, ~1.7 s): per axis, white noise
        through two first-order lags of time constant SIM_EST_XY_TAU (a second-order
        Gauss-Markov process) scaled to the stationary std SIM_EST_XY_STD (position) and
        SIM_EST_VXY_STD (velocity), independent of each other as measured."""
        std_p, std_v, tau = self._est_cfg
        a = math.exp(-dt / tau)
        k = math.sqrt(2.0) * math.sqrt(1.0 - a * a)  # var(lagged) = var(driving) / 2
        e = self._est
        gauss = self._rng.gauss
        for i, std in ((0, std_p), (2, std_p), (4, std_v), (6, std_v)):
            s = a * e[i] + k * std * gauss(0.0, 1.0)
            e[i] = s
            e[i + 1] = a * e[i + 1] + (1.0 - a) * s

    def _refresh(self) -> None:
        if self._noise[0] > 0.0 or self._noise[1] > 0.0:
            gauss = self._rng.gauss
            sp, sv = self._noise[0], self._noise[1]
            self._npos = (gauss(0.0, sp), gauss(0.0, sp), gauss(0.0, sp)) if sp > 0 else (0, 0, 0)
            self._nvel = (gauss(0.0, sv), gauss(0.0, sv), gauss(0.0, sv)) if sv > 0 else (0, 0, 0)
        else:
            self._npos = (0.0, 0.0, 0.0)
            self._nvel = (0.0, 0.0, 0.0)
        if self._est_cfg[0] > 0.0 or self._est_cfg[1] > 0.0:
            e = self._est
            n, v = self._npos, self._nvel
            self._npos = (n[0] + e[1], n[1] + e[3], n[2])
            self._nvel = (v[0] + e[5], v[1] + e[7], v[2])

    def _want_takeoff(self, tgt: PositionTarget) -> bool:
        pz, vz, az = tgt.pos_ned[2], tgt.vel_ned[2], tgt.acc_ned[2]
        return (
            (_isfinite(pz) and pz < self._pz - 0.2)
            or (_isfinite(vz) and vz < -0.3)
            or (_isfinite(az) and az < -0.3)
        )

    def _control_position(self, dt: float, tgt: PositionTarget) -> None:
        if self._last_mode != "pos":
            self._last_mode = "pos"
            self._pos_acc = math.inf
            self._rate_acc = math.inf
            self._yaw_hold = None
        self._last_pos_target = tgt
        self._pos_acc += dt
        if self._pos_acc >= POS_LOOP_PERIOD_S - 1e-9:
            dtc = min(self._pos_acc, 0.05) if _isfinite(self._pos_acc) else dt
            self._pos_acc = 0.0
            self._refresh()
            g = self._gains
            q = (self._qw, self._qx, self._qy, self._qz)
            yaw_now = quat_yaw(q)
            # heading: yaw > yaw_rate (integrated) > hold
            if _isfinite(tgt.yaw):
                self._yaw_hold = tgt.yaw
                yaw_ff = tgt.yaw_rate if _isfinite(tgt.yaw_rate) else math.nan
            else:
                if self._yaw_hold is None:
                    self._yaw_hold = yaw_now
                if _isfinite(tgt.yaw_rate):
                    rmax = g.rate_max[2]
                    yaw_ff = min(max(tgt.yaw_rate, -rmax), rmax)
                    self._yaw_hold = wrap_pi(self._yaw_hold + yaw_ff * dtc)
                else:
                    yaw_ff = math.nan
            yaw_sp = self._yaw_hold
            # PX4 takeoff handling
            st = self._tko_state
            if st == SPOOLUP and self._t - self._arm_t >= g.spoolup_t:
                st = READY
            if st == READY:
                if not self._landed:
                    st = FLIGHT
                elif self._want_takeoff(tgt):
                    st = RAMPUP
                    vzp = max(g.vel_p[2], 0.01)
                    self._ramp_up_limit = -G / vzp
            if st == RAMPUP:
                # ramp the climb-rate limit from "zero thrust" to the requested climb speed
                # (PX4: the flight task's speed_up constraint; here -vz of the target if it
                # asks for a climb rate, else MPC_Z_VEL_MAX_UP)
                vz_req = tgt.vel_ned[2]
                ramp_end = g.vel_up_max
                if _isfinite(vz_req) and vz_req < 0.0:
                    ramp_end = min(ramp_end, -vz_req)
                if g.tko_ramp_t > dtc:
                    self._ramp_up_limit += (ramp_end + G / max(g.vel_p[2], 0.01)) * (
                        dtc / g.tko_ramp_t
                    )
                else:
                    self._ramp_up_limit = ramp_end
                if self._ramp_up_limit >= ramp_end:
                    self._ramp_up_limit = g.vel_up_max
                    st = FLIGHT
            elif st == FLIGHT and self._landed:
                st = READY
            self._tko_state = st
            if st in (DISARMED, SPOOLUP, READY):
                # motors idle on the ground until a takeoff is wanted
                self._pvc.reset()
                self._rc.reset()
                self._idle = True
                self._gyro_rate = None
                self._q_sp = quat_from_yaw(yaw_now)
                self._thrust_sp = 0.0
                self._yaw_ff = math.nan
            else:
                self._idle = False
                up_limit = self._ramp_up_limit if st == RAMPUP else g.vel_up_max
                pos = (self._px + self._npos[0], self._py + self._npos[1], self._pz + self._npos[2])
                vel = (self._vx + self._nvel[0], self._vy + self._nvel[1], self._vz + self._nvel[2])
                body_z, thrust = self._pvc.update(
                    g, dtc, pos, vel, (self._ax, self._ay, self._az), tgt, up_limit, st == FLIGHT
                )
                # a touch since the last tick counts too: a descent that meets the ground
                # between two ticks and bounces off must not be missed
                touched, self._touched = self._touched or self._on_ground, False
                if touched and self._pvc.vel_sp[2] > GROUND_CONTACT_DESCENT_M_S:
                    # ground contact while descending (PX4 limit_thrust_during_landing): zero
                    # thrust, level at the current yaw, no integrator windup; otherwise the
                    # controller keeps fighting wind or drift on the ground and the vehicle
                    # hops instead of being detected as landed
                    self._pvc.reset()
                    self._rc.reset()
                    self._q_sp = quat_from_yaw(yaw_now)
                    self._thrust_sp = 0.0
                    self._yaw_ff = math.nan
                else:
                    if self._landed:
                        self._pvc.vel_int[0] = self._pvc.vel_int[1] = 0.0
                    self._q_sp = body_z_to_attitude(body_z, yaw_sp)
                    self._thrust_sp = thrust
                    self._yaw_ff = yaw_ff
        if self._idle:
            self._motor_cmd = (0.0, 0.0, 0.0, 0.0)
            self._rate_sp = (0.0, 0.0, 0.0)
            return
        # attitude / rate loop timing (the rate-loop hold checked inline: hot path)
        self._att_acc += dt
        self._rate_acc += dt
        if self._rate_acc < _RATE_TICK_S:
            return  # motor commands held until the next rate-loop tick
        self._rate_loop(dt, self._q_sp, self._yaw_ff, None)

    def _control_attitude(self, dt: float, tgt: AttitudeTarget) -> None:
        new = tgt is not self._att_tgt
        if new:
            self._accept_attitude_target(tgt)
        q_in, r_in = self._att_q, self._att_rates
        want_att = q_in is not None and r_in is None  # else rates (zero if none given)
        if self._last_mode != "att":
            self._last_mode = "att"
            self._att_acc = math.inf
            self._rate_acc = math.inf
            self._cm_t0 = self._t
            self._cm_att, self._cm_tick = want_att, 0  # entering: at once (see README)
        tick = int((self._t - self._cm_t0) * CONTROL_MODE_RATE_HZ)
        if tick != self._cm_tick:
            self._cm_att, self._cm_tick = want_att, tick
        self._last_pos_target = None
        self._idle = False
        pos_acc = self._pos_acc + dt
        if pos_acc >= POS_LOOP_PERIOD_S - 1e-9:
            pos_acc = 0.0
            self._refresh()
        self._pos_acc = pos_acc
        self._att_acc += dt
        thrust = self._att_thrust
        yaw_ff = math.nan
        rates: Vec3 | None
        q_sp: Quat
        if self._cm_att:
            if want_att and q_in is not None:
                q_sp = self._cm_q = q_in
                yaw_ff = tgt.yaw_rate_ff
            else:
                # switching to rates: PX4's attitude controller still runs on the last attitude
                # setpoint; each new offboard rates setpoint wins until its next tick
                q_sp = self._cm_q or (self._qw, self._qx, self._qy, self._qz)
                if new:
                    self._rate_sp = r_in or (0.0, 0.0, 0.0)
                    self._att_acc = 0.0
            rates = None
        else:
            if want_att:
                # switching to attitude: nothing turns the attitude setpoint into rates yet;
                # PX4's rate controller keeps the last rates setpoint and its thrust
                rates, thrust = self._cm_rates, self._cm_thrust
            else:
                rates = self._cm_rates = r_in or (0.0, 0.0, 0.0)
                self._cm_thrust = thrust
            q_sp = q_in or (self._qw, self._qx, self._qy, self._qz)
        self._thrust_sp = thrust
        self._q_sp = q_sp
        # attitude / rate loop timing (the rate-loop hold checked inline: hot path)
        rate_acc = self._rate_acc + dt
        self._rate_acc = rate_acc
        if rate_acc < _RATE_TICK_S:
            return  # motor commands held until the next rate-loop tick
        self._rate_loop(dt, q_sp, yaw_ff, rates)

    def _accept_attitude_target(self, tgt: AttitudeTarget) -> None:
        """Validate a new AttitudeTarget once (the autopilot passes the same object each step)."""
        self._att_tgt = tgt
        thrust = tgt.thrust_norm
        self._att_thrust = min(max(thrust, 0.0), 1.0) if _isfinite(thrust) else 0.0
        q_in = tgt.q_wxyz
        q_ok: Quat | None = None
        if q_in is not None:
            n2 = q_in[0] ** 2 + q_in[1] ** 2 + q_in[2] ** 2 + q_in[3] ** 2
            # an invalid quaternion is treated as "attitude not given"
            q_ok = quat_normalize(q_in) if _isfinite(n2) and n2 > 1e-6 else None
        self._att_q = q_ok
        r_in = tgt.body_rates_frd
        self._att_rates = (
            None
            if r_in is None
            else (
                r_in[0] if _isfinite(r_in[0]) else 0.0,
                r_in[1] if _isfinite(r_in[1]) else 0.0,
                r_in[2] if _isfinite(r_in[2]) else 0.0,
            )
        )

    def _rate_loop(self, dt: float, q_sp: Quat, yaw_ff: float, rates: Vec3 | None) -> None:
        """Rate-loop tick (attitude loop when due); `_rate_acc` holds the time since the last."""
        rate_acc = self._rate_acc
        dtr = rate_acc if rate_acc < 0.05 else dt
        self._rate_acc = 0.0
        g = self._gains
        if rates is None:
            if self._att_acc >= ATT_LOOP_PERIOD_S - 1e-9:
                self._att_acc = 0.0
                self._rate_sp = attitude_control(
                    g, (self._qw, self._qx, self._qy, self._qz), q_sp, yaw_ff
                )
        else:
            self._att_acc = math.inf
            self._rate_sp = rates
        # the gyro (PX4 sensors/vehicle_angular_velocity): SIH's noise while the rotors push,
        # low-passed; the D term acts on the filtered derivative
        s0, s1, s2 = self._gyro_std
        if s0 > 0.0 or s1 > 0.0 or s2 > 0.0:
            k = math.sqrt(SIH_IMU_PERIOD_S / dtr)
            gauss = self._gyro_rng.gauss
            raw = (
                self._wx + gauss(0.0, s0 * k),
                self._wy + gauss(0.0, s1 * k),
                self._wz + gauss(0.0, s2 * k),
            )
        else:
            raw = (self._wx, self._wy, self._wz)
        if self._gyro_rate is None:  # the rate loop starts: filters settled on the true rates
            self._gyro.reset((self._wx, self._wy, self._wz))
        omega, accel = self._gyro.update(raw, dtr, self._imu_cut[0], self._imu_cut[1])
        self._gyro_rate = omega
        torque = self._rc.update(g, omega, self._rate_sp, dtr, self._landed, accel)
        self._motor_cmd = mix_quad_x(torque, self._thrust_sp)

    def _integrate(self, dt: float) -> None:
        # motor lag
        if dt != self._alpha_dt:
            self._alpha_dt = dt
            self._alpha = 1.0 - math.exp(-dt / self._tau) if self._tau > 1e-6 else 1.0
            self._hdt = 0.5 * dt
            self._hdt2 = 0.5 * dt * dt
            self._invdt = 1.0 / dt
        a = self._alpha
        u0, u1, u2, u3 = self._u
        c0, c1, c2, c3 = self._motor_cmd
        u0 = u0 + (c0 - u0) * a
        u1 = u1 + (c1 - u1) * a
        u2 = u2 + (c2 - u2) * a
        u3 = u3 + (c3 - u3) * a
        self._u = (u0, u1, u2, u3)
        thrust = self._tmax * (u0 + u1 + u2 + u3)
        mx = self._lroll_t * (-u0 + u1 + u2 - u3)
        my = self._lpitch_t * (u0 - u1 + u2 - u3)
        mz = self._qmax * (u0 + u1 - u2 - u3)

        qw, qx, qy, qz = self._qw, self._qx, self._qy, self._qz
        # body z axis in world
        bzx = 2.0 * (qx * qz + qw * qy)
        bzy = 2.0 * (qy * qz - qw * qx)
        bzz = 1.0 - 2.0 * (qx * qx + qy * qy)
        m = self._mass
        kdv = self._kdv
        wnx, wny, wnz = self._wind
        vx, vy, vz = self._vx, self._vy, self._vz
        ax = (-thrust * bzx - kdv * (vx - wnx)) / m
        ay = (-thrust * bzy - kdv * (vy - wny)) / m
        az = (-thrust * bzz - kdv * (vz - wnz)) / m + G
        hdt2 = self._hdt2
        px = self._px + vx * dt + ax * hdt2
        py = self._py + vy * dt + ay * hdt2
        pz = self._pz + vz * dt + az * hdt2
        nvx, nvy, nvz = vx + ax * dt, vy + ay * dt, vz + az * dt

        # rotational dynamics (Euler's equations), midpoint rule
        ixx, iyy, izz, kdw = self._ixx, self._iyy, self._izz, self._kdw
        d_yz, d_zx, d_xy = self._izz_m_iyy, self._ixx_m_izz, self._iyy_m_ixx
        wx, wy, wz = self._wx, self._wy, self._wz
        hdt = self._hdt
        hx = wx + hdt * ((mx - kdw * wx - d_yz * wy * wz) / ixx)
        hy = wy + hdt * ((my - kdw * wy - d_zx * wz * wx) / iyy)
        hz = wz + hdt * ((mz - kdw * wz - d_xy * wx * wy) / izz)
        dwx = (mx - kdw * hx - d_yz * hy * hz) / ixx
        dwy = (my - kdw * hy - d_zx * hz * hx) / iyy
        dwz = (mz - kdw * hz - d_xy * hx * hy) / izz
        nwx, nwy, nwz = wx + dt * dwx, wy + dt * dwy, wz + dt * dwz
        if not (abs(nwx) < _W_LIMIT and abs(nwy) < _W_LIMIT and abs(nwz) < _W_LIMIT
                and abs(hx) < _W_LIMIT and abs(hy) < _W_LIMIT and abs(hz) < _W_LIMIT
                and abs(nvx) < _V_LIMIT and abs(nvy) < _V_LIMIT and abs(nvz) < _V_LIMIT):
            hx, hy, hz, nwx, nwy, nwz = _bounded((hx, hy, hz, nwx, nwy, nwz), _W_LIMIT)
            nvx, nvy, nvz = _bounded((nvx, nvy, nvz), _V_LIMIT)
            px, py, pz = _bounded((px, py, pz), _P_LIMIT)
        # attitude: q <- q * exp(omega_mid dt / 2)
        ang = math.sqrt(hx * hx + hy * hy + hz * hz) * dt
        if ang > 1e-12:
            s = math.sin(0.5 * ang) * dt / ang
            dw = math.cos(0.5 * ang)
            dx, dy, dz = hx * s, hy * s, hz * s
            rw = qw * dw - qx * dx - qy * dy - qz * dz
            rx = qw * dx + qx * dw + qy * dz - qz * dy
            ry = qw * dy - qx * dz + qy * dw + qz * dx
            rz = qw * dz + qx * dy - qy * dx + qz * dw
            n = 1.0 / math.sqrt(rw * rw + rx * rx + ry * ry + rz * rz)
            qw = rw * n
            qx = rx * n
            qy = ry * n
            qz = rz * n

        # ground contact
        if pz >= 0.0 and nvz >= 0.0:
            pz = 0.0
            nvx = nvy = nvz = 0.0
            nwx = nwy = nwz = 0.0
            yaw = math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
            qw, qx, qy, qz = math.cos(0.5 * yaw), 0.0, 0.0, math.sin(0.5 * yaw)
            px, py = self._px, self._py
            self._on_ground = True
            self._touched = True
        else:
            self._on_ground = False
        inv = self._invdt
        self._ax, self._ay, self._az = (nvx - vx) * inv, (nvy - vy) * inv, (nvz - vz) * inv
        self._px, self._py, self._pz = px, py, pz
        self._vx, self._vy, self._vz = nvx, nvy, nvz
        self._wx, self._wy, self._wz = nwx, nwy, nwz
        self._qw, self._qx, self._qy, self._qz = qw, qx, qy, qz
