"""A rover plans within its own PX4 limits (RO_SPEED_LIM, RO_ACCEL_LIM / RO_DECEL_LIM) and is
refused a path tighter than an Ackermann rover steers (RA_WHEEL_BASE / tan(RA_MAX_STR_ANG)).
Oracles: finite differences of the densely sampled plan."""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import numpy as np
import pytest

from companion.mission import load_mission, mission_to_flight_plan
from companion.mission.px4_params import Px4PlanningParams
from companion.planning.chunks import ROVER_ACC_SHARE, ROVER_SPEED_SHARE
from companion.planning.schedule import Schedule, VehicleLimits, build_schedule

SQUARE = Path(__file__).resolve().parents[3] / "examples" / "missions" / "rover_square.plan"


def schedule(**px4: float) -> Schedule:
    p = Px4PlanningParams().replace(**px4)
    fp = mission_to_flight_plan(load_mission(SQUARE), vehicle="rover", px4=p)
    return build_schedule(fp, None, VehicleLimits())


def sampled(s: Schedule, n: int = 40001) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(speed, |acceleration|, curvature) by finite differences of the sampled positions."""
    t = np.linspace(0.0, s.duration_s, n)
    p = s.sample(t)[:, :2]
    dt = t[1] - t[0]
    v = np.gradient(p, dt, axis=0)
    a = np.gradient(v, dt, axis=0)
    speed = np.linalg.norm(v, axis=1)
    cross = v[:, 0] * a[:, 1] - v[:, 1] * a[:, 0]
    curv = np.where(speed > 0.3, np.abs(cross) / np.maximum(speed, 1e-9) ** 3, 0.0)
    return speed[2:-2], np.linalg.norm(a, axis=1)[2:-2], curv[2:-2]


def test_the_rover_mission_speed_is_its_own_speed_limit() -> None:
    """PX4's rover drives missions at RO_SPEED_LIM (not a multicopter's MPC_XY_CRUISE 5 m/s,
    which the companion planned before: the real rover fell 12-17 m behind): the plan tops out
    at ROVER_SPEED_SHARE of it, and a slower RO_SPEED_LIM slows it."""
    for lim in (3.0, 1.5):
        speed, _acc, _curv = sampled(schedule(RO_SPEED_LIM=lim))
        assert 0.9 * ROVER_SPEED_SHARE * lim <= speed.max() <= ROVER_SPEED_SHARE * lim * 1.01


def test_the_rover_accelerates_within_its_limits() -> None:
    """With RO_ACCEL_LIM 0.5 the planned |a| (speeding up, braking and turning) stays within
    ROVER_ACC_SHARE of it; with the default 3 m/s^2 it goes above that (the limit binds)."""
    _s, acc_default, _c = sampled(schedule())
    assert acc_default.max() > ROVER_ACC_SHARE * 0.5 * 1.5
    _s, acc, _c = sampled(schedule(RO_ACCEL_LIM=0.5))
    assert acc.max() <= ROVER_ACC_SHARE * 0.5 * 1.02, acc.max()


def test_a_path_tighter_than_the_rover_steers_is_refused_before_anything_flies() -> None:
    """The square's corners: the default rover (0.56 m smallest radius) turns them on arcs
    passing within its acceptance radius of every corner (oracle: finite-difference curvature
    of the sampled plan never tighter than its radius, the closest approach to each corner);
    one with a 3 m wheel base and 0.3 rad of steering (3 / tan 0.3 = 9.70 m) cannot turn
    within the 2 m acceptance radius: refused with the radius in the message, never flown off
    the path. The minimum-snap planner refuses it too (its path through the corner turns on
    1.36 m)."""
    s = schedule()
    _s, _a, curv = sampled(s)
    p = Px4PlanningParams()
    r_min_default = p.RA_WHEEL_BASE / math.tan(p.RA_MAX_STR_ANG)
    assert 1.0 / curv.max() >= r_min_default
    pos = s.sample(np.linspace(0.0, s.duration_s, 40001))[:, :2]
    for w in s.waypoints_ned[:, :2]:
        assert float(np.min(np.linalg.norm(pos - w, axis=1))) <= 2.0  # NAV_ACC_RAD default
    with pytest.raises(ValueError, match=r"radius of at least 11\.15 m"):
        schedule(RA_WHEEL_BASE=3.0, RA_MAX_STR_ANG=0.3)
    fp = mission_to_flight_plan(load_mission(SQUARE), vehicle="rover",
                                px4=Px4PlanningParams(RA_WHEEL_BASE=3.0, RA_MAX_STR_ANG=0.3))
    with pytest.raises(ValueError, match=r"smallest turning radius 9\.70 m"):
        build_schedule(fp, None, VehicleLimits(rover_planner="minsnap"))


@pytest.mark.parametrize("name", ["rover_square.plan", "rover_corners.plan"])
def test_the_rover_drives_the_legs_and_rounds_each_corner_inside_its_acceptance(
        name: str) -> None:
    """The rover's plan (legs joined by turns inside the corners) lies on the straight legs
    except near the corners (oracle: distance of the densely sampled plan to the polyline),
    passes every waypoint within its acceptance radius (NAV_ACC_RAD 0.5 m, PX4's rover) and
    never turns tighter than the rover steers; it is faster than the minimum-snap plan of the
    same mission (which crawled rover_corners at 1.2 m/s on its 2 m/s legs)."""
    from companion.planning.rover_path import CORNER_SHARE_MAX

    path = SQUARE.parent / name
    p = Px4PlanningParams(NAV_ACC_RAD=0.5)
    fp = mission_to_flight_plan(load_mission(path), vehicle="rover", px4=p)
    s = build_schedule(fp, None, VehicleLimits())
    pos = s.sample(np.linspace(0.0, s.duration_s, 20001))[:, :2]
    pts = fp.points_ned_m()[:, :2]
    legs = [(a, b) for a, b in itertools.pairwise(pts)
            if np.linalg.norm(b - a) > 1e-6]

    def off(q: np.ndarray) -> float:
        best = math.inf
        for a, b in legs:
            d = b - a
            u = float(np.clip((q - a) @ d / (d @ d), 0.0, 1.0))
            best = min(best, float(np.linalg.norm(a + u * d - q)))
        return best

    dev = np.array([off(q) for q in pos[::5]])
    assert float(np.sqrt(np.mean(dev**2))) < 0.05 and float(dev.max()) <= 0.5 * CORNER_SHARE_MAX
    for w in s.waypoints_ned[:, :2]:
        assert float(np.min(np.linalg.norm(pos - w, axis=1))) <= 0.5 * CORNER_SHARE_MAX
    _v, _a, curv = sampled(s)
    assert 1.0 / curv.max() >= p.RA_WHEEL_BASE / math.tan(p.RA_MAX_STR_ANG)
    slow = build_schedule(fp, None, VehicleLimits(rover_planner="minsnap"))
    assert s.duration_s < slow.duration_s


def test_a_rover_is_refused_a_path_that_turns_back_on_itself() -> None:
    """A car cannot reverse on the spot: a mission that doubles back is refused by name."""
    from companion.planning.rover_path import SteeringError, rover_arc_trajectory
    from companion.trajectory import RoverLimits

    lim = RoverLimits(max_speed_m_s=2.0, max_yaw_rate_rad_s=1.5, max_lat_acc_m_s2=1.5,
                      max_curvature_1_m=1.8)
    pts = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 0.0]])
    with pytest.raises(SteeringError, match="item 7"):
        rover_arc_trajectory(pts, np.full(2, 2.0), [0.5] * 3, lim, [6, 7, 8])
