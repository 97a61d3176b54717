"""Behaviour kept through refactors: replaying every bundled mission gives the report figures
stored in tests/data/report_figures.json, to round-off.

This is a regression snapshot, not a correctness oracle: the figures were recorded from the
replays of commit d133c5d (before the issue-25 redesign), and re-recorded when the tracking
law's latency compensation became a Smith predictor over the commands sent since the sample,
instead of the last command over the whole age (session 13: the mock's RMS errors within 1 %
of the old ones, largest thrust steps 0.011-0.018), and when telemetry's velocity correction
came (session 18: RMS errors within 0.1 %, the mock's estimate agreeing with its position),
and when the sample clock's offset was slewed (one closest approach moved by 3e-7 m), and
when the drag estimator came on by default with the disturbance taken out of its balance
(session 19: RMS errors within 0.5 %, max tilt within 0.03 deg), and when the horizontal
position gains came down from kp_xy 20 / kd_xy 8.5 to 14 / 7.1 (session 31: the old ones
rocked the vehicle at 1.2 Hz on real PX4; the mock's RMS errors 0.7 % lower to 10 % higher,
every waypoint and thrust step unchanged), with the reports' new tilt-oscillation figures
(whose 2 s windows moved when the setpoint figures began at liftoff: 0.1-0.5 deg), and when
the mock flew offboard attitude setpoints SIM_SP_DELAY (6 ms) after they arrived, as PX4 does
(RMS errors within 1.1 %, largest thrust steps within 0.0013).
They hold for the BLAS kernels they were recorded with (tests/support/blas.py; one ulp in a
dot of 3 moved five_minute's plan by 10 s), and were re-recorded with OpenBLAS's Haswell kernels
(the same code: the earlier figures came from its SkylakeX kernels on an Intel host), which
tests/conftest.py picks; and when the replay flew on the autopilot's clock (session 32: RMS
errors within 0.03 %, max errors within 1e-4 m, durations unchanged, every waypoint reached).
Their correctness is asserted by the
other replay tests (waypoints from the tlog, setpoint quality, touchdown). A change of flight
behaviour must show up here and be re-recorded on purpose, with the reason in the commit:

    python -m tests.integration.test_report_figures --write
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path
from typing import Any

import pytest

from companion.app.cli import main as cli_main
from tests.support.blas import numpy_rounds_as_recorded

ROOT = Path(__file__).resolve().parents[2]
MISSIONS = ROOT / "examples" / "missions"
STORED = ROOT / "tests" / "data" / "report_figures.json"

#: (case name, file, extra replay arguments)
CASES: list[tuple[str, str, tuple[str, ...]]] = [
    *[(p.stem, p.name, ()) for p in sorted(MISSIONS.glob("*.plan")) if "rover" not in p.stem],
    ("square_waypoints", "square.waypoints", ()),
    ("rover_square", "rover_square.plan", ("--vehicle", "rover")),
    ("square_rates", "square.plan", ("--mode", "rates")),
]

#: report keys that measure the host, not the flight
_VOLATILE = {"wall_s", "real_time_factor", "file"}
_REL = 1e-6
_ABS = 1e-9


def _figures(report: dict[str, Any]) -> dict[str, Any]:
    """The report without host figures, with paths relative to the repository (warnings name
    the file)."""
    text = json.dumps({k: v for k, v in report.items() if k not in _VOLATILE})
    return dict(json.loads(text.replace(str(ROOT) + "/", "")))


def _replay_all(out: Path) -> dict[str, dict[str, Any]]:
    """Replay every case, two files at a time, and return each case's report figures."""
    batches: list[tuple[tuple[str, ...], list[tuple[str, str]]]] = []
    for name, file, args in CASES:
        # files of the same stem would share an output folder: they go in separate calls
        batch = next((b for a, b in batches if a == args
                      and all(Path(f).stem != Path(file).stem for _, f in b)), None)
        if batch is None:
            batch = []
            batches.append((args, batch))
        batch.append((name, file))
    figures: dict[str, dict[str, Any]] = {}
    for i, (args, batch) in enumerate(batches):
        batch_out = out / str(i)
        rc = cli_main(["replay", *(str(MISSIONS / f) for _, f in batch), "--out", str(batch_out),
                       "--jobs", "2", "--no-plot", *args])
        assert rc == 0, f"replay of {[f for _, f in batch]} exited {rc}"
        for name, file in batch:
            report = json.loads((batch_out / Path(file).stem / "report.json").read_text())
            figures[name] = _figures(report)
    return figures


