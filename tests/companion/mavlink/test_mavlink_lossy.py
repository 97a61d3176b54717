"""Lossy-link properties with fake time: the COMMAND_LONG client and the mission client against
small independent vehicle-side implementations written here, with random message loss."""

from __future__ import annotations

import random
from typing import Any

from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as m

from companion.mavlink import (
    CommandClient,
    CommandFinished,
    MissionClient,
    MissionResult,
    MissionTransferDone,
    WireMissionItem,
)
from tests.support.mavlink_fakes import Outbox, Px4Side, command_ack


@given(seed=st.integers(0, 10_000), loss=st.floats(0.0, 0.9))
@settings(max_examples=60, deadline=None)
def test_command_client_finishes_exactly_once(seed: int, loss: float) -> None:
    rng = random.Random(seed)
    out = Outbox()
    cc = CommandClient(out, 1, 191)
    px4 = Px4Side()
    cc.send_command(400, [1.0], now=0.0)
    finished: list[CommandFinished] = []
    t = 0.0
    confirmations: list[int] = []
    for _ in range(200):
        for msg in out.take():
            confirmations.append(msg.confirmation)
            # the request and then its ack each survive the link with probability 1 - loss
            if rng.random() >= loss and rng.random() >= loss:
                finished += [e for e in cc.on_command_ack(px4.msg(command_ack(400, 0)), t + 0.05)
                             if isinstance(e, CommandFinished)]
        t += 0.1
        finished += [e for e in cc.handle_timer(t) if isinstance(e, CommandFinished)]
        if finished and t > 5.0:
            break
    assert len(finished) == 1
    assert confirmations == list(range(len(confirmations))) and len(confirmations) <= 4
    fin = finished[0]
    assert fin.ok == (fin.result == 0) and fin.attempts == len(confirmations)


class MissionServer:
    """Independent vehicle side of the mission protocol (upload and download), lossy."""

    def __init__(self, rng: random.Random, loss: float) -> None:
        self.rng, self.loss = rng, loss
        self.px4 = Px4Side()
        self.stored: list[Any] = []
        self.incoming: list[Any] = []
        self.expect = 0
        self.count = 0
        self.next_req_at: float | None = None

    def _out(self, msg: Any) -> list[Any]:
        return [] if self.rng.random() < self.loss else [self.px4.msg(msg)]

    def _request(self, seq: int) -> list[Any]:
        # PX4: plain MISSION_REQUEST for seq 0, then MISSION_REQUEST_INT
        cls = m.MAVLink_mission_request_message if seq == 0 else \
            m.MAVLink_mission_request_int_message
        return self._out(cls(1, 191, seq, 0))

    def handle(self, msg: Any, now: float) -> list[Any]:
        if self.rng.random() < self.loss:
            return []
        kind = msg.get_type()
        if kind == "MISSION_COUNT":
            self.count, self.expect, self.incoming = msg.count, 0, []
            self.next_req_at = now + 0.3
            return self._request(0)
        if (kind == "MISSION_ITEM_INT" and self.next_req_at is None and self.count
                and msg.seq == self.count - 1):
            # PX4: a duplicate last item after completion means our ACK was lost: ack again
            return self._out(m.MAVLink_mission_ack_message(1, 191, 0, 0))
        if kind == "MISSION_ITEM_INT" and msg.seq == self.expect:
            self.incoming.append(msg)
            self.expect += 1
            if self.expect == self.count:
                self.stored, self.next_req_at = self.incoming, None
                return self._out(m.MAVLink_mission_ack_message(1, 191, 0, 0))
            self.next_req_at = now + 0.3
            return self._request(self.expect)
        if kind == "MISSION_REQUEST_LIST":
            return self._out(m.MAVLink_mission_count_message(1, 191, len(self.stored), 0))
        if kind == "MISSION_REQUEST_INT" and msg.seq < len(self.stored):
            s = self.stored[msg.seq]
            return self._out(m.MAVLink_mission_item_int_message(
                1, 191, s.seq, s.frame, s.command, s.current, s.autocontinue, s.param1,
                s.param2, s.param3, s.param4, s.x, s.y, s.z, 0))
        return []

    def tick(self, now: float) -> list[Any]:
        if self.next_req_at is not None and now >= self.next_req_at:
            self.next_req_at = now + 0.3
            return self._request(self.expect)
        return []


def drive(mc: MissionClient, out: Outbox, server: MissionServer,
          start: list[MissionTransferDone]) -> MissionTransferDone:
    done = list(start)
    t = 0.0
    for _ in range(2000):
        if done:
            break
        t += 0.05
        for msg in out.take():
            for reply in server.handle(msg, t):
                done += mc.on_message(reply, t + 0.01)
        for req in server.tick(t):
            done += mc.on_message(req, t)
        done += mc.handle_timer(t)
    assert len(done) == 1 and mc.is_idle
    return done[0]


@given(seed=st.integers(0, 10_000), loss=st.sampled_from([0.0, 0.1, 0.3]),
       n=st.integers(1, 6))
@settings(max_examples=40, deadline=None)
def test_mission_round_trip_over_lossy_link(seed: int, loss: float, n: int) -> None:
    rng = random.Random(seed)
    items = [WireMissionItem(i, 6, 16, int(i == 0), 1, 0.0, 2.0, 0.0, float(i), 473977420 + i,
                         85455940 - i, 10.0 + i) for i in range(n)]
    out = Outbox()
    mc = MissionClient(out)
    server = MissionServer(rng, loss)
    # with up to 30 % loss each way, 20 retries make a failure astronomically unlikely
    # (every lost item, request or final ACK is recovered by a re-send)
    up = drive(mc, out, server, mc.upload(items, 0.0))
    assert up.result is MissionResult.SUCCESS
    assert [s.x for s in server.stored] == [i.x for i in items]
    down = drive(mc, out, server, mc.download(0.0))
    assert down.result is MissionResult.SUCCESS and down.items == tuple(items)
