"""Static checks the project promises: `ruff` clean everywhere, `mypy --strict` clean on the pure
layers (DESIGN.md). Run as tests so CI enforces them."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PURE = [
    "companion/geometry.py",
    "companion/flatness",
    "companion/trajectory",
    "companion/control",
    "companion/mission",
    "companion/mavlink",
    "companion/planning",
    "companion/flight",
    "companion/serve/service.py",
    "companion/serve/onboard.py",
]


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", *args], cwd=ROOT, capture_output=True, text=True, timeout=600
    )


def test_ruff_clean() -> None:
    r = _run("ruff", "check", ".")
    assert r.returncode == 0, r.stdout + r.stderr


def test_mypy_strict_on_pure_layers() -> None:
    r = _run("mypy", "--strict", "--no-error-summary", *PURE)
    assert r.returncode == 0, r.stdout + r.stderr
