"""Replay campaigns on Dask: a real `dask scheduler` and two `dask worker` processes on loopback
TCP give the same results as a local cluster for the same seed; a worker killed mid-campaign
loses no finished result and the campaign completes; a second start skips the runs on disk;
a run's printed `replay` command re-creates its result."""

from __future__ import annotations

import contextlib
import json
import os
import shlex
import signal
import subprocess
import sys
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from rich.console import Console

from companion.app.campaign import CampaignOptions, run_campaign
from companion.app.cli import main as cli_main
from companion.campaign.perturb import PerturbationRanges
from companion.campaign.runner import RESULTS_FILE, WALL_CLOCK_COLUMNS

ROOT = Path(__file__).resolve().parents[2]
MISSION = str(ROOT / "tests" / "data" / "missions" / "px4_short.plan")
DASK = str(Path(sys.executable).parent / "dask")
START_TIMEOUT_S = 60.0


def _quiet() -> Console:
    return Console(quiet=True)


def _rows(out: Path) -> list[dict[str, Any]]:
    with open(out / RESULTS_FILE, encoding="utf-8") as f:
        return [json.loads(line) for line in f]


def _flight_fields(rows: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """run id -> the row without machine-dependent columns."""
    return {r["run_id"]: {k: v for k, v in r.items() if k not in WALL_CLOCK_COLUMNS}
            for r in rows}


def _stop(proc: subprocess.Popen[bytes]) -> None:
    """Stop a process group started with start_new_session (the nanny and its worker)."""
    if proc.poll() is None:
        try:
            os.killpg(proc.pid, signal.SIGTERM)
            proc.wait(timeout=15)
        except (ProcessLookupError, subprocess.TimeoutExpired):
            pass
    if proc.poll() is None:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=15)


def _read_address(proc: subprocess.Popen[bytes]) -> str:
    """The scheduler's address from its log ("Scheduler at: tcp://..."), bounded in time."""
    found: list[str] = []
    done = threading.Event()

    def reader() -> None:
        assert proc.stderr is not None
        for raw in proc.stderr:
            line = raw.decode(errors="replace")
            if "Scheduler at:" in line and not found:
                found.append(line.split("Scheduler at:")[1].strip())
                done.set()
        done.set()  # EOF: the scheduler exited

    threading.Thread(target=reader, daemon=True).start()
    if not done.wait(START_TIMEOUT_S) or not found:
        raise RuntimeError("dask scheduler did not report its address")
    return found[0]


@dataclass
class Cluster:
    address: str
    workers: list[subprocess.Popen[bytes]]


@pytest.fixture
def cluster() -> Iterator[Cluster]:
    """`dask scheduler` + two single-threaded `dask worker` processes on 127.0.0.1."""
    from distributed import Client

    procs: list[subprocess.Popen[bytes]] = []
    try:
        sched = subprocess.Popen(
            [DASK, "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard"],
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True,
        )
        procs.append(sched)
        address = _read_address(sched)
        workers = []
        for _ in range(2):
            w = subprocess.Popen(
                [DASK, "worker", address, "--host", "127.0.0.1", "--nworkers", "1",
                 "--nthreads", "1", "--no-dashboard"],
                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
            )
            procs.append(w)
            workers.append(w)
        with Client(address, timeout="30s") as client:
            client.wait_for_workers(2, timeout=START_TIMEOUT_S)
        yield Cluster(address, workers)
    finally:
        for p in reversed(procs):
            _stop(p)
        for p in procs:
            if p.stderr is not None:
                p.stderr.close()


def _opts(out: Path, **kw: Any) -> CampaignOptions:
    base: dict[str, Any] = {
        "files": [MISSION], "runs": 3, "seed": 21, "modes": ("attitude", "position"),
        "out": str(out), "require": 0.0, "keep": "failed", "ranges": PerturbationRanges(),
    }
    base.update(kw)
    return CampaignOptions(**base)


