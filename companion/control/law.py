"""Tracking control for the companion: multirotor attitude/rates setpoints and rover velocity.

Pure: every call takes `now` [s] (the companion clock, the same clock the telemetry time stamps
`t_s` are expressed in); no clock reads, no IO. Frames: world NED, body FRD, SI units.

Multirotor pipeline (`TrackingController`):

1. Latency compensation: the last state estimate (stamped `t_s`) is extrapolated to `now` with
   its velocity and its acceleration: measured if given, else a Smith predictor: the
   accelerations commanded up to `prediction_delay_s` before each instant of [t_s, now] (only
   commands already sent; before any, the one the measured attitude gives). Never the
   command being computed: extrapolating the whole age with the last command fed each command
   back into the next with gain -(kd age + kp age^2 / 2), which passes -1 once telemetry is
   ~0.1-0.17 s old (a PX4 SITL clock stall) and made the thrust alternate between its bounds
   every setpoint. The attitude is extrapolated with the body rates.
2. Acceleration command `a = a_ref + Kp e_p + Kd e_v + Ki int(e_p)` (errors reference minus
   extrapolated estimate), optionally with the reference feed-forward shifted ahead by
   `attitude_lead_s` in attitude mode (compensates PX4's attitude-loop lag): the reference
   sampled that much later when the caller passes it (`ahead`, what `TrackingSource` does),
   else a Taylor step in jerk and snap. The sample is bounded by the plan's own acceleration
   and jerk; the Taylor step multiplies the snap by lead^2 / 2, which on a jerk-limited
   profile (snap spikes of ~1000 m/s^4 where a short speed ramp starts) made the thrust jump
   by up to 0.6 between setpoints 10 ms apart.
3. Thrust vector `t = m (g e3 - a) - D v` (drag feed-forward, D configured or estimated), then
   saturation: minimum upward thrust, tilt limit (horizontal part scaled down), maximum thrust
   with vertical priority; the integrator is frozen while saturated (anti-windup) and clamped.
4. The drag-aware flatness map (`companion.flatness.multirotor_setpoint`) turns the saturated
   acceleration plus the reference jerk/snap/yaw into `q_wxyz`, normalised thrust (with the
   estimated hover thrust) and the feed-forward body rates.
5. `attitude` mode sends q + thrust + yaw-rate feed-forward; `rates` mode closes the attitude
   loop here with a geometric SO(3) controller (Lee et al.) whose feed-forward is the flatness
   body rate (of the reference's jerk plus a share of the feedback's derivative,
   `feedback_rate_ff`), and sends body rates + thrust.

Bad input (non-finite or stale telemetry, singular flatness) never produces NaN: the output falls
back to a level hover at the current heading with the hover-thrust estimate and is flagged
(`fallback=True`, `reason`).

Rover (`RoverController`): velocity + yaw-rate setpoints from rover flatness with a cross-track /
along-track / heading correction.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import replace

import numpy as np
import numpy.typing as npt

from companion.control.commands import AttitudeCommand, RateCommand
from companion.control.core import tracking_post, tracking_pre
from companion.control.estimation import (
    DisturbanceObserver,
    DragConfig,
    DragEstimator,
    HoverThrustConfig,
    HoverThrustEstimator,
    body_z_ned,
)
from companion.control.gains import (
    AttitudeGains,
    TrackingConfig,
    TrackingDiagnostics,
    rates_mode_gains,
)
from companion.control.prediction import predict_attitude, predict_held, predict_lagged
from companion.control.so3 import (
    all_finite,
    body_z_down,
    quat_integrate_f,
    quat_normalize,
    quat_normalize_f,
    quat_to_dcm,
    quat_to_dcm_f,
    rotate_f,
    so3_rate_command,
    so3_rate_command_f,
    tilt_guard_f,
    yaw_of_dcm,
    yaw_quat,
)
from companion.control.state import StateEstimate
from companion.flatness import MultirotorParams
from companion.flatness._formulas import FLOAT
from companion.flatness.numeric import multirotor_attitude_scalar
from companion.flatness.reference import Reference

FloatArray = npt.NDArray[np.float64]



#: `TrackingController._smooth_position` takes a position this far [m] from its prediction as
#: it is (an estimator reset, a GPS switch): smoothing it would crawl there over many samples.
POSITION_SNAP_M = 1.0
#: `TrackingController._command_hover_thrust`: the hover thrust of the command moves at most this
#: much [normalised thrust] per second.
HOVER_SLEW_PER_S = 0.5


# ----------------------------------------------------------------------------- controller


class TrackingController:
    """Multirotor trajectory-tracking controller (see the module docstring).

    Call `attitude(now, estimate, ref)` or `rates(now, estimate, ref)` at the setpoint rate;
    pass the newest estimate each time (a repeated estimate is recognised by its `t_s`).
    """

    def __init__(self, config: TrackingConfig) -> None:
        self.config = config
        p = config.params
        htc = config.hover_thrust_config or HoverThrustConfig(
            initial_hover_thrust=p.hover_thrust,
            drag_over_mass=p.drag / p.mass if config.drag_feedforward else 0.0,
            g=p.g,
        )
        self.hover_estimator = HoverThrustEstimator(htc)
        dc = config.drag_config or DragConfig(initial_drag_over_mass=p.drag / p.mass, g=p.g)
        self.drag_estimator = DragEstimator(dc)
        self.disturbance = DisturbanceObserver(config.disturbance_config)
        self._gain_lists = {
            rates: (g.kp().tolist(), g.kd().tolist(), g.ki().tolist(), g.i_max().tolist())
            for rates, g in ((False, config.gains),
                             (True, rates_mode_gains(config.gains, config.attitude_gains,
                                                     config.rates_separation)
                              if config.rates_separation > 0.0 else config.gains))
        }
        self._kp_l, self._kd_l, self._ki_l, self._imax_l = self._gain_lists[False]
        self._integ_l = [0.0, 0.0, 0.0]
        # False: the integrator and the estimators (hover thrust, drag, disturbance) learn
        # nothing (the vehicle may not be flying these commands: `TrackingSource`'s handover)
        self.learning = True
        self._tilt_rad = config.max_tilt_rad
        self._cos_tilt = math.cos(config.max_tilt_rad)
        self._tan_tilt = math.tan(config.max_tilt_rad)
        self._t_last_update: float | None = None
        self._last_est: StateEstimate | None = None
        self._prev_est: StateEstimate | None = None
        self._thrust_hist: deque[tuple[float, float]] = deque(maxlen=256)
        # (time [s], body rates commanded [rad/s FRD]) in rates mode, for the attitude predictor
        self._rate_hist: deque[tuple[float, float, float, float]] = deque(maxlen=256)
        # (time, ax, ay, az): the (saturated) acceleration commanded at each update [s, m/s^2]
        self._acc_hist: deque[tuple[float, float, float, float]] = deque(maxlen=256)
        self._last_yaw = 0.0
        self._last_diag: TrackingDiagnostics | None = None
        self._diag_pending: tuple[Sequence[float] | None, Sequence[float] | None] | None = None

    # -- state --------------------------------------------------------------------------------
    @property
    def hover_thrust(self) -> float:
        """Hover thrust in use (estimate if enabled, else the configured value)."""
        if self.config.estimate_hover_thrust:
            return self.hover_estimator.hover_thrust
        return self.config.params.hover_thrust

    @property
    def drag(self) -> float:
        """Linear drag coefficient in use [N/(m/s)] (0 without drag feed-forward)."""
        if not self.config.drag_feedforward:
            return 0.0
        if self.config.estimate_drag:
            return self.drag_estimator.drag_over_mass * self.config.params.mass
        return self.config.params.drag

    def reset(self) -> None:
        """Clear the integrator, the disturbance estimate and the telemetry history (e.g. on
        entering offboard)."""
        self._integ_l = [0.0, 0.0, 0.0]
        self._yaw_sp = None
        self._p_smooth = None
        # the disturbance too: while PX4 flew (a pilot's Hold) the thrust it applied was not
        # ours, and the samples around the switch read as a force (real PX4: a stale estimate
        # pushed a resumed flight 0.22 m back from where it took over, at rest)
        self.disturbance.reset()
        self._t_last_update = None
        self._last_est = None
        self._prev_est = None
        self._thrust_hist.clear()
        self._rate_hist.clear()
        self._acc_hist.clear()

    @property
    def tilt_limit_rad(self) -> float:
        """Tilt limit of the commanded thrust vector in force [rad]."""
        return self._tilt_rad

    def limit_tilt(self, max_tilt_rad: float | None) -> None:
        """From the next update on, limit the commanded tilt to `max_tilt_rad` [rad] where that
        is tighter than `config.max_tilt_rad` (a landing: PX4's MPC_TILTMAX_LND); None restores
        the configured limit."""
        c = self.config.max_tilt_rad
        tilt = c if max_tilt_rad is None else min(c, max_tilt_rad)
        if not 0.0 < tilt < math.pi / 2:
            raise ValueError(f"tilt limit must be in (0, 90) deg, got {math.degrees(tilt)}")
        if tilt != self._tilt_rad:
            self._tilt_rad = tilt
            self._cos_tilt = math.cos(tilt)
            self._tan_tilt = math.tan(tilt)

    @property
    def last(self) -> TrackingDiagnostics | None:
        """What the last update computed (built on first access after each update)."""
        pending = self._diag_pending
        if pending is not None:
            self._diag_pending = None
            now, e_p, e_v, a_sat, integ, h, D, tau, sat, reason = self._diag
            e_R, e_omega = pending
            self._last_diag = TrackingDiagnostics(
                t_s=now,
                pos_err_ned=np.array(e_p),
                vel_err_ned=np.array(e_v),
                acc_cmd_ned=np.array(a_sat),
                integrator_ned=np.array(integ),
                hover_thrust=h,
                drag=D,
                extrapolation_s=tau,
                saturated=sat,
                attitude_err_frd=np.zeros(3) if e_R is None else np.array(e_R),
                fallback=False,
                reason=reason,
                rate_err_frd=np.zeros(3) if e_omega is None else np.array(e_omega),
            )
        return self._last_diag

    # -- public API ---------------------------------------------------------------------------
    def attitude(self, now: float, est: StateEstimate, ref: Reference,
                 ahead: Reference | None = None) -> AttitudeCommand:
        """`attitude` mode setpoint at `now`: q + normalised thrust + yaw-rate feed-forward.

        `ahead`: the reference `config.attitude_lead_s` later (its acceleration, jerk and snap
        are the lead feed-forward); None: a Taylor step from `ref` instead."""
        out = self.attitude_values(now, est, ref, ahead)
        if isinstance(out, AttitudeCommand):
            return out
        q_des, thrust, rate_ff, sat = out
        return AttitudeCommand(np.array(q_des), thrust, rate_ff, saturated=sat)

    def attitude_values(
        self, now: float, est: StateEstimate, ref: Reference, ahead: Reference | None = None
    ) -> tuple[tuple[float, float, float, float], float, float, bool] | AttitudeCommand:
        """`attitude` without building the command: a regular one as its plain floats
        `(q_wxyz, thrust_norm, yaw_rate_ff, saturated)`, a hover fallback as the (flagged)
        `AttitudeCommand`. Same state update as `attitude` (it is `attitude`'s core)."""
        out = self._core(now, est, ref, self.config.attitude_lead_s, ahead=ahead)
        if out is None:
            return self._fallback_attitude(now, est)
        q_des, thrust, _omega_ff, sat = out
        self._record_thrust(now, thrust)
        rate_ff = self._yaw_rate_ff
        self._publish_diag(None)
        return q_des, thrust, rate_ff, sat

    def rates(self, now: float, est: StateEstimate, ref: Reference) -> RateCommand:
        """`rates` mode setpoint at `now`: body rates from the SO(3) loop + thrust."""
        out = self._core(now, est, ref, 0.0, rates=True)
        if out is None:
            return self._fallback_rates(now, est)
        q_des_t, thrust, omega_ff_t, sat = out
        # the SO(3) loop on floats (the numpy versions' bits, see so3's "the loop in floats")
        R = quat_to_dcm_f(self._q_now)
        Rd = quat_to_dcm_f(q_des_t)
        gains = self._link_gains()
        omega_t, e_R, Rt_Rd = so3_rate_command_f(R, Rd, omega_ff_t, gains)
        # the flown tilt within the limit too, not only the setpoint's (the loop closes over
        # the link and lags); its rates bounded as the loop's
        w_now = est.omega_frd.tolist()
        w0, w1, w2 = tilt_guard_f(R, omega_t, self._tilt_rad, w_now)
        lim = gains.max_rate_rp
        w0, w1 = min(max(w0, -lim), lim), min(max(w1, -lim), lim)
        f0, f1, f2 = rotate_f(Rt_Rd, omega_ff_t)
        e_omega = (w_now[0] - f0, w_now[1] - f1, w_now[2] - f2)
        # Thrust along the actual body z (Lee): project the desired thrust direction
        # (Rd[:, 2] . R[:, 2], the same products in the same order as (R^T Rd)[2][2]).
        proj = Rt_Rd[2][2]
        thrust = min(max(thrust * max(proj, 0.5), self.config.thrust_min), self.config.thrust_max)
        self._publish_diag(e_R, e_omega)
        isfinite = math.isfinite
        if not (isfinite(w0) and isfinite(w1) and isfinite(w2) and isfinite(thrust)):
            return self._fallback_rates(now, est, "non-finite rate command")
        self._record_thrust(now, thrust)
        self._rate_hist.append((now, w0, w1, w2))
        omega = np.array([w0, w1, w2])
        return RateCommand(omega, thrust, saturated=sat)

    # -- internals ----------------------------------------------------------------------------
    def _link_gains(self) -> AttitudeGains:
        """The attitude gains for the link's round trip `link_rtt_s` (`for_link_rtt`; cached
        per round-trip value, which changes about once a second)."""
        rtt = self.link_rtt_s
        cached = self._gains_for_rtt
        if cached is not None and (cached[0] == rtt or (cached[0] != cached[0] and rtt != rtt)):
            return cached[1]
        gains = self.config.attitude_gains.for_link_rtt(rtt)
        self._gains_for_rtt = (rtt, gains)
        return gains

    def _record_thrust(self, now: float, thrust: float) -> None:
        self._thrust_hist.append((now, thrust))

    def _mean_thrust(self, t0: float, t1: float) -> float:
        """Time average of the (zero-order-hold) thrust command history over [t0, t1]."""
        if not self._thrust_hist or t1 <= t0:
            return math.nan
        total = 0.0
        covered = 0.0
        t_next = math.inf
        for ti, ui in reversed(self._thrust_hist):  # newest first; stop once before t0
            if t_next <= t0:
                break
            a = ti if ti > t0 else t0
            b = t_next if t_next < t1 else t1
            if b > a:
                total += ui * (b - a)
                covered += b - a
            t_next = ti
        if covered < 0.5 * (t1 - t0):
            return math.nan
        return total / covered

    def _ingest(self, est: StateEstimate) -> None:
        """Remember a new telemetry sample and feed the estimators."""
        last = self._last_est
        if last is not None and est.t_s <= last.t_s:
            return
        self._prev_est, self._last_est = last, est
        dt = math.inf if last is None else est.t_s - last.t_s
        self._smooth_position(est, last, dt)
        if last is None or not self.learning:
            return
        if not (1e-3 < dt < 0.5):
            return
        hover, drag = self.config.estimate_hover_thrust, self.config.estimate_drag
        dist = self.config.estimate_disturbance
        if not (hover or drag or dist):
            return
        delay = self.config.thrust_delay_s
        if est.acc_ned is not None:
            u = self._mean_thrust(est.t_s - delay - 0.01, est.t_s - delay + 0.01)
        else:
            u = self._mean_thrust(last.t_s - delay, est.t_s - delay)
        if not math.isfinite(u):
            return
        airborne = est.airborne and last.airborne
        if hover:
            # plain floats: the z components of what the drag branch computes with arrays
            vz, vz_last = float(est.vel_ned[2]), float(last.vel_ned[2])
            if est.acc_ned is None:
                acc_z = (vz - vz_last) / dt
                v_mid_z = 0.5 * (vz + vz_last)
            else:
                acc_z = float(est.acc_ned[2])
                v_mid_z = vz
            zb_mid_z = 0.5 * (body_z_down(est.q_wxyz) + body_z_down(last.q_wxyz))
            self.hover_estimator.update(est.t_s, acc_z, u, zb_mid_z, v_mid_z, airborne)
        if drag:
            # plain floats (the same element-wise IEEE operations as the array expressions)
            v1, v0 = est.vel_ned.tolist(), last.vel_ned.tolist()
            if est.acc_ned is None:
                acc, v_mid = [(a - b) / dt for a, b in zip(v1, v0, strict=True)], [
                    0.5 * (a + b) for a, b in zip(v1, v0, strict=True)]
            else:
                acc, v_mid = est.acc_ned.tolist(), v1
            zb_mid = [0.5 * (a + b) for a, b in
                      zip(body_z_ned(est.q_wxyz), body_z_ned(last.q_wxyz), strict=True)]
            self.drag_estimator.update(
                est.t_s, acc, v_mid, u, zb_mid, self.hover_thrust, airborne,
                self.disturbance.acc_ne if dist else (0.0, 0.0),
            )
        if dist:
            # the model's horizontal acceleration over the interval: mean thrust, mid-interval
            # attitude and velocity (plain floats: this runs at the telemetry rate)
            q0, q1 = last.q_wxyz.tolist(), est.q_wxyz.tolist()
            zx = (q0[1] * q0[3] + q0[0] * q0[2]) + (q1[1] * q1[3] + q1[0] * q1[2])
            zy = (q0[2] * q0[3] - q0[0] * q0[1]) + (q1[2] * q1[3] - q1[0] * q1[1])
            f = u * self.config.params.g / self.hover_thrust
            dm = self.drag / self.config.params.mass
            v0, v1 = last.vel_ned.tolist(), est.vel_ned.tolist()
            a_model = (-f * zx - dm * 0.5 * (v0[0] + v1[0]),
                       -f * zy - dm * 0.5 * (v0[1] + v1[1]))
            self.disturbance.update(est.t_s, (v1[0], v1[1]), a_model, u, airborne)

    def _command_hover_thrust(self, dt: float) -> float:
        """The hover thrust the command is normalised with: the estimate, followed at most
        HOVER_SLEW_PER_S per second. The estimator's first updates after lift-off can move it by
        40 % at once (a vehicle 19 % heavier than told, in the campaign: the thrust stepped 0.66
        -> 0.93 between two setpoints 10 ms apart); its models of the vehicle use the estimate
        itself."""
        h = self.hover_thrust
        prev = self._h_cmd
        if prev is None or dt <= 0.0:
            self._h_cmd = h if prev is None else prev
            return self._h_cmd
        step = HOVER_SLEW_PER_S * dt
        self._h_cmd = prev + min(max(h - prev, -step), step)
        return self._h_cmd

    def _smooth_position(self, est: StateEstimate, last: StateEstimate | None,
                         dt: float) -> None:
        """The position the feedback uses: each sample's position, blended into the previous
        smoothed one carried forward by the mean velocity, with weight dt / (tau + dt) (tau =
        `config.position_smoothing_s`). A position that agrees with its velocity passes as it
        is; white noise on it is cut: the mock's SIM_POS_NOISE 0.09 m (campaign) made the
        vertical P term jump the thrust by up to 0.28 between setpoints 10 ms apart. A jump of
        more than POSITION_SNAP_M (an estimator reset) is taken at once."""
        tau = self.config.position_smoothing_s
        p = est.pos_ned.tolist()
        prev = self._p_smooth
        if tau <= 0.0 or prev is None or last is None or not 1e-3 < dt < 0.5:
            self._p_smooth = (p[0], p[1], p[2]) if tau > 0.0 else None
            return
        v0, v1 = last.vel_ned.tolist(), est.vel_ned.tolist()
        h = 0.5 * dt
        pred = (prev[0] + (v0[0] + v1[0]) * h, prev[1] + (v0[1] + v1[1]) * h,
                prev[2] + (v0[2] + v1[2]) * h)
        if math.dist(pred, p) > POSITION_SNAP_M:
            self._p_smooth = (p[0], p[1], p[2])
            return
        b = dt / (tau + dt)
        self._p_smooth = (pred[0] + b * (p[0] - pred[0]), pred[1] + b * (p[1] - pred[1]),
                          pred[2] + b * (p[2] - pred[2]))

    def _core(
        self, now: float, est: StateEstimate, ref: Reference, lead_s: float, rates: bool = False,
        ahead: Reference | None = None,
    ) -> tuple[tuple[float, float, float, float], float, tuple[float, float, float], bool] | None:
        """q_des, thrust_norm, omega_ff_frd, saturated; None -> fallback (see _fallback_reason).
        `rates`: use the `rates_mode_gains` position gains. `ahead`: the reference `lead_s`
        later, whose acceleration, jerk and snap replace the Taylor step of the lead."""
        self._kp_l, self._kd_l, self._ki_l, self._imax_l = self._gain_lists[rates]
        c = self.config
        p = c.params
        self._fallback_reason = ""
        isfinite = math.isfinite
        # Each vector as floats once: the finiteness checks below are `est.is_finite()` and
        # `ref.is_finite()` on these lists, and the arithmetic further down uses them too.
        px0, py0, pz0 = pos0 = est.pos_ned.tolist()
        vx0, vy0, vz0 = vel0 = est.vel_ned.tolist()
        q_est = est.q_wxyz.tolist()
        w_est = est.omega_frd.tolist()
        acc0 = est.acc_ned.tolist() if est.acc_ned is not None else []
        if not (
            isfinite(now)
            and isfinite(est.t_s)
            and all(map(isfinite, pos0 + vel0 + q_est + w_est + acc0))
            and 0.5 < math.hypot(*q_est) < 2.0  # est.quat_ok()
        ):
            self._fallback_reason = "telemetry not finite"
            return None
        rp = ref.pos_ned.tolist()
        rv = ref.vel_ned.tolist()
        ra = ref.acc_ned.tolist()
        rj = ref.jerk_ned.tolist()
        rs = ref.snap_ned.tolist()
        if not all(map(isfinite, rp + rv + ra + rj + rs + [ref.yaw, ref.yaw_rate, ref.yaw_acc])):
            self._fallback_reason = "reference not finite"
            return None
        if ahead is not None and lead_s > 0.0:
            la, lj, ls = ahead.acc_ned.tolist(), ahead.jerk_ned.tolist(), ahead.snap_ned.tolist()
            if not all(map(isfinite, la + lj + ls)):
                self._fallback_reason = "reference not finite"
                return None
        else:
            la = lj = ls = []
        age = now - est.t_s
        if age > c.stale_after_s:
            self._fallback_reason = f"telemetry stale ({age:.2f} s old)"
            return None
        self._ingest(est)
        if self._p_smooth is not None:
            px0, py0, pz0 = self._p_smooth
        qw, qx, qy, qz = q_est
        self._last_yaw = math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))

        dt_ctrl = 0.0 if self._t_last_update is None else now - self._t_last_update
        dt_ctrl = min(max(dt_ctrl, 0.0), 0.1)
        self._t_last_update = now

        # Plain floats from here to the flatness call: this runs at the setpoint rate on
        # single samples, where numpy's per-operation overhead dominates.
        # 1. latency compensation
        tau = min(max(age, 0.0), c.max_extrapolation_s) if c.latency_compensation else 0.0
        if acc0 or tau <= 0.0:
            ax0, ay0, az0 = acc0 if acc0 else (0.0, 0.0, 0.0)
            h2 = 0.5 * tau * tau
            pos = (px0 + vx0 * tau + ax0 * h2, py0 + vy0 * tau + ay0 * h2,
                   pz0 + vz0 * tau + az0 * h2)
            vel = (vx0 + ax0 * tau, vy0 + ay0 * tau, vz0 + az0 * tau)
        else:
            pos, vel = self._predict(est.t_s, tau, (px0, py0, pz0), (vx0, vy0, vz0), q_est)
        if tau > 0 and rates and c.rate_prediction_lag_s > 0.0 and self._rate_hist:
            self._q_now = predict_attitude(self._rate_hist, est.t_s, tau, q_est, w_est,
                                           c.rate_prediction_lag_s)
        else:
            self._q_now = (
                quat_integrate_f(q_est, w_est, tau) if tau > 0 else quat_normalize_f(*q_est)
            )

        # 2. acceleration command
        # the feed-forward: the reference's acceleration, jerk and snap `lead_s` ahead (sampled,
        # or a Taylor step from now)
        if la:
            a_ff, j_ff, rs = (la[0], la[1], la[2]), (lj[0], lj[1], lj[2]), ls
        else:
            L = lead_s
            hL2 = 0.5 * L * L
            a_ff = (ra[0] + rj[0] * L + rs[0] * hL2, ra[1] + rj[1] * L + rs[1] * hL2,
                    ra[2] + rj[2] * L + rs[2] * hL2)
            j_ff = (rj[0] + rs[0] * L, rj[1] + rs[1] * L, rj[2] + rs[2] * L)
        # 3. the core (companion.control.core, the source of the generated C): feedback,
        # thrust vector t = m (g e3 - a) - D v with drag and disturbance, limits, anti-windup
        h = self._command_hover_thrust(dt_ctrl)
        D = self.drag
        params = self._params_for_drag(D)
        # the feedback's derivative in the jerk (rates mode): the vehicle's acceleration from
        # its (extrapolated) attitude and the last thrust command, not differentiated velocities
        share = c.feedback_rate_ff if rates and self._thrust_hist else 0.0
        a_m = (self._acc_of(self._q_now, self._thrust_hist[-1][1], vel) if share > 0.0
               else (0.0, 0.0, 0.0))
        dx, dy = self.disturbance.acc_ne if c.estimate_disturbance else (0.0, 0.0)
        yaw, yaw_rate, slewed = self._slew_yaw(ref, dt_ctrl)
        integ = self._integ_l
        pre = tracking_pre(FLOAT, (
            *rp, *rv, *ra, *a_ff, *j_ff, *rs, *pos, *vel, *a_m, *integ, *self._kp_l,
            *self._kd_l, *self._ki_l, *self._imax_l, dx, dy, yaw, yaw_rate,
            0.0 if slewed else ref.yaw_acc, h, D, params.drag, p.mass, p.g, c.thrust_min,
            c.thrust_max, self._cos_tilt, self._tan_tilt, share,
            1.0 if c.drag_velocity == "estimate" else 0.0, dt_ctrl,
            1.0 if est.airborne and self.learning else 0.0))
        integ[:] = pre["integ"]
        sat = pre["sat"]
        self._acc_hist.append((now, *pre["acc_d"]))

        # 4. flatness map
        try:
            qw, qx, qy, qz, thrust_n, wx, wy, wz, singular = multirotor_attitude_scalar(
                pre["v_drag"], pre["acc"], pre["jerk"], pre["snap"], yaw, yaw_rate,
                pre["yaw_acc"], params)
        except ValueError as exc:  # e.g. absurd magnitudes the flatness map refuses
            self._fallback_reason = f"flatness map refused the input: {exc}"
            return None
        if not all(map(isfinite, (qw, qx, qy, qz, wx, wy, wz, h * thrust_n / (p.mass * p.g)))):
            self._fallback_reason = "flatness output not finite"
            return None
        q_des, thrust, omega_ff = tracking_post(FLOAT, (qw, qx, qy, qz), thrust_n,
                                                (wx, wy, wz), singular, h, p.mass, p.g,
                                                c.thrust_min, c.thrust_max)
        self._diag = (now, pre["e_p"], pre["e_v"], pre["acc_d"], tuple(integ), h, D, tau, sat,
                      "singular flatness point" if singular else "")
        self.last_q_des = q_des
        return q_des, thrust, omega_ff, sat

    def _slew_yaw(self, ref: Reference, dt: float) -> tuple[float, float, bool]:
        """The yaw to command [rad], its rate feed-forward [rad/s] and whether the rate limit
        `config.max_yaw_rate_rad_s` acted: the reference's yaw, followed at most that fast
        (the short way round) from the yaw commanded last."""
        lim = self.config.max_yaw_rate_rad_s
        r = ref.yaw_rate if math.isfinite(ref.yaw_rate) else 0.0
        prev = self._yaw_sp
        if prev is None or dt <= 0.0:
            yaw = ref.yaw if prev is None else prev
            rate = min(max(r, -lim), lim)
            self._yaw_sp, self._yaw_rate_ff = yaw, rate
            return yaw, rate, abs(r) > lim or (prev is not None and yaw != ref.yaw)
        gap = math.remainder(ref.yaw - prev, 2.0 * math.pi)
        step = lim * dt
        if abs(gap) <= step and abs(r) <= lim:
            yaw, rate, slewed = ref.yaw, r, False
        else:
            yaw = prev + min(max(gap, -step), step)
            rate = min(max(r, -lim), lim) if abs(gap) <= step else math.copysign(lim, gap)
            slewed = True
        self._yaw_sp, self._yaw_rate_ff = yaw, rate
        return yaw, rate, slewed

    def _predict(self, t_s: float, tau: float, p0: tuple[float, float, float],
                 v0: tuple[float, float, float], q_wxyz: list[float]
                 ) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        """Position and velocity [m, m/s, NED] `tau` [s] after the sample taken at `t_s`
        (p0, v0), integrating the acceleration the vehicle has in between: at time t the one
        commanded at t - `prediction_delay_s` (zero-order hold; a Smith predictor: only commands
        already sent enter, and the telemetry that later shows their effect replaces them);
        before the first command known, the one the measured attitude gives (`_sample_acc`)."""
        d = self.config.prediction_delay_s
        t0, t1 = t_s, t_s + tau
        segs: list[tuple[float, float, float, float]] = []  # (start, ax, ay, az), newest first
        cur: tuple[float, float, float] | None = None
        for tc, ax, ay, az in reversed(self._acc_hist):
            st = tc + d
            if st <= t0:
                cur = (ax, ay, az)
                break
            if st < t1:
                segs.append((st, ax, ay, az))
        lag = self.config.prediction_lag_s
        if lag > 0.0:
            return predict_lagged(t0, t1, p0, v0, self._sample_acc(t_s, q_wxyz, v0),
                                  cur, segs, lag)
        return predict_held(t0, t1, p0, v0,
                            cur if cur is not None else self._sample_acc(t_s, q_wxyz, v0), segs)

    def _sample_acc(self, t_s: float, q_wxyz: Sequence[float],
                    vel: Sequence[float]) -> tuple[float, float, float]:
        """The vehicle's acceleration at telemetry time `t_s` [m/s^2, NED]:
        a = g e3 - (u g / h) z_b - D v / m with the measured attitude `q_wxyz` (its body z axis
        z_b), the velocity `vel` and the thrust u commanded `thrust_delay_s` before `t_s`
        (the hover thrust before any was commanded). Only past commands enter it, so the
        extrapolation that uses it does not feed the command being computed back into itself."""
        d = self.config.thrust_delay_s
        u = self._mean_thrust(t_s - d - 0.01, t_s - d + 0.01)
        return self._acc_of(q_wxyz, u if math.isfinite(u) else self.hover_thrust, vel)

    def _acc_of(self, q_wxyz: Sequence[float], u: float,
                vel: Sequence[float]) -> tuple[float, float, float]:
        """Newton: a = g e3 - (u g / h) z_b - D v / m [m/s^2, NED] at attitude `q_wxyz` (body z
        axis z_b), normalised thrust `u` (h: the hover thrust in use) and velocity `vel`."""
        p = self.config.params
        g0 = p.g
        qw, qx, qy, qz = q_wxyz
        # body z axis (third column of C_eb) in NED
        zx = 2.0 * (qx * qz + qw * qy)
        zy = 2.0 * (qy * qz - qw * qx)
        zz = 1.0 - 2.0 * (qx * qx + qy * qy)
        f = u * g0 / self.hover_thrust
        dm = self.drag / p.mass
        dx, dy = self.disturbance.acc_ne if self.config.estimate_disturbance else (0.0, 0.0)
        return (-f * zx - dm * vel[0] + dx, -f * zy - dm * vel[1] + dy,
                g0 - f * zz - dm * vel[2])

    def _publish_diag(
        self, e_R: Sequence[float] | None, e_omega: Sequence[float] | None = None
    ) -> None:
        """Diagnostics of this update (from `_diag`), built lazily by `last`."""
        self._diag_pending = (e_R, e_omega)

    def _params_for_drag(self, drag: float) -> MultirotorParams:
        """Flatness parameters with drag `drag` (cached: constructing them validates inertia;
        the very float object of the last call, the configured drag, skips the rounding)."""
        cached = self._params_cache
        if cached is not None and drag is self._drag_seen:
            return cached[1]
        key = round(drag, 4)
        if cached is None or cached[0] != key:
            cached = (key, replace(self.config.params, drag=key))
            self._params_cache = cached
        self._drag_seen = drag
        return cached[1]

    def _fallback_q(self, est: StateEstimate) -> FloatArray:
        yaw = self._last_yaw
        if est.quat_ok():
            yaw = yaw_of_dcm(quat_to_dcm(est.q_wxyz))
        return yaw_quat(yaw if math.isfinite(yaw) else 0.0)

    def _fallback_attitude(self, now: float, est: StateEstimate) -> AttitudeCommand:
        reason = self._fallback_reason or "fallback"
        h = self.hover_thrust
        self._record_fb(now, reason)
        self._record_thrust(now, h)
        return AttitudeCommand(self._fallback_q(est), h, 0.0, fallback=True, reason=reason)

    def _fallback_rates(
        self, now: float, est: StateEstimate, reason: str | None = None
    ) -> RateCommand:
        reason = reason or self._fallback_reason or "fallback"
        h = self.hover_thrust
        omega = np.zeros(3)
        if est.quat_ok():
            omega, _ = so3_rate_command(
                quat_normalize(est.q_wxyz), self._fallback_q(est), np.zeros(3),
                self.config.attitude_gains,
            )
            if not all_finite(omega):
                omega = np.zeros(3)
        self._record_fb(now, reason)
        self._record_thrust(now, h)
        return RateCommand(omega, h, fallback=True, reason=reason)

    def _record_fb(self, now: float, reason: str) -> None:
        z = np.zeros(3)
        self._diag_pending = None
        self._last_diag = TrackingDiagnostics(
            t_s=now if math.isfinite(now) else math.nan,
            pos_err_ned=z,
            vel_err_ned=z,
            acc_cmd_ned=z,
            integrator_ned=np.array(self._integ_l),
            hover_thrust=self.hover_thrust,
            drag=self.drag,
            extrapolation_s=0.0,
            saturated=False,
            attitude_err_frd=z,
            fallback=True,
            reason=reason,
        )

    _fallback_reason: str = ""
    _p_smooth: tuple[float, float, float] | None = None  # `_smooth_position` [m, NED]
    _h_cmd: float | None = None  # `_command_hover_thrust`
    _yaw_sp: float | None = None  # the yaw commanded last [rad] (`_slew_yaw`)
    #: the link's round-trip time [s] (NaN: unknown), set by the caller before each update:
    #: rates mode's attitude gains follow it (`AttitudeGains.for_link_rtt`)
    link_rtt_s: float = math.nan
    _gains_for_rtt: tuple[float, AttitudeGains] | None = None
    _yaw_rate_ff: float = 0.0  # its rate feed-forward [rad/s]
    _params_cache: tuple[float, MultirotorParams] | None = None
    _drag_seen: float | None = None
    _diag: tuple[
        float,
        tuple[float, ...],
        tuple[float, ...],
        tuple[float, ...],
        tuple[float, ...],
        float,
        float,
        float,
        bool,
        str,
    ]
    _q_now: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    #: the attitude the last regular update steered to (w, x, y, z), body FRD -> NED
    last_q_des: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
