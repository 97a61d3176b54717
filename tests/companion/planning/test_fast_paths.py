"""The schedule's fast path equals its general path: `Schedule.reference` with a numpy origin
(direct construction) vs an origin given as a list (numpy broadcasting, the constructor)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from tests.support.fields import fields_equal


def test_schedule_reference_fast_path_equals_general_path() -> None:
    from companion.mission import load_mission, mission_to_flight_plan
    from companion.planning.schedule import VehicleLimits, build_schedule
    from companion.replay.runner import DEFAULT_QUAD

    root = Path(__file__).resolve().parents[3]
    m = load_mission(root / "examples" / "missions" / "hold_and_jump.plan")
    sched = build_schedule(mission_to_flight_plan(m, vehicle="quad"), DEFAULT_QUAD,
                           VehicleLimits())
    origin = np.array([0.25, -1.5, -0.125])
    kinds = set()
    for t in np.linspace(-1.0, sched.duration_s + 1.0, 157).tolist():
        kinds.add(sched.piece_at(t).kind)
        fast = sched.reference(t, origin=origin)
        # an origin given as a list takes the general path (numpy broadcasting, constructor)
        fields_equal(fast, sched.reference(t, origin=origin.tolist()))  # type: ignore[arg-type]
        no_origin = sched.reference(t)
        np.testing.assert_array_equal(no_origin.pos_ned + origin, fast.pos_ned)
    assert "traj" in kinds
