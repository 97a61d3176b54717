"""The two LAPACK routines the planner needs (banded Cholesky: ``dpbtrf``, ``dpbtrs``), from
SciPy's own LAPACK wrapper without the cost of importing ``scipy.linalg``.

``import scipy.linalg`` takes ~0.25 s (it pulls in numpy.testing, numpy.f2py and most of SciPy's
linear algebra) before a replay or a flight can plan; the two routines live in one extension
module, ``scipy/linalg/_flapack``, which loads in ~4 ms on its own. It is loaded from SciPy's
installed files, so the functions are the very ones ``scipy.linalg.lapack.dpbtrf`` /
``dpbtrs`` name (same library, same results bit for bit; tests/companion/trajectory/
test_fast_paths.py compares them). When ``scipy.linalg`` is already imported, or the module
cannot be found or loaded that way (another SciPy layout), the public import is used.
"""

from __future__ import annotations

import importlib.machinery
import importlib.util
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

LapackFn = Callable[..., Any]

_FUNCS: tuple[LapackFn, LapackFn] | None = None


def _public() -> tuple[LapackFn, LapackFn]:
    import scipy.linalg.lapack

    return scipy.linalg.lapack.dpbtrf, scipy.linalg.lapack.dpbtrs


def _direct() -> tuple[LapackFn, LapackFn] | None:
    """dpbtrf, dpbtrs of SciPy's ``linalg/_flapack`` extension, loaded by path (None: not
    found or not loadable)."""
    spec = importlib.util.find_spec("scipy")  # locates the package without importing it
    if spec is None or not spec.submodule_search_locations:
        return None
    name = "scipy.linalg._flapack"
    for folder in spec.submodule_search_locations:
        for suffix in importlib.machinery.EXTENSION_SUFFIXES:
            path = Path(folder) / "linalg" / f"_flapack{suffix}"
            if not path.is_file():
                continue
            ext = importlib.util.spec_from_file_location(name, path)
            if ext is None or ext.loader is None:
                return None
            had = name in sys.modules
            mod = importlib.util.module_from_spec(ext)
            ext.loader.exec_module(mod)
            if not had:  # single-phase init registers it; scipy.linalg would find it later
                sys.modules.pop(name, None)  # with its parents missing: leave no trace
            return mod.dpbtrf, mod.dpbtrs
    return None


def banded_cholesky() -> tuple[LapackFn, LapackFn]:
    """(dpbtrf, dpbtrs): LAPACK's banded Cholesky factorisation and solve, as SciPy wraps
    them (the signatures of ``scipy.linalg.lapack.dpbtrf`` / ``dpbtrs``)."""
    global _FUNCS
    if _FUNCS is None:
        funcs = None
        if "scipy.linalg" not in sys.modules:
            try:
                funcs = _direct()
            except Exception:  # any layout or loader surprise: the public way below
                funcs = None
        _FUNCS = funcs if funcs is not None else _public()
    return _FUNCS
