"""The Rust nearest-distance grid and chamfer misfit against scipy's k-d tree and numpy."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from pointrig import _core
from pointrig.errors import InputError
from pointrig.geometry import chamfer_misfit, nearest_distances, nearest_distances_grouped


def _scan_cloud(rng: np.random.Generator, n: int, outliers: float = 0.02) -> np.ndarray:
    """A noisy cylinder seen as a depth frame (``(n, 3)``, metres) with uniform outliers."""
    t = rng.uniform(0.0, np.pi, n)
    z = rng.uniform(0.0, 1.2, n)
    p = np.c_[0.15 * np.cos(t), z, 2.0 - 0.15 * np.sin(t)] + rng.normal(0, 0.003, (n, 3))
    k = int(outliers * n)
    p[:k] = rng.uniform([-1.0, -0.5, 1.0], [1.0, 1.7, 3.5], (k, 3))
    return p


@pytest.mark.parametrize("cap", [1e-3, 0.02, 0.3, 1e6])
def test_distances_equal_the_kd_tree(cap: float) -> None:
    """Every capped distance equals scipy's exact nearest distance capped, for queries on
    the surface, off it, and far outside the points' box."""
    rng = np.random.default_rng(1)
    pts = _scan_cloud(rng, 3000)
    q = np.vstack([_scan_cloud(rng, 2000), rng.uniform(-5, 5, (200, 3)),
                   [[100.0, -40.0, 7.0]]])
    want = np.minimum(cKDTree(pts).query(q)[0], cap)
    got = _core.capped_nn_distances(q, pts, cap)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    np.testing.assert_allclose(nearest_distances(q, pts, cap), want, rtol=0, atol=1e-12)


def test_grouped_distances_equal_the_kd_tree_per_group() -> None:
    """Each group's queries against its own points only, as scipy's k-d tree of that group
    gives them (capped); a group without points gives the cap, one without queries nothing;
    offsets that do not end at the row count are a typed error."""
    rng = np.random.default_rng(4)
    pts = [_scan_cloud(rng, 800), np.zeros((0, 3)), _scan_cloud(rng, 300) + [0.0, 0.0, 1.0],
           _scan_cloud(rng, 500)]
    qs = [_scan_cloud(rng, 400), _scan_cloud(rng, 50), np.zeros((0, 3)),
          rng.uniform(-2, 2, (120, 3))]
    cap = 0.25
    want = np.concatenate([np.minimum(cKDTree(p).query(q)[0], cap) if len(p) else
                           np.full(len(q), cap) for p, q in zip(pts, qs)])
    offs = [np.concatenate([[0], np.cumsum([len(x) for x in xs])]) for xs in (qs, pts)]
    got = nearest_distances_grouped(np.concatenate(qs), offs[0], np.concatenate(pts), offs[1],
                                    cap)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    with pytest.raises(InputError, match="query_offsets"):
        nearest_distances_grouped(np.concatenate(qs), offs[0] - 1, np.concatenate(pts),
                                  offs[1], cap)


def test_degenerate_clouds() -> None:
    """A single point, duplicated points, a flat and a collinear cloud: exact distances."""
    rng = np.random.default_rng(2)
    q = rng.normal(size=(300, 3))
    clouds = [np.zeros((1, 3)), np.repeat(rng.normal(size=(1, 3)), 50, axis=0),
              np.c_[rng.normal(size=(400, 2)), np.zeros(400)],
              np.c_[np.linspace(-1, 1, 200), np.zeros((200, 2))]]
    for pts in clouds:
        want = cKDTree(pts).query(q)[0]
        np.testing.assert_allclose(nearest_distances(q, pts), want, rtol=0, atol=1e-12)
    assert np.all(nearest_distances(q, np.empty((0, 3)), 0.5) == 0.5)


def test_chamfer_equals_the_pairwise_oracle() -> None:
    """The chamfer misfit against all pairwise distances in numpy, caps below, inside and
    above the distances' range."""
    rng = np.random.default_rng(3)
    a = _scan_cloud(rng, 400)
    b = _scan_cloud(rng, 700) + [0.01, 0.0, 0.0]
    d = np.linalg.norm(a[:, None] - b[None], axis=2)
    for cap in (1e-3, 0.01, 0.2, 50.0):
        ref = np.minimum(d.min(1), cap).mean() + np.minimum(d.min(0), cap).mean()
        assert chamfer_misfit(a, b, cap) == pytest.approx(ref, rel=1e-12)


def test_bad_input_is_a_typed_error() -> None:
    """Non-finite points, a non-positive cap, empty sets for the chamfer, wrong shapes."""
    ok = np.zeros((4, 3))
    bad = ok.copy()
    bad[2, 1] = np.nan
    with pytest.raises(InputError):
        _core.capped_nn_distances(ok, bad, 1.0)
    with pytest.raises(ValueError):
        _core.capped_nn_distances(ok, ok, 0.0)
    with pytest.raises(ValueError):
        _core.chamfer_misfit(np.empty((0, 3)), ok, 1.0)
    with pytest.raises(ValueError):
        _core.capped_nn_distances(np.zeros((4, 2)), ok, 1.0)


