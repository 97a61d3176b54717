"""`Touchdown`: the reference past the plan descends smoothly, ground contact is declared only on
PX4's "hit ground" evidence, and then the thrust ramps to zero with the attitude level.

The synthetic vehicle here follows flight time, so the sources run without the handover at
the start (`handover_s=0`; the handover has its own tests in test_handover.py)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from companion.control import Reference
from companion.flatness import MultirotorParams
from companion.flight.tracking import Touchdown, TrackingSource, tilt_of_q
from companion.mavlink.setpoints import AttitudeSetpoint, RatesSetpoint
from companion.mavlink.telemetry import Attitude, ExtendedState, LocalPosition, TelemetrySnapshot

PARAMS = MultirotorParams(mass=1.0, inertia=(0.025, 0.025, 0.030), hover_thrust=0.5, drag=1.0)
END_S = 2.0  # the plan ends here, 0.5 m above the ground (NED z = 0 is the ground)
YAW = 0.7


def plan(t: float) -> Reference:
    """At rest 0.5 m up until END_S (a plan that ended)."""
    return Reference(np.array([1.0, 2.0, -0.5]), yaw=YAW)


def snap(now: float, z: float, vz: float, landed_state: int = 2) -> TelemetrySnapshot:
    q = (math.cos(YAW / 2), 0.0, 0.0, math.sin(YAW / 2))
    return TelemetrySnapshot(
        position=LocalPosition(now, now, (1.0, 2.0, z), (0.0, 0.0, vz), "LOCAL_POSITION_NED"),
        attitude=Attitude(now, q, (0.0, 0.0, 0.0)),
        extended=ExtendedState(now, landed_state, 0),
        now_s=now)


@pytest.mark.parametrize("v0", [0.0, 0.669, 1.2])
def test_descent_offset_is_continuous_and_its_own_derivative(v0: float) -> None:
    td = Touchdown(0.0, descent_m_s=0.7, v0_m_s=v0, accel_m_s2=1.0)
    ts = np.linspace(0.0, 3.0, 3001)
    z = np.array([td.offset(t)[0] for t in ts])
    v = np.array([td.offset(t)[1] for t in ts])
    a = np.array([td.offset(t)[2] for t in ts])
    dt = ts[1] - ts[0]
    # finite differences of the position give the speed, of the speed the acceleration
    assert np.allclose(np.gradient(z, dt)[1:-1], v[1:-1], atol=2e-3)
    assert np.allclose(np.gradient(v, dt)[1:-1], a[1:-1], atol=2e-3)
    # the acceleration is continuous (no thrust step where the touchdown takes over or reaches
    # its speed: steps of up to 1 m/s^2 before) and never above accel_m_s2
    assert np.max(np.abs(np.diff(a))) < 0.01
    assert np.max(np.abs(a)) <= 1.0 + 1e-12
    assert np.max(np.abs(np.diff(a))) / dt <= 4.0 + 1e-6  # jerk within jerk_m_s3
    assert v[-1] == pytest.approx(0.7) and a[-1] == 0.0 and z[0] == 0.0
    assert v[0] == v0  # takes over the plan's descent speed without a jump
    with pytest.raises(ValueError):
        Touchdown(0.0, descent_m_s=0.0)
    with pytest.raises(ValueError):
        Touchdown(0.0, v0_m_s=-0.1)


def test_touchdown_takes_over_where_the_plan_stops_cruising_down() -> None:
    """`Schedule.final_descent_cruise`: at the returned time the plan descends at >= 95 % of
    MPC_LAND_SPEED, straight down, at a steady speed (no slow-down begun: the touchdown's
    reference takes over without an acceleration step), and from there on to its end it only
    slows (the stop 0.5 m above the ground the touchdown replaces)."""
    from pathlib import Path

    from companion.mission import load_mission, mission_to_flight_plan
    from companion.planning.config import VehicleFile
    from companion.planning.schedule import build_schedule

    vf = VehicleFile()
    root = Path(__file__).resolve().parents[3]
    for name in ("tests/data/missions/square_8ms.plan", "tests/data/missions/px4_short.plan"):
        fp = mission_to_flight_plan(load_mission(root / name))
        sched = build_schedule(fp, vf.params, vf.limits, handover_height_m=0.5)
        t, v = sched.final_descent_cruise(0.7)
        assert sched.duration_s - 2.0 < t < sched.duration_s
        r = sched.reference(t)
        assert r.vel_ned[2] == pytest.approx(v) and v >= 0.95 * 0.7
        assert math.hypot(r.vel_ned[0], r.vel_ned[1]) < 0.1
        assert abs(r.acc_ned[2]) <= 0.05
        after = [sched.reference(x).vel_ned[2] for x in np.linspace(t, sched.duration_s, 80)]
        assert np.all(np.diff(after) <= 1e-9)  # only slows
        assert after[-1] == pytest.approx(0.0, abs=1e-6)


@pytest.mark.parametrize("mode", ["attitude", "rates"])
def test_contact_only_when_still_with_the_reference_below_then_thrust_to_zero(mode: str) -> None:
    td = Touchdown(END_S, descent_m_s=0.7)
    src = TrackingSource(plan, mode, PARAMS, touchdown=td, handover_s=0.0)  # type: ignore[arg-type]
    t0 = 100.0  # local clock at reference time 0
    out = []
    for k in range(1, 601):  # 6 s at 100 Hz
        t = 0.01 * k
        now = t0 + t
        # the vehicle follows the descent until it meets the ground 0.5 m down, then sits
        depth = td.offset(t - END_S)[0] if t > END_S else 0.0
        z = min(-0.5 + depth, 0.0)
        vz = td.offset(t - END_S)[1] if t > END_S and z < 0.0 else 0.0
        out.append((t, src(t, snap(now, z, vz)), src.contact_s))
    touchdown_t = END_S + next(t for t in np.linspace(0, 4, 40001)
                               if td.offset(t)[0] >= 0.5)
    contact = next(t for t, _, c in out if c is not None)
    # ground contact is declared contact_s after the reference got gap_m below the still
    # vehicle (never while it follows the descent, never during the ramp-in)
    assert touchdown_t + td.contact_s < contact < touchdown_t + td.contact_s + 0.3 + 0.05
    before = [sp for t, sp, c in out if t < touchdown_t]
    assert all(sp.thrust_norm > 0.3 for sp in before)  # flying the descent
    after = [(t, sp) for t, sp, c in out if c is not None]
    thrusts = [sp.thrust_norm for _, sp in after]
    assert all(b <= a + 1e-12 for a, b in itertools.pairwise(thrusts))
    assert all(sp.thrust_norm == 0.0 for t, sp in after if t > contact + td.ramp_s + 0.011)
    for _, sp in after:
        if mode == "attitude":
            assert isinstance(sp, AttitudeSetpoint)
            w, x, y, z = sp.q_wxyz
            assert x == 0.0 and y == 0.0  # level
            assert 2.0 * math.atan2(z, w) == pytest.approx(YAW)  # at the current heading
        else:
            assert isinstance(sp, RatesSetpoint) and sp.omega_frd == (0.0, 0.0, 0.0)


def test_no_contact_while_the_vehicle_follows_the_descent() -> None:
    td = Touchdown(END_S, descent_m_s=0.7)
    src = TrackingSource(plan, "attitude", PARAMS, touchdown=td, handover_s=0.0)
    for k in range(1, 1001):
        t = 0.01 * k
        z = -0.5 + (td.offset(t - END_S)[0] if t > END_S else 0.0)  # on the reference
        vz = td.offset(t - END_S)[1] if t > END_S else 0.0
        sp = src(t, snap(t, z, vz))
        assert src.contact_s is None and sp.thrust_norm > 0.3
    assert src.touching_down


def snap_off(now: float, z: float, vz: float, off_ne: tuple[float, float],
             v_ne: tuple[float, float]) -> TelemetrySnapshot:
    q = (math.cos(YAW / 2), 0.0, 0.0, math.sin(YAW / 2))
    return TelemetrySnapshot(
        position=LocalPosition(now, now, (1.0 + off_ne[0], 2.0 + off_ne[1], z),
                               (v_ne[0], v_ne[1], vz), "LOCAL_POSITION_NED"),
        attitude=Attitude(now, q, (0.0, 0.0, 0.0)),
        extended=ExtendedState(now, 2, 0),
        now_s=now)


@pytest.mark.parametrize("mode", ["attitude", "rates"])
def test_touchdown_keeps_the_landing_tilt_limit_when_the_feet_touch_off_target(mode: str) -> None:
    """The vehicle descends 0.3 m beside the reference drifting at 0.3 m/s and stops on the
    ground: the horizontal feedback then meets a thrust the vertical loop is lowering, and the
    commanded tilt (of the attitude sent, or in rates mode of the attitude the rates steer to)
    must stay within the touchdown's 12 deg (PX4's MPC_TILTMAX_LND), not the 45 deg of the air
    (a real-PX4 flight was commanded 44 deg there and tipped over). Before the touchdown the
    same offset is corrected with more tilt than that (the limit is the touchdown's only)."""
    td = Touchdown(END_S, descent_m_s=0.7)
    src = TrackingSource(plan, mode, PARAMS, touchdown=td, handover_s=0.0)  # type: ignore[arg-type]
    before, during = [], []
    for k in range(1, 501):
        t = 0.01 * k
        depth = td.offset(t - END_S)[0] if t > END_S else 0.0
        z = min(-0.5 + depth, 0.0)
        vz = td.offset(t - END_S)[1] if t > END_S and z < 0.0 else 0.0
        sp = src(t, snap_off(t, z, vz, (0.3, -0.3), (0.3, -0.3)))
        if isinstance(sp, AttitudeSetpoint):
            q = sp.q_wxyz
        else:
            assert src.controller is not None
            q = tuple(float(c) for c in src.controller.last_q_des)  # type: ignore[assignment]
        (during if t > END_S else before).append(math.degrees(tilt_of_q(q)))  # type: ignore[arg-type]
    assert max(before) > 15.0  # the air limit allows it, and the offset asks for it
    assert max(during) <= 12.0 + 1e-6
