"""Minimum-snap (or minimum-jerk) piecewise Bezier planning through waypoints.

Formulation (fixed durations). Each segment is a polynomial of degree ``2s - 1`` (s = 4 for
snap, 3 for jerk) written in Hermite form by its derivatives of orders ``0..s-1`` at both ends,
so derivatives up to ``s - 1`` are continuous by construction. The cost
``J = sum_k int ||p^(s)(t)||^2 dt`` is then a quadratic form in the joint derivatives whose
Hessian is block-tridiagonal (joints couple only through the segment between them). Minimising
over the free joint derivatives is one symmetric positive definite banded solve (Cholesky,
``scipy.linalg.solveh_banded``, bandwidth ``2s - 1``): linear in the number of segments and
exact to round-off. At free joints the optimum is additionally continuous in derivatives
``s .. 2s - 2`` (the minimum-snap optimality conditions), exactly as MINCO's.

Time allocation (``durations=None``): trapezoidal speed profile per segment as the initial
guess; refinement of ``sum h + rho J(h)`` with the analytic gradient
``dJ/dh_k = x_k^T (dQ_k/dh_k) x_k`` (envelope theorem at the optimum) by L-BFGS-B; then a
per-segment saturation / feasibility pass that scales each segment's duration to the limit
it is closest to and finally stretches time wherever a limit is still exceeded.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np
import scipy.linalg
import scipy.optimize
from numpy.typing import ArrayLike, NDArray

from companion.trajectory.bezier import FloatArray, PiecewiseBezier, _monomial_matrix, hermite
from companion.trajectory.limits import Limits, RoverLimits, _validate, segment_worst

__all__ = ["PlanResult", "plan", "plan_with_info"]

YawSpec = float | Sequence[float] | NDArray[np.float64] | str | None
DerivSpec = Mapping[int, ArrayLike | None]

#: Safety margin on limits used by the time allocation (sampling cannot see every peak exactly).
ALLOCATION_MARGIN = 0.995
#: Duration of the hover trajectory returned for a single waypoint (s), unless given.
HOVER_DURATION_S = 1.0
_MERGE_TOL_M = 1e-9


# =========================================================================== basis matrices
@lru_cache(maxsize=8)
def _basis(s: int) -> tuple[FloatArray, FloatArray]:
    """(H, Qt) for half-order s: P = H @ x_scaled, J = x_scaled^T Qt x_scaled on [0, 1].

    ``x_scaled`` = [D_0 .. D_{s-1} at start, D_0 .. D_{s-1} at end] in normalised time.
    """
    n = 2 * s - 1
    eye = np.eye(2 * s)
    H = hermite(eye[:s], eye[s:], 1.0).control_points.copy()  # (2s, 2s): column = input
    a = _monomial_matrix(n) @ H  # monomial coefficients in tau of each input
    k = np.arange(s, n + 1)
    fall = np.array([math.factorial(int(i)) / math.factorial(int(i) - s) for i in k])
    B = a[s:, :] * fall[:, None]  # coefficients of q^(s), powers 0..s-1
    p = np.arange(s)
    hilb = 1.0 / (p[:, None] + p[None, :] + 1.0)
    Qt = B.T @ hilb @ B
    Qt = 0.5 * (Qt + Qt.T)
    H.setflags(write=False)
    Qt.setflags(write=False)
    return H, Qt


class _System:
    """Banded minimum-derivative system for a fixed structure (which joint derivatives are
    fixed); ``solve(h)`` can be called repeatedly with new durations."""

    def __init__(self, fixed_mask: NDArray[np.bool_], fixed_vals: FloatArray, s: int) -> None:
        self.s = s
        self.n_joints = fixed_mask.shape[0]
        self.m = self.n_joints - 1
        self.d = fixed_vals.shape[2]
        self.H, self.Qt = _basis(s)
        o = np.tile(np.arange(s), 2).astype(np.float64)
        self.o = o
        self.expo = 1.0 - 2.0 * s + o[:, None] + o[None, :]
        free = ~fixed_mask.reshape(-1)
        self.free = free
        self.nf = int(free.sum())
        fmap = np.full(free.shape[0], -1, dtype=np.int64)
        fmap[free] = np.arange(self.nf)
        self.x0 = np.where(free[:, None], 0.0, fixed_vals.reshape(-1, self.d))
        self.gidx = np.arange(self.m)[:, None] * s + np.arange(2 * s)[None, :]  # (M, 2s)
        fa = fmap[self.gidx]
        ai = fa[:, :, None]
        bj = fa[:, None, :]
        self.u = 2 * s - 1
        mask = (ai >= 0) & (bj >= 0) & (ai <= bj)
        self.band_mask = mask
        self.band_flat = ((self.u + ai - bj) * self.nf + bj)[mask] if self.nf else None
        self.fa = fa
        self.free_rows = fa >= 0  # (M, 2s)

    def solve(self, h: FloatArray) -> tuple[FloatArray, float]:
        """Joint derivatives x (n_joints * s, d) and cost J for durations h (M,)."""
        s, d = self.s, self.d
        Q = self.Qt[None, :, :] * h[:, None, None] ** self.expo[None, :, :]
        x = self.x0.copy()
        if self.nf:
            xk = x[self.gidx]
            y = Q @ xk
            rows = self.fa[self.free_rows]
            rhs = np.empty((self.nf, d))
            yf = y[self.free_rows]
            for c in range(d):
                rhs[:, c] = -np.bincount(rows, weights=yf[:, c], minlength=self.nf)
            ab = np.bincount(
                self.band_flat, weights=Q[self.band_mask], minlength=(self.u + 1) * self.nf
            ).reshape(self.u + 1, self.nf)
            # Jacobi scaling for conditioning across very different durations
            diag = ab[self.u]
            if np.any(diag <= 0.0):
                raise ValueError(
                    "the trajectory is under-determined: some free derivative does not affect "
                    "the cost (fix more boundary derivatives)"
                )
            sc = 1.0 / np.sqrt(diag)
            for r in range(self.u + 1):
                off = self.u - r  # ab[r, j] = A[j - off, j]
                if off >= self.nf:
                    continue
                ab[r, off:] *= sc[: self.nf - off] * sc[off:]
            try:
                z = scipy.linalg.solveh_banded(ab, rhs * sc[:, None], check_finite=False)
            except np.linalg.LinAlgError as exc:
                raise ValueError(
                    "the trajectory problem is singular (under-determined free derivatives)"
                ) from exc
            x[self.free] = z * sc[:, None]
        xk = x[self.gidx]
        cost = float(np.sum(xk * (Q @ xk)))
        return x, cost

    def cost_grad(self, x: FloatArray, h: FloatArray) -> FloatArray:
        """dJ*/dh (M,) at the optimum x (envelope theorem: fixed joint derivatives)."""
        dQ = self.Qt[None] * (self.expo[None] * h[:, None, None] ** (self.expo[None] - 1.0))
        xk = x[self.gidx]
        return np.asarray(np.sum(xk * (dQ @ xk), axis=(1, 2)), dtype=np.float64)

    def control_points(self, x: FloatArray, h: FloatArray) -> FloatArray:
        """Bezier control points (M, 2s, d) of the segments."""
        xk = x[self.gidx] * (h[:, None] ** self.o[None, :])[:, :, None]
        return np.asarray(self.H @ xk, dtype=np.float64)


# =========================================================================== input checks
def _vec(value: ArrayLike, d: int, what: str) -> FloatArray:
    v = np.asarray(value, dtype=np.float64).reshape(-1)
    if v.shape[0] != d:
        raise ValueError(f"{what} must have {d} components, got {v.shape[0]}")
    if not np.all(np.isfinite(v)):
        raise ValueError(f"{what} is not finite: {v.tolist()}")
    return v


def _orders(spec: DerivSpec | None, s: int, d: int, what: str) -> dict[int, FloatArray | None]:
    out: dict[int, FloatArray | None] = {}
    if spec is None:
        return out
    if not isinstance(spec, Mapping):
        raise ValueError(f"{what} must be a mapping {{order: vector}}, e.g. {{1: [1, 0, 0]}}")
    for order, value in spec.items():
        if not isinstance(order, int | np.integer) or not 1 <= int(order) <= s - 1:
            raise ValueError(
                f"{what}: derivative order {order!r} is not allowed (use 1..{s - 1}: "
                f"velocity..{'jerk' if s == 4 else 'acceleration'})"
            )
        names = {1: "velocity", 2: "acceleration", 3: "jerk"}
        out[int(order)] = (
            None if value is None else _vec(value, d, f"{what} {names[int(order)]}")
        )
    return out


def _check_waypoints(waypoints: ArrayLike) -> FloatArray:
    try:
        wp = np.array(waypoints, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"waypoints must be a numeric array of shape (M, 2) or (M, 3): {exc}")
    if wp.ndim != 2 or wp.shape[1] not in (2, 3):
        raise ValueError(
            f"waypoints must have shape (M, 2) for a rover or (M, 3) for a multirotor, "
            f"got {wp.shape}"
        )
    if wp.shape[0] < 1:
        raise ValueError("at least one waypoint is needed")
    bad = ~np.all(np.isfinite(wp), axis=1)
    if np.any(bad):
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(f"waypoint {i} has a non-finite coordinate: {wp[i].tolist()}")
    return wp


# =========================================================================== time allocation
def _trapezoid_durations(lengths: FloatArray, vmax: float, amax: float) -> FloatArray:
    """Rest-to-rest time (s) of a trapezoidal (or triangular) speed profile per segment."""
    full = lengths >= vmax * vmax / amax
    return np.where(full, lengths / vmax + vmax / amax, 2.0 * np.sqrt(lengths / amax))


def _scale_factor(name: str, ratio: FloatArray) -> FloatArray:
    """Time-scale factor per segment that would bring the value to the limit (heuristic)."""
    power = {"speed": 1.0, "acc": 0.5, "jerk": 1.0 / 3.0, "tilt": 0.5, "max_thrust": 0.5,
             "min_thrust": 0.5, "body_rate": 1.0 / 3.0, "yaw_rate": 1.0, "lat_acc": 0.5}[name]
    return np.asarray(np.maximum(ratio, 1e-6) ** power, dtype=np.float64)


def _ratios(
    worst: dict[str, FloatArray], limits: Limits | RoverLimits, params: Any
) -> dict[str, FloatArray]:
    """Per-segment 'value / allowed' ratio of each limit (>1 means exceeded)."""
    out: dict[str, FloatArray] = {}
    margin = ALLOCATION_MARGIN
    for name, v in worst.items():
        if name == "tilt":
            lim = float(limits.max_tilt_rad) * margin  # type: ignore[union-attr,arg-type]
            out[name] = np.tan(np.minimum(v, 1.5)) / math.tan(lim)
        elif name in ("max_thrust", "min_thrust"):
            mg = float(params.mass) * float(params.g)
            if name == "max_thrust":
                cap = float(limits.max_thrust_n) * margin  # type: ignore[union-attr,arg-type]
                out[name] = np.maximum(v - mg, 0.0) / max(cap - mg, 1e-9)
            else:
                floor = float(limits.min_thrust_n) / margin  # type: ignore[union-attr,arg-type]
                out[name] = np.maximum(mg - v, 0.0) / max(mg - floor, 1e-9)
        else:
            attr = {
                "speed": "max_speed_m_s",
                "acc": "max_acc_m_s2",
                "jerk": "max_jerk_m_s3",
                "body_rate": "max_body_rate_rad_s",
                "yaw_rate": "max_yaw_rate_rad_s",
                "lat_acc": "max_lat_acc_m_s2",
            }[name]
            out[name] = v / (float(getattr(limits, attr)) * margin)
    return out


@dataclass(frozen=True)
class PlanResult:
    """A plan with diagnostics: the trajectory, its cost J (integral of the squared snap or
    jerk, SI) and the number of fixed-duration solves used by the time allocation."""

    trajectory: PiecewiseBezier
    cost: float
    solves: int


class _Planner:
    def __init__(
        self,
        wp: FloatArray,
        s: int,
        start: dict[int, FloatArray | None],
        end: dict[int, FloatArray | None],
        interior: dict[int, dict[int, FloatArray | None]],
        yaw: YawSpec,
        yaw_wp: FloatArray | None,
    ) -> None:
        self.wp = wp
        self.s = s
        n_j, d = wp.shape
        mask = np.zeros((n_j, s), dtype=bool)
        vals = np.zeros((n_j, s, d))
        mask[:, 0] = True
        vals[:, 0, :] = wp
        for j in range(1, s):
            for idx, spec in ((0, start), (n_j - 1, end)):
                v = spec[j] if j in spec else np.zeros(d)
                if v is not None:
                    mask[idx, j] = True
                    vals[idx, j] = v
        for idx, spec_i in interior.items():
            for j, v in spec_i.items():
                if v is not None:
                    mask[idx, j] = True
                    vals[idx, j] = v
        self.system = _System(mask, vals, s)
        self.yaw = yaw
        self.yaw_wp = yaw_wp
        self.solves = 0

    def solve(self, h: FloatArray) -> tuple[FloatArray, float]:
        self.solves += 1
        return self.system.solve(h)

    def build(self, h: FloatArray) -> tuple[PiecewiseBezier, float]:
        x, cost = self.solve(h)
        cp = self.system.control_points(x, h)
        traj = PiecewiseBezier.from_control_points(cp, h)
        yaw_traj = _yaw_channel(self.wp, x.reshape(-1, self.s, traj.dim), h, self.s,
                                self.yaw, self.yaw_wp)
        if yaw_traj is not None:
            traj = traj.with_yaw(yaw_traj)
        return traj, cost

    # ------------------------------------------------------------------ allocation
    def allocate(
        self, limits: Limits | RoverLimits, params: Any
    ) -> FloatArray:
        wp = self.wp
        lengths = np.linalg.norm(np.diff(wp, axis=0), axis=1)
        vmax = limits.max_speed_m_s
        amax = limits.max_lat_acc_m_s2 if isinstance(limits, RoverLimits) else limits.max_acc_m_s2
        h0 = _trapezoid_durations(lengths, vmax, amax)
        import os
        if os.environ.get("NOREF"):
            h = h0
        else:
            h = self._refine(h0)
        h = self._saturate(h, limits, params)
        h = self._balance(h, limits, params, int(os.environ.get("NBAL", "0")))
        return h

    def _balance(
        self, h: FloatArray, limits: Limits | RoverLimits, params: Any, iterations: int
    ) -> FloatArray:
        """Shorten segments that have slack (their most active limit below its value), keeping
        every limit satisfied; accept a step only when the total time decreases."""
        ok, factor = self._feasible(h, limits, params)
        step = 0.5
        for _ in range(iterations):
            trial = h * np.clip(factor, 0.5, 1.0) ** step
            ok_t, f_t = self._feasible(trial, limits, params)
            tries = 0
            while not ok_t and tries < 6:
                trial = trial * np.maximum(f_t, 1.0) ** 1.0 * np.where(f_t > 1.0, 1.002, 1.0)
                ok_t, f_t = self._feasible(trial, limits, params)
                tries += 1
            if ok_t and trial.sum() < h.sum() * (1.0 - 1e-4):
                h, factor = trial, f_t
            else:
                step *= 0.5
                if step < 0.05:
                    break
        return h

    def _refine(self, h0: FloatArray) -> FloatArray:
        """Minimise sum(h) + rho J(h) (analytic gradient), rho balancing the initial guess."""
        _, j0 = self.solve(h0)
        if not np.isfinite(j0) or j0 <= 0.0:
            return h0
        t0 = float(h0.sum())
        rho = t0 / ((2 * self.s - 1) * j0)
        lz = np.log(h0)

        def fun(z: FloatArray) -> tuple[float, FloatArray]:
            h = np.exp(z)
            x, j = self.solve(h)
            g = 1.0 + rho * self.system.cost_grad(x, h)
            return float(h.sum() + rho * j) / t0, g * h / t0

        res = scipy.optimize.minimize(
            fun,
            lz,
            jac=True,
            method="L-BFGS-B",
            bounds=[(z - 2.0, z + 2.0) for z in lz],
            options={"maxiter": 60, "gtol": 1e-6},
        )
        return np.exp(np.asarray(res.x, dtype=np.float64))

    def _feasible(
        self, h: FloatArray, limits: Limits | RoverLimits, params: Any
    ) -> tuple[bool, FloatArray]:
        """Whether durations h satisfy every limit (sampled, with margin) and the per-segment
        time-scale factor that would bring each segment to its most active limit."""
        traj, _ = self.build(h)
        ratios = _ratios(segment_worst(traj, limits, params), limits, params)
        factor = np.full(h.shape[0], 1e-6)
        for name, r in ratios.items():
            factor = np.maximum(factor, _scale_factor(name, r))
        return bool(np.all(factor <= 1.0)), factor

    def _saturate(
        self, h: FloatArray, limits: Limits | RoverLimits, params: Any
    ) -> FloatArray:
        """Scale all durations by the smallest common factor that satisfies every limit
        (bisection; a uniform time scaling keeps the path shape), then stretch locally where a
        limit is still exceeded."""
        ok, factor = self._feasible(h, limits, params)
        # bracket [lo (infeasible), hi (feasible)] around the factor predicted by the ratios
        guess = float(np.max(factor))
        lo, hi = None, None
        alpha = guess
        for _ in range(40):
            ok, factor = self._feasible(h * alpha, limits, params)
            if ok:
                hi = alpha
                if lo is not None:
                    break
                alpha *= 0.9
                lo_try = alpha
                ok2, _ = self._feasible(h * lo_try, limits, params)
                if not ok2:
                    lo = lo_try
                    break
                hi = lo_try
                alpha = lo_try * 0.9
            else:
                lo = alpha
                if hi is not None:
                    break
                alpha *= max(1.1, float(np.max(factor)))
        if hi is None:
            raise ValueError("time allocation could not satisfy the limits (check their values)")
        if lo is not None:
            for _ in range(10):
                mid = math.sqrt(lo * hi)
                if self._feasible(h * mid, limits, params)[0]:
                    hi = mid
                else:
                    lo = mid
                if hi / lo < 1.002:
                    break
        return h * hi


# =========================================================================== yaw channel
def _wrap_pi(a: FloatArray) -> FloatArray:
    return np.asarray((a + np.pi) % (2.0 * np.pi) - np.pi, dtype=np.float64)


def _unwrap_sequence(yaw: FloatArray) -> FloatArray:
    """Unwrap so that each step is the short way round (|step| <= pi)."""
    out = yaw.astype(np.float64).copy()
    for k in range(1, out.shape[0]):
        out[k] = out[k - 1] + float(_wrap_pi(np.array(yaw[k] - out[k - 1])))
    return out


def _solve_1d(
    values: FloatArray, h: FloatArray, s: int, mask_extra: NDArray[np.bool_] | None = None,
    vals_extra: FloatArray | None = None,
) -> PiecewiseBezier:
    n_j = values.shape[0]
    mask = np.zeros((n_j, s), dtype=bool)
    vals = np.zeros((n_j, s, 1))
    mask[:, 0] = True
    vals[:, 0, 0] = values
    mask[0, :] = True
    mask[-1, :] = True
    if mask_extra is not None and vals_extra is not None:
        mask |= mask_extra
        vals[mask_extra] = vals_extra[mask_extra]
    sys_ = _System(mask, vals, s)
    x, _ = sys_.solve(h)
    return PiecewiseBezier.from_control_points(sys_.control_points(x, h), h)


def _heading_at_joints(derivs: FloatArray, wp: FloatArray) -> tuple[FloatArray, FloatArray,
                                                                     FloatArray]:
    """Heading psi = atan2(v_y, v_x), its rate and acceleration at the joints (rad, rad/s,
    rad/s^2). Where the horizontal speed vanishes the direction of the first non-zero
    derivative (or of the neighbouring waypoint) is used and the rates are zero."""
    n_j = derivs.shape[0]
    s = derivs.shape[1]
    psi = np.zeros(n_j)
    rate = np.zeros(n_j)
    acc = np.zeros(n_j)
    scale = max(float(np.max(np.abs(derivs[:, 1, :2]))), 1e-9)
    for k in range(n_j):
        v = derivs[k, 1, :2]
        a = derivs[k, 2, :2] if s > 2 else np.zeros(2)
        j = derivs[k, 3, :2] if s > 3 else np.zeros(2)
        V2 = float(v @ v)
        if V2 > (1e-6 * scale) ** 2:
            psi[k] = math.atan2(v[1], v[0])
            cross = v[0] * a[1] - v[1] * a[0]
            dot = v[0] * a[0] + v[1] * a[1]
            rate[k] = cross / V2
            acc[k] = ((v[0] * j[1] - v[1] * j[0]) * V2 - 2.0 * cross * dot) / (V2 * V2)
            continue
        direction = None
        for order in range(2, s):
            w = derivs[k, order, :2]
            if float(w @ w) > 1e-18:
                direction = w
                break
        if direction is None:
            other = wp[k + 1] if k + 1 < n_j else wp[k - 1] if k > 0 else wp[k]
            diff = (other - wp[k])[:2]
            if k + 1 >= n_j:
                diff = -diff
            direction = diff if float(diff @ diff) > 0.0 else np.array([1.0, 0.0])
        psi[k] = math.atan2(direction[1], direction[0])
    return psi, rate, acc


def _yaw_channel(
    wp: FloatArray,
    derivs: FloatArray,
    h: FloatArray,
    s: int,
    yaw: YawSpec,
    yaw_wp: FloatArray | None,
) -> PiecewiseBezier | None:
    if yaw is None:
        return None
    m = h.shape[0]
    if isinstance(yaw, str):
        psi, rate, acc = _heading_at_joints(derivs, wp)
        psi_u = psi.copy()
        for k in range(1, psi.shape[0]):
            psi_u[k] = psi_u[k - 1] + float(_wrap_pi(np.array(psi[k] - psi_u[k - 1])))
        n_j = m + 1
        mask = np.zeros((n_j, s), dtype=bool)
        vals = np.zeros((n_j, s, 1))
        mask[:, 1] = True
        vals[:, 1, 0] = rate
        if s > 3:  # the heading acceleration needs the jerk, known only for snap plans
            mask[:, 2] = True
            vals[:, 2, 0] = acc
        return _solve_1d(psi_u, h, s, mask, vals)
    if yaw_wp is None:
        raise AssertionError("per-waypoint yaw missing")  # pragma: no cover
    if yaw_wp.shape[0] == 1:
        cp = np.full((m, 2 * s, 1), float(yaw_wp[0]))
        return PiecewiseBezier.from_control_points(cp, h)
    return _solve_1d(_unwrap_sequence(yaw_wp), h, s)


# =========================================================================== public API
def plan(
    waypoints: ArrayLike,
    *,
    durations: ArrayLike | None = None,
    order: str = "snap",
    start: DerivSpec | None = None,
    end: DerivSpec | None = None,
    constraints: Mapping[int, DerivSpec] | None = None,
    limits: Limits | RoverLimits | None = None,
    params: Any = None,
    yaw: YawSpec = None,
) -> PiecewiseBezier:
    """Plan a minimum-snap (``order="snap"``, degree 7, C4+) or minimum-jerk (``"jerk"``,
    degree 5, C3+) piecewise Bezier trajectory through ``waypoints`` (M, d), d = 2 or 3, metres
    (NED for a multirotor).

    - ``durations`` (M-1,) seconds per segment; None: time allocation under ``limits``.
    - ``start`` / ``end``: ``{order: vector}`` boundary derivatives (1 = velocity,
      2 = acceleration, 3 = jerk); unspecified ones are zero (rest); ``None`` leaves one free.
    - ``constraints``: ``{waypoint index: {order: vector}}`` fixed derivatives at interior
      waypoints (fixing jerk of a snap plan there lets the snap jump at that waypoint).
    - ``limits``: :class:`Limits` (multirotor) or :class:`RoverLimits` (d = 2); ``params`` a
      ``MultirotorParams`` for tilt, thrust and body-rate limits.
    - ``yaw``: None (no yaw channel), a float (fixed yaw, rad), M per-waypoint yaws (rad,
      unwrapped the short way round), or ``"velocity"`` (follow the horizontal velocity
      heading: matched in value, rate and acceleration at every waypoint).

    Consecutive duplicate waypoints are merged with a warning; a single waypoint gives a hover
    trajectory of ``HOVER_DURATION_S`` (or ``durations[0]``). Raises ValueError with the
    offending waypoint on bad input.
    """
    return plan_with_info(
        waypoints,
        durations=durations,
        order=order,
        start=start,
        end=end,
        constraints=constraints,
        limits=limits,
        params=params,
        yaw=yaw,
    ).trajectory


def plan_with_info(
    waypoints: ArrayLike,
    *,
    durations: ArrayLike | None = None,
    order: str = "snap",
    start: DerivSpec | None = None,
    end: DerivSpec | None = None,
    constraints: Mapping[int, DerivSpec] | None = None,
    limits: Limits | RoverLimits | None = None,
    params: Any = None,
    yaw: YawSpec = None,
) -> PlanResult:
    """:func:`plan` returning a :class:`PlanResult` (trajectory, cost, number of solves)."""
    wp = _check_waypoints(waypoints)
    n_in, d = wp.shape
    if order not in ("snap", "jerk"):
        raise ValueError(f'order must be "snap" or "jerk", got {order!r}')
    s = 4 if order == "snap" else 3
    start_spec = _orders(start, s, d, "start")
    end_spec = _orders(end, s, d, "end")
    interior_in: dict[int, dict[int, FloatArray | None]] = {}
    if constraints is not None:
        if not isinstance(constraints, Mapping):
            raise ValueError("constraints must be a mapping {waypoint index: {order: vector}}")
        for idx, spec in constraints.items():
            if not isinstance(idx, int | np.integer) or not 0 < int(idx) < n_in - 1:
                raise ValueError(
                    f"constraint at waypoint {idx!r}: only interior waypoints 1..{n_in - 2} take "
                    f"constraints (use start/end for the first and last)"
                )
            interior_in[int(idx)] = _orders(spec, s, d, f"waypoint {idx}")
    if limits is not None:
        if isinstance(limits, RoverLimits) and d != 2:
            raise ValueError("RoverLimits need 2-D waypoints (x, y)")
        if not isinstance(limits, Limits | RoverLimits):
            raise ValueError("limits must be Limits or RoverLimits")
        if isinstance(limits, Limits) and limits.needs_params:
            if params is None:
                raise ValueError(
                    "tilt, thrust and body-rate limits need params=MultirotorParams(...)"
                )
            if d != 3:
                raise ValueError("tilt, thrust and body-rate limits need 3-D waypoints")
            if limits.max_thrust_n is not None and (
                limits.max_thrust_n <= float(params.mass) * float(params.g)
            ):
                raise ValueError(
                    f"max_thrust_n = {limits.max_thrust_n} N cannot hover the "
                    f"{params.mass} kg vehicle (needs more than m g = "
                    f"{float(params.mass) * float(params.g):.2f} N)"
                )
            if limits.min_thrust_n is not None and (
                limits.min_thrust_n >= float(params.mass) * float(params.g)
            ):
                raise ValueError(
                    f"min_thrust_n = {limits.min_thrust_n} N is above the hover thrust m g"
                )
    # yaw spec
    yaw_wp: FloatArray | None = None
    if isinstance(yaw, str):
        if yaw != "velocity":
            raise ValueError(f'yaw must be None, a number, per-waypoint values or "velocity", '
                             f"got {yaw!r}")
    elif yaw is not None:
        ya = np.asarray(yaw, dtype=np.float64).reshape(-1)
        if ya.shape[0] == 1:
            if not np.isfinite(ya[0]):
                raise ValueError(f"yaw is not finite: {ya[0]}")
        elif ya.shape[0] != n_in:
            raise ValueError(f"yaw has {ya.shape[0]} values for {n_in} waypoints")
        else:
            bad = ~np.isfinite(ya)
            if np.any(bad):
                i = int(np.flatnonzero(bad)[0])
                raise ValueError(f"waypoint {i} has a non-finite yaw: {ya[i]}")
        yaw_wp = ya
    # durations
    h_in: FloatArray | None = None
    if durations is not None:
        h_in = np.asarray(durations, dtype=np.float64).reshape(-1)
        expected = max(n_in - 1, 1) if n_in == 1 else n_in - 1
        if n_in == 1 and h_in.shape[0] == 0:
            h_in = None
        elif h_in.shape[0] != expected:
            raise ValueError(f"{n_in} waypoints need {n_in - 1} durations, got {h_in.shape[0]}")
        if h_in is not None:
            bad = ~np.isfinite(h_in) | (h_in <= 0.0)
            if np.any(bad):
                i = int(np.flatnonzero(bad)[0])
                raise ValueError(
                    f"duration {h_in[i]} of the segment from waypoint {i} to {i + 1} must be a "
                    f"finite positive number of seconds"
                )
    # merge consecutive duplicates
    same = (
        np.max(np.abs(np.diff(wp, axis=0)), axis=1) <= _MERGE_TOL_M
        if n_in > 1
        else np.zeros(0, dtype=bool)
    )
    keep = list(range(n_in)) if not np.any(same) else [0]
    merged_segments: list[int] = []
    if np.any(same):
        for i in range(1, n_in):
            if not same[i - 1]:
                keep.append(i)
                continue
            warnings.warn(
                f"waypoint {i} duplicates waypoint {keep[-1]}; merged", UserWarning, stacklevel=3
            )
            if i in interior_in:
                if keep[-1] in interior_in and keep[-1] != 0:
                    raise ValueError(
                        f"waypoints {keep[-1]} and {i} coincide and both carry constraints"
                    )
                if keep[-1] != 0:
                    interior_in[keep[-1]] = interior_in[i]
                del interior_in[i]
            merged_segments.append(i - 1)
    if len(keep) < n_in:
        if keep[-1] != n_in - 1:
            # the last waypoint merged into an earlier one: interior constraints there are moot
            interior_in.pop(keep[-1], None)
        remap = {old: new for new, old in enumerate(keep)}
        interior = {remap[k]: v for k, v in interior_in.items() if k in remap}
        interior = {k: v for k, v in interior.items() if 0 < k < len(keep) - 1}
        wp = wp[keep]
        if yaw_wp is not None and yaw_wp.shape[0] == n_in:
            yaw_wp = yaw_wp[keep]
        if h_in is not None:
            # the time of a merged zero-length segment goes to the previous kept segment
            # (or the next one when it is the first)
            h_new = h_in.copy()
            merged = set(merged_segments)
            kept = [k for k in range(h_in.shape[0]) if k not in merged]
            for seg in merged_segments:
                if kept:
                    before = [k for k in kept if k < seg]
                    target = before[-1] if before else kept[0]
                    h_new[target] += h_in[seg]
            h_in = h_new[kept] if kept else None
    else:
        interior = interior_in
    n_j = wp.shape[0]

    if n_j == 1:
        if any(v is not None and np.any(v != 0) for v in (*start_spec.values(),
                                                            *end_spec.values())):
            raise ValueError("a single waypoint gives a hover: start/end derivatives must be 0")
        hover = float(h_in.sum()) if h_in is not None else HOVER_DURATION_S
        cp = np.repeat(wp[None, :, :], 2 * s, axis=1)
        h = np.array([hover])
        traj = PiecewiseBezier.from_control_points(cp, h)
        if yaw is not None:
            psi0 = float(yaw_wp[0]) if yaw_wp is not None else 0.0
            traj = traj.with_yaw(
                PiecewiseBezier.from_control_points(np.full((1, 2 * s, 1), psi0), h)
            )
        return PlanResult(traj, 0.0, 0)

    planner = _Planner(wp, s, start_spec, end_spec, interior, yaw, yaw_wp)
    if h_in is None:
        if limits is None:
            raise ValueError("give either durations or limits (for the time allocation)")
        h = planner.allocate(limits, params)
    else:
        h = h_in
    traj, cost = planner.build(h)
    if limits is not None:
        _validate(traj, limits, params)
    return PlanResult(traj, cost, planner.solves)
