"""Shared helpers of the gen_c golden tests (compiler lookup, tolerance rule, builds)."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
import numpy.typing as npt

ROOT = Path(__file__).resolve().parents[2]
LIB = ROOT / "gen_c" / "ecca_setpoint"
TESTS = ROOT / "gen_c" / "tests"
STRICT = ("-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic")
# The extra warnings PX4 builds C with (px4_add_common_flags), minus -Wno-* relaxations.
PX4_EXTRA = ("-Wdouble-promotion", "-Wfloat-conversion", "-Wshadow", "-Wmissing-prototypes",
             "-Wstrict-prototypes", "-Wundef", "-Wcast-align", "-Wbad-function-cast",
             "-Wfloat-equal", "-Wmissing-declarations", "-Wnested-externs", "-Wpointer-arith",
             "-Wlogical-op", "-Winit-self", "-Wuninitialized")
GEN_SOURCES = ("ecca_setpoint.c", "ecca_gen_d.c", "ecca_gen_f.c")
RTOL_DOUBLE = 1e-12
RTOL_FLOAT = 1e-4


def cc() -> str:
    path = shutil.which("cc") or shutil.which("gcc")
    assert path is not None, "a C compiler (cc) is required by the gen_c tests"
    return path


def run(cmd: list[str], cwd: Path | None = None,
        timeout: float = 120) -> subprocess.CompletedProcess[str]:
    proc = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=timeout,
                          check=False)
    assert proc.returncode == 0, (
        f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stdout}\n{proc.stderr}")
    return proc


def assert_close(got: npt.ArrayLike, expect: npt.ArrayLike, rtol: float, what: str) -> None:
    """|got - expect| <= rtol * max(max |expect| over the field, 1), componentwise (the rule of
    gen_c/tests/test_ecca_setpoint.c)."""
    g = np.atleast_1d(np.asarray(got, dtype=np.float64))
    e = np.atleast_1d(np.asarray(expect, dtype=np.float64))
    assert g.shape == e.shape, f"{what}: shape {g.shape} != {e.shape}"
    assert np.all(np.isfinite(g)), f"{what}: non-finite {g}"
    scale = max(1.0, float(np.max(np.abs(e))))
    err = float(np.max(np.abs(g - e)))
    assert err <= rtol * scale, (
        f"{what}: got {g}, expected {e}, error {err:.3g} > {rtol * scale:.3g}")
