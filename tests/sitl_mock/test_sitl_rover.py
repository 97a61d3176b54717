"""The mock rover steers like PX4 main's SIH Ackermann rover (issue 29).

Oracles, each independent of the mock's code: Ackermann geometry (the turning radius at full
steering is L / tan(delta_max)); the bicycle model's steady state with SIH's yaw damping
(radius (L / tan delta)(1 + KDW v / (C L^2)), C = SIH's 500 N/rad); Newton with SIH's force
budget (400 N at full throttle, rolling resistance 0.3 m g, SIH_KDV per earth-centred axis, whose
along-track share is at least 1/sqrt(3)); PX4's rate limits on its setpoints and actuators
(RO_ACCEL_LIM, RO_DECEL_LIM, RA_STR_RATE_LIM); PX4's corner formulas written out here
(RA_ACC_RAD_GAIN x L / sin(delta_max) / tan(angle / 2), RO_MAX_THR_SPEED x (1 - RO_SPEED_RED x
(pi - angle) / pi)); and airframe 10045's own defaults file. Telemetry-judged properties use the
mock's MAVLink output (LOCAL_POSITION_NED, ATTITUDE, POSITION_TARGET_LOCAL_NED) through the
sans-IO harness on a fake clock.

Note: PX4 limits its speed *setpoint* (RO_ACCEL_LIM) and *throttle* slew, not the vehicle's
acceleration: real PX4 main's rover goes 0 -> 2.3 m/s in ~0.5 s (~5 m/s^2, BENCHMARKS.md). So
the vehicle's own acceleration is judged against SIH's force budget, the limits where PX4 applies
them.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink
from scipy.optimize import least_squares

from sitl_mock.navigator import Navigator
from sitl_mock.params import ALIASES, PARAMS, ParamStore
from sitl_mock.rover import Rover
from sitl_mock.setpoints import AttitudeTarget, PositionTarget, RoverPositionTarget
from sitl_mock.vehicle import make_vehicle
from tests.sitl_mock.test_sitl_mission_protocol import upload
from tests.support.autopilot_harness import Harness

REPO = Path(__file__).resolve().parents[2]
DT = 0.004
SIH_FORCE_N = 400.0  # SIH's drive force at full throttle
SIH_MU_ROLL = 0.3  # SIH's rolling resistance coefficient
SIH_C = 500.0  # SIH's cornering stiffness [N/rad]
G = 9.81
VEL_ONLY = 0b110111000111  # SET_POSITION_TARGET_LOCAL_NED: vx, vy, vz
POS_ONLY = 2552  # x, y, z (MAVSDK's position mask)


def _fit_radius(xy: np.ndarray) -> float:
    """Radius of the geometric least-squares circle through the points."""

    def res(c: np.ndarray) -> np.ndarray:
        return np.asarray(np.hypot(xy[:, 0] - c[0], xy[:, 1] - c[1]) - c[2])

    c0 = np.array([xy[:, 0].mean(), xy[:, 1].mean(), np.ptp(xy[:, 0]) / 2.0])
    return float(least_squares(res, c0).x[2])


def _circle(params: ParamStore, throttle: float, seconds: float = 12.0) -> Rover:
    """The rover at full right steering and constant throttle (its physics alone)."""
    rv = Rover(params)
    for _ in range(round(seconds / DT)):
        rv.step_actuators(DT, throttle, 1.0)
    return rv


def _track(rv: Rover, seconds: float) -> np.ndarray:
    """(north, east, speed, yaw, yaw rate) every step for `seconds` at full right steering."""
    rows = []
    thr = rv.throttle
    for _ in range(round(seconds / DT)):
        rv.step_actuators(DT, thr, 1.0)
        s = rv.state
        rows.append((s.pos_ned[0], s.pos_ned[1], math.hypot(*s.vel_ned[:2]), s.yaw,
                     s.omega_frd[2]))
    return np.array(rows)


# ----------------------------------------------------------------------------- geometry


def test_full_steering_radius_is_wheel_base_over_tan_max_steering_without_yaw_damping() -> None:
    """Without SIH's yaw damping the path at full steering is the Ackermann circle
    L / tan(delta_max), whatever the speed; the velocity stays along the heading (no slip)."""
    p = ParamStore({"SIH_KDW": 0.0})
    want = p["RA_WHEEL_BASE"] / math.tan(p["RA_MAX_STR_ANG"])
    for throttle in (0.35, 0.6):
        rv = _circle(p, throttle)
        a = _track(rv, 6.0)
        assert a[:, 2].min() > 0.5  # driving, not creeping
        assert _fit_radius(a[:, :2]) == pytest.approx(want, rel=0.01)
        s = rv.state
        assert math.atan2(s.vel_ned[1], s.vel_ned[0]) == pytest.approx(s.yaw, abs=1e-9)


def test_full_steering_radius_widens_with_speed_by_the_bicycle_model_with_yaw_damping() -> None:
    """SIH's yaw damping SIH_KDW: steady curvature tan(delta) / L / (1 + KDW v / (C L^2)),
    judged sample by sample from the path (heading change per distance)."""
    p = ParamStore()
    Rover(p)  # airframe 10045's SIH_KDW 10, SIH_MASS 20, ...
    wb, kdw, ang = p["RA_WHEEL_BASE"], p["SIH_KDW"], p["RA_MAX_STR_ANG"]
    assert kdw == 10.0
    radii = []
    for throttle in (0.35, 0.6):
        a = _track(_circle(p, throttle), 6.0)
        ds = np.hypot(np.diff(a[:, 0]), np.diff(a[:, 1]))
        dpsi = np.abs(np.diff(np.unwrap(a[:, 3])))
        v = 0.5 * (a[1:, 2] + a[:-1, 2])
        want = math.tan(ang) / wb / (1.0 + kdw * v / (SIH_C * wb * wb))
        k = 25  # 0.1 s windows: within 5 % (the yaw rate settles in ~0.06 s while the speed
        # swings with the heading), over the 6 s within 1 %
        got = np.add.reduceat(dpsi, np.arange(0, len(ds), k)) / np.add.reduceat(
            ds, np.arange(0, len(ds), k))
        exp = np.add.reduceat(want * ds, np.arange(0, len(ds), k)) / np.add.reduceat(
            ds, np.arange(0, len(ds), k))
        assert np.max(np.abs(got / exp - 1.0)) < 0.05
        assert dpsi.sum() / ds.sum() == pytest.approx(float(np.sum(want * ds) / ds.sum()),
                                                      rel=0.01)
        radii.append(_fit_radius(a[:, :2]))
    assert radii[1] > radii[0] > wb / math.tan(ang)


def test_the_rover_never_turns_in_place() -> None:
    """Whatever it is asked (velocities behind and beside it, a goal behind it, a yaw rate
    alone, an attitude), the heading changes only with distance driven: over every 0.2 s,
    |d yaw| <= distance x tan(delta_max) / L (+ 0.02 rad: the tyres settle below 0.05 m/s)."""
    p = ParamStore()
    rv = make_vehicle("rover", p)
    kmax = math.tan(p["RA_MAX_STR_ANG"]) / p["RA_WHEEL_BASE"]
    plan = [
        (PositionTarget(vel_ned=(0.0, 2.0, math.nan)), 3.0),
        (PositionTarget(vel_ned=(-1.0, 0.0, math.nan)), 4.0),  # behind it
        (PositionTarget(yaw_rate=1.0), 3.0),  # ignored by PX4's Ackermann rover
        (AttitudeTarget((0.7071, 0.0, 0.0, 0.7071), 0.5, None), 2.0),  # unsupported: stop
        (PositionTarget(pos_ned=(-8.0, -3.0, math.nan)), 12.0),  # a goal behind it
        (PositionTarget(vel_ned=(0.0, 0.0, math.nan)), 2.0),
    ]
    rows = []
    for tgt, seconds in plan:
        for _ in range(round(seconds / DT)):
            rv.step(DT, tgt, True)
            s = rv.state
            rows.append((s.pos_ned[0], s.pos_ned[1], s.yaw))
    a = np.array(rows)
    ds = np.hypot(np.diff(a[:, 0]), np.diff(a[:, 1]))
    dpsi = np.abs(np.diff(np.unwrap(a[:, 2])))
    k = 50
    dist = np.add.reduceat(ds, np.arange(0, len(ds), k))
    turn = np.add.reduceat(dpsi, np.arange(0, len(ds), k))
    assert np.all(turn <= dist * kmax * (1 + 1e-9) + 0.02)
    assert turn.sum() > math.pi  # it did turn a lot, by driving


def test_yaw_rate_alone_or_an_attitude_neither_moves_nor_turns_a_standing_rover() -> None:
    p = ParamStore()
    rv = Rover(p)
    for tgt in (PositionTarget(yaw_rate=0.8), PositionTarget(yaw=2.0),
                AttitudeTarget(None, 0.8, (0.0, 0.0, 1.0))):
        for _ in range(round(2.0 / DT)):
            rv.step(DT, tgt, True)
        s = rv.state
        assert s.pos_ned == (0.0, 0.0, 0.0) and s.yaw == 0.0 and s.omega_frd[2] == 0.0


# ----------------------------------------------------------------------------- speed


def _harness_offboard(velocity: tuple[float, float] | None = None) -> Harness:
    h = Harness(step_s=0.02, vehicle_kind="rover")
    h.wait_ready()
    _vel(h, (0.0, 0.0))
    h.run(0.3, lambda: _vel(h, (0.0, 0.0)))
    h.set_mode(6)
    h.arm()
    h.run(1.1, lambda: _vel(h, (0.0, 0.0)))
    assert h.ap.armed and h.heartbeat().custom_mode == 6 << 16
    return h


def _vel(h: Harness, v: tuple[float, float]) -> None:
    h.send(mavlink.MAVLink_set_position_target_local_ned_message(
        0, 1, 1, 1, VEL_ONLY, 0, 0, 0, v[0], v[1], 0, 0, 0, 0, 0, 0))


def _speeds(h: Harness, since: float) -> tuple[np.ndarray, np.ndarray]:
    lp = h.timed("LOCAL_POSITION_NED", since)
    return (np.array([t for t, _m in lp]), np.array([math.hypot(m.vx, m.vy) for _t, m in lp]))


def test_speed_stays_within_sih_force_budget_when_asked_for_far_more() -> None:
    """10 m/s asked, north, east and along a diagonal: the speed setpoint is capped at
    RO_SPEED_LIM and the rover's speed at what its feed-forward throttle RO_SPEED_LIM /
    RO_MAX_THR_SPEED can hold against SIH's rolling resistance and least possible drag
    (SIH_KDV / sqrt(3)), plus 5 % for the PI integral over the test."""
    h = _harness_offboard()
    p = h.ap.params
    lim = p["RO_SPEED_LIM"]
    thr = lim / p["RO_MAX_THR_SPEED"] * 1.05
    force = SIH_FORCE_N * thr - SIH_MU_ROLL * p["SIH_MASS"] * G
    bound = math.sqrt(force / (p["SIH_KDV"] / math.sqrt(3.0)))
    t0 = h.now_boot
    for v in ((10.0, 0.0), (0.0, 10.0), (-7.07, -7.07)):
        h.run(8.0, lambda v=v: _vel(h, v))  # type: ignore[misc]
    _t, speed = _speeds(h, t0)
    assert speed.max() <= bound
    assert speed.max() > 0.9 * lim  # it does drive fast
    targets = [math.hypot(m.vx, m.vy) for m in h.msgs("POSITION_TARGET_LOCAL_NED", t0)]
    assert max(targets) <= lim + 1e-6


def test_speed_setpoint_and_throttle_slew_within_px4_limits_and_acceleration_within_newton(
) -> None:
    """From telemetry: the speed setpoint (POSITION_TARGET_LOCAL_NED) rises at most
    RO_ACCEL_LIM and falls at most RO_DECEL_LIM per second, except where PX4 drops it onto
    the commanded speed (the rover already slower than the ramp); the throttle (ATTITUDE_TARGET
    thrust) moves at most RO_ACCEL_LIM / RO_MAX_THR_SPEED per second; the rover's acceleration
    (finite differences of LOCAL_POSITION_NED) within SIH's force budget."""
    h = _harness_offboard()
    p = h.ap.params
    t0 = h.now_boot
    for v, sec in (((2.5, 0.0), 6.0), ((0.0, 0.0), 4.0), ((0.0, 1.5), 8.0), ((0.0, 0.0), 4.0)):
        h.run(sec, lambda v=v: _vel(h, v))  # type: ignore[misc]
    pt = h.timed("POSITION_TARGET_LOCAL_NED", t0)
    t = np.array([x for x, _m in pt])
    sp = np.array([math.hypot(m.vx, m.vy) for _x, m in pt])
    dv, dt = np.diff(sp), np.diff(t)
    up = dv > p["RO_ACCEL_LIM"] * dt + 1e-6
    down = -dv > p["RO_DECEL_LIM"] * dt + 1e-6
    assert not up.any()
    commanded = {0.0, 2.5, 1.5}
    assert all(round(float(x), 6) in commanded for x in sp[1:][down])  # jumps onto the command
    thr = [(x, m.thrust) for x, m in h.timed("ATTITUDE_TARGET", t0)]
    a = np.array(thr)
    rate = max(p["RO_ACCEL_LIM"], p["RO_DECEL_LIM"]) / p["RO_MAX_THR_SPEED"]
    assert np.all(np.abs(np.diff(a[:, 1])) <= rate * np.diff(a[:, 0]) + 1e-6)
    ts, speed = _speeds(h, t0)
    acc = np.diff(speed) / np.diff(ts)
    m = p["SIH_MASS"]
    push = (SIH_FORCE_N * 2.5 / p["RO_MAX_THR_SPEED"] * 1.02) / m
    brake = (SIH_MU_ROLL * m * G + p["SIH_KDV"] * speed[:-1] ** 2) / m + 0.5 * G  # + kinetic
    assert np.all(acc <= push) and np.all(-acc <= brake)
    assert acc.max() > p["RO_ACCEL_LIM"]  # like PX4's rover: faster than its setpoint ramp


