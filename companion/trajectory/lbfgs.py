"""Projected L-BFGS over a box, pure numpy (the time allocation's optimiser)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from companion.trajectory.bezier import FloatArray

__all__ = ["projected_lbfgs"]


def projected_lbfgs(
    fun: Callable[[FloatArray], tuple[float, Callable[[], FloatArray]]],
    x0: FloatArray,
    lo: FloatArray,
    hi: FloatArray,
    maxiter: int,
    ftol: float = 1e-5,
    gtol: float = 1e-6,
    memory: int = 8,
) -> FloatArray:
    """Minimise a smooth function over the box [lo, hi]: L-BFGS directions (two-loop
    recursion), components pushing into an active bound dropped, projected backtracking
    (Armijo) line search. ``fun(x)`` returns the value and a thunk computing the gradient at
    x, called only for points the line search accepts (and before ``fun`` is called again).
    Pure numpy on 1-D vectors (dot products only): unlike scipy's L-BFGS-B it makes no
    multi-threaded BLAS calls, which slow these small problems down by an order of
    magnitude."""
    x = np.minimum(np.maximum(x0, lo), hi)
    f, grad = fun(x)
    g = grad()
    hist: list[tuple[FloatArray, FloatArray, float]] = []
    for _ in range(maxiter):
        q = g.copy()
        alphas = []
        for s_, y_, r_ in reversed(hist):
            a = r_ * float(s_ @ q)
            q -= a * y_
            alphas.append(a)
        if hist:
            s_, y_, _ = hist[-1]
            q *= float(s_ @ y_) / float(y_ @ y_)
        else:
            q *= 1.0 / max(float(np.abs(g).max()), 1e-12)
        for (s_, y_, r_), a in zip(hist, reversed(alphas), strict=True):
            b = r_ * float(y_ @ q)
            q += (a - b) * s_
        d = -q
        at_lo = x <= lo
        at_hi = x >= hi
        d[(at_lo & (d < 0.0)) | (at_hi & (d > 0.0))] = 0.0
        slope = float(g @ d)
        if slope >= 0.0:  # not a descent direction: restart from the projected gradient
            hist.clear()
            d = -g / max(float(np.abs(g).max()), 1e-12)
            d[(at_lo & (d < 0.0)) | (at_hi & (d > 0.0))] = 0.0
            slope = float(g @ d)
            if slope >= 0.0:
                break
        step = 1.0
        for _ in range(30):
            xn = np.minimum(np.maximum(x + step * d, lo), hi)
            fn, grad = fun(xn)
            if fn <= f + 1e-4 * float(g @ (xn - x)):
                break
            step *= 0.5
        else:
            break
        gn = grad()
        s_ = xn - x
        y_ = gn - g
        sy = float(s_ @ y_)
        if sy > 1e-12 * float(y_ @ y_):
            hist.append((s_, y_, 1.0 / sy))
            if len(hist) > memory:
                hist.pop(0)
        converged = f - fn <= ftol * max(abs(f), abs(fn), 1.0)
        x, f, g = xn, fn, gn
        if converged:
            break
        free = ~(((x <= lo) & (g > 0.0)) | ((x >= hi) & (g < 0.0)))
        if not free.any() or float(np.abs(g[free]).max()) <= gtol:
            break
    return np.asarray(x, dtype=np.float64)

