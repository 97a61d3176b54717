"""gen_c: the library compiles with the strict flags (and PX4's warning set, and as C++ from a
PX4-style module), is freestanding (only <math.h> symbols, no mutable globals), builds through
CMake add_subdirectory, and the C test program passes on the golden vectors without Python."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import pytest

from tests.support.gen_c import (
    GEN_SOURCES,
    LIB,
    PX4_EXTRA,
    STRICT,
    TESTS,
    cc,
    run,
)

# Symbols a freestanding build may need from outside: <math.h> (double and float forms).
_MATH = {"sqrt", "sin", "cos", "tan", "atan2", "asin", "acos", "atan", "fabs", "fmin", "fmax",
         "floor", "ceil", "pow", "exp", "log", "hypot", "copysign", "fmod"}
# GCC merges sin(x) and cos(x) into sincos(x) at -O2 (glibc and newlib provide it).
_MATH |= {"sincos"}
ALLOWED_UNDEFINED = _MATH | {f + "f" for f in _MATH}


@pytest.fixture(scope="module")
def objects(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("gen_c_obj")
    objs = {}
    for src in GEN_SOURCES:
        obj = out / (Path(src).stem + ".o")
        # The required flags plus PX4's extra warnings (a superset: passing it passes both).
        run([cc(), *STRICT, *PX4_EXTRA, "-O2", "-I", str(LIB), "-c", str(LIB / src), "-o",
             str(obj)])
        objs[src] = obj
    return objs


def test_strict_and_px4_warning_flags_compile_every_source(objects: dict[str, Path]) -> None:
    assert set(objects) == set(GEN_SOURCES)
    assert all(p.stat().st_size > 0 for p in objects.values())


def test_header_is_usable_from_cpp(tmp_path: Path) -> None:
    cxx = shutil.which("c++") or shutil.which("g++")
    assert cxx is not None, "a C++ compiler is needed (PX4 modules are C++)"
    src = tmp_path / "module.cpp"
    src.write_text(
        '#include "ecca_setpoint.h"\n'
        "int step(const ecca_bezier_segment_f &seg, float t, const ecca_multirotor_params_f &p,\n"
        "         ecca_attitude_setpoint_f &out) {\n"
        "  return ecca_full_setpoint_f(&seg, t, &p, nullptr, &out);\n}\n")
    run([cxx, "-std=c++14", "-Wall", "-Wextra", "-Werror", "-pedantic", "-I", str(LIB), "-c",
         str(src), "-o", str(tmp_path / "module.o")])


def _nm(obj: Path) -> list[tuple[str, str]]:
    nm = shutil.which("nm")
    assert nm is not None
    out = run([nm, str(obj)]).stdout
    syms = []
    for line in out.splitlines():
        parts = line.split()
        if len(parts) >= 2:
            syms.append((parts[-2], parts[-1]))
    return syms


def test_freestanding_only_math_symbols_and_no_mutable_globals(objects: dict[str, Path],
                                                               tmp_path: Path) -> None:
    combined = tmp_path / "ecca_setpoint_all.o"  # partial link: what the library needs outside
    run([cc(), "-r", "-nostdlib", *(str(o) for o in objects.values()), "-o", str(combined)])
    undefined = {name for kind, name in _nm(combined) if kind == "U"}
    assert undefined <= ALLOWED_UNDEFINED, f"the library needs {undefined - ALLOWED_UNDEFINED}"
    assert "sqrt" in undefined and "sqrtf" in undefined
    for src, obj in objects.items():
        syms = _nm(obj)
        # D/d: initialised data, B/b: bss, C: common -> mutable state; R/r (const) is fine.
        mutable = [(k, n) for k, n in syms if k in ("D", "d", "B", "b", "C")]
        assert mutable == [], f"{src} has mutable globals {mutable}"
    assert any(k == "T" and n == "ecca_full_setpoint_f" for k, n in _nm(objects["ecca_setpoint.c"]))


def test_no_allocation_or_io_in_sources() -> None:
    for path in [*sorted(LIB.glob("*.[ch]")), LIB / "ecca_setpoint_impl.inc"]:
        code = path.read_text()
        includes = set(re.findall(r'#include\s*[<"]([^>"]+)[>"]', code))
        assert includes <= {"math.h", "ecca_setpoint.h", "ecca_setpoint_gen.h", "ecca_gen_d.h",
                            "ecca_gen_f.h", "ecca_setpoint_impl.inc"}, (path.name, includes)
        # static: only functions (return types below) and const data, no mutable state.
        assert re.search(r"\b(malloc|calloc|free|printf|static\s+(?!const|int|float|double|void"
                         r"|ECCA_REAL\s+ECCA_API\())",
                         code) is None or path.name.startswith("ecca_gen_"), path.name


@pytest.fixture(scope="module")
def c_test_program(tmp_path_factory: pytest.TempPathFactory) -> Path:
    exe = tmp_path_factory.mktemp("gen_c_ctest") / "test_ecca_setpoint"
    run([cc(), *STRICT, "-O2", "-I", str(LIB), str(TESTS / "test_ecca_setpoint.c"),
         *(str(LIB / s) for s in GEN_SOURCES), "-lm", "-o", str(exe)])
    return exe


def test_c_program_passes_on_golden_vectors(c_test_program: Path) -> None:
    out = run([str(c_test_program), str(TESTS / "vectors.json")]).stdout
    m = re.search(r"PASS: (\d+) cases, (\d+) checks, 0 failures", out)
    assert m is not None, out
    assert int(m.group(1)) >= 60 and int(m.group(2)) >= 2000


def test_c_program_detects_a_wrong_vector(c_test_program: Path, tmp_path: Path) -> None:
    """The C checker is not vacuous: a 1e-9 relative change in one expected thrust fails it."""
    text = (TESTS / "vectors.json").read_text()
    m = re.search(r'"thrust_n":(-?[0-9.e+-]+)', text)
    assert m is not None
    bad = float(m.group(1)) * (1 + 1e-9) + 1e-9
    (tmp_path / "v.json").write_text(text[: m.start(1)] + repr(bad) + text[m.end(1):])
    import subprocess

    proc = subprocess.run([str(c_test_program), str(tmp_path / "v.json")], capture_output=True,
                          text=True, timeout=60, check=False)
    assert proc.returncode == 1
    assert "FAIL multirotor[0]" in proc.stdout and "double thrust_n" in proc.stdout
    assert "float thrust_n" not in proc.stdout  # 1e-9 is inside the float tolerance


def test_cmake_add_subdirectory_builds_and_links(tmp_path: Path) -> None:
    cmake = shutil.which("cmake")
    assert cmake is not None, "cmake is required for the add_subdirectory check"
    proj = tmp_path / "proj"
    proj.mkdir()
    (proj / "CMakeLists.txt").write_text(
        "cmake_minimum_required(VERSION 3.13)\nproject(consumer C)\n"
        f'add_subdirectory("{LIB}" ecca_setpoint)\n'
        f'add_executable(t "{TESTS / "test_ecca_setpoint.c"}")\n'
        "target_link_libraries(t PRIVATE ecca_setpoint)\n")
    build = tmp_path / "build"
    run([cmake, "-S", str(proj), "-B", str(build)])
    run([cmake, "--build", str(build)])
    assert list(build.rglob("libecca_setpoint.a"))
    out = run([str(build / "t"), str(TESTS / "vectors.json")]).stdout
    assert "PASS:" in out


def test_cmake_single_variant_option(tmp_path: Path) -> None:
    """-DECCA_SETPOINT_DOUBLE=OFF builds a float-only library (no double code at all)."""
    cmake = shutil.which("cmake")
    assert cmake is not None
    build = tmp_path / "build"
    run([cmake, "-S", str(LIB), "-B", str(build), "-DECCA_SETPOINT_DOUBLE=OFF"])
    run([cmake, "--build", str(build)])
    archives = list(build.rglob("libecca_setpoint.a"))
    assert len(archives) == 1
    names = {n for k, n in _nm(archives[0]) if k == "T"}
    assert "ecca_full_setpoint_f" in names and "ecca_f_multirotor" in names
    assert not any(n.startswith("ecca_d_") for n in names)
    assert "ecca_full_setpoint" not in names
