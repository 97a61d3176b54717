"""The flatness formulas of the manual (docs/theory/), written once over an abstract scalar backend.

This module is the single source of truth of the math. The same function bodies are evaluated

* on CasADi ``SX`` symbols (:mod:`companion.flatness.symbolic` wraps them into ``casadi.Function``
  objects; the C generator emits C from those),
* on numpy arrays of shape ``(N,)`` (one array per vector component: the fast batched path),
* on Python floats (the fast single-sample path),

so the numeric and symbolic results can only differ by floating-point evaluation order.

Every branch is expressed with ``where`` (both sides are evaluated), so every division uses a
"safe" denominator that is replaced by 1 where the branch is not taken: nothing produces inf or
NaN, also in generated C.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

# A scalar of the backend: casadi.SX, numpy.ndarray of shape (N,), or float.
S = Any
Vec3 = tuple[S, S, S]

# ----------------------------------------------------------------------------- thresholds
#: Thrust below this fraction of the hover thrust ``m g`` is "low": attitude kept from the
#: thrust direction (or level if it has none), rate/acceleration feed-forward zeroed, flagged.
THRUST_MIN_FRAC = 1e-3
#: Thrust below this fraction of ``m g`` has no usable direction: ``z_b`` is set to down (level).
THRUST_DIR_FRAC = 1e-9
#: ``|cos(roll)| = |y_c x z_b|`` below this: heading singular (``z_b`` parallel to ``y_c``),
#: attitude from the yaw direction projected on the thrust plane, rates zeroed, flagged.
COS_ROLL_MIN = 1e-3
#: PX4 bodyzToAttitude: ``|z_b . e3|`` below this counts as horizontal thrust and ``x_b`` is
#: chosen pointing down.
HORIZONTAL_EPS = 1e-6
#: Rover speed (m/s) below this is "stopped": rates zeroed, flagged.
ROVER_SPEED_MIN = 1e-3
#: Rover speed (m/s) / acceleration (m/s^2) below this has no usable direction.
ROVER_DIR_EPS = 1e-9

#: Bits of the ``flags`` output.
FLAG_LOW_THRUST = 1
FLAG_HEADING_SINGULAR = 2
FLAG_INVERTED = 4


# ----------------------------------------------------------------------------- backends


class Backend:
    """Elementary functions of one scalar type. Subclasses: CasADi, numpy, float."""

    def where(self, c: S, a: S, b: S) -> S:
        raise NotImplementedError

    def sqrt(self, x: S) -> S:
        raise NotImplementedError

    def sin(self, x: S) -> S:
        raise NotImplementedError

    def cos(self, x: S) -> S:
        raise NotImplementedError

    def atan(self, x: S) -> S:
        raise NotImplementedError

    def atan2(self, y: S, x: S) -> S:
        raise NotImplementedError

    def fabs(self, x: S) -> S:
        raise NotImplementedError

    def fmax(self, a: S, b: S) -> S:
        raise NotImplementedError

    def fmin(self, a: S, b: S) -> S:
        raise NotImplementedError

    def lor(self, a: S, b: S) -> S:
        raise NotImplementedError

    def land(self, a: S, b: S) -> S:
        raise NotImplementedError

    def lnot(self, a: S) -> S:
        raise NotImplementedError

    def hypot(self, *xs: S) -> S:
        """sqrt of the sum of squares (floats: `math.hypot`, correctly rounded)."""
        raise NotImplementedError

    def lazy_where(self, c: S, a: Any, b: Any, n: int) -> tuple[S, ...]:
        """`where` on the n-tuples `a()` and `b()` (callables): on floats only the taken one
        is evaluated."""
        ta, tb = a(), b()
        return tuple(self.where(c, ta[i], tb[i]) for i in range(n))


class CasadiBackend(Backend):
    """CasADi ``SX`` symbols. casadi is imported when the backend is made (by the symbolic
    functions only): the numeric path, which flies, never loads it."""

    def __init__(self) -> None:
        import casadi

        self._ca = casadi

    def where(self, c: S, a: S, b: S) -> S:
        return self._ca.if_else(c, a, b)

    def sqrt(self, x: S) -> S:
        return self._ca.sqrt(x)

    def sin(self, x: S) -> S:
        return self._ca.sin(x)

    def cos(self, x: S) -> S:
        return self._ca.cos(x)

    def atan(self, x: S) -> S:
        return self._ca.atan(x)

    def atan2(self, y: S, x: S) -> S:
        return self._ca.atan2(y, x)

    def fabs(self, x: S) -> S:
        return self._ca.fabs(x)

    def fmax(self, a: S, b: S) -> S:
        return self._ca.fmax(a, b)

    def fmin(self, a: S, b: S) -> S:
        return self._ca.fmin(a, b)

    def lor(self, a: S, b: S) -> S:
        return self._ca.logic_or(a, b)

    def land(self, a: S, b: S) -> S:
        return self._ca.logic_and(a, b)

    def lnot(self, a: S) -> S:
        return self._ca.logic_not(a)

    def hypot(self, *xs: S) -> S:
        return self._ca.sqrt(sum((x * x for x in xs[1:]), xs[0] * xs[0]))


class NumpyBackend(Backend):
    def where(self, c: S, a: S, b: S) -> S:
        return np.where(c, a, b)

    def sqrt(self, x: S) -> S:
        return np.sqrt(x)

    def sin(self, x: S) -> S:
        return np.sin(x)

    def cos(self, x: S) -> S:
        return np.cos(x)

    def atan(self, x: S) -> S:
        return np.arctan(x)

    def atan2(self, y: S, x: S) -> S:
        return np.arctan2(y, x)

    def fabs(self, x: S) -> S:
        return np.abs(x)

    def fmax(self, a: S, b: S) -> S:
        return np.maximum(a, b)

    def fmin(self, a: S, b: S) -> S:
        return np.minimum(a, b)

    def lor(self, a: S, b: S) -> S:
        return np.logical_or(a, b)

    def land(self, a: S, b: S) -> S:
        return np.logical_and(a, b)

    def lnot(self, a: S) -> S:
        return np.logical_not(a)

    def hypot(self, *xs: S) -> S:
        return np.sqrt(sum((np.asarray(x) * x for x in xs[1:]), np.asarray(xs[0]) * xs[0]))


class FloatBackend(Backend):
    # The elementary functions are the math builtins themselves (no wrapper frame: this
    # backend runs once per setpoint).
    sqrt = staticmethod(math.sqrt)  # type: ignore[assignment]
    sin = staticmethod(math.sin)  # type: ignore[assignment]
    cos = staticmethod(math.cos)  # type: ignore[assignment]
    atan = staticmethod(math.atan)  # type: ignore[assignment]
    atan2 = staticmethod(math.atan2)  # type: ignore[assignment]
    fabs = staticmethod(abs)  # type: ignore[assignment]

    def where(self, c: S, a: S, b: S) -> S:
        return a if c else b

    def fmax(self, a: S, b: S) -> S:
        return a if a >= b else b

    def fmin(self, a: S, b: S) -> S:
        return a if a <= b else b

    def lor(self, a: S, b: S) -> S:
        return bool(a) or bool(b)

    def land(self, a: S, b: S) -> S:
        return bool(a) and bool(b)

    def lnot(self, a: S) -> S:
        return not a

    hypot = staticmethod(math.hypot)

    def lazy_where(self, c: S, a: Any, b: Any, n: int) -> tuple[S, ...]:
        return tuple(a() if c else b())


NUMPY = NumpyBackend()
FLOAT = FloatBackend()


# ----------------------------------------------------------------------------- vector helpers


def _dot(a: Vec3, b: Vec3) -> S:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _cross(a: Vec3, b: Vec3) -> Vec3:
    return (
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    )


def dcm_to_quat(ops: Backend, C: tuple[Vec3, Vec3, Vec3]) -> tuple[S, S, S, S]:
    """Unit quaternion (w >= 0) of the rows ``C`` of a rotation matrix, Shepperd's method."""
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = C
    d0 = 1.0 + m00 + m11 + m22  # 4 w^2
    d1 = 1.0 + m00 - m11 - m22  # 4 x^2
    d2 = 1.0 - m00 + m11 - m22  # 4 y^2
    d3 = 1.0 - m00 - m11 + m22  # 4 z^2
    wx = m21 - m12  # 4 w x
    wy = m02 - m20
    wz = m10 - m01
    xy = m01 + m10
    xz = m02 + m20
    yz = m12 + m21
    d23 = ops.fmax(d2, d3)
    c0 = d0 >= ops.fmax(d1, d23)
    c1 = d1 >= d23
    c2 = d2 >= d3
    dk = ops.where(c0, d0, ops.where(c1, d1, ops.where(c2, d2, d3)))
    w = ops.where(c0, dk, ops.where(c1, wx, ops.where(c2, wy, wz)))
    x = ops.where(c0, wx, ops.where(c1, dk, ops.where(c2, xy, xz)))
    y = ops.where(c0, wy, ops.where(c1, xy, ops.where(c2, dk, yz)))
    z = ops.where(c0, wz, ops.where(c1, xz, ops.where(c2, yz, dk)))
    # Each component is numerator / (2 sqrt(dk)) (dk >= 1 for a rotation matrix): the common
    # factor cancels in the normalisation, which also makes w >= 0.
    n2 = w * w + x * x + y * y + z * z
    k = ops.where(w < 0.0, -1.0, 1.0) / ops.sqrt(ops.fmax(n2, 1e-300))
    return (w * k, x * k, y * k, z * k)


