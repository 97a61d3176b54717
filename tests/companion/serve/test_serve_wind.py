"""serve learns the wind while PX4 holds the vehicle still, and refuses (and says so before the
switch) a mission the vehicle cannot fly in it. Oracles: the attitude that balances a known
horizontal force (written out by hand), the mission's own check."""

from __future__ import annotations

import math

import pytest
from scipy.spatial.transform import Rotation

from companion.control.estimation import HoverWindEstimator
from companion.mavlink import FlightMode
from companion.mavlink.telemetry import LocalPosition
from companion.serve.service import (
    WIND_MIN_HELD_S,
    Announce,
    MissionStream,
    Observation,
    ServeService,
)
from tests.companion.serve.test_service import program_and_key  # noqa: F401 (the fixture)

G = 9.80665


def _holding_against(force_n: float, force_e: float) -> tuple[float, float, float, float]:
    """The attitude (w, x, y, z) at rest under a horizontal force per mass (force_n, force_e)
    [m/s^2]: 0 = g e3 - (T/m) z_b + f, so the body z axis z_b lies along (f_n, f_e, g)."""
    zb = [force_n, force_e, G]
    n = math.sqrt(sum(c * c for c in zb))
    zb = [c / n for c in zb]
    rot, _ = Rotation.align_vectors([zb], [[0.0, 0.0, 1.0]])
    x, y, z, w = rot.as_quat()
    return (float(w), float(x), float(y), float(z))


@pytest.mark.parametrize(("fn", "fe"), [(3.0, -2.0), (-6.0, 0.5), (0.0, 0.0)])
def test_the_hover_attitude_gives_the_force(fn: float, fe: float) -> None:
    est = HoverWindEstimator(tau_s=1.0)
    q = _holding_against(fn, fe)
    for k in range(200):
        est.update(k * 0.05, (0.05, -0.05, 0.0), q, True)
    assert est.acc_ne is not None
    assert est.acc_ne[0] == pytest.approx(fn, abs=1e-6)
    assert est.acc_ne[1] == pytest.approx(fe, abs=1e-6)
    assert est.held_s == pytest.approx(199 * 0.05)


def test_moving_or_on_the_ground_teaches_it_nothing() -> None:
    est = HoverWindEstimator()
    q = _holding_against(5.0, 0.0)
    for k in range(100):
        est.update(k * 0.05, (2.0, 0.0, 0.0), q, True)  # flying somewhere: not still
        est.update(k * 0.05 + 0.01, (0.0, 0.0, 0.0), q, False)  # on the ground
    assert est.acc_ne is None


def _obs(t: float, mode: FlightMode, q: tuple[float, float, float, float]) -> Observation:
    return Observation(now_s=t, link_ok=True, armed=True, mode=mode, landed_state=2,
                       position=LocalPosition(t, t, (0.0, 0.0, -5.0), (0.0, 0.0, 0.0),
                                              "LOCAL_POSITION_NED"),
                       yaw=0.0, attitude_q=q)


def _hold_then_offboard(prog_key: tuple[object, tuple[int, int]], force: tuple[float, float]
                        ) -> tuple[ServeService, list[object], list[object]]:
    prog, key = prog_key
    svc = ServeService()
    svc.on_planned(key, prog, 0.0)  # type: ignore[arg-type]
    q = _holding_against(*force)
    before: list[object] = []
    t = 0.0
    while t < WIND_MIN_HELD_S + 3.0:  # PX4 holds the vehicle in the wind
        before += svc.update(_obs(t, FlightMode.HOLD, q))
        t += 0.05
    after = list(svc.update(_obs(t, FlightMode.OFFBOARD, q)))
    return svc, before, after


def test_a_wind_it_cannot_hold_against_is_announced_and_the_mission_not_flown(
        program_and_key: tuple[object, tuple[int, int]]) -> None:  # noqa: F811
    """A force of g tan(50 deg): holding alone needs 50 deg of tilt (limit 45)."""
    svc, before, after = _hold_then_offboard(program_and_key,
                                             (G * math.tan(math.radians(50.0)), 0.0))
    said = [a.text for a in before if isinstance(a, Announce)]
    assert any("not flyable" in s and "holding still" in s for s in said), said
    assert svc.state == "offboard_hold"
    assert not isinstance(svc.stream, MissionStream)
    assert any(isinstance(a, Announce) and "not flyable" in a.text for a in after)


def test_a_light_wind_flies_the_mission(
        program_and_key: tuple[object, tuple[int, int]]) -> None:  # noqa: F811
    svc, before, _ = _hold_then_offboard(program_and_key, (1.0, 0.5))
    assert not any(isinstance(a, Announce) and "wind" in a.text for a in before)
    assert svc.state == "mission" and isinstance(svc.stream, MissionStream)
    assert svc.wind_check is not None and svc.wind_check.flyable
