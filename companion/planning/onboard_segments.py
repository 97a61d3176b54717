"""Planned flights as the onboard module's segments (companion.onboard.protocol uploads them):
back-to-back Bezier segments (breaks [s], NED control points [m], yaw control points [rad]),
and the module's law parameters from a vehicle file. Shared by `fly --onboard`
(companion.app.fly_onboard), `serve --onboard` (companion.serve.onboard) and the lockstep
replay's onboard flight (companion.replay.onboard)."""

from __future__ import annotations

import itertools
import math

import numpy as np
from numpy.typing import NDArray

from companion.control import Reference, TrackingConfig
from companion.control.estimation import DisturbanceConfig
from companion.control.shaping import ShapedReference, ShapingConfig
from companion.mavlink.velocity_correction import VELOCITY_CORRECTION_RAD_S
from companion.onboard.protocol import MAX_SEGMENTS, LawParams
from companion.planning.config import VehicleFile, onboard_velocity_correction
from companion.planning.schedule import Schedule
from companion.trajectory import Bezier, PiecewiseBezier
from companion.trajectory.bezier import monomial_matrix

FloatArray = NDArray[np.float64]
Segments = tuple[list[float], list[FloatArray], list[FloatArray]]

#: The module refuses to start farther than this from the trajectory's start [m].
START_TOLERANCE_M = 1.5
#: The module holds the end point this long before the final action [s].
HOLD_S = 1.0


class OnboardError(ValueError):
    """The onboard flight cannot start (exit 2): no module, not ready, refused upload."""


def module_final_action(final_action: str) -> str:
    """The module's final action for a plan's (`land`, `rtl`; anything else: `hold`)."""
    return final_action if final_action in ("land", "rtl") else "hold"


def check_fits(segs: Segments) -> None:
    """OnboardError unless the module holds `segs` (at most MAX_SEGMENTS segments)."""
    if len(segs[1]) > MAX_SEGMENTS:
        raise OnboardError(f"the trajectory has {len(segs[1])} segments; the module holds "
                           f"{MAX_SEGMENTS}")


def trajectory_segments(out: Segments, traj: PiecewiseBezier, yaw: PiecewiseBezier | None,
                        yaw0: float, origin: FloatArray) -> None:
    """Append `traj`'s segments (positions shifted by `origin`; the yaw's, or `yaw0` held)."""
    breaks, cps, ycps = out
    for i, d in enumerate(np.diff(np.asarray(traj.breaks, dtype=np.float64))):
        cp = np.asarray(traj.control_points[i], dtype=np.float64)
        if cp.shape[1] != 3:
            raise OnboardError("the onboard module flies 3-D trajectories only")
        cps.append(cp + origin)
        ycps.append(np.full(cp.shape[0], yaw0) if yaw is None
                    else np.asarray(yaw.control_points[i], dtype=np.float64)[:, 0])
        breaks.append(breaks[-1] + float(d))


def schedule_segments(schedule: Schedule, origin: FloatArray) -> Segments:
    """A schedule as back-to-back Bezier segments (breaks [s], NED control points [m] shifted
    by `origin`, yaw control points [rad]): trajectories segment by segment, in-place turns
    as their yaw segments at the held point, holds as constant segments."""
    out: Segments = ([0.0], [], [])
    breaks, cps, ycps = out
    for piece in schedule.pieces:
        if piece.duration_s <= 0.0:
            continue
        if piece.kind == "traj":
            tr = piece.traj
            assert tr is not None
            trajectory_segments(out, tr, piece.turn if piece.turn is not None else tr.yaw,
                                piece.yaw0, origin)
        elif piece.kind == "turn":
            turn = piece.turn
            assert turn is not None
            dur = np.diff(np.asarray(turn.breaks, dtype=np.float64))
            for i, d in enumerate(dur):
                yc = np.asarray(turn.control_points[i], dtype=np.float64)[:, 0]
                cps.append(np.tile(piece.pos_ned + origin, (len(yc), 1)))
                ycps.append(yc)
                breaks.append(breaks[-1] + float(d))
        else:
            cps.append(np.tile(piece.pos_ned + origin, (2, 1)))
            ycps.append(np.full(2, piece.yaw0))
            breaks.append(breaks[-1] + piece.duration_s)
    return out


#: Pieces shorter than this [s] left at a window's ends are dropped (their time is kept).
MIN_SEGMENT_S = 1e-3


