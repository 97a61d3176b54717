"""Tracking benchmark: figure-8 errors of the setpoint modes on the mock (lockstep) and, with
`--target mock px4`, through the public API on `sitl_mock serve` and real PX4 SITL side by side.

Lockstep, no MAVLink: the `sitl_mock` quadrotor model (PX4 SIH-like physics + PX4-like
controller cascade) is stepped at its physics rate; the companion controller sees telemetry at
the rate PX4 streams LOCAL_POSITION_NED/ODOMETRY (default 30 Hz) delivered one telemetry
period late, and sends setpoints at 100 Hz.

Trajectory: x = 5 sin(phi), y = 2.5 sin(2 phi), z = -5 m (NED), yaw 0; phi' ramps smoothly
(septic smoothstep, continuous through snap) from 0 to its final value over 3 s; the final value
gives the requested peak speed. Errors: horizontal distance to the reference at the same time,
over the second lap (2 pi <= phi < 4 pi).

Modes: `position` (position-only setpoints, PX4's controller closes the loop: the naive
baseline), `position_ff` (position + velocity + acceleration feed-forward), `attitude`
(companion tracking controller, q + thrust), `rates` (companion SO(3) loop, body rates + thrust).

Run: `.venv/bin/python bench/bench_tracking.py [--harness mavlink|direct] [--write]`
(--write prints the markdown table for BENCHMARKS.md). The default harness goes through MAVLink
with `sitl_mock.lockstep.LockstepSim` (ODOMETRY telemetry at 30 Hz, one period of extra
latency); `direct` steps the vehicle model with setpoint objects.
API targets (`--target mock px4`): `--param NAME=VALUE` (repeatable) changes the autopilot, not
the companion: e.g. `--param SIH_MASS=0.8` flies a lighter vehicle than the companion's default
TrackingConfig assumes (1 kg, hover 0.5), `--param MPC_THR_HOVER=0.55` gives PX4 a hover thrust
10 % off. The mock gets it as `serve --param` (its parameter store, as PARAM_SET would), PX4 as
PX4_PARAM_<NAME> at boot (rcS sets it before SIH starts; SIH also re-reads SIH_MASS on a live
parameter update); the bench reads each one back with PARAM_REQUEST_READ before the pattern and
records it per cell in OUT/tracking.json and in the table's "autopilot parameters" column.
The module also exposes the lockstep harness (`run_lockstep`, `figure8_reference`) used by
bench/tests/test_tracking_lockstep.py.
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import sys
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from companion.control import (
    Reference,
    StateEstimate,
    TrackingConfig,
    TrackingController,
    position_command,
)
from companion.flatness import MultirotorParams
from sitl_mock.params import ParamStore
from sitl_mock.setpoints import AttitudeTarget, PositionTarget, Target
from sitl_mock.vehicle import make_vehicle

FloatArray = npt.NDArray[np.float64]
MODES = ("position", "position_ff", "attitude", "rates")
RAMP_S = 3.0
FIG8_DPDPHI_MAX = math.sqrt(50.0)  # max |d p / d phi| of the figure-8 (at phi = 0)
NOISE_PARAMS = {"SIM_POS_NOISE": 0.02, "SIM_VEL_NOISE": 0.05, "SIM_GYRO_NOISE": 0.01}


# ----------------------------------------------------------------------------- reference


def _ramp_terms(t: float, omega: float) -> tuple[float, float, float, float, float]:
    """phi and its first four time derivatives for the smooth ramp of phi' to `omega`."""
    if t >= RAMP_S:
        return omega * (t - 0.5 * RAMP_S), omega, 0.0, 0.0, 0.0
    if t <= 0.0:
        return 0.0, 0.0, 0.0, 0.0, 0.0
    x = t / RAMP_S
    s = 35 * x**4 - 84 * x**5 + 70 * x**6 - 20 * x**7
    s1 = 140 * x**3 - 420 * x**4 + 420 * x**5 - 140 * x**6
    s2 = 420 * x**2 - 1680 * x**3 + 2100 * x**4 - 840 * x**5
    s3 = 840 * x - 5040 * x**2 + 8400 * x**3 - 4200 * x**4
    integral = 7 * x**5 - 14 * x**6 + 10 * x**7 - 2.5 * x**8
    T = RAMP_S
    return omega * T * integral, omega * s, omega * s1 / T, omega * s2 / T**2, omega * s3 / T**3


