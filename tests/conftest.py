"""Test-session set-up, before anything imports numpy.

OpenBLAS's Haswell kernels (`OPENBLAS_CORETYPE`) on an x86-64 CPU with AVX2, unless the caller
chose: the stored report figures were recorded with them, and OpenBLAS would pick its SkylakeX
kernels on an Intel CPU with AVX-512, whose dots of 3 round otherwise (tests/support/blas.py).
Mock and companion processes the tests start inherit the choice."""

from __future__ import annotations

import os
from pathlib import Path


def _cpu_flags() -> set[str]:
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return set()
    for line in text.splitlines():
        if line.startswith("flags"):
            return set(line.partition(":")[2].split())
    return set()


if "OPENBLAS_CORETYPE" not in os.environ and {"avx2", "fma"} <= _cpu_flags():
    os.environ["OPENBLAS_CORETYPE"] = "Haswell"
