"""Parameters the mock models, with PX4 names and PX4 (SIH quadrotor) defaults; the rover's
with the defaults of PX4 main's SIH Ackermann rover (airframe 10045, `ROVER_AIRFRAME`).

Both the vehicle model (dynamics, flight control) and the autopilot core read their
parameters from one `ParamStore`, so `--param NAME=VALUE` and MAVLink PARAM_SET reach both.
Append new parameters here; never rename one (clients address them by name).
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, replace


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: default value, whether it is an INT32 on the wire, a short description, and
    the accepted values: ``lo..hi`` (inclusive) and, for enumerations, the listed ``values``.
    ``mock_range`` is True where the range is the mock's own (PX4 has none, or PX4's would break
    the simulation, e.g. a mass of 0 kg); False where it is PX4's parameter metadata."""

    default: float
    is_int: bool
    doc: str
    lo: float = -math.inf
    hi: float = math.inf
    values: tuple[int, ...] = ()
    mock_range: bool = False

    def check(self, name: str, value: float) -> float:
        """The value as stored (integers rounded), or ValueError naming the accepted range."""
        v = float(value)
        if not math.isfinite(v):
            raise ValueError(f"parameter {name} must be finite, got {value!r}")
        if self.is_int and not v.is_integer():
            raise ValueError(f"parameter {name} is an integer, got {value!r}")
        if self.values and v not in self.values:
            allowed = ", ".join(str(x) for x in self.values)
            raise ValueError(f"parameter {name}: {v:g} is not one of {allowed}")
        if not self.lo <= v <= self.hi:
            raise ValueError(f"parameter {name}: {v:g} out of range {self.lo:g}..{self.hi:g}")
        return v


