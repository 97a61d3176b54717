"""A rover plans within its own PX4 limits (RO_SPEED_LIM, RO_ACCEL_LIM / RO_DECEL_LIM) and is
refused a path tighter than an Ackermann rover steers (RA_WHEEL_BASE / tan(RA_MAX_STR_ANG)).
Oracles: finite differences of the densely sampled plan."""

from __future__ import annotations

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
    """The square's corners turn on a radius the default rover (0.56 m smallest radius) drives
    but one with a 3 m wheel base and 0.3 rad of steering (3 / tan 0.3 = 9.70 m) cannot: its
    plan is refused with the radius in the message, never flown off the path."""
    _s, _a, curv = sampled(schedule())
    p = Px4PlanningParams()
    r_min_default = p.RA_WHEEL_BASE / math.tan(p.RA_MAX_STR_ANG)
    tightest = 1.0 / curv.max()
    assert r_min_default < tightest < 3.0 / math.tan(0.3)
    with pytest.raises(ValueError, match=r"smallest turning radius 9\.70 m"):
        schedule(RA_WHEEL_BASE=3.0, RA_MAX_STR_ANG=0.3)
