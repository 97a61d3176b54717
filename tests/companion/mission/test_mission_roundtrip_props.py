"""Round trips of the mission conversions (companion.mission.convert): file -> model -> file,
model -> wire -> model -> wire, and wire -> MAVLink bytes (float32) -> model, on random valid
missions (positions on the degE7 grid, altitudes on the millimetre grid, as the wire carries
them)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as mavlink2

from companion.mavlink import WireMissionItem, item_from_msg, item_to_msg
from companion.mission import (
    GeoPoint,
    Mission,
    MissionItem,
    loads_mission,
    mission_from_wire,
    mission_to_wpl,
    mission_upload_items,
    ned_to_geodetic,
)

SETTINGS = settings(max_examples=150, deadline=None)

homes = st.builds(
    GeoPoint,  # not within 0.5 deg of the equator: (0, 0) means "no position" in a mission
    st.integers(5_000_000, 600_000_000).map(lambda v: v / 1e7) | st.integers(
        -600_000_000, -5_000_000).map(lambda v: v / 1e7),
    st.integers(-1_790_000_000, 1_790_000_000).map(lambda v: v / 1e7),
    st.integers(-100_000, 3_000_000).map(lambda v: v / 1e3),
)
#: a few steps of 0.25 (float32-exact), NaN for "not set"
quarters = st.integers(0, 240).map(lambda v: v / 4)
alts_rel = st.integers(1_000, 120_000).map(lambda v: v / 1e3)


@st.composite
def missions(draw: Any) -> Mission:
    """A valid mission: takeoff, then waypoints / loiters / speed changes / delays / a DO_JUMP
    back, maybe an RTL or LAND at the end; position frames 3 (relative) or 0 (AMSL)."""
    home = draw(homes)
    rows: list[tuple[int, int, tuple[float, ...]]] = []  # (command, frame, params)

    def position(cmd: int, p1: float, p2: float, p4: float) -> None:
        n, e = draw(st.integers(-1500, 1500)), draw(st.integers(-1500, 1500))
        lat, lon, _ = ned_to_geodetic(np.array([float(n), float(e), 0.0]), home)
        lat_q, lon_q = round(float(lat) * 1e7) / 1e7, round(float(lon) * 1e7) / 1e7
        rel = draw(alts_rel)
        frame = draw(st.sampled_from([3, 0]))
        alt = rel if frame == 3 else round(home.alt_amsl_m + rel, 3)
        rows.append((cmd, frame, (p1, p2, 0.0, p4, lat_q, lon_q, alt)))

    position(22, 0.0, 0.0, math.nan)
    for _ in range(draw(st.integers(1, 8))):
        kind = draw(st.sampled_from(["wp", "wp", "loiter", "speed", "delay", "jump"]))
        if kind == "wp":
            yaw = draw(st.one_of(st.just(math.nan), st.integers(-180, 180).map(float)))
            position(16, draw(quarters), draw(st.integers(0, 20)) / 2, yaw)
        elif kind == "loiter":
            position(19, draw(quarters), 0.0, math.nan)
        elif kind == "speed":
            rows.append((178, 2, (1.0, draw(st.integers(2, 30)) / 2, -1.0, 0.0, 0.0, 0.0, 0.0)))
        elif kind == "delay":
            rows.append((93, 2, (draw(quarters), -1.0, -1.0, -1.0, 0.0, 0.0, 0.0)))
        elif len(rows) >= 2:
            target = draw(st.integers(2, len(rows)))  # an item index after the takeoff
            rows.append((177, 2, (float(target), float(draw(st.integers(0, 2))), 0.0, 0.0,
                                  0.0, 0.0, 0.0)))
    end = draw(st.sampled_from([None, 20, 21]))
    if end == 20:
        rows.append((20, 2, (0.0,) * 7))
    elif end == 21:
        position(21, 0.0, 0.0, math.nan)
    items = tuple(
        MissionItem(index=k, command=cmd, frame=frame,
                    params=(p[0], p[1], p[2], p[3], p[4], p[5], p[6]))
        for k, (cmd, frame, p) in enumerate(rows, start=1)
    )
    # through the file parser, so the mission is one a file can hold (every check applied)
    return loads_mission(mission_to_wpl(Mission(Path("gen.waypoints"), home, items)),
                         source="gen.waypoints")


def _nan_eq(a: tuple[float, ...], b: tuple[float, ...]) -> bool:
    return all(x == y or (math.isnan(x) and math.isnan(y)) for x, y in zip(a, b, strict=True))


def _wire_key(w: WireMissionItem, mm: bool = False) -> tuple[Any, ...]:
    """The wire fields (NaN comparable; ``mm``: altitude to the millimetre)."""
    fields = (w.param1, w.param2, w.param3, w.param4)
    return (w.seq, w.frame, w.command, w.current, w.autocontinue, w.x, w.y,
            round(w.z, 3) if mm else w.z, w.mission_type,
            tuple("nan" if math.isnan(p) else p for p in fields))


def _same_items(a: tuple[MissionItem, ...], b: tuple[MissionItem, ...]) -> bool:
    def key(it: MissionItem) -> tuple[Any, ...]:
        return (it.index, it.command, it.frame, it.autocontinue, it.current,
                tuple("nan" if math.isnan(p) else p for p in it.params))

    return [key(x) for x in a] == [key(y) for y in b]


@SETTINGS
@given(missions())
def test_file_model_file(m: Mission) -> None:
    text = mission_to_wpl(m)
    back = loads_mission(text, source="gen.waypoints")
    assert back.home == m.home
    assert _same_items(back.items, m.items)
    assert mission_to_wpl(back) == text


@SETTINGS
@given(missions())
def test_model_wire_model_wire(m: Mission) -> None:
    wire = mission_upload_items(m)
    back = mission_from_wire(wire, m.home)
    assert [it.index for it in back.items] == [it.index for it in m.items]
    for a, b in zip(m.items, back.items, strict=True):
        assert (a.command, a.autocontinue) == (b.command, b.autocontinue)
        assert _nan_eq(a.params[:4], b.params[:4])
        if a.has_latlon:  # positions: frame 3, degE7 exact, altitude relative to home
            assert b.frame == 3
            assert (b.lat_deg, b.lon_deg) == (a.lat_deg, a.lon_deg)
            assert b.alt_rel_home_m(m.home) == round(a.alt_rel_home_m(m.home), 3)
    again = mission_upload_items(back)
    assert [_wire_key(w, mm=True) for w in again] == [_wire_key(w, mm=True) for w in wire]
    # a fixpoint from then on: wire -> model -> wire is exact
    assert [_wire_key(w) for w in mission_upload_items(mission_from_wire(again, m.home))] == [
        _wire_key(w) for w in again]


@SETTINGS
@given(missions())
def test_wire_bytes_model(m: Mission) -> None:
    wire = mission_upload_items(m)
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    decoded: list[WireMissionItem] = []
    for w in wire:
        buf = item_to_msg(w, 1, 1).pack(mav)
        decoded.append(item_from_msg(mav.decode(bytearray(buf))))
    # float32 params and altitude on the wire: the model is the same after the millimetre rounding
    assert _same_items(mission_from_wire(decoded, m.home).items,
                       mission_from_wire(wire, m.home).items)
