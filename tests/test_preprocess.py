"""Sparse points (flying pixels, outliers) go, the subject stays: in the rest surface and in
every input frame."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from scipy.spatial import cKDTree

from pointrig.config import PipelineConfig, PreprocessConfig, RegistrationConfig
from pointrig.errors import ConfigError, EmptyFrameError
from pointrig.geometry import knn_graph, remove_sparse_points, remove_statistical_outliers
from pointrig.pipeline import extract
from pointrig.preprocess import remove_sparse_frames, rest_surface
from pointrig.registration import register_sequence
from pointrig.sequence import PointSequence
from pointrig.synth import Camera, NoiseConfig, synthesize


def _plane_with_curtain(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A 60 x 60 grid at 5 mm (a surface seen by a depth camera) plus a curtain of flying
    pixels behind one edge (one per edge sample, up to 30 cm back) and uniform outliers;
    returns ``(points (N, 3), is_surface (N,))``."""
    rng = np.random.default_rng(seed)
    g = np.arange(60) * 0.005
    xx, yy = np.meshgrid(g, g)
    plane = np.column_stack([xx.ravel(), yy.ravel(), np.full(xx.size, 2.0)])
    plane[:, 2] += rng.normal(0, 0.001, len(plane))
    edge = plane[plane[:, 0] == g[-1]]
    curtain = edge + np.column_stack([np.zeros((len(edge), 2)),
                                      rng.uniform(0.0, 0.3, len(edge))])
    curtain = curtain[curtain[:, 2] > 2.05]  # within a few spacings they are surface-like
    outliers = rng.uniform([-0.3, -0.3, 1.7], [0.6, 0.6, 2.4], (40, 3))
    pts = np.vstack([plane, curtain, outliers])
    return pts, np.arange(len(pts)) < len(plane)


def test_sparse_points_go_where_the_statistical_removal_keeps_them() -> None:
    pts, surf = _plane_with_curtain()
    kept = remove_sparse_points(pts, 10, 4.0)
    tree = cKDTree(pts)
    idx = tree.query(kept)[1]
    assert np.all(tree.query(kept)[0] == 0.0)  # points are copied, not moved
    assert np.all(np.diff(idx) > 0)  # input order
    assert surf[idx].all()  # every curtain point and outlier is gone
    assert len(kept) >= 0.99 * surf.sum()  # and the surface stays
    # the statistical removal keeps some of them (the failure this guards against)
    sor = remove_statistical_outliers(pts, 20, 2.0)
    assert not surf[tree.query(sor)[1]].all()
    # 0 turns it off
    np.testing.assert_array_equal(remove_sparse_points(pts, 10, 0.0), pts)


def test_rest_surface_of_a_kinect_frame_lies_on_the_subject() -> None:
    """Default Kinect noise with flying pixels and 2 % outliers: the rest points against the
    renderer's true surface (oracle), with and without the sparse-point filter."""
    noise = dataclasses.replace(NoiseConfig(seed=2), outliers=0.02)
    syn = synthesize("human", n_frames=1, seed=1, camera=Camera.kinect(640), noise=noise)
    surface = syn.surface[0]
    size = float(np.linalg.norm(surface.max(0) - surface.min(0)))
    far = {}
    for ratio in (0.0, 4.0):
        rest = rest_surface(syn.frames[0], 2000, sparse_ratio=ratio)
        d = cKDTree(surface).query(rest)[0]
        far[ratio] = float(np.mean(d > 0.03 * size))
    assert far[0.0] > 0.03  # without it, farthest-point sampling picks the flying pixels
    assert far[4.0] < 0.005


def test_rest_sparse_parameters_are_validated() -> None:
    seq = PointSequence([np.random.default_rng(0).normal(size=(200, 3)) * 0.1 + [0, 0, 2]] * 2)
    for kw in ({"rest_sparse_ratio": 0.5}, {"rest_sparse_ratio": -1.0},
               {"rest_sparse_neighbors": 0}):
        with pytest.raises(ConfigError, match="rest_sparse"):
            register_sequence(seq, dataclasses.replace(RegistrationConfig(), **kw))


def _kth_distance_oracle(points: np.ndarray, k: int) -> np.ndarray:
    """Brute force: each point's distance to its ``k``-th nearest other point, ``(N,)``."""
    d = np.linalg.norm(points[:, None] - points[None], axis=-1)
    return np.sort(d, axis=1)[:, k]