PARAMS: dict[str, ParamSpec] = {
    # Identity
    "MAV_SYS_ID": ParamSpec(1, True, "MAVLink system id"),
    # Commander / offboard
    "COM_OF_LOSS_T": ParamSpec(1.0, False, "offboard setpoint loss timeout [s]"),
    "COM_OBL_RC_ACT": ParamSpec(
        0,
        True,
        "offboard loss action: 0 position hold, 1 altitude, 2 manual, 3 return, 4 land,"
        " 5 hold, 6 terminate, 7 disarm",
    ),
    "COM_DISARM_PRFLT": ParamSpec(10.0, False, "auto-disarm if no takeoff after arming [s]"),
    "COM_DISARM_LAND": ParamSpec(2.0, False, "auto-disarm after landing [s]"),
    "COM_ARM_WO_GPS": ParamSpec(0, True, "allow arming without a position estimate"),
    # Navigator / mission
    "MIS_TAKEOFF_ALT": ParamSpec(2.5, False, "default takeoff altitude above home [m]"),
    "NAV_ACC_RAD": ParamSpec(2.0, False, "default waypoint acceptance radius [m]"),
    "RTL_RETURN_ALT": ParamSpec(30.0, False, "return altitude above home [m] (MC airframes: 30)"),
    # Multicopter position control (PX4 defaults)
    "MPC_THR_HOVER": ParamSpec(0.5, False, "hover thrust the controllers assume [0..1]"),
    "MPC_THR_MIN": ParamSpec(0.12, False, "minimum collective thrust in flight [0..1]"),
    "MPC_THR_MAX": ParamSpec(1.0, False, "maximum collective thrust [0..1]"),
    "MPC_XY_CRUISE": ParamSpec(5.0, False, "horizontal cruise speed in auto modes [m/s]"),
    "MPC_XY_VEL_MAX": ParamSpec(12.0, False, "maximum horizontal velocity [m/s]"),
    "MPC_Z_VEL_MAX_UP": ParamSpec(3.0, False, "maximum climb rate [m/s]"),
    "MPC_Z_VEL_MAX_DN": ParamSpec(1.5, False, "maximum descent rate [m/s]"),
    "MPC_TKO_SPEED": ParamSpec(1.5, False, "takeoff climb rate [m/s]"),
    "MPC_LAND_SPEED": ParamSpec(0.7, False, "landing descent rate [m/s]"),
    "MPC_TILTMAX_AIR": ParamSpec(45.0, False, "maximum tilt in position control [deg]"),
    "MPC_ACC_HOR": ParamSpec(3.0, False, "horizontal acceleration in auto modes [m/s^2]"),
    "MPC_XY_P": ParamSpec(0.95, False, "horizontal position gain [1/s]"),
    "MPC_Z_P": ParamSpec(1.0, False, "vertical position gain [1/s]"),
    "MPC_XY_VEL_P_ACC": ParamSpec(1.8, False, "horizontal velocity P gain [1/s]"),
    "MPC_XY_VEL_I_ACC": ParamSpec(0.4, False, "horizontal velocity I gain [1/s^2]"),
    "MPC_XY_VEL_D_ACC": ParamSpec(0.2, False, "horizontal velocity D gain [-]"),
    "MPC_Z_VEL_P_ACC": ParamSpec(4.0, False, "vertical velocity P gain [1/s]"),
    "MPC_Z_VEL_I_ACC": ParamSpec(2.0, False, "vertical velocity I gain [1/s^2]"),
    "MPC_Z_VEL_D_ACC": ParamSpec(0.0, False, "vertical velocity D gain [-]"),
    # Multicopter attitude / rate control (PX4 defaults)
    "MC_ROLL_P": ParamSpec(6.5, False, "roll attitude gain [1/s]"),
    "MC_PITCH_P": ParamSpec(6.5, False, "pitch attitude gain [1/s]"),
    "MC_YAW_P": ParamSpec(2.8, False, "yaw attitude gain [1/s]"),
    "MC_ROLLRATE_MAX": ParamSpec(220.0, False, "maximum roll rate [deg/s]"),
    "MC_PITCHRATE_MAX": ParamSpec(220.0, False, "maximum pitch rate [deg/s]"),
    "MC_YAWRATE_MAX": ParamSpec(200.0, False, "maximum yaw rate [deg/s]"),
    "MC_AIRMODE": ParamSpec(0, True, "airmode: 0 off (saturation lowers the collective only), "
                            "1 roll/pitch, 2 roll/pitch/yaw may raise it"),
    # SIH quadrotor model (PX4 SIH defaults)
    "SIH_MASS": ParamSpec(1.0, False, "vehicle mass [kg]"),
    "SIH_IXX": ParamSpec(0.025, False, "inertia about body x [kg m^2]"),
    "SIH_IYY": ParamSpec(0.025, False, "inertia about body y [kg m^2]"),
    "SIH_IZZ": ParamSpec(0.030, False, "inertia about body z [kg m^2]"),
    "SIH_T_MAX": ParamSpec(5.0, False, "maximum thrust of one rotor [N]"),
    "SIH_Q_MAX": ParamSpec(0.1, False, "maximum torque of one rotor [N m]"),
    "SIH_L_ROLL": ParamSpec(0.2, False, "roll arm length [m]"),
    "SIH_L_PITCH": ParamSpec(0.2, False, "pitch arm length [m]"),
    "SIH_KDV": ParamSpec(1.0, False, "linear drag coefficient, world frame [N/(m/s)]"),
    "SIH_KDW": ParamSpec(0.025, False, "angular drag coefficient [N m/(rad/s)]"),
    "SIH_T_TAU": ParamSpec(0.05, False, "rotor thrust time constant [s]"),
    # Rover: the mock's first names, kept for clients that address them (ALIASES: each one is the
    # PX4 rover parameter it stands for, value and range; setting either sets both)
    "RO_MAX_SPEED": ParamSpec(3.0, False, "= RO_SPEED_LIM (the mock's old name) [m/s]"),
    "RO_MAX_YAW_RATE": ParamSpec(180.0, False, "= RO_YAW_RATE_LIM (the mock's old name) [deg/s]"),
    "RO_MAX_ACCEL": ParamSpec(3.0, False, "= RO_ACCEL_LIM (the mock's old name) [m/s^2]"),
    # Simulated battery
    "SIM_BAT_DRAIN": ParamSpec(1800.0, False, "time to drain the battery from full [s]"),
    "SIM_BAT_MIN_PCT": ParamSpec(20.0, False, "battery floor for the drain model [%]"),
    # Vehicle model additions (sitl-vehicle): PX4 defaults where PX4 has the parameter
    "MC_ROLLRATE_P": ParamSpec(0.15, False, "roll rate P gain [normalised torque/(rad/s)]"),
    "MC_ROLLRATE_I": ParamSpec(0.2, False, "roll rate I gain"),
    "MC_ROLLRATE_D": ParamSpec(0.003, False, "roll rate D gain"),
    "MC_PITCHRATE_P": ParamSpec(0.15, False, "pitch rate P gain [normalised torque/(rad/s)]"),
    "MC_PITCHRATE_I": ParamSpec(0.2, False, "pitch rate I gain"),
    "MC_PITCHRATE_D": ParamSpec(0.003, False, "pitch rate D gain"),
    "MC_YAWRATE_P": ParamSpec(0.2, False, "yaw rate P gain [normalised torque/(rad/s)]"),
    "MC_YAWRATE_I": ParamSpec(0.1, False, "yaw rate I gain"),
    "MC_YAWRATE_D": ParamSpec(0.0, False, "yaw rate D gain"),
    "MC_YAW_WEIGHT": ParamSpec(0.4, False, "yaw weight of the attitude controller [0..1]"),
    "MPC_THR_XY_MARG": ParamSpec(0.3, False, "horizontal thrust margin kept at full thrust"),
    "MPC_TKO_RAMP_T": ParamSpec(3.0, False, "takeoff thrust ramp time [s]"),
    "COM_SPOOLUP_TIME": ParamSpec(1.0, False, "motor spool-up time after arming [s]"),
    "MPC_LAND_ALT1": ParamSpec(10.0, False, "below this height start slowing the descent [m]"),
    "MPC_LAND_ALT2": ParamSpec(5.0, False, "below this height descend at MPC_LAND_SPEED [m]"),
    "MPC_ACC_UP_MAX": ParamSpec(4.0, False, "maximum upward acceleration in auto modes [m/s^2]"),
    "MPC_ACC_DOWN_MAX": ParamSpec(3.0, False, "maximum downward acceleration, auto [m/s^2]"),
    "NAV_MC_ALT_RAD": ParamSpec(0.8, False, "waypoint altitude acceptance radius [m]"),
    "SIM_POS_NOISE": ParamSpec(0.0, False, "std of simulated position noise [m] (0 = off)"),
    "SIM_VEL_NOISE": ParamSpec(0.0, False, "std of simulated velocity noise [m/s] (0 = off)"),
    "SIM_GYRO_NOISE": ParamSpec(0.0, False, "std of simulated gyro noise [rad/s] (0 = off)"),
    "MPC_TILTMAX_LND": ParamSpec(12.0, False, "maximum tilt during the takeoff ramp [deg]"),
    # Wind gusts (no PX4 equivalent; PX4 v1.16's SIH has no wind at all): a seeded first-order
    # Gauss-Markov process added to the steady wind, horizontal axes at full, vertical at half std
    "SIM_WIND_GUST": ParamSpec(0.0, False, "std of wind gusts per horizontal axis [m/s] (0 = off)"),
    "SIM_WIND_GUST_T": ParamSpec(2.0, False, "correlation time of wind gusts [s]"),
}


