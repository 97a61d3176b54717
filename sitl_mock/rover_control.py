"""PX4 main's Ackermann rover control structure, written anew for the mock (no clock, no I/O).

The stages of PX4-Autopilot's rover_ackermann module with lib/rover_control and
lib/pure_pursuit, each a small class owning its state. Frame: local NED (north, east) [m], yaw
from north [rad], SI units; PX4's degree parameters are converted where they are read.

    RoverPositionTarget --PositionControl--> (speed [m/s], bearing [rad])
      pure pursuit along start -> goal (lookahead PP_LOOKAHD_GAIN x speed in
      [PP_LOOKAHD_MIN, PP_LOOKAHD_MAX]); speed from the jerk-limited braking law
      (RO_JERK_LIM, RO_DECEL_LIM) towards the arrival speed, capped at RO_SPEED_LIM and the
      cruising speed; stop within the acceptance radius
    speed --SpeedControl--> throttle: the setpoint slewed at RO_ACCEL_LIM / RO_DECEL_LIM,
      feed-forward speed / RO_MAX_THR_SPEED plus PI (RO_SPEED_P, RO_SPEED_I)
    bearing --AttitudeControl--> yaw rate: the yaw setpoint slewed at the yaw rate the steering
      allows, times RO_YAW_P, within RO_YAW_RATE_LIM
    yaw rate --RateControl--> steering: limited to min(RO_YAW_RATE_LIM, v tan(RA_MAX_STR_ANG) /
      RA_WHEEL_BASE), slewed at RO_YAW_ACCEL_LIM / RO_YAW_DECEL_LIM; Ackermann feed-forward
      atan(r L / v) plus PI (RO_YAW_RATE_P, RO_YAW_RATE_I)
    Actuators: throttle slewed at RO_ACCEL_LIM / RO_MAX_THR_SPEED (easing: RO_DECEL_LIM),
      steering at RA_STR_RATE_LIM; both normalised to -1..1 (steering: of RA_MAX_STR_ANG).

As in PX4, the attitude and rate stages take the speed from the throttle (throttle x
RO_MAX_THR_SPEED), so the wheels steer before the rover rolls. The AUTO helpers
(`transition_angle`, `corner_acceptance_radius`, `arrival_speed`, `min_corner_speed`) are PX4's
AckermannAutoMode: cut a corner on the arc of the smallest turning radius and slow down to
RO_MAX_THR_SPEED x (1 - RO_SPEED_RED x turn / pi), no slower than the speed at which the yaw rate
limit and the steering limit meet.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

from sitl_mock.setpoints import RoverPositionTarget

_isfinite = math.isfinite
EPS = 1e-6


def wrap_pi(a: float) -> float:
    """Angle wrapped to [-pi, pi) [rad]."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def _clip(x: float, lo: float, hi: float) -> float:
    return lo if x < lo else hi if x > hi else x


def _normalise(x: float, x_max: float) -> float:
    """x / x_max clipped to -1..1 (PX4's interpolate onto [-1, 1]); 0 if x_max <= 0."""
    return _clip(x / x_max, -1.0, 1.0) if x_max > 0.0 else 0.0


class Slew:
    """A value moving towards its target by at most `rate` x dt per update (PX4's SlewRate);
    a rate <= 0 means no limit."""

    def __init__(self, value: float = 0.0) -> None:
        self.value = value

    def toward(self, target: float, rate: float, dt: float) -> float:
        if rate > 0.0:
            step = rate * dt
            self.value += _clip(target - self.value, -step, step)
        else:
            self.value = target
        return self.value

    def toward_measured(self, target: float, measured: float, rate: float, dt: float) -> float:
        """`toward`, then back on the target if the slewed value ended farther from the
        measurement than the target itself (PX4's rover slews re-initialise that way: a
        vehicle already past the ramp is not pulled back to it)."""
        self.toward(target, rate, dt)
        if abs(self.value - measured) > abs(target - measured):
            self.value = target
        return self.value


