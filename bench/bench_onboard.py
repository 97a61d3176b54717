"""Onboard module vs streamed setpoints vs PX4's own position control, on real PX4 (issue 26).

One fresh PX4 v1.16 SITL per flight, real time. Every cell flies the figure-8 of
bench_tracking.py (two laps; lap 2 judged, horizontal error against the reference at the
plan's clock, PX4's estimate and the simulator's truth):

- `onboard`: the trajectory (the figure-8 as degree-7 Hermite segments of 0.25 s, bent for the
  tilt limit as `fly --onboard` bends its plans: `bend_for_tilt`; `--no-bend`) uploaded to
  the module (gen_c/px4_module) after the takeoff; OFFBOARD; the module flies it. Its clock is
  the autopilot's (the module's start report).
- `attitude`: the companion streams attitude setpoints at 100 Hz (bench_tracking's API cell).
- `position`: PX4's position control fed position, velocity and acceleration (the same).

Cells: 6 m/s, and 8 m/s on the figure scaled 2x; `--degraded`: the onboard and streamed
cells again through a relay that delays every datagram by 20 ms and drops 5 % (bench/
udp_degrade.py). After each onboard flight the module's own timing (`dyn ... status`: the
step's CPU time, mean and p99). `--square`: the bundled square mission by `fly` and by
`fly --onboard` (report figures).

Usage:
  python bench/bench_onboard.py --out bench_out/onboard [--repeat 1] [--degraded] [--square]
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import dataclasses
import json
import math
import re
import shutil
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(REPO))

import api_harness as H  # noqa: E402, N812
import bench_tracking as B  # noqa: E402, N812
from udp_degrade import DegradedLink  # noqa: E402

from companion.aio import Vehicle, VehicleConfig  # noqa: E402
from companion.aio.onboard import module_states, upload  # noqa: E402
from companion.control import Reference  # noqa: E402
from companion.control.shaping import ShapingConfig  # noqa: E402
from companion.mavlink import FlightMode, LinkConfig  # noqa: E402
from companion.onboard import protocol as P  # noqa: E402, N812
from companion.planning.config import VehicleFile  # noqa: E402
from companion.planning.onboard_segments import bend_for_tilt, law_params  # noqa: E402
from companion.trajectory.bezier import hermite  # noqa: E402
from gen_c import px4module  # noqa: E402
from px4_harness import Px4Sitl, find_px4_sitl, flight_lock  # noqa: E402

SEG_S = 0.25
TILT_DEG = 45.0
FIGURE8 = B.figure8_reference  # the original (patched_figure replaces the module's name)
#: the degraded link (`--latency`, `--loss`)
LINK = {"latency_s": 0.02, "loss": 0.05}
#: extra hover before OFFBOARD [s] (`--hover-s`: separates the hover's length from the link)
HOVER = {"s": 0.0}
#: `--law`: LawParams fields the onboard cells override
LAW_OVERRIDE: dict[str, Any] = {}
#: `--upload-after-takeoff`: the onboard cells upload from the hover after PX4's takeoff
AFTER_TAKEOFF = {"on": False}
#: `--ctl`: the streamed cells' controller overrides
CTL: list[str] = []
#: arm at this time since PX4's boot [s] (`--arm-at`; 0: at once): PX4's estimate errs the same
#: way at the same time since boot (SIH's sensor noise), so cells compared at equal boot times
ARM_AT = {"s": 0.0}
#: `--start-at`: every cell starts its figure at this time since PX4's boot [s] (0: as soon as
#: it can). PX4 SIH's estimate errs the same way at the same time since boot, so cells that
#: start together meet the same estimate errors (onboard and streamed paired).
START_AT = {"s": 0.0}
#: `--no-bend`: the onboard cells upload the figure as it is, not bent ahead of time for the
#: tilt limit (`bend_for_tilt`, what fly --onboard uploads)
BEND: dict[str, Any] = {"on": True, "margin_deg": None}


async def wait_boot(v: Vehicle, boot_s: float) -> None:
    """Wait (bounded by the boot clock) until PX4's clock reaches `boot_s` [s]."""
    t_end = time.monotonic() + boot_s + 30.0
    while time.monotonic() < t_end:
        p = v.telemetry.position
        if p is not None and p.time_boot_s >= boot_s:
            return
        await asyncio.sleep(0.004)