def figure8_reference(t: float, peak_speed: float, alt_m: float = 5.0) -> tuple[Reference, float]:
    """Figure-8 reference at time t and its phase phi (see the module docstring)."""
    omega = peak_speed / FIG8_DPDPHI_MAX
    phi, p1, p2, p3, p4 = _ramp_terms(t, omega)
    out = np.zeros((5, 3))
    for axis, (amp, k) in enumerate(((5.0, 1.0), (2.5, 2.0))):
        # f(phi) = amp sin(k phi); f^(n) = amp k^n sin(k phi + n pi / 2)
        f = [amp * k**n * math.sin(k * phi + n * math.pi / 2) for n in range(5)]
        out[0, axis] = f[0]
        out[1, axis] = f[1] * p1
        out[2, axis] = f[2] * p1**2 + f[1] * p2
        out[3, axis] = f[3] * p1**3 + 3 * f[2] * p1 * p2 + f[1] * p3
        out[4, axis] = (
            f[4] * p1**4 + 6 * f[3] * p1**2 * p2 + f[2] * (3 * p2**2 + 4 * p1 * p3) + f[1] * p4
        )
    out[0, 2] = -alt_m
    return Reference(out[0], out[1], out[2], out[3], out[4], 0.0, 0.0, 0.0), phi


# ----------------------------------------------------------------------------- harness


def _v3(a: FloatArray) -> tuple[float, float, float]:
    return (float(a[0]), float(a[1]), float(a[2]))


@dataclass
class RunResult:
    """Time series of one lockstep run (sampled at the setpoint rate)."""

    t: FloatArray
    pos: FloatArray
    ref: FloatArray
    phase: FloatArray
    hover_thrust: FloatArray
    thrust_cmd: FloatArray
    fallbacks: int
    max_tilt_deg: float
    extra: dict[str, FloatArray] = field(default_factory=dict)

    def lap_errors(self, lap: int = 2) -> tuple[float, float]:
        """(RMS, max) horizontal error [m] over lap `lap` (1-based) of the phase."""
        sel = (self.phase >= 2 * math.pi * (lap - 1)) & (self.phase < 2 * math.pi * lap)
        if not np.any(sel):
            raise ValueError(f"the run did not complete lap {lap}")
        e = np.linalg.norm(self.pos[sel, :2] - self.ref[sel, :2], axis=1)
        return float(np.sqrt(np.mean(e**2))), float(np.max(e))


def mock_params(overrides: dict[str, float] | None = None) -> ParamStore:
    """SIH-like defaults with 60 deg tilt allowed (the figure-8 at 6 m/s needs ~46 deg)."""
    ov: dict[str, float] = {"MPC_TILTMAX_AIR": 60.0}
    ov.update(overrides or {})
    return ParamStore(ov)


def default_controller_config(**kw: object) -> TrackingConfig:
    """Companion config as a user would set it for the SIH quad: nominal mass, D, hover 0.5."""
    params = MultirotorParams(1.0, np.diag([0.025, 0.025, 0.030]), hover_thrust=0.5, drag=1.0)
    return TrackingConfig(params=params, **kw)  # type: ignore[arg-type]


def run_lockstep(
    mode: str,
    reference: Callable[[float], tuple[Reference, float]],
    seconds: float,
    *,
    params: ParamStore | None = None,
    controller: TrackingController | None = None,
    physics_hz: float = 500.0,
    telemetry_hz: float = 30.0,
    setpoint_hz: float = 100.0,
    latency_s: float | None = None,
    start_pos: tuple[float, float, float] = (0.0, 0.0, -5.0),
    seed: int = 0,
    drag_per_kg: float = 0.0,
) -> RunResult:
    """Fly `reference` for `seconds` in lockstep with the mock quad in `mode` (see MODES;
    `drag_per_kg`: position_ff's drag feed-forward D/m, as `TrackingSource` sends it).

    Telemetry snapshots are taken every 1/telemetry_hz s and delivered `latency_s` later
    (default one telemetry period); setpoints are computed every 1/setpoint_hz s from the newest
    delivered snapshot and held until the next one.
    """
    if mode not in MODES:
        raise ValueError(f"unknown mode {mode!r}, use one of {MODES}")
    store = params if params is not None else mock_params()
    veh = make_vehicle("quad", store, seed=seed)
    hover_true = store["SIH_MASS"] * 9.80665 / (4.0 * store["SIH_T_MAX"])
    veh.set_state(pos_ned=start_pos, motors=hover_true)  # type: ignore[attr-defined]
    veh.mark_airborne(hover_true)  # type: ignore[attr-defined]
    ctl = controller or TrackingController(default_controller_config())
    lat = (1.0 / telemetry_hz) if latency_s is None else latency_s
    n_phys = round(seconds * physics_hz)
    dt = 1.0 / physics_hz
    tel_every = max(1, round(physics_hz / telemetry_hz))
    sp_every = max(1, round(physics_hz / setpoint_hz))
    queue: deque[tuple[float, StateEstimate]] = deque()
    latest: StateEstimate | None = None
    target: Target = PositionTarget(pos_ned=start_pos, yaw=0.0)
    ts, ps, rs, phs, hs, us = [], [], [], [], [], []
    fallbacks = 0
    max_tilt = 0.0
    for k in range(n_phys + 1):
        t = k * dt
        if k % tel_every == 0:
            s = veh.state
            est = StateEstimate(
                t, np.array(s.pos_ned), np.array(s.vel_ned), np.array(s.q_wxyz),
                np.array(s.omega_frd), None, not s.landed,
            )
            queue.append((t + lat, est))
        while queue and queue[0][0] <= t + 1e-9:
            latest = queue.popleft()[1]
        if k % sp_every == 0:
            ref, phase = reference(t)
            if mode in ("position", "position_ff"):
                pc = position_command(ref, feedforward=(mode == "position_ff"),
                                      drag_per_kg=drag_per_kg)
                target = PositionTarget(
                    _v3(pc.pos_ned), _v3(pc.vel_ned), _v3(pc.acc_ned), pc.yaw, pc.yaw_rate
                )
                thrust = math.nan
            elif latest is None:
                thrust = math.nan
            elif mode == "attitude":
                ac = ctl.attitude(t, latest, ref)
                fallbacks += ac.fallback
                q = ac.q_wxyz
                target = AttitudeTarget((float(q[0]), float(q[1]), float(q[2]), float(q[3])),
                                        ac.thrust_norm, None, ac.yaw_rate_ff)
                thrust = ac.thrust_norm
            else:
                rc = ctl.rates(t, latest, ref)
                fallbacks += rc.fallback
                target = AttitudeTarget(None, rc.thrust_norm, _v3(rc.omega_frd))
                thrust = rc.thrust_norm
            s = veh.state
            ts.append(t)
            ps.append(s.pos_ned)
            rs.append(ref.pos_ned)
            phs.append(phase)
            hs.append(ctl.hover_thrust)
            us.append(thrust)
            _w, x, y, _z = s.q_wxyz
            cz = 1.0 - 2.0 * (x * x + y * y)
            max_tilt = max(max_tilt, math.degrees(math.acos(max(-1.0, min(1.0, cz)))))
        veh.step(dt, target, True)
    return RunResult(
        np.array(ts), np.array(ps), np.array(rs), np.array(phs), np.array(hs), np.array(us),
        fallbacks, max_tilt,
    )


