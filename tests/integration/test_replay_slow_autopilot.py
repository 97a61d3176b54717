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


def _fly(speed: float):  # type: ignore[no-untyped-def]
    config = ReplayConfig(mock_params=(("SIM_SPEED_FACTOR", speed),))
    return run_prepared(prepare_mission(SQUARE, config), config, None).report


def test_a_mission_on_a_slow_autopilot_flies_as_the_same_mission_at_full_speed() -> None:
    full, slow = _fly(1.0), _fly(SLOW)
    assert full.result == "ok" and slow.result == "ok", (full.result, slow.result)
    assert full.rms_error_m is not None and slow.rms_error_m is not None
    # tracked as well (0.05 against 0.04 m measured; 0.17 m with the control law's clock local)
    assert slow.rms_error_m <= full.rms_error_m + 0.03
    # the vehicle flies the plan's speeds in its own time, not 1 / SLOW times as fast
    assert slow.max_speed_m_s <= full.max_speed_m_s * 1.05
    # and the clock that drives the mock sees the flight take 1 / SLOW as long
    assert slow.duration_s == pytest.approx(full.duration_s / SLOW, rel=0.03)
