"""`serve --onboard`'s decisions (companion.serve.onboard) on injected observations, module
reports and time: no sockets, no clock. Oracles: the plan itself (the uploaded segments trace
the join and then the planned mission) and the actions (what is uploaded, announced, never
streamed or requested)."""

from __future__ import annotations

import asyncio
import dataclasses
from typing import Any

import numpy as np
import pytest

import companion.aio.onboard as aio_onboard
import companion.onboard.protocol as P
from companion.mavlink import FlightMode
from companion.planning.onboard_segments import OnboardError
from companion.serve.onboard import (
    UPLOAD_RETRY_S,
    OnboardServeService,
    OnboardTrajectory,
    onboard_trajectory,
)
from companion.serve.program import MissionProgram, plan_program
from companion.serve.runner import check_module
from companion.serve.service import (
    AbortOnboard,
    Announce,
    LogEvent,
    Observation,
    RequestMode,
    ServiceConfig,
    UploadOnboard,
)
from companion.trajectory import Bezier
from tests.companion.serve.test_service import MISSIONS, obs, wire_items

HOVER = (0.2, 0.1, -4.0)  # after PX4's takeoff of px4_short.plan (NED from home, m)


@pytest.fixture(scope="module")
def program() -> MissionProgram:
    items, home = wire_items(MISSIONS / "px4_short.plan")
    return plan_program(items, home, (7, len(items)), ServiceConfig())


def status(state: int, value: int = 0) -> P.Ack:
    return P.Ack(state, 0, P.OP_STATUS, value)


def see(t: float, ack: P.Ack | None, **kw: Any) -> Observation:
    o = obs(t, **kw)
    return dataclasses.replace(o, module=ack, module_t_s=None if ack is None else t)


def texts(acts: list[Any]) -> list[str]:
    return [a.text for a in acts if isinstance(a, Announce)]


def planned(program: MissionProgram) -> OnboardServeService:
    svc = OnboardServeService(ServiceConfig())
    svc.on_planned(program.key, program, 0.0)
    return svc


def loaded(program: MissionProgram) -> tuple[OnboardServeService, OnboardTrajectory,
                                             list[Any]]:
    """A service whose trajectory from HOVER was uploaded and verified (and what it did)."""
    svc = planned(program)
    req = next(a for a in svc.update(see(1.0, status(P.STATE_READY), pos=HOVER))
               if isinstance(a, UploadOnboard))
    tr = svc.plan_onboard(req)
    assert isinstance(tr, OnboardTrajectory)
    return svc, tr, svc.on_uploaded(req.token, tr, 1.4, crc=0x1234)


def evaluate(tr: OnboardTrajectory, t: float) -> np.ndarray:
    breaks, cps, _ = tr.segments
    i = int(np.clip(np.searchsorted(breaks, t, side="right") - 1, 0, len(cps) - 1))
    return Bezier(cps[i], breaks[i + 1] - breaks[i]).evaluate(t - breaks[i])


@pytest.mark.parametrize(("pos", "reached"), [(HOVER, 0), ((5.0, 1.0, -4.0), 1),
                                              ((10.5, 3.0, -4.2), 2)])
def test_the_upload_joins_from_where_the_vehicle_holds_then_flies_the_plan(
        program: MissionProgram, pos: tuple[float, float, float], reached: int) -> None:
    svc = planned(program)
    tr = onboard_trajectory(svc, UploadOnboard(1, program, obs(5.0, pos=pos), reached, 0.0))
    assert np.allclose(tr.start_ned, pos)
    # after the join: the planned mission itself, to its flown end (PX4 lands: the final action)
    for t in np.linspace(tr.join_s, tr.duration_s, 50):
        ref = program.reference(tr.t_join + t - tr.join_s).pos_ned
        assert np.linalg.norm(evaluate(tr, float(t)) - ref) < 1e-6
    assert np.linalg.norm(evaluate(tr, tr.duration_s) - program.reference(program.t_end).pos_ned
                          ) < 1e-6
    assert tr.final_action == "land"
    # what the module is sent verifies on its own terms (degree <= 7, <= 256 segments)
    law = P.LawParams((1.0,) * 3, (1.0,) * 3, (0.1,) * 3, (1.0,) * 3, 0.5, 0.3, 1.0, 9.81, 0.1,
                      0.9, 0.7)
    up = P.encode_upload(*tr.segments, law, sysid=255, compid=190)
    assert abs(up.duration_s - tr.duration_s) < 1e-9


def test_nothing_is_uploaded_before_a_mission_the_module_and_a_vehicle_holding_still(
        program: MissionProgram) -> None:
    svc = OnboardServeService(ServiceConfig())
    assert not any(isinstance(a, UploadOnboard) for a in svc.update(see(1.0, status(0))))
    svc.on_planned(program.key, program, 1.0)
    # on the ground, no module report, moving: no upload
    for o in (see(2.0, status(0), armed=False, landed=1), see(2.1, None),
              dataclasses.replace(see(2.2, status(0)), position=dataclasses.replace(
                  obs(2.2).position, vel_ned=(0.0, 0.0, -1.0)))):  # type: ignore[arg-type]
        assert not any(isinstance(a, UploadOnboard) for a in svc.update(o))
    assert svc.stream is None


