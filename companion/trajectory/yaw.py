"""The yaw channel of a plan: per-waypoint yaws (a 1-D minimum-derivative channel through
them, unwrapped the short way round), or a heading that follows the horizontal velocity (a
speed-weighted least-squares fit with snap smoothing, :func:`velocity_heading`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from companion.trajectory.bezier import FloatArray, PiecewiseBezier, monomial_matrix
from companion.trajectory.minsnap import BandedSystem

__all__ = ["YawSpec", "velocity_heading", "yaw_channel"]

#: What ``plan(..., yaw=...)`` takes: None, a yaw [rad], per-waypoint yaws [rad] or "velocity".
YawSpec = float | Sequence[float] | NDArray[np.float64] | str | None

#: yaw="velocity": heading samples per segment and smoothing time as a fraction of the median
#: segment duration (see ``_heading_fit``).
HEADING_SAMPLES_PER_SEGMENT = 16
VELOCITY_YAW_SMOOTHING = 0.1


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
    cache: dict[str, BandedSystem] | None = None,
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
    sys_ = BandedSystem(mask, vals, s)
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
    sysm = BandedSystem(mask, np.zeros((n_j, s, 1)), s)
    hp = sysm.powers(h, 0)
    basis = monomial_matrix(2 * s - 1) @ sysm.H  # (2s, 2s): coefficient of tau^p per input
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


def yaw_channel(
    traj: PiecewiseBezier,
    is_waypoint: NDArray[np.bool_],
    h: FloatArray,
    s: int,
    yaw: YawSpec,
    yaw_wp: FloatArray | None,
    cache: dict[str, BandedSystem] | None = None,
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