# ----------------------------------------------------------------------------- multirotor


def multirotor(
    ops: Backend,
    vel: Vec3,
    acc: Vec3,
    jerk: Vec3,
    snap: Vec3,
    yaw: S,
    yaw_rate: S,
    yaw_acc: S,
    mass: S,
    inertia: tuple[Vec3, Vec3, Vec3],
    g: S,
    hover_thrust: S,
    drag: S,
) -> dict[str, Any]:
    """Multirotor flat outputs -> setpoint (docs/theory/multirotor.md), components as tuples.

    Returns a dict with ``thrust, thrust_dot, thrust_ddot, thrust_norm`` (scalars), ``q_wxyz``
    (4-tuple), ``C_eb`` (3 rows of 3), ``omega_frd, omega_dot_frd, moment_frd`` (3-tuples),
    ``flags`` (float bit set, see ``FLAG_*``) and ``singular`` (float 0/1).
    """
    m = mass
    D = drag
    # Thrust vector t = m (g e3 - a) - D v and its derivatives (world NED, N, N/s, N/s^2).
    t = (-m * acc[0] - D * vel[0], -m * acc[1] - D * vel[1], m * (g - acc[2]) - D * vel[2])
    td = (-m * jerk[0] - D * acc[0], -m * jerk[1] - D * acc[1], -m * jerk[2] - D * acc[2])
    tdd = (-m * snap[0] - D * jerk[0], -m * snap[1] - D * jerk[1], -m * snap[2] - D * jerk[2])
    T = ops.sqrt(_dot(t, t))
    mg = m * g
    low = THRUST_MIN_FRAC * mg > T
    no_dir = THRUST_DIR_FRAC * mg > T
    T_dir = ops.where(no_dir, 1.0, T)
    z_b: Vec3 = (
        ops.where(no_dir, 0.0, t[0] / T_dir),
        ops.where(no_dir, 0.0, t[1] / T_dir),
        ops.where(no_dir, 1.0, t[2] / T_dir),
    )
    # Heading (PX4 ControlMath::bodyzToAttitude).
    cy = ops.cos(yaw)
    sy = ops.sin(yaw)
    x_c: Vec3 = (cy, sy, 0.0)
    y_c: Vec3 = (-sy, cy, 0.0)
    zc = z_b[0] * cy + z_b[1] * sy  # x_c . z_b
    u: Vec3 = (cy * z_b[2], sy * z_b[2], -zc)  # y_c x z_b
    n = ops.sqrt(z_b[2] * z_b[2] + zc * zc)  # |y_c x z_b| = |cos(roll)|
    sing = n < COS_ROLL_MIN
    # x_b = sigma * u / n: flipped when inverted (keep the nose to the front); PX4 takes
    # x_b = +e3 for (nearly) horizontal thrust.
    horiz = ops.fabs(z_b[2]) < HORIZONTAL_EPS
    sigma = ops.where(horiz, ops.where(u[2] < 0.0, -1.0, 1.0), ops.where(z_b[2] < 0.0, -1.0, 1.0))
    k_n = sigma / ops.where(sing, 1.0, n)
    # Heading-singular fallback: x_c projected on the plane normal to z_b (norm ~ 1 there).
    w_c: Vec3 = (cy - zc * z_b[0], sy - zc * z_b[1], -zc * z_b[2])
    k_w = 1.0 / ops.sqrt(ops.where(sing, _dot(w_c, w_c), 1.0))
    x_b: Vec3 = (
        ops.where(sing, w_c[0] * k_w, u[0] * k_n),
        ops.where(sing, w_c[1] * k_w, u[1] * k_n),
        ops.where(sing, w_c[2] * k_w, u[2] * k_n),
    )
    y_b = _cross(z_b, x_b)
    inverted = z_b[2] <= 0.0

    # Rates. T_s / den are safe denominators; results are zeroed below where not valid.
    zero_ff = ops.lor(low, sing)
    T_s = ops.where(low, 1.0, T)
    T_d = _dot(td, z_b)
    p = -_dot(td, y_b) / T_s
    q = _dot(td, x_b) / T_s
    xc_xb = _dot(x_c, x_b)
    xc_yb = _dot(x_c, y_b)
    yc_yb = _dot(y_c, y_b)
    yc_zb = y_c[0] * z_b[0] + y_c[1] * z_b[1]
    den = ops.where(sing, 1.0, yc_yb)
    r = (yaw_rate * xc_xb + q * yc_zb) / den
    T_dd = _dot(tdd, z_b) + ops.where(low, 0.0, T * (p * p + q * q))
    p_d = -(_dot(tdd, y_b) + 2.0 * T_d * p) / T_s + q * r
    q_d = (_dot(tdd, x_b) - 2.0 * T_d * q) / T_s - p * r
    r_d = (
        yaw_acc * xc_xb
        + 2.0 * yaw_rate * r * xc_yb
        - 2.0 * yaw_rate * q * zc
        - p * q * yc_yb
        - p * r * yc_zb
        + q_d * yc_zb
    ) / den
    omega: Vec3 = (
        ops.where(zero_ff, 0.0, p),
        ops.where(zero_ff, 0.0, q),
        ops.where(zero_ff, 0.0, r),
    )
    omega_d: Vec3 = (
        ops.where(zero_ff, 0.0, p_d),
        ops.where(zero_ff, 0.0, q_d),
        ops.where(zero_ff, 0.0, r_d),
    )
    # Moments M = J omega' + omega x (J omega) (body FRD, N m).
    J = inertia
    Jw: Vec3 = (_dot(J[0], omega), _dot(J[1], omega), _dot(J[2], omega))
    Jwd: Vec3 = (_dot(J[0], omega_d), _dot(J[1], omega_d), _dot(J[2], omega_d))
    gyro = _cross(omega, Jw)
    moment: Vec3 = (Jwd[0] + gyro[0], Jwd[1] + gyro[1], Jwd[2] + gyro[2])

    C_rows: tuple[Vec3, Vec3, Vec3] = (
        (x_b[0], y_b[0], z_b[0]),
        (x_b[1], y_b[1], z_b[1]),
        (x_b[2], y_b[2], z_b[2]),
    )
    quat = dcm_to_quat(ops, C_rows)
    thrust_norm = ops.fmin(ops.fmax(hover_thrust * T / mg, 0.0), 1.0)
    flags = (
        ops.where(low, float(FLAG_LOW_THRUST), 0.0)
        + ops.where(sing, float(FLAG_HEADING_SINGULAR), 0.0)
        + ops.where(inverted, float(FLAG_INVERTED), 0.0)
    )
    singular = ops.where(ops.lor(zero_ff, inverted), 1.0, 0.0)
    return {
        "thrust": T,
        "thrust_dot": T_d,
        "thrust_ddot": T_dd,
        "thrust_norm": thrust_norm,
        "q_wxyz": quat,
        "C_eb": C_rows,
        "omega_frd": omega,
        "omega_dot_frd": omega_d,
        "moment_frd": moment,
        "flags": flags,
        "singular": singular,
    }


