"""Position-mode setpoint source against the trajectory's own evaluate (independent code path:
numpy vectorised Horner vs the source's pure-Python fast evaluator)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.aio import TrajectoryPositionSource, hold_setpoint
from companion.mavlink import Attitude, LocalPosition, TelemetrySnapshot
from companion.trajectory import PiecewiseBezier, hermite

SNAP = TelemetrySnapshot()


def traj_with_yaw() -> PiecewiseBezier:
    rng = np.random.default_rng(3)
    segs, yaws = [], []
    start = rng.normal(size=(3, 3))
    ystart = rng.normal(size=(3, 1))
    for h in (1.0, 2.5, 0.7):
        end = rng.normal(size=(3, 3))
        yend = rng.normal(size=(3, 1))
        segs.append(hermite(start, end, h))
        yaws.append(hermite(ystart, yend, h))
        start, ystart = end, yend
    return PiecewiseBezier(segs, yaw=PiecewiseBezier(yaws))


@pytest.mark.parametrize("t", np.linspace(-0.5, 4.7, 21))
def test_matches_trajectory_evaluate(t: float) -> None:
    traj = traj_with_yaw()
    src = TrajectoryPositionSource(traj)
    assert src._fast == traj.scalar_evaluator(2).values  # the fast path is in use
    sp = src(float(t), SNAP)
    tc = min(max(t, 0.0), traj.duration)
    assert np.allclose(sp.pos_ned, traj.evaluate(tc, 0), atol=1e-9)
    assert traj.yaw is not None
    y = float(traj.yaw.evaluate(tc, 0)[0])
    assert math.isclose(math.cos(sp.yaw), math.cos(y), abs_tol=1e-9)  # type: ignore[arg-type]
    assert math.isclose(math.sin(sp.yaw), math.sin(y), abs_tol=1e-9)  # type: ignore[arg-type]
    if t < traj.duration:
        assert np.allclose(sp.vel_ned, traj.evaluate(tc, 1), atol=1e-9)
        assert np.allclose(sp.acc_ned, traj.evaluate(tc, 2), atol=1e-9)
        assert math.isclose(sp.yaw_rate, float(traj.yaw.evaluate(tc, 1)[0]), abs_tol=1e-9)  # type: ignore[arg-type]
    else:  # after the end: hold the end point at rest
        assert sp.vel_ned == (0.0, 0.0, 0.0) and sp.acc_ned == (0.0, 0.0, 0.0)


def test_feedforward_levels_and_fixed_yaw() -> None:
    traj = traj_with_yaw().with_yaw(None)
    sp = TrajectoryPositionSource(traj, feedforward="none", yaw=0.5)(1.0, SNAP)
    assert sp.vel_ned is None and sp.acc_ned is None and sp.yaw == 0.5 and sp.yaw_rate is None
    sp = TrajectoryPositionSource(traj, feedforward="vel")(1.0, SNAP)
    assert sp.vel_ned is not None and sp.acc_ned is None and sp.yaw is None


def test_hold_setpoint_uses_position_and_heading() -> None:
    yaw = 0.8
    snap = TelemetrySnapshot(
        position=LocalPosition(0.0, 0.0, (1.0, 2.0, -3.0), (0.5, 0.0, 0.0), "LOCAL_POSITION_NED"),
        attitude=Attitude(0.0, (math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)), (0, 0, 0)))
    sp = hold_setpoint(snap)
    assert sp is not None and sp.pos_ned == (1.0, 2.0, -3.0) and sp.vel_ned == (0.0, 0.0, 0.0)
    assert sp.yaw == pytest.approx(yaw)
    assert hold_setpoint(TelemetrySnapshot()) is None


class _DuckTrajectory:
    """Only ``duration`` and ``evaluate`` (no scalar evaluator): the source's generic path."""

    def __init__(self, traj: PiecewiseBezier) -> None:
        self._traj = traj
        self.yaw = None if traj.yaw is None else _DuckTrajectory(traj.yaw)

    @property
    def duration(self) -> float:
        return self._traj.duration

    def evaluate(self, t: float, order: int = 0) -> np.ndarray:
        assert 0.0 <= t <= self._traj.duration  # the source clamps before asking
        return self._traj.evaluate(t, order)


@pytest.mark.parametrize("feedforward", ["acc", "vel", "none"])
def test_duck_typed_trajectory_gives_the_same_setpoints(feedforward: str) -> None:
    traj = traj_with_yaw()
    fast = TrajectoryPositionSource(traj, feedforward=feedforward)
    duck = TrajectoryPositionSource(_DuckTrajectory(traj), feedforward=feedforward)
    for t in (-1.0, 0.0, 0.4, 1.0, 3.3, traj.duration, traj.duration + 2.0):
        a, b = fast(t, SNAP), duck(t, SNAP)
        for x, y in ((a.pos_ned, b.pos_ned), (a.vel_ned, b.vel_ned), (a.acc_ned, b.acc_ned),
                     (a.yaw, b.yaw), (a.yaw_rate, b.yaw_rate)):
            assert (x is None) == (y is None)
            if x is not None:
                assert np.allclose(x, y, rtol=1e-12, atol=1e-12)  # type: ignore[arg-type]
    for src in (fast, duck):
        with pytest.raises(ValueError, match="NaN"):
            src(math.nan, SNAP)
