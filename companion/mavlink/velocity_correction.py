"""The horizontal velocity correction's update step, written once over the flatness backends
(floats, CasADi ``SX``), like `companion.control.observer`.

`telemetry.VelocityCorrection.update` evaluates it on Python floats
(``companion.flatness._formulas.FLOAT``) at each position sample;
:func:`symbolic_velocity_correction_step` builds the same expressions on CasADi symbols, the
source ``gen_c`` emits as C (``ecca_velocity_correction_step``), which the onboard PX4 module
calls. What stays outside is the bookkeeping the step does not own: the sample clock (`dt`), the
same sample again, the finiteness checks and whether there is a previous sample (folded into
`run` by the caller).

A second-order complementary filter (both poles at -w): between samples the filtered position
moves with the reported velocity (trapezoid over the two samples) plus the correction c; the
position's innovation r then pulls it by a r and c by b r, with a = min(1, 2 w dt) and
b = w^2 dt; each axis of c is clamped to the bound. With `dt` outside (DT_MIN_S, DT_MAX_S),
without `run`, or with |r| beyond the reset distance (an estimator reset), the filter restarts
from the sample and holds c. Frames and units: NED north, east [m, m/s], `dt` [s], `w` [rad/s].
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import companion.flatness._formulas as fm

S = Any

#: Natural frequency [rad/s] of the correction (both poles there: it follows a changing velocity
#: error with a time constant of ~1 / this).
VELOCITY_CORRECTION_RAD_S = 4.0
#: The correction's magnitude is clamped to this [m/s] per axis.
VELOCITY_CORRECTION_MAX_M_S = 1.0
#: A position that jumps this far [m] from the filter's prediction is an estimator reset: the
#: filter restarts from it and keeps its correction.
POSITION_RESET_M = 1.0
#: The step integrates over intervals in (DT_MIN_S, DT_MAX_S) [s] only (else: restart).
DT_MIN_S = 1e-3
DT_MAX_S = 0.5

#: (name, size) of the step's inputs, in order: the layout of the generated function's input
#: vector (`symbolic_velocity_correction_step`).
VCORR_INPUTS: tuple[tuple[str, int], ...] = (
    ("p_hat", 2),  # the filtered position north, east after the last sample [m]
    ("vel_prev", 2),  # the last sample's reported velocity north, east [m/s]
    ("corr", 2),  # the correction north, east [m/s]
    ("pos", 2),  # the new sample's position north, east [m]
    ("vel", 2),  # the new sample's reported velocity north, east [m/s]
    ("dt", 1),  # time since the last sample [s]
    ("omega", 1),  # the filter's natural frequency w [rad/s]
    ("max_corr", 1),  # bound of each axis of the correction [m/s]
    ("reset_m", 1),  # an innovation longer than this [m] restarts the filter
    ("run", 1),  # 1: update (a previous sample); 0: restart from the sample
)
#: (name, size) of the step's outputs, in order.
VCORR_OUTPUTS: tuple[tuple[str, int], ...] = (
    ("p_hat", 2),  # the filtered position after this sample [m]
    ("corr", 2),  # the correction after this sample [m/s]
)
VCORR_N_IN = sum(n for _, n in VCORR_INPUTS)
VCORR_N_OUT = sum(n for _, n in VCORR_OUTPUTS)


def velocity_correction_step(
    ops: fm.Backend, p_hat: Sequence[S], vel_prev: Sequence[S], corr: Sequence[S],
    pos: Sequence[S], vel: Sequence[S], dt: S, omega: S, max_corr: S, reset_m: S, run: S,
) -> tuple[tuple[S, S], tuple[S, S]]:
    """One sample: the new (p_hat, corr). Without `run`, with `dt` outside (DT_MIN_S,
    DT_MAX_S) or an innovation longer than `reset_m`, p_hat takes the sample `pos` and corr is
    held."""
    ok = ops.land(run, ops.land(dt > DT_MIN_S, dt < DT_MAX_S))
    cx, cy = corr[0], corr[1]
    h = 0.5 * dt
    qx = p_hat[0] + (vel_prev[0] + vel[0]) * h + cx * dt
    qy = p_hat[1] + (vel_prev[1] + vel[1]) * h + cy * dt
    rx, ry = pos[0] - qx, pos[1] - qy
    update = ops.land(ok, ops.lnot(ops.hypot(rx, ry) > reset_m))
    a = ops.fmin(1.0, 2.0 * omega * dt)
    b = omega * omega * dt
    ux = ops.fmin(max_corr, ops.fmax(-max_corr, cx + b * rx))
    uy = ops.fmin(max_corr, ops.fmax(-max_corr, cy + b * ry))
    return ((ops.where(update, qx + a * rx, pos[0]), ops.where(update, qy + a * ry, pos[1])),
            (ops.where(update, ux, cx), ops.where(update, uy, cy)))


def velocity_correction_step_vector(ops: fm.Backend, x: Sequence[S]) -> list[S]:
    """The step on one input vector `x` (`VCORR_INPUTS`, flattened): the outputs
    (`VCORR_OUTPUTS`, flattened)."""
    p, c = velocity_correction_step(ops, x[0:2], x[2:4], x[4:6], x[6:8], x[8:10], x[10], x[11],
                                    x[12], x[13], x[14] > 0.5)
    return [p[0], p[1], c[0], c[1]]


def symbolic_velocity_correction_step(name: str = "ecca_velocity_correction_step") -> Any:
    """The step as a ``casadi.Function`` `name`: one input vector ``x`` (`VCORR_INPUTS`) and one
    output vector ``y`` (`VCORR_OUTPUTS`), from the same expressions the companion evaluates."""
    import casadi as ca

    x = ca.SX.sym("x", VCORR_N_IN)
    y = velocity_correction_step_vector(fm.CasadiBackend(), [x[i] for i in range(VCORR_N_IN)])
    return ca.Function(name, [x], [ca.vertcat(*y)], ["x"], ["y"])