# ----------------------------------------------------------------------------- MAVLink lockstep


class _MavClient:
    """Minimal offboard client on pymavlink's codec for `sitl_mock.lockstep.LockstepSim`."""

    def __init__(self, sim: Any) -> None:
        from pymavlink.dialects.v20 import common as mavlink2

        self.m = mavlink2
        self.sim = sim
        self.mav = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
        self.mav.robust_parsing = True
        self.custom_mode = 0
        self.armed = False

    def send(self, msg: Any) -> None:
        self.sim.send(msg.pack(self.mav))

    def receive(self) -> list[Any]:
        out: list[Any] = []
        for d in self.sim.recv():
            for msg in self.mav.parse_buffer(d) or []:
                if msg.get_type() == "HEARTBEAT" and msg.get_srcComponent() == 1:
                    self.custom_mode = int(msg.custom_mode)
                    self.armed = bool(msg.base_mode & 128)
                out.append(msg)
        return out

    def boot_ms(self) -> int:
        return int(self.sim.now * 1000.0)

    def heartbeat(self) -> None:
        m = self.m
        self.send(m.MAVLink_heartbeat_message(m.MAV_TYPE_ONBOARD_CONTROLLER,
                                              m.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))

    def command(self, cmd: int, *params: float) -> None:
        p = [*params, *([0.0] * (7 - len(params)))]
        self.send(self.m.MAVLink_command_long_message(1, 1, cmd, 0, *p))

    def position(self, pc: Any) -> None:
        mask = 0
        for i, v in enumerate(pc.pos_ned):
            mask |= (1 << i) if not math.isfinite(v) else 0
        for i, v in enumerate(pc.vel_ned):
            mask |= (8 << i) if not math.isfinite(v) else 0
        for i, v in enumerate(pc.acc_ned):
            mask |= (64 << i) if not math.isfinite(v) else 0
        mask |= 1024 if not math.isfinite(pc.yaw) else 0
        mask |= 2048 if not math.isfinite(pc.yaw_rate) else 0

        def z(v: float) -> float:
            return v if math.isfinite(v) else 0.0

        self.send(self.m.MAVLink_set_position_target_local_ned_message(
            self.boot_ms(), 1, 1, self.m.MAV_FRAME_LOCAL_NED, mask,
            *(z(float(v)) for v in pc.pos_ned), *(z(float(v)) for v in pc.vel_ned),
            *(z(float(v)) for v in pc.acc_ned), z(pc.yaw), z(pc.yaw_rate)))

    def attitude(self, q: FloatArray, thrust: float, yaw_rate: float) -> None:
        self.send(self.m.MAVLink_set_attitude_target_message(
            self.boot_ms(), 1, 1, 3, [float(c) for c in q], 0.0, 0.0, yaw_rate, thrust))

    def rates(self, omega: FloatArray, thrust: float) -> None:
        self.send(self.m.MAVLink_set_attitude_target_message(
            self.boot_ms(), 1, 1, 128, [1.0, 0.0, 0.0, 0.0], float(omega[0]), float(omega[1]),
            float(omega[2]), thrust))