@pytest.fixture(scope="module")
def local_result(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("campaign_local")
    assert run_campaign(_opts(out, workers=2), _quiet()) == 0
    return out


def test_external_cluster_gives_the_local_results(cluster: Cluster, local_result: Path,
                                                  tmp_path: Path) -> None:
    out = tmp_path / "remote"
    code = cli_main(["campaign", MISSION, "--runs", "3", "--seed", "21",
                     "--mode", "attitude,position", "--require", "0", "--out", str(out),
                     "--scheduler", cluster.address])
    assert code == 0
    remote = _rows(out)
    assert len(remote) == 6
    assert _flight_fields(remote) == _flight_fields(_rows(local_result))
    # both worker processes flew runs (the scheduler spread the tasks)
    assert len({r["worker"] for r in remote}) == 2
    # the outputs exist and agree with the rows
    import pyarrow.parquet as pq

    table = pq.read_table(out / "runs.parquet").to_pylist()
    assert {r["run_id"] for r in table} == {r["run_id"] for r in remote}
    summary = json.loads((out / "summary.json").read_text())
    assert summary["runs"] == 6
    assert summary["successes"] == sum(r["ok"] for r in remote)
    assert "data:image/png;base64," in (out / "report.html").read_text()


def test_a_killed_worker_loses_no_finished_result(cluster: Cluster, tmp_path: Path) -> None:
    out = tmp_path / "kill"
    seen: list[dict[str, Any]] = []

    def on_result(row: dict[str, Any]) -> None:
        seen.append(row)
        if len(seen) == 1:  # the first result is on disk: kill one worker (nanny and all)
            os.killpg(cluster.workers[0].pid, signal.SIGKILL)

    code = run_campaign(_opts(out, runs=4, modes=("attitude",), scheduler=cluster.address),
                        _quiet(), on_result=on_result)
    assert code == 0
    cluster.workers[0].wait(timeout=15)
    rows = _rows(out)
    assert [r["run_id"] for r in rows] == [r["run_id"] for r in seen]
    assert sorted(r["run_index"] for r in rows) == [0, 1, 2, 3]
    assert rows[0] == seen[0]  # the result stored before the kill is still there, unchanged


def test_resume_skips_the_runs_on_disk(local_result: Path, tmp_path: Path) -> None:
    out = tmp_path / "resume"
    out.mkdir()
    first = _rows(local_result)
    keep = [r for r in first if r["run_index"] < 2]
    # a crash while appending leaves a torn last line: it is ignored, that run flies again
    text = "".join(json.dumps(r) + "\n" for r in keep) + '{"run_id": "torn'
    (out / RESULTS_FILE).write_text(text)
    flown: list[str] = []
    code = run_campaign(_opts(out, workers=1), _quiet(),
                        on_result=lambda r: flown.append(r["run_id"]))
    assert code == 0
    assert sorted(flown) == sorted(r["run_id"] for r in first if r["run_index"] == 2)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["campaign"]["skipped_on_disk"] == len(keep)
    assert summary["runs"] == 6
    # a third start flies nothing; with --require 100 % it fails exactly when a run failed
    flown.clear()
    code = run_campaign(_opts(out, workers=1, require=1.0), _quiet(),
                        on_result=lambda r: flown.append(r["run_id"]))
    assert flown == []
    assert code == (0 if all(r["ok"] for r in first) else 1)


def test_a_runs_replay_command_recreates_its_result(local_result: Path,
                                                    tmp_path: Path) -> None:
    rows = _rows(local_result)
    for mode in ("attitude", "position"):
        row = next(r for r in rows if r["mode"] == mode and r["wind_m_s"] > 0)
        argv = shlex.split(row["command"])[3:]
        out = tmp_path / mode
        code = cli_main([*argv, "--out", str(out)])
        assert code == (0 if row["ok"] else 1)
        rep = json.loads((out / Path(MISSION).stem / "report.json").read_text())
        for key in ("result", "rms_error_m", "max_error_m", "waypoints_reached", "duration_s",
                    "max_tilt_deg", "max_body_rate_rad_s", "max_waypoint_miss_geo_m"):
            assert rep[key] == row[key], key
        assert len(rep["failsafes"]) == row["failsafes"]
