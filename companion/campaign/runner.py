"""Campaign execution: one Dask task per replayed flight, results kept on disk as they arrive.

A task carries everything a worker needs (the mission file's bytes, the mode, the sampled
perturbation), so workers on other machines need no shared filesystem. The client appends
each result to `runs.jsonl` (flushed and fsynced) the moment it arrives; a campaign started
again over the same folder skips every run whose replay command is already there. A worker
that dies takes only its unfinished runs with it: Dask re-runs them elsewhere (replays are
deterministic, so a re-run gives the same result).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import math
import os
import shlex
import tempfile
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, cast

from companion.campaign.perturb import Perturbation, PerturbationRanges, sample

if TYPE_CHECKING:
    from companion.flight.report import FlightReport
    from companion.replay.config import Mode
    from companion.replay.runner import PreparedMission, ReplayConfig, ReplayRun

Keep = Literal["all", "failed", "none"]
RESULTS_FILE = "runs.jsonl"
TLOG_DIR = "tlogs"
#: Columns that depend on the machine, not on the flight (left out when comparing runs).
WALL_CLOCK_COLUMNS = ("wall_s", "real_time_factor", "worker", "task_s")

#: Dask settings of the local cluster's workers (for `dask worker` processes of your own:
#: DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED=False in their environment).
NO_PROFILER = {"distributed.worker.profile.enabled": False}

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RunTask:
    """One replay of a campaign, self-contained (picklable, sent to a worker)."""

    run_id: str
    file: str
    mission_bytes: bytes
    suffix: str
    mode: str
    run_index: int
    rate_hz: float
    perturbation: Perturbation
    keep: Keep
    command: str


@dataclass(frozen=True)
class RunOutcome:
    """What a worker sends back: the result row and the tlog bytes if they are to be kept."""

    row: dict[str, Any]
    tlog: bytes | None


def replay_command(file: str, mode: str, rate_hz: float, p: Perturbation) -> str:
    """The `python -m companion replay` command that re-creates one campaign run."""
    args = ["python", "-m", "companion", "replay", file]
    args += ["--onboard"] if mode == ONBOARD else ["--mode", mode]
    if rate_hz != 100.0:
        args += ["--rate", repr(rate_hz)]
    return shlex.join([*args, *p.replay_args()])


def make_tasks(
    files: Sequence[str],
    modes: Sequence[str],
    runs: int,
    seed: int,
    ranges: PerturbationRanges,
    *,
    rate_hz: float = 100.0,
    keep: Keep = "failed",
) -> list[RunTask]:
    """Every run of the campaign: run i of every file and mode flies perturbation i."""
    perts = [sample(ranges, seed, i) for i in range(runs)]
    tasks = []
    for f in files:
        data = Path(f).read_bytes()
        for mode in modes:
            for i, p in enumerate(perts):
                tasks.append(RunTask(
                    run_id=f"{f}|{mode}|{i}", file=f, mission_bytes=data,
                    suffix=Path(f).suffix, mode=mode, run_index=i, rate_hz=rate_hz,
                    perturbation=p, keep=keep, command=replay_command(f, mode, rate_hz, p),
                ))
    return tasks


def _mission_path(data: bytes, suffix: str) -> Path:
    """The mission's bytes as a file in this machine's temp folder (one per content)."""
    d = Path(tempfile.gettempdir()) / "ecca-campaign-missions"
    d.mkdir(parents=True, exist_ok=True)
    path = d / f"{hashlib.sha256(data).hexdigest()[:24]}{suffix}"
    if not path.exists():
        fd, tmp = tempfile.mkstemp(dir=d)
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    return path


def execute_run(task: RunTask) -> RunOutcome:
    """Fly one run (on a worker); never raises for a flight problem (it becomes the result)."""
    import socket
    import time

    t0 = time.perf_counter()
    from companion.replay.runner import prepare_mission

    config = task.perturbation.replay_config(base_config(task.mode, task.rate_hz))
    tlog_bytes = None
    with tempfile.TemporaryDirectory(prefix="ecca-run-") as tmp:
        tlog_path = Path(tmp) / "flight.tlog"
        try:
            # (no time-optimal bounds: the results table does not report them)
            prep = prepare_mission(_mission_path(task.mission_bytes, task.suffix), config,
                                   bounds=False)
            # --keep failed: fly without a tlog (writing one costs 10-30 %) and fly a failed
            # run again with one; the replay is deterministic, so it is the same flight
            with_tlog = task.keep == "all"
            run = _fly(prep, config, tlog_path if with_tlog else None)
            if task.keep == "failed" and not run.ok:
                again = _fly(prep, config, tlog_path)
                if _flight_metrics(again.report) != _flight_metrics(run.report):
                    log.warning("run %s: the re-flight for its tlog differs", task.run_id)
                run, with_tlog = again, True
            row = _row(task, run.report, run.ok)
            if with_tlog:
                tlog_bytes = tlog_path.read_bytes()
        except Exception as exc:  # a bug or a bad file: recorded as this run's failure
            log.exception("campaign run %s failed", task.run_id)
            row = _row(task, None, False, error=f"{type(exc).__name__}: {exc}")
    row["worker"] = socket.gethostname() + f":{os.getpid()}"
    row["task_s"] = round(time.perf_counter() - t0, 4)  # the whole task on the worker, wall
    return RunOutcome(row, tlog_bytes)


#: The campaign's mode in which the onboard module flies (the streamed ones: setpoint modes).
ONBOARD = "onboard"


def base_config(mode: str, rate_hz: float) -> ReplayConfig:
    """A run's configuration before its perturbation: a quad, streaming setpoints in `mode`
    at `rate_hz`, or ONBOARD: the mock's onboard module flies (attitude law, no stream)."""
    from companion.replay.runner import ReplayConfig

    if mode == ONBOARD:
        return ReplayConfig(vehicle="quad", mode="attitude", rate_hz=rate_hz, onboard=True)
    if mode not in ("position", "attitude", "rates"):
        raise ValueError(f"mode must be position, attitude, rates or {ONBOARD}, got {mode!r}")
    return ReplayConfig(vehicle="quad", mode=cast("Mode", mode), rate_hz=rate_hz)