# ----------------------------------------------------------------------------- OFFBOARD


def test_offboard_position_setpoint_drives_there_and_stops_within_nav_acc_rad() -> None:
    """A position behind and beside the rover (mask 2552): it loops round (it cannot turn on
    the spot), stops within NAV_ACC_RAD (0.5 m, airframe 10045) and stays."""
    h = Harness(step_s=0.02, vehicle_kind="rover")
    h.wait_ready()
    goal = (-6.0, 4.0)
    h.run(0.3, lambda: h.pos_setpoint(*goal, 0.0, mask=POS_ONLY))
    h.set_mode(6)
    h.arm()
    assert h.ap.params["NAV_ACC_RAD"] == 0.5
    track: list[tuple[float, float]] = []

    def go() -> None:
        h.pos_setpoint(*goal, 0.0, mask=POS_ONLY)
        track.append(h.ap.state.pos_ned[:2])

    h.run(25.0, go)
    s = h.ap.state
    assert math.dist(s.pos_ned[:2], goal) <= 0.5
    assert math.hypot(*s.vel_ned[:2]) < 0.05
    assert max(math.dist(q, (0.0, 0.0)) for q in track) < 15.0  # a loop, not a wander


# ----------------------------------------------------------------------------- AUTO.MISSION


def _plan_items(plan: Path) -> tuple[list[object], list[tuple[float, float]]]:
    """MISSION_ITEM_INT messages of a .plan and its waypoints (north, east) [m] about home."""
    doc = json.loads(plan.read_text())
    lat0, lon0, _ = doc["mission"]["plannedHomePosition"]
    items, wps = [], []
    for seq, it in enumerate(doc["mission"]["items"]):
        q = [math.nan if v is None else float(v) for v in it["params"]]
        items.append(mavlink.MAVLink_mission_item_int_message(
            1, 1, seq, it["frame"], it["command"], 1 if seq == 0 else 0, 1, q[0], q[1], q[2],
            q[3], round(q[4] * 1e7), round(q[5] * 1e7), q[6], 0))
        r = 6371000.0
        wps.append((math.radians(q[4] - lat0) * r,
                    math.radians(q[5] - lon0) * r * math.cos(math.radians(lat0))))
    return items, wps


