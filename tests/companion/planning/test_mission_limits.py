"""Mission planning inside the vehicle's limits: per-leg speeds (DO_CHANGE_SPEED from the next
leg on), PX4's vertical profiles from its parameters, the corridor around the legs and the
time-optimal bound. Speeds are measured by finite differences of the schedule's positions;
the PX4 formulas are written out here independently of companion/planning/schedule.py."""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from companion.flatness import MultirotorParams
from companion.mission import load_mission, mission_to_flight_plan, parse_plan
from companion.mission.px4_params import Px4PlanningParams
from companion.planning.schedule import VehicleLimits, build_schedule
from companion.trajectory import Limits, plan
from companion.trajectory.bound import KinematicLimits, time_optimal_duration

ROOT = Path(__file__).resolve().parents[3]
PARAMS = MultirotorParams(mass=1.0, inertia=(0.025, 0.025, 0.03), drag=1.0)
LIMITS = VehicleLimits(max_tilt_rad=math.radians(45.0))
HOME = (47.397742, 8.545594, 488.0)
M_PER_DEG_LAT = 111_132.0


def _item(cmd: int, params: list[Any], frame: int = 3) -> dict[str, Any]:
    return {"type": "SimpleItem", "command": cmd, "frame": frame, "autoContinue": True,
            "doJumpId": 0, "params": params}  # fmt: skip


def _wp(north_m: float, alt_m: float) -> dict[str, Any]:
    return _item(16, [0, 0, 0, None, HOME[0] + north_m / M_PER_DEG_LAT, HOME[1], alt_m])


def _plan_text(items: list[dict[str, Any]]) -> str:
    for i, it in enumerate(items, start=1):
        it["doJumpId"] = i
    return json.dumps({
        "fileType": "Plan", "version": 1, "groundStation": "test",
        "mission": {"version": 2, "firmwareType": 12, "vehicleType": 2, "cruiseSpeed": 5,
                    "hoverSpeed": 5, "plannedHomePosition": list(HOME), "items": items},
        "geoFence": {"version": 2, "polygons": [], "circles": []},
        "rallyPoints": {"version": 2, "points": []},
    })  # fmt: skip


