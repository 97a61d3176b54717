"""The tracking law's core, written once over the flatness backends (floats, CasADi ``SX``).

From the reference and the (latency-compensated) estimate to the attitude and thrust command:
position / velocity feedback with the integrator, the drag and disturbance feed-forward, the
thrust limits (minimum, tilt, maximum; vertical first), the integrator's anti-windup, the jerk
of the limited thrust vector, then the flatness map. `TrackingController` evaluates it on Python
floats every setpoint (``companion.flatness._formulas.FLOAT``); :func:`symbolic_core` builds the
same expressions on CasADi symbols, the source ``gen_c`` emits as C (``ecca_tracking_core``), so
the law that flies in the companion and the generated C have one source. What stays outside is
state the core does not own: the estimators (hover thrust, drag, disturbance), latency
compensation and attitude prediction, the yaw slew, the fallbacks.

Frames and units: NED [m, m/s, m/s^2, m/s^3, m/s^4], body FRD, thrust [N] and normalised
(0..1 of full thrust, `hover` at hover). Every branch is a ``where`` (both sides evaluated on
symbols; on floats only the taken one where it costs: ``lazy_where``), every division safe.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import companion.flatness._formulas as fm
from companion.control.saturation import saturated_jerk

S = Any
Vec3 = tuple[S, S, S]

#: (name, size) of the core's inputs, in order: the layout of the generated function's
#: input vector (`symbolic_core`) and of `CORE_INPUT` rows (the golden vectors).
CORE_INPUTS: tuple[tuple[str, int], ...] = (
    ("ref_pos", 3),  # reference position [m NED]
    ("ref_vel", 3),  # reference velocity [m/s]
    ("ref_acc", 3),  # reference acceleration now [m/s^2] (feedback jerk, drag rate)
    ("acc_ff", 3),  # feed-forward acceleration (the reference's, lead applied) [m/s^2]
    ("jerk_ff", 3),  # feed-forward jerk [m/s^3]
    ("snap_ff", 3),  # feed-forward snap [m/s^4]
    ("pos", 3),  # estimated position, latency-compensated [m]
    ("vel", 3),  # estimated velocity, latency-compensated [m/s]
    ("acc_meas", 3),  # the vehicle's acceleration from attitude and thrust [m/s^2]
    ("integ", 3),  # integrator state [m/s^2]
    ("kp", 3),  # position gain [1/s^2]
    ("kd", 3),  # velocity gain [1/s]
    ("ki", 3),  # integral gain [1/s^3]
    ("i_max", 3),  # integrator bound [m/s^2]
    ("dist_ne", 2),  # estimated disturbance acceleration north, east [m/s^2]
    ("yaw", 3),  # yaw [rad], its rate [rad/s], its acceleration [rad/s^2]
    ("hover", 1),  # hover thrust in use [normalised]
    ("drag", 1),  # linear drag of the thrust vector [N/(m/s)]
    ("drag_map", 1),  # the drag the flatness map uses (the controller rounds it) [N/(m/s)]
    ("mass", 1),  # [kg]
    ("g", 1),  # [m/s^2]
    ("thrust_min", 1),  # [normalised]
    ("thrust_max", 1),  # [normalised]
    ("cos_tilt", 1),  # cos of the tilt limit
    ("tan_tilt", 1),  # tan of the tilt limit
    ("fb_share", 1),  # share of the feedback's derivative in the jerk (0: none)
    ("drag_est", 1),  # 1: drag of the estimated velocity; 0: of the reference's
    ("dt", 1),  # time since the last update [s] (0: first)
    ("learn", 1),  # 1: airborne and learning (the integrator runs)
)
#: (name, size) of the core's outputs, in order.
CORE_OUTPUTS: tuple[tuple[str, int], ...] = (
    ("q_wxyz", 4),  # desired attitude, body FRD -> NED, w >= 0
    ("thrust", 1),  # normalised thrust, within [thrust_min, thrust_max]
    ("omega_ff", 3),  # feed-forward body rates [rad/s FRD] (0 where singular)
    ("saturated", 1),  # 1 while a thrust limit acts
    ("integ", 3),  # integrator state after this update
    ("acc", 3),  # the acceleration the command gives, disturbance included [m/s^2]
    ("singular", 1),  # 1 at a singular flatness point (rates zeroed)
)
CORE_N_IN = sum(n for _, n in CORE_INPUTS)
CORE_N_OUT = sum(n for _, n in CORE_OUTPUTS)


def limit_thrust(ops: fm.Backend, t_vec: Vec3, t_min: S, t_max: S, cos_tilt: S,
                 tan_tilt: S) -> tuple[Vec3, S]:
    """The thrust vector `t_vec` [N, NED; down when level] within the limits: a minimum upward
    part `t_min` cos(tilt), at most `t_max` vertically, the horizontal part within the tilt cone
    and the magnitude `t_max` (vertical first), a magnitude of at least `t_min`. Returns the
    limited vector and whether a limit acted."""
    tx, ty, tz = t_vec
    lo = t_min * cos_tilt
    c1 = tz < lo
    tz = ops.where(c1, lo, tz)
    c2 = tz > t_max
    tz = ops.where(c2, t_max, tz)
    h_lim = ops.fmin(tz * tan_tilt, ops.sqrt(ops.fmax(t_max * t_max - tz * tz, 0.0)))
    hn = ops.hypot(tx, ty)
    c3 = hn > h_lim
    k = h_lim / ops.where(c3, hn, 1.0)  # hn > h_lim >= 0 where used
    tx = ops.where(c3, tx * k, tx)
    ty = ops.where(c3, ty * k, ty)
    c4 = t_min > ops.hypot(tx, ty, tz)
    tz = ops.where(c4, ops.sqrt(ops.fmax(t_min * t_min - tx * tx - ty * ty, 0.0)), tz)
    return (tx, ty, tz), ops.lor(ops.lor(c1, c2), ops.lor(c3, c4))


def tracking_pre(ops: fm.Backend, x: Sequence[S]) -> dict[str, Any]:
    """The core up to the flatness map, on the inputs `x` (`CORE_INPUTS` order, flattened).
    Returns ``v_drag, acc, jerk, snap, yaw_acc, sat, integ, acc_d, e_p, e_v`` (the flatness
    map's velocity, acceleration (whose thrust vector with ``drag_map`` is the limited one),
    jerk, snap and yaw acceleration; whether limited; the
    integrator after the update; the acceleration with the disturbance; the position and
    velocity errors)."""
    rp, rv, ra = x[0:3], x[3:6], x[6:9]
    a_ff, j_ff, rs = x[9:12], x[12:15], x[15:18]
    pos, vel, a_m = x[18:21], x[21:24], x[24:27]
    integ, kp, kd, ki, imax = x[27:30], x[30:33], x[33:36], x[36:39], x[39:42]
    dx, dy = x[42], x[43]
    yaw_acc_in = x[46]
    h, D, D_map, m, g0 = x[47], x[48], x[49], x[50], x[51]
    thr_min, thr_max, cos_t, tan_t = x[52], x[53], x[54], x[55]
    share, drag_est, dt, learn = x[56], x[57], x[58], x[59]
    # position and velocity feedback (per component, written out: this runs every setpoint)
    e_p = (rp[0] - pos[0], rp[1] - pos[1], rp[2] - pos[2])
    e_v = (rv[0] - vel[0], rv[1] - vel[1], rv[2] - vel[2])
    a_cmd = (
        a_ff[0] + kp[0] * e_p[0] + kd[0] * e_v[0] + integ[0],
        a_ff[1] + kp[1] * e_p[1] + kd[1] * e_v[1] + integ[1],
        a_ff[2] + kp[2] * e_p[2] + kd[2] * e_v[2] + integ[2],
    )
    # the commanded acceleration's rate with `share` of the feedback's derivative
    # (TrackingController._feedback_jerk)
    fb = share > 0.0
    j_ff = (
        ops.where(fb, j_ff[0] + share * (kp[0] * e_v[0] + kd[0] * (ra[0] - a_m[0])
                                         + ki[0] * e_p[0]), j_ff[0]),
        ops.where(fb, j_ff[1] + share * (kp[1] * e_v[1] + kd[1] * (ra[1] - a_m[1])
                                         + ki[1] * e_p[1]), j_ff[1]),
        ops.where(fb, j_ff[2] + share * (kp[2] * e_v[2] + kd[2] * (ra[2] - a_m[2])
                                         + ki[2] * e_p[2]), j_ff[2]),
    )
    # thrust vector t = m (g e3 - (a - d)) - D v, then its limits
    est = drag_est > 0.5
    v_drag = (ops.where(est, vel[0], rv[0]), ops.where(est, vel[1], rv[1]),
              ops.where(est, vel[2], rv[2]))
    t_vec = (
        -m * (a_cmd[0] - dx) - D * v_drag[0],
        -m * (a_cmd[1] - dy) - D * v_drag[1],
        m * (g0 - a_cmd[2]) - D * v_drag[2],
    )
    n_per_norm = m * g0 / h  # N per unit normalised thrust
    t_min = thr_min * n_per_norm
    t_max = thr_max * n_per_norm
    t_sat, sat = limit_thrust(ops, t_vec, t_min, t_max, cos_t, tan_t)
    a_sat = (
        -(t_sat[0] + D * v_drag[0]) / m,
        -(t_sat[1] + D * v_drag[1]) / m,
        g0 - (t_sat[2] + D * v_drag[2]) / m,
    )
    # anti-windup: integrate only in the air and when not limited (or when it unwinds)
    run = ops.land(dt > 0.0, learn > 0.5)
    integ_new = []
    for i in range(3):
        di = ki[i] * e_p[i] * dt
        step = ops.land(run, ops.lor(ops.lnot(sat), di * integ[i] < 0.0))
        integ_new.append(ops.where(step, ops.fmin(ops.fmax(integ[i] + di, -imax[i]), imax[i]),
                                   integ[i]))
    acc_d = (a_sat[0] + dx, a_sat[1] + dy, a_sat[2])
    v_dot = (ops.where(est, acc_d[0], ra[0]), ops.where(est, acc_d[1], ra[1]),
             ops.where(est, acc_d[2], ra[2]))

    def limited(t: Vec3) -> Vec3:
        return limit_thrust(ops, t, t_min, t_max, cos_t, tan_t)[0]

    jerk = ops.lazy_where(sat, lambda: saturated_jerk(limited, t_vec, t_sat, j_ff, v_dot, m, D),
                          lambda: j_ff, 3)
    # the flatness map's acceleration: the one whose thrust vector, with the map's drag
    # (`drag_map`, rounded), is `t_sat` itself, so the commanded attitude stays within the tilt
    # limit (with `a_sat` the map's thrust vector was t_sat + (D - D_map) v: real PX4, 45.001 deg
    # against a 45 deg limit); the same as `a_sat` where D_map == D
    a_map = (
        -(t_sat[0] + D_map * v_drag[0]) / m,
        -(t_sat[1] + D_map * v_drag[1]) / m,
        g0 - (t_sat[2] + D_map * v_drag[2]) / m,
    )
    return {
        "v_drag": v_drag,
        "acc": a_map,
        "jerk": jerk,
        "snap": (ops.where(sat, 0.0, rs[0]), ops.where(sat, 0.0, rs[1]),
                 ops.where(sat, 0.0, rs[2])),
        "yaw_acc": ops.where(sat, 0.0, yaw_acc_in),
        "sat": sat,
        "integ": tuple(integ_new),
        "acc_d": acc_d,
        "e_p": e_p,
        "e_v": e_v,
    }


def tracking_post(ops: fm.Backend, quat: Sequence[S], thrust_n: S, omega: Vec3, singular: S,
                  hover: S, mass: S, g: S, thr_min: S, thr_max: S) -> tuple[Any, S, Vec3]:
    """After the flatness map: the unit quaternion with w >= 0 (`so3.quat_normalize_f`), the
    thrust [N] normalised with the hover thrust in use and limited, the feed-forward rates
    (zero at a singular point). (docs/theory/multirotor.md, "Thrust for MAVLink")"""
    qw, qx, qy, qz = quat
    n = ops.hypot(qw, qx, qy, qz)
    ok = n > 1e-12
    n = ops.where(qw < 0.0, -n, n)
    n = ops.where(ok, n, 1.0)
    q = (ops.where(ok, qw / n, 1.0), ops.where(ok, qx / n, 0.0), ops.where(ok, qy / n, 0.0),
         ops.where(ok, qz / n, 0.0))
    thrust = hover * thrust_n / (mass * g)
    thrust = ops.fmin(ops.fmax(thrust, thr_min), thr_max)
    omega_ff = (ops.where(singular, 0.0, omega[0]), ops.where(singular, 0.0, omega[1]),
                ops.where(singular, 0.0, omega[2]))
    return q, thrust, omega_ff


def tracking_core(ops: fm.Backend, x: Sequence[S]) -> list[S]:
    """The whole core on inputs `x` (`CORE_INPUTS`, flattened): the outputs (`CORE_OUTPUTS`,
    flattened). The flatness map is `companion.flatness._formulas.multirotor` on `ops` (the
    source of the generated C)."""
    pre = tracking_pre(ops, x)
    yaw, yaw_rate = x[44], x[45]
    hover, drag_map, mass, g = x[47], x[49], x[50], x[51]
    eye = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))  # inertia: moments are not used
    f = fm.multirotor(ops, pre["v_drag"], pre["acc"], pre["jerk"], pre["snap"], yaw, yaw_rate,
                      pre["yaw_acc"], mass, eye, g, hover, drag_map)
    q, thrust, omega = tracking_post(ops, f["q_wxyz"], f["thrust"], f["omega_frd"],
                                     f["singular"] > 0.5, hover, mass, g, x[52], x[53])
    return [*q, thrust, *omega, ops.where(pre["sat"], 1.0, 0.0), *pre["integ"], *pre["acc_d"],
            f["singular"]]


def symbolic_core(name: str = "ecca_tracking_core") -> Any:
    """The core as a ``casadi.Function`` `name`: one input vector ``x`` (`CORE_INPUTS`) and one
    output vector ``y`` (`CORE_OUTPUTS`), from the same expressions the companion evaluates."""
    import casadi as ca

    x = ca.SX.sym("x", CORE_N_IN)
    ops = fm.CasadiBackend()
    y = tracking_core(ops, [x[i] for i in range(CORE_N_IN)])
    return ca.Function(name, [x], [ca.vertcat(*y)], ["x"], ["y"])