def _fly(prep: PreparedMission, config: ReplayConfig, tlog_path: Path | None) -> ReplayRun:
    from companion.aio.tlog import TlogWriter
    from companion.replay.runner import run_prepared

    if tlog_path is None:
        return run_prepared(prep, config, None)
    with TlogWriter(tlog_path, buffer_bytes=1 << 20) as tlog:
        return run_prepared(prep, config, tlog)


def _flight_metrics(rep: FlightReport) -> dict[str, Any]:
    return {k: v for k, v in rep.to_dict().items()
            if k not in ("wall_s", "real_time_factor", "tlog_frames")}


def _row(task: RunTask, rep: FlightReport | None, ok: bool, error: str = "") -> dict[str, Any]:
    """One flat row of the results table (keys carry units)."""
    row: dict[str, Any] = {
        "run_id": task.run_id,
        "file": task.file,
        "mission": Path(task.file).stem,
        "mode": task.mode,
        "run_index": task.run_index,
    }
    row.update(task.perturbation.as_row())
    if rep is None:
        row.update({"result": f"error: {error}", "ok": False})
        for k in _METRICS:
            row[k] = None
    else:
        wps = rep.waypoints
        margins = [w.acceptance_radius_m - _approach(w.closest_approach_m) for w in wps]
        row.update({
            "result": rep.result,
            "ok": bool(ok),
            "rms_error_m": rep.rms_error_m,
            "max_error_m": rep.max_error_m,
            "waypoints_reached": int(rep.waypoints_reached),
            "waypoints_total": len(wps),
            "min_waypoint_margin_m": _finite(min(margins)) if margins else None,
            "max_tilt_deg": rep.max_tilt_deg,
            "max_thrust_norm": rep.max_thrust_norm,
            "max_body_rate_rad_s": rep.max_body_rate_rad_s,
            "max_speed_m_s": rep.max_speed_m_s,
            "duration_s": rep.duration_s,
            "planned_duration_s": rep.planned_duration_s,
            "geofence_violations": int(rep.geofence_violations or 0),
            "failsafes": len(rep.failsafes),
            "max_waypoint_miss_geo_m": rep.max_waypoint_miss_geo_m,
            "simulated_s": rep.simulated_s,
            "wall_s": rep.wall_s,
            "real_time_factor": rep.real_time_factor,
        })
        est = rep.estimates
        row.update({  # the tracking law's own estimates (None: position mode)
            "est_wind_m_s": None if est is None else est.wind_m_s,
            "est_wind_from_deg": None if est is None else est.wind_from_deg,
            "est_mass_ratio": None if est is None else est.mass_ratio,
            "slowed_s": None if est is None else est.slowed_s,
        })
    row["command"] = task.command
    row["tlog"] = None
    return row


def _approach(c: float | None) -> float:
    """A waypoint's closest approach [m] (None: never approached, inf)."""
    return math.inf if c is None else c