class ParamStore(Mapping[str, float]):
    """Mutable name -> value store over `PARAMS`; unknown names raise KeyError.

    `set` is the user's (overrides, `--param`, PARAM_SET); `set_default` is an airframe's
    (PX4's `param set-default`: it never replaces a value the user set). Names in ALIASES move
    together with the parameter they stand for."""

    def __init__(self, overrides: Mapping[str, float] | None = None) -> None:
        self._values: dict[str, float] = {k: float(v.default) for k, v in PARAMS.items()}
        self._user: set[str] = set()  # names the user set (an airframe default leaves them be)
        self.version = 0  # counts changes: readers re-read their cached values on change
        for name, value in (overrides or {}).items():
            self.set(name, value)

    def __getitem__(self, name: str) -> float:
        return self._values[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._values)

    def __len__(self) -> int:
        return len(self._values)

    def set(self, name: str, value: float) -> None:
        """Set a known parameter; ValueError (value unchanged) if the value is not finite, not an
        integer for an integer parameter, or outside the parameter's range (`ParamSpec`)."""
        spec = PARAMS.get(name)
        if spec is None:
            raise KeyError(f"unknown parameter {name!r}")
        v = spec.check(name, value)
        for n in _linked(name):
            self._values[n] = v
            self._user.add(n)
        self.version += 1

    def set_default(self, name: str, value: float) -> None:
        """An airframe's default (PX4 `param set-default`): taken unless the user set `name`."""
        if name in self._user:
            return
        v = PARAMS[name].check(name, value)
        for n in _linked(name):
            self._values[n] = v
        self.version += 1

    def apply_airframe(self, defaults: Mapping[str, float]) -> None:
        """`set_default` for each NAME -> value (e.g. ROVER_AIRFRAME)."""
        for name, value in defaults.items():
            self.set_default(name, value)

    def index(self, name: str) -> int:
        """Position of `name` in the stable parameter list (MAVLink param_index)."""
        return list(PARAMS).index(name)


