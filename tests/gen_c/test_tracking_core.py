"""The tracking law's core as generated C (`ecca_tracking_core`, double and float) against the
Python core the companion flies (companion.control.core on floats), on golden vectors recorded
at the setpoints of real-PX4 flights (gen_c/tests/core_vectors.json, bench/core_vectors.py:
figure-8 at 6 m/s, attitude mode nominal and rates mode with SIH_MASS 0.8) and on random
inputs: double to 1e-9, float to 1e-4 relative (scale max(|field|, 1)), the limits and the
integrator included. Float evaluates the float-rounded inputs; a vector whose saturation
decision sits within float rounding of its threshold is compared only where it cannot flip."""

from __future__ import annotations

import json

import numpy as np
import pytest

import companion.flatness._formulas as fm
from companion.control.core import CORE_INPUTS, CORE_N_IN, CORE_OUTPUTS, tracking_core
from gen_c import native
from tests.support.core_inputs import OFFSET, random_core_inputs
from tests.support.gen_c import TESTS, assert_close

VECTORS = TESTS / "core_vectors.json"
OUT = {name: sum(n for _, n in CORE_OUTPUTS[:i]) for i, (name, _) in enumerate(CORE_OUTPUTS)}
FIELDS = [(name, OUT[name], n) for name, n in CORE_OUTPUTS]
RTOL_DOUBLE = 1e-9
RTOL_FLOAT = 1e-4


def golden() -> np.ndarray:
    doc = json.loads(VECTORS.read_text(encoding="utf-8"))
    assert [tuple(x) for x in doc["inputs_layout"]] == list(CORE_INPUTS), (
        "core_vectors.json was recorded with another input layout: run bench/core_vectors.py")
    return np.array(doc["inputs"], dtype=np.float64)


def f32(x: np.ndarray) -> np.ndarray:
    return x.astype(np.float32).astype(np.float64)


def compare(got: np.ndarray, exp: list[float], rtol: float, what: str) -> None:
    for name, o, n in FIELDS:
        assert_close(got[o:o + n], exp[o:o + n], rtol, f"{what} {name}")


def test_the_golden_vectors_come_from_flights_that_exercised_the_limits_and_integrator() -> None:
    xs = golden()
    doc = json.loads(VECTORS.read_text(encoding="utf-8"))
    assert {f["target"] for f in doc["flights"]} == {"px4"}
    assert xs.shape[1] == CORE_N_IN and len(xs) >= 150
    ys = [tracking_core(fm.FLOAT, x.tolist()) for x in xs]
    sat = [y[OUT["saturated"]] == 1.0 for y in ys]
    integ = [x[OFFSET["integ"]:OFFSET["integ"] + 3] for x in xs]
    moved = [not np.array_equal(y[OUT["integ"]:OUT["integ"] + 3], i)
             for y, i in zip(ys, integ, strict=True)]
    assert sum(sat) >= 40 and sum(not s for s in sat) >= 40
    assert sum(m and not s for m, s in zip(moved, sat, strict=True)) >= 40  # the integrator ran
    assert sum(x[OFFSET["fb_share"]] > 0 for x in xs) >= 40  # rates mode's feedback jerk
    assert any(x[OFFSET["drag"]] > 0 for x in xs)


def test_c_double_agrees_with_python_on_real_flight_vectors(lib: native.NativeSetpoint) -> None:
    for i, x in enumerate(golden()):
        compare(lib.tracking_core(x), tracking_core(fm.FLOAT, x.tolist()), RTOL_DOUBLE,
                f"vector {i}")


def test_c_double_agrees_with_python_on_random_inputs(lib: native.NativeSetpoint) -> None:
    for i, x in enumerate(random_core_inputs(np.random.default_rng(41), 400)):
        compare(lib.tracking_core(x), tracking_core(fm.FLOAT, x.tolist()), RTOL_DOUBLE,
                f"random {i}")


def _near_switch(x: np.ndarray) -> bool:
    """The saturation decision of `x` changes within float rounding of its inputs."""
    base = tracking_core(fm.FLOAT, x.tolist())[OUT["saturated"]]
    for k in (1.0 + 2e-7, 1.0 - 2e-7):
        y = x.copy()
        y[OFFSET["pos"]:OFFSET["pos"] + 3] *= k
        if tracking_core(fm.FLOAT, y.tolist())[OUT["saturated"]] != base:
            return True
    return False


def test_c_float_agrees_with_python_on_real_flight_vectors(lib: native.NativeSetpoint) -> None:
    n = 0
    for i, x in enumerate(golden()):
        xf = f32(x)
        if _near_switch(xf):
            continue
        compare(lib.tracking_core(xf, precision="float"), tracking_core(fm.FLOAT, xf.tolist()),
                RTOL_FLOAT, f"vector {i}")
        n += 1
    assert n >= 150  # (the vectors on a threshold are rare)


def test_c_refuses_what_it_cannot_evaluate(lib: native.NativeSetpoint) -> None:
    x = golden()[0]
    for name, bad in (("pos", np.nan), ("vel", np.inf), ("hover", 0.0), ("mass", -1.0),
                      ("g", 0.0), ("kp", 1e13)):
        y = x.copy()
        y[OFFSET[name]] = bad
        with pytest.raises(ValueError):
            lib.tracking_core(y)
    with pytest.raises(ValueError):
        lib.tracking_core(x[:-1])


def test_the_c_offsets_of_the_checked_inputs_are_the_python_layout() -> None:
    src = (TESTS.parent / "ecca_setpoint" / "ecca_setpoint_impl.inc").read_text()
    for name, macro in (("hover", "HOVER"), ("mass", "MASS"), ("g", "G")):
        assert f"#define ECCA_CORE_IN_{macro} {OFFSET[name]}\n" in src
    hdr = (TESTS.parent / "ecca_setpoint" / "ecca_setpoint.h").read_text()
    assert f"#define ECCA_CORE_N_IN {CORE_N_IN}\n" in hdr
    assert f"#define ECCA_CORE_N_OUT {sum(n for _, n in CORE_OUTPUTS)}\n" in hdr

