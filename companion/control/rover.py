"""Rover path following: velocity + yaw-rate setpoints from rover flatness with cross-track,
along-track and heading correction."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from companion.control.commands import PositionCommand
from companion.control.so3 import quat_to_dcm, yaw_of_dcm
from companion.control.state import StateEstimate
from companion.flatness import rover_setpoint
from companion.flatness.reference import Reference

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class RoverGains:
    """Rover path-following gains.

    k_along [1/s]: speed correction per metre of along-track error.
    k_cross [1/m]: heading correction atan(k * cross-track error), k = k_cross at low speed.
    k_heading [1/s]: yaw-rate correction per radian of heading error.
    max_speed [m/s], max_yaw_rate [rad/s]: command limits.
    crab_tau_s [s], speed_tau_s [s]: the heading-to-course offset's and the speed ratio's
    filters.
    """

    k_along: float = 1.0
    k_cross: float = 0.8
    lookahead_s: float = 0.7
    """The heading correction's gain is at most 1 / (lookahead_s * v) [1/m] at the driven speed
    v (see :meth:`RoverController.cross_gain`); <= 0: no cap."""
    k_heading: float = 2.0
    max_speed: float = 3.0
    max_yaw_rate: float = math.radians(90.0)
    crab_tau_s: float = 2.0
    """Time constant [s] of the heading-to-course offset estimate (see RoverController)."""
    speed_tau_s: float = 2.0
    """Time constant [s] of the speed-ratio estimate (see RoverController)."""


#: The heading-to-course offset is learnt only while the rover drives straight this fast or
#: faster [m/s], turning slower than CRAB_MAX_TURN_RAD_S, and only offsets up to CRAB_MAX_RAD.
CRAB_MIN_SPEED_M_S = 0.5
CRAB_MAX_TURN_RAD_S = 0.15
CRAB_MAX_RAD = math.radians(30.0)
#: The speed ratio (driven / commanded) is learnt while the command is at least this [m/s] and
#: changes slower than SPEED_RATIO_MAX_DCMD [m/s^2]; it is kept within SPEED_RATIO_RANGE.
SPEED_RATIO_MIN_CMD_M_S = 0.8
SPEED_RATIO_MAX_DCMD = 0.5
SPEED_RATIO_RANGE = (0.5, 2.0)
#: Arrived at a stop of the reference: its speed below ARRIVED_REF_SPEED_M_S and the rover at
#: most ARRIVED_LAG_M short of it along its heading (or past it: a car cannot back up to it).
ARRIVED_REF_SPEED_M_S = 0.05
ARRIVED_LAG_M = 0.3
#: Farther than ARRIVED_LAG_M behind its reference the rover is commanded at least this [m/s].
CREEP_SPEED_M_S = 0.5


class RoverController:
    """Rover tracking: velocity + yaw-rate setpoints from rover flatness plus a correction.

    PX4 turns a rover's estimated heading to the commanded velocity's direction; where that
    estimate is off (PX4 SIH's Ackermann rover drove straight legs 10-12 deg off its heading
    estimate: a magnetometer-fused yaw error) the rover drives off the commanded course and the
    cross-track feedback leaves a steady error (0.3 m at 12 deg). The offset between the
    estimated heading and the course over the ground (from the velocity) is learnt while driving
    straight (``crab_tau_s``) and added to the commanded direction.

    PX4's rover drives its speed open loop on a throttle feed-forward (RO_SPEED_P 0.001 on the
    SIH airframe): commanded speeds came out 10-40 % faster, and the along-track feedback left
    the rover ahead of its reference. The ratio of driven to commanded speed is learnt while
    the planned speed is steady and the command not clamped (``speed_tau_s``), and the planned
    speed (the feed-forward) divided by it.

    ``arrived``: the reference is at a stop and the rover has reached it (or passed it: a car
    cannot back up), e.g. at the mission's end.
    """

    def __init__(self, gains: RoverGains | None = None) -> None:
        self.gains = gains or RoverGains()
        self._last_heading: float | None = None
        self.last_lag_m = 0.0  # along-track error of the last update: > 0 behind [m]
        self.crab_rad = 0.0  # estimated heading minus course over the ground [rad]
        self.speed_ratio = 1.0  # driven / commanded speed
        self.arrived = False  # at a stop of the reference, reached (or passed) and slow
        self._t_prev: float | None = None
        self._cmd_prev: float | None = None  # the last reference speed [m/s]
        self._sent_prev: float | None = None  # the last speed sent [m/s]

    def update(self, now: float, est: StateEstimate, ref: Reference,
               path: Reference | None = None, ahead: Reference | None = None
               ) -> PositionCommand:
        """Velocity (NED, z NaN), yaw and yaw-rate setpoint at `now`.

        The reference heading/speed/yaw rate come from rover flatness of the xy reference;
        the along-track error corrects the speed, the cross-track error the heading, the heading
        error the yaw rate. ``path``: the reference where its path passes closest to the
        rover (default ``ref``): the heading, the cross-track error and the planned speed come
        from it, the along-track error from ``ref`` (a rover behind its reference time steers
        by the path beside it, not by a point round the next corner). ``ahead``: the path a
        little further on, whose planned speed is commanded (PX4's rover answers a speed
        command ~0.5 s late: it braked 0.9 m past the end point on the planned speed beside
        it); default ``path``. Bad input -> stop (zero velocity, zero yaw rate), flagged.
        """
        beside = ref if path is None else path
        lead = beside if ahead is None else ahead
        k = self.gains
        if not (math.isfinite(now) and est.is_finite() and ref.is_finite()
                and beside.is_finite()):
            return PositionCommand(
                vel_ned=np.array([0.0, 0.0, math.nan]), yaw_rate=0.0,
                fallback=True, reason="input not finite",
            )
        try:
            rs = rover_setpoint(beside.vel_ned[:2], beside.acc_ned[:2], beside.jerk_ned[:2])
        except ValueError as exc:
            return PositionCommand(
                vel_ned=np.array([0.0, 0.0, math.nan]), yaw_rate=0.0,
                fallback=True, reason=f"rover flatness refused the input: {exc}",
            )
        speed = float(np.hypot(lead.vel_ned[0], lead.vel_ned[1])) if lead.is_finite() \
            else float(np.asarray(rs.speed).reshape(-1)[0])
        psi_ref = float(np.asarray(rs.yaw).reshape(-1)[0])
        r_ref = float(np.asarray(rs.yaw_rate).reshape(-1)[0])
        if not (math.isfinite(psi_ref) and math.isfinite(r_ref) and math.isfinite(speed)):
            psi_ref, r_ref, speed = beside.yaw, 0.0, 0.0
        if speed < 1e-3 and self._last_heading is not None:
            psi_ref = self._last_heading
        self._last_heading = psi_ref
        # latency: extrapolate the position with the measured velocity
        tau = min(max(now - est.t_s, 0.0), 0.25)
        pos = est.pos_ned[:2] + est.vel_ned[:2] * tau
        t_hat = np.array([math.cos(psi_ref), math.sin(psi_ref)])
        n_hat = np.array([-math.sin(psi_ref), math.cos(psi_ref)])
        e_at = float((ref.pos_ned[:2] - pos) @ t_hat)
        e_ct = float((beside.pos_ned[:2] - pos) @ n_hat)
        self.last_lag_m = e_at
        yaw_est = yaw_of_dcm(quat_to_dcm(est.q_wxyz))
        dt = 0.0 if self._t_prev is None else now - self._t_prev
        self._t_prev = now
        self._learn_crab(dt, est, yaw_est)
        self._learn_speed_ratio(dt, est, speed)
        # the learnt ratio scales the planned speed (the feed-forward) only: at a stop the
        # along-track feedback alone brings the rover in
        speed_cmd = min(max(speed / self.speed_ratio + k.k_along * e_at, 0.0), k.max_speed)
        if e_at > ARRIVED_LAG_M and speed_cmd < CREEP_SPEED_M_S:
            # short of the reference: never a speed the rover does not move for (PX4's SIH
            # rover stood still 0.3 m short of the end on 0.2 m/s)
            speed_cmd = CREEP_SPEED_M_S
        self._sent_prev = speed_cmd
        # position only: at rest PX4's rover reported 0.6-0.8 m/s of velocity while standing
        self.arrived = speed < ARRIVED_REF_SPEED_M_S and e_at <= ARRIVED_LAG_M
        # the course wanted over the ground, as the heading PX4 must hold for it
        v_now = math.hypot(float(est.vel_ned[0]), float(est.vel_ned[1]))
        heading_cmd = psi_ref + math.atan(self.cross_gain(v_now) * e_ct) + self.crab_rad
        yaw_now = yaw_est + float(est.omega_frd[2]) * tau
        herr = math.remainder(heading_cmd - yaw_now, 2.0 * math.pi)
        yaw_rate = r_ref + k.k_heading * herr
        yaw_rate = min(max(yaw_rate, -k.max_yaw_rate), k.max_yaw_rate)
        vel = np.array(
            [speed_cmd * math.cos(heading_cmd), speed_cmd * math.sin(heading_cmd), math.nan]
        )
        return PositionCommand(vel_ned=vel, yaw_rate=yaw_rate)


    def cross_gain(self, speed_m_s: float) -> float:
        """The cross-track gain [1/m] at ``speed_m_s``: ``k_cross``, and at most
        1 / (``lookahead_s`` * speed), i.e. the course aims at a point at least ``lookahead_s``
        of driving ahead. The cross-track error closes at about speed * gain [1/s] (de/dt = -v
        sin(atan(k e)) ~ -v k e): with a fixed k_cross that rate grew with the speed, and at
        2.4 rad/s (0.8/m at 3 m/s) against PX4's heading loop and the link's latency the PX4
        main SIH rover weaved +-1.5 m on a straight leg after a corner (rover_square at
        RO_SPEED_LIM); the cap holds it at 1 / lookahead_s (1.4 rad/s, binding above 1.8 m/s)."""
        k = self.gains
        v = abs(speed_m_s) if math.isfinite(speed_m_s) else 0.0
        if v > 0.0 and k.lookahead_s > 0.0:  # (lookahead_s <= 0: no cap)
            return min(k.k_cross, 1.0 / (k.lookahead_s * v))
        return k.k_cross

    def _learn_speed_ratio(self, dt: float, est: StateEstimate, planned_m_s: float) -> None:
        """Low-pass driven / commanded speed while the planned speed is steady and the rover
        cruises (see the class doc); ``planned_m_s``: this cycle's reference speed."""
        prev, self._cmd_prev = self._cmd_prev, planned_m_s
        sent = self._sent_prev
        if prev is None or sent is None or not (0.0 < dt < 1.0) \
                or prev < SPEED_RATIO_MIN_CMD_M_S or sent < SPEED_RATIO_MIN_CMD_M_S \
                or sent >= self.gains.max_speed \
                or abs(planned_m_s - prev) > SPEED_RATIO_MAX_DCMD * dt:
            return  # not steady, or the command was clamped (its answer is not the ratio's)
        driven = math.hypot(float(est.vel_ned[0]), float(est.vel_ned[1]))
        lo, hi = SPEED_RATIO_RANGE
        sample = min(max(driven / sent, lo), hi)
        self.speed_ratio += (sample - self.speed_ratio) * min(dt / self.gains.speed_tau_s, 1.0)

    def _learn_crab(self, dt: float, est: StateEstimate, yaw_est: float) -> None:
        """Low-pass the estimated heading minus the course over the ground while driving
        straight (see the class doc)."""
        vx, vy = float(est.vel_ned[0]), float(est.vel_ned[1])
        if not (0.0 < dt < 1.0) or math.hypot(vx, vy) < CRAB_MIN_SPEED_M_S \
                or abs(float(est.omega_frd[2])) > CRAB_MAX_TURN_RAD_S:
            return
        off = math.remainder(yaw_est - math.atan2(vy, vx), 2.0 * math.pi)
        if abs(off) > CRAB_MAX_RAD:
            return
        self.crab_rad += (off - self.crab_rad) * min(dt / self.gains.crab_tau_s, 1.0)