# Appended by the autopilot side (battery failsafe thresholds and action, PX4 names/defaults).
PARAMS.update(
    {
        "BAT_LOW_THR": ParamSpec(0.15, False, "low battery threshold [0..1]"),
        "BAT_CRIT_THR": ParamSpec(0.07, False, "critical battery threshold [0..1]"),
        "BAT_EMERGEN_THR": ParamSpec(0.05, False, "emergency battery threshold [0..1]"),
        "COM_LOW_BAT_ACT": ParamSpec(
            0, True, "battery failsafe: 0 warning, 2 land, 3 return at critical / land at emergency"
        ),
    }
)

# Appended by the vehicle model (estimator error like EKF2 on SIH's GPS; mock-only names: PX4 has
# no parameter for it, the error emerges from its GPS simulation and EKF2).
PARAMS.update(
    {
        "SIM_EST_XY_STD": ParamSpec(
            0.0, False, "std of the slowly varying horizontal estimator error [m] (0 = off)"
        ),
        "SIM_EST_XY_TAU": ParamSpec(1.7, False, "time constant of the estimator errors [s]"),
        # AUTO trajectory jerk limit (PX4 default 4, range 1-80)
        "MPC_JERK_AUTO": ParamSpec(4.0, False, "jerk limit of AUTO trajectories [m/s^3]"),
        "SIM_EST_VXY_STD": ParamSpec(
            0.0, False, "std of the slowly varying horizontal velocity estimate error [m/s]"
        ),
    }
)

# Appended for the companion's planner (it reads every PX4 parameter it plans with over MAVLink;
# the mock stores this one, its own AUTO flight uses MPC_ACC_HOR like PX4's auto modes).
PARAMS.update(
    {
        "MPC_ACC_HOR_MAX": ParamSpec(
            5.0, False, "maximum horizontal acceleration in velocity-controlled modes [m/s^2]"
        ),
    }
)

# Appended by the vehicle model: PX4's gyro pipeline (sensors/vehicle_angular_velocity, PX4 names
# and defaults) and SIH's gyro noise (hard-coded in SIH: no PX4 parameter, hence a mock-only name).
PARAMS.update(
    {
        "IMU_GYRO_CUTOFF": ParamSpec(
            40.0, False, "low-pass cutoff of the gyro the rate loop and ATTITUDE use [Hz]"
        ),
        "IMU_DGYRO_CUTOFF": ParamSpec(
            30.0, False, "low-pass cutoff of the angular acceleration (rate loop D term) [Hz]"
        ),
        "SIM_GYRO_SIH": ParamSpec(
            1.0, False, "scale of SIH's gyro noise (0.14/0.07/0.03 rad/s roll/pitch/yaw per "
            "250 Hz sample while the rotors push; 0 = off)"
        ),
        "SIM_SP_DELAY": ParamSpec(
            0.006, False, "an offboard attitude/rates setpoint is flown this long after it "
            "arrives [s]: PX4 v1.16 SIH answers 4-9 ms later than the mock without it "
            "(bench/attitude_sweep.py, 0.8-1.6 Hz); 0 = from the next step"
        ),
        "SIM_SPEED_FACTOR": ParamSpec(
            1.0, False, "simulated seconds per second of the clock that drives the mock (the "
            "wall clock, or a replay's lockstep clock), read at boot: PX4 SITL on a slow host "
            "runs at 0.7-0.93x real time (PX4_SIM_SPEED_FACTOR sets it on purpose); the "
            "vehicle, its clock and its stamps all run at that rate"
        ),
        "SIM_SPEED_CHG_T": ParamSpec(
            0.0, False, "simulated time since boot [s] at which the speed factor becomes "
            "SIM_SPEED_CHG (0 = never), read at boot: PX4 SITL slowed from 0.98x to 0.65x "
            "real time mid-flight when its host got busy (2026-12-01)"
        ),
        "SIM_SPEED_CHG": ParamSpec(
            1.0, False, "the speed factor from SIM_SPEED_CHG_T on (see SIM_SPEED_FACTOR)"
        ),
    }
)

# Appended for PX4's AUTO trajectory (PositionSmoothing): the reference waits for a vehicle that
# lags behind it by up to MPC_XY_ERR_MAX (PX4 name, default and range).
PARAMS.update(
    {
        "MPC_XY_ERR_MAX": ParamSpec(
            2.0, False, "horizontal lag behind the AUTO reference at which it stops advancing [m]"
        ),
        # PX4's landing near the ground: the crawl below MPC_LAND_ALT3 needs a distance sensor,
        # which SIH simulates (downward, flat ground); the land detector's three stages
        "MPC_LAND_ALT3": ParamSpec(1.0, False, "height below which AUTO landing crawls [m]"),
        "MPC_LAND_CRWL": ParamSpec(0.3, False, "AUTO landing crawl speed [m/s]"),
        "SIH_DISTSNSR_MIN": ParamSpec(0.0, False, "distance sensor minimum range [m]"),
        "SIH_DISTSNSR_MAX": ParamSpec(100.0, False, "distance sensor maximum range [m]"),
        "LNDMC_TRIG_TIME": ParamSpec(
            1.0, False, "land detection time (3 stages: contact, maybe landed, landed) [s]"
        ),
    }
)

