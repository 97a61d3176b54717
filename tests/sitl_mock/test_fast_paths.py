"""The mock's per-step fast paths against their oracles (pymavlink, the general paths, physics).

- `MessageCodec.pack_frame` (header + CRC state cached per length/seq/ids) against pymavlink's
  `pack` over every seq, with zero tails (MAVLink 2 truncation), NaN, extremes of int ranges;
- `unpack_single` (SET_ATTITUDE_TARGET straight from the bytes) against pymavlink's parser, and
  None for anything that is not exactly one clean frame of that message;
- the autopilot's SET_ATTITUDE_TARGET hot path against its general path (pymavlink decode + the
  message handler): same target, same counters, for random fields incl. invalid ones;
- the vehicles' snapshot-free accessors (landed, local_position_valid, battery_remaining,
  attitude) against the snapshot; a parameter change reaching the physics (ParamStore.version).
"""

from __future__ import annotations

import contextlib
import math
import struct
from typing import Any
from unittest import mock

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as mavlink

from sitl_mock.autopilot import Autopilot
from sitl_mock.autopilot import links as ap_module
from sitl_mock.mavwire import codec, unpack_single
from sitl_mock.params import ParamStore
from sitl_mock.quad import Quadrotor
from sitl_mock.rover import Rover
from sitl_mock.setpoints import AttitudeTarget, IdleTarget, PositionTarget, make_attitude_target

G = 9.80665
SAT = mavlink.MAVLink_set_attitude_target_message
C_SAT = codec(SAT)
API = ("127.0.0.1", 14540)

f32 = st.floats(width=32)  # incl. NaN, +-inf, -0.0, subnormals
f32_or_zero = st.one_of(st.just(0.0), f32)  # zeros often: trailing-zero truncation


def _same(a: Any, b: Any) -> bool:
    """Equal values, NaN equal to NaN, element-wise for sequences."""
    if isinstance(a, float) and isinstance(b, float):
        if math.isnan(a) or math.isnan(b):
            return math.isnan(a) and math.isnan(b)
        return a == b and math.copysign(1.0, a) == math.copysign(1.0, b)
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    return type(a) is type(b) and a == b


def _pack(msg: Any, seq: int, sysid: int = 255, compid: int = 190) -> bytes:
    mav = mavlink.MAVLink(None, sysid, compid)
    mav.seq = seq
    return bytes(msg.pack(mav))


def _parse(data: bytes) -> list[Any]:
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    return parser.parse_buffer(data) or []


# ------------------------------------------------------------------------------ pack_frame
@settings(max_examples=60, deadline=None)
@given(
    st.integers(0, 2**32 - 1),
    st.lists(f32_or_zero, min_size=6, max_size=6),
    st.integers(0, 255),
    st.integers(0, 255),
)
def test_pack_frame_over_every_seq_matches_pymavlink(
    t: int, f: list[float], sysid: int, compid: int
) -> None:
    """Header/CRC cache: every seq twice (cache miss, then hit) and two payload lengths."""
    c = codec(mavlink.MAVLink_attitude_message)
    short = (t, *f[:3], 0.0, 0.0, 0.0)  # trailing zeros: a shorter payload, other cache keys
    for seq in range(512):
        vals = (t, *f) if seq % 2 else short
        ref = _pack(mavlink.MAVLink_attitude_message(*vals), seq % 256, sysid, compid)
        assert c.pack_frame(seq, sysid, compid, vals) == ref


_I32 = st.integers(-(2**31), 2**31 - 1)
_I16 = st.integers(-(2**15), 2**15 - 1)


@settings(max_examples=80, deadline=None)
@given(
    st.integers(0, 2**32 - 1),
    st.lists(st.one_of(st.just(0), _I32), min_size=4, max_size=4),
    st.lists(st.one_of(st.just(0), _I16), min_size=3, max_size=3),
    st.one_of(st.just(0), st.integers(0, 2**16 - 1)),
    st.integers(0, 255),
)
def test_pack_frame_integer_extremes_match_pymavlink(
    t: int, i32: list[int], i16: list[int], hdg: int, seq: int
) -> None:
    vals = (t, *i32, *i16, hdg)
    ref = _pack(mavlink.MAVLink_global_position_int_message(*vals), seq, 1, 1)
    assert codec(mavlink.MAVLink_global_position_int_message).pack_frame(seq, 1, 1, vals) == ref


