"""The rover fidelity benchmark's measures (bench/bench_rover_fidelity.py) on synthetic records
with known answers: a circle of known radius, a speed ramp with known timing, a square driven
with a known offset."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))

import bench_rover_fidelity as B  # noqa: N812


def test_circle_fit_recovers_a_noisy_arc() -> None:
    rng = np.random.default_rng(3)
    a = np.linspace(0.3, 5.0, 400)
    xy = np.column_stack([2.0 + 0.9 * np.cos(a), -1.0 + 0.9 * np.sin(a)])
    xy += rng.normal(0.0, 0.005, xy.shape)
    cx, cy, r = B.circle_fit(xy)
    assert (cx, cy, r) == pytest.approx((2.0, -1.0, 0.9), abs=0.005)


def test_step_metrics_of_a_known_ramp_and_stop() -> None:
    """Speed 0 until 0.5 s after the command, a 5 m/s^2 ramp to 2.4 m/s, steady; the stop:
    a 3 m/s^2 ramp down from the stop command."""
    t = np.arange(0.0, 16.0, 0.01)
    v = np.where(t < 1.5, 0.0, np.minimum(5.0 * (t - 1.5), 2.4))
    stop = 11.0
    v = np.where(t >= stop, np.maximum(2.4 - 3.0 * (t - stop), 0.0), v)
    rec = B.Record(truth=[(ti, 0.0, 0.0, vi, 0.0, 0.0, 0.0) for ti, vi in zip(t, v, strict=True)],
                   marks={"step": 1.0, "stop": stop})
    # positions integrated from the speed (north only)
    north = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * 0.01)])
    rec.truth = [(ti, n, 0.0, vi, 0.0, 0.0, 0.0) for ti, n, vi in zip(t, north, v, strict=True)]
    m = B.step_metrics(rec)
    assert m["steady_m_s"] == pytest.approx(2.4)
    assert m["dead_s"] == pytest.approx(0.5 + 0.1 / 5.0, abs=0.011)
    assert m["rise_s"] == pytest.approx(0.8 * 2.4 / 5.0, abs=0.011)
    assert m["peak_acc_m_s2"] == pytest.approx(5.0, rel=0.02)
    assert m["overshoot"] == pytest.approx(2.4 / B.STEP_SPEED - 1.0)
    assert m["stop_s"] == pytest.approx((2.4 - 0.1) / 3.0, abs=0.011)
    assert m["stop_m"] == pytest.approx((2.4**2 - 0.1**2) / 6.0, rel=0.02)


def test_mission_metrics_of_the_square_driven_with_an_offset() -> None:
    """rover_square driven 0.2 m inside its legs: closest approach 0.2 * sqrt(2) at the corners,
    cross-track 0.2 m; the start at home does not count for the last waypoint."""
    _items, home, wps = B.plan_items(B.PLAN)
    ne = B._ne(np.array([w[0] for w in wps]), np.array([w[1] for w in wps]), *home)
    side = float(ne[0, 0])  # 30 m north
    o = 0.2
    pts = []
    for a, b in [((o, o), (side - o, o)), ((side - o, o), (side - o, side - o)),
                 ((side - o, side - o), (o, side - o)), ((o, side - o), (o, 1.0))]:
        for u in np.linspace(0.0, 1.0, 200):
            pts.append((a[0] + u * (b[0] - a[0]), a[1] + u * (b[1] - a[1])))
    rec = B.Record(truth=[(float(i), n, e, 1.0, 0.0, 0.0, 0.0) for i, (n, e) in enumerate(pts)],
                   marks={"arm": 0.0, "end": float(len(pts))})
    m = B.mission_metrics(rec, B.PLAN)
    for c in m["closest_m"][:3]:
        assert c == pytest.approx(o * math.sqrt(2.0), abs=0.02)
    assert m["closest_m"][3] == pytest.approx(math.hypot(o, 1.0), abs=0.01)  # not the start
    assert m["xtrack_rms_m"] == pytest.approx(o, abs=0.01)


def test_write_subsection_keeps_the_section_and_replaces_only_itself(tmp_path: Path) -> None:
    """A `### sub` block goes at the end of its `## title` section, then replaces itself; the
    section's own text and the next section stay as they were."""
    from benchmarks_md import write_subsection

    md = tmp_path / "B.md"
    md.write_text("# B\n\n## A\n\nold table\n\n## Next\n\nkeep\n")
    write_subsection("A", "Sub", "### Sub\n\nfirst\n", md)
    assert md.read_text() == "# B\n\n## A\n\nold table\n\n### Sub\n\nfirst\n\n## Next\n\nkeep\n"
    write_subsection("A", "Sub", "### Sub\n\nsecond\n", md)
    assert md.read_text() == "# B\n\n## A\n\nold table\n\n### Sub\n\nsecond\n\n## Next\n\nkeep\n"
    with pytest.raises(ValueError):
        write_subsection("Missing", "Sub", "### Sub\n", md)


def test_estimate_error_of_a_known_offset_and_the_fitted_time_constant() -> None:
    """A trace whose estimate is the truth moved by (0.3, -0.2) m and 2 deg, stamped on a clock
    1 % slow and received 10-30 ms late (the truth 10 ms late, the link's least delay): the
    errors come back as those offsets (the receive-clock mapping, drift and ends included, adds
    < 1 cm at 2 m/s, < 3 cm at worst); the Gauss-Markov fit returns the time constant of an exact
    model autocorrelation."""
    import rover_estimate_error as E  # noqa: N812

    rng = np.random.default_rng(1)
    rec: dict[str, list[tuple[float, ...]]] = {"lpos": [], "att": [], "truth": []}
    for k in range(1500):
        t = 0.02 * k
        rec["truth"].append((t + 0.01, 2.0 * t, 0.0, 2.0, 0.0, 0.0, 0.0, 0.0))
        boot = t * 0.99  # the autopilot's clock
        late = 0.01 + 0.02 * float(rng.random())
        rec["lpos"].append((t + late, 2.0 * t + 0.3, -0.2, 2.0, 0.0, boot))
        rec["att"].append((t + late, math.radians(2.0), 0.0, boot))
    f = E.flight_errors(rec)
    assert np.abs(f["pos"] - [0.3, -0.2]).max() < 0.01 + 2.0 * 0.01
    assert float(np.median(np.abs(f["pos"][:, 0] - 0.3))) < 0.01
    assert np.degrees(f["yaw"]) == pytest.approx(2.0, abs=1e-6)
    lags = np.arange(int(E.MAX_LAG_S / E.GRID_S) + 1) * E.GRID_S
    assert E.fit_tau((1.0 + lags / 1.7) * np.exp(-lags / 1.7)) == pytest.approx(1.7, rel=1e-3)
