"""Parameter read client against an in-memory PX4 stand-in on fake time: values round-trip
through real MAVLink frames (REAL32 as is, INT32 bytewise as PX4 sends it), lost requests and
replies are retried 0.5 s apart, a name that never comes back is reported by name after three
tries, a wrongly typed answer is refused."""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as m

from companion.mavlink import (
    LinkConfig,
    ParamBusyError,
    ParamClient,
    ParamReadDone,
    ParamType,
    VehicleLink,
    decode_param_value,
    encode_param_value,
)
from tests.support.mavlink_fakes import Outbox, Px4Side

REAL32, INT32 = m.MAV_PARAM_TYPE_REAL32, m.MAV_PARAM_TYPE_INT32


def _int_bits(v: int) -> float:
    """PX4's bytewise encoding, written independently: the int32's bytes read as a float32."""
    return float(struct.unpack("<f", struct.pack("<i", v))[0])


@dataclass
class FakeParams:
    """PX4's PARAM_REQUEST_READ handling: answers a known name with PARAM_VALUE, ignores an
    unknown one (PX4 v1.16). ``drop[name]``: how many requests for it are lost first."""

    values: dict[str, tuple[float, int]]
    drop: dict[str, int] = field(default_factory=dict)
    px4: Px4Side = field(default_factory=Px4Side)
    requests: list[str] = field(default_factory=list)

    def answer(self, sent: list[Any]) -> list[Any]:
        out = []
        for msg in sent:
            assert msg.get_type() == "PARAM_REQUEST_READ"
            assert (msg.target_system, msg.target_component, msg.param_index) == (1, 1, -1)
            name = msg.param_id
            self.requests.append(name)
            if self.drop.get(name, 0) > 0:
                self.drop[name] -= 1
                continue
            if name not in self.values:
                continue
            value, ptype = self.values[name]
            wire = _int_bits(int(value)) if ptype == INT32 else value
            out.append(self.px4.msg(m.MAVLink_param_value_message(
                name.encode(), wire, ptype, len(self.values), 0)))
        return out


STEP = 0.0625  # fake time step [s] (exact in binary: deadlines fall on steps)


def run(client: ParamClient, out: Outbox, fake: FakeParams, names: list[str],
        expect: dict[str, ParamType] | None = None, t_end: float = 10.0,
        step: float = STEP) -> ParamReadDone:
    """Drive a read on fake time (replies arrive one step after the requests)."""
    events = client.read(names, 0.0, expect)
    t = 0.0
    while not events and t < t_end:
        replies = fake.answer(out.take())
        t += step
        for r in replies:
            events += client.on_message(r, t)
        events += client.handle_timer(t)
    assert len(events) == 1, events
    return events[0]


def make(values: dict[str, tuple[float, int]], **kw: Any) -> tuple[ParamClient, Outbox,
                                                                    FakeParams]:
    out = Outbox()
    return ParamClient(out, **kw), out, FakeParams(values)


def test_floats_and_bytewise_int32_read_back_including_16_character_names() -> None:
    client, out, fake = make({"MPC_Z_VEL_MAX_UP": (2.25, REAL32), "MPC_XY_CRUISE": (8.5, REAL32),
                              "COM_OBL_RC_ACT": (3, INT32), "MAV_SYS_ID": (-7, INT32)})
    done = run(client, out, fake, ["MPC_Z_VEL_MAX_UP", "MPC_XY_CRUISE", "COM_OBL_RC_ACT",
                                   "MAV_SYS_ID"])
    assert done.ok and done.problem() == ""
    assert done.values == {"MPC_Z_VEL_MAX_UP": 2.25, "MPC_XY_CRUISE": 8.5,
                           "COM_OBL_RC_ACT": 3.0, "MAV_SYS_ID": -7.0}
    assert done.attempts == 4 and client.is_idle


def test_lost_requests_or_replies_are_retried_half_a_second_apart() -> None:
    client, out, fake = make({"A": (1.0, REAL32), "B": (2.0, REAL32)})
    fake.drop = {"A": 2}  # the first two requests (or their replies) are lost: the third works
    done = run(client, out, fake, ["A", "B"])
    assert done.ok and done.values == {"A": 1.0, "B": 2.0}
    assert fake.requests.count("A") == 3 and fake.requests.count("B") == 1
    assert done.t_s == 1.0 + STEP  # third request at 1.0 s, answered one step later


def test_a_parameter_that_never_comes_back_is_named_after_three_tries() -> None:
    client, out, fake = make({"MPC_XY_CRUISE": (5.0, REAL32)})
    done = run(client, out, fake, ["MPC_LAND_ALT2", "MPC_XY_CRUISE", "NOT_A_PARAM"])
    assert not done.ok
    assert done.missing == ("MPC_LAND_ALT2", "NOT_A_PARAM")  # in request order
    assert done.values == {"MPC_XY_CRUISE": 5.0}
    assert fake.requests.count("MPC_LAND_ALT2") == 3 and fake.requests.count("NOT_A_PARAM") == 3
    assert done.t_s == 1.5  # given up at the third timeout, not before
    assert "MPC_LAND_ALT2" in done.problem() and "NOT_A_PARAM" in done.problem()


