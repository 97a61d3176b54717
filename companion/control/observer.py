"""The disturbance observer's update step, written once over the flatness backends (floats,
CasADi ``SX``), like `companion.control.core`.

`DisturbanceObserver.update` evaluates it on Python floats (``companion.flatness._formulas.FLOAT``)
at each telemetry sample; :func:`symbolic_disturbance_step` builds the same expressions on CasADi
symbols, the source ``gen_c`` emits as C (``ecca_disturbance_step``), which the onboard PX4 module
calls. What stays outside is the bookkeeping the step does not own: the sample clock (`dt`), the
finiteness checks and whether the observer has a previous velocity (folded into `learn` by the
caller), the model's acceleration `a_model` (its ingredients differ between callers).

Luenberger velocity observer with a horizontal disturbance state, both poles at -w:

    v_hat' = a_model + d_hat + 2 w (v - v_hat),   d_hat' = w^2 (v - v_hat)

discretised as a prediction over `dt` and a correction with gains min(2 w dt, 1) and w^2 dt;
the estimate's magnitude is bounded by `max_acc`. Frames and units: NED north, east [m/s,
m/s^2], `dt` [s], `w` [rad/s].
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import companion.flatness._formulas as fm

S = Any

#: Longest interval [s] between two samples the step integrates over (longer: resynchronise).
DT_MAX_S = 0.5

#: (name, size) of the step's inputs, in order: the layout of the generated function's input
#: vector (`symbolic_disturbance_step`).
DIST_INPUTS: tuple[tuple[str, int], ...] = (
    ("v_hat", 2),  # the observer's velocity north, east after the last sample [m/s]
    ("d_hat", 2),  # the disturbance estimate north, east [m/s^2]
    ("vel", 2),  # the new velocity sample north, east [m/s]
    ("a_model", 2),  # the model's acceleration over the interval north, east [m/s^2]
    ("dt", 1),  # time since the last sample [s]
    ("bandwidth", 1),  # the observer's bandwidth w [rad/s]
    ("max_acc", 1),  # bound of the estimate's magnitude [m/s^2]
    ("learn", 1),  # 1: update (airborne, thrust above idle, a previous v_hat); 0: follow vel
)
#: (name, size) of the step's outputs, in order.
DIST_OUTPUTS: tuple[tuple[str, int], ...] = (
    ("v_hat", 2),  # the observer's velocity after this sample [m/s]
    ("d_hat", 2),  # the disturbance estimate after this sample [m/s^2]
)
DIST_N_IN = sum(n for _, n in DIST_INPUTS)
DIST_N_OUT = sum(n for _, n in DIST_OUTPUTS)


def disturbance_step(ops: fm.Backend, v_hat: Sequence[S], d_hat: Sequence[S], vel: Sequence[S],
                     a_model: Sequence[S], dt: S, bandwidth: S, max_acc: S,
                     learn: S) -> tuple[tuple[S, S], tuple[S, S]]:
    """One sample: the new (v_hat, d_hat). Without `learn`, or with `dt` outside (0, DT_MAX_S),
    v_hat takes the sample `vel` and d_hat is held."""
    run = ops.land(learn, ops.land(dt > 0.0, dt < DT_MAX_S))
    w = bandwidth
    k1 = ops.fmin(2.0 * w * dt, 1.0)
    k2 = w * w * dt
    dx, dy = d_hat[0], d_hat[1]
    px = v_hat[0] + (a_model[0] + dx) * dt
    py = v_hat[1] + (a_model[1] + dy) * dt
    ex, ey = vel[0] - px, vel[1] - py
    vx, vy = px + k1 * ex, py + k1 * ey
    dx, dy = dx + k2 * ex, dy + k2 * ey
    n = ops.hypot(dx, dy)
    big = n > max_acc
    s = ops.where(big, n, 1.0)  # n > max_acc > 0 where used
    dx = ops.where(big, dx * max_acc / s, dx)
    dy = ops.where(big, dy * max_acc / s, dy)
    return ((ops.where(run, vx, vel[0]), ops.where(run, vy, vel[1])),
            (ops.where(run, dx, d_hat[0]), ops.where(run, dy, d_hat[1])))


def disturbance_step_vector(ops: fm.Backend, x: Sequence[S]) -> list[S]:
    """The step on one input vector `x` (`DIST_INPUTS`, flattened): the outputs
    (`DIST_OUTPUTS`, flattened)."""
    v, d = disturbance_step(ops, x[0:2], x[2:4], x[4:6], x[6:8], x[8], x[9], x[10],
                            x[11] > 0.5)
    return [v[0], v[1], d[0], d[1]]


def symbolic_disturbance_step(name: str = "ecca_disturbance_step") -> Any:
    """The step as a ``casadi.Function`` `name`: one input vector ``x`` (`DIST_INPUTS`) and one
    output vector ``y`` (`DIST_OUTPUTS`), from the same expressions the companion evaluates."""
    import casadi as ca

    x = ca.SX.sym("x", DIST_N_IN)
    y = disturbance_step_vector(fm.CasadiBackend(), [x[i] for i in range(DIST_N_IN)])
    return ca.Function(name, [x], [ca.vertcat(*y)], ["x"], ["y"])
