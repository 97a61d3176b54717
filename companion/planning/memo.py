"""A memo of planned chunks for callers that schedule many near-identical flight plans, keyed by
the exact bits of the planner's input (:class:`PlanMemo`, :func:`exact_key`)."""

from __future__ import annotations

import collections
import dataclasses
from collections.abc import Callable

import numpy as np

from companion.trajectory import PiecewiseBezier

__all__ = ["PlanMemo", "exact_key"]


class PlanMemo:
    """Bounded memo of planned chunks for callers that schedule many near-identical flight
    plans (the fuzz campaign: a mutation that leaves a stop-to-stop piece as it was).

    The key is the chunk planner's exact complete input (every float by its bits, so 0.0 and
    -0.0 differ and NaN matches only NaN; arrays by dtype, shape and bytes); the planner is
    deterministic, so a served trajectory is the one planning would give (read-only arrays,
    shared). Only successful plans are kept; the least recently used entry goes beyond
    `max_entries`. ``planned`` / ``served`` count the chunks planned and served."""

    def __init__(self, max_entries: int = 4096) -> None:
        if max_entries < 1:
            raise ValueError(f"max_entries must be >= 1, got {max_entries}")
        self.max_entries = max_entries
        self.planned = 0
        self.served = 0
        self._entries: collections.OrderedDict[object, PiecewiseBezier] = (
            collections.OrderedDict()
        )

    def __len__(self) -> int:
        return len(self._entries)

    def get_or_plan(self, key: object, plan_fn: Callable[[], PiecewiseBezier]) -> PiecewiseBezier:
        """The trajectory stored under `key` (see :func:`exact_key`), else ``plan_fn()``
        stored."""
        hit = self._entries.get(key)
        if hit is not None:
            self._entries.move_to_end(key)
            self.served += 1
            return hit
        traj = plan_fn()
        self.planned += 1
        self._entries[key] = traj
        if len(self._entries) > self.max_entries:
            self._entries.popitem(last=False)
        return traj


def exact_key(value: object) -> object:
    """A hashable key equal for two values only when they are the same bit for bit: floats by
    their hex form (0.0 and -0.0 differ, NaN equals NaN), arrays by dtype, shape and bytes,
    dataclasses by type and fields, sequences element-wise; str, int, bool and None as they
    are. TypeError for anything else."""
    if isinstance(value, float):
        return ("f", value.hex())
    if value is None or isinstance(value, (str, int, bool)):
        return value
    if isinstance(value, np.ndarray):
        return ("a", value.dtype.str, value.shape, value.tobytes())
    if isinstance(value, np.floating):
        return ("f", float(value).hex())
    if isinstance(value, (tuple, list)):
        return (type(value).__name__, *(exact_key(v) for v in value))
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return (type(value).__qualname__,
                *(exact_key(getattr(value, f.name)) for f in dataclasses.fields(value)))
    raise TypeError(f"no exact key for {type(value).__name__}")