def _samples(s: Any, dt: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    """Positions (N, 3) and finite-difference velocities (N-1, 3) at the midpoints."""
    t = np.arange(0.0, s.duration_s, dt)
    p = s.sample(t)
    return 0.5 * (p[1:] + p[:-1]), np.diff(p, axis=0) / dt


def test_speed_changes_take_effect_on_the_following_legs_only() -> None:
    items = [
        _item(22, [0, 0, 0, None, HOME[0], HOME[1], 10]),
        _wp(120.0, 10),
        _item(178, [1, 3, -1, 0, 0, 0, 0], frame=2),
        _wp(240.0, 10),
        _item(178, [1, 8, -1, 0, 0, 0, 0], frame=2),
        _wp(360.0, 10),
        _item(21, [0, 0, 0, None, HOME[0] + 360.0 / M_PER_DEG_LAT, HOME[1], 0]),
    ]
    # MPC_TILTMAX_AIR 55 deg: the plan may tilt the 45 deg of LIMITS (10 deg below it), so
    # 8 m/s is within the level speed against the drag
    fp = mission_to_flight_plan(parse_plan(_plan_text(items), source="speeds.plan"),
                                px4=Px4PlanningParams(MPC_TILTMAX_AIR=55.0))
    s = build_schedule(fp, PARAMS, LIMITS)
    mid, vel = _samples(s)
    at_alt = mid[:, 2] < -9.5
    north, speed = mid[at_alt, 0], np.hypot(vel[at_alt, 0], vel[at_alt, 1])
    for lo, hi, v in ((0.0, 120.0, 5.0), (120.0, 240.0, 3.0), (240.0, 360.0, 8.0)):
        leg = (north > lo + 1.0) & (north < hi - 1.0)
        top = float(speed[leg].max())
        assert top <= v * 1.01, (lo, hi, top)
        assert top >= 0.9 * v, (lo, hi, top)  # the leg's own speed is reached, not the minimum


def _px4_land_rate(h: float, px4: Px4PlanningParams) -> float:
    """PX4 (FlightTaskAuto / land): MPC_Z_VEL_MAX_DN above MPC_LAND_ALT1, MPC_LAND_SPEED below
    MPC_LAND_ALT2, linear in height between."""
    if h >= px4.MPC_LAND_ALT1:
        return px4.MPC_Z_VEL_MAX_DN
    if h <= px4.MPC_LAND_ALT2:
        return px4.MPC_LAND_SPEED
    f = (h - px4.MPC_LAND_ALT2) / (px4.MPC_LAND_ALT1 - px4.MPC_LAND_ALT2)
    return px4.MPC_LAND_SPEED + f * (px4.MPC_Z_VEL_MAX_DN - px4.MPC_LAND_SPEED)


@pytest.mark.parametrize("final", ["land", "rtl"])
def test_vertical_profiles_follow_the_vehicle_parameters(final: str) -> None:
    px4 = Px4PlanningParams(MPC_TKO_SPEED=2.0, MPC_Z_VEL_MAX_DN=2.5, MPC_Z_VEL_MAX_UP=4.0,
                            MPC_LAND_SPEED=0.8, MPC_LAND_ALT1=12.0, MPC_LAND_ALT2=4.0,
                            RTL_RETURN_ALT=45.0)  # fmt: skip
    items = [_item(22, [0, 0, 0, None, HOME[0], HOME[1], 30]), _wp(60.0, 30)]
    if final == "land":
        items.append(_item(21, [0, 0, 0, None, HOME[0] + 60.0 / M_PER_DEG_LAT, HOME[1], 0]))
    else:
        items.append(_item(20, [0, 0, 0, 0, 0, 0, 0], frame=2))
    fp = mission_to_flight_plan(parse_plan(_plan_text(items), source="v.plan"), px4=px4)
    s = build_schedule(fp, PARAMS, LIMITS)
    mid, vel = _samples(s)
    height, vz = -mid[:, 2], vel[:, 2]
    climb = vz < -1e-3
    takeoff = climb & (height < 30.0) & (np.hypot(mid[:, 0], mid[:, 1]) < 0.5)
    if final == "rtl":
        takeoff &= np.arange(len(vz)) < len(vz) // 2
    assert float(-vz[takeoff].min()) <= px4.MPC_TKO_SPEED * 1.01
    assert float(-vz[takeoff].min()) >= 0.9 * px4.MPC_TKO_SPEED
    if final == "rtl":
        rtl_climb = climb & (height > 30.5)
        assert float(-vz[rtl_climb].min()) <= px4.MPC_Z_VEL_MAX_UP * 1.01
        assert float(-vz[rtl_climb].min()) >= 0.9 * px4.MPC_Z_VEL_MAX_UP
        assert float(height.max()) == pytest.approx(px4.RTL_RETURN_ALT, abs=0.05)
    desc = vz > 1e-3
    allowed = np.array([_px4_land_rate(h, px4) for h in height[desc]])
    assert np.all(vz[desc] <= allowed * 1.01 + 1e-3)
    fast = desc & (height > px4.MPC_LAND_ALT1 + 3.0)
    assert float(vz[fast].max()) >= 0.9 * px4.MPC_Z_VEL_MAX_DN  # not the landing speed all the way


def _polyline_deviation(p: np.ndarray, pts: np.ndarray, acc: np.ndarray) -> np.ndarray:
    """Distance of each point to the nearest leg of the polyline, 0 inside an acceptance
    sphere (brute force over all legs: independent of the planner's leg bookkeeping)."""
    best = np.full(p.shape[0], np.inf)
    for a, b in itertools.pairwise(pts):
        ab = b - a
        f = np.clip((p - a) @ ab / float(ab @ ab), 0.0, 1.0)
        best = np.minimum(best, np.linalg.norm(p - (a + f[:, None] * ab), axis=1))
    for w, r in zip(pts, acc, strict=True):
        best[np.linalg.norm(p - w, axis=1) <= r] = 0.0
    return best


@pytest.mark.parametrize("name", ["five_minute.plan", "survey.plan", "ten_waypoints.plan",
                                  "rover_square.plan"])
def test_mission_path_stays_in_the_corridor_under_dense_sampling(name: str) -> None:
    """Multirotors by default; a rover with `rover_corridor_m` set (off by default). The
    corridor refinement's rover path turns on 0.38 m at its slowest corner, tighter than PX4
    SIH's Ackermann rover steers (0.56 m: such a plan is refused); the rover here steers
    1.0 rad (0.21 m)."""
    rover = name.startswith("rover")
    fp = mission_to_flight_plan(load_mission(ROOT / "examples" / "missions" / name),
                                vehicle="rover" if rover else "quad",
                                px4=Px4PlanningParams(RA_MAX_STR_ANG=1.0) if rover else None)
    limits = dataclasses.replace(LIMITS, rover_corridor_m=1.0) if rover else LIMITS
    s = build_schedule(fp, None if rover else PARAMS, limits)
    end = [] if fp.touchdown_ned_m is None else [fp.touchdown_ned_m]
    pts = np.array([fp.start_ned_m, *[w.pos_ned_m for w in fp.waypoints], *end])
    acc = np.array([fp.waypoints[0].acceptance_radius_m,
                    *[w.acceptance_radius_m for w in fp.waypoints], *[0.0] * len(end)])  # fmt: skip
    t = np.arange(0.0, s.duration_s, 0.01)
    p = s.sample(t)
    dev = _polyline_deviation(p, pts, acc)
    assert float(dev.max()) <= LIMITS.corridor_m + 1e-3  # type: ignore[operator]


def test_bound_matches_closed_form_trapezoids() -> None:
    lim = KinematicLimits(
        max_speed_xy_m_s=5.0, max_climb_m_s=3.0, max_descent_m_s=1.5,
        max_acc_xy_m_s2=5.0, max_acc_up_m_s2=4.0, max_acc_down_m_s2=3.0,
    )  # fmt: skip
    cases = [
        # 90 m level: accelerate at 5 to 5 m/s and brake at 5
        ([[0, 0, -10], [90, 0, -10]], 90 / 5 + 5 / 5),
        # 40 m climb at 3 m/s: accelerate up at 4, brake (downward) at 3
        ([[0, 0, -20], [0, 0, -60]], 40 / 3 + 3 / 8 + 3 / 6),
        # 40 m descent at 1.5 m/s: accelerate down at 3, brake (upward) at 4
        ([[0, 0, -60], [0, 0, -20]], 40 / 1.5 + 1.5 / 6 + 1.5 / 8),
        # 4 m level, never reaches 5 m/s: triangle 2 sqrt(d / a)
        ([[0, 0, -10], [4, 0, -10]], 2 * math.sqrt(4 / 5)),
    ]
    for pts, expected in cases:
        traj = plan(np.array(pts, float), limits=Limits(max_speed_m_s=3.0, max_acc_m_s2=2.0))
        assert time_optimal_duration(traj, lim) == pytest.approx(expected, rel=2e-3)


@pytest.mark.parametrize("name", ["square.plan", "survey.plan", "hold_and_jump.plan"])
def test_bound_is_below_every_planned_piece(name: str) -> None:
    fp = mission_to_flight_plan(load_mission(ROOT / "examples" / "missions" / name))
    s = build_schedule(fp, PARAMS, LIMITS)
    bounds = s.piece_bounds_s()
    for piece, b in zip(s.pieces, bounds, strict=True):
        assert 0.0 < b <= piece.duration_s + 1e-9


def test_each_axis_stays_within_its_own_px4_limit() -> None:
    """Horizontal, climb and descent speed and acceleration, each against its own PX4
    parameter, by finite differences of the positions, on a mission that climbs and descends
    between waypoints (an isotropic limit alone would let the vertical axis use the
    horizontal one's acceleration)."""
    px4 = Px4PlanningParams(
        MPC_ACC_HOR_MAX=6.0, MPC_ACC_UP_MAX=2.0, MPC_ACC_DOWN_MAX=1.5,
        MPC_Z_VEL_MAX_UP=2.0, MPC_Z_VEL_MAX_DN=1.0, MPC_XY_VEL_MAX=12.0,
    )  # fmt: skip
    items = [_item(22, [0, 0, 0, None, HOME[0], HOME[1], 10]),
             _wp(20.0, 25), _wp(40.0, 10), _wp(70.0, 30), _wp(90.0, 12),
             _item(21, [0, 0, 0, None, HOME[0] + 90.0 / M_PER_DEG_LAT, HOME[1], 0])]  # fmt: skip
    fp = mission_to_flight_plan(parse_plan(_plan_text(items), source="zig.plan"), px4=px4)
    s = build_schedule(fp, PARAMS, LIMITS)
    dt = 0.01
    t = np.arange(0.0, s.duration_s, dt)
    p = s.sample(t)
    v = np.diff(p, axis=0) / dt
    a = np.diff(p, 2, axis=0) / dt**2
    tol = 1.02
    assert float(np.max(np.hypot(a[:, 0], a[:, 1]))) <= px4.MPC_ACC_HOR_MAX * tol
    assert float(np.max(-a[:, 2])) <= px4.MPC_ACC_UP_MAX * tol
    assert float(np.max(a[:, 2])) <= px4.MPC_ACC_DOWN_MAX * tol
    assert float(np.max(-v[:, 2])) <= px4.MPC_Z_VEL_MAX_UP * tol
    assert float(np.max(v[:, 2])) <= px4.MPC_Z_VEL_MAX_DN * tol


def test_speed_items_above_the_level_speed_are_said_once_and_the_bound_uses_that_speed(
        caplog: pytest.LogCaptureFixture) -> None:
    """DO_CHANGE_SPEED legs at 15, 10 and 17 m/s on SIH's quad (1 kg, D = 1 N/(m/s)): at the
    35 deg planning tilt the thrust's horizontal part m g tan(35 deg) balances the drag at
    6.87 m/s, so those legs fly at that speed, a single warning says so with the speed, and the
    time-optimal bound is held to the same speed (before: no word, and a bound of 146 s for a
    225 s plan, 1.54x, as if 15-17 m/s were reachable)."""
    from companion.planning.config import VehicleFile

    vf = VehicleFile()
    v_level = 9.80665 * math.tan(math.radians(35.0)) * vf.params.mass / vf.params.drag
    fp = mission_to_flight_plan(load_mission(ROOT / "tests" / "data" / "missions"
                                             / "speed_items.plan"))
    with caplog.at_level("WARNING", logger="companion.planning.schedule"):
        s = build_schedule(fp, vf.params, vf.limits)
    said = [r.getMessage() for r in caplog.records if "mission speed" in r.getMessage()]
    assert len(said) == 1 and list(s.warnings) == said
    assert "10, 15, 17 m/s" in said[0] and f"{v_level:.1f} m/s" in said[0]
    _mid, vel = _samples(s)
    speed = np.hypot(vel[:, 0], vel[:, 1])
    assert 0.9 * v_level <= float(speed.max()) <= v_level * 1.001  # delivered up to the cap
    bound = s.time_optimal_bound_s()
    assert bound <= s.duration_s and s.duration_s / bound < 1.15
    # within the cap: nothing to say
    caplog.clear()
    with caplog.at_level("WARNING", logger="companion.planning.schedule"):
        quiet = build_schedule(mission_to_flight_plan(load_mission(
            ROOT / "examples" / "missions" / "square.plan")), vf.params, vf.limits)
    assert quiet.warnings == () and not [r for r in caplog.records
                                         if "mission speed" in r.getMessage()]
