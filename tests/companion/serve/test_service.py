"""The serve state machine (companion.serve.service) on injected observations and time, and its
helpers (mission from downloaded items, rotating tlogs). No sockets, no clock."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from pymavlink import mavutil

from companion.mavlink import FlightMode, WireMissionItem
from companion.mavlink.telemetry import HomePosition, LocalPosition, MissionCurrent
from companion.mission import load_mission, mission_to_flight_plan, mission_upload_items
from companion.planning.config import VehicleFile
from companion.planning.schedule import build_schedule
from companion.serve.program import plan_program
from companion.serve.runner import RotatingTlog
from companion.serve.service import (
    Announce,
    DownloadMission,
    HoldStream,
    LogEvent,
    MissionStream,
    Observation,
    PlanJoin,
    RequestMode,
    ServeService,
    ServiceConfig,
)

MISSIONS = Path(__file__).resolve().parents[2] / "data" / "missions"


def wire_items(path: Path) -> tuple[list[WireMissionItem], HomePosition]:
    """A mission file as PX4 would return it on download (MISSION_ITEM_INT), and its home."""
    m = load_mission(path)
    # mission_upload_items gives exactly the MISSION_ITEM_INTs PX4 stores and returns
    items = [WireMissionItem(i, u.frame, u.command, int(i == 0), u.autocontinue, u.param1,
                         u.param2, u.param3, u.param4, u.x, u.y, u.z)
             for i, u in enumerate(mission_upload_items(m))]
    home = HomePosition(0.0, m.home.lat_deg, m.home.lon_deg, m.home.alt_amsl_m, (0.0, 0.0, 0.0))
    return items, home


def obs(t: float, *, armed: bool = True, mode: FlightMode | None = FlightMode.HOLD,
        pos: tuple[float, float, float] = (0.0, 0.0, -5.0), landed: int = 2,
        mission: MissionCurrent | None = None, link_ok: bool = True) -> Observation:
    return Observation(now_s=t, link_ok=link_ok, armed=armed, mode=mode, landed_state=landed,
                       position=LocalPosition(t, t, pos, (0.0, 0.0, 0.0), "LOCAL_POSITION_NED"),
                       yaw=0.0, mission=mission)


@pytest.fixture(scope="module")
def program_and_key() -> tuple[object, tuple[int, int]]:
    items, home = wire_items(MISSIONS / "px4_short.plan")
    key = (1234, len(items))
    return plan_program(items, home, key, ServiceConfig()), key


def test_downloaded_items_plan_like_the_mission_file() -> None:
    """Oracle: the same file planned straight from disk (plannedHomePosition as home)."""
    path = MISSIONS / "px4_short.plan"
    items, home = wire_items(path)
    prog = plan_program(items, home, (1, len(items)), ServiceConfig())
    vf = VehicleFile()
    direct = build_schedule(mission_to_flight_plan(load_mission(path), vehicle="quad"),
                            vf.params, vf.limits)
    np.testing.assert_allclose(prog.schedule.waypoints_ned, direct.waypoints_ned, atol=0.02)
    assert prog.final_action == direct.final_action == "land"
    # the flown part stops above the land point: PX4 lands itself
    assert prog.t_end < direct.duration_s
    # (the last point to reach is the LAND item, above the land point: no touchdown point)
    assert abs(prog.reference(prog.t_end).pos_ned[2] - direct.waypoints_ned[-1][2]) < 0.05


def test_the_vehicles_planning_parameters_reach_the_plan() -> None:
    """A faster MPC_XY_CRUISE (the mission's legs have no DO_CHANGE_SPEED) and a larger
    NAV_ACC_RAD read from the vehicle change the downloaded mission's plan accordingly."""
    from companion.mission.px4_params import Px4PlanningParams

    items, home = wire_items(MISSIONS / "px4_short.plan")
    slow = plan_program(items, home, (1, len(items)),
                        ServiceConfig(px4=Px4PlanningParams(MPC_XY_CRUISE=3.0)))
    fast = plan_program(items, home, (1, len(items)),
                        ServiceConfig(px4=Px4PlanningParams(MPC_XY_CRUISE=10.0, NAV_ACC_RAD=4.0)))
    assert fast.t_end < slow.t_end
    assert max(fast.schedule.acceptance_m) == 4.0 > max(slow.schedule.acceptance_m)


def test_a_speed_item_above_the_level_speed_is_announced_to_the_pilot() -> None:
    """serve plans the downloaded mission like `fly`, and says to the ground station what the
    plan cannot give (a 15-17 m/s speed item flown at the 6.9 m/s level speed cap)."""
    items, home = wire_items(MISSIONS / "speed_items.plan")
    prog = plan_program(items, home, (1, len(items)), ServiceConfig())
    acts = ServeService().on_planned((1, len(items)), prog, 0.0)
    said = [a.text for a in acts if isinstance(a, Announce) and "above" in a.text]
    assert len(said) == 1 and "15" in said[0] and "6.9 m/s" in said[0]
    items, home = wire_items(MISSIONS / "px4_short.plan")
    quiet = ServeService().on_planned((1, len(items)), plan_program(
        items, home, (1, len(items)), ServiceConfig()), 0.0)
    assert not [a for a in quiet if isinstance(a, Announce) and "above" in a.text]


def test_hold_is_streamed_only_while_armed_and_flying() -> None:
    svc = ServeService()
    svc.update(obs(0.0, armed=False, landed=1))
    assert svc.stream is None
    svc.update(obs(0.1, armed=True, landed=1))  # armed on the ground
    assert svc.stream is None
    svc.update(obs(0.2, pos=(1.0, 2.0, -3.0)))
    assert isinstance(svc.stream, HoldStream)
    assert svc.stream.setpoint.pos_ned == (1.0, 2.0, -3.0)
    svc.update(obs(0.3, pos=(1.5, 2.0, -3.0)))  # outside OFFBOARD the hold follows the vehicle
    assert svc.stream.setpoint.pos_ned == (1.5, 2.0, -3.0)
    svc.update(obs(0.4, link_ok=False))
    assert svc.stream is None


def test_the_hold_stands_the_vehicle_still_in_truth_not_in_the_estimate() -> None:
    """The estimate's velocity reads (0.4, -0.3) m/s more than the vehicle moves (its position
    says so: ``vel_correction_ned``; the vehicle stands still). The hold setpoint's velocity is
    what the estimate reads at rest, so PX4's velocity loop, flying it at the switch to
    OFFBOARD, stops the vehicle."""
    svc = ServeService()
    standing = LocalPosition(0.2, 0.2, (1.0, 2.0, -3.0), (0.4, -0.3, 0.05), "LOCAL_POSITION_NED",
                             vel_correction_ned=(-0.4, 0.3, 0.0))
    svc.update(dataclasses.replace(obs(0.2), position=standing))
    assert isinstance(svc.stream, HoldStream)
    # the estimate's reading of "stopped"
    assert svc.stream.setpoint.vel_ned[:2] == pytest.approx(standing.vel_ned[:2])
    assert svc.stream.setpoint.vel_ned[2] == 0.0


def test_mission_is_downloaded_again_only_when_px4_reports_another_one() -> None:
    svc = ServeService()
    acts = svc.update(obs(0.0, mission=MissionCurrent(0.0, 0, 5, 111)))
    assert [a.key for a in acts if isinstance(a, DownloadMission)] == [(111, 5)]
    # while the download/plan runs, and afterwards with the same id: nothing new
    assert not [a for a in svc.update(obs(0.1, mission=MissionCurrent(0.1, 0, 5, 111)))
                if isinstance(a, DownloadMission)]
    svc.on_planned((111, 5), "the vehicle has no mission", 0.2)
    assert not [a for a in svc.update(obs(0.3, mission=MissionCurrent(0.3, 0, 5, 111)))
                if isinstance(a, DownloadMission)]
    acts = svc.update(obs(0.4, mission=MissionCurrent(0.4, 0, 5, 222)))
    assert [a.key for a in acts if isinstance(a, DownloadMission)] == [(222, 5)]
    svc.on_planned((222, 5), "the vehicle has no mission", 0.45)
    acts = svc.update(obs(0.5, mission=MissionCurrent(0.5, 0, 65535, 0)))
    assert any(isinstance(a, Announce) and "no mission" in a.text for a in acts)


def test_offboard_flies_the_plan_and_leaving_it_holds_in_the_same_update(
        program_and_key: tuple[object, tuple[int, int]]) -> None:
    prog, key = program_and_key
    svc = ServeService()
    svc.on_planned(key, prog, 0.0)  # type: ignore[arg-type]
    start = prog.reference(prog.t_begin).pos_ned  # type: ignore[attr-defined]
    p0 = (float(start[0]), float(start[1]), float(start[2]))
    svc.update(obs(1.0, pos=p0))
    acts = svc.update(obs(1.05, mode=FlightMode.OFFBOARD, pos=p0))
    assert isinstance(svc.stream, MissionStream), acts
    ms = svc.stream
    # the reference starts at the vehicle and ends on the plan
    assert np.linalg.norm(ms.source.reference(0.0).pos_ned - np.asarray(p0)) < 0.05
    svc.update(obs(4.0, mode=FlightMode.OFFBOARD, pos=p0))
    assert svc.stream is ms
    acts = svc.update(obs(4.05, mode=FlightMode.POSCTL, pos=(3.0, 0.0, -4.0)))
    assert isinstance(svc.stream, HoldStream)
    assert svc.stream.setpoint.pos_ned == (3.0, 0.0, -4.0)
    assert any(isinstance(a, Announce) and "paused" in a.text for a in acts)


def test_a_deferred_join_holds_until_planned_and_flies_the_same_join_from_then(
        program_and_key: tuple[object, tuple[int, int]]) -> None:
    """The runner plans the join off its event loop (defer_join): entering OFFBOARD only asks for
    it and keeps holding; the result flies from the time it arrives, the same join as planned
    in place (position and velocity at equal flight times)."""
    prog, key = program_and_key
    p0 = (8.0, -1.0, -4.0)  # beside the first leg: a real join
    now = ServeService()
    now.on_planned(key, prog, 0.0)  # type: ignore[arg-type]
    now.update(obs(0.0, pos=p0))
    now.update(obs(0.05, mode=FlightMode.OFFBOARD, pos=p0))
    assert isinstance(now.stream, MissionStream) and now.stream.join_s > 0.0
    svc = ServeService(defer_join=True)
    svc.on_planned(key, prog, 0.0)  # type: ignore[arg-type]
    svc.update(obs(0.0, pos=p0))
    acts = svc.update(obs(0.05, mode=FlightMode.OFFBOARD, pos=p0))
    reqs = [a for a in acts if isinstance(a, PlanJoin)]
    assert len(reqs) == 1 and svc.state == "joining"
    assert isinstance(svc.stream, HoldStream) and svc.stream.setpoint.pos_ned == p0
    # further observations while it is planned: still holding, not asked twice
    acts = svc.update(obs(0.1, mode=FlightMode.OFFBOARD, pos=p0))
    assert not [a for a in acts if isinstance(a, PlanJoin)]
    assert isinstance(svc.stream, HoldStream)
    result = svc.plan_join(reqs[0])
    acts = svc.on_joined(reqs[0].token, result, 0.35)
    assert svc.state == "mission" and isinstance(svc.stream, MissionStream)
    assert svc.stream.t0_s == 0.35
    assert any(isinstance(a, Announce) and "flying mission" in a.text for a in acts)
    for t in (0.0, 0.5, 1.0, now.stream.join_s + 1.0):
        a, b = now.stream.source.reference(t), svc.stream.source.reference(t)
        assert np.allclose(a.pos_ned, b.pos_ned) and np.allclose(a.vel_ned, b.vel_ned)


def test_a_join_planned_after_the_pilot_left_offboard_or_the_mission_changed_is_discarded(
        program_and_key: tuple[object, tuple[int, int]]) -> None:
    prog, key = program_and_key
    p0 = (8.0, -1.0, -4.0)
    svc = ServeService(defer_join=True)
    svc.on_planned(key, prog, 0.0)  # type: ignore[arg-type]
    svc.update(obs(0.0, pos=p0))
    first = next(a for a in svc.update(obs(0.05, mode=FlightMode.OFFBOARD, pos=p0))
             if isinstance(a, PlanJoin))
    svc.update(obs(0.1, mode=FlightMode.HOLD, pos=(8.5, -1.0, -4.0)))  # the pilot takes over
    acts = svc.on_joined(first.token, svc.plan_join(first), 0.3)
    assert any(isinstance(a, LogEvent) and a.event == "join_discarded" for a in acts)
    assert svc.state == "hold" and isinstance(svc.stream, HoldStream)
    assert svc.stream.setpoint.pos_ned == (8.5, -1.0, -4.0)
    # back in OFFBOARD: a new request; the old result, arriving late, is discarded too
    second = next(a for a in svc.update(obs(0.4, mode=FlightMode.OFFBOARD, pos=p0))
              if isinstance(a, PlanJoin))
    assert second.token != first.token
    svc.on_joined(first.token, svc.plan_join(first), 0.5)
    assert svc.state == "joining" and isinstance(svc.stream, HoldStream)
    # the mission changes while the join is planned: hold, and the join is never flown
    acts = svc.on_planned((999, 3), prog, 0.55)  # type: ignore[arg-type]
    assert svc.state == "offboard_hold"
    assert any(isinstance(a, Announce) and "changed in flight" in a.text for a in acts)
    acts = svc.on_joined(second.token, svc.plan_join(second), 0.6)
    assert any(isinstance(a, LogEvent) and a.event == "join_discarded" for a in acts)
    assert isinstance(svc.stream, HoldStream) and svc.state == "offboard_hold"
    # a join that cannot be planned holds with its reason
    svc.update(obs(0.7, mode=FlightMode.HOLD, pos=p0))
    third = next(a for a in svc.update(obs(0.8, mode=FlightMode.OFFBOARD, pos=p0))
             if isinstance(a, PlanJoin))
    acts = svc.on_joined(third.token, "no joining trajectory", 0.9)
    assert svc.state == "offboard_hold" and isinstance(svc.stream, HoldStream)
    assert any(isinstance(a, Announce) and "cannot join" in a.text for a in acts)


def test_end_of_plan_requests_the_final_action_while_streaming(
        program_and_key: tuple[object, tuple[int, int]]) -> None:
    prog, key = program_and_key
    svc = ServeService()
    svc.on_planned(key, prog, 0.0)  # type: ignore[arg-type]
    end = prog.reference(prog.t_end).pos_ned  # type: ignore[attr-defined]
    pe = (float(end[0]), float(end[1]), float(end[2]))
    svc.update(obs(0.0, pos=pe))
    svc.reached = len(prog.waypoints) - 1  # type: ignore[attr-defined]
    svc.t_progress = prog.t_end - 0.01  # type: ignore[attr-defined]
    svc.update(obs(0.05, mode=FlightMode.OFFBOARD, pos=pe))
    acts: list[object] = []
    t = 0.1
    while not any(isinstance(a, RequestMode) for a in acts) and t < 30.0:
        acts = list(svc.update(obs(t, mode=FlightMode.OFFBOARD, pos=pe)))
        t += 0.05
    req = [a for a in acts if isinstance(a, RequestMode)]
    assert req and req[0].mode is FlightMode.LAND
    assert isinstance(svc.stream, HoldStream)  # still streaming until PX4 switches
    # PX4 switched: the mission is done for this flight, re-entering OFFBOARD just holds
    svc.update(obs(t + 0.1, mode=FlightMode.LAND, pos=pe))
    acts = svc.update(obs(t + 0.2, mode=FlightMode.OFFBOARD, pos=pe))
    assert isinstance(svc.stream, HoldStream)
    # disarming resets the flight
    svc.update(obs(t + 0.3, armed=False, landed=1, mode=FlightMode.LAND, pos=pe))
    assert svc.stream is None and not svc.done and svc.reached == 0


def test_shutdown_asks_for_hold_only_when_flying_on_our_stream() -> None:
    svc = ServeService()
    assert any(isinstance(a, RequestMode) and a.mode is FlightMode.HOLD
               for a in svc.shutdown(obs(0.0, mode=FlightMode.OFFBOARD)))
    assert not any(isinstance(a, RequestMode) for a in svc.shutdown(obs(0.0)))
    assert not any(isinstance(a, RequestMode)
                   for a in svc.shutdown(obs(0.0, armed=False, mode=FlightMode.OFFBOARD)))


def test_join_from_anywhere_beside_the_mission_can_be_planned(
        program_and_key: tuple[object, tuple[int, int]]) -> None:
    prog, key = program_and_key
    rng = np.random.default_rng(3)
    for _ in range(12):
        svc = ServeService()
        svc.on_planned(key, prog, 0.0)  # type: ignore[arg-type]
        p = (float(rng.uniform(-3, 13)), float(rng.uniform(-3, 11)), float(rng.uniform(-6, -2)))
        svc.reached = int(rng.integers(0, len(prog.waypoints)))  # type: ignore[attr-defined]
        svc.update(obs(0.0, pos=p))
        acts = svc.update(obs(0.05, mode=FlightMode.OFFBOARD, pos=p))
        assert isinstance(svc.stream, MissionStream), (p, acts)
        r0 = svc.stream.source.reference(0.0)
        assert np.linalg.norm(r0.pos_ned - np.asarray(p)) < 0.05
        assert all(math.isfinite(float(x)) for x in r0.pos_ned)


def test_rotating_tlog_rotates_keeps_the_newest_and_stays_readable(tmp_path: Path) -> None:
    from pymavlink.dialects.v20 import common as mavlink2

    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    frame = mav.heartbeat_encode(2, 12, 29, 0, 3).pack(mav)
    tl = RotatingTlog(tmp_path, max_bytes=1024, keep=3)
    for i in range(200):
        tl.write(frame, 1.7e9 + i)
        if i == 10:
            tl.rotate()
    tl.close()
    files = sorted(tmp_path.glob("serve-*.tlog"))
    assert len(files) == 3
    assert all(f.stat().st_size <= 1024 for f in files)
    m = mavutil.mavlink_connection(str(files[-1]))
    n = 0
    while (msg := m.recv_match(type="HEARTBEAT")) is not None:
        assert msg.custom_mode == 0 and msg._timestamp >= 1.7e9
        n += 1
    m.close()
    assert n == files[-1].stat().st_size // (len(frame) + 8)


def test_a_new_mission_in_flight_stops_the_old_one_and_holds(
        program_and_key: tuple[object, tuple[int, int]]) -> None:
    prog, key = program_and_key
    svc = ServeService()
    svc.on_planned(key, prog, 0.0)  # type: ignore[arg-type]
    start = prog.reference(prog.t_begin).pos_ned  # type: ignore[attr-defined]
    p0 = (float(start[0]), float(start[1]), float(start[2]))
    svc.update(obs(0.0, pos=p0))
    svc.update(obs(0.05, mode=FlightMode.OFFBOARD, pos=p0))
    assert isinstance(svc.stream, MissionStream)
    svc.update(obs(2.0, mode=FlightMode.OFFBOARD, pos=p0))
    acts = svc.on_planned((999, 3), prog, 2.1)  # type: ignore[arg-type]
    assert isinstance(svc.stream, HoldStream)
    assert any(isinstance(a, Announce) and "changed in flight" in a.text for a in acts)
    # still in OFFBOARD: it keeps holding until the pilot re-enters OFFBOARD
    svc.update(obs(2.2, mode=FlightMode.OFFBOARD, pos=p0))
    assert isinstance(svc.stream, HoldStream)
    svc.update(obs(2.3, mode=FlightMode.HOLD, pos=p0))
    svc.update(obs(2.4, mode=FlightMode.OFFBOARD, pos=p0))
    assert isinstance(svc.stream, MissionStream)


def test_final_action_is_requested_again_every_3_s_while_still_in_offboard(
        program_and_key: tuple[object, tuple[int, int]]) -> None:
    prog, key = program_and_key
    svc = ServeService()
    svc.on_planned(key, prog, 0.0)  # type: ignore[arg-type]
    end = prog.reference(prog.t_end).pos_ned  # type: ignore[attr-defined]
    pe = (float(end[0]), float(end[1]), float(end[2]))
    svc.update(obs(0.0, pos=pe))
    svc.reached = len(prog.waypoints) - 1  # type: ignore[attr-defined]
    svc.t_progress = prog.t_end - 0.01  # type: ignore[attr-defined]
    svc.update(obs(0.05, mode=FlightMode.OFFBOARD, pos=pe))
    times: list[float] = []
    for i in range(2, 400):  # 20 s at 20 Hz, PX4 never switches
        t = i * 0.05
        acts = svc.update(obs(t, mode=FlightMode.OFFBOARD, pos=pe))
        times += [t for a in acts if isinstance(a, RequestMode)
                  and a.mode is FlightMode.LAND and a.why.startswith("mission end: land")]
    assert len(times) >= 5 and svc.state == "finishing"
    gaps = np.diff(times)
    assert np.all(gaps >= 3.0 - 1e-9) and np.all(gaps <= 3.0 + 0.05 + 1e-9)
    # PX4 switched: no more requests, re-entering OFFBOARD holds
    svc.update(obs(20.1, mode=FlightMode.LAND, pos=pe))
    for t in (20.2, 24.0, 28.0):
        acts = svc.update(obs(t, mode=FlightMode.OFFBOARD, pos=pe))
        assert not any(isinstance(a, RequestMode) for a in acts)
    assert svc.state == "offboard_hold"


@pytest.mark.parametrize("y_held", [0.6, 1.5, 2.4, 3.4, 4.5, 5.5])
@pytest.mark.parametrize("speed", [0.0, 0.3, 1.0])
def test_the_resume_join_never_backs_up_along_the_leg(
        program_and_key: tuple[object, tuple[int, int]], y_held: float, speed: float) -> None:
    """Paused on the leg wp 1 (10, 0) -> wp 2 (10, 8) of px4_short.plan (the leg points along
    +y, east) and resumed: the reference must move on toward wp 2, never back toward wp 1
    (real PX4, CI: the old join was planned as a three-piece time allocation whose last piece
    swung the vehicle 0.45 m back at -0.85 m/s, and the EKF's accelerometer bias estimate went
    from 0 to -0.2 m/s^2 in those swings, which drifted the landing after it by 1.4-2.5 m).
    Oracles: the east velocity of the reference is never negative (beyond the vehicle's own at
    the start); it stays within 1.1 x the planning limits of acceleration; position and velocity
    are continuous where the join meets the plan."""
    prog, key = program_and_key
    svc = ServeService()
    svc.on_planned(key, prog, 0.0)  # type: ignore[arg-type]
    svc.reached = 2  # wp 0 (takeoff point) and wp 1 passed  # type: ignore[attr-defined]
    p = (9.3, y_held, -4.15)
    v = (0.2, speed, 0.1)  # drifting on in Hold, as PX4 brakes
    o = Observation(now_s=0.0, link_ok=True, armed=True, mode=FlightMode.HOLD, landed_state=2,
                    position=LocalPosition(0.0, 0.0, p, v, "LOCAL_POSITION_NED"), yaw=1.57)
    svc.update(o)
    svc.update(dataclasses.replace(o, now_s=0.05, mode=FlightMode.OFFBOARD))
    ms = svc.stream
    assert isinstance(ms, MissionStream)
    ts = np.linspace(0.0, ms.join_s + (prog.t_end - ms.t_join), 400)  # type: ignore[attr-defined]
    refs = [ms.source.reference(float(t)) for t in ts]
    vel = np.array([r.vel_ned for r in refs])
    acc = np.array([r.acc_ned for r in refs])
    assert np.linalg.norm(refs[0].pos_ned - np.asarray(p)) < 0.05
    assert vel[:, 1].min() >= min(0.0, speed) - 0.05, vel[:, 1].min()
    limits = ServiceConfig().limits
    assert np.linalg.norm(acc, axis=1).max() <= 1.1 * limits.max_acc_m_s2 + 1e-6
    # the join meets the plan: no jump in position or velocity across join_s
    a, b = ms.source.reference(ms.join_s - 1e-6), ms.source.reference(ms.join_s + 1e-6)
    assert np.linalg.norm(a.pos_ned - b.pos_ned) < 1e-3
    assert np.linalg.norm(a.vel_ned - b.vel_ned) < 1e-2
    # it ends on wp 2
    end = ms.source.reference(float(ts[-1])).pos_ned
    assert math.hypot(end[0] - 10.0, end[1] - 8.0) < 0.1


def test_a_rovers_mission_is_refused_with_the_reason_never_flown() -> None:
    """The service streams a multicopter's setpoints (attitude, rates, position joins): a rover
    (HEARTBEAT type 10) must not be sent them; its mission is refused with what to use."""
    items, home = wire_items(MISSIONS.parents[2] / "examples" / "missions" / "rover_square.plan")
    with pytest.raises(ValueError, match="drive a rover's mission with"):
        plan_program(items, home, (1, len(items)), ServiceConfig(), vehicle="rover")


def test_the_missions_reference_runs_on_the_flight_clock(
        program_and_key: tuple[object, tuple[int, int]]) -> None:
    """With a clock (the runner's FlightClock: flight time following the autopilot's, which a
    busy host slows), the stream hands its source flight time since the join, not the caller's
    time: on a PX4 SITL at half speed a reference on the caller's clock ran twice as fast as
    planned in the vehicle's own time."""
    prog, key = program_and_key
    p0 = (8.0, -1.0, -4.0)
    svc = ServeService(clock=lambda: lambda t: 100.0 + 0.5 * t)  # an autopilot at half speed
    svc.on_planned(key, prog, 0.0)  # type: ignore[arg-type]
    svc.update(obs(0.0, pos=p0))
    svc.update(obs(0.05, mode=FlightMode.OFFBOARD, pos=p0))
    ms = svc.stream
    assert isinstance(ms, MissionStream) and ms.t0_s == 0.05
    seen: list[float] = []
    spy = dataclasses.replace(ms, source=lambda t, _tel: seen.append(t))  # type: ignore[arg-type, func-returns-value]
    spy.setpoint(4.05, None)
    assert seen == [pytest.approx(2.0)]  # 4 s of ours: 2 s of the vehicle's
    dataclasses.replace(spy, clock=None).setpoint(4.05, None)
    assert seen[-1] == pytest.approx(4.0)  # without a clock: the caller's own
