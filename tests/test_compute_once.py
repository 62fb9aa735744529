"""Work the pipeline does once instead of several times: a frame's normals kept for the steps
that estimate them again (geometry.reuse_normals), with the same values as computed afresh."""

from __future__ import annotations

import numpy as np
import pytest

import pointrig.geometry as geometry
from pointrig import _core
from pointrig.geometry import estimate_normals, keep_normals, reuse_normals


def _sphere_cap(n: int, seed: int) -> np.ndarray:
    """``(n, 3)`` points on the camera-facing half of a 0.3 m sphere 2 m away, metres."""
    d = np.random.default_rng(seed).normal(size=(3 * n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d = d[d[:, 2] < 0][:n]
    return np.array([0.0, 0.0, 2.0]) + 0.3 * d


@pytest.fixture
def native_calls(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """Counts the calls of the native normal estimator."""
    calls = [0]
    real = _core.surface_normals

    def counting(*args: object) -> np.ndarray:
        calls[0] += 1
        return real(*args)

    monkeypatch.setattr(_core, "surface_normals", counting)
    return calls


def test_reused_normals_equal_fresh_ones_and_are_computed_once(native_calls: list[int]
                                                                ) -> None:
    """Inside the block a repeated estimate (an equal copy of the points, not the same array)
    is the first one bit for bit without a second native call; another radius, source or
    camera, or changed points, is computed anew; the caller may change what it got; after the
    block everything is computed again. Oracle: the estimate outside any block."""
    pts = _sphere_cap(2000, 1)
    src = _sphere_cap(3000, 2)
    fresh = estimate_normals(pts, 0.04)
    fresh_src = estimate_normals(pts, 0.04, source=src)
    assert native_calls[0] == 2
    with reuse_normals():
        first = estimate_normals(pts, 0.04)
        first[:] = 0.0  # the caller's copy, not the kept one
        again = estimate_normals(pts.copy(), 0.04)
        assert native_calls[0] == 3
        np.testing.assert_array_equal(again, fresh)
        np.testing.assert_array_equal(estimate_normals(pts, 0.04, source=src), fresh_src)
        estimate_normals(pts, 0.05)
        estimate_normals(pts, 0.04, camera=(0.0, 0.0, 5.0))
        moved = pts.copy()
        moved[0, 0] += 1e-12
        estimate_normals(moved, 0.04)
        assert native_calls[0] == 7
        np.testing.assert_array_equal(estimate_normals(pts, 0.04, source=src), fresh_src)
        assert native_calls[0] == 7
    estimate_normals(pts, 0.04)
    assert native_calls[0] == 8
    assert not geometry._NORMALS.store and geometry._NORMALS.nbytes == 0


def test_budget_and_keep_normals(native_calls: list[int]) -> None:
    """At most the budget is kept, the oldest dropped first; ``keep_normals`` drops every
    other radius."""
    a, b, c = (_sphere_cap(1000, s) for s in (3, 4, 5))
    one = estimate_normals(a, 0.04).nbytes
    native_calls[0] = 0
    with reuse_normals(max_bytes=2 * one):
        for p in (a, b, c):
            estimate_normals(p, 0.04)
        assert native_calls[0] == 3
        assert geometry._NORMALS.nbytes <= 2 * one
        estimate_normals(c, 0.04)
        estimate_normals(b, 0.04)
        assert native_calls[0] == 3  # the two newest kept
        estimate_normals(a, 0.04)
        assert native_calls[0] == 4  # the oldest dropped
    with reuse_normals():
        estimate_normals(a, 0.04)
        estimate_normals(b, 0.05)
        keep_normals(0.05)
        estimate_normals(b, 0.05)
        assert native_calls[0] == 6
        estimate_normals(a, 0.04)
        assert native_calls[0] == 7
