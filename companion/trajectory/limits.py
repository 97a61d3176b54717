"""Feasibility limits of a trajectory and their check (pure numpy).

Multirotor quantities follow MATH.md: NED world frame, thrust vector
``t = m (g e3 - a) - D v`` (N), collective thrust ``T = |t|``, tilt = angle between the body
z axis ``z_b = t / T`` and straight down ``e3``. Body rates come from the flatness module.
Rover quantities follow the unicycle relations: speed ``V = |v|``, yaw rate
``(x' y'' - y' x'') / V^2``, lateral acceleration ``|x' y'' - y' x''| / V``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from companion.trajectory.bezier import PiecewiseBezier

FloatArray = NDArray[np.float64]

__all__ = ["LimitReport", "Limits", "RoverLimits", "check"]

#: Samples per segment used by :func:`check` before local refinement around the worst sample.
SAMPLES_PER_SEGMENT = 48
#: Below this speed (m/s) the rover yaw rate / lateral acceleration are not evaluated (singular).
ROVER_MIN_SPEED_M_S = 1e-3


def _positive(name: str, value: float | None, *, optional: bool) -> float | None:
    if value is None:
        if optional:
            return None
        raise ValueError(f"{name} is required")
    v = float(value)
    if not math.isfinite(v) or v <= 0.0:
        raise ValueError(f"{name} must be a finite positive number, got {value}")
    return v


@dataclass(frozen=True)
class Limits:
    """Multirotor (or generic point-mass) limits. SI units; None disables a limit.

    ``max_tilt_rad`` is the angle between the thrust axis and vertical; thrust limits are the
    collective thrust in newtons; ``max_body_rate_rad_s`` bounds the norm of ``omega_frd``.
    Tilt, thrust and body-rate limits need ``MultirotorParams`` when planning or checking.
    """

    max_speed_m_s: float
    max_acc_m_s2: float
    max_jerk_m_s3: float | None = None
    max_tilt_rad: float | None = None
    max_thrust_n: float | None = None
    min_thrust_n: float | None = None
    max_body_rate_rad_s: float | None = None

    def __post_init__(self) -> None:
        _positive("max_speed_m_s", self.max_speed_m_s, optional=False)
        _positive("max_acc_m_s2", self.max_acc_m_s2, optional=False)
        _positive("max_jerk_m_s3", self.max_jerk_m_s3, optional=True)
        _positive("max_tilt_rad", self.max_tilt_rad, optional=True)
        _positive("max_thrust_n", self.max_thrust_n, optional=True)
        _positive("max_body_rate_rad_s", self.max_body_rate_rad_s, optional=True)
        if self.max_tilt_rad is not None and self.max_tilt_rad >= math.pi / 2:
            raise ValueError(f"max_tilt_rad must be below pi/2 (90 deg), got {self.max_tilt_rad}")
        if self.min_thrust_n is not None:
            v = float(self.min_thrust_n)
            if not math.isfinite(v) or v < 0.0:
                raise ValueError(f"min_thrust_n must be finite and >= 0, got {self.min_thrust_n}")
            if self.max_thrust_n is not None and v >= self.max_thrust_n:
                raise ValueError(
                    f"min_thrust_n ({v}) must be below max_thrust_n ({self.max_thrust_n})"
                )

    @property
    def needs_params(self) -> bool:
        """True when a limit needs the vehicle parameters (mass, drag, inertia)."""
        return any(
            x is not None
            for x in (
                self.max_tilt_rad,
                self.max_thrust_n,
                self.min_thrust_n,
                self.max_body_rate_rad_s,
            )
        )


@dataclass(frozen=True)
class RoverLimits:
    """Rover (unicycle) limits: speed (m/s), yaw rate (rad/s), lateral acceleration (m/s^2)."""

    max_speed_m_s: float
    max_yaw_rate_rad_s: float
    max_lat_acc_m_s2: float

    def __post_init__(self) -> None:
        _positive("max_speed_m_s", self.max_speed_m_s, optional=False)
        _positive("max_yaw_rate_rad_s", self.max_yaw_rate_rad_s, optional=False)
        _positive("max_lat_acc_m_s2", self.max_lat_acc_m_s2, optional=False)


@dataclass(frozen=True)
class LimitReport:
    """Result of checking one limit.

    ``worst`` is the largest value found (the smallest for a ``min`` limit such as
    ``min_thrust``), at global time ``time_s`` in ``segment``; ``exceeded`` compares it with
    ``limit``. ``bound`` is a cheap convex-hull upper bound over the whole trajectory where one
    exists (speed, acc, jerk), else None.
    """

    name: str
    limit: float
    worst: float
    time_s: float
    segment: int
    exceeded: bool
    bound: float | None = None
    kind: str = "max"


# --------------------------------------------------------------------------- metrics
def _limit_table(
    limits: Limits | RoverLimits,
) -> list[tuple[str, float, str]]:
    """(name, limit value, kind) of each active limit."""
    out: list[tuple[str, float, str]] = []
    if isinstance(limits, RoverLimits):
        out.append(("speed", limits.max_speed_m_s, "max"))
        out.append(("yaw_rate", limits.max_yaw_rate_rad_s, "max"))
        out.append(("lat_acc", limits.max_lat_acc_m_s2, "max"))
        return out
    out.append(("speed", limits.max_speed_m_s, "max"))
    out.append(("acc", limits.max_acc_m_s2, "max"))
    if limits.max_jerk_m_s3 is not None:
        out.append(("jerk", limits.max_jerk_m_s3, "max"))
    if limits.max_tilt_rad is not None:
        out.append(("tilt", limits.max_tilt_rad, "max"))
    if limits.max_thrust_n is not None:
        out.append(("max_thrust", limits.max_thrust_n, "max"))
    if limits.min_thrust_n is not None:
        out.append(("min_thrust", limits.min_thrust_n, "min"))
    if limits.max_body_rate_rad_s is not None:
        out.append(("body_rate", limits.max_body_rate_rad_s, "max"))
    return out


def _validate(traj: PiecewiseBezier, limits: Limits | RoverLimits, params: Any) -> None:
    if isinstance(limits, RoverLimits):
        if traj.dim != 2:
            raise ValueError(f"RoverLimits apply to 2-D trajectories, this one is {traj.dim}-D")
        return
    if not isinstance(limits, Limits):
        raise TypeError("limits must be Limits or RoverLimits")
    if limits.needs_params:
        if params is None:
            raise ValueError(
                "tilt, thrust and body-rate limits need the vehicle parameters "
                "(params=MultirotorParams(...))"
            )
        if traj.dim != 3:
            raise ValueError("tilt, thrust and body-rate limits apply to 3-D trajectories")


def _thrust_vectors(vel: FloatArray, acc: FloatArray, params: Any) -> FloatArray:
    """Thrust vector t = m (g e3 - a) - D v (N), NED, shape (N, 3)."""
    m = float(params.mass)
    g = float(params.g)
    drag = float(getattr(params, "drag", 0.0))
    tv = -m * acc - drag * vel
    tv[:, 2] += m * g
    return tv


@dataclass(frozen=True)
class _Samples:
    """Flat-output derivatives sampled at some times (NED, SI; yaw in rad)."""

    vel: FloatArray
    acc: FloatArray
    jerk: FloatArray | None
    snap: FloatArray | None
    yaw: FloatArray
    yaw_rate: FloatArray
    yaw_acc: FloatArray

    def time_scaled(self, alpha: float) -> _Samples:
        """The samples of the same trajectory slowed down by ``alpha`` (t -> alpha t)."""
        return _Samples(
            vel=self.vel / alpha,
            acc=self.acc / alpha**2,
            jerk=None if self.jerk is None else self.jerk / alpha**3,
            snap=None if self.snap is None else self.snap / alpha**4,
            yaw=self.yaw,
            yaw_rate=self.yaw_rate / alpha,
            yaw_acc=self.yaw_acc / alpha**2,
        )


def _sample(traj: PiecewiseBezier, t: FloatArray, names: list[str]) -> _Samples:
    vel = traj.evaluate(t, 1)
    acc = traj.evaluate(t, 2)
    need_jerk = "jerk" in names or "body_rate" in names
    jerk = traj.evaluate(t, 3) if need_jerk else None
    snap = traj.evaluate(t, 4) if "body_rate" in names else None
    if traj.yaw is None:
        z = np.zeros(t.shape[0])
        yaw, yaw_rate, yaw_acc = z, z, z
    else:
        yaw = traj.yaw.evaluate(t, 0)[:, 0]
        yaw_rate = traj.yaw.evaluate(t, 1)[:, 0]
        yaw_acc = traj.yaw.evaluate(t, 2)[:, 0]
    return _Samples(vel, acc, jerk, snap, yaw, yaw_rate, yaw_acc)


def _metrics(smp: _Samples, names: list[str], params: Any) -> dict[str, FloatArray]:
    """Values of each named quantity at the sampled times."""
    out: dict[str, FloatArray] = {}
    vel, acc = smp.vel, smp.acc
    if "speed" in names:
        out["speed"] = np.linalg.norm(vel, axis=1)
    if "acc" in names:
        out["acc"] = np.linalg.norm(acc, axis=1)
    if "jerk" in names and smp.jerk is not None:
        out["jerk"] = np.linalg.norm(smp.jerk, axis=1)
    if "yaw_rate" in names or "lat_acc" in names:
        speed = np.linalg.norm(vel, axis=1)
        cross = vel[:, 0] * acc[:, 1] - vel[:, 1] * acc[:, 0]
        ok = speed > ROVER_MIN_SPEED_M_S
        safe_v = np.where(ok, speed, 1.0)
        out["yaw_rate"] = np.where(ok, np.abs(cross) / (safe_v * safe_v), 0.0)
        out["lat_acc"] = np.where(ok, np.abs(cross) / safe_v, 0.0)
    if any(n in names for n in ("tilt", "max_thrust", "min_thrust")):
        tv = _thrust_vectors(vel, acc, params)
        thrust = np.linalg.norm(tv, axis=1)
        cos_tilt = np.where(thrust > 0.0, tv[:, 2] / np.where(thrust > 0.0, thrust, 1.0), -1.0)
        out["tilt"] = np.arccos(np.clip(cos_tilt, -1.0, 1.0))
        out["max_thrust"] = thrust
        out["min_thrust"] = thrust
    if "body_rate" in names:
        out["body_rate"] = _body_rate_norm(smp, params)
    return out


def _body_rate_norm(smp: _Samples, params: Any) -> FloatArray:
    """|omega_frd| (rad/s) from the flatness module (imported lazily: flatness sits above
    trajectory in the layering)."""
    from companion.flatness import multirotor_setpoint

    assert smp.jerk is not None and smp.snap is not None
    sp = multirotor_setpoint(
        smp.vel, smp.acc, smp.jerk, smp.snap, smp.yaw, smp.yaw_rate, smp.yaw_acc, params
    )
    omega = np.asarray(sp.omega_frd, dtype=np.float64).reshape(-1, 3)
    return np.asarray(np.linalg.norm(omega, axis=1), dtype=np.float64)


def _sample_times(traj: PiecewiseBezier, per_segment: int) -> tuple[FloatArray, FloatArray]:
    """Sample times (global, s) and their segment index; includes both ends of each segment."""
    s = np.linspace(0.0, 1.0, per_segment)
    t = traj.breaks[:-1, None] + traj.durations[:, None] * s[None, :]
    seg = np.repeat(np.arange(traj.num_segments), per_segment).astype(np.float64)
    return t.reshape(-1), seg


def segment_samples(
    traj: PiecewiseBezier, limits: Limits | RoverLimits, per_segment: int = SAMPLES_PER_SEGMENT
) -> _Samples:
    """Samples (``per_segment`` per segment, ends included) for :func:`segment_worst`."""
    names = [n for n, _, _ in _limit_table(limits)]
    t, _ = _sample_times(traj, per_segment)
    return _sample(traj, t, names)


def segment_worst(
    smp: _Samples,
    num_segments: int,
    limits: Limits | RoverLimits,
    params: Any = None,
) -> dict[str, FloatArray]:
    """Per-segment worst sampled value (M,) of every active limit (used by the planner)."""
    table = _limit_table(limits)
    names = [n for n, _, _ in table]
    vals = _metrics(smp, names, params)
    out: dict[str, FloatArray] = {}
    for name, _, kind in table:
        v = vals[name].reshape(num_segments, -1)
        out[name] = v.min(axis=1) if kind == "min" else v.max(axis=1)
    return out


def check(
    traj: PiecewiseBezier, limits: Limits | RoverLimits, params: Any = None
) -> dict[str, LimitReport]:
    """Check every active limit of ``limits`` on ``traj``.

    For speed, acceleration and jerk the convex hull of the derivative control points gives an
    upper bound (``bound``); all values are then confirmed by dense sampling
    (``SAMPLES_PER_SEGMENT`` per segment) refined around the worst sample. ``params`` is a
    ``MultirotorParams`` (needed for tilt, thrust and body-rate limits). Returns
    ``{name: LimitReport}`` with names among speed, acc, jerk, tilt, max_thrust, min_thrust,
    body_rate (multirotor) or speed, yaw_rate, lat_acc (rover). Body rates use the trajectory's
    yaw channel (yaw 0 when it has none). Rover yaw rate and lateral acceleration are not
    evaluated below ``ROVER_MIN_SPEED_M_S`` (singular at rest).
    """
    _validate(traj, limits, params)
    table = _limit_table(limits)
    names = [n for n, _, _ in table]
    t, seg = _sample_times(traj, SAMPLES_PER_SEGMENT)
    vals = _metrics(_sample(traj, t, names), names, params)
    hull_order = {"speed": 1, "acc": 2, "jerk": 3}
    reports: dict[str, LimitReport] = {}
    for name, limit, kind in table:
        v = vals[name]
        i = int(np.argmin(v) if kind == "min" else np.argmax(v))
        # refine around the worst sample with a fine grid over the two neighbouring intervals
        k = int(seg[i])
        h = float(traj.durations[k])
        dt = h / (SAMPLES_PER_SEGMENT - 1)
        lo = max(float(traj.breaks[k]), float(t[i]) - dt)
        hi = min(float(traj.breaks[k + 1]), float(t[i]) + dt)
        tf = np.linspace(lo, hi, 33)
        vf = _metrics(_sample(traj, tf, [name]), [name], params)[name]
        j = int(np.argmin(vf) if kind == "min" else np.argmax(vf))
        worst, t_worst = float(v[i]), float(t[i])
        if (kind == "min" and vf[j] < worst) or (kind == "max" and vf[j] > worst):
            worst, t_worst = float(vf[j]), float(tf[j])
        bound: float | None = None
        if name in hull_order:
            bound = float(np.max(traj.hull_bounds(hull_order[name])))
        exceeded = worst < limit if kind == "min" else worst > limit
        reports[name] = LimitReport(
            name=name,
            limit=float(limit),
            worst=worst,
            time_s=t_worst,
            segment=k,
            exceeded=bool(exceeded),
            bound=bound,
            kind=kind,
        )
    return reports
