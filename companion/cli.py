"""Command line: `python -m companion COMMAND ...`.

Exit codes: 0 success, 1 flight/runtime failure (vehicle refused, link lost, limit exceeded),
2 bad input (unreadable or invalid file, bad option), 130 interrupted by the user.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Sequence
from pathlib import Path

from rich.console import Console
from rich.table import Table

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130

console = Console(stderr=False, width=None if sys.stdout.isatty() else 110)
err_console = Console(stderr=True)


def _cmd_demo(args: argparse.Namespace) -> int:
    from companion.demo import run_demo, save_plot

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
    console.print(f"Plot written to [bold]{out / 'demo.png'}[/bold]")
    return EXIT_OK if result.limits_ok else EXIT_FAILURE


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of `python -m companion`."""
    parser = argparse.ArgumentParser(
        prog="python -m companion",
        description="ecca-offboard: plan trajectories and fly them with PX4 offboard control.",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", required=True)

    demo = sub.add_parser("demo", help="plan a trajectory offline, print setpoints, save a plot")
    demo.add_argument("--out", default="demo_out", help="output folder (default demo_out)")
    demo.add_argument("--rate", type=float, default=50.0, help="sample rate [Hz] (default 50)")
    demo.add_argument("--every", type=int, default=50, help="print every Nth sample")
    demo.set_defaults(func=_cmd_demo)
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
    except (ValueError, FileNotFoundError) as exc:
        err_console.print(f"[red]error:[/red] {exc}")
        return EXIT_BAD_INPUT


if __name__ == "__main__":
    sys.exit(main())
