"""The mock's AUTO.MISSION on issue 24's items, as PX4 v1.16 flies them: NAV_DELAY waits at the
point (mission_block.cpp: NAV_CMD_DELAY's time_inside = param1), a NAV_LAND in the middle of a
mission lands and takes off again for the next position item (Commander::handleAutoDisarm: no
auto-disarm amid an unfinished AUTO.MISSION; Mission::do_need_vertical_takeoff), and VTOL
takeoff/land fly as takeoff/land on a multicopter."""

from __future__ import annotations

import itertools
import math

from tests.sitl_mock.test_sitl_mission_protocol import (
    HOME,
    east_of_home,
    item,
    north_of_home,
    start_auto_mission,
)
from tests.support.autopilot_harness import Harness


def _fly(items: list[object], until_s: float, done: object) -> tuple[Harness, list[tuple[
        float, tuple[float, float, float], tuple[float, float, float], bool]]]:
    """Upload, arm, AUTO.MISSION; record (t, pos, vel, landed) until ``done(h)`` or ``until_s``."""
    h = start_auto_mission(items)
    track: list[tuple[float, tuple[float, float, float], tuple[float, float, float], bool]] = []
    h.run_until(lambda: done(h), until_s,  # type: ignore[operator]
                lambda: track.append((h.now_boot, h.ap.state.pos_ned, h.ap.state.vel_ned,
                                      bool(h.ap.state.landed))))
    return h, track


def test_nav_delay_holds_at_the_previous_waypoint() -> None:
    items = [
        item(0, 22, HOME[0], HOME[1], 5.0),
        item(1, 16, north_of_home(15.0), HOME[1], 5.0),
        item(2, 93, frame=2, p1=5.0, p2=-1.0),
        item(3, 16, north_of_home(15.0), east_of_home(15.0), 5.0),
    ]
    h, track = _fly(items, 90.0, lambda h: any("Mission finished" in t for t in h.texts()))
    assert any("Mission finished" in t for t in h.texts())
    # PX4 starts the delay when the waypoint is reached (NAV_ACC_RAD 2 m out) and holds that
    # setpoint: the vehicle stays within the radius for the delay, and comes to rest there
    best = run = 0.0
    rest = False
    for (t0, p, v, _), (t1, _, _, _) in itertools.pairwise(track):
        near = math.hypot(p[0] - 15.0, p[1], p[2] + 5.0) <= 2.0 + 0.3
        rest = rest or (near and math.hypot(*v) < 0.1)
        run = run + (t1 - t0) if near else 0.0
        best = max(best, run)
    assert best >= 5.0 - 0.05, best
    assert rest
    assert {m.seq for m in h.msgs("MISSION_ITEM_REACHED")} >= {1, 2, 3}


def test_mission_lands_mid_way_stays_armed_and_flies_on() -> None:
    items = [
        item(0, 22, HOME[0], HOME[1], 4.0),
        item(1, 21, north_of_home(10.0), HOME[1], 0.0),
        item(2, 22, north_of_home(10.0), HOME[1], 4.0),
        item(3, 16, north_of_home(10.0), east_of_home(10.0), 4.0),
        item(4, 21, north_of_home(10.0), east_of_home(10.0), 0.0),
    ]
    h, track = _fly(items, 150.0, lambda h: not h.ap.armed)
    # landed near item 1, later flew to item 3 (reached) and landed there, disarmed at the end
    landed_at = [p for _, p, _, landed in track if landed]
    assert any(math.hypot(p[0] - 10.0, p[1]) < 1.0 for p in landed_at)
    assert any(math.hypot(p[0] - 10.0, p[1] - 10.0) < 1.0 for p in landed_at)
    assert 3 in {m.seq for m in h.msgs("MISSION_ITEM_REACHED")}
    assert not h.ap.armed


def test_vtol_takeoff_and_land_fly_as_takeoff_and_land() -> None:
    items = [
        item(0, 84, HOME[0], HOME[1], 6.0),
        item(1, 16, north_of_home(10.0), HOME[1], 6.0),
        item(2, 85, north_of_home(10.0), HOME[1], 0.0),
    ]
    h, track = _fly(items, 90.0, lambda h: not h.ap.armed)
    assert max(-p[2] for _, p, _, _ in track) > 5.0
    end = track[-1][1]
    assert math.hypot(end[0] - 10.0, end[1]) < 1.0 and abs(end[2]) < 0.3
    assert not h.ap.armed
