"""`ProgressGovernor` and the rover's `TrackingSource`: the reference waits for a rover that
cannot drive the planned speed, instead of running away from it (on real PX4's SIH rover the
reference of the bundled square ended 12-17 m ahead of the rover, which was then switched to
Hold short of the last waypoint, reported "ok")."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.flight.sequence import (
    EndPolicy,
    FlightSequence,
    SendCommand,
    SequenceConfig,
    VehicleView,
)
from companion.flight.tracking import ProgressGovernor, TrackingSource
from companion.mavlink.px4_mode import FlightMode
from companion.mavlink.setpoints import PositionSetpoint
from companion.mavlink.telemetry import Attitude, LocalPosition, TelemetrySnapshot
from companion.planning.schedule import trajectory_reference
from companion.trajectory import RoverLimits, plan


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.floats(0.0, 0.2), st.floats(-5.0, 10.0)), min_size=1,
                max_size=60))
def test_reference_time_never_runs_backwards_nor_faster_than_flight_time(
        steps: list[tuple[float, float]]) -> None:
    gov = ProgressGovernor(free_m=1.0, stop_m=3.0)
    t, last = 0.0, gov.update(0.0, 0.0)
    for dt, lag in steps:
        t += dt
        ref = gov.update(t, lag)
        assert last <= ref <= last + dt + 1e-12
        # the rate is the lag's: full up to free_m, none from stop_m on, linear between
        want = 1.0 if lag <= 1.0 else 0.0 if lag >= 3.0 else (3.0 - lag) / 2.0
        if dt > 0.0:
            assert ref - last == pytest.approx(want * dt, abs=1e-12)
        last = ref


def test_reset_takes_the_next_flight_time_as_the_reference_time() -> None:
    gov = ProgressGovernor()
    assert gov.update(1.0, 0.0) == 1.0  # the first flight time is taken as it is
    gov.update(3.0, 5.0)  # stopped
    assert gov.t_ref == 1.0
    gov.reset()
    assert gov.update(5.0, 0.0) == 5.0 and gov.update(5.5, 0.0) == pytest.approx(5.5)
    with pytest.raises(ValueError):
        ProgressGovernor(free_m=3.0, stop_m=1.0)


SQUARE = np.array([[0.0, 0.0], [30.0, 0.0], [30.0, 20.0], [5.0, 20.0]])


def drive(source: TrackingSource, top_speed: float, t_end: float
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A car-like rover of our own (course follows the commanded velocity's direction through
    a yaw-rate loop with a 1.2 rad/s limit, speed follows the command with a 0.3 s lag and
    saturates at `top_speed`) driven by `source` for `t_end` s at 50 Hz, starting at rest on
    the plan's start heading north. Returns (times, positions (N, 2), governed reference
    positions (N, 2))."""
    dt = 0.02
    x = y = psi = v = 0.0
    ts, pos, refs = [], [], []
    for k in range(int(t_end / dt)):
        t = k * dt
        q = (math.cos(psi / 2), 0.0, 0.0, math.sin(psi / 2))
        snap = TelemetrySnapshot(
            position=LocalPosition(t, t, (x, y, 0.0), (v * math.cos(psi), v * math.sin(psi), 0.0),
                                   "LOCAL_POSITION_NED"),
            attitude=Attitude(t, q, (0.0, 0.0, 0.0)), now_s=t)
        sp = source(t, snap)
        assert isinstance(sp, PositionSetpoint) and sp.vel_ned is not None
        vx, vy = sp.vel_ned[0], sp.vel_ned[1]
        v_cmd = min(math.hypot(vx, vy), top_speed)
        if v_cmd > 1e-3:
            err = math.remainder(math.atan2(vy, vx) - psi, 2.0 * math.pi)
            r = max(min(3.0 * err, 1.2), -1.2) * min(v / 0.5, 1.0)  # no turning in place
        else:
            r = 0.0
        v += (v_cmd - v) * dt / 0.3
        psi += r * dt
        x += v * math.cos(psi) * dt
        y += v * math.sin(psi) * dt
        ref = source.last_reference
        assert ref is not None
        ts.append(t)
        pos.append((x, y))
        refs.append((float(ref.pos_ned[0]), float(ref.pos_ned[1])))
    return np.array(ts), np.array(pos), np.array(refs)


