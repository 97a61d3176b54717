"""The replay's onboard flight: the planned schedule flown by the onboard module inside the mock
(`sitl_mock.onboard`, the same C as the PX4 module) over the `LockstepLink`, the way
`fly --onboard` flies it on PX4 (companion.app.fly_onboard).

Order: wait for a healthy vehicle; ask the module for its state (OP_STATUS until it answers;
no answer within STATUS_TIMEOUT_S, or not ready: the flight fails with nothing else sent);
convert the schedule to the module's segments at where the vehicle stands
(`companion.planning.onboard_segments.schedule_segments`); upload them with the sans-IO `Uploader`
(each part acknowledged, the CRC-32 echoed); OFFBOARD, arm; then follow the module's reports
until it is done and PX4's final action (land, RTL) disarmed the vehicle, or hold is reached.
The companion streams no setpoint. The flight's clock is the module's: its start report gives
the trajectory's start on the autopilot's clock, which is the flight log's clock too.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from companion.aio.tlog import TlogWriter
from companion.control import TrackingConfig
from companion.flight.report import SetpointLimits
from companion.flight.summary import FlightLog
from companion.flight.tracking import vehicle_limited
from companion.mavlink.commands import (
    MAV_CMD_COMPONENT_ARM_DISARM,
    MAV_CMD_DO_SET_MODE,
    CommandFinished,
    UnsolicitedAck,
)
from companion.mavlink.px4_mode import FlightMode
from companion.onboard.protocol import (
    OP_STATUS,
    PROTO_NAME,
    STATE_DONE,
    STATE_ERROR,
    STATE_LOADED,
    STATE_NAMES,
    STATE_READY,
    STATE_STOPPED,
    Ack,
    Upload,
    Uploader,
    decode_ack,
    encode_upload,
    request,
)
from companion.planning.config import onboard_config, onboard_velocity_correction
from companion.planning.onboard_segments import (
    HOLD_S,
    START_TOLERANCE_M,
    OnboardError,
    bend_for_tilt,
    check_fits,
    law_from_tracking,
    module_final_action,
    schedule_segments,
)
from companion.planning.schedule import Schedule
from companion.replay.config import ReplayConfig
from companion.replay.flight import drive, recorded_link
from companion.replay.lockstep import LockstepLink

#: How long the companion asks the module for its state before giving up [s].
STATUS_TIMEOUT_S = 3.0
#: OP_STATUS is sent again this often until the module answers [s].
STATUS_INTERVAL_S = 0.5
#: After the module is done: how long PX4's final action may take to disarm [s].
END_WAIT_S = 60.0
_READY_STATES = (STATE_READY, STATE_DONE, STATE_STOPPED, STATE_ERROR, STATE_LOADED)


class OnboardFlight:
    """The companion's side of an onboard flight in lockstep (see the module docstring):
    `on_events(events, now)` takes the link's events, `tick(now)` runs one cycle; `done`,
    `ok` and `reason` tell how it ended. `hover`: PX4's MPC_THR_HOVER (the module's law)."""

    def __init__(self, config: ReplayConfig, schedule: Schedule, lk: LockstepLink,
                 log: FlightLog, hover: float) -> None:
        self.config = config
        self.schedule = schedule
        self.lk = lk
        self.link = lk.link
        self.log = log
        self.hover = hover
        self.origin = np.zeros(3)
        self.phase = "wait"
        self.reason = ""
        self.module_state: int | None = None
        self.upload: Upload | None = None
        self.uploader: Uploader | None = None
        self.setpoints_sent = 0  # the companion streams none
        self.states: list[tuple[float, str]] = []  # the module's state changes
        self._t_phase = 0.0
        self._t_status = -math.inf
        self._final = module_final_action(schedule.final_action)

    @property
    def done(self) -> bool:
        return self.phase in ("done", "failed")

    @property
    def ok(self) -> bool:
        return self.phase == "done"

    def _to(self, phase: str, now: float) -> None:
        self.phase = phase
        self._t_phase = now

    def late_s(self) -> float:
        """The module flies on the autopilot's clock: never late."""
        return 0.0

    def abort(self, now: float, reason: str) -> None:
        """End the flight with `reason` (nothing more is sent)."""
        if not self.done:
            self.reason = reason
            self._to("failed", now)

    def _send(self, op: int, data: tuple[float, ...] | list[float], now: float) -> None:
        self.link.send_float_array(PROTO_NAME, op, data, now)
        self.lk.to_vehicle(self.link.frames_to_send())

    def on_events(self, events: list[Any], now: float) -> None:
        """The link's events: the module's reports and the command results."""
        for ev in events:
            if isinstance(ev, UnsolicitedAck):
                ack = decode_ack(ev.command, ev.result, ev.progress, ev.result_param2)
                if ack is not None:
                    self._on_ack(ack, now)
            elif isinstance(ev, CommandFinished):
                self._on_command(ev, now)

    def _on_ack(self, ack: Ack, now: float) -> None:
        if ack.start:
            t0 = ack.value / 1000.0  # the trajectory's start on the autopilot's clock [s]
            self.log.fly_t0 = t0
            self.log.fly_t1 = t0 + self.schedule.duration_s
            return
        if ack.state != self.module_state:
            self.module_state = ack.state
            self.states.append((now, STATE_NAMES.get(ack.state, str(ack.state))))
        if self.phase == "status" and ack.op == OP_STATUS:
            if ack.state not in _READY_STATES or self.link.armed:
                self.abort(now, f"the onboard module is {STATE_NAMES.get(ack.state, ack.state)}"
                          f"{' and the vehicle armed' if self.link.armed else ''}: not ready")
                return
            self._start_upload(now)
        elif self.phase == "upload" and self.uploader is not None:
            self.uploader.on_ack(ack, now)
        elif self.phase == "fly":
            if ack.state == STATE_STOPPED:
                self.abort(now, "stopped: OFFBOARD left (the pilot or a failsafe took over)")
            elif ack.state == STATE_ERROR:
                self.abort(now, "refused: the vehicle was not at the trajectory's start")

    def _on_command(self, ev: CommandFinished, now: float) -> None:
        if self.phase == "mode" and ev.command == MAV_CMD_DO_SET_MODE:
            if not ev.ok:
                self.abort(now, f"OFFBOARD refused: {ev.reason}")
                return
            self._to("arm", now)
            self.link.arm(now)
            self.lk.to_vehicle(self.link.frames_to_send())
        elif self.phase == "arm" and ev.command == MAV_CMD_COMPONENT_ARM_DISARM:
            if not ev.ok:
                self.abort(now, f"arming refused: {ev.reason}")
                return
            self.log.armed_t = now
            self._to("fly", now)

    def _start_upload(self, now: float) -> None:
        pos = self.link.telemetry.position
        assert pos is not None
        sched = self.schedule
        self.origin = np.asarray(pos.pos_ned, dtype=np.float64) - sched.reference(0.0).pos_ned
        limits = SetpointLimits.of_px4(sched.px4)
        tracking = vehicle_limited(TrackingConfig(params=self.config.params), limits)
        tracking = onboard_config(tracking, dict(self.config.onboard_law))
        law = law_from_tracking(tracking, self.hover,
                                onboard_velocity_correction(dict(self.config.onboard_law)))
        # bent ahead of time where it asks for more tilt than the limit (the module cannot)
        breaks, cps, ycps = segs = bend_for_tilt(schedule_segments(sched, self.origin), law)
        try:
            check_fits(segs)
        except OnboardError as exc:
            self.abort(now, str(exc))
            return
        cfg = self.link.config
        self.upload = encode_upload(breaks, cps, ycps, law,
                                    sysid=cfg.sysid, compid=cfg.compid, final_action=self._final,
                                    hold_s=HOLD_S, start_tolerance_m=START_TOLERANCE_M)
        self.uploader = Uploader(self.upload)
        self._to("upload", now)

    def tick(self, now: float) -> None:
        """One cycle of the companion at `now` [s simulated]."""
        link = self.link
        if self.phase == "wait":
            st = link.telemetry.sys_status
            if (link.heartbeat.link_up and st is not None and st.armable
                    and link.telemetry.position is not None):
                self._to("status", now)
        if self.phase == "status":
            if now - self._t_phase > STATUS_TIMEOUT_S:
                self.abort(now, "no onboard module answers; nothing was sent to fly")
            elif now - self._t_status >= STATUS_INTERVAL_S:
                self._t_status = now
                cfg = link.config
                self._send(OP_STATUS, request(cfg.sysid, cfg.compid), now)
        elif self.phase == "upload":
            u = self.uploader
            assert u is not None
            msg = u.poll(now)
            if msg is not None:
                self._send(msg[0], msg[1], now)
            if u.failed:
                self.abort(now, f"upload not verified: {u.failed}; nothing was flown")
            elif u.verified:
                self._to("mode", now)
                link.set_mode(FlightMode.OFFBOARD, now)
                self.lk.to_vehicle(link.frames_to_send())
        elif (self.phase == "fly" and self.module_state == STATE_DONE
              and link.mode is not FlightMode.OFFBOARD):
            self._to("end", now)
        if self.phase == "end":
            if not link.armed:
                self.log.disarmed_t = now
                self._to("done", now)
            elif self._final == "hold" and link.mode is FlightMode.HOLD:
                self._to("done", now)
            elif now - self._t_phase > END_WAIT_S:
                self.abort(now, f"not disarmed {END_WAIT_S:g} s after the final action")


def fly_onboard_schedule(
    config: ReplayConfig,
    schedule: Schedule,
    home: tuple[float, float, float],
    tlog: TlogWriter | None,
    hover: float,
    progress: Callable[[float, float], None] | None = None,
) -> tuple[OnboardFlight, FlightLog]:
    """Fly `schedule` with the onboard module of a fresh mock in lockstep (the companion's
    cycle at `config.rate_hz`); returns the flight and its log (as `fly_schedule`)."""
    lk, log = recorded_link(config, home, tlog)
    flight = OnboardFlight(config, schedule, lk, log, hover)
    drive(flight, lk, config, schedule.duration_s, progress)
    return flight, log
