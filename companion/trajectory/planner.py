"""Minimum-snap (or minimum-jerk) piecewise Bezier planning through waypoints: the entry points
:func:`plan` and :func:`plan_with_info` (input checks, duplicate waypoints, hover, then the
planning proper).

The planner's sections live in their own modules:

- :mod:`companion.trajectory.minsnap`: the fixed-durations problem, one banded solve
  (:class:`~companion.trajectory.minsnap.BandedSystem`);
- :mod:`companion.trajectory.allocation`: the time allocation under the limits
  (:class:`~companion.trajectory.allocation.Planner`), with the sampled limit penalty
  (:mod:`companion.trajectory.penalty`) and its optimiser (:mod:`companion.trajectory.lbfgs`);
- :mod:`companion.trajectory.joints`: the joints on the straight legs and the problem over them;
- :mod:`companion.trajectory.corridor`: the corridor around the legs;
- :mod:`companion.trajectory.yaw`: the yaw channel.

Planning time: see :mod:`companion.trajectory.allocation` (cost) and BENCHMARKS.md
("Planner").
"""

from __future__ import annotations

import itertools
import math
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from companion.trajectory.bezier import FloatArray, PiecewiseBezier
from companion.trajectory.corridor import (
    CORRIDOR_PASSES,
    corridor_breaches,
    corridor_deviation,
    plan_corridor,
    segment_distances,
    split_breaches,
)
from companion.trajectory.joints import (
    ALLOCATION_PIECES,
    ROVER_ALLOCATION_PIECES,
    PlanProblem,
    ramp_fractions,
)
from companion.trajectory.limits import Limits, RoverLimits, validate_limits
from companion.trajectory.penalty import ALLOCATION_MARGIN
from companion.trajectory.yaw import YawSpec, velocity_heading

__all__ = [
    "ALLOCATION_MARGIN",
    "DerivSpec",
    "PlanResult",
    "YawSpec",
    "corridor_deviation",
    "plan",
    "plan_with_info",
    "segment_distances",
    "velocity_heading",
]

#: A boundary or interior derivative spec: ``{order: vector or None}`` (1 = velocity, ...).
DerivSpec = Mapping[int, ArrayLike | None]

#: Duration of the hover trajectory returned for a single waypoint (s), unless given.
HOVER_DURATION_S = 1.0
_MERGE_TOL_M = 1e-9


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
      heading: speed-weighted least-squares fit with snap smoothing, see
      :mod:`companion.trajectory.yaw`).

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
        fracs = ramp_fractions(wp, limits, params, caps_in)
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
    problem = PlanProblem(wp, s, start_spec, end_spec, interior, yaw, yaw_wp, caps_in, limits)
    if acc_j is not None and h_in is None and isinstance(limits, Limits):
        assert corridor_m is not None
        planner, traj, cost, seg_leg, is_waypoint, solves = plan_corridor(
            problem, fracs, limits, params, float(corridor_m), acc_j
        )
    else:
        planner, traj, cost, seg_leg, is_waypoint = problem.plan(fracs, params, h_in)
        solves = planner.solves
    if acc_j is not None and not isinstance(limits, Limits):
        # rover: each refinement re-runs the (exact-extrema) allocation
        assert corridor_m is not None
        for _ in range(CORRIDOR_PASSES):
            bad = corridor_breaches(traj, wp, seg_leg, float(corridor_m), acc_j)
            if not bad.any():
                break
            fracs, _ = split_breaches(fracs, seg_leg, bad)
            planner, traj, cost, seg_leg, is_waypoint = problem.plan(fracs, params, h_in)
            solves += planner.solves
        else:
            if corridor_breaches(traj, wp, seg_leg, float(corridor_m), acc_j).any():
                raise ValueError(
                    f"the planned path leaves the {corridor_m:g} m corridor around the legs "
                    f"after {CORRIDOR_PASSES} refinements (fly the legs rest to rest, or widen "
                    f"the corridor)"
                )
    if limits is not None:
        validate_limits(traj, limits, params)
    kept_times = traj.breaks[np.flatnonzero(is_waypoint)]
    kept_index = np.cumsum(np.isin(np.arange(n_in), keep)) - 1
    return PlanResult(traj, cost, kept_times[kept_index[owner]], solves)

