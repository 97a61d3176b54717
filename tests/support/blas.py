"""Which rounding this host's BLAS gives numpy's small products.

numpy hands 3x3 products and dots of 3 to OpenBLAS, whose kernel is chosen per CPU at load time
unless `OPENBLAS_CORETYPE` names one. Both its Haswell (AVX2) and SkylakeX (AVX-512) kernels
round a 3x3 product's entry and a matrix-vector product's as a chain of fused multiply-adds;
a 1-D dot of 3 (and so a norm of 3) the SkylakeX kernels round as the chain too, the Haswell
ones as plain (a0 b0 + a1 b1) + a2 b2. One ulp in a dot is enough for a closed-loop replay to
drift: the same commit replayed five_minute.plan with a plan of 329.9 s under the SkylakeX
kernels and 319.4 s under the Haswell ones (the planner's time allocation ends in another
local optimum). The stored report figures were recorded with the Haswell kernels, which run
on any x86-64 CPU with AVX2; `tests/conftest.py` picks them unless the caller chose."""

from __future__ import annotations

import math
from collections.abc import Callable
from fractions import Fraction

import numpy as np


def fma_exact(a: float, b: float, c: float) -> float:
    """a * b + c rounded once (exact rational arithmetic)."""
    if a * b == 0.0:
        return a * b + c  # exact zero product: IEEE's sign of zero
    return float(Fraction(a) * Fraction(b) + Fraction(c))


def _dot_chain(a: np.ndarray, b: np.ndarray) -> float:
    return fma_exact(a[2], b[2], fma_exact(a[1], b[1], fma_exact(a[0], b[0], 0.0)))


def _dot_plain(a: np.ndarray, b: np.ndarray) -> float:
    return float((a[0] * b[0] + a[1] * b[1]) + a[2] * b[2])


def _rounds_as(dot: Callable[[np.ndarray, np.ndarray], float]) -> bool:
    """numpy's 3x3 products and matrix-vector products round as the FMA chain (fma(a2, b2,
    fma(a1, b1, a0 b0)); fma(a2, v2, fma(a0, v0, a1 v1))) and its 1-D dots and norms of 3 as
    `dot`."""
    rng = np.random.default_rng(0)
    for _ in range(200):
        A, B, v, w = (rng.normal(size=(3, 3)), rng.normal(size=(3, 3)), rng.normal(size=3),
                      rng.normal(size=3))
        chain = [[fma_exact(A[i, 2], B[2, j], fma_exact(A[i, 1], B[1, j], A[i, 0] * B[0, j]))
                  for j in range(3)] for i in range(3)]
        mv = [fma_exact(A[i, 2], v[2], fma_exact(A[i, 0], v[0], A[i, 1] * v[1]))
              for i in range(3)]
        if ((A @ B).tolist() != chain or (A @ v).tolist() != mv
                or float(v @ w) != dot(v, w)
                or float(np.linalg.norm(v)) != float(np.sqrt(dot(v, v)))):
            return False
    return True


def numpy_rounds_as_fma_chain() -> bool:
    """numpy's small products and dots all round as the FMA chain (OpenBLAS's SkylakeX
    kernels): the companion's float fast paths then reproduce numpy bit for bit."""
    return _rounds_as(_dot_chain)


def numpy_elementary_functions_are_libms() -> bool:
    """numpy's float64 exp, log, sin and cos give the C library's values (its AVX2 builds call
    it; its AVX-512 builds have their own, which round otherwise: tests/support/cpu_env.py)."""
    rng = np.random.default_rng(1)
    x = rng.normal(scale=4.0, size=2000)
    pos = np.abs(x) + 1e-3
    return (np.exp(x).tolist() == [math.exp(v) for v in x.tolist()]
            and np.log(pos).tolist() == [math.log(v) for v in pos.tolist()]
            and np.sin(x).tolist() == [math.sin(v) for v in x.tolist()]
            and np.cos(x).tolist() == [math.cos(v) for v in x.tolist()])


def numpy_rounds_as_recorded() -> bool:
    """numpy rounds as when the stored report figures were recorded: its small products as
    OpenBLAS's Haswell kernels (1-D dots of 3 without FMA), its elementary functions as the C
    library."""
    return _rounds_as(_dot_plain) and numpy_elementary_functions_are_libms()