class PI:
    """PX4's PID without D: out = kp e + integral (then clipped to +-out_lim); the integral
    grows by ki e dt afterwards, within +-i_lim."""

    def __init__(self) -> None:
        self.integral = 0.0

    def update(self, error: float, kp: float, ki: float, dt: float, i_lim: float = 1.0,
               out_lim: float = 1.0) -> float:
        out = kp * error + self.integral
        new = self.integral + ki * error * dt
        if _isfinite(new):
            self.integral = _clip(new, -i_lim, i_lim)
        return _clip(out, -out_lim, out_lim)

    def reset(self) -> None:
        self.integral = 0.0


@dataclass(frozen=True)
class RoverParams:
    """The rover parameters the controller reads, SI units (angles rad, rates rad/s)."""

    wheel_base_m: float
    max_steer_rad: float
    steer_rate_rad_s: float  # <= 0: no limit
    acc_rad_gain: float
    acc_rad_max_m: float
    nav_acc_rad_m: float
    yaw_rate_p: float
    yaw_rate_i: float
    max_yaw_rate: float
    yaw_accel: float  # <= 0: no limit
    yaw_decel: float
    yaw_rate_th: float
    yaw_p: float
    accel: float  # <= 0: no limit
    decel: float
    jerk: float
    max_thr_speed: float
    speed_lim: float
    speed_p: float
    speed_i: float
    speed_red: float
    speed_th: float
    lookahead_gain: float
    lookahead_max_m: float
    lookahead_min_m: float

    @classmethod
    def read(cls, p: Mapping[str, float]) -> RoverParams:
        """From a parameter store (PX4 names and units)."""
        d = math.radians
        return cls(
            wheel_base_m=p["RA_WHEEL_BASE"], max_steer_rad=p["RA_MAX_STR_ANG"],
            steer_rate_rad_s=d(p["RA_STR_RATE_LIM"]), acc_rad_gain=p["RA_ACC_RAD_GAIN"],
            acc_rad_max_m=p["RA_ACC_RAD_MAX"], nav_acc_rad_m=p["NAV_ACC_RAD"],
            yaw_rate_p=p["RO_YAW_RATE_P"], yaw_rate_i=p["RO_YAW_RATE_I"],
            max_yaw_rate=d(p["RO_YAW_RATE_LIM"]), yaw_accel=d(p["RO_YAW_ACCEL_LIM"]),
            yaw_decel=d(p["RO_YAW_DECEL_LIM"]), yaw_rate_th=d(p["RO_YAW_RATE_TH"]),
            yaw_p=p["RO_YAW_P"], accel=p["RO_ACCEL_LIM"], decel=p["RO_DECEL_LIM"],
            jerk=p["RO_JERK_LIM"], max_thr_speed=p["RO_MAX_THR_SPEED"],
            speed_lim=p["RO_SPEED_LIM"], speed_p=p["RO_SPEED_P"], speed_i=p["RO_SPEED_I"],
            speed_red=p["RO_SPEED_RED"], speed_th=p["RO_SPEED_TH"],
            lookahead_gain=p["PP_LOOKAHD_GAIN"], lookahead_max_m=p["PP_LOOKAHD_MAX"],
            lookahead_min_m=p["PP_LOOKAHD_MIN"],
        )

    def max_yaw_rate_at(self, speed: float) -> float:
        """Largest yaw rate [rad/s] at `speed` [m/s]: the steering limit's or RO_YAW_RATE_LIM."""
        steer = abs(speed) * math.tan(self.max_steer_rad) / self.wheel_base_m
        return min(steer, self.max_yaw_rate)


# ----------------------------------------------------------------------------- guidance


def speed_from_distance(jerk: float, accel: float, distance: float, final_speed: float = 0.0
                        ) -> float:
    """Highest speed [m/s] from which a jerk- (`jerk` m/s^3) and acceleration-limited (`accel`
    m/s^2) braking reaches `final_speed` within `distance` [m] (the braking law of PX4's
    trajectory library, used by its multicopter AUTO trajectories and its rovers:
    v^2 / (2 a) + v a / j ~ distance), never below `final_speed` (the law's jerk term alone
    would ask for less near the end)."""
    b = 4.0 * accel * accel / jerk
    c = -2.0 * accel * distance - final_speed * final_speed
    return max(0.5 * (-b + math.sqrt(b * b - 4.0 * c)), final_speed)



