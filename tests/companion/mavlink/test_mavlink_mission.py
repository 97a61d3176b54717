"""Mission transfer client, every failure case modelled on MAVSDK's
mavlink_mission_transfer_client_test.cpp (fake time, recorded sender)."""

from __future__ import annotations

import dataclasses
from typing import Any

import pytest
from pymavlink.dialects.v20 import common as m

from companion.mavlink import (
    MissionBusyError,
    MissionClient,
    MissionResult,
    MissionTransferDone,
    WireMissionItem,
)
from tests.support.mavlink_fakes import Outbox, Px4Side

TIMEOUT = 0.25
RETRIES = 20


def item(seq: int, mission_type: int = 0) -> WireMissionItem:
    return WireMissionItem(seq=seq, frame=6, command=16, current=int(seq == 0), autocontinue=1,
                       param1=1.0, param2=2.0, param3=3.0, param4=4.0, x=473977420 + seq,
                       y=85455940, z=10.0 + seq, mission_type=mission_type)


def make() -> tuple[MissionClient, Outbox, Px4Side]:
    out = Outbox()
    return MissionClient(out, timeout_s=TIMEOUT, retries=RETRIES), out, Px4Side()


def req_int(px4: Px4Side, seq: int, mission_type: int = 0) -> Any:
    return px4.msg(m.MAVLink_mission_request_int_message(1, 191, seq, mission_type))


def req_float(px4: Px4Side, seq: int) -> object:
    return px4.msg(m.MAVLink_mission_request_message(1, 191, seq, 0))


def ack(px4: Px4Side, result: int, mission_type: int = 0) -> object:
    return px4.msg(m.MAVLink_mission_ack_message(1, 191, result, mission_type))


def item_matches(msg: Any, it: WireMissionItem) -> bool:
    got = {f: getattr(msg, f) for f in ("seq", "frame", "command", "current", "autocontinue",
                                         "param1", "param2", "param3", "param4", "x", "y", "z",
                                         "mission_type")}
    return got == dataclasses.asdict(it) and msg.target_system == 1


def only(events: list[MissionTransferDone]) -> MissionTransferDone:
    assert len(events) == 1
    return events[0]


# -- local validation ---------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("items", "mission_type", "expected"),
    [
        ([], 0, MissionResult.NO_MISSION_AVAILABLE),
        ([item(0), item(2)], 0, MissionResult.INVALID_SEQUENCE),
        ([item(0, 1), item(1, 1)], 0, MissionResult.MISSION_TYPE_NOT_CONSISTENT),
        ([item(0), item(1, 1), item(2)], 0, MissionResult.MISSION_TYPE_NOT_CONSISTENT),
        ([dataclasses.replace(item(0), current=0), item(1)], 0, MissionResult.CURRENT_INVALID),
        ([item(0), dataclasses.replace(item(1), current=1)], 0, MissionResult.CURRENT_INVALID),
    ],
)
def test_upload_rejects_bad_items_locally(items: list[WireMissionItem], mission_type: int,
                                          expected: MissionResult) -> None:
    mc, out, _ = make()
    done = only(mc.upload(items, 0.0, mission_type))
    assert done.result is expected
    assert out.sent == [] and mc.is_idle


# -- upload -------------------------------------------------------------------------------------
def test_upload_sends_count_and_resends_it_then_times_out() -> None:
    mc, out, _ = make()
    items = [item(0, 1), item(1, 1)]
    items = [dataclasses.replace(i, current=0) for i in items]  # fence: no current needed
    assert mc.upload(items, 0.0, mission_type=1) == []
    (cnt,) = out.take()
    assert cnt.get_type() == "MISSION_COUNT" and cnt.count == 2 and cnt.mission_type == 1
    t = 0.0
    for _ in range(RETRIES):
        t += TIMEOUT
        assert mc.handle_timer(t) == []
        (again,) = out.take()
        assert again.get_type() == "MISSION_COUNT" and again.count == 2
    done = only(mc.handle_timer(t + TIMEOUT))
    assert done.result is MissionResult.TIMEOUT and mc.is_idle
    assert pytest.approx(5.25) == (RETRIES + 1) * TIMEOUT


def test_upload_success_answers_request_and_request_int_with_item_int() -> None:
    mc, out, px4 = make()
    items = [item(0), item(1), item(2)]
    mc.upload(items, 0.0)
    out.take()
    # PX4 v1.16 asks seq 0 with plain MISSION_REQUEST, then switches to MISSION_REQUEST_INT
    assert mc.on_message(req_float(px4, 0), 0.1) == []
    for seq in (1, 2):
        assert mc.on_message(req_int(px4, seq), 0.1 + 0.2 * seq) == []
    sent = out.take()
    assert [s.get_type() for s in sent] == ["MISSION_ITEM_INT"] * 3
    assert all(item_matches(s, it) for s, it in zip(sent, items, strict=True))
    done = only(mc.on_message(ack(px4, 0), 0.8))
    assert done.result is MissionResult.SUCCESS and done.operation == "upload"
    assert mc.handle_timer(10.0) == [] and mc.is_idle


