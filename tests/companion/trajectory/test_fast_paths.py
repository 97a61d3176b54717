"""The planner's LAPACK routines loaded straight from SciPy's `_flapack` extension
(`companion.trajectory._lapack`, skipping the ~0.25 s import of scipy.linalg) are SciPy's own:
the same bits as `scipy.linalg.lapack.dpbtrf` / `dpbtrs` on banded systems, and planning does
not import scipy.linalg."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[3]


def _banded_spd(rng: np.random.Generator, n: int, u: int) -> np.ndarray:
    """Upper banded storage (u + 1, n) of a random symmetric positive definite matrix."""
    a = rng.standard_normal((n, n))
    full = a @ a.T + n * np.eye(n)
    band = np.zeros((u + 1, n))
    for k in range(u + 1):  # ab[u - k, j] = A[j - k, j]
        band[u - k, k:] = np.diagonal(full, offset=k)
    return band


@pytest.mark.parametrize("n,u", [(5, 1), (24, 7), (61, 5)])
def test_direct_lapack_equals_scipy_linalg_lapack(n: int, u: int) -> None:
    import scipy.linalg.lapack as public

    from companion.trajectory import _lapack

    direct = _lapack._direct()
    assert direct is not None, "scipy's _flapack extension was not found"
    pbtrf, pbtrs = direct
    rng = np.random.default_rng(n * 100 + u)
    ab = _banded_spd(rng, n, u)
    rhs = rng.standard_normal((n, 3))
    cb, info = pbtrf(ab.copy(), lower=0)
    cb_ref, info_ref = public.dpbtrf(ab.copy(), lower=0)
    assert info == info_ref == 0
    np.testing.assert_array_equal(cb, cb_ref)
    z, info = pbtrs(cb, rhs, lower=0)
    z_ref, _ = public.dpbtrs(cb_ref, rhs, lower=0)
    np.testing.assert_array_equal(z, z_ref)
    # and it solves the system
    full = np.zeros((n, n))
    for k in range(u + 1):
        full += np.diag(ab[u - k, k:], k) + (np.diag(ab[u - k, k:], -k) if k else 0.0)
    np.testing.assert_allclose(full @ z, rhs, rtol=1e-9, atol=1e-9)


def test_planning_does_not_import_scipy_linalg() -> None:
    code = (
        "import sys\n"
        "from companion.mission import load_mission, mission_to_flight_plan\n"
        "from companion.planning.schedule import VehicleLimits, build_schedule\n"
        "from companion.replay.runner import DEFAULT_QUAD\n"
        f"m = load_mission({str(ROOT / 'examples' / 'missions' / 'square.plan')!r})\n"
        "s = build_schedule(mission_to_flight_plan(m, vehicle='quad'), DEFAULT_QUAD, "
        "VehicleLimits())\n"
        "assert s.duration_s > 10.0\n"
        "print(sorted(k for k in sys.modules if k.startswith('scipy')))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                         text=True, timeout=120, check=True).stdout
    assert out.strip() == "[]"
