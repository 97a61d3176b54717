"""serve's runner gives the service its flight clock (companion.serve.runner._Session): flight
time follows the autopilot's clock from the position samples' time_boot, as `fly`'s does; the
onboard service, whose module flies on the autopilot's own clock, gets none."""

from __future__ import annotations

import itertools
from types import SimpleNamespace

import pytest

from companion.mavlink.telemetry import LocalPosition
from companion.serve.onboard import OnboardServeService
from companion.serve.runner import _Session
from companion.serve.service import ServeService


def _session(service: ServeService) -> tuple[_Session, SimpleNamespace]:
    v = SimpleNamespace(telemetry=SimpleNamespace(position=None))
    return _Session(v, service, None, None, None), v  # type: ignore[arg-type]


def test_flight_time_follows_an_autopilot_at_half_speed() -> None:
    service = ServeService()
    session, v = _session(service)
    assert service.clock == session.flight_clock
    flight_time = session.flight_clock()
    t_local = 50.0
    flight = [flight_time(t_local)]
    for k in range(1, 401):  # 20 s of ours, samples every 50 ms, the autopilot at half speed
        t_local = 50.0 + 0.05 * k
        boot = 10.0 + 0.025 * k
        v.telemetry.position = LocalPosition(t_local - 0.004, boot, (0.0, 0.0, -5.0),
                                             (0.0, 0.0, 0.0), "LOCAL_POSITION_NED")
        flight.append(flight_time(t_local))
    assert all(b >= a for a, b in itertools.pairwise(flight))
    # the last 10 s of ours: 5 s of flight time (the clock settles within a second)
    assert flight[-1] - flight[200] == pytest.approx(5.0, abs=0.05)


def test_the_onboard_service_has_no_flight_clock() -> None:
    service = OnboardServeService()
    _session(service)
    assert service.clock is None
