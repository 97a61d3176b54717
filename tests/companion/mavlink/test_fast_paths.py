"""Per-cycle fast paths of companion.mavlink: the direct value constructors give the same frozen
objects as the dataclass constructors, the telemetry snapshot is reused only while nothing
changed, message dispatch ignores what it should, and setpoint validation converts and refuses
exactly as documented."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as m

from companion.mavlink import (
    Attitude,
    LocalPosition,
    PositionSetpoint,
    SetpointError,
    TelemetrySnapshot,
    TelemetryState,
    VehicleLink,
    build_setpoint,
)
from companion.mavlink.setpoints import make_position_setpoint
from companion.mavlink.telemetry import _attitude, _local_position, _snapshot
from tests.support.mavlink_fakes import Px4Side, heartbeat

V = (1.0, -2.5, 3.25)
Q = (0.5, 0.5, -0.5, 0.5)


@pytest.mark.parametrize(
    ("fast", "slow", "args"),
    [
        (_local_position, LocalPosition, (1.5, 2.0, V, (0.1, 0.2, 0.3), "LOCAL_POSITION_NED",
                                            (0.4, -0.5, 0.0))),
        (_attitude, Attitude, (0.25, Q, V)),
        (_snapshot, TelemetrySnapshot,
         (LocalPosition(0.0, 0.0, V, V, "ODOMETRY"), Attitude(0.0, Q, V), None, None, None)),
        (make_position_setpoint, PositionSetpoint, (V, None, V, 0.3, None)),
    ],
)
def test_direct_constructors_equal_the_dataclass_constructors(fast: Any, slow: Any,
                                                              args: tuple[Any, ...]) -> None:
    a, b = fast(*args), slow(*args)
    assert type(a) is type(b) and a == b and hash(a) == hash(b) and repr(a) == repr(b)
    # every field set, nothing else: a field added to the dataclass must be added here too
    assert set(vars(a)) == {f.name for f in dataclasses.fields(slow)}
    assert {k: v for k, v in vars(a).items() if not (isinstance(v, float) and math.isnan(v))} \
        == {k: v for k, v in vars(b).items() if not (isinstance(v, float) and math.isnan(v))}
    with pytest.raises(dataclasses.FrozenInstanceError):
        setattr(a, dataclasses.fields(slow)[0].name, 9.0)
    assert dataclasses.replace(a) == b


def test_snapshot_reused_only_while_unchanged() -> None:
    tel, px4 = TelemetryState(), Px4Side()
    s0 = tel.snapshot()
    assert s0 == TelemetrySnapshot() and tel.snapshot() is s0
    tel.update(px4.msg(m.MAVLink_local_position_ned_message(10, 1.0, 2.0, -3.0, 0.5, 0, 0)), 1.0)
    s1 = tel.snapshot()
    assert s1 is not s0 and s1.position is tel.position and tel.snapshot() is s1
    assert s1.position is not None and s1.position.pos_ned == (1.0, 2.0, -3.0)
    tel.update(px4.msg(m.MAVLink_attitude_quaternion_message(20, *Q, 0.1, 0.2, 0.3)), 2.0)
    s2 = tel.snapshot()
    assert s2.attitude is not None and s2.attitude.q_wxyz == Q and s2.position is s1.position
    tel.extended = None  # direct assignment (no update) is seen too
    tel.home = s2.home
    assert tel.snapshot() is s2
    tel.position = None
    assert tel.snapshot().position is None and tel.snapshot().attitude is s2.attitude


def test_dispatch_ignores_other_systems_and_unhandled_types() -> None:
    link = VehicleLink()
    px4, other = Px4Side(), Px4Side(sysid=2)
    link.receive_bytes(px4.frame(heartbeat(29, 50593792)), 0.0)
    lpos = m.MAVLink_local_position_ned_message(10, 1.0, 2.0, -3.0, 0, 0, 0)
    assert link.receive_bytes(other.frame(lpos), 1.0) == []
    assert link.telemetry.position is None and link.heartbeat.last_rx_s == 0.0
    # a type nobody handles still keeps the link alive, and produces no event
    vfr = m.MAVLink_vfr_hud_message(1.0, 2.0, 90, 50, -3.0, 0.1)
    assert link.receive_bytes(px4.frame(vfr), 1.5) == []
    assert link.heartbeat.last_rx_s == 1.5
    (ev,) = link.receive_bytes(px4.frame(lpos), 2.0)
    assert isinstance(ev, LocalPosition) and ev.t_s == 2.0 and ev.pos_ned == (1.0, 2.0, -3.0)
    assert link.telemetry.position is ev and link.heartbeat.last_rx_s == 2.0


FIN = st.floats(-1e3, 1e3)


@given(vals=st.lists(FIN, min_size=11, max_size=11), kinds=st.lists(st.integers(0, 2),
                                                                       min_size=11, max_size=11))
@settings(max_examples=40, deadline=None)
def test_numpy_and_int_components_give_the_same_message(vals: list[float],
                                                        kinds: list[int]) -> None:
    """Components may be float, numpy float64 or int: the message carries the same floats."""
    conv: list[Any] = [v if k == 0 else np.float64(v) if k == 1 else round(v)
                       for v, k in zip(vals, kinds, strict=True)]
    ref = [float(c) for c in conv]
    sp = PositionSetpoint(tuple(conv[0:3]), tuple(conv[3:6]), tuple(conv[6:9]), conv[9], conv[10])
    msg = build_setpoint(sp, 1, 1, 7)
    got = [msg.x, msg.y, msg.z, msg.vx, msg.vy, msg.vz, msg.afx, msg.afy, msg.afz, msg.yaw,
           msg.yaw_rate]
    assert got == ref and all(type(g) is float for g in got)


@pytest.mark.parametrize("field", ["pos_ned", "vel_ned", "acc_ned"])
def test_vectors_need_three_components(field: str) -> None:
    with pytest.raises(SetpointError, match="3 components"):
        build_setpoint(PositionSetpoint(**{field: (1.0, 2.0)}), 1, 1, 0)  # type: ignore[arg-type]
