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

Time allocation (``durations=None``). Each waypoint leg is split into ``ALLOCATION_PIECES``
segments whose extra joints lie on the straight leg. (1) Initial guess: a trapezoidal speed
profile along the polyline (rest at the ends, a corner speed at each waypoint from its turn
angle, forward-backward acceleration passes). (2) Refinement: projected L-BFGS over log-durations of
``sum h + rho J(h) + w P(h)``, P a smooth sampled penalty of the limit violations (speed,
acceleration, jerk, tilt, thrust), with the analytic gradient: ``dJ/dh_k = x_k^T (dQ_k/dh_k)
x_k`` (envelope theorem at the optimum) and dP/dh through one adjoint solve of the same banded
system (computed only for the points the line search accepts). (3) Saturation: the smallest
uniform time scaling that satisfies every limit (bisection; a uniform scaling keeps the path,
so speed, acceleration and jerk scale in closed form and only tilt, thrust and body rate are
recomputed). (4) Feasibility pass: stretch the segments where a limit is still exceeded (by
re-solved dense sampling, ``limits.SAMPLES_PER_SEGMENT`` per segment), until every limit holds.

Rover (:class:`RoverLimits`). Yaw rate ``|v x a| / V^2`` and lateral acceleration
``|v x a| / V`` peak sharply where the path turns while the speed dips (near a sharp corner
the minimum-snap path can nearly stop and swing round): such peaks are far narrower than any
fixed sampling grid and hypersensitive to round-off, which is what made the former
penalty-plus-local-stretch scheme miss violations, fail ("could not satisfy the limits") and
swing between runs. Rovers therefore use ``ROVER_ALLOCATION_PIECES`` (1) segment per leg,
refine ``sum h + rho J`` only (no sampled penalty: a smooth objective, deterministic), and
meet the limits by one exact uniform time scaling of the shorter of the refined and initial
durations: the maxima come from the critical points of each segment's polynomials
(``limits.rover_extrema``), and scaling all durations by k keeps the path while speed and yaw
rate scale by 1/k and lateral acceleration by 1/k^2 (``_Planner._rover_stretch``), so the
result always exists and meets every limit.

Corridor (``corridor_m``, multirotor). The segments that leave the corridor are split in three
on their leg; the split is decided on the refinement's durations (before the saturation, which
rescales them mostly uniformly and so keeps the path's shape), and the refinement of the new
joint set is warm-started from the previous durations (a split segment's duration shared by
its pieces), for as many iterations as the share of split segments calls for
(``_warm_iterations``); the saturation then runs once, and a path that still leaves the
corridor after it is split and re-allocated again (warm-started).

