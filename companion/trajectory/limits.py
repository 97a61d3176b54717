"""Feasibility limits of a trajectory and their check (pure numpy).

Multirotor quantities follow docs/theory/multirotor.md: NED world frame, thrust vector
``t = m (g e3 - a) - D v`` (N), collective thrust ``T = |t|``, tilt = angle between the body
z axis ``z_b = t / T`` and straight down ``e3``. Body rates come from the flatness module.
Rover quantities follow the unicycle relations: speed ``V = |v|``, yaw rate
``(x' y'' - y' x'') / V^2``, lateral acceleration ``|x' y'' - y' x''| / V``.
"""

from __future__ import annotations

import math
from collections.abc import Collection
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import NDArray

from companion.trajectory.bezier import PiecewiseBezier, monomial_matrix
from companion.trajectory.rover_extrema import ROVER_MIN_SPEED_M_S, rover_extrema

#: A rover path's curvature is checked where the path moves faster than this [m/s]: at a stop
#: the polynomial's direction may turn freely, and a car-like rover crawls through its turns.
ROVER_CURVATURE_MIN_SPEED_M_S = 0.3

FloatArray = NDArray[np.float64]

__all__ = ["LimitReport", "Limits", "RoverLimits", "check"]

#: Samples per segment used by :func:`check` before local refinement around the worst sample.
SAMPLES_PER_SEGMENT = 48

#: The rover quantities :func:`rover_extrema` gives exactly (critical points).
_ROVER_EXACT = frozenset(("speed", "yaw_rate", "lat_acc"))


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
    max_acc_axes_m_s2: tuple[float, float, float] | None = None
    """Per-axis acceleration limits (horizontal, up, down) [m/s^2] on top of the norm limit
    ``max_acc_m_s2`` (NED: up is -z), e.g. PX4's MPC_ACC_HOR_MAX, MPC_ACC_UP_MAX,
    MPC_ACC_DOWN_MAX; None: the norm limit only."""

    max_vel_axes_m_s: tuple[float, float, float] | None = None
    """Per-axis speed limits (horizontal, climb, descent) [m/s] on top of ``max_speed_m_s``
    (NED: climbing is -z), e.g. PX4's MPC_XY_VEL_MAX, MPC_Z_VEL_MAX_UP, MPC_Z_VEL_MAX_DN."""

    def __post_init__(self) -> None:
        for name in ("max_acc_axes_m_s2", "max_vel_axes_m_s"):
            value = getattr(self, name)
            if value is None:
                continue
            axes = tuple(float(v) for v in value)
            if len(axes) != 3 or not all(math.isfinite(v) and v > 0.0 for v in axes):
                raise ValueError(
                    f"{name} must be three positive values (horizontal, up, down), got {value!r}"
                )
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
    """Rover limits: speed (m/s), yaw rate (rad/s), lateral acceleration (m/s^2); optional: the
    norm of the acceleration (m/s^2, covers speeding up and braking: PX4's RO_ACCEL_LIM /
    RO_DECEL_LIM) and, for a car-like (Ackermann) rover, the path curvature (1/m: tan(largest
    steering angle) / wheel base). Curvature is geometric: slowing down does not reduce it, so
    the time allocation cannot meet it; ``check`` reports it (``curvature``)."""

    max_speed_m_s: float
    max_yaw_rate_rad_s: float
    max_lat_acc_m_s2: float
    max_acc_m_s2: float | None = None
    max_curvature_1_m: float | None = None

    def __post_init__(self) -> None:
        _positive("max_speed_m_s", self.max_speed_m_s, optional=False)
        _positive("max_yaw_rate_rad_s", self.max_yaw_rate_rad_s, optional=False)
        _positive("max_lat_acc_m_s2", self.max_lat_acc_m_s2, optional=False)
        _positive("max_acc_m_s2", self.max_acc_m_s2, optional=True)
        _positive("max_curvature_1_m", self.max_curvature_1_m, optional=True)


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
    limits: Limits | RoverLimits, geometric: bool = False
) -> list[tuple[str, float, str]]:
    """(name, limit value, kind) of each active limit; a rover's curvature (which no time
    allocation changes) only with ``geometric``."""
    out: list[tuple[str, float, str]] = []
    if isinstance(limits, RoverLimits):
        out.append(("speed", limits.max_speed_m_s, "max"))
        out.append(("yaw_rate", limits.max_yaw_rate_rad_s, "max"))
        out.append(("lat_acc", limits.max_lat_acc_m_s2, "max"))
        if limits.max_acc_m_s2 is not None:
            out.append(("acc", limits.max_acc_m_s2, "max"))
        if geometric and limits.max_curvature_1_m is not None:
            out.append(("curvature", limits.max_curvature_1_m, "max"))
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


