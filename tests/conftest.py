"""Test-session set-up, before anything imports numpy: the numeric set-up the stored report
figures were recorded with (tests/support/cpu_env.py: OpenBLAS's Haswell kernels, numpy's loops
without their AVX-512 builds), unless the caller chose. Mock and companion processes the tests
start inherit the choice."""

from __future__ import annotations

import os
from typing import Any

import pytest

from tests.support.cpu_env import pinned_environment
from tests.support.phases import scope_of

os.environ.update(pinned_environment(os.environ))


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config: pytest.Config, log: Any) -> Any:
    """`--dist loadgroup`: the px4 set as one unit of work (tests/support/phases.py). xdist's own
    grouping by `xdist_group` marks renames node ids, which pytest 9.2 no longer lets it do."""
    if config.getvalue("dist") != "loadgroup":
        return None
    from xdist.scheduler import LoadScopeScheduling

    class Px4AsOneUnit(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return scope_of(nodeid)

    return Px4AsOneUnit(config, log)