def test_upload_timeout_not_triggered_while_transfer_progresses() -> None:
    mc, _out, px4 = make()
    mc.upload([item(0), item(1), item(2)], 0.0)
    t = 0.0
    for seq in range(3):
        t += 0.8 * TIMEOUT
        mc.handle_timer(t)
        mc.on_message(req_int(px4, seq), t)
    t += 0.8 * TIMEOUT
    assert mc.handle_timer(t) == []
    assert only(mc.on_message(ack(px4, 0), t)).result is MissionResult.SUCCESS


def test_upload_rerequest_resends_same_item() -> None:
    mc, out, px4 = make()
    items = [item(0), item(1)]
    mc.upload(items, 0.0)
    out.take()
    mc.on_message(req_int(px4, 0), 0.1)
    mc.on_message(req_int(px4, 0), 0.2)  # item 0 got lost: asked again
    mc.on_message(req_int(px4, 1), 0.3)
    sent = out.take()
    assert [s.seq for s in sent] == [0, 0, 1]
    assert only(mc.on_message(ack(px4, 0), 0.4)).result is MissionResult.SUCCESS


def test_upload_gives_up_after_repeated_requests_of_same_item() -> None:
    mc, out, px4 = make()
    mc.upload([item(0), item(1)], 0.0)
    events: list[MissionTransferDone] = []
    n = 0
    while not events and n < 100:
        events = mc.on_message(req_int(px4, 0), 0.01 * n)
        n += 1
    assert only(events).result is MissionResult.TIMEOUT
    assert n == RETRIES + 1
    assert out.sent[-1].get_type() == "MISSION_ACK" and out.sent[-1].type == 15


def test_upload_lost_final_ack_recovered_by_resending_last_item() -> None:
    """PX4 re-acks a duplicate last item (mavlink_mission.cpp, state IDLE)."""
    mc, out, px4 = make()
    items = [item(0), item(1)]
    mc.upload(items, 0.0)
    mc.on_message(req_int(px4, 0), 0.1)
    mc.on_message(req_int(px4, 1), 0.2)
    out.take()  # the final MISSION_ACK is lost
    assert mc.handle_timer(0.2 + TIMEOUT) == []
    (again,) = out.take()
    assert item_matches(again, items[1])
    assert only(mc.on_message(ack(px4, 0), 0.5)).result is MissionResult.SUCCESS


def test_upload_timeout_after_item_when_vehicle_goes_silent() -> None:
    mc, _, px4 = make()
    mc.upload([item(0), item(1)], 0.0)
    mc.on_message(req_int(px4, 0), 0.1)
    t = 0.1
    for _ in range(RETRIES):
        t += TIMEOUT
        assert mc.handle_timer(t) == []
    done = only(mc.handle_timer(t + TIMEOUT))
    assert done.result is MissionResult.TIMEOUT
    assert mc.on_message(ack(px4, 0), t + 1.0) == []  # a late ack is ignored


@pytest.mark.parametrize("bad_seq", [2, 5])
def test_upload_wrong_sequence_request_cancels(bad_seq: int) -> None:
    mc, out, px4 = make()
    mc.upload([item(0), item(1), item(2)], 0.0)
    mc.on_message(req_int(px4, 0), 0.1)
    out.take()
    done = only(mc.on_message(req_int(px4, bad_seq), 0.2))  # skips item 1 / out of range
    assert done.result is MissionResult.INVALID_SEQUENCE
    (cancel,) = out.take()
    assert cancel.get_type() == "MISSION_ACK" and cancel.type == 15


def test_upload_ack_too_early_is_protocol_error() -> None:
    mc, _, px4 = make()
    mc.upload([item(0), item(1)], 0.0)
    mc.on_message(req_int(px4, 0), 0.1)
    assert only(mc.on_message(ack(px4, 0), 0.2)).result is MissionResult.PROTOCOL_ERROR


@pytest.mark.parametrize(
    ("nack", "expected"),
    [(1, MissionResult.PROTOCOL_ERROR), (2, MissionResult.UNSUPPORTED_FRAME),
     (3, MissionResult.UNSUPPORTED), (4, MissionResult.TOO_MANY_MISSION_ITEMS),
     (5, MissionResult.INVALID_PARAM), (6, MissionResult.INVALID_PARAM),
     (12, MissionResult.INVALID_PARAM), (13, MissionResult.INVALID_SEQUENCE),
     (14, MissionResult.DENIED), (15, MissionResult.CANCELLED)],
)
def test_upload_nacks_are_mapped(nack: int, expected: MissionResult) -> None:
    mc, _, px4 = make()
    mc.upload([item(0), item(1)], 0.0)
    mc.on_message(req_int(px4, 0), 0.1)
    done = only(mc.on_message(ack(px4, nack), 0.2))
    assert done.result is expected and done.mav_result == nack


