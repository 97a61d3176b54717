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

Control (quad_control.py on flight_control.py's laws): position loop <= 100 Hz, attitude loop
<= 250 Hz, rate loop <= 500 Hz (motor commands are held between rate-loop ticks), PX4's takeoff
handling (spool-up, ready, thrust ramp, flight) and a PX4-like land detector. Physics and sensor
noise (SIM_*_NOISE) in quad_physics.py; the noise is added to what the controller and `state`
see. This module holds the state (one slotted class), its interface and the step.
"""

from __future__ import annotations

import math

from sitl_mock.flight_control import McGains
from sitl_mock.quad_control import (
    ATT_LOOP_PERIOD_S,
    CONTROL_MODE_RATE_HZ,
    GROUND_CONTACT_DESCENT_M_S,
    POS_LOOP_PERIOD_S,
    RATE_LOOP_PERIOD_S,
    SIH_IMU_PERIOD_S,
    QuadControl,
)
from sitl_mock.quad_state import _TAKEOFF_STATE_NAMES, DISARMED, FLIGHT, SIH_GYRO_NOISE, SPOOLUP
from sitl_mock.setpoints import AttitudeTarget, PositionTarget, Quat, Target, Vec3
from sitl_mock.vehicle_state import AttitudeTargetReport, VehicleState, make_state

_isfinite = math.isfinite

PARAM_REFRESH_S = 0.1
GUST_PERIOD_S = 0.02  # the gust process is updated at 50 Hz (held in between)
MAX_STEP_S = 1.0 / 250.0  # longer steps are split (integration always at >= 250 Hz)
_SPLIT_ABOVE_S = MAX_STEP_S + 1e-12
# the model constants live with their parts (quad_state.py, quad_control.py); named here too
__all__ = [
    "ATT_LOOP_PERIOD_S",
    "CONTROL_MODE_RATE_HZ",
    "GROUND_CONTACT_DESCENT_M_S",
    "GUST_PERIOD_S",
    "MAX_STEP_S",
    "PARAM_REFRESH_S",
    "POS_LOOP_PERIOD_S",
    "RATE_LOOP_PERIOD_S",
    "SIH_GYRO_NOISE",
    "SIH_IMU_PERIOD_S",
    "Quadrotor",
]


class Quadrotor(QuadControl):
    """PX4 SIH-like quadrotor with a PX4-like controller; see the module docstring."""

    kind = "quad"
    __slots__ = ()

    # ------------------------------------------------------------------ interface
    def set_wind(self, vel_ned: Vec3) -> None:
        """Steady wind [m/s NED]."""
        if not all(_isfinite(c) for c in vel_ned):
            raise ValueError("wind velocity must be finite")
        self._wind_base = (float(vel_ned[0]), float(vel_ned[1]), float(vel_ned[2]))
        self._apply_gust()

    @property
    def wind(self) -> Vec3:
        """Wind the airframe sees now, steady part plus gust [m/s NED]."""
        return self._wind

    def set_local_position_valid(self, valid: bool) -> None:
        """Fault injection flag only: the controller keeps using the true state."""
        self._local_pos_valid = bool(valid)
        self._state_cache = None

    def set_battery_remaining(self, fraction: float) -> None:
        """Force the battery state of charge (0..1)."""
        self._battery = min(max(float(fraction), 0.0), 1.0)
        self._state_cache = None

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
        vel = (self._vx + self._nvel[0], self._vy + self._nvel[1], self._vz + self._nvel[2])
        self._state_cache = st = self._snapshot(pos, vel)
        return st

    @property
    def true_state(self) -> VehicleState:
        """Snapshot of the true motion (`state` without the estimator error and noise)."""
        return self._snapshot((self._px, self._py, self._pz), (self._vx, self._vy, self._vz))

    def _snapshot(self, pos: Vec3, vel: Vec3) -> VehicleState:
        """The state with position `pos` [m NED] and velocity `vel` [m/s NED], the rest as is."""
        u = self._u
        return make_state(  # positional: the VehicleState field order
            self._t,
            pos,
            vel,
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
