"""flight.png of a replay, drawn from plain arrays, in this process or in a helper process.

Importing matplotlib costs ~0.5 s of CPU and drawing the figure another ~0.5 s. `PlotWorker`
starts a helper process that imports matplotlib while the flight is still being simulated and
then draws each figure it is sent, so a replay does not pay the import, and a run of several
files draws one file's figure while the next one flies. Any failure of the helper (it could not
start, died, timed out, raised) falls back to drawing in this process, so the PNG never depends
on it.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import traceback
from dataclasses import dataclass
from multiprocessing.connection import Connection
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:  # the helper process imports this module: it stays light
    from companion.replay.runner import Draw, FlightPicture

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class PlotData:
    """Everything flight.png shows (NED metres, seconds of simulated time).

    `plan_t` [s] from the start of the planned schedule with the planned positions `plan_ned`
    (N, 3); `t`/`pos_ned` the flown position samples; `px4_pos_ned` the PX4-mission flight, if
    any; `waypoints_ned` (K, 3) with their `acceptance_m`; `t_fly0` the simulated time at which
    the plan started; `err_t`/`err_m` the tracking error series; `legs` the per-leg figures of
    the report (`companion.planning.legs.leg_figures`), drawn in a fourth panel when given.
    """

    title: str
    plan_t: FloatArray
    plan_ned: FloatArray
    t: FloatArray
    pos_ned: FloatArray
    px4_pos_ned: FloatArray | None
    waypoints_ned: FloatArray
    acceptance_m: tuple[float, ...]
    t_fly0: float
    err_t: FloatArray
    err_m: FloatArray
    legs: tuple[dict[str, Any], ...] = ()


def draw_flight_png(path: str | Path, d: PlotData) -> None:
    """Write flight.png: top view and altitude / tracking error vs time, planned vs flown."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle

    fig, ax = plt.subplots(1, 4 if d.legs else 3, figsize=(21 if d.legs else 16, 5.2))
    try:
        plan, pos = d.plan_ned, d.pos_ned
        ax[0].plot(plan[:, 1], plan[:, 0], "--", color="C0", label="planned")
        ax[0].plot(pos[:, 1], pos[:, 0], color="C1", label="flown (companion)")
        if d.px4_pos_ned is not None and len(d.px4_pos_ned):
            p4 = d.px4_pos_ned
            ax[0].plot(p4[:, 1], p4[:, 0], color="C2", alpha=0.7, label="flown (PX4 mission)")
        wps = d.waypoints_ned
        for w, r in zip(wps, d.acceptance_m, strict=True):
            ax[0].add_patch(Circle((w[1], w[0]), r, fill=False, color="C3", lw=0.8))
        ax[0].plot(wps[:, 1], wps[:, 0], "x", color="C3", label="waypoints")
        ax[0].set(xlabel="East [m]", ylabel="North [m]", title="Top view", aspect="equal")
        ax[0].legend(fontsize=8)
        ax[1].plot(d.plan_t + d.t_fly0, -plan[:, 2], "--", label="planned")
        ax[1].plot(d.t, -pos[:, 2], label="flown")
        ax[1].set(xlabel="t [s]", ylabel="altitude above start [m]", title="Altitude")
        ax[1].legend(fontsize=8)
        if len(d.err_t):
            ax[2].plot(d.err_t, d.err_m)
        ax[2].set(xlabel="t [s]", ylabel="|flown - planned| [m]", title="Tracking error")
        if d.legs:
            _draw_legs(ax[3], d.legs)
        fig.suptitle(d.title)
        fig.tight_layout()
        # tight_layout leaves a placeholder layout engine, which makes savefig run a second,
        # non-rendering draw first; the layout is already final: drop it (same pixels, faster)
        fig.set_layout_engine(None)
        fig.savefig(path, dpi=80)
    finally:
        plt.close(fig)


