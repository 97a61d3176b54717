"""Tracking control for the companion: multirotor attitude/rates setpoints and rover velocity.

Pure: every call takes `now` [s] (the companion clock, the same clock the telemetry time stamps
`t_s` are expressed in); no clock reads, no IO. Frames: world NED, body FRD, SI units.

Multirotor pipeline (`TrackingController`):

1. Latency compensation: the last state estimate (stamped `t_s`) is extrapolated to `now` with
   its velocity and the acceleration (measured if given, else the last commanded one); the
   attitude with the body rates.
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
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np
import numpy.typing as npt

from companion._frozen import frozen_new
from companion.estimation import (
    DragConfig,
    DragEstimator,
    HoverThrustConfig,
    HoverThrustEstimator,
)
from companion.flatness import MultirotorParams, rover_setpoint
from companion.flatness.numeric import multirotor_attitude_scalar

FloatArray = npt.NDArray[np.float64]

_NAN3 = np.full(3, math.nan)


def _vec3(x: object, name: str) -> FloatArray:
    if type(x) is np.ndarray and x.dtype == np.float64 and x.shape == (3,):
        return x  # the common case, already what the reshape below would give (a view)
    a = np.asarray(x, dtype=np.float64).reshape(-1)
    if a.shape != (3,):
        raise ValueError(f"{name} must have 3 components, got shape {a.shape}")
    return a


def _finite(*arrays: FloatArray) -> bool:
    isfinite = math.isfinite
    return all(all(map(isfinite, a.tolist())) for a in arrays)


def _quat_normalize_f(w: float, x: float, y: float, z: float) -> tuple[float, float, float, float]:
    """`quat_normalize` on floats."""
    n = math.hypot(w, x, y, z)
    if not (math.isfinite(n) and n > 1e-12):
        return (1.0, 0.0, 0.0, 0.0)
    if w < 0.0:
        n = -n
    return (w / n, x / n, y / n, z / n)


def _quat_integrate_f(
    q: list[float], omega: list[float], dt: float
) -> tuple[float, float, float, float]:
    """`quat_integrate` on floats (same operations, same rounding)."""
    rx, ry, rz = omega[0] * dt, omega[1] * dt, omega[2] * dt
    ang = math.sqrt(rx * rx + ry * ry + rz * rz)
    w1, x1, y1, z1 = q
    if ang < 1e-12:
        return _quat_normalize_f(w1, x1, y1, z1)
    k = math.sin(0.5 * ang) / ang
    w2, x2, y2, z2 = math.cos(0.5 * ang), k * rx, k * ry, k * rz
    return _quat_normalize_f(
        w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
        w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
        w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
    )


def _body_z_down(q: FloatArray) -> float:
    """C_eb[2, 2] of a quaternion, as `quat_to_dcm` computes it (normalised; bad -> 1)."""
    w, x, y, z = q.tolist()
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if not (math.isfinite(n) and n > 0.0):
        return 1.0
    x, y = x / n, y / n
    return float(1 - 2 * (x * x + y * y))


# ----------------------------------------------------------------------------- small SO(3) kit
# Written out for (3,)/(4,) arrays: the controller runs at 100-250 Hz on single samples, where
# the batched geometry helpers' generality costs more than the arithmetic.


def quat_to_dcm(q_wxyz: FloatArray) -> FloatArray:
    """DCM C_eb (3, 3) of a quaternion (w, x, y, z) (normalised first; zero -> identity)."""
    w, x, y, z = (float(c) for c in q_wxyz)
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if not (math.isfinite(n) and n > 0.0):
        return np.eye(3)
    w, x, y, z = w / n, x / n, y / n, z / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def quat_normalize(q_wxyz: FloatArray) -> FloatArray:
    """Unit quaternion with w >= 0; non-finite or zero input gives the identity."""
    w, x, y, z = (float(c) for c in q_wxyz)
    n = math.hypot(w, x, y, z)
    if not (math.isfinite(n) and n > 1e-12):
        return np.array([1.0, 0.0, 0.0, 0.0])
    if w < 0.0:
        n = -n
    return np.array([w / n, x / n, y / n, z / n])


def quat_mul(a: FloatArray, b: FloatArray) -> FloatArray:
    """Hamilton product a * b (apply b first, then a)."""
    w1, x1, y1, z1 = (float(c) for c in a)
    w2, x2, y2, z2 = (float(c) for c in b)
    return np.array(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ]
    )


def quat_integrate(q_wxyz: FloatArray, omega_frd: FloatArray, dt: float) -> FloatArray:
    """Attitude after rotating for `dt` [s] at constant body rate `omega_frd` [rad/s]."""
    rx, ry, rz = (float(c) * dt for c in omega_frd)
    ang = math.sqrt(rx * rx + ry * ry + rz * rz)
    if ang < 1e-12:
        return quat_normalize(q_wxyz)
    k = math.sin(0.5 * ang) / ang
    dq = np.array([math.cos(0.5 * ang), k * rx, k * ry, k * rz])
    return quat_normalize(quat_mul(q_wxyz, dq))


def yaw_quat(yaw: float) -> FloatArray:
    """Level attitude with 3-2-1 yaw `yaw` [rad]."""
    return quat_normalize(np.array([math.cos(0.5 * yaw), 0.0, 0.0, math.sin(0.5 * yaw)]))


def yaw_of_dcm(C_eb: FloatArray) -> float:
    """3-2-1 yaw [rad] of C_eb (heading of the body x axis; falls back to y near gimbal lock)."""
    if math.hypot(C_eb[0, 0], C_eb[1, 0]) > 1e-6:
        return math.atan2(C_eb[1, 0], C_eb[0, 0])
    return math.atan2(-C_eb[0, 1], C_eb[1, 1])


def _vee(M: FloatArray) -> FloatArray:
    return np.array([M[2, 1], M[0, 2], M[1, 0]])


def attitude_error(C_eb: FloatArray, C_eb_des: FloatArray) -> FloatArray:
    """Lee et al. attitude error e_R = 1/2 vee(R_d^T R - R^T R_d), body FRD components.

    R = C_eb (actual), R_d = C_eb_des. |e_R| = sin(angle of R_d^T R); the rate command
    -k e_R rotates R towards R_d.
    """
    M = C_eb_des.T @ C_eb - C_eb.T @ C_eb_des
    return 0.5 * _vee(M)


# ----------------------------------------------------------------------------- values


@dataclass(frozen=True)
class StateEstimate:
    """Vehicle state from telemetry (LOCAL_POSITION_NED + ATTITUDE / ODOMETRY).

    t_s: time the estimate is valid at, in the companion clock [s].
    pos_ned [m], vel_ned [m/s], acc_ned [m/s^2, kinematic, optional]: world NED (3,).
    q_wxyz: attitude body FRD -> NED (normalised by the controller; a norm outside (0.5, 2) is
    treated as corrupt). omega_frd: body rates [rad/s].
    airborne: False on the ground (holds the hover-thrust estimator and the integrator).
    Build it from ODOMETRY (one time stamp for everything) or align the attitude to the
    position's time stamp: the controller extrapolates all of it from `t_s` to `now`.
    """

    t_s: float
    pos_ned: FloatArray
    vel_ned: FloatArray
    q_wxyz: FloatArray
    omega_frd: FloatArray
    acc_ned: FloatArray | None = None
    airborne: bool = True

    def __post_init__(self) -> None:
        object.__setattr__(self, "pos_ned", _vec3(self.pos_ned, "pos_ned"))
        object.__setattr__(self, "vel_ned", _vec3(self.vel_ned, "vel_ned"))
        object.__setattr__(self, "omega_frd", _vec3(self.omega_frd, "omega_frd"))
        q = np.asarray(self.q_wxyz, dtype=np.float64).reshape(-1)
        if q.shape != (4,):
            raise ValueError(f"q_wxyz must have 4 components, got shape {q.shape}")
        object.__setattr__(self, "q_wxyz", q)
        if self.acc_ned is not None:
            object.__setattr__(self, "acc_ned", _vec3(self.acc_ned, "acc_ned"))

    def is_finite(self) -> bool:
        """All fields finite and the quaternion not degenerate."""
        vals = [
            self.t_s,
            *self.pos_ned.tolist(),
            *self.vel_ned.tolist(),
            *self.q_wxyz.tolist(),
            *self.omega_frd.tolist(),
        ]
        if self.acc_ned is not None:
            vals += self.acc_ned.tolist()
        return all(map(math.isfinite, vals)) and self.quat_ok()

    def quat_ok(self) -> bool:
        """Quaternion finite with norm in (0.5, 2) (telemetry sends unit quaternions)."""
        n = math.hypot(*self.q_wxyz.tolist())  # NaN/inf propagate; no overflow
        return 0.5 < n < 2.0


Telemetry = StateEstimate
"""Alias: the controller's telemetry input."""