def test_an_answer_of_another_type_than_expected_is_refused_by_name() -> None:
    client, out, fake = make({"MPC_XY_CRUISE": (5, INT32), "NAV_ACC_RAD": (2.0, REAL32)})
    done = run(client, out, fake, ["MPC_XY_CRUISE", "NAV_ACC_RAD"],
               expect={"MPC_XY_CRUISE": ParamType.REAL32, "NAV_ACC_RAD": ParamType.REAL32})
    assert not done.ok and done.values == {"NAV_ACC_RAD": 2.0}
    assert "INT32" in done.wrong_type["MPC_XY_CRUISE"]
    assert done.problem().startswith("MPC_XY_CRUISE:")
    assert fake.requests.count("MPC_XY_CRUISE") == 1  # an answer, just a wrong one: not retried


def test_no_more_than_max_in_flight_requests_are_outstanding() -> None:
    names = [f"P{i}" for i in range(20)]
    client, out, fake = make({n: (float(i), REAL32) for i, n in enumerate(names)},
                             max_in_flight=8)
    events = client.read(names, 0.0)
    assert not events and len(out.sent) == 8
    done = run_rest(client, out, fake)
    assert done.ok and done.values == {n: float(i) for i, n in enumerate(names)}
    assert fake.requests == names  # each asked once, in order


def run_rest(client: ParamClient, out: Outbox, fake: FakeParams) -> ParamReadDone:
    events: list[ParamReadDone] = []
    t = 0.0
    while not events and t < 10.0:
        t += STEP
        for r in fake.answer(out.take()):
            events += client.on_message(r, t)
        events += client.handle_timer(t)
    (done,) = events
    return done


def test_replies_from_other_components_and_unrequested_names_are_ignored() -> None:
    client, _out, _fake = make({})
    client.read(["A"], 0.0)
    other = Px4Side(compid=100)  # e.g. a camera with its own parameters
    assert client.on_message(other.msg(m.MAVLink_param_value_message(b"A", 9.0, REAL32, 1, 0)),
                             0.1) == []
    px4 = Px4Side()
    assert client.on_message(px4.msg(m.MAVLink_param_value_message(b"B", 9.0, REAL32, 1, 0)),
                             0.1) == []
    (done,) = client.on_message(px4.msg(m.MAVLink_param_value_message(b"A", 4.0, REAL32, 1, 0)),
                                0.2)
    assert done.values == {"A": 4.0}
    assert client.on_message(px4.msg(m.MAVLink_param_value_message(b"A", 5.0, REAL32, 1, 0)),
                             0.3) == []  # a late duplicate after the read


def test_one_read_at_a_time_and_an_empty_read_finishes_at_once() -> None:
    client, _out, _fake = make({})
    (done,) = client.read([], 0.0)
    assert done.ok and done.values == {}
    client.read(["A"], 0.0)
    with pytest.raises(ParamBusyError):
        client.read(["B"], 0.0)
    client.cancel()
    assert client.is_idle and client.next_deadline() is None
    with pytest.raises(ValueError, match="16"):
        client.read(["SEVENTEEN_CHARS_X"], 0.0)


@given(st.integers(-(2**31), 2**31 - 1))
def test_int32_bytewise_encoding_round_trips(v: int) -> None:
    raw = struct.pack("<i", v)
    assert decode_param_value(raw, INT32) == v
    if decode_param_value(struct.pack("<f", _int_bits(v)), INT32) == v:  # not a signalling NaN
        assert encode_param_value(v, INT32) == pytest.approx(_int_bits(v), nan_ok=True)


def _param_value_frame(name: bytes, raw_value: bytes, ptype: int) -> bytes:
    """A PX4 PARAM_VALUE frame whose param_value holds exactly ``raw_value`` (4 bytes)."""
    from pymavlink.generator.mavcrc import x25crc

    px4 = Px4Side()
    frame = bytearray(px4.frame(m.MAVLink_param_value_message(name, 1.0, ptype, 1, 0)))
    frame[10:14] = raw_value  # MAVLink 2: the payload starts at byte 10, param_value first
    crc = x25crc(bytes(frame[1:-2]))
    crc.accumulate(bytes([m.MAVLink_param_value_message.crc_extra]))
    frame[-2:] = struct.pack("<H", crc.crc)
    return bytes(frame)


def test_an_int32_whose_bytes_form_a_signalling_nan_is_read_exactly() -> None:
    link = VehicleLink(LinkConfig())
    link.params.read(["X"], 0.0, {"X": ParamType.INT32})
    events = link.receive_bytes(_param_value_frame(b"X", struct.pack("<i", -4194305), INT32), 0.1)
    (done,) = [e for e in events if isinstance(e, ParamReadDone)]
    assert done.values == {"X": -4194305.0}


def test_the_vehicle_link_reads_parameters_from_bytes() -> None:
    link = VehicleLink(LinkConfig())
    link.params.read(["MPC_XY_CRUISE"], 0.0)
    px4 = Px4Side()
    sent = px4.decode(link.frames_to_send())
    assert [s.get_type() for s in sent] == ["PARAM_REQUEST_READ"]
    assert link.get_timer() is not None and link.get_timer() <= 0.5  # type: ignore[operator]
    reply = px4.frame(m.MAVLink_param_value_message(b"MPC_XY_CRUISE", 7.5, REAL32, 1, 3))
    events = link.receive_bytes(reply, 0.1)
    (done,) = [e for e in events if isinstance(e, ParamReadDone)]
    assert done.values == {"MPC_XY_CRUISE": 7.5}