def test_pack_frame_rejects_ids_outside_a_byte_even_after_caching_valid_ones() -> None:
    c = codec(mavlink.MAVLink_timesync_message)
    for sysid, compid in ((0, 1), (1, 0), (1, 1), (0, 0)):
        assert c.pack_frame(3, sysid, compid, (0, 5)) == _pack(
            mavlink.MAVLink_timesync_message(0, 5), 3, sysid, compid
        )
    for sysid, compid in ((256, 0), (0, 256), (-1, 1), (1, 257)):
        with pytest.raises(struct.error):
            c.pack_frame(3, sysid, compid, (0, 5))
    with pytest.raises(TypeError):  # fewer than the required fields
        c.pack_frame(0, 1, 1, (0,))


def test_make_attitude_target_is_the_dataclass() -> None:
    a = make_attitude_target((1.0, 0.0, 0.0, 0.0), 0.5, None, 0.25)
    b = AttitudeTarget((1.0, 0.0, 0.0, 0.0), 0.5, None, 0.25)
    assert type(a) is AttitudeTarget and a == b and hash(a) == hash(b) and repr(a) == repr(b)
    with pytest.raises(AttributeError):
        a.thrust_norm = 0.1  # type: ignore[misc]


# ------------------------------------------------------------------------------ unpack_single
@st.composite
def sat_fields(draw: st.DrawFn) -> tuple[Any, ...]:
    """SET_ATTITUDE_TARGET constructor values; zeros at the wire tail are frequent."""
    return (
        draw(st.integers(0, 2**32 - 1)),
        draw(st.sampled_from((0, 1, 2, 255))),  # target_system
        draw(st.sampled_from((0, 1, 5, 255))),  # target_component
        draw(st.one_of(st.just(0), st.integers(0, 255))),  # type_mask
        draw(st.lists(f32_or_zero, min_size=4, max_size=4)),
        draw(f32_or_zero),
        draw(f32_or_zero),
        draw(f32_or_zero),
        draw(f32_or_zero),
    )


@settings(max_examples=150, deadline=None)
@given(sat_fields(), st.integers(0, 255), st.integers(0, 255), st.integers(0, 255))
def test_unpack_single_matches_pymavlink(
    vals: tuple[Any, ...], seq: int, sysid: int, compid: int
) -> None:
    data = _pack(SAT(*vals), seq, sysid, compid)
    (ref,) = _parse(data)
    f = unpack_single(data, C_SAT)
    assert f is not None
    # wire order: time, q[4], roll/pitch/yaw rate, thrust, target sys/comp, type_mask
    want = (
        ref.time_boot_ms,
        *ref.q,
        ref.body_roll_rate,
        ref.body_pitch_rate,
        ref.body_yaw_rate,
        ref.thrust,
        ref.target_system,
        ref.target_component,
        ref.type_mask,
    )
    assert _same(f, want)


def test_unpack_single_refuses_everything_but_one_clean_frame() -> None:
    sp = SAT(5, 1, 1, 0, [1.0, 0.0, 0.0, 0.0], 0.1, 0.2, 0.3, 0.5)
    good = _pack(sp, 7)
    assert unpack_single(good, C_SAT) is not None
    bad_crc = good[:-1] + bytes((good[-1] ^ 1,))
    signed = good[:2] + b"\x01" + good[3:]
    other = _pack(mavlink.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3), 7)
    v1 = bytes(sp.pack(mavlink.MAVLink(None, 255, 190, use_native=False), force_mavlink1=True))
    too_long = bytearray(good[:-2])
    too_long[1] += 1
    too_long += b"\x01"
    for data in (
        b"", good[:-1], good + good, good + b"\x00", bad_crc, signed, other, v1, bytes(too_long),
        good[:11],
    ):
        assert unpack_single(data, C_SAT) is None, data.hex()