def _finite(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


_METRICS = (
    "rms_error_m", "max_error_m", "waypoints_reached", "waypoints_total",
    "min_waypoint_margin_m", "max_tilt_deg", "max_thrust_norm", "max_body_rate_rad_s",
    "max_speed_m_s", "duration_s", "planned_duration_s", "geofence_violations", "failsafes",
    "max_waypoint_miss_geo_m", "simulated_s", "wall_s", "real_time_factor", "est_wind_m_s",
    "est_wind_from_deg", "est_mass_ratio", "slowed_s",
)


# ----------------------------------------------------------------------------- results on disk


class ResultStore:
    """`runs.jsonl` in the campaign folder: one finished run per line, appended and fsynced."""

    def __init__(self, out_dir: Path) -> None:
        self.out_dir = out_dir
        self.path = out_dir / RESULTS_FILE
        out_dir.mkdir(parents=True, exist_ok=True)
        self._repair()

    def _repair(self) -> None:
        """Cut a line left incomplete by a crash mid-append, so the next row starts a line."""
        if not self.path.exists():
            return
        data = self.path.read_bytes()
        if data and not data.endswith(b"\n"):
            with open(self.path, "r+b") as f:
                f.truncate(data.rfind(b"\n") + 1)

    def load(self) -> list[dict[str, Any]]:
        """Every complete row on disk (a line cut short by a crash is ignored)."""
        rows = []
        if self.path.exists():
            with open(self.path, encoding="utf-8") as f:
                for line in f:
                    with contextlib.suppress(json.JSONDecodeError):
                        rows.append(json.loads(line))
        return rows

    def append(self, outcome: RunOutcome) -> dict[str, Any]:
        """Store one result (and its tlog); returns the row as stored."""
        row = dict(outcome.row)
        if outcome.tlog is not None:
            d = self.out_dir / TLOG_DIR
            d.mkdir(exist_ok=True)
            name = f"{row['mission']}_{row['mode']}_{row['run_index']:05d}.tlog"
            tmp = d / f".{name}.tmp"
            tmp.write_bytes(outcome.tlog)
            os.replace(tmp, d / name)
            row["tlog"] = f"{TLOG_DIR}/{name}"
        with open(self.path, "a", encoding="utf-8") as f:
            f.write(json.dumps(row, allow_nan=False) + "\n")
            f.flush()
            os.fsync(f.fileno())
        return row


# ----------------------------------------------------------------------------- on Dask


@dataclass
class CampaignProgress:
    """Counters the caller's progress display reads."""

    total: int = 0
    skipped: int = 0
    done: int = 0
    failed: int = 0
    lost: int = 0
    lost_ids: list[str] = field(default_factory=list)


@contextlib.contextmanager
def dask_client(scheduler: str | None, n_workers: int | None = None) -> Iterator[Any]:
    """A client of the cluster at `scheduler` (tcp://HOST:PORT), or of a local cluster of
    `n_workers` single-threaded worker processes (default: one per core)."""
    import dask
    from distributed import Client, LocalCluster

    logging.getLogger("distributed").setLevel(logging.WARNING)  # its import set INFO
    if scheduler is not None:
        with Client(scheduler, timeout="30s") as client:  # type: ignore[no-untyped-call]
            yield client
        return
    n = n_workers or os.cpu_count() or 1
    # the worker's statistical profiler samples the task thread's stack every 10 ms; on a
    # pure-Python replay that costs 10-30 % (measured), and campaigns never look at it
    with dask.config.set(NO_PROFILER):
        cluster = LocalCluster(  # type: ignore[no-untyped-call]
            n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None,
            silence_logs=logging.WARNING,
        )
    with cluster, Client(cluster) as client:  # type: ignore[no-untyped-call]
        yield client


def run_tasks(
    client: Any,
    tasks: Sequence[RunTask],
    store: ResultStore,
    progress: CampaignProgress,
    on_result: Callable[[dict[str, Any]], None] | None = None,
) -> list[dict[str, Any]]:
    """Run the tasks not yet in `store` on `client`; returns every stored row of `tasks`.

    Results are stored as they finish (in completion order). A task lost with its worker
    more often than the scheduler allows (`distributed.scheduler.allowed-failures`) is
    counted in `progress.lost` and left for the next start to pick up."""
    from distributed import as_completed

    done_cmds = {r["command"]: r for r in store.load()}
    todo = [t for t in tasks if t.command not in done_cmds]
    progress.total = len(tasks)
    progress.skipped = len(tasks) - len(todo)
    progress.failed = sum(1 for t in tasks if t.command in done_cmds
                          and not done_cmds[t.command]["ok"])
    futures = [
        client.submit(execute_run, t, key=f"ecca-run-{_digest(t.command)}", pure=False)
        for t in todo
    ]
    for fut in as_completed(futures):  # type: ignore[no-untyped-call]
        try:
            outcome = fut.result()
        except Exception as exc:  # KilledWorker, a cancelled task: not a flight result
            progress.lost += 1
            progress.lost_ids.append(str(fut.key))
            log.warning("campaign task %s lost: %s", fut.key, exc)
            continue
        finally:
            fut.release()
        row = store.append(outcome)
        done_cmds[row["command"]] = row
        progress.done += 1
        if not row["ok"]:
            progress.failed += 1
        if on_result is not None:
            on_result(row)
    return [done_cmds[t.command] for t in tasks if t.command in done_cmds]


def _digest(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()[:20]


__all__ = [
    "CampaignProgress",
    "Keep",
    "ResultStore",
    "RunOutcome",
    "RunTask",
    "dask_client",
    "execute_run",
    "make_tasks",
    "replay_command",
    "run_tasks",
]