def test_upload_cancel_sends_cancel_ack() -> None:
    mc, out, px4 = make()
    mc.upload([item(0), item(1)], 0.0)
    mc.on_message(req_int(px4, 0), 0.1)
    out.take()
    assert only(mc.cancel(0.2)).result is MissionResult.CANCELLED
    (msg,) = out.take()
    assert msg.get_type() == "MISSION_ACK" and msg.type == 15 and msg.target_system == 1
    assert mc.handle_timer(5.0) == [] and mc.is_idle


def test_random_messages_while_idle_are_ignored() -> None:
    mc, out, px4 = make()
    assert mc.on_message(req_int(px4, 0), 0.0) == []
    assert mc.on_message(ack(px4, 0), 0.0) == []
    assert mc.handle_timer(1.0) == [] and out.sent == []


def test_busy() -> None:
    mc, _, _ = make()
    mc.download(0.0)
    with pytest.raises(MissionBusyError):
        mc.upload([item(0)], 0.1)


def test_messages_from_other_systems_are_ignored() -> None:
    mc, out, _ = make()
    mc.upload([item(0)], 0.0)
    out.take()
    assert mc.on_message(req_int(Px4Side(sysid=2), 0), 0.1) == [] and out.sent == []


# -- download -----------------------------------------------------------------------------------
def test_download_success_and_item_round_trip() -> None:
    mc, out, px4 = make()
    items = [item(0), item(1), item(2)]
    mc.download(0.0)
    (lst,) = out.take()
    assert lst.get_type() == "MISSION_REQUEST_LIST"
    mc.on_message(px4.msg(m.MAVLink_mission_count_message(1, 191, 3, 0)), 0.1)
    for seq, it in enumerate(items):
        (rq,) = out.take()
        assert rq.get_type() == "MISSION_REQUEST_INT" and rq.seq == seq
        d = dataclasses.asdict(it)
        msg = px4.msg(m.MAVLink_mission_item_int_message(1, 191, **d))
        events = mc.on_message(msg, 0.2 + seq)
    done = only(events)
    assert done.result is MissionResult.SUCCESS and done.items == tuple(items)
    (fin,) = out.take()
    assert fin.get_type() == "MISSION_ACK" and fin.type == 0


def test_download_empty() -> None:
    mc, out, px4 = make()
    mc.download(0.0)
    out.take()
    done = only(mc.on_message(px4.msg(m.MAVLink_mission_count_message(1, 191, 0, 0)), 0.1))
    assert done.result is MissionResult.SUCCESS and done.items == ()
    assert [x.get_type() for x in out.take()] == ["MISSION_ACK"]


def test_download_resends_list_then_times_out() -> None:
    mc, out, _ = make()
    mc.download(0.0)
    t = 0.0
    for _ in range(RETRIES):
        t += TIMEOUT
        mc.handle_timer(t)
    assert out.types().count("MISSION_REQUEST_LIST") == RETRIES + 1
    assert only(mc.handle_timer(t + TIMEOUT)).result is MissionResult.TIMEOUT


def test_download_rerequests_missing_item_and_ignores_out_of_order() -> None:
    mc, out, px4 = make()
    mc.download(0.0)
    mc.on_message(px4.msg(m.MAVLink_mission_count_message(1, 191, 2, 0)), 0.1)
    out.take()
    d1 = dataclasses.asdict(item(1))
    assert mc.on_message(px4.msg(m.MAVLink_mission_item_int_message(1, 191, **d1)), 0.2) == []
    assert out.take() == []  # seq 1 while 0 expected: ignored
    mc.handle_timer(0.1 + TIMEOUT)
    (rq,) = out.take()
    assert rq.get_type() == "MISSION_REQUEST_INT" and rq.seq == 0


def test_download_nack_and_cancel() -> None:
    mc, out, px4 = make()
    mc.download(0.0)
    assert only(mc.on_message(ack(px4, 14), 0.1)).result is MissionResult.DENIED
    mc.download(1.0)
    mc.on_message(px4.msg(m.MAVLink_mission_count_message(1, 191, 2, 0)), 1.1)
    out.take()
    assert only(mc.cancel(1.2)).result is MissionResult.CANCELLED
    assert out.take()[-1].type == 15


# -- clear --------------------------------------------------------------------------------------
def test_clear_success_and_retry() -> None:
    mc, out, px4 = make()
    mc.clear(0.0)
    mc.handle_timer(TIMEOUT)
    assert out.types() == ["MISSION_CLEAR_ALL", "MISSION_CLEAR_ALL"]
    assert only(mc.on_message(ack(px4, 0), 0.3)).result is MissionResult.SUCCESS