def test_a_refused_upload_is_announced_nothing_flown_and_tried_again_later(
        program: MissionProgram) -> None:
    svc = planned(program)
    acts = svc.update(see(1.0, status(P.STATE_READY), pos=HOVER))
    req = next(a for a in acts if isinstance(a, UploadOnboard))
    acts = svc.on_uploaded(req.token, "not verified (the module's CRC 0x1 is not 0x2)", 1.5)
    assert any("upload failed, not flying" in t for t in texts(acts))
    assert not any(isinstance(a, (RequestMode, UploadOnboard)) for a in acts)
    assert not any(isinstance(a, UploadOnboard)
                   for a in svc.update(see(1.5 + UPLOAD_RETRY_S - 0.1, status(0), pos=HOVER)))
    # OFFBOARD is PX4's to refuse (the module holds nothing): were it entered, nothing is flown
    acts = svc.update(see(3.0, status(P.STATE_READY), pos=HOVER, mode=FlightMode.OFFBOARD))
    assert svc.stream is None and svc.state == "hold" and not texts(acts)
    acts = svc.update(see(1.5 + UPLOAD_RETRY_S + 0.1, status(0), pos=HOVER))
    assert any(isinstance(a, UploadOnboard) for a in acts)


def test_the_modules_reports_are_announced_and_a_pilots_mode_change_is_never_fought(
        program: MissionProgram) -> None:
    svc, tr, acts = loaded(program)
    assert any("onboard ready" in t for t in texts(acts))
    # loaded and still there: not uploaded again
    assert not any(isinstance(a, UploadOnboard)
                   for a in svc.update(see(1.6, status(P.STATE_LOADED, 11), pos=HOVER)))
    # the pilot's OFFBOARD: the module flies
    off = FlightMode.OFFBOARD
    svc.update(see(2.0, status(P.STATE_LOADED, 11), pos=HOVER, mode=off))
    acts = svc.update(see(2.5, status(P.STATE_FLYING, 100), pos=HOVER, mode=off))
    assert any("module flying mission from wp 1/" in t for t in texts(acts))  # wp 0 here
    # its clock passes wp 1 of the plan (the plan passing a waypoint counts, as with serve)
    t_wp1 = float(program.wp_times[1]) - tr.t_join + tr.join_s
    svc.update(see(5.0, status(P.STATE_FLYING, int(t_wp1 * 1000) + 50), pos=(10.0, 0.5, -4.0),
                   mode=off))
    assert svc.reached >= 2 and svc.t_progress > program.t_begin
    # the pilot's Hold: the module stops itself (its next report says so); the service
    # requests nothing, streams nothing
    acts = svc.update(see(5.5, status(P.STATE_FLYING, 3500), pos=(10.0, 1.0, -4.0),
                          mode=FlightMode.HOLD))
    acts += svc.update(see(5.8, status(P.STATE_STOPPED), pos=(10.0, 1.0, -4.0),
                           mode=FlightMode.HOLD))
    assert any("module stopped at wp" in t for t in texts(acts))
    assert not any(isinstance(a, RequestMode) for a in acts) and svc.stream is None
    # held still again: a fresh trajectory from there joins the rest of the plan
    acts = svc.update(see(7.0, status(P.STATE_STOPPED), pos=(10.0, 1.5, -4.0)))
    again = next(a for a in acts if isinstance(a, UploadOnboard))
    assert again.reached == svc.reached >= 2
    tr2 = svc.plan_onboard(again)
    assert isinstance(tr2, OnboardTrajectory) and tr2.t_join >= float(program.wp_times[1])
    svc.on_uploaded(again.token, tr2, 7.3)
    svc.update(see(8.0, status(P.STATE_LOADED), pos=(10.0, 1.5, -4.0), mode=off))
    svc.update(see(8.5, status(P.STATE_FLYING, 10), pos=(10.0, 1.5, -4.0), mode=off))
    # the module's end: complete, its final action is its own (no mode requested here)
    acts = svc.update(see(12.0, status(P.STATE_HOLDING, int(tr2.duration_s * 1000)),
                          pos=(10.0, 8.0, -4.0), mode=off))
    assert any("mission complete, land by the module" in t for t in texts(acts))
    acts += svc.update(see(13.0, status(P.STATE_DONE), pos=(10.0, 8.0, -3.0),
                           mode=FlightMode.LAND, landed=4))
    assert not any(isinstance(a, (RequestMode, UploadOnboard)) for a in acts)
    assert svc.stream is None
    # stopping the service mid-flight requests nothing: the module finishes alone
    stop = svc.shutdown(see(14.0, status(P.STATE_FLYING), mode=off))
    assert not any(isinstance(a, RequestMode) for a in stop)
    assert any(isinstance(a, LogEvent) for a in stop)


