"""Cross-compile the C setpoint library for a Cortex-M7 and measure code size and stack use.

``build_arm(variant, out_dir)`` compiles one variant ("double" or "float") with
``arm-none-eabi-gcc -mcpu=cortex-m7 -mfpu=fpv5-d16 -mfloat-abi=hard -O2 -fstack-usage``
(plus ``-fcallgraph-info=su`` to get the call graph), links it against newlib's libm in a
minimal program (all symbols must resolve) and returns the library's code size
(arm-none-eabi-size) and the worst-case stack depth of each public function: its own frame plus
the deepest chain of callees inside the library (from the .su/.ci files; newlib's math
functions are not included). Imports nothing from ``companion``.
"""

from __future__ import annotations

import re
import shutil
import subprocess
from dataclasses import dataclass, field
from pathlib import Path

LIB_DIR = Path(__file__).resolve().parent / "ecca_setpoint"
ARM_CC = "arm-none-eabi-gcc"
ARM_SIZE = "arm-none-eabi-size"
ARM_FLAGS = ("-mcpu=cortex-m7", "-mfpu=fpv5-d16", "-mfloat-abi=hard", "-mthumb", "-O2",
             "-fstack-usage", "-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic",
             "-ffunction-sections", "-fdata-sections")
PUBLIC = ("ecca_bezier_eval", "ecca_multirotor_setpoint", "ecca_rover_setpoint",
          "ecca_full_setpoint", "ecca_full_rover_setpoint", "ecca_ackermann_setpoint",
          "ecca_full_ackermann_setpoint", "ecca_tracking_core", "ecca_disturbance_step",
          "ecca_velocity_correction_step")


class CrossBuildError(RuntimeError):
    """The cross-compiler is missing or the build failed."""


@dataclass(frozen=True)
class ArmReport:
    """Result of one variant's Cortex-M7 build (bytes)."""

    variant: str
    text: int
    data: int
    bss: int
    worst_stack: dict[str, int] = field(default_factory=dict)
    compiler: str = ""

    @property
    def max_stack(self) -> int:
        return max(self.worst_stack.values())


def have_arm_toolchain() -> bool:
    return shutil.which(ARM_CC) is not None and shutil.which(ARM_SIZE) is not None


def _run(cmd: list[str], cwd: Path) -> str:
    proc = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=300, check=False)
    if proc.returncode != 0:
        raise CrossBuildError(f"{' '.join(cmd)} failed:\n{proc.stderr}")
    return proc.stdout


_NODE = re.compile(r'node: \{ title: "([^"]+)" label: "([^"]*)"')
_EDGE = re.compile(r'edge: \{ sourcename: "([^"]+)" targetname: "([^"]+)"')
_BYTES = re.compile(r"\\n(\d+) bytes \((static|dynamic|bounded)")


def _worst_stack(ci_files: list[Path]) -> dict[str, int]:
    own: dict[str, int] = {}
    edges: dict[str, set[str]] = {}
    for ci in ci_files:
        text = ci.read_text()
        for title, label in _NODE.findall(text):
            m = _BYTES.search(label)
            if m:
                own[title] = int(m.group(1))
        for src, dst in _EDGE.findall(text):
            edges.setdefault(src, set()).add(dst)
    memo: dict[str, int] = {}

    def depth(name: str, seen: frozenset[str]) -> int:
        if name in memo:
            return memo[name]
        if name in seen:
            raise CrossBuildError(f"recursion through {name}: stack use unbounded")
        below = [depth(c, seen | {name}) for c in edges.get(name, ())]
        memo[name] = own.get(name, 0) + max(below, default=0)
        return memo[name]

    return {name: depth(name, frozenset()) for name in own}


def build_arm(variant: str, out_dir: Path, lib_dir: Path = LIB_DIR) -> ArmReport:
    """Cross-compile one variant ("double" or "float") into ``out_dir`` and measure it."""
    if not have_arm_toolchain():
        raise CrossBuildError(f"{ARM_CC} not found (Debian: apt-get install gcc-arm-none-eabi "
                              "libnewlib-arm-none-eabi)")
    if variant not in ("double", "float"):
        raise ValueError(f"variant must be 'double' or 'float', got {variant!r}")
    out_dir.mkdir(parents=True, exist_ok=True)
    gen = "ecca_gen_d.c" if variant == "double" else "ecca_gen_f.c"
    other = "ECCA_SETPOINT_NO_FLOAT" if variant == "double" else "ECCA_SETPOINT_NO_DOUBLE"
    objs = []
    for src, defs in (("ecca_setpoint.c", [f"-D{other}"]), (gen, [])):
        obj = out_dir / (Path(src).stem + ".o")
        _run([ARM_CC, *ARM_FLAGS, "-fcallgraph-info=su", *defs, f"-I{lib_dir}", "-c",
              str(lib_dir / src), "-o", str(obj)], out_dir)
        objs.append(obj)
    # Link check: a minimal bare-metal program using every public function of the variant.
    sfx = "" if variant == "double" else "_f"
    real = variant
    main = out_dir / "main.c"
    main.write_text(
        '#include "ecca_setpoint.h"\n'
        f"volatile {real} g_t;\n"
        "int main(void) {\n"
        f"  ecca_bezier_segment{sfx} seg = {{{{{{0}}}}, {{0}}, 1}};\n"
        f"  ecca_multirotor_params{sfx} p = {{1, {{{{0.01, 0, 0}}, {{0, 0.01, 0}}, "
        "{0, 0, 0.02}}, 9.80665f, 0.5f, 0};\n"
        f"  ecca_flat_state{sfx} s; ecca_attitude_setpoint{sfx} a; ecca_heading_setpoint{sfx} h;\n"
        f"  ecca_steering_setpoint{sfx} k;\n"
        f"  int rc = ecca_full_setpoint{sfx}(&seg, g_t, &p, &s, &a);\n"
        f"  rc += ecca_full_rover_setpoint{sfx}(&seg, g_t, &s, &h);\n"
        f"  rc += ecca_bezier_eval{sfx}(&seg, g_t, &s) + ecca_rover_setpoint{sfx}(&s, &h);\n"
        f"  rc += ecca_multirotor_setpoint{sfx}(&s, &p, &a);\n"
        f"  rc += ecca_full_ackermann_setpoint{sfx}(&seg, g_t, 0.5f, &s, &k);\n"
        f"  rc += ecca_ackermann_setpoint{sfx}(&s, 0.5f, &k);\n"
        "  return rc;\n}\n")
    flags_link = [f for f in ARM_FLAGS if f not in ("-fstack-usage", "-pedantic")]
    _run([ARM_CC, *flags_link, f"-I{lib_dir}", str(main), *map(str, objs), "-lm",
          "--specs=nosys.specs", "-Wl,--gc-sections", "-o", str(out_dir / "fw.elf")], out_dir)
    size_out = _run([ARM_SIZE, *map(str, objs)], out_dir)
    text = data = bss = 0
    for line in size_out.splitlines()[1:]:
        parts = line.split()
        text, data, bss = text + int(parts[0]), data + int(parts[1]), bss + int(parts[2])
    stacks = _worst_stack(sorted(out_dir.glob("*.ci")))
    worst = {name + sfx: stacks[name + sfx] for name in PUBLIC}
    version = _run([ARM_CC, "--version"], out_dir).splitlines()[0]
    return ArmReport(variant=variant, text=text, data=data, bss=bss, worst_stack=worst,
                     compiler=version)
