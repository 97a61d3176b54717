"""Keeping a plan near its straight legs: distances to the legs and the corridor refinement.

Corridor (``corridor_m``, multirotor). The segments that leave the corridor are split in three
on their leg; the split is decided on the refinement's durations (before the saturation, which
rescales them mostly uniformly and so keeps the path's shape), and the refinement of the new
joint set is warm-started from the previous durations (a split segment's duration shared by
its pieces), for as many iterations as the share of split segments calls for
(``warm_iterations``); the saturation then runs once, and a path that still leaves the
corridor after it is split and re-allocated again (warm-started). Rovers split the same way and
re-run their exact-extrema allocation after each split (in
:func:`companion.trajectory.planner.plan_with_info`).
"""

from __future__ import annotations

import math
from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import NDArray

from companion.trajectory.allocation import Planner, warm_iterations
from companion.trajectory.bezier import FloatArray, PiecewiseBezier
from companion.trajectory.joints import PlanProblem
from companion.trajectory.limits import Limits
from companion.trajectory.penalty import component_sum

__all__ = [
    "CORRIDOR_PASSES",
    "CORRIDOR_SAMPLES_PER_SEGMENT",
    "corridor_breaches",
    "corridor_deviation",
    "plan_corridor",
    "point_segment_distance",
    "segment_distances",
    "split_breaches",
]

#: Passes of the corridor refinement (each splits the segments that leave the corridor).
CORRIDOR_PASSES = 6
#: Samples per segment of the corridor check.
CORRIDOR_SAMPLES_PER_SEGMENT = 24


def split_breaches(
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


def plan_corridor(
    problem: PlanProblem,
    fracs: list[list[float]],
    limits: Limits,
    params: Any,
    corridor_m: float,
    acc_j: FloatArray,
) -> tuple[Planner, PiecewiseBezier, float, NDArray[np.intp], NDArray[np.bool_], int]:
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
        return corridor_breaches(traj, wp, seg_leg, corridor_m, acc_j)

    planner, seg_leg, is_wp = planner_of(fracs)
    solves = 0
    h = planner.refined(limits, params)
    for _ in range(CORRIDOR_PASSES):
        bad = breaches(planner.position(h), seg_leg)
        if not bad.any():
            break
        fracs, h_split = split_breaches(fracs, seg_leg, bad, h)
        assert h_split is not None
        solves += planner.solves
        planner, seg_leg, is_wp = planner_of(fracs)
        h = planner.refined(limits, params, h_split, maxiter=warm_iterations(bad))
    h = planner.saturate(h, limits, params)
    traj, cost = planner.build(h)
    for _ in range(CORRIDOR_PASSES):
        bad = breaches(traj, seg_leg)
        if not bad.any():
            return planner, traj, cost, seg_leg, is_wp, solves + planner.solves
        fracs, h_split = split_breaches(fracs, seg_leg, bad, h)
        solves += planner.solves
        planner, seg_leg, is_wp = planner_of(fracs)
        h = planner.saturate(
            planner.refined(limits, params, h_split, maxiter=warm_iterations(bad)),
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
    # np.einsum's order, see component_sum: the same values)
    dim = p.shape[-1]
    ab = [b[..., k] - a[..., k] for k in range(dim)]
    rel = [p[..., k] - a[..., k] for k in range(dim)]
    den = component_sum([x * x for x in ab])
    t = component_sum([r * x for r, x in zip(rel, ab, strict=True)]) / np.where(
        den > 0.0, den, 1.0
    )
    t = np.where(den > 0.0, np.clip(t, 0.0, 1.0), 0.0)
    diff = [r - t * x for r, x in zip(rel, ab, strict=True)]
    return np.asarray(np.sqrt(component_sum([x * x for x in diff])), dtype=np.float64)


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


def corridor_breaches(
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

