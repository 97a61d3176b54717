"""Fuzzing (hypothesis): mission text -> loader -> flight plan -> schedule; MAVLink datagrams
into the companion's link and into the mock (PARAM_SET included). Only documented errors, and
every target still usable after each input (see targets.py). Longer runs: campaign.py (plain
mutation, one core) or atheris_main.py (coverage-guided)."""

from __future__ import annotations

import json
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.fuzz import corpus
from tests.fuzz.campaign import mutate
from tests.fuzz.targets import (
    LINK_CLASSES,
    Finding,
    LinkTarget,
    MissionTarget,
    MockTarget,
    mission_target,
)

# Example counts sized for CI's 25-minute budget (fresh random examples every run: over many
# runs the fuzzing goes on; long campaigns: python -m tests.fuzz.campaign)
FUZZ = settings(max_examples=90, deadline=None, derandomize=False,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
MISSION_SEEDS = corpus.mission_seeds()

extreme_numbers = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([1e300, -1e300, 1e15, 1e8, 10_000.0, 10_001.0, 3600.0, 3601.0, 40.0, 40.5,
                     200.0, 0.0, -0.0, -1.0, -2.0, 65_535, 2**31, 2**63]),
)


@FUZZ
@given(seed=st.sampled_from(MISSION_SEEDS), rng=st.randoms(use_true_random=False),
       rounds=st.integers(1, 4))
def test_mutated_mission_files(seed: bytes, rng: Any, rounds: int) -> None:
    data = seed
    for _ in range(rounds):
        data = mutate(data, rng, MISSION_SEEDS)
    mission_target(data)


def _plans() -> list[dict[str, Any]]:
    out = []
    for s in MISSION_SEEDS:
        try:
            doc = json.loads(s)
        except ValueError:
            continue
        if isinstance(doc, dict) and isinstance(doc.get("mission"), dict) and isinstance(
                doc["mission"].get("items"), list) and doc["mission"]["items"]:
            out.append(doc)
    return out


PLANS = _plans()


@FUZZ
@given(st.data())
def test_plans_with_extreme_item_values(data: st.DataObject) -> None:
    """Numbers at and beyond PX4's limits in any param of any item (the 1e300 class)."""
    doc = json.loads(json.dumps(data.draw(st.sampled_from(PLANS))))
    items = [it for it in doc["mission"]["items"] if isinstance(it.get("params"), list)]
    for _ in range(data.draw(st.integers(1, 3))):
        if not items:
            break
        it = data.draw(st.sampled_from(items))
        k = data.draw(st.integers(0, len(it["params"]) - 1))
        it["params"][k] = data.draw(extreme_numbers)
    if data.draw(st.booleans()) and isinstance(doc["mission"].get("plannedHomePosition"), list):
        doc["mission"]["plannedHomePosition"][2] = data.draw(extreme_numbers)
    try:
        text = json.dumps(doc)
    except (ValueError, OverflowError):
        return
    mission_target(text.encode())


@pytest.fixture(scope="module")
def memo_target() -> MissionTarget:
    return MissionTarget(memo_entries=256, verify_every=1)


@settings(max_examples=12, deadline=None, derandomize=False,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                 HealthCheck.function_scoped_fixture])
@given(seed=st.sampled_from(MISSION_SEEDS[:8]), rng=st.randoms(use_true_random=False))
def test_mutated_missions_served_from_the_plan_memo_schedule_as_planned(
    memo_target: MissionTarget, seed: bytes, rng: Any
) -> None:
    """The campaign's memo (verify_every=1): every input served from it, even in part, is
    scheduled again without it and must come out the same bit for bit."""
    memo_target(seed)
    memo_target(mutate(seed, rng, MISSION_SEEDS))
    stats = memo_target.stats()
    assert stats["entries"] == min(stats["chunks_planned"], 256)


def test_the_memo_check_finds_a_memo_that_serves_another_plan() -> None:
    """The verification can fail: a memo whose entries were moved by 1 m is caught on the
    next input served from it."""
    target = MissionTarget(memo_entries=64, verify_every=1)
    square = (corpus.ROOT / "examples" / "missions" / "square.plan").read_bytes()
    assert target(square) == "flown"
    entries = target.memo._entries
    for key, traj in entries.items():
        entries[key] = type(traj).from_control_points(traj.control_points + 1.0,
                                                      traj.durations, traj.yaw)
    with pytest.raises(Finding, match="memo served a schedule different"):
        target(square)
    assert target.stats()["inputs_from_memo"] == 1


chunk_kinds = st.one_of(st.integers(0, 255), st.sampled_from([0, 0xF0, 0xFF]))
fuzz_chunks = st.lists(st.tuples(chunk_kinds, st.binary(max_size=80)), max_size=12)


def _input(chs: list[tuple[int, bytes]]) -> bytes:
    return b"".join(corpus.chunk(k, d) for k, d in chs)


@FUZZ
@given(fuzz_chunks)
def test_datagrams_into_the_companion_link(chs: list[tuple[int, bytes]]) -> None:
    LinkTarget()(_input(chs))


@FUZZ
@given(st.binary(max_size=400))
def test_raw_bytes_into_the_companion_link(blob: bytes) -> None:
    LinkTarget()(blob)


@pytest.fixture(scope="module")
def mock() -> MockTarget:
    return MockTarget(renew_every=60, check_every=10)


@FUZZ
@given(fuzz_chunks)
def test_datagrams_into_the_mock(mock: MockTarget, chs: list[tuple[int, bytes]]) -> None:
    mock(_input(chs))


@FUZZ
@given(st.lists(st.tuples(st.integers(0, 255), extreme_numbers, st.integers(0, 255)),
                min_size=1, max_size=6))
def test_param_set_of_any_value_into_the_mock(
    mock: MockTarget, sets: list[tuple[int, float, int]]
) -> None:
    import struct

    data = b""
    for idx, value, ptype in sets:
        try:
            packed = struct.pack("<f", value)
        except OverflowError:
            packed = struct.pack("<f", float("inf") if value > 0 else float("-inf"))
        data += corpus.chunk(0xF0, bytes((idx,)) + packed + bytes((ptype,)))
        data += corpus.chunk(0xFF, b"\x00" * 10)
    mock(data)


def test_seed_corpora_pass() -> None:
    """Every seed input is handled (a regression net for the corpus the campaign starts from)."""
    for s in MISSION_SEEDS:
        mission_target(s)
    link, mock = LinkTarget(), MockTarget(renew_every=1000, check_every=50)
    for s in corpus.datagram_seeds(len(LINK_CLASSES), 80):
        link(s)
    for s in corpus.datagram_seeds(len(mock.classes), len(mock.param_names)):
        mock(s)
    mock.check_usable()