@dataclass(frozen=True)
class Reference:
    """Flat-output reference at one time: NED position and derivatives, 3-2-1 yaw and derivatives.

    pos_ned [m], vel_ned [m/s], acc_ned [m/s^2], jerk_ned [m/s^3], snap_ned [m/s^4] (3,);
    yaw [rad], yaw_rate = d(yaw)/dt [rad/s], yaw_acc [rad/s^2].
    """

    pos_ned: FloatArray
    vel_ned: FloatArray = field(default_factory=lambda: np.zeros(3))
    acc_ned: FloatArray = field(default_factory=lambda: np.zeros(3))
    jerk_ned: FloatArray = field(default_factory=lambda: np.zeros(3))
    snap_ned: FloatArray = field(default_factory=lambda: np.zeros(3))
    yaw: float = 0.0
    yaw_rate: float = 0.0
    yaw_acc: float = 0.0

    def __post_init__(self) -> None:
        for name in ("pos_ned", "vel_ned", "acc_ned", "jerk_ned", "snap_ned"):
            object.__setattr__(self, name, _vec3(getattr(self, name), name))

    def is_finite(self) -> bool:
        """All fields finite."""
        return all(
            map(
                math.isfinite,
                [
                    *self.pos_ned.tolist(),
                    *self.vel_ned.tolist(),
                    *self.acc_ned.tolist(),
                    *self.jerk_ned.tolist(),
                    *self.snap_ned.tolist(),
                    self.yaw,
                    self.yaw_rate,
                    self.yaw_acc,
                ],
            )
        )


