"""The README's two test phases under pytest-xdist: the `px4` set is one unit of work, so that one
worker flies it test after test (one PX4 at a time: every PX4 SITL instance sends its GCS link to
UDP 14550), while the other tests are scheduled one by one on the free worker."""

from __future__ import annotations

PX4_DIR = "tests/px4/"
PX4_SCOPE = "px4"


def scope_of(nodeid: str) -> str:
    """The unit of work a test (pytest node id, relative to the repository) belongs to."""
    return PX4_SCOPE if nodeid.startswith(PX4_DIR) else nodeid
