"""Quadrotor state: the slots every part of the model shares, their initial values, parameters.

`QuadState` is the root of the quadrotor's classes: `QuadPhysics` (quad_physics.py) integrates
it, `QuadControl` (quad_control.py) runs the controllers on it, `Quadrotor` (quad.py) is the
vehicle-model interface. One slotted object: the per-step code reads plain slots.
"""

from __future__ import annotations

import math
import random

from sitl_mock.estimate_error import horizontal_config
from sitl_mock.flight_control import (
    AngularVelocityFilter,
    McGains,
    PositionVelocityController,
    RateController,
)
from sitl_mock.params import ParamStore
from sitl_mock.setpoints import AttitudeTarget, PositionTarget, Quat, Vec3
from sitl_mock.vehicle_state import VehicleState

# takeoff states (PX4 TakeoffHandling)
DISARMED, SPOOLUP, READY, RAMPUP, FLIGHT = range(5)
_TAKEOFF_STATE_NAMES = ("disarmed", "spoolup", "ready_for_takeoff", "rampup", "flight")
#: SIH's gyro noise std per sample while the rotors push, roll/pitch/yaw [rad/s]
#: (SIH reconstruct_sensors_signals; times SIM_GYRO_SIH)
SIH_GYRO_NOISE = (0.14, 0.07, 0.03)


class QuadState:
    """The quadrotor's state and parameters (see quad.py); created at rest at home."""

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

    def reset_integrators(self) -> None:
        """Reset velocity/rate integrators and the heading hold."""
        self._pvc.reset()
        self._rc.reset()
        self._yaw_hold = None


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
        self._est_cfg = horizontal_config(p)
        self._bat_drain = max(p["SIM_BAT_DRAIN"], 1.0)
        self._bat_min = min(max(p["SIM_BAT_MIN_PCT"] / 100.0, 0.0), 1.0)