# The Ackermann rover (PX4's rover_ackermann module, lib/rover_control, lib/pure_pursuit): PX4's
# names with the defaults of airframe 10045 `sihsim_rover_ackermann` (rc.rover_ackermann_defaults
# and the airframe file of PX4 main); the quadrotor never reads them. Angles as PX4 has them.
PARAMS.update(
    {
        "RA_WHEEL_BASE": ParamSpec(0.321, False, "wheel base (front to rear axle) [m]"),
        "RA_MAX_STR_ANG": ParamSpec(0.5236, False, "maximum steering angle [rad]"),
        "RA_STR_RATE_LIM": ParamSpec(360.0, False, "steering rate limit [deg/s] (-1 = none)"),
        "RA_ACC_RAD_GAIN": ParamSpec(2.0, False, "gain on the corner-cutting acceptance radius"),
        "RA_ACC_RAD_MAX": ParamSpec(3.0, False, "largest acceptance radius at corners [m]"),
        "RO_YAW_RATE_P": ParamSpec(0.25, False, "yaw rate P gain [rad steering/(rad/s)]"),
        "RO_YAW_RATE_I": ParamSpec(0.01, False, "yaw rate I gain [rad steering/rad]"),
        "RO_YAW_RATE_LIM": ParamSpec(180.0, False, "yaw rate limit [deg/s]"),
        "RO_YAW_ACCEL_LIM": ParamSpec(400.0, False, "yaw acceleration limit [deg/s^2] (-1 = none)"),
        "RO_YAW_DECEL_LIM": ParamSpec(800.0, False, "yaw deceleration limit [deg/s^2] (-1 = none)"),
        "RO_YAW_RATE_TH": ParamSpec(3.0, False, "yaw rates below this read as 0 [deg/s]"),
        "RO_YAW_P": ParamSpec(5.0, False, "yaw P gain [1/s]"),
        "RO_ACCEL_LIM": ParamSpec(3.0, False, "acceleration limit [m/s^2] (-1 = none)"),
        "RO_DECEL_LIM": ParamSpec(3.0, False, "deceleration limit [m/s^2] (-1 = none)"),
        "RO_JERK_LIM": ParamSpec(10.0, False, "jerk limit of the braking law [m/s^3] (-1 = none)"),
        "RO_MAX_THR_SPEED": ParamSpec(3.2, False, "speed at full throttle (feed-forward) [m/s]"),
        "RO_SPEED_LIM": ParamSpec(3.0, False, "speed limit [m/s] (-1 = not configured)"),
        "RO_SPEED_P": ParamSpec(0.001, False, "speed P gain [throttle/(m/s)]"),
        "RO_SPEED_I": ParamSpec(0.001, False, "speed I gain [throttle/m]"),
        "RO_SPEED_RED": ParamSpec(1.0, False, "corner speed reduction gain (-1 = none)"),
        "RO_SPEED_TH": ParamSpec(0.1, False, "speeds below this read as 0 [m/s]"),
        "PP_LOOKAHD_GAIN": ParamSpec(1.0, False, "pure pursuit lookahead per speed [s]"),
        "PP_LOOKAHD_MAX": ParamSpec(10.0, False, "pure pursuit maximum lookahead [m]"),
        "PP_LOOKAHD_MIN": ParamSpec(1.0, False, "pure pursuit minimum lookahead [m]"),
    }
)

# Appended by the rover model: a heading estimate error like EKF2's on SIH (mock-only names, the
# style of SIM_EST_XY_*; the rover also reads those: estimate_error.py).
PARAMS.update(
    {
        "SIM_EST_YAW_STD": ParamSpec(
            0.0, False, "std of the slowly varying heading estimate error [deg] (0 = off)"
        ),
        "SIM_EST_YAW_TAU": ParamSpec(
            2.1, False, "time constant of the heading estimate error [s]"
        ),
        "SIM_EST_YAW_BIAS": ParamSpec(
            0.0, False, "rover: std of the heading estimate's bias for a whole start [deg] "
            "(0 = off)"
        ),
        "SIM_EST_LEAD_S": ParamSpec(
            0.0, False, "rover: the position estimate leads the truth by this much travel [s] "
            "(EKF2 on SIH's GPS: ~0.1 s)"
        ),
    }
)

