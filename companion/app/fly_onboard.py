"""`fly --onboard`: the flight planned here, flown by the onboard PX4 module (gen_c/px4_module).

Order (nothing that moves the vehicle before every check passed): connect; ask the module for
its state (no answer, or not ready: exit 2 with nothing else sent); read PX4's planning
parameters; plan; the mission's home against the vehicle; the trajectory as degree-7 segments
(at most the module's 256); upload it part by part and verify its CRC-32 with the module (a
trajectory that does not verify is never flown: exit 2). Then OFFBOARD (the module publishes
offboard_control_mode while it holds a verified trajectory), arm in OFFBOARD, and follow the
module's reports: it flies the trajectory, holds its end and commands the mission's final
action itself. The companion sends no setpoint; if it or its link dies the module finishes.
A pilot's mode change stops the module for good (exit 1, the vehicle left to the pilot).
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from rich.console import Console
from rich.markup import escape

from companion.flight.policy import HANDOVER_HEIGHT_M
from companion.flight.report import FloatArray, SetpointLimits, TrackRecorder, missed_result
from companion.mavlink import FlightMode, LinkConfig
from companion.mission.px4_params import Px4PlanningParams
from companion.onboard.protocol import (
    STATE_DONE,
    STATE_ERROR,
    STATE_NAMES,
    STATE_READY,
    STATE_STOPPED,
    Upload,
    encode_upload,
)
from companion.planning.onboard_segments import (
    HOLD_S,
    START_TOLERANCE_M,
    OnboardError,
    Segments,
    bend_for_tilt,
    check_fits,
    law_params,
    module_final_action,
    schedule_segments,
    trajectory_segments,
)
from companion.planning.vehicle_params import read_planning_params

from .fly import (
    HOME_WAIT_S,
    MAX_HOME_OFFSET_M,
    FlyOptions,
    PlannedFlight,
    check_inputs,
    mission_figures,
    plan_flight,
    print_planning_params,
    rehome_at_vehicle,
    summary_table,
    write_report,
)

if TYPE_CHECKING:
    from companion.aio.base import VehicleBase

#: After the trajectory, how long the companion follows PX4's landing or hold [s].
END_WAIT_S = 60.0


def planned_segments(planned: PlannedFlight, origin: FloatArray) -> Segments:
    """The planned flight's segments in local NED (plan frame + `origin`)."""
    if planned.schedule is not None:
        if planned.t_off_s > 0.0:
            raise OnboardError("the onboard module flies the mission from the ground")
        return schedule_segments(planned.schedule, origin)
    traj = planned.trajectory
    assert traj is not None
    out: Segments = ([float(traj.breaks[0])], [], [])
    trajectory_segments(out, traj, traj.yaw, 0.0, origin)
    return out


