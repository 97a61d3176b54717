"""One fast constructor for frozen dataclasses on per-cycle paths."""

from __future__ import annotations

from typing import Any, TypeVar

T = TypeVar("T")


def frozen_new(cls: type[T], **fields: Any) -> T:
    """Instance of the (frozen, non-slots) dataclass ``cls`` with ``fields`` set as given,
    without running ``__init__`` / ``__post_init__``: for values the caller already has in the
    final form (the constructor would only assign or convert them). The caller passes every
    field; nothing is checked."""
    obj: T = object.__new__(cls)
    obj.__dict__.update(fields)
    return obj
