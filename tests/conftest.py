"""Test-session set-up, before anything imports numpy: the numeric set-up the stored report
figures were recorded with (tests/support/cpu_env.py: OpenBLAS's Haswell kernels, numpy's loops
without their AVX-512 builds), unless the caller chose. Mock and companion processes the tests
start inherit the choice."""

from __future__ import annotations

import os

from tests.support.cpu_env import pinned_environment

os.environ.update(pinned_environment(os.environ))
