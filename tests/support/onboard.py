"""Building the onboard PX4 module for tests: the SDK beside the PX4 SITL, a folder outside /tmp
(PX4's /tmp is private), the module's `status` line parsed."""

from __future__ import annotations

import re
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from px4_harness import Px4Sitl, find_px4_sitl


def sdk_dir() -> Path | None:
    """The dyn SDK of the PX4 SITL the tests use (`<px4_sitl>/sdk`), or None."""
    loc, _ = find_px4_sitl()
    if loc is None:
        return None
    for base in (loc.root, loc.binary.parent.parent):
        if (base / "sdk" / "include" / "px4_dyn_abi.h").exists():
            return base / "sdk"
    return None


@contextmanager
def module_folder() -> Iterator[Path]:
    """A fresh folder under /var/tmp for module files, removed afterwards."""
    path = Path(tempfile.mkdtemp(prefix="ecca-onboard-test-", dir="/var/tmp"))
    try:
        yield path
    finally:
        shutil.rmtree(path, ignore_errors=True)


_STATUS = re.compile(r"state (\d+), segments (\d+)/(\d+), crc 0x([0-9a-f]+), progress ([0-9.]+)")


def module_state(px4: Px4Sitl, module: Path) -> tuple[int, float]:
    """(state, progress 0..1) from `dyn MODULE status` in that PX4."""
    out = px4.command("dyn", str(module), "status").stdout
    m = _STATUS.search(out)
    assert m is not None, f"no status line in {out!r}"
    return int(m[1]), float(m[5])