def _odometry_estimate(msg: Any) -> StateEstimate:
    """StateEstimate from ODOMETRY (LOCAL_NED pose, BODY_FRD velocity and rates)."""
    q = np.array([float(c) for c in msg.q])
    vb = np.array([msg.vx, msg.vy, msg.vz], dtype=float)
    from companion.control import quat_to_dcm

    v_ned = quat_to_dcm(q) @ vb
    return StateEstimate(msg.time_usec * 1e-6, np.array([msg.x, msg.y, msg.z], dtype=float),
                         v_ned, q, np.array([msg.rollspeed, msg.pitchspeed, msg.yawspeed]))


def run_mavlink_lockstep(
    mode: str,
    reference: Callable[[float], tuple[Reference, float]],
    seconds: float,
    *,
    params: ParamStore | None = None,
    controller: TrackingController | None = None,
    physics_hz: float = 500.0,
    setpoint_hz: float = 100.0,
    latency_s: float = 1.0 / 30.0,
    seed: int = 0,
    drag_per_kg: float = 0.0,
) -> RunResult:
    """Like `run_lockstep`, through MAVLink with `sitl_mock.lockstep.LockstepSim`.

    Arms and takes off in OFFBOARD with a position setpoint at the reference's start point,
    waits until it hovers there, then flies `reference` (time 0 = start of the pattern).
    Telemetry: ODOMETRY at PX4's onboard rate (30 Hz), delivered `latency_s` late to the
    controller; setpoints: SET_POSITION_TARGET_LOCAL_NED or SET_ATTITUDE_TARGET at setpoint_hz.
    Errors use the simulator's true state.
    """
    from sitl_mock.lockstep import LockstepSim

    if mode not in MODES:
        raise ValueError(f"unknown mode {mode!r}, use one of {MODES}")
    store = params if params is not None else mock_params()
    sim = LockstepSim("quad", store, seed=seed, physics_hz=physics_hz)
    cli = _MavClient(sim)
    ctl = controller or TrackingController(default_controller_config())
    ref0, _ = reference(0.0)
    hold = position_command(ref0, feedforward=False)
    dt = 1.0 / setpoint_hz
    # boot, prime, OFFBOARD, arm, climb to the start point and settle
    t_hb = -1.0
    offboard_sent = arm_sent = False
    settled_since: float | None = None
    while True:
        sim.step(dt)
        cli.receive()
        if sim.now - t_hb >= 1.0:
            cli.heartbeat()
            t_hb = sim.now
        cli.position(hold)
        if sim.now > 1.0 and not offboard_sent:
            cli.command(176, 1.0, 6.0, 0.0)
            offboard_sent = True
        if sim.now > 4.0 and offboard_sent and not cli.armed and not arm_sent:
            cli.command(400, 1.0)
            arm_sent = True
        if arm_sent and not cli.armed and sim.now > 6.0:
            cli.command(400, 1.0)  # retry once the estimator is surely ready
            arm_sent = sim.now < 8.0
        s = sim.autopilot.state
        close = (np.linalg.norm(np.array(s.pos_ned) - ref0.pos_ned) < 0.2
                 and np.linalg.norm(s.vel_ned) < 0.2)
        if cli.armed and cli.custom_mode == (6 << 16) and close:
            settled_since = sim.now if settled_since is None else settled_since
            if sim.now - settled_since > 1.0:
                break
        else:
            settled_since = None
        if sim.now > 40.0:
            raise RuntimeError("mock did not reach the start point in OFFBOARD within 40 s")
    t0 = sim.now
    ctl.reset()
    queue: deque[tuple[float, StateEstimate]] = deque()
    latest: StateEstimate | None = None
    ts, ps, rs, phs, hs, us = [], [], [], [], [], []
    fallbacks = 0
    max_tilt = 0.0
    n = round(seconds / dt)
    for k in range(n + 1):
        now = t0 + k * dt
        sim.step_until(now)
        for msg in cli.receive():
            if msg.get_type() == "ODOMETRY":
                est = _odometry_estimate(msg)
                queue.append((est.t_s + latency_s, est))
        while queue and queue[0][0] <= now + 1e-9:
            latest = queue.popleft()[1]
        if sim.now - t_hb >= 1.0:
            cli.heartbeat()
            t_hb = sim.now
        ref, phase = reference(now - t0)
        thrust = math.nan
        if mode in ("position", "position_ff"):
            cli.position(position_command(ref, feedforward=(mode == "position_ff"),
                                          drag_per_kg=drag_per_kg))
        elif latest is None:
            cli.position(hold)
        elif mode == "attitude":
            ac = ctl.attitude(now, latest, ref)
            fallbacks += ac.fallback
            cli.attitude(ac.q_wxyz, ac.thrust_norm, ac.yaw_rate_ff)
            thrust = ac.thrust_norm
        else:
            rc = ctl.rates(now, latest, ref)
            fallbacks += rc.fallback
            cli.rates(rc.omega_frd, rc.thrust_norm)
            thrust = rc.thrust_norm
        s = sim.autopilot.state
        ts.append(now - t0)
        ps.append(s.pos_ned)
        rs.append(ref.pos_ned)
        phs.append(phase)
        hs.append(ctl.hover_thrust)
        us.append(thrust)
        _w, x, y, _z = s.q_wxyz
        cz = 1.0 - 2.0 * (x * x + y * y)
        max_tilt = max(max_tilt, math.degrees(math.acos(max(-1.0, min(1.0, cz)))))
        if cli.custom_mode != (6 << 16):
            raise RuntimeError(f"vehicle left OFFBOARD at t = {now - t0:.2f} s")
    return RunResult(
        np.array(ts), np.array(ps), np.array(rs), np.array(phs), np.array(hs), np.array(us),
        fallbacks, max_tilt,
    )