def braking_speed(p: RoverParams, distance_m: float, final_speed: float) -> float:
    """Highest speed [m/s] from which the rover still brakes to `final_speed` within
    `distance_m` (RO_DECEL_LIM, RO_JERK_LIM; without a jerk limit v^2 = vf^2 + 2 a d; without a
    deceleration limit unbounded)."""
    d = max(distance_m, 0.0)
    if not p.decel > 0.0:
        return math.inf
    if not p.jerk > 0.0:
        return math.sqrt(final_speed * final_speed + 2.0 * p.decel * d)
    return speed_from_distance(p.jerk, p.decel, d, final_speed)


def pure_pursuit_bearing(goal: tuple[float, float], start: tuple[float, float],
                         pos: tuple[float, float], speed: float, p: RoverParams) -> float:
    """Bearing [rad] to steer for on the line start -> goal (PX4's pure pursuit): towards the
    point of the line one lookahead distance away (lookahead = PP_LOOKAHD_GAIN |speed| within
    [PP_LOOKAHD_MIN, PP_LOOKAHD_MAX]); straight at the goal when it is nearer than that, when the
    rover is past it or the line has no length; when the line is out of reach, to its nearest
    point (or to the start / goal if that point lies before / beyond the segment)."""
    lookahead = _clip(p.lookahead_gain * abs(speed), p.lookahead_min_m, p.lookahead_max_m)
    gx, gy = goal
    sx, sy = start
    px, py = pos
    lx, ly = gx - sx, gy - sy
    length = math.hypot(lx, ly)
    to_goal = math.atan2(gy - py, gx - px)
    if math.hypot(gx - px, gy - py) < lookahead or length < EPS:
        return to_goal
    ux, uy = lx / length, ly / length
    along = (px - sx) * ux + (py - sy) * uy  # signed distance of the rover along the line
    if along > length:
        return to_goal
    fx, fy = sx + along * ux, sy + along * uy  # foot of the perpendicular from the rover
    off = math.hypot(fx - px, fy - py)
    if off > lookahead:
        if along < EPS:
            return math.atan2(sy - py, sx - px)
        return math.atan2(fy - py, fx - px)
    ahead = along + math.sqrt(lookahead * lookahead - off * off)
    return math.atan2(sy + ahead * uy - py, sx + ahead * ux - px)


def transition_angle(prev: tuple[float, float] | None, curr: tuple[float, float],
                     nxt: tuple[float, float] | None) -> float:
    """Angle [rad] at `curr` between the legs to `prev` and to `nxt`: pi straight on, pi/2 a
    right-angle corner, 0 a U-turn; NaN without a previous or next waypoint (or overlapping)."""
    if prev is None or nxt is None:
        return math.nan
    ax, ay = prev[0] - curr[0], prev[1] - curr[1]
    bx, by = nxt[0] - curr[0], nxt[1] - curr[1]
    na, nb = math.hypot(ax, ay), math.hypot(bx, by)
    if na < EPS or nb < EPS:
        return math.nan
    return math.acos(_clip((ax * bx + ay * by) / (na * nb), -1.0, 1.0))


def corner_acceptance_radius(angle: float, p: RoverParams) -> float:
    """Acceptance radius [m] at a corner of `angle` (PX4's AckermannAutoMode): the distance from
    the corner at which an arc of the smallest turning radius RA_WHEEL_BASE / sin(RA_MAX_STR_ANG)
    joins both legs, times RA_ACC_RAD_GAIN, within [NAV_ACC_RAD, RA_ACC_RAD_MAX]; NAV_ACC_RAD
    without a corner or when RA_ACC_RAD_MAX < NAV_ACC_RAD."""
    nav = p.nav_acc_rad_m
    if not _isfinite(angle) or p.acc_rad_max_m < nav:
        return nav
    half_tan = math.tan(angle / 2.0)
    if half_tan < EPS:
        return p.acc_rad_max_m
    turning = p.wheel_base_m / math.sin(p.max_steer_rad)
    return _clip(p.acc_rad_gain * turning / half_tan, nav, p.acc_rad_max_m)


def min_corner_speed(p: RoverParams) -> float:
    """Speed [m/s] below which the steering, not RO_YAW_RATE_LIM, limits the yaw rate."""
    return p.wheel_base_m * p.max_yaw_rate / math.tan(p.max_steer_rad)