def window(segs: Segments, t_from: float, t_to: float) -> Segments:
    """The part of `segs` between its times `t_from` and `t_to` [s] (segments cut with de
    Casteljau's split, the same curve), its breaks from 0."""
    breaks, cps, ycps = segs
    out: Segments = ([0.0], [], [])
    for i in range(len(cps)):
        a, b = breaks[i], breaks[i + 1]
        lo, hi = max(a, t_from), min(b, t_to)
        if hi - lo < MIN_SEGMENT_S:
            continue
        pos, yaw = Bezier(cps[i], b - a), Bezier(ycps[i][:, None], b - a)
        if hi < b - MIN_SEGMENT_S:
            pos, yaw = pos.split(hi - a)[0], yaw.split(hi - a)[0]
        if lo > a + MIN_SEGMENT_S:
            pos, yaw = pos.split(lo - a)[1], yaw.split(lo - a)[1]
        out[1].append(np.array(pos.control_points))
        out[2].append(np.array(yaw.control_points)[:, 0])
        out[0].append(out[0][-1] + (hi - lo))
    return out


def concatenate(first: Segments, second: Segments) -> Segments:
    """`first` then `second`, the yaw of `second` shifted by whole turns to go on from where
    `first`'s ends (the module's law takes the yaw as an angle: only the jump would matter)."""
    breaks, cps, ycps = ([*first[0]], [*first[1]], [*first[2]])
    shift = 0.0
    if ycps and second[2]:
        gap = float(ycps[-1][-1]) - float(second[2][0][0])
        shift = 2.0 * math.pi * round(gap / (2.0 * math.pi))
    for i, (cp, ycp) in enumerate(zip(second[1], second[2], strict=True)):
        cps.append(cp)
        ycps.append(ycp + shift)
        breaks.append(breaks[-1] + second[0][i + 1] - second[0][i])
    return breaks, cps, ycps


def law_from_tracking(cfg: TrackingConfig, hover: float,
                      vel_correction_rad_s: float = VELOCITY_CORRECTION_RAD_S) -> LawParams:
    """The module's law parameters: the attitude-mode tracking configuration's gains, model,
    limits and disturbance observer (its bandwidth; 0 without `estimate_disturbance`), the
    vehicle's hover thrust (PX4's MPC_THR_HOVER) [normalised] and the velocity correction's
    frequency [rad/s] (0: none; by default the streamed law's)."""
    g = cfg.gains
    p = cfg.params
    dist = ((cfg.disturbance_config or DisturbanceConfig()).bandwidth_rad_s
            if cfg.estimate_disturbance else 0.0)

    def three(a: object) -> tuple[float, float, float]:
        x = np.asarray(a, dtype=np.float64)
        return float(x[0]), float(x[1]), float(x[2])

    return LawParams(three(g.kp()), three(g.kd()), three(g.ki()), three(g.i_max()), hover,
                     p.drag if cfg.drag_feedforward else 0.0, p.mass, p.g, cfg.thrust_min,
                     cfg.thrust_max, cfg.max_tilt_rad, cfg.drag_velocity == "estimate",
                     cfg.attitude_lead_s, dist, vel_correction_rad_s)


def law_params(vf: VehicleFile, hover: float, tilt_rad: float) -> LawParams:
    """The module's law parameters: the vehicle file's attitude-mode gains and model, PX4's
    hover thrust and tilt limit [rad]; the gains and the velocity correction are the onboard
    law's (`[onboard]`)."""
    return law_from_tracking(vf.onboard_tracking_config(tilt_rad), hover,
                             onboard_velocity_correction(vf.onboard_overrides))


def _reference(segs: Segments) -> tuple[list[Bezier], FloatArray]:
    """`segs`' position segments as Beziers, and their breaks [s]."""
    breaks, cps, _ = segs
    return ([Bezier(cp, b - a) for cp, a, b in zip(cps, breaks[:-1], breaks[1:], strict=True)],
            np.asarray(breaks, dtype=np.float64))


def segments_reference(segs: Segments, t_s: float) -> Reference:
    """The position and its derivatives of `segs` at time `t_s` [s] (clamped to its span)."""
    beziers, bk = _reference(segs)
    return _evaluate(beziers, bk, t_s)


