"""Shared by the bench scripts: replace (or append) one `## Title` section of BENCHMARKS.md."""

from __future__ import annotations

import re
from pathlib import Path

BENCHMARKS_MD = Path(__file__).resolve().parents[1] / "BENCHMARKS.md"


def write_section(title: str, text: str, path: Path = BENCHMARKS_MD) -> None:
    """Put `text` (starting with `## {title}`) in place of that section, or append it."""
    old = path.read_text(encoding="utf-8") if path.exists() else "# Benchmarks\n"
    pat = re.compile(rf"^## {re.escape(title)}\n.*?(?=^## |\Z)", re.S | re.M)
    body = text.rstrip("\n") + "\n"
    if pat.search(old):
        new = pat.sub(lambda _: body + "\n", old, count=1)
    else:
        new = old.rstrip("\n") + "\n\n" + body
    path.write_text(new.rstrip("\n") + "\n", encoding="utf-8")


def write_subsection(title: str, sub: str, text: str, path: Path = BENCHMARKS_MD) -> None:
    """Put `text` (starting with `### {sub}`) in place of that subsection of section `title`,
    or at the section's end; the rest of the section stays (ValueError without the section)."""
    old = path.read_text(encoding="utf-8") if path.exists() else ""
    sec = re.compile(rf"^## {re.escape(title)}\n.*?(?=^## |\Z)", re.S | re.M).search(old)
    if sec is None:
        raise ValueError(f"no section '## {title}' in {path}")
    body = text.rstrip("\n") + "\n"
    section = sec.group(0)
    pat = re.compile(rf"^### {re.escape(sub)}\n.*?(?=^### |^## |\Z)", re.S | re.M)
    if pat.search(section):
        new_section = pat.sub(lambda _: body + "\n", section, count=1)
    else:
        new_section = section.rstrip("\n") + "\n\n" + body + "\n"
    path.write_text((old[: sec.start()] + new_section + old[sec.end():]).rstrip("\n") + "\n",
                    encoding="utf-8")