#: The mock's old rover names -> the PX4 parameter each one is (one value: setting either sets
#: both; the old names keep working for clients and scripts that address them).
ALIASES: dict[str, str] = {
    "RO_MAX_SPEED": "RO_SPEED_LIM",
    "RO_MAX_YAW_RATE": "RO_YAW_RATE_LIM",
    "RO_MAX_ACCEL": "RO_ACCEL_LIM",
}
_LINKS: dict[str, tuple[str, ...]] = {}
for _old, _new in ALIASES.items():
    _LINKS[_old] = _LINKS[_new] = (_old, _new)


def _linked(name: str) -> tuple[str, ...]:
    """`name` and its alias, if it has one."""
    return _LINKS.get(name, (name,))


#: Airframe 10045 `sihsim_rover_ackermann` (PX4 main): its `param set-default` values for the
#: parameters the rover shares with the quadrotor (the rover's own RA_/RO_/PP_ defaults above are
#: already this airframe's). The rover model applies them to its store (`apply_airframe`).
ROVER_AIRFRAME: dict[str, float] = {
    "NAV_ACC_RAD": 0.5,
    "SIH_MASS": 20.0,
    "SIH_IXX": 0.4333,
    "SIH_IYY": 1.6833,
    "SIH_IZZ": 2.0833,
    "SIH_KDV": 50.0,
    "SIH_KDW": 10.0,
}