def figure8_seconds(peak_speed: float, laps: float = 2.0) -> float:
    """Run time covering the ramp and `laps` full laps (+ a small margin, + 1 s for the
    tracking source's handover at the start: `TrackingSource.start_delay_s`, ~0.75 s)."""
    omega = peak_speed / FIG8_DPDPHI_MAX
    return 0.5 * RAMP_S + laps * 2 * math.pi / omega + 1.2


# ----------------------------------------------------------------------------- main


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="figure-8 tracking errors per setpoint mode")
    ap.add_argument("--speeds", type=float, nargs="+", default=[2.0, 6.0])
    ap.add_argument("--harness", choices=("mavlink", "direct"), default="mavlink",
                    help="mavlink: sitl_mock.lockstep over MAVLink (default); direct: step the "
                         "vehicle model with setpoint objects")
    ap.add_argument("--telemetry-hz", type=float, default=30.0,
                    help="telemetry rate of the direct harness (MAVLink: ODOMETRY at 30 Hz)")
    ap.add_argument("--noise", action="store_true",
                    help="mock sensor noise on: SIM_POS_NOISE 0.02 m, SIM_VEL_NOISE 0.05 m/s, "
                         "SIM_GYRO_NOISE 0.01 rad/s")
    ap.add_argument("--write", action="store_true", help="print the BENCHMARKS.md table")
    ap.add_argument("--target", nargs="+", choices=("lockstep", "mock", "px4"),
                    default=["lockstep"],
                    help="lockstep: the mock in lockstep (default); mock / px4: the companion's "
                         "public API (Vehicle + TrackingSource) over UDP against `sitl_mock "
                         "serve` / a real PX4 SITL, in real time, one fresh autopilot per run "
                         "(several targets: side by side in one run)")
    ap.add_argument("--modes", nargs="+", default=None,
                    help="API targets: modes to fly (default position attitude rates, plus the "
                         "hover floor 'hover')")
    ap.add_argument("--repeat", type=int, default=1, help="API targets: runs per cell")
    ap.add_argument("--reuse", action="append", default=[], metavar="JSON",
                    help="API targets: add the rows of an earlier run (its OUT/tracking.json) "
                         "for targets this run does not fly, e.g. the mock beside a PX4 run")
    ap.add_argument("--request-hz", type=float, default=None,
                    help="API targets: request LOCAL_POSITION_NED and ATTITUDE_QUATERNION at "
                         "this rate (default: the autopilot's, 30/50 Hz on PX4)")
    ap.add_argument("--ctl", action="append", default=[], metavar="NAME=VALUE",
                    help="API targets: override a TrackingConfig/TrackingGains field (tuning)")
    ap.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                    help="API targets: set an autopilot parameter before the flight "
                         "(repeatable; mock: `serve --param`, PX4: PX4_PARAM_<NAME> at boot, "
                         "before SIH starts), read back over MAVLink; the companion is not "
                         "told (its TrackingConfig stays the default). E.g. SIH_MASS=0.8, "
                         "MPC_THR_HOVER=0.55. Recorded per cell; rows of other parameters "
                         "from --reuse sit beside this run's")
    ap.add_argument("--out", default=None,
                    help="API targets: folder for tlogs, autopilot logs and tracking.json "
                         "(default bench_out/tracking, with --param bench_out/tracking-NAME=V)")
    ap.add_argument("--ablation", action="store_true",
                    help="instead: companion modes at 6 m/s without drag feed-forward and/or "
                         "without the attitude lead (comparable to PX4 SITL's PD + flatness)")
    args = ap.parse_args(argv)
    try:
        params = parse_params(args.param)
    except ValueError as exc:
        ap.error(str(exc))
    if params and (args.ablation or args.target == ["lockstep"]):
        ap.error("--param sets the autopilot's parameters: --target mock and/or px4")
    if args.out is None:
        args.out = "bench_out/tracking" + "".join(f"-{k}={v:g}" for k, v in params.items())
    if args.ablation:
        return _ablation(args)
    if args.target != ["lockstep"]:
        if "lockstep" in args.target:
            ap.error("--target lockstep cannot be combined with mock/px4")
        return _api_main(args)
    rows: list[tuple[float, str, float, float, float]] = []
    store_overrides = NOISE_PARAMS if args.noise else {}
    t0 = time.perf_counter()
    for v in args.speeds:
        secs = figure8_seconds(v)

        def ref(t: float, v: float = v) -> tuple[Reference, float]:
            return figure8_reference(t, v)

        for mode in MODES:
            if args.harness == "mavlink":
                res = run_mavlink_lockstep(mode, ref, secs, params=mock_params(store_overrides))
            else:
                res = run_lockstep(mode, ref, secs, telemetry_hz=args.telemetry_hz,
                                   params=mock_params(store_overrides))
            rms, mx = res.lap_errors(2)
            rows.append((v, mode, rms, mx, res.max_tilt_deg))
            print(f"{v:4.1f} m/s {mode:12s} RMS {rms:6.3f} m  max {mx:6.3f} m  "
                  f"tilt {res.max_tilt_deg:5.1f} deg  fallbacks {res.fallbacks}", flush=True)
    print(f"wall time {time.perf_counter() - t0:.1f} s")
    base = {v: r for v, m, r, _, _ in rows if m == "position"}
    for v, mode, rms, _, _ in rows:
        if mode != "position":
            print(f"{v:4.1f} m/s {mode:12s} RMS / position-only = {rms / base[v]:.3f}")
    if 6.0 in base:
        dev = base[6.0] / 4.6 - 1.0
        print(f"position-only baseline at 6 m/s: {base[6.0]:.2f} m vs PX4 SITL 4.6 m "
              f"({dev:+.0%}, {'within' if abs(dev) <= 0.3 else 'OUTSIDE'} 30 %)")
    if args.write:
        print()
        print("| peak speed | mode | RMS [m] | max [m] | RMS / position-only | max tilt [deg] |")
        print("|---|---|---|---|---|---|")
        for v, mode, rms, mx, tilt in rows:
            print(f"| {v:.0f} m/s | {mode} | {rms:.3f} | {mx:.3f} | {rms / base[v]:.3f} | "
                  f"{tilt:.1f} |")
    return 0


