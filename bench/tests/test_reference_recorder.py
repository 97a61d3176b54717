"""The benchmarks' setpoint-source wrapper (bench/api_harness.py `ReferenceRecorder`) hands the
flight what the wrapped source says of itself: `Vehicle._flight_view` reads `blind_s`,
`stalled_s`, `reference_time_s` and `arrived` off the source it flies, and a wrapper that hid
them silently turned off the law's blind safety net (BLIND_S) in every recorded flight."""

from __future__ import annotations

import sys
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))

from api_harness import ReferenceRecorder

from companion.aio.vehicle import Vehicle


class _Source:
    blind_s = 2.5
    stalled_s = 1.25
    reference_time_s = 7.0
    arrived = True

    def __call__(self, t_s: float, telemetry: Any) -> None:
        return None


def test_the_flight_sees_the_wrapped_sources_state() -> None:
    vehicle = SimpleNamespace(  # what `_flight_view` reads of a Vehicle
        link=SimpleNamespace(telemetry=SimpleNamespace(extended=None, position=None)),
        _link_lost_at=None, link_ok=True, is_armed=True, mode=None)
    view = Vehicle._flight_view(vehicle, ReferenceRecorder(_Source()))  # type: ignore[arg-type]
    assert view.blind_s == 2.5
    assert view.stalled_s == 1.25
    assert view.traj_time_s == 7.0
    assert view.arrived is True


def test_an_unknown_attribute_is_still_an_error() -> None:
    with pytest.raises(AttributeError):
        ReferenceRecorder(_Source()).no_such_thing  # noqa: B018