# Accepted values: PX4 v1.16 parameter metadata (min, max, enumerated values; the build's
# etc/extras/parameters.json, checked by tests/sitl_mock/test_sitl_param_ranges.py) for every
# parameter PX4 has. `_MOCK_RANGES` below replaces or completes a range where PX4 gives none or
# PX4's would break the simulation (PX4 itself does not enforce ranges on PARAM_SET; the mock
# does).
PX4_RANGES: dict[str, tuple[float | None, float | None, tuple[int, ...]]] = {
    "MAV_SYS_ID": (1, 250, ()),
    "COM_OF_LOSS_T": (0.0, 60.0, ()),
    "COM_OBL_RC_ACT": (None, None, (0, 1, 2, 3, 4, 5, 6, 7)),
    "COM_DISARM_PRFLT": (None, None, ()),
    "COM_DISARM_LAND": (None, None, ()),
    "COM_ARM_WO_GPS": (None, None, (0, 1, 2)),
    "MIS_TAKEOFF_ALT": (0.0, None, ()),
    "NAV_ACC_RAD": (0.05, 200.0, ()),
    "RTL_RETURN_ALT": (0.0, None, ()),
    "MPC_THR_HOVER": (0.1, 0.8, ()),
    "MPC_THR_MIN": (0.05, 0.5, ()),
    "MPC_THR_MAX": (0.0, 1.0, ()),
    "MPC_XY_CRUISE": (3.0, 20.0, ()),
    "MPC_XY_VEL_MAX": (0.0, 20.0, ()),
    "MPC_Z_VEL_MAX_UP": (0.5, 8.0, ()),
    "MPC_Z_VEL_MAX_DN": (0.5, 4.0, ()),
    "MPC_TKO_SPEED": (1.0, 5.0, ()),
    "MPC_LAND_SPEED": (0.6, None, ()),
    "MPC_TILTMAX_AIR": (20.0, 89.0, ()),
    "MPC_ACC_HOR": (2.0, 15.0, ()),
    "MPC_ACC_HOR_MAX": (2.0, 15.0, ()),
    "MPC_XY_P": (0.0, 2.0, ()),
    "MPC_Z_P": (0.1, 1.5, ()),
    "MPC_XY_VEL_P_ACC": (1.2, 5.0, ()),
    "MPC_XY_VEL_I_ACC": (0.0, 60.0, ()),
    "MPC_XY_VEL_D_ACC": (0.1, 2.0, ()),
    "MPC_Z_VEL_P_ACC": (2.0, 15.0, ()),
    "MPC_Z_VEL_I_ACC": (0.2, 3.0, ()),
    "MPC_Z_VEL_D_ACC": (0.0, 2.0, ()),
    "MPC_JERK_AUTO": (1.0, 80.0, ()),
    "MPC_XY_ERR_MAX": (0.1, 10.0, ()),
    "MPC_LAND_ALT3": (0.0, 122.0, ()),
    "MPC_LAND_CRWL": (0.1, None, ()),
    "SIH_DISTSNSR_MIN": (0.0, 10.0, ()),
    "SIH_DISTSNSR_MAX": (0.0, 1000.0, ()),
    "LNDMC_TRIG_TIME": (0.1, 10.0, ()),
    "MC_ROLL_P": (0.0, 12.0, ()),
    "MC_PITCH_P": (0.0, 12.0, ()),
    "MC_YAW_P": (0.0, 5.0, ()),
    "MC_ROLLRATE_MAX": (0.0, 1800.0, ()),
    "MC_PITCHRATE_MAX": (0.0, 1800.0, ()),
    "MC_YAWRATE_MAX": (0.0, 1800.0, ()),
    "MC_AIRMODE": (None, None, (0, 1, 2)),
    "SIH_MASS": (0.0, None, ()),
    "SIH_IXX": (0.0, None, ()),
    "SIH_IYY": (0.0, None, ()),
    "SIH_IZZ": (0.0, None, ()),
    "SIH_T_MAX": (0.0, None, ()),
    "SIH_Q_MAX": (0.0, None, ()),
    "SIH_L_ROLL": (0.0, None, ()),
    "SIH_L_PITCH": (0.0, None, ()),
    "SIH_KDV": (0.0, None, ()),
    "SIH_KDW": (0.0, None, ()),
    "SIH_T_TAU": (None, None, ()),
    "SIM_BAT_DRAIN": (1.0, 86400.0, ()),
    "SIM_BAT_MIN_PCT": (0.0, 100.0, ()),
    "MC_ROLLRATE_P": (0.01, 0.5, ()),
    "MC_ROLLRATE_I": (0.0, None, ()),
    "MC_ROLLRATE_D": (0.0, 0.01, ()),
    "MC_PITCHRATE_P": (0.01, 0.6, ()),
    "MC_PITCHRATE_I": (0.0, None, ()),
    "MC_PITCHRATE_D": (0.0, None, ()),
    "MC_YAWRATE_P": (0.0, 0.6, ()),
    "MC_YAWRATE_I": (0.0, None, ()),
    "MC_YAWRATE_D": (0.0, None, ()),
    "MC_YAW_WEIGHT": (0.0, 1.0, ()),
    "MPC_THR_XY_MARG": (0.0, 0.5, ()),
    "MPC_TKO_RAMP_T": (0.0, 5.0, ()),
    "COM_SPOOLUP_TIME": (0.0, 30.0, ()),
    "MPC_LAND_ALT1": (0.0, 122.0, ()),
    "MPC_LAND_ALT2": (0.0, 122.0, ()),
    "MPC_ACC_UP_MAX": (2.0, 15.0, ()),
    "MPC_ACC_DOWN_MAX": (2.0, 15.0, ()),
    "NAV_MC_ALT_RAD": (0.05, 200.0, ()),
    "MPC_TILTMAX_LND": (5.0, 89.0, ()),
    "BAT_LOW_THR": (0.12, 0.5, ()),
    "BAT_CRIT_THR": (0.05, 0.5, ()),
    "BAT_EMERGEN_THR": (0.03, 0.5, ()),
    "COM_LOW_BAT_ACT": (None, None, (0, 2, 3)),
    "IMU_GYRO_CUTOFF": (0.0, 1000.0, ()),
    "IMU_DGYRO_CUTOFF": (0.0, 1000.0, ()),
    "RA_WHEEL_BASE": (0.0, 100.0, ()),
    "RA_MAX_STR_ANG": (0.0, 1.5708, ()),
    "RA_STR_RATE_LIM": (-1.0, 1000.0, ()),
    "RA_ACC_RAD_GAIN": (1.0, 100.0, ()),
    "RA_ACC_RAD_MAX": (-1.0, 100.0, ()),
    "RO_YAW_RATE_P": (0.0, 100.0, ()),
    "RO_YAW_RATE_I": (0.0, 100.0, ()),
    "RO_YAW_RATE_LIM": (0.0, 10000.0, ()),
    "RO_YAW_ACCEL_LIM": (-1.0, 10000.0, ()),
    "RO_YAW_DECEL_LIM": (-1.0, 10000.0, ()),
    "RO_YAW_RATE_TH": (0.0, 100.0, ()),
    "RO_YAW_P": (0.0, 100.0, ()),
    "RO_ACCEL_LIM": (-1.0, 100.0, ()),
    "RO_DECEL_LIM": (-1.0, 100.0, ()),
    "RO_JERK_LIM": (-1.0, 100.0, ()),
    "RO_MAX_THR_SPEED": (0.0, 100.0, ()),
    "RO_SPEED_LIM": (-1.0, 100.0, ()),
    "RO_SPEED_P": (0.0, 100.0, ()),
    "RO_SPEED_I": (0.0, 100.0, ()),
    "RO_SPEED_TH": (0.0, 100.0, ()),
    "PP_LOOKAHD_GAIN": (0.1, 100.0, ()),
    "PP_LOOKAHD_MAX": (0.1, 100.0, ()),
    "PP_LOOKAHD_MIN": (0.1, 100.0, ()),
}