# ----------------------------------------------------------------------------- API targets

API_MODES = ("position", "attitude", "rates")
HOVER_S = 30.0


def _controller_factory(overrides: list[str]) -> Any:
    """A TrackingSource factory with TrackingConfig / TrackingGains fields overridden
    (`kp_xy=12`, `attitude_lead_s=0.1`, ...; `hover_thrust=0.55`: the hover thrust the companion
    is told, `mass=0.8` likewise; `tilt_max_deg=50`: the tilt limit it is told, default PX4's
    45 deg); None without overrides (the defaults)."""
    if not overrides:
        return None
    from dataclasses import fields, replace

    from companion.control import AttitudeGains, TrackingGains
    from companion.flight.report import SetpointLimits
    from companion.flight.tracking import TrackingSource

    gain_names = {f.name for f in fields(TrackingGains)}
    att_names = {f.name for f in fields(AttitudeGains)}
    gkw: dict[str, object] = {}
    akw: dict[str, object] = {}
    ckw: dict[str, object] = {}
    pkw: dict[str, object] = {}
    tilt_deg: float | None = None
    for item in overrides:
        k, _, v = item.partition("=")
        val: object = {"true": True, "false": False}.get(v.lower())
        if val is None:
            try:
                val = float(v)
            except ValueError:
                val = v
        if k in ("hover_thrust", "mass"):  # what the companion is told (MultirotorParams)
            pkw[k] = val
            continue
        if k == "tilt_max_deg":  # the tilt limit the companion is told (PX4's MPC_TILTMAX_AIR)
            tilt_deg = float(val)  # type: ignore[arg-type]
            continue
        (gkw if k in gain_names else akw if k in att_names else ckw)[k] = val
    base = default_controller_config()
    cfg = replace(base, gains=replace(base.gains, **gkw),
                  attitude_gains=replace(base.attitude_gains, **akw),
                  params=replace(base.params, **pkw), **ckw)

    limits = None if tilt_deg is None else SetpointLimits(tilt_max_rad=math.radians(tilt_deg))
    if limits is not None:
        cfg = replace(cfg, max_tilt_rad=limits.tilt_max_rad)

    def factory(ref: Any, mode: str) -> Any:
        return TrackingSource(ref, mode, tracking=cfg, limits=limits)

    return factory


#: Run i of a cell holds i x this long after the takeoff before it starts [s]: PX4 SITL's sensor
#: noise is the same in every launch (bench_fidelity.py), so unstaggered repeats measure one
#: stretch of EKF2's error again instead of another one.
STAGGER_S = 7.0


