"""The least tracking error any controller can reach on a periodic reference under a tilt limit.

A multirotor holding its altitude gets at most g tan(tilt limit) of horizontal specific force
[m/s^2]; with linear drag D/m [1/s] its horizontal motion is p'' = u - (D/m) p', |u| <= that.
Over one period T of a periodic reference this script finds, by convex optimisation (CasADi +
IPOPT, trapezoidal collocation, periodic boundary), the motion that keeps the mean squared
horizontal distance to the reference least. No lag, no estimation error, perfect knowledge: a
lower bound for every real controller, and the cost of the limit itself.

    .venv/bin/python bench/tilt_bound.py --speed 6 --dm 1.0 1.25 0.833 --tilt 45 50

prints, per case, the bound (RMS and largest distance [m]) and what the reference itself asks
for (largest tilt [deg], share of the period above the limit), for bench_tracking's figure-8.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
G = 9.80665
#: ref(t) -> (position, velocity, acceleration), horizontal (2,) each [m, m/s, m/s^2]
PlanarRef = Callable[[float], tuple[FloatArray, FloatArray, FloatArray]]


@dataclass(frozen=True)
class Bound:
    """Result of `tilt_bound`: rms_m / max_m, the least tracking error [m] (RMS over the period
    and the largest distance then); need_max_deg, the most tilt the reference asks for; share
    of the period it asks for more than the limit; the optimal path's positions (N, 2)."""

    rms_m: float
    max_m: float
    need_max_deg: float
    share_over: float
    path: FloatArray


def tilt_bound(ref: PlanarRef, period_s: float, drag_per_kg: float, tilt_deg: float,
               n: int = 600, t0: float = 0.0, g: float = G) -> Bound:
    """The least RMS horizontal error over one period [t0, t0 + period_s) of `ref`."""
    import casadi as ca

    ts = t0 + np.arange(n) * period_s / n
    samples = [ref(float(t)) for t in ts]
    p_ref = np.array([s[0] for s in samples]).T
    v_ref = np.array([s[1] for s in samples]).T
    a_ref = np.array([s[2] for s in samples]).T
    need = a_ref + drag_per_kg * v_ref
    need_deg = np.degrees(np.arctan(np.linalg.norm(need, axis=0) / g))
    dt = period_s / n
    umax = g * math.tan(math.radians(tilt_deg))
    opti = ca.Opti()
    p, v, u = opti.variable(2, n), opti.variable(2, n), opti.variable(2, n)
    for k in range(n):
        k1 = (k + 1) % n
        a0 = u[:, k] - drag_per_kg * v[:, k]
        a1 = u[:, k1] - drag_per_kg * v[:, k1]
        opti.subject_to(v[:, k1] == v[:, k] + 0.5 * dt * (a0 + a1))
        opti.subject_to(p[:, k1] == p[:, k] + 0.5 * dt * (v[:, k] + v[:, k1]))
        opti.subject_to(ca.sumsqr(u[:, k]) <= umax**2)
    opti.minimize(ca.sumsqr(p - p_ref) / n)
    opti.set_initial(p, p_ref)
    opti.set_initial(v, v_ref)
    opti.set_initial(u, need)
    opti.solver("ipopt", {"print_time": False}, {"print_level": 0, "max_iter": 1000, "sb": "yes"})
    sol = opti.solve()
    path = np.asarray(sol.value(p))
    err = np.linalg.norm(path - p_ref, axis=0)
    return Bound(float(np.sqrt(np.mean(err**2))), float(np.max(err)), float(np.max(need_deg)),
                 float(np.mean(need_deg > tilt_deg)), path.T)


def figure8(speed: float) -> tuple[PlanarRef, float, float]:
    """bench_tracking's figure-8 at `speed` [m/s]: (ref, period [s], a start past its ramp)."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_tracking import FIG8_DPDPHI_MAX, figure8_reference

    def ref(t: float) -> tuple[FloatArray, FloatArray, FloatArray]:
        r = figure8_reference(t, speed)[0]
        return r.pos_ned[:2], r.vel_ned[:2], r.acc_ned[:2]

    return ref, 2 * math.pi * FIG8_DPDPHI_MAX / speed, 10.0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--speed", type=float, default=6.0, help="figure-8 peak speed [m/s]")
    ap.add_argument("--dm", type=float, nargs="+", default=[1.0, 1.25, 1 / 1.2],
                    help="drag per mass D/m [1/s] (SIH: 1 N/(m/s) over the mass)")
    ap.add_argument("--tilt", type=float, nargs="+", default=[45.0, 50.0], help="limit [deg]")
    args = ap.parse_args(argv)
    ref, period, t0 = figure8(args.speed)
    print("| D/m [1/s] | tilt limit [deg] | reference needs up to [deg] | share above | "
          "least RMS [m] | least max [m] |")
    print("| --- | --- | --- | --- | --- | --- |")
    for tilt in args.tilt:
        for dm in args.dm:
            b = tilt_bound(ref, period, dm, tilt, t0=t0)
            print(f"| {dm:.3f} | {tilt:.0f} | {b.need_max_deg:.1f} | {b.share_over * 100:.0f} % | "
                  f"{b.rms_m:.4f} | {b.max_m:.4f} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