_MOCK_RANGES: dict[str, tuple[float, float]] = {
    # PX4 has no range: the mock's (disarm timeouts: -1 disables, as in PX4)
    "COM_DISARM_PRFLT": (-1.0, 3600.0),
    "COM_DISARM_LAND": (-1.0, 3600.0),
    "MIS_TAKEOFF_ALT": (0.0, 10_000.0),  # GF_MAX_VER_DIST's maximum
    "RTL_RETURN_ALT": (0.0, 10_000.0),
    "MPC_LAND_SPEED": (0.6, 4.0),  # MPC_Z_VEL_MAX_DN's maximum
    "MPC_LAND_CRWL": (0.1, 4.0),
    "MC_ROLLRATE_I": (0.0, 10.0),
    "MC_PITCHRATE_I": (0.0, 10.0),
    "MC_YAWRATE_I": (0.0, 10.0),
    "MC_PITCHRATE_D": (0.0, 0.1),
    "MC_YAWRATE_D": (0.0, 0.1),
    # SIH: PX4 allows 0 (a division by zero in SIH too) and has no maximum; small vehicles only
    "SIH_MASS": (0.05, 100.0),
    "SIH_IXX": (1e-4, 10.0),
    "SIH_IYY": (1e-4, 10.0),
    "SIH_IZZ": (1e-4, 10.0),
    "SIH_T_MAX": (0.1, 1000.0),
    "SIH_Q_MAX": (1e-3, 100.0),
    "SIH_L_ROLL": (0.01, 5.0),
    "SIH_L_PITCH": (0.01, 5.0),
    "SIH_KDV": (0.0, 100.0),
    "SIH_KDW": (0.0, 10.0),
    "SIH_T_TAU": (1e-3, 10.0),
    # rover geometry: PX4 allows 0 (its rover then refuses to drive) and a steering angle a hair
    # past pi/2 (tan < 0); the mock keeps to what an Ackermann rover can be
    "RA_WHEEL_BASE": (0.01, 100.0),
    "RA_MAX_STR_ANG": (0.01, 1.5),
    # PX4 main only (not in PX4 v1.16's metadata): PX4 main's range
    "RO_SPEED_RED": (-1.0, 100.0),
    # mock-only parameters (the old rover names: their PX4 parameter's range, see ALIASES)
    "RO_MAX_SPEED": (-1.0, 100.0),
    "RO_MAX_YAW_RATE": (0.0, 10000.0),
    "RO_MAX_ACCEL": (-1.0, 100.0),
    "SIM_POS_NOISE": (0.0, 10.0),
    "SIM_VEL_NOISE": (0.0, 10.0),
    "SIM_GYRO_NOISE": (0.0, 1.0),
    "SIM_WIND_GUST": (0.0, 30.0),
    "SIM_WIND_GUST_T": (0.05, 600.0),
    "SIM_EST_XY_STD": (0.0, 10.0),
    "SIM_EST_VXY_STD": (0.0, 10.0),
    "SIM_EST_XY_TAU": (0.05, 600.0),
    "SIM_EST_YAW_STD": (0.0, 180.0),
    "SIM_EST_YAW_TAU": (0.05, 600.0),
    "SIM_EST_LEAD_S": (0.0, 2.0),
    "SIM_EST_YAW_BIAS": (0.0, 180.0),
    "SIM_GYRO_SIH": (0.0, 10.0),
    "SIM_SP_DELAY": (0.0, 0.1),
    "SIM_SPEED_FACTOR": (0.1, 10.0),
    "SIM_SPEED_CHG_T": (0.0, 1e6),
    "SIM_SPEED_CHG": (0.1, 10.0),
}


def _with_ranges() -> None:
    for name, spec in PARAMS.items():
        lo, hi, values = PX4_RANGES.get(name, (None, None, ()))
        mock = name in _MOCK_RANGES
        if mock:
            lo, hi = _MOCK_RANGES[name]
        PARAMS[name] = replace(
            spec,
            lo=-math.inf if lo is None else float(lo),
            hi=math.inf if hi is None else float(hi),
            values=values,
            mock_range=mock,
        )


_with_ranges()
