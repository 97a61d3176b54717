"""The handover at the start of attitude/rates setpoints (`TrackingSource`, HANDOVER_S).

PX4 v1.16 switches its controllers to a new offboard setpoint kind only at the commander's next
2 Hz control-mode publication, so for up to 0.5 s after the first attitude setpoint its own
position control still flies (real PX4 SITL, serve: our thrust went from 0.65 to 1.0 while PX4
applied its own 0.44-0.48, then PX4 applied the 1.0). Oracles: the reference stands at its start
for HANDOVER_S and its clock then runs from 0 (the plan's own times, shifted by the wait);
the controller learns nothing from a vehicle that may not be flying its commands; the commands
during the wait hold the vehicle (hover, level, for a vehicle at rest); then the reference starts
where the vehicle is."""

from __future__ import annotations

import math
from itertools import pairwise

import numpy as np
import pytest

from companion.control import Reference
from companion.flatness import MultirotorParams
from companion.flight.tracking import HANDOVER_S, RAMP_S, TrackingSource, tilt_of_q
from companion.mavlink.setpoints import AttitudeSetpoint, RatesSetpoint
from companion.mavlink.telemetry import Attitude, ExtendedState, LocalPosition, TelemetrySnapshot

PARAMS = MultirotorParams(mass=1.0, inertia=(0.025, 0.025, 0.030), hover_thrust=0.5, drag=1.0)
START = np.array([3.0, -2.0, -5.0])
T0 = 50.0  # local clock at flight time 0 [s]


def plan(t: float) -> Reference:
    """From rest at START, 1 m/s^2 north."""
    return Reference(START + np.array([0.5 * t * t, 0.0, 0.0]), np.array([t, 0.0, 0.0]),
                     np.array([1.0, 0.0, 0.0]))


def snap(now: float, pos: np.ndarray, vel: tuple[float, float, float]) -> TelemetrySnapshot:
    return TelemetrySnapshot(
        position=LocalPosition(now, now, tuple(float(c) for c in pos), vel,  # type: ignore[arg-type]
                               "LOCAL_POSITION_NED"),
        attitude=Attitude(now, (1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0)),
        extended=ExtendedState(now, 2, 0), now_s=now)


@pytest.mark.parametrize("mode", ["attitude", "rates"])
def test_the_reference_waits_at_its_start_then_runs_its_own_times(mode: str) -> None:
    # (the vehicle here never moves: no slowing down for it, the reference runs on its time)
    src = TrackingSource(plan, mode, PARAMS, time_scaling=False)  # type: ignore[arg-type]
    assert src(0.0, snap(T0, START, (0.0, 0.0, 0.0))) is not None  # priming
    ts = np.arange(1, 301) * 0.01
    held, after = [], []
    for t in ts:
        sp = src(float(t), snap(T0 + t, START, (0.0, 0.0, 0.0)))
        tr = src.reference_time_s
        assert tr is not None
        (held if t < HANDOVER_S - 1e-9 else after).append((float(t), tr, sp))
    # waiting: the reference time stands at 0 and the vehicle, at rest at the start, is held
    # there (thrust at hover, level)
    assert all(tr == 0.0 for _, tr, _ in held)
    for _, _, sp in held:
        assert isinstance(sp, AttitudeSetpoint if mode == "attitude" else RatesSetpoint)
        assert sp.thrust_norm == pytest.approx(0.5, abs=0.02)
        if isinstance(sp, AttitudeSetpoint):
            assert tilt_of_q(sp.q_wxyz) < math.radians(1.0)
    # then the reference's clock ramps up (never backwards, never faster than flight time)
    # and runs on with flight time, behind by the wait plus half the ramp (one setpoint period
    # of rounding)
    trs = np.array([tr for _, tr, _ in after])
    assert np.all(np.diff(trs) >= 0.0) and np.all(np.diff(trs) <= 0.01 + 1e-9)
    shifts = [t - tr for t, tr, _ in after if t >= after[0][0] + RAMP_S]
    assert max(shifts) - min(shifts) < 1e-9
    assert abs(shifts[0] - (HANDOVER_S + 0.5 * RAMP_S)) <= 0.011
    # and the command moves on with it: the vehicle still at rest at the start now lags a
    # reference accelerating north, so it is tilted north
    last = after[-1][2]
    assert isinstance(last, (AttitudeSetpoint, RatesSetpoint))
    if isinstance(last, AttitudeSetpoint):
        w, x, y, z = last.q_wxyz
        body_z_north = 2.0 * (x * z + w * y)  # R[0, 2]: the body z axis's north component
        assert body_z_north < -math.sin(math.radians(5.0))  # thrust (-body z) points north


