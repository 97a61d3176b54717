"""Flights through the companion's public API (`Vehicle` + `TrackingSource`) against a real PX4
SITL or the mock over UDP, and their analysis from the flight's .tlog.

Used by bench_tracking.py (`--target mock|px4`) and bench_fidelity.py, so the mock and real PX4
are flown by the same code in the same run.

Metrics come from the .tlog (receive times in Unix seconds), from the autopilot's own messages:
- estimate: LOCAL_POSITION_NED, placed at its sample time (time_boot_ms mapped to the local
  clock by `clock_map`: the lower envelope of receive - boot time, without the link latency,
  following the autopilot clock's drift);
- truth: HIL_STATE_QUATERNION (PX4 SITL streams the simulator's state on request; so does the
  mock, its true state, since its rover got an estimate model), projected to PX4's local frame
  through HOME_POSITION (geodetic + local position of home).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import subprocess
import sys
import time
from collections.abc import AsyncIterator, Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from pymavlink import mavutil

from companion.aio import CommandError, Vehicle, VehicleConfig
from companion.control import Reference
from companion.flight.tracking import TrackingSource
from companion.mavlink import LinkConfig, TelemetrySnapshot
from companion.mission import GeoPoint, geodetic_to_ned

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from px4_harness import Px4Sitl, find_px4_sitl  # noqa: E402

FloatArray = npt.NDArray[np.float64]
HIL_STATE_QUATERNION = 115
LOCAL_POSITION_NED = 32
ATTITUDE_QUATERNION = 31
TARGETS = ("mock", "px4")


@dataclass(frozen=True)
class Endpoint:
    """Where the companion connects: URL and the autopilot's system id."""

    kind: str
    url: str
    target_system: int


@contextlib.contextmanager
def launch(kind: str, log_dir: Path, *, mock_args: tuple[str, ...] = (),
           px4_params: dict[str, float] | None = None) -> Iterator[Endpoint]:
    """A fresh autopilot: real PX4 SITL (`px4`) or `python -m sitl_mock serve` (`mock`), both in
    real time on loopback; stopped on exit."""
    log_dir.mkdir(parents=True, exist_ok=True)
    if kind == "px4":
        loc, why = find_px4_sitl()
        if loc is None:
            raise RuntimeError(f"no PX4 SITL: {why}")
        with Px4Sitl(location=loc, params=px4_params, log=log_dir / "px4-console.log") as px4:
            yield Endpoint("px4", px4.url, px4.target_system)
        return
    if kind != "mock":
        raise ValueError(f"unknown target {kind!r}, use one of {TARGETS}")
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = int(s.getsockname()[1])
    err = open(log_dir / "mock-stderr.log", "w")  # noqa: SIM115
    proc = subprocess.Popen(
        [sys.executable, "-m", "sitl_mock", "serve", "--bind", "127.0.0.1:0", "--remote",
         f"127.0.0.1:{port}", "--no-gcs", "--speed", "1", *mock_args],
        stdout=subprocess.PIPE, stderr=err, text=True)
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        if not line.startswith("sitl_mock ready"):
            raise RuntimeError(f"mock did not start: {line!r}")
        yield Endpoint("mock", f"udpin://127.0.0.1:{port}", 1)
    finally:
        proc.terminate()
        try:
            proc.wait(5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)
        if proc.stdout is not None:
            proc.stdout.close()
        err.close()


# ----------------------------------------------------------------------------- flying


class ReferenceRecorder:
    """A setpoint source wrapper that remembers when reference time 0 was (Unix seconds), and
    the flight time it was given at each call (`clock`: Unix seconds, flight time [s]). The
    flight's clock follows the autopilot's (`companion.flight.clock.FlightClock`): PX4 SITL's
    runs ~1.2 % slower than the wall clock on this host, so a reference timed by the wall clock
    drifts ~0.7 s behind the flown one over a 60 s figure-8."""

    def __init__(self, source: Callable[[float, TelemetrySnapshot], Any]) -> None:
        self.source = source
        self.clock: list[tuple[float, float]] = []
        #: per setpoint of a multirotor TrackingSource (`TRACE_FIELDS`), for diagnosis
        self.trace: list[tuple[float, ...]] = []

    @property
    def t0_unix(self) -> float | None:
        """When flight time 0 was [Unix s] (None before the first setpoint)."""
        return self.clock[0][0] - self.clock[0][1] if self.clock else None

    def __getattr__(self, name: str) -> Any:
        # what the flight reads of its source (reference_time_s, arrived, stalled_s, blind_s:
        # `Vehicle._flight_view`) is the wrapped source's: without it the recorded flights
        # lost the law's blind safety net (BLIND_S)
        if name == "source":  # (not set yet)
            raise AttributeError(name)
        return getattr(self.source, name)

    def __call__(self, t_s: float, telemetry: TelemetrySnapshot) -> Any:
        if t_s <= 0.0:
            return self.source(t_s, telemetry)
        self.clock.append((time.time() - (time.monotonic() - telemetry.now_s), t_s))
        out = self.source(t_s, telemetry)
        row = trace_row(self.source, t_s, out)
        if row is not None:
            self.trace.append(row)
        return out


