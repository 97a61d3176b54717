"""Options shared by `replay` and `campaign`: what one replayed flight is perturbed with."""

from __future__ import annotations

import argparse
import dataclasses
from typing import Any


def mock_param(text: str) -> tuple[str, float]:
    """Parse NAME=VALUE (a sitl_mock parameter)."""
    name, _, value = text.partition("=")
    try:
        return name.strip(), float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE, got {text!r}") from None


def north_east(text: str) -> tuple[float, float]:
    """Parse N,E [m]."""
    try:
        n, e = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected N,E in metres, got {text!r}") from None
    return n, e


def add_perturbation_options(p: argparse.ArgumentParser) -> None:
    """The `replay` options a campaign run is re-created with."""
    p.add_argument("--wind-from", type=float, default=135.0, metavar="DEG",
                   help="compass direction the wind blows from [deg] (default 135, south-east)")
    p.add_argument("--hover-thrust", type=float, default=None, metavar="X",
                   help="hover thrust the companion assumes, 0..1 (default 0.5)")
    p.add_argument("--latency", type=float, default=0.0, metavar="S",
                   help="telemetry delay, vehicle -> companion [s] (default 0)")
    p.add_argument("--jitter", type=float, default=0.0, metavar="S",
                   help="extra uniform telemetry delay 0..S [s] (default 0)")
    p.add_argument("--loss", type=float, default=0.0, metavar="PCT",
                   help="datagram loss in both directions [%%] (default 0)")
    p.add_argument("--start-offset", type=north_east, default=(0.0, 0.0), metavar="N,E",
                   help="vehicle placed N,E metres from the planned home (default 0,0; write "
                        "--start-offset=-1,2 for a negative north)")
    p.add_argument("--mock-param", type=mock_param, action="append", default=[],
                   metavar="NAME=VALUE",
                   help="true vehicle/sensor parameter of the mock, e.g. SIH_MASS=1.2 "
                        "(repeatable; sitl_mock/params.py)")


def replay_config_kwargs(args: argparse.Namespace) -> dict[str, Any]:
    """ReplayConfig keyword arguments from parsed `replay` options."""
    from companion.replay.runner import DEFAULT_QUAD

    params = DEFAULT_QUAD
    if args.hover_thrust is not None:
        params = dataclasses.replace(params, hover_thrust=args.hover_thrust)
    return {
        "vehicle": args.vehicle,
        "mode": args.mode,
        "rate_hz": args.rate,
        "wind_m_s": args.wind,
        "wind_from_deg": args.wind_from,
        "seed": args.seed,
        "params": params,
        "mock_params": tuple(args.mock_param),
        "latency_s": args.latency,
        "jitter_s": args.jitter,
        "loss_pct": args.loss,
        "start_offset_ne_m": tuple(args.start_offset),
        "onboard": bool(getattr(args, "onboard", False)),
    }