def _fps_numpy(points: np.ndarray, n: int, seed: int) -> np.ndarray:
    """Farthest-point sampling as a plain numpy loop (the oracle)."""
    m = len(points)
    rng = np.random.default_rng(seed)
    idx = np.empty(n, dtype=np.int64)
    idx[0] = rng.integers(m)
    d = np.sum((points - points[idx[0]]) ** 2, axis=1)
    for i in range(1, n):
        idx[i] = int(np.argmax(d))
        d = np.minimum(d, np.sum((points - points[idx[i]]) ** 2, axis=1))
    return idx


def test_farthest_point_sampling_equals_the_numpy_loop() -> None:
    """The same indices as the numpy loop, on a depth-like cloud and on a grid full of
    ties; ``n >= m`` returns every index."""
    from pointrig.geometry import farthest_point_sampling

    rng = np.random.default_rng(4)
    cloud = _scan_cloud(rng, 5000)
    g = np.stack(np.meshgrid(*[np.arange(8.0)] * 3, indexing="ij"), -1).reshape(-1, 3) * 0.01
    for pts, n, seed in ((cloud, 700, 0), (cloud, 50, 9), (g, 200, 3)):
        np.testing.assert_array_equal(farthest_point_sampling(pts, n, seed),
                                      _fps_numpy(pts, n, seed))
    np.testing.assert_array_equal(farthest_point_sampling(g[:10], 10), np.arange(10))


@pytest.mark.parametrize("k", [1, 2, 11, 30])
def test_kth_distances_equal_the_kd_tree(k: int) -> None:
    """The ``k``-th nearest distance equals scipy's ``query(points, k)[:, -1]``, the query
    set being the points themselves (each its own first) and a set off them."""
    rng = np.random.default_rng(5)
    pts = _scan_cloud(rng, 2500)
    tree = cKDTree(pts)
    np.testing.assert_allclose(_core.kth_nn_distances(pts, pts, k),
                               tree.query(pts, k=[k])[0][:, 0], rtol=0, atol=1e-12)
    q = rng.uniform(-2, 3, (300, 3))
    np.testing.assert_allclose(_core.kth_nn_distances(q, pts, k),
                               tree.query(q, k=[k])[0][:, 0], rtol=0, atol=1e-12)
    with pytest.raises(ValueError):
        _core.kth_nn_distances(q, pts[:3], 4)


def test_remove_sparse_points_keeps_what_the_kd_tree_rule_keeps() -> None:
    """:func:`remove_sparse_points` keeps exactly the points whose ``k``-th neighbour
    distance (itself not counted; by scipy) is within ``ratio`` times its median."""
    from pointrig.geometry import remove_sparse_points

    rng = np.random.default_rng(6)
    pts = _scan_cloud(rng, 4000, outliers=0.05)
    for k, ratio in ((10, 4.0), (4, 2.0)):
        dk = cKDTree(pts).query(pts, k=k + 1)[0][:, -1]
        want = pts[dk <= ratio * np.median(dk)]
        assert len(want) < len(pts)
        np.testing.assert_array_equal(remove_sparse_points(pts, k, ratio), want)


def test_stray_points_far_away_keep_distances_exact() -> None:
    """Stray points a kilometre and a thousand kilometres from the subject (searched in far
    levels of their own) and queries beyond them: nearest and k-th distances equal scipy's."""
    rng = np.random.default_rng(7)
    pts = _scan_cloud(rng, 3000)
    pts[:3] = [[0.0, 1e3, 2.0], [-2e6, 0.5, 2.0], [0.3, 0.2, 1e6]]
    q = np.vstack([_scan_cloud(rng, 500), [[0.0, 2e3, 2.0], [-1e6, 0.0, 0.0], [5.0, 5.0, 5.0]]])
    tree = cKDTree(pts)
    for cap in (0.01, 1.0, 1e7):
        np.testing.assert_allclose(_core.capped_nn_distances(q, pts, cap),
                                   np.minimum(tree.query(q)[0], cap), rtol=1e-12, atol=1e-9)
    for k in (1, 10):
        np.testing.assert_allclose(_core.kth_nn_distances(q, pts, k),
                                   tree.query(q, k=[k])[0][:, 0], rtol=1e-12, atol=1e-9)


def test_no_cap_means_no_cap() -> None:
    """``nearest_distances`` without a cap returns the exact distance even to a point
    10^9 m away, and an empty point set gives the largest float."""
    pts = np.array([[0.0, 1e9, 0.0], [0.0, 2e9, 0.0]])
    q = np.zeros((2, 3))
    np.testing.assert_allclose(nearest_distances(q, pts), [1e9, 1e9], rtol=1e-15)
    assert np.all(nearest_distances(q, np.empty((0, 3))) == np.finfo(np.float64).max)
