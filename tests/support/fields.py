"""Field-by-field equality of two frozen dataclass values (the fast-path tests' comparison):
same type, numpy fields float64 of the same shape and bit-equal, other fields equal."""

from __future__ import annotations

import numpy as np


def fields_equal(a: object, b: object) -> None:
    """Assert `a` and `b` are the same dataclass type with equal fields (arrays: float64, same
    shape, bit-equal)."""
    assert type(a) is type(b)
    for name in a.__dataclass_fields__:  # type: ignore[attr-defined]
        x, y = getattr(a, name), getattr(b, name)
        if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
            assert isinstance(x, np.ndarray) and isinstance(y, np.ndarray), name
            assert x.dtype == y.dtype == np.float64 and x.shape == y.shape, name
            assert np.array_equal(x, y), name
        else:
            assert x == y, name
