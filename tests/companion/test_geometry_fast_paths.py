"""`dcm_to_quat` of one (3, 3) matrix (a float fast path: the rates-mode controller calls it every
setpoint) gives the bits of the batched array code, which a (1, 3, 3) batch still runs."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from companion.geometry import dcm_to_quat


def _same_bits(m: np.ndarray) -> None:
    single = dcm_to_quat(m)
    batched = dcm_to_quat(m[None])[0]
    assert single.shape == (4,) and single.dtype == np.float64
    assert single.tobytes() == batched.tobytes(), (single, batched)


def test_rotations_and_perturbed_matrices_give_the_array_paths_bits() -> None:
    rng = np.random.default_rng(11)
    rots = Rotation.random(3000, random_state=12).as_matrix()
    for m in rots:
        _same_bits(m)
    for m in rots[:1000]:
        _same_bits(m + rng.normal(0.0, 1e-3, (3, 3)))  # not quite orthogonal
    for _ in range(1000):
        _same_bits(rng.normal(0.0, 1.0, (3, 3)))  # any matrix: every branch, negative w


@pytest.mark.parametrize("angle_gap", [1e-12, 1e-9, 1e-6, 1e-3])
def test_rotations_near_pi_give_the_array_paths_bits(angle_gap: float) -> None:
    rng = np.random.default_rng(13)
    for ax in rng.normal(size=(200, 3)):
        _same_bits(Rotation.from_rotvec(ax / np.linalg.norm(ax) * (math.pi - angle_gap))
                   .as_matrix())


@pytest.mark.parametrize("diag", [(1.0, 1.0, 1.0), (-1.0, -1.0, 1.0), (1.0, -1.0, -1.0),
                                  (-1.0, 1.0, -1.0), (0.0, 0.0, 0.0), (0.5, 0.5, 0.5),
                                  (-1.0, -1.0, -1.0)])
def test_ties_between_branches_pick_the_same_branch(diag: tuple[float, float, float]) -> None:
    _same_bits(np.diag(diag))


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
@pytest.mark.parametrize("where", [(0, 0), (1, 2), (2, 1)])
def test_non_finite_matrices_still_take_the_array_path(bad: float, where: tuple[int, int]
                                                       ) -> None:
    m = np.eye(3)
    m[where] = bad
    with np.errstate(invalid="ignore"):
        single, batched = dcm_to_quat(m), dcm_to_quat(m[None])[0]
    assert single.tobytes() == batched.tobytes()


@settings(max_examples=300, deadline=None)
@given(st.lists(st.floats(-1e3, 1e3), min_size=9, max_size=9))
def test_any_finite_matrix_gives_the_array_paths_bits(vals: list[float]) -> None:
    _same_bits(np.array(vals).reshape(3, 3))
