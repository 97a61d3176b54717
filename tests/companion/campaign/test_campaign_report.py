"""Campaign summary: success rates per mission and mode, --require verdict, worst runs first,
and the Parquet table round trip."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pyarrow.parquet as pq

from companion.campaign.report import summarize, write_outputs


def _row(mission: str, mode: str, i: int, ok: bool, max_err: float | None) -> dict[str, Any]:
    return {
        "run_id": f"{mission}|{mode}|{i}", "file": f"{mission}.plan", "mission": mission,
        "mode": mode, "run_index": i, "ok": ok, "result": "ok" if max_err else "error: x",
        "rms_error_m": None if max_err is None else max_err / 3, "max_error_m": max_err,
        "min_waypoint_margin_m": 1.0 if ok else -2.0, "waypoints_reached": 4 if ok else 2,
        "waypoints_total": 4, "wind_m_s": float(i), "mass_error": 0.01 * i,
        "command": f"python -m companion replay {mission}.plan --seed {i}", "tlog": None,
    }


ROWS = (
    [_row("a", "attitude", i, i != 3, 0.5 + i) for i in range(10)]  # 90 %
    + [_row("a", "position", i, True, 0.2) for i in range(10)]  # 100 %
    + [_row("b", "attitude", i, i < 5, None if i == 9 else 1.0) for i in range(10)]  # 50 %
)


def test_success_rates_and_the_require_verdict() -> None:
    s = summarize(ROWS, 0.9, {"seed": 1})
    rates = {(g["mission"], g["mode"]): g["success_rate"] for g in s["groups"]}
    assert rates == {("a", "attitude"): 0.9, ("a", "position"): 1.0, ("b", "attitude"): 0.5}
    assert not s["passed"]
    assert summarize([r for r in ROWS if r["mission"] == "a"], 0.9, {})["passed"]
    assert not summarize([r for r in ROWS if r["mission"] == "a"], 0.95, {})["passed"]
    assert s["runs"] == 30 and s["successes"] == 9 + 10 + 5


def test_worst_runs_are_the_failures_largest_error_first() -> None:
    worst = summarize(ROWS, 0.5, {})["worst"]
    n_failed = sum(not r["ok"] for r in ROWS)
    assert all(not w["ok"] for w in worst[:n_failed])
    errs = [w["max_error_m"] for w in worst[:n_failed]]
    assert errs[0] is None  # a run without a result counts as the worst
    finite = [e for e in errs if e is not None]
    assert finite == sorted(finite, reverse=True)
    assert all(w["command"].startswith("python -m companion replay") for w in worst)


def test_outputs_round_trip_through_parquet(tmp_path: Path) -> None:
    write_outputs(tmp_path, ROWS, 0.9, {"seed": 1})
    back = pq.read_table(tmp_path / "runs.parquet").to_pylist()
    key = lambda r: r["run_id"]  # noqa: E731
    assert sorted(back, key=key) == sorted(ROWS, key=key)
    page = (tmp_path / "report.html").read_text()
    assert page.count("data:image/png;base64,") == 2 and "FAILED" in page