def test_rover_square_auto_mission_like_px4_main() -> None:
    """examples/missions/rover_square.plan (a 30 m square): every waypoint reported reached in
    order and passed within NAV_ACC_RAD; slower through each corner than along the legs; the
    last one ends it standing within NAV_ACC_RAD, armed, in Hold ("Mission finished"), like PX4
    main's rover (BENCHMARKS.md: 0.3-0.5 m at the corners, standing 0.3 m from the last)."""
    items, wps = _plan_items(REPO / "examples" / "missions" / "rover_square.plan")
    h = Harness(step_s=0.02, vehicle_kind="rover")
    h.run(0.1)
    assert upload(h, items) == 0
    h.wait_ready()
    h.arm()
    h.set_mode(4, 4)
    rows: list[tuple[float, float, float]] = []

    def rec() -> None:
        s = h.ap.state
        rows.append((s.pos_ned[0], s.pos_ned[1], math.hypot(*s.vel_ned[:2])))

    h.run_until(lambda: any("Mission finished" in t for t in h.texts()), 90.0, rec)
    h.run(3.0, rec)
    a = np.array(rows)
    nav_acc = h.ap.params["NAV_ACC_RAD"]
    for i, (n, e) in enumerate(wps):
        d = np.hypot(a[:, 0] - n, a[:, 1] - e)
        assert d.min() <= nav_acc, f"waypoint {i}: closest {d.min():.2f} m"
        if i < len(wps) - 1:
            near = a[d < 2.0, 2]
            leg = a[(d > 10.0) & (d < 12.0), 2]
            assert near.min() < 0.85 * leg.max(), f"waypoint {i}: no slow-down"
    seqs = [m.seq for m in h.msgs("MISSION_ITEM_REACHED")]  # repeated at 1 Hz
    assert [q for i, q in enumerate(seqs) if i == 0 or q != seqs[i - 1]] == [0, 1, 2, 3]
    assert math.dist(h.ap.state.pos_ned[:2], wps[-1]) <= nav_acc
    assert a[-1, 2] < 0.05 and h.ap.armed
    assert h.heartbeat().custom_mode == (4 << 16) | (3 << 24)  # AUTO.LOITER (Hold)