def reference_of_arrays(
    pos_ned: FloatArray,
    vel_ned: FloatArray,
    acc_ned: FloatArray,
    jerk_ned: FloatArray,
    snap_ned: FloatArray,
    yaw: float,
    yaw_rate: float,
    yaw_acc: float,
) -> Reference:
    """`Reference(...)` from vectors that are already float64 arrays of shape (3,) (what its
    `__post_init__` would make of them; not checked) and float scalars: the per-setpoint fast
    path of the schedule, without the constructor's conversions."""
    return frozen_new(
        Reference, pos_ned=pos_ned, vel_ned=vel_ned, acc_ned=acc_ned, jerk_ned=jerk_ned,
        snap_ned=snap_ned, yaw=yaw, yaw_rate=yaw_rate, yaw_acc=yaw_acc,
    )


def state_estimate_of_arrays(
    t_s: float,
    pos_ned: FloatArray,
    vel_ned: FloatArray,
    q_wxyz: FloatArray,
    omega_frd: FloatArray,
    airborne: bool = True,
) -> StateEstimate:
    """`StateEstimate(...)` (without `acc_ned`) from float64 arrays of shape (3,) / (4,) (not
    checked): the per-sample fast path of the telemetry adapter, without the conversions."""
    return frozen_new(
        StateEstimate, t_s=t_s, pos_ned=pos_ned, vel_ned=vel_ned, q_wxyz=q_wxyz,
        omega_frd=omega_frd, acc_ned=None, airborne=airborne,
    )


def reference_from_trajectory(traj: object, t: float, yaw: float = 0.0) -> Reference:
    """Sample a `PiecewiseBezier`-like trajectory (NED, 3-D) at time `t` [s].

    Needs `.duration`, `.evaluate(t, order)` and `.yaw` (a 1-D trajectory or None). Beyond the
    ends the position holds and the derivatives are zero. Without a yaw channel `yaw` is used.
    """
    duration = float(getattr(traj, "duration"))  # noqa: B009
    evaluate: Callable[[float, int], FloatArray] = getattr(traj, "evaluate")  # noqa: B009
    tc = min(max(t, 0.0), duration)
    inside = 0.0 <= t <= duration
    d = [np.asarray(evaluate(tc, k), dtype=np.float64).reshape(3) for k in range(5)]
    if not inside:
        d[1:] = [np.zeros(3)] * 4
    yaw_traj = getattr(traj, "yaw", None)
    psi, psi_d, psi_dd = yaw, 0.0, 0.0
    if yaw_traj is not None:
        ev: Callable[[float, int], FloatArray] = getattr(yaw_traj, "evaluate")  # noqa: B009
        psi = float(np.asarray(ev(tc, 0)).reshape(-1)[0])
        if inside:
            psi_d = float(np.asarray(ev(tc, 1)).reshape(-1)[0])
            psi_dd = float(np.asarray(ev(tc, 2)).reshape(-1)[0])
    return Reference(d[0], d[1], d[2], d[3], d[4], psi, psi_d, psi_dd)


@dataclass(frozen=True)
class AttitudeCommand:
    """SET_ATTITUDE_TARGET with attitude (type_mask 3): q + normalised thrust + yaw-rate ff.

    q_wxyz: unit quaternion body FRD -> NED, w >= 0. thrust_norm: 0..1, no hover scaling.
    yaw_rate_ff: yaw rate feed-forward [rad/s]. fallback/reason: a hover fallback was produced.
    saturated: the tilt/thrust limits were active.
    """

    q_wxyz: FloatArray
    thrust_norm: float
    yaw_rate_ff: float
    fallback: bool = False
    reason: str = ""
    saturated: bool = False


@dataclass(frozen=True)
class RateCommand:
    """SET_ATTITUDE_TARGET with attitude ignored (type_mask 128): body rates + thrust.

    omega_frd: body rates [rad/s]. thrust_norm: 0..1, no hover scaling.
    """

    omega_frd: FloatArray
    thrust_norm: float
    fallback: bool = False
    reason: str = ""
    saturated: bool = False


