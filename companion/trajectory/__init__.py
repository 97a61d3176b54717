"""Trajectories: Bezier segments, piecewise Bezier trajectories and the minimum-snap planner.

``plan`` builds a :class:`PiecewiseBezier` through waypoints (fixed durations or time-allocated
under :class:`Limits` / :class:`RoverLimits`); ``check`` reports the worst value of every limit.
"""

from companion.trajectory.bezier import Bezier, PiecewiseBezier, hermite
from companion.trajectory.limits import LimitReport, Limits, RoverLimits, check
from companion.trajectory.planner import PlanResult, plan, plan_with_info

__all__ = [
    "Bezier",
    "LimitReport",
    "Limits",
    "PiecewiseBezier",
    "PlanResult",
    "RoverLimits",
    "check",
    "hermite",
    "plan",
    "plan_with_info",
]
