"""benchmarks/bench_dembones.py's adapters: the mesh edges, the skinning and Dem Bones'
transform layout, against brute-force numpy forms (Dem Bones itself is an optional benchmark
dependency and not needed here)."""

from __future__ import annotations

import numpy as np
from benchmarks.bench_dembones import blend, dem_bones_transforms, knn_pairs
from scipy.spatial.transform import Rotation


def test_knn_pairs_against_all_distances() -> None:
    """Every pair of a point and one of its k nearest others, once, i < j (oracle: the full
    distance matrix)."""
    rng = np.random.default_rng(2)
    p = rng.normal(size=(60, 3))
    k = 4
    d = np.linalg.norm(p[:, None] - p[None], axis=2)
    np.fill_diagonal(d, np.inf)
    want = {tuple(sorted((i, int(j)))) for i in range(60) for j in np.argsort(d[i])[:k]}
    got = knn_pairs(p, k)
    assert got.shape[1] == 2 and np.all(got[:, 0] < got[:, 1])
    assert {tuple(map(int, e)) for e in got} == want
    assert len(got) == len(want)


def test_blend_against_a_per_point_loop() -> None:
    """Linear blend skinning against the sum over bones written out point by point."""
    rng = np.random.default_rng(3)
    rest = rng.normal(size=(7, 3))
    w = rng.random((7, 3))
    w /= w.sum(1, keepdims=True)
    R = Rotation.random(2 * 3, random_state=4).as_matrix().reshape(2, 3, 3, 3)
    T = rng.normal(size=(2, 3, 3))
    got = blend(rest, w, R, T)
    for f in range(2):
        for m in range(7):
            want = sum(w[m, b] * (R[f, b] @ rest[m] + T[f, b]) for b in range(3))
            np.testing.assert_allclose(got[f, m], want, rtol=1e-12, atol=1e-12)


def test_dem_bones_blocks_to_rotations_and_translations() -> None:
    """Dem Bones' (4F, 4B) matrix of column-vector affine blocks, frame by row block and bone
    by column block, read back as R, T (oracle: the blocks written by hand)."""
    R = Rotation.random(3 * 2, random_state=5).as_matrix().reshape(3, 2, 3, 3)
    T = np.arange(18, dtype=float).reshape(3, 2, 3)
    m = np.zeros((12, 8))
    for f in range(3):
        for b in range(2):
            m[4 * f:4 * f + 3, 4 * b:4 * b + 3] = R[f, b]
            m[4 * f:4 * f + 3, 4 * b + 3] = T[f, b]
            m[4 * f + 3, 4 * b + 3] = 1.0
    r, t = dem_bones_transforms(m, 3, 2)
    np.testing.assert_array_equal(r, R)
    np.testing.assert_array_equal(t, T)
