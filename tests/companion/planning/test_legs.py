"""Per-leg figures against synthetic flights whose answers are known by construction: a flown
path with a known lateral bump (deviation max and RMS), constant-speed legs (mean/max speed and
time), DO_CHANGE_SPEED in the plan (cruise speed per leg), and the time-optimal bound shown as
"-" until one is given."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.mission import FlightPlan, load_mission, mission_to_flight_plan
from companion.planning.legs import (
    leg_figures,
    leg_spans,
    passages,
    plan_legs,
    segment_distance,
    worst_leg_text,
)
from tests.support.fence_plans import write_plan

coord = st.floats(-100.0, 100.0, allow_nan=False)


@settings(max_examples=60, deadline=None)
@given(st.lists(coord, min_size=9, max_size=9))
def test_segment_distance_matches_a_brute_force_minimum(v: list[float]) -> None:
    a, b, p = np.array(v[0:3]), np.array(v[3:6]), np.array(v[6:9])
    # oracle: the closest of 20,001 points spread along the segment
    s = np.linspace(0.0, 1.0, 20_001)[:, None]
    brute = float(np.min(np.linalg.norm(a + s * (b - a) - p, axis=1)))
    step = float(np.linalg.norm(b - a)) / 20_000
    got = float(segment_distance(p[None, :], a, b)[0])
    assert got <= brute + 1e-9
    assert got >= brute - step  # the brute force overestimates by at most half a step


def _plan(tmp_path: Path, pts: list[tuple[float, float]], **kw: object) -> FlightPlan:
    return mission_to_flight_plan(load_mission(write_plan(tmp_path / "m.plan", pts, **kw)))  # type: ignore[arg-type]


def _fly(points: list[np.ndarray], speeds: list[float], rate_hz: float = 50.0
         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Straight constant-speed flight through `points` (speed k on segment k), sampled at
    `rate_hz`: (t, pos, vel)."""
    ts, ps, vs = [np.zeros(1)], [points[0][None, :]], [np.zeros((1, 3))]
    t0 = 0.0
    for a, b, v in zip(points[:-1], points[1:], speeds, strict=True):
        d = float(np.linalg.norm(b - a))
        dur = d / v
        t = np.arange(1, round(dur * rate_hz) + 1) / rate_hz
        u = (b - a) / d
        ts.append(t0 + t)
        ps.append(a + np.outer(np.minimum(t * v, d), u))
        vs.append(np.tile(u * v, (len(t), 1)))
        t0 += t[-1]
    return np.concatenate(ts), np.concatenate(ps), np.concatenate(vs)


def test_constant_speed_legs_give_their_speed_time_and_zero_deviation(tmp_path: Path) -> None:
    fp = _plan(tmp_path, [(40, 0), (40, 30)], land=False)
    legs = plan_legs(fp)
    assert [(g.start_item, g.end_item) for g in legs] == [(None, 1), (1, 2), (2, 3)]
    pts = [np.array(fp.start_ned_m)] + [np.array(w.pos_ned_m) for w in fp.waypoints]
    t, p, v = _fly(pts, [1.0, 4.0, 2.0])
    rows = leg_figures(legs, t, p, vel_ned=v)
    for row, speed, length in zip(rows, (1.0, 4.0, 2.0), (10.0, 40.0, 30.0), strict=True):
        assert row["length_m"] == pytest.approx(length, abs=0.01)
        assert row["mean_speed_m_s"] == pytest.approx(speed, rel=0.02)
        assert row["max_speed_m_s"] == pytest.approx(speed, rel=1e-6)
        assert row["time_s"] == pytest.approx(length / speed, abs=0.05)
        assert row["max_deviation_m"] == pytest.approx(0.0, abs=1e-6)
    # without velocities: finite differences give the same speeds
    rows_fd = leg_figures(legs, t, p)
    assert [r["max_speed_m_s"] for r in rows_fd] == pytest.approx([1.0, 4.0, 2.0], rel=0.02)


def test_lateral_bump_gives_its_known_max_and_rms_deviation(tmp_path: Path) -> None:
    fp = _plan(tmp_path, [(60, 0)], land=False)
    legs = plan_legs(fp)
    leg = legs[1]  # item 1 (0, 0, -10) -> item 2 (60, 0, -10)
    # flown: north s in [0, 60], east 3 sin(pi s / 60) (a bump), at 10 m altitude
    s = np.linspace(0.0, 60.0, 6001)
    bump = 3.0 * np.sin(np.pi * s / 60.0)
    climb = np.column_stack([np.zeros(101), np.zeros(101), -np.linspace(0, 10, 101)])
    flown = np.column_stack([s, bump, np.full_like(s, -10.0)])
    pos = np.vstack([climb, flown[1:]])
    t = np.arange(len(pos)) * 0.01
    row = leg_figures(legs, t, pos)[1]
    assert row["leg"] == "item 1 to item 2"
    assert row["max_deviation_m"] == pytest.approx(3.0, abs=1e-3)
    # RMS of 3 sin over a half period is 3 / sqrt(2) (the passages trim < 1 % of the samples)
    assert row["rms_deviation_m"] == pytest.approx(3.0 / np.sqrt(2.0), rel=0.01)
    assert leg.cruise_speed_m_s == pytest.approx(5.0)  # MPC_XY_CRUISE default
    sp = leg_spans(pos, legs)[1]
    assert sp is not None and pos[sp[1], 0] == pytest.approx(60.0, abs=0.05)


