"""The generated setpoint library compiled once for the gen_c tests that only call it (a
compile takes ~2 s; test_gen_c_native builds its own, to test the cache)."""

from __future__ import annotations

import pytest

from gen_c import native


@pytest.fixture(scope="session")
def lib(tmp_path_factory: pytest.TempPathFactory) -> native.NativeSetpoint:
    return native.NativeSetpoint(native.build_library(cache=tmp_path_factory.mktemp("lib")))
