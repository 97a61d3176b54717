"""Online estimators for the tracking controller: hover thrust and linear drag.

Pure: every call takes the sample time `now` [s]; no clock, no IO.

Hover thrust: a scalar Kalman filter on the vertical specific-force balance (the idea of PX4's
mc_hover_thrust_estimator, written here in NED with tilt and linear drag). With the linear
thrust model of docs/theory/multirotor.md (`T = m g u / h`, `u` the normalised thrust, `h` the
hover thrust) the vertical acceleration in NED is

    a_z = g - g * u * (z_b . e3) / h - (D / m) * v_z

so a measured `a_z` (down positive) together with the commanded `u` and the attitude tells
`h`. The state is `h` itself (random walk); the measurement is non-linear in `h` and is
linearised at the current estimate (extended KF). Innovations outside `gate_sigma` standard
deviations are rejected; if they stay rejected (the hover thrust really changed, e.g. a payload
was added) the variance is inflated so the filter re-converges. No update is made on the
ground, at low thrust, at large tilt, or while the vehicle accelerates hard vertically (the
linear model is worst there).

Drag: `DragEstimator` estimates `k = D / m` [1/s] from the horizontal balance
`a_h + g u z_b_h / h = -k v_h` with the current hover-thrust estimate.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from companion._frozen import frozen_new
from companion.control.observer import disturbance_step
from companion.flatness._formulas import FLOAT

FloatArray = npt.NDArray[np.float64]

G0 = 9.80665
"""Standard gravity [m/s^2]."""


@dataclass(frozen=True)
class HoverThrustConfig:
    """Tuning of `HoverThrustEstimator` (defaults follow PX4's HTE_* parameters in spirit).

    initial_hover_thrust: prior, normalised 0..1 (PX4 MPC_THR_HOVER).
    initial_std: 1-sigma of the prior [normalised thrust].
    process_noise_std: random-walk intensity [normalised thrust / sqrt(s)].
    acc_noise_std: initial 1-sigma of the vertical acceleration measurement [m/s^2].
    acc_noise_min_std / acc_noise_max_std: bounds of the adaptive measurement noise [m/s^2].
    noise_time_constant_s: time constant of the measurement-noise adaptation [s] (0 = fixed).
    gate_sigma: innovation gate [standard deviations].
    recover_after_s: continuous rejection longer than this inflates the variance [s].
    hover_thrust_min / hover_thrust_max: bounds of the estimate.
    min_thrust_norm: no update below this commanded thrust (ground, idle, free fall).
    max_tilt_rad: no update above this tilt (thrust model and drag least certain).
    max_vertical_acc: no update when the measured (kinematic) vertical acceleration exceeds
        this magnitude [m/s^2].
    drag_over_mass: known linear drag D/m [1/s] used in the measurement model.
    g: gravity [m/s^2].
    """

    initial_hover_thrust: float = 0.5
    initial_std: float = 0.1
    process_noise_std: float = 0.01
    acc_noise_std: float = 1.0
    acc_noise_min_std: float = 0.2
    acc_noise_max_std: float = 20.0
    noise_time_constant_s: float = 2.0
    gate_sigma: float = 3.0
    recover_after_s: float = 1.0
    hover_thrust_min: float = 0.1
    hover_thrust_max: float = 0.9
    min_thrust_norm: float = 0.05
    max_tilt_rad: float = math.radians(60.0)
    max_vertical_acc: float = 5.0
    drag_over_mass: float = 0.0
    g: float = G0

    def __post_init__(self) -> None:
        if not self.hover_thrust_min < self.hover_thrust_max:
            raise ValueError("hover thrust bounds must satisfy min < max")
        if not self.hover_thrust_min <= self.initial_hover_thrust <= self.hover_thrust_max:
            raise ValueError(
                f"initial hover thrust {self.initial_hover_thrust} outside "
                f"[{self.hover_thrust_min}, {self.hover_thrust_max}]"
            )
        for name in ("initial_std", "process_noise_std", "acc_noise_std", "gate_sigma", "g"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0.0):
                raise ValueError(f"{name} must be positive and finite, got {v}")


@dataclass(frozen=True)
class HoverThrustStatus:
    """Result of one `HoverThrustEstimator.update` call.

    hover_thrust: current estimate [normalised 0..1]; hover_thrust_std its 1-sigma.
    innovation: measured minus predicted vertical acceleration [m/s^2] (NaN if not computed).
    innovation_std: 1-sigma of the innovation [m/s^2] (NaN if not computed).
    test_ratio: innovation^2 / (gate^2 * innovation variance); > 1 means rejected.
    fused: the measurement updated the estimate.
    reason: why it was not fused ("" when fused).
    """

    t_s: float
    hover_thrust: float
    hover_thrust_std: float
    innovation: float
    innovation_std: float
    test_ratio: float
    fused: bool
    reason: str


class HoverThrustEstimator:
    """Scalar extended Kalman filter for the normalised hover thrust (see module docstring)."""

    def __init__(self, config: HoverThrustConfig | None = None) -> None:
        self.config = config or HoverThrustConfig()
        self._h = self.config.initial_hover_thrust
        self._var = self.config.initial_std**2
        self._acc_var = self.config.acc_noise_std**2
        self._t_last: float | None = None
        self._rejecting_since: float | None = None
        self._residual_lpf = 0.0

    @property
    def hover_thrust(self) -> float:
        """Current estimate [normalised thrust 0..1]."""
        return self._h

    @property
    def hover_thrust_std(self) -> float:
        """1-sigma uncertainty of the estimate [normalised thrust]."""
        return math.sqrt(self._var)

    def reset(self, hover_thrust: float | None = None) -> None:
        """Back to the prior (or to `hover_thrust` with the prior's uncertainty)."""
        c = self.config
        h = c.initial_hover_thrust if hover_thrust is None else float(hover_thrust)
        self._h = min(max(h, c.hover_thrust_min), c.hover_thrust_max)
        self._var = c.initial_std**2
        self._acc_var = c.acc_noise_std**2
        self._t_last = None
        self._rejecting_since = None
        self._residual_lpf = 0.0

    def predict_acc_z(
        self, thrust_norm: float, cos_tilt: float, vel_z_ned: float = 0.0
    ) -> float:
        """Vertical acceleration [m/s^2, NED, down positive] the model predicts."""
        c = self.config
        return c.g - c.g * thrust_norm * cos_tilt / self._h - c.drag_over_mass * vel_z_ned

    def update(
        self,
        now: float,
        acc_z_ned: float,
        thrust_norm: float,
        cos_tilt: float = 1.0,
        vel_z_ned: float = 0.0,
        airborne: bool = True,
    ) -> HoverThrustStatus:
        """Fuse one sample taken at `now` [s].

        acc_z_ned: measured vertical acceleration, NED (down positive) [m/s^2].
        thrust_norm: normalised collective thrust acting over the sample (0..1).
        cos_tilt: z_b . e3 of the attitude over the sample (1 = level).
        vel_z_ned: vertical velocity (for the drag term) [m/s].
        airborne: False holds the estimate (on the ground the thrust does not lift).
        """
        c = self.config
        dt = 0.0 if self._t_last is None else max(0.0, now - self._t_last)
        if self._t_last is None or now >= self._t_last:
            self._t_last = now
        # Random-walk prediction (variance grows even while holding, bounded).
        self._var = min(self._var + c.process_noise_std**2 * dt, 0.25)

        values = (acc_z_ned, thrust_norm, cos_tilt, vel_z_ned, now)
        reason = ""
        if not all(map(math.isfinite, values)):
            reason = "non-finite input"
        elif not airborne:
            reason = "not airborne"
        elif thrust_norm < c.min_thrust_norm:
            reason = "thrust too low"
        elif cos_tilt < math.cos(c.max_tilt_rad):
            reason = "tilt too large"
        elif abs(acc_z_ned) > c.max_vertical_acc:
            reason = "vertical acceleration too large"
        if reason:
            self._rejecting_since = None
            return self._status(now, math.nan, math.nan, math.nan, False, reason)

        u = thrust_norm * cos_tilt
        innov = acc_z_ned - self.predict_acc_z(thrust_norm, cos_tilt, vel_z_ned)
        # d(a_z)/dh of a_z = g - g u / h: + g u / h^2
        H = c.g * u / (self._h * self._h)
        S = max(H * H * self._var + self._acc_var, self._acc_var)
        ratio = innov * innov / (c.gate_sigma**2 * S)
        fused = ratio < 1.0
        residual = innov
        if fused:
            K = self._var * H / S
            self._h = min(max(self._h + K * innov, c.hover_thrust_min), c.hover_thrust_max)
            self._var = min(max((1.0 - K * H) * self._var, 1e-12), 0.25)
            residual = acc_z_ned - self.predict_acc_z(thrust_norm, cos_tilt, vel_z_ned)
            self._rejecting_since = None
        else:
            if self._rejecting_since is None:
                self._rejecting_since = now
            elif now - self._rejecting_since > c.recover_after_s:
                # Persistent rejection: the hover thrust changed or the filter is overconfident.
                self._var = min(self._var + 100.0 * c.process_noise_std**2 * max(dt, 1e-3), 0.25)
        self._adapt_noise(dt, residual, H)
        return self._status(
            now, innov, math.sqrt(S), ratio, fused, "" if fused else "innovation gate"
        )

    def _adapt_noise(self, dt: float, residual: float, H: float) -> None:
        c = self.config
        if c.noise_time_constant_s <= 0.0 or dt <= 0.0:
            return
        alpha = dt / (c.noise_time_constant_s + dt)
        self._residual_lpf += alpha * (residual - self._residual_lpf)
        r = residual - self._residual_lpf
        target = r * r + H * H * self._var
        var = (1.0 - alpha) * self._acc_var + alpha * target
        self._acc_var = min(max(var, c.acc_noise_min_std**2), c.acc_noise_max_std**2)

    def _status(
        self, now: float, innov: float, innov_std: float, ratio: float, fused: bool, reason: str
    ) -> HoverThrustStatus:
        return frozen_new(  # HoverThrustStatus(...) without the frozen __init__ (per sample)
            HoverThrustStatus,
            t_s=now,
            hover_thrust=self._h,
            hover_thrust_std=math.sqrt(self._var),
            innovation=innov,
            innovation_std=innov_std,
            test_ratio=ratio,
            fused=fused,
            reason=reason,
        )


@dataclass(frozen=True)
class DragConfig:
    """Tuning of `DragEstimator`.

    initial_drag_over_mass: prior D/m [1/s]; initial_std its 1-sigma.
    process_noise_std: random walk [1/s / sqrt(s)].
    acc_noise_std: horizontal acceleration measurement noise [m/s^2].
    min_speed: no update below this horizontal speed [m/s] (no information).
    gate_sigma: innovation gate [standard deviations].
    max_value: upper bound of the estimate [1/s].
    """

    initial_drag_over_mass: float = 0.0
    initial_std: float = 0.5
    process_noise_std: float = 0.005
    acc_noise_std: float = 1.0
    min_speed: float = 1.0
    gate_sigma: float = 4.0
    max_value: float = 5.0
    g: float = G0


def body_z_ned(q_wxyz: FloatArray) -> tuple[float, float, float]:
    """Body z axis in NED of a quaternion (w, x, y, z): `so3.quat_to_dcm(q_wxyz)[:, 2]` as
    floats by the same operations (normalised first; zero or non-finite -> (0, 0, 1)), for the
    drag estimator's input at the telemetry rate."""
    w, x, y, z = q_wxyz.tolist()
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if not (math.isfinite(n) and n > 0.0):
        return (0.0, 0.0, 1.0)
    w, x, y, z = w / n, x / n, y / n, z / n
    return (2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y))


def _floats(x: FloatArray | Sequence[float]) -> list[float]:
    """A vector as a list of Python floats (an array's `tolist`)."""
    return x.tolist() if isinstance(x, np.ndarray) else [float(c) for c in x]


class DragEstimator:
    """Scalar Kalman filter for the linear drag per unit mass `k = D / m` [1/s].

    Measurement per horizontal axis i: `y_i = a_i + g u (z_b)_i / h - d_i = -k v_i`, linear in
    `k`, with `d` the disturbance estimated elsewhere (wind: `DisturbanceObserver`). Mass enters
    through `k`: a vehicle 20 % lighter than told has a `k` 25 % above the configured D/m.
    """

    def __init__(self, config: DragConfig | None = None) -> None:
        self.config = config or DragConfig()
        self._k = self.config.initial_drag_over_mass
        self._var = self.config.initial_std**2
        self._t_last: float | None = None

    @property
    def drag_over_mass(self) -> float:
        """Current estimate of D/m [1/s]."""
        return self._k

    @property
    def std(self) -> float:
        """1-sigma of the estimate [1/s]."""
        return math.sqrt(self._var)

    def update(
        self,
        now: float,
        acc_ned: FloatArray | Sequence[float],
        vel_ned: FloatArray | Sequence[float],
        thrust_norm: float,
        z_b_ned: FloatArray | Sequence[float],
        hover_thrust: float,
        airborne: bool = True,
        disturbance_ne: tuple[float, float] = (0.0, 0.0),
    ) -> bool:
        """Fuse the horizontal balance at `now`; returns True if anything was fused.

        acc_ned, vel_ned: measured acceleration [m/s^2] and velocity [m/s], NED (3,).
        thrust_norm: normalised thrust acting; z_b_ned: body z axis in NED (3,);
        hover_thrust: current hover-thrust estimate (0..1).
        disturbance_ne: the force per mass [m/s^2, north, east] explained elsewhere
        (`DisturbanceObserver`'s estimate: wind on the drag), taken out of the balance first,
        so a steady wind is not read as drag: `y_i - d_i = -k v_i`.
        """
        c = self.config
        dt = 0.0 if self._t_last is None else max(0.0, now - self._t_last)
        self._t_last = now if self._t_last is None else max(now, self._t_last)
        self._var = min(self._var + c.process_noise_std**2 * dt, 4.0)
        # Python floats, not numpy scalars: the estimate is the controller's drag, which
        # enters every setpoint's arithmetic (a numpy scalar operation costs ~5x more; the
        # same IEEE results)
        af, vf, zf = _floats(acc_ned), _floats(vel_ned), _floats(z_b_ned)
        if not (airborne and all(map(math.isfinite, af)) and all(map(math.isfinite, vf))
                and all(map(math.isfinite, zf)) and math.isfinite(thrust_norm)
                and math.isfinite(hover_thrust) and hover_thrust > 0.0):
            return False
        if math.hypot(vf[0], vf[1]) < c.min_speed:
            return False
        fused_any = False
        R = c.acc_noise_std**2
        for i in (0, 1):
            y = af[i] + c.g * thrust_norm * zf[i] / hover_thrust - disturbance_ne[i]
            H = -vf[i]
            innov = y - H * self._k
            S = H * H * self._var + R
            if innov * innov > c.gate_sigma**2 * S:
                continue
            K = self._var * H / S
            self._k = float(min(max(self._k + K * innov, 0.0), c.max_value))
            self._var = float(max((1.0 - K * H) * self._var, 1e-12))
            fused_any = True
        return fused_any


__all__ = [
    "G0",
    "DragConfig",
    "DragEstimator",
    "HoverThrustConfig",
    "HoverThrustEstimator",
    "HoverThrustStatus",
    "body_z_ned",
]


@dataclass(frozen=True)
class DisturbanceConfig:
    """Tuning of `DisturbanceObserver`.

    bandwidth_rad_s: natural frequency of the observer's error dynamics [rad/s] (critically
        damped): the estimate of a step in the force settles (to 2 %) in about 6 / bandwidth
        seconds; higher follows gusts, lower passes less velocity noise.
    max_acc: bound of the estimate's magnitude [m/s^2].
    min_thrust_norm: no update below this commanded thrust (on the ground, idle).
    """

    bandwidth_rad_s: float = 1.5
    max_acc: float = 8.0
    min_thrust_norm: float = 0.05

    def __post_init__(self) -> None:
        for name in ("bandwidth_rad_s", "max_acc"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0.0):
                raise ValueError(f"{name} must be positive and finite, got {v}")


class DisturbanceObserver:
    """Horizontal force the model does not explain, as an acceleration d [m/s^2, NED x, y]:
    wind on the drag (D (v - w) instead of D v: d = D w / m), a drag coefficient off by dD
    (d = -dD v / m), a thrust axis offset. A velocity observer with a disturbance state
    (Luenberger, both poles at -bandwidth):

        v' = a_model + d,   a_model = -(u g / h) z_b,h - (D / m) v_h
        v_hat' = a_model + d_hat + 2 w (v - v_hat),   d_hat' = w^2 (v - v_hat)

    with the commanded normalised thrust u (paired with the sample as the hover-thrust
    estimator pairs it), the measured attitude (body z axis z_b), the hover thrust h in use and
    the configured drag D / m. It integrates the velocity rather than differencing it, so the
    velocity noise reaches the estimate filtered twice. The vertical axis is the hover-thrust
    estimator's. Pure: every call takes the sample time.
    """

    def __init__(self, config: DisturbanceConfig | None = None) -> None:
        self.config = config or DisturbanceConfig()
        self._v: tuple[float, float] | None = None  # v_hat [m/s]
        self._d = (0.0, 0.0)
        self._t: float | None = None

    @property
    def acc_ne(self) -> tuple[float, float]:
        """The estimate d [m/s^2] (north, east)."""
        return self._d

    def reset(self) -> None:
        """Forget the estimate."""
        self._v, self._d, self._t = None, (0.0, 0.0), None

    def update(self, t_s: float, vel_ne: tuple[float, float], a_model_ne: tuple[float, float],
               u: float, airborne: bool) -> tuple[float, float]:
        """Fuse one velocity sample `vel_ne` [m/s] taken at `t_s` [s], with the model's
        acceleration `a_model_ne` [m/s^2] over the interval since the last one. On the ground
        (or below min_thrust_norm) the observer follows the velocity and holds its estimate."""
        c = self.config
        t_last, self._t = self._t, t_s
        learn = (airborne and u >= c.min_thrust_norm and self._v is not None
                 and t_last is not None and all(map(math.isfinite, (*vel_ne, *a_model_ne))))
        if not learn and not all(map(math.isfinite, vel_ne)):
            self._v = None
            return self._d
        # the step written once with the generated C's (companion.control.observer)
        v, self._d = disturbance_step(
            FLOAT, self._v if self._v is not None else vel_ne, self._d, vel_ne, a_model_ne,
            t_s - t_last if t_last is not None else 0.0, c.bandwidth_rad_s, c.max_acc, learn)
        self._v = v
        return self._d


class HoverWindEstimator:
    """The steady horizontal force per mass [m/s^2, north, east] on a multirotor that holds
    still under someone else's control (PX4 in Hold or Position mode, before the companion
    flies): at rest the thrust cancels gravity and it, so d = (T/m) z_b,h with T/m = g / z_b,z,
    i.e. d_h = g z_b,h / z_b,z from the attitude alone (z_b: body z axis in NED; no thrust
    command or drag model needed). Samples count while airborne with |v| below `still_m_s`;
    low-passed with `tau_s`. Pure: every call takes the sample time."""

    def __init__(self, still_m_s: float = 0.3, tau_s: float = 3.0, g: float = G0) -> None:
        self.still_m_s = still_m_s
        self.tau_s = tau_s
        self.g = g
        self._d: tuple[float, float] | None = None
        self._t: float | None = None
        self.held_s = 0.0  # time [s] of still samples fused

    @property
    def acc_ne(self) -> tuple[float, float] | None:
        """The estimate (None before any still sample)."""
        return self._d

    def update(self, t_s: float, vel_ned: tuple[float, float, float],
               q_wxyz: tuple[float, float, float, float], airborne: bool) -> None:
        """Fuse one sample (position/velocity and attitude of about the same time)."""
        t_last, self._t = self._t, t_s
        if not airborne or math.hypot(*vel_ned) > self.still_m_s:
            return
        w, x, y, z = q_wxyz
        zx, zy = 2.0 * (x * z + w * y), 2.0 * (y * z - w * x)
        zz = 1.0 - 2.0 * (x * x + y * y)
        if not zz > 0.5:  # tilted beyond 60 deg: not holding still
            return
        dn, de = self.g * zx / zz, self.g * zy / zz
        if not (math.isfinite(dn) and math.isfinite(de)):
            return
        dt = 0.0 if t_last is None else min(max(t_s - t_last, 0.0), 1.0)
        if self._d is None:
            self._d = (dn, de)
        else:
            a = min(dt / self.tau_s, 1.0)
            self._d = (self._d[0] + a * (dn - self._d[0]), self._d[1] + a * (de - self._d[1]))
        self.held_s += dt