def arrival_speed(cruising: float, angle: float, stop: bool, p: RoverParams) -> float:
    """Speed [m/s] to arrive at a waypoint with: 0 at the last one (no corner) or where the
    rover stops (`stop`); else RO_MAX_THR_SPEED x (1 - RO_SPEED_RED x (pi - angle) / pi), at
    least `min_corner_speed`, at most `cruising`; `cruising` when RO_SPEED_RED <= 0."""
    if stop or not _isfinite(angle):
        return 0.0
    if p.speed_red > 0.0:
        red = _clip(p.speed_red * (math.pi - angle) / math.pi, 0.0, 1.0)
        return min(max(p.max_thr_speed * (1.0 - red), min_corner_speed(p)), cruising)
    return cruising


def position_control(target: RoverPositionTarget, pos: tuple[float, float], yaw: float,
                     p: RoverParams) -> tuple[float, float]:
    """(speed [m/s], bearing [rad]) towards `target` (PX4's AckermannPosControl): stop with the
    heading held within the acceptance radius or without a goal."""
    gx, gy = target.position_ne
    if not (_isfinite(gx) and _isfinite(gy)):
        return 0.0, yaw
    dist = math.hypot(gx - pos[0], gy - pos[1])
    if dist <= target.acceptance_radius_m:
        return 0.0, yaw
    arrival = target.arrival_speed if _isfinite(target.arrival_speed) else 0.0
    brake_dist = dist - target.acceptance_radius_m if arrival > EPS else dist
    speed = min(braking_speed(p, brake_dist, abs(arrival)), max(p.speed_lim, 0.0))
    if _isfinite(target.cruising_speed):
        speed = math.copysign(min(speed, abs(target.cruising_speed)), target.cruising_speed)
    sx, sy = target.start_ne
    start = (sx, sy) if _isfinite(sx) and _isfinite(sy) else pos
    bearing = pure_pursuit_bearing((gx, gy), start, pos, speed, p)
    return speed, bearing if speed >= 0.0 else wrap_pi(bearing + math.pi)


# ----------------------------------------------------------------------------- control loops


class SpeedControl:
    """Speed setpoint -> throttle (PX4's AckermannSpeedControl / RoverControl::speedControl)."""

    def __init__(self) -> None:
        self.adjusted = Slew()
        self.pi = PI()

    def update(self, speed_sp: float, speed: float, dt: float, p: RoverParams) -> float:
        """Throttle -1..1 for `speed_sp` [m/s] at the measured forward `speed` [m/s]."""
        if not p.speed_lim > 0.0:
            return 0.0  # RO_SPEED_LIM not configured: PX4's rover refuses to drive
        sp = _clip(speed_sp, -p.speed_lim, p.speed_lim)
        rate = p.accel if abs(sp) >= abs(speed) else p.decel
        adj = self.adjusted.toward_measured(sp, speed, rate, dt)
        out = _normalise(adj, p.max_thr_speed) if p.max_thr_speed > 0.0 else 0.0
        if abs(adj) > EPS:
            out += self.pi.update(adj - speed, p.speed_p, p.speed_i, dt)
        else:
            self.pi.reset()
        return _clip(out, -1.0, 1.0)

    def reset(self, speed: float) -> None:
        self.adjusted.value = speed
        self.pi.reset()


class AttitudeControl:
    """Yaw setpoint -> yaw rate setpoint (PX4's AckermannAttControl): the setpoint moves at
    most at the yaw rate the rover can reach at its (throttle-estimated) speed."""

    def __init__(self) -> None:
        self.adjusted = 0.0

    def update(self, yaw_sp: float, yaw: float, speed_est: float, dt: float,
               p: RoverParams) -> float:
        rate = p.max_yaw_rate_at(speed_est)
        sp = wrap_pi(yaw_sp)
        if rate > EPS:
            step = rate * dt
            self.adjusted = wrap_pi(self.adjusted + _clip(wrap_pi(sp - self.adjusted), -step, step))
            if abs(wrap_pi(self.adjusted - yaw)) > abs(wrap_pi(sp - yaw)):
                self.adjusted = sp
        else:
            self.adjusted = sp
        return _clip(p.yaw_p * wrap_pi(self.adjusted - yaw), -p.max_yaw_rate, p.max_yaw_rate)

    def reset(self, yaw: float) -> None:
        self.adjusted = yaw