Cost. One refinement is capped at ``REFINE_WORK_BUDGET`` iterations x segments (plans of up to
300 segments get the full ``REFINE_MAXITER``). The feasibility passes look at 16 samples per
segment first and at the dense ``limits.SAMPLES_PER_SEGMENT`` only when those pass. 100
waypoints, 297 segments, all multirotor limits: about 55 fixed-duration solves, each with one
penalty evaluation of 8 samples per segment. All samples of all segments are evaluated
with one matrix product per step (no per-segment Python loops, no multi-threaded BLAS), and the
body rate goes through the flatness map only at samples where a cheap attitude-free upper bound
(``limits._body_rate_bound``) comes within the margin of the limit. See BENCHMARKS.md
("Planner") for timings.
"""

from __future__ import annotations

import itertools
import math
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np
import scipy.linalg
import scipy.linalg.lapack
from numpy.typing import ArrayLike, NDArray

from companion.trajectory.bezier import FloatArray, PiecewiseBezier, _monomial_matrix, hermite
from companion.trajectory.limits import (
    Limits,
    RoverLimits,
    TimeScaledRatio,
    _validate,
    axis_acc_ratio,
    axis_ratio,
    rover_extrema,
    segment_samples,
    segment_worst,
    thin_matmul,
)

__all__ = ["PlanResult", "plan", "plan_with_info", "velocity_heading"]

YawSpec = float | Sequence[float] | NDArray[np.float64] | str | None
DerivSpec = Mapping[int, ArrayLike | None]

#: Safety margin on limits used by the time allocation (sampling cannot see every peak exactly).
ALLOCATION_MARGIN = 0.995
#: Pieces per waypoint leg used by the time allocation (intermediate joints on the straight leg
#: give the speed profile room to accelerate, cruise and brake).
ALLOCATION_PIECES = 3
#: Time-allocation objective sum(h) + rho J + w P: rho relative to the initial guess, w, and
#: the L-BFGS iteration cap. Multirotor: a moderate w keeps the problem well conditioned, so
#: L-BFGS gets there in fewer iterations (the saturation and feasibility passes enforce the
#: limits exactly afterwards). Rover: no penalty (w = 0, a smooth objective whose optimum
#: moves continuously with the waypoints); the limits are then met by an exact uniform time
#: scaling (see ``_Planner._allocate_rover``).
REFINE_RHO = 0.01
REFINE_PENALTY_WEIGHT = 1e3
REFINE_MAXITER = 45
ROVER_REFINE_MAXITER = 60
#: Pieces per waypoint leg of a time-allocated rover plan: joints pinned on the straight legs
#: force tight turns at sharp corners, which the yaw-rate limit then slows down (about 2.7x
#: longer plans with 3 pieces on random 8-10 waypoint sets).
ROVER_ALLOCATION_PIECES = 1
#: Rover: passes that shorten the segments with slack (exact per-segment ratio < 1) before
#: the uniform scaling again; kept only while the total duration drops.
ROVER_LOCAL_PASSES = 6
REFINE_FTOL = 1e-5
#: Work cap of one multirotor refinement: iterations x segments (each iteration costs a
#: banded solve and a penalty evaluation per segment). Plans of up to
#: REFINE_WORK_BUDGET / REFINE_MAXITER segments get REFINE_MAXITER iterations; larger ones
#: fewer, at least REFINE_MIN_ITER (planning time stays bounded on long missions).
REFINE_WORK_BUDGET = 13_500
REFINE_MIN_ITER = 10


#: Warm-started refinement after a corridor split of a plan over the full work budget: the
#: budget times this multiple of the share of segments split, at least REFINE_WARM_FLOOR
#: (plans within the budget keep every iteration, see ``_warm_iterations``).
REFINE_WARM_GAIN = 3.0
REFINE_WARM_FLOOR = 6_750
#: yaw="velocity": heading samples per segment and smoothing time as a fraction of the median
#: segment duration (see ``_heading_fit``).
HEADING_SAMPLES_PER_SEGMENT = 16
VELOCITY_YAW_SMOOTHING = 0.1
#: Samples per segment of the feasibility passes' first look (see ``_Planner._max_ratio``).
COARSE_SAMPLES_PER_SEGMENT = 16
#: Samples per segment while bisecting the common time scale (final checks use more).
BISECTION_SAMPLES_PER_SEGMENT = 16
#: The multirotor feasibility pass stretches the offending segments only while the worst
#: limit ratio stays below this multiple of the best seen; beyond it the local stretch is
#: distorting the path and the pass falls back to uniform scaling.
LOCAL_STRETCH_GIVE_UP = 1.25
#: Jerk penalised in the allocation per rad/s of the body-rate limit, in units of g.
BODY_RATE_JERK_PROXY = 0.8
#: Passes of the multirotor local stretch tried before the uniform time scaling; below
#: LOCAL_STRETCH_FINISH (worst limit ratio) a uniform scaling by the excess ends it.
LOCAL_STRETCH_PASSES = 25
LOCAL_STRETCH_FINISH = 1.01
#: Uniform rescalings by the remaining excess tried when finishing a local stretch.
LOCAL_STRETCH_FINISH_TRIES = 3
#: Slack passes after the saturation (multirotor): segments whose worst limit ratio is below
#: SHRINK_SLACK are shortened by max(ratio, SHRINK_MIN_FACTOR) per pass.
SHRINK_PASSES = 6
SHRINK_SLACK = 0.95
SHRINK_MIN_FACTOR = 0.6
#: Duration of the hover trajectory returned for a single waypoint (s), unless given.
HOVER_DURATION_S = 1.0
_MERGE_TOL_M = 1e-9


_PBTRF = scipy.linalg.lapack.dpbtrf  # banded Cholesky factorisation (LAPACK)
_PBTRS = scipy.linalg.lapack.dpbtrs  # banded Cholesky solve


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


def _pair_sources(
    target: NDArray[np.intp], source: NDArray[np.intp], n_targets: int, pad: int
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """For ``np.bincount(target, weights=v[source])`` with at most two terms per target: the
    first and second source of each target in input order (``pad``, the index of an appended
    zero, where there is none), see :func:`_pair_sum`."""
    first = np.full(n_targets, pad, dtype=np.intp)
    second = np.full(n_targets, pad, dtype=np.intp)
    order = np.argsort(target, kind="stable")
    t_sorted = target[order]
    src_sorted = source[order]
    new = np.ones(t_sorted.shape[0], dtype=bool)
    new[1:] = t_sorted[1:] != t_sorted[:-1]
    first[t_sorted[new]] = src_sorted[new]
    rest = ~new
    if rest.any():
        again = np.zeros(t_sorted.shape[0], dtype=bool)
        again[1:] = rest[1:] & rest[:-1]
        if again.any():
            raise AssertionError("a band entry with more than two terms")  # pragma: no cover
        second[t_sorted[rest]] = src_sorted[rest]
    return first, second


def _pair_sum(v: FloatArray, src: tuple[NDArray[np.intp], NDArray[np.intp]]) -> FloatArray:
    """``v.reshape(-1)[first] + v.reshape(-1)[second]`` with a zero appended to v (equal to
    the ``np.bincount`` sum of at most two terms)."""
    flat = np.concatenate([v.reshape(-1), _ZERO])
    out: FloatArray = flat[src[0]]
    out += flat[src[1]]
    return out


_ZERO = np.zeros(1)


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
        # bandwidth: the widest index span of the free derivatives one segment couples (2s - 1
        # at most; 2s - 3 with every waypoint position fixed, which makes the factorisation
        # about twice as cheap)
        hi_f = np.max(fa, axis=1)
        lo_f = np.min(np.where(fa >= 0, fa, np.iinfo(np.int64).max), axis=1)
        spans = np.where(hi_f >= 0, hi_f - lo_f, 0)
        self.u = max(int(spans.max()) if spans.shape[0] else 0, 1)
        mask = (ai >= 0) & (bj >= 0) & (ai <= bj)
        self.band_mask = mask
        # band storage (LAPACK upper, u + 1 rows) in Fortran order: entry (u + a - b, b) at
        # flat index b * (u + 1) + u + a - b, so that dpbtrf factorises it in place
        self.band_flat = (bj * (self.u + 1) + self.u + ai - bj)[mask]
        self.fa = fa
        self.free_rows = fa >= 0  # (M, 2s)
        rows = fa[self.free_rows]
        self.rhs_index = (rows[:, None] * self.d + np.arange(self.d)[None, :]).reshape(-1)
        self.free_idx = np.flatnonzero(free)
        # flat indices of the free rows' entries (a 1-D scatter is several times faster)
        self._free_flat = (self.free_idx[:, None] * self.d + np.arange(self.d)[None, :]).reshape(-1)
        self.free_rows_idx = np.flatnonzero(self.free_rows.reshape(-1))
        self.band_take = np.flatnonzero(mask.reshape(-1))
        # the same sums as np.bincount over (band_flat, band_take) and (rhs_index, free rows)
        # as two gathers and one addition: every entry has at most two terms (a joint is shared
        # by two segments), and (0 + a) + b == a + b exactly
        self._band_src = _pair_sources(
            self.band_flat, self.band_take, (self.u + 1) * self.nf, self.m * 4 * s * s
        )
        rhs_src = (self.free_rows_idx[:, None] * self.d + np.arange(self.d)[None, :]).reshape(-1)
        self._rhs_src = _pair_sources(
            self.rhs_index, rhs_src, self.nf * self.d, self.m * 2 * s * self.d
        )
        # exponent index of each Q entry: h^(1-2s+o_a+o_b), exponents 1-2s .. -1
        self.expo_idx = (self.expo - (1.0 - 2.0 * s)).astype(np.intp)
        # band storage entry (r, j) holds A[j - (u - r), j]: row index per entry for scaling
        band_i = np.arange(self.nf)[None, :] - (self.u - np.arange(self.u + 1))[:, None]
        self.band_i = np.clip(band_i, 0, max(self.nf - 1, 0))
        # the fixed part x0 per segment window, restricted to the window columns it is not
        # zero in (positions, fixed boundary derivatives)
        x0_windows = np.concatenate(
            [self.x0[:-s].reshape(self.m, s, self.d), self.x0[s:].reshape(self.m, s, self.d)],
            axis=1,
        )
        self._x0_cols = np.flatnonzero(np.any(x0_windows != 0.0, axis=(0, 2)))
        self._x0_windows = np.ascontiguousarray(x0_windows[:, self._x0_cols, :])
        self._factor: tuple[FloatArray, FloatArray] | None = None
        self._last: tuple[FloatArray, FloatArray, FloatArray] | None = None  # h, hp, Q
        self._windows: tuple[FloatArray, FloatArray] | None = None  # x, windows(x)
        #: the last solve without a data term: (h, x, cost or NaN)
        self._solved: tuple[FloatArray, FloatArray, float] | None = None

    def _prepare(self, h: FloatArray) -> tuple[FloatArray, FloatArray]:
        """(hp, Q) for durations h: hp = h^o (M, 2s), Q_k = h^(1-2s) S Qt S, S = diag(hp)."""
        last = self._last
        if last is not None and last[0] is h:
            return last[1], last[2]
        s = self.s
        m = h.shape[0]
        hp = np.empty((m, 2 * s))
        hp[:, 0] = 1.0
        for i in range(1, s):
            hp[:, i] = hp[:, i - 1] * h
        hp[:, s:] = hp[:, :s]
        # h^e for e = 1-2s .. -1, then gather per Q entry
        pw = np.empty((m, 2 * s - 1))
        pw[:, -1] = 1.0 / h
        for i in range(2 * s - 3, -1, -1):
            pw[:, i] = pw[:, i + 1] * pw[:, -1]
        Q = pw[:, self.expo_idx]
        Q *= self.Qt
        self._last = (h, hp, Q)
        return hp, Q

    def windows(self, x: FloatArray) -> FloatArray:
        """Per-segment joint derivatives (M, 2s, d) of x (n_joints * s, d) (cached for the
        last solution returned by :meth:`solve`; treat as read-only)."""
        cached = self._windows
        if cached is not None and cached[0] is x:
            return cached[1]
        s, m = self.s, self.m
        d = x.shape[1]
        return np.concatenate([x[:-s].reshape(m, s, d), x[s:].reshape(m, s, d)], axis=1)

    def powers(self, h: FloatArray, r: int) -> FloatArray:
        """h^(o_a - r) for the 2s Hermite inputs, shape (M, 2s)."""
        hp, _ = self._prepare(h)
        return hp if r == 0 else hp / h[:, None] ** r

    def solve(
        self,
        h: FloatArray,
        fit: tuple[FloatArray, FloatArray] | None = None,
        with_cost: bool = True,
    ) -> tuple[FloatArray, float]:
        """Joint derivatives x (n_joints * s, d, read-only) and cost J for durations h (M,)
        (NaN without ``with_cost``).

        ``fit = (R, g)`` adds a per-segment quadratic data term ``x_k^T R_k x_k - 2 g_k . x_k``
        (R (M, 2s, 2s), g (M, 2s, d)) to the objective (same band structure); the returned
        cost is the derivative cost J alone."""
        last = self._solved
        if fit is None and last is not None and last[0].shape == h.shape and (
            np.array_equal(last[0], h)
        ):
            # the same durations as the last solve (e.g. the refinement's result, checked
            # again): the same solution; its factorisation is still the current one
            x, cost = last[1], last[2]
            if with_cost and math.isnan(cost):
                cost = self.cost(x, h)
                self._solved = (last[0], x, cost)
            return x, cost if with_cost else math.nan
        d = self.d
        _, Q = self._prepare(h)
        A = Q if fit is None else Q + fit[0]
        x = self.x0.copy()
        if self.nf:
            # A x0 per segment from the window columns where x0 is not zero (the zero terms
            # add nothing: the same sums)
            cols = self._x0_cols
            yk = np.matmul(A[:, :, cols], self._x0_windows)
            if fit is not None:
                yk -= fit[1]
            rhs = -_pair_sum(yk, self._rhs_src).reshape(self.nf, d)
            ab = _pair_sum(A, self._band_src).reshape(self.nf, self.u + 1).T
            # Jacobi scaling for conditioning across very different durations
            diag = ab[self.u]
            if np.any(diag <= 0.0):
                raise ValueError(
                    "the trajectory is under-determined: some free derivative does not affect "
                    "the cost (fix more boundary derivatives)"
                )
            sc = 1.0 / np.sqrt(diag)
            ab *= sc[self.band_i]
            ab *= sc[None, :]
            cb, info = _PBTRF(ab, lower=0, overwrite_ab=1)
            if info != 0:
                raise ValueError(
                    "the trajectory problem is singular (under-determined free derivatives)"
                )
            self._factor = (cb, sc)
            z, info = _PBTRS(cb, rhs * sc[:, None], lower=0)
            x.reshape(-1)[self._free_flat] = (z * sc[:, None]).reshape(-1)
        xk = self.windows(x)
        cost = float(np.einsum("mad,mad->", xk, Q @ xk)) if with_cost else math.nan
        x.setflags(write=False)  # its windows are cached
        self._windows = (x, xk)
        self._solved = None if fit is not None else (h.copy(), x, cost)
        return x, cost

    def cost(self, x: FloatArray, h: FloatArray) -> float:
        """Cost J of the joint derivatives x (as :meth:`solve` returns) for durations h."""
        _, Q = self._prepare(h)
        xk = self.windows(x)
        return float(np.einsum("mad,mad->", xk, Q @ xk))

    def adjoint(self, g_full: FloatArray) -> FloatArray:
        """lambda = A^-1 g_F for the last factorised system, scattered to all joint
        derivatives (zeros at fixed ones); g_full has shape (n_joints * s, d)."""
        lam = np.zeros_like(g_full)
        if self.nf and self._factor is not None:
            cb, sc = self._factor
            z, _ = _PBTRS(cb, np.take(g_full, self.free_idx, axis=0) * sc[:, None], lower=0)
            lam.reshape(-1)[self._free_flat] = (z * sc[:, None]).reshape(-1)
        return lam

    def dq(self, h: FloatArray) -> FloatArray:
        """dQ_k / dh_k (M, 2s, 2s)."""
        _, Q = self._prepare(h)
        return np.asarray(Q * self.expo[None] / h[:, None, None], dtype=np.float64)

    def dq_x(self, x: FloatArray, h: FloatArray) -> FloatArray:
        """(dQ_k / dh_k) x_k per segment, (M, 2s, d)."""
        return np.asarray(self.dq(h) @ self.windows(x), dtype=np.float64)

    def cost_grad(self, x: FloatArray, h: FloatArray, dqx: FloatArray | None = None) -> FloatArray:
        """dJ*/dh (M,) at the optimum x (envelope theorem: fixed joint derivatives);
        ``dqx``: ``dq_x(x, h)`` if already computed."""
        if dqx is None:
            dqx = self.dq_x(x, h)
        return np.asarray(np.einsum("mad,mad->m", self.windows(x), dqx), dtype=np.float64)

    def control_points(self, x: FloatArray, h: FloatArray) -> FloatArray:
        """Bezier control points (M, 2s, d) of the segments."""
        xk = self.windows(x) * self.powers(h, 0)[:, :, None]
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
        out[int(order)] = None if value is None else _vec(value, d, f"{what} {names[int(order)]}")
    return out


def _check_waypoints(waypoints: ArrayLike) -> FloatArray:
    try:
        wp = np.array(waypoints, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(
            f"waypoints must be a numeric array of shape (M, 2) or (M, 3): {exc}"
        ) from exc
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
def _polyline_profile_durations(
    joints: FloatArray,
    is_waypoint: NDArray[np.bool_],
    vmax: float,
    amax: float,
    seg_vmax: FloatArray | None = None,
) -> FloatArray:
    """Initial durations (s) from a trapezoidal speed profile along the polyline: rest at both
    ends, a corner speed ``vmax cos^2(turn / 2)`` at each waypoint, at most ``vmax`` on the legs
    and acceleration ``amax / 2`` between (forward-backward pass, as in classic velocity
    planning). A single leg reduces to the rest-to-rest trapezoid. ``seg_vmax`` (M,) caps the
    speed per segment (a joint takes the lower cap of its two segments)."""
    seg = np.diff(joints, axis=0)
    lengths = np.linalg.norm(seg, axis=1)
    n_j = joints.shape[0]
    vseg = np.full(n_j - 1, vmax) if seg_vmax is None else np.minimum(seg_vmax, vmax)
    cap = np.empty(n_j)
    cap[1:-1] = np.minimum(vseg[1:], vseg[:-1])
    cap[0] = cap[-1] = 0.0
    wp_idx = np.flatnonzero(is_waypoint)
    legs = np.diff(joints[wp_idx], axis=0)
    unit = legs / np.maximum(np.linalg.norm(legs, axis=1), 1e-12)[:, None]
    cos_turn = np.clip(np.sum(unit[1:] * unit[:-1], axis=1), -1.0, 1.0)
    cap[wp_idx[1:-1]] = cap[wp_idx[1:-1]] * 0.5 * (1.0 + cos_turn)
    a = 0.5 * amax
    v = cap.tolist()
    ls = lengths.tolist()
    for k in range(1, n_j):
        v[k] = min(v[k], math.sqrt(v[k - 1] ** 2 + 2.0 * a * ls[k - 1]))
    for k in range(n_j - 2, -1, -1):
        v[k] = min(v[k], math.sqrt(v[k + 1] ** 2 + 2.0 * a * ls[k]))
    v0 = np.array(v[:-1])
    v1 = np.array(v[1:])
    # accelerate from v0 and decelerate to v1, with a cruise at vmax in between if needed
    peak = np.sqrt(np.maximum((2.0 * a * lengths + v0 * v0 + v1 * v1) / 2.0, 0.0))
    d_acc = (vseg * vseg - v0 * v0) / (2.0 * a)
    d_dec = (vseg * vseg - v1 * v1) / (2.0 * a)
    cruise = (vseg - v0) / a + (vseg - v1) / a + (lengths - d_acc - d_dec) / vseg
    h = np.where(peak <= vseg, (2.0 * peak - v0 - v1) / a, cruise)
    return np.asarray(np.maximum(h, 1e-3), dtype=np.float64)


def _ratios(
    worst: dict[str, FloatArray], limits: Limits | RoverLimits, params: Any
) -> dict[str, FloatArray]:
    """Per-segment 'value / allowed' ratio of each limit (> 1 means exceeded), with the
    allocation margin applied."""
    out: dict[str, FloatArray] = {}
    margin = ALLOCATION_MARGIN
    for name, v in worst.items():
        if name == "tilt":
            assert isinstance(limits, Limits) and limits.max_tilt_rad is not None
            out[name] = v / (limits.max_tilt_rad * margin)
        elif name == "max_thrust":
            assert isinstance(limits, Limits) and limits.max_thrust_n is not None
            out[name] = v / (limits.max_thrust_n * margin)
        elif name == "min_thrust":
            assert isinstance(limits, Limits) and limits.min_thrust_n is not None
            out[name] = (limits.min_thrust_n / margin) / np.maximum(v, 1e-12)
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


def _projected_lbfgs(
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


def _component_sum(terms: list[FloatArray]) -> FloatArray:
    """Sum of the per-component arrays ``terms`` in the order ``np.einsum`` sums a contiguous
    axis of that length (3: ``(t0 + t2) + t1``), so that a component-major layout gives the
    same values as the former component-minor ``einsum``."""
    if len(terms) == 3:
        return terms[0] + terms[2] + terms[1]
    out = terms[0]
    for t in terms[1:]:
        out = out + t
    return out


class _Penalty:
    """Sampled smooth penalty ``P = sum_k h_k / n sum_j max(0, g)^3`` of the limit violations
    ``g`` (dimensionless, > 0 when violated) of speed, acceleration, jerk, tilt and thrust, with
    its exact gradient w.r.t. the durations through the optimal joint derivatives (adjoint of
    the banded system). Used only to steer the time allocation; limits are enforced after."""

    def __init__(
        self,
        system: _System,
        limits: Limits | RoverLimits,
        params: Any,
        n_samples: int = 8,
        speed_scale: FloatArray | None = None,
    ) -> None:
        self.system = system
        self.n = n_samples
        s = system.s
        deg = 2 * s - 1
        mono = _monomial_matrix(deg) @ system.H  # (deg+1, 2s): coefficient of tau^p
        tau = (np.arange(n_samples) + 0.5) / n_samples
        self.W: dict[int, FloatArray] = {}
        for r in (1, 2, 3):
            p = np.arange(r, deg + 1)
            fall = np.array([math.factorial(int(i)) / math.factorial(int(i) - r) for i in p])
            V = tau[:, None] ** (p - r)[None, :].astype(np.float64) * fall[None, :]
            self.W[r] = V @ mono[r:, :]
        m = ALLOCATION_MARGIN
        self.terms: list[tuple[str, float]] = [("speed", (limits.max_speed_m_s * m) ** 2)]
        self.params = params
        self.limits = limits
        if isinstance(limits, Limits):
            self.terms.append(("acc", (limits.max_acc_m_s2 * m) ** 2))
            if limits.max_jerk_m_s3 is not None:
                self.terms.append(("jerk", (limits.max_jerk_m_s3 * m) ** 2))
            elif limits.max_body_rate_rad_s is not None and params is not None:
                # the body rate is not in the penalty (it needs the flatness map): its jerk
                # proxy |omega| ~ |j_perp| / (T / m) at hover thrust steers the allocation
                # away from corners that only a uniform slow-down could make feasible
                proxy = BODY_RATE_JERK_PROXY * limits.max_body_rate_rad_s * float(params.g)
                self.terms.append(("jerk", (proxy * m) ** 2))
            if limits.max_tilt_rad is not None:
                self.terms.append(("tilt", math.tan(limits.max_tilt_rad * m) ** 2))
            if limits.max_thrust_n is not None:
                self.terms.append(("max_thrust", (limits.max_thrust_n * m) ** 2))
            if limits.min_thrust_n is not None and limits.min_thrust_n > 0.0:
                self.terms.append(("min_thrust", (limits.min_thrust_n / m) ** 2))
        self.orders = sorted(
            {3 if n == "jerk" else 2 if n != "speed" else 1 for n, _ in self.terms} | {1}
        )
        if any(n in ("tilt", "max_thrust", "min_thrust") for n, _ in self.terms):
            self.orders = sorted(set(self.orders) | {1, 2})
        self.W_all = np.vstack([self.W[r] for r in self.orders])
        self.W_all_r = np.vstack([r * self.W[r] for r in self.orders])
        self.order_pow = np.array(self.orders, dtype=np.float64)[:, None]
        kin_order = {"speed": 1, "acc": 2, "jerk": 3}
        # (R, 1, M): 1 / limit^2 per derivative order and segment (per-segment speed caps)
        self.kin_inv_lim2 = np.zeros((len(self.orders), 1, system.m))
        for name, lim2 in self.terms:
            if name in kin_order:
                row = np.full(system.m, 1.0 / lim2)
                if name == "speed" and speed_scale is not None:
                    row = row / (speed_scale * speed_scale)
                self.kin_inv_lim2[self.orders.index(kin_order[name]), 0, :] = row
        self.dyn_terms = [(nm, lim2) for nm, lim2 in self.terms if nm not in kin_order]
        # per-axis speed and acceleration (horizontal, up, down), squared with the margin
        self.axis_terms: list[tuple[int, tuple[float, float, float]]] = []
        if isinstance(limits, Limits):
            for order, axes in ((1, limits.max_vel_axes_m_s), (2, limits.max_acc_axes_m_s2)):
                if axes is not None:
                    h2, up2, dn2 = ((v * m) ** 2 for v in axes)
                    self.axis_terms.append((self.orders.index(order), (h2, up2, dn2)))
        self.W_all_T = np.ascontiguousarray(self.W_all.T)
        self.W_all_rT = np.ascontiguousarray(self.W_all_r.T)

    def _violations(
        self, d_all: FloatArray, grad: bool = True
    ) -> tuple[FloatArray, FloatArray | None]:
        """Per-sample penalty phi (n, M) from the sampled derivatives d_all (R, n, d, M: the
        components of all segments contiguous) and, if ``grad``, dphi/d(d_all) (shape of d_all;
        None when nothing is violated). Sums over the d components are formed as
        ``(x0 + x2) + x1``, the order np.einsum uses on a contiguous (..., 3) axis."""
        n, m = d_all.shape[1], d_all.shape[3]
        dim = d_all.shape[2]
        sq = d_all * d_all
        g_kin = _component_sum([sq[:, :, k] for k in range(dim)])
        g_kin *= self.kin_inv_lim2
        g_kin -= 1.0
        active = bool(g_kin.max() > 0.0)
        g_all = None
        if active:
            pos = np.maximum(g_kin, 0.0)
            w = pos * pos
            wp = w * pos
            phi = wp[0]
            for r in range(1, wp.shape[0]):
                phi = phi + wp[r]
            if grad:
                w *= 6.0 * self.kin_inv_lim2
                g_all = d_all * w[:, :, None, :]
        else:
            phi = np.zeros((n, m))
        for row, (h2, up2, dn2) in self.axis_terms if dim == 3 else ():
            vec, vsq = d_all[row], sq[row]  # components and their squares, (n, 3, M)
            inv_z = np.where(vec[:, 2] < 0.0, 1.0 / up2, 1.0 / dn2)
            g_h = (vsq[:, 0] + vsq[:, 1]) / h2 - 1.0
            g_z = vsq[:, 2] * inv_z - 1.0
            for g, axes, inv in ((g_h, (0, 1), 1.0 / h2), (g_z, (2,), inv_z)):
                if not g.max() > 0.0:
                    continue
                pos = np.maximum(g, 0.0)
                w = pos * pos
                phi = phi + w * pos
                if not grad:
                    continue
                if g_all is None:
                    g_all = np.zeros_like(d_all)
                w6 = 6.0 * w * inv
                for ax in axes:
                    g_all[row, :, ax] += w6 * vec[:, ax]
        if not self.dyn_terms:
            return phi, g_all
        i1, i2 = self.orders.index(1), self.orders.index(2)
        mass = float(self.params.mass)
        drag = float(getattr(self.params, "drag", 0.0))
        mg = mass * float(self.params.g)
        tv = -mass * d_all[i2]
        if drag:
            tv -= drag * d_all[i1]
        tv[:, 2] += mg
        dsum = None
        t2 = None
        tsq = None  # squared thrust components
        for name, lim2 in self.dyn_terms:
            if tsq is None:
                tsq = tv * tv
            if name == "tilt":
                tz = np.maximum(tv[:, 2], 1e-3 * mg)
                hor = tsq[:, 0] + tsq[:, 1]
                inv = 1.0 / (lim2 * tz * tz)
                g = hor * inv - 1.0
                if not g.max() > 0.0:
                    continue
                pos = np.maximum(g, 0.0)
                w = pos * pos
                phi += w * pos
                if not grad:
                    continue
                w *= 6.0 * inv
                if dsum is None:
                    dsum = np.zeros_like(tv)
                dsum[:, 0] += w * tv[:, 0]
                dsum[:, 1] += w * tv[:, 1]
                dsum[:, 2] -= w * hor / tz
            else:
                if t2 is None:
                    t2 = _component_sum([tsq[:, k] for k in range(tv.shape[1])])
                sign = 1.0 if name == "max_thrust" else -1.0
                g = sign * (t2 / lim2 - 1.0)
                if not g.max() > 0.0:
                    continue
                pos = np.maximum(g, 0.0)
                w = pos * pos
                phi += w * pos
                if not grad:
                    continue
                w *= sign * 6.0 / lim2
                if dsum is None:
                    dsum = np.zeros_like(tv)
                dsum += w[:, None, :] * tv
        if dsum is not None:
            if g_all is None:
                g_all = np.zeros_like(d_all)
            g_all[i2] -= mass * dsum
            if drag:
                g_all[i1] -= drag * dsum
        return phi, g_all

    def sampled(self, x: FloatArray, h: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(d_all (R, n, d, M) sampled derivatives, zs (2s, d, M) scaled joint derivatives,
        ihp) at the optimum x(h). The samples are component-major (each component of all
        segments contiguous) for the element-wise penalty terms."""
        sysm = self.system
        s = sysm.s
        xk = sysm.windows(x)
        m, d = xk.shape[0], xk.shape[2]
        hp = sysm.powers(h, 0)
        zs = np.ascontiguousarray((xk * hp[:, :, None]).transpose(1, 2, 0))  # (2s, d, M)
        ihp = (1.0 / h)[None, :] ** self.order_pow  # (R, M)
        d_all = thin_matmul(self.W_all, zs.reshape(2 * s, d * m)).reshape(
            len(self.orders), self.n, d, m
        )
        d_all *= ihp[:, None, None, :]
        return d_all, zs, ihp

    def value(self, x: FloatArray, h: FloatArray) -> tuple[float, Any]:
        """Penalty P at the optimum x(h), and the state :meth:`gradient` needs."""
        d_all, zt, ihp = self.sampled(x, h)
        phi, g_all = self._violations(d_all)
        if g_all is None:
            return 0.0, None
        phis = np.sum(phi, axis=0)
        return float(phis @ h) / self.n, (phis, g_all, zt, ihp)

    def gradient(
        self, state: Any, x: FloatArray, h: FloatArray, dqx: FloatArray | None = None
    ) -> FloatArray:
        """dP/dh (M,) from :meth:`value`'s state (explicit dependence through the sample
        times plus the adjoint of the banded system for the dependence through x(h)).
        ``dqx``: ``system.dq_x(x, h)`` if already computed (shared with ``cost_grad``)."""
        if state is None:
            return np.zeros(h.shape[0])
        phis, g_all, zs, ihp = state
        sysm = self.system
        s = sysm.s
        n = self.n
        d, m = g_all.shape[2], g_all.shape[3]
        hp = sysm.powers(h, 0)
        inv_h = 1.0 / h
        dh = phis / n
        # back-projection: U = sum_r W_r^T G_r h^-r, V = sum_r r W_r^T G_r h^-r
        g_all *= (ihp * (h / n)[None, :])[:, None, None, :]
        gt = g_all.reshape(len(self.orders) * n, d * m)
        U = thin_matmul(self.W_all_T, gt).reshape(2 * s, d, m)
        V = thin_matmul(self.W_all_rT, gt).reshape(2 * s, d, m)
        # sum over the inputs a and components of zs * (o U - V), in the order of the former
        # np.einsum("amd,amd->m") (components as in _component_sum, then a in turn)
        prod = zs * (sysm.o[:, None, None] * U - V)  # (2s, d, M)
        per_a = _component_sum([prod[:, k] for k in range(d)])
        acc = per_a[0]
        for a in range(1, per_a.shape[0]):
            acc = acc + per_a[a]
        dh += acc * inv_h
        U *= hp.T[:, None, :]  # dP/dx per segment window, (2s, d, M)
        g_full = np.zeros_like(x)
        g_full[: m * s] += U[:s].transpose(2, 0, 1).reshape(-1, d)
        g_full[s:] += U[s:].transpose(2, 0, 1).reshape(-1, d)
        lam = sysm.adjoint(g_full)
        if dqx is None:
            dqx = sysm.dq_x(x, h)
        dh -= np.einsum("mad,mad->m", sysm.windows(lam), dqx)
        return np.asarray(dh, dtype=np.float64)

    def value_grad(
        self, x: FloatArray, h: FloatArray, dqx: FloatArray | None = None
    ) -> tuple[float, FloatArray]:
        """Penalty P and its total derivative dP/dh (M,) at the optimum x(h).

        Arrays are kept in (order, sample, segment, axis) layout: one matrix product maps the
        joint derivatives of all segments to the samples and one maps the sensitivities back.
        """
        p, state = self.value(x, h)
        return p, self.gradient(state, x, h, dqx)


