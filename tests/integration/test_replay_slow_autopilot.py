"""A slow autopilot clock (PX4 SITL on a busy host runs at 0.7-0.93x real time; the mock's
SIM_SPEED_FACTOR models it) is flown as well as a real-time one.

Measured 2026-12-01 on real PX4 SITL at 0.7x: the companion's sample clock fell seconds behind,
its tracking law flew its hover fallback for 20 s in OFFBOARD while the vehicle sank. In the mock
at 0.7 the same companion then hung in its fallback (the replay never ended); with the sample
clock fixed but the reference and the control law on the companion's clock, the vehicle flew
the plan 1/0.7 times too fast in its own time (7.1 m/s on a 5 m/s plan) and the report, timing
samples by the autopilot's clock, said "ok" with 33 m RMS. Oracles: the same flight at full
speed, the plan's speed limit, and the mock's own speed factor (time_boot against the clock that
drives it)."""

from __future__ import annotations

from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from companion.replay.runner import ReplayConfig, prepare_mission, run_prepared
from sitl_mock.lockstep import LockstepSim

ROOT = Path(__file__).resolve().parents[2]
SQUARE = ROOT / "examples" / "missions" / "square.plan"
SLOW = 0.7


def test_the_mocks_clock_runs_at_its_speed_factor() -> None:
    sim = LockstepSim("quad", {"SIM_SPEED_FACTOR": SLOW})
    sim.step_until(10.0)  # the driving clock
    mav = mavlink2.MAVLink(None)
    boots = []
    for data in sim.recv():
        for msg in mav.parse_buffer(data) or []:
            if hasattr(msg, "time_boot_ms"):
                boots.append(msg.time_boot_ms * 1e-3)
    assert boots and max(boots) == pytest.approx(SLOW * 10.0, abs=0.05)


def test_the_mocks_clock_changes_its_rate_at_sim_speed_chg_t() -> None:
    sim = LockstepSim("quad", {"SIM_SPEED_FACTOR": 0.98, "SIM_SPEED_CHG_T": 4.9,
                               "SIM_SPEED_CHG": 0.65})
    mav = mavlink2.MAVLink(None)
    seen: list[tuple[float, float]] = []  # (driving clock, time_boot) [s]
    for k in range(1, 41):
        sim.step_until(k * 0.25)
        for data in sim.recv():
            for msg in mav.parse_buffer(data) or []:
                if msg.get_type() == "ATTITUDE":  # 100 Hz, stamped when built
                    seen.append((k * 0.25, msg.time_boot_ms * 1e-3))
    last = {t: boot for t, boot in seen}  # the newest stamp by each driving time
    # 4.9 s of the vehicle's time at 0.98 take 5 s; then 0.65 s of it per second
    assert last[4.0] == pytest.approx(0.98 * 4.0, abs=0.011)
    assert last[10.0] == pytest.approx(4.9 + 0.65 * 5.0, abs=0.011)


def _fly(*params: tuple[str, float]):  # type: ignore[no-untyped-def]
    config = ReplayConfig(mock_params=params)
    return run_prepared(prepare_mission(SQUARE, config), config, None).report


@pytest.fixture(scope="module")
def full():  # type: ignore[no-untyped-def]
    """The square at full speed (the oracle of this module's slow flights)."""
    return _fly(("SIM_SPEED_FACTOR", 1.0))


def test_a_mission_on_a_slow_autopilot_flies_as_the_same_mission_at_full_speed(
        full) -> None:  # type: ignore[no-untyped-def]
    slow = _fly(("SIM_SPEED_FACTOR", SLOW))
    assert full.result == "ok" and slow.result == "ok", (full.result, slow.result)
    assert full.rms_error_m is not None and slow.rms_error_m is not None
    # tracked as well (0.05 against 0.04 m measured; 0.17 m with the control law's clock local)
    assert slow.rms_error_m <= full.rms_error_m + 0.03
    # judged over the plan only: the report's end of tracking, taken from flight time, kept
    # moving with the clock's lag and took in the touchdown (0.35 m against 0.09 m measured)
    assert full.max_error_m is not None and slow.max_error_m is not None
    assert slow.max_error_m <= full.max_error_m + 0.05
    # the vehicle flies the plan's speeds in its own time, not 1 / SLOW times as fast
    assert slow.max_speed_m_s <= full.max_speed_m_s * 1.05
    # and the clock that drives the mock sees the flight take 1 / SLOW as long
    assert slow.duration_s == pytest.approx(full.duration_s / SLOW, rel=0.03)


def test_an_autopilot_that_slows_down_mid_flight_is_flown_through(full) -> None:  # type: ignore[no-untyped-def]
    """PX4 SITL slowed from 0.98x to 0.65x real time mid-flight when its host got busy (real
    PX4, 2026-12-01): the sample clock's drift, fitted over 20 s, lagged; the samples looked
    staler and staler, and the law flew its hover fallback. Measured in the mock before the
    change detector: "tracking blind for 2.0 s", handed over to LAND at 52.7 s, 1.8 m RMS."""
    step = _fly(("SIM_SPEED_FACTOR", 0.98), ("SIM_SPEED_CHG_T", 30.0), ("SIM_SPEED_CHG", 0.65))
    assert step.result == "ok", step.result
    assert full.rms_error_m is not None and step.rms_error_m is not None
    assert step.rms_error_m <= full.rms_error_m + 0.03  # 0.050 against 0.041 m measured
    assert all(wp.reached for wp in step.waypoints)
