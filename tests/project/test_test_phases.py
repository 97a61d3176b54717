"""The README's two test phases: a test module that flies the mock in wall-clock time carries the
`realtime` marker, so that it runs in the second phase and never beside a computing test.

A module counts as flying in wall-clock time when it starts the mock as a served process or
in-process server (`run_mock`, `run_companion`, `connect_drone`, `MockServer`) or talks to it
through MAVSDK; tests/px4/ is the `px4` set (its conftest marks it).
"""

from __future__ import annotations

import re
from pathlib import Path

from tests.support.phases import scope_of

ROOT = Path(__file__).resolve().parents[2]
FLIES_IN_REAL_TIME = re.compile(
    r"\b(run_mock|run_companion|connect_drone|MockServer)\b|^\s*(import|from) mavsdk\b", re.M)
MARKED = re.compile(r"^pytestmark = .*pytest\.mark\.realtime\b", re.M)


def _test_modules() -> list[Path]:
    found = [*ROOT.joinpath("tests").rglob("test_*.py"),
             *ROOT.joinpath("bench", "tests").glob("test_*.py")]
    return sorted(p for p in found if ROOT.joinpath("tests", "px4") not in p.parents
                  and p != Path(__file__).resolve())


def test_every_module_flying_the_mock_in_real_time_is_marked_realtime() -> None:
    texts = {p: p.read_text(encoding="utf-8") for p in _test_modules()}
    unmarked = [str(p.relative_to(ROOT)) for p, text in texts.items()
                if FLIES_IN_REAL_TIME.search(text) and not MARKED.search(text)]
    assert unmarked == []


def test_the_oracle_sees_the_modules_it_is_about() -> None:
    flying = [p.name for p in _test_modules()
              if FLIES_IN_REAL_TIME.search(p.read_text(encoding="utf-8"))]
    # the served mock, MAVSDK and the in-process server, each found by the pattern
    assert {"test_cli_fly.py", "test_mavsdk_mock.py", "test_signing_udp.py"} <= set(flying)


def test_readme_runs_the_two_phases() -> None:
    text = ROOT.joinpath("README.md").read_text(encoding="utf-8")
    assert "--dist worksteal -m 'not realtime and not px4'" in text
    assert "--dist loadgroup -m 'realtime or px4'" in text


def test_the_px4_set_is_one_unit_of_work_and_nothing_else_is() -> None:
    px4 = [p.relative_to(ROOT).as_posix() + "::test_x"
           for p in ROOT.joinpath("tests", "px4").glob("test_*.py")]
    assert len(px4) > 3 and {scope_of(n) for n in px4} == {"px4"}
    others = ["tests/integration/test_cli_fly.py::test_a",
              "tests/integration/test_cli_fly.py::test_b",
              "bench/tests/test_px4_like.py::test_c", "tests/companion/test_px4.py::test_d"]
    assert [scope_of(n) for n in others] == others
