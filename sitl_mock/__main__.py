"""Command line: `python -m sitl_mock serve [...]`, a PX4-like SITL vehicle on UDP.

Exit codes: 0 clean stop (Ctrl-C / SIGTERM), 2 bad arguments, 1 runtime error.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import signal
import sys
import time
from collections.abc import Sequence

from sitl_mock.autopilot import Autopilot
from sitl_mock.faults import LinkFaults, ScenarioFaults, parse_blackouts
from sitl_mock.params import PARAMS, ParamStore
from sitl_mock.server import Addr, LinkConfig, MockServer, ServerConfig
from sitl_mock.signing import read_key_file
from sitl_mock.vehicle import DEFAULT_HOME


def _addr(text: str) -> Addr:
    host, sep, port = text.rpartition(":")
    if not sep or not host:
        raise argparse.ArgumentTypeError(f"expected HOST:PORT, got {text!r}")
    try:
        p = int(port)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"bad port in {text!r}") from exc
    if not 0 <= p <= 65535:
        raise argparse.ArgumentTypeError(f"port out of range in {text!r}")
    return host, p


def _remote(text: str) -> Addr | None:
    return None if text.lower() in ("none", "off", "") else _addr(text)


def _param(text: str) -> tuple[str, float]:
    name, sep, value = text.partition("=")
    if not sep:
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE, got {text!r}")
    name = name.strip().upper()
    if name not in PARAMS:
        raise argparse.ArgumentTypeError(f"unknown parameter {name!r}")
    try:
        return name, float(value)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"parameter {name} needs a number, got {value!r}") from exc


def _home(text: str) -> tuple[float, float, float]:
    parts = text.split(",")
    if len(parts) != 3:
        raise argparse.ArgumentTypeError("expected LAT,LON,ALT (degrees, degrees, m AMSL)")
    try:
        lat, lon, alt = (float(p) for p in parts)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"bad number in --home {text!r}") from exc
    if not (-90 <= lat <= 90 and -180 <= lon <= 180):
        raise argparse.ArgumentTypeError("home latitude/longitude out of range")
    return lat, lon, alt


#: `serve --estimator` presets. ekf2: the errors of PX4 v1.16 SITL's estimate (LOCAL_POSITION_NED
#: minus HIL_STATE_QUATERNION, SIH quad, hovering; bench/bench_fidelity.py): position 0.10-0.20 m
#: and velocity 0.13-0.35 m/s per axis, autocorrelation 0.87 after 1 s, 0.2-0.35 after 5 s.
ESTIMATOR_PRESETS: dict[str, dict[str, float]] = {
    "ideal": {},
    "ekf2": {"SIM_EST_XY_STD": 0.16, "SIM_EST_VXY_STD": 0.22, "SIM_EST_XY_TAU": 1.7},
}
#: The rover's (`serve --vehicle rover --estimator ...`). ekf2: PX4 main's EKF2 on SIH's
#: Ackermann rover (airframe 10045) against HIL_STATE_QUATERNION, over 6 speed-step/turn flights
#: and 6 rover_square missions of bench_rover_fidelity.py (2026-12-01, each on a fresh PX4,
#: staggered starts), read by bench/rover_estimate_error.py (BENCHMARKS.md "The estimate leads,
#: and its heading is off for a whole start"):
#: - the position estimate (GLOBAL_POSITION_INT, geodetic, so no EKF origin in it) leads the
#:   truth along the motion by 0.11 s of travel (0.10-0.13 s in every speed band from 0.5 to
#:   3.5 m/s; 0.3 m at 3 m/s): SIM_EST_LEAD_S;
#: - what remains while driving: 0.14 / 0.15 m (N / E std; 0.09-0.19 m by flight),
#:   autocorrelation fitted by (1 + t/tau) e^(-t/tau) with tau 1.35 s; velocity 0.23 / 0.25 m/s;
#: - heading on the straight legs: a mean per flight of -4.9 to +3.1 deg (RMS 3.0 deg) and
#:   2.6 deg (std, tau 2.6 s) about it. Pure pursuit then holds the estimate 3.4 m x tan(error)
#:   beside the leg (0.22 m RMS over the 24 legs), the cross-track PX4's own path shows.
ROVER_ESTIMATOR_PRESETS: dict[str, dict[str, float]] = {
    "ideal": {},
    "ekf2": {"SIM_EST_XY_STD": 0.145, "SIM_EST_VXY_STD": 0.24, "SIM_EST_XY_TAU": 1.35,
             "SIM_EST_YAW_STD": 2.6, "SIM_EST_YAW_TAU": 2.6, "SIM_EST_YAW_BIAS": 3.0,
             "SIM_EST_LEAD_S": 0.11},
}


def estimator_preset(name: str, vehicle: str) -> dict[str, float]:
    """The SIM_EST_* values of `serve --estimator NAME` for `vehicle` ("quad" or "rover")."""
    return (ROVER_ESTIMATOR_PRESETS if vehicle == "rover" else ESTIMATOR_PRESETS)[name]


def _signing_key(path: str) -> bytes:
    try:
        return read_key_file(path)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="python -m sitl_mock", description=__doc__)
    sub = ap.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("serve", help="run the mock vehicle on UDP (like PX4 SITL)")
    s.add_argument("--vehicle", choices=("quad", "rover"), default="quad")
    s.add_argument("--bind", type=_addr, default=("127.0.0.1", 14580), help="offboard link bind")
    s.add_argument(
        "--remote", type=_remote, default=("127.0.0.1", 14540), help="offboard link first peer"
    )
    s.add_argument("--gcs-bind", type=_addr, default=("127.0.0.1", 18570))
    s.add_argument(
        "--gcs-remote", type=_remote, default=("127.0.0.1", 14550), help="'none' disables"
    )
    s.add_argument("--no-gcs", action="store_true", help="run without the GCS link")
    s.add_argument("--serial", metavar="DEVICE", default=None,
                   help="offboard link on a serial line instead of UDP (like TELEM2): a device "
                   "path, or 'pty' for a new pseudo-terminal whose path the ready line shows")
    s.add_argument("--serial-baud", type=int, default=921600, help="baud rate (default 921600)")
    s.add_argument("--param", type=_param, action="append", default=[], metavar="NAME=VALUE")
    s.add_argument("--home", type=_home, default=DEFAULT_HOME, metavar="LAT,LON,ALT")
    s.add_argument("--speed", type=float, default=1.0, help="simulated seconds per wall second")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--physics-hz", type=float, default=250.0)
    s.add_argument("--estimator-ready", type=float, default=3.0, help="seconds after boot")
    s.add_argument(
        "--estimator",
        choices=sorted(ESTIMATOR_PRESETS),
        default="ideal",
        help="ideal: the controller and telemetry see the true state; ekf2: horizontal "
        "position/velocity errors as measured on PX4 v1.16 SITL (SIH + EKF2; the rover: "
        "position, velocity and heading errors as measured on PX4 main's SIH rover), "
        "--param wins",
    )
    s.add_argument(
        "--signing-key",
        type=_signing_key,
        default=None,
        metavar="FILE",
        help="MAVLink 2 signing key (64 hex digits or 32 raw bytes): sign everything sent, "
        "refuse unsigned and wrongly signed frames (like PX4 with MAV_SIGN_CFG 2)",
    )
    s.add_argument(
        "--onboard",
        action="store_true",
        help="host the onboard module (gen_c/px4_module, the same C through ctypes; compiled "
        "with the system C compiler at first use) as PX4 hosts `dyn ecca_onboard.px4mod "
        "start`: `python -m companion fly MISSION --onboard` flies against it",
    )
    f = s.add_argument_group("fault injection (offboard link unless --fault-gcs)")
    f.add_argument("--loss", type=float, default=0.0, help="packet loss [%%] both directions")
    f.add_argument("--latency", type=float, default=0.0, help="one-way latency [s]")
    f.add_argument("--jitter", type=float, default=0.0, help="extra random latency [s]")
    f.add_argument("--duplicate", type=float, default=0.0, help="duplication [%%]")
    f.add_argument("--reorder", type=float, default=0.0, help="reordering [%%]")
    f.add_argument("--blackout", type=str, default="", help="windows 'T0-T1,T2-T3' [s]")
    f.add_argument("--fault-gcs", action="store_true", help="apply the link faults to GCS too")
    f.add_argument("--pilot-takeover", type=float, default=None, metavar="T")
    f.add_argument("--position-loss", type=str, default=None, metavar="T0-T1")
    f.add_argument("--low-battery", type=float, default=None, metavar="T")
    f.add_argument("--low-battery-level", type=float, default=0.12, metavar="FRACTION")
    return ap


async def _serve(args: argparse.Namespace) -> int:
    try:
        params = ParamStore({**estimator_preset(args.estimator, args.vehicle),
                             **dict(args.param)})
        faults = LinkFaults(
            loss_pct=args.loss,
            latency_s=args.latency,
            jitter_s=args.jitter,
            duplicate_pct=args.duplicate,
            reorder_pct=args.reorder,
            blackouts=parse_blackouts(args.blackout),
        )
        pos_loss = None
        if args.position_loss:
            w = parse_blackouts(args.position_loss)
            if len(w) != 1:
                raise ValueError("--position-loss takes one window T0-T1")
            pos_loss = w[0]
        scenario = ScenarioFaults(
            pilot_takeover_s=args.pilot_takeover,
            local_position_loss=pos_loss,
            low_battery_s=args.low_battery,
            low_battery_remaining=args.low_battery_level,
        )
    except ValueError as exc:
        print(f"sitl_mock: {exc}", file=sys.stderr)
        return 2
    if args.onboard:
        if args.vehicle != "quad":
            print("sitl_mock: --onboard flies a quad only", file=sys.stderr)
            return 2
        from gen_c.native import NativeBuildError
        from sitl_mock.onboard import onboard_library

        try:
            onboard_library()  # compile (or load from the cache) before the clock runs
        except (NativeBuildError, OSError) as exc:
            print(f"sitl_mock: --onboard: cannot build the module: {exc}", file=sys.stderr)
            return 1
    links = [LinkConfig("offboard", args.bind, args.remote, serial=args.serial,
                        baud=args.serial_baud)]
    if not args.no_gcs:
        links.append(LinkConfig("gcs", args.gcs_bind, args.gcs_remote))
    link_faults = {"offboard": (faults, faults)}
    if args.fault_gcs:
        link_faults["gcs"] = (faults, faults)

    def make(remotes: dict[str, Addr | None], now: float) -> Autopilot:
        return Autopilot(
            args.vehicle,
            params,
            args.home,
            args.seed,
            physics_hz=args.physics_hz,
            now=now,
            remotes=remotes,
            link_faults=link_faults,
            scenario=scenario,
            estimator_ready_s=args.estimator_ready,
            signing_key=args.signing_key,
            unix_boot_s=time.time(),
            onboard=args.onboard,
        )

    try:
        server = MockServer(make, ServerConfig(links=links, speed=args.speed))
        await server.start()
    except (OSError, ValueError) as exc:
        print(f"sitl_mock: cannot start: {exc}", file=sys.stderr)
        return 1
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(NotImplementedError, RuntimeError):
            loop.add_signal_handler(sig, server.stop)
    parts = []
    for lk in links:
        host, port = server.bound[lk.name]
        if lk.serial is not None:
            parts.append(f"{lk.name}=serial:{host}")
            continue
        remote = f"{lk.remote[0]}:{lk.remote[1]}" if lk.remote else "none"
        parts.append(f"{lk.name}={host}:{port}->{remote}")
    signed = " signing=required" if args.signing_key is not None else ""
    onboard = " onboard" if args.onboard else ""
    print(f"sitl_mock ready {args.vehicle} " + " ".join(parts) + signed + onboard, flush=True)
    await server.run()
    print("sitl_mock stopped", flush=True)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.cmd == "serve":
        if not (args.speed > 0 and args.speed <= 100):
            print("sitl_mock: --speed must be in (0, 100]", file=sys.stderr)
            return 2
        try:
            return asyncio.run(_serve(args))
        except KeyboardInterrupt:
            return 0
    return 2


if __name__ == "__main__":
    sys.exit(main())