def scaled_figure8(scale: float) -> Callable[[float, float], Reference]:
    """bench_tracking's figure-8, `scale` times larger at the same peak speed."""
    def ref(t: float, speed: float) -> Reference:
        r, _ = FIGURE8(t, speed / scale)
        return Reference(np.array([r.pos_ned[0] * scale, r.pos_ned[1] * scale, r.pos_ned[2]]),
                         r.vel_ned * scale, r.acc_ned * scale, r.jerk_ned * scale,
                         r.snap_ned * scale)
    return ref


@contextlib.contextmanager
def patched_figure(scale: float) -> Iterator[None]:
    """bench_tracking's reference and duration for the scaled figure (its cells use them)."""
    f8, secs = B.figure8_reference, B.figure8_seconds

    def fig(t: float, speed: float, alt_m: float = 5.0) -> tuple[Reference, float]:
        _, phi = f8(t, speed / scale, alt_m)
        return scaled_figure8(scale)(t, speed), phi

    B.figure8_reference = fig  # type: ignore[assignment]
    B.figure8_seconds = lambda speed, laps=2.0: secs(speed / scale, laps)  # type: ignore[assignment]
    try:
        yield
    finally:
        B.figure8_reference, B.figure8_seconds = f8, secs  # type: ignore[assignment]


def hermite_segments(ref: Callable[[float], Reference], duration: float
                     ) -> tuple[list[float], list[np.ndarray]]:
    """The reference as degree-7 Hermite segments (position..jerk matched at every joint)."""
    n = max(1, math.ceil(duration / SEG_S))
    ts = np.linspace(0.0, duration, n + 1)

    def derivs(t: float) -> np.ndarray:
        r = ref(float(t))
        return np.array([r.pos_ned, r.vel_ned, r.acc_ned, r.jerk_ned])

    d = [derivs(t) for t in ts]
    cps = [hermite(d[i], d[i + 1], float(ts[i + 1] - ts[i])).control_points for i in range(n)]
    return [float(t) for t in ts], cps