# ------------------------------------------------------------------------------ autopilot
def _ob_state(ap: Autopilot) -> tuple[Any, ...]:
    tgt = ap.offboard.target
    fields = (
        None
        if tgt is None
        else (type(tgt).__name__, tgt.q_wxyz, tgt.thrust_norm, tgt.body_rates_frd, tgt.yaw_rate_ff)
    )
    return fields, ap.offboard.last_t, dict(ap.stats)


@settings(max_examples=40, deadline=None)
@given(st.lists(sat_fields(), min_size=1, max_size=12))
def test_setpoint_hot_path_equals_the_general_path(setpoints: list[tuple[Any, ...]]) -> None:
    """Same datagrams into two autopilots, one with the hot path disabled (pymavlink decode)."""
    fast = Autopilot(now=0.0, remotes={"offboard": API})
    slow = Autopilot(now=0.0, remotes={"offboard": API})
    t = 0.0
    for seq, vals in enumerate(setpoints):
        t += 0.01
        data = _pack(SAT(*vals), seq % 256)
        fast.receive_datagram(data, API, t)
        with mock.patch.object(ap_module, "unpack_single", return_value=None):
            slow.receive_datagram(data, API, t)
        assert _same(_ob_state(fast), _ob_state(slow))
    assert fast.stats["rx_messages"] == slow.stats["rx_messages"] == len(setpoints)


def test_setpoint_hot_path_drives_the_vehicle_like_the_general_path() -> None:
    """An offboard attitude flight: identical telemetry bytes with and without the hot path."""
    client = mavlink.MAVLink(None, 255, 190)

    def fly(use_hot_path: bool) -> list[bytes]:
        ap = Autopilot(now=0.0, remotes={"offboard": API}, estimator_ready_s=0.5)
        out: list[bytes] = []
        patch = (
            contextlib.nullcontext()
            if use_hot_path
            else mock.patch.object(ap_module, "unpack_single", return_value=None)
        )
        with patch:
            for k in range(1, 301):
                t = k * 0.01
                yaw = 0.3 * math.sin(t)
                q = [math.cos(yaw / 2), 0.0, 0.02, math.sin(yaw / 2)]
                sp = mavlink.MAVLink_set_attitude_target_message(0, 1, 1, 7, q, 0, 0, 0, 0.6)
                ap.receive_datagram(sp.pack(client), API, t)
                if k == 60:  # OFFBOARD, then arm
                    for cmd in (
                        mavlink.MAVLink_command_long_message(1, 1, 176, 0, 1, 6, 0, 0, 0, 0, 0),
                        mavlink.MAVLink_command_long_message(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0),
                    ):
                        ap.receive_datagram(cmd.pack(client), API, t)
                ap.advance(t)
                out += [d for d, _ in ap.datagrams_to_send(t)]
        assert ap.armed and not ap.state.landed  # it flew
        return out

    assert fly(True) == fly(False)


# ------------------------------------------------------------------------------ vehicles
def _accessors_match(v: Any) -> None:
    s = v.state
    assert v.landed == s.landed
    assert v.local_position_valid == s.local_position_valid
    assert v.battery_remaining == s.battery_remaining
    q, w = v.attitude
    assert q == s.q_wxyz
    # the rates are the measured ones (a quadrotor's filtered, noisy gyro while its rate loop
    # runs; PX4's vehicle_angular_velocity), state.omega_frd the true ones
    if v.kind == "rover":
        assert w == s.omega_frd
    else:
        assert all(abs(a - b) < 0.5 for a, b in zip(w, s.omega_frd, strict=True))


def test_quad_accessors_equal_the_snapshot_through_a_flight_and_faults() -> None:
    p = ParamStore({"SIM_POS_NOISE": 0.05, "SIM_GYRO_NOISE": 0.01})
    q = Quadrotor(p, seed=4)
    plan: list[tuple[Any, bool, int]] = [
        (IdleTarget(), False, 50),
        (PositionTarget((0.0, 0.0, -3.0)), True, 1500),
        (AttitudeTarget((0.99, 0.05, 0.0, 0.1), 0.55, None, 0.2), True, 200),
        (AttitudeTarget(None, 0.3, (0.2, -0.1, 0.4)), True, 200),
        (PositionTarget((0.0, 0.0, 0.5), (0.0, 0.0, 1.0)), True, 1500),  # down into the ground
        (IdleTarget(), False, 50),
    ]
    n = 0
    for target, armed, steps in plan:
        for _ in range(steps):
            q.step(0.004, target, armed)
            n += 1
            if n == 700:
                q.set_local_position_valid(False)
            if n == 1200:
                q.set_battery_remaining(0.3)
                q.set_local_position_valid(True)
            _accessors_match(q)
    assert q.landed and q.battery_remaining < 0.3  # landed again, drained since


