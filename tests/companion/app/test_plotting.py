"""PlotWorker: the PNG drawn by the helper process is the one drawn in-process, and every way the
helper can fail (killed, wedged, raising) still leaves the PNG (or the real error) and no process
behind."""

from __future__ import annotations

import os
import signal
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from companion.app.plotting import PlotData, PlotWorker, draw_flight_png


def _data(n: int = 4000) -> PlotData:
    t = np.linspace(0.0, 60.0, n)
    plan = np.column_stack([10 * np.sin(t / 10), 10 * np.cos(t / 10), -5 - 0 * t])
    pos = plan + 0.05 * np.sin(7 * t)[:, None]
    return PlotData(
        title="test: quad, attitude mode", plan_t=t, plan_ned=plan, t=t + 2.0, pos_ned=pos,
        px4_pos_ned=plan[::3] + 0.3,
        waypoints_ned=plan[np.linspace(0, n - 1, 5).astype(int)],
        acceptance_m=(1.0,) * 5,
        t_fly0=2.0, err_t=t + 2.0, err_m=np.linalg.norm(pos - plan, axis=1),
    )


@pytest.fixture
def worker() -> Iterator[PlotWorker]:
    w = PlotWorker(timeout_s=20.0)
    try:
        yield w
    finally:
        proc = w._proc
        w.close()
        assert proc is None or proc.poll() is not None  # reaped


def test_helper_png_equals_in_process_png(worker: PlotWorker, tmp_path: Path) -> None:
    d = _data()
    assert worker.alive
    helper_pid = worker._proc.pid  # type: ignore[union-attr]
    assert helper_pid != os.getpid()
    worker.draw(tmp_path / "helper.png", d)
    worker.draw(tmp_path / "again.png", d)  # the same helper serves several figures
    assert worker.failures == [] and worker.alive
    draw_flight_png(tmp_path / "here.png", d)
    here = (tmp_path / "here.png").read_bytes()
    assert here[:8] == b"\x89PNG\r\n\x1a\n" and len(here) > 10_000
    assert (tmp_path / "helper.png").read_bytes() == here
    assert (tmp_path / "again.png").read_bytes() == here


def test_killed_helper_falls_back_to_drawing_here(worker: PlotWorker, tmp_path: Path) -> None:
    assert worker._proc is not None
    worker._proc.kill()
    worker._proc.wait(10)
    worker.draw(tmp_path / "a.png", _data())
    assert (tmp_path / "a.png").read_bytes()[:4] == b"\x89PNG"
    assert not worker.alive and worker.failures == []  # seen dead before sending: no attempt
    worker.draw(tmp_path / "b.png", _data())  # and stays in-process afterwards
    assert (tmp_path / "b.png").exists()


def test_wedged_helper_times_out_and_is_killed(tmp_path: Path) -> None:
    w = PlotWorker(timeout_s=1.0)
    try:
        assert w._proc is not None
        proc = w._proc
        os.kill(proc.pid, signal.SIGSTOP)  # never reads: the request (> pipe buffer) blocks
        w.draw(tmp_path / "a.png", _data(20_000))
        assert (tmp_path / "a.png").read_bytes()[:4] == b"\x89PNG"
        assert len(w.failures) == 1 and not w.alive
        assert proc.poll() is not None  # killed and reaped, not left stopped
    finally:
        if w._proc is not None:
            os.kill(w._proc.pid, signal.SIGCONT)
        w.close()


def test_error_in_helper_is_reported_and_raised_here(worker: PlotWorker, tmp_path: Path) -> None:
    missing = tmp_path / "no_such_dir" / "a.png"
    with pytest.raises(FileNotFoundError):
        worker.draw(missing, _data())
    assert len(worker.failures) == 1 and "FileNotFoundError" in worker.failures[0]
    assert not worker.alive


def test_close_is_idempotent(tmp_path: Path) -> None:
    w = PlotWorker()
    proc = w._proc
    w.close()
    w.close()
    assert proc is None or proc.poll() is not None
    w.draw(tmp_path / "a.png", _data(100))  # closed: draws here
    assert (tmp_path / "a.png").exists()


def test_per_leg_panel_is_drawn_even_for_legs_never_flown(tmp_path: Path) -> None:
    import dataclasses

    import matplotlib.image as mpimg

    legs = (
        {"from_item": None, "to_item": 1, "max_deviation_m": 0.0, "rms_deviation_m": 0.0,
         "mean_speed_m_s": 1.2, "cruise_speed_m_s": 1.5},
        {"from_item": 1, "to_item": 2, "max_deviation_m": 2.5, "rms_deviation_m": 1.1,
         "mean_speed_m_s": 4.1, "cruise_speed_m_s": 5.0},
        {"from_item": 2, "to_item": 3, "max_deviation_m": None, "rms_deviation_m": None,
         "mean_speed_m_s": None, "cruise_speed_m_s": 5.0},  # never reached
    )
    draw_flight_png(tmp_path / "three.png", _data(500))
    draw_flight_png(tmp_path / "four.png", dataclasses.replace(_data(500), legs=legs))
    three, four = mpimg.imread(tmp_path / "three.png"), mpimg.imread(tmp_path / "four.png")
    assert three.shape[0] == four.shape[0]
    assert four.shape[1] > three.shape[1] * 1.2  # a fourth panel
    # the added strip is not blank: the deviation bars are drawn in red (C3)
    strip = four[:, three.shape[1]:, :3]
    red = (strip[..., 0] > 0.7) & (strip[..., 1] < 0.3) & (strip[..., 2] < 0.3)
    assert red.sum() > 50