def test_every_frame_is_cleaned_as_the_brute_force_rule_says() -> None:
    frames = [_plane_with_curtain(seed)[0][::3] for seed in range(3)]
    seq = PointSequence(frames, source="mem.npz", fmt="npz")
    out, removed = remove_sparse_frames(seq, 6, 3.0)
    assert out.source == seq.source and out.fmt == "npz" and out.names == seq.names
    for pts, kept, frac in zip(frames, out.frames, removed, strict=True):
        dk = _kth_distance_oracle(pts, 6)
        np.testing.assert_array_equal(kept, pts[dk <= 3.0 * np.median(dk)])
        assert frac == pytest.approx(1 - len(kept) / len(pts)) and 0 < frac < 0.2
    same, none = remove_sparse_frames(seq, 6, 0.0)
    assert same is seq and not none.any()


def test_a_frame_left_nearly_empty_is_an_error_naming_it() -> None:
    rng = np.random.default_rng(0)
    blob = rng.normal(size=(60, 3)) * 0.01 + [0, 0, 2]  # 60 close points ...
    scatter = rng.uniform(-1, 1, (40, 3)) + [0, 0, 2]  # ... and 40 far apart: these go
    seq = PointSequence([np.vstack([blob, blob + 0.001]), np.vstack([blob, scatter])],
                        source="rec.ply")
    assert [len(f) for f in remove_sparse_frames(seq, 5, 4.0)[0].frames] == [120, 60]
    with pytest.raises(EmptyFrameError, match=r"rec\.ply: frame 1: only 60 .*sparse_ratio = 0"):
        remove_sparse_frames(seq, 5, 4.0, min_points=70)


def test_extract_uses_the_cleaned_frames_and_records_both_counts(tmp_path) -> None:
    """A Kinect human with 2 % outliers: extract removes them from every frame (the counts in
    skeleton.json), and ``sparse_ratio = 0`` leaves the input as it is."""
    noise = dataclasses.replace(NoiseConfig(seed=3), outliers=0.02)
    syn = synthesize("arm", n_frames=4, seed=1, camera=Camera.kinect(320), noise=noise)
    seq = syn.to_point_sequence()
    cfg = PipelineConfig()
    res = extract(seq, cfg, tmp_path / "on", stop_after="structure", pictures=False)
    used = [len(f) for f in remove_sparse_frames(seq, 10, 4.0)[0].frames]
    doc = json.loads((tmp_path / "on" / "skeleton.json").read_text())
    assert doc["source"]["points_per_frame"] == [len(f) for f in seq.frames]
    assert doc["source"]["points_used_per_frame"] == used
    assert doc["params"]["preprocess"]["sparse_ratio"] == 4.0
    np.testing.assert_allclose(res.sparse_removed, 1 - np.array(used) / seq.counts)
    assert (res.sparse_removed > 0.01).all()  # at least half of the 2 % outliers go
    off = dataclasses.replace(cfg, preprocess=PreprocessConfig(sparse_ratio=0))
    res0 = extract(seq, off, None, stop_after="registration")
    assert not res0.sparse_removed.any()
    assert res0.registration.key != res.registration.key  # a different input for step 1


@pytest.mark.parametrize("kw", [{"sparse_ratio": 1.0}, {"sparse_ratio": -2.0},
                                {"sparse_ratio": float("inf")}, {"sparse_neighbors": 0},
                                {"sparse_neighbors": 2.5}, {"sparse_ratio": "4"}])
def test_frame_sparse_parameters_are_checked_when_the_config_is_made(kw) -> None:
    with pytest.raises(ConfigError, match=r"\[preprocess\] sparse_"):
        PreprocessConfig(**kw)


@pytest.mark.parametrize("cap", [None, 1.2])
def test_knn_graph_is_the_brute_force_neighbour_graph(cap) -> None:
    rng = np.random.default_rng(3)
    X = rng.normal(size=(120, 3))
    X[:40] *= 0.2  # a dense clump, so a cap cuts some edges
    k = 6
    D = np.linalg.norm(X[:, None] - X[None], axis=2)
    np.fill_diagonal(D, np.inf)
    nearest = np.argsort(D, axis=1)[:, :k]
    kth = np.sort(D, axis=1)[:, k - 1]
    want = np.zeros_like(D)
    for i in range(len(X)):
        for j in nearest[i]:
            if cap is None or D[i, j] <= cap * np.median(kth):
                want[i, j] = D[i, j]
    G = knn_graph(X, k, cap=cap).toarray()
    np.testing.assert_allclose(G, want, rtol=0, atol=1e-12)
    if cap is not None:
        assert 0 < np.count_nonzero(G) < len(X) * k
