"""The benchmarks' mapping of autopilot sample times onto the local clock (bench/api_harness.py
`clock_map`), against a simulated autopilot whose true sample times are known: a lockstep clock
like PX4 SITL's (4 ms of simulated time per step, each step taking a little longer in wall time,
sometimes much longer when the host is busy) and telemetry leaving with a random link delay."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))

from api_harness import clock_map


def _lockstep_autopilot(seed: int, seconds: float = 120.0) -> tuple[np.ndarray, np.ndarray,
                                                                   np.ndarray]:
    """(boot stamps [s], receive times [s], true local times of the samples [s]) of a 100 Hz
    stream from an autopilot that steps 4 ms of its clock per lockstep step."""
    rng = np.random.default_rng(seed)
    steps = round(seconds / 0.004)
    wall_dt = 0.004 + rng.exponential(40e-6, steps)  # usleep overshoot: ~1 % slow
    busy = rng.random(steps) < 0.0005  # host busy (every ~8 s): a step takes 5-40 ms longer
    wall_dt[busy] += rng.uniform(0.005, 0.04, int(busy.sum()))
    wall = 1.7e9 + np.cumsum(wall_dt)
    boot = 12.0 + 0.004 * np.arange(1, steps + 1)
    pick = np.flatnonzero(np.diff(np.floor(boot / 0.01), prepend=0.0) > 0)  # every 10 ms
    delay = rng.exponential(0.0005, len(pick))
    burst = rng.random(len(pick)) < 0.05  # batched behind other traffic
    delay[burst] += rng.uniform(0.005, 0.03, int(burst.sum()))
    return boot[pick], wall[pick] + delay, wall[pick]


def test_mapped_sample_times_follow_an_irregularly_drifting_lockstep_clock() -> None:
    for seed in range(3):
        boot, recv, true = _lockstep_autopilot(seed)
        err = clock_map(boot, recv) - true
        # the clocks drift ~1.5 s apart over the run; the mapping stays within a few ms
        assert float(np.ptp(recv - boot)) > 1.0
        assert abs(float(np.median(err))) < 0.002
        assert float(np.percentile(np.abs(err), 95)) < 0.003


def test_constant_offset_maps_to_the_smallest_delay() -> None:
    rng = np.random.default_rng(4)
    boot = np.arange(0.0, 30.0, 0.01)
    true = boot + 1.7e9 + 0.123
    recv = true + 0.002 + rng.exponential(0.003, len(boot))
    mapped = clock_map(boot, recv)
    assert np.all(mapped >= true + 0.002 - 1e-9)
    assert float(np.median(mapped - true)) < 0.0035
    assert np.all(np.diff(mapped) > 0.0)


def test_empty_series_maps_to_empty() -> None:
    assert len(clock_map(np.array([]), np.array([]))) == 0
