"""gen_c generator: the checked-in library matches the generator, output is deterministic,
the CasADi pin is enforced, and the golden vectors still match the Python path."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from gen_c import generate
from tests.support.gen_c import LIB, ROOT, TESTS, assert_close


@pytest.fixture(scope="module")
def fresh(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("gen_c_fresh")
    generate.write_library(out, copy_hand_written=True)
    return out


def test_check_command_passes_on_checked_in_library() -> None:
    proc = subprocess.run([sys.executable, "-m", "gen_c", "--check"], cwd=ROOT,
                          capture_output=True, text=True, timeout=120, check=False)
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr
    assert "up to date" in proc.stdout


def test_check_reports_a_unified_diff_for_an_edited_copy(fresh: Path, tmp_path: Path) -> None:
    lib = tmp_path / "lib"
    shutil.copytree(fresh, lib)
    assert generate.check_library(lib) == ""
    path = lib / "ecca_gen_d.c"
    text = path.read_text()
    path.write_text(text.replace("return 0;", "return 1;", 1))
    (lib / "ecca_gen_f.h").unlink()
    diff = generate.check_library(lib)
    assert "--- " in diff and "+++ " in diff and "@@" in diff
    assert "ecca_gen_d.c" in diff and "missing generated file" in diff
    proc = subprocess.run([sys.executable, "-m", "gen_c", "--check", "--out", str(lib)],
                          cwd=ROOT, capture_output=True, text=True, timeout=120, check=False)
    assert proc.returncode == 1 and "out of date" in proc.stderr


def test_generation_is_deterministic_and_complete(fresh: Path, tmp_path: Path) -> None:
    second = generate.write_library(tmp_path, copy_hand_written=False)
    assert {p.name for p in second} == {"ecca_gen_d.c", "ecca_gen_d.h", "ecca_gen_f.c",
                                        "ecca_gen_f.h", "ecca_setpoint_gen.h"}
    for p in second:
        assert p.read_bytes() == (fresh / p.name).read_bytes(), p.name
    for name in generate.HAND_WRITTEN:  # --out gives a complete, buildable library
        assert (fresh / name).read_bytes() == (LIB / name).read_bytes()


def test_generated_files_carry_the_banner_and_the_pinned_version() -> None:
    for name in ("ecca_gen_d.c", "ecca_gen_d.h", "ecca_gen_f.c", "ecca_gen_f.h",
                 "ecca_setpoint_gen.h"):
        head = (LIB / name).read_text()[:600]
        assert "GENERATED FILE, DO NOT EDIT" in head and "python -m gen_c" in head, name
    assert '"3.8.2"' in (LIB / "ecca_setpoint_gen.h").read_text()
    assert generate.CASADI_VERSION == "3.8.2"
    pyproject = (ROOT / "pyproject.toml").read_text()
    assert f'"casadi=={generate.CASADI_VERSION}"' in pyproject


def test_float_variant_has_no_double_math() -> None:
    code = (LIB / "ecca_gen_f.c").read_text()
    body = code[code.index("#include <math.h>"):]
    assert "double" not in body
    double_calls = re.findall(r"(?<![\w.])(sqrt|sin|cos|atan2|fabs|fmin|fmax|pow)\(", body)
    assert double_calls == []
    assert re.search(r"(?<![\w.])sqrtf\(", body) and re.search(r"(?<![\w.])atan2f\(", body)
    # every floating literal is a float literal
    assert re.findall(r"(?<![\w.])\d+\.\d*(?:e[+-]\d+)?(?![\w.])", body.split("*/", 1)[-1]) == []


def test_wrong_casadi_version_is_refused(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(generate.ca, "__version__", "3.6.0")
    with pytest.raises(generate.GeneratorError, match=r"3\.8\.2.*3\.6\.0"):
        generate.generate_sources()


def test_changed_flatness_api_fails_loudly() -> None:
    import casadi as ca

    x = ca.SX.sym("vel_ned", 3)
    bogus = ca.Function("multirotor_setpoint", [x], [x], ["vel_ned"], ["thrust"])
    with pytest.raises(generate.GeneratorError, match="changed its inputs"):
        generate.multirotor_function("ecca_d_multirotor", bogus)
    # a rover function without the wheel base (the pre-Ackermann API) is refused as well
    v, a, j = (ca.SX.sym(n, 2) for n in ("vel_xy", "acc_xy", "jerk_xy"))
    old_rover = ca.Function("rover_setpoint", [v, a, j], [v[0]], ["vel_xy", "acc_xy", "jerk_xy"],
                            ["yaw"])
    with pytest.raises(generate.GeneratorError, match="changed its inputs"):
        generate.ackermann_function("ecca_d_ackermann", old_rover)


def test_golden_vectors_match_the_current_python_path() -> None:
    """vectors.json is checked in; regenerating from today's Python path agrees with it (a stale
    file after a flatness change fails here, not only in the C test)."""
    stored = json.loads((TESTS / "vectors.json").read_text())
    fresh_vectors = generate.make_vectors()
    assert stored["casadi_version"] == generate.CASADI_VERSION
    for kind in ("bezier", "multirotor", "rover", "full", "ackermann", "full_ackermann"):
        assert len(stored[kind]) == len(fresh_vectors[kind]) > 0
        for a, b in zip(stored[kind], fresh_vectors[kind], strict=True):
            for group in ("expect", "expect_state"):
                for key, val in a.get(group, {}).items():
                    if key in ("flags", "singular"):
                        assert val == b[group][key], (kind, key)
                    else:
                        assert_close(val, b[group][key], 1e-12, f"{kind} {group}.{key}")
