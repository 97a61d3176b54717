"""What the onboard module (gen_c/px4_module) is given to fly: a plan as back-to-back Bezier
segments (`schedule_segments`) and the tracking law's parameters (`law_from_tracking`).

Shared by `fly --onboard` (companion.app.fly_onboard) and the lockstep replay's onboard flight
(companion.replay.onboard); the upload protocol itself is `companion.onboard.protocol`.
"""

from __future__ import annotations

import numpy as np

from companion.control import TrackingConfig
from companion.flight.report import FloatArray
from companion.onboard.protocol import LawParams
from companion.planning.schedule import Schedule
from companion.trajectory import PiecewiseBezier

#: The module refuses to start farther than this from the trajectory's start [m].
START_TOLERANCE_M = 1.5
#: The module holds the end point this long before the final action [s].
HOLD_S = 1.0


class OnboardError(ValueError):
    """The onboard flight cannot start (exit 2): no module, not ready, refused upload."""


Segments = tuple[list[float], list[FloatArray], list[FloatArray]]


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


def law_from_tracking(cfg: TrackingConfig, hover: float) -> LawParams:
    """The module's law parameters: the attitude-mode tracking configuration's gains, model
    and limits, and the vehicle's hover thrust (PX4's MPC_THR_HOVER) [normalised]."""
    g = cfg.gains
    p = cfg.params

    def three(a: object) -> tuple[float, float, float]:
        x = np.asarray(a, dtype=np.float64)
        return float(x[0]), float(x[1]), float(x[2])

    return LawParams(three(g.kp()), three(g.kd()), three(g.ki()), three(g.i_max()), hover,
                     p.drag if cfg.drag_feedforward else 0.0, p.mass, p.g, cfg.thrust_min,
                     cfg.thrust_max, cfg.max_tilt_rad, cfg.drag_velocity == "estimate",
                     cfg.attitude_lead_s)