#: Columns of `ReferenceRecorder.trace` (NED, SI units): flight time, reference time, the
#: time scaler's rate, the flown reference's position / velocity / acceleration, the plan's
#: position at the reference time (the bend is the difference), the estimate's position, the
#: controller's disturbance and drag per mass and hover thrust, the command (thrust, and the
#: body rates of rates mode).
TRACE_FIELDS = ("t", "t_ref", "rate", "rx", "ry", "rz", "rvx", "rvy", "rvz", "rax", "ray",
                "raz", "px", "py", "ex", "ey", "ez", "dx", "dy", "dm", "hover", "thrust",
                "wx", "wy", "wz")


def trace_row(source: Any, t_s: float, out: Any) -> tuple[float, ...] | None:
    """One `TRACE_FIELDS` row of a TrackingSource's last call (None for other sources)."""
    ctl = getattr(source, "controller", None)
    ref = getattr(source, "last_reference", None)
    if ctl is None or ref is None:
        return None
    t_ref = source.reference_time_s
    t_ref = t_s if t_ref is None else t_ref
    gov = source.governor
    p = source.reference(max(t_ref, 0.0)).pos_ned.tolist()
    est = source._est  # the estimate the call used (None before the first telemetry)
    e = est.pos_ned.tolist() if est is not None else [math.nan] * 3
    w = getattr(out, "omega_frd", (math.nan,) * 3)
    d = ctl.disturbance.acc_ne
    return (t_s, t_ref, gov.rate if gov is not None else 1.0, *ref.pos_ned.tolist(),
            *ref.vel_ned.tolist(), *ref.acc_ned.tolist(), p[0], p[1], *e, d[0], d[1],
            ctl.drag / ctl.config.params.mass, ctl.hover_thrust,
            float(getattr(out, "thrust_norm", math.nan)), *w)


@dataclass
class Flight:
    """One flight of a reference: its tlog, when reference time 0 was, the flight time given at
    each setpoint (`clock`: rows Unix s, flight time s; `ReferenceRecorder`) and the source's
    handover delay (`TrackingSource.start_delay_s`)."""

    tlog: Path
    t0_unix: float
    duration_s: float
    reference: Callable[[float], Reference]
    origin_ned: FloatArray
    notes: dict[str, Any] = field(default_factory=dict)
    clock: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    start_delay_s: float = 0.0


def shifted(reference: Callable[[float], Reference], dx: float, dy: float
            ) -> Callable[[float], Reference]:
    """`reference` moved horizontally by (dx, dy) [m]."""
    off = np.array([dx, dy, 0.0])

    def ref(t: float) -> Reference:
        r = reference(t)
        return Reference(r.pos_ned + off, r.vel_ned, r.acc_ned, r.jerk_ned, r.snap_ned, r.yaw,
                         r.yaw_rate, r.yaw_acc)

    return ref


@contextlib.asynccontextmanager
async def airborne(ep: Endpoint, *, tlog: Path, alt_m: float = 5.0, truth_hz: float = 50.0,
                   telemetry_hz: float | None = None) -> AsyncIterator[Vehicle]:
    """Connect (recording `tlog`), stream ground truth, arm and take off to `alt_m`; yields the
    hovering vehicle. It is left in the air: the caller stops the autopilot."""
    # stale telemetry after 1 s (default 0.5 s): on the shared 2-core bench host a loaded moment
    # must not end a flight that measures the autopilot
    config = VehicleConfig(tlog_path=str(tlog), connect_timeout_s=20.0, armable_timeout_s=40.0,
                           stale_telemetry_s=1.0)
    async with Vehicle.connect(ep.url, config=config,
                               link_config=LinkConfig(target_sysid=ep.target_system)) as v:
        with contextlib.suppress(CommandError):  # older mocks had no separate ground truth
            await v.set_message_interval(HIL_STATE_QUATERNION, truth_hz)
        if telemetry_hz is not None:
            for msg_id in (LOCAL_POSITION_NED, ATTITUDE_QUATERNION):
                await v.set_message_interval(msg_id, telemetry_hz)
        await v.arm()
        await v.takeoff(alt_m)
        await asyncio.sleep(1.0)  # let the takeoff transient settle (not synchronisation)
        yield v