async def _onboard_flight(url: str, target: int, module: Path, px4: Px4Sitl, speed: float,
                          scale: float, tlog: Path) -> dict[str, Any]:
    """Upload on the ground (or, with `--upload-after-takeoff`, from the hover after the
    takeoff: the figure then starts where the vehicle is, as the streamed cells' plan does),
    then take off and switch to OFFBOARD 1 s after the takeoff, as the streamed cells start:
    PX4's estimate errs differently the longer it has flown (a 7 s longer hover before the
    start: 0.13-0.16 m instead of 0.085 m), so every cell starts its pattern at about the same
    time after the takeoff, whatever the upload took."""
    fig = scaled_figure8(scale)
    duration = B.figure8_seconds(speed / scale)
    config = VehicleConfig(tlog_path=str(tlog), connect_timeout_s=20.0, armable_timeout_s=40.0,
                           stale_telemetry_s=1.0)
    async with Vehicle.connect(url, config=config,
                               link_config=LinkConfig(target_sysid=target)) as v:
        await v.set_message_interval(H.HIL_STATE_QUATERNION, 50.0)
        await H.fresh_position(v)
        hover = (await v.read_params(["MPC_THR_HOVER"]))["MPC_THR_HOVER"]
        cfg = v.link.config
        law = law_params(VehicleFile(), hover, math.radians(TILT_DEG))
        law = dataclasses.replace(law, **LAW_OVERRIDE)
        r0 = fig(0.0, speed).pos_ned  # (its height: 5 m up, where the takeoff ends)

        async def load() -> tuple[Callable[[float], Reference], float, int, int]:
            """The figure from where the vehicle is (horizontally), uploaded and verified."""
            pos = v.telemetry.position
            assert pos is not None
            shifted = H.shifted(lambda t: fig(t, speed), pos.pos_ned[0] - r0[0],
                                pos.pos_ned[1] - r0[1])
            breaks, cps = hermite_segments(shifted, duration)
            if BEND["on"]:  # as fly --onboard uploads: bent ahead of time for the tilt limit
                cfg_b = (None if BEND["margin_deg"] is None else
                         ShapingConfig(margin_rad=math.radians(BEND["margin_deg"])))
                breaks, cps, _ = bend_for_tilt((breaks, cps, [np.zeros(8) for _ in cps]), law,
                                               cfg_b)
            up = P.encode_upload(breaks, cps, None, law,
                                 sysid=cfg.sysid, compid=cfg.compid, final_action="hold",
                                 hold_s=1.0, start_tolerance_m=3.0)
            t_up = time.monotonic()
            u = await upload(v, up)
            if not u.verified:
                raise RuntimeError(f"upload failed: {u.failed}")
            return shifted, time.monotonic() - t_up, len(cps), u.resent

        if not AFTER_TAKEOFF["on"]:
            ref, up_s, n_seg, resent = await load()
        if ARM_AT["s"] > 0.0:
            await wait_boot(v, ARM_AT["s"])
        await v.arm()
        await v.takeoff(5.0)
        await asyncio.sleep(1.0 + HOVER["s"])  # the streamed cells' settle (not a sync)
        if AFTER_TAKEOFF["on"]:  # from the hover: no start offset (the upload takes ~0.4 s)
            ref, up_s, n_seg, resent = await load()
        if START_AT["s"] > 0.0:
            await wait_boot(v, START_AT["s"])
        await v.set_mode(FlightMode.OFFBOARD)
        t0_boot = math.nan
        state: Any = None
        try:
            async with asyncio.timeout(duration + 60.0):  # a frozen simulation sends nothing
                async for _, a in module_states(v):
                    state = a.state
                    if a.start:
                        t0_boot = a.value / 1000.0
                    elif a.state in (P.STATE_DONE, P.STATE_STOPPED, P.STATE_ERROR):
                        break
        except TimeoutError as exc:
            raise RuntimeError(f"no end of the flight within {duration + 60:.0f} s "
                               f"(last state {state})") from exc
        status = px4.command("dyn", str(module), "status").stdout
    data = H.read_flight_tlog(tlog, target)
    fl = H.Flight(tlog, 0.0, duration, ref, np.zeros(3),
                  clock=np.column_stack([data.lpos_t, data.lpos_boot - t0_boot]))

    def select(t: float) -> bool:
        return 2 * math.pi <= FIGURE8(t, speed / scale)[1] < 4 * math.pi

    est = H.horizontal_errors(data.lpos_t, data.lpos[:, :3], fl, select)
    tr = H.horizontal_errors(data.truth_t, data.truth, fl, select)
    rms, mx = H.rms_max(est)
    trms, tmx = H.rms_max(tr)
    m = re.search(r"step mean (\d+) ns p99 < (\d+) ns", status)
    age = re.search(r"sample age mean (\d+) us max (\d+) us", status)
    return {"rms": rms, "max": mx, "truth_rms": trms, "truth_max": tmx, "n": len(est),
            "state": P.STATE_NAMES.get(state, state), "segments": n_seg,
            "upload_s": up_s, "resent": resent,
            "step_mean_ns": float(m[1]) if m else math.nan,
            "step_p99_ns": float(m[2]) if m else math.nan, "start_boot_s": t0_boot,
            "age_mean_us": float(age[1]) if age else math.nan,
            "age_max_us": float(age[2]) if age else math.nan}


def onboard_cell(module: Path, speed: float, scale: float, out: Path, degraded: bool
                 ) -> dict[str, Any]:
    loc, why = find_px4_sitl()
    if loc is None:
        raise RuntimeError(why)
    shutil.rmtree(out, ignore_errors=True)  # tlogs append: start each cell afresh
    out.mkdir(parents=True)
    with Px4Sitl(location=loc, log=out / "px4-console.log") as px4:
        r = px4.command("dyn", str(module), "start")
        if r.returncode != 0:
            raise RuntimeError(f"module did not start: {r.stdout}")
        if degraded:
            with DegradedLink(px4.port, **LINK) as relay:
                return asyncio.run(_onboard_flight(relay.url, px4.target_system, module, px4,
                                                   speed, scale, out / "flight.tlog"))
        return asyncio.run(_onboard_flight(px4.url, px4.target_system, module, px4, speed,
                                           scale, out / "flight.tlog"))


