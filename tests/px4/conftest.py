"""Real PX4 v1.16 SITL (SIH quadrotor) for the `px4` test set.

Every test gets a fresh PX4 (`px4_harness.Px4Sitl`: its own instance, ports, parameters and
estimator) that is stopped in the fixture's finally. Without a PX4 SITL (`$ECCA_PX4_SITL`, else
`../shared/px4_sitl`), every test here is skipped with the reason; CI has one, and sets
`ECCA_REQUIRE_PX4=1` so that a lost PX4 fails the run instead of skipping the set. On a failure the
tail of PX4's console is printed with the test's output.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from px4_harness import Px4Sitl, find_px4_sitl

_LOCATION, _WHY = find_px4_sitl()


def pytest_collection_modifyitems(config: Any, items: list[pytest.Item]) -> None:
    here = Path(__file__).parent
    if _LOCATION is None and os.environ.get("ECCA_REQUIRE_PX4"):
        # CI sets this: there a missing PX4 is a broken set-up, not a reason to skip the set
        raise pytest.UsageError(f"ECCA_REQUIRE_PX4 is set but there is no PX4 SITL: {_WHY}")
    for item in items:
        if Path(str(item.fspath)).parent == here:
            item.add_marker(pytest.mark.px4)
            if _LOCATION is None:
                item.add_marker(pytest.mark.skip(reason=f"no real PX4 SITL: {_WHY}"))


@pytest.fixture
def px4(tmp_path: Path) -> Iterator[Px4Sitl]:
    """A fresh PX4 SITL (SIH quad, default parameters), ready for takeoff."""
    sitl = Px4Sitl(location=_LOCATION, log=tmp_path / "px4-console.log")
    try:
        sitl.start()
        print(f"PX4 instance {sitl.instance}: {sitl.url}, sysid {sitl.target_system}")
        yield sitl
    finally:
        text = sitl.console_text()
        sitl.stop()
        print("---- PX4 console (tail) ----")
        print("\n".join(text.splitlines()[-40:]))
