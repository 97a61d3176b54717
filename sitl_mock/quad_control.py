"""Quadrotor control: the PX4-like cascade the `Quadrotor` runs on each physics step.

Position/velocity loop <= 100 Hz (with PX4's takeoff handling: spool-up, ready, thrust ramp,
flight), attitude loop <= 250 Hz, rate loop <= 500 Hz with the IMU_GYRO_CUTOFF-filtered gyro;
offboard attitude targets switch control mode at CONTROL_MODE_RATE_HZ. The state it reads and writes
lives in `QuadState`'s slots (quad_state.py).
"""

from __future__ import annotations

import math
import random

from sitl_mock.flight_control import (
    G,
    attitude_control,
    body_z_to_attitude,
    mix_quad_x,
    quat_from_yaw,
    quat_normalize,
    quat_yaw,
    wrap_pi,
)
from sitl_mock.quad_physics import QuadPhysics
from sitl_mock.quad_state import DISARMED, FLIGHT, RAMPUP, READY, SPOOLUP
from sitl_mock.setpoints import AttitudeTarget, PositionTarget, Quat, Vec3

_isfinite = math.isfinite

POS_LOOP_PERIOD_S = 0.01
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
#: Touching the ground while the position controller asks for more than this descent rate
#: [m/s] is "ground contact" (PX4's land detector stage): the thrust is cut (see
#: `_control_position`); the land detector uses the same threshold. Half of PX4's landing crawl
#: (MPC_LAND_CRWL 0.3 m/s), so an AUTO landing that crawls onto the ground is detected.
GROUND_CONTACT_DESCENT_M_S = 0.15
_RATE_TICK_S = RATE_LOOP_PERIOD_S - 1e-9
_TWOPI = 2.0 * math.pi  # (random.py's TWOPI)
_sqrt, _log, _cos, _sin = math.sqrt, math.log, math.cos, math.sin


def gauss3(rng: random.Random, s0: float, s1: float, s2: float) -> Vec3:
    """``(rng.gauss(0.0, s0), rng.gauss(0.0, s1), rng.gauss(0.0, s2))`` written out: the same
    draws, the same pair caching (``rng.gauss_next``) and the same values as CPython's
    `random.Random.gauss`, without three calls per rate-loop tick (tests/sitl_mock/
    test_fast_paths.py compares them)."""
    rnd = rng.random
    z = rng.gauss_next  # type: ignore[attr-defined]
    if z is None:  # a pair for the first two, a new pair for the third (its twin kept)
        x2pi = rnd() * _TWOPI
        g2rad = _sqrt(-2.0 * _log(1.0 - rnd()))
        z, z1 = _cos(x2pi) * g2rad, _sin(x2pi) * g2rad
        x2pi = rnd() * _TWOPI
        g2rad = _sqrt(-2.0 * _log(1.0 - rnd()))
        z2 = _cos(x2pi) * g2rad
        rng.gauss_next = _sin(x2pi) * g2rad  # type: ignore[attr-defined]
    else:  # the kept one first, then a pair
        x2pi = rnd() * _TWOPI
        g2rad = _sqrt(-2.0 * _log(1.0 - rnd()))
        z1, z2 = _cos(x2pi) * g2rad, _sin(x2pi) * g2rad
        rng.gauss_next = None  # type: ignore[attr-defined]
    return (0.0 + z * s0, 0.0 + z1 * s1, 0.0 + z2 * s2)


class QuadControl(QuadPhysics):
    """The quadrotor's controllers (their state is in `QuadState`'s slots)."""

    __slots__ = ()

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
            n0, n1, n2 = gauss3(self._gyro_rng, s0 * k, s1 * k, s2 * k)
            raw = (self._wx + n0, self._wy + n1, self._wz + n2)
        else:
            raw = (self._wx, self._wy, self._wz)
        if self._gyro_rate is None:  # the rate loop starts: filters settled on the true rates
            self._gyro.reset((self._wx, self._wy, self._wz))
        omega, accel = self._gyro.update(raw, dtr, self._imu_cut[0], self._imu_cut[1])
        self._gyro_rate = omega
        torque = self._rc.update(g, omega, self._rate_sp, dtr, self._landed, accel)
        self._motor_cmd = mix_quad_x(torque, self._thrust_sp, g.airmode)