def _diff(path: str, want: Any, got: Any, out: list[str]) -> None:
    if isinstance(want, dict) and isinstance(got, dict):
        for k in sorted(set(want) | set(got)):
            if k not in want or k not in got:
                out.append(f"{path}.{k}: only in {'stored' if k in want else 'replay'}")
            else:
                _diff(f"{path}.{k}", want[k], got[k], out)
    elif isinstance(want, list) and isinstance(got, list):
        if len(want) != len(got):
            out.append(f"{path}: {len(want)} stored entries, {len(got)} replayed")
        for i, (a, b) in enumerate(zip(want, got, strict=False)):
            _diff(f"{path}[{i}]", a, b, out)
    elif (isinstance(want, float | int) and not isinstance(want, bool)
          and isinstance(got, float | int) and not isinstance(got, bool)):
        if not math.isclose(float(want), float(got), rel_tol=_REL, abs_tol=_ABS):
            out.append(f"{path}: stored {want!r}, replayed {got!r}")
    elif want != got:
        out.append(f"{path}: stored {want!r}, replayed {got!r}")


@pytest.mark.slow
@pytest.mark.skipif(
    not numpy_rounds_as_recorded(),
    reason="this host's numpy rounds otherwise than when the figures were recorded (OpenBLAS "
           "Haswell's dots of 3, needing AVX2; exp/log/sin/cos as the C library's; "
           "tests/support/blas.py, tests/support/cpu_env.py)")
def test_bundled_missions_replay_to_the_stored_report_figures(tmp_path: Path) -> None:
    stored = json.loads(STORED.read_text())
    assert sorted(stored) == sorted(name for name, _, _ in CASES)
    got = _replay_all(tmp_path)
    problems: list[str] = []
    for name in stored:
        _diff(name, stored[name], got[name], problems)
    assert not problems, "report figures changed:\n" + "\n".join(problems[:40])


def test_the_comparison_notices_a_changed_figure() -> None:
    """The differ is not blind: a relative change of 1e-5 in one nested figure is reported,
    round-off (1e-9) is not."""
    base = {"a": {"legs": [{"time_s": 9.768, "leg": "x"}], "ok": True}}
    changed = json.loads(json.dumps(base))
    changed["a"]["legs"][0]["time_s"] *= 1 + 1e-5
    problems: list[str] = []
    _diff("m", base, changed, problems)
    assert problems == [f"m.a.legs[0].time_s: stored 9.768, replayed {9.768 * (1 + 1e-5)!r}"]
    rounded = json.loads(json.dumps(base))
    rounded["a"]["legs"][0]["time_s"] *= 1 + 1e-9
    problems.clear()
    _diff("m", base, rounded, problems)
    assert problems == []


if __name__ == "__main__":
    if sys.argv[1:] != ["--write"]:
        sys.exit(__doc__)
    import os
    import tempfile

    from tests.support.cpu_env import pinned_environment

    if pinned_environment(os.environ):  # numpy is loaded: again, with the tests' set-up
        os.execve(sys.executable, [sys.executable, "-m", "tests.integration.test_report_figures",
                                   "--write"], {**os.environ, **pinned_environment(os.environ)})

    with tempfile.TemporaryDirectory() as d:
        STORED.write_text(json.dumps(_replay_all(Path(d)), indent=1, sort_keys=True) + "\n")
    print(f"wrote {STORED}")
