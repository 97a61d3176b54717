"""The manual (README.md and the MkDocs site under docs/) builds cleanly and its examples run.

- `mkdocs build --strict` into a temporary folder: a broken link, a missing page or an API
  reference that no longer resolves fails the build (skipped only without mkdocs, i.e. without
  the `docs` extra).
- Every ```python block of README.md and docs/**/*.md is executed, the blocks of one page in
  order in one namespace (a later block may use an earlier one's names), from the repository
  root. A block that cannot run here (it needs a vehicle, a network, a long flight) is preceded
  by `<!-- docs-test: skip REASON -->`, and the reason is required.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PAGES = sorted([ROOT / "README.md", *(ROOT / "docs").rglob("*.md")])
SKIP = re.compile(r"<!--\s*docs-test:\s*skip\b(?P<reason>.*?)-->")
FENCE = re.compile(r"^(?P<indent> *)```(?P<info>[^\n`]*)$")


def python_blocks(text: str) -> list[tuple[int, str, str | None]]:
    """(line number, code, skip reason or None) of every ```python block of a markdown text."""
    lines = text.splitlines()
    out: list[tuple[int, str, str | None]] = []
    i = 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        indent, info = m.group("indent"), m.group("info").strip()
        j = i + 1
        while j < len(lines) and lines[j].strip() != "```":
            j += 1
        if info.split(" ")[0] == "python":
            body = "\n".join(ln[len(indent):] for ln in lines[i + 1 : j])
            prev = next((ln for ln in reversed(lines[:i]) if ln.strip()), "")
            s = SKIP.search(prev)
            out.append((i + 1, body, s.group("reason").strip() if s else None))
        i = j + 1
    return out


def _page_id(p: Path) -> str:
    return str(p.relative_to(ROOT))


def test_pages_exist() -> None:
    assert (ROOT / "mkdocs.yml").is_file()
    assert len(PAGES) > 10


def test_readme_is_a_front_page() -> None:
    assert len((ROOT / "README.md").read_text(encoding="utf-8").splitlines()) <= 200


def _pages_with_examples() -> list[Path]:
    return [p for p in PAGES if python_blocks(p.read_text(encoding="utf-8"))]


@pytest.mark.parametrize("page", _pages_with_examples(), ids=_page_id)
def test_python_examples_run(page: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    blocks = python_blocks(page.read_text(encoding="utf-8"))
    monkeypatch.chdir(ROOT)
    namespace: dict[str, object] = {"__name__": "__docs__"}
    ran = 0
    for line, code, reason in blocks:
        if reason is not None:
            assert reason, f"{_page_id(page)}:{line}: a skipped example must say why"
            continue
        try:
            exec(compile(code, f"{_page_id(page)}:{line}", "exec"), namespace)
        except Exception as exc:  # the page and line of the failing example, then the cause
            raise AssertionError(f"example at {_page_id(page)}:{line} failed: {exc!r}") from exc
        ran += 1
    if not ran:
        pytest.skip("every python example on this page is marked to skip (reasons on the page)")


def test_mkdocs_build_strict(tmp_path: Path) -> None:
    pytest.importorskip("mkdocs", reason="mkdocs is not installed (pip install -e '.[docs]')")
    pytest.importorskip("mkdocstrings", reason="mkdocstrings is not installed (the docs extra)")
    mkdocs = shutil.which("mkdocs", path=str(Path(sys.executable).parent))
    cmd = [mkdocs] if mkdocs else [sys.executable, "-m", "mkdocs"]
    proc = subprocess.run(
        [*cmd, "build", "--strict", "--site-dir", str(tmp_path / "site")],
        cwd=ROOT, capture_output=True, text=True, timeout=300,
        env={**__import__("os").environ, "NO_MKDOCS_2_WARNING": "1"},
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert (tmp_path / "site" / "index.html").is_file()
    assert (tmp_path / "site" / "reference" / "flatness" / "index.html").is_file()