async def fresh_position(v: Vehicle, timeout_s: float = 5.0, max_age_s: float = 0.2) -> None:
    """Wait (bounded) until the latest LOCAL_POSITION_NED is at most `max_age_s` old: `fly`
    refuses to start on stale telemetry, which a loaded machine can delay for a moment."""
    t_end = time.monotonic() + timeout_s
    while time.monotonic() < t_end:
        pos = v.telemetry.position
        if pos is not None and time.monotonic() - pos.t_s <= max_age_s:
            return
        await asyncio.sleep(0.02)


async def fly_on(v: Vehicle, mode: str, reference: Callable[[float], Reference],
                 duration_s: float, *, source_factory: Callable[..., Any] | None = None
                 ) -> Flight:
    """Fly `reference` (shifted horizontally to start where the vehicle is) in `mode` for
    `duration_s` with a `TrackingSource` (or `source_factory(reference, mode)`), then Hold."""
    from companion.planning.config import VehicleFile

    await fresh_position(v)
    pos = v.telemetry.position
    assert pos is not None
    r0 = reference(0.0).pos_ned
    ref = shifted(reference, pos.pos_ned[0] - r0[0], pos.pos_ned[1] - r0[1])
    if source_factory is None:
        params = VehicleFile().params

        def source_factory(r: Callable[[float], Reference], m: str) -> Any:
            return TrackingSource(r, m, params)

    rec = ReferenceRecorder(source_factory(ref, mode))
    await v.fly(mode=mode, setpoint_source=rec, duration_s=duration_s)
    assert rec.t0_unix is not None
    if rec.trace and v.config.tlog_path:
        np.savez_compressed(Path(v.config.tlog_path).with_name("trace.npz"),
                            fields=np.array(TRACE_FIELDS), trace=np.array(rec.trace))
    return Flight(Path(v.config.tlog_path or ""), rec.t0_unix, duration_s, ref,
                  np.array(ref(0.0).pos_ned), {"source": rec.source},
                  np.array(rec.clock).reshape(-1, 2),
                  float(getattr(rec.source, "start_delay_s", 0.0)))


async def fly_reference(
    ep: Endpoint, mode: str, reference: Callable[[float], Reference], duration_s: float, *,
    tlog: Path, alt_m: float = 5.0, source_factory: Callable[..., Any] | None = None,
    truth_hz: float = 50.0, before: Callable[[Vehicle], Any] | None = None,
    telemetry_hz: float | None = None,
) -> Flight:
    """Connect, stream ground truth, arm, take off to `alt_m`, fly `reference` (shifted to start
    where the takeoff ended) in `mode` for `duration_s`, then hold. The vehicle is left in the
    air: the caller stops the autopilot."""
    async with airborne(ep, tlog=tlog, alt_m=alt_m, truth_hz=truth_hz,
                        telemetry_hz=telemetry_hz) as v:
        if before is not None:
            await before(v)
        return await fly_on(v, mode, reference, duration_s, source_factory=source_factory)


# ----------------------------------------------------------------------------- tlog analysis


@dataclass
class TlogData:
    """Autopilot messages of one flight (receive times in Unix seconds)."""

    lpos_t: FloatArray  # sample time (time_boot mapped to the local clock)
    lpos: FloatArray  # (N, 6) x y z vx vy vz
    truth_t: FloatArray
    truth: FloatArray  # (M, 3) local NED
    att_t: FloatArray
    att_rpy: FloatArray  # (K, 3) roll pitch yaw [rad] (ATTITUDE)
    att_rates: FloatArray  # (K, 3) body rates [rad/s]
    extra: dict[str, list[Any]]
    lpos_recv: FloatArray = field(default_factory=lambda: np.zeros(0))  # receive times
    lpos_boot: FloatArray = field(default_factory=lambda: np.zeros(0))  # time_boot [s]


def clock_map(boot_s: FloatArray, recv_s: FloatArray, block_s: float = 0.25) -> FloatArray:
    """Local times of samples stamped `boot_s` (the autopilot's clock) received at `recv_s`.

    Each sample gives recv - boot = offset + link delay (delay >= 0). The offset is taken as the
    lower envelope of recv - boot: the smallest value in each `block_s` of boot time, linearly
    interpolated between those samples (constant beyond the first/last). Local, because real
    PX4 SITL's offset does not follow a line: its lockstep clock (SIH steps 4 ms of simulated
    time, then sleeps; simulator_sih `lockstep_loop`) falls behind ours by ~0.7-1.1 % on
    average and by more whenever the host is busy, so a line fitted below the whole flight's
    minima sat 16 ms (median; 4-29 ms) below the offset PX4's own TIMESYNC replies give in a
    220 s flight, moving every PX4 sample 16 ms early. The envelope agrees with TIMESYNC within
    the 4 ms lockstep step (PX4 and the mock). Assumes some sample of each block met (nearly)
    no delay: true on loopback, where telemetry leaves within a step of its sample."""
    if len(boot_s) == 0:
        return boot_s
    off = recv_s - boot_s
    blk = np.floor(boot_s / block_s).astype(np.int64)
    order = np.lexsort((off, blk))  # by block, then offset: the first of each block is its min
    first = order[np.r_[True, blk[order][1:] != blk[order][:-1]]]
    first = first[np.argsort(boot_s[first], kind="stable")]
    return boot_s + np.interp(boot_s, boot_s[first], off[first])