def test_a_module_that_refuses_the_start_is_announced(program: MissionProgram) -> None:
    svc, _, _ = loaded(program)
    acts = svc.update(see(2.0, status(P.STATE_ERROR), pos=HOVER, mode=FlightMode.OFFBOARD))
    assert any("refused to start" in t for t in texts(acts))
    assert svc.stream is None and svc.state == "hold"


class _Vehicle:
    """Records what is sent; the module's answers come from the patched `module_status`."""

    def __init__(self) -> None:
        self.sent: list[object] = []


@pytest.mark.parametrize("answer", [None, status(P.STATE_FLYING), status(P.STATE_RECEIVING)])
def test_serve_onboard_exits_2_without_a_ready_module(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Any, answer: P.Ack | None) -> None:
    from companion.serve.runner import EventLog

    async def fake_status(v: Any) -> P.Ack | None:
        return answer

    monkeypatch.setattr(aio_onboard, "module_status", fake_status)
    events = EventLog(tmp_path / "events.jsonl")
    try:
        with pytest.raises(OnboardError):  # the CLI's exit 2 (a ValueError)
            asyncio.run(check_module(_Vehicle(), events))
    finally:
        events.close()
    assert "onboard_module" in (tmp_path / "events.jsonl").read_text()


def test_serve_onboard_accepts_a_ready_module(monkeypatch: pytest.MonkeyPatch,
                                              tmp_path: Any) -> None:
    from companion.serve.runner import EventLog

    async def fake_status(v: Any) -> P.Ack | None:
        return status(P.STATE_READY)

    monkeypatch.setattr(aio_onboard, "module_status", fake_status)
    events = EventLog(tmp_path / "events.jsonl")
    try:
        asyncio.run(check_module(_Vehicle(), events))
    finally:
        events.close()


def test_the_modules_end_counts_when_its_final_mode_is_seen_before_its_done_report(
        program: MissionProgram) -> None:
    """PX4's LAND (the module's final action) seen before the module's HOLDING or DONE report:
    the module's next report decides (complete, not stopped); nothing uploaded while landing."""
    svc, tr, _ = loaded(program)
    off = FlightMode.OFFBOARD
    svc.update(see(2.0, status(P.STATE_FLYING, 0), pos=HOVER, mode=off))
    svc.update(see(9.0, status(P.STATE_FLYING, int(tr.duration_s * 1000) - 300),
                   pos=(10.0, 8.0, -4.0), mode=off))
    # PX4's LAND seen before the module's next report: no verdict yet
    acts = svc.update(see(10.0, status(P.STATE_FLYING, int(tr.duration_s * 1000) - 300),
                          pos=(10.0, 8.0, -3.9), mode=FlightMode.LAND, landed=4))
    assert not texts(acts) and svc.state == "onboard"
    acts = svc.update(see(10.3, status(P.STATE_DONE, int(tr.duration_s * 1000) + 1000),
                          pos=(10.0, 8.0, -3.8), mode=FlightMode.LAND, landed=4))
    assert any("mission complete" in t for t in texts(acts)), texts(acts)
    assert not any("stopped" in t for t in texts(acts))
    for k in range(5):  # slowing down near the ground: still nothing to upload
        acts = svc.update(see(11.0 + k, status(P.STATE_STOPPED), pos=(10.0, 8.0, -0.2),
                              mode=FlightMode.LAND, landed=4))
        assert not any(isinstance(a, UploadOnboard) for a in acts)


def test_an_unflown_trajectory_is_dropped_on_landing_and_a_silent_module_is_announced(
        program: MissionProgram) -> None:
    svc = planned(program)
    assert not texts(svc.update(see(0.5, None, pos=HOVER)))  # no report yet: nothing said
    acts = svc.update(see(1.0, status(P.STATE_READY), pos=HOVER))
    assert not texts(acts)  # its first report: nothing said either
    req = next(a for a in acts if isinstance(a, UploadOnboard))
    tr = svc.plan_onboard(req)
    assert isinstance(tr, OnboardTrajectory)
    svc.on_uploaded(req.token, tr, 1.4)
    last = dataclasses.replace(see(2.0, status(P.STATE_LOADED), pos=HOVER), module_t_s=1.5)
    assert not texts(svc.update(last))  # its last report 0.5 s ago: it answers
    acts = svc.update(dataclasses.replace(last, now_s=4.0))  # 2.5 s ago: silent
    assert any("onboard module silent" in t for t in texts(acts))
    acts = svc.update(see(4.5, status(P.STATE_LOADED), pos=HOVER))
    assert any("answers again" in t for t in texts(acts))
    acts = svc.update(see(5.0, status(P.STATE_LOADED), pos=(0.2, 0.1, 0.0), armed=False,
                          landed=1))
    assert [a for a in acts if isinstance(a, AbortOnboard)]
    assert not any(isinstance(a, AbortOnboard)
                   for a in svc.update(see(5.5, status(P.STATE_READY), armed=False, landed=1)))
