"""Optional extras of the distribution: which modules each one brings, checked before use.

A core install (``pip install ecca-offboard``) flies, serves, reads status and replays without
a plot. Plots, campaigns and the manual need an extra (``pyproject.toml``). A command that needs
a missing extra calls :func:`require`; ``python -m companion`` turns the
:class:`MissingExtraError` into exit code 2 and a message with the install line.

The check looks the modules up without importing them (``importlib.util.find_spec``), so it
costs nothing even for matplotlib, whose import is left to the plot helper process.
"""

from __future__ import annotations

import importlib.util

DISTRIBUTION = "ecca-offboard"

#: Extra name -> the top-level modules it must make importable (as in pyproject.toml).
EXTRAS: dict[str, tuple[str, ...]] = {
    "plot": ("matplotlib",),
    "campaign": ("distributed", "pyarrow", "matplotlib"),
}


class MissingExtraError(Exception):
    """A command needs an extra that is not installed; the message says how to install it."""

    def __init__(self, extra: str, module: str, what: str) -> None:
        self.extra = extra
        self.module = module
        super().__init__(
            f"{what} needs the [{extra}] extra ({module} is not installed): "
            f"{install_line(extra)}"
        )


def install_line(extra: str) -> str:
    """The pip command that installs `extra`, e.g. ``pip install 'ecca-offboard[plot]'``."""
    return f"pip install '{DISTRIBUTION}[{extra}]'"


def missing_module(extra: str) -> str | None:
    """The first module of `extra` that cannot be imported here, or None if all can."""
    for name in EXTRAS[extra]:
        try:
            spec = importlib.util.find_spec(name)
        except (ImportError, ValueError):  # a broken parent, or a module without a spec
            spec = None
        if spec is None:
            return name
    return None


def available(extra: str) -> bool:
    """True if every module of `extra` can be imported."""
    return missing_module(extra) is None


def require(extra: str, what: str) -> None:
    """Raise :class:`MissingExtraError` (exit 2 from the CLI) naming `extra` if one of its
    modules is missing; `what` names the command or feature in the message ("campaign")."""
    module = missing_module(extra)
    if module is not None:
        raise MissingExtraError(extra, module, what)


__all__ = ["EXTRAS", "MissingExtraError", "available", "install_line", "missing_module", "require"]