def replay_plot_data(p: FlightPicture) -> PlotData:
    """What flight.png shows for a replay: the plan sampled at 20 Hz, the flown positions and
    the tracking error (all NED, shifted by the flight's `origin`), and the per-leg figures of
    its report, if any."""
    schedule, log, origin = p.schedule, p.log, p.origin
    ts = np.linspace(0.0, schedule.duration_s, max(int(schedule.duration_s * 20), 2))
    te, err = p.tracking_error()
    p4 = None
    if p.px4_log is not None and p.px4_log.pos:
        p4 = np.asarray(p.px4_log.pos, dtype=np.float64).reshape(-1, 3)
    return PlotData(
        title=p.title,
        plan_t=ts,
        plan_ned=schedule.sample(ts) + origin,
        t=np.asarray(log.t, dtype=np.float64),
        pos_ned=np.asarray(log.pos, dtype=np.float64).reshape(-1, 3),
        px4_pos_ned=p4,
        waypoints_ned=schedule.waypoints_ned + origin,
        acceptance_m=tuple(schedule.acceptance_m),
        t_fly0=log.fly_t0 or 0.0,
        err_t=te,
        err_m=err,
        legs=tuple(p.legs or ()),
    )


def replay_drawer(plotter: PlotWorker | None = None) -> Draw:
    """A replay's `draw` (`companion.replay.runner.replay_file`): flight.png drawn by
    `plotter`'s helper process, or in this process when None."""

    def draw(path: Path, picture: FlightPicture) -> None:
        data = replay_plot_data(picture)
        if plotter is not None:
            plotter.draw(path, data)
        else:
            draw_flight_png(path, data)

    return draw


def _leg_tick(leg: dict[str, Any], k: int) -> str:
    a, b = leg.get("from_item"), leg.get("to_item")
    if a is None and b is None:
        return str(k)
    return f"{'-' if a is None else a}>{'-' if b is None else b}"


def _draw_legs(ax: Any, legs: tuple[dict[str, Any], ...]) -> None:
    """Per leg (x: from>to mission items): max and RMS deviation from the straight leg (bars,
    left axis); flown mean speed and planned cruise speed (markers, right axis)."""
    x = np.arange(len(legs))

    def col(key: str) -> FloatArray:
        return np.array([np.nan if g.get(key) is None else float(g[key]) for g in legs])

    dev, speeds = col("max_deviation_m"), np.concatenate([col("mean_speed_m_s"),
                                                          col("cruise_speed_m_s")])
    ax.bar(x - 0.2, dev, 0.4, color="C3", label="max deviation")
    ax.bar(x + 0.2, col("rms_deviation_m"), 0.4, color="C1", label="RMS deviation")
    ax.set(xlabel="leg (mission items)", ylabel="distance to the straight leg [m]",
           title="Per leg")
    ax.set_xticks(x, [_leg_tick(g, k) for k, g in enumerate(legs)], rotation=60, fontsize=7)
    sp = ax.twinx()
    sp.plot(x, col("mean_speed_m_s"), "o", color="C0", ms=4, label="flown mean speed")
    sp.plot(x, col("cruise_speed_m_s"), "_", color="k", ms=10, label="planned cruise speed")
    sp.set_ylabel("speed [m/s]")
    # head room above the data for the legend
    if np.isfinite(dev).any():
        ax.set_ylim(0.0, max(float(np.nanmax(dev)), 0.1) * 1.5)
    if np.isfinite(speeds).any():
        sp.set_ylim(0.0, max(float(np.nanmax(speeds)), 0.1) * 1.5)
    h1, l1 = ax.get_legend_handles_labels()
    h2, l2 = sp.get_legend_handles_labels()
    ax.legend(h1 + h2, l1 + l2, fontsize=7, loc="upper center", ncol=2)