def test_a_rover_slower_than_its_plan_is_waited_for_and_passes_every_waypoint() -> None:
    """The plan cruises at 2.7 m/s; the rover tops out at 1.6 m/s. On the flight clock the
    plan gets more than 10 m ahead of it (oracle: the plan sampled at flight time); the
    governed reference stays within the governor's stop lag plus the controller's own along-
    track slack, its time reaches the plan's end only when the rover is near that end, and
    the rover passes every corner within 0.5 m."""
    lim = RoverLimits(max_speed_m_s=2.7, max_yaw_rate_rad_s=math.radians(60.0),
                      max_lat_acc_m_s2=1.5)
    traj = plan(SQUARE, limits=lim, yaw="velocity")
    ref_fn = trajectory_reference(traj)
    source = TrackingSource(ref_fn, "rover")
    ts, pos, refs = drive(source, top_speed=1.6, t_end=traj.duration * 2.0)
    clock = np.array([ref_fn(float(t)).pos_ned[:2] for t in ts])
    assert float(np.max(np.linalg.norm(clock - pos, axis=1))) > 10.0  # it would run away
    gap = np.linalg.norm(refs - pos, axis=1)
    assert float(gap.max()) < 4.0, float(gap.max())
    assert source.reference_time_s is not None
    assert source.reference_time_s >= traj.duration  # it got there, later than planned
    for wp in SQUARE[1:]:
        assert float(np.min(np.linalg.norm(pos - wp, axis=1))) < 0.5, wp
    # the reference reached its end while the rover was within the stop lag of it
    end = SQUARE[-1]
    i_end = int(np.argmax(np.linalg.norm(refs - end, axis=1) < 1e-6))
    assert i_end > 0 and float(np.linalg.norm(pos[i_end] - end)) < 4.0


def test_a_rover_as_fast_as_its_plan_flies_the_clock() -> None:
    """A rover that keeps up: the governed reference time stays within 1.5 s of flight time
    (the governor does not slow a vehicle that follows)."""
    lim = RoverLimits(max_speed_m_s=1.5, max_yaw_rate_rad_s=math.radians(60.0),
                      max_lat_acc_m_s2=1.0)
    traj = plan(SQUARE, limits=lim, yaw="velocity")
    source = TrackingSource(trajectory_reference(traj), "rover")
    ts, _pos, _refs = drive(source, top_speed=3.0, t_end=traj.duration)
    assert source.reference_time_s is not None
    assert ts[-1] - source.reference_time_s < 1.5


def test_a_governed_flight_ends_at_the_reference_end_near_the_last_waypoint() -> None:
    """`FlightSequence` with the source's own (lagging) reference time: no handover while that
    time is short of the duration, even past the duration on the flight clock; then Hold once
    within settle_m of the end, or settle_s after the reference ended."""
    def seq() -> FlightSequence:
        s = FlightSequence(SequenceConfig(
            rate_hz=50.0, duration_s=10.0, pilot_start=True,
            end=EndPolicy(handover_mode=FlightMode.HOLD, land_and_disarm=False,
                          settle_s=20.0, settle_m=0.5, end_ned=(30.0, 0.0, 0.0))))
        s.update(0.0, VehicleView(armed=True, mode=FlightMode.OFFBOARD))
        return s

    far = dict(armed=True, mode=FlightMode.OFFBOARD, pos_ned=(20.0, 0.0, 0.0))
    s = seq()
    for k in range(1, 1500):  # 30 s of flight time, the reference only at 8 s
        acts = s.update(k * 0.02, VehicleView(**far, traj_time_s=8.0))  # type: ignore[arg-type]
        assert not any(isinstance(a, SendCommand) for a in acts)
    # the reference ends at 30 s; the rover arrives 5 s later
    acts = s.update(30.0, VehicleView(**far, traj_time_s=10.0))  # type: ignore[arg-type]
    assert not any(isinstance(a, SendCommand) for a in acts)
    acts = s.update(35.0, VehicleView(armed=True, mode=FlightMode.OFFBOARD,
                                      pos_ned=(29.7, 0.1, 0.0), traj_time_s=10.0))
    assert [a for a in acts if isinstance(a, SendCommand)] == [
        SendCommand.set_mode(FlightMode.HOLD)]
    # one that never arrives: Hold settle_s after its reference ended, saying how far it is
    s = seq()
    s.update(30.0, VehicleView(**far, traj_time_s=10.0))  # type: ignore[arg-type]
    acts = s.update(49.9, VehicleView(**far, traj_time_s=10.0))  # type: ignore[arg-type]
    assert not any(isinstance(a, SendCommand) for a in acts)
    acts = s.update(50.0, VehicleView(**far, traj_time_s=10.0))  # type: ignore[arg-type]
    assert any(isinstance(a, SendCommand) for a in acts) and "10.0 m from its end" in s.reason


