"""Time allocation of a fixed joint set: durations per segment under the vehicle limits.

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
rate scale by 1/k and lateral acceleration by 1/k^2 (``Planner._rover_stretch``), so the
result always exists and meets every limit. An optional limit on the norm of the acceleration
(``RoverLimits.max_acc_m_s2``) scales by 1/k^2 too; its maximum is sampled
(``ROVER_ACC_SAMPLES`` per segment). The curvature limit of a car-like rover is geometric (no
scaling changes it): the caller checks it.

Cost. One refinement is capped at ``REFINE_WORK_BUDGET`` iterations x segments (plans of up to
300 segments get the full ``REFINE_MAXITER``). The feasibility passes look at 16 samples per
segment first and at the dense ``limits.SAMPLES_PER_SEGMENT`` only when those pass. 100
waypoints, 297 segments, all multirotor limits: about 55 fixed-duration solves, each with one
penalty evaluation of 8 samples per segment. All samples of all segments are evaluated
with one matrix product per step (no per-segment Python loops, no multi-threaded BLAS), and the
body rate goes through the flatness map only at samples where a cheap attitude-free upper bound
(``limits.body_rate_bound``) comes within the margin of the limit. See BENCHMARKS.md
("Planner") for timings.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from companion.trajectory.bezier import FloatArray, PiecewiseBezier
from companion.trajectory.lbfgs import projected_lbfgs
from companion.trajectory.limits import (
    Limits,
    RoverLimits,
    TimeScaledRatio,
    axis_acc_ratio,
    axis_ratio,
    segment_samples,
    segment_worst,
)
from companion.trajectory.minsnap import BandedSystem
from companion.trajectory.penalty import ALLOCATION_MARGIN, LimitPenalty
from companion.trajectory.rover_extrema import rover_extrema
from companion.trajectory.yaw import YawSpec, yaw_channel

__all__ = ["Planner", "refine_iterations", "warm_iterations"]

#: Time-allocation objective sum(h) + rho J + w P: rho relative to the initial guess, w, and
#: the L-BFGS iteration cap. Multirotor: a moderate w keeps the problem well conditioned, so
#: L-BFGS gets there in fewer iterations (the saturation and feasibility passes enforce the
#: limits exactly afterwards). Rover: no penalty (w = 0, a smooth objective whose optimum
#: moves continuously with the waypoints); the limits are then met by an exact uniform time
#: scaling (see ``Planner._allocate_rover``).
REFINE_RHO = 0.01
REFINE_PENALTY_WEIGHT = 1e3
REFINE_MAXITER = 45
ROVER_REFINE_MAXITER = 60
#: Rover: passes that shorten the segments with slack (exact per-segment ratio < 1) before
#: the uniform scaling again; kept only while the total duration drops.
ROVER_LOCAL_PASSES = 6
#: Samples per segment for a rover's acceleration limit (its uniform-scaling factor).
ROVER_ACC_SAMPLES = 33
REFINE_FTOL = 1e-5
#: Work cap of one multirotor refinement: iterations x segments (each iteration costs a
#: banded solve and a penalty evaluation per segment). Plans of up to
#: REFINE_WORK_BUDGET / REFINE_MAXITER segments get REFINE_MAXITER iterations; larger ones
#: fewer, at least REFINE_MIN_ITER (planning time stays bounded on long missions).
REFINE_WORK_BUDGET = 13_500
REFINE_MIN_ITER = 10
#: Warm-started refinement after a corridor split of a plan over the full work budget: the
#: budget times this multiple of the share of segments split, at least REFINE_WARM_FLOOR
#: (plans within the budget keep every iteration, see ``warm_iterations``).
REFINE_WARM_GAIN = 3.0
REFINE_WARM_FLOOR = 6_750
#: Samples per segment of the feasibility passes' first look (see ``Planner.max_ratio``).
COARSE_SAMPLES_PER_SEGMENT = 16
#: Samples per segment while bisecting the common time scale (final checks use more).
BISECTION_SAMPLES_PER_SEGMENT = 16
#: The multirotor feasibility pass stretches the offending segments only while the worst
#: limit ratio stays below this multiple of the best seen; beyond it the local stretch is
#: distorting the path and the pass falls back to uniform scaling.
LOCAL_STRETCH_GIVE_UP = 1.25
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


def refine_iterations(segments: int, budget: float = REFINE_WORK_BUDGET) -> int:
    """L-BFGS iteration cap of a multirotor refinement over `segments` segments with the work
    `budget` (iterations x segments)."""
    return max(REFINE_MIN_ITER, min(REFINE_MAXITER, int(budget) // max(segments, 1)))


def warm_iterations(bad: NDArray[np.bool_]) -> int:
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


class Planner:
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
        self.system = BandedSystem(mask, vals, s)
        self.yaw = yaw
        self.yaw_wp = yaw_wp
        self.solves = 0
        #: (samples per segment, smallest uniform stretch factor) of the last ratio check
        self._stretch_floor: tuple[int, float] = (0, 0.0)
        #: lower bound of the uniform scaling factor of the durations the last local stretch
        #: started from (0 when unknown)
        self._uniform_floor = 0.0
        #: the per-waypoint yaw channel's banded system (same structure at every build)
        self._yaw_systems: dict[str, BandedSystem] = {}
        #: the durations and dense samples of the last dense :meth:`max_ratio`
        self._dense: tuple[FloatArray, Any] | None = None
        #: the last :meth:`build`: (durations, trajectory, cost or NaN); the saturation's
        #: checks and the final build often ask for the same durations again
        self._built: tuple[FloatArray, PiecewiseBezier, float] | None = None

    def solve(self, h: FloatArray, with_cost: bool = True) -> tuple[FloatArray, float]:
        """:meth:`BandedSystem.solve` for durations h [s], counted in ``solves``."""
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
        yaw_traj = yaw_channel(
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
        return self.saturate(self.refined(limits, params, start), limits, params)

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
            "max_lat_acc / max_acc"
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
        traj = PiecewiseBezier.from_control_points(self.system.control_points(x, h), h)
        ex = rover_extrema(traj)
        m = ALLOCATION_MARGIN
        k = np.maximum(
            np.maximum(
                ex["speed"][0] / (limits.max_speed_m_s * m * self._scale()),
                ex["yaw_rate"][0] / (limits.max_yaw_rate_rad_s * m),
            ),
            np.sqrt(ex["lat_acc"][0] / (limits.max_lat_acc_m_s2 * m)),
        )
        if limits.max_acc_m_s2 is not None:
            # |a| scales by 1/k^2: the largest of each segment's samples (ROVER_ACC_SAMPLES)
            tau = np.linspace(0.0, 1.0, ROVER_ACC_SAMPLES)
            t = traj.breaks[:-1, None] + traj.durations[:, None] * tau[None, :]
            acc = np.linalg.norm(traj.evaluate(t.ravel(), 2), axis=1).reshape(t.shape)
            k = np.maximum(k, np.sqrt(acc.max(axis=1) / (limits.max_acc_m_s2 * m)))
        return np.asarray(k, dtype=np.float64)

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
            None
            if rover
            else LimitPenalty(self.system, limits, params, speed_scale=self.speed_scale)
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
        z = projected_lbfgs(fun, z0, lz - 3.0, lz + 3.0, maxiter, ftol=REFINE_FTOL)
        return np.exp(z)

    def max_ratio(
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
        alpha, from the dense samples of the last :meth:`max_ratio` of h (no new solve:
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

    def saturate(self, h: FloatArray, limits: Limits | RoverLimits, params: Any) -> FloatArray:
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
            worst, per_seg = self.max_ratio(h, limits, params, coarse=True)
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
            worst, per_seg = self.max_ratio(h, limits, params, coarse=True)
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
            worst, per_seg = self.max_ratio(h, limits, params, coarse=True)
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
                worst, per_seg = self.max_ratio(h, limits, params)
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
                        else self.max_ratio(done, limits, params)[0]
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
                worst, per_seg_c = self.max_ratio(cand, limits, params, coarse=True)
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
                return self.max_ratio(h * alpha, limits, params)[0]

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