@contextlib.contextmanager
def degraded_launch() -> Iterator[None]:
    """api_harness.launch through the degrading relay (the streamed cells)."""
    orig = H.launch

    @contextlib.contextmanager
    def launch(kind: str, log_dir: Path, **kw: Any) -> Iterator[H.Endpoint]:
        with orig(kind, log_dir, **kw) as ep:
            port = int(ep.url.rsplit(":", 1)[1])
            with DegradedLink(port, **LINK) as relay:
                yield H.Endpoint(ep.kind, relay.url, ep.target_system)

    H.launch = launch  # type: ignore[assignment]
    try:
        yield
    finally:
        H.launch = orig  # type: ignore[assignment]


@contextlib.contextmanager
def start_at_fly_on() -> Iterator[None]:
    """api_harness.fly_on waiting first for PX4's clock to reach `--start-at` (streamed cells)."""
    orig = H.fly_on

    async def fly_on(v: Vehicle, *a: Any, **kw: Any) -> Any:
        await wait_boot(v, START_AT["s"])
        return await orig(v, *a, **kw)

    H.fly_on = fly_on  # type: ignore[assignment]
    try:
        yield
    finally:
        H.fly_on = orig  # type: ignore[assignment]


def streamed_cell(mode: str, speed: float, scale: float, out: Path, degraded: bool
                  ) -> dict[str, Any]:
    with patched_figure(scale), (degraded_launch() if degraded else contextlib.nullcontext()), \
            (start_at_fly_on() if START_AT["s"] > 0.0 else contextlib.nullcontext()):
        return B._api_cell_retry("px4", mode, speed, out, 0, list(CTL), None, {})


