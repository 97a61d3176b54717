"""Sans-IO core of `serve --onboard`: the service with the onboard PX4 module flying the mission.

The pilot triggers the mission as with `serve` (uploads it from the ground station, takes off,
switches to OFFBOARD) and the service plans it the same way (:func:`plan_program`, the same
join). What differs:

- The service never sends a setpoint (``stream`` stays None). PX4 allows OFFBOARD only while the
  module holds a verified trajectory (the module then publishes ``offboard_control_mode``).
- So the trajectory is uploaded before the pilot's switch: whenever the vehicle flies, holds
  still (slower than ``STILL_M_S``) outside OFFBOARD and the planned mission is not flown yet,
  the service plans the join from where the vehicle holds to the rest of the plan, converts it
  to the module's segments (companion.planning.onboard_segments) and asks the caller to upload
  it (:class:`UploadOnboard`; the CRC must verify). A vehicle that drifts more than
  ``REUPLOAD_M`` from the loaded start gets a fresh upload (the module refuses to start
  1.5 m away). An upload that does not verify is announced; OFFBOARD stays refused by PX4, the
  vehicle stays in the pilot's mode; another try ``UPLOAD_RETRY_S`` later.
- In OFFBOARD the module flies; the service follows its reports (the module's clock gives the
  schedule time and the waypoints passed) and announces start, stop and completion. The module
  holds the end point and commands the final action itself.
- A pilot's mode change stops the module for good (the module does it; the service requests no
  mode, ever). The module cannot resume mid-trajectory: once the vehicle holds still again, the
  service uploads a fresh trajectory joining the rest of the plan from there, and the pilot's
  next OFFBOARD flies it (as `serve` resumes).
- If the service or its link dies mid-flight, the module finishes the trajectory and commands
  the final action (no PX4 failsafe); stopping the service requests no Hold.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from companion.mavlink.px4_mode import FlightMode
from companion.onboard.protocol import (
    OP_STATUS,
    STATE_DONE,
    STATE_ERROR,
    STATE_FLYING,
    STATE_HOLDING,
    STATE_LOADED,
    STATE_RECEIVING,
    STATE_STOPPED,
    Ack,
)
from companion.planning.onboard_segments import (
    Segments,
    check_fits,
    concatenate,
    module_final_action,
    schedule_segments,
    trajectory_segments,
    window,
)
from companion.serve.program import MissionProgram
from companion.serve.service import (
    MAV_SEVERITY_INFO,
    MAV_SEVERITY_WARNING,
    AbortOnboard,
    Action,
    Announce,
    LogEvent,
    Observation,
    ServeService,
    ServiceConfig,
    UploadOnboard,
    is_flying,
)

#: Upload only while the vehicle holds this still [m/s] (the join starts from rest).
STILL_M_S = 0.3
#: Upload again once the vehicle is this far [m] from the loaded trajectory's start.
REUPLOAD_M = 0.5
#: After a failed upload, try again this much later [s].
UPLOAD_RETRY_S = 5.0
#: The module's reports (every 0.5 s) older than this [s] say nothing of its state.
MODULE_STALE_S = 2.0
#: EXTENDED_SYS_STATE's landing: no upload while PX4 lands.
LANDED_STATE_LANDING = 4


@dataclass(frozen=True)
class OnboardTrajectory:
    """What is uploaded: the segments (local NED), where the join ends on the schedule
    (``t_join`` [s]) and how long it takes (``join_s`` [s]), the start, the final action."""

    segments: Segments
    t_join: float
    join_s: float
    start_ned: tuple[float, float, float]
    final_action: str  # the module's: land, rtl or hold

    @property
    def duration_s(self) -> float:
        return self.segments[0][-1] - self.segments[0][0]


@dataclass(frozen=True)
class _Loaded:
    req: UploadOnboard
    traj: OnboardTrajectory
    at_s: float  # when its CRC was verified [s]


def onboard_trajectory(service: ServeService, req: UploadOnboard) -> OnboardTrajectory:
    """The join from ``req.obs`` then the rest of the plan up to its flown end, as the
    module's segments (ValueError when there is none within the limits or the module's)."""
    prog = req.program
    t_join, join = service.join_choice(prog, req.obs, req.reached, req.t_progress)
    rest = window(schedule_segments(prog.schedule, prog.origin), t_join, prog.t_end)
    first: Segments = ([0.0], [], [])
    if join is not None:
        yaw0 = req.obs.yaw if req.obs.yaw is not None else 0.0
        trajectory_segments(first, join, join.yaw, yaw0, np.zeros(3))
    segs = concatenate(first, rest)
    if not segs[1]:
        raise ValueError("nothing of the mission is left to fly")
    check_fits(segs)
    s0 = segs[1][0][0]
    return OnboardTrajectory(segs, t_join, 0.0 if join is None else float(join.duration),
                             (float(s0[0]), float(s0[1]), float(s0[2])),
                             module_final_action(prog.final_action))


class OnboardServeService(ServeService):
    """The service for `serve --onboard` (see the module doc). States: idle (not flying),
    hold (flying outside OFFBOARD: uploads), onboard (the module flies the mission),
    finishing (the module completed it; its final action takes over)."""

    def __init__(self, config: ServiceConfig | None = None) -> None:
        super().__init__(config, defer_join=True)
        self._token = 0
        self._uploading: UploadOnboard | None = None
        self._loaded: _Loaded | None = None  # verified in the module, not flown yet
        self._flown: _Loaded | None = None  # the one the module flies
        self._retry_at = -math.inf
        self._clock_s = 0.0  # the flown trajectory's clock, from the module's reports [s]
        self._module_ok: bool | None = None  # its reports came lately (None: not yet seen)
        self._said: tuple[int, int] | None = None  # (program, reached) last announced ready

    # -- inputs ------------------------------------------------------------------------------
    def plan_onboard(self, req: UploadOnboard) -> OnboardTrajectory | str:
        """The trajectory to upload for ``req``, or why there is none. Reads only the
        configuration and ``req``: safe to call from a worker thread."""
        try:
            return onboard_trajectory(self, req)
        except ValueError as exc:
            return str(exc)

    def on_uploaded(self, token: int, result: OnboardTrajectory | str, now_s: float,
                    crc: int = 0) -> list[Action]:
        """The upload ``token`` ended: verified (its trajectory) or not (why)."""
        req = self._uploading
        if req is None or req.token != token:
            return [LogEvent("onboard_upload_discarded", {"token": token})]
        self._uploading = None
        if isinstance(result, str):
            self._loaded, self._retry_at = None, now_s + UPLOAD_RETRY_S
            return [Announce(f"ecca: onboard upload failed, not flying: {result}",
                             MAV_SEVERITY_WARNING),
                    LogEvent("onboard_upload_failed", {"why": result})]
        out: list[Action] = [LogEvent("onboard_loaded", {
            "segments": len(result.segments[1]), "duration_s": round(result.duration_s, 2),
            "crc": f"0x{crc:08x}", "t_join": round(result.t_join, 3),
            "join_s": round(result.join_s, 3), "start_ned": [round(c, 3) for c in
                                                             result.start_ned]})]
        if self.state != "hold" or req.program is not self.program:
            return [*out, LogEvent("onboard_upload_stale", {"state": self.state})]
        self._loaded = _Loaded(req, result, now_s)
        key = (id(req.program), req.reached)
        if key != self._said:
            self._said = key
            out.append(Announce(f"ecca: onboard ready, OFFBOARD flies from "
                                f"{self._progress_text()} ({result.duration_s:.0f} s)"))
        return out

    def on_planned(self, key: tuple[int, int], result: MissionProgram | str,
                   now_s: float) -> list[Action]:
        flying = self.state == "onboard"
        out = super().on_planned(key, result, now_s)
        self._loaded = None  # the module holds the old mission's: upload again
        if flying:  # the module's trajectory cannot change in flight
            out.insert(0, Announce("ecca: mission changed in flight: the module flies the "
                                   "uploaded one to its end (change mode to stop it)",
                                   MAV_SEVERITY_WARNING))
        return out

    def shutdown(self, obs: Observation) -> list[Action]:
        """Stopping: nothing requested; a module flying finishes the trajectory itself."""
        return [LogEvent("shutdown", {"hold_requested": False, "state": self.state})]

    # -- decisions -----------------------------------------------------------------------------
    def _module(self, obs: Observation) -> Ack | None:
        t = obs.module_t_s
        if obs.module is None or t is None or obs.now_s - t > MODULE_STALE_S:
            return None
        return obs.module

    def _decide(self, obs: Observation, fresh: bool) -> list[Action]:
        out: list[Action] = []
        ack = self._module(obs)
        mstate = None if ack is None else ack.state
        ok = ack is not None
        if self._module_ok is not None and ok != self._module_ok:  # (seen once before)
            out += [Announce("ecca: onboard module answers again" if ok else
                             "ecca: onboard module silent, OFFBOARD will be refused",
                             MAV_SEVERITY_INFO if ok else MAV_SEVERITY_WARNING),
                    LogEvent("onboard_module", {"answers": ok})]
        if ok or self._module_ok is not None:
            self._module_ok = ok
        if not is_flying(obs):
            if self.state != "idle":
                out.append(LogEvent("state", {"state": "idle", "why": "not flying"}))
            if self._loaded is not None:  # on the ground: no OFFBOARD for an unflown one
                out.append(AbortOnboard("the vehicle landed or disarmed"))
            self.state, self._loaded, self._flown = "idle", None, None
            return out
        offboard = obs.mode is FlightMode.OFFBOARD
        if self.state == "onboard":
            return self._follow(obs, ack, offboard)
        if self.state == "finishing":
            if not offboard:
                self.state = "hold"
                out.append(LogEvent("final_action", {"mode": obs.mode.name if obs.mode
                                                     else None}))
            return out
        if offboard:  # the module flies, or the pilot's OFFBOARD is none of ours
            loaded = self._loaded
            if loaded is not None and mstate in (STATE_FLYING, STATE_HOLDING):
                self.state, self._flown, self._loaded = "onboard", loaded, None
                self._clock_s = 0.0
                out += [Announce(f"ecca: module flying mission from {self._progress_text()}"),
                        LogEvent("state", {"state": "onboard",
                                           "t_join": round(loaded.traj.t_join, 3),
                                           "join_s": round(loaded.traj.join_s, 3),
                                           "reached": self.reached})]
                return out + self._follow(obs, ack, offboard)
            if loaded is not None and mstate == STATE_ERROR:
                self._loaded = None
                out += [Announce("ecca: the module refused to start: the vehicle was not at "
                                 "its trajectory's start", MAV_SEVERITY_WARNING),
                        LogEvent("onboard_start_refused", {})]
            return out
        if self.state != "hold":
            out.append(LogEvent("state", {"state": "hold", "why": "flying outside OFFBOARD"}))
            self.state = "hold"
        out += self._watch_wind(obs, fresh)
        return out + self._upload(obs, fresh, mstate)

    def _follow(self, obs: Observation, ack: Ack | None, offboard: bool) -> list[Action]:
        """The module flies: its clock as progress; its end, or its stop."""
        fl, prog = self._flown, self.program
        assert fl is not None
        mstate = None if ack is None else ack.state
        if (ack is not None and ack.op == OP_STATUS and not ack.crc and not ack.start
                and mstate in (STATE_FLYING, STATE_HOLDING, STATE_DONE)):
            self._clock_s = max(self._clock_s, ack.value / 1000.0)
            t = fl.traj.t_join + max(0.0, self._clock_s - fl.traj.join_s)
            while (prog is fl.req.program and self.reached < len(prog.wp_times)
                   and prog.wp_times[self.reached] <= t and self._clock_s >= fl.traj.join_s):
                self.reached += 1
            if prog is fl.req.program:
                self.t_progress = max(self.t_progress, min(t, prog.t_end))
        # its end: holding, done, or its clock there (a lost report)
        if mstate in (STATE_HOLDING, STATE_DONE) or self._clock_s >= fl.traj.duration_s:
            self.done, self.state, self._flown = True, "finishing", None
            return [Announce(f"ecca: mission complete, {fl.traj.final_action} by the module"),
                    LogEvent("mission_complete", {"reached": self.reached, "onboard": True,
                                                  "final_action": fl.traj.final_action})]
        # its stop: the module's own report, or out of OFFBOARD with no report from it (after
        # a mode change its next report says STOPPED, or DONE when its end came first)
        if mstate in (STATE_STOPPED, STATE_ERROR) or (not offboard and mstate != STATE_FLYING):
            self.state, self._flown = "hold", None
            return [Announce(f"ecca: module stopped at {self._progress_text()} (OFFBOARD "
                             f"left); OFFBOARD again flies the rest from there"),
                    LogEvent("state", {"state": "hold", "why": "left OFFBOARD",
                                       "mode": obs.mode.name if obs.mode else None})]
        return []

    def _upload(self, obs: Observation, fresh: bool, mstate: int | None) -> list[Action]:
        """Upload the trajectory from here when there is a mission to fly, the module is not
        flying and the vehicle holds still (again when it drifted or the module lost it)."""
        prog, pos = self.program, obs.position
        if (prog is None or self.done or not fresh or pos is None or self._uploading is not None
                or obs.landed_state == LANDED_STATE_LANDING
                or mstate is None or mstate in (STATE_FLYING, STATE_HOLDING)
                or obs.now_s < self._retry_at or float(np.linalg.norm(pos.vel_ned)) > STILL_M_S):
            return []
        wc = self.wind_check
        if wc is not None and not wc.flyable:
            return []
        loaded = self._loaded
        if loaded is not None and loaded.req.program is prog and (
                loaded.req.reached == self.reached) and math.dist(
                pos.pos_ned, loaded.traj.start_ned) <= REUPLOAD_M and (
                mstate in (STATE_LOADED, STATE_RECEIVING) or (obs.module_t_s or 0.0)
                <= loaded.at_s):
            return []  # still loaded (a report older than the upload may say otherwise)
        self._token += 1
        self._uploading = UploadOnboard(self._token, prog, obs, self.reached, self.t_progress)
        return [self._uploading,
                LogEvent("onboard_upload", {"reached": self.reached,
                                            "pos_ned": [round(c, 3) for c in pos.pos_ned]})]
