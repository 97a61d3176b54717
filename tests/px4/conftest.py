"""Real PX4 SITL for the `px4` test set: v1.16 (SIH quadrotor, fixture `px4`) and PX4 built from
main (SIH Ackermann rover, fixture `px4_rover`).

Every test gets a fresh PX4 (`px4_harness.Px4Sitl`: its own instance, ports, parameters and
estimator) that is stopped in the fixture's finally. Without a PX4 SITL (`$ECCA_PX4_SITL`, else
`../shared/px4_sitl`; for the rover `$ECCA_PX4_MAIN_SITL`, else `../shared/px4_main_sitl`), the
tests that need it are skipped with the reason; CI has both, and sets `ECCA_REQUIRE_PX4=1` so that
a lost PX4 fails the run instead of skipping the set. On a failure the
tail of PX4's console is printed with the test's output.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from px4_harness import STARTED_MARK, Px4Sitl, find_px4_sitl

_LOCATION, _WHY = find_px4_sitl()
_MAIN_LOCATION, _MAIN_WHY = find_px4_sitl("main")


def pytest_collection_modifyitems(config: Any, items: list[pytest.Item]) -> None:
    here = Path(__file__).parent
    if os.environ.get("ECCA_REQUIRE_PX4"):
        # CI sets this: there a missing PX4 is a broken set-up, not a reason to skip the set
        for loc, why in ((_LOCATION, _WHY), (_MAIN_LOCATION, _MAIN_WHY)):
            if loc is None:
                raise pytest.UsageError(f"ECCA_REQUIRE_PX4 is set but there is no PX4 SITL: {why}")
    for item in items:
        if Path(str(item.fspath)).parent == here:
            item.add_marker(pytest.mark.px4)
            rover = "px4_rover" in getattr(item, "fixturenames", ())
            loc, why = (_MAIN_LOCATION, _MAIN_WHY) if rover else (_LOCATION, _WHY)
            if loc is None:
                item.add_marker(pytest.mark.skip(reason=f"no real PX4 SITL: {why}"))


def _running(sitl: Px4Sitl, what: str) -> Iterator[Px4Sitl]:
    """Start `sitl`, yield it, and stop it whatever happens, printing its console's tail."""
    try:
        sitl.start()
        print(f"{what} instance {sitl.instance}: {sitl.url}, sysid {sitl.target_system}")
        yield sitl
    finally:
        text = sitl.console_text()
        sitl.stop()
        print("---- PX4 console (tail) ----")
        print("\n".join(text.splitlines()[-40:]))


@pytest.fixture
def px4(tmp_path: Path) -> Iterator[Px4Sitl]:
    """A fresh PX4 SITL (SIH quad, default parameters), ready for takeoff."""
    yield from _running(Px4Sitl(location=_LOCATION, log=tmp_path / "px4-console.log"), "PX4")


@pytest.fixture
def px4_rover(tmp_path: Path) -> Iterator[Px4Sitl]:
    """A fresh PX4 built from main driving SIH's Ackermann rover, started (its estimator takes
    ~6 s more before it can arm: a test retries arming)."""
    yield from _running(Px4Sitl(location=_MAIN_LOCATION, model="sihsim_rover_ackermann",
                                log=tmp_path / "px4-console.log", ready_mark=STARTED_MARK),
                        "PX4 (main) rover")
