"""Gains and configuration of the tracking law, and its per-update diagnostics."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np
import numpy.typing as npt

from companion.control.estimation import (
    DisturbanceConfig,
    DragConfig,
    HoverThrustConfig,
)
from companion.flatness import MultirotorParams

FloatArray = npt.NDArray[np.float64]





@dataclass(frozen=True)
class TrackingGains:
    """Position-loop gains: a = a_ref + kp e_p + kd e_v + ki int(e_p) (per axis, xy and z).

    kp [1/s^2], kd [1/s], ki [1/s^3]; i_max_xy / i_max_z: clamp of the integrator's
    acceleration contribution [m/s^2]. The xy defaults (omega_n 3.7 rad/s, zeta 0.95) were
    measured on real PX4 v1.16 SITL (SIH) over UDP flying `fly` missions (square_8ms: takeoff,
    a square at 8 m/s, a 10 m descent): the session-5 values, kp_xy 20 / kd_xy 8.5, had become
    the stability limit there. The commanded attitude swung +-15-25 deg at 1.2 Hz all flight,
    hover included, and the vehicle with it. Wobble of the vehicle's attitude (high-passed RMS)
    was 4.6-5.8 deg at 20 / 8.5, 3.2 at 17.5 / 8, 2.1-2.2 at 15 / 7.4 and 1.6 at 12 / 6.5.
    Tracking: 0.134-0.137 m RMS, 0.134, 0.140-0.142 and 0.148-0.149 on the square; figure-8 at
    6 m/s (truth RMS) 0.196, -, 0.192, 0.198 m. The mock rocks only from kp_xy ~25 (27 before its
    setpoint delay `SIM_SP_DELAY`; BENCHMARKS.md, "The 1.2 Hz rocking"). They assume telemetry
    latency under ~50 ms; with ~100 ms use kp_xy 6, kd_xy 4.5, ki_xy 1 and attitude gains
    k_roll = k_pitch = 6.5.
    """

    kp_xy: float = 14.0
    kd_xy: float = 7.1
    ki_xy: float = 3.0
    kp_z: float = 8.0
    kd_z: float = 5.5
    ki_z: float = 2.0
    i_max_xy: float = 2.0
    i_max_z: float = 4.0

    def kp(self) -> FloatArray:
        """(3,) proportional gains."""
        return np.array([self.kp_xy, self.kp_xy, self.kp_z])

    def kd(self) -> FloatArray:
        """(3,) derivative gains."""
        return np.array([self.kd_xy, self.kd_xy, self.kd_z])

    def ki(self) -> FloatArray:
        """(3,) integral gains."""
        return np.array([self.ki_xy, self.ki_xy, self.ki_z])

    def i_max(self) -> FloatArray:
        """(3,) integrator clamps [m/s^2]."""
        return np.array([self.i_max_xy, self.i_max_xy, self.i_max_z])


@dataclass(frozen=True)
class AttitudeGains:
    """Companion-side SO(3) attitude loop producing body-rate commands.

    k_roll/k_pitch/k_yaw: attitude gains [1/s]. Roll/pitch 10 (PX4's MC_ROLL_P is 6.5), tuned
        on real PX4 v1.16 SITL with the default position gains: 6.5 forced `rates_mode_gains`
        to soften the position loop (rates 6 m/s 0.17 m RMS vs 0.10 m), 12 lost the
        large-angle recovery (170 deg: overshoot back above 10 deg) and oscillated on the mock
        at 2 m/s. With ~100 ms telemetry latency use 6.5 (10 gives 0.46 m there, 6.5 < 0.1 m).
        k_yaw is PX4's MC_YAW_P.
    max_rate_rp / max_rate_yaw: rate command limits [rad/s] (MC_*RATE_MAX).
    large_angle: scale e_R by 1/cos(angle/2) so the error grows monotonically up to 180 deg
    (Lee 2011's alternative error function; small-angle behaviour unchanged). Used only
    without `tilt_priority`.
    tilt_priority: PX4's attitude law (mc_att_control, Brescianini et al. 2013): the thrust
    axis is steered first (the reduced attitude), the yaw about it only with weight
    k_yaw / k_roll, and the error is 2 sin(angle / 2) about the error axis (monotone to 180
    deg). Without it the full SO(3) error mixes a yaw the vehicle cannot follow (a weak yaw
    axis, a fast planned heading change at a corner) into roll and pitch: a rates-mode flight
    on the mock in 1.5 m/s wind reached 86 deg of tilt at a square's corner that way.
    yaw_weight: PX4's MC_YAW_WEIGHT; the yaw error's gain is then k_yaw / yaw_weight on the
    weighted yaw, k_yaw on small yaw errors as before.
    delay_gain_product: on a link with round-trip time RTT [s] (`TrackingController.link_rtt_s`)
        the roll/pitch/yaw gains are capped at delay_gain_product / RTT [1/s] (`for_link_rtt`).
        The companion's attitude loop closes over the link: on the mock, k_roll 10 whirled at
        50 ms of telemetry latency (growing to 2.8 rad/s RMS of body rate) and flew clean at
        30 ms; 8 and 6.5 flew 50 ms clean (0.30 / 0.28 rad/s, as with no latency). 0.35 puts
        50 ms at 7; the few-ms round trip of a wired link or PX4 SITL leaves the gains as they
        are.
    """

    k_roll: float = 10.0
    k_pitch: float = 10.0
    k_yaw: float = 2.8
    max_rate_rp: float = math.radians(220.0)
    max_rate_yaw: float = math.radians(200.0)
    large_angle: bool = True
    tilt_priority: bool = True
    yaw_weight: float = 0.4
    delay_gain_product: float = 0.35

    def __post_init__(self) -> None:
        if not 0.0 < self.yaw_weight <= 1.0:
            raise ValueError(f"yaw_weight must be in (0, 1], got {self.yaw_weight}")
        if not (math.isfinite(self.delay_gain_product) and self.delay_gain_product > 0.0):
            raise ValueError(f"delay_gain_product must be > 0, got {self.delay_gain_product}")

    def for_link_rtt(self, rtt_s: float) -> AttitudeGains:
        """These gains on a link with round-trip time `rtt_s` [s]: each of k_roll, k_pitch and
        k_yaw capped at `delay_gain_product` / `rtt_s` (unchanged for an unknown (NaN) or
        non-positive round trip, and where the cap is above them)."""
        if not rtt_s > 0.0:
            return self
        cap = self.delay_gain_product / rtt_s
        if cap >= max(self.k_roll, self.k_pitch, self.k_yaw):
            return self
        return replace(self, k_roll=min(self.k_roll, cap), k_pitch=min(self.k_pitch, cap),
                       k_yaw=min(self.k_yaw, cap))


def rates_mode_gains(gains: TrackingGains, attitude: AttitudeGains,
                     separation: float = 2.5) -> TrackingGains:
    """Position gains for `rates` mode with `TrackingConfig.rates_separation` > 0 (the default was
    2.5 until the feedback rate feed-forward, `feedback_rate_ff`, replaced the cap): the
    horizontal loop's natural frequency sqrt(kp_xy) [rad/s] is capped at min(k_roll, k_pitch) /
    `separation`, so the companion's own attitude loop (which `attitude` mode leaves to PX4's
    faster one) stays that much quicker than the position loop it serves (cascade separation).
    The damping ratio is kept (kd_xy scales with the frequency) and ki_xy scales with its cube;
    vertical gains are untouched. Why 2.5: with kp_xy 20 and k_roll 6.5 the mock in lockstep
    flew the 2 m/s figure-8 in a limit cycle (tilt 33 deg instead of 15); with k_roll 10 and
    kp_xy 20 (separation 2.2) two of four real-time mock flights at 6 m/s oscillated (0.45 m);
    capped to kp_xy 16, none of three did. Re-measured uncapped: real PX4 SITL on a loaded
    machine flew the 2 m/s figure-8 in a 1.4-1.5 Hz oscillation (0.39 m RMS, 0.11 m on a quieter
    run), the real-time mock with PX4-like estimate errors (`serve --estimator ekf2 --jitter
    0.01`) oscillated at 1.5 Hz at 6 m/s (tilt 60 deg instead of 48) in 2 of 2 flights; capped,
    or uncapped with `feedback_rate_ff` 0.25, it did not."""
    cap = min(attitude.k_roll, attitude.k_pitch) / separation
    wn = math.sqrt(gains.kp_xy)
    if wn <= cap:
        return gains
    s = cap / wn
    return replace(gains, kp_xy=gains.kp_xy * s * s, kd_xy=gains.kd_xy * s,
                   ki_xy=gains.ki_xy * s ** 3)


@dataclass(frozen=True)
class TrackingConfig:
    """Configuration of `TrackingController`.

    params: vehicle (mass [kg], inertia, hover_thrust prior, drag D [N/(m/s)] prior).
    drag_feedforward: include -D v in the thrust vector (D from params or the estimator).
    drag_velocity: velocity used in the drag term: "reference" (smooth feed-forward) or
        "estimate" (the extrapolated measured velocity).
    estimate_hover_thrust / estimate_drag: run the online estimators.
    latency_compensation: extrapolate the last estimate to `now`.
    max_extrapolation_s: cap of the extrapolation horizon [s].
    stale_after_s: older telemetry -> hover fallback [s].
    attitude_lead_s: in `attitude` mode the feed-forward is evaluated this far ahead to offset
        the lag of PX4's attitude loop (~1/MC_ROLL_P) [s]: the reference sampled at
        now + lead when the caller passes it (`attitude(..., ahead=)`), else a Taylor step in
        jerk and snap (fine on smooth references only). `rates` mode needs no lead: it feeds
        the flatness body rates forward instead.
    thrust_delay_s: delay between a thrust command and its effect, used to pair commands with
        measured accelerations for the hover-thrust estimator [s].
    prediction_delay_s: the latency compensation's Smith predictor takes the acceleration at
        time t to be the one commanded this long before [s] (0: from the moment it was sent;
        the command being computed never enters).
    prediction_lag_s: if > 0, the predictor's acceleration starts at the one the measured
        attitude gives at the sample and follows the commands as a first-order lag with this
        time constant [s] (the attitude loop's, ~1/MC_ROLL_P) instead of taking them at once.
    rate_prediction_lag_s: `rates` mode, if > 0: the attitude is extrapolated over the
        telemetry's age with body rates that follow the rates commanded since the sample with
        this time constant [s] (the autopilot's rate loop) instead of the measured rates held.
    max_tilt_rad: tilt limit of the commanded thrust vector.
    thrust_min / thrust_max: normalised thrust bounds.
    feedback_rate_ff: `rates` mode, share (0..1) of the feedback part of the commanded
        acceleration's derivative (kp e_v + kd (a_ref - a) + ki e_p, `a` from the attitude) fed
        to the flatness map as jerk, i.e. forward as body rates (0: the reference's jerk only;
        the attitude loop then lags the feedback by ~1/k_roll). It buys the phase margin the
        position loop would otherwise need a cap for, but puts k_roll + share * kd_xy on the
        measured (delayed) tilt. 0.25 keeps that at ~12 with the default gains (linear model,
        rate loop 20 ms: phase margin 42 deg, delay margin 59 ms, vs 39 deg / 62 ms for the
        former cap kp_xy 16 and 35 deg / 55 ms uncapped without it). On real PX4 v1.16 SITL,
        share 0.5 and 1 with k_roll 10 oscillated at 1.7-2 Hz; share 1 with k_roll 4 flew
        6 m/s well (0.108 m) but 2 m/s badly (0.153 m). BENCHMARKS.md, "Tracking on real PX4:
        where the error came from".
    max_yaw_rate_rad_s: the yaw the law commands follows the reference's yaw at most this fast
        [rad/s] (PX4's MPC_YAWRAUTO_MAX, 45 deg/s): a heading that follows the velocity turns
        at up to ~155 deg/s at a square's corner, more than a quad's weak yaw axis gives while
        it tilts hard, and chasing it saturated the rate loops (rates mode on the mock: 72-86
        deg of tilt in 1.5 m/s of wind). Beyond it the yaw lags the plan and catches up.
    estimate_disturbance: estimate the horizontal force the model does not explain (wind on
        the drag, a wrong drag coefficient; `DisturbanceObserver`, tuned by
        `disturbance_config`) and cancel it with the thrust. The position integrator alone
        holds at most i_max_xy (2 m/s^2); 5.4 m/s of wind on the SIH quad is ~8 m/s^2.
    position_smoothing_s: time constant [s] of the velocity-aided position smoothing the
        feedback uses (`TrackingController._smooth_position`; 0: the raw position).
    rates_separation: if > 0, `rates` mode flies `rates_mode_gains(gains, attitude_gains,
        rates_separation)` (the cascade-separation cap, 2.5 before the feed-forward); 0 (the
        default) flies the configured gains.
    shape_reference: bend a reference that needs more tilt than `max_tilt_rad` into one within
        it, ahead of time (`companion.control.shaping.ShapedReference`, run by the flight's
        `TrackingSource`); a reference within the limit is flown unchanged.
    shape_margin_rad: the tilt [rad] the bent reference leaves to the feedback; None:
        `ShapingConfig`'s default.
    """

    params: MultirotorParams
    gains: TrackingGains = TrackingGains()
    attitude_gains: AttitudeGains = AttitudeGains()
    drag_feedforward: bool = True
    drag_velocity: Literal["reference", "estimate"] = "estimate"
    estimate_hover_thrust: bool = True
    estimate_drag: bool = True
    hover_thrust_config: HoverThrustConfig | None = None
    drag_config: DragConfig | None = None
    latency_compensation: bool = True
    max_extrapolation_s: float = 0.25
    stale_after_s: float = 0.5
    attitude_lead_s: float = 0.15
    thrust_delay_s: float = 0.05
    prediction_delay_s: float = 0.0
    prediction_lag_s: float = 0.0
    rate_prediction_lag_s: float = 0.0
    max_tilt_rad: float = math.radians(60.0)
    thrust_min: float = 0.08
    thrust_max: float = 1.0
    feedback_rate_ff: float = 0.25
    rates_separation: float = 0.0
    max_yaw_rate_rad_s: float = math.radians(45.0)
    estimate_disturbance: bool = True
    position_smoothing_s: float = 0.1
    disturbance_config: DisturbanceConfig | None = None
    shape_reference: bool = True
    shape_margin_rad: float | None = None

    def __post_init__(self) -> None:
        if not 0.0 < self.max_tilt_rad < math.radians(89.0):
            raise ValueError("max_tilt_rad must be in (0, 89) deg")
        if not 0.0 <= self.thrust_min < self.thrust_max <= 1.0:
            raise ValueError("thrust bounds must satisfy 0 <= min < max <= 1")
        if not 0.0 < self.params.hover_thrust < 1.0:
            raise ValueError("params.hover_thrust must be in (0, 1)")
        if not 0.0 <= self.feedback_rate_ff <= 1.0:
            raise ValueError("feedback_rate_ff must be in [0, 1]")
        if not (math.isfinite(self.prediction_delay_s) and self.prediction_delay_s >= 0.0):
            raise ValueError("prediction_delay_s must be >= 0")
        for name in ("prediction_lag_s", "rate_prediction_lag_s"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) >= 0.0):
                raise ValueError(f"{name} must be >= 0")
        if not (math.isfinite(self.rates_separation) and self.rates_separation >= 0.0):
            raise ValueError("rates_separation must be >= 0 (0: no cap)")
        if not (math.isfinite(self.max_yaw_rate_rad_s) and self.max_yaw_rate_rad_s > 0.0):
            raise ValueError("max_yaw_rate_rad_s must be > 0")
        m = self.shape_margin_rad
        if m is not None and not (math.isfinite(m) and 0.0 <= m < self.max_tilt_rad):
            raise ValueError("shape_margin_rad must be in [0, max_tilt_rad)")


@dataclass(frozen=True)
class TrackingDiagnostics:
    """What the last `TrackingController` update computed (for logs and tests).

    Errors are reference minus estimate (NED). attitude_err_frd: Lee's e_R (rates mode; zero in
    attitude mode, where PX4 closes the attitude loop); rate_err_frd: Lee's e_Omega =
    omega - R^T R_d omega_d with the measured rates (rates mode), body FRD [rad/s].
    """

    t_s: float
    pos_err_ned: FloatArray
    vel_err_ned: FloatArray
    acc_cmd_ned: FloatArray
    integrator_ned: FloatArray
    hover_thrust: float
    drag: float
    extrapolation_s: float
    saturated: bool
    attitude_err_frd: FloatArray
    fallback: bool
    reason: str
    rate_err_frd: FloatArray = field(default_factory=lambda: np.zeros(3))