def test_rover_accessors_equal_the_snapshot() -> None:
    rv = Rover(ParamStore(), seed=0)
    for k in range(300):
        armed = 20 <= k < 280
        rv.step(0.004, PositionTarget((5.0, 3.0, 0.0)), armed)
        if k == 100:
            rv.set_local_position_valid(False)
        _accessors_match(rv)


def test_parameter_change_reaches_the_physics() -> None:
    """Disarmed drop with drag: a_z = G - SIH_KDV * v_z / SIH_MASS, before and after a change."""
    p = ParamStore()
    q = Quadrotor(p, seed=0)
    q.set_state(pos_ned=(0.0, 0.0, -500.0), vel_ned=(0.0, 0.0, 5.0))
    dt = 0.004

    def accel_error() -> float:
        vz0 = q.state.vel_ned[2]
        q.step(dt, IdleTarget(), False)
        want = G - p["SIH_KDV"] * vz0 / p["SIH_MASS"]
        return abs(q.state.acc_ned[2] - want)

    assert accel_error() < 1e-9
    for name, value in (("SIH_KDV", 3.0), ("SIH_MASS", 2.5)):
        p.set(name, value)
        for _ in range(30):  # > PARAM_REFRESH_S: the new value is in use
            q.step(dt, IdleTarget(), False)
        assert accel_error() < 1e-9, name


# ------------------------------------------------------------------------------ quiet streams
def _lockstep_flight(quiet: frozenset[int], faults: bool) -> tuple[list[bytes], dict[str, int],
                                                                   tuple[int, ...]]:
    """A lockstep flight through every kind of stream state: AUTO takeoff (position targets),
    OFFBOARD attitude setpoints, a local-position loss (no ODOMETRY), a state far from home and
    one that is not finite (GLOBAL_POSITION_INT not known unbuilt / not encodable); optional
    link faults (loss, latency, jitter, duplicates, reordering both ways)."""
    from sitl_mock.faults import LinkFaults, ScenarioFaults
    from sitl_mock.lockstep import LockstepSim

    f = (LinkFaults(loss_pct=5.0), LinkFaults(loss_pct=8.0, latency_s=0.02, jitter_s=0.01,
                                              duplicate_pct=3.0, reorder_pct=3.0))
    sim = LockstepSim(seed=3, faults=f if faults else None, estimator_ready_s=0.5,
                      scenario=ScenarioFaults(local_position_loss=(9.0, 10.0)),
                      params={"SIM_POS_NOISE": 0.05, "SIM_WIND_GUST": 1.0},
                      unread_streams=quiet)
    client = mavlink.MAVLink(None, 255, 190)
    out: list[bytes] = []

    def send(m: Any) -> None:
        sim.send(m.pack(client))
        client.seq = (client.seq + 1) & 0xFF

    for k in range(1, 1601):
        t = k * 0.01
        if k in (100, 110, 120):  # arm, NAV_TAKEOFF to 5 m
            send(mavlink.MAVLink_command_long_message(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0))
            send(mavlink.MAVLink_command_long_message(1, 1, 22, 0, 0, 0, 0, math.nan, 0, 0, 5))
        if k >= 600:  # OFFBOARD attitude setpoints
            q = [math.cos(0.1), 0.0, 0.03, math.sin(0.1)]
            send(mavlink.MAVLink_set_attitude_target_message(0, 1, 1, 7, q, 0, 0, 0, 0.5))
            if k in (650, 660, 670):
                send(mavlink.MAVLink_command_long_message(1, 1, 176, 0, 1, 6, 0, 0, 0, 0, 0))
        if k == 1200:
            sim.autopilot.vehicle.set_state(pos_ned=(3e5, -2e5, -50.0))
        if k == 1400:
            sim.autopilot.vehicle.set_state(pos_ned=(0.0, 0.0, math.nan))
        sim.step_until(t)
        out += sim.recv()
    ap = sim.autopilot
    lk = ap.comms.by_name["offboard"]
    return out, dict(ap.stats), (lk.tx.stats.passed, lk.tx.stats.dropped,
                                 lk.tx.stats.duplicated, lk.tx.stats.reordered, lk.mav.seq)


