"""Layering rules of DESIGN.md, checked on the source text (AST), not by importing."""

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


def test_sitl_mock_is_independent_of_companion() -> None:
    assert (ROOT / "sitl_mock").is_dir()
    assert _offenders("sitl_mock", ("companion", "gen_c")) == []


def test_gen_c_native_imports_nothing_from_companion() -> None:
    native = ROOT / "gen_c" / "native.py"
    if native.exists():
        mods = _imported_modules(native)
        assert not [m for m in mods if m == "companion" or m.startswith("companion.")]


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