def test_a_rover_that_overshot_its_end_is_done_once_its_source_says_arrived() -> None:
    """A car that ran 0.8 m past the end cannot back up into the acceptance radius: once the
    reference is at its end and the source says the rover arrived (reached or passed it, and
    slow), the flight hands over at once instead of waiting out settle_s."""
    s = FlightSequence(SequenceConfig(
        rate_hz=50.0, duration_s=10.0, pilot_start=True,
        end=EndPolicy(handover_mode=FlightMode.HOLD, land_and_disarm=False,
                      settle_s=20.0, settle_m=0.5, end_ned=(30.0, 0.0, 0.0))))
    s.update(0.0, VehicleView(armed=True, mode=FlightMode.OFFBOARD))
    past = dict(armed=True, mode=FlightMode.OFFBOARD, pos_ned=(30.8, 0.0, 0.0))
    # arrived while the reference still runs: nothing yet (a stop mid-mission)
    acts = s.update(5.0, VehicleView(**past, traj_time_s=5.0, arrived=True))  # type: ignore[arg-type]
    assert not any(isinstance(a, SendCommand) for a in acts)
    acts = s.update(12.0, VehicleView(**past, traj_time_s=10.0))  # type: ignore[arg-type]
    assert not any(isinstance(a, SendCommand) for a in acts)
    acts = s.update(12.5, VehicleView(**past, traj_time_s=10.0, arrived=True))  # type: ignore[arg-type]
    assert [a for a in acts if isinstance(a, SendCommand)] == [
        SendCommand.set_mode(FlightMode.HOLD)]


def test_a_rover_that_makes_no_progress_is_switched_to_hold() -> None:
    """A stuck rover: the governor stops the reference (its lag at the stop distance) and
    counts how long it has stood still; the flight sequence hands over to Hold after
    stall_s, saying why, instead of streaming forever."""
    gov = ProgressGovernor()
    gov.update(0.0, 0.0)
    for k in range(1, 101):
        gov.update(k * 0.1, 3.5)  # 3.5 m behind: stopped
    assert gov.stalled_s == pytest.approx(10.0)
    gov.update(10.1, 0.5)  # it moves again
    assert gov.stalled_s == 0.0
    s = FlightSequence(SequenceConfig(
        rate_hz=50.0, duration_s=30.0, pilot_start=True,
        end=EndPolicy(handover_mode=FlightMode.HOLD, land_and_disarm=False, stall_s=20.0)))
    s.update(0.0, VehicleView(armed=True, mode=FlightMode.OFFBOARD))
    view = dict(armed=True, mode=FlightMode.OFFBOARD, traj_time_s=4.0)
    acts = s.update(25.0, VehicleView(**view, stalled_s=19.9))  # type: ignore[arg-type]
    assert not any(isinstance(a, SendCommand) for a in acts)
    acts = s.update(25.1, VehicleView(**view, stalled_s=20.0))  # type: ignore[arg-type]
    assert [a for a in acts if isinstance(a, SendCommand)] == [
        SendCommand.set_mode(FlightMode.HOLD)]
    assert "no progress" in s.reason
