"""`python -m companion campaign FILE... --runs N`: Monte-Carlo replay campaigns on Dask.

Exit codes: 0 every mission/mode reached --require, 1 one did not (or runs were lost to
worker failures), 2 bad input (unreadable mission, bad option).
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rich.console import Console
from rich.markup import escape

from companion.app.extras import require
from companion.app.paths import output_folder
from companion.campaign.perturb import PerturbationRanges

if TYPE_CHECKING:
    from companion.campaign.runner import Keep

EXIT_OK, EXIT_FAILURE, EXIT_BAD_INPUT = 0, 1, 2
#: The modes a campaign compares: the streamed setpoint modes, and onboard (the mock's onboard
#: module flies the upload, as `fly --onboard` on PX4); the default is the streamed ones.
MODES = ("position", "attitude", "rates", "onboard")
DEFAULT_MODES = ("position", "attitude", "rates")

#: Range options: (option, PerturbationRanges field, metavar, help)
_RANGE_OPTIONS = (
    ("--wind-max", "wind_max_m_s", "M/S", "steady wind 0..M/S, any direction"),
    ("--gust-max", "gust_max_m_s", "M/S", "gust std 0..M/S (SIM_WIND_GUST)"),
    ("--mass-error", "mass_error", "FRAC", "true mass = assumed * (1 +- FRAC)"),
    ("--inertia-error", "inertia_error", "FRAC", "true inertia per axis = assumed * (1 +- FRAC)"),
    ("--hover-thrust-error", "hover_thrust_error", "FRAC",
     "hover thrust told to the companion and MPC_THR_HOVER = 0.5 * (1 +- FRAC)"),
    ("--drag-error", "drag_error", "FRAC", "true drag SIH_KDV = 1 * (1 +- FRAC)"),
    ("--latency-max", "latency_max_s", "S", "telemetry latency 0..S"),
    ("--jitter-max", "jitter_max_s", "S", "telemetry jitter 0..S"),
    ("--loss-max", "loss_max_pct", "PCT", "datagram loss 0..PCT in both directions"),
    ("--pos-noise-max", "pos_noise_max_m", "M",
     "position noise std 0..M (SIM_POS_NOISE; velocity noise half of it)"),
    ("--start-offset-max", "start_offset_max_m", "M", "vehicle 0..M from the planned home"),
)


@dataclass
class CampaignOptions:
    """Everything `campaign` needs (what the CLI parses; the API for tests and benches)."""

    files: list[str]
    runs: int = 20
    seed: int = 0
    modes: tuple[str, ...] = DEFAULT_MODES
    rate_hz: float = 100.0
    ranges: PerturbationRanges = field(default_factory=PerturbationRanges)
    out: str = "campaign_out"
    scheduler: str | None = None
    workers: int | None = None
    keep: Keep = "failed"
    require: float = 0.95


def add_campaign_parser(sub: Any) -> None:
    """Register `campaign` on the subparsers of `python -m companion`."""
    cp = sub.add_parser(
        "campaign",
        help="Monte-Carlo replays of missions under sampled wind, vehicle and link errors (Dask)",
    )
    cp.add_argument("files", nargs="+", metavar="FILE", help=".plan or QGC WPL 110 files")
    cp.add_argument("--runs", type=int, required=True, metavar="N",
                    help="runs per mission and mode")
    cp.add_argument("--seed", type=int, default=0, help="campaign seed (default 0)")
    cp.add_argument("--mode", dest="modes", default=",".join(DEFAULT_MODES), metavar="M[,M...]",
                    help="modes: position, attitude, rates (streamed setpoints), onboard (the "
                         "mock's onboard module flies the upload) (default "
                         "position,attitude,rates)")
    cp.add_argument("--onboard", action="store_true",
                    help="add the onboard mode to --mode's: onboard and streamed flights under "
                         "the same perturbations (docs/guides/onboard.md)")
    cp.add_argument("--rate", type=float, default=100.0, help="setpoint rate [Hz] (default 100)")
    cp.add_argument("--scheduler", default=None, metavar="tcp://HOST:8786",
                    help="an existing Dask scheduler (default: a local cluster on all cores)")
    cp.add_argument("--workers", type=int, default=None, metavar="N",
                    help="local cluster size (default: one worker per core)")
    cp.add_argument("--keep", choices=("all", "failed", "none"), default="failed",
                    help="per-run tlogs to keep (default failed)")
    cp.add_argument("--require", type=float, default=95.0, metavar="PCT",
                    help="exit 1 if a mission/mode succeeds in fewer than PCT %% of runs "
                         "(default 95)")
    cp.add_argument("--out", default="campaign_out", type=output_folder,
                    help="output folder (default ./campaign_out)")
    defaults = PerturbationRanges()
    for opt, name, metavar, text in _RANGE_OPTIONS:
        d = getattr(defaults, name)
        cp.add_argument(opt, dest=name, type=float, default=d, metavar=metavar,
                        help=f"{text} (default {d:g}; 0 = off)")
    cp.set_defaults(func=cmd_campaign)


def options_from_args(args: argparse.Namespace) -> CampaignOptions:
    """Validate the parsed options (ValueError with the reason)."""
    modes = tuple(m.strip() for m in args.modes.split(",") if m.strip())
    if getattr(args, "onboard", False) and "onboard" not in modes:
        modes = (*modes, "onboard")
    bad = [m for m in modes if m not in MODES]
    if bad or not modes:
        raise ValueError(f"--mode takes {', '.join(MODES)}; got {args.modes!r}")
    if args.runs < 1:
        raise ValueError(f"--runs must be >= 1, got {args.runs}")
    if args.seed < 0:
        raise ValueError(f"--seed must be >= 0, got {args.seed}")
    if not 0.0 <= args.require <= 100.0:
        raise ValueError(f"--require is a percentage 0..100, got {args.require}")
    if args.workers is not None and args.workers < 1:
        raise ValueError(f"--workers must be >= 1, got {args.workers}")
    ranges = PerturbationRanges(**{f.name: getattr(args, f.name)
                                   for f in fields(PerturbationRanges)})
    return CampaignOptions(
        files=list(dict.fromkeys(args.files)), runs=args.runs, seed=args.seed, modes=modes,
        rate_hz=args.rate, ranges=ranges, out=args.out, scheduler=args.scheduler,
        workers=args.workers, keep=args.keep, require=args.require / 100.0,
    )


def cmd_campaign(args: argparse.Namespace) -> int:
    """`campaign` from parsed arguments (MissingExtraError without the [campaign] extra)."""
    require("campaign", "campaign")
    console = Console()
    try:
        return run_campaign(options_from_args(args), console)
    except (OSError, TimeoutError) as exc:  # scheduler unreachable, cluster start failed
        console.print(f"[red]campaign failed:[/red] {type(exc).__name__}: {exc}")
        return EXIT_FAILURE


def run_campaign(
    opts: CampaignOptions,
    console: Console,
    on_result: Any = None,
) -> int:
    """Run (or resume) a campaign, write its outputs, print the summary; returns the exit code.
    `on_result(row)` is called in the client for every run as it is stored."""
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )
    from rich.table import Table

    from companion.campaign.report import write_outputs
    from companion.campaign.runner import (
        CampaignProgress,
        ResultStore,
        dask_client,
        make_tasks,
        run_tasks,
    )
    from companion.mission import MissionError
    from companion.replay.runner import ReplayConfig, prepare_mission

    for f in opts.files:  # every file must load (and its plan keep inside its geofence)
        try:  # before anything is flown
            prepare_mission(f, ReplayConfig(vehicle="quad"))
        except (MissionError, OSError) as exc:
            console.print(f"[red]error:[/red] {escape(str(exc))}")
            return EXIT_BAD_INPUT
        except ValueError:
            pass  # a plan the planner cannot make: every run records why
    if opts.rate_hz < 20.0 or opts.rate_hz > 500.0:
        raise ValueError(f"setpoint rate must be 20..500 Hz, got {opts.rate_hz}")
    out = Path(opts.out)
    store = ResultStore(out)
    tasks = make_tasks(opts.files, opts.modes, opts.runs, opts.seed, opts.ranges,
                       rate_hz=opts.rate_hz, keep=opts.keep)
    prog = CampaignProgress()
    t0 = time.perf_counter()
    with Progress(
        TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
        TextColumn("{task.fields[failed]} failed"), TimeElapsedColumn(), TextColumn("ETA"),
        TimeRemainingColumn(), console=console, transient=False,
    ) as bar:
        task_id = bar.add_task("campaign", total=len(tasks), failed=0)

        def on_row(row: dict[str, Any]) -> None:
            bar.update(task_id, completed=prog.skipped + prog.done, failed=prog.failed)
            if on_result is not None:
                on_result(row)

        where = opts.scheduler or "a local cluster"
        with dask_client(opts.scheduler, opts.workers) as client:
            n_workers = len(client.scheduler_info().get("workers", {}))
            bar.console.print(
                f"{len(tasks)} runs ({len(opts.files)} file(s) x {len(opts.modes)} mode(s) x "
                f"{opts.runs}) on {where} with {n_workers} worker(s)"
            )
            rows = run_tasks(client, tasks, store, prog, on_row)
        bar.update(task_id, completed=prog.skipped + prog.done, failed=prog.failed)
    wall = time.perf_counter() - t0
    meta = {
        "seed": opts.seed, "runs_per_mission_mode": opts.runs, "files": opts.files,
        "modes": list(opts.modes), "rate_hz": opts.rate_hz, "keep": opts.keep,
        "ranges": {f.name: getattr(opts.ranges, f.name) for f in fields(PerturbationRanges)},
        "executed": prog.done, "skipped_on_disk": prog.skipped, "lost": prog.lost,
    }
    summary = write_outputs(out, rows, opts.require, meta)
    table = Table(title=f"Campaign summary ({len(rows)} runs); outputs in {out}")
    for col in ("mission", "mode", "runs", "success", "RMS err p90 m", "max err p90 m"):
        table.add_column(col)
    for g in summary["groups"]:
        rate = f"{100 * g['success_rate']:.1f} %"
        p90r, p90m = g["rms_error_m"]["p90"], g["max_error_m"]["p90"]
        table.add_row(
            g["mission"], g["mode"], str(g["runs"]),
            f"[green]{rate}[/green]" if g["meets_require"] else f"[red]{rate}[/red]",
            "-" if p90r is None else f"{p90r:.2f}", "-" if p90m is None else f"{p90m:.2f}",
        )
    console.print(table)
    console.print(f"{prog.done} run(s) flown in {wall:.1f} s, {prog.skipped} already on disk; "
                  f"report: {out / 'report.html'}")
    if summary["worst"] and not summary["worst"][0]["ok"]:
        console.print("worst run, to replay it:")
        console.print(summary["worst"][0]["command"], markup=False, soft_wrap=True)
    if prog.lost:
        console.print(f"[red]{prog.lost} run(s) lost to worker failures[/red]; run the same "
                      "command again to fly them")
        return EXIT_FAILURE
    return EXIT_OK if summary["passed"] else EXIT_FAILURE


__all__ = ["CampaignOptions", "add_campaign_parser", "cmd_campaign", "run_campaign"]