def test_navigator_corner_acceptance_radius_and_arrival_speed_are_px4s() -> None:
    """The leg target for a right-angle corner: acceptance RA_ACC_RAD_GAIN x L / sin(delta_max)
    / tan(45 deg) within [NAV_ACC_RAD, RA_ACC_RAD_MAX], arrival speed max(RO_MAX_THR_SPEED x
    (1 - RO_SPEED_RED / 2), L x RO_YAW_RATE_LIM / tan(delta_max)); the last waypoint: arrival 0
    and NAV_ACC_RAD; heights ignored."""
    p = ParamStore()
    rv = make_vehicle("rover", p)
    nav = Navigator(p, ground_vehicle=True)
    nav.goto((30.0, 0.0, -25.0), math.nan, 0.0, rv.state, next_ned=(30.0, 30.0, 7.0), stop=False)
    tgt = nav.update(0.01, rv.state)
    assert isinstance(tgt, RoverPositionTarget)
    wb, ang = p["RA_WHEEL_BASE"], p["RA_MAX_STR_ANG"]
    acc = min(max(p["RA_ACC_RAD_GAIN"] * wb / math.sin(ang) / math.tan(math.pi / 4),
                  p["NAV_ACC_RAD"]), p["RA_ACC_RAD_MAX"])
    arrive = max(p["RO_MAX_THR_SPEED"] * (1 - p["RO_SPEED_RED"] / 2),
                 wb * math.radians(p["RO_YAW_RATE_LIM"]) / math.tan(ang))
    assert tgt.acceptance_radius_m == pytest.approx(acc)
    assert tgt.arrival_speed == pytest.approx(arrive)
    assert tgt.position_ne == (30.0, 0.0) and tgt.start_ne == (0.0, 0.0)
    assert tgt.cruising_speed == p["RO_SPEED_LIM"]
    nav.goto((30.0, 30.0, 0.0), math.nan, 0.0, rv.state, start_ned=(30.0, 0.0, 0.0))
    tgt = nav.update(0.01, rv.state)
    assert isinstance(tgt, RoverPositionTarget)
    assert tgt.arrival_speed == 0.0 and tgt.acceptance_radius_m == p["NAV_ACC_RAD"]
    assert tgt.start_ne == (30.0, 0.0)