# ----------------------------------------------------------------------------- rover


def rover(
    ops: Backend,
    vel_xy: tuple[S, S],
    acc_xy: tuple[S, S],
    jerk_xy: tuple[S, S],
    wheel_base: S | None = None,
) -> dict[str, S]:
    """Rover flat output derivatives -> heading, speed and rates (docs/theory/rover.md).

    ``vel_xy``, ``acc_xy``, ``jerk_xy``: derivatives of the planar NED position (x north,
    y east; m/s, m/s^2, m/s^3). Returns the unicycle map: ``yaw`` (rad), ``speed`` (m/s),
    ``speed_dot`` (m/s^2), ``yaw_rate`` (rad/s), ``yaw_acc`` (rad/s^2) and ``singular`` (float
    0/1: stopped, rates zeroed). With a ``wheel_base`` L (m, rear to front axle; car-like
    bicycle model about the rear axle) also the Ackermann map: ``curvature`` kappa (1/m, > 0
    turning right, i.e. clockwise seen from above as a positive NED yaw rate),
    ``curvature_rate`` (1/(m s)), ``steer_angle`` delta = atan(L kappa) (rad, > 0 right) and
    ``steer_rate`` (rad/s); all four 0 where ``singular``.
    """
    vx, vy = vel_xy
    ax, ay = acc_xy
    jx, jy = jerk_xy
    V2 = vx * vx + vy * vy
    V = ops.sqrt(V2)
    A2 = ax * ax + ay * ay
    slow = V < ROVER_SPEED_MIN
    no_v = V < ROVER_DIR_EPS
    no_a = A2 < ROVER_DIR_EPS * ROVER_DIR_EPS
    yaw = ops.where(
        no_v,
        ops.where(no_a, 0.0, ops.atan2(ops.where(no_a, 0.0, ay), ops.where(no_a, 1.0, ax))),
        ops.atan2(ops.where(no_v, 0.0, vy), ops.where(no_v, 1.0, vx)),
    )
    V_s = ops.where(slow, 1.0, V)
    V2_s = ops.where(slow, 1.0, V2)
    cr = vx * ay - vy * ax  # V^2 yaw_rate = V^3 curvature
    dt = vx * ax + vy * ay  # V speed_dot
    cr_d = vx * jy - vy * jx  # d(cr)/dt (the a x a term vanishes)
    speed_dot = ops.where(slow, 0.0, dt / V_s)
    yaw_rate = ops.where(slow, 0.0, cr / V2_s)
    yaw_acc = ops.where(slow, 0.0, (cr_d * V2 - 2.0 * cr * dt) / (V2_s * V2_s))
    out = {
        "yaw": yaw,
        "speed": V,
        "speed_dot": speed_dot,
        "yaw_rate": yaw_rate,
        "yaw_acc": yaw_acc,
        "singular": ops.where(slow, 1.0, 0.0),
    }
    if wheel_base is None:
        return out
    # Ackermann (bicycle model, rear-axle reference): kappa = cr / V^3 and
    # kappa' = cr' / V^3 - 3 cr V' / V^4 = (cr' V^2 - 3 cr (v . a)) / V^5.
    V3_s = V2_s * V_s
    kappa = ops.where(slow, 0.0, cr / V3_s)
    kappa_d = ops.where(slow, 0.0, (cr_d * V2 - 3.0 * cr * dt) / (V3_s * V2_s))
    Lk = wheel_base * kappa  # tan(delta); 0 where slow, so delta = delta' = 0 there
    out["curvature"] = kappa
    out["curvature_rate"] = kappa_d
    out["steer_angle"] = ops.atan(Lk)
    out["steer_rate"] = wheel_base * kappa_d / (1.0 + Lk * Lk)
    return out
