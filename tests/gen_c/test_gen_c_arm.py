"""gen_c: both variants cross-compile for a Cortex-M7 (arm-none-eabi-gcc -mcpu=cortex-m7
-mfpu=fpv5-d16 -mfloat-abi=hard -O2 -fstack-usage), link against newlib's libm, hold no RAM
(.data/.bss) and have a bounded, measured worst-case stack."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

from gen_c import crossbuild


@pytest.mark.parametrize("variant", ["double", "float"])
def test_cortex_m7_build(variant: str, tmp_path: Path) -> None:
    assert crossbuild.have_arm_toolchain(), (
        "arm-none-eabi-gcc is required (README test command installs gcc-arm-none-eabi)")
    r = crossbuild.build_arm(variant, tmp_path)
    assert (tmp_path / "fw.elf").stat().st_size > 0
    assert r.data == 0 and r.bss == 0  # no mutable globals
    assert 2_000 < r.text < 64_000
    assert set(r.worst_stack) == {n + ("" if variant == "double" else "_f")
                                  for n in crossbuild.PUBLIC}
    # Every public function has a frame, the full setpoint is the deepest chain, and it fits
    # comfortably in a PX4 work-queue stack.
    assert all(v > 0 for v in r.worst_stack.values())
    full = r.worst_stack["ecca_full_setpoint" + ("" if variant == "double" else "_f")]
    assert full == r.max_stack and full < 4096
    print(f"gen_c Cortex-M7 {variant}: text {r.text} B, worst stack {r.worst_stack} ({r.compiler})")


def test_float_variant_uses_no_double_arithmetic(tmp_path: Path) -> None:
    """On a single-precision FPU every double operation is a slow soft-float call: the float
    variant's machine code must contain no double-precision instruction or helper."""
    crossbuild.build_arm("float", tmp_path)
    objdump = shutil.which("arm-none-eabi-objdump")
    assert objdump is not None
    for obj in ("ecca_setpoint.o", "ecca_gen_f.o"):
        asm = subprocess.run([objdump, "-d", str(tmp_path / obj)], capture_output=True,
                             text=True, timeout=60, check=True).stdout
        assert "vadd.f32" in asm or "vmul.f32" in asm or obj == "ecca_setpoint.o"
        assert ".f64" not in asm, f"{obj} uses double-precision instructions"
        assert "__aeabi_d" not in asm, f"{obj} calls soft-float double helpers"