@pytest.mark.parametrize("faults", [False, True])
def test_quiet_streams_leave_every_other_datagram_as_it_was(faults: bool) -> None:
    """Streams nobody reads left unbuilt (a lockstep flight without a log): every other
    datagram is the same bytes at the same time (sequence numbers, fault-channel draws), and
    the counters are the same, as when every stream is built. (A quiet message whose fate is
    not known unbuilt, here GLOBAL_POSITION_INT far from home, is built and sent as usual.)"""
    from sitl_mock.autopilot.telemetry import QUIETABLE

    quiet = frozenset(QUIETABLE)
    full, full_stats, full_ch = _lockstep_flight(frozenset(), faults)
    lean, lean_stats, lean_ch = _lockstep_flight(quiet, faults)

    def ids(frames: list[bytes]) -> list[int]:
        return [d[7] | (d[8] << 8) | (d[9] << 16) for d in frames]

    def others(frames: list[bytes]) -> list[bytes]:
        return [d for d, i in zip(frames, ids(frames), strict=True) if i not in quiet]

    assert others(lean) == others(full)
    assert lean_stats == full_stats and lean_ch == full_ch
    assert full_stats["tx_encode_errors"] > 0  # the non-finite state was not encodable
    assert {30, 33, 83, 85, 331} <= set(ids(full))  # every quiet stream was really there
    assert 0 < ids(lean).count(33) < 0.2 * ids(full).count(33)  # built while far from home
    assert len(lean) < 0.5 * len(full)


def test_quiet_streams_refuse_what_cannot_be_known_unbuilt() -> None:
    from sitl_mock.lockstep import LockstepSim

    with pytest.raises(ValueError, match="cannot be left unbuilt"):
        LockstepSim(unread_streams=frozenset({mavlink.MAVLINK_MSG_ID_PING}))
    ap = Autopilot(now=0.0, signing_key=bytes(32), unix_boot_s=1.7e9)
    with pytest.raises(ValueError, match="signed link"):
        ap.quiet_streams("offboard", {30})


# ------------------------------------------------------------------------------ rate loop
def test_gauss3_equals_three_random_gauss_calls() -> None:
    import random

    from sitl_mock.quad_control import gauss3

    a, b = random.Random(9), random.Random(9)
    for k in range(20001):
        s = (0.3, 1e-3, 2.0) if k % 7 else (0.0, 5.0, 0.0)
        if k % 1000 == 17:  # a gauss call in between: the kept twin moves
            assert a.gauss() == b.gauss()
        assert gauss3(a, *s) == tuple(b.gauss(0.0, x) for x in s)


@pytest.mark.parametrize("faults", [False, True])
@pytest.mark.parametrize("remote", [API, None])
def test_frames_to_send_are_the_datagrams_to_send(faults: bool, remote: Any) -> None:
    """The lockstep pipe's drain (bytes only) against `datagrams_to_send` on twin autopilots."""
    from sitl_mock.faults import LinkFaults

    f = (None, LinkFaults(loss_pct=10.0, latency_s=0.015, jitter_s=0.01, duplicate_pct=5.0,
                          reorder_pct=5.0)) if faults else None
    kw: dict[str, Any] = {"remotes": {"offboard": remote}, "estimator_ready_s": 0.2, "seed": 2}
    if f is not None:
        kw["link_faults"] = {"offboard": f}
    a, b = Autopilot(now=0.0, **kw), Autopilot(now=0.0, **kw)
    got_a: list[bytes] = []
    got_b: list[bytes] = []
    for k in range(1, 400):
        t = k * 0.01
        a.advance(t)
        b.advance(t)
        if k % 3:
            got_a += [d for d, _ in a.datagrams_to_send(t, "offboard")]
            got_b += b.frames_to_send(t, "offboard")
    assert got_a == got_b
    assert (len(got_a) > 500) == (remote is not None)
