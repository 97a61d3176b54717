"""The replay's fast paths fly the same flight as its general paths:

- without a tlog the mock leaves the streams the companion does not read unbuilt
  (`UNREAD_STREAMS`): the same log and report as the flight that builds and logs them all,
  under link faults (loss and delayed telemetry draw from the link's random stream per datagram),
  wind, gusts and sensor noise;
- a campaign's runs plan without the time-optimal bounds: the same flight, only the bound
  figures of the report are unknown.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import pytest

from companion.aio.tlog import TlogWriter
from companion.replay.runner import DEFAULT_QUAD, ReplayConfig, prepare_mission, run_prepared

ROOT = Path(__file__).resolve().parents[2]
MISSION = ROOT / "examples" / "missions" / "square.plan"
WALL = ("wall_s", "real_time_factor", "tlog_frames")
BOUNDS = ("bound_s", "planned_over_bound")


def _report(run: Any) -> dict[str, Any]:
    return {k: v for k, v in run.report.to_dict().items() if k not in WALL}


@pytest.mark.parametrize("mode", ["attitude", "position"])
def test_flight_without_a_tlog_is_the_flight_with_one(tmp_path: Path, mode: str) -> None:
    config = ReplayConfig(
        mode=mode, seed=5, wind_m_s=3.0, wind_from_deg=250.0, latency_s=0.02, jitter_s=0.01,
        loss_pct=3.0, params=dataclasses.replace(DEFAULT_QUAD, hover_thrust=0.53),
        mock_params=(("SIM_WIND_GUST", 0.8), ("SIM_POS_NOISE", 0.04), ("SIH_MASS", 1.08)),
    )
    prep = prepare_mission(MISSION, config)
    with TlogWriter(tmp_path / "flight.tlog", buffer_bytes=1 << 20) as tlog:
        logged = run_prepared(prep, config, tlog)
    lean = run_prepared(prep, config, None)
    assert _report(lean) == _report(logged)
    assert dataclasses.asdict(lean.log) == dataclasses.asdict(logged.log)
    assert lean.flight.lk.sim.autopilot.stats == logged.flight.lk.sim.autopilot.stats
    assert logged.report.tlog_frames > 2 * len(lean.log.t)  # the logged flight had them all
    assert lean.report.result == "ok" and len(lean.log.t) > 1000


def test_campaign_plan_without_bounds_flies_the_same_flight() -> None:
    config = ReplayConfig(seed=2, wind_m_s=2.0)
    full = prepare_mission(MISSION, config)
    lean = prepare_mission(MISSION, config, bounds=False)
    assert lean.bound_s is None and lean.leg_bounds_s is None and full.bound_s is not None
    a, b = _report(run_prepared(full, config, None)), _report(run_prepared(lean, config, None))
    assert b["bound_s"] is None and a["bound_s"] > 0
    assert {k: v for k, v in a.items() if k not in (*BOUNDS, "legs")} == \
        {k: v for k, v in b.items() if k not in (*BOUNDS, "legs")}
    assert [{k: v for k, v in leg.items() if "bound" not in k} for leg in a["legs"]] == \
        [{k: v for k, v in leg.items() if "bound" not in k} for leg in b["legs"]]