def parse_params(items: list[str]) -> dict[str, float]:
    """`--param NAME=VALUE` items as {NAME: value} (ValueError on a malformed one)."""
    out: dict[str, float] = {}
    for item in items:
        name, sep, value = item.partition("=")
        name = name.strip().upper()
        try:
            val = float(value)
        except ValueError:
            val = math.nan
        if not (sep and name and math.isfinite(val)):
            raise ValueError(f"--param needs NAME=VALUE with a finite number, got {item!r}")
        out[name] = val
    return out


def _api_cell(target: str, mode: str, speed: float, out: Path, idx: int,
              ctl: list[str] | None = None, telemetry_hz: float | None = None,
              params: dict[str, float] | None = None) -> dict[str, float]:
    """One flight on a fresh autopilot (run `idx` holds idx x STAGGER_S after the takeoff);
    lap-2 (or hover) errors vs the estimate and the truth, and the companion's hover-thrust
    estimate at the end. `params`: autopilot parameters set before it starts (the mock's
    `--param`, PX4's PX4_PARAM_<NAME> at boot) and read back over MAVLink before the pattern
    (a name the autopilot does not have, or another value, fails the cell)."""
    import asyncio

    import api_harness as H  # noqa: N812
    from tracking_report import params_label

    params = params or {}
    factory = _controller_factory(ctl or [])

    async def before(v: Any) -> None:
        if params:
            got = await v.read_params(list(params))  # PARAM_REQUEST_READ: the user's check
            bad = {k: got[k] for k, want in params.items()
                   if not math.isclose(got[k], want, rel_tol=1e-6, abs_tol=1e-6)}
            if bad:
                raise RuntimeError(f"{target} reports {bad}, not the values set ({params})")
        await asyncio.sleep(STAGGER_S * idx)  # a hold of the bench (docstring), not a sync

    slug = "" if not params else "-" + params_label(params).replace(", ", "-")
    folder = out / f"{target}-{mode}-{speed:g}{slug}-{idx}"
    shutil.rmtree(folder, ignore_errors=True)  # tlogs append: start each cell afresh
    mock_args = tuple(a for k, v in params.items() for a in ("--param", f"{k}={v!r}"))
    with H.launch(target, folder, mock_args=mock_args, px4_params=params or None) as ep:
        if mode in ("hover", "px4_hold"):
            def hold_ref(t: float) -> tuple[Reference, float]:
                return Reference(np.array([0.0, 0.0, -5.0])), 0.0

            duration = HOVER_S + 5.0
            fl = asyncio.run(H.fly_reference(
                ep, "attitude" if mode == "hover" else "position",
                lambda t: hold_ref(t)[0], duration, tlog=folder / "flight.tlog",
                source_factory=factory, telemetry_hz=telemetry_hz, before=before))

            def select(t: float) -> bool:
                return t >= 5.0
        else:
            def ref8(t: float) -> Reference:
                return figure8_reference(t, speed)[0]

            duration = figure8_seconds(speed)
            fl = asyncio.run(H.fly_reference(ep, mode, ref8, duration,
                                              tlog=folder / "flight.tlog",
                                              source_factory=factory,
                                              telemetry_hz=telemetry_hz, before=before))
            def select(t: float) -> bool:
                return 2 * math.pi <= figure8_reference(t, speed)[1] < 4 * math.pi

        data = H.read_flight_tlog(fl.tlog, ep.target_system)
    est = H.horizontal_errors(data.lpos_t, data.lpos[:, :3], fl, select)
    rms, mx = H.rms_max(est)
    tr = H.horizontal_errors(data.truth_t, data.truth, fl, select)
    trms, tmx = H.rms_max(tr)
    if len(tr) == 0:  # the mock has no estimator: its estimate is the truth
        trms, tmx = rms, mx
    ctl_used = getattr(fl.notes.get("source"), "controller", None)  # None in position mode
    hover = float(ctl_used.hover_thrust) if ctl_used is not None else math.nan
    src = fl.notes.get("source")
    figs = src.estimates() if src is not None and hasattr(src, "estimates") else None
    return {"rms": rms, "max": mx, "truth_rms": trms, "truth_max": tmx, "n": float(len(est)),
            "hover_est": hover,
            # the law's own: how far it slowed its reference (the errors here are against the
            # plan's clock), the disturbance it estimated
            "slowed_s": math.nan if figs is None else figs.slowed_s,
            "dist": math.nan if figs is None else figs.disturbance_m_s2}


def _api_cell_retry(target: str, mode: str, speed: float, out: Path, idx: int,
                    ctl: list[str], telemetry_hz: float | None, params: dict[str, float]
                    ) -> dict[str, float]:
    """`_api_cell`, flown once more on a fresh autopilot if the first attempt fails (the
    failure is printed: a flaky start on a loaded machine must not cost a 30-minute run)."""
    try:
        return _api_cell(target, mode, speed, out, idx, ctl, telemetry_hz, params)
    except Exception as exc:  # reported, then one retry
        print(f"{target} {mode} {speed:g} m/s run {idx}: {type(exc).__name__}: {exc}; "
              "flying it again", flush=True)
        return _api_cell(target, mode, speed, out, idx, ctl, telemetry_hz, params)