class RateControl:
    """Yaw rate setpoint -> steering angle (PX4's AckermannRateControl): Ackermann
    feed-forward atan(r L / v) plus PI on the yaw rate error while driving forwards."""

    def __init__(self) -> None:
        self.adjusted = Slew()
        self.pi = PI()

    def update(self, rate_sp: float, rate: float, speed_est: float, dt: float,
               p: RoverParams) -> float:
        """Steering angle [rad] (not yet limited) for `rate_sp` [rad/s]."""
        if abs(speed_est) <= EPS:
            self.pi.reset()
            self.adjusted.value = rate
            return 0.0
        lim = p.max_yaw_rate_at(speed_est)
        sp = _clip(rate_sp, -lim, lim)
        slew = p.yaw_accel if abs(sp) >= abs(rate) else p.yaw_decel
        adj = self.adjusted.toward_measured(sp, rate, slew, dt)
        steer = math.atan(adj * p.wheel_base_m / speed_est)
        if speed_est > EPS:  # backwards driving is non-minimum-phase: feed-forward only
            steer += self.pi.update(adj - rate, p.yaw_rate_p, p.yaw_rate_i, dt)
        return steer

    def reset(self, rate: float) -> None:
        self.adjusted.value = rate
        self.pi.reset()


class Actuators:
    """Normalised throttle and steering with PX4's actuator slew rates (AckermannActControl)."""

    def __init__(self) -> None:
        self.throttle = Slew()
        self.steering = Slew()

    def update(self, throttle_sp: float, steering_sp: float, dt: float,
               p: RoverParams) -> tuple[float, float]:
        """(throttle, steering) outputs, each -1..1."""
        thr_sp = _clip(throttle_sp, -1.0, 1.0)
        cur = self.throttle.value
        lim = p.accel if abs(thr_sp) > abs(cur) else p.decel
        rate = lim / p.max_thr_speed if lim > 0.0 and p.max_thr_speed > 0.0 else 0.0
        self.throttle.toward_measured(thr_sp, cur, rate, dt)
        srate = p.steer_rate_rad_s / p.max_steer_rad if p.steer_rate_rad_s > 0.0 else 0.0
        self.steering.toward(_clip(steering_sp, -1.0, 1.0), srate, dt)
        return self.throttle.value, self.steering.value

    def stop(self) -> None:
        """Outputs to zero at once (PX4's stopVehicle; disarmed)."""
        self.throttle.value = self.steering.value = 0.0


class AckermannController:
    """The whole chain from a (speed, bearing) or position goal to actuator outputs."""

    def __init__(self) -> None:
        self.speed = SpeedControl()
        self.attitude = AttitudeControl()
        self.rate = RateControl()
        self.actuators = Actuators()
        self.speed_sp = 0.0
        self.yaw_sp = 0.0
        self.rate_sp = 0.0

    def reset(self, speed: float, yaw: float, rate: float) -> None:
        """Restart every stage from the measured state (PX4 resets on a mode change)."""
        self.speed.reset(speed)
        self.attitude.reset(yaw)
        self.rate.reset(rate)

    def drive(self, speed_sp: float, bearing: float, speed: float, yaw: float, rate: float,
              dt: float, p: RoverParams) -> tuple[float, float]:
        """(throttle, steering) outputs for `speed_sp` [m/s] along `bearing` [rad], from the
        measured forward speed [m/s], yaw [rad] and yaw rate [rad/s] (dead-banded by
        RO_SPEED_TH / RO_YAW_RATE_TH as PX4 reads them)."""
        v_meas = speed if abs(speed) > p.speed_th else 0.0
        r_meas = rate if abs(rate) > p.yaw_rate_th else 0.0
        self.speed_sp, self.yaw_sp = speed_sp, bearing
        throttle = self.speed.update(speed_sp, v_meas, dt, p)
        # the attitude and rate loops take the speed from the throttle already commanded
        v_est = self.actuators.throttle.value * p.max_thr_speed
        v_est = v_est if abs(v_est) > p.speed_th else 0.0
        self.rate_sp = self.attitude.update(bearing, yaw, v_est, dt, p)
        steer = self.rate.update(self.rate_sp, r_meas, v_est, dt, p)
        return self.actuators.update(throttle, _normalise(steer, p.max_steer_rad), dt, p)
