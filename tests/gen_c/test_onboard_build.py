"""The onboard module builds: `python -m gen_c px4-module` against the PX4 dyn SDK (a shared
object exporting PX4's dyn entry point, the uORB layouts it expects taken from the SDK's own orb
definitions), and both of its C files cross-compile for a Cortex-M7."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from gen_c import crossbuild, px4module
from tests.support.gen_c import LIB, ROOT, run
from tests.support.onboard import module_folder, sdk_dir

SDK = sdk_dir()
needs_sdk = pytest.mark.skipif(SDK is None, reason="no PX4 dyn SDK beside the PX4 SITL "
                               "(../shared/px4_sitl/sdk)")
MODULE = ROOT / "gen_c" / "px4_module"


@needs_sdk
def test_the_documented_command_builds_a_dyn_module() -> None:
    assert SDK is not None
    with module_folder() as d:
        out = d / "ecca_onboard.px4mod"
        proc = subprocess.run([sys.executable, "-m", "gen_c", "px4-module", "--sdk", str(SDK),
                               "-o", str(out)], capture_output=True, text=True, timeout=300,
                              cwd=ROOT, check=False)
        assert proc.returncode == 0, proc.stderr
        syms = run(["nm", "-D", "--defined-only", str(out)]).stdout
        assert re.search(r" T px4_module_main$", syms, re.M)
        assert re.search(r" T ecca_onboard_main$", syms, re.M)
        # what it calls of PX4 is what bin/px4 exports (dyn resolves it at load)
        undefined = set(re.findall(r" U (\w+)", run(["nm", "-D", "--undefined-only",
                                                      str(out)]).stdout))
        px4 = SDK.parent / "bin" / "px4"
        exported = set(re.findall(r" [TDBRW] (\w+)$", run(["nm", "-D", "--defined-only",
                                                             str(px4)]).stdout, re.M))
        libc = {"memset", "memcpy", "memcmp", "strcmp", "strncmp", "sqrt", "cos", "tan", "sin",
                "atan2", "atan", "fabs", "fmax", "fmin", "clock_gettime", "floor", "sincos",
                "sched_get_priority_max", "sched_get_priority_min", "__stack_chk_fail"}
        assert undefined - exported - libc == set()
    bad = subprocess.run([sys.executable, "-m", "gen_c", "px4-module", "--sdk", "/nonexistent",
                          "-o", "/var/tmp/x.px4mod"], capture_output=True, text=True,
                         timeout=60, cwd=ROOT, check=False)
    assert bad.returncode == 2 and "SDK" in bad.stderr


@needs_sdk
def test_the_expected_layouts_are_the_sdk_s_orb_definitions() -> None:
    assert SDK is not None
    got = px4module.read_layouts(SDK)
    assert set(got) == set(px4module.TOPICS)
    for topic, (size, digest) in got.items():
        src = (SDK / "tools" / "orb_defs" / f"{topic}.cpp").read_text()
        assert f"ORB_DEFINE({topic}, struct {topic}_s, {size}, {digest}u," in src
    header = px4module.layout_header({**got, "vehicle_status": (got["vehicle_status"][0], 7)})
    assert "#define ECCA_LAYOUT_vehicle_status_HASH 7u" in header


def test_the_module_cross_compiles_for_a_cortex_m7(tmp_path: Path) -> None:
    assert crossbuild.have_arm_toolchain(), "arm-none-eabi-gcc is required"
    sdk_inc = None if SDK is None else SDK / "include"
    layouts = {t: (8, 1) for t in px4module.TOPICS}
    (tmp_path / "ecca_onboard_layout.h").write_text(px4module.layout_header(layouts))
    flags = ["-mcpu=cortex-m7", "-mfpu=fpv5-d16", "-mfloat-abi=hard", "-mthumb", "-O2",
             "-Wall", "-Wextra", "-Wshadow", "-Wdouble-promotion", "-Wundef",
             f"-I{LIB}", f"-I{MODULE}", f"-I{tmp_path}", "-DECCA_SETPOINT_NO_FLOAT"]
    # the logic: plain C99, every warning an error
    run([crossbuild.ARM_CC, *flags, "-std=c99", "-pedantic", "-Werror", "-c",
         str(MODULE / "ecca_onboard_core.c"), "-o", str(tmp_path / "core.o")])
    if sdk_inc is not None:  # the PX4 glue, against the SDK's uORB headers
        run([crossbuild.ARM_CC, *flags, "-std=gnu11", "-Wno-implicit-function-declaration",
             "-DECCA_DYN", "-include", str(sdk_inc / "visibility.h"), f"-I{sdk_inc}", "-c",
             str(MODULE / "ecca_onboard.c"), "-o", str(tmp_path / "glue.o")])
    size = run([crossbuild.ARM_CC.replace("gcc", "size"), str(tmp_path / "core.o")]).stdout
    text, data, bss = (int(x) for x in size.splitlines()[1].split()[:3])
    assert data == 0 and bss == 0 and 0 < text < 16_000  # the logic holds no globals