async def fly_onboard(opts: FlyOptions, console: Console) -> int:
    """Run `fly --onboard`; the exit code (0 ok, 1 flight failure, 2 cannot start)."""
    from companion.aio import Vehicle, VehicleConfig, safe_exit
    from companion.aio.onboard import module_states, module_status, upload
    inputs = check_inputs(opts)
    if opts.connect is None:
        raise OnboardError("--onboard needs --connect: the module runs inside PX4")
    if opts.mode != "attitude":
        raise OnboardError("the onboard module flies attitude setpoints: use --mode attitude")
    log_path = inputs.log_path
    vconfig = VehicleConfig(tlog_path=log_path, connect_timeout_s=opts.connect_timeout_s)
    link = LinkConfig(target_sysid=opts.target_system).with_signing_key(opts.signing_key)
    recorder = TrackRecorder()
    async with contextlib.AsyncExitStack() as stack:
        v = await stack.enter_async_context(Vehicle.connect(opts.connect, config=vconfig,
                                                            link_config=link))
        st = await module_status(v)
        if st is None:
            raise OnboardError("no onboard module answers (load it: `dyn FILE.px4mod start`, "
                               "see docs/guides/onboard.md); nothing was sent to fly")
        if st.state not in (STATE_READY, STATE_DONE, STATE_STOPPED, STATE_ERROR) or v.is_armed:
            raise OnboardError(f"the onboard module is {STATE_NAMES.get(st.state, st.state)} "
                               f"{'and the vehicle armed' if v.is_armed else ''}: not ready")
        console.print(f"Onboard module ready; logging to {escape(log_path)}")
        await stack.enter_async_context(safe_exit(v))
        px4 = None
        if inputs.mission is not None:
            px4 = await read_planning_params(v.fetch_params, inputs.vehicle.px4_overrides,
                                             vehicle="quad")
            print_planning_params(console, px4)
        if inputs.mission is not None:
            # planned from where the vehicle stands to the file's own coordinates
            horiz, here, _ = await rehome_at_vehicle(v, inputs.mission, HOME_WAIT_S)
            if horiz > MAX_HOME_OFFSET_M:
                raise OnboardError(f"{opts.target}: planned home is {horiz:.0f} m from the "
                                   f"vehicle (limit {MAX_HOME_OFFSET_M:g} m)")
            inputs = dataclasses.replace(inputs, mission=here)
        planned = await asyncio.to_thread(plan_flight, opts, inputs, False,
                                          None if px4 is None else px4.params, True,
                                          HANDOVER_HEIGHT_M)
        pos = v.telemetry.position
        if pos is None:
            raise OnboardError("no position telemetry")
        # a mission is flown from the ground (its plan takes off); a pattern starts where
        # PX4's takeoff ends, `alt_m` above here
        origin = np.asarray(pos.pos_ned, dtype=float) - planned.start_rel
        if inputs.mission is None:
            origin = origin + np.array([0.0, 0.0, -planned.alt_m])
        hover = (await v.read_params(["MPC_THR_HOVER"]))["MPC_THR_HOVER"]
        limits = SetpointLimits.of_px4(px4.params if px4 is not None else Px4PlanningParams())
        law = law_params(inputs.vehicle, hover, limits.tilt_max_rad)
        # bent ahead of time where it asks for more tilt than the limit (the module cannot)
        breaks, cps, ycps = segs = await asyncio.to_thread(  # ~0.3 s of QPs per minute
            bend_for_tilt, planned_segments(planned, origin), law)
        check_fits(segs)
        final = module_final_action(planned.final_action)
        up: Upload = encode_upload(breaks, cps, ycps, law,
                                   sysid=link.sysid, compid=link.compid, final_action=final,
                                   hold_s=HOLD_S, start_tolerance_m=START_TOLERANCE_M)
        t_up = time.monotonic()
        u = await upload(v, up)
        if not u.verified:
            raise OnboardError(f"upload not verified: {u.failed}; nothing was flown")
        console.print(f"Trajectory uploaded: {len(cps)} segments, {up.duration_s:.1f} s, CRC "
                      f"0x{up.crc:08x} echoed by the module ({time.monotonic() - t_up:.2f} s, "
                      f"{u.resent} parts sent again)")
        if inputs.mission is None:
            await v.arm()
            await v.takeoff(planned.alt_m)
            await v.set_mode(FlightMode.OFFBOARD)
        else:
            await v.set_mode(FlightMode.OFFBOARD)
            await v.arm(keep_mode=True)
        t_armed = time.monotonic()
        # the module's start on the autopilot's clock (its start reports): the reference of a
        # position sample is the trajectory at the sample's own autopilot time (a simulator
        # slower than real time runs the module's clock slower too)
        clock: dict[str, float] = {}
        console.print("Armed in OFFBOARD: the module flies")

        async def record() -> None:
            early: list[tuple[float, FloatArray]] = []  # before the first start report
            async for p in v.position():
                if v.mode is not FlightMode.OFFBOARD:
                    continue
                early.append((p.time_boot_s, np.asarray(p.pos_ned, dtype=float)))
                t0 = clock.get("t0_boot")
                if t0 is None:
                    continue
                for tb, pos_ned in early:
                    t = min(max(tb - t0, 0.0), planned.duration_s)
                    recorder.add(tb, pos_ned, planned.rel_ref(t, origin).pos_ned)
                early.clear()

        rec = asyncio.get_running_loop().create_task(record())
        last = None
        try:
            end = t_armed + up.duration_s + END_WAIT_S
            async for _, a in module_states(v):
                if a.start:
                    clock["t0_boot"] = a.value / 1000.0
                    continue
                if a.state != last:
                    console.print(f"module: {STATE_NAMES.get(a.state, a.state)}")
                    last = a.state
                if a.state in (STATE_STOPPED, STATE_ERROR):
                    break
                if a.state == STATE_DONE and v.mode is not FlightMode.OFFBOARD:
                    break
                if time.monotonic() > end:
                    break
        finally:
            rec.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await rec
        flown_s = time.monotonic() - t_armed
        if last == STATE_DONE and planned.final_action == "land":
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(_disarmed(v), END_WAIT_S)
        result = ("ok" if last == STATE_DONE else
                  "stopped: OFFBOARD left (the pilot or a failsafe took over)"
                  if last == STATE_STOPPED else
                  "refused: the vehicle was not at the trajectory's start"
                  if last == STATE_ERROR else f"module {STATE_NAMES.get(last or 0)} at the end")
        report = dataclasses.replace(
            recorder.summary(planned.waypoints_rel + origin, planned.acceptance_m,
                             duration_s=flown_s, planned_duration_s=planned.duration_s),
            result=result, mode="onboard", target=opts.target,
            final_action=planned.final_action)
        report = mission_figures(report, planned, recorder, origin, None)
        report = dataclasses.replace(report, result=missed_result(report) if result == "ok"
                                     else result)
        report = dataclasses.replace(report, ok=report.result == "ok")
    console.print(summary_table(report))
    console.print(f"Report: {escape(str(write_report(log_path, report)))}")
    console.print(f"Done. Log: {escape(str(Path(log_path).resolve()))}")
    return 0 if report.result == "ok" else 1


async def _disarmed(v: VehicleBase) -> None:
    while v.is_armed:
        await asyncio.sleep(0.2)  # poll the armed state until PX4 disarms after landing