def _evaluate(beziers: list[Bezier], bk: FloatArray, t_s: float) -> Reference:
    i = int(np.clip(np.searchsorted(bk, t_s, side="right") - 1, 0, len(beziers) - 1))
    seg = beziers[i]
    u = min(max(t_s - float(bk[i]), 0.0), seg.duration)
    d = [seg.evaluate(u, k) for k in range(5)]
    return Reference(d[0], d[1], d[2], d[3], d[4])


def _poly_bezier(coef: list[float], u0: float, u1: float, degree: int) -> FloatArray:
    """Control points (degree + 1,) of the polynomial `coef` (in u, lowest power first) over
    u in [u0, u1], degree-elevated to `degree`."""
    q = np.polynomial.Polynomial(coef)(np.polynomial.Polynomial([u0, u1 - u0])).coef
    n = len(coef) - 1
    a = np.zeros(n + 1)
    a[: len(q)] = q
    bz = Bezier(np.linalg.solve(monomial_matrix(n), a)[:, None], 1.0)
    while bz.degree < degree:
        bz = bz.elevate()
    return bz.control_points[:, 0]


def bend_for_tilt(segs: Segments, law: LawParams, config: ShapingConfig | None = None
                  ) -> Segments:
    """`segs` bent ahead of time for the law's tilt limit, as the streamed law bends its
    reference online (`companion.control.shaping.ShapedReference`, with the law's drag per
    mass and no disturbance): the module flies what it is given, and a reference past its tilt
    limit leaves it at the limit, falling behind, then catching up. The bend is the same
    quintic B-spline correction, added exactly: segments where it is non-zero are split at its
    knots and get its polynomial as Bezier control points (north, east). Segments it leaves
    alone come back unchanged; so does the whole trajectory where no bend is needed, or where
    the bent one would not fit the module (more than MAX_SEGMENTS segments)."""
    _, cps, ycps = segs
    if not cps:
        return segs
    beziers, bk = _reference(segs)
    cfg = config or ShapingConfig()
    shaped = ShapedReference(lambda t: _evaluate(beziers, bk, t), cfg,
                             max_tilt_rad=law.max_tilt_rad, g=law.g)
    shaped.drag_per_kg = law.drag / law.mass
    h = cfg.knot_s
    n_int = math.ceil(float(bk[-1]) / h)
    corr: dict[int, tuple[list[float], list[float]]] = {}
    for i in range(n_int + 1):  # the solves a flight makes, knot interval by knot interval;
        shaped.advance((i + 0.5) * h)  # interval i's knots are final once it is reached
        c = shaped.correction_poly(i)
        if c is not None:
            corr[i] = c
    if not corr:
        return segs
    out: Segments = ([0.0], [], [])
    for i, (seg, ycp) in enumerate(zip(beziers, ycps, strict=True)):
        a, b = float(bk[i]), float(bk[i + 1])
        ks = range(math.floor(a / h), math.ceil(b / h))
        if not any(k in corr for k in ks):
            out[1].append(cps[i])
            out[2].append(ycp)
            out[0].append(out[0][-1] + (b - a))
            continue
        cuts = [a, *(k * h for k in ks if a + MIN_SEGMENT_S < k * h < b - MIN_SEGMENT_S), b]
        yaw = Bezier(np.asarray(ycp, dtype=np.float64)[:, None], b - a)
        for lo, hi in itertools.pairwise(cuts):
            pos_piece, yaw_piece = seg, yaw
            if hi < b:
                pos_piece, yaw_piece = pos_piece.split(hi - a)[0], yaw_piece.split(hi - a)[0]
            if lo > a:
                pos_piece = pos_piece.split(lo - a)[1]
                yaw_piece = yaw_piece.split(lo - a)[1]
            k = math.floor(0.5 * (lo + hi) / h)
            c = corr.get(k)
            pts = np.array(pos_piece.control_points)
            if c is not None:
                deg = max(pos_piece.degree, len(c[0]) - 1)
                while pos_piece.degree < deg:
                    pos_piece = pos_piece.elevate()
                pts = np.array(pos_piece.control_points)
                for axis in (0, 1):
                    pts[:, axis] += _poly_bezier(c[axis], lo / h - k, hi / h - k, deg)
            out[1].append(pts)
            out[2].append(np.array(yaw_piece.control_points)[:, 0])
            out[0].append(out[0][-1] + (hi - lo))
    return out if len(out[1]) <= MAX_SEGMENTS else segs