def validate_limits(traj: PiecewiseBezier, limits: Limits | RoverLimits, params: Any) -> None:
    """Check that `limits` apply to `traj` (RoverLimits: 2-D; tilt, thrust and body-rate
    limits: 3-D with ``params``); ValueError (TypeError for a wrong limits type) if not."""
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
    """Thrust vector t = m (g e3 - a) - D v (N), NED, shape (N, 3), read-only (the last one is
    reused for the same arrays: the limit metrics and the body-rate bound of one set of
    samples both need it)."""
    last = _TV_LAST[0]
    if last is not None and last[0] is vel and last[1] is acc and last[2] is params:
        return last[3]
    m = float(params.mass)
    g = float(params.g)
    drag = float(getattr(params, "drag", 0.0))
    tv = -m * acc - drag * vel
    tv[:, 2] += m * g
    tv.setflags(write=False)
    _TV_LAST[0] = (vel, acc, params, tv)
    return tv


_TV_LAST: list[tuple[FloatArray, FloatArray, Any, FloatArray] | None] = [None]


@dataclass(frozen=True)
class Samples:
    """Flat-output derivatives sampled at some times (NED, SI; yaw in rad)."""

    vel: FloatArray
    acc: FloatArray
    jerk: FloatArray | None
    snap: FloatArray | None
    yaw: FloatArray
    yaw_rate: FloatArray
    yaw_acc: FloatArray

    def time_scaled(self, alpha: float) -> Samples:
        """The samples of the same trajectory slowed down by ``alpha`` (t -> alpha t)."""
        return Samples(
            vel=self.vel / alpha,
            acc=self.acc / alpha**2,
            jerk=None if self.jerk is None else self.jerk / alpha**3,
            snap=None if self.snap is None else self.snap / alpha**4,
            yaw=self.yaw,
            yaw_rate=self.yaw_rate / alpha,
            yaw_acc=self.yaw_acc / alpha**2,
        )


def _sample(traj: PiecewiseBezier, t: FloatArray, names: list[str]) -> Samples:
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
    return Samples(vel, acc, jerk, snap, yaw, yaw_rate, yaw_acc)


def _norm(v: FloatArray) -> FloatArray:
    """Row norms of an (N, d) array."""
    return np.asarray(np.sqrt(np.einsum("ij,ij->i", v, v)), dtype=np.float64)


def _metrics(smp: Samples, names: list[str], params: Any) -> dict[str, FloatArray]:
    """Values of each named quantity at the sampled times."""
    out: dict[str, FloatArray] = {}
    vel, acc = smp.vel, smp.acc
    if "speed" in names:
        out["speed"] = _norm(vel)
    if "acc" in names:
        out["acc"] = _norm(acc)
    if "jerk" in names and smp.jerk is not None:
        out["jerk"] = _norm(smp.jerk)
    if "yaw_rate" in names or "lat_acc" in names or "curvature" in names:
        speed = _norm(vel)
        cross = vel[:, 0] * acc[:, 1] - vel[:, 1] * acc[:, 0]
        ok = speed > ROVER_MIN_SPEED_M_S
        safe_v = np.where(ok, speed, 1.0)
        out["yaw_rate"] = np.where(ok, np.abs(cross) / (safe_v * safe_v), 0.0)
        out["lat_acc"] = np.where(ok, np.abs(cross) / safe_v, 0.0)
        # curvature |v x a| / V^3 where the rover moves (ROVER_CURVATURE_MIN_SPEED_M_S): at a
        # stop the path's direction may turn freely in the polynomial, not in the rover
        moving = speed > ROVER_CURVATURE_MIN_SPEED_M_S
        safe_m = np.where(moving, speed, 1.0)
        out["curvature"] = np.where(moving, np.abs(cross) / safe_m**3, 0.0)
    if any(n in names for n in ("tilt", "max_thrust", "min_thrust")):
        tv = _thrust_vectors(vel, acc, params)
        thrust = _norm(tv)
        cos_tilt = np.where(thrust > 0.0, tv[:, 2] / np.where(thrust > 0.0, thrust, 1.0), -1.0)
        out["tilt"] = np.arccos(np.clip(cos_tilt, -1.0, 1.0))
        out["max_thrust"] = thrust
        out["min_thrust"] = thrust
    if "body_rate" in names:
        out["body_rate"] = _body_rate_norm(smp, params)
    return out


