"""Telemetry latency must not change the flight: the companion measures the link's round trip
(TIMESYNC) and moves each sample back by it (`estimate_from_telemetry`).

A constant latency is invisible to the sample clock (it finds sample times only up to the link's
smallest latency). Before, 30-50 ms of it drove a whirl in attitude and rates mode on the mock:
the tilt went round at ~1 Hz, growing to ~45 deg by the end of the square, while the position
error stayed at 0.2-0.3 m RMS and the report said "ok". Oracle: the mock's own attitude stream
(the body-rate norm of every ATTITUDE_QUATERNION) and position, against the same flight with no
latency.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from companion.flight.tracking import MAX_LINK_RTT_S, estimate_from_telemetry
from companion.mavlink.telemetry import Attitude, LocalPosition, TelemetrySnapshot
from companion.replay.runner import ReplayConfig, ReplayRun, prepare_mission, run_prepared

MISSION = Path(__file__).resolve().parents[2] / "examples" / "missions" / "square.plan"


def _fly(mode: str, latency_s: float) -> ReplayRun:
    config = ReplayConfig(mode=mode, latency_s=latency_s)  # type: ignore[arg-type]
    return run_prepared(prepare_mission(MISSION, config, bounds=False), config, None)


def _body_rate_rms(run: ReplayRun) -> float:
    """RMS of the measured body-rate norm [rad/s] between takeoff and the end of the plan."""
    log = run.log
    assert log.fly_t0 is not None and log.fly_t1 is not None
    t = np.asarray(log.att_t)
    w = np.asarray(log.rate_norm)
    inside = (t >= log.fly_t0) & (t <= log.fly_t1)
    return float(np.sqrt(np.mean(w[inside] ** 2)))


@pytest.mark.parametrize("mode", ["attitude", "rates"])
def test_telemetry_latency_does_not_make_the_flight_whirl(mode: str) -> None:
    nominal = _fly(mode, 0.0)
    late = _fly(mode, 0.05)
    assert nominal.ok and late.ok
    assert late.report.rms_error_m is not None and nominal.report.rms_error_m is not None
    # measured: nominal 0.02-0.04 m, 50 ms 0.03 m (before: 0.27 m with the whirl)
    assert late.report.rms_error_m < max(2.0 * nominal.report.rms_error_m, 0.08)
    # measured: body rates 0.3 rad/s RMS both (before: 2.9); tilt within 3 deg (before: +13)
    assert _body_rate_rms(late) < 1.3 * _body_rate_rms(nominal)
    assert late.report.max_tilt_deg < nominal.report.max_tilt_deg + 5.0


def _snapshot(rtt: float) -> TelemetrySnapshot:
    pos = LocalPosition(t_s=10.0, time_boot_s=10.0, pos_ned=(1.0, 2.0, -3.0),
                        vel_ned=(0.5, 0.0, 0.0), source="LOCAL_POSITION_NED")
    att = Attitude(t_s=10.0, q_wxyz=(1.0, 0.0, 0.0, 0.0), omega_frd=(0.0, 0.0, 0.0))
    return TelemetrySnapshot(position=pos, attitude=att, now_s=10.01, link_rtt_s=rtt)


@pytest.mark.parametrize(("rtt", "shift"), [(math.nan, 0.0), (0.0, 0.0), (-1.0, 0.0),
                                           (0.03, 0.03), (5.0, MAX_LINK_RTT_S)])
def test_a_sample_is_moved_back_by_the_round_trip(rtt: float, shift: float) -> None:
    """Unknown (NaN) or non-positive: the receive time; else moved back by it, capped."""
    est = estimate_from_telemetry(_snapshot(rtt))
    assert est is not None
    assert est.t_s == pytest.approx(10.0 - shift, abs=1e-12)
    np.testing.assert_allclose(est.pos_ned, [1.0, 2.0, -3.0])
