"""Argument types for output paths: a folder or file the command will create, checked while the
options are parsed (bad input, exit 2) instead of failing with a bare OS error mid-command."""

from __future__ import annotations

import argparse
from pathlib import Path


def _blocked_parent(path: Path) -> Path | None:
    """The nearest existing ancestor of ``path`` that is not a folder, or None."""
    for parent in path.parents:
        if parent.exists():
            return None if parent.is_dir() else parent
    return None


def output_folder(text: str) -> str:
    """An output folder: absent (it will be created) or an existing folder."""
    path = Path(text)
    if path.exists() and not path.is_dir():
        raise argparse.ArgumentTypeError(f"{text}: exists and is a file, not a folder")
    blocked = _blocked_parent(path)
    if blocked is not None:
        raise argparse.ArgumentTypeError(
            f"{text}: cannot create the folder, {blocked} is a file, not a folder")
    return text


def output_file(text: str) -> str:
    """An output file: absent or an existing file (appended to or replaced by the command),
    not a folder."""
    path = Path(text)
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{text}: exists and is a folder, not a file")
    blocked = _blocked_parent(path)
    if blocked is not None:
        raise argparse.ArgumentTypeError(f"{text}: {blocked} is a file, not a folder")
    return text