def _body_rate_norm(smp: Samples, params: Any) -> FloatArray:
    """|omega_frd| (rad/s) from the flatness module (imported lazily: importing
    companion.flatness loads CasADi, which trajectory work without body-rate limits does not
    need)."""
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


#: Largest matrix product (multiply-adds) handed to BLAS in one call: OpenBLAS goes
#: multi-threaded above about 2^18, which on these thin products is slower and burns a second
#: core (other jobs share the machine).
_BLAS_CHUNK = 1 << 18


def thin_matmul(a: FloatArray, b: FloatArray) -> FloatArray:
    """``a @ b`` for a short ``a`` (r, k) and a wide ``b`` (k, n), in column chunks small enough
    to keep BLAS single-threaded."""
    r, k = a.shape
    n = b.shape[1]
    step = max(1, _BLAS_CHUNK // max(r * k, 1))
    if n <= step:
        return np.asarray(a @ b, dtype=np.float64)
    out = np.empty((r, n))
    for i in range(0, n, step):
        np.matmul(a, b[:, i : i + step], out=out[:, i : i + step])
    return out


@lru_cache(maxsize=64)
def _grid_matrix(degree: int, per_segment: int, order: int) -> FloatArray:
    """(per_segment, degree + 1) matrix mapping a segment's control points to its ``order``-th
    derivative with respect to normalised time at ``linspace(0, 1, per_segment)``."""
    tau = np.linspace(0.0, 1.0, per_segment)
    if order > degree:
        out = np.zeros((per_segment, degree + 1))
    else:
        k = np.arange(order, degree + 1)
        fall = np.array([math.factorial(int(i)) / math.factorial(int(i) - order) for i in k])
        V = tau[:, None] ** (k - order)[None, :].astype(np.float64) * fall[None, :]
        out = V @ monomial_matrix(degree)[order:, :]
    out.setflags(write=False)
    return out


def _grid_derivatives(
    traj: PiecewiseBezier, per_segment: int, orders: tuple[int, ...]
) -> list[FloatArray]:
    """Derivatives of the given orders at ``per_segment`` evenly spaced times of every segment
    (both ends included, each end from its own segment), shape (M * per_segment, d) each, in
    the order of :func:`_sample_times`. One stacked matrix product per order, straight into
    the segment-major layout (no transposed copy of the samples)."""
    cp = traj.control_points
    m, n1, d = cp.shape
    inv_h = 1.0 / traj.durations
    out = []
    for r in orders:
        v = np.matmul(_grid_matrix(n1 - 1, per_segment, r), cp)  # (M, per_segment, d)
        if r:
            v *= (inv_h**r)[:, None, None]
        out.append(v.reshape(m * per_segment, d))
    return out


def segment_samples(
    traj: PiecewiseBezier, limits: Limits | RoverLimits, per_segment: int = SAMPLES_PER_SEGMENT
) -> Samples:
    """Samples (``per_segment`` per segment, ends included) for :func:`segment_worst`.

    Evaluated segment by segment on a fixed normalised-time grid (one matrix product), so a
    segment's end sample comes from that segment itself."""
    names = [n for n, _, _ in _limit_table(limits)]
    need_jerk = "jerk" in names or "body_rate" in names
    need_snap = "body_rate" in names
    orders = (1, 2, 3, 4) if need_snap else (1, 2, 3) if need_jerk else (1, 2)
    ders = _grid_derivatives(traj, per_segment, orders)
    n = traj.num_segments * per_segment
    ytraj = traj.yaw
    ycp = None if ytraj is None else ytraj.control_points
    if ytraj is None or ycp is None or not ycp.size or bool(np.all(ycp == ycp.flat[0])):
        # no yaw channel, or a constant one (e.g. one heading for the whole plan)
        z = np.zeros(n)
        yaw = z if ycp is None or not ycp.size else np.full(n, float(ycp.flat[0]))
        yaw_rate, yaw_acc = z, z
    else:
        yaw, yaw_rate, yaw_acc = (
            y[:, 0] for y in _grid_derivatives(ytraj, per_segment, (0, 1, 2))
        )
    return Samples(
        ders[0],
        ders[1],
        ders[2] if need_jerk else None,
        ders[3] if need_snap else None,
        yaw,
        yaw_rate,
        yaw_acc,
    )


def body_rate_bound(smp: Samples, params: Any) -> FloatArray:
    """Cheap upper bound of ``|omega_frd|`` (rad/s) per sample, without the attitude.

    With the thrust vector t (norm T, axis z_b = t / T) and its derivative t', the flatness
    map gives ``p^2 + q^2 = |t' - (t' . z_b) z_b|^2 / T^2`` exactly and the yaw rate
    ``r = (yaw' x_c . x_b + q y_c . z_b) / (y_c . y_b)`` with ``|y_c . y_b| = |y_c x z_b| >=
    |z_b,3|`` and ``|y_c . z_b| <= |z_b,horizontal|``, hence
    ``|r| <= (|yaw'| + |(p, q)| |z_b,horizontal|) / |z_b,3|``. Infinite where z_b is (nearly)
    horizontal or the thrust is (nearly) zero; multiplied by 1 + 1e-9 against round-off."""
    assert smp.jerk is not None
    tv = _thrust_vectors(smp.vel, smp.acc, params)
    td = -float(params.mass) * smp.jerk - float(getattr(params, "drag", 0.0)) * smp.acc
    return _rate_bound(tv, td, smp.yaw_rate, params)


def _rate_bound(tv: FloatArray, td: FloatArray, yaw_rate: FloatArray, params: Any) -> FloatArray:
    """:func:`body_rate_bound` from the thrust vector tv, its derivative td (N, 3) and the
    yaw rate (N,)."""
    t2 = np.einsum("ij,ij->i", tv, tv)
    ok = t2 > 1e-12 * (float(params.mass) * float(params.g)) ** 2
    t2s = np.where(ok, t2, 1.0)
    tdt = np.einsum("ij,ij->i", td, tv)
    w2 = np.maximum(np.einsum("ij,ij->i", td, td) - tdt * tdt / t2s, 0.0) / t2s
    hor = np.sqrt((tv[:, 0] ** 2 + tv[:, 1] ** 2) / t2s)
    vert = np.abs(tv[:, 2]) / np.sqrt(t2s)
    ok &= vert > 1e-6
    r = (np.abs(yaw_rate) + np.sqrt(w2) * hor) / np.where(ok, vert, 1.0)
    bound = np.sqrt(w2 + r * r) * (1.0 + 1e-9)
    return np.asarray(np.where(ok, bound, np.inf), dtype=np.float64)


class TimeScaledRatio:
    """Largest value / allowed ratio over the samples of a trajectory slowed down uniformly by
    ``alpha`` (t -> alpha t), for the planner's common time scale search.

    ``ratio(alpha)`` equals ``max`` over samples and active limits of value / (margin * limit)
    (allowed / value for ``min_thrust``), the same quantity as :func:`segment_worst` on
    ``smp.time_scaled(alpha)`` with ``screen=margin``. Speed, acceleration and jerk scale
    exactly (alpha^-1, ^-2, ^-3) and are reduced once; tilt, thrust and the body-rate bound are
    recomputed from pre-scaled terms; the flatness map runs only where the bound exceeds the
    body-rate limit. Multirotor :class:`Limits` only.
    """

    def __init__(
        self,
        smp: Samples,
        limits: Limits,
        params: Any,
        margin: float,
        speed_scale: FloatArray | None = None,
    ) -> None:
        """``speed_scale`` (N,): per-sample speed cap as a fraction of ``max_speed_m_s``."""
        self.smp = smp
        self.limits = limits
        self.params = params
        self.margin = margin
        speed = _norm(smp.vel) if speed_scale is None else _norm(smp.vel) / speed_scale
        self.kin: list[tuple[int, float]] = [
            (1, float(np.max(speed)) / (limits.max_speed_m_s * margin)),
            (2, float(np.max(_norm(smp.acc))) / (limits.max_acc_m_s2 * margin)),
        ]
        if limits.max_jerk_m_s3 is not None:
            assert smp.jerk is not None
            self.kin.append((3, float(np.max(_norm(smp.jerk))) / (limits.max_jerk_m_s3 * margin)))
        if limits.max_acc_axes_m_s2 is not None:
            self.kin.append((2, float(np.max(axis_acc_ratio(smp.acc, limits))) / margin))
        if limits.max_vel_axes_m_s is not None:
            self.kin.append(
                (1, float(np.max(axis_ratio(smp.vel, limits.max_vel_axes_m_s))) / margin)
            )
        self.dynamic = limits.needs_params
        if self.dynamic:
            m = float(params.mass)
            drag = float(getattr(params, "drag", 0.0))
            self.t_acc = -m * smp.acc
            self.t_vel = -drag * smp.vel
            self.mg = m * float(params.g)
            if limits.max_body_rate_rad_s is not None:
                assert smp.jerk is not None
                self.td_jerk = -m * smp.jerk
                self.td_acc = -drag * smp.acc

    def __call__(self, alpha: float) -> float:
        lim = self.limits
        margin = self.margin
        worst = max(k / alpha**r for r, k in self.kin)
        if not self.dynamic:
            return worst
        tv = self.t_acc / alpha**2 + self.t_vel / alpha
        tv[:, 2] += self.mg
        t2 = np.einsum("ij,ij->i", tv, tv)
        if lim.max_thrust_n is not None:
            worst = max(worst, math.sqrt(float(np.max(t2))) / (lim.max_thrust_n * margin))
        if lim.min_thrust_n is not None and lim.min_thrust_n > 0.0:
            t_min = math.sqrt(float(np.min(t2)))
            worst = max(worst, math.inf if t_min <= 0.0 else lim.min_thrust_n / margin / t_min)
        if lim.max_tilt_rad is not None:
            thrust = np.sqrt(t2)
            cos_t = np.where(thrust > 0.0, tv[:, 2] / np.where(thrust > 0.0, thrust, 1.0), -1.0)
            tilt = math.acos(min(max(float(np.min(cos_t)), -1.0), 1.0))
            worst = max(worst, tilt / (lim.max_tilt_rad * margin))
        if lim.max_body_rate_rad_s is not None:
            smp = self.smp
            td = self.td_jerk / alpha**3 + self.td_acc / alpha**2
            cap = lim.max_body_rate_rad_s * margin
            bound = _rate_bound(tv, td, smp.yaw_rate / alpha, self.params)
            idx = np.flatnonzero(bound > cap)
            rate = float(np.max(bound))
            if idx.shape[0]:
                rate = float(np.max(bound[bound <= cap], initial=0.0))
                sub = smp.time_scaled(alpha)
                assert sub.jerk is not None and sub.snap is not None
                exact = _body_rate_norm(
                    Samples(
                        sub.vel[idx],
                        sub.acc[idx],
                        sub.jerk[idx],
                        sub.snap[idx],
                        sub.yaw[idx],
                        sub.yaw_rate[idx],
                        sub.yaw_acc[idx],
                    ),
                    self.params,
                )
                rate = max(rate, float(np.max(exact)))
            worst = max(worst, rate / cap)
        return worst


def axis_ratio(vec: FloatArray, axes: tuple[float, float, float]) -> FloatArray:
    """Per-sample ratio (N,) of vectors (N, 3) NED to per-axis limits (horizontal norm, up
    (-z), down (+z))."""
    hor = np.sqrt(vec[:, 0] ** 2 + vec[:, 1] ** 2) / axes[0]
    ver = np.where(vec[:, 2] < 0.0, -vec[:, 2] / axes[1], vec[:, 2] / axes[2])
    return np.asarray(np.maximum(hor, ver), dtype=np.float64)


def axis_acc_ratio(acc: FloatArray, limits: Limits) -> FloatArray:
    """Per-sample ratio (N,) of the acceleration (N, 3) NED to the per-axis limits
    ``limits.max_acc_axes_m_s2`` (horizontal, up, down); zeros without them."""
    if limits.max_acc_axes_m_s2 is None or acc.shape[1] != 3:
        return np.zeros(acc.shape[0])
    return axis_ratio(acc, limits.max_acc_axes_m_s2)


def _screened_body_rate(smp: Samples, params: Any, threshold: float) -> FloatArray:
    """``|omega_frd|`` where its cheap bound exceeds ``threshold``, else the bound (<= the
    threshold): the flatness map runs only on the samples that could matter."""
    bound = body_rate_bound(smp, params)
    idx = np.flatnonzero(bound > threshold)
    if idx.shape[0] == 0:
        return bound
    assert smp.jerk is not None and smp.snap is not None
    sub = Samples(
        smp.vel[idx],
        smp.acc[idx],
        smp.jerk[idx],
        smp.snap[idx],
        smp.yaw[idx],
        smp.yaw_rate[idx],
        smp.yaw_acc[idx],
    )
    out = bound.copy()
    out[idx] = _body_rate_norm(sub, params)
    return out


def segment_worst(
    smp: Samples,
    num_segments: int,
    limits: Limits | RoverLimits,
    params: Any = None,
    screen: float | None = None,
) -> dict[str, FloatArray]:
    """Per-segment worst sampled value (M,) of every active limit (used by the planner).

    ``screen`` (e.g. the planner's margin 0.995): the body rate is computed through the
    flatness map only at samples whose cheap upper bound (:func:`body_rate_bound`) exceeds
    ``screen * max_body_rate_rad_s``; elsewhere the bound stands in. A segment's value is then
    exact whenever it exceeds ``screen * limit`` and otherwise an upper bound that does not."""
    table = _limit_table(limits)
    names = [n for n, _, _ in table]
    body = (
        screen is not None
        and "body_rate" in names
        and isinstance(limits, Limits)
        and limits.max_body_rate_rad_s is not None
    )
    vals = _metrics(smp, [n for n in names if n != "body_rate"] if body else names, params)
    if body:
        assert isinstance(limits, Limits) and limits.max_body_rate_rad_s is not None
        assert screen is not None
        vals["body_rate"] = _screened_body_rate(smp, params, screen * limits.max_body_rate_rad_s)
    out: dict[str, FloatArray] = {}
    for name, _, kind in table:
        v = vals[name].reshape(num_segments, -1)
        out[name] = v.min(axis=1) if kind == "min" else v.max(axis=1)
    return out


def check(
    traj: PiecewiseBezier, limits: Limits | RoverLimits, params: Any = None,
    only: Collection[str] | None = None,
) -> dict[str, LimitReport]:
    """Check every active limit of ``limits`` on ``traj``.

    For speed, acceleration and jerk the convex hull of the derivative control points gives an
    upper bound (``bound``); all values are then confirmed by dense sampling
    (``SAMPLES_PER_SEGMENT`` per segment) refined around the worst sample. ``params`` is a
    ``MultirotorParams`` (needed for tilt, thrust and body-rate limits). Returns
    ``{name: LimitReport}`` with names among speed, acc, jerk, tilt, max_thrust, min_thrust,
    body_rate (multirotor) or speed, yaw_rate, lat_acc (rover). Body rates use the trajectory's
    yaw channel (yaw 0 when it has none). Rover yaw rate and lateral acceleration are not
    evaluated below ``ROVER_MIN_SPEED_M_S`` (singular at rest); rover maxima also include
    :func:`rover_extrema` (critical points), which sees peaks narrower than the grid.
    ``only``: check just these of the active limits (each report is the same as in a full
    check; a rover's critical points are computed only when one of theirs is asked for).
    """
    validate_limits(traj, limits, params)
    table = [row for row in _limit_table(limits, geometric=True)
             if only is None or row[0] in only]
    names = [n for n, _, _ in table]
    t, seg = _sample_times(traj, SAMPLES_PER_SEGMENT)
    vals = _metrics(_sample(traj, t, names), names, params)
    hull_order = {"speed": 1, "acc": 2, "jerk": 3}
    exact = (rover_extrema(traj) if isinstance(limits, RoverLimits)
             and not _ROVER_EXACT.isdisjoint(names) else None)
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
        if exact is not None and name in exact:
            # rover: maxima at the critical points catch peaks narrower than the grid
            ke = int(np.argmax(exact[name][0]))
            if float(exact[name][0][ke]) > worst:
                worst = float(exact[name][0][ke])
                k = ke
                t_worst = float(traj.breaks[ke] + exact[name][1][ke] * traj.durations[ke])
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
