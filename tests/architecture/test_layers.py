"""The import graph follows the layers of DESIGN.md and docs/architecture.md: no circles, no
import from a lower layer up to a higher one, a root with at most four modules, no source file
over 800 lines, sitl_mock independent of companion, bench and tests independent of each other.

Imports are read from the source (every `import` and `from ... import`, also inside functions:
a lazy import is still a dependency)."""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

#: companion's packages by layer, lowest first; a module may import its own layer or lower
LAYERS: list[set[str]] = [
    {"geometry", "_frozen"},
    {"flatness", "mavlink"},
    {"trajectory", "control", "onboard"},
    {"mission"},
    {"planning"},
    {"flight"},
    {"aio", "replay"},
    {"serve", "campaign"},
    {"app"},
]
RANK = {name: i for i, layer in enumerate(LAYERS) for name in layer}


def _modules(top: str) -> Iterator[tuple[str, Path]]:
    for path in sorted((ROOT / top).rglob("*.py")):
        rel = path.relative_to(ROOT).with_suffix("")
        parts = list(rel.parts)
        if parts[-1] == "__init__":
            parts.pop()
        yield ".".join(parts), path


def _is_module(name: str) -> bool:
    base = ROOT.joinpath(*name.split("."))
    return base.with_suffix(".py").exists() or (base / "__init__.py").exists()


def _imports(path: Path, module: str) -> set[str]:
    """Absolute names of the modules `path` imports (relative imports resolved)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                pkg = package.split(".")
                base = ".".join(pkg[: len(pkg) - node.level + 1] + ([base] if base else []))
            subs = [f"{base}.{a.name}" for a in node.names]
            # `from pkg import mod` of submodules only depends on them (pkg's __init__ is
            # already running when a module inside pkg does it); any other name is pkg's own
            if not all(_is_module(s) for s in subs):
                found.add(base)
            found.update(subs)
    return found


def _graph(top: str) -> dict[str, set[str]]:
    mods = dict(_modules(top))
    return {m: {i for i in _imports(p, m) if i in mods and i != m} for m, p in mods.items()}


def _package(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import circle of `graph` (module-level edges, package __init__ edges included)."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(m: str) -> list[str] | None:
        state[m] = 1
        stack.append(m)
        for n in sorted(graph[m]):
            if state.get(n) == 1:
                return [*stack[stack.index(n):], n]
            if n not in state:
                c = visit(n)
                if c:
                    return c
        stack.pop()
        state[m] = 2
        return None

    for m in sorted(graph):
        if m not in state:
            c = visit(m)
            if c:
                return c
    return None


def _layer_violations(graph: dict[str, set[str]]) -> list[str]:
    bad = []
    for m, deps in sorted(graph.items()):
        pm = _package(m)
        if pm not in RANK:
            continue
        for d in sorted(deps):
            pd = _package(d)
            if pd in RANK and RANK[pd] > RANK[pm]:
                bad.append(f"{m} ({pm}, layer {RANK[pm]}) imports {d} ({pd}, layer {RANK[pd]})")
    return bad


def test_every_companion_package_has_a_layer() -> None:
    names = {p.name if p.is_dir() else p.stem for p in (ROOT / "companion").iterdir()
             if (p.is_dir() and (p / "__init__.py").exists()) or p.suffix == ".py"}
    names -= {"__init__", "__main__"}
    assert names == set(RANK), (sorted(names - set(RANK)), sorted(set(RANK) - names))


def test_companion_root_holds_at_most_four_modules() -> None:
    loose = sorted(p.name for p in (ROOT / "companion").glob("*.py")
                   if p.name not in {"__init__.py", "__main__.py"})
    assert len(loose) <= 4, loose


@pytest.mark.parametrize("top", ["companion", "sitl_mock", "gen_c"])
def test_no_import_circles(top: str) -> None:
    assert _cycle(_graph(top)) is None, " -> ".join(_cycle(_graph(top)) or [])


def test_no_import_from_a_lower_layer_up() -> None:
    assert _layer_violations(_graph("companion")) == []


def test_the_checks_catch_a_circle_and_an_upward_import() -> None:
    g = {"companion.flatness.a": {"companion.app.cli"},
         "companion.app.cli": {"companion.flatness.a"}}
    assert _cycle(g) == ["companion.app.cli", "companion.flatness.a", "companion.app.cli"]
    assert _layer_violations(g) == [
        "companion.flatness.a (flatness, layer 1) imports companion.app.cli (app, layer 8)"]


@pytest.mark.parametrize(("top", "forbidden"), [
    ("sitl_mock", "companion"), ("bench", "tests"), ("tests", "bench"),
    ("companion", "tests"), ("companion", "bench"), ("px4_harness", "companion"),
])
def test_independent_trees(top: str, forbidden: str) -> None:
    bad = sorted(f"{m} imports {i}" for m, p in _modules(top) for i in _imports(p, m)
                 if i == forbidden or i.startswith(forbidden + "."))
    # bench's modules import each other by bare name (run from bench/); those are not `tests`
    assert bad == []


#: the packages that run the mock (replay's lockstep flights, `fly --mock`); nothing below them
MOCK_USERS = {"replay", "campaign", "app"}


def test_only_the_replay_layers_import_the_mock() -> None:
    bad = sorted(f"{m} imports {i}" for m, p in _modules("companion") for i in _imports(p, m)
                 if i.split(".")[0] == "sitl_mock" and _package(m) not in MOCK_USERS)
    assert bad == []


#: the trees the 800-line rule covers (examples holds no Python today: covered once it does)
SOURCE_TREES = ("companion", "sitl_mock", "gen_c", "bench", "tests", "examples", "px4_harness")


def test_no_source_file_over_800_lines() -> None:
    long = sorted(f"{p.relative_to(ROOT)}: {n}" for top in SOURCE_TREES
                  for p in (ROOT / top).rglob("*.py")
                  if (n := len(p.read_text().splitlines())) > 800)
    assert long == []