def square_cell(module: Path, onboard: bool, out: Path) -> dict[str, Any]:
    loc, why = find_px4_sitl()
    if loc is None:
        raise RuntimeError(why)
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    with Px4Sitl(location=loc, log=out / "px4-console.log") as px4:
        if onboard:
            px4.command("dyn", str(module), "start")
        log = out / "flight.tlog"
        proc = subprocess.run(
            [sys.executable, "-m", "companion", "fly", "examples/missions/square.plan",
             *(["--onboard"] if onboard else []), "--connect", px4.url, "--target-system",
             str(px4.target_system), "--log", str(log)],
            cwd=REPO, capture_output=True, text=True, timeout=400, check=False)
        rep = json.loads(Path(str(log) + ".report.json").read_text())
    wps = rep.get("waypoints") or []
    closest = [w.get("closest_approach_m") for w in wps]
    sent = subprocess.run([sys.executable, str(HERE / "tlog_setpoints.py"), str(log)],
                          capture_output=True, text=True, timeout=120, check=False).stdout
    return {"exit": proc.returncode, "result": rep.get("result"),
            "waypoints": f"{rep.get('waypoints_reached')}/{len(wps)}",
            "worst_waypoint_m": max((c for c in closest if c is not None), default=None),
            "rms": rep.get("rms_error_m"), "max": rep.get("max_error_m"),
            "duration_s": rep.get("duration_s"), "planned_s": rep.get("planned_duration_s"),
            "companion_setpoints_in_offboard": sent.strip()}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=Path("bench_out/onboard"))
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--degraded", action="store_true")
    ap.add_argument("--square", action="store_true")
    ap.add_argument("--cells", nargs="+", default=["6:1", "8:2"], metavar="SPEED:SCALE")
    ap.add_argument("--modes", nargs="+", default=["onboard", "attitude", "position"])
    ap.add_argument("--latency", type=float, default=0.02, help="degraded link: delay [s]")
    ap.add_argument("--loss", type=float, default=0.05, help="degraded link: loss (0..1)")
    ap.add_argument("--hover-s", type=float, default=0.0,
                    help="onboard cells: hover this much longer before OFFBOARD [s]")
    ap.add_argument("--arm-at", type=float, default=0.0,
                    help="onboard cells: arm at this time since PX4's boot [s]")
    ap.add_argument("--start-at", type=float, nargs="+", default=[0.0], metavar="S",
                    help="every cell starts its figure at S seconds since PX4's boot (several: "
                         "each cell once per S, onboard and streamed paired; 0: at once)")
    ap.add_argument("--no-bend", action="store_true",
                    help="onboard cells: upload the figure as it is (default: bent ahead of "
                         "time for the tilt limit, as fly --onboard uploads)")
    ap.add_argument("--bend-margin-deg", type=float, default=None,
                    help="onboard cells: the bend's tilt margin left to the feedback [deg] "
                         "(default: ShapingConfig's, as fly --onboard)")
    ap.add_argument("--law", nargs="*", default=[], metavar="FIELD=VALUE",
                    help="onboard cells: override LawParams fields (kp/kd/ki/i_max scale the "
                         "onboard law's horizontal gains by VALUE; others are set, e.g. "
                         "vel_correction_rad_s=0 to fly without the velocity correction)")
    ap.add_argument("--ctl", nargs="*", default=[], metavar="FIELD=VALUE",
                    help="streamed cells: TrackingConfig / TrackingGains overrides "
                         "(bench_tracking's --ctl)")
    ap.add_argument("--upload-after-takeoff", action="store_true",
                    help="onboard cells: plan the figure from the hover after PX4's takeoff "
                         "and upload it then (no start offset), not on the ground")
    args = ap.parse_args(argv)
    AFTER_TAKEOFF["on"] = args.upload_after_takeoff
    BEND["on"] = not args.no_bend
    BEND["margin_deg"] = args.bend_margin_deg
    CTL[:] = args.ctl
    base = law_params(VehicleFile(), 0.5, math.radians(TILT_DEG))
    for item in args.law:
        k, v = item.split("=")
        if k in ("kp", "kd", "ki", "i_max"):
            g = getattr(base, k)
            LAW_OVERRIDE[k] = (g[0] * float(v), g[1] * float(v), g[2])
        else:
            LAW_OVERRIDE[k] = float(v)
    LINK.update(latency_s=args.latency, loss=args.loss)
    HOVER["s"] = args.hover_s
    ARM_AT["s"] = args.arm_at
    loc, why = find_px4_sitl()
    if loc is None:
        print(f"no PX4 SITL: {why}")
        return 2
    sdk = loc.root / "sdk"
    args.out.mkdir(parents=True, exist_ok=True)
    module = px4module.build_px4_module(sdk, Path("/var/tmp") / "ecca-bench-onboard.px4mod")
    rows: list[dict[str, Any]] = []
    results = args.out / "onboard.json"
    t_start = time.perf_counter()
    with flight_lock():
        for cell in args.cells:
            speed, scale = (float(x) for x in cell.split(":"))
            for link in ([False, True] if args.degraded else [False]):
                for start in args.start_at:
                    START_AT["s"] = start
                    tag = f"-s{start:g}" if start > 0.0 else ""
                    for mode in args.modes:
                        if link and mode == "position":
                            continue  # PX4's own control: no companion link in its loop
                        for k in range(args.repeat):
                            name = (f"{mode}-{speed:g}-x{scale:g}"
                                    f"{'-degraded' if link else ''}{tag}-{k}")
                            out = args.out / name
                            t = time.perf_counter()
                            try:
                                res = (onboard_cell(module, speed, scale, out, link)
                                       if mode == "onboard" else
                                       streamed_cell(mode, speed, scale, out, link))
                            except Exception as exc:  # one failed flight is reported
                                res = {"error": f"{type(exc).__name__}: {exc}"}
                            res.update(mode=mode, speed=speed, scale=scale, degraded=link,
                                       run=k, start_at=start, wall_s=time.perf_counter() - t)
                            rows.append(res)
                            print(json.dumps({k2: v for k2, v in res.items()
                                              if not isinstance(v, list)}), flush=True)
                            results.write_text(json.dumps(rows, indent=1, default=str))
        if args.square:
            for onboard in (False, True):
                res = square_cell(module, onboard, args.out / f"square-{int(onboard)}")
                res.update(mode="onboard" if onboard else "attitude", cell="square")
                rows.append(res)
                print(json.dumps(res), flush=True)
                results.write_text(json.dumps(rows, indent=1, default=str))
    print(f"wall time {time.perf_counter() - t_start:.0f} s; {results}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
