"""AUTO-mode navigator of the mock: takeoff, goto, loiter, land, RTL (flown on the quad model)."""

from __future__ import annotations

import dataclasses
import math

import pytest

from sitl_mock.navigator import Navigator, speed_from_distance
from sitl_mock.params import ParamStore
from sitl_mock.quad import Quadrotor
from sitl_mock.setpoints import PositionTarget, RoverPositionTarget
from sitl_mock.vehicle import VehicleState, make_vehicle

DT = 0.004


class Flight:
    """A quadrotor flown by the navigator; records states and targets."""

    def __init__(self, params: ParamStore | None = None, z: float | None = None) -> None:
        self.p = params or ParamStore()
        self.v = Quadrotor(self.p, seed=0)
        if z is not None:
            self.v.set_state(pos_ned=(0.0, 0.0, z), motors=0.49)
            self.v.mark_airborne(0.49)
        self.nav = Navigator(self.p)
        self.states: list[VehicleState] = []
        self.targets: list[PositionTarget] = []

    def run(self, seconds: float, until_reached: bool = True) -> float:
        t = 0.0
        for _ in range(round(seconds / DT)):
            tgt = self.nav.update(DT, self.v.state)
            self.v.step(DT, tgt, True)
            t += DT
            self.states.append(self.v.state)
            self.targets.append(tgt)
            if until_reached and self.nav.reached:
                break
        return t


def test_takeoff_climbs_at_takeoff_speed_and_reaches_altitude() -> None:
    f = Flight()
    f.nav.takeoff(5.0, f.v.state)
    assert f.nav.phase == "takeoff" and not f.nav.reached
    t = f.run(20.0)
    assert f.nav.reached
    assert -f.v.state.pos_ned[2] == pytest.approx(5.0, abs=0.5)
    assert t < 15.0
    assert max(-s.vel_ned[2] for s in f.states) <= f.p["MPC_TKO_SPEED"] * 1.15
    assert all(abs(s.pos_ned[0]) < 0.05 and abs(s.pos_ned[1]) < 0.05 for s in f.states)
    for tg in f.targets:
        assert tg.has_motion()