def read_flight_tlog(path: Path, target_system: int, keep: tuple[str, ...] = ()) -> TlogData:
    """Decode `path`; messages of the autopilot (`target_system`, component 1) only."""
    conn = mavutil.mavlink_connection(str(path))
    lp: list[tuple[float, ...]] = []
    hil: list[tuple[float, float, float, float]] = []
    att: list[tuple[float, ...]] = []
    home: tuple[float, float, float, float, float, float] | None = None
    extra: dict[str, list[Any]] = {k: [] for k in keep}
    want = ["LOCAL_POSITION_NED", "HIL_STATE_QUATERNION", "HOME_POSITION", "ATTITUDE", *keep]
    try:
        for _ in range(10_000_000):
            m = conn.recv_match(type=want)
            if m is None:
                break
            if m.get_srcSystem() != target_system or m.get_srcComponent() != 1:
                continue
            kind = m.get_type()
            t = float(m._timestamp)
            if kind == "LOCAL_POSITION_NED":
                lp.append((t, m.time_boot_ms * 1e-3, m.x, m.y, m.z, m.vx, m.vy, m.vz))
            elif kind == "HIL_STATE_QUATERNION":
                hil.append((t, m.lat * 1e-7, m.lon * 1e-7, m.alt * 1e-3))
            elif kind == "HOME_POSITION":
                home = (m.latitude * 1e-7, m.longitude * 1e-7, m.altitude * 1e-3, m.x, m.y, m.z)
            elif kind == "ATTITUDE":
                att.append((t, m.time_boot_ms * 1e-3, m.roll, m.pitch, m.yaw, m.rollspeed,
                            m.pitchspeed, m.yawspeed))
            if kind in extra:
                extra[kind].append(m)
    finally:
        conn.close()
    lpa = np.array(lp, dtype=float).reshape(-1, 8)
    truth_t = np.zeros(0)
    truth = np.zeros((0, 3))
    if hil and home is not None:
        h = np.array(hil)
        g = GeoPoint(home[0], home[1], home[2])
        truth = geodetic_to_ned(h[:, 1], h[:, 2], h[:, 3], g) + np.array(home[3:])
        truth_t = h[:, 0]
    ata = np.array(att, dtype=float).reshape(-1, 8)
    return TlogData(clock_map(lpa[:, 1], lpa[:, 0]), lpa[:, 2:8], truth_t, truth,
                    clock_map(ata[:, 1], ata[:, 0]), ata[:, 2:5], ata[:, 5:8], extra,
                    lpa[:, 0], lpa[:, 1])


def horizontal_errors(t_unix: FloatArray, pos: FloatArray, flight: Flight,
                      select: Callable[[float], bool]) -> FloatArray:
    """|pos - reference| horizontally [m] at the samples whose reference time passes `select`.
    Reference time is the plan's clock of the flight: the flight time the source was given at
    that moment (`Flight.clock`; else the time since the first setpoint) less its handover
    delay (`Flight.start_delay_s`, about 0.75 s in attitude and rates mode), not less any
    slowing down for the vehicle (reported apart, as slowed_s)."""
    delay, clock = flight.start_delay_s, flight.clock
    flown = (np.interp(np.asarray(t_unix, dtype=float), clock[:, 0], clock[:, 1],
                       left=math.nan, right=math.nan)  # only while it flew
             if len(clock) > 1 else np.asarray(t_unix, dtype=float) - flight.t0_unix)
    out = []
    for t, p in zip(flown, pos, strict=True):
        tr = float(t) - delay
        if 0.0 <= tr <= flight.duration_s - delay and select(tr):  # the flown part
            r = flight.reference(tr).pos_ned
            out.append(math.hypot(p[0] - r[0], p[1] - r[1]))
    return np.array(out)


def rms_max(e: FloatArray) -> tuple[float, float]:
    """(RMS, max) of an error series (NaN when empty)."""
    if len(e) == 0:
        return math.nan, math.nan
    return float(np.sqrt(np.mean(e**2))), float(np.max(e))