@dataclass(frozen=True)
class PositionCommand:
    """SET_POSITION_TARGET_LOCAL_NED: NaN components mean "not given" (ignore bit set).

    pos_ned [m], vel_ned [m/s], acc_ned [m/s^2] world NED (3,); yaw [rad]; yaw_rate [rad/s].
    """

    pos_ned: FloatArray = field(default_factory=lambda: _NAN3.copy())
    vel_ned: FloatArray = field(default_factory=lambda: _NAN3.copy())
    acc_ned: FloatArray = field(default_factory=lambda: _NAN3.copy())
    yaw: float = math.nan
    yaw_rate: float = math.nan
    fallback: bool = False
    reason: str = ""


def position_command(
    ref: Reference, feedforward: bool = True, hold: StateEstimate | None = None,
    drag_per_kg: float = 0.0,
) -> PositionCommand:
    """`position` mode: the reference as a PX4 position setpoint (PX4 closes the loop).

    feedforward False sends position + yaw only (the naive baseline); True adds velocity,
    acceleration and the yaw rate. `drag_per_kg` = D / m [1/s] (linear world-frame drag,
    docs/theory/multirotor.md)
    adds the acceleration that cancels the drag at the reference velocity, D v / m, to the
    acceleration feed-forward: PX4 turns that feed-forward into thrust without a drag model, so
    without it its velocity integral has to carry the drag (6 m/s^2 at 6 m/s on SIH) and the
    vehicle lags. A non-finite reference gives a flagged hold at `hold`'s position and heading,
    or raises ValueError when no `hold` estimate is given.
    """
    if not ref.is_finite():
        if hold is not None and hold.is_finite():
            return PositionCommand(
                pos_ned=hold.pos_ned.copy(),
                yaw=yaw_of_dcm(quat_to_dcm(hold.q_wxyz)),
                fallback=True,
                reason="reference not finite",
            )
        raise ValueError("reference is not finite; refusing to build a position setpoint")
    if feedforward:
        acc = ref.acc_ned + drag_per_kg * ref.vel_ned if drag_per_kg else ref.acc_ned.copy()
        return PositionCommand(ref.pos_ned.copy(), ref.vel_ned.copy(), acc, ref.yaw, ref.yaw_rate)
    return PositionCommand(pos_ned=ref.pos_ned.copy(), yaw=ref.yaw)


# ----------------------------------------------------------------------------- configuration


