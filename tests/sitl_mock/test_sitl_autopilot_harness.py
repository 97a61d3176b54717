"""The sitl_mock test harness (tests/support/autopilot_harness.py) itself."""

from __future__ import annotations

from tests.support.autopilot_harness import Harness


def test_harness_collects_heartbeats_at_1hz() -> None:
    h = Harness()
    h.run(5.0)
    beats = h.timed("HEARTBEAT")
    assert 4 <= len(beats) <= 6
    assert all(m.get_srcSystem() == 1 and m.get_srcComponent() == 1 for _t, m in beats)
