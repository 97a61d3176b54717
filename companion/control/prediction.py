"""The latency compensation's refinements (`TrackingConfig.prediction_lag_s`,
`rate_prediction_lag_s`): the state carried from a telemetry sample to now with the vehicle's
response to the commands sent since lagging them, as its attitude and rate loops do."""

from __future__ import annotations

import math
from collections.abc import Reversible

from companion.control.so3 import quat_integrate_f

#: Step [s] of the rates-mode attitude predictor (`predict_attitude`).
ATT_PREDICT_STEP_S = 0.005


def predict_attitude(rate_hist: Reversible[tuple[float, float, float, float]], t_s: float,
                     tau: float, q: list[float], w: list[float],
                     lag: float) -> tuple[float, float, float, float]:
    """The attitude `tau` [s] after the sample at `t_s` (attitude `q`, body rates `w`
    [rad/s FRD]) in rates mode: the body rates start at `w` and follow the rates commanded
    since (each from the moment it was sent) as a first-order lag of time constant `lag`
    [s] (the autopilot's rate loop), integrated in steps of at most ATT_PREDICT_STEP_S.
    Holding `w` instead carries a roll the command is already stopping past the limit."""
    cmds: list[tuple[float, tuple[float, float, float]]] = []  # newest first
    target = (w[0], w[1], w[2])  # the command in force at the sample
    for tc, x, y, z in reversed(rate_hist):
        if tc <= t_s:
            target = (x, y, z)
            break
        cmds.append((tc, (x, y, z)))
    cmds.reverse()
    t1 = t_s + tau
    wx, wy, wz = w[0], w[1], w[2]
    qq = (q[0], q[1], q[2], q[3])
    t = t_s
    # piecewise between the commands' send times, each piece in steps of at most
    # ATT_PREDICT_STEP_S; over a step the rates' exact mean enters the rotation
    for ts, nxt in [*cmds, (t1, target)]:
        end = min(ts, t1)
        if end > t:
            n = max(1, math.ceil((end - t) / ATT_PREDICT_STEP_S))
            h = (end - t) / n
            a = 1.0 - math.exp(-h / lag)
            m = lag / h * a  # the mean of the lag's exponential over a step
            for _ in range(n):
                rx, ry, rz = wx - target[0], wy - target[1], wz - target[2]
                qq = quat_integrate_f(list(qq), [target[0] + rx * m, target[1] + ry * m,
                                                 target[2] + rz * m], h)
                wx, wy, wz = wx - rx * a, wy - ry * a, wz - rz * a
            t = end
        target = nxt
    return qq


def predict_lagged(t0: float, t1: float, p0: tuple[float, float, float],
                   v0: tuple[float, float, float], a0: tuple[float, float, float],
                   cur: tuple[float, float, float] | None,
                   segs: list[tuple[float, float, float, float]], lag: float
                   ) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """`_predict` with the vehicle's acceleration lagging the commands: it starts at `a0`
    (the measured attitude's, at `t0`) and relaxes toward the command in force (`cur`, then
    each of `segs`, newest first) with time constant `lag` [s] (the attitude loop's)."""
    p = list(p0)
    v = list(v0)
    a = list(a0)
    c = list(cur) if cur is not None else list(a0)
    t = t0
    for st, bx, by, bz in [*reversed(segs), (t1, 0.0, 0.0, 0.0)]:
        h = st - t
        if h > 0.0:
            e = math.exp(-h / lag)
            f1 = lag * (1.0 - e)  # integral of e^(-s/lag) over [0, h]
            f2 = lag * (h - f1)  # its double integral
            for i in range(3):
                r = a[i] - c[i]
                p[i] += v[i] * h + 0.5 * c[i] * h * h + r * f2
                v[i] += c[i] * h + r * f1
                a[i] = c[i] + r * e
            t = st
        c = [bx, by, bz]
    return (p[0], p[1], p[2]), (v[0], v[1], v[2])


def predict_held(t0: float, t1: float, p0: tuple[float, float, float],
                 v0: tuple[float, float, float], a: tuple[float, float, float],
                 segs: list[tuple[float, float, float, float]]
                 ) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """Position and velocity [m, m/s, NED] at `t1` from (`p0`, `v0`) at `t0`: acceleration `a`
    [m/s^2], then each command of `segs` (start [s], ax, ay, az; newest first) from its start,
    held (zero-order hold; the Smith predictor of `TrackingController._predict`)."""
    px, py, pz = p0
    vx, vy, vz = v0
    t = t0
    for st, bx, by, bz in reversed(segs):
        h = st - t
        h2 = 0.5 * h * h
        px += vx * h + a[0] * h2
        py += vy * h + a[1] * h2
        pz += vz * h + a[2] * h2
        vx += a[0] * h
        vy += a[1] * h
        vz += a[2] * h
        a, t = (bx, by, bz), st
    h = t1 - t
    h2 = 0.5 * h * h
    return ((px + vx * h + a[0] * h2, py + vy * h + a[1] * h2, pz + vz * h + a[2] * h2),
            (vx + a[0] * h, vy + a[1] * h, vz + a[2] * h))
