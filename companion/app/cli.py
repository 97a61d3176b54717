"""Command line: `python -m companion COMMAND ...`.

Exit codes: 0 success, 1 flight/runtime failure (vehicle refused, link lost, limit exceeded),
2 bad input (unreadable or invalid file, bad option) or an extra the command needs is not
installed (the message names it), 3 no vehicle heard within the connect timeout (`fly
--connect`, `status`), 130 interrupted by the user.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import math
import sys
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rich.console import Console
from rich.markup import escape
from rich.table import Table

from companion.app.campaign import add_campaign_parser
from companion.app.extras import MissingExtraError, available, install_line, require
from companion.app.link_options import add_signing_option
from companion.app.paths import output_file, output_folder
from companion.app.replay_options import add_perturbation_options, mock_param

if TYPE_CHECKING:
    from companion.flight.report import FlightReport
    from companion.replay.runner import ReplayConfig

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_BAD_INPUT = 2
EXIT_NO_VEHICLE = 3
EXIT_INTERRUPTED = 130

console = Console(stderr=False, width=None if sys.stdout.isatty() else 110)
err_console = Console(stderr=True)


def print_error(label: str, message: object, style: str = "red") -> None:
    """`label: message` on stderr; the message is shown as written (square brackets included,
    not read as console markup)."""
    err_console.print(f"[{style}]{label}:[/{style}] {escape(str(message))}", soft_wrap=True)


@contextlib.contextmanager
def _quiet_mission_log() -> Iterator[None]:
    """Silence the mission loader/planner warnings (for a second pass over the same file)."""
    logger = logging.getLogger("companion.mission")
    old = logger.disabled
    logger.disabled = True
    try:
        yield
    finally:
        logger.disabled = old


def _cmd_demo(args: argparse.Namespace) -> int:
    require("plot", "demo")  # the plot is what the demo makes: fail before the work
    from companion.app.demo import run_demo, save_plot

    result = run_demo(rate_hz=args.rate)
    traj = result.trajectory
    console.print(
        f"[bold]Planned[/bold] {traj.num_segments} minimum-snap segments, "
        f"duration {traj.duration:.2f} s, limits {'met' if result.limits_ok else 'EXCEEDED'}"
    )
    table = Table(
        title=f"Flatness setpoints (every {args.every}th sample at {args.rate:g} Hz; "
        "t s, NED m, roll/pitch/yaw deg, thrust 0..1, p/q/r rad/s)"
    )
    for col in ("t", "N", "E", "D", "roll", "pitch", "yaw", "thrust", "p", "q", "r"):
        table.add_column(col, justify="right")
    for i in range(0, len(result.t_s), args.every):
        p = result.pos_ned[i]
        e = result.euler_deg[i]
        w = result.omega_frd[i]
        table.add_row(
            f"{result.t_s[i]:.2f}", *(f"{v:.2f}" for v in p), *(f"{v:.1f}" for v in e),
            f"{result.thrust_norm[i]:.3f}", *(f"{v:.3f}" for v in w),
        )
    console.print(table)
    out = Path(args.out)
    save_plot(result, out / "demo.png")
    console.print(f"Plot written to [bold]{escape(str(out / 'demo.png'))}[/bold]")
    return EXIT_OK if result.limits_ok else EXIT_FAILURE


def _replay_one(
    path: str, out: str, config: ReplayConfig, queue: Any, plot: bool = True
) -> tuple[str, FlightReport | None, str | None]:
    """Worker: replay one file (with flight.png if `plot`); returns (path, report or None,
    error message or None)."""
    from companion.app.plotting import replay_drawer
    from companion.mission import MissionError
    from companion.replay.runner import replay_file

    def progress(t: float, expected: float) -> None:
        if queue is not None:
            queue.put((path, t, expected))

    try:
        result = replay_file(path, out, config, progress, replay_drawer() if plot else None)
    except (MissionError, ValueError, OSError) as exc:
        return path, None, str(exc)
    return path, result.report, None


def _cmd_replay(args: argparse.Namespace) -> int:
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from companion.app.replay_options import replay_config_kwargs
    from companion.mission import load_mission, mission_to_flight_plan
    from companion.replay.runner import ReplayConfig

    # validates the options before any work
    config = ReplayConfig(**replay_config_kwargs(args),
                          compare_px4_mission=args.compare_px4_mission)
    plot = not args.no_plot
    if plot and not available("plot"):
        plot = False  # the flight still runs: tlog and report.json are written
        print_error("note", f"no flight.png: the plot needs the [plot] extra "
                    f"({install_line('plot')}); --no-plot skips it", style="yellow")
    # size the progress bars with the nominal mission durations (bad files fail later, cleanly,
    # and warnings are shown then: this pass is silent)
    totals: dict[str, float] = {}
    for f in args.files:
        try:
            with _quiet_mission_log():
                fp = mission_to_flight_plan(load_mission(f), vehicle=args.vehicle)
            totals[f] = fp.nominal_duration_s() + 30.0
        except Exception:
            totals[f] = 1.0
    results: dict[str, tuple[FlightReport | None, str | None]] = {}
    with Progress(
        TextColumn("{task.description}"), BarColumn(), TextColumn("{task.fields[sim]}"),
        TimeElapsedColumn(), console=console, transient=False,
    ) as progress:
        tasks = {
            f: progress.add_task(escape(Path(f).name), total=totals[f], sim="")
            for f in args.files
        }
        if args.jobs <= 1:
            from companion.app.plotting import PlotWorker, replay_drawer
            from companion.mission import MissionError
            from companion.replay.runner import replay_file

            # a helper process draws the flight.png files; it imports matplotlib while the
            # first file flies, which the replay would otherwise wait for
            with PlotWorker() if plot else contextlib.nullcontext() as plotter:
                for f in args.files:
                    def cb(t: float, expected: float, f: str = f) -> None:
                        totals[f] = expected
                        progress.update(tasks[f], completed=t, total=expected,
                                        sim=f"sim {t:6.0f} s")

                    try:
                        r = replay_file(
                            f, args.out, config, cb, replay_drawer(plotter) if plot else None,
                        )
                        results[f] = (r.report, None)
                    except (MissionError, ValueError, OSError) as exc:
                        results[f] = (None, str(exc))
                    progress.update(tasks[f], completed=totals[f], total=totals[f])
        else:
            with mp.Manager() as manager, ProcessPoolExecutor(max_workers=args.jobs) as pool:
                queue = manager.Queue()
                futures = [pool.submit(_replay_one, f, args.out, config, queue, plot)
                           for f in args.files]
                pending = set(futures)
                while pending:
                    while not queue.empty():
                        f, t, expected = queue.get()
                        totals[f] = expected
                        progress.update(tasks[f], completed=t, total=expected,
                                        sim=f"sim {t:6.0f} s")
                    done = {fu for fu in pending if fu.done()}
                    for fu in done:
                        f, rep, err = fu.result()
                        results[f] = (rep, err)
                        progress.update(tasks[f], completed=totals[f], total=totals[f])
                    pending -= done
                    if pending:
                        import time

                        time.sleep(0.1)  # UI refresh period, not synchronisation
    mode_label = ("velocity + yaw-rate" if args.vehicle == "rover" else
                  "onboard module" if args.onboard else f"{args.mode} mode")
    table = Table(title=escape(f"Replay summary ({args.vehicle}, {mode_label}); outputs in "
                               f"{args.out}"))
    # file names are never cut: they wrap (fold) in their own column
    widest = max([len(Path(f).name) for f in args.files] + [len(_PX4_ROW)])
    table.add_column("file", overflow="fold", min_width=min(40, widest))
    # two-line headers keep the table within 80-110 columns: wider tables get cut off
    for col in ("result", "duration\ns", "RMS err\nm", "max err\nm", "waypoints",
                "max tilt\ndeg", "x real\ntime"):
        table.add_column(col)
    exit_code = EXIT_OK
    errors: list[str] = []
    for f in args.files:
        rep, err = results[f]
        if rep is None:
            table.add_row(escape(Path(f).name), "[red]error (below)[/red]", "", "", "", "", "",
                          "")
            errors.append(str(err))
            exit_code = EXIT_BAD_INPUT
            continue
        ok, verdict = _verdict(rep)
        if not ok and exit_code == EXIT_OK:
            exit_code = EXIT_FAILURE
        rms = rep.rms_error_m
        mx = rep.max_error_m
        table.add_row(
            escape(Path(f).name),
            "[green]ok[/green]" if ok else f"[yellow]{escape(verdict)}[/yellow]",
            f"{rep.duration_s:.1f}",
            "-" if rms is None else f"{rms:.2f}",
            "-" if mx is None else f"{mx:.2f}",
            f"{rep.waypoints_reached}/{len(rep.waypoints)}",
            f"{rep.max_tilt_deg:.1f}",
            f"{rep.real_time_factor}",
        )
        px4 = rep.px4_mission
        if px4 is not None:
            px4_ok, px4_verdict = _verdict(px4)
            if not px4_ok and exit_code == EXIT_OK:
                exit_code = EXIT_FAILURE
            table.add_row(
                _PX4_ROW,
                "ok" if px4_ok else f"[yellow]{escape(px4_verdict)}[/yellow]",
                f"{px4.duration_s:.1f}", "-", "-",
                f"{px4.waypoints_reached}/{len(px4.waypoints)}",
                f"{px4.max_tilt_deg:.1f}", "",
            )
    console.print(table)
    _print_leg_lines(args.files, results)
    for err in errors:
        print_error("error", err)
    return exit_code


def _print_leg_lines(
    files: Sequence[str], results: dict[str, tuple[FlightReport | None, str | None]]
) -> None:
    """Below the summary table: per file, the worst leg (path deviation, speeds, time vs the
    bound) and every geofence breach (per-leg detail is in report.json)."""
    from companion.planning.legs import worst_leg_text

    for f in files:
        rep = results[f][0]
        if rep is None:
            continue
        name = escape(Path(f).name)
        legs = rep.legs
        if legs:
            bound = rep.bound_s
            planned = (f"planned {rep.planned_duration_s:.1f} s (bound "
                       f"{'-' if bound is None else format(bound, '.1f')} s); ")
            console.print(f"{name}: {planned}{escape(worst_leg_text(legs))}", soft_wrap=True)
        if rep.geofence_breaches is not None:
            for b in rep.geofence_breaches:
                console.print(f"[red]{name}: geofence breach in flight:[/red] "
                              f"{escape(str(b['message']))}", soft_wrap=True)


_PX4_ROW = "  (PX4 AUTO.MISSION)"


def _verdict(rep: FlightReport) -> tuple[bool, str]:
    """(flown completely, what went wrong) of a replay report (or its PX4 mission part)."""
    missed = len(rep.waypoints) - rep.waypoints_reached
    if rep.result != "ok":
        return False, rep.result
    return missed == 0, f"missed {missed} waypoint(s)"


def _cmd_fly(args: argparse.Namespace) -> int:
    import asyncio

    from companion.app.fly import FlyOptions, fly

    opts = FlyOptions(
        target=args.target, connect=args.connect, mode=args.mode, rate_hz=args.rate,
        vehicle_file=args.vehicle_file, log=args.log, size_m=args.size, speed_m_s=args.speed,
        alt_m=args.alt, laps=args.laps, mock_params=tuple(args.mock_param),
        busy_wait=args.busy_wait, sender_cpu=args.sender_cpu, target_system=args.target_system,
        signing_key=args.signing_key, connect_timeout_s=args.timeout, wind=args.wind,
    )
    if args.onboard:
        from companion.app.fly_onboard import fly_onboard

        return _run_vehicle_command(lambda: asyncio.run(fly_onboard(opts, console)))
    return _run_vehicle_command(lambda: asyncio.run(fly(opts, console)))


def _cmd_status(args: argparse.Namespace) -> int:
    import asyncio

    from companion.app.fly import status

    return _run_vehicle_command(
        lambda: asyncio.run(status(args.connect, console, timeout_s=args.timeout,
                                   target_system=args.target_system,
                                   signing_key=args.signing_key)), "status failed")


def _cmd_serve(args: argparse.Namespace) -> int:
    import asyncio

    from companion.serve.runner import ServeOptions, serve

    opts = ServeOptions(
        connect=args.connect, mode=args.mode, rate_hz=args.rate, vehicle_file=args.vehicle_file,
        log_dir=args.log_dir, target_system=args.target_system,
        tlog_max_bytes=int(args.tlog_max_mb * 1024 * 1024), tlog_keep=args.tlog_keep,
        signing_key=args.signing_key, onboard=args.onboard,
    )
    return _run_vehicle_command(lambda: asyncio.run(serve(opts, console)))


def _run_vehicle_command(run: Callable[[], int], label: str = "flight failed") -> int:
    """Map vehicle-side failures to a pilot-readable message: exit code 3 when no vehicle was
    heard within the connect timeout, 1 for any other failure (``label`` leads its message)."""
    from companion.aio import ConnectTimeoutError, VehicleError
    from companion.aio.transports import TransportError

    try:
        return run()
    except ConnectTimeoutError as exc:
        print_error("error", exc)
        return EXIT_NO_VEHICLE
    except (VehicleError, TransportError, TimeoutError) as exc:
        result = getattr(exc, "result", None)
        extra = f" (MAVLink result {result})" if result is not None else ""
        print_error(label, f"{exc}{extra}")
        return EXIT_FAILURE


def _timeout_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--timeout", type=_positive_float, default=10.0, metavar="SECONDS",
                   help="give up (exit 3) if no vehicle HEARTBEAT is heard within this "
                   "(default 10)")


def _target_system_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--target-system", type=_system_id, default=1, metavar="ID",
                   help="the autopilot's MAVLink system id, PX4's MAV_SYS_ID (default 1)")


def _system_id(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        v = 0
    if not 1 <= v <= 255:
        raise argparse.ArgumentTypeError(f"a MAVLink system id is 1-255, got {text!r}")
    return v


def _positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        v = 0
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 1, got {text!r}")
    return v


def _positive_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        v = float("nan")
    if not (v > 0 and v < float("inf")):
        raise argparse.ArgumentTypeError(f"expected a number > 0, got {text!r}")
    return v


def _wind(text: str) -> tuple[float, float]:
    """SPEED@FROM: wind speed [m/s] and the compass direction it blows from [deg]."""
    speed, sep, frm = text.partition("@")
    try:
        s, f = float(speed), float(frm) if sep else math.nan
    except ValueError:
        s = f = math.nan
    if not (math.isfinite(s) and s >= 0.0 and math.isfinite(f)):
        raise argparse.ArgumentTypeError(
            f"expected SPEED@FROM (m/s @ compass deg it blows from, e.g. 6@270), got {text!r}")
    return (s, f % 360.0)


def _altitude(text: str) -> float:
    v = _positive_float(text)
    if not v > 0.5:
        raise argparse.ArgumentTypeError(f"the altitude must be above 0.5 m, got {text!r}")
    return v


def _connect_url(text: str) -> str:
    from companion.aio.transports import parse_url

    try:
        parse_url(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of `python -m companion`."""
    parser = argparse.ArgumentParser(
        prog="python -m companion",
        description="ecca-offboard: plan trajectories and fly them with PX4 offboard control.",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", required=True)

    demo = sub.add_parser("demo", help="plan a trajectory offline, print setpoints, save a plot")
    demo.add_argument("--out", default="demo_out", type=output_folder,
                      help="output folder (default demo_out)")
    demo.add_argument("--rate", type=float, default=50.0, help="sample rate [Hz] (default 50)")
    demo.add_argument("--every", type=int, default=50, help="print every Nth sample")
    demo.set_defaults(func=_cmd_demo)

    rp = sub.add_parser(
        "replay",
        help="fly mission files in the mock SITL faster than real time; write log, report, plot",
    )
    rp.add_argument("files", nargs="+", metavar="FILE", help=".plan or QGC WPL 110 files")
    rp.add_argument("--vehicle", choices=("quad", "rover"), default="quad")
    rp.add_argument("--mode", choices=("position", "attitude", "rates"), default="attitude",
                    help="setpoint mode (default attitude)")
    rp.add_argument("--rate", type=float, default=100.0, help="setpoint rate [Hz] (default 100)")
    rp.add_argument("--onboard", action="store_true",
                    help="the mock's onboard module flies the uploaded trajectory (the PX4 "
                         "module's C; a quad in attitude mode; see docs/guides/onboard.md)")
    rp.add_argument("--compare-px4-mission", action="store_true",
                    help="also fly the file in the mock's AUTO.MISSION and report both")
    rp.add_argument("--wind", type=float, default=0.0, metavar="SPEED",
                    help="steady wind speed [m/s] (default 0)")
    rp.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    rp.add_argument("--jobs", type=_positive_int, default=1,
                    help="files replayed in parallel (default 1)")
    rp.add_argument("--out", default="replay_out", type=output_folder,
                    help="output folder (default ./replay_out)")
    rp.add_argument("--no-plot", action="store_true",
                    help="write no flight.png (the plot needs the [plot] extra)")
    add_perturbation_options(rp)
    rp.set_defaults(func=_cmd_replay)

    add_campaign_parser(sub)

    fl = sub.add_parser("fly", help="take off, fly a mission file or pattern in offboard, land")
    fl.add_argument("target", metavar="TARGET",
                    help="a .plan / QGC WPL file, or a pattern: figure8, circle, square")
    fl.add_argument("--connect", metavar="URL", default=None, type=_connect_url,
                    help="vehicle link, e.g. udpin://0.0.0.0:14540 (default: an embedded mock)")
    _target_system_option(fl)
    _timeout_option(fl)
    add_signing_option(fl)
    fl.add_argument("--mode", choices=("position", "attitude", "rates"), default="attitude")
    fl.add_argument("--rate", type=float, default=100.0, help="setpoint rate [Hz] (default 100)")
    fl.add_argument("--vehicle-file", metavar="FILE.toml", default=None,
                    help="vehicle parameters and limits (see companion/planning/config.py)")
    # the former spelling; `--vehicle` is the vehicle kind (quad | rover) in `replay`
    fl.add_argument("--vehicle", dest="vehicle_file", metavar="FILE.toml",
                    help=argparse.SUPPRESS)
    fl.add_argument("--log", metavar="FILE.tlog", default=None, type=output_file,
                    help="flight log (default flight-<UTC time>.tlog here)")
    fl.add_argument("--size", type=_positive_float, default=10.0,
                    help="pattern size [m] (default 10)")
    fl.add_argument("--speed", type=_positive_float, default=3.0,
                    help="pattern speed [m/s] (default 3)")
    fl.add_argument("--alt", type=_altitude, default=5.0,
                    help="pattern altitude above the start [m] (> 0.5, default 5)")
    fl.add_argument("--laps", type=_positive_int, default=1, help="pattern laps (default 1)")
    fl.add_argument("--wind", type=_wind, default=None, metavar="SPEED@FROM",
                    help="the wind to expect (m/s @ compass deg it blows from, e.g. 6@270): a "
                         "plan the vehicle cannot fly in it (tilt limit, drag of the vehicle "
                         "file) exits 2 before anything is sent; attitude and rates modes")
    fl.add_argument("--busy-wait", action="store_true",
                    help="sender thread busy-waits each deadline (tightest timing, costs a core)")
    fl.add_argument("--sender-cpu", type=int, default=None, metavar="N",
                    help="pin the setpoint sender thread to core N")
    fl.add_argument("--mock-param", type=mock_param, action="append", default=[],
                    metavar="NAME=VALUE", help="parameter of the embedded mock (repeatable)")
    fl.add_argument("--onboard", action="store_true",
                    help="upload the trajectory to the onboard PX4 module (gen_c/px4_module) "
                         "and let it fly inside the autopilot: no setpoint streamed "
                         "(--connect and attitude mode; see docs/guides/onboard.md)")
    fl.set_defaults(func=_cmd_fly)

    sv = sub.add_parser(
        "serve", help="companion-computer service: stream hold setpoints, fly the pilot's "
        "mission smoothly whenever the pilot selects OFFBOARD (never arms or takes off)")
    sv.add_argument("--connect", metavar="URL", required=True,
                    help="vehicle link: udpin://0.0.0.0:14540, serial:///dev/ttyAMA0:921600 or "
                    "a serial device path (default baud 921600)")
    _target_system_option(sv)
    sv.add_argument("--mode", choices=("position", "attitude", "rates"), default="attitude")
    sv.add_argument("--rate", type=float, default=50.0, help="setpoint rate [Hz] (default 50)")
    sv.add_argument("--vehicle-file", metavar="FILE.toml", default=None,
                    help="vehicle parameters, limits and gains (see companion/planning/config.py)")
    sv.add_argument("--vehicle", dest="vehicle_file", metavar="FILE.toml",
                    help=argparse.SUPPRESS)
    sv.add_argument("--log-dir", metavar="DIR", default="ecca-logs", type=output_folder,
                    help="folder for rotating .tlog files and events.jsonl (default ecca-logs)")
    sv.add_argument("--tlog-max-mb", type=float, default=64.0,
                    help="start a new .tlog beyond this size [MiB] (default 64)")
    sv.add_argument("--tlog-keep", type=int, default=20,
                    help="keep the newest N .tlog files (default 20)")
    sv.add_argument("--onboard", action="store_true",
                    help="the onboard PX4 module (gen_c/px4_module) flies the mission: checked "
                         "at start (absent or not ready: exit 2), the trajectory uploaded "
                         "while the vehicle holds, no setpoint streamed (attitude mode; see "
                         "docs/guides/onboard.md)")
    add_signing_option(sv)
    sv.set_defaults(func=_cmd_serve)

    stp = sub.add_parser("status", help="connect and print the vehicle state")
    stp.add_argument("--connect", metavar="URL", required=True, type=_connect_url,
                     help="e.g. udpin://0.0.0.0:14540")
    _target_system_option(stp)
    _timeout_option(stp)
    add_signing_option(stp)
    stp.set_defaults(func=_cmd_status)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the process exit code."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # argparse exits 2 on bad options
        return int(exc.code or 0)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(levelname)s %(name)s: %(message)s",
    )
    logging.getLogger("matplotlib").setLevel(logging.WARNING)
    try:
        return int(args.func(args))
    except KeyboardInterrupt:
        err_console.print("[yellow]interrupted[/yellow]")
        return EXIT_INTERRUPTED
    except MissingExtraError as exc:
        print_error("error", exc)
        return EXIT_BAD_INPUT
    except (ValueError, FileNotFoundError) as exc:
        print_error("error", exc)
        return EXIT_BAD_INPUT


if __name__ == "__main__":
    sys.exit(main())
