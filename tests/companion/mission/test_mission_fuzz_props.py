"""Fuzzing the loaders: random and mutated .plan JSON and QGC WPL text give a MissionError or a
valid mission, never another exception; what loads also expands without a traceback."""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from companion.mission import (
    Mission,
    MissionError,
    loads_mission,
    mission_to_flight_plan,
    mission_upload_items,
    parse_plan,
    parse_wpl,
    split_flight_plan,
)

EXAMPLES = Path(__file__).resolve().parents[3] / "examples" / "missions"
DATA = Path(__file__).resolve().parents[2] / "data" / "missions"
SETTINGS = settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])

BASE_PLANS = [
    json.loads((EXAMPLES / n).read_text())
    for n in ("square.plan", "hold_and_jump.plan", "survey.plan")
] + [json.loads((DATA / n).read_text()) for n in ("all_commands.plan", "geofence.plan")]
BASE_WPL = [
    (EXAMPLES / "square.waypoints").read_text(),
    (DATA / "all_commands.waypoints").read_text(),
]

numbers = st.one_of(
    st.integers(min_value=-(2**70), max_value=2**70),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0, 1, 2, 3, 5, 6, 10, 11, 16, 17, 19, 20, 21, 22, 177, 178, 195, 197, -1, -2]),
)
scalars = st.one_of(st.none(), st.booleans(), numbers, st.text(max_size=8))
json_values = st.recursive(
    scalars,
    lambda children: st.one_of(
        st.lists(children, max_size=6),
        st.dictionaries(
            st.sampled_from(
                ["type", "command", "frame", "params", "items", "mission", "version",
                 "fileType", "polygon", "circle", "center", "radius", "inclusion", "points",
                 "TransectStyleComplexItem", "Items", "complexItemType", "doJumpId"]
            ) | st.text(max_size=5),
            children,
            max_size=6,
        ),
    ),
    max_leaves=16,
)  # fmt: skip


def _flies_or_clean_error(m: Mission) -> None:
    for vehicle in ("quad", "rover"):
        try:
            fp = mission_to_flight_plan(m, max_items=2000, vehicle=vehicle)
        except MissionError as exc:
            assert str(exc).startswith(str(m.source))
            continue
        pts = fp.points_ned_m()
        assert np.all(np.isfinite(pts))
        for c in split_flight_plan(fp):
            assert np.all(np.isfinite(c.points_ned_m))
            assert all(math.isfinite(s) and s > 0 for s in c.leg_speed_m_s)
    try:
        up = mission_upload_items(m)
    except MissionError as exc:
        assert str(exc).startswith(str(m.source))
        return
    assert all(math.isfinite(u.z) for u in up)


def _load(text: str | bytes, source: str) -> None:
    try:
        m = loads_mission(text, source=source)
    except MissionError as exc:
        assert str(exc).startswith(source + ": ")
        return
    _flies_or_clean_error(m)


@SETTINGS
@given(json_values)
def test_random_json_documents(doc: Any) -> None:
    try:
        text = json.dumps(doc)
    except (ValueError, OverflowError):
        return
    try:
        m = parse_plan(text, source="fuzz.plan")
    except MissionError as exc:
        assert str(exc).startswith("fuzz.plan: ")
        return
    _flies_or_clean_error(m)


def _paths(obj: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    out = [prefix]
    if isinstance(obj, dict):
        for k, v in obj.items():
            out += _paths(v, (*prefix, k))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            out += _paths(v, (*prefix, i))
    return out


@SETTINGS
@given(st.data())
def test_mutated_plans(data: st.DataObject) -> None:
    doc = copy.deepcopy(data.draw(st.sampled_from(BASE_PLANS)))
    paths = _paths(doc)
    for _ in range(data.draw(st.integers(1, 3))):
        path = data.draw(st.sampled_from(paths[1:]))
        parent: Any = doc
        try:
            for key in path[:-1]:
                parent = parent[key]
            action = data.draw(st.sampled_from(["replace", "delete"]))
            if action == "delete":
                del parent[path[-1]]
            else:
                parent[path[-1]] = data.draw(json_values)
        except (KeyError, IndexError, TypeError):
            continue
    try:
        text = json.dumps(doc)
    except (ValueError, OverflowError):
        return
    _load(text, "mutated.plan")


@SETTINGS
@given(st.data())
def test_truncated_or_spliced_text(data: st.DataObject) -> None:
    base = data.draw(st.sampled_from([json.dumps(d) for d in BASE_PLANS] + BASE_WPL))
    i = data.draw(st.integers(0, len(base)))
    j = data.draw(st.integers(i, len(base)))
    junk = data.draw(st.text(max_size=10))
    _load(base[:i] + junk + base[j:], "spliced.txt")


wpl_tokens = st.one_of(
    st.sampled_from(["0", "1", "2", "3", "16", "22", "177", "nan", "inf", "-1", "1e309", "",
                     "47.3977", "8.5456", "488", "x", "1.5", "-0", "0x10", " "]),
    st.text(alphabet="0123456789.-eE+naif \t", max_size=6),
)  # fmt: skip


@SETTINGS
@given(st.lists(st.lists(wpl_tokens, min_size=0, max_size=14), max_size=8))
def test_random_wpl_lines(rows: list[list[str]]) -> None:
    text = "QGC WPL 110\n" + "\n".join("\t".join(r) for r in rows)
    try:
        m = parse_wpl(text, source="fuzz.waypoints")
    except MissionError as exc:
        assert str(exc).startswith("fuzz.waypoints: ")
        return
    _flies_or_clean_error(m)


@SETTINGS
@given(st.data())
def test_mutated_wpl(data: st.DataObject) -> None:
    lines = data.draw(st.sampled_from(BASE_WPL)).splitlines()
    for _ in range(data.draw(st.integers(1, 3))):
        k = data.draw(st.integers(0, len(lines) - 1))
        fields = lines[k].split("\t")
        op = data.draw(st.sampled_from(["field", "drop_line", "dup_line", "drop_field"]))
        if op == "field":
            fields[data.draw(st.integers(0, len(fields) - 1))] = data.draw(wpl_tokens)
            lines[k] = "\t".join(fields)
        elif op == "drop_line":
            del lines[k]
        elif op == "dup_line":
            lines.insert(k, lines[k])
        elif len(fields) > 1:
            del fields[data.draw(st.integers(0, len(fields) - 1))]
            lines[k] = "\t".join(fields)
        if not lines:
            break
    _load("\n".join(lines), "mutated.waypoints")


@SETTINGS
@given(st.binary(max_size=200))
def test_random_bytes(blob: bytes) -> None:
    _load(blob, "blob.bin")
    _load(b"QGC WPL 110\n" + blob, "blob.waypoints")
    _load(b'{"fileType": "Plan", ' + blob, "blob.plan")
