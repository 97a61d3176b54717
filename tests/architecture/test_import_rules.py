"""Layering rules of DESIGN.md, checked on the source text (AST), not by importing.

The rules for ``sitl_mock`` (DESIGN.md's, narrowed for the onboard module of issue 26):
``sitl_mock`` never imports ``companion``; of ``gen_c`` it may import exactly
``gen_c.onboard_native`` (the onboard module's C core through ctypes, `sitl_mock.onboard`) and
what that needs, ``gen_c.native``; both of those import nothing from ``companion``, so the
mock stays an independent implementation that runs the same C as the PX4 module."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _imported_modules(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
    return names


def _offenders(package: str, forbidden: tuple[str, ...]) -> list[str]:
    bad = []
    for path in sorted((ROOT / package).rglob("*.py")):
        for mod in _imported_modules(path):
            if any(mod == f or mod.startswith(f + ".") for f in forbidden):
                bad.append(f"{path.relative_to(ROOT)} imports {mod}")
    return bad


#: What sitl_mock may import of gen_c (the onboard module's C core and its loader).
SITL_MOCK_GEN_C = ("gen_c.onboard_native", "gen_c.native")


def test_sitl_mock_is_independent_of_companion() -> None:
    assert (ROOT / "sitl_mock").is_dir()
    assert _offenders("sitl_mock", ("companion",)) == []


def test_sitl_mock_imports_only_the_onboard_core_of_gen_c() -> None:
    used = set()
    bad = []
    for path in sorted((ROOT / "sitl_mock").rglob("*.py")):
        for mod in _imported_modules(path):
            if mod == "gen_c" or mod.startswith("gen_c."):
                used.add(mod)
                if mod not in SITL_MOCK_GEN_C:
                    bad.append(f"{path.relative_to(ROOT)} imports {mod}")
    assert bad == []
    assert "gen_c.onboard_native" in used  # the rule is exercised (sitl_mock/onboard.py)


def test_gen_c_runtime_loaders_import_nothing_from_companion() -> None:
    """gen_c.native and gen_c.onboard_native (which sitl_mock and companion import) import
    nothing from companion, and of gen_c only each other (not the generator)."""
    for name in SITL_MOCK_GEN_C:
        path = ROOT.joinpath(*name.split(".")).with_suffix(".py")
        assert path.exists(), path
        mods = _imported_modules(path)
        assert not [m for m in mods if m == "companion" or m.startswith("companion.")], name
        assert not [m for m in mods if m.startswith("gen_c.") and m not in SITL_MOCK_GEN_C], name


def test_pure_layers_do_not_import_io_layers() -> None:
    pure = ["companion/geometry.py", "companion/trajectory", "companion/flatness"]
    io_mods = ("companion.aio", "companion.mavlink", "companion.app.cli", "companion.replay.runner",
               "sitl_mock", "asyncio", "socket")
    bad = []
    for rel in pure:
        p = ROOT / rel
        files = [p] if p.is_file() else sorted(p.rglob("*.py"))
        for f in files:
            for mod in _imported_modules(f):
                if any(mod == m or mod.startswith(m + ".") for m in io_mods):
                    bad.append(f"{rel}: {mod}")
    assert bad == []


def test_the_rule_checker_sees_imports() -> None:
    # Guard against a checker that silently finds nothing.
    mods = _imported_modules(Path(__file__))
    assert "ast" in mods and "pathlib" in mods