def test_goto_smooth_and_within_limits() -> None:
    f = Flight(z=-10.0)
    f.nav.goto((30.0, -20.0, -15.0), math.nan, 2.0, f.v.state)
    t = f.run(40.0)
    assert f.nav.reached and f.nav.phase == "goto"
    s = f.v.state
    assert math.hypot(s.pos_ned[0] - 30.0, s.pos_ned[1] + 20.0) <= 2.0
    cruise, acc = f.p["MPC_XY_CRUISE"], f.p["MPC_ACC_HOR"]
    ref_speeds = [math.hypot(tg.vel_ned[0], tg.vel_ned[1]) for tg in f.targets]
    assert max(ref_speeds) <= cruise + 1e-9
    assert max(ref_speeds) > 0.9 * cruise  # the leg is long enough to reach cruise
    ref_acc = [
        math.hypot(b.vel_ned[0] - a.vel_ned[0], b.vel_ned[1] - a.vel_ned[1]) / DT
        for a, b in zip(f.targets, f.targets[1:], strict=False)
    ]
    assert max(ref_acc) <= acc + 1e-6
    assert max(math.hypot(s.vel_ned[0], s.vel_ned[1]) for s in f.states) <= cruise * 1.15
    # ~36 m at 5 m/s plus acceleration/braking: finishes in a plausible time
    assert 7.0 < t < 14.0
    # faces the waypoint while flying (MPC_YAW_MODE 0)
    bearing = math.atan2(-20.0, 30.0)
    mid = f.states[len(f.states) // 2]
    assert abs(math.remainder(mid.yaw - bearing, 2 * math.pi)) < math.radians(10.0)


def test_goto_continue_to_hold_position() -> None:
    f = Flight(z=-10.0)
    f.nav.goto((10.0, 0.0, -10.0), 0.5, 1.0, f.v.state)
    f.run(20.0)
    f.run(10.0, until_reached=False)
    s = f.v.state
    # the velocity integral that carried the drag makes it overshoot, then bleed back (PX4+SIH)
    assert max(st.pos_ned[0] for st in f.states) < 11.0
    assert math.dist(s.pos_ned, (10.0, 0.0, -10.0)) < 0.4
    assert s.yaw == pytest.approx(0.5, abs=0.02)


def test_loiter_brakes_and_holds() -> None:
    f = Flight(z=-10.0)
    f.nav.goto((100.0, 0.0, -10.0), math.nan, 2.0, f.v.state)
    f.run(6.0, until_reached=False)
    v0 = f.v.state.vel_ned[0]
    assert v0 > 3.0
    f.nav.loiter(f.v.state)
    assert f.nav.reached and f.nav.phase == "loiter"
    x_start = f.v.state.pos_ned[0]
    f.run(8.0, until_reached=False)
    s = f.v.state
    assert math.hypot(*s.vel_ned) < 0.2
    # stopped within a plausible braking distance (v^2 / 2a plus controller lag)
    assert 0.0 < s.pos_ned[0] - x_start < v0 * v0 / (2 * f.p["MPC_ACC_HOR"]) + v0 * 1.5


def test_land_descends_slowly_near_ground_and_detects_landing() -> None:
    f = Flight(z=-15.0)
    f.nav.land(f.v.state)
    assert f.nav.phase == "land"
    f.run(60.0)
    assert f.nav.reached and f.nav.phase == "landed"
    s = f.v.state
    assert s.landed and s.on_ground
    assert math.hypot(s.pos_ned[0], s.pos_ned[1]) < 0.3
    # descent speed: fast high up, MPC_LAND_SPEED below MPC_LAND_ALT2
    high = [st.vel_ned[2] for st in f.states if -st.pos_ned[2] > 12.0]
    low = [st.vel_ned[2] for st in f.states if 0.5 < -st.pos_ned[2] < 4.0]
    assert max(high) > f.p["MPC_LAND_SPEED"] * 1.5
    assert max(low) == pytest.approx(f.p["MPC_LAND_SPEED"], abs=0.1)
    assert max(st.vel_ned[2] for st in f.states) <= f.p["MPC_Z_VEL_MAX_DN"] + 0.15


@pytest.mark.parametrize("wind_m_s", [4.0, 8.0])
def test_land_in_wind_is_detected_and_the_vehicle_stays_down(wind_m_s: float) -> None:
    """A quad landing in steady wind must not keep fighting the wind on the ground (it would
    tilt, saturate the mixer and hop, resetting the land detector forever): after touchdown
    it is detected as landed within LNDMC_TRIG_TIME + 0.5 s (PX4: three stages of a third
    each), stays on the ground with the motors near idle, and does not slide further than the
    wind pushed it during the descent."""
    f = Flight(z=-6.0)
    w = wind_m_s / math.sqrt(2.0)
    f.v.set_wind((w, -w, 0.0))
    f.nav.land(f.v.state)
    f.run(40.0)
    assert f.nav.reached and f.nav.phase == "landed"
    touchdown = next(i for i, st in enumerate(f.states) if st.on_ground)
    landed = next(i for i, st in enumerate(f.states) if st.landed)
    assert (landed - touchdown) * DT <= f.p["LNDMC_TRIG_TIME"] + 0.5
    after = f.states[landed:]
    assert all(st.on_ground for st in after)
    slide = math.dist(after[0].pos_ned[:2], after[-1].pos_ned[:2])
    assert slide < 0.05
    # after the land detector: no thrust (a landed, still-armed vehicle idles its motors)
    f.run(2.0, until_reached=False)
    assert all(st.on_ground and st.landed and st.thrust_norm < 0.1 for st in f.states[-400:])


def test_rtl_climbs_returns_and_lands_at_home() -> None:
    p = ParamStore({"RTL_RETURN_ALT": 8.0})
    f = Flight(p, z=-4.0)
    f.v.set_state(pos_ned=(25.0, 10.0, -4.0), motors=0.49)
    f.nav.rtl(f.v.state)
    assert f.nav.phase == "rtl_climb"
    phases = []
    for _ in range(40):
        f.run(2.0)
        phases.append(f.nav.phase)
        if f.nav.reached:
            break
    assert f.nav.reached and f.nav.phase == "landed"
    assert "rtl_return" in phases
    s = f.v.state
    assert math.hypot(s.pos_ned[0], s.pos_ned[1]) < 1.0 and s.landed
    # it climbed to the return altitude before flying home
    far = [st for st in f.states if math.hypot(st.pos_ned[0], st.pos_ned[1]) > 20.0]
    assert min(st.pos_ned[2] for st in f.states) == pytest.approx(-8.0, abs=0.5)
    assert all(-st.pos_ned[2] >= 3.5 for st in far)


def test_rtl_keeps_a_higher_current_altitude() -> None:
    p = ParamStore({"RTL_RETURN_ALT": 5.0})
    f = Flight(p, z=-12.0)
    f.v.set_state(pos_ned=(15.0, 0.0, -12.0), motors=0.49)
    f.nav.rtl(f.v.state)
    f.run(4.0, until_reached=False)
    assert f.nav.phase == "rtl_return"
    assert f.v.state.pos_ned[2] == pytest.approx(-12.0, abs=0.5)


def test_navigator_is_pure_and_deterministic() -> None:
    def trace() -> list[PositionTarget]:
        p = ParamStore()
        v = make_vehicle("quad", p, seed=0)
        nav = Navigator(p)
        nav.takeoff(3.0, v.state)
        out = []
        for _ in range(2000):
            tgt = nav.update(DT, v.state)
            v.step(DT, tgt, True)
            out.append(tgt)
        return out

    a, b = trace(), trace()
    assert repr(a) == repr(b)


def test_navigator_rejects_bad_input() -> None:
    f = Flight(z=-5.0)
    with pytest.raises(ValueError):
        f.nav.goto((math.nan, 0.0, -5.0), 0.0, 2.0, f.v.state)
    with pytest.raises(ValueError):
        f.nav.takeoff(math.inf, f.v.state)
    with pytest.raises(ValueError):
        f.nav.update(0.0, f.v.state)


def test_set_cruise_speed_changes_and_restores_speed() -> None:
    f = Flight(z=-10.0)
    f.nav.set_cruise_speed(2.0)
    assert f.nav.cruise_speed == 2.0
    f.nav.goto((40.0, 0.0, -10.0), 0.0, 2.0, f.v.state)
    f.run(10.0, until_reached=False)
    assert max(tg.vel_ned[0] for tg in f.targets) == pytest.approx(2.0, abs=1e-9)
    f.nav.set_cruise_speed(math.nan)
    assert f.nav.cruise_speed == f.p["MPC_XY_CRUISE"]
    f.nav.set_cruise_speed(100.0)
    assert f.nav.cruise_speed == f.p["MPC_XY_VEL_MAX"]


def test_ground_vehicle_navigation_with_the_rover() -> None:
    """A ground vehicle's goto is a 2-D leg (the mission altitude is ignored) driven to within
    its acceptance radius at no more than RO_SPEED_LIM as the speed setpoint; RTL drives home and
    stops there (NAV_ACC_RAD); takeoff and land complete at once."""
    p = ParamStore()
    rv = make_vehicle("rover", p, seed=0)
    nav = Navigator(p, ground_vehicle=True)
    nav.takeoff(10.0, rv.state)
    assert nav.reached
    nav.goto((20.0, -15.0, -30.0), math.nan, 1.0, rv.state)  # mission altitude is ignored
    for _ in range(round(40.0 / 0.01)):
        tgt = nav.update(0.01, rv.state)
        assert isinstance(tgt, RoverPositionTarget) and tgt.position_ne == (20.0, -15.0)
        rv.step(0.01, tgt, True)
        assert rv.state.pos_ned[2] == 0.0
        last = rv.last_position_target
        assert last is not None and math.hypot(*last.vel_ned[:2]) <= p["RO_SPEED_LIM"] + 1e-9
        if nav.reached:
            break
    assert nav.reached and math.dist(rv.state.pos_ned[:2], (20.0, -15.0)) <= 1.0
    assert nav.cruise_speed == p["RO_SPEED_LIM"]
    nav.rtl(rv.state)
    for _ in range(round(40.0 / 0.01)):
        rv.step(0.01, nav.update(0.01, rv.state), True)
        if nav.reached:
            break
    assert nav.phase == "landed" and nav.reached
    assert math.hypot(*rv.state.pos_ned[:2]) < p["NAV_ACC_RAD"]
    nav.land(rv.state)
    assert nav.reached and nav.phase == "landed"


def test_auto_reference_is_jerk_limited_and_brakes_in_time() -> None:
    """MPC_JERK_AUTO: the reference acceleration of a goto changes by at most jerk * dt per
    update and never exceeds MPC_ACC_HOR; the braking law leaves room to stop on the goal.
    The last step of a ramp (onto a steady speed) may change it by up to twice that: while
    the vehicle lags the reference, the reference's time runs slower than the clock
    (MPC_XY_ERR_MAX) and the ramp's last step is shorter than the one it was planned with."""
    f = Flight(z=-10.0)
    jerk, a_max = f.p["MPC_JERK_AUTO"], f.p["MPC_ACC_HOR"]
    assert jerk == 4.0  # PX4's default
    f.nav.goto((40.0, 0.0, -10.0), math.nan, 2.0, f.v.state)
    f.run(25.0, until_reached=False)
    acc = [t.acc_ned for t in f.targets]
    for a0, a1, a2 in zip(acc, acc[1:], acc[2:], strict=False):
        if a1 == (0.0, 0.0, 0.0):  # the reference snapped onto the goal or cruises
            continue
        ramp_end = a2 == (0.0, 0.0, 0.0)
        assert math.dist(a0, a1) <= jerk * DT * (2.0 if ramp_end else 1.001)
        assert math.hypot(a1[0], a1[1]) <= a_max * 1.001
    assert max(t.vel_ned[0] for t in f.targets) == pytest.approx(f.p["MPC_XY_CRUISE"], rel=0.01)
    assert f.targets[-1].pos_ned[0] == 40.0  # the reference ends on the goal
    # the braking law: from speed_from_distance(d), a jerk-limited stop needs at most d
    for d in (0.5, 2.0, 10.0, 30.0):
        v = speed_from_distance(jerk, a_max, d)
        t_ramp = a_max / jerk
        if v <= a_max * t_ramp:  # triangular deceleration profile: a peak sqrt(v j)
            t_half = math.sqrt(v / jerk)
            need = v * 2 * t_half - jerk * t_half**3  # exact distance of the symmetric ramp
        else:
            dv_ramp = 0.5 * jerk * t_ramp**2
            t_const = (v - 2 * dv_ramp) / a_max
            need = (v * t_ramp - jerk * t_ramp**3 / 6
                    + (v - dv_ramp) * t_const - 0.5 * a_max * t_const**2
                    + dv_ramp * t_ramp - jerk * t_ramp**3 / 6)
        assert 0.0 < need <= d


@pytest.mark.parametrize("kdv", [1.0, 3.0])
def test_auto_reference_waits_for_a_vehicle_that_lags_behind(kdv: float) -> None:
    """PX4's PositionSmoothing: while the vehicle is behind the AUTO reference, the reference
    advances by dt * (1 - lag / MPC_XY_ERR_MAX), so it never leads by MPC_XY_ERR_MAX or more;
    its velocity (the feed-forward) still reaches the cruise speed. With SIH's drag the vehicle
    cruises below the reference's speed (real PX4 v1.16 SITL, default parameters: 3.8-4.4 m/s on
    40 m legs at MPC_XY_CRUISE 5), more so the stronger the drag."""
    p = ParamStore()
    p.set("SIH_KDV", kdv)
    f = Flight(params=p, z=-10.0)
    f.nav.goto((60.0, 0.0, -10.0), math.nan, 2.0, f.v.state)
    f.run(30.0)
    assert f.nav.reached
    err_max = f.p["MPC_XY_ERR_MAX"]
    lead = [math.hypot(t.pos_ned[0] - s.pos_ned[0], t.pos_ned[1] - s.pos_ned[1])
            for t, s in zip(f.targets, f.states, strict=True)]
    assert max(lead) < err_max
    assert max(lead) > 0.1 * err_max  # the vehicle did lag: the property was exercised
    cruise = f.p["MPC_XY_CRUISE"]
    assert max(t.vel_ned[0] for t in f.targets) == pytest.approx(cruise, rel=0.01)
    v_max = max(s.vel_ned[0] for s in f.states)
    assert v_max < cruise
    if kdv > 1.0:
        assert v_max < 0.8 * cruise


def test_the_reference_runs_at_its_own_speed_when_the_vehicle_is_ahead() -> None:
    """No stretch when the vehicle is ahead of the reference (the lag points against the
    reference's velocity): the reference position advances by its velocity times dt."""
    f = Flight(z=-10.0)
    f.nav.goto((30.0, 0.0, -10.0), math.nan, 2.0, f.v.state)
    f.run(3.0, until_reached=False)
    ref = f.targets[-1]
    ahead = dataclasses.replace(f.v.state, pos_ned=(ref.pos_ned[0] + 1.0, 0.0, -10.0))
    behind = dataclasses.replace(f.v.state, pos_ned=(ref.pos_ned[0] - 1.0, 0.0, -10.0))
    x0 = ref.pos_ned[0]
    step_ahead = f.nav.update(DT, ahead).pos_ned[0] - x0
    x1 = x0 + step_ahead
    step_behind = f.nav.update(DT, behind).pos_ned[0] - x1
    v = ref.vel_ned[0]
    assert step_ahead == pytest.approx(v * DT, rel=0.05)
    # 1 m behind with MPC_XY_ERR_MAX 2 m: half the step
    assert step_behind == pytest.approx(0.5 * v * DT, rel=0.05)


@pytest.mark.parametrize(("dist_max", "crawls"), [(100.0, True), (0.0, False)])
def test_auto_land_crawls_the_last_metre_when_the_distance_sensor_sees_the_ground(
        dist_max: float, crawls: bool) -> None:
    """PX4 FlightTaskAuto: below MPC_LAND_ALT3 the landing descends at MPC_LAND_CRWL when a
    distance sensor measures the ground (SIH simulates one, range SIH_DISTSNSR_MAX); without
    it the last metre is flown at MPC_LAND_SPEED."""
    p = ParamStore()
    p.set("SIH_DISTSNSR_MAX", dist_max)
    f = Flight(params=p, z=-6.0)
    f.nav.land(f.v.state)
    f.run(60.0)
    assert f.nav.reached and f.v.state.landed
    alt3 = f.p["MPC_LAND_ALT3"]
    low = [s.vel_ned[2] for s in f.states if 0.2 < -s.pos_ned[2] < alt3 - 0.3]
    assert low
    expected = f.p["MPC_LAND_CRWL"] if crawls else f.p["MPC_LAND_SPEED"]
    assert sum(low) / len(low) == pytest.approx(expected, abs=0.05)


@pytest.mark.parametrize("trig_s", [1.0, 3.0])
def test_landing_is_detected_after_the_land_detector_trigger_time(trig_s: float) -> None:
    """PX4's land detector passes three stages (ground contact, maybe landed, landed) of
    LNDMC_TRIG_TIME / 3 each: a vehicle that settled on the ground is reported landed no sooner
    than LNDMC_TRIG_TIME after touchdown, and not much later."""
    p = ParamStore()
    p.set("LNDMC_TRIG_TIME", trig_s)
    f = Flight(params=p, z=-3.0)
    f.nav.land(f.v.state)
    f.run(40.0)
    touchdown = next(i for i, st in enumerate(f.states) if st.on_ground)
    landed = next(i for i, st in enumerate(f.states) if st.landed)
    held = (landed - touchdown + 1) * DT  # the touchdown step counts
    assert trig_s - 1e-9 <= held <= trig_s + 0.1