def _serve(rx: Connection, tx: Connection) -> None:
    """Helper process: import matplotlib now, then draw each (path, PlotData) received on `rx`
    and answer None or the error text on `tx`; stop when the parent's end closes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot  # the import is the point: done before any request arrives

    while True:
        try:
            req = rx.recv()
        except (EOFError, OSError):
            return
        path, data = req
        try:
            draw_flight_png(path, data)
            tx.send(None)
        except Exception:
            tx.send(traceback.format_exc())


def _main() -> None:
    """The helper process's entry point. Requests come on stdin; answers go out on the pipe
    that was stdout, and fd 1 itself is pointed at stderr so that nothing printed, from Python
    or from C, can corrupt the answers."""
    reply = Connection(os.dup(1), readable=False)
    os.dup2(2, 1)
    _serve(Connection(0, writable=False), reply)


def _send(conn: Connection, obj: object, result: list[BaseException | None]) -> None:
    try:
        conn.send(obj)
        result.append(None)
    except BaseException as exc:  # reported to the caller's thread
        result.append(exc)


class PlotWorker:
    """A helper process that draws flight.png files (see the module docstring).

    Use as a context manager around one or several replays; `draw` blocks until the PNG is
    written (by the helper, or here if the helper fails). `timeout_s` bounds one drawing.
    """

    def __init__(self, timeout_s: float = 120.0) -> None:
        self.timeout_s = timeout_s
        self.failures: list[str] = []  # why the helper was not used, for diagnostics
        self._conn: Connection | None = None  # requests out
        self._reply: Connection | None = None  # answers in
        self._proc: subprocess.Popen[bytes] | None = None
        if os.name != "posix":
            self.failures.append("plot process needs POSIX pipes: drawing in this process")
            return
        # a fresh interpreter running this module (not multiprocessing's spawn, which would
        # re-import the caller's __main__ script), with this package importable
        pkg_root = str(Path(__file__).resolve().parents[2])
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(
            p for p in (pkg_root, env.get("PYTHONPATH", "")) if p)
        try:
            proc = subprocess.Popen(
                [sys.executable, "-c", "from companion.app.plotting import _main; _main()"],
                stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                env=env, close_fds=True,
            )
        except OSError as exc:
            self.failures.append(f"could not start the plot process: {exc}")
            return
        assert proc.stdin is not None and proc.stdout is not None
        self._conn = Connection(os.dup(proc.stdin.fileno()), readable=False)
        self._reply = Connection(os.dup(proc.stdout.fileno()), writable=False)
        proc.stdin.close()
        proc.stdout.close()
        self._proc = proc

    @property
    def alive(self) -> bool:
        """True while the helper process is up and usable."""
        return self._conn is not None and self._proc is not None and self._proc.poll() is None

    def draw(self, path: str | Path, data: PlotData) -> None:
        """Write the PNG for `data` at `path` (helper process, else in this process)."""
        if self.alive:
            assert self._conn is not None and self._reply is not None
            # sent from a thread: a request larger than the pipe buffer blocks until the
            # helper reads it, and a helper that never does must not hang the replay
            sent: list[BaseException | None] = []
            sender = threading.Thread(
                target=_send, args=(self._conn, (str(path), data), sent), daemon=True)
            sender.start()
            sender.join(self.timeout_s)
            try:
                if not sent:
                    self.failures.append("plot process did not take the request")
                elif sent[0] is not None:
                    self.failures.append(f"could not send to the plot process: {sent[0]!r}")
                elif self._reply.poll(self.timeout_s):
                    err = self._reply.recv()
                    if err is None:
                        return
                    self.failures.append(f"plot process failed: {err}")
                else:
                    self.failures.append(f"plot process timed out after {self.timeout_s:g} s")
            except (EOFError, OSError) as exc:
                self.failures.append(f"plot process lost: {exc!r}")
            # a helper that failed once is not trusted again; killing it first breaks the
            # pipe, so a send still blocked in the thread returns before the pipe is closed
            if self._proc is not None:
                self._proc.kill()
            sender.join(5.0)
            self._stop(kill=True)
        draw_flight_png(path, data)

    def close(self) -> None:
        """Stop the helper (idempotent). It holds nothing unfinished between `draw` calls, so it
        is terminated rather than waited for (it may still be importing matplotlib)."""
        self._stop(kill=False)

    def _stop(self, kill: bool) -> None:
        conn, reply, proc = self._conn, self._reply, self._proc
        self._conn = self._reply = self._proc = None
        if proc is not None:
            if kill:
                proc.kill()
            else:
                proc.terminate()
        for c in (conn, reply):
            if c is not None:
                c.close()
        if proc is not None:
            try:
                proc.wait(5.0)
            except subprocess.TimeoutExpired:  # pragma: no cover - SIGTERM ignored
                proc.kill()
                proc.wait(5.0)

    def __enter__(self) -> PlotWorker:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