@dataclass(frozen=True)
class TrackingGains:
    """Position-loop gains: a = a_ref + kp e_p + kd e_v + ki int(e_p) (per axis, xy and z).

    kp [1/s^2], kd [1/s], ki [1/s^3]; i_max_xy / i_max_z: clamp of the integrator's
    acceleration contribution [m/s^2]. The xy defaults (omega_n 4.5 rad/s, zeta 0.95) were tuned
    on real PX4 v1.16 SITL over UDP, figure-8 at 2 and 6 m/s (BENCHMARKS.md); kp_xy 30
    oscillates there in attitude mode, so they sit at about 2/3 of the stability limit. They
    assume telemetry latency under ~50 ms; with ~100 ms use kp_xy 6, kd_xy 4.5, ki_xy 1 and
    attitude gains k_roll = k_pitch = 6.5.
    """

    kp_xy: float = 20.0
    kd_xy: float = 8.5
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
    (Lee 2011's alternative error function; small-angle behaviour unchanged).
    """

    k_roll: float = 10.0
    k_pitch: float = 10.0
    k_yaw: float = 2.8
    max_rate_rp: float = math.radians(220.0)
    max_rate_yaw: float = math.radians(200.0)
    large_angle: bool = True


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
    rates_separation: if > 0, `rates` mode flies `rates_mode_gains(gains, attitude_gains,
        rates_separation)` (the cascade-separation cap, 2.5 before the feed-forward); 0 (the
        default) flies the configured gains.
    """

    params: MultirotorParams
    gains: TrackingGains = TrackingGains()
    attitude_gains: AttitudeGains = AttitudeGains()
    drag_feedforward: bool = True
    drag_velocity: Literal["reference", "estimate"] = "estimate"
    estimate_hover_thrust: bool = True
    estimate_drag: bool = False
    hover_thrust_config: HoverThrustConfig | None = None
    drag_config: DragConfig | None = None
    latency_compensation: bool = True
    max_extrapolation_s: float = 0.25
    stale_after_s: float = 0.5
    attitude_lead_s: float = 0.15
    thrust_delay_s: float = 0.05
    max_tilt_rad: float = math.radians(60.0)
    thrust_min: float = 0.08
    thrust_max: float = 1.0
    feedback_rate_ff: float = 0.25
    rates_separation: float = 0.0

    def __post_init__(self) -> None:
        if not 0.0 < self.max_tilt_rad < math.radians(89.0):
            raise ValueError("max_tilt_rad must be in (0, 89) deg")
        if not 0.0 <= self.thrust_min < self.thrust_max <= 1.0:
            raise ValueError("thrust bounds must satisfy 0 <= min < max <= 1")
        if not 0.0 < self.params.hover_thrust < 1.0:
            raise ValueError("params.hover_thrust must be in (0, 1)")
        if not 0.0 <= self.feedback_rate_ff <= 1.0:
            raise ValueError("feedback_rate_ff must be in [0, 1]")
        if not (math.isfinite(self.rates_separation) and self.rates_separation >= 0.0):
            raise ValueError("rates_separation must be >= 0 (0: no cap)")


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


# ----------------------------------------------------------------------------- SO(3) loop


def so3_rate_command(
    q_wxyz: FloatArray,
    q_des_wxyz: FloatArray,
    omega_ff_frd: FloatArray,
    gains: AttitudeGains,
) -> tuple[FloatArray, FloatArray]:
    """Geometric attitude controller: body-rate command and the attitude error.

    omega_cmd = R^T R_d omega_ff - K e_R (optionally e_R / cos(angle/2)), limited per axis.
    q_wxyz: actual attitude; q_des_wxyz: desired; omega_ff_frd: desired body rates (in the
    desired body frame) [rad/s]. Returns (omega_cmd_frd [rad/s], e_R).
    """
    R = quat_to_dcm(q_wxyz)
    Rd = quat_to_dcm(q_des_wxyz)
    return so3_rate_command_dcm(R, Rd, omega_ff_frd, gains)


def so3_rate_command_dcm(
    R: FloatArray, Rd: FloatArray, omega_ff_frd: FloatArray, gains: AttitudeGains
) -> tuple[FloatArray, FloatArray]:
    """`so3_rate_command` with the attitudes given as DCMs C_eb (actual R, desired Rd)."""
    Rt_Rd = R.T @ Rd
    e_R = attitude_error(R, Rd)
    k = np.array([gains.k_roll, gains.k_pitch, gains.k_yaw])
    err = e_R
    if gains.large_angle:
        # 1 + tr(R_d^T R) = 4 cos^2(angle / 2)
        c_half = 0.5 * math.sqrt(max(1.0 + float(np.trace(Rt_Rd)), 0.0))
        err = e_R / max(c_half, 0.05)
    ff = np.asarray(omega_ff_frd, dtype=np.float64)
    if not _finite(ff):
        ff = np.zeros(3)
    omega = Rt_Rd @ ff - k * err
    lim = np.array([gains.max_rate_rp, gains.max_rate_rp, gains.max_rate_yaw])
    omega = np.minimum(np.maximum(omega, -lim), lim)
    return omega, e_R


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
        self._gain_lists = {
            rates: (g.kp().tolist(), g.kd().tolist(), g.ki().tolist(), g.i_max().tolist())
            for rates, g in ((False, config.gains),
                             (True, rates_mode_gains(config.gains, config.attitude_gains,
                                                     config.rates_separation)
                              if config.rates_separation > 0.0 else config.gains))
        }
        self._kp_l, self._kd_l, self._ki_l, self._imax_l = self._gain_lists[False]
        self._integ_l = [0.0, 0.0, 0.0]
        self._cos_tilt = math.cos(config.max_tilt_rad)
        self._tan_tilt = math.tan(config.max_tilt_rad)
        self._t_last_update: float | None = None
        self._last_est: StateEstimate | None = None
        self._prev_est: StateEstimate | None = None
        self._last_acc_cmd: tuple[float, float, float] = (0.0, 0.0, 0.0)
        self._thrust_hist: deque[tuple[float, float]] = deque(maxlen=256)
        self._last_yaw = 0.0
        self._last_diag: TrackingDiagnostics | None = None
        self._diag_pending: tuple[FloatArray | None, FloatArray | None] | None = None

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
        """Clear the integrator and the telemetry history (e.g. on entering offboard)."""
        self._integ_l = [0.0, 0.0, 0.0]
        self._t_last_update = None
        self._last_est = None
        self._prev_est = None
        self._last_acc_cmd = (0.0, 0.0, 0.0)
        self._thrust_hist.clear()

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
                attitude_err_frd=np.zeros(3) if e_R is None else e_R,
                fallback=False,
                reason=reason,
                rate_err_frd=np.zeros(3) if e_omega is None else e_omega,
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
        rate_ff = ref.yaw_rate if math.isfinite(ref.yaw_rate) else 0.0
        self._publish_diag(None)
        return q_des, thrust, rate_ff, sat

    def rates(self, now: float, est: StateEstimate, ref: Reference) -> RateCommand:
        """`rates` mode setpoint at `now`: body rates from the SO(3) loop + thrust."""
        out = self._core(now, est, ref, 0.0, rates=True)
        if out is None:
            return self._fallback_rates(now, est)
        q_des_t, thrust, omega_ff_t, sat = out
        omega_ff = np.array(omega_ff_t)
        R = quat_to_dcm(np.array(self._q_now))
        Rd = quat_to_dcm(np.array(q_des_t))
        omega, e_R = so3_rate_command_dcm(R, Rd, omega_ff, self.config.attitude_gains)
        e_omega = est.omega_frd - (R.T @ Rd) @ omega_ff
        # Thrust along the actual body z (Lee): project the desired thrust direction.
        proj = float(Rd[:, 2] @ R[:, 2])
        thrust = min(max(thrust * max(proj, 0.5), self.config.thrust_min), self.config.thrust_max)
        self._publish_diag(e_R, e_omega)
        if not (_finite(omega) and math.isfinite(thrust)):
            return self._fallback_rates(now, est, "non-finite rate command")
        self._record_thrust(now, thrust)
        return RateCommand(omega, thrust, saturated=sat)

    # -- internals ----------------------------------------------------------------------------
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
        if last is None:
            return
        dt = est.t_s - last.t_s
        if not (1e-3 < dt < 0.5):
            return
        hover, drag = self.config.estimate_hover_thrust, self.config.estimate_drag
        if not (hover or drag):
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
            zb_mid_z = 0.5 * (_body_z_down(est.q_wxyz) + _body_z_down(last.q_wxyz))
            self.hover_estimator.update(est.t_s, acc_z, u, zb_mid_z, v_mid_z, airborne)
        if drag:
            acc = est.acc_ned if est.acc_ned is not None else (est.vel_ned - last.vel_ned) / dt
            zb = quat_to_dcm(est.q_wxyz)[:, 2]
            zb_prev = quat_to_dcm(last.q_wxyz)[:, 2]
            zb_mid = 0.5 * (zb + zb_prev)
            v_mid = 0.5 * (est.vel_ned + last.vel_ned) if est.acc_ned is None else est.vel_ned
            self.drag_estimator.update(
                est.t_s, acc, v_mid, u, zb_mid, self.hover_thrust, airborne
            )

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
        qw, qx, qy, qz = q_est
        self._last_yaw = math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))

        dt_ctrl = 0.0 if self._t_last_update is None else now - self._t_last_update
        dt_ctrl = min(max(dt_ctrl, 0.0), 0.1)
        self._t_last_update = now

        # Plain floats from here to the flatness call: this runs at the setpoint rate on
        # single samples, where numpy's per-operation overhead dominates.
        # 1. latency compensation
        tau = min(max(age, 0.0), c.max_extrapolation_s) if c.latency_compensation else 0.0
        if acc0:
            ax0, ay0, az0 = acc0
        else:
            ax0, ay0, az0 = self._last_acc_cmd
        h2 = 0.5 * tau * tau
        pos = (px0 + vx0 * tau + ax0 * h2, py0 + vy0 * tau + ay0 * h2, pz0 + vz0 * tau + az0 * h2)
        vel = (vx0 + ax0 * tau, vy0 + ay0 * tau, vz0 + az0 * tau)
        self._q_now = (
            _quat_integrate_f(q_est, w_est, tau) if tau > 0 else _quat_normalize_f(*q_est)
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
        kp, kd, integ = self._kp_l, self._kd_l, self._integ_l
        # (per component, written out: a comprehension costs a frame per call)
        e_p = (rp[0] - pos[0], rp[1] - pos[1], rp[2] - pos[2])
        e_v = (rv[0] - vel[0], rv[1] - vel[1], rv[2] - vel[2])
        a_cmd = (
            a_ff[0] + kp[0] * e_p[0] + kd[0] * e_v[0] + integ[0],
            a_ff[1] + kp[1] * e_p[1] + kd[1] * e_v[1] + integ[1],
            a_ff[2] + kp[2] * e_p[2] + kd[2] * e_v[2] + integ[2],
        )
        if rates and c.feedback_rate_ff > 0.0 and self._thrust_hist:
            j_ff = self._feedback_jerk(j_ff, ra, e_p, e_v, vel, c.feedback_rate_ff)

        # 3. thrust vector t = m (g e3 - a) - D v with drag, saturation
        h = self.hover_thrust
        D = self.drag
        v_drag = vel if c.drag_velocity == "estimate" else rv
        m = p.mass
        g0 = p.g
        t_vec = (
            -m * a_cmd[0] - D * v_drag[0],
            -m * a_cmd[1] - D * v_drag[1],
            m * (g0 - a_cmd[2]) - D * v_drag[2],
        )
        t_sat, sat = self._saturate(t_vec, h)
        a_sat = (
            -(t_sat[0] + D * v_drag[0]) / m,
            -(t_sat[1] + D * v_drag[1]) / m,
            g0 - (t_sat[2] + D * v_drag[2]) / m,
        )

        # anti-windup: integrate only in the air and when not saturated (or when it unwinds)
        if dt_ctrl > 0.0 and est.airborne:
            ki, imax = self._ki_l, self._imax_l
            for i in range(3):
                di = ki[i] * e_p[i] * dt_ctrl
                if sat and di * integ[i] >= 0.0:
                    continue  # saturated: only let the integrator unwind
                integ[i] = min(max(integ[i] + di, -imax[i]), imax[i])
        self._last_acc_cmd = a_sat

        # 4. flatness map
        params = self._params_for_drag(D)
        jerk = (0.0, 0.0, 0.0) if sat else j_ff
        snap = (0.0, 0.0, 0.0) if sat else rs
        yaw_rate = ref.yaw_rate
        yaw_acc = 0.0 if sat else ref.yaw_acc
        try:
            qw, qx, qy, qz, thrust_n, wx, wy, wz, singular = multirotor_attitude_scalar(
                v_drag, a_sat, jerk, snap, ref.yaw, yaw_rate, yaw_acc, params
            )
        except ValueError as exc:  # e.g. absurd magnitudes the flatness map refuses
            self._fallback_reason = f"flatness map refused the input: {exc}"
            return None
        # normalised thrust with the hover thrust in use
        # (docs/theory/multirotor.md, "Thrust for MAVLink")
        thrust = h * thrust_n / (m * p.g)
        if not all(map(isfinite, (qw, qx, qy, qz, wx, wy, wz, thrust))):
            self._fallback_reason = "flatness output not finite"
            return None
        omega_ff = (0.0, 0.0, 0.0) if singular else (float(wx), float(wy), float(wz))
        q_des = _quat_normalize_f(float(qw), float(qx), float(qy), float(qz))
        thrust = min(max(thrust, c.thrust_min), c.thrust_max)
        self._diag = (now, e_p, e_v, a_sat, tuple(integ), h, D, tau, sat,
                      "singular flatness point" if singular else "")
        self.last_q_des = q_des
        return q_des, thrust, omega_ff, sat

    def _feedback_jerk(
        self,
        j_ref: tuple[float, float, float],
        a_ref: list[float],
        e_p: tuple[float, float, float],
        e_v: tuple[float, float, float],
        vel: tuple[float, float, float],
        share: float,
    ) -> tuple[float, float, float]:
        """Time derivative of the commanded acceleration [m/s^3, NED], its feedback part scaled
        by `share`: j_ref + share (kp e_v + kd (a_ref - a) + ki e_p). The vehicle's acceleration
        `a` comes from its (extrapolated) attitude and the last thrust command,
        a = g e3 - (u g / h) z_b - D v / m, not from differentiated velocities. Fed to the
        flatness map in `rates` mode, the body rates then carry the commanded attitude's own
        rotation forward (share 1: exactly; tests/unit/test_control.py checks it against finite
        differences), so the P attitude loop only corrects what the rate loop missed."""
        p = self.config.params
        g0 = p.g
        h = self.hover_thrust
        u = self._thrust_hist[-1][1]
        qw, qx, qy, qz = self._q_now
        # body z axis (third column of C_eb) in NED
        zx = 2.0 * (qx * qz + qw * qy)
        zy = 2.0 * (qy * qz - qw * qx)
        zz = 1.0 - 2.0 * (qx * qx + qy * qy)
        f = u * g0 / h
        dm = self.drag / p.mass
        a = (-f * zx - dm * vel[0], -f * zy - dm * vel[1], g0 - f * zz - dm * vel[2])
        kp, kd, ki = self._kp_l, self._kd_l, self._ki_l
        return (
            j_ref[0] + share * (kp[0] * e_v[0] + kd[0] * (a_ref[0] - a[0]) + ki[0] * e_p[0]),
            j_ref[1] + share * (kp[1] * e_v[1] + kd[1] * (a_ref[1] - a[1]) + ki[1] * e_p[1]),
            j_ref[2] + share * (kp[2] * e_v[2] + kd[2] * (a_ref[2] - a[2]) + ki[2] * e_p[2]),
        )

    def _publish_diag(self, e_R: FloatArray | None, e_omega: FloatArray | None = None) -> None:
        """Diagnostics of this update (from `_diag`), built lazily by `last`."""
        self._diag_pending = (e_R, e_omega)

    def _params_for_drag(self, drag: float) -> MultirotorParams:
        """Flatness parameters with drag `drag` (cached: constructing them validates inertia)."""
        key = round(drag, 4)
        cached = self._params_cache
        if cached is None or cached[0] != key:
            cached = (key, replace(self.config.params, drag=key))
            self._params_cache = cached
        return cached[1]

    def _saturate(
        self, t_vec: tuple[float, float, float], hover_thrust: float
    ) -> tuple[tuple[float, float, float], bool]:
        """Limit the thrust vector [N]: min upward, tilt, max magnitude (vertical first)."""
        c = self.config
        p = c.params
        n_per_norm = p.mass * p.g / hover_thrust  # N per unit normalised thrust
        T_min = c.thrust_min * n_per_norm
        T_max = c.thrust_max * n_per_norm
        tx, ty, tz = t_vec
        # t = T z_b points along body z (down when level); the lift is -t. Vertical part: t_z.
        sat = False
        if tz < T_min * self._cos_tilt:
            tz = T_min * self._cos_tilt
            sat = True
        if tz > T_max:
            tz = T_max
            sat = True
        h_lim = min(tz * self._tan_tilt, math.sqrt(max(T_max * T_max - tz * tz, 0.0)))
        hn = math.hypot(tx, ty)
        if hn > h_lim:
            k = h_lim / hn
            tx, ty = tx * k, ty * k
            sat = True
        if T_min > math.hypot(tx, ty, tz):
            tz = math.sqrt(max(T_min * T_min - tx * tx - ty * ty, 0.0))
            sat = True
        return (tx, ty, tz), sat

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
            if not _finite(omega):
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
    _params_cache: tuple[float, MultirotorParams] | None = None
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


# ----------------------------------------------------------------------------- rover


@dataclass(frozen=True)
class RoverGains:
    """Rover path-following gains.

    k_along [1/s]: speed correction per metre of along-track error.
    k_cross [1/m]: heading correction atan(k_cross * cross-track error).
    k_heading [1/s]: yaw-rate correction per radian of heading error.
    max_speed [m/s], max_yaw_rate [rad/s]: command limits.
    """

    k_along: float = 1.0
    k_cross: float = 0.8
    k_heading: float = 2.0
    max_speed: float = 3.0
    max_yaw_rate: float = math.radians(90.0)


class RoverController:
    """Rover tracking: velocity + yaw-rate setpoints from rover flatness plus a correction."""

    def __init__(self, gains: RoverGains | None = None) -> None:
        self.gains = gains or RoverGains()
        self._last_heading: float | None = None

    def update(self, now: float, est: StateEstimate, ref: Reference) -> PositionCommand:
        """Velocity (NED, z NaN), yaw and yaw-rate setpoint at `now`.

        The reference heading/speed/yaw rate come from rover flatness of the xy reference;
        the along-track error corrects the speed, the cross-track error the heading, the heading
        error the yaw rate. Bad input -> stop (zero velocity, zero yaw rate), flagged.
        """
        k = self.gains
        if not (math.isfinite(now) and est.is_finite() and ref.is_finite()):
            return PositionCommand(
                vel_ned=np.array([0.0, 0.0, math.nan]), yaw_rate=0.0,
                fallback=True, reason="input not finite",
            )
        try:
            rs = rover_setpoint(ref.vel_ned[:2], ref.acc_ned[:2], ref.jerk_ned[:2])
        except ValueError as exc:
            return PositionCommand(
                vel_ned=np.array([0.0, 0.0, math.nan]), yaw_rate=0.0,
                fallback=True, reason=f"rover flatness refused the input: {exc}",
            )
        speed = float(np.asarray(rs.speed).reshape(-1)[0])
        psi_ref = float(np.asarray(rs.yaw).reshape(-1)[0])
        r_ref = float(np.asarray(rs.yaw_rate).reshape(-1)[0])
        if not (math.isfinite(psi_ref) and math.isfinite(r_ref) and math.isfinite(speed)):
            psi_ref, r_ref, speed = ref.yaw, 0.0, 0.0
        if speed < 1e-3 and self._last_heading is not None:
            psi_ref = self._last_heading
        self._last_heading = psi_ref
        # latency: extrapolate the position with the measured velocity
        tau = min(max(now - est.t_s, 0.0), 0.25)
        pos = est.pos_ned[:2] + est.vel_ned[:2] * tau
        e = ref.pos_ned[:2] - pos
        t_hat = np.array([math.cos(psi_ref), math.sin(psi_ref)])
        n_hat = np.array([-math.sin(psi_ref), math.cos(psi_ref)])
        e_at = float(e @ t_hat)
        e_ct = float(e @ n_hat)
        speed_cmd = min(max(speed + k.k_along * e_at, 0.0), k.max_speed)
        heading_cmd = psi_ref + math.atan(k.k_cross * e_ct)
        yaw_now = yaw_of_dcm(quat_to_dcm(est.q_wxyz))
        yaw_now += float(est.omega_frd[2]) * tau
        herr = math.remainder(heading_cmd - yaw_now, 2.0 * math.pi)
        yaw_rate = r_ref + k.k_heading * herr
        yaw_rate = min(max(yaw_rate, -k.max_yaw_rate), k.max_yaw_rate)
        vel = np.array(
            [speed_cmd * math.cos(heading_cmd), speed_cmd * math.sin(heading_cmd), math.nan]
        )
        return PositionCommand(vel_ned=vel, yaw_rate=yaw_rate)


__all__ = [
    "AttitudeCommand",
    "AttitudeGains",
    "PositionCommand",
    "RateCommand",
    "Reference",
    "RoverController",
    "RoverGains",
    "StateEstimate",
    "Telemetry",
    "TrackingConfig",
    "TrackingController",
    "TrackingDiagnostics",
    "TrackingGains",
    "attitude_error",
    "position_command",
    "quat_integrate",
    "quat_to_dcm",
    "reference_from_trajectory",
    "reference_of_arrays",
    "so3_rate_command",
    "so3_rate_command_dcm",
    "state_estimate_of_arrays",
    "yaw_quat",
]