def test_passages_follow_the_mission_order_when_a_point_is_revisited(tmp_path: Path) -> None:
    # out and back: item 3 = item 1's position; the passage of item 3 is the late one
    fp = _plan(tmp_path, [(30, 0), (0, 0.01)], land=False)
    legs = plan_legs(fp)
    pts = [np.array(fp.start_ned_m)] + [np.array(w.pos_ned_m) for w in fp.waypoints]
    t, p, _ = _fly(pts, [1.0, 3.0, 3.0])
    pas = passages(p, legs)
    assert pas[0] == 0 and all(a is not None for a in pas)
    assert pas == sorted(pas)  # type: ignore[type-var]
    assert t[pas[-1]] == pytest.approx(t[-1], abs=0.05)  # type: ignore[index]


def test_do_change_speed_sets_the_cruise_speed_of_the_following_legs(tmp_path: Path) -> None:
    path = write_plan(tmp_path / "s.plan", [(20, 0), (40, 0), (60, 0)], land=False)
    doc = json.loads(path.read_text())
    items = doc["mission"]["items"]
    # DO_CHANGE_SPEED 8 m/s after item 2 (reached at item 2: applies from the next leg on)
    items.insert(2, {"type": "SimpleItem", "command": 178, "frame": 2, "autoContinue": True,
                     "doJumpId": 9, "params": [1, 8, -1, 0, 0, 0, 0]})
    path.write_text(json.dumps(doc))
    legs = plan_legs(mission_to_flight_plan(load_mission(path)))
    speeds = {(g.start_item, g.end_item): g.cruise_speed_m_s for g in legs}
    assert speeds[(1, 2)] == pytest.approx(5.0)
    later = [v for (a, _b), v in speeds.items() if a is not None and a >= 3]
    assert later and all(v == pytest.approx(8.0) for v in later)


def test_bound_gives_time_over_bound_and_missing_bound_shows_a_dash(tmp_path: Path) -> None:
    fp = _plan(tmp_path, [(40, 0)], land=False)
    legs = plan_legs(fp)
    pts = [np.array(fp.start_ned_m)] + [np.array(w.pos_ned_m) for w in fp.waypoints]
    t, p, v = _fly(pts, [1.0, 4.0])
    rows = leg_figures(legs, t, p, vel_ned=v, bounds_s=[None, 8.0])
    assert rows[0]["bound_s"] is None and rows[0]["time_over_bound"] is None
    assert rows[1]["time_over_bound"] == pytest.approx(10.0 / 8.0, abs=0.01)
    text = worst_leg_text(leg_figures(legs, t, p, vel_ned=v))
    assert "(bound - s)" in text
    with pytest.raises(ValueError):
        leg_figures(legs, t, p, bounds_s=[1.0])


def test_planned_samples_give_planned_time_and_speed(tmp_path: Path) -> None:
    from companion.planning.fence_check import sample_schedule
    from companion.planning.schedule import build_schedule
    from companion.replay.runner import DEFAULT_QUAD

    fp = _plan(tmp_path, [(60, 0)], land=False)
    sched = build_schedule(fp, DEFAULT_QUAD)
    pt, pp = sample_schedule(sched)
    legs = plan_legs(fp)
    rows = leg_figures(legs, pt, pp, planned_t_s=pt, planned_ned=pp)
    # the planned leg never exceeds its cruise speed, and flying the plan exactly is the plan
    for r in rows:
        assert r["planned_max_speed_m_s"] <= r["cruise_speed_m_s"] * 1.02
        assert r["time_s"] == pytest.approx(r["planned_time_s"], abs=1e-6)
    assert sum(r["planned_time_s"] for r in rows) <= sched.duration_s + 1e-6


def _passages_reference(p: np.ndarray, legs: list) -> list:  # type: ignore[type-arg]
    """The passage rule written plainly over whole arrays (one sample at a time)."""
    out: list = [0]  # type: ignore[type-arg]
    i0 = 0
    for k, leg in enumerate(legs):
        end = np.asarray(leg.end_ned_m)
        d = [float(np.linalg.norm(p[i] - end)) for i in range(i0, len(p))]
        entered = [i for i, x in enumerate(d) if x <= leg.acceptance_m]
        if entered:
            j = entered[0]
            while j + 1 < len(d) and d[j + 1] < d[j]:
                j += 1
        else:
            stop = len(d)
            if k + 1 < len(legs):
                nend = np.asarray(legs[k + 1].end_ned_m)
                nxt = [i for i in range(len(d)) if float(np.linalg.norm(p[i0 + i] - nend))
                       <= legs[k + 1].acceptance_m]
                if nxt and nxt[0] > 0:
                    stop = nxt[0]
            j = int(np.argmin(d[:stop]))
        out.append(i0 + j)
        i0 += j
    return out


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(50, 3000))
def test_passages_equal_a_plain_reference_on_noisy_flights(seed: int, n: int) -> None:
    import tempfile

    rng = np.random.default_rng(seed)
    with tempfile.TemporaryDirectory() as d:
        fp = _plan(Path(d), [(30, 0), (30, 20), (0, 20)], land=False)
    legs = list(plan_legs(fp))
    pts = [np.array(fp.start_ned_m)] + [np.array(w.pos_ned_m) for w in fp.waypoints]
    # a noisy, sometimes wandering flight along the path (may miss points, may stop short)
    s = np.sort(rng.uniform(0, len(pts) - 1, n))
    k = np.minimum(s.astype(int), len(pts) - 2)
    f = (s - k)[:, None]
    base = np.array([pts[i] for i in k]) * (1 - f) + np.array([pts[i + 1] for i in k]) * f
    p = base + rng.normal(0.0, rng.uniform(0.01, 3.0), base.shape)
    assert passages(p, legs) == _passages_reference(p, legs)
