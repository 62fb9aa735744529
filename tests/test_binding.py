"""The native boundary: bad arrays raise Python exceptions, never panic; results match an
independent oracle."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pointrig import _core
from pointrig.errors import InputError


def test_kabsch_matches_scipy(rng):
    src = rng.normal(size=(50, 3))
    rot = Rotation.random(random_state=3)
    dst = rot.apply(src) + [0.1, 0.2, -0.3] + rng.normal(scale=1e-3, size=(50, 3))
    R, t = _core.kabsch(src, dst)
    est, _ = Rotation.align_vectors(dst - dst.mean(0), src - src.mean(0))
    np.testing.assert_allclose(R, est.as_matrix(), atol=1e-9)
    assert np.isclose(np.linalg.det(R), 1.0)
    np.testing.assert_allclose(t, dst.mean(0) - src.mean(0) @ R.T, atol=1e-12)


def test_wrong_shape_raises_value_error(rng):
    with pytest.raises(ValueError, match=r"\(n, 3\)"):
        _core.kabsch(rng.normal(size=(10, 4)), rng.normal(size=(10, 4)))


def test_non_contiguous_raises(rng):
    a = rng.normal(size=(10, 6))[:, ::2]
    assert not a.flags.c_contiguous
    with pytest.raises(ValueError, match="contiguous"):
        _core.kabsch(a, a)


def test_nan_raises_input_error(rng):
    a = rng.normal(size=(10, 3))
    b = a.copy()
    b[4, 2] = np.nan
    with pytest.raises(InputError, match="row 4"):
        _core.kabsch(a, b)


def test_wrong_dtype_and_lengths(rng):
    with pytest.raises(TypeError):
        _core.kabsch(np.zeros((10, 3), dtype=np.float32), np.zeros((10, 3)))
    with pytest.raises(ValueError, match="same number"):
        _core.kabsch(rng.normal(size=(10, 3)), rng.normal(size=(9, 3)))
    with pytest.raises(ValueError, match="one entry per point"):
        _core.kabsch(rng.normal(size=(10, 3)), rng.normal(size=(10, 3)), np.ones(3))


def test_fortran_ordered_array_is_rejected_not_read_transposed(rng):
    a = np.asfortranarray(rng.normal(size=(10, 3)))
    assert a.flags.f_contiguous and not a.flags.c_contiguous
    with pytest.raises(ValueError, match="C-contiguous"):
        _core.kabsch(a, np.ascontiguousarray(a))