@dataclass(frozen=True)
class PlanResult:
    """A plan with diagnostics.

    ``trajectory``; ``cost`` J (integral of the squared snap or jerk, SI units);
    ``waypoint_times`` (s) when each input waypoint is reached (duplicates share a time);
    ``solves``: number of fixed-duration solves the time allocation used.
    """

    trajectory: PiecewiseBezier
    cost: float
    waypoint_times: FloatArray
    solves: int


def refine_iterations(segments: int, budget: float = REFINE_WORK_BUDGET) -> int:
    """L-BFGS iteration cap of a multirotor refinement over `segments` segments with the work
    `budget` (iterations x segments)."""
    return max(REFINE_MIN_ITER, min(REFINE_MAXITER, int(budget) // max(segments, 1)))


def _warm_iterations(bad: NDArray[np.bool_]) -> int:
    """Iteration cap of the warm-started refinement after splitting the segments flagged in
    `bad`: all ``REFINE_MAXITER`` while the split plan is within the full work budget, else
    the budget in proportion to the share of segments split (``REFINE_WARM_GAIN``), at least
    ``REFINE_WARM_FLOOR``."""
    new_segments = bad.shape[0] + 2 * int(np.count_nonzero(bad))
    if refine_iterations(new_segments) >= REFINE_MAXITER:
        return REFINE_MAXITER  # within the full budget anyway: every iteration
    frac = float(np.count_nonzero(bad)) / max(bad.shape[0], 1)
    budget = max(REFINE_WARM_FLOOR, REFINE_WORK_BUDGET * min(1.0, REFINE_WARM_GAIN * frac))
    return refine_iterations(new_segments, budget)


def _stretch_factors(per_seg: FloatArray) -> FloatArray:
    """Duration factors of one feasibility pass: each segment over a limit grows by its ratio
    (at most 1.5), its neighbours by 0.2 %."""
    bad = per_seg > 1.0
    grow = np.where(bad, np.minimum(per_seg, 1.5) * 1.002, 1.0)
    grow[1:] = np.maximum(grow[1:], np.where(bad[:-1], 1.002, 1.0))
    grow[:-1] = np.maximum(grow[:-1], np.where(bad[1:], 1.002, 1.0))
    return np.asarray(grow, dtype=np.float64)


class _Planner:
    """One planning problem: joints (waypoints and, for time allocation, intermediate points on
    the straight legs), their fixed derivatives, and the yaw specification."""

    def __init__(
        self,
        joints: FloatArray,
        is_waypoint: NDArray[np.bool_],
        s: int,
        start: dict[int, FloatArray | None],
        end: dict[int, FloatArray | None],
        interior: dict[int, dict[int, FloatArray | None]],
        yaw: YawSpec,
        yaw_wp: FloatArray | None,
        speed_scale: FloatArray | None = None,
    ) -> None:
        self.joints = joints
        #: per-segment speed cap as a fraction of the limits' max_speed_m_s (None: all 1)
        self.speed_scale = speed_scale
        self.is_waypoint = is_waypoint
        self.s = s
        n_j, d = joints.shape
        mask = np.zeros((n_j, s), dtype=bool)
        vals = np.zeros((n_j, s, d))
        mask[:, 0] = True
        vals[:, 0, :] = joints
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
        # uniform time scaling maps the optimum onto the optimum when every fixed
        # non-position derivative is zero: limits can then be checked on scaled samples
        self.homogeneous = bool(np.all(vals[:, 1:, :] == 0.0))
        self.system = _System(mask, vals, s)
        self.yaw = yaw
        self.yaw_wp = yaw_wp
        self.solves = 0
        #: (samples per segment, smallest uniform stretch factor) of the last ratio check
        self._stretch_floor: tuple[int, float] = (0, 0.0)
        #: lower bound of the uniform scaling factor of the durations the last local stretch
        #: started from (0 when unknown)
        self._uniform_floor = 0.0
        #: the per-waypoint yaw channel's banded system (same structure at every build)
        self._yaw_systems: dict[str, _System] = {}
        #: the durations and dense samples of the last dense :meth:`_max_ratio`
        self._dense: tuple[FloatArray, Any] | None = None
        #: the last :meth:`build`: (durations, trajectory, cost or NaN); the saturation's
        #: checks and the final build often ask for the same durations again
        self._built: tuple[FloatArray, PiecewiseBezier, float] | None = None

    def solve(self, h: FloatArray, with_cost: bool = True) -> tuple[FloatArray, float]:
        self.solves += 1
        return self.system.solve(h, with_cost=with_cost)

    def build(self, h: FloatArray, with_cost: bool = True) -> tuple[PiecewiseBezier, float]:
        """The trajectory (with its yaw channel) for durations h and its cost J (NaN without
        ``with_cost``). The last build is reused for equal durations (same result)."""
        built = self._built
        if built is not None and built[0].shape == h.shape and np.array_equal(built[0], h):
            if not with_cost:
                return built[1], math.nan
            _, cost = self.solve(h)  # the system's last solve: no new factorisation
            return built[1], cost
        x, cost = self.solve(h, with_cost)
        cp = self.system.control_points(x, h)
        traj = PiecewiseBezier.from_control_points(cp, h)
        yaw_traj = _yaw_channel(
            traj, self.is_waypoint, h, self.s, self.yaw, self.yaw_wp, self._yaw_systems
        )
        if yaw_traj is not None:
            traj = traj.with_yaw(yaw_traj)
        self._built = (h.copy(), traj, cost)
        return traj, cost

    # ------------------------------------------------------------------ allocation
    def allocate(
        self, limits: Limits | RoverLimits, params: Any, start: FloatArray | None = None
    ) -> FloatArray:
        """Durations (s) per segment: trapezoid guess, penalised refinement, saturation.
        ``start`` (multirotor): warm start of the refinement (see :meth:`refined`)."""
        if isinstance(limits, RoverLimits):
            return self._allocate_rover(self._initial_guess(limits), limits)
        return self._saturate(self.refined(limits, params, start), limits, params)

    def _initial_guess(self, limits: Limits | RoverLimits) -> FloatArray:
        """Trapezoidal-profile durations along the joints (s), see
        :func:`_polyline_profile_durations`."""
        vmax = limits.max_speed_m_s
        amax = limits.max_lat_acc_m_s2 if isinstance(limits, RoverLimits) else limits.max_acc_m_s2
        seg_vmax = None if self.speed_scale is None else vmax * self.speed_scale
        return _polyline_profile_durations(self.joints, self.is_waypoint, vmax, amax, seg_vmax)

    def refined(
        self,
        limits: Limits,
        params: Any,
        start: FloatArray | None = None,
        maxiter: int | None = None,
    ) -> FloatArray:
        """The refinement's durations (s), before the saturation. ``start``: a warm start (e.g.
        the refined durations of a coarser joint set, a split segment's duration shared by its
        pieces); the objective (its weights and box) stays the one set by the trapezoid guess,
        only the starting point changes. ``maxiter``: iteration cap (default
        :func:`refine_iterations` of the number of segments)."""
        return self._refine(self._initial_guess(limits), limits, params, start, maxiter)

    def position(self, h: FloatArray) -> PiecewiseBezier:
        """The position trajectory (no yaw channel) for durations h."""
        x, _ = self.solve(h, with_cost=False)
        return PiecewiseBezier.from_control_points(self.system.control_points(x, h), h)

    # ------------------------------------------------------------------ rover allocation
    def _rover_stretch(self, h: FloatArray, limits: RoverLimits) -> FloatArray:
        """Uniform time scaling of h meeting every rover limit (guaranteed feasible).

        Scaling all durations by k maps the (homogeneous) optimum onto the same path traversed
        k times slower: speed and yaw rate scale by 1/k and lateral acceleration by 1/k^2, and
        the set where they are evaluated (speed >= ``ROVER_MIN_SPEED_M_S``) only shrinks for
        k > 1, so ``k = max(r_speed, r_yaw, sqrt(r_lat)) >= 1`` meets every limit exactly. A
        first k < 1 (limits not active) is re-checked and corrected by a second step with
        k >= 1. Non-homogeneous problems (non-zero fixed derivatives) are re-solved and grown
        geometrically until the exact maxima pass."""
        for i in range(200):
            k = float(np.max(self._rover_segment_ratio(h, limits)))
            if not math.isfinite(k):
                raise ValueError(
                    "rover time allocation: the limits cannot be evaluated (non-finite values)"
                )
            if i == 0 and self.homogeneous and 0.0 < k < 1.0:
                h = h * k  # limits not active: speed up to the tightest one, then re-check
                continue
            if k <= 1.0:
                return h
            h = h * (k * (1.0 + 1e-9) if self.homogeneous else min(max(k, 1.05), 4.0))
        raise ValueError(
            "rover time allocation could not satisfy the limits: the fixed start/end or "
            "waypoint derivatives are not reachable within max_speed / max_yaw_rate / "
            "max_lat_acc"
        )

    def _allocate_rover(self, h0: FloatArray, limits: RoverLimits) -> FloatArray:
        """Rover durations: the shortest of the refined durations, the initial guess and
        durations proportional to the segment lengths, each after the feasible uniform scaling
        of :meth:`_rover_stretch`; then segments with slack are shortened (factor >= 0.5 per
        pass, ``ROVER_LOCAL_PASSES``) and the whole scaled again, while that helps. Every
        candidate ends with :meth:`_rover_stretch`, so the result meets every limit."""
        lengths = np.linalg.norm(np.diff(self.joints, axis=0), axis=1)
        cands = [self._refine(h0, limits, None), h0, np.maximum(lengths, 1e-9)]
        best: FloatArray | None = None
        for h in cands:
            hs = self._rover_stretch(h, limits)
            if best is None or float(hs.sum()) < float(best.sum()):
                best = hs
        assert best is not None
        for _ in range(ROVER_LOCAL_PASSES):
            k = self._rover_segment_ratio(best, limits)
            if not np.all(np.isfinite(k)):
                break
            hs = self._rover_stretch(best * np.clip(k, 0.5, 1.0), limits)
            if float(hs.sum()) >= float(best.sum()) * (1.0 - 1e-3):
                break
            best = hs
        return best

    def _rover_segment_ratio(self, h: FloatArray, limits: RoverLimits) -> FloatArray:
        """Per-segment uniform-scaling factor ``max(r_speed, r_yaw, sqrt(r_lat))`` (M,),
        r = exact maximum (:func:`limits.rover_extrema`) / (margin * limit), of the
        trajectory with durations h (> 1: over a limit)."""
        x, _ = self.solve(h)
        ex = rover_extrema(PiecewiseBezier.from_control_points(self.system.control_points(x, h), h))
        m = ALLOCATION_MARGIN
        return np.asarray(
            np.maximum(
                np.maximum(
                    ex["speed"][0] / (limits.max_speed_m_s * m * self._scale()),
                    ex["yaw_rate"][0] / (limits.max_yaw_rate_rad_s * m),
                ),
                np.sqrt(ex["lat_acc"][0] / (limits.max_lat_acc_m_s2 * m)),
            ),
            dtype=np.float64,
        )

    def _refine(
        self,
        h0: FloatArray,
        limits: Limits | RoverLimits,
        params: Any,
        start: FloatArray | None = None,
        maxiter: int | None = None,
    ) -> FloatArray:
        """Minimise ``sum(h) + rho J(h) + w P(h)`` over log-durations (projected L-BFGS) and the
        analytic gradient (envelope theorem for J, adjoint of the banded system for the
        sampled limit penalty P). rho is set relative to the initial guess (small: time
        dominates, the penalty keeps the limits). Rover: w = 0 (no P), see
        ``_allocate_rover``. ``start``: start the search there instead of at h0 (clipped to
        the box around h0)."""
        _, j0 = self.solve(h0)
        if not np.isfinite(j0) or j0 <= 0.0:
            return h0 if start is None else start
        t0 = float(h0.sum())
        rho = REFINE_RHO * t0 / ((2 * self.s - 1) * j0)
        rover = isinstance(limits, RoverLimits)
        penalty = (
            None if rover else _Penalty(self.system, limits, params, speed_scale=self.speed_scale)
        )
        lz = np.log(h0)
        weight = REFINE_PENALTY_WEIGHT
        if maxiter is None:
            maxiter = ROVER_REFINE_MAXITER if rover else refine_iterations(h0.shape[0])

        def fun(z: FloatArray) -> tuple[float, Callable[[], FloatArray]]:
            h = np.exp(z)
            x, j = self.solve(h)
            p, state = (0.0, None) if penalty is None else penalty.value(x, h)

            def grad() -> FloatArray:
                # the factorisation of this h is still current: the line search asks for the
                # gradient of the point it accepts before solving another one
                dqx = self.system.dq_x(x, h)
                g = 1.0 + rho * self.system.cost_grad(x, h, dqx)
                if penalty is not None:
                    g = g + weight * penalty.gradient(state, x, h, dqx)
                return np.asarray(g * h / t0, dtype=np.float64)

            return float(h.sum() + rho * j + weight * p) / t0, grad

        z0 = lz if start is None else np.log(np.maximum(start, 1e-300))
        z = _projected_lbfgs(fun, z0, lz - 3.0, lz + 3.0, maxiter, ftol=REFINE_FTOL)
        return np.exp(z)

    def _max_ratio(
        self, h: FloatArray, limits: Limits | RoverLimits, params: Any, coarse: bool = False
    ) -> tuple[float, FloatArray]:
        """Largest value/limit ratio (with margin) over the trajectory and per segment.

        ``coarse``: first on ``COARSE_SAMPLES_PER_SEGMENT`` samples per segment, returned when
        they already exceed a limit (a sampled excess is an excess); otherwise, as always
        without it, on the dense ``limits.SAMPLES_PER_SEGMENT`` ones: a pass that only needs
        to know where to stretch skips the dense sampling, a feasible verdict is always the
        dense check's."""
        traj, _ = self.build(h, with_cost=False)
        m = h.shape[0]
        if coarse:
            worst, per_seg = self._ratio_of(
                segment_samples(traj, limits, COARSE_SAMPLES_PER_SEGMENT), m, limits, params
            )
            if worst > 1.0:
                return worst, per_seg
        smp = segment_samples(traj, limits)
        self._dense = (h.copy(), smp)
        return self._ratio_of(smp, m, limits, params)

    def _scaled_ratio(
        self, h: FloatArray, limits: Limits | RoverLimits, params: Any
    ) -> Callable[[float], float] | None:
        """The dense check's worst ratio of the durations ``alpha * h`` as a function of
        alpha, from the dense samples of the last :meth:`_max_ratio` of h (no new solve:
        scaling every duration by alpha time-scales the optimum when the problem is
        homogeneous); None when that does not apply."""
        dense = self._dense
        if (
            not self.homogeneous
            or not isinstance(limits, Limits)
            or dense is None
            or dense[0].shape != h.shape
            or not np.array_equal(dense[0], h)
        ):
            return None
        smp = dense[1]
        per = smp.vel.shape[0] // max(h.shape[0], 1)
        scale = None if self.speed_scale is None else np.repeat(self.speed_scale, per)
        return TimeScaledRatio(smp, limits, params, ALLOCATION_MARGIN, speed_scale=scale)

    def _scale(self) -> FloatArray | float:
        """Per-segment speed scale (M,), or 1.0 without per-segment caps."""
        return 1.0 if self.speed_scale is None else self.speed_scale

    def _ratio_of(
        self, smp: Any, m: int, limits: Limits | RoverLimits, params: Any
    ) -> tuple[float, FloatArray]:
        ratios = _ratios(
            segment_worst(smp, m, limits, params, screen=ALLOCATION_MARGIN), limits, params
        )
        if self.speed_scale is not None:
            ratios["speed"] = ratios["speed"] / self.speed_scale
        if isinstance(limits, Limits) and limits.max_acc_axes_m_s2 is not None:
            ratios["acc_axes"] = (
                axis_acc_ratio(smp.acc, limits).reshape(m, -1).max(axis=1) / ALLOCATION_MARGIN
            )
        if isinstance(limits, Limits) and limits.max_vel_axes_m_s is not None:
            ratios["vel_axes"] = (
                axis_ratio(smp.vel, limits.max_vel_axes_m_s).reshape(m, -1).max(axis=1)
                / ALLOCATION_MARGIN
            )
        per_seg = np.max(np.stack(list(ratios.values())), axis=0)
        # the smallest uniform stretch these samples could pass with: speeds fall as 1 / k,
        # accelerations as 1 / k^2, jerks as 1 / k^3 (see _uniform_scale's lower bound)
        powers = {"speed": 1.0, "vel_axes": 1.0, "acc": 2.0, "acc_axes": 2.0, "jerk": 3.0}
        self._stretch_floor = (
            smp.vel.shape[0] // max(m, 1),
            max(
                (float(np.max(ratios[k])) ** (1.0 / p) for k, p in powers.items() if k in ratios),
                default=0.0,
            ),
        )
        return float(np.max(per_seg)), per_seg

    def _saturate(self, h: FloatArray, limits: Limits | RoverLimits, params: Any) -> FloatArray:
        """Scale all durations by the smallest common factor that satisfies every limit
        (bisection; a uniform time scaling keeps the path shape), then stretch locally where a
        limit is still exceeded (feasibility pass). Multirotor: first try stretching only
        the segments over a limit (a tight corner then slows only its own neighbourhood); kept
        when it ends feasible and shorter than the uniform scaling."""
        local = None
        floor = 0.0
        if isinstance(limits, Limits):
            local = self._local_stretch(h, limits, params)
            floor = self._uniform_floor
        if local is not None and float(local.sum()) < float(h.sum()) * floor:
            # the uniform scaling cannot beat it: its factor is at least `floor`
            return local
        h_uniform = h = h * self._uniform_scale(h, limits, params)
        if local is not None and float(local.sum()) < float(h.sum()):
            return local
        # feasibility pass on the real trajectory (re-solved, not scaled)
        best = math.inf  # the smallest worst ratio seen
        for _ in range(30):
            worst, per_seg = self._max_ratio(h, limits, params, coarse=True)
            if worst <= 1.0:
                return self._shrink(h, per_seg, limits, params)
            best = min(best, worst)
            if worst > LOCAL_STRETCH_GIVE_UP * best:
                # stretching single segments of a minimum-snap path can make it balloon
                # (a long segment between short ones overshoots): stop making it worse
                break
            h = h * _stretch_factors(per_seg)
        # fallback: uniform scaling of the bisection's durations, which keeps the path shape
        # (speed ~ 1/k, acceleration ~ 1/k^2, ...); only the dense check's last percent is missing
        h = h_uniform
        for _ in range(60):
            h = h * 1.02
            worst, per_seg = self._max_ratio(h, limits, params, coarse=True)
            if worst <= 1.0:
                return self._shrink(h, per_seg, limits, params)
        raise ValueError("time allocation could not satisfy the limits (check their values)")

    def _local_stretch(
        self, h: FloatArray, limits: Limits | RoverLimits, params: Any
    ) -> FloatArray | None:
        """Stretch only the segments over a limit (and their neighbours a little) until the
        plan is feasible; None if that does not converge within ``LOCAL_STRETCH_PASSES``."""
        best = math.inf
        self._uniform_floor = 0.0
        for npass in range(LOCAL_STRETCH_PASSES):
            worst, per_seg = self._max_ratio(h, limits, params, coarse=True)
            if npass == 0 and self.homogeneous and self._stretch_floor[0] == (
                BISECTION_SAMPLES_PER_SEGMENT
            ):
                # the samples of the uniform scaling's bisection (same grid): the factor it
                # finds is at least the floor of their speed, acceleration and jerk ratios
                self._uniform_floor = self._stretch_floor[1]
            if worst <= 1.0:
                return h
            best = min(best, worst)
            if worst > LOCAL_STRETCH_GIVE_UP * best:
                return None  # the path balloons between unequal segments: scale uniformly
            if worst < LOCAL_STRETCH_FINISH:
                # a few segments just over: a uniform scaling by the excess finishes it (the
                # local passes can circle around such small excesses for many passes); the
                # excess from the dense samples (the coarse look can miss part of it)
                # (a scaling that leaves a small excess is scaled again by it)
                worst, per_seg = self._max_ratio(h, limits, params)
                if worst <= 1.0:
                    return h
                done, w = h, worst
                # a uniform scaling: the dense samples of h time-scaled (no re-solve)
                scaled = self._scaled_ratio(h, limits, params)
                alpha = 1.0
                for _ in range(LOCAL_STRETCH_FINISH_TRIES):
                    done = done * (w * 1.001)
                    alpha *= w * 1.001
                    w = (
                        scaled(alpha)
                        if scaled is not None
                        else self._max_ratio(done, limits, params)[0]
                    )
                    if w <= 1.0:
                        return done
                    if w >= LOCAL_STRETCH_FINISH:
                        break
            bad = per_seg > 1.0
            grow = np.where(bad, np.sqrt(np.minimum(per_seg, 2.25)) * 1.002, 1.0)
            spread = np.where(bad, np.sqrt(grow), 1.0)
            grow[1:] = np.maximum(grow[1:], spread[:-1])
            grow[:-1] = np.maximum(grow[:-1], spread[1:])
            h = h * grow
        return None

    def _shrink(
        self, h: FloatArray, per_seg: FloatArray, limits: Limits | RoverLimits, params: Any
    ) -> FloatArray:
        """Shorten the segments that a uniform time scaling left with slack (a tight corner
        slows the whole plan down): each pass shrinks every segment whose worst limit ratio
        is below ``SHRINK_SLACK`` by ``max(ratio, SHRINK_MIN_FACTOR)``, stretches back the
        segments (and neighbours) the re-solved plan pushes over a limit, and is kept only if
        the plan is feasible and shorter. `h` must be feasible (`per_seg` its ratios)."""
        best_h, best_t = h, float(h.sum())
        for _ in range(SHRINK_PASSES):
            slack = per_seg < SHRINK_SLACK
            if not slack.any():
                break
            cand = best_h * np.where(slack, np.maximum(per_seg, SHRINK_MIN_FACTOR), 1.0)
            lowest = math.inf
            for _ in range(8):
                if float(cand.sum()) >= best_t * (1.0 - 1e-3):
                    # stretching only lengthens it: it can no longer be kept
                    worst = math.inf
                    break
                worst, per_seg_c = self._max_ratio(cand, limits, params, coarse=True)
                if worst <= 1.0:
                    break
                lowest = min(lowest, worst)
                if worst > LOCAL_STRETCH_GIVE_UP * lowest:
                    # the stretched candidate balloons (as in the feasibility pass): give up
                    # this shrink instead of spending the remaining checks on it
                    worst = math.inf
                    break
                cand = cand * _stretch_factors(per_seg_c)
            if worst > 1.0:
                break
            total = float(cand.sum())
            if total >= best_t * (1.0 - 1e-3):
                break
            best_h, best_t, per_seg = cand, total, per_seg_c
        return best_h

    def _uniform_scale(self, h: FloatArray, limits: Limits | RoverLimits, params: Any) -> float:
        """Smallest common factor of the durations at which every limit holds on the sampled
        trajectory (bisection to 0.1 %; exact time scaling of the samples when the problem is
        homogeneous, else re-solved)."""
        m = h.shape[0]
        if self.homogeneous:
            # coarse samples for the bisection; the feasibility pass re-checks densely
            traj, _ = self.build(h, with_cost=False)
            base = segment_samples(traj, limits, BISECTION_SAMPLES_PER_SEGMENT)
            if isinstance(limits, Limits):
                per_sample = (
                    None
                    if self.speed_scale is None
                    else np.repeat(self.speed_scale, BISECTION_SAMPLES_PER_SEGMENT)
                )
                ratio: Callable[[float], float] = TimeScaledRatio(
                    base, limits, params, ALLOCATION_MARGIN, speed_scale=per_sample
                )
            else:

                def ratio(alpha: float) -> float:
                    return self._ratio_of(base.time_scaled(alpha), m, limits, params)[0]
        else:

            def ratio(alpha: float) -> float:
                return self._max_ratio(h * alpha, limits, params)[0]

        hi = 1.0
        r = ratio(hi)
        for _ in range(60):
            if r <= 1.0:
                break
            hi *= min(max(r, 1.05), 4.0)
            r = ratio(hi)
        else:
            raise ValueError("time allocation could not satisfy the limits (check their values)")
        lo = hi
        for _ in range(60):
            lo *= 0.8
            if lo < 1e-6:
                raise ValueError("time allocation failed: the limits are never active")
            if ratio(lo) > 1.0:
                break
            hi = lo
        for _ in range(40):
            if hi / lo < 1.0 + 1e-3:
                break
            mid = math.sqrt(lo * hi)
            if ratio(mid) <= 1.0:
                hi = mid
            else:
                lo = mid
        return hi


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
    values: FloatArray,
    h: FloatArray,
    s: int,
    value_mask: NDArray[np.bool_] | None = None,
    mask_extra: NDArray[np.bool_] | None = None,
    vals_extra: FloatArray | None = None,
    cache: dict[str, _System] | None = None,
) -> PiecewiseBezier:
    """1-D minimum-derivative channel through ``values`` at the joints where ``value_mask``
    (default: all), at rest at both ends, plus extra fixed derivatives. ``cache``: holds the
    banded system under "1d" between calls with the same values, masks and number of joints
    (the durations may change)."""
    if cache is not None and "1d" in cache:
        sys_c = cache["1d"]
        x, _ = sys_c.solve(h)
        return PiecewiseBezier.from_control_points(sys_c.control_points(x, h), h)
    n_j = values.shape[0]
    mask = np.zeros((n_j, s), dtype=bool)
    vals = np.zeros((n_j, s, 1))
    mask[:, 0] = True if value_mask is None else value_mask
    vals[:, 0, 0] = np.where(mask[:, 0], values, 0.0)
    mask[0, :] = True
    mask[-1, :] = True
    if mask_extra is not None and vals_extra is not None:
        mask |= mask_extra
        vals[mask_extra] = vals_extra[mask_extra]
    sys_ = _System(mask, vals, s)
    if cache is not None:
        cache["1d"] = sys_
    x, _ = sys_.solve(h)
    return PiecewiseBezier.from_control_points(sys_.control_points(x, h), h)


def velocity_heading(traj: PiecewiseBezier,
                     max_rate_rad_s: float | None = None) -> PiecewiseBezier:
    """A yaw channel [rad] for `traj` (same durations) that follows its horizontal velocity
    heading, as ``plan(..., yaw="velocity")`` makes, but fitted after the position is planned:
    the time allocation then bounds the body rate of the translation only, and the heading
    turns as fast as the smoothing lets it (see ``_heading_fit``). With ``max_rate_rad_s`` the
    smoothing is raised until the yaw rate stays within it (a U-turn at the end of a survey
    transect turned the heading at 3.6 rad/s, above PX4's MC_YAWRATE_MAX of 3.49): the heading
    then starts turning before the turn and finishes after it."""
    return _heading_fit(traj, 4, max_rate_rad_s)


#: Factor by which `_heading_fit` raises its smoothing weight per try to meet a yaw-rate cap
#: (the smoothing time grows by its 8th root, about 1.4x), and the number of tries.
HEADING_SMOOTHING_STEP = 16.0
HEADING_SMOOTHING_TRIES = 12


def _heading_fit(traj: PiecewiseBezier, s: int,
                 max_rate_rad_s: float | None = None) -> PiecewiseBezier:
    """Yaw channel following the horizontal velocity heading: the same-durations piecewise
    polynomial minimising ``int w (yaw - atan2(v_y, v_x))^2 dt + lambda int (yaw^(s))^2 dt``,
    at rest at both ends. The weight ``w = (V / V_max)^2`` (plus a tiny floor) discounts the
    heading where the vehicle is slow (undefined at rest); ``lambda = (c * median h)^(2s)``
    smooths heading changes faster than about ``c`` times a segment
    (``VELOCITY_YAW_SMOOTHING``); scaling all durations scales the result exactly in time.
    One banded solve, like the position."""
    m = traj.num_segments
    h = np.asarray(traj.durations, dtype=np.float64)
    n = HEADING_SAMPLES_PER_SEGMENT
    tau = (np.arange(n) + 0.5) / n
    t = (traj.breaks[:-1, None] + h[:, None] * tau[None, :]).reshape(-1)
    vel = traj.evaluate(t, 1)[:, :2]
    speed2 = np.sum(vel * vel, axis=1)
    psi = np.unwrap(np.arctan2(vel[:, 1], vel[:, 0]))
    w = speed2 / max(float(np.max(speed2)), 1e-300) + 1e-6
    n_j = m + 1
    mask = np.zeros((n_j, s), dtype=bool)
    mask[0, 1:] = True
    mask[-1, 1:] = True
    sysm = _System(mask, np.zeros((n_j, s, 1)), s)
    hp = sysm.powers(h, 0)
    basis = _monomial_matrix(2 * s - 1) @ sysm.H  # (2s, 2s): coefficient of tau^p per input
    B = (tau[:, None] ** np.arange(2 * s)[None, :]) @ basis  # (n, 2s) values at the samples
    rows = B[None, :, :] * hp[:, None, :]  # (M, n, 2s): yaw sample = rows @ x_k
    wk = w.reshape(m, n) * (h[:, None] / n)  # time-integral weights
    R = np.einsum("mj,mja,mjb->mab", wk, rows, rows)
    g = np.einsum("mj,mja,mj->ma", wk, rows, psi.reshape(m, n))[:, :, None]
    lam = (VELOCITY_YAW_SMOOTHING * float(np.median(h))) ** (2 * s)
    t_check = np.linspace(0.0, float(traj.duration), max(8 * m * n, 2))
    for _ in range(HEADING_SMOOTHING_TRIES):
        x, _ = sysm.solve(h, (R / lam, g / lam))
        fit = PiecewiseBezier.from_control_points(sysm.control_points(x, h), h)
        if max_rate_rad_s is None or float(
                np.max(np.abs(fit.evaluate(t_check, 1)))) <= max_rate_rad_s:
            break
        lam *= HEADING_SMOOTHING_STEP
    return fit


def _yaw_channel(
    traj: PiecewiseBezier,
    is_waypoint: NDArray[np.bool_],
    h: FloatArray,
    s: int,
    yaw: YawSpec,
    yaw_wp: FloatArray | None,
    cache: dict[str, _System] | None = None,
) -> PiecewiseBezier | None:
    """The yaw channel of `traj` (durations h) for the yaw spec; ``cache`` (one per joint set
    and yaw spec) keeps the per-waypoint channel's banded system between calls."""
    if yaw is None:
        return None
    m = h.shape[0]
    if isinstance(yaw, str):
        return _heading_fit(traj, s)
    if yaw_wp is None:
        raise AssertionError("per-waypoint yaw missing")  # pragma: no cover
    if yaw_wp.shape[0] == 1 or bool(np.all(yaw_wp == yaw_wp[0])):
        # one heading (or the same at every waypoint): the minimum-snap channel is constant
        cp = np.full((m, 2 * s, 1), float(yaw_wp[0]))
        return PiecewiseBezier.from_control_points(cp, h)
    if cache is not None and "1d" in cache:
        return _solve_1d(np.zeros(m + 1), h, s, cache=cache)  # the cached system has the values
    values = np.zeros(m + 1)
    values[is_waypoint] = _unwrap_sequence(yaw_wp)
    return _solve_1d(values, h, s, is_waypoint, cache=cache)


# =========================================================================== public API
#: Passes of the corridor refinement (each splits the segments that leave the corridor).
CORRIDOR_PASSES = 6
#: Samples per segment of the corridor check.
CORRIDOR_SAMPLES_PER_SEGMENT = 24


@dataclass(frozen=True)
class _Problem:
    """What stays fixed while joints are added on the legs: the waypoints `wp`, the half order
    `s`, the start / end / interior derivative specs, the yaw spec, the per-leg speed caps and
    the limits."""

    wp: FloatArray
    s: int
    start: dict[int, FloatArray | None]
    end: dict[int, FloatArray | None]
    interior: dict[int, dict[int, FloatArray | None]]
    yaw: YawSpec
    yaw_wp: FloatArray | None
    caps: FloatArray | None
    limits: Limits | RoverLimits | None

    def planner(
        self, fracs: list[list[float]]
    ) -> tuple[_Planner, NDArray[np.intp], NDArray[np.bool_]]:
        """The planner with extra joints on each straight leg at the fractions `fracs[leg]`
        (each list starts with 0): (planner, leg of each segment, which joints are
        waypoints)."""
        wp = self.wp
        d = wp.shape[1]
        pts: list[FloatArray] = []
        seg_leg: list[int] = []
        for leg, f in enumerate(fracs):
            fa = np.asarray(f, dtype=np.float64)
            pts.append(wp[leg][None, :] + fa[:, None] * (wp[leg + 1] - wp[leg])[None, :])
            seg_leg += [leg] * len(f)
        joints = np.concatenate([*pts, wp[-1:]]).reshape(-1, d)
        is_waypoint = np.zeros(joints.shape[0], dtype=bool)
        starts = np.concatenate([[0], np.cumsum([len(f) for f in fracs])]).astype(np.intp)
        is_waypoint[starts] = True
        interior_j = {int(starts[idx]): spec for idx, spec in self.interior.items()}
        seg_leg_a = np.asarray(seg_leg, dtype=np.intp)
        scale: FloatArray | None = None
        caps, limits = self.caps, self.limits
        if caps is not None and limits is not None and caps.shape[0] == len(fracs):
            scale = np.minimum(caps / limits.max_speed_m_s, 1.0)[seg_leg_a]
        planner = _Planner(
            joints, is_waypoint, self.s, self.start, self.end, interior_j, self.yaw,
            self.yaw_wp, speed_scale=scale,
        )
        return planner, seg_leg_a, is_waypoint

    def plan(
        self, fracs: list[list[float]], params: Any, h_in: FloatArray | None
    ) -> tuple[_Planner, PiecewiseBezier, float, NDArray[np.intp], NDArray[np.bool_]]:
        """Plan with the joints of :meth:`planner` (durations `h_in`, or allocated under the
        limits): (planner, trajectory, cost, leg of each segment, which joints are
        waypoints)."""
        planner, seg_leg_a, is_waypoint = self.planner(fracs)
        if h_in is None:
            assert self.limits is not None
            h = planner.allocate(self.limits, params)
        else:
            h = h_in
        traj, cost = planner.build(h)
        return planner, traj, cost, seg_leg_a, is_waypoint


def _split_breaches(
    fracs: list[list[float]],
    seg_leg: NDArray[np.intp],
    bad: NDArray[np.bool_],
    h: FloatArray | None = None,
) -> tuple[list[list[float]], FloatArray | None]:
    """Split each segment flagged in `bad` (M,) in three equal pieces of its leg: the new joint
    fractions per leg and, given the segments' durations `h` (M,) [s], durations for the new
    segments (a split segment's duration shared equally by its pieces: a warm start)."""
    fracs = [list(f) for f in fracs]
    first = np.searchsorted(seg_leg, np.arange(len(fracs)))  # each leg's first segment
    for sg in np.flatnonzero(bad).tolist():
        leg = int(seg_leg[sg])
        i_f = sg - int(first[leg])
        f = fracs[leg]
        lo = f[i_f]
        hi = f[i_f + 1] if i_f + 1 < len(f) else 1.0
        f.extend((lo + (hi - lo) / 3.0, lo + 2.0 * (hi - lo) / 3.0))
    fracs = [sorted(f) for f in fracs]
    if h is None:
        return fracs, None
    pieces = np.where(bad, 3, 1)
    return fracs, np.repeat(h / pieces, pieces)


def _plan_corridor(
    problem: _Problem,
    fracs: list[list[float]],
    limits: Limits,
    params: Any,
    corridor_m: float,
    acc_j: FloatArray,
) -> tuple[_Planner, PiecewiseBezier, float, NDArray[np.intp], NDArray[np.bool_], int]:
    """Multirotor time allocation with the corridor: (planner, trajectory, cost, leg of each
    segment, waypoint joints, solves).

    The corridor is refined on the refinement's durations, before the saturation (which
    rescales them, mostly uniformly, so the path keeps its shape): each pass splits the
    segments that leave the corridor and re-runs the refinement warm-started from the previous
    durations, then the saturation runs once. Should the saturated path still leave the
    corridor, the segments are split again and the allocation redone (warm-started), at most
    ``CORRIDOR_PASSES`` times each; ValueError if it still leaves it."""
    wp = problem.wp
    planner_of = problem.planner

    def breaches(traj: PiecewiseBezier, seg_leg: NDArray[np.intp]) -> NDArray[np.bool_]:
        return _corridor_breaches(traj, wp, seg_leg, corridor_m, acc_j)

    planner, seg_leg, is_wp = planner_of(fracs)
    solves = 0
    h = planner.refined(limits, params)
    for _ in range(CORRIDOR_PASSES):
        bad = breaches(planner.position(h), seg_leg)
        if not bad.any():
            break
        fracs, h_split = _split_breaches(fracs, seg_leg, bad, h)
        assert h_split is not None
        solves += planner.solves
        planner, seg_leg, is_wp = planner_of(fracs)
        h = planner.refined(limits, params, h_split, maxiter=_warm_iterations(bad))
    h = planner._saturate(h, limits, params)
    traj, cost = planner.build(h)
    for _ in range(CORRIDOR_PASSES):
        bad = breaches(traj, seg_leg)
        if not bad.any():
            return planner, traj, cost, seg_leg, is_wp, solves + planner.solves
        fracs, h_split = _split_breaches(fracs, seg_leg, bad, h)
        solves += planner.solves
        planner, seg_leg, is_wp = planner_of(fracs)
        h = planner._saturate(
            planner.refined(limits, params, h_split, maxiter=_warm_iterations(bad)),
            limits, params,
        )
        traj, cost = planner.build(h)
    if breaches(traj, seg_leg).any():
        raise ValueError(
            f"the planned path leaves the {corridor_m:g} m corridor around the legs after "
            f"{CORRIDOR_PASSES} refinements (fly the legs rest to rest, or widen the corridor)"
        )
    return planner, traj, cost, seg_leg, is_wp, solves + planner.solves


def segment_distances(p: FloatArray, a: FloatArray, b: FloatArray) -> FloatArray:
    """Distance [m] of points `p` to the segments `a`-`b`, all (..., d) and broadcast
    together over the leading axes (projection clamped to the segment; a zero-length segment
    is its point)."""
    # component by component (contiguous arrays instead of a short last axis; the sums in
    # np.einsum's order, see _component_sum: the same values)
    dim = p.shape[-1]
    ab = [b[..., k] - a[..., k] for k in range(dim)]
    rel = [p[..., k] - a[..., k] for k in range(dim)]
    den = _component_sum([x * x for x in ab])
    t = _component_sum([r * x for r, x in zip(rel, ab, strict=True)]) / np.where(
        den > 0.0, den, 1.0
    )
    t = np.where(den > 0.0, np.clip(t, 0.0, 1.0), 0.0)
    diff = [r - t * x for r, x in zip(rel, ab, strict=True)]
    return np.asarray(np.sqrt(_component_sum([x * x for x in diff])), dtype=np.float64)


def point_segment_distance(p: FloatArray, a: FloatArray, b: FloatArray) -> FloatArray:
    """Distance (N,) of the points p (N, d) to the segment a-b [m]."""
    return segment_distances(p, a[None, :], b[None, :])


def corridor_deviation(
    points: FloatArray, waypoints: FloatArray, legs: NDArray[np.intp], acceptance_m: FloatArray
) -> FloatArray:
    """Corridor deviation (N,) [m] of `points` (N, d) flown on the waypoint legs `legs` (N,):
    distance to the nearest of that leg and its neighbours, or 0 inside a waypoint's
    acceptance radius (corners may be cut or overshot there). Vectorised over the points."""
    p = np.asarray(points, dtype=np.float64)
    wp = np.asarray(waypoints, dtype=np.float64)
    legs = np.asarray(legs, dtype=np.intp)
    n_legs = wp.shape[0] - 1
    acc = np.asarray(acceptance_m, dtype=np.float64)
    best = np.full(p.shape[0], np.inf)
    for off in (-1, 0, 1):
        other = legs + off
        ok = (other >= 0) & (other < n_legs)
        oc = np.clip(other, 0, max(n_legs - 1, 0))
        dist = segment_distances(p, wp[oc], wp[oc + 1])
        best = np.where(ok, np.minimum(best, dist), best)
    for w in (legs, legs + 1):
        diff = p - wp[w]
        near = np.sqrt(np.einsum("ij,ij->i", diff, diff)) <= acc[w]
        best[near] = 0.0
    return np.asarray(best, dtype=np.float64)


def _corridor_breaches(
    traj: PiecewiseBezier,
    wp: FloatArray,
    seg_leg: NDArray[np.intp],
    corridor_m: float,
    acceptance_m: FloatArray,
) -> NDArray[np.bool_]:
    """Which segments (M,) leave the corridor (sampled ``CORRIDOR_SAMPLES_PER_SEGMENT`` per
    segment at the midpoints of equal time steps): :func:`corridor_deviation` evaluated
    segment-wise, all segments at once (one matrix product for the samples, each segment's
    three candidate legs broadcast over its samples)."""
    n = CORRIDOR_SAMPLES_PER_SEGMENT
    p = _segment_grid_points(traj, n)  # (M, n, d)
    n_legs = wp.shape[0] - 1
    # the segment's own leg first: a sample within the corridor of it is within the corridor,
    # so the neighbouring legs and the acceptance radii are looked at only for the segments
    # with a sample outside it (the same verdict as taking the minimum over all three)
    dev = segment_distances(p, wp[seg_leg][:, None, :], wp[seg_leg + 1][:, None, :])
    rows = np.flatnonzero((dev > corridor_m).any(axis=1))
    result = np.zeros(seg_leg.shape[0], dtype=np.bool_)
    if rows.shape[0] == 0:
        return result
    p, dev, legs = p[rows], dev[rows], seg_leg[rows]
    for step in (-1, 1):  # the neighbouring legs
        cand = legs + step
        ok = (cand >= 0) & (cand < n_legs)
        cc = np.clip(cand, 0, max(n_legs - 1, 0))
        dist = segment_distances(p, wp[cc][:, None, :], wp[cc + 1][:, None, :])
        np.minimum(dev, np.where(ok[:, None], dist, np.inf), out=dev)
    out = dev > corridor_m
    for w in (legs, legs + 1):
        dw = p - wp[w][:, None, :]
        out &= ~(np.sqrt(np.einsum("mnd,mnd->mn", dw, dw)) <= acceptance_m[w][:, None])
    result[rows] = out.any(axis=1)
    return result


@lru_cache(maxsize=8)
def _midpoint_basis(degree: int, n: int) -> FloatArray:
    """(n, degree + 1) Bernstein basis at the normalised times (k + 0.5) / n."""
    tau = (np.arange(n) + 0.5) / n
    i = np.arange(degree + 1)
    comb = np.array([math.comb(degree, int(k)) for k in i], dtype=np.float64)
    out = comb[None, :] * tau[:, None] ** i[None, :] * (1.0 - tau[:, None]) ** (degree - i)[None, :]
    out.setflags(write=False)
    return out


def _segment_grid_points(traj: PiecewiseBezier, n: int) -> FloatArray:
    """Positions (M, n, d) of every segment at the normalised times (k + 0.5) / n."""
    cp = traj.control_points
    return np.asarray(np.matmul(_midpoint_basis(cp.shape[1] - 1, n), cp), dtype=np.float64)


#: Joints placed on a leg with a cruise part, at these multiples of the distance the
#: trapezoidal profile needs to accelerate (and, mirrored, to brake): short pieces where the
#: speed changes and one long piece where it cruises.
RAMP_JOINTS = (0.6, 1.4)


def _ramp_fractions(
    wp: FloatArray, limits: Limits, params: Any, caps: FloatArray | None
) -> list[list[float]]:
    """Joint fractions per leg for the time allocation: where the leg has a cruise part (the
    trapezoidal speed profile of the polyline, at the real acceleration limit, reaches the
    leg's speed), joints at ``RAMP_JOINTS`` times the acceleration and braking distances from
    its ends; otherwise ``ALLOCATION_PIECES`` equal pieces. The cruise speed also respects the
    steady tilt limit of a vehicle with drag (``g tan(tilt) m / D``)."""
    n_legs = wp.shape[0] - 1
    vmax = np.full(n_legs, limits.max_speed_m_s) if caps is None else np.minimum(
        caps, limits.max_speed_m_s
    )
    amax = limits.max_acc_m_s2
    if limits.max_tilt_rad is not None and params is not None:
        drag = float(getattr(params, "drag", 0.0))
        if drag > 0.0:
            v_tilt = float(params.g) * math.tan(limits.max_tilt_rad) * float(params.mass) / drag
            vmax = np.minimum(vmax, v_tilt)
        amax = min(amax, float(params.g) * math.tan(limits.max_tilt_rad))
    legs = np.diff(wp, axis=0)
    lengths = np.linalg.norm(legs, axis=1)
    unit = legs / np.maximum(lengths, 1e-12)[:, None]
    acc_leg = np.full(n_legs, amax)
    if limits.max_acc_axes_m_s2 is not None and wp.shape[1] == 3:
        # along a leg the per-axis limits allow min(A_h / |u_xy|, A_z / |u_z|)
        a_h, a_up, a_dn = limits.max_acc_axes_m_s2
        u_h = np.hypot(unit[:, 0], unit[:, 1])
        u_z = np.abs(unit[:, 2])
        with np.errstate(divide="ignore"):
            acc_leg = np.minimum(acc_leg, np.minimum(a_h / u_h, min(a_up, a_dn) / u_z))
    # speed at each waypoint: rest at the ends, a corner speed from the turn angle, then the
    # forward-backward acceleration passes
    v = np.zeros(n_legs + 1)
    if n_legs > 1:
        cos_turn = np.clip(np.sum(unit[1:] * unit[:-1], axis=1), -1.0, 1.0)
        v[1:-1] = np.minimum(vmax[1:], vmax[:-1]) * 0.5 * (1.0 + cos_turn)
    for i in range(1, n_legs + 1):
        v[i] = min(v[i], math.sqrt(v[i - 1] ** 2 + 2.0 * acc_leg[i - 1] * lengths[i - 1]))
    for i in range(n_legs - 1, -1, -1):
        v[i] = min(v[i], math.sqrt(v[i + 1] ** 2 + 2.0 * acc_leg[i] * lengths[i]))
    out: list[list[float]] = []
    lo_f, hi_f = RAMP_JOINTS
    for i in range(n_legs):
        length, vc = float(lengths[i]), float(vmax[i])
        base = list(np.arange(ALLOCATION_PIECES, dtype=np.float64) / ALLOCATION_PIECES)
        # ramp joints only where the leg starts or ends at rest (corners keep the equal
        # pieces: short pieces round a corner force a tight turn that slows the whole plan)
        d_acc = vc * vc / (2.0 * acc_leg[i]) if v[i] == 0.0 else 0.0
        d_dec = vc * vc / (2.0 * acc_leg[i]) if v[i + 1] == 0.0 else 0.0
        if length <= 0.0 or hi_f * (d_acc + d_dec) >= 0.9 * length or d_acc + d_dec == 0.0:
            out.append(base)
            continue
        lo_cut = hi_f * d_acc / length
        hi_cut = 1.0 - hi_f * d_dec / length
        f = [x for x in base if x == 0.0 or lo_cut + 0.05 < x < hi_cut - 0.05]
        if d_acc > 0.0:
            f += [lo_f * d_acc / length, lo_cut]
        if d_dec > 0.0:
            f += [hi_cut, 1.0 - lo_f * d_dec / length]
        out.append(sorted(f))
    return out


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
    pieces: int | None = None,
    speed_caps: ArrayLike | None = None,
    corridor_m: float | None = None,
    acceptance_m: ArrayLike | None = None,
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
      ``MultirotorParams`` for tilt, thrust and body-rate limits. They drive the time
      allocation; with explicit ``durations`` they are not enforced (use :func:`check`).
    - ``yaw``: None (no yaw channel), a float (fixed yaw, rad), M per-waypoint yaws (rad,
      unwrapped the short way round), or ``"velocity"`` (follow the horizontal velocity
      heading: speed-weighted least-squares fit with snap smoothing, see ``_heading_fit``).

    - ``speed_caps``: (M-1,) speed cap per waypoint leg [m/s] (e.g. per-leg mission speeds,
      or a climb-rate limit turned into a speed along a climbing leg), each at most
      ``limits.max_speed_m_s``; used by the time allocation.
    - ``corridor_m`` (time allocation only): keep the path within this distance [m] of the
      straight legs, except inside a waypoint's ``acceptance_m`` (M,) radius [m] (default 0):
      segments that leave it are split in three on their leg (multirotor: checked on the
      refinement's durations, each pass warm-started from the previous ones, then one
      saturation and a final check; at most ``CORRIDOR_PASSES`` passes before and after the
      saturation; ValueError if it still leaves it).
    - ``pieces``: segments per waypoint leg. Default 1 with ``durations``; with time
      allocation ``ALLOCATION_PIECES`` (3) under :class:`Limits`: the extra joints lie on the
      straight leg between the waypoints (at 1/3 and 2/3), which keeps the path close to the
      legs and lets the speed profile accelerate, cruise and brake; under
      :class:`RoverLimits` ``ROVER_ALLOCATION_PIECES`` (1). ``PlanResult.waypoint_times``
      says when each waypoint is reached.

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
        pieces=pieces,
        speed_caps=speed_caps,
        corridor_m=corridor_m,
        acceptance_m=acceptance_m,
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
    pieces: int | None = None,
    speed_caps: ArrayLike | None = None,
    corridor_m: float | None = None,
    acceptance_m: ArrayLike | None = None,
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
    if limits is not None:
        # fixed boundary / interior derivatives must themselves respect the limits
        caps = {1: ("velocity", "max_speed_m_s", limits.max_speed_m_s)}
        if isinstance(limits, Limits):
            caps[2] = ("acceleration", "max_acc_m_s2", limits.max_acc_m_s2)
            if limits.max_jerk_m_s3 is not None:
                caps[3] = ("jerk", "max_jerk_m_s3", limits.max_jerk_m_s3)
        where = [("start", start_spec), ("end", end_spec)]
        where += [(f"waypoint {i}", sp) for i, sp in interior_in.items()]
        for label, spec_d in where:
            for order_j, vec in spec_d.items():
                if vec is None or order_j not in caps:
                    continue
                what, field, cap = caps[order_j]
                if float(np.linalg.norm(vec)) > cap:
                    raise ValueError(
                        f"{label}: {what} {float(np.linalg.norm(vec)):.3g} exceeds "
                        f"{field} = {cap:g}"
                    )
    caps_in: FloatArray | None = None
    if speed_caps is not None:
        caps_in = np.asarray(speed_caps, dtype=np.float64).reshape(-1)
        if caps_in.shape[0] != max(n_in - 1, 0):
            raise ValueError(f"{n_in} waypoints need {n_in - 1} speed caps, got {caps_in.shape[0]}")
        bad = ~np.isfinite(caps_in) | (caps_in <= 0.0)
        if np.any(bad):
            i = int(np.flatnonzero(bad)[0])
            raise ValueError(
                f"speed cap {caps_in[i]} of the leg from waypoint {i} to {i + 1} must be a "
                f"finite positive speed in m/s"
            )
    # yaw spec
    yaw_wp: FloatArray | None = None
    if isinstance(yaw, str):
        if yaw != "velocity":
            raise ValueError(
                f'yaw must be None, a number, per-waypoint values or "velocity", got {yaw!r}'
            )
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
    owner = np.arange(n_in)  # original waypoint -> kept waypoint it merged into
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
            owner[i] = keep[-1]
    if len(keep) < n_in:
        if keep[-1] != n_in - 1:
            # the last waypoint merged into an earlier one: interior constraints there are moot
            interior_in.pop(keep[-1], None)
        remap = {old: new for new, old in enumerate(keep)}
        interior = {remap[k]: v for k, v in interior_in.items() if k in remap}
        interior = {k: v for k, v in interior.items() if 0 < k < len(keep) - 1}
        if caps_in is not None:
            # a kept leg keeps the lowest cap of the input legs it spans
            caps_in = np.array(
                [float(np.min(caps_in[a:b])) for a, b in itertools.pairwise(keep)]
            )
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
        if any(
            v is not None and np.any(v != 0) for v in (*start_spec.values(), *end_spec.values())
        ):
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
        return PlanResult(traj, 0.0, np.zeros(n_in), 0)

    if h_in is None and limits is None:
        raise ValueError("give either durations or limits (for the time allocation)")
    if pieces is not None:
        k = int(pieces)
    elif h_in is not None:
        k = 1
    else:
        k = ROVER_ALLOCATION_PIECES if isinstance(limits, RoverLimits) else ALLOCATION_PIECES
    if k < 1:
        raise ValueError(f"pieces must be >= 1, got {pieces}")
    if h_in is not None and k != 1:
        raise ValueError("pieces > 1 is only used by the time allocation (durations=None)")
    # joints per waypoint leg, as fractions of the leg (0 = the leg's first waypoint)
    if pieces is None and h_in is None and isinstance(limits, Limits):
        fracs = _ramp_fractions(wp, limits, params, caps_in)
    else:
        fracs = [list(np.arange(k, dtype=np.float64) / k) for _ in range(n_j - 1)]
    if corridor_m is not None and h_in is not None:
        raise ValueError("corridor_m is used by the time allocation (durations=None)")
    acc_j: FloatArray | None = None
    if corridor_m is not None:
        if not (math.isfinite(corridor_m) and corridor_m > 0.0):
            raise ValueError(f"corridor_m must be a positive distance in m, got {corridor_m}")
        acc_j = np.zeros(n_j)
        if acceptance_m is not None:
            acc_in = np.asarray(acceptance_m, dtype=np.float64).reshape(-1)
            if acc_in.shape[0] != n_in or np.any(~np.isfinite(acc_in) | (acc_in < 0.0)):
                raise ValueError(f"acceptance_m needs {n_in} finite distances >= 0 in m")
            acc_j = acc_in[keep]
        # joints one acceptance radius from each corner, on both legs: the path turns inside
        # the waypoint's acceptance sphere instead of swinging wide across the legs
        lengths = np.linalg.norm(np.diff(wp, axis=0), axis=1)
        # (rovers: a pinned turn at the corner would slow the whole plan through the rover's
        # uniform time scaling; their segments are split only where they leave the corridor)
        for leg in range(n_j - 1 if isinstance(limits, Limits) else 0):
            extra = []
            if leg > 0 and acc_j[leg] > 0.0:
                extra.append(acc_j[leg] / lengths[leg])
            if leg < n_j - 2 and acc_j[leg + 1] > 0.0:
                extra.append(1.0 - acc_j[leg + 1] / lengths[leg])
            f = fracs[leg]
            for e in extra:
                if 0.0 < e < 1.0 and min(abs(e - x) for x in [*f, 1.0]) * lengths[leg] > 0.5:
                    f.append(float(e))
            fracs[leg] = sorted(f)
    problem = _Problem(wp, s, start_spec, end_spec, interior, yaw, yaw_wp, caps_in, limits)
    if acc_j is not None and h_in is None and isinstance(limits, Limits):
        assert corridor_m is not None
        planner, traj, cost, seg_leg, is_waypoint, solves = _plan_corridor(
            problem, fracs, limits, params, float(corridor_m), acc_j
        )
    else:
        planner, traj, cost, seg_leg, is_waypoint = problem.plan(fracs, params, h_in)
        solves = planner.solves
    if acc_j is not None and not isinstance(limits, Limits):
        # rover: each refinement re-runs the (exact-extrema) allocation
        assert corridor_m is not None
        for _ in range(CORRIDOR_PASSES):
            bad = _corridor_breaches(traj, wp, seg_leg, float(corridor_m), acc_j)
            if not bad.any():
                break
            fracs, _ = _split_breaches(fracs, seg_leg, bad)
            planner, traj, cost, seg_leg, is_waypoint = problem.plan(fracs, params, h_in)
            solves += planner.solves
        else:
            if _corridor_breaches(traj, wp, seg_leg, float(corridor_m), acc_j).any():
                raise ValueError(
                    f"the planned path leaves the {corridor_m:g} m corridor around the legs "
                    f"after {CORRIDOR_PASSES} refinements (fly the legs rest to rest, or widen "
                    f"the corridor)"
                )
    if limits is not None:
        _validate(traj, limits, params)
    kept_times = traj.breaks[np.flatnonzero(is_waypoint)]
    kept_index = np.cumsum(np.isin(np.arange(n_in), keep)) - 1
    return PlanResult(traj, cost, kept_times[kept_index[owner]], solves)
