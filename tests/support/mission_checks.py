"""Shared structural checks for mission flight plans (used by unit and property tests)."""

from __future__ import annotations

import numpy as np
import pytest

from companion.mission import FlightPlan, split_flight_plan


def check_chunks(fp: FlightPlan) -> None:
    """Structural invariants of split_flight_plan, computed from the plan independently."""
    chunks = split_flight_plan(fp)
    assert chunks
    pts = fp.points_ned_m()
    merged = [pts[0]]
    for p in pts[1:]:
        if np.linalg.norm(p - merged[-1]) > 1e-3:
            merged.append(p)
    joined = [chunks[0].points_ned_m[0]]
    for c in chunks:
        m = len(c.points_ned_m)
        assert m >= 2
        assert len(c.yaw_deg) == len(c.acceptance_radius_m) == len(c.item_indices) == m
        assert len(c.leg_speed_m_s) == m - 1 and min(c.leg_speed_m_s) > 0
        assert c.max_speed_m_s == min(c.leg_speed_m_s)
        assert not c.points_ned_m.flags.writeable
        steps = np.linalg.norm(np.diff(c.points_ned_m, axis=0), axis=1)
        assert np.all(steps > 1e-3)
        np.testing.assert_array_equal(c.points_ned_m[0], joined[-1])
        joined.extend(c.points_ned_m[1:])
    np.testing.assert_allclose(np.asarray(joined), np.asarray(merged), atol=1e-3)
    # every stop of the plan is the end of a chunk
    ends = np.asarray([c.points_ned_m[-1] for c in chunks])
    for w in fp.waypoints:
        if w.stop:
            assert np.min(np.linalg.norm(ends - np.asarray(w.pos_ned_m), axis=1)) <= 1e-3
    assert sum(c.hold_after_s for c in chunks) == pytest.approx(sum(w.hold_s for w in fp.waypoints))
