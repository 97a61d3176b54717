"""The numeric set-up the stored report figures were recorded with, pinned before numpy loads.

- OpenBLAS's Haswell kernels (`OPENBLAS_CORETYPE`) on an x86-64 CPU with AVX2: OpenBLAS would
  pick its SkylakeX kernels on a CPU with AVX-512, whose dots of 3 round otherwise
  (tests/support/blas.py).
- numpy's own loops without their AVX-512 builds (`NPY_DISABLE_CPU_FEATURES`) on a CPU with
  AVX-512: numpy 2 has AVX-512 versions of float64 exp, log, sin and cos that round otherwise
  than the C library, which its AVX2 builds call. The same commit replayed the figures of an
  AVX-512 host on an AVX2-only one (AMD EPYC, 2026-12-02) with five_minute.plan's time-optimal
  bound 310.852 s instead of 310.882 s and its legs flown up to 0.2 m otherwise.

Either is left alone where the caller set it. Processes the tests start inherit the choice."""

from __future__ import annotations

import os
from pathlib import Path

#: numpy 2's names of its AVX-512 builds (x86-64 microarchitecture level 4 and later)
NUMPY_AVX512 = "X86_V4 AVX512_ICL AVX512_SPR"


def cpu_flags() -> set[str]:
    """The CPU's feature flags (/proc/cpuinfo; empty where there is none)."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return set()
    for line in text.splitlines():
        if line.startswith("flags"):
            return set(line.partition(":")[2].split())
    return set()


def pinned_environment(env: dict[str, str] | os._Environ[str]) -> dict[str, str]:
    """What to add to `env` (the variables above this CPU needs and `env` does not set)."""
    flags = cpu_flags()
    out: dict[str, str] = {}
    if "OPENBLAS_CORETYPE" not in env and {"avx2", "fma"} <= flags:
        out["OPENBLAS_CORETYPE"] = "Haswell"
    if "NPY_DISABLE_CPU_FEATURES" not in env and "avx512f" in flags:
        out["NPY_DISABLE_CPU_FEATURES"] = NUMPY_AVX512
    return out