def test_it_learns_nothing_from_a_vehicle_that_may_not_fly_its_commands() -> None:
    """While PX4 may still fly its own control the vehicle sinks 0.3 m and does not follow the
    commands: the integrator, the disturbance estimate and the hover-thrust estimate learn
    nothing from that, and the thrust holds the vehicle (damps its sink) without winding up.
    Afterwards the same vehicle teaches them (the learning is back on)."""
    src = TrackingSource(plan, "attitude", PARAMS)
    ctl = src.controller
    assert ctl is not None
    src(0.0, snap(T0, START, (0.0, 0.0, 0.0)))
    h0 = ctl.hover_thrust
    sunk = START + np.array([0.0, 0.0, 0.3])
    during = []
    t = 0.0
    while t < HANDOVER_S - 0.02:
        t += 0.01
        sp = src(t, snap(T0 + t, sunk, (0.0, 0.0, 0.4)))
        assert isinstance(sp, AttitudeSetpoint)
        during.append(sp.thrust_norm)
    assert ctl.hover_thrust == h0 and ctl.disturbance.acc_ne == (0.0, 0.0)
    # damping the sink at kd_z, no wind-up (a learning law went from 0.65 to 1.0 on real PX4;
    # what moves here is its latency compensation settling)
    assert max(during) - min(during) < 0.03 and 0.5 < during[0] < 0.8
    for _ in range(150):  # after the handover the sinking vehicle does teach the estimators
        t += 0.01
        src(t, snap(T0 + t, sunk + np.array([0.0, 0.0, 0.4 * (t - HANDOVER_S)]),
                    (0.0, 0.0, 0.4)))
    assert abs(ctl.hover_thrust - h0) > 1e-3


def test_the_flight_begins_where_the_vehicle_stopped_and_joins_the_plan_smoothly() -> None:
    """The vehicle ends the handover 0.3 m east of the reference's start (its estimate moved,
    or PX4 let it drift): the reference starts there, joins the plan within BLEND_M of travel,
    and its velocity is its position's derivative all along (finite differences)."""
    from companion.flight.tracking import BLEND_M

    # (the vehicle here never moves: no slowing down for it, the reference runs on its time)
    src = TrackingSource(plan, "attitude", PARAMS, time_scaling=False)
    here = START + np.array([0.0, 0.3, 0.0])
    src(0.0, snap(T0, START, (0.0, 0.0, 0.0)))
    t, refs = 0.0, []
    while t < HANDOVER_S + RAMP_S + 2.5:
        t += 0.01
        sp = src(t, snap(T0 + t, here, (0.0, 0.0, 0.0)))
        tr = src.reference_time_s
        assert tr is not None and isinstance(sp, AttitudeSetpoint)
        if tr > 0.0:
            refs.append((t, tr, src.last_reference, sp))
    _t0, _tr0, r0, sp0 = refs[0]
    assert np.linalg.norm(r0.pos_ned - here) < 0.01  # from where the vehicle is
    # no pull back west toward the start (0.3 m at kp_xy 20 would tilt it 31 deg): only the
    # blend's own acceleration, under 3 deg
    w, x, y, z = sp0.q_wxyz
    assert abs(2.0 * (y * z - w * x)) < math.sin(math.radians(3.0))  # body z's east component
    # the velocity flown is the derivative of the position flown over flight time
    ts = np.array([r[0] for r in refs])
    pos = np.array([r[2].pos_ned for r in refs])
    vel = np.array([r[2].vel_ned for r in refs])
    np.testing.assert_allclose(np.gradient(pos, ts, axis=0)[1:-1], vel[1:-1], atol=0.01)
    done = [r for r in refs if np.linalg.norm(plan(r[1]).pos_ned - START) >= BLEND_M]
    assert done and all(np.linalg.norm(r.pos_ned - plan(tr).pos_ned) < 1e-9
                        for _t, tr, r, _sp in done)


def test_the_setpoint_figures_start_at_liftoff_not_at_the_spin_up() -> None:
    """A vehicle standing 0.25 m above the plan's start (EKF2's height rose since the plan was
    made; real PX4 SIH: 0.1-0.25 m) that PX4 already calls in the air at the spin-up: the
    handover's end pulls its height reference back down, a thrust step, counted nowhere while
    it stands (real PX4: 0.04-0.12 in the report of a flight that was fine); once it is
    LIFTOFF_M above where it stood, steps count."""
    from companion.flight.tracking import LIFTOFF_M

    def takeoff(t: float) -> Reference:  # from rest at START, up at 0.2 m/s^2 (NED: -z)
        return Reference(START + np.array([0.0, 0.0, -0.1 * t * t]), np.array([0.0, 0.0, -0.2 * t]),
                         np.array([0.0, 0.0, -0.2]))

    def at(now: float, pos: np.ndarray, landed: int) -> TelemetrySnapshot:
        s = snap(now, pos, (0.0, 0.0, 0.0))
        return TelemetrySnapshot(position=s.position, attitude=s.attitude,
                                 extended=ExtendedState(now, landed, 0), now_s=now)

    src = TrackingSource(takeoff, "attitude", PARAMS, time_scaling=False)
    stand = START + np.array([0.0, 0.0, -0.25])
    src(0.0, at(T0, stand, 1))  # priming, on the ground
    thrusts, t = [], 0.0
    while t < HANDOVER_S + 0.2:
        t += 0.01
        sp = src(t, at(T0 + t, stand, 2))  # PX4: in the air at the spin-up
        assert isinstance(sp, AttitudeSetpoint)
        thrusts.append(sp.thrust_norm)
    step = max(abs(b - a) for a, b in pairwise(thrusts))
    assert step > 0.05  # the handover's end steps the thrust of the standing vehicle
    assert src.quality.max_thrust_step == 0.0  # not counted: not lifted
    # lifted: LIFTOFF_M above where it stood, the same step is counted
    up = stand + np.array([0.0, 0.0, -LIFTOFF_M - 0.01])
    src(t + 0.01, at(T0 + t + 0.01, up, 2))
    src(t + 0.02, at(T0 + t + 0.02, up + np.array([0.0, 0.3, 0.0]), 2))
    assert src.quality.max_thrust_step > 0.0