# ----------------------------------------------------------------------------- parameters


def _airframe_defaults() -> dict[str, float] | None:
    """`param set-default` lines of PX4 main's rover airframe 10045 and the Ackermann defaults
    script it runs, or None without PX4 main beside the repository."""
    for d in REPO.parents:
        root = d / "shared" / "px4_main_sitl" / "etc"
        files = [root / "init.d" / "rc.rover_ackermann_defaults",
                 root / "init.d-posix" / "airframes" / "10045_sihsim_rover_ackermann"]
        if all(f.is_file() for f in files):
            out: dict[str, float] = {}
            for f in files:
                for line in f.read_text().splitlines():
                    w = line.split("#")[0].split()
                    if len(w) == 4 and w[:2] == ["param", "set-default"]:
                        out[w[2]] = float(w[3])
            return out
    return None


def test_rover_parameters_are_airframe_10045s_defaults() -> None:
    want = _airframe_defaults()
    if want is None:
        pytest.skip("PX4 main's etc/ (shared/px4_main_sitl) not found beside the repository")
    store = Harness(vehicle_kind="rover").ap.params
    used = {n: v for n, v in want.items() if n in PARAMS}
    assert len(used) >= 25
    for name, value in used.items():
        assert store[name] == pytest.approx(value), name
    for old, new in ALIASES.items():
        assert store[old] == store[new]


def test_old_rover_names_move_with_their_px4_parameters_and_user_values_win() -> None:
    p = ParamStore({"RO_MAX_SPEED": 1.5, "NAV_ACC_RAD": 1.0})
    assert p["RO_SPEED_LIM"] == 1.5
    Rover(p)  # applies the airframe's defaults, not over the user's
    assert p["NAV_ACC_RAD"] == 1.0 and p["SIH_MASS"] == 20.0
    p.set("RO_YAW_RATE_LIM", 90.0)
    assert p["RO_MAX_YAW_RATE"] == 90.0