def _api_main(args: argparse.Namespace) -> int:
    import tracking_report as R  # noqa: N812

    params = parse_params(args.param)
    label = R.params_label(params)
    out = Path(args.out)
    modes = args.modes or [*API_MODES, "hover", "px4_hold"]
    rows: list[R.Row] = []
    t_start = time.perf_counter()
    cells: list[tuple[str, float]] = []
    for mode in modes:
        if mode in ("hover", "px4_hold"):
            cells.append((mode, 0.0))
        else:
            cells += [(mode, v) for v in args.speeds]
    for mode, v in cells:
        for target in args.target:
            runs = [_api_cell_retry(target, mode, v, out, i, args.ctl, args.request_hz, params)
                    for i in range(args.repeat)]
            agg: dict[str, Any] = {k: float(np.median([r[k] for r in runs])) for k in runs[0]}
            agg["rms_lo"] = min(r["rms"] for r in runs)
            agg["rms_hi"] = max(r["rms"] for r in runs)
            for i, r in enumerate(runs):  # each run's own figure, for paired comparisons
                agg[f"rms_{i}"] = r["rms"]
            agg["params"] = dict(params)  # the autopilot's, set and read back ({}: defaults)
            rows.append((target, mode, v, agg))
            print(f"{target:5s} {mode:9s} {v:4.1f} m/s [{label}] estimate RMS {agg['rms']:.3f} m "
                  f"(runs {agg['rms_lo']:.3f}-{agg['rms_hi']:.3f}) max {agg['max']:.3f} m | "
                  f"truth RMS {agg['truth_rms']:.3f} max {agg['truth_max']:.3f} m | "
                  f"companion hover estimate {agg['hover_est']:.3f} | slowed "
                  f"{agg['slowed_s']:.2f} s, disturbance {agg['dist']:.2f} m/s^2", flush=True)
    wall = time.perf_counter() - t_start
    print(f"wall time {wall:.0f} s")
    out.mkdir(parents=True, exist_ok=True)
    record = {"date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
              "argv": " ".join(sys.argv[1:]), "wall_s": wall, "repeat": args.repeat,
              "params": params, "rows": rows}
    (out / "tracking.json").write_text(json.dumps(record))
    repeats = {t: {args.repeat} for t in args.target}
    flown = {(t, label) for t in args.target}
    reused = []
    for path in args.reuse:  # rows of other targets or other parameters than this run's
        old = json.loads(Path(path).read_text())
        keep = [r for r in old["rows"] if (r[0], R.row_label(r)) not in flown]
        if not keep:
            continue
        rows += [(t, m, float(v), a) for t, m, v, a in keep]
        for t in dict.fromkeys(r[0] for r in keep):
            repeats.setdefault(t, set()).add(int(old["repeat"]))
        reused.append(f"`{old['argv']}` ({old['date']}, {old['wall_s'] / 60:.0f} min)")
    targets = [t for t in ("mock", "px4") if t in repeats]
    if args.write:
        table = R.api_table(rows, targets, repeats, STAGGER_S)
        print()
        print(table)
        if not args.ctl:  # tuning runs never overwrite the record of the defaults
            with_params = any(R.row_label(r) != "default" for r in rows)
            R.write_api_section(table, args, wall, reused, with_params)
    return 0


def _ablation(args: argparse.Namespace) -> int:
    variants: list[tuple[str, dict[str, object]]] = [
        ("full (drag ff, lead 0.15 s)", {}),
        ("drag ff, no lead", {"attitude_lead_s": 0.0}),
        ("no drag ff, lead 0.15 s", {"drag_feedforward": False}),
        ("no drag ff, no lead", {"drag_feedforward": False, "attitude_lead_s": 0.0}),
    ]
    print("| mode | variant | RMS [m] | max [m] |")
    print("|---|---|---|---|")
    for mode in ("attitude", "rates"):
        for label, kw in variants:
            if mode == "rates" and "attitude_lead_s" in kw:
                continue  # rates mode uses no lead
            ctl = TrackingController(default_controller_config(**kw))
            ref = lambda t: figure8_reference(t, 6.0)  # noqa: E731
            if args.harness == "mavlink":
                res = run_mavlink_lockstep(mode, ref, figure8_seconds(6.0), controller=ctl)
            else:
                res = run_lockstep(mode, ref, figure8_seconds(6.0), controller=ctl)
            rms, mx = res.lap_errors(2)
            if mode == "rates":  # no lead in rates mode
                label = label.replace(", lead 0.15 s", "").replace("full (drag ff)", "full")
            print(f"| {mode} | {label} | {rms:.3f} | {mx:.3f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
